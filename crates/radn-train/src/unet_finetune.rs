//! Fine-tuning OIDN's U-Net converted into a spatio-temporal network ([`TemporalUnet`]) on
//! prepared tiles (`radn prepare`): each step reads windows at a random noise level,
//! processes them as OIDN does (the beauty at the centre tile's OIDN autoexposure through the
//! PU curve, albedo clamped, normals mapped to [0, 1]), and fits the centre frame's output to
//! an independent render of it (Noise2Noise pairs: a cleaner level where there is one), in the
//! network's PU space, where OIDN trained it. With the paper's temporal loss (§5), two of three
//! windows hold only a pair of frames around the centre, not the centre itself, and are fitted
//! to the same target, so the network must learn to use its neighbours. Runs are resumable and stop at a time budget:
//! checkpoints hold the weights (Burnpack, with parameter ids), the optimizer state and the
//! step, committed by `state.json`, and every step's batch is drawn from the seed and the step
//! alone, so a resumed run continues exactly as an uninterrupted one.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams};
use burn::store::ModuleSnapshot;
use burn::tensor::{Device, Tensor};
use serde::{Deserialize, Serialize};

use radn_core::align::warp::Resampling;
use radn_nn::oidn_unet::temporal::{AuxSource, TemporalConfig, TemporalUnet, WarpSpace};
use radn_nn::oidn_unet::transfer::HDR_BEAUTY;
use radn_nn::oidn_unet::{store, temporal_store};
use radn_nn::{NnError, Result};

use crate::checkpoint::{checkpoint_files, remove_other_checkpoints, write_checkpoint};
use crate::dataset::{SplitMix, TileDataset};

mod windows;
use windows::{batch, target_for, validation_plan, window_frames, Draw};

/// The model file (`radn denoise --method temporal --model`) of the best validation so far.
pub const BEST_MODEL: &str = "best.safetensors";
/// The model file of the last checkpoint.
pub const LAST_MODEL: &str = "model.safetensors";

/// Which of the network's layers a fine-tune trains (the rest keep OIDN's weights).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TrainedLayers {
    /// The temporal blends only.
    #[default]
    Temporal,
    /// The temporal blends and the U-Net's decoder.
    TemporalAndDecoder,
    /// Everything.
    All,
}

/// What a fine-tune's training loss compares, in which space.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FinetuneLoss {
    /// L1 in the network's PU space, as OIDN trained it on clean references. Against noisy
    /// targets it fits their median, darker than their mean for Monte Carlo noise.
    PuL1,
    /// Noise2Noise's HDR loss: squared error in linear space relative to the prediction's own
    /// square (held constant) plus 0.01. Its expectation over a noisy target is least at the
    /// target's mean, so noisy targets do not bias the result.
    #[default]
    RelativeL2,
}

impl FinetuneLoss {
    /// The loss of `prediction` against `target` (both network values, PU space).
    pub fn of(self, prediction: Tensor<4>, target: Tensor<4>) -> Tensor<1> {
        match self {
            FinetuneLoss::PuL1 => (prediction - target).abs().mean(),
            FinetuneLoss::RelativeL2 => {
                let (f, t) = (pu_to_linear(prediction), pu_to_linear(target));
                let scale = f.clone().detach().powi_scalar(2) + 0.01;
                ((f - t).powi_scalar(2) / scale).mean()
            }
        }
    }
}

/// A fine-tune's settings (TOML; paths relative to the file).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FinetuneConfig {
    /// What is trained: `"oidn-temporal"` (what tells `radn train` this file is a fine-tune).
    pub network: String,
    /// The imported OIDN U-Net to convert (`radn model import-oidn`).
    pub init: String,
    /// Training tiles.
    pub train: String,
    /// Validation tiles.
    pub val: String,
    /// Encoder levels that get a Robust Average block.
    pub levels: Vec<usize>,
    /// Which layers are trained.
    #[serde(default)]
    pub trained: TrainedLayers,
    /// Windows per step.
    pub batch: usize,
    /// Crop side (a multiple of 16, at most the tile side).
    pub crop: usize,
    /// Steps in all (over every resumed run).
    pub steps: usize,
    /// Adam's learning rate for the U-Net's layers.
    pub lr: f64,
    /// Adam's learning rate for the temporal blends (their gates start at zero: Adam moves a
    /// weight by about its learning rate per step, so the U-Net's small rate would keep them
    /// nearly closed for thousands of steps).
    #[serde(default = "default_temporal_lr")]
    pub temporal_lr: f64,
    /// Adam's epsilon: it must stay small against the gates' gradients (each a mean over every
    /// pixel), or it, not the learning rate, sets how fast they open.
    #[serde(default = "default_adam_epsilon")]
    pub adam_epsilon: f32,
    /// Seed of the batches and crops.
    pub seed: u64,
    /// Steps between validations (and checkpoints).
    pub validate_every: usize,
    /// Validation tiles (the first ones of the set).
    pub val_tiles: usize,
    /// The paper's spatial-to-temporal loss conversion (§5): two of every three windows are a
    /// pair of frames, one before and one after the centre, without the centre frame, fitted to
    /// the same target; off: every window is the whole window.
    #[serde(default = "default_true")]
    pub temporal_loss: bool,
    /// The training loss.
    #[serde(default)]
    pub loss: FinetuneLoss,
    /// Alignment's colour term for the model's windows at inference
    /// ([`TemporalConfig::color_confidence`], kept in the model file).
    #[serde(default)]
    pub color_confidence: Option<f32>,
    /// Where the model's windows are moved onto the centre at inference
    /// ([`TemporalConfig::warp`], kept in the model file); training reads aligned tiles.
    #[serde(default)]
    pub warp: WarpSpace,
    /// Frames of each window whose colour is averaged into the centre frame's input
    /// ([`TemporalConfig::input_frames`], kept in the model file): in training, the centre
    /// slot of whole windows (the pairs without the centre read frames as rendered).
    #[serde(default = "default_input_frames")]
    pub input_frames: usize,
    /// The temporal pass over the results at inference ([`TemporalConfig::stabilize`], kept
    /// in the model file; training does not see it).
    #[serde(default)]
    pub stabilize: Option<radn_core::post::stabilize::StabilizeSettings>,
    /// A learned average of the window's input at the centre frame
    /// ([`TemporalConfig::input_blend`], kept in the model file), trained with the blocks.
    #[serde(default)]
    pub input_blend: bool,
}

fn default_input_frames() -> usize {
    1
}

fn default_true() -> bool {
    true
}

fn default_temporal_lr() -> f64 {
    1e-3
}

fn default_adam_epsilon() -> f32 {
    1e-8
}

/// The `network` of a fine-tune of OIDN's converted U-Net.
pub const NETWORK: &str = "oidn-temporal";

impl FinetuneConfig {
    /// Whether a TOML configuration is a fine-tune of OIDN's U-Net (its `network`).
    pub fn is_finetune(text: &str) -> bool {
        toml::from_str::<toml::Table>(text)
            .ok()
            .and_then(|t| {
                t.get("network")
                    .and_then(|v| v.as_str())
                    .map(|v| v == NETWORK)
            })
            .unwrap_or(false)
    }

    /// Parses and checks a TOML configuration.
    pub fn parse(text: &str) -> Result<Self> {
        let c: Self = toml::from_str(text).map_err(|e| NnError::Config(e.to_string()))?;
        if c.network != NETWORK {
            return Err(NnError::Config(format!(
                "network = \"{}\": a fine-tune's network is \"{NETWORK}\"",
                c.network
            )));
        }
        if c.crop == 0 || !c.crop.is_multiple_of(16) {
            return Err(NnError::Config(format!(
                "crop = {}: the U-Net needs a multiple of 16",
                c.crop
            )));
        }
        if c.batch == 0 || c.validate_every == 0 {
            return Err(NnError::Config(
                "batch and validate_every must be positive".into(),
            ));
        }
        Ok(c)
    }
}

/// A fine-tune's progress, written last at each checkpoint (its commit).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct FinetuneState {
    /// Steps completed.
    pub step: usize,
    /// Validation loss of the converted network before training (OIDN's U-Net).
    pub start_val: Option<f64>,
    /// Best validation loss so far.
    pub best_val: Option<f64>,
}

/// A fine-tuning run.
pub struct Finetune {
    config: FinetuneConfig,
    out: PathBuf,
    device: Device,
    net: TemporalUnet,
    optim: burn::optim::ModuleOptimizer,
    temporal_optim: burn::optim::ModuleOptimizer,
    /// Its progress.
    pub state: FinetuneState,
    train: TileDataset,
    val: TileDataset,
    /// The validation tiles and the target level each is scored against.
    val_plan: Vec<(usize, usize)>,
}

impl Finetune {
    /// Opens a run in `out` (resuming its last checkpoint when `resume` and there is one)
    /// from `config` (paths relative to `base`).
    pub fn new(
        config: FinetuneConfig,
        base: &Path,
        out: &Path,
        resume: bool,
        device: &Device,
    ) -> Result<Self> {
        std::fs::create_dir_all(out).map_err(|e| NnError::Save {
            path: out.to_path_buf(),
            detail: e.to_string(),
        })?;
        let train = TileDataset::open(&base.join(&config.train))?;
        let val = TileDataset::open(&base.join(&config.val))?;
        if train.manifest.tile < config.crop {
            return Err(NnError::Config(format!(
                "crop = {} is larger than the tiles ({})",
                config.crop, train.manifest.tile
            )));
        }
        if train.manifest.aux_prefilters != val.manifest.aux_prefilters {
            return Err(NnError::Config(format!(
                "the training and validation tiles hold different auxiliaries ({:?} and {:?}): \
                 prepare both with the same --aux",
                train.manifest.aux_prefilters, val.manifest.aux_prefilters
            )));
        }
        let averaged = (config.input_frames > 1)
            .then(|| format!("input_frames = {}", config.input_frames))
            .or(config.input_blend.then(|| "input_blend".to_string()));
        if let Some(what) = averaged.filter(|_| train.manifest.resampling != Resampling::Nearest) {
            return Err(NnError::Config(format!(
                "{what}: the centre's input average is made of nearest-pixel samples at \
                 inference, and these tiles were aligned with {} samples (prepare them with \
                 --resampling nearest)",
                train.manifest.resampling.name()
            )));
        }
        let unet = store::load(&base.join(&config.init), device)?;
        // the blocks' initial weights from the seed (a resumed run then loads its own)
        device.seed(config.seed);
        let temporal = TemporalConfig {
            frames: train.manifest.frames,
            levels: config.levels.clone(),
            color_confidence: config.color_confidence,
            warp: config.warp,
            // as the tiles hold them, so inference cleans them as they were cleaned
            aux: match train.manifest.aux_prefilters {
                Some(_) => AuxSource::Prefiltered,
                None => AuxSource::Rendered,
            },
            input_frames: config.input_frames,
            stabilize: config.stabilize,
            input_blend: config.input_blend,
        };
        let net = TemporalUnet::convert(unet, temporal, device)
            .map_err(|e| NnError::Config(e.to_string()))?;
        let val_plan = validation_plan(&val, config.val_tiles)?;
        let state_path = out.join("state.json");
        let mut run = Self {
            optim: AdamConfig::new().with_epsilon(config.adam_epsilon).init(),
            temporal_optim: AdamConfig::new().with_epsilon(config.adam_epsilon).init(),
            state: FinetuneState::default(),
            config,
            out: out.to_path_buf(),
            device: device.clone(),
            net,
            train,
            val,
            val_plan,
        };
        if resume && state_path.exists() {
            let load = |path: &Path, e: String| NnError::Load {
                path: path.to_path_buf(),
                detail: e,
            };
            let text = std::fs::read_to_string(&state_path)
                .map_err(|e| load(&state_path, e.to_string()))?;
            run.state =
                serde_json::from_str(&text).map_err(|e| load(&state_path, e.to_string()))?;
            let [weights, optimizer] = checkpoint_files(out, run.state.step);
            let mut bp = burn::store::BurnpackStore::from_file(&weights);
            let r = run
                .net
                .load_from(&mut bp)
                .map_err(|e| load(&weights, format!("{e:?}")))?;
            if !r.missing.is_empty() || !r.errors.is_empty() {
                return Err(load(
                    &weights,
                    "the checkpoint does not match the configured network".into(),
                ));
            }
            let eps = run.config.adam_epsilon;
            run.optim = AdamConfig::new()
                .with_epsilon(eps)
                .init()
                .load(&optimizer)
                .map_err(|e| load(&optimizer, format!("{e:?}")))?;
            let temporal = temporal_optimizer_file(out, run.state.step);
            run.temporal_optim = AdamConfig::new()
                .with_epsilon(eps)
                .init()
                .load(&temporal)
                .map_err(|e| load(&temporal, format!("{e:?}")))?;
            remove_other_checkpoints(out, run.state.step);
        }
        run.freeze();
        Ok(run)
    }

    /// The network being trained.
    pub fn net(&self) -> &TemporalUnet {
        &self.net
    }

    /// Marks the layers the configuration leaves at OIDN's weights as not trained.
    fn freeze(&mut self) {
        let encoder = self.net.unet.encoder_steps();
        let layers = self.net.unet.layers.clone();
        self.net.unet.layers = match self.config.trained {
            TrainedLayers::All => layers,
            TrainedLayers::TemporalAndDecoder => layers.frozen_below(encoder),
            TrainedLayers::Temporal => layers.no_grad(),
        };
    }

    /// The tiles, levels and crop corner of step `step`'s batch, from the seed and the step.
    fn plan(&self, step: usize) -> Vec<Draw> {
        let mut rng =
            SplitMix(self.config.seed ^ (step as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let room = self.train.manifest.tile - self.config.crop;
        let t = self.train.manifest.frames;
        (0..self.config.batch)
            .map(|_| {
                let tile = rng.below(self.train.len());
                let input = rng.below(3);
                let corner = (rng.below(room + 1), rng.below(room + 1));
                // the centre term, or the pair (k, k + t/2 + 1): one frame before the centre
                // and one after, filling the slots in turn (the centre's slot by a coin)
                let term = if self.config.temporal_loss {
                    rng.below(3)
                } else {
                    0
                };
                let frames = window_frames(t, term, rng.below(2) == 0);
                Draw {
                    tile,
                    input,
                    target: target_for(input),
                    corner,
                    frames,
                }
            })
            .collect()
    }

    /// One optimizer step; returns the training loss.
    pub fn step(&mut self) -> Result<f64> {
        let plan = self.plan(self.state.step);
        let b = batch(
            &self.train,
            &plan,
            self.config.crop,
            self.config.input_frames,
            &self.device,
        )?;
        let loss = self
            .config
            .loss
            .of(self.net.forward(b.window, None), b.target);
        let value = loss.clone().into_scalar::<f32>() as f64;
        if !value.is_finite() {
            return Err(NnError::Config(format!(
                "the loss became {value} at step {}",
                self.state.step
            )));
        }
        let mut grads = loss.backward();
        let temporal = GradientsParams::from_module(&mut grads, &self.net.temporal);
        let unet = GradientsParams::from_grads(grads, &self.net.unet);
        // modules hold tensor handles: the clones are cheap
        self.net.temporal =
            self.temporal_optim
                .step(self.config.temporal_lr, self.net.temporal.clone(), temporal);
        self.net.unet = self.optim.step(self.config.lr, self.net.unet.clone(), unet);
        self.state.step += 1;
        Ok(value)
    }

    /// The mean validation loss (L1 in PU space) of input `low` on the validation tiles
    /// (`validation_plan`): against their clean references where the set has them, else
    /// against their 32-spp render.
    pub fn validate(&self) -> Result<f64> {
        Ok(self.validation()?.0)
    }

    /// The mean validation loss and the mean PSNR (dB, PU space: 10·log10(1 / MSE)) of
    /// [`Finetune::validate`]'s tiles.
    pub fn validation(&self) -> Result<(f64, f64)> {
        // off the autodiff graph
        let plain = self.device.clone().without_autodiff();
        let net = self.net.valid();
        let n = self.val_plan.len();
        let (mut l1, mut psnr) = (0.0, 0.0);
        for &(tile, target) in &self.val_plan {
            let whole = Draw {
                tile,
                input: 2,
                target,
                corner: (0, 0),
                frames: (0..self.val.manifest.frames).collect(),
            };
            let b = batch(
                &self.val,
                &[whole],
                self.config.crop,
                self.config.input_frames,
                &plain,
            )?;
            let diff = net.forward(b.window, None) - b.target;
            l1 += diff.clone().abs().mean().into_scalar::<f32>() as f64;
            let mse = diff.powi_scalar(2).mean().into_scalar::<f32>() as f64;
            psnr += -10.0 * mse.max(1e-12).log10();
        }
        Ok((l1 / n as f64, psnr / n as f64))
    }

    /// Saves a checkpoint: weights and optimizer files named by the step, then `state.json`
    /// (the commit), then the older checkpoint's files are removed.
    pub fn checkpoint(&mut self) -> Result<()> {
        let step = self.state.step;
        let [_, optimizer] = checkpoint_files(&self.out, step);
        let optimizers = [
            (optimizer, &self.optim),
            (
                temporal_optimizer_file(&self.out, step),
                &self.temporal_optim,
            ),
        ];
        write_checkpoint(&self.out, step, &self.net, &optimizers, &self.state)
    }

    /// Trains to the configured steps or until `budget` has passed (then checkpoints and
    /// returns: run again to continue), validating and checkpointing every
    /// `validate_every` steps; `on_step` sees each step's number and loss.
    pub fn run(
        &mut self,
        budget: Option<Duration>,
        mut on_step: impl FnMut(usize, f64),
    ) -> Result<()> {
        let started = Instant::now();
        if self.state.start_val.is_none() {
            let (v, psnr) = self.validation()?;
            self.state.start_val = Some(v);
            self.state.best_val = Some(v);
            self.log("val", v, Some(psnr))?;
        }
        while self.state.step < self.config.steps {
            let loss = self.step()?;
            on_step(self.state.step, loss);
            self.log("train", loss, None)?;
            let due = self.state.step.is_multiple_of(self.config.validate_every)
                || self.state.step == self.config.steps;
            let out_of_time = budget.is_some_and(|b| started.elapsed() >= b);
            if due {
                let (v, psnr) = self.validation()?;
                self.log("val", v, Some(psnr))?;
                if self.state.best_val.is_none_or(|b| v < b) {
                    self.state.best_val = Some(v);
                    temporal_store::save(&self.net.valid(), &self.out.join(BEST_MODEL))?;
                }
            }
            if due || out_of_time {
                self.checkpoint()?;
                temporal_store::save(&self.net.valid(), &self.out.join(LAST_MODEL))?;
            }
            if out_of_time {
                break;
            }
        }
        Ok(())
    }

    /// Appends a row to `metrics.csv`.
    fn log(&self, kind: &str, loss: f64, psnr: Option<f64>) -> Result<()> {
        use std::io::Write;
        let p = self.out.join("metrics.csv");
        let new = !p.exists();
        let err = |e: std::io::Error| NnError::Save {
            path: p.clone(),
            detail: e.to_string(),
        };
        let mut f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&p)
            .map_err(err)?;
        if new {
            writeln!(f, "step,kind,loss,psnr,gates").map_err(err)?;
        }
        let psnr = psnr.map_or(String::new(), |p| format!("{p:.3}"));
        // at validations, how open each level's gate is (mean |gate|, levels in order), then
        // the learned input average's ("in=")
        let gates = if kind == "val" {
            let temporal = &self.net.temporal;
            temporal
                .openness()
                .iter()
                .map(|g| format!("{g:.4}"))
                .chain(temporal.input_openness().map(|g| format!("in={g:.4}")))
                .collect::<Vec<_>>()
                .join(" ")
        } else {
            String::new()
        };
        writeln!(f, "{},{kind},{loss:.6},{psnr},{gates}", self.state.step).map_err(err)
    }
}

/// Which of a `t`-frame tile's frames fills each slot of a training window for loss term
/// The HDR beauty's network values (PU) as scaled linear values, in tensor operations so that
/// a loss can be taken in linear space.
fn pu_to_linear(x: Tensor<4>) -> Tensor<4> {
    HDR_BEAUTY.transfer.inverse_tensor(x)
}

/// The temporal blends' optimizer state of the checkpoint of `step`.
fn temporal_optimizer_file(out: &Path, step: usize) -> PathBuf {
    out.join(format!("temporal-optimizer-{step:07}.bpk"))
}

#[cfg(test)]
mod tests {
    /// Against noisy targets (a skewed distribution, as Monte Carlo estimates are), training
    /// with the relative L2 loss settles at the targets' mean (its gradient is zero there);
    /// with PU-space L1 near their median, well below it.
    #[test]
    fn relative_l2_settles_at_the_mean_of_noisy_targets_and_pu_l1_below_it() {
        use super::{FinetuneLoss, HDR_BEAUTY};
        use burn::tensor::{Device, Tensor, TensorData};
        let device = Device::flex().autodiff();
        // exponential samples of mean 1 (a quantile grid), as linear values
        let n = 4096;
        let samples: Vec<f32> = (0..n)
            .map(|i| -(1.0 - (i as f32 + 0.5) / n as f32).ln())
            .collect();
        let mean = samples.iter().sum::<f32>() / n as f32;
        let pu = |v: &[f32]| -> Tensor<4> {
            let x = v.iter().map(|&y| HDR_BEAUTY.input(y, 1.0)).collect();
            Tensor::from_data(TensorData::new(x, [1, 1, 64, 64]), &device)
        };
        let target = pu(&samples);
        // the loss's slope with respect to a constant prediction of linear value `c`
        let slope = |loss: FinetuneLoss, c: f32| -> f32 {
            let x = pu(&vec![c; n]).require_grad();
            let grads = loss.of(x.clone(), target.clone()).backward();
            x.grad(&grads).unwrap().sum().into_scalar::<f32>()
        };
        // where gradient descent settles: the slope's zero, by bisection
        let settles = |loss: FinetuneLoss| -> f32 {
            let (mut lo, mut hi) = (0.05f32, 3.0f32);
            assert!(slope(loss, lo) < 0.0 && slope(loss, hi) > 0.0);
            for _ in 0..30 {
                let mid = 0.5 * (lo + hi);
                if slope(loss, mid) < 0.0 {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            lo
        };
        let (l2, l1) = (
            settles(FinetuneLoss::RelativeL2),
            settles(FinetuneLoss::PuL1),
        );
        assert!(
            (l2 - mean).abs() < 1e-3 * mean,
            "relative L2 settles at {l2}, mean {mean}"
        );
        assert!(l1 < 0.75 * mean, "PU L1 settles at {l1}, mean {mean}");
    }
}
