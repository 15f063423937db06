//! A frame-local stem's features as a window reads them
//! ([`crate::model::config::NetConfig::frame_local_stem`]): each frame's own features, computed
//! once per frame, warped onto the centre frame along the alignment's flow and mixed with the
//! centre frame's by confidence (centre mixing, as alignment does with the inputs). Warped band
//! by band of rows, so that only the rows one row of tiles reads exist at a time, not five
//! warped frames of features. A window aligned band by band reads its frames' features band
//! by band too ([`WindowStems::of_bands`]): the rows of each frame's band.

use std::borrow::Cow;
use std::ops::Range;
use std::sync::{Arc, Mutex};

use radn_core::align::warp::{mix_with_centre, warp_bands, Resampling};
use radn_core::align::AlignedWindow;
use radn_core::io::frame::Frame;
use radn_core::run::banding::{Band, FrameBand};
use radn_core::Plane;

/// One side frame's features and the alignment that brings them onto the centre frame.
struct Side<'a> {
    /// Its features over frame rows `features_y0..`.
    features: Cow<'a, Plane>,
    features_y0: usize,
    flow: &'a Plane,
    confidence: &'a Plane,
}

/// Every window frame's stem features, warped onto the centre frame on demand, band by band.
pub struct WindowStems<'a> {
    /// Per window frame: its features and alignment, `None` for the centre frame and for frames
    /// nothing of which is trusted (beyond the sequence ends), which take the centre's.
    sides: Vec<Option<Side<'a>>>,
    /// The centre frame's features over the aligned window's rows.
    centre: Cow<'a, Plane>,
    /// The frame row of the aligned window's first row (0 for whole frames).
    y0: usize,
    /// The frames' height.
    full_height: usize,
    /// How the features are sampled between pixels: as alignment sampled the inputs.
    resampling: Resampling,
    /// The last band asked for, kept while a row of tiles reads it.
    last: Mutex<Option<WarpedBand>>,
}

/// A band of rows and every window frame's warped features over it.
type WarpedBand = (Range<usize>, Arc<Vec<Plane>>);

impl<'a> WindowStems<'a> {
    /// The stems of `window` (its frames; `None` beyond the sequence ends) aligned as `win`
    /// with `resampling`: each frame's [`Frame::features`] where it has them, `compute(frame)`
    /// where it has not.
    pub fn new(
        window: &[Option<&'a Frame>],
        win: &'a AlignedWindow,
        resampling: Resampling,
        compute: impl Fn(&Frame) -> Plane,
    ) -> Self {
        let own = |f: &'a Frame| -> Cow<'a, Plane> {
            match &f.features {
                Some(p) => Cow::Borrowed(p),
                None => Cow::Owned(compute(f)),
            }
        };
        let full_height = win.centre().color.height();
        Self::from_features(win, resampling, 0, full_height, |k| {
            window[k].map(|f| (own(f), 0))
        })
    }

    /// The stems of a window aligned band by band (`win`, from
    /// [`radn_core::align::align_bands`] of `window`): every frame's band carries the same
    /// rows of its features in [`Frame::features`] (the sequence job puts them there).
    ///
    /// # Panics
    /// When a frame's band has no features.
    pub fn of_bands(
        window: &[Option<FrameBand<'a>>],
        win: &'a AlignedWindow,
        resampling: Resampling,
    ) -> Self {
        let r = window.len() / 2;
        let centre = window[r].expect("the centre frame of a window exists");
        Self::from_features(win, resampling, centre.y0, centre.full_height, |k| {
            window[k].map(|b| {
                let features =
                    b.frame.features.as_ref().expect(
                        "a band of a frame-local stem's window carries its frame's features",
                    );
                (Cow::Borrowed(features), b.y0)
            })
        })
    }

    /// The stems of a window aligned as `win`, whose first row is frame row `y0` of frames
    /// `full_height` rows tall; `frame(k)` gives window frame k's features and the frame row
    /// of their first row (`None` beyond the sequence ends). It is asked only for the centre
    /// frame and for side frames something of which is trusted; the others take the centre's.
    fn from_features(
        win: &'a AlignedWindow,
        resampling: Resampling,
        y0: usize,
        full_height: usize,
        mut frame: impl FnMut(usize) -> Option<(Cow<'a, Plane>, usize)>,
    ) -> Self {
        let r = win.frames.len() / 2;
        let (centre, _) = frame(r).expect("the centre frame of a window exists");
        let sides = win
            .frames
            .iter()
            .enumerate()
            .map(|(k, aligned)| {
                let trusted = k != r && aligned.confidence.data().iter().any(|&c| c > 0.0);
                if !trusted {
                    return None;
                }
                let (features, features_y0) = frame(k)?;
                Some(Side {
                    features,
                    features_y0,
                    flow: &aligned.flow,
                    confidence: &aligned.confidence,
                })
            })
            .collect();
        Self {
            sides,
            centre,
            y0,
            full_height,
            resampling,
            last: Mutex::new(None),
        }
    }

    /// Channels of the features.
    pub fn channels(&self) -> usize {
        self.centre.channels()
    }

    /// Rows `rows` (of the aligned window) of every window frame's features, warped and mixed
    /// (one plane per frame, `rows.len()` rows tall). Asking for the same rows again returns
    /// the same planes.
    pub fn rows(&self, rows: Range<usize>) -> Arc<Vec<Plane>> {
        let mut last = self.last.lock().expect("no panic while warping");
        if let Some((have, planes)) = last.as_ref() {
            if *have == rows {
                return planes.clone();
            }
        }
        let centre = self.centre.rows(rows.clone());
        let planes: Vec<Plane> = self
            .sides
            .iter()
            .map(|side| match side {
                None => centre.clone(),
                Some(s) => {
                    let flow = s.flow.rows(rows.clone());
                    let flow = Band {
                        plane: &flow,
                        y0: self.y0 + rows.start,
                        full_height: self.full_height,
                    };
                    let features = Band {
                        plane: &s.features,
                        y0: s.features_y0,
                        full_height: self.full_height,
                    };
                    let mut warped = warp_bands(&[features], flow, self.resampling)
                        .pop()
                        .expect("one plane in, one out");
                    mix_with_centre(&mut warped, &centre, &s.confidence.rows(rows.clone()));
                    warped
                }
            })
            .collect();
        let planes = Arc::new(planes);
        *last = Some((rows, planes.clone()));
        planes
    }
}
