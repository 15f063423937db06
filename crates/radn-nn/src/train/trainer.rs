//! Training (`radn train`): Noise2Noise pairs from a prepared tile set, the spatial-to-temporal
//! loss, Adam with warm-up and cosine decay, periodic validation, checkpoints, and resumption
//! that continues exactly where a run stopped (each step's randomness derives from the seed and
//! the step number; the optimizer state is saved with the weights).

use std::io::Write;

use burn::module::Module;
use std::path::{Path, PathBuf};

use burn::optim::{AdamConfig, GradientsParams};
use burn::store::ModuleSnapshot;
use burn::tensor::{Device, Tensor, TensorData};
use serde::{Deserialize, Serialize};

use crate::error::{NnError, Result};
use crate::infer::input::network_features;
use crate::model::config::{InputConfig, NetConfig, INPUT_CHANNELS};
use crate::model::demod::Demodulation;
use crate::model::learned_mix::{LearnedMix, MixWeights};
use crate::model::store;
use crate::model::{Denoiser, GuideWeights};
use crate::train::dataset::{SplitMix, Tile, TileDataset, INPUT_LEVELS};
use crate::train::layer_stats::{append_csv, gradient_norms, step_stats};
use crate::train::objective::{objective, sample_pair, LossFn, LossMode, PairRule, PixelLoss};
use radn_core::output::{write_atomically_with, write_bytes_atomically};

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
    /// `pseudo_references` is on; empty (the default) means all of them. Measured on detail-val:
    /// the OIDN teacher gains 0.4–0.5 dB at 4 spp over independent renders and loses 0.3–0.6 dB
    /// at 32–128 spp, so a run may keep it for the noisiest input only.
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
    /// burn's 1e-5: the Robust Average blocks' gradients are ~1e-7 per weight, below 1e-5,
    /// where Adam's steps shrink with the gradient — with 1e-5 those blocks moved 8× less per
    /// step than the rest of the network (measured, docs/training-signal.md).
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

/// Saved between steps so a run can resume.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct TrainState {
    /// Steps completed.
    pub step: usize,
    /// Best validation loss so far.
    pub best_val: Option<f64>,
}

/// One validation result.
#[derive(Clone, Debug, Serialize)]
pub struct Validation {
    /// Mean loss (the training objective) over the validation tiles.
    pub loss: f64,
    /// Mean PSNR (tonemapped) of the full-window output against the cleanest target.
    pub psnr: f64,
}

/// A batch as tensors: features `[B,T,C,S,S]`, values `[B,T,3,S,S]`, target `[B,3,S,S]`.
pub struct Batch {
    /// Network input.
    pub features: Tensor<5>,
    /// Linear colour the kernels are applied to.
    pub values: Tensor<5>,
    /// Centre target.
    pub target: Tensor<4>,
    /// The centre frame's guide (linear colour) `[B, 3, S, S]`, for a network that reads one.
    pub guide: Option<Tensor<4>>,
    /// Per tile, the reciprocal of the exposure its colour features were divided by
    /// (`[B, 1, 1, 1]`; 1 without exposure normalisation).
    pub inv_exposure: Tensor<4>,
}

/// Crops and stacks tiles with their chosen (input, target) levels, with the input features
/// a network configured with `inputs` reads (tiles of format 2 when it asks for exposure
/// normalisation: [`Trainer::new`] checks).
pub fn make_batch(
    tiles: &[(Tile, usize, usize, usize, usize)],
    frames: usize,
    tile: usize,
    crop: usize,
    inputs: &InputConfig,
    device: &Device,
) -> Batch {
    let b = tiles.len();
    let (mut f, mut v, mut t) = (Vec::new(), Vec::new(), Vec::new());
    let mut centre_guides = Vec::new();
    let mut inv_exposure = Vec::new();
    let cut = |data: &[f32], planes: usize, x0: usize, y0: usize, out: &mut Vec<f32>| {
        for p in 0..planes {
            for y in y0..y0 + crop {
                out.extend_from_slice(
                    &data[p * tile * tile + y * tile + x0..p * tile * tile + y * tile + x0 + crop],
                );
            }
        }
    };
    for (tl, input, target, x0, y0) in tiles {
        let mut base = Vec::with_capacity(frames * INPUT_CHANNELS * crop * crop);
        cut(
            &tl.features[*input],
            frames * INPUT_CHANNELS,
            *x0,
            *y0,
            &mut base,
        );
        let mut colour = Vec::with_capacity(frames * 3 * crop * crop);
        cut(&tl.values[*input], frames * 3, *x0, *y0, &mut colour);
        let guide = inputs.guide.then(|| {
            let mut g = Vec::with_capacity(frames * 3 * crop * crop);
            let stored = tl.guides[*input]
                .as_ref()
                .expect("a guided network trains on guided tiles (checked by Trainer::new)");
            cut(stored, frames * 3, *x0, *y0, &mut g);
            let centre = frames / 2 * 3 * crop * crop;
            centre_guides.extend_from_slice(&g[centre..centre + 3 * crop * crop]);
            g
        });
        let exposure = match tl.exposure[*input] {
            Some(e) => e,
            None if inputs.exposure => panic!("exposure normalisation needs format-2 tiles"),
            None => 1.0,
        };
        inv_exposure.push(if inputs.exposure { 1.0 / exposure } else { 1.0 });
        f.extend(network_features(
            base,
            &colour,
            guide.as_deref(),
            frames,
            crop * crop,
            inputs,
            exposure,
        ));
        v.extend(colour);
        cut(
            tl.targets[*target].as_ref().expect("sampled targets exist"),
            3,
            *x0,
            *y0,
            &mut t,
        );
    }
    Batch {
        features: Tensor::from_data(
            TensorData::new(f, [b, frames, inputs.channels(), crop, crop]),
            device,
        ),
        values: Tensor::from_data(TensorData::new(v, [b, frames, 3, crop, crop]), device),
        target: Tensor::from_data(TensorData::new(t, [b, 3, crop, crop]), device),
        guide: inputs
            .guide
            .then(|| Tensor::from_data(TensorData::new(centre_guides, [b, 3, crop, crop]), device)),
        inv_exposure: Tensor::from_data(TensorData::new(inv_exposure, [b, 1, 1, 1]), device),
    }
}

/// A batch's colour values `[B, T, 3, S, S]` blended toward their guides by `beta`, for a
/// network with the guide blend (`beta` is `None` without one: the values as they are).
fn blend_values(
    config: &NetConfig,
    features: &Tensor<5>,
    beta: Option<Tensor<5>>,
    values: Tensor<5>,
) -> Tensor<5> {
    match beta {
        Some(beta) => {
            crate::model::guide_blend::GuideBlend::new(features, beta, &config.inputs, vec![0], 3)
                .apply(values)
        }
        None => values,
    }
}

/// The learned guide mix of a batch `b`, for a network with the head (`guides` then hold its
/// weights, or the features its head reads with the result); the batch then has its centre
/// guides.
fn learned_mix<'a>(
    denoiser: &'a Denoiser,
    guides: &GuideWeights,
    b: &Batch,
) -> Option<LearnedMix<'a>> {
    let weight = match (&guides.mix, &guides.mix_features) {
        (Some(w), _) => MixWeights::Given(w.clone()),
        (None, Some(features)) => MixWeights::OfResult {
            denoiser,
            features: features.clone(),
            input: b.features.clone(),
            inv_exposure: b.inv_exposure.clone(),
        },
        (None, None) => return None,
    };
    Some(LearnedMix {
        weight,
        guide: b
            .guide
            .clone()
            .expect("a network with the guide mix reads a guide: its batches carry one"),
    })
}

/// A network configured as `config` holding the weights of the model file `path`, refused when
/// the layers differ (only the kernel settings — threshold, demodulation — and the name may).
fn start_from(path: &Path, config: NetConfig, device: &Device) -> Result<Denoiser> {
    let mut d = store::load(path, device)?;
    let layers = |c: &NetConfig| (c.arch, c.frames, c.kernel_size, c.backbone.clone());
    if layers(&d.config) != layers(&config) {
        return Err(NnError::Load {
            path: path.to_path_buf(),
            detail: format!(
                "its layers ({}) are not those of the configured network ({})",
                d.config.name, config.name
            ),
        });
    }
    let load_err = |detail: String| NnError::Load {
        path: path.to_path_buf(),
        detail,
    };
    if d.config.frame_local_stem && !config.frame_local_stem {
        return Err(load_err(
            "it has a frame-local stem and the configured network has not".into(),
        ));
    }
    if d.config.inputs != config.inputs {
        if d.config.frame_local_stem {
            return Err(load_err(
                "the inputs of a network with a frame-local stem cannot change".into(),
            ));
        }
        // a fine-tune may add input features: their first-layer weights start at zero
        d = d.with_inputs(config.inputs.clone(), device);
    }
    if config.frame_local_stem && !d.config.frame_local_stem {
        // a fine-tune may split the stem: it starts close to the model it splits
        d = d.with_frame_local_stem(device).map_err(load_err)?;
    }
    if d.config.guide_blend != config.guide_blend {
        // a fine-tune may add the guide blend: its head starts near β = 0
        d.config.inputs = config.inputs.clone();
        d = d
            .with_guide_blend(config.guide_blend, device)
            .map_err(|detail| NnError::Load {
                path: path.to_path_buf(),
                detail,
            })?;
    }
    if d.config.guide_mix_head != config.guide_mix_head
        || d.config.guide_mix_reads_result != config.guide_mix_reads_result
    {
        // a fine-tune may add the learned guide mix: its head starts at the fixed mix's weight
        d.config.inputs = config.inputs.clone();
        d.config.guide_mix_reads_result = config.guide_mix_reads_result;
        d = d
            .with_guide_mix_head(config.guide_mix_head, device)
            .map_err(load_err)?;
    }
    if d.config.scales() != config.scales() {
        // a fine-tune may add (or drop) kernel scales: the new heads start from the old ones
        d = d
            .with_kernel_scales(config.scales(), device)
            .map_err(|detail| NnError::Load {
                path: path.to_path_buf(),
                detail,
            })?;
    }
    d.config = config;
    Ok(d)
}

/// A training run in `out`: `model.safetensors`, `best.safetensors`, the checkpoint files
/// ([`checkpoint_files`]) and `state.json`, `metrics.csv`, `layers.csv`, `steps/`.
pub struct Trainer {
    /// Settings.
    pub config: TrainConfig,
    /// Output folder.
    pub out: PathBuf,
    /// The network being trained.
    pub denoiser: Denoiser,
    optim: burn::optim::ModuleOptimizer,
    /// Progress.
    pub state: TrainState,
    loss_fn: LossFn,
    train: TileDataset,
    val: TileDataset,
    device: Device,
}

impl Trainer {
    /// Starts a run, or resumes the one in `out` when `resume` is set.
    pub fn new(
        config: TrainConfig,
        base: &Path,
        out: &Path,
        resume: bool,
        device: &Device,
    ) -> Result<Self> {
        let train = TileDataset::open(&base.join(&config.train))?;
        let val = TileDataset::open(&base.join(&config.val))?;
        if train.is_empty() || val.is_empty() {
            return Err(NnError::Config(
                "the training and validation tile sets must not be empty".into(),
            ));
        }
        std::fs::create_dir_all(out).map_err(|e| NnError::Save {
            path: out.to_path_buf(),
            detail: e.to_string(),
        })?;
        // temporary files of a run killed while writing (a live run's are locked)
        radn_core::output_locks::remove_stale(out)?;
        radn_core::output_locks::remove_stale(&out.join("steps"))?;
        let net_cfg = config.net_config(base)?;
        if net_cfg.frames != train.manifest.frames {
            return Err(NnError::Config(format!(
                "the network has {} frames, the tiles {}",
                net_cfg.frames, train.manifest.frames
            )));
        }
        if net_cfg.inputs.exposure {
            for (name, set) in [(&config.train, &train), (&config.val, &val)] {
                if set.manifest.format < 2 {
                    return Err(NnError::Tiles {
                        path: base.join(name),
                        detail: "they were prepared before exposures were recorded; \
                                 the network normalises by exposure: run `radn prepare` again"
                            .into(),
                    });
                }
            }
        }
        for (name, set) in [(&config.train, &train), (&config.val, &val)] {
            if set.manifest.resampling != net_cfg.resampling {
                return Err(NnError::Tiles {
                    path: base.join(name),
                    detail: format!(
                        "their windows were aligned with {} resampling and the network \
                         aligns with {}: prepare them with `radn prepare --resampling {}`",
                        set.manifest.resampling.name(),
                        net_cfg.resampling.name(),
                        net_cfg.resampling.name()
                    ),
                });
            }
        }
        if net_cfg.inputs.guide {
            for (name, set) in [(&config.train, &train), (&config.val, &val)] {
                if set.manifest.guide.is_none() {
                    return Err(NnError::Tiles {
                        path: base.join(name),
                        detail: "they hold no guides and the network reads one: prepare them \
                                 with `radn prepare --guide oidn` (or the guide the model is \
                                 to be used with)"
                            .into(),
                    });
                }
            }
        }
        let state_path = out.join("state.json");
        let (denoiser, optim, state) = if resume && state_path.exists() {
            let state: TrainState =
                serde_json::from_str(&std::fs::read_to_string(&state_path).map_err(|e| {
                    NnError::Load {
                        path: state_path.clone(),
                        detail: e.to_string(),
                    }
                })?)
                .map_err(|e| NnError::Load {
                    path: state_path.clone(),
                    detail: e.to_string(),
                })?;
            // the Burnpack checkpoint keeps parameter ids, which the optimizer state is keyed by
            let mut d = Denoiser::new(net_cfg, device);
            let [mut ck, mut opt] = checkpoint_files(out, state.step);
            if !ck.exists() && out.join("checkpoint.bpk").exists() {
                // a run from before checkpoint files were named by their step
                (ck, opt) = (out.join("checkpoint.bpk"), out.join("optimizer.bpk"));
            }
            let mut bp = burn::store::BurnpackStore::from_file(&ck);
            let r = d.net.load_from(&mut bp).map_err(|e| NnError::Load {
                path: ck.clone(),
                detail: format!("{e:?}"),
            })?;
            if !r.missing.is_empty() || !r.errors.is_empty() {
                return Err(NnError::Load {
                    path: ck,
                    detail: "the checkpoint does not match the configured network".into(),
                });
            }
            let optim = AdamConfig::new()
                .with_epsilon(config.adam_epsilon)
                .init()
                .load(&opt)
                .map_err(|e| NnError::Load {
                    path: opt.clone(),
                    detail: format!("{e:?}"),
                })?;
            // a run killed inside a checkpoint left the next step's files, uncommitted
            if ck.file_name() != Some(std::ffi::OsStr::new("checkpoint.bpk")) {
                remove_other_checkpoints(out, state.step);
            }
            // steps after the checkpoint are redone: their logged rows would be duplicates
            drop_metrics_after(&out.join("metrics.csv"), state.step)?;
            // layer rows carry the step they measured, before it was taken
            drop_rows_from(&out.join("layers.csv"), state.step)?;
            (d, optim, state)
        } else {
            // initial weights drawn right after seeding, all at once (burn initialises lazily)
            device.seed(config.seed);
            let d = match &config.init {
                Some(init) => start_from(&base.join(init), net_cfg, device)?,
                None => {
                    let d = Denoiser::new(net_cfg, device);
                    d.materialize();
                    d
                }
            };
            (
                d,
                AdamConfig::new().with_epsilon(config.adam_epsilon).init(),
                TrainState {
                    step: 0,
                    best_val: None,
                },
            )
        };
        let loss_fn = match config.loss {
            PixelLoss::Vgg => {
                let p = config.vgg_weights.as_ref().ok_or_else(|| {
                    NnError::Config(
                        "loss = \"vgg\" needs vgg_weights = \"path/to/vgg19.safetensors\"".into(),
                    )
                })?;
                // frozen: it shapes the network's gradients but is never trained
                LossFn::Perceptual(Box::new(
                    crate::train::vgg::Vgg19::load(&base.join(p), device)?.no_grad(),
                ))
            }
            l => LossFn::Pixel(l),
        };
        Ok(Self {
            config,
            out: out.to_path_buf(),
            denoiser,
            optim,
            state,
            loss_fn,
            train,
            val,
            device: device.clone(),
        })
    }

    /// The tiles, pairs and crop offsets of a step: a pure function of (seed, step).
    pub fn plan_step(&self, step: usize) -> Vec<(usize, usize, usize, usize, usize)> {
        let mut rng = SplitMix(self.config.seed.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ step as u64);
        let tile = self.train.manifest.tile;
        let crop = self.config.crop.unwrap_or(tile).min(tile);
        (0..self.config.batch)
            .map(|_| {
                let i = rng.below(self.train.len());
                let pair = sample_pair(
                    &mut rng,
                    PairRule {
                        pseudo_for: self.config.pseudo_for(),
                        noisier_targets: self.config.noisier_targets,
                        pseudo_from_high: self.train.manifest.pseudo_level
                            == crate::train::dataset::DEFAULT_PSEUDO_LEVEL,
                    },
                );
                let (x0, y0) = (rng.below(tile - crop + 1), rng.below(tile - crop + 1));
                (i, pair.input, pair.target, x0, y0)
            })
            .collect()
    }

    /// Runs one optimizer step; returns the loss.
    pub fn step(&mut self) -> Result<f64> {
        let step = self.state.step;
        let plan = self.plan_step(step);
        let tile = self.train.manifest.tile;
        let crop = self.config.crop.unwrap_or(tile).min(tile);
        let mut tiles = Vec::new();
        for (i, input, mut target, x0, y0) in plan {
            let t = self.train.get(i)?;
            if t.targets[target].is_none() {
                // no pseudo-reference for this tile: the `high` render is the next cleanest
                // (the pair stays valid: pseudo is only drawn for `low` and `half` inputs)
                target = 0;
            }
            tiles.push((t, input, target, x0, y0));
        }
        let frames = self.train.manifest.frames;
        let inputs = self.denoiser.config.inputs.clone();
        let b = make_batch(&tiles, frames, tile, crop, &inputs, &self.device);
        let thr = self.denoiser.config.default_threshold();
        let demod = self.demodulation(&b.features);
        let (pred, guides) = self.denoiser.predict_guided(b.features.clone(), thr);
        let mix = learned_mix(&self.denoiser, &guides, &b);
        let values = blend_values(
            &self.denoiser.config,
            &b.features,
            guides.blend,
            b.values.clone(),
        );
        let loss = objective(
            &pred,
            values,
            b.target,
            demod.as_ref(),
            mix.as_ref(),
            self.config.mode,
            &self.loss_fn,
            self.config.full_weight,
            frames,
        );
        let value = loss.clone().into_scalar::<f32>() as f64;
        if !value.is_finite() {
            return Err(NnError::Config(format!(
                "the loss became {value} at step {step}"
            )));
        }
        let grads = loss.backward();
        let every = self.config.layer_stats_every;
        let watched = (every > 0 && step.is_multiple_of(every)).then(|| {
            let before = self.denoiser.layer_weights();
            let norms = gradient_norms(&before, &grads);
            (before, norms)
        });
        let grads = GradientsParams::from_grads(grads, &self.denoiser.net);
        // modules hold tensor handles: the clone is cheap
        self.denoiser.net =
            self.optim
                .step(self.config.lr_at(step), self.denoiser.net.clone(), grads);
        if let Some((before, norms)) = watched {
            let stats = step_stats(&before, &norms, &self.denoiser.layer_weights());
            append_csv(&self.out.join("layers.csv"), step, &stats)?;
        }
        self.state.step += 1;
        Ok(value)
    }

    /// The network's albedo demodulation for a batch's features (colour only), if it has one.
    fn demodulation(&self, features: &Tensor<5>) -> Option<Demodulation> {
        self.denoiser
            .config
            .demodulate
            .map(|eps| Demodulation::new(features, eps, vec![0], 3))
    }

    /// Loss and PSNR on the validation tiles (input `low`, target the cleanest available).
    pub fn validate(&self) -> Result<Validation> {
        let n = self.config.val_tiles.min(self.val.len());
        let tile = self.val.manifest.tile;
        let frames = self.val.manifest.frames;
        let thr = self.denoiser.config.default_threshold();
        // forward passes off the autodiff graph: with tracked parameters every validation tile
        // would record a graph (the `paper` network ran out of 24 GB at step 0)
        let plain = self.device.clone().without_autodiff();
        let denoiser = Denoiser {
            net: self.denoiser.net.valid(),
            config: self.denoiser.config.clone(),
        };
        let (mut loss, mut psnr) = (0.0, 0.0);
        for i in 0..n {
            let t = self.val.get(i)?;
            let target = if t.targets[3].is_some() { 3 } else { 0 };
            let b = make_batch(
                &[(t, 2, target, 0, 0)],
                frames,
                tile,
                tile,
                &denoiser.config.inputs,
                &plain,
            );
            let demod = self.demodulation(&b.features);
            let (pred, guides) = denoiser.predict_guided(b.features.clone(), thr);
            let mix = learned_mix(&denoiser, &guides, &b);
            let values = blend_values(
                &denoiser.config,
                &b.features,
                guides.blend,
                b.values.clone(),
            );
            loss += objective(
                &pred,
                values.clone(),
                b.target.clone(),
                demod.as_ref(),
                mix.as_ref(),
                self.config.mode,
                &self.loss_fn,
                self.config.full_weight,
                frames,
            )
            .into_scalar::<f32>() as f64;
            let out = crate::model::demod::filter(&pred, values, demod.as_ref());
            let out = match &mix {
                Some(m) => m.apply(out),
                None => out,
            };
            let tm = |x: Tensor<4>| {
                let x = x.clamp_min(0.0);
                (x.clone() / (x + 1.0)).powf_scalar(1.0 / 2.2)
            };
            let mse = (tm(out) - tm(b.target))
                .powf_scalar(2.0)
                .mean()
                .into_scalar::<f32>() as f64;
            psnr += radn_core::metrics::psnr_from_mse(mse);
        }
        Ok(Validation {
            loss: loss / n as f64,
            psnr: psnr / n as f64,
        })
    }

    /// Saves a checkpoint: the weights (a Burnpack file with parameter ids, for resuming, and
    /// the SafeTensors model file), the optimizer and the progress.
    ///
    /// The weights and optimizer files are named by their step ([`checkpoint_files`]) and
    /// `state.json`, written last, names the step: its rename is the commit. A run killed at any
    /// point of a checkpoint thus resumes from the last one whose `state.json` was written,
    /// whose files are still there; the earlier checkpoint's files are removed only after it.
    pub fn checkpoint(&self) -> Result<()> {
        store::save(&self.denoiser, &self.out.join("model.safetensors"))?;
        let save_err = |path: &Path, e: String| NnError::Save {
            path: path.to_path_buf(),
            detail: e,
        };
        let [weights, optimizer] = checkpoint_files(&self.out, self.state.step);
        write_atomically_with(&weights, |_, tmp| {
            let mut bp = burn::store::BurnpackStore::from_file(tmp).overwrite(true);
            self.denoiser
                .net
                .save_into(&mut bp)
                .map_err(|e| save_err(tmp, format!("{e:?}")))
        })?;
        write_atomically_with(&optimizer, |_, tmp| {
            self.optim
                .save(tmp)
                .map_err(|e| save_err(tmp, format!("{e:?}")))
        })?;
        let st = serde_json::to_string_pretty(&self.state).expect("state serialises");
        write_bytes_atomically(&self.out.join("state.json"), st.as_bytes())?;
        remove_other_checkpoints(&self.out, self.state.step);
        Ok(())
    }

    /// Appends a line to `metrics.csv` (header written once).
    pub fn log(
        &self,
        kind: &str,
        loss: f64,
        psnr: Option<f64>,
        tiles_per_s: Option<f64>,
    ) -> Result<()> {
        let p = self.out.join("metrics.csv");
        let new = !p.exists();
        let mut f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&p)
            .map_err(|e| NnError::Save {
                path: p.clone(),
                detail: e.to_string(),
            })?;
        if new {
            writeln!(f, "step,kind,loss,psnr,lr,tiles_per_s").map_err(|e| NnError::Save {
                path: p.clone(),
                detail: e.to_string(),
            })?;
        }
        let opt = |v: Option<f64>| v.map(|v| format!("{v:.6}")).unwrap_or_default();
        writeln!(
            f,
            "{},{kind},{loss:.6},{},{:.3e},{}",
            self.state.step,
            opt(psnr),
            self.config.lr_at(self.state.step.saturating_sub(1)),
            opt(tiles_per_s)
        )
        .map_err(|e| NnError::Save {
            path: p.clone(),
            detail: e.to_string(),
        })
    }
}

/// What a training loop reports after each step.
#[derive(Clone, Debug)]
pub struct Progress {
    /// Steps done.
    pub step: usize,
    /// This step's loss.
    pub loss: f64,
    /// Tiles per second over the last step.
    pub tiles_per_s: f64,
    /// The validation result, when this step validated.
    pub validation: Option<Validation>,
}

/// Removes the rows logged after `step` from a run's metrics CSV (left by a run killed between
/// checkpoints), so a resumed run's curves have one row per step and kind.
fn drop_metrics_after(path: &Path, step: usize) -> Result<()> {
    drop_rows_from(path, step + 1)
}

/// Removes the rows of a run's CSV whose first column (a step) is `first` or later.
fn drop_rows_from(path: &Path, first: usize) -> Result<()> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Ok(()); // no metrics yet
    };
    // a last line without its newline is a row cut short by a kill in mid-append
    let whole = match text.rfind('\n') {
        Some(i) => &text[..=i],
        None => "",
    };
    let kept: String = whole
        .lines()
        .enumerate()
        .filter(|(i, l)| {
            *i == 0
                || l.split(',')
                    .next()
                    .and_then(|s| s.parse::<usize>().ok())
                    .is_none_or(|s| s < first)
        })
        .map(|(_, l)| format!("{l}\n"))
        .collect();
    if kept.len() == text.len() {
        return Ok(());
    }
    write_bytes_atomically(path, kept.as_bytes())?;
    Ok(())
}

/// A run's checkpoint files for `step`: the Burnpack weights and the optimizer state.
pub fn checkpoint_files(out: &Path, step: usize) -> [PathBuf; 2] {
    [
        out.join(format!("checkpoint-{step:07}.bpk")),
        out.join(format!("optimizer-{step:07}.bpk")),
    ]
}

/// Whether `name` is a checkpoint file of some step (or of a run from before checkpoint files
/// were named by step).
fn is_checkpoint_file(name: &str) -> bool {
    let numbered = |prefix: &str| {
        name.strip_prefix(prefix)
            .and_then(|r| r.strip_suffix(".bpk"))
            .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
    };
    numbered("checkpoint-")
        || numbered("optimizer-")
        || name == "checkpoint.bpk"
        || name == "optimizer.bpk"
}

/// Removes the checkpoint files of every step but `keep` (an earlier checkpoint, or the
/// uncommitted one of a run killed before its `state.json`). A file that cannot be removed
/// is logged and left: it costs disk, not correctness.
fn remove_other_checkpoints(out: &Path, keep: usize) {
    let kept = checkpoint_files(out, keep);
    let Ok(entries) = std::fs::read_dir(out) else {
        return;
    };
    for e in entries.flatten() {
        let path = e.path();
        let name = e.file_name();
        if is_checkpoint_file(&name.to_string_lossy()) && !kept.contains(&path) {
            if let Err(err) = std::fs::remove_file(&path) {
                tracing::warn!("could not remove {}: {err}", path.display());
            }
        }
    }
}

/// Where a run keeps the weights of one validation point (`keep_steps`).
pub fn step_model_path(out: &Path, step: usize) -> PathBuf {
    out.join("steps").join(format!("step-{step}.safetensors"))
}

impl Trainer {
    /// Keeps the current weights as this step's model file, if the config asks for it.
    fn keep_step(&self) -> Result<()> {
        if self.config.keep_steps {
            store::save(&self.denoiser, &step_model_path(&self.out, self.state.step))?;
        }
        Ok(())
    }

    /// Trains until `config.steps`, validating and checkpointing every `validate_every` steps
    /// and at the end.
    pub fn run(&mut self, mut on_step: impl FnMut(&Progress)) -> Result<()> {
        if self.state.step == 0 {
            // the starting point is a candidate too: a fine-tune (`init`) that never improves
            // on it leaves its starting model as best.safetensors
            let v = self.validate()?;
            self.log("val", v.loss, Some(v.psnr), None)?;
            self.state.best_val = Some(v.loss);
            store::save(&self.denoiser, &self.out.join("best.safetensors"))?;
            self.checkpoint()?;
            self.keep_step()?;
            on_step(&Progress {
                step: 0,
                loss: f64::NAN,
                tiles_per_s: 0.0,
                validation: Some(v),
            });
        }
        while self.state.step < self.config.steps {
            let t = std::time::Instant::now();
            let loss = self.step()?;
            let tps = self.config.batch as f64 / t.elapsed().as_secs_f64();
            self.log("train", loss, None, Some(tps))?;
            let validation = if self.state.step.is_multiple_of(self.config.validate_every)
                || self.state.step == self.config.steps
            {
                let v = self.validate()?;
                self.log("val", v.loss, Some(v.psnr), None)?;
                if self.state.best_val.is_none_or(|b| v.loss < b) {
                    self.state.best_val = Some(v.loss);
                    store::save(&self.denoiser, &self.out.join("best.safetensors"))?;
                }
                self.checkpoint()?;
                self.keep_step()?;
                crate::train::curves::training_curves(
                    &self.out.join("metrics.csv"),
                    &self.out.join("curves.png"),
                )?;
                Some(v)
            } else {
                None
            };
            on_step(&Progress {
                step: self.state.step,
                loss,
                tiles_per_s: tps,
                validation,
            });
        }
        Ok(())
    }
}
