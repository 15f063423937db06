//! The guided filter (He, Sun and Tang 2013) with a multi-channel guide (albedo and normal):
//! a local linear model of the signal in the guide's channels, which keeps the guide's edges.
//! Linear in the signal for a fixed guide, so colour and AOVs get the same operator.

use rayon::prelude::*;

use crate::image::ops::box_mean;
use crate::image::plane::Plane;

/// Guided filter options.
#[derive(Clone, Copy, Debug)]
pub struct GuidedParams {
    /// Window radius in pixels.
    pub radius: usize,
    /// Regularisation ε added to the guide's covariance (larger smooths more).
    pub eps: f32,
}

impl Default for GuidedParams {
    fn default() -> Self {
        Self {
            radius: 2,
            eps: 1e-3,
        }
    }
}

/// Filters every signal with the guide's local linear models.
pub fn guided_filter(guide: &Plane, signals: &[&Plane], p: &GuidedParams) -> Vec<Plane> {
    let k = guide.channels();
    let (w, h) = (guide.width(), guide.height());
    let n = w * h;
    let r = p.radius;
    let mean_i = box_mean(guide, r);
    let pairs: Vec<(usize, usize)> = (0..k).flat_map(|a| (a..k).map(move |b| (a, b))).collect();
    let prod = Plane::from_fn(w, h, pairs.len(), |_, _, _| 0.0);
    let mut prod = prod;
    for (q, &(a, b)) in pairs.iter().enumerate() {
        let (ga, gb) = (guide.channel(a), guide.channel(b));
        prod.channel_mut(q)
            .par_iter_mut()
            .enumerate()
            .for_each(|(i, v)| *v = ga[i] * gb[i]);
    }
    let corr_ii = box_mean(&prod, r);
    signals
        .iter()
        .map(|sig| {
            let m = sig.channels();
            let mean_p = box_mean(sig, r);
            // guide × signal products
            let mut ip = Plane::zeros(w, h, k * m);
            for c in 0..m {
                for a in 0..k {
                    let (g, s) = (guide.channel(a), sig.channel(c));
                    ip.channel_mut(c * k + a)
                        .par_iter_mut()
                        .enumerate()
                        .for_each(|(i, v)| *v = g[i] * s[i]);
                }
            }
            let corr_ip = box_mean(&ip, r);
            // per pixel: a = (Σ + εI)⁻¹ cov(I, p), b = mean(p) − aᵀ mean(I)
            let coeffs: Vec<Vec<f32>> = (0..n)
                .into_par_iter()
                .map(|i| {
                    let mut sigma = vec![0f64; k * k];
                    for (q, &(a, b)) in pairs.iter().enumerate() {
                        let v = corr_ii.data()[q * n + i] as f64
                            - mean_i.data()[a * n + i] as f64 * mean_i.data()[b * n + i] as f64;
                        sigma[a * k + b] = v;
                        sigma[b * k + a] = v;
                    }
                    for a in 0..k {
                        sigma[a * k + a] += p.eps as f64;
                    }
                    let chol = cholesky(&sigma, k);
                    let mut out = vec![0f32; m * (k + 1)];
                    for c in 0..m {
                        let mp = mean_p.data()[c * n + i] as f64;
                        let cov: Vec<f64> = (0..k)
                            .map(|a| {
                                corr_ip.data()[(c * k + a) * n + i] as f64
                                    - mean_i.data()[a * n + i] as f64 * mp
                            })
                            .collect();
                        let mut a = chol_solve(&chol, k, &cov);
                        let mut b = mp
                            - (0..k)
                                .map(|q| a[q] * mean_i.data()[q * n + i] as f64)
                                .sum::<f64>();
                        // a numerically singular window (e.g. f32 cancellation in the box
                        // means of a very bright guide): fall back to the local mean
                        if !(b.is_finite() && a.iter().all(|v| v.is_finite() && v.abs() < 1e6)) {
                            a.iter_mut().for_each(|v| *v = 0.0);
                            b = mp;
                        }
                        for q in 0..k {
                            out[c * (k + 1) + q] = a[q] as f32;
                        }
                        out[c * (k + 1) + k] = b as f32;
                    }
                    out
                })
                .collect();
            let mut ab = Plane::zeros(w, h, m * (k + 1));
            for (i, co) in coeffs.iter().enumerate() {
                for (q, v) in co.iter().enumerate() {
                    ab.data_mut()[q * n + i] = *v;
                }
            }
            let mean_ab = box_mean(&ab, r);
            let mut out = Plane::zeros(w, h, m);
            out.data_mut()
                .par_chunks_mut(n)
                .enumerate()
                .for_each(|(c, ch)| {
                    for (i, v) in ch.iter_mut().enumerate() {
                        let mut s = mean_ab.data()[(c * (k + 1) + k) * n + i];
                        for q in 0..k {
                            s +=
                                mean_ab.data()[(c * (k + 1) + q) * n + i] * guide.data()[q * n + i];
                        }
                        *v = s;
                    }
                });
            out
        })
        .collect()
}

/// Cholesky factor (lower triangle, row-major) of a symmetric positive-definite k×k matrix.
fn cholesky(a: &[f64], k: usize) -> Vec<f64> {
    let mut l = vec![0f64; k * k];
    for i in 0..k {
        for j in 0..=i {
            let mut s = a[i * k + j];
            for q in 0..j {
                s -= l[i * k + q] * l[j * k + q];
            }
            l[i * k + j] = if i == j {
                s.max(1e-12).sqrt()
            } else {
                s / l[j * k + j]
            };
        }
    }
    l
}

fn chol_solve(l: &[f64], k: usize, b: &[f64]) -> Vec<f64> {
    let mut y = vec![0f64; k];
    for i in 0..k {
        let mut s = b[i];
        for q in 0..i {
            s -= l[i * k + q] * y[q];
        }
        y[i] = s / l[i * k + i];
    }
    let mut x = vec![0f64; k];
    for i in (0..k).rev() {
        let mut s = y[i];
        for q in i + 1..k {
            s -= l[q * k + i] * x[q];
        }
        x[i] = s / l[i * k + i];
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_edge_in_the_guide_survives_and_noise_is_smoothed() {
        let (w, h) = (32, 16);
        let guide = Plane::from_fn(w, h, 2, |x, _, c| {
            if c == 0 {
                if x < 16 {
                    0.1
                } else {
                    0.9
                }
            } else {
                0.5
            }
        });
        // the signal: the same step, scaled, plus a checkerboard ripple that the guide lacks
        let sig = Plane::from_fn(w, h, 1, |x, y, _| {
            (if x < 16 { 0.2 } else { 1.0 }) + if (x + y) % 2 == 0 { 0.05 } else { -0.05 }
        });
        let out = guided_filter(
            &guide,
            &[&sig],
            &GuidedParams {
                radius: 2,
                eps: 1e-4,
            },
        )
        .remove(0);
        for y in 2..h - 2 {
            // the step stays a step (no blur across x = 15 | 16) ...
            assert!(
                (out.get(15, y, 0) - 0.2).abs() < 0.03 && (out.get(16, y, 0) - 1.0).abs() < 0.03,
                "y={y}"
            );
            // ... and the ripple, which the guide does not explain, is smoothed away
            assert!(
                (out.get(8, y, 0) - 0.2).abs() < 0.02,
                "{}",
                out.get(8, y, 0)
            );
        }
    }

    #[test]
    fn filter_is_linear_in_the_signal() {
        let guide = Plane::from_fn(20, 20, 3, |x, y, c| ((x * 3 + y * 5 + c) % 7) as f32 / 7.0);
        let a = Plane::from_fn(20, 20, 1, |x, y, _| ((x * y) % 5) as f32);
        let b = Plane::from_fn(20, 20, 1, |x, y, _| ((x + 2 * y) % 3) as f32);
        let sum = Plane::from_fn(20, 20, 1, |x, y, _| a.get(x, y, 0) + b.get(x, y, 0));
        let out = guided_filter(&guide, &[&a, &b, &sum], &GuidedParams::default());
        for i in 0..400 {
            assert!((out[0].data()[i] + out[1].data()[i] - out[2].data()[i]).abs() < 1e-3);
        }
    }

    #[test]
    fn a_very_bright_nearly_flat_guide_gives_finite_output() {
        // guide channels near 330 with tiny variations: f32 box means cancel to a variance
        // of the wrong sign (found on a Cycles emitter's albedo)
        let (w, h) = (64, 64);
        let guide = Plane::from_fn(w, h, 6, |x, y, c| {
            if c < 3 {
                330.0 + ((x * 7 + y * 13 + c) % 5) as f32 * 1e-4
            } else {
                ((x + y + c) % 3) as f32 * 1e-5
            }
        });
        let sig = Plane::from_fn(w, h, 3, |x, y, c| ((x * y + c) % 11) as f32);
        let out = guided_filter(&guide, &[&sig], &GuidedParams::default());
        assert!(out[0].data().iter().all(|v| v.is_finite()));
        // and stays within the signal's range (the local-mean fallback is convex)
        assert!(out[0].data().iter().all(|&v| (-1.0..=11.0).contains(&v)));
    }
}
