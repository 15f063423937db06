//! Motion found from the frames themselves, for sequences rendered without motion vectors
//! (Cycles writes none while motion blur is on): dense flow between neighbouring frames from
//! their nearly noise-free buffers (albedo, normal, depth, and the colour smoothed), in both
//! directions, so that alignment checks it forwards and backwards exactly as it checks a
//! renderer's vectors; and the test that says two neighbours are not one shot (a cut).
//!
//! The flow is solved on a box-downsampled copy of each frame (at most
//! [`EstimateParams::max_pixels`]) built band by band, so memory stays small at any size, and
//! sampled back up to the frame's pixels row by row when alignment reads it.

pub mod dis;

use rayon::prelude::*;

use self::dis::{dis_flow, DisParams};
use crate::align::motion::bilinear;
use crate::image::plane::Plane;
use crate::io::frame::Frame;

/// Settings of motion estimation.
#[derive(Clone, Copy, Debug)]
pub struct EstimateParams {
    /// The flow is solved on the frames box-downsampled by the smallest whole factor that
    /// brings them to at most this many pixels.
    pub max_pixels: usize,
    /// The flow solver's settings.
    pub dis: DisParams,
    /// Two neighbouring frames are one shot when at least this fraction of either one's
    /// pixels is found in the other (forward–backward consistent, buffers matching).
    pub shot_match: f32,
    /// A pixel matches when its buffers differ from the other frame's by less than this
    /// (root mean square over the signal's channels).
    pub match_tolerance: f32,
    /// ... and the round trip through both flows returns within this many pixels (of the
    /// downsampled frame).
    pub round_trip_px: f32,
}

impl Default for EstimateParams {
    fn default() -> Self {
        Self {
            max_pixels: 600_000,
            dis: DisParams::default(),
            shot_match: 0.2,
            match_tolerance: 0.1,
            round_trip_px: 1.0,
        }
    }
}

/// Weight of the colour in the signal beside buffers, and alone.
const COLOR_WEIGHT_WITH_BUFFERS: f32 = 0.3;
/// Weight of the normals' components (they span [−1, 1], the albedo [0, 1]).
const NORMAL_WEIGHT: f32 = 0.5;
/// Weight of log depth: a step from 1 to 2 units of distance counts as 0.35.
const DEPTH_WEIGHT: f32 = 0.5;
/// Depth beyond which a pixel is background (the renderers write a huge depth there).
const DEPTH_CAP: f32 = 1e4;

/// What the flow is solved on: one frame's buffers, box-downsampled.
#[derive(Clone, Debug)]
pub struct MotionSignal {
    /// The downsampled, weighted channels.
    pub plane: Plane,
    /// Frame pixels per signal pixel along each axis.
    pub factor: usize,
    /// The frame's size.
    pub frame_size: (usize, usize),
}

/// Which of a frame's buffers the signal is made of (every frame of a sequence has the same).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Sources {
    albedo: bool,
    normal: bool,
    depth: bool,
}

impl Sources {
    fn of(frame: &Frame) -> Self {
        Self {
            albedo: frame.albedo.is_some(),
            normal: frame.normal.is_some(),
            depth: frame.depth.is_some(),
        }
    }

    fn channels(self) -> usize {
        1 + 3 * self.albedo as usize + 3 * self.normal as usize + self.depth as usize
    }
}

/// How a buffer's sample enters the signal (log depth, or as it is).
type SampleMap = fn(f32) -> f32;

/// Builds a [`MotionSignal`] from a frame's bands of rows, in order: each band's pixels are
/// summed into the downsampled cells they fall in.
#[derive(Debug)]
pub struct SignalBuilder {
    sums: Plane,
    counts: Vec<f32>,
    factor: usize,
    frame_size: (usize, usize),
    sources: Option<Sources>,
}

impl SignalBuilder {
    /// A builder for a frame of `width` × `height` pixels.
    pub fn new(width: usize, height: usize, params: &EstimateParams) -> Self {
        let pixels = (width * height) as f64;
        let factor = (pixels / params.max_pixels.max(1) as f64)
            .sqrt()
            .ceil()
            .max(1.0) as usize;
        let (sw, sh) = (width.div_ceil(factor), height.div_ceil(factor));
        Self {
            sums: Plane::zeros(sw, sh, 0),
            counts: vec![0.0; sw * sh],
            factor,
            frame_size: (width, height),
            sources: None,
        }
    }

    /// Adds the frame's rows `y0..y0 + band.height()`.
    pub fn add_rows(&mut self, y0: usize, band: &Frame) {
        let sources = *self.sources.get_or_insert_with(|| Sources::of(band));
        let (sw, sh) = (self.sums.width(), self.sums.height());
        if self.sums.channels() == 0 {
            self.sums = Plane::zeros(sw, sh, sources.channels());
        }
        let (w, f) = (band.width(), self.factor);
        // one row of each of the signal's channels, before its cells are summed
        let mut planes: Vec<(&Plane, usize, SampleMap)> = Vec::new();
        for (on, plane) in [
            (sources.albedo, band.albedo.as_ref()),
            (sources.normal, band.normal.as_ref()),
        ] {
            if let (true, Some(p)) = (on, plane) {
                planes.extend((0..3).map(|c| (p, c, (|v| v) as SampleMap)));
            }
        }
        if let (true, Some(d)) = (sources.depth, band.depth.as_ref()) {
            planes.push((d, 0, |d| {
                if d.is_finite() && d > 0.0 {
                    d.min(DEPTH_CAP).ln()
                } else {
                    DEPTH_CAP.ln()
                }
            }));
        }
        let mut lum = vec![0f32; w];
        for y in 0..band.height() {
            let cells = (y0 + y) / f * sw..((y0 + y) / f + 1) * sw;
            // the last cell of a row may hold fewer than `f` columns
            for (i, n) in self.counts[cells.clone()].iter_mut().enumerate() {
                *n += (w - i * f).min(f) as f32;
            }
            let c = &band.color;
            let row = y * w..(y + 1) * w;
            let (r, g, b) = (
                &c.channel(0)[row.clone()],
                &c.channel(1)[row.clone()],
                &c.channel(2)[row.clone()],
            );
            for (x, l) in lum.iter_mut().enumerate() {
                let v = 0.2126 * r[x] + 0.7152 * g[x] + 0.0722 * b[x];
                *l = if v.is_finite() { v.max(0.0) } else { 0.0 };
            }
            let sum_into = |dst: &mut [f32], src: &[f32], map: SampleMap| {
                for (x, v) in src.iter().enumerate() {
                    dst[x / f] += map(*v);
                }
            };
            sum_into(&mut self.sums.channel_mut(0)[cells.clone()], &lum, |v| v);
            for (k, (p, c, map)) in planes.iter().enumerate() {
                let src = &p.channel(*c)[row.clone()];
                sum_into(&mut self.sums.channel_mut(k + 1)[cells.clone()], src, *map);
            }
        }
    }

    /// The signal: means per cell, the colour's luminance brought to a common exposure and
    /// tonemapped, each kind of buffer weighted.
    pub fn finish(self) -> MotionSignal {
        let sources = self.sources.unwrap_or(Sources {
            albedo: false,
            normal: false,
            depth: false,
        });
        let (sw, sh) = (self.sums.width(), self.sums.height());
        let mut plane = self.sums;
        if plane.channels() == 0 {
            plane = Plane::zeros(sw, sh, 1);
        }
        for c in 0..plane.channels() {
            for (v, n) in plane.channel_mut(c).iter_mut().zip(&self.counts) {
                *v /= n.max(1.0);
            }
        }
        // luminance at a common exposure (its mean at 0.5), tonemapped, smoothed against noise
        let lum = plane.channel(0);
        let mean = lum.iter().map(|v| *v as f64).sum::<f64>() / lum.len().max(1) as f64;
        let scale = if mean > 0.0 { (1.0 / mean) as f32 } else { 1.0 };
        let buffers = sources.channels() > 1;
        let weight = if buffers {
            COLOR_WEIGHT_WITH_BUFFERS
        } else {
            1.0
        };
        let toned = Plane::from_vec(
            sw,
            sh,
            1,
            lum.iter()
                .map(|v| {
                    let x = v * scale;
                    weight * x / (1.0 + x)
                })
                .collect(),
        );
        let toned = crate::image::ops::gaussian(&toned, if buffers { 0.7 } else { 1.2 });
        plane.channel_mut(0).copy_from_slice(toned.channel(0));
        let mut k = 1 + 3 * sources.albedo as usize;
        if sources.normal {
            for c in k..k + 3 {
                plane
                    .channel_mut(c)
                    .iter_mut()
                    .for_each(|v| *v *= NORMAL_WEIGHT);
            }
            k += 3;
        }
        if sources.depth {
            plane
                .channel_mut(k)
                .iter_mut()
                .for_each(|v| *v *= DEPTH_WEIGHT);
        }
        MotionSignal {
            plane,
            factor: self.factor,
            frame_size: self.frame_size,
        }
    }
}

impl MotionSignal {
    /// The signal of a whole frame.
    pub fn of_frame(frame: &Frame, params: &EstimateParams) -> Self {
        let mut b = SignalBuilder::new(frame.width(), frame.height(), params);
        b.add_rows(0, frame);
        b.finish()
    }
}

/// The motion between two neighbouring frames, found from their signals.
#[derive(Clone, Debug)]
pub struct PairMotion {
    /// From the earlier frame to the later one (its `motion_next`), in signal pixels.
    pub forward: Plane,
    /// From the later frame to the earlier one (its `motion_prev`), in signal pixels.
    pub backward: Plane,
    /// The smaller of the two frames' fractions of pixels found in the other.
    pub matched: f32,
    /// Frame pixels per signal pixel.
    pub factor: usize,
    /// The frames' size.
    pub frame_size: (usize, usize),
}

impl PairMotion {
    /// Estimates the motion between `earlier` and `later` (signals of one sequence).
    pub fn estimate(earlier: &MotionSignal, later: &MotionSignal, params: &EstimateParams) -> Self {
        assert_eq!(earlier.frame_size, later.frame_size, "frames of one size");
        let (forward, backward) = rayon::join(
            || dis_flow(&earlier.plane, &later.plane, &params.dis),
            || dis_flow(&later.plane, &earlier.plane, &params.dis),
        );
        let matched =
            matched_fraction(&earlier.plane, &later.plane, &forward, &backward, params).min(
                matched_fraction(&later.plane, &earlier.plane, &backward, &forward, params),
            );
        Self {
            forward,
            backward,
            matched,
            factor: earlier.factor,
            frame_size: earlier.frame_size,
        }
    }

    /// Whether the two frames belong to one shot (no cut, camera jump or flash between them).
    pub fn same_shot(&self, params: &EstimateParams) -> bool {
        self.matched >= params.shot_match
    }

    /// Rows `rows` of the forward (`forward`) or backward flow at the frames' resolution, in
    /// frame pixels (radn's motion convention).
    pub fn rows(&self, forward: bool, rows: std::ops::Range<usize>) -> Plane {
        let flow = if forward {
            &self.forward
        } else {
            &self.backward
        };
        upsample_rows(flow, self.factor, self.frame_size.0, rows)
    }
}

/// A flow on the downsampled grid sampled at frame pixels `rows` (all columns), in frame
/// pixels: cell `i` covers frame pixels `i·f .. (i+1)·f`, so its centre is at `i·f + (f−1)/2`.
pub fn upsample_rows(flow: &Plane, f: usize, width: usize, rows: std::ops::Range<usize>) -> Plane {
    let h = rows.len();
    let mut out = Plane::zeros(width, h, 2);
    let ff = f as f32;
    let off = (ff - 1.0) / 2.0;
    let (fw, fh) = (flow.width(), flow.height());
    let (ox, oy) = out.data_mut().split_at_mut(width * h);
    ox.par_chunks_mut(width)
        .zip(oy.par_chunks_mut(width))
        .enumerate()
        .for_each(|(i, (rx, ry))| {
            let y = rows.start + i;
            let sy = ((y as f32 - off) / ff).clamp(0.0, (fh - 1) as f32);
            let (y0, y1) = (sy as usize, (sy as usize + 1).min(fh - 1));
            let ty = sy - y0 as f32;
            for x in 0..width {
                let sx = ((x as f32 - off) / ff).clamp(0.0, (fw - 1) as f32);
                let (x0, x1) = (sx as usize, (sx as usize + 1).min(fw - 1));
                let tx = sx - x0 as f32;
                let at = |c: usize| {
                    let ch = flow.channel(c);
                    let top = ch[y0 * fw + x0] * (1.0 - tx) + ch[y0 * fw + x1] * tx;
                    let bottom = ch[y1 * fw + x0] * (1.0 - tx) + ch[y1 * fw + x1] * tx;
                    (top * (1.0 - ty) + bottom * ty) * ff
                };
                rx[x] = at(0);
                ry[x] = at(1);
            }
        });
    out
}

/// Of `a`'s pixels that land on screen in `b` along `ab` (0 when fewer than a quarter do), the
/// fraction that return within
/// [`EstimateParams::round_trip_px`] along `ba`, and match `b` there within
/// [`EstimateParams::match_tolerance`].
fn matched_fraction(a: &Plane, b: &Plane, ab: &Plane, ba: &Plane, p: &EstimateParams) -> f32 {
    let (w, h, nc) = (a.width(), a.height(), a.channels());
    let tol2 = p.match_tolerance * p.match_tolerance * nc as f32;
    let (matched, on_screen): (usize, usize) = (0..h)
        .into_par_iter()
        .map(|y| {
            let (mut n, mut on) = (0, 0);
            for x in 0..w {
                let (u, v) = (ab.get(x, y, 0), ab.get(x, y, 1));
                let (px, py) = (x as f32 + u, y as f32 + v);
                if !(px >= -0.5 && py >= -0.5 && px <= w as f32 - 0.5 && py <= h as f32 - 0.5) {
                    continue;
                }
                on += 1;
                let back = |c: usize| bilinear(ba, c, px, py);
                if (u + back(0)).hypot(v + back(1)) > p.round_trip_px {
                    continue;
                }
                let mut e = 0f32;
                for c in 0..nc {
                    let d = bilinear(b, c, px, py) - a.get(x, y, c);
                    e += d * d;
                }
                if e <= tol2 {
                    n += 1;
                }
            }
            (n, on)
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    // pixels that leave the view (a fast pan) are not evidence of a cut; a motion that sends
    // most of the frame off screen is
    if on_screen * 4 < w * h {
        return 0.0;
    }
    matched as f32 / on_screen as f32
}

#[cfg(test)]
mod tests;
