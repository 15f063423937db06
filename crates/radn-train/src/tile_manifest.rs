//! The description of a tile set (`manifest.json`), written by [`crate::dataset::prepare`]
//! and checked by every trainer that reads the tiles.

use radn_core::align::warp::Resampling;
use radn_core::guide::oidn_settings::OidnSettings;
use serde::{Deserialize, Serialize};

/// The default pseudo-reference level (made by `radn pseudoref`).
pub const DEFAULT_PSEUDO_LEVEL: &str = "pseudo";

pub(crate) fn default_pseudo_level() -> String {
    DEFAULT_PSEUDO_LEVEL.to_string()
}

/// The dataset's description, stored as `manifest.json`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Manifest {
    /// Format version.
    pub format: u32,
    /// Tile side.
    pub tile: usize,
    /// Frames per window.
    pub frames: usize,
    /// Channels of the features per frame.
    pub feature_channels: usize,
    /// Input levels, in record order.
    pub input_levels: Vec<String>,
    /// Target levels, in record order.
    pub target_levels: Vec<String>,
    /// Number of records.
    pub records: usize,
    /// Records per shard file.
    pub records_per_shard: usize,
    /// Bytes per record.
    pub record_bytes: usize,
    /// Seed of the tile positions.
    pub seed: u64,
    /// Source scenes.
    pub scenes: Vec<String>,
    /// Records with a pseudo-reference target.
    pub with_pseudo: usize,
    /// The level folder the pseudo-references were read from (`pseudo` or `oidn`).
    #[serde(default = "default_pseudo_level")]
    pub pseudo_level: String,
    /// Where the stored guides came from (`oidn`, `denoised` or a layer name); none in tile sets
    /// without guides (all before format 3).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub guide: Option<String>,
    /// How OIDN made the `oidn` guides ([`crate::dataset::PrepareOptions::oidn`]); absent: OIDN's final-frame
    /// mode (every tile set before it was recorded).
    #[serde(default, skip_serializing_if = "OidnSettings::is_default")]
    pub oidn: OidnSettings,
    /// The guide term's tolerance the windows were aligned with
    /// ([`crate::dataset::PrepareOptions::guide_confidence`]); none without it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub guide_confidence: Option<f32>,
    /// How the windows' side frames were sampled ([`crate::dataset::PrepareOptions::resampling`]); absent in
    /// tile sets from before it: bilinear.
    #[serde(default, skip_serializing_if = "Resampling::is_bilinear")]
    pub resampling: Resampling,
    /// The most the sampled-buffer terms were loosened by the noise level
    /// ([`crate::dataset::PrepareOptions::loosen_sampled_terms`]); absent: strict.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loosen_sampled_terms: Option<f32>,
    /// OIDN's prefilters (albedo, then normal) that cleaned every frame's auxiliaries before
    /// its window was aligned ([`crate::dataset::PrepareOptions::aux_prefilter`]); none: the
    /// auxiliaries as rendered.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aux_prefilters: Option<(String, String)>,
}
