//! The guide mix: a guided network's result mixed with the centre frame's own guide,
//! `(1 − w)·r + w·g` on the beauty.
//!
//! The network's kernels average the window, and the guide blend feeds them frames already
//! moved toward their guides. They still lose some of the detail a spatial denoiser keeps in
//! each frame. The spatial denoiser, in turn, keeps per-frame error the window averages away.
//! The two errors are far from equal, so a mix of the two is closer to the truth than either.
//!
//! Like the guide blend, the mix is a per-pixel gain on every RGB group,
//! `m = 1 − w + w·g / max(r, ε)`. On the beauty, `r·m = (1 − w)·r + w·g` wherever `r ≥ ε`.
//! RGB AOVs get the beauty's gain, so AOVs that summed to the denoised beauty sum to the mixed
//! one. Alpha and single-channel AOVs are left as the kernels made them.
//!
//! An [`OutlierRamp`] raises the weight, pixel by pixel, up to the guide alone where the result
//! and the guide disagree far more than detail does: fireflies the kernels spread instead of
//! removing (caustics through glass), and pixels no sample lit that they keep dark (dense fur
//! at 4 spp).

use std::ops::Range;

use radn_core::align::AlignedWindow;
use radn_core::Plane;

use crate::infer::schedule::NoiseSchedule;
use crate::infer::signals::Signals;

/// The guide mix as a stage of a frame's chain ([`crate::infer::post::PostChain`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MixStage {
    /// The guide's weight in [0, 1].
    pub weight: f32,
    /// Where the guide alone is taken.
    pub outliers: Option<OutlierRamp>,
    /// `None`: the centre frame's guide; `Some(range)`: the window's ([`window_guide`]).
    pub window: Option<Option<f32>>,
}

impl MixStage {
    /// Mixes rows `rows` of the result `out` (stacked as `signals`) with the guide; frames
    /// without a guide, and a mix that would change nothing, are left alone.
    pub fn apply(
        &self,
        win: &AlignedWindow,
        signals: &Signals,
        out: &mut Plane,
        rows: Range<usize>,
    ) {
        let Some(guide) = &win.centre().guide else {
            return;
        };
        if !(self.weight > 0.0 || self.outliers.is_some()) {
            return;
        }
        let g = match self.window {
            Some(range) => window_guide(win, rows, range),
            None => guide.rows(rows),
        };
        mix_with_guide(out, &g, self.weight, self.outliers, &signals.rgb_aovs())
    }
}

/// `ε` of the gain: the smallest linear colour the guide is divided by. Below it, a pixel
/// takes the guide in proportion to its own value. That is far below anything visible after
/// tonemapping, and it bounds the gain an AOV can get. A result at or below zero takes none of
/// the guide (its gain is `1 − w`): a gain would multiply the guide's share by its sign.
pub const GUIDE_MIX_EPS: f32 = 1e-6;

/// Where the guide mix takes the guide alone: a ramp over `d = |t(L_r) − t(L_g)|`, the
/// difference of the result's and the guide's luminance (mean of RGB) each mapped by
/// `t(x) = x / (1 + x)`. At `d ≤ from` the mix keeps its weight; from `to` on, the pixel is
/// the guide's. In between the guide's weight rises linearly. Being a gain, it cannot lift a
/// result of exactly zero (below [`GUIDE_MIX_EPS`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutlierRamp {
    /// The difference below which a pixel keeps the mix's own weight.
    pub from: f32,
    /// The difference from which a pixel takes the guide alone.
    pub to: f32,
}

impl OutlierRamp {
    /// The guide's weight at a pixel whose mapped luminances differ by `d` (0 to 1).
    pub fn weight(&self, d: f32) -> f32 {
        ((d - self.from) / (self.to - self.from)).clamp(0.0, 1.0)
    }
}

/// Mixes `values` (colour in channels 0–2, then the signals whose RGB groups start at the
/// offsets `rgb_groups`, every one getting the beauty's gain) with `guide` (RGB, the same
/// pixels) by `weight`, raised per pixel by `outliers` where given.
pub fn mix_with_guide(
    values: &mut Plane,
    guide: &Plane,
    weight: f32,
    outliers: Option<OutlierRamp>,
    rgb_groups: &[usize],
) {
    assert_eq!(
        (values.width(), values.height()),
        (guide.width(), guide.height()),
        "the guide covers the result's pixels"
    );
    let n = values.width() * values.height();
    assert!((0.0..=1.0).contains(&weight), "a mix weight is in [0, 1]");
    if weight == 0.0 && outliers.is_none() {
        return;
    }
    // per pixel, where the ramp is on: the mix's weight, raised by the ramp
    let weights: Option<Vec<f32>> = outliers.map(|ramp| {
        mapped_luma(values)
            .iter()
            .zip(mapped_luma(guide))
            .map(|(r, g)| weight.max(ramp.weight((r - g).abs())))
            .collect()
    });
    for c in 0..3 {
        let gain: Vec<f32> = values
            .channel(c)
            .iter()
            .zip(guide.channel(c))
            .enumerate()
            .map(|(i, (&r, &g))| {
                let w = weights.as_ref().map_or(weight, |ws| ws[i]);
                // a result at or below zero cannot be moved toward the guide by a gain: the
                // guide's share would multiply its sign (a −0.01 became −1357 on dense fur)
                let toward_guide = if r > 0.0 {
                    w * g.max(0.0) / r.max(GUIDE_MIX_EPS)
                } else {
                    0.0
                };
                1.0 - w + toward_guide
            })
            .collect();
        for &at in std::iter::once(&0).chain(rgb_groups) {
            let ch = values.channel_mut(at + c);
            for (v, m) in ch[..n].iter_mut().zip(&gain) {
                *v *= m;
            }
        }
    }
}

/// Per pixel, the luminance (mean of RGB, negatives as 0) mapped by `x / (1 + x)`.
fn mapped_luma(p: &Plane) -> Vec<f32> {
    let (r, g, b) = (p.channel(0), p.channel(1), p.channel(2));
    r.iter()
        .zip(g)
        .zip(b)
        .map(|((&r, &g), &b)| {
            let l = (r.max(0.0) + g.max(0.0) + b.max(0.0)) / 3.0;
            l / (1.0 + l)
        })
        .collect()
}

/// Which guide the result is mixed with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MixGuide {
    /// The centre frame's own guide: keeps its detail, and its per-frame error.
    Centre,
    /// The window's aligned guides averaged by their confidence ([`window_guide`]). It holds
    /// less per-frame error (flicker), and loses detail wherever the warps blur or miss.
    Window,
    /// [`MixGuide::Window`] for frames the noise schedule finds too noisy
    /// ([`NoiseSchedule::noise_scale`] gives none: 4 spp and some 11-spp frames), where a
    /// frame's guide flickers most; [`MixGuide::Centre`] for cleaner ones, where the warps
    /// would cost more detail than the averaging saves.
    FollowLevel,
}

impl MixGuide {
    /// Whether a frame of noise level `level` is mixed with the window's guide.
    pub fn uses_window(self, level: Option<f32>, schedule: &NoiseSchedule) -> bool {
        match self {
            MixGuide::Centre => false,
            MixGuide::Window => true,
            MixGuide::FollowLevel => schedule.noise_scale(level).is_none(),
        }
    }
}

/// The confidence-weighted mean of the window's aligned guides over rows `rows`: per pixel,
/// `Σ c_k·r_k·g_k / Σ c_k·r_k`. The centre frame has confidence 1, so the mean is defined
/// everywhere, and a pixel no side frame reaches gets the centre's guide.
///
/// `range` is the range term of a temporal bilateral filter: with `Some(σ)`, a side frame's
/// weight at a pixel is also `r_k = exp(−(d/σ)²)`, where `d` is the difference of its guide's
/// and the centre's guide's luminance, each mapped by `x / (1 + x)` (as the [`OutlierRamp`]
/// compares). A spatial denoiser's frame-to-frame error is small and smooth, so σ of a few
/// hundredths still averages it away; a warp that blurs a one-pixel line or misses an edge
/// differs by more, and leaves the centre's guide its own detail there. `None`: `r_k = 1`.
pub fn window_guide(win: &AlignedWindow, rows: Range<usize>, range: Option<f32>) -> Plane {
    let w = win.centre().color.width();
    let n = w * rows.len();
    let mut sum = Plane::zeros(w, rows.len(), 3);
    let mut weight = vec![0f32; n];
    let centre_luma = match (range, &win.centre().guide) {
        (Some(sigma), Some(g)) => {
            assert!(sigma > 0.0, "the range term's σ is positive");
            Some(mapped_luma(&g.rows(rows.clone())))
        }
        _ => None,
    };
    for f in &win.frames {
        let Some(g) = &f.guide else { continue };
        let conf = f.confidence.rows(rows.clone());
        let g = g.rows(rows.clone());
        let mut conf = conf.channel(0).to_vec();
        if let (Some(sigma), Some(centre)) = (range, &centre_luma) {
            for ((c, l), l0) in conf.iter_mut().zip(mapped_luma(&g)).zip(centre) {
                let d = (l - l0) / sigma;
                *c *= (-d * d).exp();
            }
        }
        for ch in 0..3 {
            for ((s, &v), &c) in sum.channel_mut(ch).iter_mut().zip(g.channel(ch)).zip(&conf) {
                *s += c * v;
            }
        }
        for (s, &c) in weight.iter_mut().zip(&conf) {
            *s += c;
        }
    }
    for ch in 0..3 {
        for (s, &c) in sum.channel_mut(ch).iter_mut().zip(&weight) {
            *s /= c.max(1e-6);
        }
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shipped recipe's ramp.
    const TEST_RAMP: OutlierRamp = OutlierRamp {
        from: 0.03,
        to: 0.1,
    };

    #[test]
    fn the_beauty_becomes_the_mix_and_aovs_keep_summing_to_it() {
        // colour, two RGB AOVs that sum to it, alpha
        let (w, h) = (7, 5);
        let colour = |x: usize, y: usize, c: usize| 0.2 + 0.1 * (x + 2 * y + c) as f32;
        let share = |x: usize, c: usize| 0.25 + 0.05 * ((x + c) % 3) as f32;
        let mut values = Plane::from_fn(w, h, 10, |x, y, c| match c {
            0..=2 => colour(x, y, c),
            3..=5 => colour(x, y, c - 3) * share(x, c - 3),
            6..=8 => colour(x, y, c - 6) * (1.0 - share(x, c - 6)),
            _ => 0.75,
        });
        let guide = Plane::from_fn(w, h, 3, |x, y, c| 0.5 * colour(x, y, c) + 0.3);
        mix_with_guide(&mut values, &guide, 0.25, None, &[3, 6]);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                for c in 0..3 {
                    let want = 0.75 * colour(x, y, c) + 0.25 * guide.channel(c)[i];
                    let got = values.channel(c)[i];
                    assert!((got - want).abs() < 1e-5, "{got} {want}");
                    let sum = values.channel(3 + c)[i] + values.channel(6 + c)[i];
                    assert!((sum - got).abs() < 1e-5, "AOVs {sum} vs beauty {got}");
                }
                assert_eq!(values.channel(9)[i], 0.75, "alpha is not mixed");
            }
        }
    }

    /// A window frame at `offset` with this guide and confidence; black colour, no motion.
    fn frame_with_guide(
        offset: i32,
        guide: Plane,
        confidence: Plane,
    ) -> radn_core::align::AlignedFrame {
        let (w, h) = (guide.width(), guide.height());
        radn_core::align::AlignedFrame {
            offset,
            color: Plane::zeros(w, h, 3),
            alpha: None,
            albedo: None,
            normal: None,
            depth: None,
            aovs: vec![],
            guide: Some(guide),
            variance: None,
            confidence,
            flow: Plane::zeros(w, h, 2),
        }
    }

    #[test]
    fn the_window_guide_averages_by_confidence_and_falls_back_to_the_centre() {
        let (w, h) = (6, 4);
        // frame k's guide is k everywhere; side frames are trusted on the left half only,
        // frame +2 at half weight there
        let frame = |k: i32| {
            let conf = Plane::from_fn(w, h, 1, |x, _, _| match (k, x < w / 2) {
                (0, _) => 1.0,
                (_, false) => 0.0,
                (2, true) => 0.5,
                (_, true) => 1.0,
            });
            frame_with_guide(k, Plane::from_fn(w, h, 3, |_, _, _| k as f32), conf)
        };
        let win = AlignedWindow {
            frames: (-2..=2).map(frame).collect(),
        };
        let g = window_guide(&win, 1..3, None);
        assert_eq!((g.width(), g.height()), (w, 2));
        // left: (−2 − 1 + 0 + 1 + 0.5·2) / 4.5 = −1 / 4.5; right: the centre's 0
        for y in 0..2 {
            for x in 0..w {
                let want = if x < w / 2 { -1.0 / 4.5 } else { 0.0 };
                assert!((g.channel(1)[y * w + x] - want).abs() < 1e-6);
            }
        }
        let s = NoiseSchedule::example();
        assert!(MixGuide::Window.uses_window(Some(0.01), &s));
        assert!(!MixGuide::Centre.uses_window(Some(100.0), &s));
        assert!(MixGuide::FollowLevel.uses_window(Some(100.0), &s));
        assert!(!MixGuide::FollowLevel.uses_window(Some(0.01), &s));
    }

    #[test]
    fn the_range_term_averages_small_differences_and_keeps_the_centres_line() {
        let (w, h) = (5, 3);
        let t = |x: f32| x / (1.0 + x);
        let untone = |m: f32| m / (1.0 - m);
        // the centre's guide: 0.3 with a bright one-pixel column at x = 2 (a wire); side frame
        // k: the same shifted by k·0.004 in mapped luminance (a spatial denoiser's flicker),
        // its wire smeared to 0.6 of its contrast (a warp that blurred it)
        let centre = |x: usize| if x == 2 { 1.5 } else { 0.3 };
        let guide_of = |k: i32, x: usize| {
            let base = t(0.3) + 0.004 * k as f32;
            if k == 0 {
                centre(x)
            } else if x == 2 {
                untone(base + 0.6 * (t(1.5) - t(0.3)))
            } else {
                untone(base)
            }
        };
        let frame = |k: i32| {
            frame_with_guide(
                k,
                Plane::from_fn(w, h, 3, |x, _, _| guide_of(k, x)),
                Plane::from_fn(w, h, 1, |_, _, _| 1.0),
            )
        };
        let win = AlignedWindow {
            frames: (-2..=2).map(frame).collect(),
        };
        let mean = |x: usize| (-2..=2).map(|k| guide_of(k, x)).sum::<f32>() / 5.0;
        let plain = window_guide(&win, 0..h, None);
        let ranged = window_guide(&win, 0..h, Some(0.02));
        for y in 0..h {
            for x in 0..w {
                let (p, r) = (plain.channel(0)[y * w + x], ranged.channel(0)[y * w + x]);
                assert!(
                    (p - mean(x)).abs() < 1e-5,
                    "confidence alone: the plain mean"
                );
                if x == 2 {
                    // the blurred wire differs by 0.24 in t: ranged, the centre keeps it
                    assert!(p < 0.9 * centre(2), "the plain mean blurs the wire: {p}");
                    assert!((r - centre(2)).abs() < 1e-3, "ranged wire {r}");
                } else {
                    // flicker of up to 0.008 in t (σ = 0.02): averaged nearly as the plain
                    // mean, which is the centre's value by symmetry
                    assert!((r - p).abs() < 1e-4, "ranged {r} plain {p}");
                }
            }
        }
        // the flicker's weights are unequal but symmetric: frames ±1 count more than ±2
        let lopsided = AlignedWindow {
            frames: win.frames.iter().take(4).cloned().collect(),
        };
        let r = window_guide(&lopsided, 0..1, Some(0.02)).channel(0)[0];
        let p = window_guide(&lopsided, 0..1, None).channel(0)[0];
        assert!(
            t(r) > t(p) && t(r) < t(0.3),
            "closer frames weigh more: {r} {p}"
        );
    }

    #[test]
    fn weight_zero_keeps_the_result_and_one_gives_the_guide() {
        let r = Plane::from_fn(4, 3, 3, |x, y, c| 0.1 + (x * y + c) as f32 * 0.05);
        let g = Plane::from_fn(4, 3, 3, |x, _, c| 0.4 + (x + c) as f32 * 0.02);
        let mut same = r.clone();
        mix_with_guide(&mut same, &g, 0.0, None, &[]);
        assert_eq!(same.data(), r.data());
        let mut all = r.clone();
        mix_with_guide(&mut all, &g, 1.0, None, &[]);
        for (a, b) in all.data().iter().zip(g.data()) {
            assert!((a - b).abs() < 1e-5);
        }
    }

    #[test]
    fn outliers_take_the_guide_and_agreeing_pixels_keep_the_weight() {
        // a 4x1 strip: agreeing, a firefly, a pixel kept almost unlit, one halfway up the ramp
        let guide = Plane::from_fn(4, 1, 3, |_, _, _| 0.4);
        let t = |x: f32| x / (1.0 + x);
        // luminance whose mapped value is t(0.4) + d
        let at = |d: f32| {
            let m = t(0.4) + d;
            m / (1.0 - m)
        };
        let ramp = TEST_RAMP;
        let mid = 0.5 * (ramp.from + ramp.to);
        let r = [at(0.01), 5.0, 0.002, at(mid)];
        let mut values = Plane::from_fn(4, 1, 6, |x, _, c| if c < 3 { r[x] } else { 0.5 * r[x] });
        mix_with_guide(&mut values, &guide, 0.25, Some(ramp), &[3]);
        let want = [0.75 * r[0] + 0.25 * 0.4, 0.4, 0.4, 0.5 * r[3] + 0.5 * 0.4];
        for (x, &want) in want.iter().enumerate() {
            let got = values.channel(0)[x];
            assert!((got - want).abs() < 1e-4, "pixel {x}: {got} vs {want}");
            // the AOV (half the beauty) got the same gain
            assert!((values.channel(3)[x] - 0.5 * got).abs() < 1e-4);
        }
        // no weight of its own: the ramp alone still acts
        let mut alone = Plane::from_fn(4, 1, 3, |x, _, _| r[x]);
        mix_with_guide(&mut alone, &guide, 0.0, Some(ramp), &[]);
        assert!((alone.channel(0)[0] - r[0]).abs() < 1e-6);
        assert!((alone.channel(0)[1] - 0.4).abs() < 1e-5);
    }

    #[test]
    fn a_result_at_or_below_zero_is_not_amplified_toward_the_guide() {
        // kernels can leave a pixel no sample lit slightly below zero (dense fur at 4 spp); the
        // outlier ramp gives it the guide's full weight, and a gain of g / ε there turned
        // −0.0095 into −1357 (fur-test 9 000 000). Now it keeps (1 − w) of itself.
        let guide = Plane::from_fn(3, 1, 3, |_, _, _| 0.22);
        let r = [-0.0095f32, 0.0, 0.23];
        let mut values = Plane::from_fn(3, 1, 6, |x, _, c| if c < 3 { r[x] } else { 0.5 * r[x] });
        mix_with_guide(&mut values, &guide, 0.7, Some(TEST_RAMP), &[3]);
        for c in 0..3 {
            let v = values.channel(c);
            assert!(v[0] <= 0.0 && v[0] >= r[0], "negative result: {}", v[0]);
            assert_eq!(v[1], 0.0, "a result of zero stays zero");
            assert!(
                (v[2] - (0.3 * 0.23 + 0.7 * 0.22)).abs() < 1e-5,
                "a positive result mixes as before"
            );
            assert!(
                (values.channel(3 + c)[0] - 0.5 * v[0]).abs() < 1e-6,
                "the AOV's gain"
            );
        }
    }
}
