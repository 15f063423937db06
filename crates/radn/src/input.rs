//! Options shared by every command that reads frames: preset, mapping file, view layer,
//! NaN/Inf policy, turned into the frame reader they describe; and where a guided network's
//! guides come from.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{anyhow, Result};
use radn_core::exr_file::ExrFile;
use radn_core::frame::{FrameReader, Requirements};
use radn_core::guide::{GuideChoice, OidnGuides};
use radn_core::hygiene::NonFinitePolicy;
use radn_core::mapping::ChannelMapping;

/// How to find the buffers radn needs in the input files.
#[derive(clap::Args, Clone, Debug)]
pub struct ChannelArgs {
    /// Renderer preset: cycles, arnold, renderman, karma, generic, or auto (detect).
    #[arg(long, default_value = "auto")]
    pub preset: String,
    /// A channel mapping file (TOML, same format as crates/radn-core/presets/*.toml); overrides --preset.
    #[arg(long)]
    pub mapping: Option<PathBuf>,
    /// The view layer to use when a file holds several (e.g. "ViewLayer").
    #[arg(long)]
    pub layer: Option<String>,
    /// NaN/Inf samples: repair them (and report the count) or stop with an error.
    #[arg(long, value_enum, default_value = "repair")]
    pub nonfinite: NonFinite,
}

/// CLI form of [`NonFinitePolicy`].
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum NonFinite {
    /// Replace by the mean of finite neighbours and count.
    Repair,
    /// Refuse the file.
    Error,
}

impl ChannelArgs {
    /// A frame reader for these options; `probe` is a file used when the preset is `auto`.
    pub fn reader(&self, probe: &std::path::Path, require: Requirements) -> Result<FrameReader> {
        let mapping = if let Some(m) = &self.mapping {
            ChannelMapping::from_file(m)?
        } else if self.preset == "auto" {
            let file = ExrFile::read(probe)?;
            let m = ChannelMapping::detect(&file.channel_names()).ok_or_else(|| {
                anyhow!(
                    "'{}': no preset fits its channels ({}); pass --preset or --mapping",
                    probe.display(),
                    file.channel_names().join(", ")
                )
            })?;
            tracing::debug!(preset = %m.name, "detected channel preset");
            m
        } else {
            ChannelMapping::builtin(&self.preset).ok_or_else(|| {
                anyhow!(
                    "unknown preset '{}'; known: auto, {}",
                    self.preset,
                    ChannelMapping::builtin_names().join(", ")
                )
            })?
        };
        let mut r = FrameReader::new(mapping, require);
        r.layer = self.layer.clone();
        r.nonfinite = match self.nonfinite {
            NonFinite::Repair => NonFinitePolicy::Repair,
            NonFinite::Error => NonFinitePolicy::Error,
        };
        Ok(r)
    }
}

/// Where a guided network's per-frame guide comes from.
#[derive(clap::Args, Clone, Debug)]
pub struct GuideArgs {
    /// Network: a per-frame spatial estimate of the beauty that a guided model reads beside
    /// the noisy window (kernels are still applied to the noisy frames): `oidn` (Intel Open
    /// Image Denoise on each frame, HDR, prefiltered albedo and normal), `denoised` (the
    /// renderer's own denoised beauty beside the noisy one, e.g. Cycles' Combined with Noisy
    /// Image), a layer name, or `none`.
    #[arg(long, value_name = "oidn|denoised|LAYER|none", default_value = "none",
          value_parser = parse_guide)]
    pub guide: GuideChoice,
    /// Threads Intel Open Image Denoise uses for `--guide oidn` (0: every core).
    #[arg(long, default_value_t = 0)]
    pub oidn_threads: usize,
}

impl GuideArgs {
    /// Sets `reader` to read the guide layer, if the guide is one, and opens Intel Open Image
    /// Denoise, if the guide is its.
    pub fn apply(&self, reader: &mut FrameReader) -> Result<Option<Arc<OidnGuides>>> {
        reader.guide = self.guide.layer();
        Ok(match self.guide {
            GuideChoice::Oidn => Some(Arc::new(OidnGuides::new(self.oidn_threads)?)),
            _ => None,
        })
    }

    /// What a [`radn_core::window::WindowReader`] over `paths` needs to attach guides the
    /// reader does not read: the OIDN guides `oidn` ([`GuideArgs::apply`]) of those files.
    pub fn window_guides(
        oidn: Option<Arc<OidnGuides>>,
        paths: &[PathBuf],
    ) -> radn_core::guide::JobGuides {
        match oidn {
            Some(guides) => radn_core::guide::JobGuides::Oidn {
                guides,
                originals: paths.to_vec(),
            },
            None => radn_core::guide::JobGuides::FromReader,
        }
    }

    /// Checks that `model` (shown as `label`) and the guide go together: a guided model needs
    /// a guide, and a guide needs a guided model.
    pub fn check_model(&self, model: &radn_nn::model::Denoiser, label: &Path) -> Result<()> {
        match (model.config.inputs.guide, self.guide.is_some()) {
            (true, false) => Err(anyhow!(
                "{} reads a guide: give one with --guide oidn, --guide denoised or --guide LAYER",
                label.display()
            )),
            (false, true) => Err(anyhow!(
                "{} reads no guide, so --guide {} would change nothing: drop --guide or pass a \
                 guided model with --model",
                label.display(),
                match &self.guide {
                    GuideChoice::Layer(l) => l.as_str(),
                    GuideChoice::Oidn => "oidn",
                    _ => "denoised",
                }
            )),
            _ => Ok(()),
        }
    }
}

fn parse_guide(s: &str) -> Result<GuideChoice, String> {
    Ok(GuideChoice::parse(s))
}

/// `--loosen-confidence`'s value (`radn denoise`, `radn prepare`): how much alignment's
/// confidence terms that compare sampled buffers loosen with the noise level
/// ([`radn_nn::infer::sampled_terms_loosening`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Loosening {
    /// The command's default for the run (`crate::model::network_for` for `radn denoise`:
    /// `DEFAULT_SAMPLED_TERMS_LOOSENING` for runs with a guide, none without one).
    Auto,
    /// The strict tolerances at every level.
    Off,
    /// Loosen by the noise level, at most this many times.
    Most(f32),
}

impl Loosening {
    /// The most the terms loosen, `auto` being the command's default `auto`.
    pub fn resolve(self, auto: Option<f32>) -> Option<f32> {
        match self {
            Loosening::Auto => auto,
            Loosening::Off => None,
            Loosening::Most(k) => Some(k),
        }
    }
}

/// Parses `--loosen-confidence`: `auto`, `off` or a factor of at least 1.
pub fn parse_loosening(s: &str) -> Result<Loosening, String> {
    match s {
        "auto" => Ok(Loosening::Auto),
        "off" => Ok(Loosening::Off),
        k => match k.parse::<f32>() {
            Ok(k) if k.is_finite() && k >= 1.0 => Ok(Loosening::Most(k)),
            _ => Err(format!("'{k}' is not auto, off or a factor of at least 1")),
        },
    }
}

/// A resampling as the command line names it ([`radn_core::warp::Resampling`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ResamplingArg {
    /// The four nearest pixels.
    Bilinear,
    /// Sixteen pixels, clamped to the four nearest pixels' range.
    CatmullRom,
}

impl From<ResamplingArg> for radn_core::warp::Resampling {
    fn from(r: ResamplingArg) -> Self {
        match r {
            ResamplingArg::Bilinear => Self::Bilinear,
            ResamplingArg::CatmullRom => Self::CatmullRom,
        }
    }
}

/// When frames are denoised band by band, as the command line names it
/// ([`radn_core::job::Bands`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BandsArg {
    /// Band by band for frames of more than 2.5 megapixels, whole frames for smaller ones.
    Auto,
    /// Band by band whatever the frame's size: memory follows the band.
    Always,
    /// Whole frames whatever their size: memory follows the frame.
    Never,
}

impl From<BandsArg> for radn_core::job::Bands {
    fn from(b: BandsArg) -> Self {
        match b {
            BandsArg::Auto => Self::Auto,
            BandsArg::Always => Self::Always,
            BandsArg::Never => Self::Never,
        }
    }
}
