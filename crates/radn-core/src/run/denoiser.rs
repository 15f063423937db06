//! The denoiser contract: what a denoising method implements (a whole-window form, and a
//! band-by-band form where its result allows one) and what it returns, so that the sequence
//! job ([`crate::run::job`]) runs the classic denoiser and the networks alike.

use std::ops::Range;

use crate::error::Result;
use crate::image::plane::Plane;
use crate::io::frame::Frame;
use crate::run::banding::{FrameBand, FrameStats};

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
    /// Per-frame features computed from the frame alone, once, when it first enters a window:
    /// the sequence job stores them in [`Frame::features`] of the decoded frame itself (no
    /// copy of the frame), and every window the frame belongs to reads them there. `None`: the
    /// method has none (the default).
    fn frame_features(&self, _frame: &Frame) -> Option<Plane> {
        None
    }
    /// Whether [`WindowDenoiser::frame_features`] computes anything, so the job asks for it.
    fn has_frame_features(&self) -> bool {
        false
    }
    /// Whether the method needs each frame's beauty as rendered beside what it reads
    /// ([`Frame::rendered`]): a pass over an earlier pass's results that measures how noisy
    /// each frame was. The sequence job then decodes each frame's original input once more.
    fn needs_rendered(&self) -> bool {
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

/// The shape of a band denoiser's per-frame features ([`BandDenoiser::band_features`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BandFeatures {
    /// Channels of the features.
    pub channels: usize,
    /// Rows beyond a band's own rows that computing its features reads.
    pub halo: usize,
}

/// A method that denoises a frame band by band from bands of its window, with exactly the
/// result of denoising whole frames (the network: its receptive field is finite, and aligning
/// a band needs only the rows the motion reaches).
pub trait BandDenoiser: Sync {
    /// Output rows per band of frames `width` pixels wide, at most `limit` where the method's
    /// grid allows (a method that needs bands on a grid of rows rounds down to it).
    fn band_rows(&self, width: usize, limit: usize) -> usize;
    /// Rows of the centre frame beyond a band's output rows that denoising the band reads.
    fn halo(&self) -> usize;
    /// The shape of the method's per-frame features ([`WindowDenoiser::frame_features`] in
    /// band-by-band form), `None` when it has none (the default). The sequence job computes
    /// them band by band when a frame first enters a window
    /// ([`BandDenoiser::frame_band_features`]), keeps them on disk
    /// ([`crate::run::row_store`]) until the frame's last window is done, and gives each band
    /// of a window the rows of them its frames' bands hold, in each band's [`Frame::features`].
    fn band_features(&self) -> Option<BandFeatures> {
        None
    }
    /// The per-frame features of rows `out` (band-local) of `band`, a band of a frame whose
    /// whole-frame statistics are `stats`, holding [`BandFeatures::halo`] rows beyond `out`
    /// where the frame has them. `None` for a method without per-frame features.
    fn frame_band_features(
        &self,
        _band: FrameBand,
        _out: Range<usize>,
        _stats: &FrameStats,
    ) -> Option<Plane> {
        None
    }
    /// Denoises rows `out` (band-local) of the centre band of `window`, whose bands hold the
    /// rows [`crate::run::banding::window_band_rows`] gives (and the same rows of the per-frame
    /// features, where the method has them); `centre` describes the whole centre frame.
    fn denoise_band(
        &self,
        window: &[Option<FrameBand>],
        out: Range<usize>,
        centre: &FrameStats,
    ) -> Result<Denoised>;
}
