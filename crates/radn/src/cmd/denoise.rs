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
    pub fn kind(self) -> Option<radn_core::exr_file::SampleKind> {
        match self {
            Precision::Same => None,
            Precision::Half => Some(radn_core::exr_file::SampleKind::F16),
            Precision::Float => Some(radn_core::exr_file::SampleKind::F32),
        }
    }
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
    /// Storage of the denoised channels: the input's own type, half or float.
    #[arg(long, value_enum, default_value = "same")]
    pub output_precision: Precision,
    #[command(flatten)]
    pub classic: ClassicArgs,
    #[command(flatten)]
    pub channels: ChannelArgs,
}

/// Options of the classic (non-neural) denoiser.
#[derive(clap::Args, Clone, Debug)]
pub struct ClassicArgs {
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
}

impl ClassicArgs {
    /// The classic denoiser these options describe.
    pub fn denoiser(&self) -> ClassicDenoiser {
        let mut p = ClassicParams::default();
        p.nlm.search_radius = self.search_radius;
        p.nlm.patch_radius = self.patch_radius;
        p.nlm.strength = self.strength;
        if self.no_refine {
            p.refine = None;
        }
        if self.no_guided {
            p.guided = None;
        }
        p.demodulate = !self.no_demodulate;
        ClassicDenoiser {
            params: p,
            radius: self.radius,
        }
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
        output_kind: a.output_precision.kind(),
    };
    let method = match a.method {
        Method::Classic => a.classic.denoiser(),
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
