//! Image filters shared by alignment, metrics and the classic denoiser: Gaussian and box
//! blurs, pyramid resampling, gradients, median filtering.

use rayon::prelude::*;

use crate::image::plane::Plane;

/// Separable Gaussian blur of every channel (edge repeat).
pub fn gaussian(p: &Plane, sigma: f32) -> Plane {
    if sigma <= 0.0 {
        return p.clone();
    }
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f32 = k.iter().sum();
    let k: Vec<f32> = k.into_iter().map(|v| v / s).collect();
    separable(p, &k)
}

/// Applies the same 1-D kernel along x then y.
pub fn separable(p: &Plane, k: &[f32]) -> Plane {
    let (w, h) = (p.width(), p.height());
    let r = (k.len() / 2) as isize;
    let mut tmp = Plane::zeros(w, h, p.channels());
    tmp.data_mut()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(row, dst)| {
            let src = &p.data()[row * w..(row + 1) * w];
            for (x, d) in dst.iter_mut().enumerate() {
                let mut acc = 0.0;
                for (j, kv) in k.iter().enumerate() {
                    let xx = (x as isize + j as isize - r).clamp(0, w as isize - 1) as usize;
                    acc += kv * src[xx];
                }
                *d = acc;
            }
        });
    let mut out = Plane::zeros(w, h, p.channels());
    out.data_mut()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(row, dst)| {
            let c = row / h;
            let y = row % h;
            let ch = tmp.channel(c);
            for (x, d) in dst.iter_mut().enumerate() {
                let mut acc = 0.0;
                for (j, kv) in k.iter().enumerate() {
                    let yy = (y as isize + j as isize - r).clamp(0, h as isize - 1) as usize;
                    acc += kv * ch[yy * w + x];
                }
                *d = acc;
            }
        });
    out
}

/// Box mean of every channel over a (2r+1)² window with edge repeat, O(1) per pixel.
pub fn box_mean(p: &Plane, r: usize) -> Plane {
    let (w, h) = (p.width(), p.height());
    let area = ((2 * r + 1) * (2 * r + 1)) as f32;
    let mut out = Plane::zeros(w, h, p.channels());
    let mut tmp = vec![0f32; w * h];
    for c in 0..p.channels() {
        let dst = out.channel_mut(c);
        box_sum_into(p.channel(c), w, h, r, &mut tmp, dst);
        dst.par_iter_mut().for_each(|v| *v /= area);
    }
    out
}

/// Halves the resolution (Gaussian prefilter, then bilinear resampling at the new centres).
pub fn downsample(p: &Plane, w2: usize, h2: usize) -> Plane {
    let sx = p.width() as f32 / w2 as f32;
    let sy = p.height() as f32 / h2 as f32;
    let blurred = gaussian(p, 0.6 * sx.max(sy));
    resample(&blurred, w2, h2)
}

/// Bilinear resampling to a new size (pixel centres aligned).
pub fn resample(p: &Plane, w2: usize, h2: usize) -> Plane {
    let sx = p.width() as f32 / w2 as f32;
    let sy = p.height() as f32 / h2 as f32;
    let mut out = Plane::zeros(w2, h2, p.channels());
    out.data_mut()
        .par_chunks_mut(w2)
        .enumerate()
        .for_each(|(row, dst)| {
            let c = row / h2;
            let y = row % h2;
            for (x, d) in dst.iter_mut().enumerate() {
                *d = crate::align::motion::bilinear(
                    p,
                    c,
                    (x as f32 + 0.5) * sx - 0.5,
                    (y as f32 + 0.5) * sy - 0.5,
                );
            }
        });
    out
}

/// Central-difference gradient of a one-channel plane: (d/dx, d/dy).
pub fn gradient(p: &Plane) -> (Plane, Plane) {
    let (w, h) = (p.width(), p.height());
    let d = p.data();
    let mut gx = Plane::zeros(w, h, 1);
    let mut gy = Plane::zeros(w, h, 1);
    gx.data_mut()
        .par_chunks_mut(w)
        .zip(gy.data_mut().par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (rx, ry))| {
            let ym = y.saturating_sub(1);
            let yp = (y + 1).min(h - 1);
            for x in 0..w {
                let xm = x.saturating_sub(1);
                let xp = (x + 1).min(w - 1);
                rx[x] = (d[y * w + xp] - d[y * w + xm]) / (xp - xm).max(1) as f32;
                ry[x] = (d[yp * w + x] - d[ym * w + x]) / (yp - ym).max(1) as f32;
            }
        });
    (gx, gy)
}

/// Every sample of every channel replaced by `f` of its 3×3 neighbourhood (edge repeat; row
/// by row, the sample itself at index 4): the one loop behind the 3×3 rank filters below.
fn map_3x3(p: &Plane, f: impl Fn(&mut [f32; 9]) -> f32 + Sync) -> Plane {
    let (w, h) = (p.width(), p.height());
    let mut out = Plane::zeros(w, h, p.channels());
    out.data_mut()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(row, dst)| {
            let c = row / h;
            let y = row % h;
            let ch = p.channel(c);
            let mut v = [0f32; 9];
            for (x, d) in dst.iter_mut().enumerate() {
                let mut k = 0;
                for dy in [-1isize, 0, 1] {
                    let yy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
                    for dx in [-1isize, 0, 1] {
                        let xx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
                        v[k] = ch[yy * w + xx];
                        k += 1;
                    }
                }
                *d = f(&mut v);
            }
        });
    out
}

/// 3×3 median of every channel (edge repeat).
pub fn median3(p: &Plane) -> Plane {
    map_3x3(p, |v| {
        v.sort_unstable_by(f32::total_cmp);
        v[4]
    })
}

/// Every sample limited to `factor` times the brightest of its eight neighbours (edge repeat;
/// `hi + (factor − 1)·|hi|`, so it also holds where they are negative), per channel: an
/// isolated firefly one pixel wide is cut down to a plausible value, while every sample at most
/// `factor` times its brightest neighbour — texture, edges, any feature two pixels wide — is
/// kept exactly. Dark outliers are left alone: they do not spread into a neighbourhood's mean.
pub fn clamp_fireflies3(p: &Plane, factor: f32) -> Plane {
    map_3x3(p, |v| {
        let hi = v[..4]
            .iter()
            .chain(&v[5..])
            .fold(f32::NEG_INFINITY, |m, &x| m.max(x));
        v[4].min(hi + (factor - 1.0) * hi.abs())
    })
}

/// Luminance (Rec. 709) of an RGB plane.
pub fn luminance(rgb: &Plane) -> Plane {
    let n = rgb.pixels();
    let d = rgb.data();
    let v: Vec<f32> = (0..n)
        .into_par_iter()
        .map(|i| 0.2126 * d[i] + 0.7152 * d[n + i] + 0.0722 * d[2 * n + i])
        .collect();
    Plane::from_vec(rgb.width(), rgb.height(), 1, v)
}

/// Box sum over a (2r+1)² window of a one-channel buffer (edge repeat), by running sums:
/// the cost does not depend on `r`. Rows, then column chunks, run in parallel.
pub fn box_sum_into(src: &[f32], w: usize, h: usize, r: usize, tmp: &mut [f32], out: &mut [f32]) {
    let ri = r as isize;
    tmp.par_chunks_mut(w).enumerate().for_each(|(y, dst)| {
        let row = &src[y * w..(y + 1) * w];
        // running sums in f64: in f32 they drift along a row by the rounding of every step
        let at = |i: isize| row[i.clamp(0, w as isize - 1) as usize] as f64;
        let mut acc: f64 = (-ri..=ri).map(at).sum();
        for (x, d) in dst.iter_mut().enumerate() {
            *d = acc as f32;
            acc += at(x as isize + ri + 1) - at(x as isize - ri);
        }
    });
    const CHUNK: usize = 64;
    let tmp: &[f32] = tmp;
    let cols: Vec<(usize, Vec<f32>)> = (0..w.div_ceil(CHUNK))
        .into_par_iter()
        .map(|k| {
            let x0 = k * CHUNK;
            let x1 = (x0 + CHUNK).min(w);
            let cw = x1 - x0;
            let row = |y: isize| &tmp[(y.clamp(0, h as isize - 1) as usize) * w + x0..][..cw];
            let mut acc = vec![0f64; cw];
            for y in -ri..=ri {
                for (a, v) in acc.iter_mut().zip(row(y)) {
                    *a += *v as f64;
                }
            }
            let mut block = vec![0f32; cw * h];
            for y in 0..h {
                for (b, a) in block[y * cw..(y + 1) * cw].iter_mut().zip(&acc) {
                    *b = *a as f32;
                }
                let (add, sub) = (row(y as isize + ri + 1), row(y as isize - ri));
                for i in 0..cw {
                    acc[i] += add[i] as f64 - sub[i] as f64;
                }
            }
            (x0, block)
        })
        .collect();
    for (x0, block) in cols {
        let cw = block.len() / h;
        for y in 0..h {
            out[y * w + x0..y * w + x0 + cw].copy_from_slice(&block[y * cw..(y + 1) * cw]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_mean_matches_brute_force() {
        let p = Plane::from_fn(23, 17, 2, |x, y, c| ((x * 7 + y * 3 + c * 5) % 11) as f32);
        for r in [1usize, 5] {
            let b = box_mean(&p, r);
            for c in 0..2 {
                for y in 0..17 {
                    for x in 0..23 {
                        let mut s = 0.0;
                        for dy in -(r as isize)..=r as isize {
                            for dx in -(r as isize)..=r as isize {
                                let xx = (x as isize + dx).clamp(0, 22) as usize;
                                let yy = (y as isize + dy).clamp(0, 16) as usize;
                                s += p.get(xx, yy, c);
                            }
                        }
                        let want = s / ((2 * r + 1) * (2 * r + 1)) as f32;
                        assert!((b.get(x, y, c) - want).abs() < 1e-4, "r={r} ({x},{y})");
                    }
                }
            }
        }
    }

    #[test]
    fn median_removes_an_outlier() {
        let mut p = Plane::filled(5, 5, 1, 1.0);
        p.set(2, 2, 0, 100.0);
        assert_eq!(median3(&p).get(2, 2, 0), 1.0);
    }

    #[test]
    fn firefly_clamp_cuts_a_lone_firefly_and_keeps_detail() {
        // a ramp with a firefly, a dark speck, a 3x-bright texel and a line two pixels wide
        let mut p = Plane::from_fn(9, 7, 1, |x, y, _| {
            if x == 5 || x == 6 {
                50.0
            } else {
                0.1 * (x + y + 1) as f32
            }
        });
        p.set(2, 3, 0, 800.0);
        p.set(1, 5, 0, -4.0);
        p.set(2, 1, 0, 3.0 * p.get(3, 2, 0));
        let d = clamp_fireflies3(&p, 4.0);
        // the firefly is cut to 4x its brightest neighbour, (3, 4)
        assert!((d.get(2, 3, 0) - 4.0 * 0.1 * 8.0).abs() < 1e-5);
        for y in 0..7 {
            for x in 0..9 {
                if (x, y) != (2, 3) {
                    assert_eq!(d.get(x, y, 0), p.get(x, y, 0), "({x},{y}) changed");
                }
            }
        }
    }
}
