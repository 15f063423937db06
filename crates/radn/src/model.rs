//! The network model a command runs: a file the user names, or the default model compiled in.

use std::path::{Path, PathBuf};

use anyhow::Result;
use radn_nn::burn::tensor::Device;
use radn_nn::model::Denoiser;

/// The default model (`models/default.safetensors`, see `models/README.md`), compiled into the
/// binary so `radn denoise` works without a model flag and without files beside the executable.
pub const DEFAULT_MODEL: &[u8] = include_bytes!("../../../models/default.safetensors");

/// The name errors and reports use for the compiled-in model.
pub const DEFAULT_MODEL_NAME: &str = "<built-in default model>";

/// Loads `path`, or the compiled-in default model when none is given.
pub fn load(path: Option<&Path>, device: &Device) -> Result<Denoiser> {
    Ok(match path {
        Some(p) => radn_nn::model::store::load(p, device)?,
        None => {
            radn_nn::model::store::load_bytes(DEFAULT_MODEL, Path::new(DEFAULT_MODEL_NAME), device)?
        }
    })
}

/// How a model choice is shown to the user.
pub fn label(path: Option<&Path>) -> PathBuf {
    path.map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from(DEFAULT_MODEL_NAME))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_compiled_in_default_model_loads() {
        let d = load(None, &Device::flex()).unwrap();
        assert!(d.config.frames == 5 && d.config.kernel_taps() > 0);
    }
}
