//! OIDN's guide filters run by radn ([`GuideFilters`] over imported U-Nets): the guided path's
//! per-frame guides with no OIDN library. These are the networks OIDN picks at high quality:
//! a beauty model by the auxiliaries given (none, albedo, albedo and normal), and for
//! prefiltered guides the large albedo and normal models and the large clean-auxiliary beauty
//! model; their results equal OIDN's to about 1e-5 (`tests/oidn_unet.rs`).

use radn_core::guide::{Aux, GuideFilters, OidnQuality};
use radn_core::Plane;

use crate::oidn_unet::filter::{UnetFilter, UnetImages};

/// OIDN's high-quality guide networks on radn's CPU kernels.
pub struct BuiltinGuideFilters {
    beauty: BeautyModels,
    albedo: UnetFilter,
    normal: UnetFilter,
}

/// The HDR beauty models OIDN chooses from by the auxiliaries it is given.
pub struct BeautyModels {
    /// No auxiliaries (`rt_hdr`).
    pub plain: UnetFilter,
    /// Albedo only, clean or not (`rt_hdr_alb`).
    pub albedo: UnetFilter,
    /// Noisy albedo and normal (`rt_hdr_alb_nrm`).
    pub noisy_aux: UnetFilter,
    /// Clean (prefiltered) albedo and normal (`rt_hdr_calb_cnrm_large`).
    pub clean_aux: UnetFilter,
}

impl BuiltinGuideFilters {
    /// The beauty models and the prefilters (`rt_alb_large`, `rt_nrm_large`), all sharing
    /// one scratch.
    pub fn new(beauty: BeautyModels, albedo: UnetFilter, normal: UnetFilter) -> Self {
        let scratch = beauty.noisy_aux.scratch();
        let share = |f: UnetFilter| f.with_scratch(scratch.clone());
        Self {
            beauty: BeautyModels {
                plain: share(beauty.plain),
                albedo: share(beauty.albedo),
                clean_aux: share(beauty.clean_aux),
                noisy_aux: beauty.noisy_aux,
            },
            albedo: share(albedo),
            normal: share(normal),
        }
    }

    /// Every network, for the overlap.
    fn all(&self) -> [&UnetFilter; 6] {
        let b = &self.beauty;
        [
            &b.plain,
            &b.albedo,
            &b.noisy_aux,
            &b.clean_aux,
            &self.albedo,
            &self.normal,
        ]
    }

    /// Refuses qualities other than high: the compiled-in networks are high quality's.
    fn check(quality: OidnQuality) -> Result<(), String> {
        match quality {
            OidnQuality::High => Ok(()),
            q => Err(format!(
                "radn's built-in OIDN networks are high quality's; quality '{}' needs Intel \
                 Open Image Denoise 2.x installed",
                q.name()
            )),
        }
    }
}

impl GuideFilters for BuiltinGuideFilters {
    fn describe(&self) -> String {
        format!(
            "radn's built-in OIDN {} networks (no library)",
            self.beauty.noisy_aux.config().oidn_version
        )
    }

    fn overlap(&mut self, quality: OidnQuality) -> Result<usize, String> {
        Self::check(quality)?;
        Ok(self
            .all()
            .iter()
            .map(|f| f.config().layers.overlap())
            .max()
            .unwrap_or(0))
    }

    fn prefilter(
        &mut self,
        aux: &Plane,
        which: Aux,
        quality: OidnQuality,
    ) -> Result<Plane, String> {
        Self::check(quality)?;
        let (net, images) = match which {
            Aux::Albedo => (
                &self.albedo,
                UnetImages {
                    color: None,
                    albedo: Some(aux),
                    normal: None,
                },
            ),
            Aux::Normal => (
                &self.normal,
                UnetImages {
                    color: None,
                    albedo: None,
                    normal: Some(aux),
                },
            ),
        };
        net.run(&images, Some(1.0)).map_err(|e| e.to_string())
    }

    fn beauty(
        &mut self,
        color: &Plane,
        albedo: Option<&Plane>,
        normal: Option<&Plane>,
        quality: OidnQuality,
        clean: bool,
        scale: Option<f32>,
    ) -> Result<Plane, String> {
        Self::check(quality)?;
        // OIDN's choice: by the auxiliaries given; clean ones matter with both
        let b = &self.beauty;
        let net = match (albedo.is_some(), normal.is_some(), clean) {
            (false, false, _) => &b.plain,
            (true, false, _) => &b.albedo,
            (true, true, false) => &b.noisy_aux,
            (true, true, true) => &b.clean_aux,
            (false, true, _) => return Err("a normal needs the albedo beside it".into()),
        };
        let images = UnetImages {
            color: Some(color),
            albedo,
            normal,
        };
        net.run(&images, scale).map_err(|e| e.to_string())
    }
}
