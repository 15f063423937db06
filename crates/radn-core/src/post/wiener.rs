//! A noise-matched blend of two stages of the classic denoiser: where a smoothing stage changes
//! its input by no more than the input's remaining noise explains, its output is taken; where it
//! changes it by more (it removed detail: a reflection, a shadow edge, texture the guide does not
//! describe), the input is kept. So the classic denoiser's strength follows the noise: a 4-spp
//! frame is smoothed, a 128-spp frame only refined (it must never end below its input).
//!
//! Per pixel, with `v` the input's noise variance and `d²` the local mean squared change the
//! smoothing made, the smoothing's bias is estimated as `b² = max(0, d² − v)` and the weight of
//! the smoothed output is the Wiener gain `v / (v + b²)`. The weight is computed from the beauty
//! alone and applied to every signal, so each signal still receives one linear operator (AOVs
//! that sum to the beauty still do, alpha stays in range).

use rayon::prelude::*;

use std::ops::Range;

use crate::align::AlignedWindow;
use crate::classic::temporal::{apply_weights, temporal_variance};
use crate::image::ops::box_mean;
use crate::image::plane::Plane;

/// Options of the blend.
#[derive(Clone, Copy, Debug)]
pub struct BlendParams {
    /// Radius of the box over which the squared change is averaged (the guided filter's
    /// window: its changes are judged at the scale it works at).
    pub radius: usize,
    /// How many noise variances of change are still taken as noise (1 is the Wiener gain;
    /// larger trusts the smoothing more, and smooths 4-spp inputs more, but ends below the
    /// input on some clean ones; `docs/research/detail.md`).
    pub noise_scale: f32,
}

impl Default for BlendParams {
    fn default() -> Self {
        Self {
            radius: 1,
            noise_scale: 2.0,
        }
    }
}

/// How far [`local_variance`] reads around a pixel (its two boxes), in pixels.
pub const LOCAL_VARIANCE_RADIUS: usize = 3;

/// A frame's per-pixel, per-channel noise variance from its own neighbourhood: the squared
/// difference to the 3×3 mean, averaged over 5×5 (and corrected for the 9 samples of the mean).
/// Detail reads as noise here: it is the fallback where no other frame can be trusted.
pub fn local_variance(x: &Plane) -> Plane {
    let m = box_mean(x, 1);
    let mut d = x.clone();
    d.data_mut()
        .iter_mut()
        .zip(m.data())
        .for_each(|(v, mu)| *v = (*v - mu) * (*v - mu));
    let mut v = box_mean(&d, 2);
    v.data_mut().iter_mut().for_each(|v| *v *= 9.0 / 8.0);
    v
}

/// The per-pixel, per-channel noise variance of the centre frame's colour at rows `rows` of an
/// aligned window: the unbiased spread of the frames' colour, each weighted by its alignment
/// confidence, where more than one frame carries weight (`Σŵ² ≤ 0.95` with `ŵ` the normalised
/// confidences); elsewhere [`local_variance`] of the centre frame. It reads the centre frame
/// [`LOCAL_VARIANCE_RADIUS`] rows beyond `rows` (clamped to the window), so a band of a frame
/// gets the same values as the whole frame when its window holds those rows.
pub fn window_noise_variance(win: &AlignedWindow, rows: Range<usize>) -> Plane {
    let c = win.centre();
    let h = c.color.height();
    let wider =
        rows.start.saturating_sub(LOCAL_VARIANCE_RADIUS)..(rows.end + LOCAL_VARIANCE_RADIUS).min(h);
    let local = local_variance(&c.color.rows(wider.clone()))
        .rows(rows.start - wider.start..rows.end - wider.start);
    let colors: Vec<Plane> = win
        .frames
        .iter()
        .map(|f| f.color.rows(rows.clone()))
        .collect();
    // normalised confidences (all weight on the centre where no frame is trusted)
    let mut weights: Vec<Plane> = win
        .frames
        .iter()
        .map(|f| f.confidence.rows(rows.clone()))
        .collect();
    let centre = win.frames.len() / 2;
    for i in 0..local.pixels() {
        let sum: f32 = weights.iter().map(|w| w.data()[i].clamp(0.0, 1.0)).sum();
        for (k, w) in weights.iter_mut().enumerate() {
            let v = &mut w.data_mut()[i];
            *v = if sum > 0.0 {
                v.clamp(0.0, 1.0) / sum
            } else {
                f32::from(u8::from(k == centre))
            };
        }
    }
    let refs: Vec<&Plane> = colors.iter().collect();
    let mean = apply_weights(&weights, &refs);
    // the variance of the weighted mean, over Σŵ², is the samples' own variance
    let (of_mean, sum_w2) = temporal_variance(&weights, &refs, &mean);
    let n = local.pixels();
    let mut var = local;
    var.data_mut()
        .par_chunks_mut(n)
        .zip(of_mean.data().par_chunks(n))
        .for_each(|(out, m)| {
            for ((v, m), s2) in out.iter_mut().zip(m).zip(sum_w2.data()) {
                if m.is_finite() {
                    *v = m / s2;
                }
            }
        });
    var
}

/// The per-pixel weight (1 channel, in 0..=1) of `smoothed` over `input`: `input` and
/// `smoothed` are the beauty before and after the smoothing stage, `noise_variance` the
/// per-pixel, per-channel noise variance of `input`.
pub fn blend_weight(
    input: &Plane,
    smoothed: &Plane,
    noise_variance: &Plane,
    p: &BlendParams,
) -> Plane {
    let (w, h) = (input.width(), input.height());
    let c = input.channels().min(3);
    let mut change = Plane::zeros(w, h, 1);
    change
        .data_mut()
        .par_iter_mut()
        .enumerate()
        .for_each(|(i, d)| *d = squared_change(input, smoothed, i, c));
    let change = box_mean(&change, p.radius);
    // the noise variance, averaged over the same box: a few frames' spread underestimates
    // heavy-tailed Monte Carlo noise at most pixels, its local mean much less so
    let vc = noise_variance.channels().min(3);
    let mut v = Plane::zeros(w, h, 1);
    v.data_mut()
        .par_iter_mut()
        .enumerate()
        .for_each(|(i, v)| *v = mean_variance(noise_variance, i, vc));
    let v = box_mean(&v, p.radius);
    Plane::from_fn(w, h, 1, |x, y, _| {
        let i = y * w + x;
        wiener_gain(change.data()[i], v.data()[i] * p.noise_scale)
    })
}

/// The mean over the first `c` channels of pixel `i`'s squared change from `input` to
/// `smoothed`.
fn squared_change(input: &Plane, smoothed: &Plane, i: usize, c: usize) -> f32 {
    let n = input.pixels();
    (0..c)
        .map(|k| (smoothed.data()[k * n + i] - input.data()[k * n + i]).powi(2))
        .sum::<f32>()
        / c as f32
}

/// The mean over the first `c` channels of pixel `i`'s variance, 0 where it is not finite.
fn mean_variance(variance: &Plane, i: usize, c: usize) -> f32 {
    let n = variance.pixels();
    let s = (0..c).map(|k| variance.data()[k * n + i]).sum::<f32>() / c as f32;
    if s.is_finite() {
        s.max(0.0)
    } else {
        0.0
    }
}

/// The Wiener gain of a change `change` against noise `v` (both box means): `v / (v + b²)`,
/// `b² = max(0, change − v)`; 1 where nothing changed and there is no noise (either output is
/// the same).
fn wiener_gain(change: f32, v: f32) -> f32 {
    let bias = (change - v).max(0.0);
    if v + bias <= 0.0 {
        1.0
    } else {
        v / (v + bias)
    }
}

/// Added to the squared local brightness that [`variance_blend_weight`] divides by (a floor for
/// black pixels: brightness 0.03).
pub const RELATIVE_FLOOR: f32 = 1e-3;

/// Options of the blend against the renderer's own per-pixel variance.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VarianceBlend {
    /// Radius of the box the change and the variance are averaged over.
    pub radius: usize,
    /// Factor on the renderer's variance: a variance AOV is the samples' spread over their
    /// count, which overstates the error of stratified and low-discrepancy samplers.
    #[serde(default = "unit_scale")]
    pub scale: f32,
}

impl VarianceBlend {
    /// The blend over a box of `radius`, taking the renderer's variance as it is.
    pub fn new(radius: usize) -> Self {
        Self { radius, scale: 1.0 }
    }
}

fn unit_scale() -> f32 {
    1.0
}

/// The per-pixel weight (1 channel, in 0..=1) of `smoothed` over `input` where the renderer
/// wrote `variance`, the per-pixel, per-channel variance of `input`'s mean: the Wiener gain
/// `v / (v + b²)`, `b² = max(0, d² − v)`, with the squared change `d²` and `v` each divided by
/// the squared local brightness of `smoothed` before the box averages them, so that an error
/// counts relative to the brightness it sits in (as on a display) and dark detail is not
/// outvoted by bright pixels. The variance is the renderer's, so edges do not read as noise.
pub fn variance_blend_weight(
    input: &Plane,
    smoothed: &Plane,
    variance: &Plane,
    p: &VarianceBlend,
) -> Plane {
    let (w, h) = (input.width(), input.height());
    let n = w * h;
    let c = input.channels().min(3);
    let vc = variance.channels().min(3);
    let bright = box_mean(&smoothed.select_channels(0, c), 1);
    let mut terms = Plane::zeros(w, h, 2);
    let (change, var) = terms.data_mut().split_at_mut(n);
    change
        .par_iter_mut()
        .zip(var.par_iter_mut())
        .enumerate()
        .for_each(|(i, (d, v))| {
            let l = (0..c).map(|k| bright.data()[k * n + i]).sum::<f32>() / c as f32;
            let scale = 1.0 / (l.max(0.0).powi(2) + RELATIVE_FLOOR);
            let dd = squared_change(input, smoothed, i, c);
            *d = if dd.is_finite() { dd * scale } else { 0.0 };
            *v = mean_variance(variance, i, vc) * p.scale * scale;
        });
    let terms = box_mean(&terms, p.radius);
    Plane::from_fn(w, h, 1, |x, y, _| {
        let i = y * w + x;
        wiener_gain(terms.data()[i], terms.data()[n + i])
    })
}

/// `input + weight · (smoothed − input)` per pixel, for every channel.
pub fn blend(input: &Plane, smoothed: &Plane, weight: &Plane) -> Plane {
    let n = input.pixels();
    let mut out = input.clone();
    out.data_mut()
        .par_chunks_mut(n)
        .enumerate()
        .for_each(|(c, ch)| {
            let s = smoothed.channel(c);
            for (i, v) in ch.iter_mut().enumerate() {
                *v += weight.data()[i] * (s[i] - *v);
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classic::test_noise as noise;

    /// A 1-px stripe pattern (detail) plus noise of the given amplitude, and a "smoothing"
    /// that removes both (a flat image at the mean).
    fn case(amp: f32) -> (Plane, Plane, Plane, Plane) {
        let (w, h) = (48, 32);
        let clean = Plane::from_fn(w, h, 3, |x, _, _| if x % 2 == 0 { 0.6 } else { 0.4 });
        let input = Plane::from_fn(w, h, 3, |x, y, c| clean.get(x, y, c) + amp * noise(x, y, c));
        let smoothed = Plane::filled(w, h, 3, 0.5);
        let var = Plane::filled(w, h, 3, amp * amp / 12.0);
        (clean, input, smoothed, var)
    }

    fn mse(a: &Plane, b: &Plane) -> f32 {
        a.data()
            .iter()
            .zip(b.data())
            .map(|(x, y)| (x - y).powi(2))
            .sum::<f32>()
            / a.data().len() as f32
    }

    #[test]
    fn detail_beyond_the_noise_is_kept_and_noise_beyond_the_detail_is_smoothed() {
        // clean input (noise far below the ±0.1 stripes): the blend keeps the input
        let (clean, input, smoothed, var) = case(0.01);
        let wt = blend_weight(&input, &smoothed, &var, &BlendParams::default());
        let out = blend(&input, &smoothed, &wt);
        assert!(
            wt.data().iter().all(|&v| v < 0.01),
            "max weight {:?}",
            wt.data().iter().cloned().fold(0f32, f32::max)
        );
        assert!(mse(&out, &clean) <= mse(&input, &clean) * 1.01);
        // noise far above the stripes: the blend takes the smoothed image
        let (clean, input, smoothed, var) = case(2.0);
        let wt = blend_weight(&input, &smoothed, &var, &BlendParams::default());
        let out = blend(&input, &smoothed, &wt);
        let mean_w = wt.data().iter().sum::<f32>() / wt.data().len() as f32;
        assert!(mean_w > 0.8, "mean weight {mean_w}");
        assert!(mse(&out, &clean) < 0.3 * mse(&input, &clean));
    }

    /// Mean squared difference over columns `cols` only.
    fn mse_cols(a: &Plane, b: &Plane, cols: Range<usize>) -> f32 {
        let (w, h, c) = (a.width(), a.height(), a.channels());
        let mut s = 0.0;
        for k in 0..c {
            for y in 0..h {
                for x in cols.clone() {
                    s += (a.get(x, y, k) - b.get(x, y, k)).powi(2);
                }
            }
        }
        debug_assert!(cols.end <= w);
        s / (c * h * cols.len()) as f32
    }

    #[test]
    fn the_variance_blend_keeps_dark_detail_beside_a_bright_noisy_area_and_smooths_the_noise() {
        // left: bright and noisy (2.0, noise variance 0.03); right: dark one-pixel stripes
        // (0.02 / 0.04) nearly free of noise; the smoothing flattens both halves
        let (w, h) = (48, 32);
        let bright = |x: usize| x < w / 2;
        let clean = Plane::from_fn(w, h, 3, |x, _, _| match (bright(x), x % 2) {
            (true, _) => 2.0,
            (false, 0) => 0.02,
            (false, _) => 0.04,
        });
        let amp = |x: usize| if bright(x) { 0.6 } else { 0.001 };
        let input = Plane::from_fn(w, h, 3, |x, y, c| {
            clean.get(x, y, c) + amp(x) * noise(x, y, c)
        });
        let var = Plane::from_fn(w, h, 3, |x, _, _| amp(x) * amp(x) / 12.0);
        let smoothed = Plane::from_fn(w, h, 3, |x, _, _| if bright(x) { 2.0 } else { 0.03 });
        let p = VarianceBlend::new(4);
        let out = blend(
            &input,
            &smoothed,
            &variance_blend_weight(&input, &smoothed, &var, &p),
        );
        let (dark, lit) = (w / 2 + 1..w, 0..w / 2 - 5);
        // the dark stripes are kept, up to the border with the bright half: of the error the
        // smoothing alone makes there, less than 1% is left
        let lost = mse_cols(&smoothed, &clean, dark.clone());
        let kept = mse_cols(&out, &clean, dark.clone());
        assert!(kept < 0.01 * lost, "{kept} vs {lost}");
        // the bright half's noise is smoothed away
        assert!(mse_cols(&out, &clean, lit.clone()) < 0.3 * mse_cols(&input, &clean, lit));
        // the same box with errors counted in absolute terms lets the bright noise outvote the
        // dark stripes near the border (why the variance blend counts them relative to brightness)
        let linear = BlendParams {
            radius: 4,
            noise_scale: 1.0,
        };
        let flat = blend(
            &input,
            &smoothed,
            &blend_weight(&input, &smoothed, &var, &linear),
        );
        let flat = mse_cols(&flat, &clean, dark);
        assert!(flat > 20.0 * kept, "{flat} vs {kept}");
    }

    #[test]
    fn the_blend_is_one_linear_operator_for_every_signal() {
        let (_, input, smoothed, var) = case(0.3);
        let wt = blend_weight(&input, &smoothed, &var, &BlendParams::default());
        let a = Plane::from_fn(48, 32, 3, |x, y, c| noise(x + 7, y, c));
        let b = Plane::from_fn(48, 32, 3, |x, y, c| noise(x, y + 5, c));
        let sum = Plane::from_fn(48, 32, 3, |x, y, c| a.get(x, y, c) + b.get(x, y, c));
        let (sa, sb) = (
            Plane::filled(48, 32, 3, 0.1),
            Plane::filled(48, 32, 3, -0.2),
        );
        let ssum = Plane::filled(48, 32, 3, 0.1 - 0.2);
        let (oa, ob, os) = (
            blend(&a, &sa, &wt),
            blend(&b, &sb, &wt),
            blend(&sum, &ssum, &wt),
        );
        for i in 0..os.data().len() {
            assert!((oa.data()[i] + ob.data()[i] - os.data()[i]).abs() < 1e-5);
        }
    }

    /// A `w × h` window whose frame `k` is the constant `values[k]` with confidence `conf[k]`.
    fn flat_window(w: usize, h: usize, values: [f32; 5], conf: [f32; 5]) -> AlignedWindow {
        use crate::align::AlignedFrame;
        let frames = (0..5)
            .map(|k| AlignedFrame {
                offset: k as i32 - 2,
                color: Plane::filled(w, h, 3, values[k]),
                alpha: None,
                albedo: None,
                normal: None,
                depth: None,
                aovs: vec![],
                guide: None,
                variance: None,
                confidence: Plane::filled(w, h, 1, conf[k]),
                flow: Plane::zeros(w, h, 2),
            })
            .collect();
        AlignedWindow { frames }
    }

    #[test]
    fn the_window_noise_variance_is_the_trusted_frames_sample_variance() {
        // 1..5 equally trusted: the unbiased sample variance is 2.5
        let v = window_noise_variance(&flat_window(6, 8, [1., 2., 3., 4., 5.], [1.; 5]), 2..5);
        assert_eq!((v.width(), v.height(), v.channels()), (6, 3, 3));
        assert!(
            v.data().iter().all(|x| (x - 2.5).abs() < 1e-5),
            "{:?}",
            v.data()
        );
        // an untrusted outlier does not count: 2, 3, 4 give 1
        let v = window_noise_variance(
            &flat_window(6, 8, [100., 2., 3., 4., 0.], [0., 1., 1., 1., 0.]),
            0..8,
        );
        assert!(
            v.data().iter().all(|x| (x - 1.0).abs() < 1e-5),
            "{:?}",
            v.data()
        );
        // the centre alone: its local variance (0 on a flat frame), also where nothing is trusted
        for conf in [[0., 0., 1., 0., 0.], [0.; 5]] {
            let v = window_noise_variance(&flat_window(6, 8, [1., 2., 3., 4., 5.], conf), 0..8);
            assert!(v.data().iter().all(|&x| x == 0.0), "{conf:?}");
        }
    }
}
