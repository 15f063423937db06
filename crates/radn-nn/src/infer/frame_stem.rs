//! A frame-local stem's features of a whole frame (or band) as rendered, computed once per
//! frame and warped into each window instead of recomputed in it.

use burn::tensor::{Tensor, TensorData};
use std::ops::Range;

use radn_core::align::AlignedWindow;
use radn_core::io::frame::Frame;
use radn_core::Plane;

use crate::infer::input::{network_input, FeatureScales, Region};
use crate::profile::{timed, Stage};

use super::NetworkDenoiser;

impl NetworkDenoiser {
    /// The stem features of a frame-local network ([`crate::model::config::NetConfig::frame_local_stem`])
    /// for a whole frame as rendered, normalised by the frame's own exposure and depth: computed
    /// tile by tile with the stem's halo, so only one tile's maps exist at a time besides the
    /// result.
    pub fn frame_stem(&self, frame: &Frame) -> Plane {
        let scales =
            FeatureScales::of_centre(&frame.color, frame.albedo.as_ref(), frame.depth.as_ref());
        self.frame_stem_rows(frame, scales, 0..frame.height())
    }

    /// [`NetworkDenoiser::frame_stem`] of rows `out` of `frame` (a whole frame, or a band of
    /// one holding the stem's halo of rows beyond `out` where the frame has them) whose
    /// whole-frame scales are `scales`: the same tiles' regions as on the whole frame, so the
    /// same values.
    pub(super) fn frame_stem_rows(
        &self,
        frame: &Frame,
        scales: FeatureScales,
        out: Range<usize>,
    ) -> Plane {
        let (w, h) = (frame.width(), frame.height());
        let alone = AlignedWindow {
            frames: vec![radn_core::align::AlignedFrame {
                offset: 0,
                color: frame.color.clone(),
                alpha: None,
                albedo: frame.albedo.clone(),
                normal: frame.normal.clone(),
                depth: frame.depth.clone(),
                aovs: Vec::new(),
                guide: frame.guide.clone(),
                variance: frame.variance.clone(),
                confidence: Plane::filled(w, h, 1, 1.0),
                flow: Plane::zeros(w, h, 2),
            }],
        };
        let halo = self.denoiser.stem_radius();
        let side = if self.tile == 0 { w.max(h) } else { self.tile };
        let c = self.denoiser.stem_channels();
        let mut result = Plane::zeros(w, out.len(), c);
        for y0 in out.clone().step_by(side) {
            for x0 in (0..w).step_by(side) {
                let (x1, y1) = ((x0 + side).min(w), (y0 + side).min(out.end));
                let r = Region {
                    x0: x0.saturating_sub(halo),
                    y0: y0.saturating_sub(halo),
                    x1: (x1 + halo).min(w),
                    y1: (y1 + halo).min(h),
                };
                let (rw, rh) = r.size();
                let input = timed(Stage::Inputs, || {
                    network_input(&alone, scales, r, &self.denoiser.config.inputs)
                });
                let x = Tensor::<4>::from_data(
                    TensorData::new(input, [1, self.denoiser.config.input_channels(), rh, rw]),
                    &self.device,
                );
                let stem = self.denoiser.stem(x).to_data();
                let stem = stem.as_slice::<f32>().expect("f32 features");
                for ch in 0..c {
                    for y in y0..y1 {
                        let src = &stem[ch * rw * rh + (y - r.y0) * rw + (x0 - r.x0)..][..x1 - x0];
                        let at = (y - out.start) * w;
                        result.channel_mut(ch)[at + x0..at + x1].copy_from_slice(src);
                    }
                }
            }
        }
        result
    }
}
