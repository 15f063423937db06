//! Options shared by every command that reads frames: preset, mapping file, view layer,
//! NaN/Inf policy, turned into the frame reader they describe.

use std::path::PathBuf;

use anyhow::{anyhow, Result};
use radn_core::exr_file::ExrFile;
use radn_core::frame::{FrameReader, Requirements};
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
