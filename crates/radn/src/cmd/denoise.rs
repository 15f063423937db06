//! `radn denoise`: denoise an EXR sequence with the best path this machine allows.

use radn_core::run::motion::MotionChoice;
use std::path::PathBuf;

use anyhow::{anyhow, bail, Result};
use radn_core::classic::pipeline::ClassicDenoiser;
use radn_core::io::frame::Requirements;
use radn_core::io::sequence::{sequence_files, SequencePattern};
use radn_core::run::denoiser::WindowDenoiser;
use radn_core::run::passes::DenoiseRun;
use radn_core::setting::Setting;
use radn_nn::device::ComputeDevice;
use radn_nn::infer::NetworkDenoiser;

use crate::input::{check_threshold, classic_tuned, tune_pairs, ChannelArgs};
use crate::model::{choose_path, GuideRequest};

/// Denoising methods.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// A kernel-predicting network (the built-in models, or --model).
    Network,
    /// The non-neural temporal denoiser.
    Classic,
    /// OIDN's U-Net on each frame alone, run by radn (no temporal step, no OIDN library).
    Spatial,
    /// OIDN's U-Net converted into the spatio-temporal network (--model FILE, from radn train).
    Temporal,
}

/// Storage type of denoised channels.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum Precision {
    /// Whatever the input channel uses.
    Same,
    /// 16-bit float.
    Half,
    /// 32-bit float.
    Float,
}

impl Precision {
    /// The sample kind to force, if any.
    pub fn kind(self) -> Option<radn_core::io::exr_file::SampleKind> {
        match self {
            Precision::Same => None,
            Precision::Half => Some(radn_core::io::exr_file::SampleKind::F16),
            Precision::Float => Some(radn_core::io::exr_file::SampleKind::F32),
        }
    }
}

/// Arguments of `radn denoise`.
#[derive(clap::Args)]
#[command(next_help_heading = "Input and output")]
pub struct Args {
    /// Input: beauty.####.exr (or %04d, $F4), or a folder.
    #[arg(short, long, value_name = "PATTERN", required_unless_present = "tune")]
    pub input: Option<String>,
    /// Output pattern; every layer of the input is kept.
    #[arg(short, long, value_name = "PATTERN", required_unless_present = "tune")]
    pub output: Option<String>,
    /// Frames to write, FIRST-LAST[xSTEP] (default: all).
    #[arg(long, value_name = "RANGE")]
    pub frames: Option<String>,
    /// Extra layers denoised with the beauty's weights.
    #[arg(long, value_delimiter = ',', value_name = "A,B")]
    pub aovs: Vec<String>,
    /// Recompute existing outputs (default: skip, to resume).
    #[arg(long)]
    pub overwrite: bool,
    /// Storage of denoised channels: same, half, float.
    #[arg(
        long,
        value_enum,
        default_value = "same",
        value_name = "KIND",
        hide_possible_values = true
    )]
    pub output_precision: Precision,
    #[command(flatten)]
    pub channels: ChannelArgs,

    /// network, classic, spatial (OIDN's U-Net per frame) or temporal.
    #[arg(
        long,
        value_enum,
        default_value = "network",
        value_name = "METHOD",
        hide_possible_values = true,
        help_heading = "Quality"
    )]
    pub method: Method,
    /// auto (OIDN if found), none, oidn, denoised, LAYER.
    #[arg(
        long,
        value_name = "GUIDE",
        default_value = "auto",
        help_heading = "Quality"
    )]
    pub guide: GuideRequest,
    /// A model file instead of the built-in ones.
    #[arg(long, value_name = "FILE", help_heading = "Quality")]
    pub model: Option<PathBuf>,
    /// With --method spatial: OIDN-prefiltered's three large U-Nets (albedo, normal, beauty).
    #[arg(long, help_heading = "Quality")]
    pub prefilter: bool,
    /// 1: as tuned; lower keeps more of the input.
    #[arg(long, default_value_t = 1.0, value_parser = parse_strength, value_name = "S",
          help_heading = "Quality")]
    pub strength: f32,
    /// Network passes (more widen the temporal reach).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..),
          value_name = "N", help_heading = "Quality")]
    pub passes: u32,

    /// Where the network runs: cpu or cuda[:N].
    #[arg(
        long,
        default_value = "cpu",
        value_name = "DEVICE",
        help_heading = "Performance"
    )]
    pub device: ComputeDevice,
    /// auto, off (whole frames) or pixels.
    #[arg(
        long,
        value_name = "SIZE",
        default_value = "auto",
        help_heading = "Performance"
    )]
    pub tile: Setting<usize>,
    /// auto, always, never, or rows per band: memory follows the width.
    #[arg(
        long,
        default_value = "auto",
        value_name = "WHEN",
        help_heading = "Performance"
    )]
    pub bands: crate::input::BandsArg,
    /// Motion source: auto, renderer or estimate (from the frames).
    #[arg(
        long,
        default_value = "auto",
        value_name = "SOURCE",
        value_parser = ["auto", "renderer", "estimate"],
        hide_possible_values = true
    )]
    pub motion: String,
    /// Tiles per network call.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..),
          value_name = "N", help_heading = "Performance")]
    pub batch: u32,
    /// OIDN's threads (0: every core).
    #[arg(
        long,
        default_value_t = 0,
        value_name = "N",
        help_heading = "Performance"
    )]
    pub oidn_threads: usize,

    /// Override a tuned setting (--tune help lists them).
    #[arg(long, value_name = "KEY=VALUE", help_heading = "Advanced")]
    pub tune: Vec<String>,
}

/// Parses `--strength`: a positive number.
fn parse_strength(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("'{s}' is not a positive strength (1: as tuned)")),
    }
}

/// Keys `--tune` takes besides the recipe's and the classic denoiser's.
const RUN_KEYS: &[(&str, &str)] = &[(
    "stem-per-window",
    "run a frame-local stem in every window, as training does: on|off",
)];

/// Denoises the sequence.
pub fn run(a: Args) -> Result<()> {
    if a.tune.iter().any(|t| t == "help") {
        return print_tune_help(&a);
    }
    let (Some(input), Some(output)) = (a.input.clone(), a.output.clone()) else {
        bail!("--input and --output are required");
    };
    let wanted = sequence_files(&input, a.frames.as_deref())?;
    let motion: MotionChoice = a.motion.parse().map_err(anyhow::Error::msg)?;
    // the renderer's vectors are needed only where nothing else may stand in for them
    let needs = Requirements {
        motion: motion == MotionChoice::Renderer,
        ..Requirements::DENOISE
    };
    let mut reader = a.channels.reader(&wanted[0].1, needs)?;
    reader.aovs = a.aovs.clone();
    let (method, oidn, stabilize): (Box<dyn WindowDenoiser>, _, _) = match a.method {
        Method::Classic => {
            if matches!(&a.guide, GuideRequest::Given(g) if g.is_some()) {
                bail!("--guide steers a guided network; the classic denoiser reads no guide");
            }
            if a.device.is_gpu() {
                bail!(
                    "--device {}: the classic denoiser runs on the CPU only; use --method network",
                    a.device
                );
            }
            println!("radn: classic path (non-neural)");
            (Box::new(classic_from(&a)?), None, None)
        }
        Method::Spatial => {
            if matches!(&a.guide, GuideRequest::Given(g) if g.is_some()) {
                bail!("--guide steers a guided network; --method spatial reads no guide");
            }
            if a.device.is_gpu() {
                bail!("--device {}: --method spatial runs on the CPU", a.device);
            }
            let d = crate::model::spatial(a.model.as_deref(), a.prefilter)?;
            println!("radn: spatial path, per frame: {}", d.summary());
            reader = reader.per_frame(Requirements::AUXILIARIES);
            (Box::new(d), None, None)
        }
        Method::Temporal => {
            if matches!(&a.guide, GuideRequest::Given(g) if g.is_some()) {
                bail!("--guide steers a guided network; --method temporal reads no guide");
            }
            if a.device.is_gpu() {
                bail!("--device {}: --method temporal runs on the CPU", a.device);
            }
            let Some(path) = a.model.as_deref() else {
                bail!("--method temporal needs --model FILE (a model radn train wrote)");
            };
            let mut d = crate::model::temporal(path)?;
            // --tile: the side of the network's square tiles (memory against time)
            match a.tile {
                Setting::Auto => {}
                Setting::Off => d = d.with_tile_pixels(usize::MAX),
                Setting::Value(t) => d = d.with_tile_pixels(t.saturating_mul(t)),
            }
            println!("radn: temporal U-Net path: {}", d.summary());
            let stabilize = d.stabilizer();
            (Box::new(d), None, stabilize)
        }
        Method::Network => {
            let chosen = choose_path(a.model.as_deref(), &a.guide, a.oidn_threads, a.device)?;
            println!("{}", chosen.summary);
            reader.guide = chosen.guide.layer();
            let n = network_from(&a, chosen.network)?;
            if let Some(o) = &chosen.oidn {
                o.configure(n.recipe.guide);
                tracing::debug!("OIDN guides: {}", n.recipe.guide);
            }
            let stabilize = n.recipe.stabilize.map(|s| s.stabilizer());
            (Box::new(n), chosen.oidn, stabilize)
        }
    };
    let forced = matches!(
        a.bands,
        crate::input::BandsArg::Always | crate::input::BandsArg::Rows(_)
    );
    if forced && method.banded().is_none() {
        tracing::warn!(
            "--bands: this method runs whole frames (the classic method, --tile off or a \
             UNet), so memory follows the frame"
        );
    }
    let run = DenoiseRun {
        input: SequencePattern::parse_or_folder(&input)?,
        output: SequencePattern::parse(&output)?,
        frames: wanted.iter().map(|(f, _)| *f).collect(),
        reader,
        overwrite: a.overwrite,
        output_kind: a.output_precision.kind(),
        passes: if a.method == Method::Network {
            a.passes as usize
        } else {
            1
        },
        oidn,
        bands: a.bands.into(),
        stabilize,
        fuse_temporal: true,
        motion,
    };
    let t = std::time::Instant::now();
    radn_core::run::timing::take();
    let outputs = run.frames.len();
    let mut bar: Option<(usize, indicatif::ProgressBar)> = None;
    let report = run.run(method.as_ref(), |p| {
        if bar.as_ref().is_none_or(|(pass, _)| *pass != p.pass) {
            if let Some((_, pb)) = bar.take() {
                pb.finish_and_clear();
            }
            // the temporal pass, where there is one, comes after the denoising passes
            let label = if p.pass > run.passes {
                "temporal pass".to_string()
            } else {
                format!("pass {}/{}", p.pass, run.passes)
            };
            let pb = crate::progress::fine_frames(p.frames as u64, &label);
            bar = Some((p.pass, pb));
        }
        if let Some((_, pb)) = &bar {
            pb.set_position((p.done * crate::progress::PARTS_PER_FRAME as f64) as u64);
        }
        // stages work on different frame counts (the temporal pass reads beyond the frames it
        // writes): programs get the run's fraction and the frames it writes
        let stage = if p.frames > 0 {
            p.done / p.frames as f64
        } else {
            1.0
        };
        crate::progress::event(serde_json::json!({
            "event": "progress",
            "stage": p.pass,
            "stages": p.passes,
            "stage_done": p.done,
            "stage_frames": p.frames,
            "fraction": ((p.pass - 1) as f64 + stage) / p.passes.max(1) as f64,
            "frames": outputs,
        }));
    })?;
    if let Some((_, pb)) = bar {
        pb.finish_and_clear();
    }
    println!(
        "denoised {} frames ({} already done, skipped) in {:.1} s -> {}",
        report.written,
        report.skipped,
        t.elapsed().as_secs_f64(),
        output
    );
    if report.repaired > 0 {
        println!("repaired {} NaN/Inf input samples", report.repaired);
    }
    if report.written > 0 {
        tracing::debug!(
            "where the time went, over {} frames written:\n{}",
            report.written,
            radn_core::run::timing::report(
                &radn_core::run::timing::take(),
                t.elapsed(),
                report.written
            )
        );
    }
    // (keys sort after "event": programs read a line starting `{"event"` as an event)
    for (before, after) in &report.cuts {
        crate::progress::event(serde_json::json!({
            "event": "cut",
            "frames": [before, after],
        }));
    }
    crate::progress::event(serde_json::json!({
        "event": "finished",
        "written": report.written,
        "skipped": report.skipped,
        "repaired": report.repaired,
        "seconds": t.elapsed().as_secs_f64(),
    }));
    Ok(())
}

/// The network with the model's recipe, `--strength` and `--tune` applied, and the run's
/// tiling.
fn network_from(a: &Args, mut n: NetworkDenoiser) -> Result<NetworkDenoiser> {
    let guided = n.denoiser.config.inputs.guide;
    for (key, value) in tune_pairs(&a.tune)? {
        if key.starts_with("classic.") {
            bail!("--tune {key}: a classic denoiser setting, and this run uses the network");
        }
        if !guided && (key.starts_with("mix.") || key == "confidence.guide") {
            bail!("--tune {key}: a guided model's setting, and this run's model reads no guide");
        }
        match key {
            "stem-per-window" => {
                n.warp_stem_features = match value {
                    "on" => false,
                    "off" => true,
                    _ => bail!("--tune {key}={value}: give on or off"),
                }
            }
            _ => n.recipe.set(key, value).map_err(|e| anyhow!(e))?,
        }
    }
    let taps = n.denoiser.config.kernel_taps() as f32;
    let t = n.threshold();
    check_threshold(t, &n.denoiser.config)?;
    if a.strength != 1.0 {
        // the paper's threshold, normalised by the kernel's taps and divided by the strength;
        // past 1/K every kernel falls back to the identity, so it stops just below
        n.recipe.threshold = Some((t / a.strength).min(0.999 / taps));
    }
    match a.tile {
        Setting::Auto => {}
        Setting::Off => n.tile = 0,
        Setting::Value(t) => n.tile = t,
    }
    n.batch = a.batch as usize;
    Ok(n)
}

/// The classic denoiser with `--strength` and `--tune classic.*` applied.
fn classic_from(a: &Args) -> Result<ClassicDenoiser> {
    let mut d = classic_tuned(&a.tune)?;
    d.params.nlm.strength *= a.strength;
    Ok(d)
}

/// `--tune help`: every key with the value the run would use (the model's recipe, after any
/// other `--tune` given), and the classic denoiser's.
fn print_tune_help(a: &Args) -> Result<()> {
    let device = radn_nn::burn::tensor::Device::flex();
    let mut rows: Vec<(String, String, String, &str)> = Vec::new();
    let (guided, unguided) = match &a.model {
        Some(p) => {
            let d = crate::model::load(Some(p), &device)?;
            (d.recipe.clone(), d.recipe)
        }
        None => (
            crate::model::load_for(None, true, &device)?.recipe,
            crate::model::load(None, &device)?.recipe,
        ),
    };
    for (key, help) in radn_nn::recipe::keys::KEYS {
        rows.push((
            key.to_string(),
            guided.get(key).unwrap_or_default(),
            unguided.get(key).unwrap_or_default(),
            help,
        ));
    }
    let classic = ClassicDenoiser::default();
    for (key, help) in radn_core::classic::keys::KEYS {
        let v = classic.get(key).unwrap_or_default();
        rows.push((key.to_string(), v.clone(), v, help));
    }
    for (key, help) in RUN_KEYS {
        rows.push((key.to_string(), "off".into(), "off".into(), help));
    }
    let (g, u) = match &a.model {
        Some(p) => (p.display().to_string(), String::new()),
        None => ("guided".into(), "unguided".into()),
    };
    println!("--tune KEY=VALUE overrides one setting (repeatable). Values of the built-in models:");
    println!("{:<28} {:>12} {:>12}  meaning", "key", g, u);
    for (k, gv, uv, help) in rows {
        let uv = if a.model.is_some() { String::new() } else { uv };
        println!("{k:<28} {gv:>12} {uv:>12}  {help}");
    }
    Ok(())
}
