//! Options shared by every command that reads frames: preset, mapping file, view layer,
//! NaN/Inf policy, turned into the frame reader they describe; and where a guided network's
//! guides come from.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{anyhow, Result};
use radn_core::guide::{GuideChoice, OidnGuides};
use radn_core::io::exr_file::ExrFile;
use radn_core::io::frame::{FrameReader, Requirements};
use radn_core::io::hygiene::NonFinitePolicy;
use radn_core::io::mapping::ChannelMapping;

/// How to find the buffers radn needs in the input files.
#[derive(clap::Args, Clone, Debug)]
pub struct ChannelArgs {
    /// auto, cycles, arnold, renderman, karma, generic.
    #[arg(long, default_value = "auto", value_name = "PRESET")]
    pub preset: String,
    /// Channel mapping file (TOML); overrides --preset.
    #[arg(long, value_name = "FILE")]
    pub mapping: Option<PathBuf>,
    /// The view layer, where a file holds several.
    #[arg(long, value_name = "NAME")]
    pub layer: Option<String>,
    /// NaN/Inf samples: repair (and count) or error.
    #[arg(
        long,
        value_enum,
        default_value = "repair",
        value_name = "POLICY",
        hide_possible_values = true
    )]
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
            // the header's channel names are all it needs: one row, not a whole 8K frame
            let file = ExrFile::read_rows(probe, 0..1)?;
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

/// Where a guided network's per-frame guide comes from (`radn prepare`, `radn eval`; `radn
/// denoise` chooses its own with `--guide auto`).
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
    /// What a [`radn_core::run::window::WindowReader`] over `paths` needs to attach guides the
    /// reader does not read: the OIDN guides `oidn` of those files.
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
}

fn parse_guide(s: &str) -> Result<GuideChoice, String> {
    Ok(GuideChoice::parse(s))
}

/// A resampling as the command line names it ([`radn_core::align::warp::Resampling`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ResamplingArg {
    /// The four nearest pixels.
    Bilinear,
    /// Sixteen pixels, clamped to the four nearest pixels' range.
    CatmullRom,
    /// The nearest pixel (noise stays per pixel in a mean of warped frames).
    Nearest,
}

impl From<ResamplingArg> for radn_core::align::warp::Resampling {
    fn from(r: ResamplingArg) -> Self {
        match r {
            ResamplingArg::Bilinear => Self::Bilinear,
            ResamplingArg::CatmullRom => Self::CatmullRom,
            ResamplingArg::Nearest => Self::Nearest,
        }
    }
}

/// When frames are denoised band by band, as the command line names it
/// ([`radn_core::run::job::Bands`]): `auto`, `always`, `never`, or a number of rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BandsArg {
    /// Band by band for frames of more than 2.5 megapixels, whole frames for smaller ones.
    Auto,
    /// Band by band whatever the frame's size: memory follows the band.
    Always,
    /// Whole frames whatever their size: memory follows the frame.
    Never,
    /// Band by band in bands of at most this many rows: less memory, more rows read twice.
    Rows(usize),
}

impl std::str::FromStr for BandsArg {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "auto" => Ok(Self::Auto),
            "always" => Ok(Self::Always),
            "never" => Ok(Self::Never),
            rows => match rows.parse::<usize>() {
                Ok(n) if n > 0 => Ok(Self::Rows(n)),
                _ => Err(format!(
                    "'{rows}': give auto, always, never or a number of rows (at least 1)"
                )),
            },
        }
    }
}

impl From<BandsArg> for radn_core::run::job::Bands {
    fn from(b: BandsArg) -> Self {
        match b {
            BandsArg::Auto => Self::Auto,
            BandsArg::Always => Self::Always,
            BandsArg::Never => Self::Never,
            BandsArg::Rows(n) => Self::Rows(n),
        }
    }
}

/// `--tune`'s `KEY=VALUE` pairs, each split at its `=`.
pub fn tune_pairs(tune: &[String]) -> Result<Vec<(&str, &str)>> {
    tune.iter()
        .map(|t| {
            t.split_once('=')
                .map(|(k, v)| (k.trim(), v.trim()))
                .ok_or_else(|| anyhow!("--tune {t}: give KEY=VALUE (--tune help lists the keys)"))
        })
        .collect()
}

/// Refuses a kernel threshold outside [0, 1/K) for a network with K taps: past 1/K every
/// kernel would fall back to the identity.
pub fn check_threshold(t: f32, config: &radn_nn::model::config::NetConfig) -> Result<()> {
    let taps = config.kernel_taps() as f32;
    if !(0.0..1.0 / taps).contains(&t) {
        anyhow::bail!(
            "--tune threshold={t} must be in [0, 1/K) = [0, {:.5}) for this model",
            1.0 / taps
        );
    }
    Ok(())
}

/// The classic denoiser with `--tune classic.KEY=VALUE` applied (any other key is an error:
/// it tunes the network).
pub fn classic_tuned(tune: &[String]) -> Result<radn_core::ClassicDenoiser> {
    let mut d = radn_core::ClassicDenoiser::default();
    for (key, value) in tune_pairs(tune)? {
        if !key.starts_with("classic.") {
            return Err(anyhow!(
                "--tune {key}: a network setting, and this run uses the classic method"
            ));
        }
        d.set(key, value).map_err(|e| anyhow!(e))?;
    }
    Ok(d)
}
