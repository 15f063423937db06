//! Albedo demodulation around kernel application: the kernels filter `colour ÷ (albedo + ε)`
//! and the result is multiplied back by the centre frame's `albedo + ε`. A kernel that averages
//! across a texture edge then still returns the texture, which a small network on a CPU budget
//! otherwise blurs away (thin geometry, fur, printed patterns).
//!
//! The albedo comes from the network's own input features (channels 3..6 of every frame, the
//! warped and clamped albedo), so training and inference demodulate identically. The map is
//! linear per pixel, so AOVs that sum to the beauty still sum to the denoised beauty.

use burn::tensor::Tensor;

use crate::model::Prediction;

/// First albedo channel in a frame's input features (after log colour).
const ALBEDO: usize = 3;

/// The per-frame modulation `albedo + ε` of a window's features `[B, T, C, H, W]`:
/// `[B, T, 3, H, W]`.
pub fn albedo_factor(features: &Tensor<5>, eps: f32) -> Tensor<5> {
    features.clone().narrow(2, ALBEDO, 3).clamp_min(0.0) + eps
}

/// Demodulation of a window's values `[B, T, C, H, W]`: the channel groups listed in `rgb`
/// (offsets of 3-channel signals: colour, RGB AOVs) are divided by the frame's `albedo + ε`;
/// every other channel (alpha, single-channel AOVs) passes unchanged.
#[derive(Clone, Debug)]
pub struct Demodulation {
    /// `albedo + ε` per frame, `[B, T, 3, H, W]`.
    factor: Tensor<5>,
    /// Channel offsets of the 3-channel groups that are modulated by albedo.
    rgb: Vec<usize>,
    /// Channels of the values.
    channels: usize,
}

impl Demodulation {
    /// Demodulation with ε of the channel groups at `rgb` for a window with `features`.
    pub fn new(features: &Tensor<5>, eps: f32, rgb: Vec<usize>, channels: usize) -> Self {
        assert!(
            rgb.iter().all(|&o| o + 3 <= channels),
            "every modulated group must fit in the values' channels"
        );
        Self {
            factor: albedo_factor(features, eps),
            rgb,
            channels,
        }
    }

    /// The factor over all value channels `[B, T, channels, H, W]` (1 outside the RGB groups).
    fn full_factor(&self, frames: std::ops::Range<usize>) -> Tensor<5> {
        let f = self.factor.clone().narrow(1, frames.start, frames.len());
        over_rgb_groups(f, &self.rgb, self.channels)
    }

    /// The values `[B, T, channels, H, W]` with the RGB groups divided by their frame's albedo.
    pub fn demodulate(&self, values: Tensor<5>) -> Tensor<5> {
        let t = values.dims()[1];
        values / self.full_factor(0..t)
    }

    /// Filtered values `[B, channels, H, W]` back to radiance: the RGB groups multiplied by the
    /// centre frame's albedo.
    pub fn remodulate(&self, filtered: Tensor<4>) -> Tensor<4> {
        let t = self.factor.dims()[1];
        let [b, c, h, w] = filtered.dims();
        filtered * self.full_factor(t / 2..t / 2 + 1).reshape([b, c, h, w])
    }
}

/// A per-frame RGB factor `[B, T, 3, H, W]` over all `channels` of a window's values: the
/// factor on each 3-channel group at the offsets `rgb`, 1 on every other channel (alpha,
/// single-channel AOVs). Demodulation and the guide blend scale the values with it.
pub(crate) fn over_rgb_groups(f: Tensor<5>, rgb: &[usize], channels: usize) -> Tensor<5> {
    let [b, t, _, h, w] = f.dims();
    let ones = |n: usize| Tensor::<5>::ones([b, t, n, h, w], &f.device());
    let mut parts = Vec::new();
    let mut at = 0;
    let mut groups = rgb.to_vec();
    groups.sort_unstable();
    for o in groups {
        if o > at {
            parts.push(ones(o - at));
        }
        parts.push(f.clone());
        at = o + 3;
    }
    if at < channels {
        parts.push(ones(channels - at));
    }
    Tensor::cat(parts, 2)
}

/// The prediction's kernels applied to `values` `[B, T, C, H, W]`, through `demod` when the
/// network demodulates: the one place inference and validation filter a window.
pub fn filter(pred: &Prediction, values: Tensor<5>, demod: Option<&Demodulation>) -> Tensor<4> {
    match demod {
        Some(d) => d.remodulate(pred.apply(d.demodulate(values))),
        None => pred.apply(values),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::config::INPUT_CHANNELS;
    use crate::model::kernel::Kernels;
    use burn::tensor::{Device, TensorData};

    fn tensor5(v: Vec<f32>, dims: [usize; 5]) -> Tensor<5> {
        Tensor::from_data(TensorData::new(v, dims), &Device::default())
    }

    /// Features whose albedo is `albedo(frame, x)` on a 1×w strip.
    fn features(t: usize, w: usize, albedo: impl Fn(usize, usize) -> f32) -> Tensor<5> {
        let mut v = Vec::new();
        for f in 0..t {
            for c in 0..INPUT_CHANNELS {
                for x in 0..w {
                    v.push(if (ALBEDO..ALBEDO + 3).contains(&c) {
                        albedo(f, x)
                    } else {
                        0.5
                    });
                }
            }
        }
        tensor5(v, [1, t, INPUT_CHANNELS, 1, w])
    }

    #[test]
    fn a_box_average_over_a_texture_edge_keeps_the_texture() {
        // constant lighting 2.0 on a texture alternating albedo 0.2 / 0.8: a plain 3-tap box
        // average blurs the texture; demodulated, it returns it (up to the ε offset)
        let (t, w) = (1, 6);
        let albedo = |_: usize, x: usize| if x.is_multiple_of(2) { 0.2 } else { 0.8 };
        let feats = features(t, w, albedo);
        let colour: Vec<f32> = (0..3)
            .flat_map(|_| (0..w).map(move |x| 2.0 * albedo(0, x)))
            .collect();
        let values = tensor5(colour.clone(), [1, t, 3, 1, w]);
        let kernels = Kernels {
            weights: Tensor::from_data(
                TensorData::new(
                    (0..9)
                        .flat_map(|_| vec![1.0 / 9.0; w])
                        .collect::<Vec<f32>>(),
                    [1, 9, 1, w],
                ),
                &Device::default(),
            ),
            frames: 1,
            size: 3,
        };
        let d = Demodulation::new(&feats, 0.01, vec![0], 3);
        let out = d.remodulate(kernels.apply(d.demodulate(values.clone())));
        let got = out.to_data().try_to_vec::<f32>().unwrap();
        for x in 1..w - 1 {
            let rel = (got[x] - colour[x]).abs() / colour[x];
            assert!(rel < 0.03, "x {x}: {} for {}", got[x], colour[x]);
        }
        let plain = kernels.apply(values).to_data().try_to_vec::<f32>().unwrap();
        let rel = (plain[2] - colour[2]).abs() / colour[2];
        assert!(rel > 1.0, "the plain average blurs: {}", plain[2]);
    }

    #[test]
    fn only_rgb_groups_are_modulated_and_the_centre_frame_restores() {
        // values: colour (0..3), a 1-channel AOV (3), an RGB AOV (4..7), alpha (7)
        let (t, w, c) = (3, 2, 8);
        let feats = features(t, w, |f, _| 0.5 + f as f32); // albedo 0.5, 1.5, 2.5
        let values = tensor5(vec![1.0; t * c * w], [1, t, c, 1, w]);
        let d = Demodulation::new(&feats, 0.5, vec![0, 4], c);
        let dm = d.demodulate(values).to_data().try_to_vec::<f32>().unwrap();
        let at = |f: usize, ch: usize| dm[(f * c + ch) * w];
        assert_eq!(at(0, 0), 1.0 / 1.0);
        assert_eq!(at(1, 5), 1.0 / 2.0);
        assert_eq!(at(2, 6), 1.0 / 3.0);
        assert_eq!(at(1, 3), 1.0);
        assert_eq!(at(2, 7), 1.0);
        let back = d
            .remodulate(Tensor::ones([1, c, 1, w], &Device::default()))
            .to_data()
            .try_to_vec::<f32>()
            .unwrap();
        // the centre frame (1) has albedo 1.5: ×2.0 on RGB groups, ×1 elsewhere
        let expect = [2.0, 2.0, 2.0, 1.0, 2.0, 2.0, 2.0, 1.0];
        for (ch, e) in expect.iter().enumerate() {
            assert_eq!(back[ch * w], *e, "channel {ch}");
        }
    }
}
