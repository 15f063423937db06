//! The input blend: per pixel, the network's result is blended with the input by the classic
//! denoiser's Wiener gain ([`radn_core::classic::wiener`]), so that it keeps only the change the
//! input's noise explains and does not average a clean input's detail away.
//!
//! How many noise variances of change still count as noise (the noise scale K) must follow the
//! input's sample count: at 4 spp any blend gives noise back, from 64 spp up K ≈ 2 is best
//! (docs/detail.md). A per-pixel scale cannot tell a clean frame's dark pixels from a noisy
//! frame's, so [`BlendStrength::FollowLevel`] sets K once per frame from the frame's noise level
//! ([`radn_core::noise_level`]), gathered over the whole frame so that bands and tiles of a frame
//! get the same K.

use radn_core::classic::wiener::BlendParams;

/// How the input blend's noise scale is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BlendStrength {
    /// The same noise scale for every frame.
    Fixed(f32),
    /// Per frame, from its noise level ([`noise_scale_for_level`]).
    FollowLevel,
}

/// Options of the input blend.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InputBlend {
    /// Radius of the box the change and the noise are compared over.
    pub radius: usize,
    /// How the noise scale is chosen.
    pub strength: BlendStrength,
}

impl Default for InputBlend {
    /// Radius 1, the scale following the level (`radn denoise`'s default, `--input-blend auto`).
    fn default() -> Self {
        Self {
            radius: 1,
            strength: BlendStrength::FollowLevel,
        }
    }
}

impl InputBlend {
    /// The Wiener blend's parameters for a frame of noise level `level`; `None` where the frame
    /// is noisy enough that the network's result is kept whole.
    pub fn params(&self, level: Option<f32>) -> Option<BlendParams> {
        let noise_scale = match self.strength {
            BlendStrength::Fixed(k) => Some(k),
            BlendStrength::FollowLevel => noise_scale_for_level(level),
        }?;
        Some(BlendParams {
            radius: self.radius,
            noise_scale,
        })
    }
}

/// The smallest noise scale the level gives (that of the cleanest frames).
pub const MIN_NOISE_SCALE: f32 = 2.0;
/// The noise level at and below which the scale is [`MIN_NOISE_SCALE`].
pub const LEVEL_AT_MIN_SCALE: f32 = 0.25;
/// How steeply the scale grows with the level above [`LEVEL_AT_MIN_SCALE`] (a power).
pub const SCALE_EXPONENT: f32 = 1.0;
/// Above this scale the blend would hardly change the result: the frame is left unblended.
pub const MAX_NOISE_SCALE: f32 = 8.0;

/// The noise scale for a frame of noise level `level`:
/// `MIN_NOISE_SCALE · max(1, level / LEVEL_AT_MIN_SCALE)^SCALE_EXPONENT`, `None` (no blend)
/// above [`MAX_NOISE_SCALE`] or for a frame without a level (black). The constants were chosen
/// on the detail validation scenes (docs/detail.md).
pub fn noise_scale_for_level(level: Option<f32>) -> Option<f32> {
    let level = level.filter(|l| l.is_finite())?;
    let k = MIN_NOISE_SCALE * (level / LEVEL_AT_MIN_SCALE).max(1.0).powf(SCALE_EXPONENT);
    (k <= MAX_NOISE_SCALE).then_some(k)
}

/// How many times a tolerance set for the cleanest frames loosens for a frame of noise level
/// `level`: [`noise_scale_for_level`] over [`MIN_NOISE_SCALE`] (1 at the cleanest frames, up to
/// `MAX_NOISE_SCALE / MIN_NOISE_SCALE`), `None` where the blend leaves the frame alone. The
/// rule the colour confidence, the guide mix's range term and the sampled buffers' confidence
/// terms share (`crate::infer::NetworkDenoiser::align_params_for`).
pub fn loosening_for_level(level: Option<f32>) -> Option<f32> {
    noise_scale_for_level(level).map(|k| k / MIN_NOISE_SCALE)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scale_grows_with_the_level_and_a_noisy_frame_is_left_unblended() {
        let clean = noise_scale_for_level(Some(1e-4)).unwrap();
        assert_eq!(clean, MIN_NOISE_SCALE);
        let middle = noise_scale_for_level(Some(LEVEL_AT_MIN_SCALE * 2.0)).unwrap();
        assert!(middle > clean && middle <= MAX_NOISE_SCALE);
        // the largest scale that still blends, and a level just above it
        let edge = LEVEL_AT_MIN_SCALE * MAX_NOISE_SCALE / MIN_NOISE_SCALE;
        assert_eq!(noise_scale_for_level(Some(edge)), Some(MAX_NOISE_SCALE));
        assert_eq!(noise_scale_for_level(Some(1.01 * edge)), None);
        assert_eq!(noise_scale_for_level(Some(10.0)), None);
        assert_eq!(noise_scale_for_level(None), None);
        assert_eq!(noise_scale_for_level(Some(f32::NAN)), None);
    }

    #[test]
    fn a_fixed_scale_ignores_the_level() {
        let b = InputBlend {
            radius: 2,
            strength: BlendStrength::Fixed(4.0),
        };
        for level in [None, Some(1e-5), Some(1.0)] {
            let p = b.params(level).unwrap();
            assert_eq!((p.radius, p.noise_scale), (2, 4.0));
        }
    }
}
