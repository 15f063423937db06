//! TV-L1 optical flow: the duality-based scheme of Zach, Pock and Bischof (2007) with the
//! improvements of Wedel et al. (2009) — structure–texture decomposition of the inputs and a
//! median filter on the flow after every warp — solved coarse to fine and initialised from a
//! given flow (the renderer's motion vectors).

use rayon::prelude::*;

use crate::align::motion::bilinear;
use crate::image::ops::{downsample, gradient, median3, resample};
use crate::image::plane::Plane;

/// TV-L1 parameters. Intensities are expected in [0, 255] (the usual scale of the method's
/// published parameter values).
#[derive(Clone, Copy, Debug)]
pub struct TvL1Params {
    /// Weight of the data term (λ).
    pub lambda: f32,
    /// Coupling between the primal flow and its auxiliary variable (θ).
    pub theta: f32,
    /// Dual step size (τ ≤ 1/4).
    pub tau: f32,
    /// Pyramid levels (including the finest).
    pub levels: usize,
    /// Warps (re-linearisations) per level.
    pub warps: usize,
    /// Maximum inner iterations per warp.
    pub iterations: usize,
    /// Stop a warp's iterations when the mean squared flow update falls below this.
    pub epsilon: f32,
    /// Weight of the structure part removed from the inputs (Wedel's α; 0 disables the decomposition).
    pub texture_alpha: f32,
    /// Median-filter the flow after every warp (Wedel).
    pub median: bool,
}

impl Default for TvL1Params {
    fn default() -> Self {
        Self {
            lambda: 0.15,
            theta: 0.3,
            tau: 0.25,
            levels: 4,
            warps: 5,
            iterations: 150,
            epsilon: 1e-6,
            texture_alpha: 0.95,
            median: true,
        }
    }
}

/// Estimates the flow `u` with `i1(x + u(x)) ≈ i0(x)`, starting from `init` (2 channels, pixels).
pub fn tvl1_flow(i0: &Plane, i1: &Plane, init: &Plane, p: &TvL1Params) -> Plane {
    let (w, h) = (i0.width(), i0.height());
    let (a, b) = if p.texture_alpha > 0.0 {
        let (mut a, mut b) = (
            structure_texture(i0, p.texture_alpha),
            structure_texture(i1, p.texture_alpha),
        );
        // one scale for both images, or brightness constancy would break
        let (lo, hi) = a
            .data()
            .iter()
            .chain(b.data())
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &v| {
                (l.min(v), h.max(v))
            });
        let k = 255.0 / (hi - lo).max(1e-6);
        for img in [&mut a, &mut b] {
            img.data_mut().iter_mut().for_each(|v| *v = (*v - lo) * k);
        }
        (a, b)
    } else {
        (i0.clone(), i1.clone())
    };
    // pyramid sizes, finest first
    let mut sizes = vec![(w, h)];
    while sizes.len() < p.levels.max(1) {
        let (lw, lh) = *sizes.last().expect("non-empty");
        if lw < 32 || lh < 32 {
            break;
        }
        sizes.push((lw.div_ceil(2), lh.div_ceil(2)));
    }
    let mut pyr0 = vec![a];
    let mut pyr1 = vec![b];
    for &(lw, lh) in &sizes[1..] {
        let n0 = downsample(pyr0.last().expect("non-empty"), lw, lh);
        let n1 = downsample(pyr1.last().expect("non-empty"), lw, lh);
        pyr0.push(n0);
        pyr1.push(n1);
    }
    let coarsest = sizes.len() - 1;
    let (cw, ch) = sizes[coarsest];
    let mut u = scale_flow(
        &resample(init, cw, ch),
        cw as f32 / w as f32,
        ch as f32 / h as f32,
    );
    for level in (0..=coarsest).rev() {
        u = solve_level(&pyr0[level], &pyr1[level], u, p);
        if level > 0 {
            let (nw, nh) = sizes[level - 1];
            u = scale_flow(
                &resample(&u, nw, nh),
                nw as f32 / sizes[level].0 as f32,
                nh as f32 / sizes[level].1 as f32,
            );
        }
    }
    u
}

fn scale_flow(u: &Plane, sx: f32, sy: f32) -> Plane {
    let mut out = u.clone();
    out.channel_mut(0).iter_mut().for_each(|v| *v *= sx);
    out.channel_mut(1).iter_mut().for_each(|v| *v *= sy);
    out
}

/// One pyramid level: `warps` re-linearisations of the data term, each followed by the
/// alternating thresholding / dual-projection iterations.
fn solve_level(i0: &Plane, i1: &Plane, mut u: Plane, p: &TvL1Params) -> Plane {
    let (w, h) = (i0.width(), i0.height());
    let n = w * h;
    let (i1x, i1y) = gradient(i1);
    let lt = p.lambda * p.theta;
    let taut = p.tau / p.theta;
    // dual variables: p1 = (p11, p12) for u1, p2 = (p21, p22) for u2
    let mut dual = vec![vec![0f32; n]; 4];
    for _ in 0..p.warps {
        // warp I1 and its gradient along the current flow
        let mut i1w = vec![0f32; n];
        let mut gx = vec![0f32; n];
        let mut gy = vec![0f32; n];
        i1w.par_chunks_mut(w)
            .zip(gx.par_chunks_mut(w))
            .zip(gy.par_chunks_mut(w))
            .enumerate()
            .for_each(|(y, ((r, rx), ry))| {
                for x in 0..w {
                    let px = x as f32 + u.get(x, y, 0);
                    let py = y as f32 + u.get(x, y, 1);
                    r[x] = bilinear(i1, 0, px, py);
                    rx[x] = bilinear(&i1x, 0, px, py);
                    ry[x] = bilinear(&i1y, 0, px, py);
                }
            });
        let grad2: Vec<f32> = gx.iter().zip(&gy).map(|(a, b)| a * a + b * b).collect();
        let u0 = u.clone();
        let rho_c: Vec<f32> = (0..n)
            .map(|i| i1w[i] - gx[i] * u0.data()[i] - gy[i] * u0.data()[n + i] - i0.data()[i])
            .collect();
        let mut div1 = vec![0f32; n];
        let mut div2 = vec![0f32; n];
        for _ in 0..p.iterations {
            // thresholding step: v, then u = v + θ div p
            divergence_into(&dual[0], &dual[1], w, h, &mut div1);
            divergence_into(&dual[2], &dual[3], w, h, &mut div2);
            let (ux, uy) = u.data_mut().split_at_mut(n);
            let change: f64 = ux
                .par_iter_mut()
                .zip(uy.par_iter_mut())
                .enumerate()
                .map(|(i, (u1, u2))| {
                    let rho = rho_c[i] + gx[i] * *u1 + gy[i] * *u2;
                    let (d1, d2) = if rho < -lt * grad2[i] {
                        (lt * gx[i], lt * gy[i])
                    } else if rho > lt * grad2[i] {
                        (-lt * gx[i], -lt * gy[i])
                    } else if grad2[i] > 1e-10 {
                        (-rho * gx[i] / grad2[i], -rho * gy[i] / grad2[i])
                    } else {
                        (0.0, 0.0)
                    };
                    let n1 = *u1 + d1 + p.theta * div1[i];
                    let n2 = *u2 + d2 + p.theta * div2[i];
                    let c = (n1 - *u1).powi(2) + (n2 - *u2).powi(2);
                    *u1 = n1;
                    *u2 = n2;
                    c as f64
                })
                .sum();
            // dual ascent with projection
            for (k, comp) in [(0usize, 0usize), (2, 1)] {
                let uc = u.channel(comp);
                let (pa, pb) = dual.split_at_mut(k + 1);
                let (px, py) = (&mut pa[k], &mut pb[0]);
                project_dual(px, py, uc, w, h, taut);
            }
            if (change / n as f64) < p.epsilon as f64 {
                break;
            }
        }
        if p.median {
            u = median3(&u);
        }
    }
    u
}

/// Divergence (backward differences) of a dual field, the adjoint of the forward gradient.
fn divergence(px: &[f32], py: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut out = vec![0f32; w * h];
    divergence_into(px, py, w, h, &mut out);
    out
}

fn divergence_into(px: &[f32], py: &[f32], w: usize, h: usize, out: &mut [f32]) {
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let i = y * w + x;
            let dx = if x == 0 {
                px[i]
            } else if x + 1 == w {
                -px[i - 1]
            } else {
                px[i] - px[i - 1]
            };
            let dy = if y == 0 {
                py[i]
            } else if y + 1 == h {
                -py[i - w]
            } else {
                py[i] - py[i - w]
            };
            *o = dx + dy;
        }
    });
}

/// Wedel's structure–texture decomposition: the texture part `I − α·ROF(I)`. Removes slowly
/// varying shading so the flow follows texture rather than lighting changes.
pub fn structure_texture(img: &Plane, alpha: f32) -> Plane {
    let structure = rof(img, 0.125, 60);
    let t: Vec<f32> = img
        .data()
        .iter()
        .zip(structure.data())
        .map(|(i, s)| i - alpha * s)
        .collect();
    Plane::from_vec(img.width(), img.height(), 1, t)
}

/// One step of dual ascent with projection, shared by the flow and ROF solvers:
/// `p ← (p + τ∇v) / (1 + τ|∇v|)` with forward differences (0 at the far edges).
fn project_dual(px: &mut [f32], py: &mut [f32], v: &[f32], w: usize, h: usize, tau: f32) {
    px.par_chunks_mut(w)
        .zip(py.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (rx, ry))| {
            for x in 0..w {
                let i = y * w + x;
                let gx = if x + 1 < w { v[i + 1] - v[i] } else { 0.0 };
                let gy = if y + 1 < h { v[i + w] - v[i] } else { 0.0 };
                let norm = 1.0 + tau * (gx * gx + gy * gy).sqrt();
                rx[x] = (rx[x] + tau * gx) / norm;
                ry[x] = (ry[x] + tau * gy) / norm;
            }
        });
}

/// Rudin–Osher–Fatemi denoising by Chambolle's projection algorithm.
fn rof(f: &Plane, theta: f32, iterations: usize) -> Plane {
    let (w, h) = (f.width(), f.height());
    let n = w * h;
    let tau = 0.125f32;
    let mut px = vec![0f32; n];
    let mut py = vec![0f32; n];
    let fd = f.data();
    for _ in 0..iterations {
        let div = divergence(&px, &py, w, h);
        let v: Vec<f32> = (0..n).map(|i| div[i] - fd[i] / theta).collect();
        project_dual(&mut px, &mut py, &v, w, h, tau);
    }
    let div = divergence(&px, &py, w, h);
    Plane::from_vec(w, h, 1, (0..n).map(|i| fd[i] - theta * div[i]).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A band-limited random texture, so sub-pixel shifts are well defined.
    fn texture(w: usize, h: usize, dx: f32, dy: f32) -> Plane {
        let waves: Vec<(f32, f32, f32, f32)> = (0..24)
            .map(|k| {
                let a = k as f32 * 2.399;
                let f = 0.08 + 0.02 * (k % 7) as f32;
                (
                    f * a.cos(),
                    f * a.sin(),
                    (k * 37 % 11) as f32,
                    1.0 / (1.0 + k as f32 * 0.1),
                )
            })
            .collect();
        Plane::from_fn(w, h, 1, |x, y, _| {
            let (x, y) = (x as f32 + dx, y as f32 + dy);
            let v: f32 = waves
                .iter()
                .map(|(fx, fy, ph, amp)| amp * (fx * x + fy * y + ph).sin())
                .sum();
            128.0 + 12.0 * v
        })
    }

    #[test]
    fn recovers_a_subpixel_translation() {
        let (w, h) = (96, 80);
        let (tx, ty) = (1.37f32, -0.62f32);
        // i1(x + t) = i0(x): i1 is i0 shifted by t
        let i0 = texture(w, h, 0.0, 0.0);
        let i1 = texture(w, h, -tx, -ty);
        // start a pixel away from the answer, as a renderer vector on a reflection would be
        let init = Plane::from_fn(w, h, 2, |_, _, c| if c == 0 { 0.4 } else { 0.3 });
        let u = tvl1_flow(&i0, &i1, &init, &TvL1Params::default());
        let (mut ex, mut ey, mut n) = (0.0f64, 0.0f64, 0);
        for y in 12..h - 12 {
            for x in 12..w - 12 {
                ex += (u.get(x, y, 0) - tx) as f64;
                ey += (u.get(x, y, 1) - ty) as f64;
                n += 1;
            }
        }
        let (ex, ey) = (ex / n as f64, ey / n as f64);
        assert!(
            ex.abs() < 0.05 && ey.abs() < 0.05,
            "mean error ({ex:.4}, {ey:.4}) px"
        );
        // and pixel by pixel: every interior pixel within 0.05 px
        let mut errs: Vec<f32> = Vec::new();
        for y in 12..h - 12 {
            for x in 12..w - 12 {
                errs.push(((u.get(x, y, 0) - tx).powi(2) + (u.get(x, y, 1) - ty).powi(2)).sqrt());
            }
        }
        let worst = errs.iter().copied().fold(0.0, f32::max);
        assert!(worst < 0.05, "worst interior error {worst} px");
    }

    #[test]
    fn keeps_a_correct_initialisation() {
        let (w, h) = (64, 64);
        let i0 = texture(w, h, 0.0, 0.0);
        let i1 = texture(w, h, -2.0, 1.0);
        let init = Plane::from_fn(w, h, 2, |_, _, c| if c == 0 { 2.0 } else { -1.0 });
        let u = tvl1_flow(&i0, &i1, &init, &TvL1Params::default());
        for y in 8..h - 8 {
            for x in 8..w - 8 {
                assert!((u.get(x, y, 0) - 2.0).abs() < 0.05 && (u.get(x, y, 1) + 1.0).abs() < 0.05);
            }
        }
    }
}
