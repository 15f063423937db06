//! Refinement of the renderer's motion by TV-L1 optical flow, used only where it explains the
//! other frame better (reflections, refractions, moving shadows: motion the renderer's vectors
//! do not follow).

use rayon::prelude::*;

use super::tvl1::{tvl1_flow, TvL1Params};
use crate::align::warp::warp_plane;
use crate::eval::metrics::tonemap;
use crate::image::ops::{box_mean, downsample, gaussian, luminance, resample};
use crate::image::plane::Plane;

/// Options of the refinement.
#[derive(Clone, Copy, Debug)]
pub struct RefineParams {
    /// The flow solver's parameters.
    pub tvl1: TvL1Params,
    /// Compute the flow at most at this many pixels (the image is scaled down to fit and the
    /// flow upsampled): reflections and shadows move smoothly, and the flow's cost would
    /// otherwise dominate the denoiser on large frames.
    pub max_pixels: usize,
    /// Gaussian prefilter (pixels) of the tonemapped luminance the flow is computed on, so
    /// render noise does not drive it.
    pub prefilter_sigma: f32,
    /// Use the refined flow only where its residual is below this fraction of the renderer's.
    pub accept_ratio: f32,
    /// ... and where it differs from the renderer's by at least this many pixels.
    pub min_change_px: f32,
}

impl Default for RefineParams {
    fn default() -> Self {
        Self {
            tvl1: TvL1Params::default(),
            max_pixels: 250_000,
            prefilter_sigma: 1.0,
            accept_ratio: 0.6,
            min_change_px: 0.5,
        }
    }
}

/// A motion field and where it replaced the renderer's.
#[derive(Clone, Debug)]
pub struct RefinedMotion {
    /// The motion to use (pixels, +Y down).
    pub flow: Plane,
    /// 1 where the optical flow replaced the renderer's vector, else 0.
    pub refined: Plane,
}

/// The image the flow is computed on: tonemapped luminance, lightly prefiltered, in [0, 255].
pub fn flow_image(color: &Plane, sigma: f32) -> Plane {
    let mut l = luminance(color);
    l.data_mut()
        .iter_mut()
        .for_each(|v| *v = tonemap(*v) * 255.0);
    gaussian(&l, sigma)
}

/// Refines `renderer` (motion from the frame of `this` to the frame of `other`) by TV-L1 flow
/// between the two colour images.
pub fn refine_motion(
    this: &Plane,
    other: &Plane,
    renderer: &Plane,
    p: &RefineParams,
) -> RefinedMotion {
    let (w, h) = (this.width(), this.height());
    let i0 = flow_image(this, p.prefilter_sigma);
    let i1 = flow_image(other, p.prefilter_sigma);
    let scale = (p.max_pixels as f32 / (w * h) as f32).sqrt().min(1.0);
    let (sw, sh) = (
        ((w as f32 * scale).round() as usize).max(8),
        ((h as f32 * scale).round() as usize).max(8),
    );
    let flow = if (sw, sh) == (w, h) {
        tvl1_flow(&i0, &i1, renderer, &p.tvl1)
    } else {
        let (sx, sy) = (sw as f32 / w as f32, sh as f32 / h as f32);
        let init = scale2(&resample(renderer, sw, sh), sx, sy);
        let small = tvl1_flow(
            &downsample(&i0, sw, sh),
            &downsample(&i1, sw, sh),
            &init,
            &p.tvl1,
        );
        scale2(&resample(&small, w, h), 1.0 / sx, 1.0 / sy)
    };
    // residuals of both fields, averaged over 5×5 so noise does not decide
    let r_ren = box_mean(&residual(&i0, &i1, renderer), 2);
    let r_opt = box_mean(&residual(&i0, &i1, &flow), 2);
    let mut out = renderer.clone();
    let mut refined = Plane::zeros(w, h, 1);
    let n = w * h;
    let (ox, oy) = out.data_mut().split_at_mut(n);
    ox.par_iter_mut()
        .zip(oy.par_iter_mut())
        .zip(refined.data_mut().par_iter_mut())
        .enumerate()
        .for_each(|(i, ((mx, my), r))| {
            let (fx, fy) = (flow.data()[i], flow.data()[n + i]);
            let change = ((fx - *mx).powi(2) + (fy - *my).powi(2)).sqrt();
            if change >= p.min_change_px && r_opt.data()[i] < p.accept_ratio * r_ren.data()[i] {
                *mx = fx;
                *my = fy;
                *r = 1.0;
            }
        });
    RefinedMotion { flow: out, refined }
}

fn scale2(u: &Plane, sx: f32, sy: f32) -> Plane {
    let mut out = u.clone();
    out.channel_mut(0).iter_mut().for_each(|v| *v *= sx);
    out.channel_mut(1).iter_mut().for_each(|v| *v *= sy);
    out
}

/// |i1(x + u(x)) − i0(x)|.
fn residual(i0: &Plane, i1: &Plane, u: &Plane) -> Plane {
    let mut r = warp_plane(i1, u);
    r.data_mut()
        .par_iter_mut()
        .zip(i0.data())
        .for_each(|(v, a)| *v = (*v - a).abs());
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(w: usize, h: usize, shift: f32) -> Plane {
        // a textured square (a "reflection") moving right by `shift` over a static textured wall
        Plane::from_fn(w, h, 3, |x, y, c| {
            let (xf, yf) = (x as f32, y as f32);
            let inside = xf >= 20.0 + shift && xf < 44.0 + shift && (16.0..40.0).contains(&yf);
            let v = if inside {
                0.5 + 0.3 * ((xf - shift) * 0.7).sin() * (yf * 0.5).cos()
            } else {
                0.3 + 0.15 * (xf * 0.31 + yf * 0.23).sin()
            };
            v * [1.0, 0.9, 0.8][c]
        })
    }

    #[test]
    fn refined_flow_replaces_renderer_vectors_only_where_they_are_wrong() {
        let (w, h) = (72, 56);
        // the renderer reports no motion (as for a reflection); the square moved by 3 px
        let this = scene(w, h, 3.0);
        let prev = scene(w, h, 0.0);
        let renderer = Plane::zeros(w, h, 2);
        let p = RefineParams::default();
        let r = refine_motion(&this, &prev, &renderer, &p);
        // deep inside the square the refined flow points 3 px left (to where it was)
        let mut ok = 0;
        for y in 22..34 {
            for x in 29..41 {
                if r.refined.get(x, y, 0) > 0.0 && (r.flow.get(x, y, 0) + 3.0).abs() < 0.5 {
                    ok += 1;
                }
            }
        }
        assert!(ok > 100, "{ok} of 144 interior pixels refined correctly");
        // the static wall far from the square keeps the renderer's (correct) zero motion
        for y in 0..h {
            for x in 0..8 {
                assert_eq!(r.refined.get(x, y, 0), 0.0);
                assert_eq!(r.flow.get(x, y, 0), 0.0);
            }
        }
    }
}
