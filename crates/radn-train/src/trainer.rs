//! Training (`radn train`): Noise2Noise pairs from a prepared tile set, the spatial-to-temporal
//! loss, Adam with warm-up and cosine decay, periodic validation, checkpoints, and resumption
//! that continues exactly where a run stopped (each step's randomness derives from the seed and
//! the step number; the optimizer state is saved with the weights).

use std::io::Write;

use burn::module::Module;
use std::path::{Path, PathBuf};

use burn::optim::{AdamConfig, GradientsParams};
use burn::store::ModuleSnapshot;
use burn::tensor::{Device, Tensor};
use serde::{Deserialize, Serialize};

use crate::batch::{blend_values, make_batch};
pub use crate::checkpoint::{checkpoint_files, step_model_path};
use crate::checkpoint::{
    drop_metrics_after, drop_rows_from, remove_other_checkpoints, write_checkpoint,
};
pub use crate::config::TrainConfig;
use crate::dataset::{SplitMix, TileDataset};
use crate::layer_stats::{append_csv, gradient_norms, step_stats};
use crate::objective::{objective, sample_pair, LossFn, PairRule, PixelLoss};
use radn_nn::error::{NnError, Result};
use radn_nn::model::config::NetConfig;
use radn_nn::model::demod::Demodulation;
use radn_nn::model::store;
use radn_nn::model::Denoiser;

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
        radn_core::io::output_locks::remove_stale(out)?;
        radn_core::io::output_locks::remove_stale(&out.join("steps"))?;
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
        if train.manifest.guide == val.manifest.guide && train.manifest.oidn != val.manifest.oidn {
            return Err(NnError::Tiles {
                path: base.join(&config.val),
                detail: format!(
                    "their OIDN guides were made with {} and the training tiles' with {}: \
                     prepare both with the same --guide-quality and --guide-prefilter",
                    val.manifest.oidn, train.manifest.oidn
                ),
            });
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
            if let Some(init) = &config.init {
                // the recipe a fine-tune started from, as a run that was never stopped keeps it
                d.recipe = store::load(&base.join(init), device)?.recipe;
            }
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
        let mut denoiser = denoiser;
        if denoiser.config.inputs.guide && train.manifest.guide.as_deref() == Some("oidn") {
            // a guided model runs on guides made as its training guides were
            denoiser.recipe.guide = train.manifest.oidn;
        }
        let loss_fn = match config.loss {
            PixelLoss::Vgg => {
                let p = config.vgg_weights.as_ref().ok_or_else(|| {
                    NnError::Config(
                        "loss = \"vgg\" needs vgg_weights = \"path/to/vgg19.safetensors\"".into(),
                    )
                })?;
                // frozen: it shapes the network's gradients but is never trained
                LossFn::Perceptual(Box::new(
                    crate::vgg::Vgg19::load(&base.join(p), device)?.no_grad(),
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
                            == crate::dataset::DEFAULT_PSEUDO_LEVEL,
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
            recipe: self.denoiser.recipe.clone(),
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
                self.config.mode,
                &self.loss_fn,
                self.config.full_weight,
                frames,
            )
            .into_scalar::<f32>() as f64;
            let out = radn_nn::model::demod::filter(&pred, values, demod.as_ref());
            let tm = |x: Tensor<4>| {
                let x = x.clamp_min(0.0);
                (x.clone() / (x + 1.0)).powf_scalar(1.0 / 2.2)
            };
            let mse = (tm(out) - tm(b.target))
                .powf_scalar(2.0)
                .mean()
                .into_scalar::<f32>() as f64;
            psnr += radn_core::eval::metrics::psnr_from_mse(mse);
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
        let step = self.state.step;
        let [_, optimizer] = checkpoint_files(&self.out, step);
        write_checkpoint(
            &self.out,
            step,
            &self.denoiser.net,
            &[(optimizer, &self.optim)],
            &self.state,
        )
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
                crate::curves::training_curves(
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
