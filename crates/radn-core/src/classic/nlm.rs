//! Joint non-local means (Buades et al. 2005, with the variance-cancelling colour distance and
//! feature weights of Rousselle et al. 2012/2013): colour patch distances plus albedo, normal and
//! depth distances. Patch distances are box-filtered per search offset, so the cost does not
//! grow with the patch size. The weights are applied to any number of signals (colour and AOVs).

use rayon::prelude::*;

use crate::image::ops::box_sum_into;
use crate::image::plane::Plane;

/// NLM options.
#[derive(Clone, Copy, Debug)]
pub struct NlmParams {
    /// Search radius in pixels (noice's default is 9).
    pub search_radius: usize,
    /// Patch radius in pixels (noice's default is 3).
    pub patch_radius: usize,
    /// Colour filter strength k (larger blurs more).
    pub strength: f32,
    /// Albedo distance at which the feature weight is e^-1.
    pub albedo_sigma: f32,
    /// Normal distance at which the feature weight is e^-1.
    pub normal_sigma: f32,
    /// Relative depth distance at which the feature weight is e^-1.
    pub depth_sigma: f32,
}

impl Default for NlmParams {
    fn default() -> Self {
        Self {
            search_radius: 9,
            patch_radius: 3,
            strength: 0.45,
            albedo_sigma: 0.06,
            normal_sigma: 0.25,
            depth_sigma: 0.04,
        }
    }
}

/// What the NLM weights are computed from.
pub struct NlmGuide<'a> {
    /// The image whose patches are compared (3 channels).
    pub color: &'a Plane,
    /// Per-pixel, per-channel variance of `color`.
    pub variance: &'a Plane,
    /// Albedo (3 channels), if any.
    pub albedo: Option<&'a Plane>,
    /// Normal (3 channels), if any.
    pub normal: Option<&'a Plane>,
    /// Depth (1 channel), if any.
    pub depth: Option<&'a Plane>,
}

/// The filtered signals and how much the filter averaged at each pixel.
pub struct NlmOutput {
    /// Every signal filtered with the same weights, in the input order.
    pub signals: Vec<Plane>,
    /// Per pixel, `Σw² / (Σw)²` of the normalised weights (1 channel): the factor by which
    /// the filter divides the variance of independent per-pixel noise (1 where it kept the
    /// pixel, 1/N for a plain mean of N pixels).
    pub variance_ratio: Plane,
}

/// Filters every signal with the same NLM weights computed from `guide`.
pub fn nlm(guide: &NlmGuide, signals: &[&Plane], p: &NlmParams) -> NlmOutput {
    let (w, h) = (guide.color.width(), guide.color.height());
    let n = w * h;
    let r = p.search_radius as isize;
    let k2 = p.strength * p.strength;
    let patch_area = ((2 * p.patch_radius + 1) * (2 * p.patch_radius + 1)) as f32;
    let mut num: Vec<Plane> = signals
        .iter()
        .map(|s| Plane::zeros(w, h, s.channels()))
        .collect();
    let mut den = vec![0f32; n];
    let mut den2 = vec![0f32; n];
    let mut dist = vec![0f32; n];
    let mut tmp = vec![0f32; n];
    let mut patch = vec![0f32; n];
    let mut wf = vec![0f32; n];
    let col = guide.color.data();
    let var = guide.variance.data();
    for dy in -r..=r {
        for dx in -r..=r {
            // per-pixel colour distance and feature weight for offset (dx, dy)
            dist.par_chunks_mut(w)
                .zip(wf.par_chunks_mut(w))
                .enumerate()
                .for_each(|(y, (drow, frow))| {
                    let qy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
                    for x in 0..w {
                        let qx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
                        let (i, j) = (y * w + x, qy * w + qx);
                        let mut d = 0.0;
                        for c in 0..3 {
                            let (vp, vq) = (var[c * n + i], var[c * n + j]);
                            let diff = col[c * n + i] - col[c * n + j];
                            d += (diff * diff - (vp + vp.min(vq))) / (1e-10 + k2 * (vp + vq));
                        }
                        drow[x] = d / 3.0;
                        frow[x] = feature_energy(guide, i, j, n, p);
                    }
                });
            box_sum_into(&dist, w, h, p.patch_radius, &mut tmp, &mut patch);
            // accumulate
            let inside = |x: usize, y: usize| {
                let qx = x as isize + dx;
                let qy = y as isize + dy;
                qx >= 0 && qy >= 0 && qx < w as isize && qy < h as isize
            };
            den.par_chunks_mut(w)
                .zip(den2.par_chunks_mut(w))
                .zip(patch.par_chunks_mut(w))
                .enumerate()
                .for_each(|(y, ((drow, d2row), prow))| {
                    for x in 0..w {
                        // min(colour weight, feature weight) = exp(−max(colour energy, feature energy))
                        let e = (prow[x] / patch_area).max(0.0).max(wf[y * w + x]);
                        let wt = if inside(x, y) { (-e).exp() } else { 0.0 };
                        prow[x] = wt; // reuse as the weight buffer
                        drow[x] += wt;
                        d2row[x] += wt * wt;
                    }
                });
            for (s, acc) in signals.iter().zip(num.iter_mut()) {
                let chans = s.channels();
                acc.data_mut()
                    .par_chunks_mut(w)
                    .enumerate()
                    .for_each(|(row, arow)| {
                        let c = row / h;
                        let y = row % h;
                        let qy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
                        let src = s.channel(c);
                        for x in 0..w {
                            let qx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
                            arow[x] += patch[y * w + x] * src[qy * w + qx];
                        }
                    });
                debug_assert_eq!(chans, acc.channels());
            }
        }
    }
    for acc in num.iter_mut() {
        let n = acc.pixels();
        acc.data_mut().par_chunks_mut(n).for_each(|ch| {
            for (v, d) in ch.iter_mut().zip(&den) {
                *v /= d.max(1e-12);
            }
        });
    }
    let variance_ratio = Plane::from_fn(w, h, 1, |x, y, _| {
        let i = y * w + x;
        den2[i] / (den[i] * den[i]).max(1e-24)
    });
    NlmOutput {
        signals: num,
        variance_ratio,
    }
}

/// The feature term's exponent: the feature weight is `exp(−energy)`.
#[inline]
fn feature_energy(g: &NlmGuide, i: usize, j: usize, n: usize, p: &NlmParams) -> f32 {
    let mut e = 0.0;
    if let Some(a) = g.albedo {
        let a = a.data();
        let d: f32 = (0..3)
            .map(|c| (a[c * n + i] - a[c * n + j]).powi(2))
            .sum::<f32>()
            / 3.0;
        e += d / (p.albedo_sigma * p.albedo_sigma);
    }
    if let Some(nm) = g.normal {
        let nm = nm.data();
        let d: f32 = (0..3)
            .map(|c| (nm[c * n + i] - nm[c * n + j]).powi(2))
            .sum::<f32>()
            / 3.0;
        e += d / (p.normal_sigma * p.normal_sigma);
    }
    if let Some(z) = g.depth {
        let (a, b) = (z.data()[i], z.data()[j]);
        let d = (a - b) / a.abs().max(b.abs()).max(1e-6);
        e += d * d / (p.depth_sigma * p.depth_sigma);
    }
    e
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classic::test_noise as noise;

    #[test]
    fn constant_image_plus_noise_loses_most_of_its_variance() {
        let (w, h) = (64, 64);
        let amp = 0.2f32;
        let img = Plane::from_fn(w, h, 3, |x, y, c| 0.5 + amp * noise(x, y, c));
        let var_in = amp * amp / 12.0;
        let variance = Plane::filled(w, h, 3, var_in);
        let guide = NlmGuide {
            color: &img,
            variance: &variance,
            albedo: None,
            normal: None,
            depth: None,
        };
        let filtered = nlm(&guide, &[&img], &NlmParams::default());
        let ratio = filtered.variance_ratio.data().iter().sum::<f32>() / (w * h) as f32;
        let out = filtered.signals.into_iter().next().unwrap();
        let mean: f32 = out.data().iter().sum::<f32>() / out.data().len() as f32;
        let var_out: f32 =
            out.data().iter().map(|v| (v - mean).powi(2)).sum::<f32>() / out.data().len() as f32;
        assert!((mean - 0.5).abs() < 0.01);
        // a 19×19 search window could at best divide the variance by 361; demand at least 20×
        assert!(var_out < var_in / 20.0, "variance {var_in} -> {var_out}");
        // the reported variance ratio is what the filter did to the noise (within 2x: the
        // patch weights correlate neighbouring outputs)
        assert!(ratio < 1.0 / 20.0, "variance ratio {ratio}");
        assert!(
            var_out / var_in < 2.0 * ratio && ratio < 4.0 * var_out / var_in,
            "{ratio} vs {}",
            var_out / var_in
        );
    }

    #[test]
    fn features_keep_an_edge_sharp_and_aovs_get_the_same_weights() {
        let (w, h) = (40, 24);
        let albedo = Plane::from_fn(w, h, 3, |x, _, _| if x < 20 { 0.2 } else { 0.8 });
        let img = Plane::from_fn(w, h, 3, |x, y, c| {
            albedo.get(x, y, c) + 0.05 * noise(x, y, c)
        });
        let variance = Plane::filled(w, h, 3, 0.05 * 0.05 / 12.0);
        let guide = NlmGuide {
            color: &img,
            variance: &variance,
            albedo: Some(&albedo),
            normal: None,
            depth: None,
        };
        let aov = img.clone();
        let out = nlm(&guide, &[&img, &aov], &NlmParams::default()).signals;
        for y in 0..h {
            assert!(
                (out[0].get(19, y, 0) - 0.2).abs() < 0.03
                    && (out[0].get(20, y, 0) - 0.8).abs() < 0.03
            );
        }
        assert_eq!(out[0], out[1]);
    }
}
