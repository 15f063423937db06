//! A denoising pass and the temporal pass over its results in one sweep over whole frames: each
//! frame's result is kept in memory (with the frame as rendered beside it) for as long as the
//! temporal pass's windows need it, instead of being written to a scratch file and decoded
//! again by a second pass. The outputs equal those of the two passes run one after the other,
//! bit for bit (`a_fused_temporal_pass_writes_what_two_passes_write`); a resumed run makes
//! only the results its missing outputs' windows need.

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::PathBuf;
use std::time::Instant;

use crate::error::Result;
use crate::guide::JobGuides;
use crate::io::denoised_output::write_result;
use crate::io::exr_file::ExrFile;
use crate::io::frame::Frame;
use crate::run::denoiser::{Denoised, WindowDenoiser};
use crate::run::job::{JobReport, SequenceJob};
use crate::run::sweep::WindowSweep;

/// Runs `method` and then `temporal` (a pass over results, [`WindowDenoiser::needs_rendered`])
/// over `job`'s frames: `job` writes the final outputs, and `method` denoises the positions in
/// `span` (the outputs and as many frames around them as `temporal`'s windows reach).
/// `progress` gets (outputs done, outputs).
pub(crate) fn run_fused(
    job: &SequenceJob,
    method: &dyn WindowDenoiser,
    temporal: &dyn WindowDenoiser,
    span: Range<usize>,
    mut progress: impl FnMut(f64, usize),
) -> Result<JobReport> {
    let files: Vec<PathBuf> = job.inputs.iter().map(|(_, p)| p.clone()).collect();
    let mut sweep = WindowSweep::new(
        method,
        &job.reader,
        &files,
        job.guides.clone(),
        None,
        job.motion,
    );
    let oidn_guides = matches!(job.guides, JobGuides::Oidn { .. });
    let rt = temporal.radius();
    // results as the temporal pass reads them, and the decoded inputs of outputs to write
    let mut results: BTreeMap<usize, Frame> = BTreeMap::new();
    let mut inputs: BTreeMap<usize, ExrFile> = BTreeMap::new();
    let mut next = span.start;
    let mut report = JobReport::default();
    let total = job.output_count();
    let outputs: Vec<(usize, PathBuf, bool)> = job
        .output_frames()
        .map(|(pos, o, finished)| (pos, o.to_path_buf(), finished))
        .collect();
    for (done, (pos, output, finished)) in outputs.into_iter().enumerate() {
        super::cancel::check()?;
        let claim = (!finished).then(|| job.claim(&output)).transpose()?;
        if finished || job.done_by_another_run(&output) {
            report.skipped += 1;
            progress((done + 1) as f64, total);
            continue;
        }
        // the temporal pass's window: results of the span only, as a second pass reads them
        let window: Vec<Option<usize>> = (0..2 * rt + 1)
            .map(|k| (pos + k).checked_sub(rt).filter(|i| span.contains(i)))
            .collect();
        // the results this window reads, in increasing order (a skipped output's are made
        // only where a later window reads them)
        next = next.max(pos.saturating_sub(rt)).max(span.start);
        let last = window.iter().flatten().max().copied().unwrap_or(pos);
        while next <= last {
            let (out, _) = sweep.denoise(next)?;
            let frame = as_result(sweep.frame(next), out, oidn_guides);
            results.insert(next, frame);
            if job.outputs[next].is_some() {
                if let Some(file) = sweep.take_file(next) {
                    inputs.insert(next, file);
                }
            }
            next += 1;
        }
        let frames: Vec<Option<&Frame>> = window.iter().map(|i| i.map(|i| &results[&i])).collect();
        let out = temporal.denoise(&frames)?;
        let writing = Instant::now();
        let file = inputs
            .remove(&pos)
            .expect("an output's input is kept until written");
        let names = job.output_names(&results[&pos]);
        write_result(file, &names, &out, &output, job.output_kind)?;
        super::timing::add("writing", writing.elapsed());
        drop(claim);
        report.written += 1;
        results.retain(|&i, _| i + rt > pos);
        inputs.retain(|&i, _| i > pos);
        progress((done + 1) as f64, total);
    }
    report.repaired = sweep.repaired();
    report.cuts = job.cut_frames(sweep.cuts());
    Ok(report)
}

/// Frame `input` with its beauty, alpha and AOVs replaced by `out`, as the temporal pass reads
/// a result written by an earlier pass: the frame as rendered beside it, and no OIDN guide
/// (a pass over results gets none).
fn as_result(input: &Frame, out: Denoised, oidn_guides: bool) -> Frame {
    let mut f = input.clone();
    f.rendered = Some(std::mem::replace(&mut f.color, out.color));
    if let (Some(a), true) = (out.alpha, f.alpha.is_some()) {
        f.alpha = Some(a);
    }
    for (aov, plane) in f.aovs.iter_mut().zip(out.aovs) {
        aov.plane = plane;
    }
    if oidn_guides {
        f.guide = None;
    }
    f.features = None;
    f
}
