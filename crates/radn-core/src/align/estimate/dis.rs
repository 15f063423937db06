//! Dense optical flow on multi-channel images by dense inverse search (Kroeger, Timofte, Dai
//! and Van Gool 2016): coarse to fine, each level fits a displacement per overlapping patch by
//! inverse-compositional Gauss–Newton and blends the patches' displacements per pixel by how
//! well each explains that pixel.

use rayon::prelude::*;

use crate::align::motion::bilinear;
use crate::image::plane::Plane;

/// Settings of the flow solver.
#[derive(Clone, Copy, Debug)]
pub struct DisParams {
    /// Patch side (pixels).
    pub patch: usize,
    /// Distance between patches (pixels; below `patch`, so patches overlap).
    pub stride: usize,
    /// Gauss–Newton iterations per patch and level at most.
    pub iterations: usize,
    /// Levels stop halving once the smaller side would fall below this.
    pub coarsest_side: usize,
    /// Tikhonov term added to each patch's normal matrix, per patch pixel and channel: keeps a
    /// patch without texture at the displacement it started from (the coarser level's), rather
    /// than letting noise move it.
    pub damping: f32,
}

impl Default for DisParams {
    fn default() -> Self {
        Self {
            patch: 8,
            stride: 4,
            iterations: 12,
            coarsest_side: 12,
            damping: 1e-4,
        }
    }
}

/// The flow `u` (2 channels, pixels) with `b(x + u(x)) ≈ a(x)`: where each pixel of `a` is
/// found in `b`. `a` and `b` have the same size and channels.
pub fn dis_flow(a: &Plane, b: &Plane, p: &DisParams) -> Plane {
    assert!(
        a.same_size(b) && a.channels() == b.channels(),
        "images of one size"
    );
    let pyramid_a = pyramid(a, p.coarsest_side.max(p.patch));
    let pyramid_b = pyramid(b, p.coarsest_side.max(p.patch));
    let mut flow: Option<Plane> = None;
    for (la, lb) in pyramid_a.iter().zip(&pyramid_b).rev() {
        let init = match flow {
            None => Plane::zeros(la.width(), la.height(), 2),
            Some(f) => upsample_flow(&f, la.width(), la.height()),
        };
        flow = Some(level(la, lb, &init, p));
    }
    flow.expect("at least one level")
}

/// The image and its halvings (2×2 means), finest first, down to `min_side`.
fn pyramid(img: &Plane, min_side: usize) -> Vec<Plane> {
    let mut levels = vec![img.clone()];
    loop {
        let last = levels.last().expect("one level");
        let (w, h) = (last.width() / 2, last.height() / 2);
        if w.min(h) < min_side {
            return levels;
        }
        levels.push(halve(last, w, h));
    }
}

/// 2×2 means (the last odd row or column dropped).
fn halve(p: &Plane, w: usize, h: usize) -> Plane {
    let mut out = Plane::zeros(w, h, p.channels());
    let pw = p.width();
    out.data_mut()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(row, dst)| {
            let (c, y) = (row / h, row % h);
            let ch = p.channel(c);
            for (x, d) in dst.iter_mut().enumerate() {
                let i = 2 * y * pw + 2 * x;
                *d = 0.25 * (ch[i] + ch[i + 1] + ch[i + pw] + ch[i + pw + 1]);
            }
        });
    out
}

/// A coarser level's flow at the size of the next finer one, in its pixels.
fn upsample_flow(f: &Plane, w: usize, h: usize) -> Plane {
    let (sx, sy) = (w as f32 / f.width() as f32, h as f32 / f.height() as f32);
    Plane::from_fn(w, h, 2, |x, y, c| {
        let fx = (x as f32 + 0.5) / sx - 0.5;
        let fy = (y as f32 + 0.5) / sy - 0.5;
        bilinear(f, c, fx, fy) * if c == 0 { sx } else { sy }
    })
}

/// Where the patches of one axis start: every `stride` pixels, and one flush with the far edge.
fn starts(len: usize, patch: usize, stride: usize) -> Vec<usize> {
    if len <= patch {
        return vec![0];
    }
    let mut s: Vec<usize> = (0..=len - patch).step_by(stride).collect();
    if *s.last().expect("one start") != len - patch {
        s.push(len - patch);
    }
    s
}

/// One level: each patch's displacement refined from `init`, then blended per pixel.
fn level(a: &Plane, b: &Plane, init: &Plane, p: &DisParams) -> Plane {
    let (w, h, nc) = (a.width(), a.height(), a.channels());
    let ps = p.patch.min(w).min(h);
    let xs = starts(w, ps, p.stride);
    let ys = starts(h, ps, p.stride);
    let (gx, gy) = gradients(a);
    let patches: Vec<(f32, f32)> = ys
        .par_iter()
        .flat_map_iter(|&y0| {
            xs.iter()
                .map(|&x0| fit_patch(a, b, &gx, &gy, init, (x0, y0), ps, p))
                .collect::<Vec<_>>()
        })
        .collect();
    // per pixel, the patches that cover it, weighted by how well each one explains it
    let covering = |starts: &[usize], v: usize| -> std::ops::Range<usize> {
        let lo = starts.partition_point(|&s| s + ps <= v);
        let hi = starts.partition_point(|&s| s <= v);
        lo..hi
    };
    let cols: Vec<std::ops::Range<usize>> = (0..w).map(|x| covering(&xs, x)).collect();
    let mut out = Plane::zeros(w, h, 2);
    let (ox, oy) = out.data_mut().split_at_mut(w * h);
    ox.par_chunks_mut(w)
        .zip(oy.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (rx, ry))| {
            let rows = covering(&ys, y);
            for x in 0..w {
                let (mut sx, mut sy, mut sw) = (0f32, 0f32, 0f32);
                for j in rows.clone() {
                    for i in cols[x].clone() {
                        let (u, v) = patches[j * xs.len() + i];
                        let mut e = 0f32;
                        for c in 0..nc {
                            let d = bilinear(b, c, x as f32 + u, y as f32 + v) - a.get(x, y, c);
                            e += d * d;
                        }
                        let wgt = 1.0 / e.max(1e-6);
                        sx += wgt * u;
                        sy += wgt * v;
                        sw += wgt;
                    }
                }
                rx[x] = sx / sw;
                ry[x] = sy / sw;
            }
        });
    out
}

/// Central differences of every channel (one-sided at the edges).
fn gradients(p: &Plane) -> (Plane, Plane) {
    let (w, h) = (p.width(), p.height());
    let d = |x: usize, y: usize, c: usize, dx: bool| -> f32 {
        let (lo, hi) = if dx {
            (x.saturating_sub(1), (x + 1).min(w - 1))
        } else {
            (y.saturating_sub(1), (y + 1).min(h - 1))
        };
        let span = (hi - lo).max(1) as f32;
        if dx {
            (p.get(hi, y, c) - p.get(lo, y, c)) / span
        } else {
            (p.get(x, hi, c) - p.get(x, lo, c)) / span
        }
    };
    (
        Plane::from_fn(w, h, p.channels(), |x, y, c| d(x, y, c, true)),
        Plane::from_fn(w, h, p.channels(), |x, y, c| d(x, y, c, false)),
    )
}

/// Catmull-Rom weights of the four taps around a sample at fraction `t` past the second.
#[inline]
fn cubic_weights(t: f32) -> [f32; 4] {
    let (t2, t3) = (t * t, t * t * t);
    [
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    ]
}

/// One patch of `b` moved by a whole displacement: every pixel of a patch shifts by the same
/// amount, so the Catmull-Rom weights are shared and the lookup is separable.
struct PatchWarp<'a> {
    b: &'a Plane,
    ps: usize,
    /// Per channel, `ps × (ps + 3)` horizontally interpolated rows.
    rows: Vec<f32>,
}

impl<'a> PatchWarp<'a> {
    fn new(b: &'a Plane, ps: usize) -> Self {
        Self {
            b,
            ps,
            rows: vec![0.0; ps * (ps + 3)],
        }
    }

    /// The patch at `(x0, y0)` sampled at `+ (u, v)`, channel after channel, into `out`
    /// (`channels × ps × ps`); edges repeated.
    fn warp(&mut self, (x0, y0): (usize, usize), u: f32, v: f32, out: &mut [f32]) {
        let (w, h, ps) = (self.b.width() as isize, self.b.height() as isize, self.ps);
        let (sx, sy) = (x0 as f32 + u, y0 as f32 + v);
        let (ix, iy) = (sx.floor(), sy.floor());
        let (wx, wy) = (cubic_weights(sx - ix), cubic_weights(sy - iy));
        let (ix, iy) = (ix as isize, iy as isize);
        let cols: Vec<usize> = (0..ps + 3)
            .map(|j| (ix + j as isize - 1).clamp(0, w - 1) as usize)
            .collect();
        let interior = ix >= 1 && ix + ps as isize + 2 <= w;
        for c in 0..self.b.channels() {
            let ch = self.b.channel(c);
            for r in 0..ps + 3 {
                let row = (iy + r as isize - 1).clamp(0, h - 1) as usize * w as usize;
                let dst = &mut self.rows[r * ps..(r + 1) * ps];
                if interior {
                    let src = &ch[row + cols[0]..row + cols[0] + ps + 3];
                    for (x, d) in dst.iter_mut().enumerate() {
                        *d = wx[0] * src[x]
                            + wx[1] * src[x + 1]
                            + wx[2] * src[x + 2]
                            + wx[3] * src[x + 3];
                    }
                } else {
                    for (x, d) in dst.iter_mut().enumerate() {
                        *d = wx[0] * ch[row + cols[x]]
                            + wx[1] * ch[row + cols[x + 1]]
                            + wx[2] * ch[row + cols[x + 2]]
                            + wx[3] * ch[row + cols[x + 3]];
                    }
                }
            }
            let o = &mut out[c * ps * ps..(c + 1) * ps * ps];
            for y in 0..ps {
                let (r0, r1, r2, r3) = (
                    &self.rows[y * ps..],
                    &self.rows[(y + 1) * ps..],
                    &self.rows[(y + 2) * ps..],
                    &self.rows[(y + 3) * ps..],
                );
                for x in 0..ps {
                    o[y * ps + x] = wy[0] * r0[x] + wy[1] * r1[x] + wy[2] * r2[x] + wy[3] * r3[x];
                }
            }
        }
    }
}

/// A patch's pixels (channel after channel) from a plane.
fn gather(p: &Plane, (x0, y0): (usize, usize), ps: usize) -> Vec<f32> {
    let w = p.width();
    let mut out = Vec::with_capacity(p.channels() * ps * ps);
    for c in 0..p.channels() {
        let ch = p.channel(c);
        for y in y0..y0 + ps {
            out.extend_from_slice(&ch[y * w + x0..y * w + x0 + ps]);
        }
    }
    out
}

/// The displacement of the patch at `(x0, y0)` by inverse-compositional Gauss–Newton, from
/// the mean of `init` over the patch; kept at that start when the fit does not lower the
/// patch's error. Pixels whose match falls off `b` are left out (clamped edges would pull the
/// patch towards no motion).
#[allow(clippy::too_many_arguments)]
fn fit_patch(
    a: &Plane,
    b: &Plane,
    gx: &Plane,
    gy: &Plane,
    init: &Plane,
    at: (usize, usize),
    ps: usize,
    p: &DisParams,
) -> (f32, f32) {
    let nc = a.channels();
    let (x0, y0) = at;
    let (bw, bh) = ((b.width() - 1) as f32, (b.height() - 1) as f32);
    let (mut u0, mut v0) = (0f32, 0f32);
    for y in y0..y0 + ps {
        for x in x0..x0 + ps {
            u0 += init.get(x, y, 0);
            v0 += init.get(x, y, 1);
        }
    }
    let n = (ps * ps) as f32;
    (u0, v0) = (u0 / n, v0 / n);
    let damp = p.damping * n * nc as f32;
    let (t, ex, ey) = (gather(a, at, ps), gather(gx, at, ps), gather(gy, at, ps));
    let mut warp = PatchWarp::new(b, ps);
    let mut warped = vec![0f32; nc * ps * ps];
    // which of the patch's columns and rows land on `b` at a displacement
    let on_b = |u: f32, v: f32| -> (Vec<bool>, Vec<bool>) {
        (
            (0..ps)
                .map(|x| (0.0..=bw).contains(&(x0 as f32 + x as f32 + u)))
                .collect(),
            (0..ps)
                .map(|y| (0.0..=bh).contains(&(y0 as f32 + y as f32 + v)))
                .collect(),
        )
    };
    // mean squared error over the pixels that land on `b` (and how many do)
    let error = |warp: &mut PatchWarp, warped: &mut [f32], u: f32, v: f32| -> (f32, usize) {
        warp.warp(at, u, v, warped);
        let (cols, rows) = on_b(u, v);
        let (mut e, mut k) = (0f32, 0usize);
        for y in (0..ps).filter(|&y| rows[y]) {
            for x in (0..ps).filter(|&x| cols[x]) {
                k += 1;
                for c in 0..nc {
                    let i = c * ps * ps + y * ps + x;
                    let d = warped[i] - t[i];
                    e += d * d;
                }
            }
        }
        (e / k.max(1) as f32, k)
    };
    let (start_error, start_on) = error(&mut warp, &mut warped, u0, v0);
    let (mut u, mut v) = (u0, v0);
    for _ in 0..p.iterations {
        warp.warp(at, u, v, &mut warped);
        let (cols, rows) = on_b(u, v);
        let (mut bx, mut by) = (0f32, 0f32);
        let (mut hxx, mut hxy, mut hyy) = (damp, 0f32, damp);
        for c in 0..nc {
            for y in (0..ps).filter(|&y| rows[y]) {
                let base = c * ps * ps + y * ps;
                for x in (0..ps).filter(|&x| cols[x]) {
                    let i = base + x;
                    let (gx, gy) = (ex[i], ey[i]);
                    let d = warped[i] - t[i];
                    bx += gx * d;
                    by += gy * d;
                    hxx += gx * gx;
                    hxy += gx * gy;
                    hyy += gy * gy;
                }
            }
        }
        let det = hxx * hyy - hxy * hxy;
        let du = (hyy * bx - hxy * by) / det;
        let dv = (hxx * by - hxy * bx) / det;
        u -= du;
        v -= dv;
        if du * du + dv * dv < 1e-6 {
            break;
        }
    }
    let (end_error, end_on) = error(&mut warp, &mut warped, u, v);
    // a fit that leaves most of the patch off `b` is no fit
    if !(u.is_finite() && v.is_finite()) || end_error > start_error || 2 * end_on < start_on {
        (u0, v0)
    } else {
        (u, v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth texture with detail at several scales, in three channels.
    fn texture(x: f32, y: f32, c: usize) -> f32 {
        let k = c as f32;
        (0.11 * x + 0.7 * k).sin() * (0.07 * y - 0.3 * k).cos()
            + 0.5 * (0.31 * x + 0.23 * y + k).sin()
            + 0.25 * (0.05 * x * (1.0 + 0.1 * k) - 0.09 * y).cos()
    }

    /// The largest distance of `flow` from `(dx, dy)` at least `margin` pixels from the edges.
    fn worst_error(flow: &Plane, (dx, dy): (f32, f32), margin: usize) -> f32 {
        let (w, h) = (flow.width(), flow.height());
        let mut worst = 0f32;
        for y in margin..h - margin {
            for x in margin..w - margin {
                worst = worst.max((flow.get(x, y, 0) - dx).hypot(flow.get(x, y, 1) - dy));
            }
        }
        worst
    }

    #[test]
    fn a_sub_pixel_shift_is_found_to_a_hundredth_of_a_pixel() {
        let (w, h) = (96, 80);
        let (dx, dy) = (3.3f32, -1.7f32);
        // b shows a's content moved by (dx, dy): b(x + d) = a(x)
        let a = Plane::from_fn(w, h, 3, |x, y, c| texture(x as f32, y as f32, c));
        let b = Plane::from_fn(w, h, 3, |x, y, c| texture(x as f32 - dx, y as f32 - dy, c));
        let f = dis_flow(&a, &b, &DisParams::default());
        let worst = worst_error(&f, (dx, dy), 8);
        assert!(worst < 0.01, "worst error {worst} px");
    }

    #[test]
    fn a_large_shift_is_found_coarse_to_fine() {
        let (w, h) = (160, 128);
        let (dx, dy) = (-14.0f32, 9.5f32);
        let a = Plane::from_fn(w, h, 3, |x, y, c| texture(x as f32, y as f32, c));
        let b = Plane::from_fn(w, h, 3, |x, y, c| texture(x as f32 - dx, y as f32 - dy, c));
        let f = dis_flow(&a, &b, &DisParams::default());
        // away from the border the shift brings in from outside
        let worst = worst_error(&f, (dx, dy), 24);
        assert!(worst < 0.02, "worst error {worst} px");
    }

    #[test]
    fn a_featureless_image_gets_no_motion() {
        let a = Plane::filled(40, 40, 2, 0.5);
        let f = dis_flow(&a, &a, &DisParams::default());
        assert!(f.data().iter().all(|v| *v == 0.0));
    }
}
