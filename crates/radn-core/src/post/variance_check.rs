//! How far a frame's variance channels overstate its noise, measured against a neighbouring
//! frame: a renderer's variance AOV is its samples' spread over their count, right for
//! independent samples and many times the error of stratified and low-discrepancy ones, which
//! would make the variance blends ([`crate::post::wiener`]) keep smoothing that is not noise.
//!
//! Per pixel, the squared difference between the frame and its neighbour warped onto it by
//! the frame's motion vectors (bilinear) is compared with what the two frames' variances
//! predict for that difference; the median of the ratio over the frame says how far the
//! variance is off. Counted in a histogram, so a frame gathered band by band gives exactly the
//! whole frame's answer.

use std::ops::Range;

use crate::io::frame::Frame;

/// Below this median ratio the variance is taken to overstate the noise and is scaled by the
/// median: honest variances sit near 1 (heavy-tailed noise lowers the median, motion the
/// vectors miss raises it), overstated ones far below (measured: docs/research/transfer.md).
pub const OVERSTATED_BELOW: f32 = 0.3;

/// Fewer compared pixels than this: no measurement.
const MIN_PIXELS: u64 = 256;

/// Where more than this fraction of the compared pixels equal their warped neighbour exactly,
/// the frames share their noise (rendered with the same seed) and say nothing of its size.
const SHARED_NOISE_FRACTION: f64 = 0.1;

/// Histogram resolution: bins per decade of the ratio, and the decades covered.
const BINS_PER_DECADE: f64 = 64.0;
const LOG_MIN: f64 = -6.0;
const LOG_MAX: f64 = 4.0;

/// Which neighbour a frame is compared with (through `motion_prev` or `motion_next`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Neighbour {
    /// The frame before.
    Previous,
    /// The frame after.
    Next,
}

/// The ratios of one frame's pixels, gathered band by band.
#[derive(Clone, Debug)]
pub struct RatioHistogram {
    bins: Vec<u64>,
    identical: u64,
    total: u64,
}

impl Default for RatioHistogram {
    fn default() -> Self {
        Self {
            bins: vec![0; ((LOG_MAX - LOG_MIN) * BINS_PER_DECADE) as usize],
            identical: 0,
            total: 0,
        }
    }
}

impl RatioHistogram {
    /// Adds rows `rows` (local to `frame`, whose first row is row `frame_y0` of a frame
    /// `full_height` rows tall) compared with `other`, the neighbour's rows from `other_y0`,
    /// which must hold every row the motion reaches from them (and the one below). Pixels
    /// without variance, motion, or all four taps inside the frame are left out.
    #[allow(clippy::too_many_arguments)]
    pub fn add_rows(
        &mut self,
        frame: &Frame,
        frame_y0: usize,
        rows: Range<usize>,
        other: &Frame,
        other_y0: usize,
        towards: Neighbour,
        full_height: usize,
    ) {
        let motion = match towards {
            Neighbour::Previous => frame.motion_prev.as_ref(),
            Neighbour::Next => frame.motion_next.as_ref(),
        };
        let (Some(motion), Some(var), Some(other_var)) =
            (motion, frame.variance.as_ref(), other.variance.as_ref())
        else {
            return;
        };
        let w = frame.width();
        let (n, on) = (frame.color.pixels(), other.color.pixels());
        let (mx, my) = (motion.channel(0), motion.channel(1));
        for y in rows {
            let gy = (frame_y0 + y) as f32;
            for x in 0..w {
                let i = y * w + x;
                let (sx, sy) = (x as f32 + mx[i], gy + my[i]);
                if !(sx.is_finite() && sy.is_finite()) {
                    continue;
                }
                let (fx, fy) = (sx.floor(), sy.floor());
                if fx < 0.0 || fy < 0.0 || fx + 1.0 >= w as f32 || fy + 1.0 >= full_height as f32 {
                    continue;
                }
                let (x0, gy0) = (fx as usize, fy as usize);
                let Some(y0) = gy0
                    .checked_sub(other_y0)
                    .filter(|y0| y0 + 1 < other.height())
                else {
                    debug_assert!(false, "the neighbour's rows do not cover the motion");
                    continue;
                };
                let (ax, ay) = (sx - fx, sy - fy);
                let taps = [
                    ((1.0 - ax) * (1.0 - ay), y0 * w + x0),
                    (ax * (1.0 - ay), y0 * w + x0 + 1),
                    ((1.0 - ax) * ay, (y0 + 1) * w + x0),
                    (ax * ay, (y0 + 1) * w + x0 + 1),
                ];
                let (mut d2, mut p) = (0.0f64, 0.0f64);
                for c in 0..3 {
                    let (warped, warped_var) = taps.iter().fold((0.0, 0.0), |(s, v), &(t, j)| {
                        (
                            s + t * other.color.data()[c * on + j],
                            v + t * t * other_var.data()[c * on + j],
                        )
                    });
                    d2 += f64::from(frame.color.data()[c * n + i] - warped).powi(2);
                    p += f64::from(var.data()[c * n + i] + warped_var);
                }
                if !(d2.is_finite() && p.is_finite() && p > 0.0) {
                    continue;
                }
                self.total += 1;
                if d2 == 0.0 {
                    self.identical += 1;
                }
                self.add_ratio(d2 / p);
            }
        }
    }

    fn add_ratio(&mut self, r: f64) {
        let last = self.bins.len() - 1;
        let k = if r > 0.0 {
            ((r.log10() - LOG_MIN) * BINS_PER_DECADE).clamp(0.0, last as f64) as usize
        } else {
            0
        };
        self.bins[k] += 1;
    }

    /// The median ratio (the centre of its bin), `None` where too few pixels were compared.
    pub fn median(&self) -> Option<f32> {
        if self.total < MIN_PIXELS {
            return None;
        }
        let half = self.total.div_ceil(2);
        let mut seen = 0;
        let k = self.bins.iter().position(|&c| {
            seen += c;
            seen >= half
        })?;
        Some(10f64.powf(LOG_MIN + (k as f64 + 0.5) / BINS_PER_DECADE) as f32)
    }

    /// The median ratio where the comparison measures the noise: `None` where too few pixels
    /// were compared or the frames share their noise.
    pub fn measured(&self) -> Option<f32> {
        if (self.identical as f64) > SHARED_NOISE_FRACTION * self.total as f64 {
            return None;
        }
        self.median()
    }
}

/// The factor for a frame's variance from its comparisons with its neighbours
/// ([`RatioHistogram::measured`]): the smallest measured median where it says the variance
/// overstates the noise (the other comparison may hold motion the vectors miss, or texture
/// the warp interpolates), else `None` (keep the variance as it is).
pub fn scale_of(measured: &[Option<f32>]) -> Option<f32> {
    measured
        .iter()
        .flatten()
        .copied()
        .reduce(f32::min)
        .filter(|m| *m < OVERSTATED_BELOW)
}

/// The factor for `frame`'s variance measured against its neighbours, all whole frames.
pub fn frame_scale(frame: &Frame, prev: Option<&Frame>, next: Option<&Frame>) -> Option<f32> {
    let height = frame.height();
    let measure = |other: Option<&Frame>, towards| {
        let mut h = RatioHistogram::default();
        h.add_rows(frame, 0, 0..height, other?, 0, towards, height);
        h.measured()
    };
    scale_of(&[
        measure(prev, Neighbour::Previous),
        measure(next, Neighbour::Next),
    ])
}

/// Multiplies `frame`'s variance channels by `scale`.
pub fn apply_scale(frame: &mut Frame, scale: f32) {
    if let Some(v) = frame.variance.as_mut() {
        v.data_mut().iter_mut().for_each(|x| *x *= scale);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::plane::Plane;

    const W: usize = 64;
    const H: usize = 48;
    /// The scene moves this far per frame (x, y): the motion to the previous frame is minus it.
    const STEP: (f32, f32) = (1.5, 0.5);

    /// Uniform noise of unit variance, a pure function of its arguments.
    fn noise(x: usize, y: usize, c: usize, seed: u64) -> f32 {
        let mut h = (x as u64) << 40 ^ (y as u64) << 20 ^ (c as u64) << 8 ^ seed;
        h = h.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        h ^= h >> 31;
        h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 29;
        let u = (h >> 11) as f32 / (1u64 << 53) as f32;
        (u - 0.5) * 12f32.sqrt()
    }

    /// Frame `t` of a linear gradient moving by [`STEP`], with noise of deviation `sigma` drawn
    /// from `seed` and variance channels of `overstated` times `sigma²`.
    fn frame(t: usize, sigma: f32, seed: u64, overstated: f32) -> Frame {
        let (ox, oy) = (STEP.0 * t as f32, STEP.1 * t as f32);
        let clean = |x: usize, y: usize, c: usize| {
            0.3 + 0.004 * (x as f32 - ox) + 0.003 * (y as f32 - oy) + 0.05 * c as f32
        };
        let mut f = Frame::synthetic(Plane::from_fn(W, H, 3, |x, y, c| {
            clean(x, y, c) + sigma * noise(x, y, c, seed)
        }));
        f.variance = Some(Plane::from_fn(W, H, 3, |_, _, _| {
            overstated * sigma * sigma
        }));
        f.motion_prev = Some(Plane::from_fn(W, H, 2, |_, _, c| [-STEP.0, -STEP.1][c]));
        f
    }

    #[test]
    fn an_honest_variance_is_kept_and_an_overstated_one_scaled_to_the_noise() {
        let sigma = 0.02;
        let honest = frame_scale(
            &frame(1, sigma, 1, 1.0),
            Some(&frame(0, sigma, 2, 1.0)),
            None,
        );
        assert_eq!(honest, None);
        // 30 times the noise: the median ratio of an honest variance over 30
        let ratios = |overstated: f32| {
            let mut h = RatioHistogram::default();
            let (f, prev) = (
                frame(1, sigma, 1, overstated),
                frame(0, sigma, 2, overstated),
            );
            h.add_rows(&f, 0, 0..H, &prev, 0, Neighbour::Previous, H);
            h
        };
        let (h, honest) = (ratios(30.0), ratios(1.0));
        let (m, m1) = (h.median().unwrap(), honest.median().unwrap());
        assert!((0.5..1.5).contains(&m1), "honest median {m1}");
        assert!((m * 30.0 / m1 - 1.0).abs() < 0.1, "{m} vs {m1} / 30");
        assert_eq!(scale_of(&[h.measured()]), Some(m));
        // the smaller of two neighbours' medians; an honest one keeps the variance
        assert_eq!(scale_of(&[Some(0.05), None, Some(0.02)]), Some(0.02));
        assert_eq!(scale_of(&[Some(0.05), Some(0.7)]), Some(0.05));
        assert_eq!(scale_of(&[Some(0.6), Some(0.7)]), None);
    }

    #[test]
    fn frames_that_share_their_noise_are_not_measured() {
        // the same seed, no motion: the frames are identical, their noise says nothing
        let mut a = frame(0, 0.02, 7, 30.0);
        a.motion_prev = Some(Plane::zeros(W, H, 2));
        let b = frame(0, 0.02, 7, 30.0);
        assert_eq!(frame_scale(&a, Some(&b), None), None);
        // no motion vectors: nothing to measure either
        let mut c = frame(1, 0.02, 1, 30.0);
        c.motion_prev = None;
        assert_eq!(frame_scale(&c, Some(&b), Some(&b)), None);
    }

    #[test]
    fn band_by_band_counts_equal_the_whole_frames() {
        let (f, prev) = (frame(1, 0.02, 1, 30.0), frame(0, 0.02, 2, 30.0));
        let whole = {
            let mut h = RatioHistogram::default();
            h.add_rows(&f, 0, 0..H, &prev, 0, Neighbour::Previous, H);
            h
        };
        let mut banded = RatioHistogram::default();
        for y0 in (0..H).step_by(16) {
            let rows = y0..(y0 + 16).min(H);
            let near = y0.saturating_sub(2)..(rows.end + 2).min(H);
            banded.add_rows(
                &f.rows(rows.clone()),
                y0,
                0..rows.len(),
                &prev.rows(near.clone()),
                near.start,
                Neighbour::Previous,
                H,
            );
        }
        assert_eq!(banded.bins, whole.bins);
        assert_eq!(
            (banded.total, banded.identical),
            (whole.total, whole.identical)
        );
        assert!(whole.total > (W * H / 2) as u64);
    }
}
