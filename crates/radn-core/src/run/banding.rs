//! Banding: everything that lets a frame be read, aligned and denoised in horizontal bands of
//! rows with exactly the result of whole frames, so memory follows the band, not the frame.
//! A band of a plane ([`Band`]) or of a frame ([`FrameBand`]) samples in frame coordinates;
//! how far a frame's motion reaches ([`MotionReach`], gathered with its other whole-frame
//! statistics in [`FrameStats`]) says which rows of each window frame a band of the centre
//! frame needs ([`window_band_rows`]); the margins below say how many rows beyond that
//! alignment and the denoisers that follow it must read.

use std::ops::Range;
use std::path::Path;

use crate::error::Result;
use crate::guide::exposure::ExposureBins;
use crate::image::noise_level::NoiseLevelHistogram;
use crate::image::plane::Plane;
use crate::image::stats::{
    add_geometry_depths, add_log_luminance, log_average_luminance, mean_geometry_depth,
};
use crate::io::frame::{Frame, FrameReader};

/// Rows each one-frame hop of banded alignment needs beyond the rows its motion reaches: the
/// lookup's farther row and the 3×3 prefilter of the confidence guides. The reach is rounded
/// up to whole rows, so a lookup reads with a non-zero weight at most one row beyond it, with
/// either resampling ([`crate::align::warp::Resampling`]: bilinear's next row, Catmull-Rom's row
/// before and two after the position).
pub const HOP_MARGIN_ROWS: usize = 2;

/// Rows next to a band cut that is not a frame edge where banded alignment may differ from
/// whole-frame alignment (the confidence guides' prefilter needs the row beyond the cut): a
/// band denoiser reads this many rows more than its own receptive field on each side.
pub const ALIGNMENT_EDGE_ROWS: usize = 2;

/// Rows `y0..y0 + plane.height()` of a frame `full_height` rows tall: a horizontal band of a
/// frame's plane, sampled in the frame's coordinates. Banded alignment reads only the rows a
/// band of output needs, yet samples (and clamps at the frame's edges) exactly as a whole frame.
#[derive(Clone, Copy, Debug)]
pub struct Band<'a> {
    /// The band's rows.
    pub plane: &'a Plane,
    /// The frame row of the band's first row.
    pub y0: usize,
    /// The frame's height.
    pub full_height: usize,
}

impl<'a> Band<'a> {
    /// A whole plane as a band.
    pub fn whole(plane: &'a Plane) -> Self {
        Self {
            plane,
            y0: 0,
            full_height: plane.height(),
        }
    }

    /// Bilinear lookup of channel `c` at frame position (x, y), edges of the *frame* repeated.
    /// The position, after clamping to the frame, must lie within the band (its rows and the
    /// next one), which banded alignment guarantees by reading rows as far as motion reaches.
    #[inline]
    pub fn bilinear(&self, c: usize, x: f32, y: f32) -> f32 {
        let p = self.plane;
        let w = p.width();
        let h = self.full_height;
        let xf = x.clamp(0.0, (w - 1) as f32);
        let yf = y.clamp(0.0, (h - 1) as f32);
        let x0 = xf.floor() as usize;
        let y0 = yf.floor() as usize;
        let x1 = (x0 + 1).min(w - 1);
        let y1 = (y0 + 1).min(h - 1);
        let fx = xf - x0 as f32;
        let fy = yf - y0 as f32;
        let last = p.height() - 1;
        let (r0, r1) = (
            y0.saturating_sub(self.y0).min(last),
            y1.saturating_sub(self.y0).min(last),
        );
        // the row below is read only with a non-zero weight
        debug_assert!(
            y0 >= self.y0 && y0 - self.y0 <= last && (fy == 0.0 || y1 - self.y0 <= last),
            "band rows {}..{} do not hold row {y0}",
            self.y0,
            self.y0 + p.height()
        );
        let ch = p.channel(c);
        let a = ch[r0 * w + x0] * (1.0 - fx) + ch[r0 * w + x1] * fx;
        let b = ch[r1 * w + x0] * (1.0 - fx) + ch[r1 * w + x1] * fx;
        a * (1.0 - fy) + b * fy
    }

    /// The value of channel `c` at frame pixel (x, y), which must lie within the band.
    #[inline]
    pub fn get(&self, x: usize, y: usize, c: usize) -> f32 {
        self.plane.get(x, y - self.y0, c)
    }
}

/// The largest vertical displacement of a field, in whole pixels rounded up: how many rows
/// beyond a band one hop along it can reach.
pub fn vertical_reach(field: &Plane) -> usize {
    field
        .channel(1)
        .iter()
        .filter(|v| v.is_finite())
        .fold(0.0f32, |m, v| m.max(v.abs()))
        .ceil() as usize
}

/// Rows `y0..y0 + frame.height()` of a frame `full_height` rows tall: what banded alignment
/// reads of each frame of a window, so memory follows the band, not the frame.
#[derive(Clone, Copy, Debug)]
pub struct FrameBand<'a> {
    /// The frame's rows (every plane cropped alike).
    pub frame: &'a Frame,
    /// The frame row of the band's first row.
    pub y0: usize,
    /// The frame's height.
    pub full_height: usize,
}

impl<'a> FrameBand<'a> {
    /// A whole frame as a band.
    pub fn whole(frame: &'a Frame) -> Self {
        Self {
            frame,
            y0: 0,
            full_height: frame.height(),
        }
    }

    /// The same rows of another plane of the frame.
    pub fn of<'p>(&self, plane: &'p Plane) -> Band<'p> {
        Band {
            plane,
            y0: self.y0,
            full_height: self.full_height,
        }
    }
}

/// The bands of a window: `crops[k]` holds rows `rows[k]` of window frame k (None beyond the
/// sequence) of frames `full_height` rows tall.
pub fn frame_bands<'a>(
    crops: &'a [Option<Frame>],
    rows: &[Range<usize>],
    full_height: usize,
) -> Vec<Option<FrameBand<'a>>> {
    crops
        .iter()
        .zip(rows)
        .map(|(f, r)| {
            f.as_ref().map(|frame| FrameBand {
                frame,
                y0: r.start,
                full_height,
            })
        })
        .collect()
}

/// How many rows a frame's motion fields move a pixel at most (see
/// [`vertical_reach`]): all banded alignment needs to know of a frame before
/// reading it band by band.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MotionReach {
    /// Of the field to the previous frame.
    pub prev: usize,
    /// Of the field to the next frame.
    pub next: usize,
}

impl MotionReach {
    /// The reach of a frame's (or a band's) fields.
    pub fn of(frame: &Frame) -> Self {
        let r = |p: &Option<Plane>| p.as_ref().map_or(0, vertical_reach);
        Self {
            prev: r(&frame.motion_prev),
            next: r(&frame.motion_next),
        }
    }

    /// The larger reach of two (a frame's bands combined).
    pub fn max(self, other: Self) -> Self {
        Self {
            prev: self.prev.max(other.prev),
            next: self.next.max(other.next),
        }
    }
}

/// The reach of each hop of a window (the `reach` of [`window_band_rows`]) from its frames'
/// motion reach: the hop into frame k is described by k's field towards the centre and by its
/// neighbour's field towards k (either may be the one alignment uses). `None`: beyond the
/// sequence.
pub fn hop_reach(window: &[Option<MotionReach>]) -> Vec<usize> {
    let t = window.len();
    let r = t / 2;
    (0..t)
        .map(|k| {
            let (near, here) = match k.cmp(&r) {
                std::cmp::Ordering::Less => {
                    (window[k + 1].map(|m| m.prev), window[k].map(|m| m.next))
                }
                std::cmp::Ordering::Greater => {
                    (window[k - 1].map(|m| m.next), window[k].map(|m| m.prev))
                }
                std::cmp::Ordering::Equal => (None, None),
            };
            near.unwrap_or(0).max(here.unwrap_or(0))
        })
        .collect()
}

/// The frame rows each frame of a window must hold for banded alignment of the centre rows
/// `centre` to equal whole-frame alignment. `reach[k]` is how many rows the one-frame hop
/// between window frame k and its neighbour towards the centre can move (the larger vertical
/// motion of the two fields that describe it, [`vertical_reach`]); `reach[r]`
/// is unused. Each hop adds its reach plus [`HOP_MARGIN_ROWS`] (the lookup's farther row and
/// the 3×3 prefilter of the confidence guides).
pub fn window_band_rows(
    centre: Range<usize>,
    reach: &[usize],
    full_height: usize,
) -> Vec<Range<usize>> {
    let t = reach.len();
    let r = t / 2;
    let mut rows = vec![centre.clone(); t];
    for dir in [-1i64, 1] {
        let mut cur = centre.clone();
        for step in 1..=r {
            let k = (r as i64 + dir * step as i64) as usize;
            let grow = reach[k] + HOP_MARGIN_ROWS;
            cur = cur.start.saturating_sub(grow)..(cur.end + grow).min(full_height);
            rows[k] = cur.clone();
        }
    }
    rows
}

/// What band-by-band denoising needs to know of a whole frame before reading it band by band,
/// gathered in one pass over its bands.
#[derive(Clone, Debug)]
pub struct FrameStats {
    /// How far its motion fields reach, in rows.
    pub reach: MotionReach,
    /// (sum, count) of its geometry depths ([`crate::image::stats::add_geometry_depths`]).
    pub depth: Option<(f64, usize)>,
    /// (sum, count) of its log luminances ([`crate::image::stats::add_log_luminance`]).
    pub luminance: (f64, usize),
    /// NaN/Inf samples repaired in it.
    pub repaired: usize,
    /// The histogram its noise level is taken from ([`crate::image::noise_level`]).
    pub noise: NoiseLevelHistogram,
    /// OIDN's autoexposure bins of its beauty, then of each AOV in the reader's order: a
    /// network that runs at OIDN's exposure runs every band at the whole frame's.
    pub autoexposure: Vec<ExposureBins>,
    /// Its first row: the channel names a result is written into, without reading the file
    /// again.
    pub names: Frame,
}

impl FrameStats {
    /// Reads a frame band by band (`rows` rows at a time, one opening of the file per band)
    /// and gathers its statistics, handing each band read, with its first row, to `each_band`
    /// (the sequence job keeps the decoded rows: [`crate::run::row_store::FrameStore`]).
    pub fn gather(
        reader: &FrameReader,
        path: &Path,
        height: usize,
        rows: usize,
        mut each_band: impl FnMut(usize, &Frame) -> Result<()>,
    ) -> Result<Self> {
        let first = reader.read_rows(path, 0..rows.max(1).min(height))?;
        let mut stats = FrameStats {
            reach: MotionReach::default(),
            depth: None,
            luminance: (0.0, 0),
            repaired: 0,
            noise: NoiseLevelHistogram::default(),
            autoexposure: std::iter::once(&first.color)
                .chain(first.aovs.iter().map(|a| &a.plane))
                .map(|p| ExposureBins::new(p.width(), height))
                .collect(),
            names: first.rows(0..1),
        };
        let mut next = Some(first);
        for y0 in (0..height).step_by(rows.max(1)) {
            let band = match next.take() {
                Some(b) => b,
                None => reader.read_rows(path, y0..(y0 + rows).min(height))?,
            };
            stats.reach = stats.reach.max(MotionReach::of(&band));
            if let Some(d) = &band.depth {
                stats.depth = Some(add_geometry_depths(d, stats.depth.unwrap_or((0.0, 0))));
            }
            stats.luminance = add_log_luminance(&band.color, stats.luminance);
            stats.repaired += band.repaired;
            stats
                .noise
                .add_rows(&band.color, band.albedo.as_ref(), 0..band.height());
            let images = std::iter::once(&band.color).chain(band.aovs.iter().map(|a| &a.plane));
            for (bins, image) in stats.autoexposure.iter_mut().zip(images) {
                bins.add_rows(y0, image);
            }
            each_band(y0, &band)?;
        }
        Ok(stats)
    }

    /// The frame's mean geometry depth (1 without depth).
    pub fn mean_depth(&self) -> f32 {
        self.depth.map_or(1.0, mean_geometry_depth)
    }

    /// The frame's exposure: its log-average luminance
    /// ([`crate::image::stats::log_average_luminance`]).
    pub fn exposure(&self) -> f32 {
        log_average_luminance(self.luminance)
    }

    /// OIDN's autoexposure of the frame's beauty (`image` 0) or of its AOV `image` − 1
    /// ([`ExposureBins::exposure`]).
    pub fn autoexposure(&self, image: usize) -> f32 {
        self.autoexposure[image].exposure()
    }

    /// The frame's noise level ([`crate::image::noise_level`]; `None` for a black frame).
    pub fn noise_level(&self) -> Option<f32> {
        self.noise.level()
    }
}

/// Rows per read when gathering a frame's statistics (a multiple of every EXR block height).
pub const STATS_ROWS: usize = 64;
