//! `radn warp`: the aligned window of one frame, written out for inspection.

use std::path::PathBuf;

use anyhow::{anyhow, Result};
use radn_core::align::AlignParams;
use radn_core::io::exr_file::{ExrFile, SampleKind};
use radn_core::io::frame::Requirements;
use radn_core::io::output::{ensure_not_input, ensure_writable_dir};
use radn_core::io::sequence::sequence_files;
use radn_core::run::window::WindowReader;

use crate::input::ChannelArgs;

/// Arguments of `radn warp`.
#[derive(clap::Args)]
pub struct Args {
    /// Input sequence: a pattern (beauty.####.exr, beauty.%04d.exr, beauty.$F4.exr) or a folder.
    #[arg(short, long)]
    pub input: String,
    /// The centre frame.
    #[arg(long)]
    pub frame: i64,
    /// Limit the sequence to this range (first-last[xstep]); the window is clamped at its ends.
    #[arg(long)]
    pub frames: Option<String>,
    /// Output EXR: one layer per window slot (w-2 … w+2) with colour, albedo, normal, depth,
    /// confidence and flow.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Window radius (2 gives the paper's 5 frames).
    #[arg(long, default_value_t = 2)]
    pub radius: usize,
    /// Do not blend low-confidence pixels towards the centre frame.
    #[arg(long)]
    pub no_mix: bool,
    /// How the side frames are sampled between pixels (`radn denoise` aligns as its model
    /// was trained: catmull-rom for the compiled-in guided model, bilinear for the default).
    #[arg(long, value_enum, default_value_t = crate::input::ResamplingArg::Bilinear)]
    pub resampling: crate::input::ResamplingArg,
    #[command(flatten)]
    pub channels: ChannelArgs,
}

/// Aligns the window and writes it.
pub fn run(a: Args) -> Result<()> {
    let files = sequence_files(&a.input, a.frames.as_deref())?;
    let inputs: Vec<PathBuf> = files.iter().map(|(_, p)| p.clone()).collect();
    ensure_not_input(&a.output, &inputs)?;
    ensure_writable_dir(&a.output)?;
    let pos = files
        .iter()
        .position(|(f, _)| *f == a.frame)
        .ok_or_else(|| anyhow!("frame {} is not in the sequence '{}'", a.frame, a.input))?;
    let reader = a.channels.reader(&files[pos].1, Requirements::DENOISE)?;
    let mut windows = WindowReader::new(&reader, &inputs, a.radius);
    if windows.indices(pos).iter().any(Option::is_none) {
        tracing::info!("window clamped at the sequence end: missing frames get zero confidence");
    }
    let params = AlignParams {
        mix_centre: !a.no_mix,
        resampling: a.resampling.into(),
        ..AlignParams::default()
    };
    let win = windows.aligned(pos, &params)?;
    let (w, h) = (win.centre().color.width(), win.centre().color.height());
    let mut channels: Vec<(String, Vec<f32>)> = Vec::new();
    for f in &win.frames {
        let l = format!("w{:+}", f.offset);
        let mut push = |name: &str, p: &radn_core::Plane, comps: &[&str]| {
            for (c, comp) in comps.iter().enumerate() {
                let full = if name.is_empty() {
                    format!("{l}.{comp}")
                } else {
                    format!("{l}.{name}.{comp}")
                };
                channels.push((full, p.channel(c).to_vec()));
            }
        };
        push("", &f.color, &["R", "G", "B"]);
        if let Some(p) = &f.albedo {
            push("albedo", p, &["R", "G", "B"]);
        }
        if let Some(p) = &f.normal {
            push("normal", p, &["X", "Y", "Z"]);
        }
        if let Some(p) = &f.depth {
            push("depth", p, &["Z"]);
        }
        push("confidence", &f.confidence, &["Y"]);
        push("flow", &f.flow, &["X", "Y"]);
        let mean_c = f.confidence.data().iter().map(|&c| c as f64).sum::<f64>() / (w * h) as f64;
        println!("offset {:+}: mean confidence {:.3}", f.offset, mean_c);
    }
    ExrFile::from_channels(&a.output, w, h, channels, SampleKind::F32).write_atomic(&a.output)?;
    println!("wrote {}", a.output.display());
    Ok(())
}
