//! The network model a command runs: a file the user names, or the default model compiled in.

use std::path::{Path, PathBuf};

use anyhow::Result;
use radn_core::confidence::{DEFAULT_COLOR_CONFIDENCE, DEFAULT_GUIDE_CONFIDENCE};
use radn_nn::burn::tensor::Device;
use radn_nn::model::Denoiser;

/// The default model (`models/default.safetensors`, see `models/README.md`), compiled into the
/// binary so `radn denoise` works without a model flag and without files beside the executable.
pub const DEFAULT_MODEL: &[u8] = include_bytes!("../../../models/default.safetensors");

/// The name errors and reports use for the compiled-in model.
pub const DEFAULT_MODEL_NAME: &str = "<built-in default model>";

/// The guided model compiled in like the default: what `radn denoise --guide …` runs when no
/// `--model` is given. It is guided-lean (`models/guided-lean.safetensors`, see
/// `models/README.md`), the guided model whose whole command stays within twice OIDN's time;
/// the larger `models/guided.safetensors` is 0.07 dB ahead on validation at five times its cost.
pub const GUIDED_MODEL: &[u8] = include_bytes!("../../../models/guided-lean.safetensors");

/// The name errors and reports use for the compiled-in guided model.
pub const GUIDED_MODEL_NAME: &str = "<built-in guided model>";

/// Loads `path`, or the compiled-in default model when none is given.
pub fn load(path: Option<&Path>, device: &Device) -> Result<Denoiser> {
    load_for(path, false, device)
}

/// Loads `path`, or when none is given the compiled-in guided model if `guided` (a guide was
/// asked for), else the compiled-in default.
pub fn load_for(path: Option<&Path>, guided: bool, device: &Device) -> Result<Denoiser> {
    Ok(match path {
        Some(p) => radn_nn::model::store::load(p, device)?,
        None => {
            let (bytes, name) = builtin(guided);
            radn_nn::model::store::load_bytes(bytes, Path::new(name), device)?
        }
    })
}

fn builtin(guided: bool) -> (&'static [u8], &'static str) {
    if guided {
        (GUIDED_MODEL, GUIDED_MODEL_NAME)
    } else {
        (DEFAULT_MODEL, DEFAULT_MODEL_NAME)
    }
}

/// The network a command runs: the model `path` (or the compiled-in one `guide` calls for) on
/// `device`, after checking that the model and the guide options fit each other, with
/// alignment's default appearance term: the guide term for runs with a guide, the colour term
/// for runs without; runs with a guide also loosen the sampled buffers' terms with the noise
/// level ([`radn_nn::infer::sampled_terms_loosening`]).
pub fn network_for(
    path: Option<&Path>,
    guide: &crate::input::GuideArgs,
    device: radn_nn::device::ComputeDevice,
) -> Result<radn_nn::infer::NetworkDenoiser> {
    let device = device.open()?;
    let guided = guide.guide.is_some();
    let d = load_for(path, guided, &device)?;
    guide.check_model(&d, &label_for(path, guided))?;
    let mut n = radn_nn::infer::NetworkDenoiser::new(d, device);
    // alignment's appearance terms: the guides where the run has them, else the frames' own
    // colour (docs/guided.md, "Guide confidence" and "Colour confidence")
    n.align.confidence.guide = guided.then_some(DEFAULT_GUIDE_CONFIDENCE);
    n.color_confidence = (!guided).then_some(DEFAULT_COLOR_CONFIDENCE);
    // the sampled buffers' terms loosen with the noise level where a guide's term checks
    // appearance (docs/guided.md, "Confidence on fur")
    n.loosen_sampled_terms = guided.then_some(radn_nn::infer::DEFAULT_SAMPLED_TERMS_LOOSENING);
    Ok(n)
}

/// How a model choice is shown to the user: the file, or the compiled-in guided model for a
/// run that asked for a guide (`guided`), else the compiled-in default.
pub fn label_for(path: Option<&Path>, guided: bool) -> PathBuf {
    path.map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from(builtin(guided).1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_compiled_in_default_model_loads() {
        let d = load(None, &Device::flex()).unwrap();
        assert!(d.config.frames == 5 && d.config.kernel_taps() > 0);
        assert!(!d.config.inputs.guide);
    }

    #[test]
    fn a_guide_without_a_model_picks_the_compiled_in_guided_model() {
        let d = load_for(None, true, &Device::flex()).unwrap();
        assert!(
            d.config.inputs.guide,
            "the built-in guided model reads a guide"
        );
        assert_eq!(label_for(None, true), PathBuf::from(GUIDED_MODEL_NAME));
    }
}
