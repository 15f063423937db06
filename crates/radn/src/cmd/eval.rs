//! `radn eval`: quality and temporal stability of a result sequence against a reference, the
//! HTML report (`--html`) and temporal utilisation (`--utilization`).

use std::path::PathBuf;

use anyhow::{anyhow, Result};
use radn_core::eval::evaluation::{self, Evaluation};
use radn_core::eval::reference_noise::{self, NoiseFreeMetrics};
use radn_core::eval::report::{write_report, Shown};
use radn_core::io::frame::Requirements;
use radn_core::io::output::write_bytes_atomically;
use radn_core::io::sequence::sequence_files;
use radn_core::run::denoiser::WindowDenoiser;
use radn_core::run::window::WindowReader;
use radn_core::Plane;
use radn_nn::infer::utilization::{write_heatmap, Utilization};
use rayon::prelude::*;

use crate::input::{ChannelArgs, GuideArgs};
use crate::model::GuideRequest;

/// Arguments of `radn eval`.
#[derive(clap::Args)]
pub struct Args {
    /// The sequence to judge: a folder of numbered EXRs or a pattern.
    #[arg(long, required_unless_present = "utilization")]
    pub result: Option<String>,
    /// The reference sequence (folder or pattern); frames are matched by number.
    #[arg(long, required_unless_present = "utilization")]
    pub reference: Option<String>,
    /// Instead: temporal utilisation of a network (paper Table 1, Fig. 6) on --input: the mean
    /// and max kernel weight of each window frame, and heat maps of the centre frame's share.
    #[arg(long, requires = "input")]
    pub utilization: bool,
    /// For --utilization and --html: the model file (default: the built-in model).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// For --utilization (and --html heat maps): the noisy input sequence.
    #[arg(short, long)]
    pub input: Option<String>,
    /// For --utilization: write heat maps (PNG) of the centre frame's weight here.
    #[arg(long)]
    pub heatmaps: Option<PathBuf>,
    /// Instead: write an HTML report here (index.html with side-by-side crops of --result and
    /// every --compare sequence against --reference, the metric table and per-frame plots, and
    /// kernel-weight heat maps when --input is given).
    #[arg(long, requires_all = ["result", "reference"])]
    pub html: Option<PathBuf>,
    /// For --html: the name of --result in the report.
    #[arg(long, default_value = "radn")]
    pub name: String,
    /// For --html: more sequences to show beside --result, as NAME=PATTERN (e.g.
    /// noisy=in/beauty.####.exr, classic=classic/frame_####.exr); repeat the flag.
    #[arg(long)]
    pub compare: Vec<String>,
    /// Only these frames (first-last[xstep]).
    #[arg(long)]
    pub frames: Option<String>,
    /// For --utilization and --html heat maps of a guided model: where its guides come from.
    #[command(flatten)]
    pub guide: GuideArgs,
    /// For --utilization and --html heat maps: where the network runs, cpu or cuda[:N].
    #[arg(long, default_value = "cpu", value_name = "cpu|cuda[:N]")]
    pub device: radn_nn::device::ComputeDevice,
    /// Write per-frame and mean metrics as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write per-frame metrics as CSV here.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Channel layout of the result files.
    #[command(flatten)]
    pub channels: ChannelArgs,
    /// Preset of the reference files when it differs from the result's (default: detect).
    #[arg(long, default_value = "auto")]
    pub reference_preset: String,
    /// A second reference of the same frames, rendered with other sampling seeds (folder or
    /// pattern, read like --reference). Adds PSNR, tPSNR and temporal RMSE against the
    /// noise-free image, estimated from the two references, and how far the two references
    /// differ (their PSNR and tMAE against each other: the floor one noisy reference sets).
    #[arg(long, requires_all = ["result", "reference"], conflicts_with_all = ["utilization", "html"])]
    pub second_reference: Option<String>,
}

/// Computes and prints the metrics.
pub fn run(a: Args) -> Result<()> {
    if a.utilization {
        return utilization(&a);
    }
    if a.html.is_some() {
        return report(&a);
    }
    let (result_spec, reference_spec) = (
        a.result.clone().expect("clap requires it"),
        a.reference.clone().expect("clap requires it"),
    );
    let ev = evaluate(&a, &result_spec, &reference_spec)?;
    let rows = &ev.rows;
    print!("{}", evaluation::table(rows));
    let noise_free = match &a.second_reference {
        Some(spec) => {
            let rows = noise_free(&a, &ev, spec)?;
            println!(
                "against the noise-free image, estimated from --reference and --second-reference:"
            );
            print!("{}", reference_noise::table(&rows));
            Some(rows)
        }
        None => None,
    };
    if let Some(p) = &a.json {
        let mut json = evaluation::to_json(rows, &result_spec, &reference_spec);
        if let (Some(rows), Some(spec)) = (&noise_free, &a.second_reference) {
            let mut v: serde_json::Value = serde_json::from_str(&json)?;
            v["second_reference"] = spec.as_str().into();
            v["noise_free"] = reference_noise::to_json_value(rows);
            json = serde_json::to_string_pretty(&v)?;
        }
        write_bytes_atomically(p, json.as_bytes())?;
    }
    if let Some(p) = &a.csv {
        write_bytes_atomically(p, evaluation::to_csv(rows).as_bytes())?;
    }
    Ok(())
}

/// The reader of reference files (like `first`): the result's channel options with
/// `--reference-preset`.
fn reference_reader(
    a: &Args,
    first: &std::path::Path,
) -> Result<radn_core::io::frame::FrameReader> {
    let ref_args = ChannelArgs {
        preset: a.reference_preset.clone(),
        mapping: None,
        ..a.channels.clone()
    };
    ref_args.reader(first, Requirements::COLOR_ONLY)
}

/// `--second-reference`: reads the second reference's frames of the evaluation (every one
/// must exist) and estimates the metrics against the noise-free image.
fn noise_free(a: &Args, ev: &Evaluation, spec: &str) -> Result<Vec<NoiseFreeMetrics>> {
    let files = sequence_files(spec, None)?;
    let paths = ev
        .planes
        .iter()
        .map(|(f, _, _)| {
            files
                .iter()
                .find(|(g, _)| g == f)
                .map(|(_, p)| p.clone())
                .ok_or_else(|| anyhow!("--second-reference '{spec}' has no frame {f}"))
        })
        .collect::<Result<Vec<PathBuf>>>()?;
    let reader = reference_reader(a, &paths[0])?;
    let second = paths
        .par_iter()
        .map(|p| -> Result<Plane> {
            let (frame, _) = reader.read(p)?;
            Ok(frame.color)
        })
        .collect::<Result<Vec<Plane>>>()?;
    let frames: Vec<(i64, &Plane, &Plane, &Plane)> = ev
        .planes
        .iter()
        .zip(&second)
        .map(|((f, r, g), b)| (*f, r, g, b))
        .collect();
    Ok(reference_noise::evaluate(&frames)?)
}

/// Reads `result_spec` and `reference_spec` (frames matched by number) and computes the
/// metrics, with a progress bar.
pub fn evaluate(a: &Args, result_spec: &str, reference_spec: &str) -> Result<Evaluation> {
    let result = sequence_files(result_spec, a.frames.as_deref())?;
    let reference = sequence_files(reference_spec, None)?;
    let pairs = evaluation::match_frames(&result, &reference, result_spec, reference_spec)?;
    let rreader = a.channels.reader(&pairs[0].1, Requirements::COLOR_ONLY)?;
    let qreader = reference_reader(a, &pairs[0].2)?;
    let pb = crate::progress::frames(pairs.len() as u64, "evaluating");
    let ev = evaluation::evaluate(&pairs, &rreader, &qreader, || pb.inc(1))?;
    pb.finish_and_clear();
    Ok(ev)
}

/// `--html DIR`: evaluates --result and every --compare sequence, and writes the report with
/// the kernel-weight heat maps of the report's frame when --input is given.
fn report(a: &Args) -> Result<()> {
    let dir = a.html.clone().expect("checked by the caller");
    let reference_spec = a.reference.clone().expect("clap requires it");
    let mut specs = vec![(a.name.clone(), a.result.clone().expect("clap requires it"))];
    for c in &a.compare {
        let (n, p) = c
            .split_once('=')
            .ok_or_else(|| anyhow!("--compare '{c}' must be NAME=PATTERN"))?;
        specs.push((n.to_string(), p.to_string()));
    }
    // frames every sequence has; crops come from the middle one of the first
    let mut shown = Vec::new();
    let mut reference: Option<Plane> = None;
    let mut display: Option<i64> = None;
    for (name, spec) in &specs {
        let ev = evaluate(a, spec, &reference_spec)?;
        let shown_frame = *display.get_or_insert(ev.rows[ev.rows.len() / 2].frame);
        let (_, color, refc) = ev
            .planes
            .into_iter()
            .find(|(f, _, _)| *f == shown_frame)
            .ok_or_else(|| anyhow!("'{spec}' has no frame {shown_frame} (the report's frame)"))?;
        reference.get_or_insert(refc);
        shown.push(Shown {
            name: name.clone(),
            spec: spec.clone(),
            rows: ev.rows,
            color,
        });
    }
    let (reference, display) = (
        reference.expect("at least one sequence"),
        display.expect("at least one sequence"),
    );
    let heat = match &a.input {
        Some(input) => Some(weight_at(a, input, display)?),
        None => None,
    };
    let index = write_report(
        &dir,
        &shown,
        &reference_spec,
        &reference,
        display,
        heat.as_deref(),
    )?;
    println!("report: {}", index.display());
    Ok(())
}

/// The network's kernel weight of each window frame at frame `display` of `input`.
fn weight_at(a: &Args, input: &str, display: i64) -> Result<Vec<Plane>> {
    let files = sequence_files(input, None)?;
    let pos = files
        .iter()
        .position(|(f, _)| *f == display)
        .ok_or_else(|| anyhow!("--input '{input}' has no frame {display} (the report's frame)"))?;
    let paths: Vec<PathBuf> = files.into_iter().map(|(_, p)| p).collect();
    let (net, reader, oidn) = network_and_reader(a, &paths[pos])?;
    let mut windows = WindowReader::new(&reader, &paths, net.radius())
        .with_guides(GuideArgs::window_guides(oidn, &paths));
    Ok(net.window_utilization(&windows.read(pos)?))
}

/// The network `--model`/`--guide` name, and a reader of files like `probe` that reads the
/// guide layer it needs (and OIDN, opened, where the guide is OIDN's).
fn network_and_reader(
    a: &Args,
    probe: &std::path::Path,
) -> Result<(
    radn_nn::infer::NetworkDenoiser,
    radn_core::io::frame::FrameReader,
    Option<std::sync::Arc<radn_core::guide::OidnGuides>>,
)> {
    let chosen = crate::model::choose_path(
        a.model.as_deref(),
        &GuideRequest::Given(a.guide.guide.clone()),
        a.guide.oidn_threads,
        a.device,
    )?;
    let mut reader = a.channels.reader(probe, Requirements::DENOISE)?;
    reader.guide = chosen.guide.layer();
    Ok((chosen.network, reader, chosen.oidn))
}

/// `--utilization`: how much each frame of the window contributes to the network's kernels
/// (paper Table 1 and Fig. 6): prints the per-frame mean and max kernel weight over all pixels
/// of all frames evaluated, and writes heat maps of the centre frame's share.
fn utilization(a: &Args) -> Result<()> {
    let input = a.input.as_ref().expect("clap requires --input");
    let files = sequence_files(input, a.frames.as_deref())?;
    let (net, reader, oidn) = network_and_reader(a, &files[0].1)?;
    let model = crate::model::label_for(a.model.as_deref(), a.guide.guide.is_some());
    let paths: Vec<PathBuf> = files.iter().map(|(_, p)| p.clone()).collect();
    let mut windows = WindowReader::new(&reader, &paths, net.radius())
        .with_guides(GuideArgs::window_guides(oidn, &paths));
    let mut stats = Utilization::new(2 * net.radius() + 1);
    let pb = crate::progress::frames(files.len() as u64, "utilisation");
    for (pos, (number, _)) in files.iter().enumerate() {
        let mass = net.window_utilization(&windows.read(pos)?);
        if let Some(dir) = &a.heatmaps {
            write_heatmap(
                &mass[net.radius()],
                &dir.join(format!("centre_share_{number:04}.png")),
            )?;
        }
        stats.add(*number, &mass);
        pb.inc(1);
    }
    pb.finish_and_clear();
    print!("{}", stats.table());
    if let Some(p) = &a.json {
        let json = stats.to_json(&model.to_string_lossy(), input);
        write_bytes_atomically(p, json.as_bytes())?;
    }
    Ok(())
}
