//! Aligned windows: the 2r+1 frames around a centre frame, warped onto it along the renderer's
//! motion, each with a confidence plane, optionally mixed towards the centre by confidence.

pub mod confidence;
pub mod estimate;
pub mod motion;
pub mod warp;

use rayon::prelude::*;

use crate::align::confidence::{confidence, ConfidenceParams, Guides};
use crate::align::motion::{compose_bands, invert_band, on_screen, round_trip_error_bands};
use crate::align::warp::{
    mix_with_centre, warp_band, warp_bands_linked, Resampling, SummingPlanes,
};
use crate::image::ops::{clamp_fireflies3, luminance};
use crate::image::plane::Plane;
use crate::io::frame::Frame;
use crate::run::banding::{Band, FrameBand};

/// How many times its brightest neighbour's luminance a pixel of the centre frame may be before
/// centre mixing treats it as a firefly and copies the clamped value instead
/// ([`clamp_fireflies3`]). A one-pixel firefly (Cycles writes them into its denoising albedo as
/// well as its colour) spreads over the confidence guides' 3×3 mean and zeroes the side frames'
/// confidence around it, so centre mixing is exactly where it would spread.
pub const FIREFLY_FACTOR: f32 = 4.0;

/// Options for aligning a window.
#[derive(Clone, Copy, Debug)]
pub struct AlignParams {
    /// Confidence tolerances.
    pub confidence: ConfidenceParams,
    /// Blend each warped side frame towards the centre by `1 − confidence` (paper section 3).
    pub mix_centre: bool,
    /// Fixed-point iterations when a motion direction must be derived by inversion.
    pub invert_iterations: usize,
    /// How the side frames' planes are sampled between pixels (motion fields and depth are
    /// always sampled as before: bilinear and nearest).
    pub resampling: Resampling,
}

impl Default for AlignParams {
    fn default() -> Self {
        Self {
            confidence: ConfidenceParams::default(),
            mix_centre: true,
            invert_iterations: 6,
            resampling: Resampling::Bilinear,
        }
    }
}

/// One frame of an aligned window, warped onto the centre frame.
#[derive(Clone, Debug)]
pub struct AlignedFrame {
    /// Frame offset from the centre (−2..=2 for a 5-frame window).
    pub offset: i32,
    /// Beauty RGB.
    pub color: Plane,
    /// Alpha, if the frames have it.
    pub alpha: Option<Plane>,
    /// Albedo, if the frames have it.
    pub albedo: Option<Plane>,
    /// Normal, if the frames have it.
    pub normal: Option<Plane>,
    /// Depth, if the frames have it.
    pub depth: Option<Plane>,
    /// AOVs in the order the frames carry them.
    pub aovs: Vec<Plane>,
    /// The frame's guide ([`Frame::guide`]), warped like the colour.
    pub guide: Option<Plane>,
    /// The renderer's variance of the beauty ([`Frame::variance`]): the centre frame's only
    /// (what the blends back towards the centre's input compare with; side frames: `None`).
    pub variance: Option<Plane>,
    /// Confidence in [0, 1]: 1 for the centre frame; 0 off-screen, on disocclusion and for
    /// frames beyond the ends of the sequence.
    pub confidence: Plane,
    /// The displacement used for the lookup (pixels, +Y down).
    pub flow: Plane,
}

/// The frames of a window, all aligned to the centre one.
#[derive(Clone, Debug)]
pub struct AlignedWindow {
    /// The frames in time order; the centre is at index `frames.len() / 2`.
    pub frames: Vec<AlignedFrame>,
}

impl AlignedWindow {
    /// The centre frame.
    pub fn centre(&self) -> &AlignedFrame {
        &self.frames[self.frames.len() / 2]
    }

    /// Window radius (2 for 5 frames).
    pub fn radius(&self) -> usize {
        self.frames.len() / 2
    }
}

/// Aligns a window of frames onto its centre. `window[k]` is `None` for frames beyond the
/// ends of the sequence: they repeat the nearest available frame with zero confidence. The
/// window length must be odd and its centre present.
pub fn align_window(window: &[Option<&Frame>], params: &AlignParams) -> AlignedWindow {
    let bands: Vec<Option<FrameBand>> = window.iter().map(|f| f.map(FrameBand::whole)).collect();
    align_bands(&bands, params)
}

/// [`align_window`] for a band of the centre frame's rows: the result covers the centre band's
/// rows and equals those rows of whole-frame alignment, except within two rows of a band edge
/// that is not a frame edge (the confidence guides' prefilter needs the row beyond). Side
/// frames must hold the rows [`crate::run::banding::window_band_rows`] gives.
pub fn align_bands(window: &[Option<FrameBand>], params: &AlignParams) -> AlignedWindow {
    let t = window.len();
    assert!(t % 2 == 1, "window length must be odd");
    let r = t / 2;
    let cb = window[r].expect("the centre frame of a window must exist");
    let centre = cb.frame;
    let (w, h) = (centre.width(), centre.height());
    let full_h = cb.full_height;
    let guides_c = Guides::new(
        &centre.color,
        centre.albedo.as_ref(),
        centre.normal.as_ref(),
        centre.depth.as_ref(),
        centre
            .guide
            .as_ref()
            .filter(|_| params.confidence.guide.is_some()),
    );

    let mut slots: Vec<Option<AlignedFrame>> = (0..t).map(|_| None).collect();
    slots[r] = Some(AlignedFrame {
        offset: 0,
        color: centre.color.clone(),
        alpha: centre.alpha.clone(),
        albedo: centre.albedo.clone(),
        normal: centre.normal.clone(),
        depth: centre.depth.clone(),
        aovs: centre.aovs.iter().map(|a| a.plane.clone()).collect(),
        guide: centre.guide.clone(),
        variance: centre.variance.clone(),
        confidence: Plane::filled(w, h, 1, 1.0),
        flow: Plane::zeros(w, h, 2),
    });

    let mix_source = params
        .mix_centre
        .then(|| mixing_source(slots[r].as_ref().expect("centre is set")));

    // walk outwards in each direction, accumulating flow, validity and motion error
    for dir in [-1i32, 1] {
        let mut flow = Plane::zeros(w, h, 2);
        let mut valid = Plane::filled(w, h, 1, 1.0);
        let mut err: Option<Plane> = Some(Plane::zeros(w, h, 1));
        let mut prev_idx = r;
        for step in 1..=r {
            let idx = (r as i32 + dir * step as i32) as usize;
            let (Some(from), Some(to)) = (window[prev_idx], window[idx]) else {
                break; // beyond the sequence: filled in below
            };
            // one hop from frame `from` to frame `to`, defined on `from`'s rows
            let (native, other_way) = if dir < 0 {
                (&from.frame.motion_prev, &to.frame.motion_next)
            } else {
                (&from.frame.motion_next, &to.frame.motion_prev)
            };
            let (hop, back) = match (native, other_way) {
                (Some(n), o) => (n.clone(), o.as_ref()),
                (None, Some(o)) => (
                    invert_band(
                        to.of(o),
                        from.y0,
                        from.frame.height(),
                        params.invert_iterations,
                    ),
                    None,
                ),
                (None, None) => break,
            };
            // positions reached so far, then one more hop
            let flow_c = cb.of(&flow);
            let landed = compose_bands(flow_c, from.of(&hop));
            let hop_err = back.map(|b| round_trip_error_bands(from.of(&hop), to.of(b)));
            let new_valid = step_validity(&valid, &landed, w, cb.y0, full_h);
            err = match (err, hop_err) {
                (Some(e), Some(he)) => Some(add_sampled(&e, from.of(&he), flow_c)),
                _ => None,
            };
            flow = landed;
            valid = new_valid;
            let flow_c = cb.of(&flow);
            let tf = to.frame;
            let guides_w = Guides::new(
                &tf.color,
                tf.albedo.as_ref(),
                tf.normal.as_ref(),
                tf.depth.as_ref(),
                tf.guide
                    .as_ref()
                    .filter(|_| params.confidence.guide.is_some()),
            );
            // every plane of the frame along one flow, the taps computed once per pixel
            let mut srcs = vec![to.of(&guides_w.color), to.of(&tf.color)];
            let optional = [
                guides_w.albedo.as_ref(),
                guides_w.normal.as_ref(),
                tf.alpha.as_ref(),
                tf.albedo.as_ref(),
                tf.normal.as_ref(),
                tf.guide.as_ref(),
                guides_w.guide.as_ref(),
            ];
            srcs.extend(optional.iter().flatten().map(|p| to.of(p)));
            // the beauty (source 1) and its AOVs keep summing under Catmull-Rom's clamp
            let summing = SummingPlanes {
                lead: 1,
                parts: (srcs.len()..srcs.len() + tf.aovs.len()).collect(),
            };
            srcs.extend(tf.aovs.iter().map(|a| to.of(&a.plane)));
            let mut warped =
                warp_bands_linked(&srcs, flow_c, params.resampling, Some(&summing)).into_iter();
            let mut next = || warped.next().expect("one warped plane per source");
            let (guide_color, color) = (next(), next());
            let mut optional = optional.map(|p| p.map(|_| next()));
            let aovs: Vec<Plane> = tf.aovs.iter().map(|_| next()).collect();
            let mut take = |i: usize| optional[i].take();
            let warped_guides = Guides {
                color: guide_color,
                albedo: take(0),
                normal: take(1),
                depth: guides_w
                    .depth
                    .as_ref()
                    .map(|p| warp_nearest_depth(to.of(p), flow_c)),
                guide: take(6),
            };
            let conf = confidence(
                &guides_c,
                &warped_guides,
                &valid,
                err.as_ref(),
                step,
                &params.confidence,
            );
            let mut f = AlignedFrame {
                offset: dir * step as i32,
                color,
                alpha: take(2),
                albedo: take(3),
                normal: take(4),
                depth: warped_guides.depth,
                aovs,
                guide: take(5),
                variance: None,
                confidence: conf,
                flow: flow.clone(),
            };
            if let Some(src) = &mix_source {
                mix_frame(&mut f, src);
            }
            slots[idx] = Some(f);
            prev_idx = idx;
        }
    }

    // frames beyond the sequence ends (or without motion to reach them): repeat the nearest
    // aligned frame towards the centre, with zero confidence
    for dir in [-1i32, 1] {
        for step in 1..=r {
            let idx = (r as i32 + dir * step as i32) as usize;
            if slots[idx].is_none() {
                let near = (r as i32 + dir * (step as i32 - 1)) as usize;
                let mut f = slots[near].clone().expect("nearer slot is filled first");
                f.offset = dir * step as i32;
                f.confidence = Plane::zeros(w, h, 1);
                if let Some(src) = &mix_source {
                    mix_frame(&mut f, src);
                }
                slots[idx] = Some(f);
            }
        }
    }
    AlignedWindow {
        frames: slots
            .into_iter()
            .map(|s| s.expect("every slot is filled"))
            .collect(),
    }
}

/// The centre frame as centre mixing copies it into side frames where they are not trusted:
/// colour and every AOV scaled per pixel so that the colour's luminance is at most
/// [`FIREFLY_FACTOR`] times its brightest neighbour's (one scale for all of them, so the AOVs
/// still sum to the beauty and everything the kernels filter stays linear), the albedo clamped
/// per channel the same way. Without it a one-pixel firefly of the centre frame reaches every
/// frame of the window wherever confidence is low, and no kernel can average it away; the centre
/// frame itself keeps its firefly, which the network then sees against side frames without it.
fn mixing_source(c: &AlignedFrame) -> AlignedFrame {
    let lum = luminance(&c.color);
    let cap = clamp_fireflies3(&lum, FIREFLY_FACTOR);
    let scale: Vec<f32> = lum
        .data()
        .iter()
        .zip(cap.data())
        .map(|(&l, &m)| {
            if l > m && l > 0.0 {
                m.max(0.0) / l
            } else {
                1.0
            }
        })
        .collect();
    let scaled = |p: &Plane| {
        let mut p = p.clone();
        let n = p.pixels();
        p.data_mut().par_chunks_mut(n).for_each(|ch| {
            for (v, s) in ch.iter_mut().zip(&scale) {
                *v *= s;
            }
        });
        p
    };
    AlignedFrame {
        color: scaled(&c.color),
        aovs: c.aovs.iter().map(scaled).collect(),
        albedo: c
            .albedo
            .as_ref()
            .map(|a| clamp_fireflies3(a, FIREFLY_FACTOR)),
        ..c.clone()
    }
}

fn mix_frame(f: &mut AlignedFrame, c: &AlignedFrame) {
    mix_with_centre(&mut f.color, &c.color, &f.confidence);
    for (a, b) in [
        (&mut f.alpha, &c.alpha),
        (&mut f.albedo, &c.albedo),
        (&mut f.normal, &c.normal),
        (&mut f.depth, &c.depth),
        (&mut f.guide, &c.guide),
    ] {
        if let (Some(a), Some(b)) = (a.as_mut(), b.as_ref()) {
            mix_with_centre(a, b, &f.confidence);
        }
    }
    for (a, b) in f.aovs.iter_mut().zip(&c.aovs) {
        mix_with_centre(a, b, &f.confidence);
    }
}

/// Validity after one more hop: still valid and the new landing point is on the image.
fn step_validity(valid: &Plane, landed: &Plane, w: usize, y0: usize, full_h: usize) -> Plane {
    let mut out = Plane::zeros(w, valid.height(), 1);
    out.data_mut()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, row)| {
            for (x, o) in row.iter_mut().enumerate() {
                let ok = valid.get(x, y, 0) > 0.0
                    && on_screen(
                        w,
                        full_h,
                        x as f32 + landed.get(x, y, 0),
                        (y + y0) as f32 + landed.get(x, y, 1),
                    );
                *o = if ok { 1.0 } else { 0.0 };
            }
        });
    out
}

/// `acc(x) + hop_err(x + flow(x))`: accumulates a per-hop error along the path.
fn add_sampled(acc: &Plane, hop_err: Band, flow: Band) -> Plane {
    let mut out = warp_band(hop_err, flow);
    out.data_mut()
        .par_iter_mut()
        .zip(acc.data())
        .for_each(|(v, a)| *v += a);
    out
}

/// Warps depth taking, of the four bilinear neighbours, the one closest to the bilinear value,
/// so silhouettes do not produce depths halfway between foreground and background.
fn warp_nearest_depth(src: Band, flow: Band) -> Plane {
    let (w, h) = (flow.plane.width(), flow.plane.height());
    let full_h = src.full_height;
    let mut out = Plane::zeros(w, h, 1);
    out.data_mut()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(y, row)| {
            for (x, o) in row.iter_mut().enumerate() {
                let px = (x as f32 + flow.plane.get(x, y, 0)).clamp(0.0, (w - 1) as f32);
                let py = ((y + flow.y0) as f32 + flow.plane.get(x, y, 1))
                    .clamp(0.0, (full_h - 1) as f32);
                let (x0, y0) = (px.floor() as usize, py.floor() as usize);
                let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(full_h - 1));
                let (fx, fy) = (px - x0 as f32, py - y0 as f32);
                // the neighbour with the largest bilinear weight
                let sx = if fx < 0.5 { x0 } else { x1 };
                let sy = if fy < 0.5 { y0 } else { y1 };
                *o = src.get(sx, sy, 0);
            }
        });
    out
}

/// Which sequence positions make up the window of the frame at `index` in a sequence of
/// `len` frames: `None` beyond either end.
pub fn window_indices(index: usize, len: usize, radius: usize) -> Vec<Option<usize>> {
    (0..=2 * radius)
        .map(|k| {
            let i = index as i64 + k as i64 - radius as i64;
            (i >= 0 && i < len as i64).then_some(i as usize)
        })
        .collect()
}
