//! Judging a result sequence against a reference (paper section 7): per-frame PSNR, SSIM and
//! relMSE, temporal stability (tMAE, tPSNR of frame-to-frame differences), and their means —
//! what `radn eval`, the HTML report and the benchmarks all compute the same way.

use std::path::PathBuf;

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::eval::metrics;
use crate::image::plane::Plane;
use crate::io::frame::FrameReader;

/// Metrics of one frame.
#[derive(serde::Serialize, Clone, Debug)]
pub struct FrameMetrics {
    /// Frame number.
    pub frame: i64,
    /// PSNR (dB) of tonemapped RGB.
    pub psnr: f64,
    /// SSIM of tonemapped RGB.
    pub ssim: f64,
    /// Relative MSE of linear RGB.
    pub relmse: f64,
    /// Mean absolute error of the frame-to-frame difference (vs the previous frame), tonemapped.
    pub tmae: Option<f64>,
    /// PSNR of the frame-to-frame difference (vs the previous frame), tonemapped.
    pub tpsnr: Option<f64>,
}

/// The frames of a result sequence matched by number with a reference's: (frame, result
/// file, reference file) in the result's order; an error when they share no frame.
pub fn match_frames(
    result: &[(i64, PathBuf)],
    reference: &[(i64, PathBuf)],
    result_name: &str,
    reference_name: &str,
) -> Result<Vec<(i64, PathBuf, PathBuf)>> {
    let pairs: Vec<(i64, PathBuf, PathBuf)> = result
        .iter()
        .filter_map(|(f, p)| {
            reference
                .iter()
                .find(|(g, _)| g == f)
                .map(|(_, q)| (*f, p.clone(), q.clone()))
        })
        .collect();
    if pairs.is_empty() {
        return Err(Error::NoCommonFrames {
            result: result_name.into(),
            reference: reference_name.into(),
        });
    }
    Ok(pairs)
}

/// A result sequence judged against the reference: per-frame metrics and the colour planes.
pub struct Evaluation {
    /// Metrics of every frame found in both sequences, in frame order.
    pub rows: Vec<FrameMetrics>,
    /// (frame, result colour, reference colour), in frame order.
    pub planes: Vec<(i64, Plane, Plane)>,
}

/// Reads the matched frames (`result` files with `result_reader`, reference files with
/// `reference_reader`, in parallel; `on_frame` is called as each pair is read) and computes
/// the metrics. Temporal metrics compare each frame with the previous one where the two are
/// one sequence step apart.
pub fn evaluate(
    pairs: &[(i64, PathBuf, PathBuf)],
    result_reader: &FrameReader,
    reference_reader: &FrameReader,
    on_frame: impl Fn() + Sync,
) -> Result<Evaluation> {
    let planes: Vec<(i64, Plane, Plane)> = pairs
        .par_iter()
        .map(|(f, p, q)| -> Result<(i64, Plane, Plane)> {
            let r = result_reader.read(p)?.0;
            let g = reference_reader.read(q)?.0;
            r.ensure_size(g.width(), g.height())?;
            on_frame();
            Ok((*f, r.color, g.color))
        })
        .collect::<Result<_>>()?;
    let step = planes
        .windows(2)
        .map(|w| w[1].0 - w[0].0)
        .min()
        .unwrap_or(1);
    let rows: Vec<FrameMetrics> = planes
        .iter()
        .enumerate()
        .map(|(i, (f, r, g))| -> Result<FrameMetrics> {
            let (tmae, tpsnr) = match i.checked_sub(1).map(|j| &planes[j]) {
                Some((pf, pr, pg)) if f - pf == step => {
                    let (m, p) = metrics::temporal(pr, r, pg, g)?;
                    (Some(m), Some(p))
                }
                _ => (None, None),
            };
            Ok(FrameMetrics {
                frame: *f,
                psnr: metrics::psnr(r, g)?,
                ssim: metrics::ssim(r, g)?,
                relmse: metrics::relmse(r, g)?,
                tmae,
                tpsnr,
            })
        })
        .collect::<Result<_>>()?;
    Ok(Evaluation { rows, planes })
}

/// The mean over frames (temporal metrics over the frames that have them); `frame` is `i64::MIN`.
pub fn mean_row(rows: &[FrameMetrics]) -> FrameMetrics {
    let n = rows.len() as f64;
    let opt_mean = |f: &dyn Fn(&FrameMetrics) -> Option<f64>| {
        let v: Vec<f64> = rows.iter().filter_map(f).collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    FrameMetrics {
        frame: i64::MIN,
        psnr: rows.iter().map(|r| r.psnr).sum::<f64>() / n,
        ssim: rows.iter().map(|r| r.ssim).sum::<f64>() / n,
        relmse: rows.iter().map(|r| r.relmse).sum::<f64>() / n,
        tmae: opt_mean(&|r| r.tmae),
        tpsnr: opt_mean(&|r| r.tpsnr),
    }
}

/// The metrics as a text table: one line per frame, then the mean.
pub fn table(rows: &[FrameMetrics]) -> String {
    use std::fmt::Write;
    let mut s = format!(
        "{:>8} {:>9} {:>8} {:>10} {:>9} {:>8}\n",
        "frame", "PSNR", "SSIM", "relMSE", "tMAE", "tPSNR"
    );
    let mean = mean_row(rows);
    for r in rows.iter().chain(std::iter::once(&mean)) {
        let _ = writeln!(
            s,
            "{:>8} {:>9.3} {:>8.4} {:>10.5} {:>9} {:>8}",
            row_label(r.frame),
            r.psnr,
            r.ssim,
            r.relmse,
            opt(r.tmae, 5),
            opt(r.tpsnr, 2)
        );
    }
    s
}

/// A table row's label: the frame number, or `mean` for a mean row (`frame` is `i64::MIN`).
pub(crate) fn row_label(frame: i64) -> String {
    if frame == i64::MIN {
        "mean".to_string()
    } else {
        frame.to_string()
    }
}

/// An optional metric with `prec` decimals, `-` where the frame has none.
pub(crate) fn opt(v: Option<f64>, prec: usize) -> String {
    v.map_or("-".to_string(), |v| format!("{v:.prec$}"))
}

/// The metrics as JSON: the two sequences' names, every frame's row and the mean.
pub fn to_json(rows: &[FrameMetrics], result: &str, reference: &str) -> String {
    let mut m = serde_json::to_value(mean_row(rows)).expect("metrics serialise");
    m["frame"] = serde_json::Value::Null;
    let v =
        serde_json::json!({"result": result, "reference": reference, "frames": rows, "mean": m});
    serde_json::to_string_pretty(&v).expect("metrics serialise")
}

/// The per-frame metrics as CSV (a header line, then one line per frame).
pub fn to_csv(rows: &[FrameMetrics]) -> String {
    let mut w = csv::Writer::from_writer(Vec::new());
    for r in rows {
        w.serialize(r).expect("metrics serialise");
    }
    String::from_utf8(w.into_inner().expect("in-memory CSV")).expect("CSV of numbers is UTF-8")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(frame: i64, psnr: f64, tmae: Option<f64>) -> FrameMetrics {
        FrameMetrics {
            frame,
            psnr,
            ssim: 0.5,
            relmse: 0.1,
            tmae,
            tpsnr: tmae.map(|t| 10.0 * t),
        }
    }

    #[test]
    fn means_skip_frames_without_temporal_metrics() {
        let m = mean_row(&[
            row(1, 30.0, None),
            row(2, 32.0, Some(0.2)),
            row(3, 34.0, Some(0.4)),
        ]);
        assert!((m.psnr - 32.0).abs() < 1e-12);
        assert!((m.tmae.unwrap() - 0.3).abs() < 1e-12);
        assert_eq!(m.frame, i64::MIN);
    }

    #[test]
    fn frames_match_by_number_and_none_in_common_is_an_error() {
        let p = |f: i64| (f, PathBuf::from(format!("{f}.exr")));
        let pairs = match_frames(&[p(1), p(2), p(3)], &[p(2), p(3), p(4)], "r", "g").unwrap();
        assert_eq!(pairs.iter().map(|x| x.0).collect::<Vec<_>>(), vec![2, 3]);
        let e = match_frames(&[p(1)], &[p(2)], "r", "g")
            .unwrap_err()
            .to_string();
        assert!(e.contains("no frame number is in both 'r' and 'g'"), "{e}");
    }

    #[test]
    fn csv_and_json_hold_every_frame() {
        let rows = [row(7, 30.0, None), row(8, 31.0, Some(0.1))];
        let csv = to_csv(&rows);
        assert_eq!(csv.lines().count(), 3);
        assert!(csv.starts_with("frame,psnr,ssim,relmse,tmae,tpsnr"));
        let v: serde_json::Value = serde_json::from_str(&to_json(&rows, "r", "g")).unwrap();
        assert_eq!(v["frames"].as_array().unwrap().len(), 2);
        assert!(v["mean"]["frame"].is_null());
    }
}
