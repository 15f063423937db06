//! A training run's settings (`radn train --config run.toml`): what it trains, on which tiles,
//! with which objective and schedule; every field but the tiles has a default.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::dataset::INPUT_LEVELS;
use crate::objective::{LossMode, PixelLoss};
use radn_nn::error::{NnError, Result};
use radn_nn::model::config::NetConfig;

/// A training run's settings (TOML).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    /// Network preset name, or a path to a network TOML file.
    pub model: String,
    /// Prepared training tiles.
    pub train: PathBuf,
    /// Prepared validation tiles (kept apart from training).
    pub val: PathBuf,
    /// Tiles per step.
    #[serde(default = "d_batch")]
    pub batch: usize,
    /// Crop tiles to this size at a random position (speed); `None` uses whole tiles.
    #[serde(default)]
    pub crop: Option<usize>,
    /// Optimizer steps.
    pub steps: usize,
    /// Peak learning rate.
    #[serde(default = "d_lr")]
    pub lr: f64,
    /// Linear warm-up steps before cosine decay to 5% of the peak.
    #[serde(default = "d_warmup")]
    pub warmup: usize,
    /// Per-pixel loss: smape, l1, or vgg (paper eq. 6; needs `vgg_weights`).
    #[serde(default = "d_loss")]
    pub loss: PixelLoss,
    /// VGG19 ImageNet weights (SafeTensors, torchvision layout) for `loss = "vgg"`.
    #[serde(default)]
    pub vgg_weights: Option<PathBuf>,
    /// Temporal (the paper's conversion) or spatial loss.
    #[serde(default = "d_mode")]
    pub mode: LossMode,
    /// Weight of the full-window term added to the temporal loss (0: off; post-training).
    #[serde(default)]
    pub full_weight: f32,
    /// Validate every this many steps.
    #[serde(default = "d_every")]
    pub validate_every: usize,
    /// Validation tiles used (the first ones of the validation set).
    #[serde(default = "d_val_tiles")]
    pub val_tiles: usize,
    /// Seed of batch order, pairs and crops.
    #[serde(default = "d_seed")]
    pub seed: u64,
    /// A model file whose weights the run starts from instead of random ones: fine-tuning,
    /// e.g. the shipped model on a studio's own renders, or a trained model with a changed
    /// kernel setting (threshold, demodulation). Its layers must match `model`'s.
    #[serde(default)]
    pub init: Option<PathBuf>,
    /// Whether the pseudo-references are drawn as targets: the classic denoiser's output
    /// (`radn prepare`'s default) or the OIDN teacher's (`radn prepare --pseudo oidn`). They are
    /// the cleanest targets, but a network trained on them also learns that denoiser's
    /// mistakes (the classic one blurs thin lines and texture); `false` trains on the
    /// independent noisier renders alone (Noise2Noise pairs), which are unbiased.
    #[serde(default = "d_pseudo")]
    pub pseudo_references: bool,
    /// The input levels (`low`, `half`, `high`) whose target may be the pseudo-reference when
    /// `pseudo_references` is on; empty (the default) means all of them. The OIDN teacher helps
    /// the noisiest inputs and costs clean ones (`docs/research/detail.md`), so a run may keep
    /// it for the noisiest input only.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub pseudo_inputs: Vec<String>,
    /// Whether an independent render noisier than the input may be the target (`high → half`
    /// and the like). Noise2Noise needs independent noise in the target, not less of it; without
    /// these pairs the least noisy input level is never an input in training.
    #[serde(default)]
    pub noisier_targets: bool,
    /// Whether every validation point's weights are kept as `steps/step-N.safetensors` in the
    /// run folder, so a model can be chosen afterwards by a measure the run does not know
    /// (references, a studio's own shots) rather than by the run's own validation loss.
    #[serde(default = "d_keep_steps")]
    pub keep_steps: bool,
    /// Log every layer's weight, gradient and update norms to `layers.csv` every this many
    /// steps (0: never), so a run shows whether it moves every layer.
    #[serde(default = "d_layer_stats_every")]
    pub layer_stats_every: usize,
    /// Adam's ε (added to the root of the second moment). Default 1e-8 (PyTorch's), not
    /// burn's 1e-5: the Robust Average blocks' gradients are far below 1e-5, where Adam's steps
    /// shrink with the gradient, so with 1e-5 those blocks barely train
    /// (`docs/research/training-signal.md`).
    #[serde(default = "d_adam_epsilon")]
    pub adam_epsilon: f32,
}

fn d_batch() -> usize {
    4
}
fn d_lr() -> f64 {
    3e-4
}
fn d_warmup() -> usize {
    50
}
fn d_loss() -> PixelLoss {
    PixelLoss::Smape
}
fn d_mode() -> LossMode {
    LossMode::Temporal
}
fn d_every() -> usize {
    100
}
fn d_val_tiles() -> usize {
    16
}
fn d_seed() -> u64 {
    1
}
fn d_pseudo() -> bool {
    true
}
fn d_adam_epsilon() -> f32 {
    1e-8
}
fn d_layer_stats_every() -> usize {
    10
}
fn d_keep_steps() -> bool {
    true
}

impl TrainConfig {
    /// Parses a training config.
    pub fn parse(text: &str) -> Result<Self> {
        let config: Self = toml::from_str(text).map_err(|e| NnError::Config(e.to_string()))?;
        if let Some(bad) = config
            .pseudo_inputs
            .iter()
            .find(|l| !INPUT_LEVELS.contains(&l.as_str()))
        {
            return Err(NnError::Config(format!(
                "pseudo_inputs: unknown input level {bad:?} (the levels are {INPUT_LEVELS:?})"
            )));
        }
        Ok(config)
    }

    /// For which inputs (indexed like [`INPUT_LEVELS`]) the pseudo-reference may be the
    /// target: none without `pseudo_references`, else those of `pseudo_inputs` (all if empty).
    pub fn pseudo_for(&self) -> [bool; INPUT_LEVELS.len()] {
        std::array::from_fn(|i| {
            self.pseudo_references
                && (self.pseudo_inputs.is_empty()
                    || self.pseudo_inputs.iter().any(|l| l == INPUT_LEVELS[i]))
        })
    }

    /// The network this config trains.
    pub fn net_config(&self, base: &Path) -> Result<NetConfig> {
        let p = base.join(&self.model);
        if p.is_file() {
            let text = std::fs::read_to_string(&p)
                .map_err(|e| NnError::Config(format!("{}: {e}", p.display())))?;
            NetConfig::parse(&text)
        } else {
            NetConfig::preset(&self.model)
        }
    }

    /// The learning rate at a step: linear warm-up, then cosine decay to 5% of the peak.
    pub fn lr_at(&self, step: usize) -> f64 {
        if step < self.warmup {
            return self.lr * (step + 1) as f64 / self.warmup as f64;
        }
        let t =
            (step - self.warmup) as f64 / (self.steps.saturating_sub(self.warmup)).max(1) as f64;
        self.lr * (0.05 + 0.95 * 0.5 * (1.0 + (std::f64::consts::PI * t.min(1.0)).cos()))
    }
}
