//! Training curves as a PNG (`curves.png` beside `metrics.csv`): loss (training and
//! validation), validation PSNR and each layer group's update-to-weight ratio against the step, drawn on an RGB canvas with 8×8 bitmap
//! glyphs, so no font file or system library is needed.

use std::path::Path;

use font8x8::UnicodeFonts;

use radn_nn::error::{NnError, Result};

/// An RGB canvas.
struct Canvas {
    w: usize,
    h: usize,
    px: Vec<u8>,
}

impl Canvas {
    fn new(w: usize, h: usize) -> Self {
        Self {
            w,
            h,
            px: vec![255; w * h * 3],
        }
    }

    fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.w && (y as usize) < self.h {
            let i = (y as usize * self.w + x as usize) * 3;
            self.px[i..i + 3].copy_from_slice(&c);
        }
    }

    /// A line of the given thickness (Bresenham, widened).
    fn line(&mut self, (x0, y0): (i64, i64), (x1, y1): (i64, i64), c: [u8; 3], thick: i64) {
        let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
        let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
        let (mut x, mut y, mut err) = (x0, y0, dx + dy);
        loop {
            for ox in 0..thick {
                for oy in 0..thick {
                    self.set(x + ox - thick / 2, y + oy - thick / 2, c);
                }
            }
            if x == x1 && y == y1 {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    /// Text with its top-left corner at (x, y), glyphs scaled by `s`.
    fn text(&mut self, x: i64, y: i64, s: i64, text: &str, c: [u8; 3]) {
        for (k, ch) in text.chars().enumerate() {
            let glyph = font8x8::BASIC_FONTS.get(ch).unwrap_or([0; 8]);
            for (row, bits) in glyph.iter().enumerate() {
                for col in 0..8 {
                    if bits & (1 << col) != 0 {
                        for oy in 0..s {
                            for ox in 0..s {
                                self.set(
                                    x + (k as i64 * 8 + col) * s + ox,
                                    y + row as i64 * s + oy,
                                    c,
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    fn png(&self) -> Vec<u8> {
        radn_core::io::output::encode_png(
            &self.px,
            self.w,
            self.h,
            radn_core::io::output::PngColor::Rgb,
        )
    }
}

/// One curve.
pub struct Series {
    /// Legend text.
    pub name: String,
    /// Line colour.
    pub color: [u8; 3],
    /// Line thickness in pixels.
    pub thick: i64,
    /// (x, y) points in order.
    pub points: Vec<(f64, f64)>,
}

const AXIS: [u8; 3] = [60, 60, 60];
const GRID: [u8; 3] = [225, 225, 225];

fn fmt_tick(v: f64) -> String {
    if v.abs() >= 100.0 || v == v.trunc() {
        format!("{v:.0}")
    } else if v.abs() >= 1.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.3}")
    }
}

/// Draws one panel of curves into the canvas region starting at (ox, oy).
fn panel(cv: &mut Canvas, ox: i64, oy: i64, w: i64, h: i64, title: &str, series: &[Series]) {
    let pts: Vec<(f64, f64)> = series
        .iter()
        .flat_map(|s| s.points.iter().copied())
        .filter(|p| p.1.is_finite())
        .collect();
    cv.text(ox + 60, oy + 4, 2, title, AXIS);
    let (l, r, t, b) = (ox + 60, ox + w - 10, oy + 30, oy + h - 40);
    if pts.is_empty() {
        return;
    }
    let (mut x0, mut x1) = pts
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.0), b.max(p.0))
        });
    let (mut y0, mut y1) = pts
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.1), b.max(p.1))
        });
    if x1 <= x0 {
        x1 = x0 + 1.0;
    }
    if y1 <= y0 {
        (y0, y1) = (y0 - 0.5, y1 + 0.5);
    }
    let pad = 0.05 * (y1 - y0);
    let (y0, y1) = (y0 - pad, y1 + pad);
    x0 = x0.min(x1);
    let px = |x: f64| l + ((x - x0) / (x1 - x0) * (r - l) as f64).round() as i64;
    let py = |y: f64| b - ((y - y0) / (y1 - y0) * (b - t) as f64).round() as i64;
    for k in 0..=4 {
        let yv = y0 + (y1 - y0) * k as f64 / 4.0;
        cv.line((l, py(yv)), (r, py(yv)), GRID, 1);
        cv.text(ox + 2, py(yv) - 4, 1, &fmt_tick(yv), AXIS);
        let xv = x0 + (x1 - x0) * k as f64 / 4.0;
        let label = fmt_tick(xv.round());
        cv.text(px(xv) - 4 * label.len() as i64, b + 6, 1, &label, AXIS);
    }
    cv.line((l, t), (l, b), AXIS, 1);
    cv.line((l, b), (r, b), AXIS, 1);
    cv.text((l + r) / 2 - 16, b + 20, 1, "step", AXIS);
    for (k, s) in series.iter().enumerate() {
        let p: Vec<(i64, i64)> = s
            .points
            .iter()
            .filter(|p| p.1.is_finite())
            .map(|&(x, y)| (px(x), py(y)))
            .collect();
        for w in p.windows(2) {
            cv.line(w[0], w[1], s.color, s.thick);
        }
        if p.len() == 1 {
            cv.line(p[0], p[0], s.color, s.thick + 2);
        }
        cv.line(
            (r - 150, t + 10 + 14 * k as i64),
            (r - 130, t + 10 + 14 * k as i64),
            s.color,
            3,
        );
        cv.text(r - 124, t + 6 + 14 * k as i64, 1, &s.name, AXIS);
    }
}

/// Renders two panels side by side as PNG bytes.
pub fn two_panels(left: (&str, &[Series]), right: (&str, &[Series])) -> Vec<u8> {
    panels(&[left, right])
}

/// Renders panels side by side (500 pixels wide each) as PNG bytes.
pub fn panels(list: &[(&str, &[Series])]) -> Vec<u8> {
    let (pw, h) = (500i64, 420i64);
    let mut cv = Canvas::new((pw * list.len() as i64) as usize, h as usize);
    for (k, (title, series)) in list.iter().enumerate() {
        panel(&mut cv, k as i64 * pw, 0, pw, h, title, series);
    }
    cv.png()
}

/// The per-layer update ratios of a run's `layers.csv` as one line per layer group: log10 of
/// the group's mean ratio at each logged step.
fn update_ratio_series(layers: &Path) -> Vec<Series> {
    use crate::layer_stats::{layer_group, read_update_ratios};
    let groups = [
        ("backbone convs", [60, 60, 200]),
        ("RA blocks", [200, 120, 20]),
        ("kernel head", [180, 40, 160]),
    ];
    let rows = read_update_ratios(layers);
    groups
        .iter()
        .map(|(g, color)| {
            let mut by_step: std::collections::BTreeMap<usize, (f64, usize)> = Default::default();
            for (step, layer, r) in &rows {
                if layer_group(layer) == *g && *r > 0.0 {
                    let e = by_step.entry(*step).or_default();
                    e.0 += r;
                    e.1 += 1;
                }
            }
            Series {
                name: (*g).into(),
                color: *color,
                thick: 2,
                points: by_step
                    .into_iter()
                    .map(|(s, (sum, n))| (s as f64, (sum / n as f64).log10()))
                    .collect(),
            }
        })
        .filter(|s| !s.points.is_empty())
        .collect()
}

/// Reads a run's `metrics.csv` (and its `layers.csv`, when there is one) and writes
/// `curves.png` beside it: loss, validation PSNR and, with layer statistics, each layer group's
/// update-to-weight ratio.
pub fn training_curves(csv: &Path, png_path: &Path) -> Result<()> {
    let err = |detail: String| NnError::Save {
        path: png_path.to_path_buf(),
        detail,
    };
    let text = std::fs::read_to_string(csv)
        .map_err(|e| err(format!("cannot read {}: {e}", csv.display())))?;
    let (mut train, mut val, mut psnr) = (Vec::new(), Vec::new(), Vec::new());
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() < 4 {
            continue;
        }
        let (Ok(step), Ok(loss)) = (f[0].parse::<f64>(), f[2].parse::<f64>()) else {
            continue;
        };
        match f[1] {
            "train" => train.push((step, loss)),
            "val" => {
                val.push((step, loss));
                if let Ok(p) = f[3].parse::<f64>() {
                    psnr.push((step, p));
                }
            }
            _ => {}
        }
    }
    let losses = [
        Series {
            name: "train".into(),
            color: [150, 180, 230],
            thick: 1,
            points: train,
        },
        Series {
            name: "validation".into(),
            color: [200, 40, 40],
            thick: 3,
            points: val,
        },
    ];
    let psnrs = [Series {
        name: "validation".into(),
        color: [40, 130, 40],
        thick: 3,
        points: psnr,
    }];
    let ratios = update_ratio_series(&csv.with_file_name("layers.csv"));
    let mut list: Vec<(&str, &[Series])> =
        vec![("loss", &losses), ("validation PSNR (dB)", &psnrs)];
    if !ratios.is_empty() {
        list.push(("log10 update / weight", &ratios));
    }
    let bytes = panels(&list);
    radn_core::io::output::write_bytes_atomically(png_path, &bytes).map_err(NnError::from)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn curves_png_has_the_validation_line_and_decodes() {
        let dir = tempfile::tempdir().unwrap();
        let csv = dir.path().join("metrics.csv");
        let mut text = String::from("step,kind,loss,psnr,lr,tiles_per_s\n");
        for s in 1..=50 {
            text.push_str(&format!(
                "{s},train,{:.4},,1e-3,1.0\n",
                0.5 / (1.0 + s as f64 * 0.1)
            ));
            if s % 10 == 0 {
                text.push_str(&format!(
                    "{s},val,{:.4},{:.2},1e-3,\n",
                    0.45 / (1.0 + s as f64 * 0.1),
                    20.0 + s as f64 * 0.1
                ));
            }
        }
        std::fs::write(&csv, text).unwrap();
        let out = dir.path().join("curves.png");
        training_curves(&csv, &out).unwrap();
        let decoder =
            png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&out).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (1000, 420));
        let count = |c: [u8; 3]| buf.chunks_exact(3).filter(|p| p == &c).count();
        assert!(
            count([200, 40, 40]) > 200,
            "the validation loss line is missing"
        );
        assert!(count([40, 130, 40]) > 200, "the PSNR line is missing");
        assert!(count([60, 60, 60]) > 500, "axes and labels are missing");
    }
}
