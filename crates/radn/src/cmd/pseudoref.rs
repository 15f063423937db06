//! `radn pseudoref`: pseudo-references for a whole rendered dataset (paper section 6), made by
//! the classic denoiser from each scene's least noisy level.

use std::path::PathBuf;

use anyhow::Result;
use radn_core::io::frame::Requirements;
use radn_core::io::sequence::{scene_folders, SequencePattern};
use radn_core::run::job::SequenceJob;

use crate::input::ChannelArgs;

/// Arguments of `radn pseudoref`.
#[derive(clap::Args)]
pub struct Args {
    /// A dataset folder (scenes in sub-folders) or a single scene folder, in the datagen layout
    /// `<scene>/<level>/frame_####.exr`.
    #[arg(long)]
    pub data: PathBuf,
    /// The level to denoise (the least noisy one).
    #[arg(long, default_value = "high")]
    pub level: String,
    /// The level folder the pseudo-references are written to.
    #[arg(long, default_value = "pseudo")]
    pub out_level: String,
    /// Recompute frames that already exist (default: skip them, so a killed run resumes).
    #[arg(long)]
    pub overwrite: bool,
    /// Override a classic denoiser setting, classic.KEY=VALUE (repeatable; `radn denoise
    /// --tune help` lists the keys).
    #[arg(long, value_name = "classic.KEY=VALUE")]
    pub tune: Vec<String>,
    #[command(flatten)]
    pub channels: ChannelArgs,
}

/// Makes the pseudo-references, scene by scene.
pub fn run(a: Args) -> Result<()> {
    let scenes = scene_folders(&a.data, &a.level)?;
    let method = crate::input::classic_tuned(&a.tune)?;
    let mut jobs = Vec::new();
    for s in &scenes {
        let input = SequencePattern::from_folder(&s.join(&a.level))?;
        let frames = input.frames(None)?;
        let out = SequencePattern::parse(
            &s.join(&a.out_level)
                .join("frame_####.exr")
                .to_string_lossy(),
        )?;
        let inputs: Vec<(i64, PathBuf)> = frames.iter().map(|&f| (f, input.path(f))).collect();
        let outputs = frames.iter().map(|&f| Some(out.path(f))).collect();
        let reader = a.channels.reader(&inputs[0].1, Requirements::DENOISE)?;
        // pseudo-references are training targets: keep full precision
        let output_kind = Some(radn_core::io::exr_file::SampleKind::F32);
        jobs.push(SequenceJob {
            inputs,
            outputs,
            reader,
            overwrite: a.overwrite,
            output_kind,
            guides: radn_core::guide::JobGuides::FromReader,
            replace_denoised: true,
            bands: radn_core::run::job::Bands::Auto,
            rendered: None,
            motion: radn_core::run::motion::MotionChoice::Auto,
        });
    }
    let total: usize = jobs.iter().map(|j| j.output_count()).sum();
    let pb = crate::progress::frames(total as u64, "pseudo-refs");
    let (mut written, mut skipped, mut base) = (0, 0, 0);
    for (s, job) in scenes.iter().zip(&jobs) {
        pb.set_message(
            s.file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
        );
        let r = job.run(&method, |done, _| {
            pb.set_position(base as u64 + done as u64)
        })?;
        written += r.written;
        skipped += r.skipped;
        base += job.inputs.len();
    }
    pb.finish_and_clear();
    println!(
        "{} scenes: {written} pseudo-references written, {skipped} already there",
        scenes.len()
    );
    Ok(())
}
