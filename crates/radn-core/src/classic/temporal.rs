//! Confidence-weighted robust temporal averaging of an aligned window (paper eq. 1): per pixel,
//! the samples' minimum and maximum are dropped and the rest averaged by confidence.

use rayon::prelude::*;

use crate::align::AlignedWindow;
use crate::image::plane::Plane;

/// The robust average of paper eq. 1: mean without the minimum and the maximum (plain mean
/// for fewer than three values).
pub fn robust_mean(values: &[f32]) -> f32 {
    let n = values.len();
    if n == 0 {
        return 0.0;
    }
    let sum: f32 = values.iter().sum();
    if n < 3 {
        return sum / n as f32;
    }
    let (lo, hi) = values
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    (sum - lo - hi) / (n - 2) as f32
}

/// Per-pixel weights (one plane per window slot, summing to 1) of the confidence-weighted
/// robust average: slots with positive confidence are candidates; when there are at least
/// three, the ones with the lowest and highest luminance are dropped; the rest are weighted by
/// confidence (the centre by 1). Where no side frame is trusted the centre gets all the weight.
pub fn robust_weights(win: &AlignedWindow) -> Vec<Plane> {
    let t = win.frames.len();
    let centre = t / 2;
    let (w, h) = (win.centre().color.width(), win.centre().color.height());
    let n = w * h;
    let lum: Vec<Vec<f32>> = win
        .frames
        .iter()
        .map(|f| {
            let d = f.color.data();
            (0..n)
                .map(|i| 0.2126 * d[i] + 0.7152 * d[n + i] + 0.0722 * d[2 * n + i])
                .collect()
        })
        .collect();
    let mut out: Vec<Vec<f32>> = vec![vec![0.0; n]; t];
    let cols: Vec<Vec<f32>> = (0..n)
        .into_par_iter()
        .map(|i| {
            let conf: Vec<f32> = (0..t)
                .map(|k| {
                    if k == centre {
                        1.0
                    } else {
                        win.frames[k].confidence.data()[i]
                    }
                })
                .collect();
            let cand: Vec<usize> = (0..t).filter(|&k| conf[k] > 1e-3).collect();
            let mut keep = cand.clone();
            if cand.len() >= 3 {
                let by =
                    |a: &&usize, b: &&usize| lum[**a][i].total_cmp(&lum[**b][i]).then(a.cmp(b));
                let lo = *cand.iter().min_by(by).expect("non-empty");
                let hi = *cand.iter().max_by(by).expect("non-empty");
                keep.retain(|&k| k != lo && k != hi);
            }
            let total: f32 = keep.iter().map(|&k| conf[k]).sum();
            let mut wts = vec![0.0; t];
            if total > 0.0 {
                for &k in &keep {
                    wts[k] = conf[k] / total;
                }
            } else {
                wts[centre] = 1.0;
            }
            wts
        })
        .collect();
    for (i, wts) in cols.iter().enumerate() {
        for k in 0..t {
            out[k][i] = wts[k];
        }
    }
    out.into_iter()
        .map(|v| Plane::from_vec(w, h, 1, v))
        .collect()
}

/// Applies per-pixel slot weights to the slots' planes: `Σ_k weight_k · plane_k`.
pub fn apply_weights(weights: &[Plane], planes: &[&Plane]) -> Plane {
    let first = planes[0];
    let n = first.pixels();
    let mut out = Plane::zeros(first.width(), first.height(), first.channels());
    out.data_mut()
        .par_chunks_mut(n)
        .enumerate()
        .for_each(|(c, ch)| {
            for (k, p) in planes.iter().enumerate() {
                let src = p.channel(c);
                let wk = weights[k].data();
                for i in 0..n {
                    ch[i] += wk[i] * src[i];
                }
            }
        });
    out
}

/// Per-pixel variance (per channel) of the weighted average, estimated from the spread of the
/// window's samples; `None` where a single slot carries (almost) all the weight.
pub fn temporal_variance(weights: &[Plane], planes: &[&Plane], mean: &Plane) -> (Plane, Plane) {
    let n = mean.pixels();
    let (w, h, ch) = (mean.width(), mean.height(), mean.channels());
    let mut var = Plane::zeros(w, h, ch);
    let mut sum_w2 = Plane::zeros(w, h, 1);
    sum_w2
        .data_mut()
        .par_iter_mut()
        .enumerate()
        .for_each(|(i, s)| {
            *s = weights.iter().map(|wk| wk.data()[i] * wk.data()[i]).sum();
        });
    var.data_mut()
        .par_chunks_mut(n)
        .enumerate()
        .for_each(|(c, out)| {
            let m = mean.channel(c);
            for i in 0..n {
                let s2 = sum_w2.data()[i];
                if s2 > 0.95 {
                    out[i] = f32::NAN; // no temporal estimate here
                    continue;
                }
                let mut acc = 0.0;
                for (k, p) in planes.iter().enumerate() {
                    let d = p.channel(c)[i] - m[i];
                    acc += weights[k].data()[i] * d * d;
                }
                // unbiased weighted sample variance, then the variance of the weighted mean
                out[i] = acc / (1.0 - s2) * s2;
            }
        });
    (var, sum_w2)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::align::AlignedFrame;

    #[test]
    fn robust_mean_drops_min_and_max() {
        assert_eq!(robust_mean(&[1.0, 2.0, 3.0, 4.0, 100.0]), 3.0);
        assert_eq!(robust_mean(&[5.0, -7.0, 1.0]), 1.0);
        assert_eq!(robust_mean(&[2.0, 2.0, 2.0, 9.0]), 2.0); // ties: one of each end dropped
        assert_eq!(robust_mean(&[1.0, 3.0]), 2.0);
    }

    fn window(values: [f32; 5], conf: [f32; 5]) -> AlignedWindow {
        let frames = (0..5)
            .map(|k| AlignedFrame {
                offset: k as i32 - 2,
                color: Plane::filled(1, 1, 3, values[k]),
                alpha: None,
                albedo: None,
                normal: None,
                depth: None,
                aovs: vec![],
                guide: None,
                variance: None,
                confidence: Plane::filled(1, 1, 1, conf[k]),
                flow: Plane::zeros(1, 1, 2),
            })
            .collect();
        AlignedWindow { frames }
    }

    #[test]
    fn weights_drop_the_firefly_and_the_darkest_sample() {
        let win = window([1.0, 1.2, 1.1, 50.0, 0.2], [1.0; 5]);
        let wts = robust_weights(&win);
        let v: Vec<f32> = wts.iter().map(|p| p.data()[0]).collect();
        assert_eq!(v[3], 0.0, "firefly dropped");
        assert_eq!(v[4], 0.0, "minimum dropped");
        assert!((v[0] - 1.0 / 3.0).abs() < 1e-6 && (v[2] - 1.0 / 3.0).abs() < 1e-6);
        let planes: Vec<&Plane> = win.frames.iter().map(|f| &f.color).collect();
        let avg = apply_weights(&wts, &planes);
        assert!((avg.data()[0] - 1.1).abs() < 1e-6);
    }

    #[test]
    fn untrusted_side_frames_fall_back_to_the_centre() {
        let win = window([9.0, 9.0, 1.0, 9.0, 9.0], [0.0; 5]);
        let wts = robust_weights(&win);
        assert_eq!(wts[2].data()[0], 1.0);
        // two trusted frames: no dropping below three candidates, confidence-weighted
        let win = window([3.0, 9.0, 1.0, 9.0, 9.0], [0.5, 0.0, 1.0, 0.0, 0.0]);
        let wts = robust_weights(&win);
        assert!(
            (wts[0].data()[0] - 1.0 / 3.0).abs() < 1e-6
                && (wts[2].data()[0] - 2.0 / 3.0).abs() < 1e-6
        );
    }
}
