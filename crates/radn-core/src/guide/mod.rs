//! Guides: a per-frame spatial estimate of the beauty that a guided network reads beside the
//! noisy window (DESIGN.md §5). Kernels are still applied to the noisy frames, so AOVs, alpha
//! and thresholds keep working; the guide only steers the weights.
//!
//! A guide is either a layer the renderer wrote ([`crate::io::frame::GuideLayer`], read with the
//! frame) or Intel Open Image Denoise run on each frame ([`OidnGuides`], computed once per
//! frame from the sequence's original input files, whatever pass is running).

pub mod exposure;
pub mod filters;
pub mod oidn;
mod oidn_library;
pub mod oidn_settings;

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use crate::error::{Error, Result};
use crate::image::plane::Plane;
use crate::io::frame::{Frame, FrameReader};
use crate::run::row_store::RowStore;

pub use exposure::ExposureBins;
pub use filters::GuideFilters;
pub use oidn::{Aux, GuideTimes, OidnDenoiser, OidnDevice, OidnError};
pub use oidn_settings::{OidnQuality, OidnSettings, Prefilter};

/// Where each frame's guide comes from, as a user names it (`--guide oidn|denoised|LAYER|none`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum GuideChoice {
    /// No guide.
    #[default]
    None,
    /// Intel Open Image Denoise on each frame (prefiltered albedo and normal).
    Oidn,
    /// The renderer's denoised beauty, beside the noisy one in the same file.
    Denoised,
    /// A named layer of each file.
    Layer(String),
}

impl GuideChoice {
    /// Parses `oidn`, `denoised`, `none` or a layer name.
    pub fn parse(text: &str) -> Self {
        match text {
            "" | "none" => Self::None,
            "oidn" => Self::Oidn,
            "denoised" => Self::Denoised,
            layer => Self::Layer(layer.to_string()),
        }
    }

    /// Whether frames get a guide at all.
    pub fn is_some(&self) -> bool {
        *self != Self::None
    }

    /// The layer [`FrameReader`] reads as the guide (none for OIDN, which computes it).
    pub fn layer(&self) -> crate::io::frame::GuideLayer {
        use crate::io::frame::GuideLayer;
        match self {
            Self::Denoised => GuideLayer::Denoised,
            Self::Layer(l) => GuideLayer::Layer(l.clone()),
            Self::None | Self::Oidn => GuideLayer::None,
        }
    }
}

/// OIDN guides of a sequence: one set of filters shared by every frame (one frame at a time;
/// they use every thread they were given), computed from the original input files. The
/// filters are OIDN's library or radn's own run of its networks ([`GuideFilters`]).
pub struct OidnGuides {
    filters: Mutex<Box<dyn GuideFilters>>,
    settings: Mutex<OidnSettings>,
}

/// Rows of a frame filtered together when a guide is made band by band: about this many pixels
/// per OIDN call (plus its halo), which bounds the images radn hands OIDN.
const BAND_PIXELS: usize = 2 << 20;
/// The row grid of OIDN's network (four 2× poolings): a band starting on it is filtered as
/// those rows are within the whole frame.
const OIDN_GRID: usize = 16;
/// OIDN's scratch memory per filter when a guide is made band by band (it tiles within that).
const BAND_OIDN_MEMORY_MB: usize = 1024;

impl OidnGuides {
    /// Opens OIDN with `threads` threads (0: every core); fails with a message saying what
    /// to install where the library is missing.
    pub fn new(threads: usize) -> Result<Self> {
        Self::on(OidnDevice::Cpu, threads)
    }

    /// Opens OIDN on `device` (`threads`: the CPU device's, 0 for every core).
    pub fn on(device: OidnDevice, threads: usize) -> Result<Self> {
        let d = OidnDenoiser::on(device, threads).map_err(|e| Error::Guide {
            path: PathBuf::new(),
            detail: e.to_string(),
        })?;
        Ok(Self::with_filters(Box::new(d)))
    }

    /// Guides made by `filters` (radn's own run of OIDN's networks, where no library is).
    pub fn with_filters(filters: Box<dyn GuideFilters>) -> Self {
        Self {
            filters: Mutex::new(filters),
            settings: Mutex::new(OidnSettings::default()),
        }
    }

    /// Makes every later guide with `settings` (a guided model's recipe holds them).
    pub fn configure(&self, settings: OidnSettings) {
        *lock(&self.settings) = settings;
    }

    /// The settings guides are made with.
    pub fn settings(&self) -> OidnSettings {
        *lock(&self.settings)
    }

    /// The filters in use, for messages: "Intel Open Image Denoise 2.5.1 (PATH)", or radn's
    /// own networks.
    pub fn describe(&self) -> String {
        lock(&self.filters).describe()
    }

    /// The guide of `frame` (its beauty, albedo and normal as read from `path`).
    pub fn of_frame(&self, frame: &Frame, path: &Path) -> Result<Plane> {
        let settings = self.settings();
        let (guide, times) = lock(&self.filters)
            .denoise_frame(
                &frame.color,
                frame.albedo.as_ref(),
                frame.normal.as_ref(),
                &settings,
            )
            .map_err(|e| guide_error(path, e))?;
        record(path, times);
        Ok(guide)
    }

    /// The guide of the frame in the file at `path`, read whole by `reader`.
    pub fn of_file(&self, reader: &FrameReader, path: &Path) -> Result<Plane> {
        let (frame, _) = reader.read(path)?;
        self.of_frame(&frame, path)
    }

    /// The guide of a `width × height` frame made band by band, so that memory follows the
    /// band rather than the frame: `read` gives rows of the frame (its beauty, albedo and
    /// normal) and `write` takes the guide's rows from their first row. Every band is
    /// filtered at the whole frame's exposure (a first pass over its rows), with OIDN's own
    /// tile overlap as halo and its scratch memory bounded; the result differs from the
    /// whole frame's guide only where OIDN's tiles would
    /// (`a_guide_made_in_bands_matches_the_whole_frames`).
    pub fn of_rows(
        &self,
        path: &Path,
        (width, height): (usize, usize),
        mut read: impl FnMut(Range<usize>) -> Result<Frame>,
        mut write: impl FnMut(usize, &Plane) -> Result<()>,
    ) -> Result<()> {
        self.of_rows_in(
            path,
            (width, height),
            band_rows(width),
            &mut read,
            &mut write,
        )
    }

    /// [`OidnGuides::of_rows`] in bands of `band` rows. OIDN runs one filter at a time over
    /// every band (the albedo's, the normal's, then the beauty's, the prefiltered auxiliaries
    /// kept in scratch files between), on bands of one size, so it holds one filter's scratch
    /// memory and builds each filter once per frame.
    pub fn of_rows_in(
        &self,
        path: &Path,
        (width, height): (usize, usize),
        band: usize,
        read: &mut dyn FnMut(Range<usize>) -> Result<Frame>,
        write: &mut dyn FnMut(usize, &Plane) -> Result<()>,
    ) -> Result<()> {
        let band = band.max(1);
        if height <= band {
            // one band: the whole frame's guide, as OIDN makes it
            let f = read(0..height)?;
            return write(0, &self.of_frame(&f, path)?);
        }
        let mut bins = ExposureBins::new(width, height);
        for y0 in (0..height).step_by(band) {
            bins.add_rows(y0, &read(y0..(y0 + band).min(height))?.color);
        }
        let settings = self.settings();
        let mut d = lock(&self.filters);
        let halo = d
            .overlap(settings.quality)
            .map_err(|e| guide_error(path, e))?;
        // every band read with its halo (rows read, rows kept), starting on OIDN's 16-row
        // grid as the whole frame does (its network pools four times), all of one size but
        // the last, so that each filter is built twice per frame, not once per band
        let band = band.next_multiple_of(OIDN_GRID);
        let halo = halo.next_multiple_of(OIDN_GRID);
        let len = band + 2 * halo;
        let bands: Vec<(Range<usize>, Range<usize>)> = (0..height)
            .step_by(band)
            .map(|y0| {
                let start = y0.saturating_sub(halo);
                let end = (start + len).min(height);
                (start..end, y0..(y0 + band).min(height))
            })
            .collect();
        let scale = bins.exposure();
        d.bound_memory(Some(BAND_OIDN_MEMORY_MB));
        let result = (|| {
            let mut times = GuideTimes::default();
            // the prefiltered auxiliaries, one filter at a time
            let mut clean: Vec<Option<RowStore>> = vec![None, None];
            if let Some(q) = settings.prefilter.quality() {
                let started = Instant::now();
                for (k, which) in [Aux::Albedo, Aux::Normal].into_iter().enumerate() {
                    let mut store: Option<RowStore> = None;
                    for (rows, out) in &bands {
                        let f = read(rows.clone())?;
                        let Some(aux) = (match which {
                            Aux::Albedo => f.albedo.as_ref(),
                            Aux::Normal => f.normal.as_ref().filter(|_| f.albedo.is_some()),
                        }) else {
                            break;
                        };
                        let p = d
                            .prefilter(aux, which, q)
                            .map_err(|e| guide_error(path, e))?;
                        let s = match &mut store {
                            Some(s) => s,
                            None => store.insert(RowStore::new(path, width, height, vec![3])?),
                        };
                        s.write_rows(
                            out.start,
                            &[&p.rows(out.start - rows.start..out.end - rows.start)],
                        )?;
                        // the band's images and OIDN's scratch back before the next band's
                        crate::run::memory::release_free_memory();
                    }
                    clean[k] = store;
                }
                times.prefilters = started.elapsed();
            }
            let started = Instant::now();
            for (rows, out) in &bands {
                let f = read(rows.clone())?;
                let aux = |k: usize, own: &Option<Plane>| -> Result<Option<Plane>> {
                    match &clean[k] {
                        Some(s) => Ok(s.read_rows(rows.clone())?.pop()),
                        None => Ok(own.clone()),
                    }
                };
                let (alb, nrm) = (aux(0, &f.albedo)?, aux(1, &f.normal)?);
                let g = d
                    .beauty(
                        &f.color,
                        alb.as_ref(),
                        nrm.as_ref().filter(|_| alb.is_some()),
                        settings.quality,
                        settings.prefilter.quality().is_some(),
                        Some(scale),
                    )
                    .map_err(|e| guide_error(path, e))?;
                write(
                    out.start,
                    &g.rows(out.start - rows.start..out.end - rows.start),
                )?;
                crate::run::memory::release_free_memory();
            }
            times.beauty = started.elapsed();
            Ok(times)
        })();
        d.bound_memory(None);
        record(path, result?);
        Ok(())
    }
}

/// Rows per guide band of a frame `width` wide.
fn band_rows(width: usize) -> usize {
    (BAND_PIXELS / width.max(1)).max(64)
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

fn guide_error(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Guide {
        path: path.to_path_buf(),
        detail: e.to_string(),
    }
}

/// Logs one guide's time and adds it to the run's stages.
fn record(path: &Path, times: GuideTimes) {
    tracing::debug!(
        "{}: OIDN guide {:.2} s (prefilters {:.2} s, beauty {:.2} s)",
        path.display(),
        (times.prefilters + times.beauty).as_secs_f64(),
        times.prefilters.as_secs_f64(),
        times.beauty.as_secs_f64()
    );
    if !times.prefilters.is_zero() {
        crate::run::timing::add("OIDN prefilters", times.prefilters);
    }
    crate::run::timing::add("OIDN beauty", times.beauty);
}

/// How a sequence job gets its frames' guides beyond what its reader reads.
#[derive(Clone, Default)]
pub enum JobGuides {
    /// The reader's guide layer, if any, is all.
    #[default]
    FromReader,
    /// OIDN on the original input files `originals` (one per input of the job, in order).
    Oidn {
        /// The shared device.
        guides: std::sync::Arc<OidnGuides>,
        /// The original input file of each of the job's inputs.
        originals: Vec<PathBuf>,
    },
}
