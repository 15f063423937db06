//! The filters an OIDN guide is made with, behind one trait: Intel Open Image Denoise's
//! library ([`OidnDenoiser`]) or radn's own run of OIDN's networks (`radn_nn::oidn_unet`,
//! which needs no library), so that [`super::OidnGuides`] makes whole-frame and band-by-band
//! guides the same way over either.

use std::time::Instant;

use crate::image::plane::Plane;

use super::oidn::{Aux, GuideTimes, OidnDenoiser, OidnDevice};
use super::oidn_settings::{OidnQuality, OidnSettings};

/// OIDN's three RT filters as a guide uses them. Errors are one line, for the frame's message.
pub trait GuideFilters: Send {
    /// What runs, for the run's summary: the library and its version, or radn's networks.
    fn describe(&self) -> String;
    /// Rows of context the beauty filter at `quality` needs around a band for the band to be
    /// filtered as within the whole frame.
    fn overlap(&mut self, quality: OidnQuality) -> Result<usize, String>;
    /// The albedo or normal filter on `aux` (RGB) at `quality`.
    fn prefilter(&mut self, aux: &Plane, which: Aux, quality: OidnQuality)
        -> Result<Plane, String>;
    /// The HDR beauty filter on `color` with its auxiliaries (told they are clean where
    /// `clean`) at `quality` and input scale `scale` (`None`: OIDN's autoexposure of `color`).
    fn beauty(
        &mut self,
        color: &Plane,
        albedo: Option<&Plane>,
        normal: Option<&Plane>,
        quality: OidnQuality,
        clean: bool,
        scale: Option<f32>,
    ) -> Result<Plane, String>;
    /// Bounds the filters' scratch memory while a frame goes band by band (`None`: their own
    /// choice again).
    fn bound_memory(&mut self, _mb: Option<usize>) {}

    /// One whole frame's guide as `settings` say (OIDN's final-frame mode by default): the
    /// albedo and normal prefiltered first where they ask, then the beauty on them at OIDN's
    /// autoexposure; and the time each part took. A normal needs the albedo.
    fn denoise_frame(
        &mut self,
        color: &Plane,
        albedo: Option<&Plane>,
        normal: Option<&Plane>,
        settings: &OidnSettings,
    ) -> Result<(Plane, GuideTimes), String> {
        let mut times = GuideTimes::default();
        let (mut alb, mut nrm) = (None, None);
        let q = settings.prefilter.quality();
        if let Some(q) = q {
            let started = Instant::now();
            alb = albedo
                .map(|a| self.prefilter(a, Aux::Albedo, q))
                .transpose()?;
            nrm = normal
                .map(|n| self.prefilter(n, Aux::Normal, q))
                .transpose()?;
            times.prefilters = started.elapsed();
        }
        let started = Instant::now();
        let guide = self.beauty(
            color,
            alb.as_ref().or(albedo),
            nrm.as_ref().or(normal),
            settings.quality,
            q.is_some(),
            None,
        )?;
        times.beauty = started.elapsed();
        Ok((guide, times))
    }
}

impl GuideFilters for OidnDenoiser {
    fn describe(&self) -> String {
        let on = match self.device() {
            OidnDevice::Cpu => String::new(),
            gpu => format!(" on the {gpu}"),
        };
        format!(
            "Intel Open Image Denoise {} ({}){on}",
            self.version(),
            self.library().display()
        )
    }

    fn overlap(&mut self, quality: OidnQuality) -> Result<usize, String> {
        self.tile_overlap(quality).map_err(|e| e.to_string())
    }

    fn prefilter(
        &mut self,
        aux: &Plane,
        which: Aux,
        quality: OidnQuality,
    ) -> Result<Plane, String> {
        OidnDenoiser::prefilter(self, aux, which, quality).map_err(|e| e.to_string())
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
        self.set_input_scale(scale);
        let result = OidnDenoiser::beauty(self, color, albedo, normal, quality, clean);
        self.set_input_scale(None);
        result.map_err(|e| e.to_string())
    }

    fn bound_memory(&mut self, mb: Option<usize>) {
        self.set_max_memory_mb(mb);
    }
}
