//! Metrics with the reference's own noise taken out, from two independent reference renders.
//!
//! A path-traced reference is itself noisy. Every error measured against it includes that
//! noise. A result closer to the truth than the reference's own noise cannot score better
//! than the noise allows, and frame-to-frame metrics (tMAE) reach a floor where the
//! reference's noise changes from frame to frame. The floor shows once good methods differ
//! by less than the reference's noise.
//!
//! With a second reference `B` of the same frames, rendered with other sampling seeds, the
//! cross product `(r − A)·(r − B)` estimates the squared error against the noise-free image
//! without bias: with `A = T + a`, `B = T + b`, and `a`, `b` independent with zero mean, its
//! expectation is `(r − T)²`. The same holds for frame-to-frame differences. The estimate is
//! made on tonemapped values, like every perceptual metric here. The reference noise must then
//! have zero mean after tonemapping. That holds to second order in the noise, so it is close
//! for converged references (hundreds of samples) and not for noisy ones.
//!
//! Every row also reports the two references against each other. That is the floor a single
//! reference sets: a noise-free result scores about `reference_tmae / √2` in tMAE against
//! either reference, when the noise is close to Gaussian.

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::eval::evaluation::{opt, row_label};
use crate::eval::metrics::{self, psnr_from_mse, tonemap_plane};
use crate::image::plane::Plane;

/// One frame's metrics against the noise-free image, estimated from two references.
#[derive(serde::Serialize, Clone, Debug)]
pub struct NoiseFreeMetrics {
    /// Frame number (`i64::MIN` in a mean row).
    pub frame: i64,
    /// PSNR (dB) of tonemapped RGB against the noise-free image, estimated.
    pub psnr: f64,
    /// PSNR (dB) of the frame-to-frame difference against the noise-free image's, estimated.
    pub tpsnr: Option<f64>,
    /// Root-mean-square error of the frame-to-frame difference against the noise-free
    /// image's, estimated (tonemapped; 0 where the estimate is not positive).
    pub trmse: Option<f64>,
    /// PSNR (dB) of the first reference against the second: how noisy the references are.
    pub reference_psnr: f64,
    /// tMAE of the first reference against the second: the floor a single reference sets on
    /// tMAE.
    pub reference_tmae: Option<f64>,
}

/// The mean over the pixels and channels of `(r − a)·(r − b)`: the squared error of `r`
/// against the noise-free image, estimated without bias from two independent noisy
/// versions `a` and `b` of it. It can come out negative where `r` is within the references'
/// noise of the truth.
pub fn cross_mse(r: &[f32], a: &[f32], b: &[f32]) -> f64 {
    let s: f64 = r
        .par_iter()
        .zip(a.par_iter().zip(b.par_iter()))
        .map(|(r, (a, b))| ((r - a) as f64) * ((r - b) as f64))
        .sum();
    s / r.len().max(1) as f64
}

/// [`cross_mse`] of the frame-to-frame differences `r1 − r0` against `a1 − a0` and
/// `b1 − b0`.
pub fn temporal_cross_mse(r: [&[f32]; 2], a: [&[f32]; 2], b: [&[f32]; 2]) -> f64 {
    let n = r[1].len();
    let s: f64 = (0..n)
        .into_par_iter()
        .map(|i| {
            let dr = r[1][i] - r[0][i];
            let ea = (dr - (a[1][i] - a[0][i])) as f64;
            let eb = (dr - (b[1][i] - b[0][i])) as f64;
            ea * eb
        })
        .sum();
    s / n.max(1) as f64
}

/// The mean absolute difference of the frame-to-frame changes `a1 − a0` and `b1 − b0` (tMAE,
/// as [`crate::eval::metrics::temporal`] computes it, of values already tonemapped).
fn temporal_mae(a: [&[f32]; 2], b: [&[f32]; 2]) -> f64 {
    let n = a[1].len();
    let s: f64 = (0..n)
        .into_par_iter()
        .map(|i| (((a[1][i] - a[0][i]) - (b[1][i] - b[0][i])) as f64).abs())
        .sum();
    s / n.max(1) as f64
}

fn same_shape(a: &Plane, b: &Plane, what: String) -> Result<()> {
    if a.width() != b.width() || a.height() != b.height() || a.channels() != b.channels() {
        return Err(Error::Incompatible {
            what,
            a_w: a.width(),
            a_h: a.height(),
            b_w: b.width(),
            b_h: b.height(),
        });
    }
    Ok(())
}

/// The metrics of every frame of `frames` (frame, result colour, first reference's colour,
/// second reference's colour, in frame order, as [`crate::eval::evaluation::Evaluation::planes`]
/// holds them plus the second reference). Temporal metrics compare each frame with the
/// previous one where the two are one sequence step apart, as in
/// [`crate::eval::evaluation::evaluate`].
pub fn evaluate(frames: &[(i64, &Plane, &Plane, &Plane)]) -> Result<Vec<NoiseFreeMetrics>> {
    for (f, r, a, b) in frames {
        same_shape(r, a, format!("frame {f}: result and reference"))?;
        same_shape(a, b, format!("frame {f}: the two references"))?;
    }
    let tonemapped: Vec<[Plane; 3]> = frames
        .par_iter()
        .map(|(_, r, a, b)| [tonemap_plane(r), tonemap_plane(a), tonemap_plane(b)])
        .collect();
    let step = frames
        .windows(2)
        .map(|w| w[1].0 - w[0].0)
        .min()
        .unwrap_or(1);
    frames
        .iter()
        .enumerate()
        .map(|(i, (f, ..))| -> Result<NoiseFreeMetrics> {
            let [r, ta, tb] = &tonemapped[i];
            let mse = cross_mse(r.data(), ta.data(), tb.data());
            let previous = i
                .checked_sub(1)
                .filter(|&j| f - frames[j].0 == step)
                .map(|j| (j, &tonemapped[j]));
            let (tpsnr, trmse, reference_tmae) = match previous {
                Some((_, [r0, a0, b0])) => {
                    let tmse = temporal_cross_mse(
                        [r0.data(), r.data()],
                        [a0.data(), ta.data()],
                        [b0.data(), tb.data()],
                    );
                    let floor = temporal_mae([a0.data(), ta.data()], [b0.data(), tb.data()]);
                    (
                        Some(psnr_from_mse(tmse)),
                        Some(tmse.max(0.0).sqrt()),
                        Some(floor),
                    )
                }
                None => (None, None, None),
            };
            Ok(NoiseFreeMetrics {
                frame: *f,
                psnr: psnr_from_mse(mse),
                tpsnr,
                trmse,
                reference_psnr: psnr_from_mse(metrics::mse(ta, tb)),
                reference_tmae,
            })
        })
        .collect()
}

/// The mean over frames (temporal metrics over the frames that have them); `frame` is
/// `i64::MIN`.
pub fn mean_row(rows: &[NoiseFreeMetrics]) -> NoiseFreeMetrics {
    let mean = |v: Vec<f64>| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
    let all = |f: fn(&NoiseFreeMetrics) -> f64| mean(rows.iter().map(f).collect());
    let some = |f: fn(&NoiseFreeMetrics) -> Option<f64>| mean(rows.iter().filter_map(f).collect());
    NoiseFreeMetrics {
        frame: i64::MIN,
        psnr: all(|r| r.psnr).unwrap_or(f64::NAN),
        tpsnr: some(|r| r.tpsnr),
        trmse: some(|r| r.trmse),
        reference_psnr: all(|r| r.reference_psnr).unwrap_or(f64::NAN),
        reference_tmae: some(|r| r.reference_tmae),
    }
}

/// The metrics as a text table: one line per frame, then the mean.
pub fn table(rows: &[NoiseFreeMetrics]) -> String {
    use std::fmt::Write;
    let mut s = format!(
        "{:>8} {:>9} {:>8} {:>9} {:>11} {:>11}\n",
        "frame", "PSNR*", "tPSNR*", "tRMSE*", "ref PSNR", "ref tMAE"
    );
    let mean = mean_row(rows);
    for r in rows.iter().chain(std::iter::once(&mean)) {
        let _ = writeln!(
            s,
            "{:>8} {:>9.3} {:>8} {:>9} {:>11.3} {:>11}",
            row_label(r.frame),
            r.psnr,
            opt(r.tpsnr, 2),
            opt(r.trmse, 5),
            r.reference_psnr,
            opt(r.reference_tmae, 5)
        );
    }
    s
}

/// The metrics as a JSON value: every frame's row and the mean.
pub fn to_json_value(rows: &[NoiseFreeMetrics]) -> serde_json::Value {
    let mut m = serde_json::to_value(mean_row(rows)).expect("metrics serialise");
    m["frame"] = serde_json::Value::Null;
    serde_json::json!({"frames": rows, "mean": m})
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::metrics::psnr;

    /// The linear value whose tonemapped value is `t` (in (0, 1)).
    fn untonemap(t: f32) -> f32 {
        let l = t.clamp(1e-4, 0.999).powf(2.2);
        l / (1.0 - l)
    }

    /// Uniform noise in [-1, 1] from a hash of its arguments (a fixed, independent draw per
    /// pixel, channel, frame and stream).
    fn noise(x: usize, y: usize, c: usize, frame: usize, stream: u64) -> f32 {
        let mut h = (x as u64) ^ (y as u64) << 16 ^ (c as u64) << 32 ^ (frame as u64) << 40;
        h ^= stream.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        h = (h ^ (h >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h = (h ^ (h >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        h ^= h >> 31;
        (h >> 11) as f32 / (1u64 << 53) as f32 * 2.0 - 1.0
    }

    /// The truth at frame `f`: a texture moving one pixel per frame, tonemapped values in
    /// (0.2, 0.8).
    fn truth(x: usize, y: usize, c: usize, f: usize) -> f32 {
        let u = (x + f) as f32 * 0.37 + c as f32;
        0.5 + 0.2 * u.sin() * (y as f32 * 0.21).cos() + 0.1 * (u * 0.13).cos()
    }

    /// A plane whose tonemapped value is the truth plus `amp` times the noise of `stream`
    /// (stream 0: a smooth error instead, the same in every frame).
    fn plane(f: usize, amp: f32, stream: u64) -> Plane {
        Plane::from_fn(192, 128, 3, |x, y, c| {
            let e = if stream == 0 {
                ((x as f32 * 0.05).sin() + (y as f32 * 0.07 + f as f32).cos()) * 0.5
            } else {
                noise(x, y, c, f, stream)
            };
            untonemap(truth(x, y, c, f) + amp * e)
        })
    }

    #[test]
    fn two_noisy_references_give_the_error_against_the_truth() {
        // a result with a small error, and two references with much more noise than that
        let frames = 4;
        let result: Vec<Plane> = (0..frames).map(|f| plane(f, 0.01, 0)).collect();
        let a: Vec<Plane> = (0..frames).map(|f| plane(f, 0.03, 1)).collect();
        let b: Vec<Plane> = (0..frames).map(|f| plane(f, 0.03, 2)).collect();
        let truth: Vec<Plane> = (0..frames)
            .map(|f| Plane::from_fn(192, 128, 3, |x, y, c| untonemap(truth(x, y, c, f))))
            .collect();
        let rows = evaluate(
            &(0..frames)
                .map(|f| (f as i64 + 3, &result[f], &a[f], &b[f]))
                .collect::<Vec<_>>(),
        )
        .unwrap();
        let m = mean_row(&rows);
        let tm = |p: &Plane| tonemap_plane(p).data().to_vec();
        let mut true_psnr = 0.0;
        let mut single_psnr = 0.0;
        let (mut true_tmse, mut single_tmse) = (0.0, 0.0);
        for f in 0..frames {
            true_psnr += psnr(&result[f], &truth[f]).unwrap() / frames as f64;
            single_psnr += psnr(&result[f], &a[f]).unwrap() / frames as f64;
            if f > 0 {
                let (r0, r1, t0, t1) = (
                    tm(&result[f - 1]),
                    tm(&result[f]),
                    tm(&truth[f - 1]),
                    tm(&truth[f]),
                );
                let (a0, a1) = (tm(&a[f - 1]), tm(&a[f]));
                let n = r1.len() as f64;
                for i in 0..r1.len() {
                    let dr = r1[i] - r0[i];
                    true_tmse += ((dr - (t1[i] - t0[i])) as f64).powi(2) / n;
                    single_tmse += ((dr - (a1[i] - a0[i])) as f64).powi(2) / n;
                }
            }
        }
        let (true_trmse, single_trmse) = (
            (true_tmse / (frames - 1) as f64).sqrt(),
            (single_tmse / (frames - 1) as f64).sqrt(),
        );
        // one reference hides the result's quality under its own noise ...
        assert!(true_psnr - single_psnr > 8.0, "{true_psnr} {single_psnr}");
        assert!(
            single_trmse > 5.0 * true_trmse,
            "{single_trmse} {true_trmse}"
        );
        // ... two give it back
        assert!((m.psnr - true_psnr).abs() < 0.3, "{} {true_psnr}", m.psnr);
        let trmse = m.trmse.unwrap();
        assert!(
            (trmse - true_trmse).abs() < 0.1 * true_trmse,
            "{trmse} {true_trmse}"
        );
        // and say how noisy they are: uniform noise of amplitude 0.03 has variance 0.0003, so
        // A − B has mean square 0.0006 (32.2 dB)
        assert!(
            (m.reference_psnr - 32.2).abs() < 0.2,
            "{}",
            m.reference_psnr
        );
        // the first frame has no predecessor
        assert!(rows[0].tpsnr.is_none() && rows[1].tpsnr.is_some());
        assert!(table(&rows).lines().count() == frames + 2);
    }

    #[test]
    fn references_of_other_sizes_are_refused() {
        let (r, a) = (plane(0, 0.0, 0), plane(0, 0.05, 1));
        let b = Plane::from_fn(32, 32, 3, |_, _, _| 0.1);
        let e = evaluate(&[(5, &r, &a, &b)]).unwrap_err().to_string();
        assert!(e.contains("frame 5: the two references"), "{e}");
    }
}
