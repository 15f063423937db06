//! `radn denoise --method spatial`: every frame denoised by the imported U-Net alone, as OIDN's
//! RT filter would, with no temporal step and no OIDN library. By default the noisy-auxiliary
//! model reads the frame's albedo and normal as rendered; prefiltered, the albedo and normal
//! are first denoised by OIDN's large auxiliary models and the large clean-auxiliary beauty
//! model runs on them (OIDN-prefiltered's three networks). Each AOV is denoised by the beauty
//! model with the same auxiliaries (one-channel AOVs as grey); alpha is kept as rendered.

use radn_core::error::{Error, Result};
use radn_core::io::frame::Frame;
use radn_core::run::denoiser::{Denoised, WindowDenoiser};
use radn_core::Plane;

use crate::oidn_unet::filter::{UnetFilter, UnetImages};

/// The spatial method: a beauty U-Net and, for the prefiltered path, the albedo and normal
/// U-Nets that clean its auxiliaries first.
pub struct SpatialDenoiser {
    beauty: UnetFilter,
    prefilters: Option<(UnetFilter, UnetFilter)>,
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
            prefilters: Some((
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
            Some((a, n)) => format!(
                "{} on {} and {} (OIDN {})",
                b.weights,
                a.config().weights,
                n.config().weights,
                b.oidn_version
            ),
        }
    }
}

/// A one-channel plane as grey RGB, and an RGB plane's channel mean back.
fn as_rgb(p: &Plane) -> Plane {
    if p.channels() == 3 {
        return p.clone();
    }
    Plane::from_fn(p.width(), p.height(), 3, |x, y, _| {
        (0..p.channels()).map(|c| p.get(x, y, c)).sum::<f32>() / p.channels() as f32
    })
}

impl WindowDenoiser for SpatialDenoiser {
    fn radius(&self) -> usize {
        0
    }

    fn denoise(&self, window: &[Option<&Frame>]) -> Result<Denoised> {
        let f = window[0].expect("the centre frame is present");
        let fail = |e: crate::oidn_unet::filter::FilterError| Error::Unsupported {
            path: f.path.clone(),
            detail: e.to_string(),
        };
        let (albedo, normal) = match &self.prefilters {
            None => (f.albedo.clone(), f.normal.clone()),
            Some((a, n)) => (
                f.albedo
                    .as_ref()
                    .map(|p| {
                        a.run(
                            &UnetImages {
                                color: None,
                                albedo: Some(p),
                                normal: None,
                            },
                            None,
                        )
                    })
                    .transpose()
                    .map_err(fail)?,
                f.normal
                    .as_ref()
                    .map(|p| {
                        n.run(
                            &UnetImages {
                                color: None,
                                albedo: None,
                                normal: Some(p),
                            },
                            None,
                        )
                    })
                    .transpose()
                    .map_err(fail)?,
            ),
        };
        let run = |color: &Plane| {
            self.beauty
                .run(
                    &UnetImages {
                        color: Some(color),
                        albedo: albedo.as_ref(),
                        normal: normal.as_ref(),
                    },
                    None,
                )
                .map_err(fail)
        };
        let color = run(&f.color)?;
        let mut aovs = Vec::with_capacity(f.aovs.len());
        for a in &f.aovs {
            let out = run(&as_rgb(&a.plane))?;
            aovs.push(if a.plane.channels() == 3 {
                out
            } else {
                let grey = Plane::from_fn(out.width(), out.height(), 1, |x, y, _| {
                    (out.get(x, y, 0) + out.get(x, y, 1) + out.get(x, y, 2)) / 3.0
                });
                Plane::from_fn(out.width(), out.height(), a.plane.channels(), |x, y, _| {
                    grey.get(x, y, 0)
                })
            });
        }
        Ok(Denoised {
            color,
            alpha: f.alpha.clone(),
            aovs,
        })
    }
}
