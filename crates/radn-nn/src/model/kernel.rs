//! Kernel prediction's tensor side: the thresholded activation η_t with its identity fallback
//! (paper section 4), frame-subset renormalisation (the building block of the loss conversion,
//! paper section 5), and applying kernels to the warped frames' linear values — colour, AOVs,
//! alpha alike.

use burn::tensor::activation::softmax;
use burn::tensor::module::unfold4d;
use burn::tensor::ops::{PadMode, UnfoldOptions};
use burn::tensor::{Tensor, TensorData};

use crate::model::cpu::apply::apply_kernels;
use crate::model::cpu::is_cpu_inference;

use crate::model::config::Activation;

/// Normalised per-pixel kernels over a window: `[batch, frames · k², H, W]`, frame-major
/// (frame 0's k² taps first), each pixel's weights summing to 1.
#[derive(Clone, Debug)]
pub struct Kernels {
    /// The weights.
    pub weights: Tensor<4>,
    /// Frames covered (the window's, or 1 for a spatial kernel).
    pub frames: usize,
    /// Spatial size k.
    pub size: usize,
}

/// The activation of paper eq. 3 over dimension 1 of raw weights `[B, K, H, W]`:
/// `max(0, w − t) / Σ max(0, w − t)`; where every weight is at most `t` the kernel becomes the
/// identity (all weight on tap `identity_tap`). With [`Activation::SoftmaxEta`] a softmax
/// normalises the raw weights first; with [`Activation::NormEta`] their positive part divided
/// by its sum (a pixel whose raw weights are all ≤ 0 gets the identity).
pub fn eta(raw: Tensor<4>, t: f32, activation: Activation, identity_tap: usize) -> Tensor<4> {
    let device = raw.device();
    if is_cpu_inference(&device) {
        let dims = raw.dims();
        let data = raw.into_data();
        let out = crate::model::cpu::eta::eta(
            data.as_slice::<f32>().expect("f32 raw weights"),
            dims,
            t,
            activation,
            identity_tap,
        );
        return Tensor::from_data(TensorData::new(out, dims), &device);
    }
    eta_with_burn(raw, t, activation, identity_tap)
}

/// [`eta`] as burn operations (training, other backends).
fn eta_with_burn(raw: Tensor<4>, t: f32, activation: Activation, identity_tap: usize) -> Tensor<4> {
    let w = match activation {
        Activation::Eta => raw,
        Activation::SoftmaxEta => softmax(raw, 1),
        Activation::NormEta => {
            let positive = raw.clamp_min(0.0);
            let sum = positive.clone().sum_dim(1).clamp_min(1e-12);
            positive / sum
        }
    };
    let [b, k, h, wd] = w.dims();
    let kept = (w - t).clamp_min(0.0);
    let sum = kept.clone().sum_dim(1); // [B, 1, H, W]
    let empty = sum.clone().lower_equal_elem(0.0);
    let normalised = kept / sum.clamp_min(1e-12);
    let device = normalised.device();
    let identity = one_hot(k, identity_tap, &device)
        .reshape([1, k, 1, 1])
        .expand([b, k, h, wd]);
    normalised.mask_where(empty.expand([b, k, h, wd]), identity)
}

/// A `[K]` vector with a single 1 at `index`.
fn one_hot(k: usize, index: usize, device: &burn::tensor::Device) -> Tensor<1> {
    let mut v = vec![0.0f32; k];
    v[index] = 1.0;
    Tensor::from_floats(v.as_slice(), device)
}

impl Kernels {
    /// Taps per frame (k²).
    pub fn taps(&self) -> usize {
        self.size * self.size
    }

    /// Keeps only the frames where `mask` is true and renormalises each pixel's kernel over
    /// them. Pixels whose kernel had no weight on the kept frames fall back to the plain mean of
    /// the kept frames' centre taps.
    pub fn subset(&self, mask: &[bool]) -> Kernels {
        assert_eq!(mask.len(), self.frames, "one mask entry per frame");
        let [b, _, h, w] = self.weights.dims();
        let k2 = self.taps();
        let device = self.weights.device();
        let m: Vec<f32> = mask
            .iter()
            .flat_map(|&keep| std::iter::repeat_n(if keep { 1.0 } else { 0.0 }, k2))
            .collect();
        let m =
            Tensor::<1>::from_floats(m.as_slice(), &device).reshape([1, self.frames * k2, 1, 1]);
        let kept = self.weights.clone() * m;
        let sum = kept.clone().sum_dim(1);
        let empty = sum.clone().lower_equal_elem(1e-12);
        let normalised = kept / sum.clamp_min(1e-12);
        let n = mask.iter().filter(|&&k| k).count().max(1) as f32;
        let fallback: Vec<f32> = mask
            .iter()
            .flat_map(|&keep| {
                (0..k2).map(move |tap| if keep && tap == k2 / 2 { 1.0 / n } else { 0.0 })
            })
            .collect();
        let fallback = Tensor::<1>::from_floats(fallback.as_slice(), &device)
            .reshape([1, self.frames * k2, 1, 1])
            .expand([b, self.frames * k2, h, w]);
        Kernels {
            weights: normalised.mask_where(empty.expand([b, self.frames * k2, h, w]), fallback),
            frames: self.frames,
            size: self.size,
        }
    }

    /// Applies the kernels to the frames' values `[B, frames, C, H, W]` (linear, warped):
    /// a dot product with each pixel's k×k×frames neighbourhood. Beyond the image the edge
    /// pixels repeat (zero padding would darken the border). Returns `[B, C, H, W]`.
    pub fn apply(&self, values: Tensor<5>) -> Tensor<4> {
        let [b, t, c, h, w] = values.dims();
        assert_eq!(
            t, self.frames,
            "values must have one slice per kernel frame"
        );
        let k = self.size;
        let device = values.device();
        if is_cpu_inference(&device) {
            let weights = self.weights.clone().into_data();
            let values = values.into_data();
            let out = apply_kernels(
                weights.as_slice::<f32>().expect("f32 kernel weights"),
                values.as_slice::<f32>().expect("f32 values"),
                [b, t, c, h, w],
                k,
            );
            return Tensor::from_data(TensorData::new(out, [b, c, h, w]), &device);
        }
        let k2 = k * k;
        let pad = k / 2;
        let padded = values
            .reshape([b * t, c, h, w])
            .pad((pad, pad, pad, pad), PadMode::Edge);
        let patches = unfold4d(padded, [k, k], UnfoldOptions::new([1, 1], [0, 0], [1, 1]));
        // [B·T, C·k², H·W] → [B, T, C, k², H·W]
        let patches = patches.reshape([b, t, c, k2, h * w]);
        let weights = self.weights.clone().reshape([b, t, 1, k2, h * w]);
        (patches * weights)
            .sum_dim(3)
            .sum_dim(1)
            .reshape([b, c, h, w])
    }

    /// Total weight of each frame per pixel: `[B, frames, H, W]` (the temporal utilisation of
    /// paper Table 1 and Fig. 6).
    pub fn frame_mass(&self) -> Tensor<4> {
        let [b, _, h, w] = self.weights.dims();
        self.weights
            .clone()
            .reshape([b, self.frames, self.taps(), h * w])
            .sum_dim(2)
            .reshape([b, self.frames, h, w])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, TensorData};

    fn dev() -> Device {
        Device::flex()
    }

    fn vals(t: &Tensor<4>) -> Vec<f32> {
        t.to_data().try_to_vec::<f32>().unwrap()
    }

    fn raw(v: Vec<f32>, k: usize) -> Tensor<4> {
        Tensor::from_data(TensorData::new(v, [1, k, 1, 1]), &dev())
    }

    #[test]
    fn the_cpu_activation_equals_burns_for_every_activation_and_threshold() {
        let device = Device::flex();
        let (b, k, h, w) = (2, 25, 7, 300); // a block boundary inside each image
        let raw: Vec<f32> = (0..b * k * h * w)
            .map(|i| ((i * 7919) % 1009) as f32 / 500.0 - 1.2)
            .collect();
        for activation in [Activation::Eta, Activation::SoftmaxEta, Activation::NormEta] {
            for t in [0.0, 0.02, 0.3] {
                let x = Tensor::<4>::from_data(TensorData::new(raw.clone(), [b, k, h, w]), &device);
                let got = eta(x.clone(), t, activation, 12)
                    .into_data()
                    .try_into_vec::<f32>()
                    .unwrap();
                let want = eta_with_burn(x, t, activation, 12)
                    .into_data()
                    .try_into_vec::<f32>()
                    .unwrap();
                let worst = got
                    .iter()
                    .zip(&want)
                    .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
                assert!(
                    worst < 1e-5,
                    "{activation:?} t={t}: worst difference {worst}"
                );
                // some pixels fall back to the identity at the largest threshold
                if t == 0.3 && activation != Activation::Eta {
                    assert!(want.contains(&1.0));
                }
            }
        }
    }

    #[test]
    fn eta_sums_to_one_zeroes_below_t_and_falls_back_to_identity() {
        let k = 6;
        let out = vals(&eta(
            raw(vec![0.5, 0.1, 0.05, 0.3, -1.0, 0.2], k),
            0.15,
            Activation::Eta,
            0,
        ));
        assert!((out.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        // below t: exactly zero
        assert_eq!(out[1], 0.0);
        assert_eq!(out[2], 0.0);
        assert_eq!(out[4], 0.0);
        // above t: proportional to w − t
        assert!((out[0] - 0.35 / 0.55).abs() < 1e-6 && (out[3] - 0.15 / 0.55).abs() < 1e-6);
        // everything below t: the identity tap
        let id = vals(&eta(
            raw(vec![0.1, 0.0, -0.3, 0.05, 0.1, 0.12], k),
            0.15,
            Activation::Eta,
            3,
        ));
        assert_eq!(id, vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn raising_t_never_adds_weights() {
        let w: Vec<f32> = (0..125)
            .map(|i| ((i * 37 % 101) as f32 / 101.0) * 0.02)
            .collect();
        for act in [Activation::Eta, Activation::SoftmaxEta, Activation::NormEta] {
            let mut prev: Option<Vec<f32>> = None;
            for t in [0.0, 0.002, 0.004, 0.006, 0.008] {
                let out = vals(&eta(raw(w.clone(), 125), t, act, 62));
                assert!((out.iter().sum::<f32>() - 1.0).abs() < 1e-5);
                if let Some(p) = &prev {
                    for (a, b) in p.iter().zip(&out) {
                        assert!(!(*a == 0.0 && *b > 0.0), "t = {t} turned a weight on");
                    }
                }
                prev = Some(out);
            }
        }
    }

    #[test]
    fn the_normalised_eta_is_scale_free_keeps_uniform_kernels_and_falls_back_to_identity() {
        let k = 125;
        let w: Vec<f32> = (0..k)
            .map(|i| ((i * 37 % 101) as f32 / 101.0) * 0.02 + 0.001)
            .collect();
        let t = 1.0 / (2.0 * k as f32);
        let a = vals(&eta(raw(w.clone(), k), t, Activation::NormEta, 62));
        // the raw weights' scale does not matter: ×40 gives the same kernel
        let scaled: Vec<f32> = w.iter().map(|v| v * 40.0).collect();
        let b = vals(&eta(raw(scaled, k), t, Activation::NormEta, 62));
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 1e-6, "{x} vs {y}");
        }
        // on the normalised weights p = w / Σw: zero below t, proportional to p − t above
        let sum: f32 = w.iter().sum();
        let kept: f32 = w.iter().map(|v| (v / sum - t).max(0.0)).sum();
        for (out, v) in a.iter().zip(&w) {
            let p = v / sum;
            let want = if p <= t { 0.0 } else { (p - t) / kept };
            assert!((out - want).abs() < 1e-6, "{out} vs {want}");
        }
        // a uniform kernel stays uniform at every allowed threshold, whatever its scale
        for t in [0.0, 0.004, 0.0075, 0.99 / k as f32] {
            let u = vals(&eta(raw(vec![3.0; k], k), t, Activation::NormEta, 62));
            assert!(
                u.iter().all(|v| (v - 1.0 / k as f32).abs() < 1e-6),
                "t = {t}"
            );
        }
        // no positive raw weight: the identity tap
        let id = vals(&eta(
            raw(vec![-0.1, 0.0, -0.3, -0.05, 0.0, -0.2], 6),
            0.0,
            Activation::NormEta,
            2,
        ));
        assert_eq!(id, vec![0.0, 0.0, 1.0, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn equal_raw_weights_give_a_box_filter() {
        let out = vals(&eta(
            raw(vec![0.016; 125], 125),
            1.0 / 250.0,
            Activation::Eta,
            62,
        ));
        assert!(out.iter().all(|v| (v - 1.0 / 125.0).abs() < 1e-6));
    }

    #[test]
    fn one_hot_kernels_reproduce_shifted_inputs_exactly() {
        let (h, w, t, c) = (6usize, 7usize, 3usize, 2usize);
        let data: Vec<f32> = (0..t * c * h * w)
            .map(|i| (i as f32 * 0.37).sin())
            .collect();
        let values = Tensor::<5>::from_data(TensorData::new(data.clone(), [1, t, c, h, w]), &dev());
        // all weight on frame 2, tap (dy, dx) = (+1, −1): out(y, x) = frame2(y + 1, x − 1)
        let (frame, dy, dx) = (2usize, 1isize, -1isize);
        let tap = ((dy + 2) * 5 + (dx + 2)) as usize;
        let mut k = vec![0.0f32; t * 25 * h * w];
        for p in 0..h * w {
            k[(frame * 25 + tap) * h * w + p] = 1.0;
        }
        let kernels = Kernels {
            weights: Tensor::from_data(TensorData::new(k, [1, t * 25, h, w]), &dev()),
            frames: t,
            size: 5,
        };
        let out = kernels.apply(values).to_data().try_to_vec::<f32>().unwrap();
        for ch in 0..c {
            for y in 0..h {
                for x in 0..w {
                    // beyond the image the edge repeats
                    let sy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
                    let sx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
                    let want = data[((frame * c + ch) * h + sy) * w + sx];
                    assert_eq!(out[(ch * h + y) * w + x], want, "({ch},{y},{x})");
                }
            }
        }
    }

    #[test]
    fn frame_subsets_renormalise() {
        // 3 frames, 1×1 kernels: weights (0.5, 0.3, 0.2)
        let k = Kernels {
            weights: raw(vec![0.5, 0.3, 0.2], 3),
            frames: 3,
            size: 1,
        };
        let s = vals(&k.subset(&[true, false, true]).weights);
        assert!((s[0] - 0.5 / 0.7).abs() < 1e-6 && s[1] == 0.0 && (s[2] - 0.2 / 0.7).abs() < 1e-6);
        // a subset the kernel put no weight on falls back to the mean of its centre taps
        let k = Kernels {
            weights: raw(vec![0.0, 1.0, 0.0], 3),
            frames: 3,
            size: 1,
        };
        let s = vals(&k.subset(&[true, false, true]).weights);
        assert_eq!(s, vec![0.5, 0.0, 0.5]);
        let m = vals(
            &Kernels {
                weights: raw(vec![0.5, 0.3, 0.2], 3),
                frames: 3,
                size: 1,
            }
            .frame_mass(),
        );
        assert_eq!(m, vec![0.5, 0.3, 0.2]);
    }
}
