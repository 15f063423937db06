//! Denoising whole sequences: every frame decoded once and kept while windows need it, frames
//! whose output exists skipped (so a killed run resumes), results written into a copy of the
//! input file that keeps every other layer, through a temporary file renamed into place.

use std::collections::BTreeMap;
use std::path::PathBuf;

use std::ops::Range;
use std::path::Path;
use std::time::{Duration, Instant};

use crate::align::{
    frame_bands, hop_reach, window_band_rows, window_indices, FrameBand, MotionReach,
};
use crate::band_write::write_banded;
use crate::error::{Error, Result};
use crate::exr_file::{ExrFile, SampleKind};
use crate::frame::{add_geometry_depths, mean_geometry_depth, Frame, FrameReader};
use crate::output::{ensure_not_input, ensure_writable_dir};
use crate::plane::Plane;

/// The denoised buffers of one frame.
#[derive(Clone, Debug)]
pub struct Denoised {
    /// Beauty RGB.
    pub color: Plane,
    /// Alpha, if the input has alpha.
    pub alpha: Option<Plane>,
    /// AOVs in the reader's order.
    pub aovs: Vec<Plane>,
}

/// A method that denoises the centre frame of an aligned window of frames.
pub trait WindowDenoiser: Sync {
    /// Frames on each side of the centre (2 for the paper's 5-frame window).
    fn radius(&self) -> usize;
    /// Per-frame preparation with the frame's neighbours (e.g. motion refinement); runs once per
    /// frame before any window uses it.
    fn prepare(&self, _frame: &mut Frame, _prev: Option<&Frame>, _next: Option<&Frame>) {}
    /// Whether `prepare` changes frames; when it does not, windows use the decoded frames
    /// themselves instead of prepared copies (a whole set of frame planes less in memory).
    fn prepares_frames(&self) -> bool {
        false
    }
    /// Whether `prepare` needs the neighbours (so they are decoded one frame further out).
    fn prepare_needs_neighbours(&self) -> bool {
        false
    }
    /// Denoises `window[radius]`; `None` marks frames beyond the sequence ends.
    fn denoise(&self, window: &[Option<&Frame>]) -> Result<Denoised>;
    /// The method's band-by-band form, when it has one: the job then reads and denoises each
    /// frame in horizontal bands, so memory follows the band, not the frame.
    fn banded(&self) -> Option<&dyn BandDenoiser> {
        None
    }
}

/// A method that denoises a frame band by band from bands of its window, with exactly the
/// result of denoising whole frames (the network: its receptive field is finite, and aligning
/// a band needs only the rows the motion reaches).
pub trait BandDenoiser: Sync {
    /// Output rows per band.
    fn band_rows(&self) -> usize;
    /// Rows of the centre frame beyond a band's output rows that denoising the band reads.
    fn halo(&self) -> usize;
    /// Denoises rows `out` (band-local) of the centre band of `window`, whose bands hold the
    /// rows [`crate::align::window_band_rows`] gives; `centre` describes the whole centre frame.
    fn denoise_band(
        &self,
        window: &[Option<FrameBand>],
        out: Range<usize>,
        centre: &FrameStats,
    ) -> Result<Denoised>;
}

/// What band-by-band denoising needs to know of a whole frame before reading it band by band,
/// gathered in one pass over its bands.
#[derive(Clone, Debug)]
pub struct FrameStats {
    /// How far its motion fields reach, in rows.
    pub reach: MotionReach,
    /// (sum, count) of its geometry depths ([`crate::frame::add_geometry_depths`]).
    pub depth: Option<(f64, usize)>,
    /// NaN/Inf samples repaired in it.
    pub repaired: usize,
}

impl FrameStats {
    /// Reads a frame band by band (`rows` rows at a time) and gathers its statistics.
    pub fn gather(reader: &FrameReader, path: &Path, height: usize, rows: usize) -> Result<Self> {
        let mut stats = FrameStats {
            reach: MotionReach::default(),
            depth: None,
            repaired: 0,
        };
        for y0 in (0..height).step_by(rows.max(1)) {
            let band = reader.read_rows(path, y0..(y0 + rows).min(height))?;
            stats.reach = stats.reach.max(MotionReach::of(&band));
            if let Some(d) = &band.depth {
                stats.depth = Some(add_geometry_depths(d, stats.depth.unwrap_or((0.0, 0))));
            }
            stats.repaired += band.repaired;
        }
        Ok(stats)
    }

    /// The frame's mean geometry depth (1 without depth).
    pub fn mean_depth(&self) -> f32 {
        self.depth.map_or(1.0, mean_geometry_depth)
    }
}

/// Rows per read when gathering a frame's statistics (a multiple of every EXR block height).
const STATS_ROWS: usize = 64;

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
}

impl SequenceJob {
    /// The number of frames the job writes (the others are neighbours only).
    pub fn output_count(&self) -> usize {
        self.outputs.iter().flatten().count()
    }

    /// The frames the job writes, in order: position in `inputs`, output path, and whether it
    /// is finished already (its output exists and the job does not overwrite).
    fn output_frames(&self) -> impl Iterator<Item = (usize, &Path, bool)> {
        self.outputs.iter().enumerate().filter_map(|(pos, o)| {
            o.as_deref()
                .map(|o| (pos, o, !self.overwrite && o.exists()))
        })
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
        mut progress: impl FnMut(f64, usize),
    ) -> Result<JobReport> {
        let (_, height) = self.validate()?;
        if let Some(banded) = method.banded() {
            return self.run_banded(method.radius(), banded, height, progress);
        }
        let n = self.inputs.len();
        let r = method.radius();
        let reach = if method.prepare_needs_neighbours() {
            r + 1
        } else {
            r
        };
        let prepares = method.prepares_frames();
        let mut report = JobReport::default();
        // decoded frames of the windows in flight, each with its file (every layer) until its
        // output is written: every input is decoded once
        let mut raw: BTreeMap<usize, (Frame, Option<ExrFile>)> = BTreeMap::new();
        let mut prepared: BTreeMap<usize, Frame> = BTreeMap::new();
        let mut size: Option<(usize, usize)> = None;
        let total = self.output_count();
        for (done, (pos, output, finished)) in self.output_frames().enumerate() {
            if finished {
                report.skipped += 1;
                progress((done + 1) as f64, total);
                continue;
            }
            // decode what this window needs, once
            for k in pos.saturating_sub(reach)..(pos + reach + 1).min(n) {
                if let std::collections::btree_map::Entry::Vacant(e) = raw.entry(k) {
                    let (f, file) = self.reader.read(&self.inputs[k].1)?;
                    let (w, h) = *size.get_or_insert((f.width(), f.height()));
                    f.ensure_size(w, h)?;
                    report.repaired += f.repaired;
                    e.insert((f, Some(file)));
                }
            }
            if prepares {
                for k in pos.saturating_sub(r)..(pos + r + 1).min(n) {
                    if let std::collections::btree_map::Entry::Vacant(e) = prepared.entry(k) {
                        let mut f = raw[&k].0.clone();
                        let prev = k.checked_sub(1).and_then(|j| raw.get(&j)).map(|x| &x.0);
                        let next = raw.get(&(k + 1)).map(|x| &x.0);
                        method.prepare(&mut f, prev, next);
                        e.insert(f);
                    }
                }
            }
            let idx = window_indices(pos, n, r);
            let frame_at = |i: usize| match prepares {
                true => &prepared[&i],
                false => &raw[&i].0,
            };
            let window: Vec<Option<&Frame>> = idx.iter().map(|i| i.map(frame_at)).collect();
            let out = method.denoise(&window)?;
            drop(window);
            let (frame, file) = raw.get_mut(&pos).expect("the window's centre was decoded");
            let file = file.take().expect("each frame is written once");
            write_result(file, frame, &out, output, self.output_kind)?;
            report.written += 1;
            // forget frames no later window needs
            raw.retain(|&k, _| k + reach > pos);
            prepared.retain(|&k, _| k + r > pos);
            progress((done + 1) as f64, total);
        }
        Ok(report)
    }
}

impl SequenceJob {
    /// [`SequenceJob::run`] band by band: each output frame is denoised in bands of rows, each
    /// band from only the rows of its window's frames that the band reaches (decoded for it and
    /// dropped after), and written block by block as its rows are done, so memory follows the
    /// band's size rather than the frame's.
    fn run_banded(
        &self,
        r: usize,
        method: &dyn BandDenoiser,
        height: usize,
        mut progress: impl FnMut(f64, usize),
    ) -> Result<JobReport> {
        let n = self.inputs.len();
        let mut report = JobReport::default();
        let mut stats: BTreeMap<usize, FrameStats> = BTreeMap::new();
        let band = method.band_rows().max(1);
        let halo = method.halo();
        let frames = self.output_count();
        for (done, (pos, output, finished)) in self.output_frames().enumerate() {
            if finished {
                report.skipped += 1;
                progress((done + 1) as f64, frames);
                continue;
            }
            let idx = window_indices(pos, n, r);
            for &k in idx.iter().flatten() {
                if let std::collections::btree_map::Entry::Vacant(e) = stats.entry(k) {
                    let s =
                        FrameStats::gather(&self.reader, &self.inputs[k].1, height, STATS_ROWS)?;
                    report.repaired += s.repaired;
                    e.insert(s);
                }
            }
            let reach: Vec<Option<MotionReach>> =
                idx.iter().map(|i| i.map(|k| stats[&k].reach)).collect();
            let hops = hop_reach(&reach);
            // the channel names the result is written into, from the centre frame's first row
            let names = self.reader.read_rows(&self.inputs[pos].1, 0..1)?;
            let started = Instant::now();
            let (mut reading, mut denoising) = (Duration::ZERO, Duration::ZERO);
            let denoise_band = |out: Range<usize>| -> Result<Denoised> {
                let t = Instant::now();
                let centre = out.start.saturating_sub(halo)..(out.end + halo).min(height);
                let rows = window_band_rows(centre.clone(), &hops, height);
                let crops = idx
                    .iter()
                    .zip(&rows)
                    .map(|(i, rows)| {
                        i.map(|k| self.reader.read_rows(&self.inputs[k].1, rows.clone()))
                            .transpose()
                    })
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
                progress(done as f64 + out.end as f64 / height as f64, frames);
                Ok(d)
            };
            write_banded(
                &self.inputs[pos].1,
                output,
                &names,
                self.output_kind,
                band,
                denoise_band,
            )?;
            let total = started.elapsed();
            tracing::debug!(
                "{}: {:.1} s, of which reading bands {:.1} s, denoising {:.1} s, writing {:.1} s",
                output.display(),
                total.as_secs_f64(),
                reading.as_secs_f64(),
                denoising.as_secs_f64(),
                (total - reading - denoising).as_secs_f64()
            );
            report.written += 1;
            stats.retain(|&k, _| k + r > pos);
            progress((done + 1) as f64, frames);
        }
        Ok(report)
    }
}

/// Writes denoised buffers over the input's own channels (named by `frame`, which may be any
/// band of it), keeping everything else; `kind` overrides the storage type of the denoised
/// channels.
pub fn write_result(
    mut file: ExrFile,
    frame: &Frame,
    out: &Denoised,
    path: &std::path::Path,
    kind: Option<SampleKind>,
) -> Result<()> {
    if out.color.width() != file.width() || out.color.height() != file.height() {
        return Err(Error::Incompatible {
            what: "denoised result".into(),
            a_w: out.color.width(),
            a_h: out.color.height(),
            b_w: file.width(),
            b_h: file.height(),
        });
    }
    let mut put = |name: &str, data: &[f32]| {
        if let Some(k) = kind {
            file.convert_channel(name, k);
        }
        file.set_channel(name, data, kind.unwrap_or(SampleKind::F32));
    };
    for (c, name) in frame.color_channels.iter().enumerate() {
        put(name, out.color.channel(c));
    }
    if let (Some(a), Some(name)) = (&out.alpha, &frame.alpha_channel) {
        put(name, a.channel(0));
    }
    for (aov, plane) in frame.aovs.iter().zip(&out.aovs) {
        for (c, name) in aov.channels.iter().enumerate() {
            put(name, plane.channel(c));
        }
    }
    file.write_atomic(path)
}
