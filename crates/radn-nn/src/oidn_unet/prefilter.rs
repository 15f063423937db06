//! OIDN's albedo and normal prefilters: a frame's auxiliaries cleaned by their own U-Nets
//! before a clean-auxiliary beauty network (`calb_cnrm`) reads them, as OIDN-prefiltered
//! does. The cleaned pair travels beside the frame as its per-frame features (albedo, then
//! normal), computed once per frame, whole or band by band.

use std::ops::Range;

use radn_core::error::{Error, Result};
use radn_core::io::frame::Frame;
use radn_core::Plane;

use crate::oidn_unet::filter::{UnetFilter, UnetImages};

/// Channels of the cleaned auxiliaries kept as a frame's features: albedo, then normal.
pub const CLEAN_AUX_CHANNELS: usize = 6;

/// The albedo and normal U-Nets that clean a frame's auxiliaries.
pub struct AuxPrefilter {
    albedo: UnetFilter,
    normal: UnetFilter,
}

impl AuxPrefilter {
    /// Cleans albedo with `albedo` (e.g. `rt_alb`) and normals with `normal` (`rt_nrm`).
    pub fn new(albedo: UnetFilter, normal: UnetFilter) -> Self {
        Self { albedo, normal }
    }

    /// Rows beyond a band's rows that cleaning it reads (the prefilters' overlap).
    pub fn reach(&self) -> usize {
        self.albedo
            .config()
            .layers
            .overlap()
            .max(self.normal.config().layers.overlap())
    }

    /// OIDN's names of the two prefilters, for a run's summary.
    pub fn names(&self) -> (String, String) {
        (
            self.albedo.config().weights.clone(),
            self.normal.config().weights.clone(),
        )
    }

    /// Frame (or band) `f`'s albedo and normal cleaned (every row of `f`: rows within
    /// [`AuxPrefilter::reach`] of a band's cut are not yet the whole frame's), in tiles of at
    /// most `budget` pixels (the filters' own when `None`); `None` for a buffer `f` lacks.
    pub fn clean(
        &self,
        f: &Frame,
        budget: Option<usize>,
    ) -> Result<(Option<Plane>, Option<Plane>)> {
        let run = |net: &UnetFilter, p: &Plane, albedo: bool| {
            let images = UnetImages {
                color: None,
                albedo: albedo.then_some(p),
                normal: (!albedo).then_some(p),
            };
            match budget {
                Some(b) => net.run_within(&images, Some(1.0), b),
                None => net.run(&images, Some(1.0)),
            }
            .map_err(|e| Error::Unsupported {
                path: f.path.clone(),
                detail: e.to_string(),
            })
        };
        Ok((
            f.albedo
                .as_ref()
                .map(|p| run(&self.albedo, p, true))
                .transpose()?,
            f.normal
                .as_ref()
                .map(|p| run(&self.normal, p, false))
                .transpose()?,
        ))
    }

    /// Rows `out` of frame (or band) `f`'s cleaned auxiliaries as one features plane
    /// ([`CLEAN_AUX_CHANNELS`]); zeros where `f` lacks a buffer or cleaning fails (the beauty
    /// network then refuses the frame with its path, or meets the same error again).
    pub fn features(&self, f: &Frame, out: Range<usize>, budget: Option<usize>) -> Plane {
        let mut features = Plane::zeros(f.width(), out.len(), CLEAN_AUX_CHANNELS);
        if let Ok((Some(a), Some(n))) = self.clean(f, budget) {
            for (k, p) in [a, n].iter().enumerate() {
                for c in 0..3 {
                    let src = &p.channel(c)[out.start * f.width()..out.end * f.width()];
                    features.channel_mut(3 * k + c).copy_from_slice(src);
                }
            }
        }
        features
    }
}

/// The cleaned albedo and normal held in frame `f`'s features ([`AuxPrefilter::features`]),
/// `(None, None)` where the frame lacks a buffer or its features.
pub fn cleaned_of(f: &Frame) -> (Option<Plane>, Option<Plane>) {
    match &f.features {
        Some(clean) if f.albedo.is_some() && f.normal.is_some() => {
            let part = |k: usize| {
                Plane::from_fn(f.width(), f.height(), 3, |x, y, c| {
                    clean.get(x, y, 3 * k + c)
                })
            };
            (Some(part(0)), Some(part(1)))
        }
        _ => (None, None),
    }
}

impl std::fmt::Debug for AuxPrefilter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (albedo, normal) = self.names();
        write!(f, "AuxPrefilter({albedo}, {normal})")
    }
}
