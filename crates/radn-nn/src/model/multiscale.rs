//! Multi-scale kernel reconstruction (Vogels et al. 2018, section 4.3): kernels predicted at
//! full, 1/2, 1/4 … resolution are applied to the window downsampled to that resolution (2×2
//! box averages), and the filtered images are combined coarse to fine. At scale `s`, with
//! `f_s` the scale's filtered image, `o_{s+1}` the combined result of the coarser scales, `D`
//! the 2×2 box downsampling and `U` its nearest-neighbour upsampling:
//!
//! `o_s = f_s + α_s · (U(o_{s+1}) − U(D(f_s)))`
//!
//! i.e. the low frequencies of the fine result are replaced by the coarser result where the
//! predicted blend weight `α_s ∈ [0, 1]` says so. A 5×5 kernel at 1/4 resolution reaches 20 px
//! at the cost of a full-resolution 5×5 kernel over 1/16 of the pixels.
//!
//! Every step is linear in the filtered values (the kernels and blend weights depend only on
//! the network's features), so AOVs that sum to the beauty still do, alpha and albedo
//! demodulation stay exact, and with `α = 0` everywhere the result is exactly the finest
//! scale's kernels. Sizes that are not multiples of 2^(scales − 1) are padded at the right and
//! bottom by repeating the edge, and the result is cropped back.

use burn::tensor::module::avg_pool2d;
use burn::tensor::ops::{AvgPoolOptions, PadMode};
use burn::tensor::{Tensor, TensorData};

use crate::model::cpu::is_cpu_inference;
use crate::model::cpu::pool::box_downsample;

use crate::model::kernel::Kernels;

/// Kernels at several scales and the blend weights that combine them.
#[derive(Clone, Debug)]
pub struct MultiScaleKernels {
    /// Kernels per scale, finest first; scale `s` works on the (padded) window downsampled by
    /// 2^s.
    pub scales: Vec<Kernels>,
    /// Blend weights `α_s` `[B, 1, H_s, W_s]` in 0..=1 for every scale but the coarsest.
    pub blend: Vec<Tensor<4>>,
    /// The unpadded output size (h, w).
    pub size: (usize, usize),
}

/// The 2×2 box average of `[N, C, H, W]` (H and W even).
pub fn downsample(x: Tensor<4>) -> Tensor<4> {
    let device = x.device();
    let [n, c, h, w] = x.dims();
    if is_cpu_inference(&device) && h % 2 == 0 && w % 2 == 0 {
        let data = x.into_data();
        let out = box_downsample(data.as_slice::<f32>().expect("f32 maps"), [n * c, h, w]);
        return Tensor::from_data(TensorData::new(out, [n, c, h / 2, w / 2]), &device);
    }
    avg_pool2d(x, AvgPoolOptions::new([2, 2]))
}

/// Nearest-neighbour upsampling by 2 of `[N, C, H, W]`: each value fills a 2×2 block, so
/// `downsample(upsample(x)) == x`.
pub fn upsample(x: Tensor<4>) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    x.reshape([n, c, h, 1, w, 1])
        .expand([n, c, h, 2, w, 2])
        .reshape([n, c, 2 * h, 2 * w])
}

/// The size `(h, w)` padded up to a multiple of 2^(scales − 1).
pub fn padded_size(h: usize, w: usize, scales: usize) -> (usize, usize) {
    let m = 1 << (scales.max(1) - 1);
    (h.div_ceil(m) * m, w.div_ceil(m) * m)
}

/// Pads `[N, C, H, W]` at the right and bottom to `(ph, pw)` by repeating the edge.
pub fn pad_to(x: Tensor<4>, ph: usize, pw: usize) -> Tensor<4> {
    let [_, _, h, w] = x.dims();
    if h == ph && w == pw {
        return x;
    }
    x.pad((0, pw - w, 0, ph - h), PadMode::Edge)
}

impl MultiScaleKernels {
    /// Applies the kernels to the window's values `[B, T, C, H, W]` (linear, warped, at the
    /// unpadded size): `[B, C, H, W]`.
    pub fn apply(&self, values: Tensor<5>) -> Tensor<4> {
        let [b, t, c, h, w] = values.dims();
        assert_eq!((h, w), self.size, "values must have the kernels' size");
        let [_, _, ph, pw] = self.scales[0].weights.dims();
        let mut level = pad_to(values.reshape([b * t, c, h, w]), ph, pw);
        let mut filtered = Vec::with_capacity(self.scales.len());
        for (s, k) in self.scales.iter().enumerate() {
            if s > 0 {
                level = downsample(level);
            }
            let [_, _, hs, ws] = level.dims();
            filtered.push(k.apply(level.clone().reshape([b, t, c, hs, ws])));
        }
        self.combine(filtered).slice([0..b, 0..c, 0..h, 0..w])
    }

    /// The coarse-to-fine combination of per-scale images (each `[B, C, H_s, W_s]`, padded).
    fn combine(&self, filtered: Vec<Tensor<4>>) -> Tensor<4> {
        let mut it = filtered.into_iter().rev();
        let mut out = it.next().expect("at least one scale");
        for (f, alpha) in it.zip(self.blend.iter().rev()) {
            let low = upsample(downsample(f.clone()));
            out = f + alpha.clone() * (upsample(out) - low);
        }
        out
    }

    /// Every scale's kernels restricted to a subset of the window's frames, renormalised
    /// (paper section 5); the blend weights are kept.
    pub fn subset(&self, mask: &[bool]) -> MultiScaleKernels {
        MultiScaleKernels {
            scales: self.scales.iter().map(|k| k.subset(mask)).collect(),
            blend: self.blend.clone(),
            size: self.size,
        }
    }

    /// Per-pixel weight of each frame in the combined result `[B, T, H, W]`: each scale's
    /// frame mass, combined like the images (a frame's share is a linear functional too).
    pub fn frame_mass(&self) -> Tensor<4> {
        let masses: Vec<Tensor<4>> = self.scales.iter().map(|k| k.frame_mass()).collect();
        let [b, t, _, _] = masses[0].dims();
        let (h, w) = self.size;
        self.combine(masses).slice([0..b, 0..t, 0..h, 0..w])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, TensorData};

    fn t4(v: Vec<f32>, shape: [usize; 4]) -> Tensor<4> {
        Tensor::from_data(TensorData::new(v, shape), &Device::flex())
    }

    fn vals<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.to_data().try_to_vec::<f32>().unwrap()
    }

    #[test]
    fn the_cpu_box_average_equals_burns_pooling() {
        let (n, c, h, w) = (3, 5, 10, 14);
        let v: Vec<f32> = (0..n * c * h * w)
            .map(|i| ((i * 7919) % 977) as f32 / 97.0 - 4.0)
            .collect();
        let x = t4(v, [n, c, h, w]);
        let cpu = vals(downsample(x.clone()));
        let burn = vals(avg_pool2d(x, AvgPoolOptions::new([2, 2])));
        assert_eq!(cpu.len(), n * c * (h / 2) * (w / 2));
        let worst = cpu
            .iter()
            .zip(&burn)
            .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst < 1e-5, "worst difference {worst}");
    }

    #[test]
    fn upsampling_repeats_blocks_and_downsampling_undoes_it() {
        let x = t4(vec![1.0, 2.0, 3.0, 4.0], [1, 1, 2, 2]);
        let up = upsample(x.clone());
        assert_eq!(up.dims(), [1, 1, 4, 4]);
        assert_eq!(
            vals(up.clone()),
            vec![1., 1., 2., 2., 1., 1., 2., 2., 3., 3., 4., 4., 3., 3., 4., 4.]
        );
        assert_eq!(vals(downsample(up)), vals(x));
        assert_eq!(padded_size(13, 16, 3), (16, 16));
        let p = pad_to(t4(vec![1.0, 2.0], [1, 1, 1, 2]), 2, 4);
        assert_eq!(vals(p), vec![1., 2., 2., 2., 1., 2., 2., 2.]);
    }

    fn det(seed: usize, n: usize) -> Vec<f32> {
        (0..n)
            .map(|i| (((i + 7 * seed) * 2654435761usize) % 1000) as f32 / 1000.0)
            .collect()
    }

    /// Random normalised kernels (5×5×3) at 3 scales of a 12×10 window and random blend
    /// weights.
    fn kernels(alpha: Option<f32>) -> MultiScaleKernels {
        let (t, k, h, w) = (3, 5, 12, 8);
        let scales = (0..3)
            .map(|s| {
                let (hs, ws) = (h >> s, w >> s);
                let raw = t4(det(s + 1, t * k * k * hs * ws), [1, t * k * k, hs, ws]);
                let sum = raw.clone().sum_dim(1);
                Kernels {
                    weights: raw / sum,
                    frames: t,
                    size: k,
                }
            })
            .collect();
        let blend = (0..2)
            .map(|s| {
                let (hs, ws) = (h >> s, w >> s);
                match alpha {
                    Some(a) => Tensor::full([1, 1, hs, ws], a, &Device::flex()),
                    None => t4(det(s + 9, hs * ws), [1, 1, hs, ws]),
                }
            })
            .collect();
        MultiScaleKernels {
            scales,
            blend,
            size: (11, 7),
        }
    }

    fn values(seed: usize, c: usize) -> Tensor<5> {
        Tensor::from_data(
            TensorData::new(det(seed, 3 * c * 11 * 7), [1, 3, c, 11, 7]),
            &Device::flex(),
        )
    }

    #[test]
    fn with_all_weight_on_the_finest_scale_it_is_exactly_the_finest_kernels() {
        let m = kernels(Some(0.0));
        let v = values(3, 3);
        let got = vals(m.apply(v.clone()));
        // the finest kernels alone, on the same edge-padded window, cropped
        let padded = pad_to(v.clone().reshape([3, 3, 11, 7]), 12, 8).reshape([1, 3, 3, 12, 8]);
        let want = vals(m.scales[0].apply(padded).slice([0..1, 0..3, 0..11, 0..7]));
        assert_eq!(got, want);
        // and the blend does change the result when it is not zero
        let other = vals(kernels(Some(0.7)).apply(v));
        assert!(got.iter().zip(&other).any(|(a, b)| (a - b).abs() > 1e-3));
    }

    #[test]
    fn linear_in_the_values_constant_preserving_and_frame_shares_sum_to_one() {
        let m = kernels(None);
        let (a, b) = (values(1, 3), values(2, 3));
        let sum = vals(m.apply(a.clone() + b.clone()));
        let parts: Vec<f32> = vals(m.apply(a))
            .iter()
            .zip(vals(m.apply(b)))
            .map(|(x, y)| x + y)
            .collect();
        for (s, p) in sum.iter().zip(&parts) {
            assert!((s - p).abs() < 1e-5, "{s} vs {p}");
        }
        // alpha of 1 everywhere stays 1: every scale's kernels sum to 1 and the combination
        // keeps constants
        let ones = Tensor::<5>::ones([1, 3, 1, 11, 7], &Device::flex());
        for v in vals(m.apply(ones)) {
            assert!((v - 1.0).abs() < 1e-5, "{v}");
        }
        let mass = m.frame_mass();
        assert_eq!(mass.dims(), [1, 3, 11, 7]);
        for v in vals(mass.sum_dim(1)) {
            assert!((v - 1.0).abs() < 1e-5, "{v}");
        }
    }

    #[test]
    fn the_subset_of_every_scale_is_renormalised() {
        let m = kernels(None).subset(&[false, true, false]);
        let mass = m.frame_mass();
        let v = vals(mass);
        let px = 11 * 7;
        assert!(v[..px].iter().chain(&v[2 * px..]).all(|x| x.abs() < 1e-6));
        assert!(v[px..2 * px].iter().all(|x| (x - 1.0).abs() < 1e-5));
    }
}
