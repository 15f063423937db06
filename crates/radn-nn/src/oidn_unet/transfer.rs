//! OIDN's input and output processing around its U-Net: how each input image is sanitised and
//! mapped into the range the network was trained on, and how its output is mapped back. The
//! HDR beauty is scaled by the input scale (OIDN's autoexposure unless given) and passed
//! through the "PU" curve normalised by its value at 65504; an LDR beauty and the albedo
//! prefilter's input through sRGB; normals are clamped to [−1, 1] and mapped by ×0.5 + 0.5.
//! NaN becomes 0 everywhere. The curves' constants are OIDN's (`core/color.h`), written as
//! OIDN writes them (the nearest f32 is what both use).

use burn::tensor::Tensor;

/// A transfer function between linear values and the network's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Transfer {
    /// None (normals).
    Linear,
    /// sRGB (LDR beauties, the albedo prefilter).
    Srgb,
    /// OIDN's perceptual-uniform curve, normalised to 1 at the largest half float (HDR).
    Pu,
}

/// The largest HDR value the PU curve is normalised at.
const Y_MAX: f32 = 65504.0;

#[allow(clippy::excessive_precision)]
mod pu {
    pub const A: f32 = 1.412_837_6e3;
    pub const B: f32 = 1.645_931_7;
    pub const C: f32 = 4.313_849_8e-1;
    pub const D: f32 = -2.941_396_1e-3;
    pub const E: f32 = 1.926_532_5e-1;
    pub const F: f32 = 6.260_261e-3;
    pub const G: f32 = 9.986_201_5e-1;
    pub const Y0: f32 = 1.579_457_6e-6;
    pub const Y1: f32 = 3.220_876_3e-2;
    pub const X0: f32 = 2.231_517_1e-3;
    pub const X1: f32 = 3.709_747_5e-1;
}

mod srgb {
    pub const A: f32 = 12.92;
    pub const B: f32 = 1.055;
    pub const C: f32 = 1.0 / 2.4;
    pub const D: f32 = -0.055;
    pub const Y0: f32 = 0.003_130_8;
    pub const X0: f32 = 0.040_45;
}

fn pu_forward(y: f32) -> f32 {
    use pu::*;
    if y <= Y0 {
        A * y
    } else if y <= Y1 {
        B * y.powf(C) + D
    } else {
        E * (y + F).ln() + G
    }
}

fn pu_inverse(x: f32) -> f32 {
    use pu::*;
    if x <= X0 {
        x / A
    } else if x <= X1 {
        ((x - D) / B).powf(1.0 / C)
    } else {
        ((x - G) / E).exp() - F
    }
}

/// PU(65504), the curve's normalisation (computed as OIDN does, in f32).
fn pu_norm() -> f32 {
    pu_forward(Y_MAX)
}

impl Transfer {
    /// Linear → network value.
    pub fn forward(self, y: f32) -> f32 {
        match self {
            Transfer::Linear => y,
            Transfer::Srgb => {
                use srgb::*;
                if y <= Y0 {
                    A * y
                } else {
                    B * y.powf(C) + D
                }
            }
            Transfer::Pu => pu_forward(y) * (1.0 / pu_norm()),
        }
    }

    /// Network value → linear.
    pub fn inverse(self, x: f32) -> f32 {
        match self {
            Transfer::Linear => x,
            Transfer::Srgb => {
                use srgb::*;
                if x <= X0 {
                    x / A
                } else {
                    ((x - D) / B).powf(1.0 / C)
                }
            }
            Transfer::Pu => pu_inverse(x * pu_norm()),
        }
    }
}

impl Transfer {
    /// [`Transfer::forward`] as tensor operations (differentiable) on values already
    /// sanitised (not NaN, within the transfer's range), for blends made in linear space.
    pub fn forward_tensor<const D: usize>(self, y: Tensor<D>) -> Tensor<D> {
        match self {
            Transfer::Linear => y,
            // each branch reads its argument clamped to its own range, so that the branches
            // not taken have finite gradients (a power's is infinite at zero)
            Transfer::Srgb => {
                use srgb::*;
                let low = y.clone() * A;
                let high = y.clone().clamp_min(Y0).powf_scalar(C) * B + D;
                high.mask_where(y.lower_equal_elem(Y0), low)
            }
            Transfer::Pu => {
                use pu::*;
                let low = y.clone() * A;
                let mid = y.clone().clamp(Y0, Y1).powf_scalar(C) * B + D;
                let high = (y.clone().clamp_min(Y1) + F).log() * E + G;
                high.mask_where(y.clone().lower_equal_elem(Y1), mid)
                    .mask_where(y.lower_equal_elem(Y0), low)
                    * (1.0 / pu_norm())
            }
        }
    }

    /// [`Transfer::inverse`] as tensor operations (differentiable), for losses in linear space.
    pub fn inverse_tensor(self, x: Tensor<4>) -> Tensor<4> {
        match self {
            Transfer::Linear => x,
            Transfer::Srgb => {
                use srgb::*;
                let low = x.clone() / A;
                let high = ((x.clone() - D) / B).clamp_min(0.0).powf_scalar(1.0 / C);
                high.mask_where(x.lower_equal_elem(X0), low)
            }
            Transfer::Pu => {
                use pu::*;
                let x = x * pu_norm();
                let low = x.clone() / A;
                let mid = ((x.clone() - D) / B).clamp_min(0.0).powf_scalar(1.0 / C);
                let high = ((x.clone() - G) / E).exp() - F;
                high.mask_where(x.clone().lower_equal_elem(X1), mid)
                    .mask_where(x.lower_equal_elem(X0), low)
            }
        }
    }
}

/// How one input image is prepared: its transfer, whether it is signed (normals) and whether
/// it is HDR (unbounded above) and scaled by the input scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Processing {
    /// The transfer function applied after sanitising.
    pub transfer: Transfer,
    /// Values in [−1, 1] mapped to [0, 1] (normals).
    pub signed: bool,
    /// Unbounded above and multiplied by the input scale (an HDR beauty).
    pub hdr: bool,
}

impl Processing {
    /// The network value of linear input `v` at input scale `scale`.
    pub fn input(self, v: f32, scale: f32) -> f32 {
        let v = if self.hdr { v * scale } else { v };
        let v = if v.is_nan() { 0.0 } else { v };
        let lo = if self.signed { -1.0 } else { 0.0 };
        let hi = if self.hdr { f32::MAX } else { 1.0 };
        let v = v.clamp(lo, hi);
        let v = if self.signed { v * 0.5 + 0.5 } else { v };
        self.transfer.forward(v)
    }

    /// The linear output of network value `x` at input scale `scale`.
    pub fn output(self, x: f32, scale: f32) -> f32 {
        let x = if x.is_nan() {
            0.0
        } else {
            x.clamp(0.0, f32::MAX)
        };
        let mut v = self.transfer.inverse(x);
        if self.signed {
            v = (v * 2.0 - 1.0).max(-1.0);
        }
        if !self.hdr {
            v = v.min(1.0);
        }
        let out_scale = if self.hdr && scale != 0.0 {
            1.0 / scale
        } else if self.hdr {
            0.0
        } else {
            1.0
        };
        v * out_scale
    }
}

/// An HDR beauty: scaled by the input scale, through the PU curve.
pub const HDR_BEAUTY: Processing = Processing {
    transfer: Transfer::Pu,
    signed: false,
    hdr: true,
};

/// Albedo beside a beauty: clamped to [0, 1], no transfer.
pub const AUX_ALBEDO: Processing = Processing {
    transfer: Transfer::Linear,
    signed: false,
    hdr: false,
};

/// Normal beside a beauty: clamped to [−1, 1] and mapped to [0, 1].
pub const AUX_NORMAL: Processing = Processing {
    transfer: Transfer::Linear,
    signed: true,
    hdr: false,
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tensor_inverse_is_the_scalar_inverse() {
        use burn::tensor::{Device, TensorData};
        let values: Vec<f32> = (0..400).map(|i| (i as f32 / 399.0).powi(3) * 1.2).collect();
        let device = Device::flex();
        for t in [Transfer::Linear, Transfer::Srgb, Transfer::Pu] {
            let x: Tensor<4> =
                Tensor::from_data(TensorData::new(values.clone(), [1, 1, 20, 20]), &device);
            let got = t.inverse_tensor(x).into_data().try_to_vec::<f32>().unwrap();
            for (&v, &g) in values.iter().zip(&got) {
                let want = t.inverse(v);
                assert!(
                    (g - want).abs() <= 1e-5 * want.abs().max(1.0),
                    "{t:?}({v}) = {want}, tensor {g}"
                );
            }
        }
    }

    #[test]
    fn the_tensor_forward_is_the_scalar_forward() {
        use burn::tensor::{Device, TensorData};
        let values: Vec<f32> = (0..400)
            .map(|i| (i as f32 / 399.0).powi(4) * 300.0)
            .collect();
        let device = Device::flex();
        for t in [Transfer::Linear, Transfer::Srgb, Transfer::Pu] {
            let y: Tensor<4> =
                Tensor::from_data(TensorData::new(values.clone(), [1, 1, 20, 20]), &device);
            let got = t.forward_tensor(y).into_data().try_to_vec::<f32>().unwrap();
            for (&v, &g) in values.iter().zip(&got) {
                let want = t.forward(v);
                assert!(
                    (g - want).abs() <= 1e-5 * want.abs().max(1e-3),
                    "{t:?}({v}) = {want}, tensor {g}"
                );
            }
        }
    }

    #[test]
    fn the_curves_invert_and_pu_reaches_one_at_the_largest_half() {
        for t in [Transfer::Linear, Transfer::Srgb, Transfer::Pu] {
            for &y in &[0.0, 1e-7, 1e-4, 0.01, 0.2, 0.5, 1.0] {
                let back = t.inverse(t.forward(y));
                assert!(
                    (back - y).abs() <= 1e-4 * y.max(1e-3),
                    "{t:?} {y} -> {back}"
                );
            }
        }
        assert!((Transfer::Pu.forward(65504.0) - 1.0).abs() < 1e-6);
        let hdr = Processing {
            transfer: Transfer::Pu,
            signed: false,
            hdr: true,
        };
        for &y in &[0.01f32, 3.0, 400.0] {
            let back = hdr.output(hdr.input(y, 0.5), 0.5);
            assert!((back - y).abs() < 1e-3 * y, "{y} -> {back}");
        }
        assert_eq!(hdr.input(f32::NAN, 1.0), 0.0);
        assert_eq!(hdr.input(-3.0, 1.0), 0.0);
        assert_eq!(AUX_NORMAL.input(-2.0, 1.0), 0.0);
        assert_eq!(AUX_NORMAL.input(1.0, 1.0), 1.0);
        assert_eq!(AUX_ALBEDO.input(1.5, 1.0), 1.0);
    }
}
