//! `radn denoise --method temporal`: OIDN's U-Net converted into the paper's spatio-temporal
//! network ([`TemporalUnet`](crate::oidn_unet::temporal::TemporalUnet), fine-tuned by `radn train`) over each frame's window. The window
//! is aligned onto its centre frame by the renderer's motion with radn's confidence and centre
//! mixing (as the training tiles were), then the network runs on the aligned frames
//! ([`TemporalFilter`]). Each AOV goes through the same network over its aligned window with
//! the same auxiliaries (one-channel AOVs as grey); alpha is kept as rendered.

use std::borrow::Cow;

use radn_core::align::{align_window, AlignParams};
use radn_core::error::{Error, Result};
use radn_core::io::frame::Frame;
use radn_core::run::denoiser::{Denoised, WindowDenoiser};
use radn_core::Plane;

use crate::oidn_unet::denoiser::{as_rgb, to_channels};
use crate::oidn_unet::filter::{UnetImages, DEFAULT_MAX_TILE_PIXELS};
use crate::oidn_unet::temporal_filter::TemporalFilter;

/// The temporal method: a converted U-Net and how its windows are aligned.
pub struct TemporalDenoiser {
    filter: TemporalFilter,
    align: AlignParams,
    name: String,
}

impl TemporalDenoiser {
    /// Runs `filter` on windows aligned with radn's default alignment (the training tiles')
    /// and the colour term `color_confidence` (the model's); `name` labels the model in the
    /// run's summary.
    pub fn new(filter: TemporalFilter, color_confidence: Option<f32>, name: String) -> Self {
        let mut align = AlignParams::default();
        align.confidence.color = color_confidence;
        Self {
            filter,
            align,
            name,
        }
    }

    /// Which model runs, for the run's summary line.
    pub fn summary(&self) -> String {
        let c = self.filter.unet().config();
        format!(
            "{} ({} over {} frames, OIDN {})",
            self.name,
            c.weights,
            self.filter.frames(),
            c.oidn_version
        )
    }
}

impl WindowDenoiser for TemporalDenoiser {
    fn radius(&self) -> usize {
        self.filter.frames() / 2
    }

    fn denoise(&self, window: &[Option<&Frame>]) -> Result<Denoised> {
        let r = self.radius();
        let centre = window[r].expect("the centre frame is present");
        let win = align_window(window, &self.align);
        let fail = |e: crate::oidn_unet::filter::FilterError| Error::Unsupported {
            path: centre.path.clone(),
            detail: e.to_string(),
        };
        // one plane per frame of the window through the network, with every frame's aligned
        // auxiliaries, at the exposure of the centre's plane as rendered
        let run = |planes: &[Cow<Plane>], rendered: &Plane| -> Result<Plane> {
            let images: Vec<UnetImages> = win
                .frames
                .iter()
                .zip(planes)
                .map(|(f, p)| UnetImages {
                    color: Some(p),
                    albedo: f.albedo.as_ref(),
                    normal: f.normal.as_ref(),
                })
                .collect();
            let scale = self.filter.unet().autoexposure(rendered);
            self.filter
                .run(&images, scale, DEFAULT_MAX_TILE_PIXELS)
                .map_err(fail)
        };
        let colors: Vec<Cow<Plane>> = win.frames.iter().map(|f| Cow::Borrowed(&f.color)).collect();
        let color = run(&colors, &centre.color)?;
        let mut aovs = Vec::with_capacity(centre.aovs.len());
        for (k, a) in centre.aovs.iter().enumerate() {
            let planes: Vec<Cow<Plane>> = win.frames.iter().map(|f| as_rgb(&f.aovs[k])).collect();
            let out = run(&planes, &as_rgb(&a.plane))?;
            aovs.push(to_channels(out, a.plane.channels()));
        }
        Ok(Denoised {
            color,
            alpha: centre.alpha.clone(),
            aovs,
        })
    }
}
