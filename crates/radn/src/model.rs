//! The network a command runs: a file the user names, or one of the models compiled in; and
//! which path `radn denoise` takes when the guide is left to it (the guided path, its guides
//! from an OIDN library where one opens, else from radn's compiled-in copies of OIDN's networks).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{anyhow, Result};
use radn_core::guide::{GuideChoice, OidnDevice, OidnGuides};
use radn_nn::burn::tensor::Device;
use radn_nn::device::ComputeDevice;
use radn_nn::infer::NetworkDenoiser;
use radn_nn::model::Denoiser;

/// The unguided default model (`models/default.safetensors`, card `models/default.md`),
/// compiled into the binary so `radn denoise` works without files beside the executable.
pub const DEFAULT_MODEL: &[u8] = include_bytes!("../../../models/default.safetensors");

/// The name errors and reports use for the compiled-in unguided model.
pub const DEFAULT_MODEL_NAME: &str = "<built-in default model>";

/// The guided model compiled in like the default (`models/guided-mix.safetensors`, card
/// `models/guided-mix.md`): what runs over OIDN when no `--model` is given.
pub const GUIDED_MODEL: &[u8] = include_bytes!("../../../models/guided-mix.safetensors");

/// The name errors and reports use for the compiled-in guided model.
pub const GUIDED_MODEL_NAME: &str = "<built-in guided model>";

/// OIDN's noisy-auxiliary U-Net (`rt_hdr_alb_nrm`), converted by `radn model import-oidn`
/// and compiled in (Apache-2.0, `models/NOTICE`): what `--method spatial` runs.
const UNET_BEAUTY: &[u8] = include_bytes!("../../../models/oidn-rt_hdr_alb_nrm.safetensors");
/// OIDN's large clean-auxiliary U-Net (`rt_hdr_calb_cnrm_large`), for `--prefilter`.
const UNET_BEAUTY_CLEAN: &[u8] =
    include_bytes!("../../../models/oidn-rt_hdr_calb_cnrm_large.safetensors");
/// OIDN's colour-only U-Net (`rt_hdr`), for guides of frames without auxiliaries.
const UNET_BEAUTY_PLAIN: &[u8] = include_bytes!("../../../models/oidn-rt_hdr.safetensors");
/// OIDN's albedo-only U-Net (`rt_hdr_alb`), for guides of frames without normals.
const UNET_BEAUTY_ALBEDO: &[u8] = include_bytes!("../../../models/oidn-rt_hdr_alb.safetensors");
/// OIDN's large albedo prefilter (`rt_alb_large`).
const UNET_ALBEDO: &[u8] = include_bytes!("../../../models/oidn-rt_alb_large.safetensors");
/// OIDN's large normal prefilter (`rt_nrm_large`).
const UNET_NORMAL: &[u8] = include_bytes!("../../../models/oidn-rt_nrm_large.safetensors");

/// OIDN's standard albedo prefilter (`rt_alb`), for converted networks with prefiltered
/// auxiliaries.
const UNET_ALBEDO_STANDARD: &[u8] = include_bytes!("../../../models/oidn-rt_alb.safetensors");
/// OIDN's standard normal prefilter (`rt_nrm`).
const UNET_NORMAL_STANDARD: &[u8] = include_bytes!("../../../models/oidn-rt_nrm.safetensors");

/// One of the compiled-in OIDN U-Nets (`bytes`), named `<built-in NAME>` in messages.
fn builtin_unet(bytes: &[u8], name: &str) -> Result<radn_nn::oidn_unet::filter::UnetFilter> {
    Ok(radn_nn::oidn_unet::filter::UnetFilter::new(
        &radn_nn::oidn_unet::store::load_bytes(
            bytes,
            Path::new(&format!("<built-in {name}>")),
            &Device::flex(),
        )?,
    ))
}

/// The spatial method: the U-Net file `path` or the compiled-in one, and with `prefilter`
/// the compiled-in auxiliary prefilters and (without `path`) the clean-auxiliary model.
pub fn spatial(
    path: Option<&Path>,
    prefilter: bool,
) -> Result<radn_nn::oidn_unet::denoiser::SpatialDenoiser> {
    use radn_nn::oidn_unet::{denoiser::SpatialDenoiser, filter::UnetFilter, store};
    let device = Device::flex();
    let beauty = match path {
        Some(p) => UnetFilter::new(&store::load(p, &device)?),
        None if prefilter => builtin_unet(UNET_BEAUTY_CLEAN, "rt_hdr_calb_cnrm_large")?,
        None => builtin_unet(UNET_BEAUTY, "rt_hdr_alb_nrm")?,
    };
    Ok(if prefilter {
        SpatialDenoiser::prefiltered(
            beauty,
            builtin_unet(UNET_ALBEDO, "rt_alb_large")?,
            builtin_unet(UNET_NORMAL, "rt_nrm_large")?,
        )
    } else {
        SpatialDenoiser::new(beauty)
    })
}

/// OIDN's standard albedo and normal prefilters (compiled in), which clean the auxiliaries of
/// converted clean-auxiliary networks, at inference and in their training tiles.
pub fn aux_prefilter() -> Result<radn_nn::oidn_unet::prefilter::AuxPrefilter> {
    Ok(radn_nn::oidn_unet::prefilter::AuxPrefilter::new(
        builtin_unet(UNET_ALBEDO_STANDARD, "rt_alb")?,
        builtin_unet(UNET_NORMAL_STANDARD, "rt_nrm")?,
    ))
}

/// The temporal method: the converted U-Net in model file `path`.
pub fn temporal(path: &Path) -> Result<radn_nn::oidn_unet::window_denoiser::TemporalDenoiser> {
    use radn_nn::oidn_unet::temporal::AuxSource;
    use radn_nn::oidn_unet::temporal_filter::TemporalFilter;
    use radn_nn::oidn_unet::temporal_store;
    use radn_nn::oidn_unet::window_denoiser::TemporalDenoiser;
    let net = temporal_store::load(path, &Device::flex())?;
    let prefilter = match net.config().aux {
        AuxSource::Rendered => None,
        AuxSource::Prefiltered => Some(aux_prefilter()?),
    };
    Ok(TemporalDenoiser::new(
        TemporalFilter::new(&net),
        net.config(),
        path.display().to_string(),
        prefilter,
    ))
}

/// OIDN's guides made by radn's compiled-in copies of OIDN's high-quality networks: the guided
/// path where no OIDN library is installed.
pub fn builtin_guides() -> Result<OidnGuides> {
    use radn_nn::oidn_unet::guide_filters::{BeautyModels, BuiltinGuideFilters};
    let net = builtin_unet;
    let filters = BuiltinGuideFilters::new(
        BeautyModels {
            plain: net(UNET_BEAUTY_PLAIN, "rt_hdr")?,
            albedo: net(UNET_BEAUTY_ALBEDO, "rt_hdr_alb")?,
            noisy_aux: net(UNET_BEAUTY, "rt_hdr_alb_nrm")?,
            clean_aux: net(UNET_BEAUTY_CLEAN, "rt_hdr_calb_cnrm_large")?,
        },
        net(UNET_ALBEDO, "rt_alb_large")?,
        net(UNET_NORMAL, "rt_nrm_large")?,
    );
    Ok(OidnGuides::with_filters(Box::new(filters)))
}

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

/// How a model choice is shown to the user: the file, or the compiled-in guided model for a
/// run that asked for a guide (`guided`), else the compiled-in default.
pub fn label_for(path: Option<&Path>, guided: bool) -> PathBuf {
    path.map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from(builtin(guided).1))
}

/// Which guide a run asked for: a choice, or `auto` (the best path this machine allows).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum GuideRequest {
    /// OIDN where a library is found (or the model needs a guide), none otherwise.
    Auto,
    /// This guide (`none` included).
    Given(GuideChoice),
}

impl std::str::FromStr for GuideRequest {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        Ok(match s {
            "auto" => GuideRequest::Auto,
            s => GuideRequest::Given(GuideChoice::parse(s)),
        })
    }
}

/// The network a run takes, its guide, and the line that tells the user which path it is.
pub struct ChosenPath {
    /// The network, running its model's recipe.
    pub network: NetworkDenoiser,
    /// The guide its frames get.
    pub guide: GuideChoice,
    /// OIDN, opened, where the guide is OIDN's.
    pub oidn: Option<Arc<OidnGuides>>,
    /// One line: which path, which model, which library.
    pub summary: String,
}

/// Chooses the network and its guide: a given guide is taken as given (with the built-in
/// model that reads it, unless `model` names one); `auto` takes the guided path when the
/// model reads a guide or no `model` is named (OIDN's guides come from its library where one
/// opens, else from radn's copies of its networks), and the unguided model otherwise. The
/// model and the guide are checked against each other.
pub fn choose_path(
    model: Option<&Path>,
    request: &GuideRequest,
    oidn_threads: usize,
    device: ComputeDevice,
) -> Result<ChosenPath> {
    let dev = device.open()?;
    let (denoiser, guide, oidn) = match request {
        GuideRequest::Given(guide) => {
            let d = load_for(model, guide.is_some(), &dev)?;
            check_model(&d, guide, &label_for(model, guide.is_some()))?;
            let oidn = open_oidn_for(guide, oidn_threads, device)?;
            (d, guide.clone(), oidn)
        }
        GuideRequest::Auto => match model {
            Some(p) => {
                let d = load_for(Some(p), false, &dev)?;
                let guide = if d.config.inputs.guide {
                    GuideChoice::Oidn
                } else {
                    GuideChoice::None
                };
                let oidn = open_oidn_for(&guide, oidn_threads, device)?;
                (d, guide, oidn)
            }
            None => (
                load_for(None, true, &dev)?,
                GuideChoice::Oidn,
                Some(Arc::new(open_oidn(oidn_threads, device)?)),
            ),
        },
    };
    let label = label_for(model, guide.is_some());
    let summary = match (&guide, &oidn) {
        (_, Some(o)) => format!(
            "radn: guided path: {} over {}",
            label.display(),
            o.describe()
        ),
        (GuideChoice::None, _) => format!("radn: unguided path: {}", label.display()),
        (GuideChoice::Denoised, _) => format!(
            "radn: guided path: {} over the renderer's denoised layer",
            label.display()
        ),
        (GuideChoice::Layer(l), _) => {
            format!("radn: guided path: {} over layer '{l}'", label.display())
        }
        (GuideChoice::Oidn, None) => unreachable!("an OIDN guide has its library open"),
    };
    Ok(ChosenPath {
        network: NetworkDenoiser::new(denoiser, dev),
        guide,
        oidn,
        summary,
    })
}

/// OIDN opened for `guide` where it is OIDN's (an error saying what to install where the
/// library is missing).
fn open_oidn_for(
    guide: &GuideChoice,
    threads: usize,
    device: ComputeDevice,
) -> Result<Option<Arc<OidnGuides>>> {
    Ok(match guide {
        GuideChoice::Oidn => Some(Arc::new(open_oidn(threads, device)?)),
        _ => None,
    })
}

/// OIDN on the network's device: on a GPU run its CUDA device (the guides then cost the CPU
/// nothing), falling back to the CPU with a warning where OIDN cannot use that GPU; where no
/// OIDN library opens, radn's compiled-in copies of its networks.
fn open_oidn(threads: usize, device: ComputeDevice) -> Result<OidnGuides> {
    let library = match device.into() {
        OidnDevice::Cpu => OidnGuides::new(threads),
        gpu => OidnGuides::on(gpu, threads).or_else(|e| {
            let cpu = OidnGuides::new(threads)?;
            tracing::warn!("{e}; OIDN's guides are made on the CPU instead");
            Ok(cpu)
        }),
    };
    match library {
        Ok(o) => Ok(o),
        Err(e) => {
            tracing::debug!("no OIDN library ({e}): guides from radn's built-in networks");
            builtin_guides()
        }
    }
}

/// Checks that `model` (shown as `label`) and `guide` go together: a guided model needs a
/// guide, and a guide needs a guided model.
pub fn check_model(model: &Denoiser, guide: &GuideChoice, label: &Path) -> Result<()> {
    match (model.config.inputs.guide, guide.is_some()) {
        (true, false) => Err(anyhow!(
            "{} reads a guide: give one with --guide oidn, --guide denoised or --guide LAYER",
            label.display()
        )),
        (false, true) => Err(anyhow!(
            "{} reads no guide, so --guide {} would change nothing: drop --guide or pass a \
             guided model with --model",
            label.display(),
            match guide {
                GuideChoice::Layer(l) => l.as_str(),
                GuideChoice::Oidn => "oidn",
                _ => "denoised",
            }
        )),
        _ => Ok(()),
    }
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

    #[test]
    fn a_given_guide_and_model_must_fit() {
        let cpu = radn_nn::device::ComputeDevice::Cpu;
        let none = GuideRequest::Given(GuideChoice::None);
        let p = choose_path(None, &none, 1, cpu).unwrap();
        assert!(!p.network.denoiser.config.inputs.guide && p.oidn.is_none());
        assert!(p.summary.contains("unguided") && !p.summary.contains("pyoidn"));
        let layer = GuideRequest::Given(GuideChoice::Layer("Combined".into()));
        let p = choose_path(None, &layer, 1, cpu).unwrap();
        assert!(p.network.denoiser.config.inputs.guide);
        assert!(p.summary.contains("layer 'Combined'"), "{}", p.summary);
        assert_eq!("auto".parse::<GuideRequest>(), Ok(GuideRequest::Auto));
        assert_eq!(
            "none".parse::<GuideRequest>(),
            Ok(GuideRequest::Given(GuideChoice::None))
        );
    }
}
