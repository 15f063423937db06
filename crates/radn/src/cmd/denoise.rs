//! `radn denoise`: denoise an EXR sequence.

use std::path::PathBuf;

use anyhow::{anyhow, Result};
use radn_core::classic::pipeline::{ClassicDenoiser, ClassicParams};
use radn_core::frame::Requirements;
use radn_core::job::SequenceJob;
use radn_core::sequence::SequencePattern;

use crate::input::{sequence_files, ChannelArgs};

/// Denoising methods.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum Method {
    /// The non-neural pipeline: flow-refined alignment, robust temporal average, joint NLM, guided filter.
    Classic,
}

/// Arguments of `radn denoise`.
#[derive(clap::Args)]
pub struct Args {
    /// Input sequence: a pattern (beauty.####.exr, beauty.%04d.exr, beauty.$F4.exr) or a folder.
    #[arg(short, long)]
    pub input: String,
    /// Output pattern (same frame-number syntax); every layer of the input is kept.
    #[arg(short, long)]
    pub output: String,
    /// Frames to denoise (first-last[xstep]); default: every frame found.
    #[arg(long)]
    pub frames: Option<String>,
    /// Denoising method.
    #[arg(long, value_enum, default_value = "classic")]
    pub method: Method,
    /// Extra layers to denoise with the beauty's weights (comma-separated layer names, e.g. DiffCol,GlossCol).
    #[arg(long, value_delimiter = ',')]
    pub aovs: Vec<String>,
    /// Recompute frames whose output already exists (default: skip them, so a killed run resumes).
    #[arg(long)]
    pub overwrite: bool,
    /// Frames on each side of the centre (2 = the paper's 5-frame window).
    #[arg(long, default_value_t = 2)]
    pub radius: usize,
    /// Classic: NLM search radius in pixels.
    #[arg(long, default_value_t = 9)]
    pub search_radius: usize,
    /// Classic: NLM patch radius in pixels.
    #[arg(long, default_value_t = 3)]
    pub patch_radius: usize,
    /// Classic: NLM strength (larger removes more noise and more detail).
    #[arg(long, default_value_t = 0.45)]
    pub strength: f32,
    /// Classic: do not refine the renderer's motion with optical flow.
    #[arg(long)]
    pub no_refine: bool,
    /// Classic: skip the guided filter.
    #[arg(long)]
    pub no_guided: bool,
    /// Classic: filter the beauty itself instead of beauty / albedo.
    #[arg(long)]
    pub no_demodulate: bool,
    #[command(flatten)]
    pub channels: ChannelArgs,
}

/// Builds the classic denoiser from the command-line options.
pub fn classic_from(a: &Args) -> ClassicDenoiser {
    let mut p = ClassicParams::default();
    p.nlm.search_radius = a.search_radius;
    p.nlm.patch_radius = a.patch_radius;
    p.nlm.strength = a.strength;
    if a.no_refine {
        p.refine = None;
    }
    if a.no_guided {
        p.guided = None;
    }
    p.demodulate = !a.no_demodulate;
    ClassicDenoiser {
        params: p,
        radius: a.radius,
    }
}

/// Denoises the sequence.
pub fn run(a: Args) -> Result<()> {
    let inputs = sequence_files(&a.input, a.frames.as_deref())?;
    let out_pattern = SequencePattern::parse(&a.output)?;
    if out_pattern.as_str() == a.input {
        return Err(anyhow!(
            "refusing to write: the output pattern '{}' is the input pattern",
            a.output
        ));
    }
    let outputs: Vec<PathBuf> = inputs.iter().map(|(f, _)| out_pattern.path(*f)).collect();
    let mut reader = a.channels.reader(&inputs[0].1, Requirements::DENOISE)?;
    reader.aovs = a.aovs.clone();
    let job = SequenceJob {
        inputs,
        outputs,
        reader,
        overwrite: a.overwrite,
    };
    let method = match a.method {
        Method::Classic => classic_from(&a),
    };
    let pb = crate::progress::frames(job.inputs.len() as u64, "denoising");
    let t = std::time::Instant::now();
    let report = job.run(&method, |done, _| pb.set_position(done as u64))?;
    pb.finish_and_clear();
    println!(
        "denoised {} frames ({} already done, skipped) in {:.1} s -> {}",
        report.written,
        report.skipped,
        t.elapsed().as_secs_f64(),
        a.output
    );
    if report.repaired > 0 {
        println!("repaired {} NaN/Inf input samples", report.repaired);
    }
    Ok(())
}
