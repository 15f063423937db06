//! The guide blend of a guided network ([`crate::model::config::NetConfig::guide_blend`]):
//! before the kernels filter a window, every frame's noisy values move toward that frame's
//! guide by a per-pixel weight `β` the network predicts, so the kernels average the aligned
//! guides (a learned temporal filter over the per-frame spatial estimates) where the network
//! trusts them and the noisy frames elsewhere.
//!
//! It is applied as a gain on each RGB group, `m = 1 − β + β·g / max(x, ε)` with `x` and `g` the
//! frame's colour and guide from the network's own input features (so training and inference
//! blend identically; with exposure normalisation `ε` is relative to the frame's exposure). On
//! the beauty, `x·m = (1 − β)·x + β·g` wherever `x ≥ ε`. Every RGB AOV gets the same gain, so
//! AOVs that sum to the beauty still sum to the blended beauty, and the kernels keep them
//! summing to the denoised beauty: the guide is shared among the AOVs in proportion to their
//! part of the noisy pixel. Alpha (and any single-channel AOV) is not blended.

use burn::tensor::Tensor;

use crate::model::config::{InputConfig, INPUT_CHANNELS};
use crate::model::demod::over_rgb_groups;

/// `ε` of the gain: the smallest colour (in the network's colour units) a guide is divided by.
pub const GUIDE_BLEND_EPS: f32 = 1e-2;

/// The per-frame gains of one window.
#[derive(Clone, Debug)]
pub struct GuideBlend {
    /// `1 − β + β·g / max(x, ε)` per frame, `[B, T, 3, H, W]`.
    gain: Tensor<5>,
    /// Channel offsets of the 3-channel groups that are blended.
    rgb: Vec<usize>,
    /// Channels of the values.
    channels: usize,
}

impl GuideBlend {
    /// The blend of the RGB groups at `rgb` (of values with `channels` channels) for a window
    /// with network input `features` (`[B, T, C, H, W]`, read as `inputs` says) and blend
    /// weights `beta` (`[B, T, 1, H, W]`).
    pub fn new(
        features: &Tensor<5>,
        beta: Tensor<5>,
        inputs: &InputConfig,
        rgb: Vec<usize>,
        channels: usize,
    ) -> Self {
        assert!(inputs.guide, "a guide blend needs a guide in the inputs");
        let guide_at = INPUT_CHANNELS + usize::from(inputs.noise);
        // the features hold ln(1 + v) of the (exposure-normalised) colour and guide
        let linear = |at: usize| features.clone().narrow(2, at, 3).exp() - 1.0;
        let (x, g) = (linear(0).clamp_min(0.0), linear(guide_at).clamp_min(0.0));
        let [_, _, c, _, _] = beta.dims();
        assert_eq!(c, 1, "one blend weight per pixel and frame");
        let beta = beta.repeat_dim(2, 3);
        let gain = (beta.clone().neg() + 1.0) + beta * g / x.clamp_min(GUIDE_BLEND_EPS);
        Self {
            gain,
            rgb,
            channels,
        }
    }

    /// The values `[B, T, channels, H, W]` blended toward their guides.
    pub fn apply(&self, values: Tensor<5>) -> Tensor<5> {
        values * over_rgb_groups(self.gain.clone(), &self.rgb, self.channels)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, TensorData};

    const GUIDED: InputConfig = InputConfig {
        exposure: true,
        noise: false,
        guide: true,
    };

    /// Features of one pixel per frame: log colour `x`, log guide `g`, the rest zero.
    fn features(x: &[f32], g: &[f32]) -> Tensor<5> {
        let t = x.len();
        let c = GUIDED.channels();
        let mut v = vec![0.0f32; t * c];
        for k in 0..t {
            for ch in 0..3 {
                v[k * c + ch] = x[k].ln_1p();
                v[k * c + INPUT_CHANNELS + ch] = g[k].ln_1p();
            }
        }
        Tensor::from_data(TensorData::new(v, [1, t, c, 1, 1]), &Device::default())
    }

    fn beta(b: &[f32]) -> Tensor<5> {
        Tensor::from_data(
            TensorData::new(b.to_vec(), [1, b.len(), 1, 1, 1]),
            &Device::default(),
        )
    }

    fn vals(t: Tensor<5>) -> Vec<f32> {
        t.to_data().try_to_vec::<f32>().unwrap()
    }

    #[test]
    fn the_beauty_moves_toward_its_guide_and_aovs_keep_summing_to_it() {
        let (x, g) = ([0.5f32, 2.0, 0.004], [1.0f32, 1.0, 0.5]);
        let b = [0.0f32, 0.25, 1.0];
        // values: beauty (3), two AOVs splitting it 30/70 (3 + 3), alpha (1)
        let c = 10;
        let mut v = Vec::new();
        for xk in x {
            v.extend([xk; 3]);
            v.extend([0.3 * xk; 3]);
            v.extend([0.7 * xk; 3]);
            v.push(0.9);
        }
        let values = Tensor::from_data(TensorData::new(v, [1, 3, c, 1, 1]), &Device::default());
        let blend = GuideBlend::new(&features(&x, &g), beta(&b), &GUIDED, vec![0, 3, 6], c);
        let out = vals(blend.apply(values));
        for k in 0..3 {
            let f = &out[k * c..(k + 1) * c];
            let want = if x[k] >= GUIDE_BLEND_EPS {
                (1.0 - b[k]) * x[k] + b[k] * g[k]
            } else {
                // below ε the guide enters in proportion to the colour
                (1.0 - b[k]) * x[k] + b[k] * g[k] * x[k] / GUIDE_BLEND_EPS
            };
            assert!(
                (f[0] - want).abs() < 1e-5 * want.max(1.0),
                "frame {k}: {} vs {want}",
                f[0]
            );
            for ch in 0..3 {
                assert!((f[3 + ch] + f[6 + ch] - f[ch]).abs() < 1e-6, "AOVs sum");
            }
            assert_eq!(f[9], 0.9, "alpha is not blended");
        }
    }
}
