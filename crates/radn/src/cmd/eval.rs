//! `radn eval`: quality and temporal stability of a result sequence against a reference.

use std::path::PathBuf;

use anyhow::{anyhow, Result};
use radn_core::frame::Requirements;
use radn_core::metrics;
use radn_core::Plane;
use rayon::prelude::*;

use crate::input::{sequence_files, ChannelArgs};

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
}

/// Metrics of one frame.
#[derive(serde::Serialize, Clone, Debug)]
pub struct FrameMetrics {
    /// Frame number.
    pub frame: i64,
    /// PSNR (dB) of tonemapped RGB.
    pub psnr: f64,
    /// SSIM of tonemapped RGB.
    pub ssim: f64,
    /// Relative MSE of linear RGB.
    pub relmse: f64,
    /// Mean absolute error of the frame-to-frame difference (vs the previous frame), tonemapped.
    pub tmae: Option<f64>,
    /// PSNR of the frame-to-frame difference (vs the previous frame), tonemapped.
    pub tpsnr: Option<f64>,
}

/// Computes and prints the metrics.
pub fn run(a: Args) -> Result<()> {
    if a.utilization {
        return crate::cmd::utilization::run(&a);
    }
    if a.html.is_some() {
        return crate::cmd::report::run(&a);
    }
    let (result_spec, reference_spec) = (
        a.result.clone().expect("clap requires it"),
        a.reference.clone().expect("clap requires it"),
    );
    let rows = evaluate(&a, &result_spec, &reference_spec)?.rows;
    let mean = mean_row(&rows);
    println!(
        "{:>8} {:>9} {:>8} {:>10} {:>9} {:>8}",
        "frame", "PSNR", "SSIM", "relMSE", "tMAE", "tPSNR"
    );
    for r in rows.iter().chain(std::iter::once(&mean)) {
        let label = if r.frame == i64::MIN {
            "mean".to_string()
        } else {
            r.frame.to_string()
        };
        let opt =
            |v: Option<f64>, prec: usize| v.map_or("-".to_string(), |v| format!("{v:.prec$}"));
        println!(
            "{:>8} {:>9.3} {:>8.4} {:>10.5} {:>9} {:>8}",
            label,
            r.psnr,
            r.ssim,
            r.relmse,
            opt(r.tmae, 5),
            opt(r.tpsnr, 2)
        );
    }
    if let Some(p) = &a.json {
        let mut m = serde_json::to_value(&mean)?;
        m["frame"] = serde_json::Value::Null;
        let v = serde_json::json!({"result": result_spec, "reference": reference_spec, "frames": rows, "mean": m});
        write_atomic(p, serde_json::to_string_pretty(&v)?.as_bytes())?;
    }
    if let Some(p) = &a.csv {
        let mut w = csv::Writer::from_writer(Vec::new());
        for r in &rows {
            w.serialize(r)?;
        }
        write_atomic(p, &w.into_inner()?)?;
    }
    Ok(())
}

/// A result sequence judged against the reference: per-frame metrics and the colour planes.
pub struct Evaluation {
    /// Metrics of every frame found in both sequences, in frame order.
    pub rows: Vec<FrameMetrics>,
    /// (frame, result colour, reference colour), in frame order.
    pub planes: Vec<(i64, Plane, Plane)>,
}

/// Reads `result_spec` and `reference_spec` (frames matched by number) and computes the metrics.
pub fn evaluate(a: &Args, result_spec: &str, reference_spec: &str) -> Result<Evaluation> {
    let result = sequence_files(result_spec, a.frames.as_deref())?;
    let reference = sequence_files(reference_spec, None)?;
    let pairs: Vec<(i64, PathBuf, PathBuf)> = result
        .iter()
        .filter_map(|(f, p)| {
            reference
                .iter()
                .find(|(g, _)| g == f)
                .map(|(_, q)| (*f, p.clone(), q.clone()))
        })
        .collect();
    if pairs.is_empty() {
        return Err(anyhow!(
            "no frame number is in both '{result_spec}' and '{reference_spec}'"
        ));
    }
    let rreader = a.channels.reader(&pairs[0].1, Requirements::COLOR_ONLY)?;
    let ref_args = ChannelArgs {
        preset: a.reference_preset.clone(),
        mapping: None,
        ..a.channels.clone()
    };
    let qreader = ref_args.reader(&pairs[0].2, Requirements::COLOR_ONLY)?;
    let pb = crate::progress::frames(pairs.len() as u64, "evaluating");
    let planes: Vec<(i64, Plane, Plane)> = pairs
        .par_iter()
        .map(|(f, p, q)| -> Result<(i64, Plane, Plane)> {
            let r = rreader.read(p)?.0;
            let g = qreader.read(q)?.0;
            r.ensure_size(g.width(), g.height())?;
            pb.inc(1);
            Ok((*f, r.color, g.color))
        })
        .collect::<Result<_>>()?;
    pb.finish_and_clear();
    let step = planes
        .windows(2)
        .map(|w| w[1].0 - w[0].0)
        .min()
        .unwrap_or(1);
    let rows: Vec<FrameMetrics> = planes
        .iter()
        .enumerate()
        .map(|(i, (f, r, g))| -> Result<FrameMetrics> {
            let (tmae, tpsnr) = match i.checked_sub(1).map(|j| &planes[j]) {
                Some((pf, pr, pg)) if f - pf == step => {
                    let (m, p) = metrics::temporal(pr, r, pg, g)?;
                    (Some(m), Some(p))
                }
                _ => (None, None),
            };
            Ok(FrameMetrics {
                frame: *f,
                psnr: metrics::psnr(r, g)?,
                ssim: metrics::ssim(r, g)?,
                relmse: metrics::relmse(r, g)?,
                tmae,
                tpsnr,
            })
        })
        .collect::<Result<_>>()?;
    Ok(Evaluation { rows, planes })
}

/// The mean over frames (temporal metrics over the frames that have them); `frame` is `i64::MIN`.
pub fn mean_row(rows: &[FrameMetrics]) -> FrameMetrics {
    let n = rows.len() as f64;
    let opt_mean = |f: &dyn Fn(&FrameMetrics) -> Option<f64>| {
        let v: Vec<f64> = rows.iter().filter_map(f).collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    FrameMetrics {
        frame: i64::MIN,
        psnr: rows.iter().map(|r| r.psnr).sum::<f64>() / n,
        ssim: rows.iter().map(|r| r.ssim).sum::<f64>() / n,
        relmse: rows.iter().map(|r| r.relmse).sum::<f64>() / n,
        tmae: opt_mean(&|r| r.tmae),
        tpsnr: opt_mean(&|r| r.tpsnr),
    }
}

/// Writes a small report file through a temporary file renamed into place.
pub fn write_atomic(path: &std::path::Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| anyhow!("cannot create '{}': {e}", dir.display()))?;
    let mut tmp = tempfile_in(dir)?;
    tmp.write_all(bytes)
        .map_err(|e| anyhow!("cannot write '{}': {e}", path.display()))?;
    tmp.persist(path)
        .map_err(|e| anyhow!("cannot write '{}': {}", path.display(), e.error))?;
    Ok(())
}

/// Encodes 8-bit pixels as PNG and writes them atomically.
pub fn write_png(
    path: &std::path::Path,
    bytes: &[u8],
    w: usize,
    h: usize,
    color: png::ColorType,
) -> Result<()> {
    let mut buf = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut buf, w as u32, h as u32);
        enc.set_color(color);
        enc.set_depth(png::BitDepth::Eight);
        let mut wr = enc
            .write_header()
            .map_err(|e| anyhow!("cannot encode '{}': {e}", path.display()))?;
        wr.write_image_data(bytes)
            .map_err(|e| anyhow!("cannot encode '{}': {e}", path.display()))?;
    }
    write_atomic(path, &buf)
}

fn tempfile_in(dir: &std::path::Path) -> Result<tempfile::NamedTempFile> {
    radn_core::output::output_tempfile(dir, ".radn-", ".tmp")
        .map_err(|e| anyhow!("cannot write to '{}': {e}", dir.display()))
}
