//! Denoising whole sequences: every frame decoded once and kept while windows need it (in
//! memory, or band by band in a scratch file from which each band reads only the rows it
//! reaches: [`crate::run::row_store`]), frames whose output exists skipped (so a killed
//! run resumes), results written into a copy of the input file that keeps every other layer,
//! through a temporary file renamed into place. Each output frame is claimed while it is made
//! ([`crate::io::output_locks::OutputClaim`]), so two runs on one output write each frame once.

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::align::estimate::{EstimateParams, SignalBuilder};
use crate::align::window_indices;
use crate::error::{Error, Result};
use crate::guide::JobGuides;
use crate::io::denoised_output::{write_banded, write_result};
use crate::io::exr_file::{ExrFile, SampleKind};
use crate::io::frame::{Frame, FrameReader};
use crate::io::output::{ensure_not_input, ensure_writable_dir};
use crate::io::output_locks::OutputClaim;
use crate::post::variance_check::{apply_scale, scale_of, Neighbour, RatioHistogram};
use crate::run::banding::{
    frame_bands, hop_reach, window_band_rows, FrameBand, FrameStats, MotionReach, STATS_ROWS,
};
use crate::run::denoiser::{BandDenoiser, Denoised, WindowDenoiser};
use crate::run::motion::{MotionChoice, MotionSource, SequenceMotion, Vectors};
use crate::run::row_store::{FrameStore, RowStore};
use crate::run::sweep::WindowSweep;

/// Whether frames are denoised band by band, where the method can
/// ([`WindowDenoiser::banded`]). Band by band, memory follows the band, not the frame; whole
/// frames are decoded once each and kept while their windows need them, which is faster
/// (`docs/research/benchmarks.md`, "Peak memory") and takes memory in proportion to the frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Bands {
    /// Band by band for frames of more than [`AUTO_BAND_PIXELS`] pixels, whole frames for
    /// smaller ones.
    #[default]
    Auto,
    /// Band by band whatever the frame's size.
    Always,
    /// Whole frames whatever their size.
    Never,
    /// Band by band whatever the frame's size, in bands of at most this many rows (the
    /// method's own band, or fewer: less memory, more halo rows read and computed twice).
    Rows(usize),
}

/// The frame size above which [`Bands::Auto`] goes band by band: 2.5 megapixels, so 1080p
/// and 2K frames run whole (about 2 GB with the default model) and larger ones band by band
/// (about 1 GB at 1080p, growing only with the frame's width).
pub const AUTO_BAND_PIXELS: usize = 2_500_000;

impl Bands {
    /// Whether frames of `width` × `height` go band by band.
    pub fn for_frame(self, width: usize, height: usize) -> bool {
        match self {
            Bands::Auto => width * height > AUTO_BAND_PIXELS,
            Bands::Always => true,
            Bands::Never => false,
            Bands::Rows(_) => true,
        }
    }

    /// The most output rows a band may have (no limit but the method's own unless
    /// [`Bands::Rows`]).
    pub fn row_limit(self) -> usize {
        match self {
            Bands::Rows(n) => n.max(1),
            _ => usize::MAX,
        }
    }
}

/// One sequence to denoise.
pub struct SequenceJob {
    /// Input frames in order: (frame number, path).
    pub inputs: Vec<(i64, PathBuf)>,
    /// Output path for each input frame; `None` for a frame that is only read, as a neighbour
    /// in the windows of the frames that are denoised.
    pub outputs: Vec<Option<PathBuf>>,
    /// How frames are read.
    pub reader: FrameReader,
    /// Recompute frames whose output already exists.
    pub overwrite: bool,
    /// Storage type of the denoised channels (None: the input channel's own type).
    pub output_kind: Option<SampleKind>,
    /// How frames get the guides the reader does not read (Intel Open Image Denoise).
    pub guides: JobGuides,
    /// Also write the result into the renderer's denoised beauty, where a file holds one beside
    /// the noisy beauty ([`Frame::denoised_channels`]): on for outputs, off for the scratch
    /// files between passes, so later passes still find the renderer's guide there.
    pub replace_denoised: bool,
    /// Whether a method that can goes band by band.
    pub bands: Bands,
    /// The original input file behind each input, where the inputs are an earlier pass's
    /// results: a method that asks for the frames as rendered
    /// ([`WindowDenoiser::needs_rendered`]) gets them from these. `None`: the inputs are
    /// the frames as rendered.
    pub rendered: Option<Vec<PathBuf>>,
    /// Which motion windows are aligned with.
    pub motion: MotionChoice,
}

/// What a run did.
#[derive(Clone, Debug, Default)]
pub struct JobReport {
    /// Frames denoised and written.
    pub written: usize,
    /// Frames skipped because their output existed.
    pub skipped: usize,
    /// NaN/Inf samples repaired in the inputs.
    pub repaired: usize,
    /// Cuts found where motion was estimated: the frame numbers on either side of each.
    pub cuts: Vec<(i64, i64)>,
}

impl SequenceJob {
    /// The frame numbers on either side of each cut, from the positions before them.
    pub(crate) fn cut_frames(&self, cuts: impl Iterator<Item = usize>) -> Vec<(i64, i64)> {
        cuts.map(|k| (self.inputs[k].0, self.inputs[k + 1].0))
            .collect()
    }

    /// The number of frames the job writes (the others are neighbours only).
    pub fn output_count(&self) -> usize {
        self.outputs.iter().flatten().count()
    }

    /// The frames the job writes, in order: position in `inputs`, output path, and whether it
    /// is finished already (its output exists and the job does not overwrite).
    pub(crate) fn output_frames(&self) -> impl Iterator<Item = (usize, &Path, bool)> {
        self.outputs.iter().enumerate().filter_map(|(pos, o)| {
            o.as_deref()
                .map(|o| (pos, o, !self.overwrite && o.exists()))
        })
    }

    /// Claims `output` for this run ([`OutputClaim`]), waiting while another run on the same
    /// output folder writes it.
    pub(crate) fn claim(&self, output: &Path) -> Result<OutputClaim> {
        OutputClaim::acquire(output, || {
            tracing::info!(
                "{}: another run is writing it; waiting for that run",
                output.display()
            )
        })
    }

    /// Whether `output`, claimed by this run, was written meanwhile by another run on the same
    /// folder (and this run does not overwrite).
    pub(crate) fn done_by_another_run(&self, output: &Path) -> bool {
        let done = !self.overwrite && output.exists();
        if done {
            tracing::info!("{}: written by another run", output.display());
        }
        done
    }

    /// The channel names a result of `frame` is written into: its beauty, alpha and AOVs, and
    /// the renderer's denoised beauty where [`SequenceJob::replace_denoised`] says so.
    pub(crate) fn output_names(&self, frame: &Frame) -> Frame {
        let mut names = frame.rows(0..0);
        if !self.replace_denoised {
            names.denoised_channels = None;
        }
        names
    }

    /// Checks before any work: no output may be an input, every output folder must be writable,
    /// and the inputs must be EXR files of one size (read from their headers).
    /// Returns the frames' size.
    pub fn validate(&self) -> Result<(usize, usize)> {
        let inputs: Vec<PathBuf> = self.inputs.iter().map(|(_, p)| p.clone()).collect();
        for out in self.outputs.iter().flatten() {
            ensure_not_input(out, &inputs)?;
        }
        let mut dirs: Vec<PathBuf> = self
            .outputs
            .iter()
            .flatten()
            .filter_map(|p| p.parent().map(|d| d.join("x")))
            .collect();
        dirs.dedup();
        for d in dirs {
            // also removes what runs killed while writing here left (a live run's are locked)
            ensure_writable_dir(&d)?;
        }
        // every input is an EXR of one size (headers only): fail now, not after hours of work
        let mut first: Option<(usize, usize)> = None;
        for (_, p) in &self.inputs {
            let (w, h) = ExrFile::read_size(p)?;
            let (ew, eh) = *first.get_or_insert((w, h));
            if (w, h) != (ew, eh) {
                return Err(Error::SizeMismatch {
                    path: p.clone(),
                    expected_w: ew,
                    expected_h: eh,
                    found_w: w,
                    found_h: h,
                });
            }
        }
        first.ok_or_else(|| Error::Unsupported {
            path: PathBuf::new(),
            detail: "the sequence has no frames".into(),
        })
    }

    /// Runs the job; `progress` is called with (output frames done, total) after each output
    /// frame, and with fractions of a frame as bands of it are done.
    pub fn run(
        &self,
        method: &dyn WindowDenoiser,
        progress: impl FnMut(f64, usize),
    ) -> Result<JobReport> {
        let size = self.validate()?;
        self.run_validated(method, size, progress)
    }

    /// [`SequenceJob::run`] for a job whose [`SequenceJob::validate`] has passed (its frames
    /// of `size`, width and height): a run of several passes checks the whole run once, not
    /// each pass.
    pub(crate) fn run_validated(
        &self,
        method: &dyn WindowDenoiser,
        size: (usize, usize),
        mut progress: impl FnMut(f64, usize),
    ) -> Result<JobReport> {
        if let Some(banded) = method
            .banded()
            .filter(|_| self.bands.for_frame(size.0, size.1))
        {
            let r = method.radius();
            return self.run_banded(r, banded, method.needs_rendered(), size, progress);
        }
        let files: Vec<PathBuf> = self.inputs.iter().map(|(_, p)| p.clone()).collect();
        let mut sweep = WindowSweep::new(
            method,
            &self.reader,
            &files,
            self.guides.clone(),
            self.rendered.as_deref(),
            self.motion,
        );
        let mut report = JobReport::default();
        let total = self.output_count();
        for (done, (pos, output, finished)) in self.output_frames().enumerate() {
            super::cancel::check()?;
            let claim = (!finished).then(|| self.claim(output)).transpose()?;
            if finished || self.done_by_another_run(output) {
                report.skipped += 1;
                progress((done + 1) as f64, total);
                continue;
            }
            let started = Instant::now();
            let (out, times) = sweep.denoise(pos)?;
            let writing = Instant::now();
            let file = sweep.take_file(pos).expect("each frame is written once");
            let names = self.output_names(sweep.frame(pos));
            write_result(file, &names, &out, output, self.output_kind)?;
            super::timing::add("writing", writing.elapsed());
            drop(claim);
            tracing::debug!(
                "{}: {:.1} s, of which decoding the frames new to this window {:.1} s, \
                 preparing them {:.1} s, denoising {:.1} s, writing {:.1} s",
                output.display(),
                started.elapsed().as_secs_f64(),
                times.decoding.as_secs_f64(),
                times.preparing.as_secs_f64(),
                times.denoising.as_secs_f64(),
                writing.elapsed().as_secs_f64()
            );
            report.written += 1;
            progress((done + 1) as f64, total);
        }
        report.repaired = sweep.repaired();
        report.cuts = self.cut_frames(sweep.cuts());
        Ok(report)
    }
}

impl SequenceJob {
    /// Frame `k`'s variance scale, band by band from its decoded rows against its neighbours'
    /// (those decoded): what [`WindowSweep`] finds on whole frames
    /// ([`crate::post::variance_check`]). `None` where the frame has no variance or it is kept
    /// as it is.
    fn variance_scale(
        &self,
        k: usize,
        decoded: &BTreeMap<usize, FrameStore>,
        stats: &BTreeMap<usize, FrameStats>,
        motion: &SequenceMotion,
        height: usize,
    ) -> Result<Option<f32>> {
        let reach = if motion.estimating() {
            motion.reach(k)
        } else {
            stats[&k].reach
        };
        // the neighbours decoded, each with its own histogram; each band of the frame read once
        let mut neighbours: Vec<(&FrameStore, Neighbour, usize, RatioHistogram)> = [
            (k.checked_sub(1), Neighbour::Previous, reach.prev),
            (Some(k + 1), Neighbour::Next, reach.next),
        ]
        .into_iter()
        .filter_map(|(j, towards, reach)| {
            let store = decoded.get(&j?)?;
            Some((store, towards, reach, RatioHistogram::default()))
        })
        .collect();
        if neighbours.is_empty() {
            return Ok(None);
        }
        for y0 in (0..height).step_by(STATS_ROWS) {
            let rows = y0..(y0 + STATS_ROWS).min(height);
            let mut frame = decoded[&k].read(rows.clone())?;
            if motion.estimating() {
                motion.attach(k, &mut frame, rows.clone());
            }
            if frame.variance.is_none() {
                return Ok(None);
            }
            for (store, towards, reach, ratios) in &mut neighbours {
                // the rows its motion reaches, and the one below for the bilinear taps
                let near = y0.saturating_sub(*reach + 1)..(rows.end + *reach + 2).min(height);
                let other = store.read(near.clone())?;
                ratios.add_rows(
                    &frame,
                    y0,
                    0..rows.len(),
                    &other,
                    near.start,
                    *towards,
                    height,
                );
            }
        }
        let measured: Vec<Option<f32>> = neighbours.iter().map(|n| n.3.measured()).collect();
        Ok(scale_of(&measured))
    }

    /// [`SequenceJob::run`] band by band: each output frame is denoised in bands of rows, each
    /// band from only the rows of its window's frames that the band reaches, and written block
    /// by block as its rows are done, so memory follows the band's size rather than the
    /// frame's. Each frame is decoded once, when it first enters a window, into a scratch file
    /// (with its OIDN guide and the method's per-frame features, where there are any) that
    /// its bands are read from until its last window is done.
    fn run_banded(
        &self,
        r: usize,
        method: &dyn BandDenoiser,
        needs_rendered: bool,
        (width, height): (usize, usize),
        mut progress: impl FnMut(f64, usize),
    ) -> Result<JobReport> {
        let n = self.inputs.len();
        let mut report = JobReport::default();
        let mut stats: BTreeMap<usize, FrameStats> = BTreeMap::new();
        // of the frames in the windows in flight, on disk: their decoded rows, the method's
        // per-frame features, and their OIDN guides (each computed once, on the whole frame)
        let mut decoded: BTreeMap<usize, FrameStore> = BTreeMap::new();
        let mut features: BTreeMap<usize, RowStore> = BTreeMap::new();
        let mut oidn: BTreeMap<usize, RowStore> = BTreeMap::new();
        // and, for a method that reads them, their beauties as rendered where the inputs are
        // an earlier pass's results (else a frame's own beauty is its rendered one)
        let mut rendered: BTreeMap<usize, RowStore> = BTreeMap::new();
        let band = method.band_rows(width, self.bands.row_limit()).max(1);
        let halo = method.halo();
        tracing::debug!("band by band: {band} rows per band, {halo} rows of halo on each side");
        let frames = self.output_count();
        // the sequence's motion: the renderer's, or estimated as each frame is decoded
        let mut motion = SequenceMotion::new(self.motion, EstimateParams::default());
        let name = |k: usize| {
            let p = &self.inputs[k].1;
            p.file_name().map_or_else(
                || p.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            )
        };
        for (done, (pos, output, finished)) in self.output_frames().enumerate() {
            super::cancel::check()?;
            let claim = (!finished).then(|| self.claim(output)).transpose()?;
            if finished || self.done_by_another_run(output) {
                report.skipped += 1;
                progress((done + 1) as f64, frames);
                continue;
            }
            let mut idx = window_indices(pos, n, r);
            let gathering = Instant::now();
            for &k in idx.iter().flatten() {
                if let std::collections::btree_map::Entry::Vacant(e) = stats.entry(k) {
                    // one decoding of the frame: its statistics, its rows kept for its bands
                    // and, where motion is estimated, its signal
                    let mut store: Option<FrameStore> = None;
                    let mut signal: Option<SignalBuilder> = None;
                    let mut vectors = Vectors::Missing;
                    // the signal is built until the source is decided (on the whole first
                    // frame: its first rows may be still sky) and while motion is estimated
                    let build = r > 0 && motion.source() != Some(MotionSource::Renderer);
                    let s = FrameStats::gather(
                        &self.reader,
                        &self.inputs[k].1,
                        height,
                        STATS_ROWS,
                        |y0, band| {
                            vectors = vectors.and(band);
                            if build {
                                signal
                                    .get_or_insert_with(|| {
                                        SignalBuilder::new(width, height, motion.params())
                                    })
                                    .add_rows(y0, band);
                            }
                            let store = match &mut store {
                                Some(s) => s,
                                None => store.insert(FrameStore::new(band, height)?),
                            };
                            store.write(y0, band)
                        },
                    )?;
                    if r > 0 && motion.decide(vectors, &self.inputs[k].1)? != MotionSource::Renderer
                    {
                        if let Some(b) = signal {
                            motion.add_signal(k, b.finish(), name);
                        }
                    } else if r > 0 && motion.lacks_vectors(vectors) {
                        return Err(self.reader.missing_motion(&self.inputs[k].1));
                    }
                    report.repaired += s.repaired;
                    e.insert(s);
                    decoded.insert(k, store.expect("a frame has rows"));
                }
            }
            if motion.estimating() {
                motion.cut_window(&mut idx);
            }
            // the centre's variance channels, checked against its neighbours
            let scale = self.variance_scale(pos, &decoded, &stats, &motion, height)?;
            if let Some(s) = scale {
                tracing::debug!("frame {pos}: variance channels scaled by {s:.4} (checked)");
            }
            if let (true, Some(originals)) = (needs_rendered, &self.rendered) {
                for &k in idx.iter().flatten() {
                    let original = &originals[k];
                    if *original == self.inputs[k].1 || rendered.contains_key(&k) {
                        continue;
                    }
                    let store = RowStore::new(&self.inputs[k].1, width, height, vec![3])?;
                    for y0 in (0..height).step_by(STATS_ROWS) {
                        let rows = y0..(y0 + STATS_ROWS).min(height);
                        let f = self.reader.read_rows(original, rows)?;
                        f.ensure_size(width, f.height())?;
                        store.write_rows(y0, &[&f.color])?;
                    }
                    rendered.insert(k, store);
                }
            }
            super::timing::add("decoding (bands)", gathering.elapsed());
            if let JobGuides::Oidn { guides, originals } = &self.guides {
                for &k in idx.iter().flatten() {
                    if let std::collections::btree_map::Entry::Vacant(e) = oidn.entry(k) {
                        // band by band too: from the decoded rows where they are the original's
                        let path = &self.inputs[k].1;
                        let store = RowStore::new(path, width, height, vec![3])?;
                        let own = &decoded[&k];
                        let original = &originals[k];
                        guides.of_rows(
                            original,
                            (width, height),
                            |rows| {
                                if original == path {
                                    own.read(rows)
                                } else {
                                    self.reader.read_rows(original, rows)
                                }
                            },
                            |y0, g| store.write_rows(y0, &[g]),
                        )?;
                        e.insert(store);
                        // OIDN's scratch and the guide's bands are free now: neither the next
                        // guide nor the network's bands would reuse all of it (see `memory`)
                        super::memory::release_free_memory();
                    }
                }
            }
            let gathering = gathering.elapsed();
            // rows `rows` of window frame k, with its guide's rows and, once they exist, its
            // per-frame features' rows
            let read_band = |k: usize,
                             rows: Range<usize>,
                             features: &BTreeMap<usize, RowStore>|
             -> Result<Frame> {
                let mut f = decoded[&k].read(rows.clone())?;
                if motion.estimating() {
                    motion.attach(k, &mut f, rows.clone());
                }
                if let (true, Some(s)) = (k == pos, scale) {
                    apply_scale(&mut f, s);
                }
                if let Some(store) = oidn.get(&k) {
                    f.guide = store.read_rows(rows.clone())?.pop();
                }
                if let Some(store) = features.get(&k) {
                    f.features = store.read_rows(rows.clone())?.pop();
                }
                if needs_rendered {
                    f.rendered = match rendered.get(&k) {
                        Some(store) => store.read_rows(rows)?.pop(),
                        None => Some(f.color.clone()),
                    };
                }
                Ok(f)
            };
            let computing = Instant::now();
            if let Some(shape) = method.band_features() {
                for &k in idx.iter().flatten() {
                    if features.contains_key(&k) {
                        continue;
                    }
                    let path = &self.inputs[k].1;
                    let store = RowStore::new(path, width, height, vec![shape.channels])?;
                    for y0 in (0..height).step_by(band) {
                        let out = y0..(y0 + band).min(height);
                        let rows =
                            y0.saturating_sub(shape.halo)..(out.end + shape.halo).min(height);
                        let crop = read_band(k, rows.clone(), &features)?;
                        let f = method
                            .frame_band_features(
                                FrameBand {
                                    frame: &crop,
                                    y0: rows.start,
                                    full_height: height,
                                },
                                out.start - rows.start..out.end - rows.start,
                                &stats[&k],
                            )
                            .expect("a method with per-frame features computes them");
                        store.write_rows(out.start, &[&f])?;
                    }
                    features.insert(k, store);
                }
            }
            let computing = computing.elapsed();
            let reach: Vec<Option<MotionReach>> = idx
                .iter()
                .map(|i| {
                    i.map(|k| {
                        if motion.estimating() {
                            motion.reach(k)
                        } else {
                            stats[&k].reach
                        }
                    })
                })
                .collect();
            let hops = hop_reach(&reach);
            let started = Instant::now();
            let (mut reading, mut denoising) = (Duration::ZERO, Duration::ZERO);
            let denoise_band = |out: Range<usize>| -> Result<Denoised> {
                super::cancel::check()?;
                let t = Instant::now();
                let centre = out.start.saturating_sub(halo)..(out.end + halo).min(height);
                let rows = window_band_rows(centre.clone(), &hops, height);
                let crops = idx
                    .iter()
                    .zip(&rows)
                    .map(|(i, rows)| i.map(|k| read_band(k, rows.clone(), &features)).transpose())
                    .collect::<Result<Vec<Option<Frame>>>>()?;
                let bands = frame_bands(&crops, &rows, height);
                reading += t.elapsed();
                let t = Instant::now();
                let d = method.denoise_band(
                    &bands,
                    out.start - centre.start..out.end - centre.start,
                    &stats[&pos],
                )?;
                denoising += t.elapsed();
                // a band's blocks differ in size from the next band's (alignment reaches,
                // tiles at the frame's edge): without a release the heap's holes add up
                super::memory::release_free_memory();
                progress(done as f64 + out.end as f64 / height as f64, frames);
                Ok(d)
            };
            let names = self.output_names(&stats[&pos].names);
            write_banded(
                &self.inputs[pos].1,
                output,
                &names,
                self.output_kind,
                band,
                denoise_band,
            )?;
            drop(claim);
            let total = started.elapsed();
            super::timing::add("reading bands", reading);
            super::timing::add("writing", total - reading - denoising);
            tracing::debug!(
                "{}: {:.1} s, of which reading bands {:.1} s, denoising {:.1} s, writing {:.1} s \
                 (and {:.1} s before, for decoding the frames new to this window with their \
                 statistics and guides, and {:.1} s for their per-frame features)",
                output.display(),
                total.as_secs_f64(),
                reading.as_secs_f64(),
                denoising.as_secs_f64(),
                (total - reading - denoising).as_secs_f64(),
                gathering.as_secs_f64(),
                computing.as_secs_f64()
            );
            report.written += 1;
            stats.retain(|&k, _| k + r > pos);
            decoded.retain(|&k, _| k + r > pos);
            oidn.retain(|&k, _| k + r > pos);
            features.retain(|&k, _| k + r > pos);
            rendered.retain(|&k, _| k + r > pos);
            motion.forget_before((pos + 1).saturating_sub(r));
            progress((done + 1) as f64, frames);
        }
        report.cuts = self.cut_frames(motion.cuts());
        Ok(report)
    }
}
