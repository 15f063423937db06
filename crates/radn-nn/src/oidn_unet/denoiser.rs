//! `radn denoise --method spatial`: every frame denoised by the imported U-Net alone, as OIDN's
//! RT filter would, with no temporal step and no OIDN library. By default the noisy-auxiliary
//! model reads the frame's albedo and normal as rendered; prefiltered, the albedo and normal
//! are first denoised by OIDN's large auxiliary models and the large clean-auxiliary beauty
//! model runs on them (OIDN-prefiltered's three networks). Each AOV is denoised by the beauty
//! model with the same auxiliaries (one-channel AOVs as grey); alpha is kept as rendered.

use std::borrow::Cow;
use std::ops::Range;

use radn_core::error::{Error, Result};
use radn_core::io::frame::Frame;
use radn_core::run::banding::{FrameBand, FrameStats};
use radn_core::run::denoiser::BandFeatures;
use radn_core::run::denoiser::{BandDenoiser, Denoised, WindowDenoiser};
use radn_core::Plane;

use crate::oidn_unet::config::ALIGNMENT;
use crate::oidn_unet::filter::{UnetFilter, UnetImages};
use crate::oidn_unet::prefilter::{cleaned_of, AuxPrefilter, CLEAN_AUX_CHANNELS};

/// Pixels of one network tile when frames go band by band (`--bands`): bands are about as
/// tall as a tile is wide, so that the overlap computed twice stays small, and the feature
/// maps of one tile bound the memory whatever the frame's width.
pub const BAND_TILE_PIXELS: usize = 3 << 18;

/// The spatial method: a beauty U-Net and, for the prefiltered path, the albedo and normal
/// U-Nets that clean its auxiliaries first.
pub struct SpatialDenoiser {
    beauty: UnetFilter,
    prefilters: Option<AuxPrefilter>,
}

impl SpatialDenoiser {
    /// The noisy-auxiliary path: `beauty` reads the auxiliaries as rendered.
    pub fn new(beauty: UnetFilter) -> Self {
        Self {
            beauty,
            prefilters: None,
        }
    }

    /// The prefiltered path: `albedo` and `normal` clean the auxiliaries, then `beauty` runs.
    pub fn prefiltered(beauty: UnetFilter, albedo: UnetFilter, normal: UnetFilter) -> Self {
        let scratch = beauty.scratch();
        Self {
            prefilters: Some(AuxPrefilter::new(
                albedo.with_scratch(scratch.clone()),
                normal.with_scratch(scratch),
            )),
            beauty,
        }
    }

    /// Which OIDN models run, for the run's summary line.
    pub fn summary(&self) -> String {
        let b = &self.beauty.config();
        match &self.prefilters {
            None => format!("{} (OIDN {})", b.weights, b.oidn_version),
            Some(p) => {
                let (a, n) = p.names();
                format!("{} on {a} and {n} (OIDN {})", b.weights, b.oidn_version)
            }
        }
    }
}

/// A one-channel plane as grey RGB, and an RGB plane's channel mean back.
pub(crate) fn as_rgb(p: &Plane) -> Cow<'_, Plane> {
    if p.channels() == 3 {
        return Cow::Borrowed(p);
    }
    Cow::Owned(Plane::from_fn(p.width(), p.height(), 3, |x, y, _| {
        (0..p.channels()).map(|c| p.get(x, y, c)).sum::<f32>() / p.channels() as f32
    }))
}

/// A network's RGB result as a plane of `channels` channels: itself for RGB, else the mean of
/// its channels in each (the grey a one-channel AOV went in as, [`as_rgb`]).
pub(crate) fn to_channels(out: Plane, channels: usize) -> Plane {
    if channels == 3 {
        return out;
    }
    Plane::from_fn(out.width(), out.height(), channels, |x, y, _| {
        (out.get(x, y, 0) + out.get(x, y, 1) + out.get(x, y, 2)) / 3.0
    })
}

/// The auxiliaries the beauty network reads, as planes of the rows of the frame (or band) it
/// is given: as rendered, or cleaned by the prefilters.
type Auxiliaries<'a> = (Option<Cow<'a, Plane>>, Option<Cow<'a, Plane>>);

impl SpatialDenoiser {
    /// Rows beyond a band's output rows that the beauty network reads (its overlap), and that
    /// the auxiliary prefilters read (none without them).
    fn reaches(&self) -> (usize, usize) {
        let beauty = self.beauty.config().layers.overlap();
        let prefilter = self.prefilters.as_ref().map_or(0, AuxPrefilter::reach);
        (beauty, prefilter)
    }

    /// `net` on `images` at input scale `scale`, in tiles of at most `budget` pixels (the
    /// filter's own when `None`), failing with the frame's path.
    fn run(
        net: &UnetFilter,
        images: &UnetImages,
        scale: f32,
        budget: Option<usize>,
        path: &std::path::Path,
    ) -> Result<Plane> {
        match budget {
            Some(b) => net.run_within(images, Some(scale), b),
            None => net.run(images, Some(scale)),
        }
        .map_err(|e| Error::Unsupported {
            path: path.to_path_buf(),
            detail: e.to_string(),
        })
    }

    /// Rows `out` of frame `f` (all of `f`, or a band of a frame whose first row is on the
    /// networks' 16-row grid, holding the beauty's overlap beyond `out` where the frame has
    /// it), denoised with auxiliaries `aux` (of `f`'s rows) at input scales `scales` (the
    /// beauty's, then each AOV's) in tiles of at most `budget` pixels (the filters' own when
    /// `None`).
    fn denoise_rows(
        &self,
        f: &Frame,
        aux: Auxiliaries,
        out: Range<usize>,
        scales: &[f32],
        budget: Option<usize>,
    ) -> Result<Denoised> {
        // the beauty network on the rows its output rows read (on the band's grid: `out`
        // starts on it, and the overlap is a multiple of 16)
        let (reach, _) = self.reaches();
        let rows = out.start.saturating_sub(reach)..(out.end + reach).min(f.height());
        let whole = rows.len() == f.height();
        let crop = |p: Cow<'_, Plane>| -> Plane {
            if whole {
                p.into_owned()
            } else {
                p.rows(rows.clone())
            }
        };
        let (albedo, normal) = if whole {
            aux
        } else {
            (
                aux.0.map(|p| Cow::Owned(crop(p))),
                aux.1.map(|p| Cow::Owned(crop(p))),
            )
        };
        let keep = out.start - rows.start..out.end - rows.start;
        let run = |color: &Plane, scale: f32| -> Result<Plane> {
            let images = UnetImages {
                color: Some(color),
                albedo: albedo.as_deref(),
                normal: normal.as_deref(),
            };
            let d = Self::run(&self.beauty, &images, scale, budget, &f.path)?;
            Ok(if keep.len() == d.height() {
                d
            } else {
                d.rows(keep.clone())
            })
        };
        let color = if whole {
            run(&f.color, scales[0])?
        } else {
            run(&crop(Cow::Borrowed(&f.color)), scales[0])?
        };
        let mut aovs = Vec::with_capacity(f.aovs.len());
        for (a, &scale) in f.aovs.iter().zip(&scales[1..]) {
            let out = if whole {
                run(&as_rgb(&a.plane), scale)?
            } else {
                run(&as_rgb(&crop(Cow::Borrowed(&a.plane))), scale)?
            };
            aovs.push(to_channels(out, a.plane.channels()));
        }
        Ok(Denoised {
            color,
            alpha: f.alpha.as_ref().map(|a| a.rows(out.clone())),
            aovs,
        })
    }
}

impl WindowDenoiser for SpatialDenoiser {
    fn radius(&self) -> usize {
        0
    }

    fn denoise(&self, window: &[Option<&Frame>]) -> Result<Denoised> {
        let f = window[0].expect("the centre frame is present");
        let scales: Vec<f32> = std::iter::once(&f.color)
            .chain(f.aovs.iter().map(|a| &a.plane))
            .map(|p| self.beauty.autoexposure(p))
            .collect();
        let aux = if let Some(p) = &self.prefilters {
            let (a, n) = p.clean(f, None)?;
            (a.map(Cow::Owned), n.map(Cow::Owned))
        } else {
            (
                f.albedo.as_ref().map(Cow::Borrowed),
                f.normal.as_ref().map(Cow::Borrowed),
            )
        };
        self.denoise_rows(f, aux, 0..f.height(), &scales, None)
    }

    fn banded(&self) -> Option<&dyn BandDenoiser> {
        Some(self)
    }
}

impl BandDenoiser for SpatialDenoiser {
    fn band_rows(&self, _width: usize, limit: usize) -> usize {
        // about a square tile's side with the beauty's overlap, on the networks' 16-row grid
        // so that every band starts on the whole frame's
        let side = (BAND_TILE_PIXELS as f64).sqrt() as usize;
        let rows = side.saturating_sub(2 * self.reaches().0).min(limit);
        (rows / ALIGNMENT * ALIGNMENT).max(ALIGNMENT)
    }

    fn halo(&self) -> usize {
        self.reaches().0.next_multiple_of(ALIGNMENT)
    }

    fn band_features(&self) -> Option<BandFeatures> {
        // the prefiltered path cleans each frame's auxiliaries band by band first, with the
        // prefilters' own halo, and keeps them beside the frame
        self.prefilters.as_ref().map(|_| BandFeatures {
            channels: CLEAN_AUX_CHANNELS,
            halo: self.reaches().1.next_multiple_of(ALIGNMENT),
        })
    }

    fn frame_band_features(
        &self,
        band: FrameBand,
        out: Range<usize>,
        _stats: &FrameStats,
    ) -> Option<Plane> {
        let p = self.prefilters.as_ref()?;
        Some(p.features(band.frame, out, Some(BAND_TILE_PIXELS)))
    }

    fn denoise_band(
        &self,
        window: &[Option<FrameBand>],
        out: Range<usize>,
        centre: &FrameStats,
    ) -> Result<Denoised> {
        let f = window[0].expect("the centre band is present").frame;
        let scales: Vec<f32> = centre
            .autoexposure
            .iter()
            .map(|bins| self.beauty.exposure_of(bins))
            .collect();
        let aux = match &self.prefilters {
            // the model's own message for a missing auxiliary
            Some(_) => {
                let (a, n) = cleaned_of(f);
                (a.map(Cow::Owned), n.map(Cow::Owned))
            }
            None => (
                f.albedo.as_ref().map(Cow::Borrowed),
                f.normal.as_ref().map(Cow::Borrowed),
            ),
        };
        self.denoise_rows(f, aux, out, &scales, Some(BAND_TILE_PIXELS))
    }
}
