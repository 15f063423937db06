//! The HTML report (`radn eval --html DIR`): a report to look at rather than read —
//! side-by-side crops of every method against the reference, kernel-weight heat maps, the
//! metric table and per-frame plots.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::eval::evaluation::{mean_row, FrameMetrics};
use crate::eval::metrics::tonemap;
use crate::image::plane::Plane;
use crate::io::output::{write_bytes_atomically, write_png, PngColor};

/// One sequence shown in the report.
pub struct Shown {
    /// Its name in the report.
    pub name: String,
    /// Where it was read from (pattern or folder).
    pub spec: String,
    /// Its metrics per frame.
    pub rows: Vec<FrameMetrics>,
    /// Colour of the frame the crops come from.
    pub color: Plane,
}

/// Side length of the square crops (pixels of the frame; shown enlarged when small).
const CROP: usize = 96;

/// Writes the report into `dir` (`index.html` and its images in `img/`): crops of every
/// `shown` sequence and of the `reference` (colour of frame `display`, read from
/// `reference_spec`) where the reference has the most detail and where the first sequence errs
/// most, the metric table and per-frame charts, and — given the kernel-weight planes of each
/// window frame at `display` (`heat`, in window order) — their heat maps. Returns the page's path.
pub fn write_report(
    dir: &Path,
    shown: &[Shown],
    reference_spec: &str,
    reference: &Plane,
    display: i64,
    heat: Option<&[Plane]>,
) -> Result<PathBuf> {
    let img = dir.join("img");
    std::fs::create_dir_all(&img).map_err(|source| Error::Write {
        path: img.clone(),
        source,
    })?;
    // what an earlier report run killed while writing left behind
    crate::io::output_locks::remove_stale(dir)?;
    crate::io::output_locks::remove_stale(&img)?;

    // crops: the most detailed region of the reference, and where the main result errs most
    let crops = choose_crops(reference, &shown[0].color);
    write_png(
        &img.join("reference_full.png"),
        &outlined(&rgb8(reference), reference.width(), &crops),
        reference.width(),
        reference.height(),
        PngColor::Rgb,
    )?;
    for (k, &(x, y, s)) in crops.iter().enumerate() {
        for (j, sh) in shown.iter().enumerate() {
            let c = sh.color.crop_clamped(x as isize, y as isize, s, s);
            write_crop(&img.join(format!("crop{k}_{j}.png")), &c)?;
        }
        let c = reference.crop_clamped(x as isize, y as isize, s, s);
        write_crop(&img.join(format!("crop{k}_ref.png")), &c)?;
    }

    // kernel weight of each window frame at the report's frame
    let heat = heat.map(|mass| weight_maps(mass, &img)).transpose()?;

    let html = page(shown, reference_spec, display, &crops, heat.as_deref());
    let index = dir.join("index.html");
    write_bytes_atomically(&index, html.as_bytes())?;
    Ok(index)
}

/// Two square regions (x, y, size): the one with the most reference detail (gradient energy)
/// and, apart from it, the one where `result` is furthest from the reference.
fn choose_crops(reference: &Plane, result: &Plane) -> Vec<(usize, usize, usize)> {
    let (w, h) = (reference.width(), reference.height());
    let s = CROP.min(w).min(h);
    let tr = crate::eval::metrics::tonemap_plane(reference);
    let to = crate::eval::metrics::tonemap_plane(result);
    let step = (s / 4).max(1);
    let score = |x0: usize, y0: usize, f: &dyn Fn(usize, usize) -> f32| -> f32 {
        let mut t = 0.0;
        for y in (y0..y0 + s).step_by(2) {
            for x in (x0..x0 + s).step_by(2) {
                t += f(x, y);
            }
        }
        t
    };
    let detail = |x: usize, y: usize| -> f32 {
        let (xn, yn) = ((x + 1).min(w - 1), (y + 1).min(h - 1));
        (0..3)
            .map(|c| {
                (tr.get(xn, y, c) - tr.get(x, y, c)).abs()
                    + (tr.get(x, yn, c) - tr.get(x, y, c)).abs()
            })
            .sum()
    };
    let error = |x: usize, y: usize| -> f32 {
        (0..3)
            .map(|c| (to.get(x, y, c) - tr.get(x, y, c)).powi(2))
            .sum()
    };
    let positions: Vec<(usize, usize)> = (0..=(h - s))
        .step_by(step)
        .flat_map(|y| (0..=(w - s)).step_by(step).map(move |x| (x, y)))
        .collect();
    let best = |f: &dyn Fn(usize, usize) -> f32, avoid: Option<(usize, usize)>| {
        positions
            .iter()
            .filter(|(x, y)| {
                avoid.is_none_or(|(ax, ay)| x.abs_diff(ax) >= s / 2 || y.abs_diff(ay) >= s / 2)
            })
            .map(|&(x, y)| (score(x, y, f), x, y))
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, x, y)| (x, y))
    };
    let mut out = Vec::new();
    if let Some((x, y)) = best(&detail, None) {
        out.push((x, y, s));
        if let Some((x2, y2)) = best(&error, Some((x, y))) {
            out.push((x2, y2, s));
        }
    }
    out
}

/// Tonemapped 8-bit sRGB-ish RGB bytes of a colour plane (the metrics' tonemap).
fn rgb8(p: &Plane) -> Vec<u8> {
    let (w, h) = (p.width(), p.height());
    let mut v = Vec::with_capacity(w * h * 3);
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                v.push((tonemap(p.get(x, y, c.min(p.channels() - 1))) * 255.0).round() as u8);
            }
        }
    }
    v
}

/// Draws the crop rectangles (yellow) onto RGB bytes.
fn outlined(rgb: &[u8], w: usize, crops: &[(usize, usize, usize)]) -> Vec<u8> {
    let mut v = rgb.to_vec();
    let mut put = |x: usize, y: usize| {
        let i = (y * w + x) * 3;
        if i + 2 < v.len() {
            v[i..i + 3].copy_from_slice(&[255, 220, 0]);
        }
    };
    for &(x0, y0, s) in crops {
        for t in 0..s {
            put(x0 + t, y0);
            put(x0 + t, y0 + s - 1);
            put(x0, y0 + t);
            put(x0 + s - 1, y0 + t);
        }
    }
    v
}

/// Writes a crop enlarged (nearest neighbour) to at least 256 pixels wide, so noise is visible.
fn write_crop(path: &Path, c: &Plane) -> Result<()> {
    let scale = (256 / c.width().max(1)).max(1);
    let rgb = rgb8(c);
    let (w, h) = (c.width() * scale, c.height() * scale);
    let mut big = Vec::with_capacity(w * h * 3);
    for y in 0..h {
        for x in 0..w {
            let i = ((y / scale) * c.width() + x / scale) * 3;
            big.extend_from_slice(&rgb[i..i + 3]);
        }
    }
    write_png(path, &big, w, h, PngColor::Rgb)
}

/// A weight in [0, 1] as a colour: dark blue (none) through teal and green to yellow (all).
fn ramp(v: f32) -> [u8; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [0.07, 0.04, 0.33],
        [0.23, 0.32, 0.55],
        [0.13, 0.57, 0.55],
        [0.37, 0.79, 0.38],
        [0.99, 0.91, 0.15],
    ];
    let t = v.clamp(0.0, 1.0) * 4.0;
    let i = (t.floor() as usize).min(3);
    let f = t - i as f32;
    let mut out = [0u8; 3];
    for c in 0..3 {
        out[c] = ((STOPS[i][c] * (1.0 - f) + STOPS[i + 1][c] * f) * 255.0).round() as u8;
    }
    out
}

/// Writes the kernel weight of each window frame (`mass`, in window order) as colour maps;
/// returns the window offsets with their mean weight.
fn weight_maps(mass: &[Plane], img: &Path) -> Result<Vec<(i64, f64)>> {
    let t = mass.len();
    let mut out = Vec::new();
    for (k, m) in mass.iter().enumerate() {
        let offset = k as i64 - (t / 2) as i64;
        let rgb: Vec<u8> = m.data().iter().flat_map(|&v| ramp(v)).collect();
        write_png(
            &img.join(format!("weight_{k}.png")),
            &rgb,
            m.width(),
            m.height(),
            PngColor::Rgb,
        )?;
        let mean = m.data().iter().map(|&v| v as f64).sum::<f64>() / m.pixels() as f64;
        out.push((offset, mean));
    }
    Ok(out)
}

/// Escapes text for HTML.
fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

const COLORS: [&str; 6] = [
    "#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b",
];

/// An SVG line chart of one metric per frame, one line per sequence.
fn chart(shown: &[Shown], title: &str, get: &dyn Fn(&FrameMetrics) -> Option<f64>) -> String {
    let (w, h, l, b) = (520.0, 260.0, 56.0, 36.0);
    let pts: Vec<(i64, f64)> = shown
        .iter()
        .flat_map(|s| s.rows.iter().filter_map(|r| get(r).map(|v| (r.frame, v))))
        .collect();
    if pts.is_empty() {
        return String::new();
    }
    let (f0, f1) = (
        pts.iter().map(|p| p.0).min().unwrap_or(0),
        pts.iter().map(|p| p.0).max().unwrap_or(1),
    );
    let (mut v0, mut v1) = (
        pts.iter().map(|p| p.1).fold(f64::INFINITY, f64::min),
        pts.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max),
    );
    let pad = ((v1 - v0) * 0.08).max(1e-6);
    v0 -= pad;
    v1 += pad;
    let x = |f: i64| l + (w - l - 10.0) * (f - f0) as f64 / ((f1 - f0).max(1)) as f64;
    let y = |v: f64| 10.0 + (h - b - 10.0) * (1.0 - (v - v0) / (v1 - v0));
    let mut s = format!(
        "<svg width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\" class=\"chart\"><text x=\"{}\" y=\"{}\" class=\"t\">{}</text>",
        l,
        h - 4.0,
        esc(title)
    );
    for k in 0..=4 {
        let v = v0 + (v1 - v0) * k as f64 / 4.0;
        let _ = write!(
            s,
            "<line x1=\"{l}\" x2=\"{}\" y1=\"{y:.1}\" y2=\"{y:.1}\" class=\"g\"/><text x=\"{}\" y=\"{:.1}\" class=\"a\" text-anchor=\"end\">{}</text>",
            w - 10.0,
            l - 4.0,
            y(v) + 4.0,
            fmt_axis(v),
            y = y(v)
        );
    }
    for f in f0..=f1 {
        let _ = write!(
            s,
            "<text x=\"{:.1}\" y=\"{}\" class=\"a\" text-anchor=\"middle\">{f}</text>",
            x(f),
            h - b + 14.0
        );
    }
    for (i, sh) in shown.iter().enumerate() {
        let line: Vec<String> = sh
            .rows
            .iter()
            .filter_map(|r| get(r).map(|v| format!("{:.1},{:.1}", x(r.frame), y(v))))
            .collect();
        let _ = write!(
            s,
            "<polyline points=\"{}\" fill=\"none\" stroke=\"{}\" stroke-width=\"2\"/>",
            line.join(" "),
            COLORS[i % COLORS.len()]
        );
    }
    s.push_str("</svg>");
    s
}

fn fmt_axis(v: f64) -> String {
    if v.abs() >= 10.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.4}")
    }
}

/// The whole page.
fn page(
    shown: &[Shown],
    reference: &str,
    display: i64,
    crops: &[(usize, usize, usize)],
    heat: Option<&[(i64, f64)]>,
) -> String {
    let mut s = String::from(
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>radn report</title><style>\
body{font-family:system-ui,sans-serif;margin:24px;background:#fafafa;color:#222}\
table{border-collapse:collapse;margin:8px 0}td,th{padding:4px 10px;border-bottom:1px solid #ddd;text-align:right}\
th:first-child,td:first-child{text-align:left}.best{font-weight:bold;color:#0a6}\
figure{display:inline-block;margin:4px;text-align:center}figure img{image-rendering:pixelated;border:1px solid #ccc}\
.chart{background:#fff;border:1px solid #ddd;margin:4px}.g{stroke:#eee}.a{font-size:11px;fill:#666}.t{font-size:13px}\
.key span{display:inline-block;width:12px;height:12px;margin:0 4px 0 12px;vertical-align:middle}\
code{background:#eee;padding:1px 4px}</style></head><body><h1>radn report</h1>",
    );
    let _ = write!(
        s,
        "<p>Reference: <code>{}</code>. Crops and heat maps show frame {display}.</p>",
        esc(reference)
    );
    // metric table, best value per column in bold
    let means: Vec<FrameMetrics> = shown.iter().map(|x| mean_row(&x.rows)).collect();
    let best = |f: &dyn Fn(&FrameMetrics) -> Option<f64>, higher: bool| -> Option<f64> {
        let it = means.iter().filter_map(f);
        if higher {
            it.fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v))))
        } else {
            it.fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.min(v))))
        }
    };
    type Col<'a> = (
        &'a str,
        Box<dyn Fn(&FrameMetrics) -> Option<f64>>,
        bool,
        usize,
    );
    let cols: Vec<Col> = vec![
        ("PSNR (dB)", Box::new(|r| Some(r.psnr)), true, 2),
        ("SSIM", Box::new(|r| Some(r.ssim)), true, 4),
        ("relMSE", Box::new(|r| Some(r.relmse)), false, 5),
        ("tMAE", Box::new(|r| r.tmae), false, 5),
        ("tPSNR (dB)", Box::new(|r| r.tpsnr), true, 2),
    ];
    s.push_str("<h2>Metrics (mean over frames)</h2><table><tr><th>sequence</th>");
    for c in &cols {
        let _ = write!(s, "<th>{}</th>", c.0);
    }
    s.push_str("<th>frames</th></tr>");
    for (sh, m) in shown.iter().zip(&means) {
        let _ = write!(
            s,
            "<tr><td title=\"{}\">{}</td>",
            esc(&sh.spec),
            esc(&sh.name)
        );
        for (_, f, higher, prec) in &cols {
            let b = best(f.as_ref(), *higher);
            match f(m) {
                Some(v) => {
                    let cls = if Some(v) == b { " class=\"best\"" } else { "" };
                    let _ = write!(s, "<td{cls}>{v:.prec$}</td>", prec = *prec);
                }
                None => s.push_str("<td>-</td>"),
            }
        }
        let _ = write!(s, "<td>{}</td></tr>", sh.rows.len());
    }
    s.push_str("</table><p>PSNR and SSIM on tonemapped colour; relMSE on linear colour; tMAE and tPSNR compare frame-to-frame differences with the reference's (temporal stability; lower tMAE is steadier).</p>");
    // plots
    s.push_str("<h2>Per frame</h2><div class=\"key\">");
    for (i, sh) in shown.iter().enumerate() {
        let _ = write!(
            s,
            "<span style=\"background:{}\"></span>{}",
            COLORS[i % COLORS.len()],
            esc(&sh.name)
        );
    }
    s.push_str("</div>");
    s.push_str(&chart(shown, "PSNR (dB) per frame", &|r| Some(r.psnr)));
    s.push_str(&chart(shown, "SSIM per frame", &|r| Some(r.ssim)));
    s.push_str(&chart(shown, "tMAE per frame (lower is steadier)", &|r| {
        r.tmae
    }));
    // crops
    s.push_str("<h2>Crops</h2><figure><img src=\"img/reference_full.png\"><figcaption>reference, crops outlined</figcaption></figure>");
    for (k, &(x, y, size)) in crops.iter().enumerate() {
        let what = if k == 0 {
            "most detailed region"
        } else {
            "where the first sequence errs most"
        };
        let _ = write!(
            s,
            "<h3>Crop {} — {what} ({size}×{size} at {x}, {y})</h3><div>",
            k + 1
        );
        for (j, sh) in shown.iter().enumerate() {
            let _ = write!(
                s,
                "<figure><img src=\"img/crop{k}_{j}.png\"><figcaption>{}</figcaption></figure>",
                esc(&sh.name)
            );
        }
        let _ = write!(
            s,
            "<figure><img src=\"img/crop{k}_ref.png\"><figcaption>reference</figcaption></figure></div>"
        );
    }
    if let Some(heat) = heat {
        s.push_str("<h2>Kernel weight per window frame</h2><p>The share of each output pixel's kernel that falls on each frame of the 5-frame window (paper Fig. 6): dark blue none, yellow all. Mean over pixels under each map.</p><div>");
        for (k, (offset, mean)) in heat.iter().enumerate() {
            let _ = write!(
                s,
                "<figure><img src=\"img/weight_{k}.png\" width=\"256\"><figcaption>frame {offset:+} — mean {mean:.3}</figcaption></figure>"
            );
        }
        s.push_str("</div>");
    }
    s.push_str("</body></html>\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crops_find_the_detail_and_the_error() {
        // flat reference except a checkerboard at (10..40, 60..90); result wrong at (100.., 0..)
        let (w, h) = (160, 120);
        let reference = Plane::from_fn(w, h, 3, |x, y, _| {
            if (10..40).contains(&x) && (60..90).contains(&y) {
                ((x + y) % 2) as f32
            } else {
                0.3
            }
        });
        let mut result = reference.clone();
        for y in 0..40 {
            for x in 120..160 {
                for c in 0..3 {
                    result.set(x, y, c, 5.0);
                }
            }
        }
        let crops = choose_crops(&reference, &result);
        assert_eq!(crops.len(), 2);
        let contains = |(x, y, s): (usize, usize, usize), px: usize, py: usize| {
            (x..x + s).contains(&px) && (y..y + s).contains(&py)
        };
        assert!(contains(crops[0], 25, 75), "{crops:?}");
        assert!(contains(crops[1], 140, 20), "{crops:?}");
    }

    #[test]
    fn ramp_runs_from_dark_blue_to_yellow() {
        assert!(ramp(0.0)[2] > ramp(0.0)[0] && ramp(0.0)[0] < 40);
        assert!(ramp(1.0)[0] > 240 && ramp(1.0)[2] < 60);
    }
}
