//! A denoising run as a user asks for it: chosen frames of a sequence, written to an output
//! pattern, in one pass or several (paper section 3: running the network again on its own
//! output widens the temporal reach), optionally followed by a temporal pass over the results
//! ([`crate::post::stabilize`]). A frame range is denoised exactly as the same frames of a run over
//! the whole sequence: every pass reads the neighbours beyond the range that its windows, and
//! the later passes' windows, reach.

use crate::run::motion::MotionChoice;
use std::path::PathBuf;

use crate::error::{Error, Result};
use crate::guide::{JobGuides, OidnGuides};
use crate::io::exr_file::{ExrFile, SampleKind};
use crate::io::frame::FrameReader;
use crate::io::sequence::SequencePattern;
use crate::post::stabilize::TemporalStabilizer;
use crate::run::denoiser::WindowDenoiser;
use crate::run::job::{Bands, JobReport, SequenceJob};

/// Chosen frames of a sequence to denoise into an output pattern, in `passes` passes.
pub struct DenoiseRun {
    /// The input sequence.
    pub input: SequencePattern,
    /// Where the results go (the same frame numbers).
    pub output: SequencePattern,
    /// The frames to write, in order (each must exist in `input`).
    pub frames: Vec<i64>,
    /// How frames are read.
    pub reader: FrameReader,
    /// Recompute frames whose output already exists.
    pub overwrite: bool,
    /// Storage type of the denoised channels (None: the input channel's own type; after
    /// several passes, the type of the first wanted frame's beauty as rendered, for every
    /// channel written).
    pub output_kind: Option<SampleKind>,
    /// Passes in all (at least 1): pass p + 1 denoises pass p's results.
    pub passes: usize,
    /// Intel Open Image Denoise guides, computed from the original inputs in every pass
    /// (a guide layer is read by `reader`; scratch files between passes keep it as it was).
    pub oidn: Option<std::sync::Arc<OidnGuides>>,
    /// Whether a method that can goes band by band.
    pub bands: Bands,
    /// A temporal pass over the last denoising pass's results, run after it as one more pass
    /// ([`crate::post::stabilize`]); `None`: the denoising passes' results are the outputs.
    pub stabilize: Option<TemporalStabilizer>,
    /// Runs one denoising pass over whole frames and the temporal pass in one sweep, the
    /// results kept in memory rather than written to scratch files and decoded again
    /// ([`crate::run::fused`]; the same outputs, faster). Off: always pass after pass.
    pub fuse_temporal: bool,
    /// Which motion windows are aligned with.
    pub motion: MotionChoice,
}

/// Where a run is: pass `pass` of `passes` has written `done` (fractional while a frame is in
/// progress) of its `frames` frames.
#[derive(Clone, Copy, Debug)]
pub struct PassProgress {
    /// The pass, from 1.
    pub pass: usize,
    /// Passes in all.
    pub passes: usize,
    /// Frames of this pass done.
    pub done: f64,
    /// Frames this pass writes.
    pub frames: usize,
}

impl DenoiseRun {
    /// Runs every pass with `method`, then the temporal pass where there is one; `progress` is
    /// told how each pass advances. Earlier passes write full-precision results into a scratch
    /// folder beside the output (removed at the end); the last pass writes the outputs. A run
    /// whose outputs all exist (and that does not overwrite) does no work, however many
    /// passes. The report is the last pass's (its repairs are those in the original inputs,
    /// counted by the first pass).
    pub fn run(
        &self,
        method: &dyn WindowDenoiser,
        mut progress: impl FnMut(PassProgress),
    ) -> Result<JobReport> {
        if self.output.as_str() == self.input.as_str() {
            return Err(Error::OutputIsInput {
                pattern: self.output.as_str().to_string(),
            });
        }
        // the method of each pass: the denoising passes, then the temporal pass
        let mut methods: Vec<&dyn WindowDenoiser> = vec![method; self.passes.max(1)];
        if let Some(st) = &self.stabilize {
            methods.push(st);
        }
        let passes = methods.len();
        let radii: Vec<usize> = methods.iter().map(|m| m.radius()).collect();
        // how far beyond a pass's frames the later passes' windows reach
        let later_reach = |pass: usize| radii[pass..].iter().sum::<usize>();
        let numbers = &self.frames;
        // the frames every window of every pass reads
        let context = later_reach(0) + usize::from(method.prepare_needs_neighbours());
        let all = self.input.with_context(numbers, context)?;
        let inputs: Vec<(i64, PathBuf)> = all.iter().map(|&f| (f, self.input.path(f))).collect();
        let outputs: Vec<Option<PathBuf>> = all
            .iter()
            .map(|f| numbers.contains(f).then(|| self.output.path(*f)))
            .collect();
        let originals: std::collections::BTreeMap<i64, PathBuf> = inputs.iter().cloned().collect();
        // the outputs' storage: after earlier passes, whose scratch results are 32-bit, the
        // type of the beauty as rendered (the first wanted frame's) stands for "the input's own"
        let last_kind = match self.output_kind {
            None if passes > 1 => {
                // its first row tells (a whole 8K frame would cost gigabytes)
                let path = self.input.path(numbers[0]);
                let file = ExrFile::read_rows(&path, 0..1)?;
                let frame = self.reader.frame_from(&file)?;
                file.channel_kind(&frame.color_channels[0])
            }
            kind => kind,
        };
        // a pass over results that measures the frames as rendered gets no OIDN guides (it
        // reads none; computing them again would cost a second OIDN run per frame)
        let job = |inputs: Vec<(i64, PathBuf)>,
                   outputs: Vec<Option<PathBuf>>,
                   last: bool,
                   over_results: bool| {
            let guides = match &self.oidn {
                Some(g) if !over_results => JobGuides::Oidn {
                    guides: g.clone(),
                    originals: inputs.iter().map(|(f, _)| originals[f].clone()).collect(),
                },
                _ => JobGuides::FromReader,
            };
            let rendered =
                over_results.then(|| inputs.iter().map(|(f, _)| originals[f].clone()).collect());
            SequenceJob {
                inputs,
                outputs,
                reader: self.reader.clone(),
                overwrite: self.overwrite || !last,
                output_kind: if last {
                    last_kind
                } else {
                    Some(SampleKind::F32)
                },
                guides,
                replace_denoised: last,
                bands: self.bands,
                rendered,
                motion: self.motion,
            }
        };
        // the whole run is checked first, also one with nothing left to do: an output that is
        // an input under another spelling of its path is refused, not counted as done
        let size = job(inputs.clone(), outputs.clone(), true, false).validate()?;
        // a finished run (every output there) does no work, however many passes
        if !self.overwrite && outputs.iter().flatten().all(|o| o.exists()) {
            return Ok(JobReport {
                skipped: numbers.len(),
                ..JobReport::default()
            });
        }
        // pass p denoises the wanted frames and, before the last pass, as many frames around
        // them as the later passes' windows reach (positions in `all`)
        let (first, last) = (
            all.iter().position(|f| *f == numbers[0]),
            all.iter().position(|f| Some(f) == numbers.last()),
        );
        let (first, last) = first
            .zip(last)
            .expect("the wanted frames are in their context");
        let span = |pass: usize| {
            let e = later_reach(pass);
            first.saturating_sub(e)..(last + e + 1).min(all.len())
        };
        // one denoising pass over whole frames and the temporal pass: one sweep, no scratch
        if let (Some(st), true) = (&self.stabilize, self.fuse_temporal && self.passes <= 1) {
            let banded = method.banded().is_some()
                && self.bands.for_frame(size.0, size.1)
                && !method.needs_rendered();
            if !banded {
                let job = job(inputs, outputs, true, false);
                let frames = job.output_count();
                progress(PassProgress {
                    pass: 1,
                    passes: 1,
                    done: 0.0,
                    frames,
                });
                return crate::run::fused::run_fused(&job, method, st, span(1), |done, _| {
                    progress(PassProgress {
                        pass: 1,
                        passes: 1,
                        done,
                        frames,
                    })
                });
            }
        }
        // earlier passes write to a scratch folder beside the output; the last writes the output
        let scratch = if passes > 1 {
            let dir = self
                .output
                .path(numbers[0])
                .parent()
                .map(PathBuf::from)
                .unwrap_or_default();
            let write_err = |source| Error::Write {
                path: dir.clone(),
                source,
            };
            std::fs::create_dir_all(&dir).map_err(write_err)?;
            Some(
                crate::io::output_locks::ScratchFolder::create(&dir, ".radn-passes-")
                    .map_err(write_err)?,
            )
        } else {
            None
        };
        // what the current pass reads: positions in `all` and their files
        let mut reading = 0..all.len();
        let mut files: Vec<PathBuf> = inputs.into_iter().map(|(_, p)| p).collect();
        let mut report = JobReport::default();
        let (mut repaired, mut cuts) = (0, Vec::new());
        for pass in 1..=passes {
            let is_last = pass == passes;
            let outs: Vec<Option<PathBuf>> = reading
                .clone()
                .map(|i| {
                    if is_last {
                        outputs[i].clone()
                    } else {
                        span(pass).contains(&i).then(|| {
                            let dir = scratch
                                .as_ref()
                                .expect("scratch exists with several passes");
                            dir.path()
                                .join(format!("pass{pass}"))
                                .join(format!("frame_{:08}.exr", all[i]))
                        })
                    }
                })
                .collect();
            let ins = reading
                .clone()
                .zip(&files)
                .map(|(i, p)| (all[i], p.clone()));
            let over_results = pass > self.passes.max(1);
            let job = job(ins.collect(), outs.clone(), is_last, over_results);
            let frames = job.output_count();
            progress(PassProgress {
                pass,
                passes,
                done: 0.0,
                frames,
            });
            // every input was checked above, and earlier passes' results are radn's own
            let r = job.run_validated(methods[pass - 1], size, |done, _| {
                progress(PassProgress {
                    pass,
                    passes,
                    done,
                    frames,
                })
            })?;
            // NaN/Inf are repaired in the original inputs, which only the first pass reads
            // and cuts are found in them too
            if pass == 1 {
                repaired = r.repaired;
                cuts.clone_from(&r.cuts);
            }
            if is_last {
                report = JobReport {
                    repaired,
                    cuts: cuts.clone(),
                    ..r
                };
            } else {
                reading = span(pass);
                files = outs.into_iter().flatten().collect();
            }
        }
        Ok(report)
    }
}
