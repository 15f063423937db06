//! Per-pixel confidence that a warped side frame shows the same surface as the centre frame.

use rayon::prelude::*;

use crate::frame::FAR_DEPTH;
use crate::plane::Plane;

/// Tolerances of the confidence terms. Each term is 1 for perfect agreement and falls off
/// smoothly; the confidence is their product.
#[derive(Clone, Copy, Debug)]
pub struct ConfidenceParams {
    /// Forward–backward motion error (pixels, summed over hops) at which the motion term is e^-1.
    pub motion_px: f32,
    /// Relative albedo difference (3×3 prefiltered) at which the albedo term is e^-1.
    pub albedo: f32,
    /// Normal cosine below which the normal term is 0 ...
    pub normal_cos_lo: f32,
    /// ... and above which it is 1.
    pub normal_cos_hi: f32,
    /// Relative depth difference per frame of distance at which the depth term is e^-1.
    pub depth_rel: f32,
    /// Relative colour difference (3×3 prefiltered) at which the background term is e^-1.
    /// Renderers give the background no motion, so only its appearance can be checked.
    pub background_color: f32,
}

impl Default for ConfidenceParams {
    fn default() -> Self {
        Self {
            motion_px: 0.75,
            albedo: 0.12,
            normal_cos_lo: 0.80,
            normal_cos_hi: 0.95,
            depth_rel: 0.06,
            background_color: 0.08,
        }
    }
}

/// The buffers confidence compares, 3×3 prefiltered so render noise does not read as change.
#[derive(Clone, Debug)]
pub struct Guides {
    /// Prefiltered colour.
    pub color: Plane,
    /// Prefiltered albedo.
    pub albedo: Option<Plane>,
    /// Prefiltered normal.
    pub normal: Option<Plane>,
    /// Depth (not filtered: averaging across silhouettes would invent depths).
    pub depth: Option<Plane>,
}

impl Guides {
    /// Prefilters a frame's buffers.
    pub fn new(
        color: &Plane,
        albedo: Option<&Plane>,
        normal: Option<&Plane>,
        depth: Option<&Plane>,
    ) -> Self {
        Self {
            color: box3(color),
            albedo: albedo.map(box3),
            normal: normal.map(box3),
            depth: depth.cloned(),
        }
    }
}

/// True where a pixel shows the background (no geometry): infinite depth, or no normal.
#[inline]
fn is_background(g: &Guides, i: usize, n: usize) -> bool {
    if let Some(d) = &g.depth {
        return d.data()[i] >= 0.5 * FAR_DEPTH;
    }
    if let Some(nm) = &g.normal {
        let d = nm.data();
        let l2 = d[i] * d[i] + d[n + i] * d[n + i] + d[2 * n + i] * d[2 * n + i];
        return l2 < 0.01;
    }
    false
}

/// Combines motion validity and buffer agreement into a confidence plane.
///
/// `valid` is 0 where the lookup left the image (or the frame is missing), `motion_err` the
/// accumulated forward–backward error in pixels (None where it cannot be checked), `hops` the
/// frame distance to the centre, `warped` the side frame's guides warped onto the centre.
pub fn confidence(
    centre: &Guides,
    warped: &Guides,
    valid: &Plane,
    motion_err: Option<&Plane>,
    hops: usize,
    p: &ConfidenceParams,
) -> Plane {
    let (w, h) = (valid.width(), valid.height());
    let n = w * h;
    let mut out = Plane::zeros(w, h, 1);
    let depth_tol = p.depth_rel * hops.max(1) as f32;
    out.data_mut()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, row)| {
            for (x, o) in row.iter_mut().enumerate() {
                let i = y * w + x;
                if valid.data()[i] <= 0.0 {
                    *o = 0.0;
                    continue;
                }
                let mut c = 1.0f32;
                let bg_c = is_background(centre, i, n);
                let bg_w = is_background(warped, i, n);
                if bg_c != bg_w {
                    *o = 0.0;
                    continue;
                }
                if bg_c {
                    let d = rel_diff3(&centre.color, &warped.color, i, n, 0.02);
                    c *= gauss(d, p.background_color);
                } else {
                    if let Some(e) = motion_err {
                        c *= gauss(e.data()[i], p.motion_px);
                    }
                    if let (Some(a), Some(b)) = (&centre.albedo, &warped.albedo) {
                        c *= gauss(rel_diff3(a, b, i, n, 0.02), p.albedo);
                    }
                    if let (Some(a), Some(b)) = (&centre.normal, &warped.normal) {
                        c *= normal_term(a, b, i, n, p);
                    }
                    if let (Some(a), Some(b)) = (&centre.depth, &warped.depth) {
                        let (da, db) = (a.data()[i], b.data()[i]);
                        let rel = (da - db).abs() / da.abs().max(db.abs()).max(1e-6);
                        c *= gauss(rel, depth_tol);
                    }
                }
                *o = c * valid.data()[i];
            }
        });
    out
}

#[inline]
fn gauss(d: f32, tol: f32) -> f32 {
    let r = d / tol;
    (-r * r).exp()
}

/// L1 difference of two RGB pixels relative to their L1 magnitude.
#[inline]
fn rel_diff3(a: &Plane, b: &Plane, i: usize, n: usize, eps: f32) -> f32 {
    let (a, b) = (a.data(), b.data());
    let mut d = 0.0;
    let mut m = 0.0;
    for c in 0..3 {
        d += (a[c * n + i] - b[c * n + i]).abs();
        m += a[c * n + i].abs() + b[c * n + i].abs();
    }
    d / (0.5 * m + eps)
}

#[inline]
fn normal_term(a: &Plane, b: &Plane, i: usize, n: usize, p: &ConfidenceParams) -> f32 {
    let (a, b) = (a.data(), b.data());
    let (mut dot, mut la, mut lb) = (0.0, 0.0, 0.0);
    for c in 0..3 {
        dot += a[c * n + i] * b[c * n + i];
        la += a[c * n + i] * a[c * n + i];
        lb += b[c * n + i] * b[c * n + i];
    }
    if la < 1e-8 || lb < 1e-8 {
        return 1.0;
    }
    let cos = dot / (la * lb).sqrt();
    let t = ((cos - p.normal_cos_lo) / (p.normal_cos_hi - p.normal_cos_lo)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// 3×3 box filter with edge repeat.
pub fn box3(p: &Plane) -> Plane {
    crate::image_ops::box_mean(p, 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn guides(albedo: f32, depth: f32) -> Guides {
        let color = Plane::filled(4, 4, 3, 0.5);
        let a = Plane::filled(4, 4, 3, albedo);
        let nrm = Plane::from_fn(4, 4, 3, |_, _, c| if c == 2 { 1.0 } else { 0.0 });
        let d = Plane::filled(4, 4, 1, depth);
        Guides::new(&color, Some(&a), Some(&nrm), Some(&d))
    }

    #[test]
    fn agreement_gives_one_and_disagreement_gives_nearly_zero() {
        let valid = Plane::filled(4, 4, 1, 1.0);
        let p = ConfidenceParams::default();
        let same = confidence(&guides(0.5, 3.0), &guides(0.5, 3.0), &valid, None, 1, &p);
        assert!(same.data().iter().all(|&c| (c - 1.0).abs() < 1e-6));
        let other_albedo = confidence(&guides(0.5, 3.0), &guides(0.9, 3.0), &valid, None, 1, &p);
        assert!(other_albedo.data().iter().all(|&c| c < 0.01));
        let other_depth = confidence(&guides(0.5, 3.0), &guides(0.5, 4.5), &valid, None, 1, &p);
        assert!(other_depth.data().iter().all(|&c| c < 0.01));
        let bg_vs_fg = confidence(
            &guides(0.5, 3.0),
            &guides(0.5, FAR_DEPTH),
            &valid,
            None,
            1,
            &p,
        );
        assert!(bg_vs_fg.data().iter().all(|&c| c == 0.0));
        let offscreen = confidence(
            &guides(0.5, 3.0),
            &guides(0.5, 3.0),
            &Plane::zeros(4, 4, 1),
            None,
            1,
            &p,
        );
        assert!(offscreen.data().iter().all(|&c| c == 0.0));
    }

    #[test]
    fn motion_error_lowers_confidence() {
        let valid = Plane::filled(4, 4, 1, 1.0);
        let p = ConfidenceParams::default();
        let err = Plane::filled(4, 4, 1, 3.0);
        let c = confidence(
            &guides(0.5, 3.0),
            &guides(0.5, 3.0),
            &valid,
            Some(&err),
            1,
            &p,
        );
        assert!(c.data().iter().all(|&c| c < 1e-6));
    }
}
