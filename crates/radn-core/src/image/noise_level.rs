//! A frame's noise level: one number that says how noisy a whole frame is, so that what must
//! follow the sample count (the network's input blend, [`crate::post::wiener`]) can follow it
//! per frame rather than per pixel (a 128-spp frame's dark pixels are as noisy, relatively, as a
//! 4-spp frame's bright ones, yet want the settings of a clean frame: docs/research/detail.md).
//!
//! The level is the 99th percentile over the frame of the relative noise variance of its
//! luminance, divided by the albedo where the frame has one (so that texture does not read as
//! noise). A high percentile, not the median: the noisiest pixels are where a frame's error is,
//! and a frame that is mostly smooth and bright has a tiny median even at 4 spp (docs/research/detail.md:
//! on such a test scene the median read as a 128-spp frame and the blend gave the noise back). Each
//! pixel's variance comes from the horizontal second difference `x[i-1] − 2·x[i] + x[i+1]`, which
//! cancels a linear ramp and has variance `6σ²` on independent pixel noise, divided by the
//! squared mean of the same three pixels. It reads no other row, so a frame gathered band by
//! band (the statistics pass) gets exactly the level of the whole frame: the percentile is taken
//! from a histogram of integer counts.

use std::ops::Range;

use crate::image::plane::Plane;

/// Added to the albedo before dividing by it (dark albedo would amplify noise without bound).
const ALBEDO_EPSILON: f32 = 0.02;
/// Pixels whose three-pixel mean luminance is below this are left out (black has no relative
/// noise).
const MIN_MEAN: f32 = 1e-6;
/// Histogram bins per octave of relative variance.
const BINS_PER_OCTAVE: f32 = 32.0;
/// The smallest octave the histogram holds (2^-40); smaller variances count in the first bin.
const MIN_OCTAVE: f32 = -40.0;
/// Octaves the histogram spans (up to 2^8); larger variances count in the last bin.
const OCTAVES: usize = 48;

/// Which quantile of the per-pixel relative variances is a frame's level.
pub const LEVEL_QUANTILE: f64 = 0.99;

/// The histogram a frame's level is a quantile of, filled row by row.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NoiseLevelHistogram {
    counts: Vec<u64>,
}

impl Default for NoiseLevelHistogram {
    fn default() -> Self {
        Self {
            counts: vec![0; OCTAVES * BINS_PER_OCTAVE as usize],
        }
    }
}

impl NoiseLevelHistogram {
    /// The histogram of a whole frame (`albedo` of the same size, if the frame has one).
    pub fn of_frame(color: &Plane, albedo: Option<&Plane>) -> Self {
        let mut h = Self::default();
        h.add_rows(color, albedo, 0..color.height());
        h
    }

    /// Counts rows `rows` of `color` (and `albedo`, the same size) into the histogram.
    pub fn add_rows(&mut self, color: &Plane, albedo: Option<&Plane>, rows: Range<usize>) {
        let w = color.width();
        if w < 3 {
            return;
        }
        let mut luminance = vec![0f32; w];
        for y in rows {
            for (x, l) in luminance.iter_mut().enumerate() {
                *l = (0..3)
                    .map(|c| {
                        let v = color.get(x, y, c);
                        match albedo {
                            Some(a) => v / (a.get(x, y, c).max(0.0) + ALBEDO_EPSILON),
                            None => v,
                        }
                    })
                    .sum::<f32>()
                    / 3.0;
            }
            for t in luminance.windows(3) {
                let mean = (t[0] + t[1] + t[2]) / 3.0;
                let second = t[0] - 2.0 * t[1] + t[2];
                if !(mean >= MIN_MEAN && second.is_finite()) {
                    continue;
                }
                let variance = second * second / 6.0 / (mean * mean);
                self.counts[bin(variance)] += 1;
            }
        }
    }

    /// Adds another histogram's counts (another band of the same frame).
    pub fn merge(&mut self, other: &Self) {
        self.counts
            .iter_mut()
            .zip(&other.counts)
            .for_each(|(a, b)| *a += b);
    }

    /// The frame's noise level: the [`LEVEL_QUANTILE`] of its relative noise variances;
    /// `None` for a frame with no pixel counted (black, or narrower than 3 pixels).
    pub fn level(&self) -> Option<f32> {
        self.quantile(LEVEL_QUANTILE)
    }

    /// The `q`-quantile (0..=1) of the counted relative variances (the centre of its bin);
    /// `None` for a frame with no pixel counted.
    pub fn quantile(&self, q: f64) -> Option<f32> {
        let total: u64 = self.counts.iter().sum();
        if total == 0 {
            return None;
        }
        let rank = ((q.clamp(0.0, 1.0) * total as f64).ceil() as u64).max(1);
        let mut seen = 0;
        let k = self.counts.iter().position(|&c| {
            seen += c;
            seen >= rank
        })?;
        Some(((k as f32 + 0.5) / BINS_PER_OCTAVE + MIN_OCTAVE).exp2())
    }
}

/// The histogram bin of a relative variance.
fn bin(variance: f32) -> usize {
    let last = OCTAVES * BINS_PER_OCTAVE as usize - 1;
    if variance <= 0.0 {
        return 0;
    }
    let k = ((variance.log2() - MIN_OCTAVE) * BINS_PER_OCTAVE).floor();
    (k.max(0.0) as usize).min(last)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A gradient times a texture, plus noise of relative standard deviation `sigma`.
    fn frame(w: usize, h: usize, sigma: f32, seed: u64) -> (Plane, Plane) {
        let mut state = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
        let mut gauss = move || {
            // Box–Muller from a 64-bit LCG
            let mut u = || {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
            };
            let (a, b) = (u(), u());
            ((-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()) as f32
        };
        let albedo = Plane::from_fn(
            w,
            h,
            3,
            |x, y, _| {
                if (x / 2 + y / 3) % 2 == 0 {
                    0.8
                } else {
                    0.2
                }
            },
        );
        let color = Plane::from_fn(w, h, 3, |x, y, c| {
            let shade = 0.5 + x as f32 / w as f32 + 0.3 * y as f32 / h as f32;
            albedo.get(x, y, c) * shade
        });
        let mut noisy = color.clone();
        for v in noisy.data_mut() {
            *v *= 1.0 + sigma * gauss();
        }
        (noisy, albedo)
    }

    #[test]
    fn the_level_is_the_relative_noise_variance_through_texture() {
        // per-channel relative noise sigma; the luminance of three channels with independent
        // noise has relative variance sigma²/3 (below about 5 % noise the albedo's ε leaves a
        // trace of this texture's 4:1 steps in the level)
        for sigma in [0.3f32, 0.1] {
            let (c, a) = frame(200, 60, sigma, 3);
            let h = NoiseLevelHistogram::of_frame(&c, Some(&a));
            let expected = sigma * sigma / 3.0;
            // the median and the 99th percentile of a scaled chi-square with one degree of
            // freedom are 0.455 and 6.63 times its mean
            for (q, factor) in [(0.5, 0.455), (LEVEL_QUANTILE, 6.63)] {
                let v = h.quantile(q).unwrap();
                let ratio = v / (factor * expected);
                assert!(
                    (0.8..1.25).contains(&ratio),
                    "sigma {sigma}, q {q}: {v}, ratio {ratio}"
                );
            }
            assert_eq!(h.level(), h.quantile(LEVEL_QUANTILE));
        }
    }

    #[test]
    fn without_the_albedo_texture_reads_as_noise() {
        let (c, a) = frame(200, 60, 0.03, 4);
        let with = NoiseLevelHistogram::of_frame(&c, Some(&a))
            .quantile(0.5)
            .unwrap();
        let without = NoiseLevelHistogram::of_frame(&c, None)
            .quantile(0.5)
            .unwrap();
        assert!(without > 10.0 * with, "{without} vs {with}");
    }

    #[test]
    fn bands_give_exactly_the_whole_frames_level() {
        let (c, a) = frame(97, 70, 0.1, 5);
        let whole = NoiseLevelHistogram::of_frame(&c, Some(&a));
        let mut banded = NoiseLevelHistogram::default();
        for y0 in (0..70).step_by(16) {
            let rows = y0..(y0 + 16).min(70);
            let mut band = NoiseLevelHistogram::default();
            band.add_rows(
                &c.rows(rows.clone()),
                Some(&a.rows(rows.clone())),
                0..rows.len(),
            );
            banded.merge(&band);
        }
        assert_eq!(banded, whole);
        assert!(whole.level().is_some());
    }

    #[test]
    fn a_black_or_narrow_frame_has_no_level() {
        let black = Plane::from_fn(10, 10, 3, |_, _, _| 0.0);
        assert_eq!(NoiseLevelHistogram::of_frame(&black, None).level(), None);
        let narrow = Plane::from_fn(2, 10, 3, |_, _, _| 1.0);
        assert_eq!(NoiseLevelHistogram::of_frame(&narrow, None).level(), None);
    }
}
