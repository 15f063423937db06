//! A frame-local stem's features as a window reads them
//! ([`crate::model::config::NetConfig::frame_local_stem`]): each frame's own features, computed
//! once per frame, warped onto the centre frame along the alignment's flow and mixed with the
//! centre frame's by confidence (centre mixing, as alignment does with the inputs). Warped band
//! by band of rows, so that only the rows one row of tiles reads exist at a time, not five
//! warped frames of features.

use std::borrow::Cow;
use std::ops::Range;
use std::sync::{Arc, Mutex};

use radn_core::align::AlignedWindow;
use radn_core::banding::Band;
use radn_core::frame::Frame;
use radn_core::warp::{mix_with_centre, warp_bands, Resampling};
use radn_core::Plane;

/// One side frame's features and the alignment that brings them onto the centre frame.
struct Side<'a> {
    features: Cow<'a, Plane>,
    flow: &'a Plane,
    confidence: &'a Plane,
}

/// Every window frame's stem features, warped onto the centre frame on demand, band by band.
pub struct WindowStems<'a> {
    /// Per window frame: its features and alignment, `None` for the centre frame and for frames
    /// nothing of which is trusted (beyond the sequence ends), which take the centre's.
    sides: Vec<Option<Side<'a>>>,
    centre: Cow<'a, Plane>,
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
        let r = window.len() / 2;
        let centre = own(window[r].expect("the centre frame of a window exists"));
        let sides = win
            .frames
            .iter()
            .zip(window)
            .enumerate()
            .map(|(k, (aligned, frame))| match frame {
                Some(f) if k != r && aligned.confidence.data().iter().any(|&c| c > 0.0) => {
                    Some(Side {
                        features: own(f),
                        flow: &aligned.flow,
                        confidence: &aligned.confidence,
                    })
                }
                _ => None,
            })
            .collect();
        Self {
            sides,
            centre,
            resampling,
            last: Mutex::new(None),
        }
    }

    /// Channels of the features.
    pub fn channels(&self) -> usize {
        self.centre.channels()
    }

    /// Rows `rows` of every window frame's features, warped and mixed (one plane per frame,
    /// `rows.len()` rows tall). Asking for the same rows again returns the same planes.
    pub fn rows(&self, rows: Range<usize>) -> Arc<Vec<Plane>> {
        let mut last = self.last.lock().expect("no panic while warping");
        if let Some((have, planes)) = last.as_ref() {
            if *have == rows {
                return planes.clone();
            }
        }
        let full_height = self.centre.height();
        let centre = self.centre.rows(rows.clone());
        let planes: Vec<Plane> = self
            .sides
            .iter()
            .map(|side| match side {
                None => centre.clone(),
                Some(s) => {
                    let flow = s.flow.rows(rows.clone());
                    let band = Band {
                        plane: &flow,
                        y0: rows.start,
                        full_height,
                    };
                    let mut warped = warp_bands(&[Band::whole(&s.features)], band, self.resampling)
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
