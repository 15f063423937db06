//! Image-quality and temporal-stability metrics against a reference.
//!
//! PSNR, SSIM and the temporal metrics are computed on tonemapped values
//! `t(x) = (x / (1 + x))^(1/2.2)` of the clamped-at-zero linear RGB, so HDR highlights do not
//! dominate; relMSE is computed on linear HDR values.

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::image::plane::Plane;

/// The largest PSNR reported (identical images would otherwise give infinity).
pub const PSNR_CAP: f64 = 100.0;

/// The tonemapping used by the perceptual metrics.
#[inline]
pub fn tonemap(x: f32) -> f32 {
    let x = x.max(0.0);
    (x / (1.0 + x)).powf(1.0 / 2.2)
}

/// Tonemaps every sample of a plane.
pub fn tonemap_plane(p: &Plane) -> Plane {
    let mut out = p.clone();
    out.data_mut().par_iter_mut().for_each(|v| *v = tonemap(*v));
    out
}

fn check(a: &Plane, b: &Plane, what: &str) -> Result<()> {
    if a.width() != b.width() || a.height() != b.height() || a.channels() != b.channels() {
        return Err(Error::Incompatible {
            what: what.into(),
            a_w: a.width(),
            a_h: a.height(),
            b_w: b.width(),
            b_h: b.height(),
        });
    }
    Ok(())
}

/// Mean squared error between two planes of the same shape.
pub fn mse(a: &Plane, b: &Plane) -> f64 {
    let s: f64 = a
        .data()
        .par_iter()
        .zip(b.data())
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum();
    s / a.data().len() as f64
}

/// PSNR in dB of values in [0, 1], capped at [`PSNR_CAP`].
pub fn psnr_from_mse(mse: f64) -> f64 {
    if mse <= 0.0 {
        PSNR_CAP
    } else {
        (10.0 * (1.0 / mse).log10()).min(PSNR_CAP)
    }
}

/// PSNR of tonemapped `result` against tonemapped `reference`.
pub fn psnr(result: &Plane, reference: &Plane) -> Result<f64> {
    check(result, reference, "PSNR")?;
    Ok(psnr_from_mse(mse(
        &tonemap_plane(result),
        &tonemap_plane(reference),
    )))
}

/// Relative MSE on linear values: mean of `(x − y)² / (y² + 0.01)`.
pub fn relmse(result: &Plane, reference: &Plane) -> Result<f64> {
    check(result, reference, "relMSE")?;
    let s: f64 = result
        .data()
        .par_iter()
        .zip(reference.data())
        .map(|(&x, &y)| ((x - y) as f64).powi(2) / ((y as f64).powi(2) + 0.01))
        .sum();
    Ok(s / result.data().len() as f64)
}

/// SSIM (Wang et al. 2004: 11×11 Gaussian window, σ = 1.5, K1 = 0.01, K2 = 0.03) of the
/// tonemapped images, averaged over pixels and channels.
pub fn ssim(result: &Plane, reference: &Plane) -> Result<f64> {
    check(result, reference, "SSIM")?;
    let a = tonemap_plane(result);
    let b = tonemap_plane(reference);
    let (c1, c2) = ((0.01f64).powi(2), (0.03f64).powi(2));
    let (w, h) = (a.width(), a.height());
    let mut total = 0.0;
    for c in 0..a.channels() {
        let x = a.channel(c);
        let y = b.channel(c);
        let xx: Vec<f32> = x.iter().map(|v| v * v).collect();
        let yy: Vec<f32> = y.iter().map(|v| v * v).collect();
        let xy: Vec<f32> = x.iter().zip(y).map(|(a, b)| a * b).collect();
        let [mx, my, sxx, syy, sxy] =
            [x, y, &xx[..], &yy[..], &xy[..]].map(|s| gaussian_blur(s, w, h));
        let s: f64 = (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (mx, my) = (mx[i] as f64, my[i] as f64);
                let vx = sxx[i] as f64 - mx * mx;
                let vy = syy[i] as f64 - my * my;
                let cv = sxy[i] as f64 - mx * my;
                ((2.0 * mx * my + c1) * (2.0 * cv + c2))
                    / ((mx * mx + my * my + c1) * (vx + vy + c2))
            })
            .sum();
        total += s / (w * h) as f64;
    }
    Ok(total / a.channels() as f64)
}

/// The SSIM window: Gaussian σ = 1.5 (truncated at 3σ ≈ the usual 11×11).
fn gaussian_blur(src: &[f32], w: usize, h: usize) -> Vec<f32> {
    crate::image::ops::gaussian(&Plane::from_vec(w, h, 1, src.to_vec()), 1.5).into_vec()
}

/// Temporal stability of one frame pair: the error of the result's frame-to-frame change
/// against the reference's, on tonemapped values. Returns (tMAE, tPSNR).
pub fn temporal(
    result_prev: &Plane,
    result: &Plane,
    reference_prev: &Plane,
    reference: &Plane,
) -> Result<(f64, f64)> {
    check(result, reference, "temporal metrics")?;
    check(
        result_prev,
        result,
        "temporal metrics (consecutive results)",
    )?;
    check(
        reference_prev,
        reference,
        "temporal metrics (consecutive references)",
    )?;
    let [a0, a1, b0, b1] = [result_prev, result, reference_prev, reference].map(tonemap_plane);
    let n = a1.data().len();
    let (abs, sq): (f64, f64) = (0..n)
        .into_par_iter()
        .map(|i| {
            let d = ((a1.data()[i] - a0.data()[i]) - (b1.data()[i] - b0.data()[i])) as f64;
            (d.abs(), d * d)
        })
        .reduce(|| (0.0, 0.0), |x, y| (x.0 + y.0, x.1 + y.1));
    Ok((abs / n as f64, psnr_from_mse(sq / n as f64)))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(f: impl Fn(usize, usize, usize) -> f32) -> Plane {
        Plane::from_fn(32, 24, 3, f)
    }

    #[test]
    fn psnr_of_known_error() {
        // tonemapped values differ by a constant 0.1 -> MSE 0.01 -> 20 dB
        let inv = |t: f32| {
            let l = t.powf(2.2);
            l / (1.0 - l)
        };
        let a = img(|_, _, _| inv(0.5));
        let b = img(|_, _, _| inv(0.6));
        assert!((psnr(&a, &b).unwrap() - 20.0).abs() < 1e-3);
        assert_eq!(psnr(&a, &a).unwrap(), PSNR_CAP);
    }

    #[test]
    fn ssim_is_one_for_identical_and_drops_with_noise() {
        let a = img(|x, y, c| 0.3 + 0.2 * ((x + 2 * y + c) as f32 * 0.3).sin());
        assert!((ssim(&a, &a).unwrap() - 1.0).abs() < 1e-9);
        let b = img(|x, y, c| {
            let seed = ((x * 73856093) ^ (y * 19349663) ^ (c * 83492791)) as u32;
            let r = seed.wrapping_mul(2654435761) >> 8;
            a.get(x, y, c) + (r as f32 / (1 << 24) as f32 - 0.5) * 0.3
        });
        let s = ssim(&b, &a).unwrap();
        assert!(s < 0.9 && s > 0.0, "{s}");
    }

    #[test]
    fn relmse_known_value_and_temporal_of_static_error() {
        let a = img(|_, _, _| 1.1);
        let b = img(|_, _, _| 1.0);
        assert!((relmse(&a, &b).unwrap() - 0.01 / 1.01).abs() < 1e-6);
        // a constant error does not flicker: zero temporal error
        let (tmae, tpsnr) = temporal(&a, &a, &b, &b).unwrap();
        assert_eq!(tmae, 0.0);
        assert_eq!(tpsnr, PSNR_CAP);
        // a result that changes while the reference does not
        let c = img(|_, _, _| 1.2);
        let (tmae, _) = temporal(&a, &c, &b, &b).unwrap();
        assert!((tmae - (tonemap(1.2) - tonemap(1.1)) as f64).abs() < 1e-6);
    }

    #[test]
    fn size_mismatch_is_an_error() {
        let a = Plane::zeros(4, 4, 3);
        let b = Plane::zeros(4, 5, 3);
        assert!(psnr(&a, &b).is_err());
    }
}
