//! The input blend, a stage after the kernels: per pixel, the network's result is blended with
//! the input by the Wiener gain ([`radn_core::post::wiener`]), so that it keeps only the
//! change the input's noise explains and does not average a clean input's detail away.
//!
//! How many noise variances of change still count as noise (the noise scale K) must follow the
//! input's sample count: at 4 spp any blend gives noise back, on clean frames K ≈ 2 is best. A
//! per-pixel scale cannot tell a clean frame's dark pixels from a noisy frame's, so by default
//! K is set once per frame from the frame's noise level by the recipe's
//! [`NoiseSchedule`]. Where the frame carries the renderer's per-pixel variance, the stage blends
//! against that instead ([`radn_core::post::wiener::variance_blend_weight`]): it does not read
//! edges as noise as the window's estimate does, so it runs on every frame.

use std::ops::Range;

use radn_core::align::AlignedWindow;
use radn_core::post::wiener::{
    blend, blend_weight, variance_blend_weight, window_noise_variance, BlendParams, VarianceBlend,
};
use radn_core::Plane;
use serde::{Deserialize, Serialize};

use crate::infer::schedule::NoiseSchedule;
use crate::infer::signals::Signals;

/// Options of the input blend.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputBlend {
    /// Radius of the box the change and the noise are compared over.
    pub radius: usize,
    /// The same noise scale for every frame; `None`: per frame, from the noise schedule.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise_scale: Option<f32>,
    /// Box radius of the blend on frames that carry the renderer's variance; `Some(0)` or
    /// `None`: those frames get the estimated blend too. An unguided model's recipe stored
    /// without it gets the tuned radius when read ([`crate::recipe::Recipe::from_toml`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub variance_radius: Option<usize>,
    /// Factor on the renderer's variance in that blend (`None`: 1): a variance AOV is the
    /// samples' spread over their count, which overstates the error of stratified samplers.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub variance_scale: Option<f32>,
}

impl InputBlend {
    /// The stage for a frame of noise level `level` that carries the renderer's variance or
    /// not; `None` where the frame keeps the network's result.
    pub fn stage(
        &self,
        level: Option<f32>,
        schedule: &NoiseSchedule,
        renderer_variance: bool,
    ) -> Option<BlendStage> {
        match self.variance_radius {
            Some(radius) if renderer_variance && radius > 0 => {
                return Some(BlendStage::RendererVariance(VarianceBlend {
                    radius,
                    scale: self.variance_scale.unwrap_or(1.0),
                }))
            }
            _ => {}
        }
        self.params(level, schedule).map(BlendStage::Estimated)
    }

    /// The Wiener blend's parameters for a frame of noise level `level`; `None` where the
    /// schedule finds the frame noisy enough that the network's result is kept whole.
    pub fn params(&self, level: Option<f32>, schedule: &NoiseSchedule) -> Option<BlendParams> {
        let noise_scale = match self.noise_scale {
            Some(k) => Some(k),
            None => schedule.noise_scale(level),
        }?;
        Some(BlendParams {
            radius: self.radius,
            noise_scale,
        })
    }
}

/// How one frame's input blend runs.
#[derive(Clone, Copy, Debug)]
pub enum BlendStage {
    /// Against the noise estimated from the window, at the schedule's scale for the frame.
    Estimated(BlendParams),
    /// Against the renderer's variance, which the frame carries.
    RendererVariance(VarianceBlend),
}

impl BlendStage {
    /// Rows beyond a result's own that the stage reads of the network's result (the variance
    /// blend's box, and the brightness box inside it).
    pub fn radius(&self) -> usize {
        match self {
            Self::Estimated(p) => p.radius,
            Self::RendererVariance(v) => v.radius + 1,
        }
    }
}

/// The input blend of the kernels' result `filtered` (every signal, stacked as [`Signals`])
/// over rows `read` of `win`: per pixel, the Wiener gain of the beauty's change against the
/// noise (the renderer's variance, or the window's estimate, as `stage` says), applied to every
/// signal alike (still one linear operator per signal, so AOVs keep summing and alpha stays in
/// range).
pub fn apply(
    win: &AlignedWindow,
    filtered: &Plane,
    read: Range<usize>,
    stage: &BlendStage,
) -> Plane {
    let input = Signals::centre_values(win, read.clone());
    let (beauty_in, beauty_out) = (input.select_channels(0, 3), filtered.select_channels(0, 3));
    let weight = match (stage, &win.centre().variance) {
        (BlendStage::RendererVariance(v), Some(var)) => {
            variance_blend_weight(&beauty_in, &beauty_out, &var.rows(read), v)
        }
        (BlendStage::Estimated(p), _) => blend_weight(
            &beauty_in,
            &beauty_out,
            &window_noise_variance(win, read),
            p,
        ),
        (BlendStage::RendererVariance(_), None) => {
            unreachable!("a renderer-variance blend is chosen only for frames that carry one")
        }
    };
    blend(&input, filtered, &weight)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scale_follows_the_schedule_and_a_noisy_frame_is_left_unblended() {
        let s = NoiseSchedule::example();
        let b = InputBlend {
            radius: 1,
            noise_scale: None,
            variance_radius: Some(4),
            variance_scale: None,
        };
        assert_eq!(b.params(Some(1e-5), &s).unwrap().noise_scale, s.min_scale);
        assert!(b.params(Some(10.0 * s.noisiest_level()), &s).is_none());
        assert!(b.params(None, &s).is_none());
        // a frame with the renderer's variance is blended against it at every level
        for level in [None, Some(1e-5), Some(10.0 * s.noisiest_level())] {
            match b.stage(level, &s, true) {
                Some(BlendStage::RendererVariance(v)) => assert_eq!((v.radius, v.scale), (4, 1.0)),
                other => panic!("{other:?}"),
            }
        }
        let off = InputBlend {
            variance_radius: Some(0),
            ..b
        };
        assert!(off.stage(None, &s, true).is_none());
        assert!(matches!(
            off.stage(Some(1e-5), &s, true),
            Some(BlendStage::Estimated(_))
        ));
    }

    #[test]
    fn a_fixed_scale_ignores_the_level() {
        let b = InputBlend {
            radius: 2,
            noise_scale: Some(4.0),
            variance_radius: Some(4),
            variance_scale: None,
        };
        for level in [None, Some(1e-5), Some(1.0)] {
            let p = b.params(level, &NoiseSchedule::example()).unwrap();
            assert_eq!((p.radius, p.noise_scale), (2, 4.0));
        }
    }
}
