//! A frame's noise as a function of brightness, fitted on the frame itself: per pixel variance
//! that detail does not inflate, whatever the renderer's sampler.
//!
//! Monte Carlo noise grows with brightness; its relative variance (variance over squared
//! luminance) is about the same among pixels of similar luminance. Detail only ever adds to a
//! pixel's local spread, so among the pixels of one luminance band a low quantile of the
//! relative local spread measures the noise and not the texture. The frame's pixels are split
//! into bands of equal count by luminance; each band's noise is that quantile, never above a
//! darker band's (where a bright band is all texture, its quantile is still texture); a pixel's
//! variance is its band's relative variance times its squared luminance. A whole-frame fit: the classic
//! method, which runs whole frames, uses it.

use crate::image::ops::box_mean;
use crate::image::plane::Plane;

/// A frame's per-pixel, per-channel noise variance from its own neighbourhood: the squared
/// difference to the 3×3 mean, averaged over 5×5 (and corrected for the 9 samples of the mean).
/// Detail reads as noise here: it is the fallback where no other frame can be trusted.
pub fn local_variance(x: &Plane) -> Plane {
    let m = box_mean(x, 1);
    let mut d = x.clone();
    d.data_mut()
        .iter_mut()
        .zip(m.data())
        .for_each(|(v, mu)| *v = (*v - mu) * (*v - mu));
    let mut v = box_mean(&d, 2);
    v.data_mut().iter_mut().for_each(|v| *v *= 9.0 / 8.0);
    v
}

/// Luminance bands of the fit.
const BANDS: usize = 24;
/// Pixels darker than this are left out of the fit (black has no relative noise).
const MIN_LUMINANCE: f32 = 1e-6;

/// The fitted relative noise variance of each luminance band of a frame.
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseModel {
    /// Upper luminance edge of each band, ascending.
    edges: Vec<f32>,
    /// Relative variance of each band.
    relative: Vec<f32>,
}

impl NoiseModel {
    /// Fits the model on `color` (RGB), the band's `quantile` (0..1) of the pixels' relative
    /// local variance; `None` where too few pixels are lit to fit.
    pub fn fit(color: &Plane, quantile: f32) -> Option<Self> {
        let lum = mean_over_channels(color);
        let spread = mean_over_channels(&local_variance(color));
        let mut px: Vec<(f32, f32)> = lum
            .iter()
            .zip(&spread)
            .filter(|(l, s)| **l > MIN_LUMINANCE && s.is_finite() && l.is_finite())
            .map(|(l, s)| (*l, s / (l * l)))
            .collect();
        if px.len() < BANDS * 16 {
            return None;
        }
        px.sort_by(|a, b| a.0.total_cmp(&b.0));
        let per = px.len() / BANDS;
        let mut edges = Vec::with_capacity(BANDS);
        let mut relative = Vec::with_capacity(BANDS);
        for b in 0..BANDS {
            let end = if b + 1 == BANDS {
                px.len()
            } else {
                (b + 1) * per
            };
            let band = &px[b * per..end];
            let mut rel: Vec<f32> = band.iter().map(|p| p.1).collect();
            let k = ((quantile.clamp(0.0, 1.0) * rel.len() as f32) as usize).min(rel.len() - 1);
            let (_, q, _) = rel.select_nth_unstable_by(k, f32::total_cmp);
            edges.push(band[band.len() - 1].0);
            relative.push(*q);
        }
        // Monte Carlo noise is relatively smaller on brighter pixels: a band whose quantile is
        // above a darker band's is read as texture there, and takes the darker band's value
        for b in 1..relative.len() {
            relative[b] = relative[b].min(relative[b - 1]);
        }
        Some(Self { edges, relative })
    }

    /// The relative variance at luminance `l` (its band's).
    pub fn relative_variance(&self, l: f32) -> f32 {
        let b = self
            .edges
            .partition_point(|e| *e < l)
            .min(self.edges.len() - 1);
        self.relative[b]
    }

    /// Per pixel (and, the same, per channel) noise variance of `color`.
    pub fn variance(&self, color: &Plane) -> Plane {
        let lum = mean_over_channels(color);
        let mut v = Plane::zeros(color.width(), color.height(), color.channels());
        let n = color.pixels();
        for c in 0..color.channels() {
            v.data_mut()[c * n..(c + 1) * n]
                .iter_mut()
                .zip(&lum)
                .for_each(|(v, l)| {
                    let l = l.max(0.0);
                    *v = self.relative_variance(l) * l * l;
                });
        }
        v
    }
}

/// The mean over the first three channels, per pixel.
fn mean_over_channels(p: &Plane) -> Vec<f32> {
    let c = p.channels().min(3);
    let n = p.pixels();
    (0..n)
        .map(|i| (0..c).map(|k| p.data()[k * n + i]).sum::<f32>() / c as f32)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame of smooth shading with a fine high-contrast texture on its right half, and
    /// Gaussian noise whose variance grows with brightness (σ² = a·L): the true variance per
    /// pixel is known.
    fn frame(a: f32, seed: u64) -> (Plane, Plane) {
        let (w, h) = (192, 128);
        let mut x = Plane::zeros(w, h, 3);
        let mut truth = Plane::zeros(w, h, 3);
        let mut s = seed;
        let mut gauss = move || {
            // Box–Muller over a 64-bit LCG
            let mut u = || {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((s >> 11) as f64 / (1u64 << 53) as f64).max(1e-12)
            };
            let (u1, u2) = (u(), u());
            ((-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()) as f32
        };
        for y in 0..h {
            for xx in 0..w {
                let shade = 0.05 + 2.0 * (xx as f32 / w as f32) * (y as f32 / h as f32 + 0.2);
                let texture = if xx >= w / 2 && (xx + y) % 2 == 0 {
                    0.3
                } else {
                    1.0
                };
                let clean = shade * texture;
                for c in 0..3 {
                    let var = a * clean;
                    truth.set(xx, y, c, var);
                    x.set(xx, y, c, clean + var.sqrt() * gauss());
                }
            }
        }
        (x, truth)
    }

    #[test]
    fn texture_does_not_read_as_noise_and_the_fit_follows_the_noise_level() {
        for a in [0.02f32, 0.002] {
            let (x, truth) = frame(a, 7);
            let model = NoiseModel::fit(&x, 0.1).expect("a lit frame");
            let v = model.variance(&x);
            let w = x.width();
            // mean estimate over the textured half against the truth there
            let (mut est, mut tru) = (0.0f64, 0.0f64);
            for y in 8..x.height() - 8 {
                for xx in w / 2 + 8..w - 8 {
                    est += v.get(xx, y, 0) as f64;
                    tru += truth.get(xx, y, 0) as f64;
                }
            }
            let ratio = est / tru;
            // the local spread of the texture is ~50x the noise there at a = 0.002: a fit that
            // read texture as noise would be far above 1
            assert!(
                (0.3..2.0).contains(&ratio),
                "a = {a}: estimate / truth = {ratio}"
            );
        }
    }

    #[test]
    fn a_black_frame_has_no_model() {
        assert!(NoiseModel::fit(&Plane::zeros(64, 64, 3), 0.1).is_none());
    }
}
