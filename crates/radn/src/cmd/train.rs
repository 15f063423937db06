//! `radn train`: train a network on prepared tiles.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use radn_train::trainer::{TrainConfig, Trainer};
use radn_train::unet_finetune::{Finetune, FinetuneConfig};

/// Arguments of `radn train`.
#[derive(clap::Args)]
pub struct Args {
    /// Training config (TOML): model preset, tile folders, steps, learning rate, loss, ...
    #[arg(long)]
    pub config: PathBuf,
    /// Run folder: model.safetensors, best.safetensors, checkpoint-STEP.bpk, optimizer-STEP.bpk,
    /// state.json (written last: the checkpoint's commit), metrics.csv.
    #[arg(long)]
    pub out: PathBuf,
    /// Continue the run in --out from its last checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// Training tiles to use instead of the config's `train` (relative to the working folder).
    #[arg(long)]
    pub train: Option<PathBuf>,
    /// Validation tiles to use instead of the config's `val` (relative to the working folder).
    #[arg(long)]
    pub val: Option<PathBuf>,
    /// Train to this many steps instead of the config's `steps` (e.g. to extend a finished run
    /// with --resume; the cosine schedule is recomputed for the new length).
    #[arg(long)]
    pub steps: Option<usize>,
    /// Where to train: cpu or cuda[:N] (needs a build with the `cuda` feature,
    /// scripts/build-cuda). Checkpoints and model files are the same on both.
    #[arg(long, default_value = "cpu", value_name = "cpu|cuda[:N]")]
    pub device: radn_nn::device::ComputeDevice,
    /// Stop after this many minutes, at a checkpoint (continue with --resume). Fine-tunes of
    /// OIDN's U-Net (`network = "oidn-temporal"`) only.
    #[arg(long, value_name = "MINUTES")]
    pub budget: Option<f64>,
}

/// Trains.
pub fn run(a: Args) -> Result<()> {
    let text = std::fs::read_to_string(&a.config)
        .with_context(|| format!("cannot read '{}'", a.config.display()))?;
    if FinetuneConfig::is_finetune(&text) {
        return finetune(&a, &text);
    }
    if a.budget.is_some() {
        bail!("--budget: only fine-tunes of OIDN's U-Net stop at a time budget");
    }
    let mut config =
        TrainConfig::parse(&text).with_context(|| format!("'{}'", a.config.display()))?;
    let cwd = std::env::current_dir().context("cannot read the working folder")?;
    if let Some(t) = &a.train {
        config.train = cwd.join(t);
    }
    if let Some(v) = &a.val {
        config.val = cwd.join(v);
    }
    if let Some(n) = a.steps {
        config.steps = n;
    }
    let base = a.config.parent().map(PathBuf::from).unwrap_or_default();
    let device = a.device.open_for_training()?;
    let mut trainer = Trainer::new(config.clone(), &base, &a.out, a.resume, &device)?;
    let pb = steps_bar(config.steps, trainer.state.step);
    println!(
        "training '{}' on {} ({} parameters) from step {} to {}",
        trainer.denoiser.config.name,
        a.device,
        trainer.denoiser.num_params(),
        trainer.state.step,
        config.steps
    );
    trainer.run(|p| {
        pb.set_position(p.step as u64);
        pb.set_message(format!("loss {:.4}  {:.2} tiles/s", p.loss, p.tiles_per_s));
        if let Some(v) = &p.validation {
            pb.println(format!(
                "step {:>6}: validation loss {:.4}, PSNR {:.2} dB",
                p.step, v.loss, v.psnr
            ));
        }
    })?;
    pb.finish_and_clear();
    println!(
        "done: {} (best: {})",
        a.out.join("model.safetensors").display(),
        a.out.join("best.safetensors").display()
    );
    Ok(())
}

/// `radn train` on a fine-tune of OIDN's U-Net converted into a spatio-temporal network.
fn finetune(a: &Args, text: &str) -> Result<()> {
    let mut config =
        FinetuneConfig::parse(text).with_context(|| format!("'{}'", a.config.display()))?;
    let cwd = std::env::current_dir().context("cannot read the working folder")?;
    let base = a.config.parent().map(PathBuf::from).unwrap_or_default();
    if let Some(t) = &a.train {
        config.train = cwd.join(t).display().to_string();
    }
    if let Some(v) = &a.val {
        config.val = cwd.join(v).display().to_string();
    }
    if let Some(n) = a.steps {
        config.steps = n;
    }
    let device = a.device.open_for_training()?;
    let mut run = Finetune::new(config.clone(), &base, &a.out, a.resume, &device)?;
    println!(
        "fine-tuning OIDN's U-Net with Robust Average blocks at levels {:?} on {} from step {} to {}",
        config.levels, a.device, run.state.step, config.steps
    );
    let pb = steps_bar(config.steps, run.state.step);
    let budget = a
        .budget
        .map(|m| std::time::Duration::from_secs_f64(m * 60.0));
    run.run(budget, |step, loss| {
        pb.set_position(step as u64);
        pb.set_message(format!("loss {loss:.4}"));
    })?;
    pb.finish_and_clear();
    println!(
        "stopped at step {} of {}: validation loss {:.5} (the converted network before training: {:.5}); checkpoint in {}",
        run.state.step,
        config.steps,
        run.state.best_val.unwrap_or(f64::NAN),
        run.state.start_val.unwrap_or(f64::NAN),
        a.out.display()
    );
    Ok(())
}

/// A progress bar over a run's `steps`, at step `at`.
fn steps_bar(steps: usize, at: usize) -> indicatif::ProgressBar {
    let pb = indicatif::ProgressBar::new(steps as u64);
    pb.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} steps  ETA {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    pb.set_position(at as u64);
    pb
}
