//! Per-pixel confidence that a warped side frame shows the same surface as the centre frame.

use rayon::prelude::*;

use crate::image::plane::Plane;
use crate::image::stats::FAR_DEPTH;

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
    /// Relative difference of the frames' spatial guides (3×3 prefiltered, e.g. OIDN's result
    /// of each frame) at which the guide term is e^-1; `None` leaves the guides out.
    ///
    /// Motion vectors follow the surface, so the geometric terms cannot see a surface whose
    /// shading changed between frames: a reflection sliding over a turning metal face, a
    /// refraction through turning glass, a light that moved. A noisy frame's colour is too noisy
    /// to compare pixel by pixel, but a spatial denoiser's result is not, so where every frame
    /// has one the term rejects such changes before the kernels average them in.
    pub guide: Option<f32>,
    /// Relative difference of the frames' own colour (3×3 prefiltered) at which the colour
    /// term is e^-1 on surfaces; `None` leaves it out. The unguided counterpart of
    /// [`ConfidenceParams::guide`]: it must be loose enough that render noise does not read as
    /// change.
    pub color: Option<f32>,
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
            guide: None,
            color: None,
        }
    }
}

impl ConfidenceParams {
    /// These tolerances with the terms that compare sampled buffers (albedo, normal and depth)
    /// loosened `k` times (`k` ≥ 1; below 1 counts as 1): the albedo and depth tolerances
    /// multiplied by `k`, the normal term's cosine thresholds moved `k` times as far from 1 (at
    /// most to −1). A noisy frame's buffers are noisy too where one pixel covers several
    /// surfaces (fur, grass, foliage): each sample of a 4-spp pixel hits a strand or what lies
    /// behind it, so two frames of the same fur differ by more than the strict tolerances
    /// allow. The motion, background, colour and guide terms are left as they are: the guide
    /// term is what catches a reflection sliding over its surface, and loosening it too let
    /// such ghosts back in on validation (docs/research/guided.md, "Confidence on fur").
    pub fn loosened(self, k: f32) -> Self {
        let k = k.max(1.0);
        let cos = |c: f32| (1.0 - (1.0 - c) * k).max(-1.0);
        Self {
            albedo: self.albedo * k,
            normal_cos_lo: cos(self.normal_cos_lo),
            normal_cos_hi: cos(self.normal_cos_hi),
            depth_rel: self.depth_rel * k,
            ..self
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
    /// The frame's prefiltered spatial guide ([`ConfidenceParams::guide`]).
    pub guide: Option<Plane>,
}

impl Guides {
    /// Prefilters a frame's buffers.
    pub fn new(
        color: &Plane,
        albedo: Option<&Plane>,
        normal: Option<&Plane>,
        depth: Option<&Plane>,
        guide: Option<&Plane>,
    ) -> Self {
        Self {
            color: box3(color),
            albedo: albedo.map(box3),
            normal: normal.map(box3),
            depth: depth.cloned(),
            guide: guide.map(box3),
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
                    if let (Some(tol), Some(a), Some(b)) = (p.guide, &centre.guide, &warped.guide) {
                        c *= gauss(rel_diff3(a, b, i, n, 0.02), tol);
                    }
                    if let Some(tol) = p.color {
                        c *= gauss(rel_diff3(&centre.color, &warped.color, i, n, 0.02), tol);
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
    crate::image::ops::box_mean(p, 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn guides(albedo: f32, depth: f32) -> Guides {
        let color = Plane::filled(4, 4, 3, 0.5);
        let a = Plane::filled(4, 4, 3, albedo);
        let nrm = Plane::from_fn(4, 4, 3, |_, _, c| if c == 2 { 1.0 } else { 0.0 });
        let d = Plane::filled(4, 4, 1, depth);
        Guides::new(&color, Some(&a), Some(&nrm), Some(&d), None)
    }

    #[test]
    fn loosening_lets_a_noisy_buffers_difference_through_and_still_rejects_another_surface() {
        let valid = Plane::filled(4, 4, 1, 1.0);
        let strict = ConfidenceParams::default();
        assert_eq!(format!("{:?}", strict.loosened(1.0)), format!("{strict:?}"));
        assert_eq!(format!("{:?}", strict.loosened(0.5)), format!("{strict:?}"));
        let loose = strict.loosened(4.0);
        assert!((loose.albedo - 4.0 * strict.albedo).abs() < 1e-6);
        assert!(
            (loose.normal_cos_lo - 0.2).abs() < 1e-6 && (loose.normal_cos_hi - 0.8).abs() < 1e-6
        );
        assert_eq!(loose.motion_px, strict.motion_px);
        let guided = ConfidenceParams {
            guide: Some(0.6),
            ..strict
        };
        assert_eq!(
            guided.loosened(4.0).guide,
            Some(0.6),
            "the guide term is kept"
        );
        assert_eq!(strict.loosened(100.0).normal_cos_lo, -1.0);
        // fur at 4 spp: the 3×3 albedo differs by a fifth between frames (strand or skin)
        let (c, w) = (guides(0.5, 3.0), guides(0.6, 3.1));
        let at = |p: &ConfidenceParams| confidence(&c, &w, &valid, None, 1, p).data()[5];
        assert!(at(&strict) < 0.35, "strict: {}", at(&strict));
        assert!(at(&loose) > 0.8, "loosened: {}", at(&loose));
        // another surface still reads as one: albedo 0.2 against 0.8, or depth 3 against 6
        for other in [guides(0.8, 3.0), guides(0.2, 6.0)] {
            let c = confidence(&guides(0.2, 3.0), &other, &valid, None, 1, &loose).data()[5];
            assert!(c < 0.2, "{c}");
        }
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

    #[test]
    fn a_changed_guide_lowers_confidence_only_with_the_guide_term_on() {
        // the same surface (albedo, normal and depth agree) whose shading changed: the side
        // frame's guide is twice as bright in the left half
        let frame = |bright: f32| {
            let color = Plane::filled(8, 4, 3, 0.5);
            let albedo = Plane::filled(8, 4, 3, 0.5);
            let normal = Plane::from_fn(8, 4, 3, |_, _, c| if c == 2 { 1.0 } else { 0.0 });
            let depth = Plane::filled(8, 4, 1, 3.0);
            let guide = Plane::from_fn(8, 4, 3, |x, _, _| if x < 4 { bright } else { 0.5 });
            Guides::new(
                &color,
                Some(&albedo),
                Some(&normal),
                Some(&depth),
                Some(&guide),
            )
        };
        let (centre, side) = (frame(0.5), frame(1.0));
        let valid = Plane::filled(8, 4, 1, 1.0);
        let off = ConfidenceParams::default();
        let c = confidence(&centre, &side, &valid, None, 1, &off);
        assert!(c.data().iter().all(|&c| (c - 1.0).abs() < 1e-6));
        let on = ConfidenceParams {
            guide: Some(0.6),
            ..off
        };
        let c = confidence(&centre, &side, &valid, None, 1, &on);
        // columns 0-2: L1 difference 3 * 0.5 over the mean L1 magnitude 3 * 0.75 (+ ε 0.02),
        // 0.661, so e^-(0.661 / 0.6)^2 = 0.30; columns 3 and 4 see both halves through the
        // prefilter; columns 5-7 agree
        let expected = (-((1.5f32 / 2.27) / 0.6).powi(2)).exp();
        for row in c.data().chunks(8) {
            assert!(
                row[..3].iter().all(|&v| (v - expected).abs() < 1e-4),
                "{row:?}"
            );
            assert!(
                row[3] > expected && row[3] < row[4] && row[4] < 1.0,
                "{row:?}"
            );
            assert!(row[5..].iter().all(|&v| (v - 1.0).abs() < 1e-6), "{row:?}");
        }
    }
}
