//! Motion fields in radn's convention (pixels, +Y down, displacement from a pixel of this
//! frame to the same surface point in another frame): sampling, composition and inversion.

use rayon::prelude::*;

use crate::image::plane::Plane;
use crate::run::banding::Band;

/// Bilinear lookup of channel `c` at continuous position (x, y), pixel centres at integers;
/// positions outside the plane repeat the edge.
#[inline]
pub fn bilinear(plane: &Plane, c: usize, x: f32, y: f32) -> f32 {
    Band::whole(plane).bilinear(c, x, y)
}

/// True when position (x, y) lies on the image (within the outer pixels' footprint).
#[inline]
pub fn on_screen(width: usize, height: usize, x: f32, y: f32) -> bool {
    x >= -0.5 && y >= -0.5 && x <= width as f32 - 0.5 && y <= height as f32 - 0.5
}

/// Chains two displacement fields: first `a` (defined on this frame), then `b` (defined on the
/// frame `a` leads to, sampled where `a` lands).
pub fn compose(a: &Plane, b: &Plane) -> Plane {
    compose_bands(Band::whole(a), Band::whole(b))
}

/// [`compose`] on bands: the result covers `a`'s rows; `b` must hold every row `a` reaches.
pub fn compose_bands(a: Band, b: Band) -> Plane {
    let (w, h) = (a.plane.width(), a.plane.height());
    let mut out = Plane::zeros(w, h, 2);
    let (ox, oy) = out.data_mut().split_at_mut(w * h);
    ox.par_chunks_mut(w)
        .zip(oy.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (rx, ry))| {
            for x in 0..w {
                let dx = a.plane.get(x, y, 0);
                let dy = a.plane.get(x, y, 1);
                let px = x as f32 + dx;
                let py = (y + a.y0) as f32 + dy;
                rx[x] = dx + b.bilinear(0, px, py);
                ry[x] = dy + b.bilinear(1, px, py);
            }
        });
    out
}

/// Inverts a displacement field by fixed-point iteration: given `f` on frame A (A → B), returns
/// `g` on frame B with `g(x) = y - x` where `y + f(y) = x`. Used when a renderer writes motion
/// in only one direction.
pub fn invert(f: &Plane, iterations: usize) -> Plane {
    invert_band(Band::whole(f), 0, f.height(), iterations)
}

/// [`invert`] for frame B's rows `y0..y0 + height` from a band of `f`, which must hold the rows
/// the inverse reaches (as far as `f`'s largest vertical displacement, plus one).
pub fn invert_band(f: Band, y0: usize, height: usize, iterations: usize) -> Plane {
    let w = f.plane.width();
    let mut out = Plane::zeros(w, height, 2);
    let (ox, oy) = out.data_mut().split_at_mut(w * height);
    ox.par_chunks_mut(w)
        .zip(oy.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (rx, ry))| {
            for x in 0..w {
                let (tx, ty) = (x as f32, (y + y0) as f32);
                let mut px = tx - f.get(x, y + y0, 0);
                let mut py = ty - f.get(x, y + y0, 1);
                for _ in 0..iterations {
                    px = tx - f.bilinear(0, px, py);
                    py = ty - f.bilinear(1, px, py);
                }
                rx[x] = px - tx;
                ry[x] = py - ty;
            }
        });
    out
}

/// Forward–backward consistency error in pixels: how far `there` (this → other) followed by
/// `back` (other → this, sampled where `there` lands) ends from the start.
pub fn round_trip_error(there: &Plane, back: &Plane) -> Plane {
    round_trip_error_bands(Band::whole(there), Band::whole(back))
}

/// [`round_trip_error`] on bands: covers `there`'s rows; `back` must hold every row reached.
pub fn round_trip_error_bands(there: Band, back: Band) -> Plane {
    let r = compose_bands(there, back);
    let (w, h) = (r.width(), r.height());
    let mut out = Plane::zeros(w, h, 1);
    out.data_mut()
        .par_iter_mut()
        .enumerate()
        .for_each(|(i, e)| {
            let (dx, dy) = (r.data()[i], r.data()[w * h + i]);
            *e = (dx * dx + dy * dy).sqrt();
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_interpolates_and_clamps() {
        let p = Plane::from_fn(4, 3, 1, |x, y, _| (x + 10 * y) as f32);
        assert!((bilinear(&p, 0, 1.5, 0.5) - 6.5).abs() < 1e-6);
        assert_eq!(bilinear(&p, 0, -3.0, 0.0), 0.0);
        assert_eq!(bilinear(&p, 0, 10.0, 10.0), 23.0);
    }

    #[test]
    fn composing_constant_translations_adds_them() {
        let a = Plane::from_fn(8, 8, 2, |_, _, c| if c == 0 { 1.0 } else { -0.5 });
        let b = Plane::from_fn(8, 8, 2, |_, _, c| if c == 0 { 0.25 } else { 2.0 });
        let r = compose(&a, &b);
        assert!((r.get(3, 3, 0) - 1.25).abs() < 1e-6 && (r.get(3, 3, 1) - 1.5).abs() < 1e-6);
    }

    #[test]
    fn inverting_a_rotation_field_round_trips() {
        // small rotation about the centre: f(y) = R y - y
        let (w, h, a) = (32usize, 32usize, 0.05f32);
        let (cx, cy) = (15.5f32, 15.5f32);
        let f = Plane::from_fn(w, h, 2, |x, y, c| {
            let (dx, dy) = (x as f32 - cx, y as f32 - cy);
            let (rx, ry) = (a.cos() * dx - a.sin() * dy, a.sin() * dx + a.cos() * dy);
            if c == 0 {
                rx - dx
            } else {
                ry - dy
            }
        });
        let g = invert(&f, 8);
        let e = round_trip_error(&g, &f);
        // away from the borders, where the inverse would leave the image
        for y in 6..26 {
            for x in 6..26 {
                assert!(e.get(x, y, 0) < 1e-3, "{x},{y}: {}", e.get(x, y, 0));
            }
        }
    }
}
