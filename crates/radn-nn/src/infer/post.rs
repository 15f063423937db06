//! A window's result: the kernels' result over the rows asked for, then the stages after the
//! network that the recipe switches on, in order (the input blend, the guide mix), each over
//! the same stacking of signals (colour, then each AOV, then alpha).

use burn::tensor::Tensor;
use std::ops::Range;

use radn_core::align::AlignedWindow;
use radn_core::classic::wiener::{blend, blend_weight, window_noise_variance};
use radn_core::denoiser::Denoised;
use radn_core::Plane;

use crate::infer::input::{FeatureScales, Region};
use crate::infer::stems::WindowStems;
use crate::model::demod::{filter, Demodulation};
use crate::model::guide_blend::GuideBlend;
use crate::profile::{timed, Stage};

use super::{guide_mix, NetworkDenoiser};

impl NetworkDenoiser {
    /// Denoises rows `rows` of an aligned window (a band of a frame whose whole-frame
    /// feature scales are `scales`); rows beyond the window's own are never read, so a band must carry the
    /// receptive field's rows around `rows` unless they are the frame's edge.
    pub fn denoise_rows(
        &self,
        win: &AlignedWindow,
        stems: Option<&WindowStems>,
        scales: FeatureScales,
        rows: Range<usize>,
    ) -> Denoised {
        let blend_params = self
            .recipe
            .input_blend
            .and_then(|b| b.params(scales.noise_level, &self.recipe.schedule));
        let (mut out, learned) = match &blend_params {
            None => self.filtered_rows(win, stems, scales, rows.clone()),
            Some(p) => {
                // the blend's boxes read the result `radius` rows beyond `rows`
                let h = win.centre().color.height();
                let wide = rows.start.saturating_sub(p.radius)..(rows.end + p.radius).min(h);
                let (filtered, learned) = self.filtered_rows(win, stems, scales, wide.clone());
                let inside = rows.start - wide.start..rows.end - wide.start;
                let learned = learned.map(|w| w.rows(inside.clone()));
                let blended = timed(Stage::InputBlend, || {
                    let input = centre_values(win, wide.clone());
                    let var = window_noise_variance(win, wide.clone());
                    let weight = blend_weight(
                        &input.select_channels(0, 3),
                        &filtered.select_channels(0, 3),
                        &var,
                        p,
                    );
                    blend(&input, &filtered, &weight).rows(inside)
                });
                (blended, learned)
            }
        };
        let c = win.centre();
        let aov_ch: Vec<usize> = c.aovs.iter().map(|a| a.channels()).collect();
        let mix = self.recipe.guide_mix;
        let mixes = mix.weight > 0.0 || mix.outliers.is_some() || learned.is_some();
        if let (Some(guide), true) = (&c.guide, mixes) {
            timed(Stage::GuideMix, || {
                let rgb_groups: Vec<usize> = aov_ch
                    .iter()
                    .scan(3, |at, &n| {
                        let start = *at;
                        *at += n;
                        Some((n == 3).then_some(start))
                    })
                    .flatten()
                    .collect();
                let g = if let Some(range) = self.guide_mix_range_for(scales.noise_level) {
                    guide_mix::window_guide(win, rows.clone(), range)
                } else {
                    guide.rows(rows.clone())
                };
                let weight = match &learned {
                    Some(w) => guide_mix::MixWeight::PerPixel(w.channel(0)),
                    None => guide_mix::MixWeight::Uniform(mix.weight),
                };
                guide_mix::mix_with_guide(&mut out, &g, weight, mix.outliers, &rgb_groups)
            });
        }
        let has_alpha = c.alpha.is_some();
        let color = out.select_channels(0, 3);
        let mut at = 3;
        let aovs = aov_ch
            .iter()
            .map(|&n| {
                let p = out.select_channels(at, n);
                at += n;
                p
            })
            .collect();
        let alpha = has_alpha.then(|| out.select_channels(at, 1));
        Denoised { color, alpha, aovs }
    }

    /// The kernels' result for rows `rows` of an aligned window, every signal stacked along
    /// channels: colour, then each AOV, then alpha; and the weights of the learned guide mix
    /// over those rows where the network has one and the recipe's `guide_mix.learned`
    /// asks for it.
    fn filtered_rows(
        &self,
        win: &AlignedWindow,
        stems: Option<&WindowStems>,
        scales: FeatureScales,
        rows: Range<usize>,
    ) -> (Plane, Option<Plane>) {
        let c = win.centre();
        let t = win.frames.len();
        // every signal stacked along channels: colour, AOVs, alpha
        let mut chans = 3;
        let aov_ch: Vec<usize> = c.aovs.iter().map(|a| a.channels()).collect();
        chans += aov_ch.iter().sum::<usize>();
        let has_alpha = c.alpha.is_some();
        if has_alpha {
            chans += 1;
        }
        // the window's values (colour, AOVs, alpha of every frame) for one tile's region
        let values = |r: Region| {
            let mut v = Vec::with_capacity(t * chans * r.pixels());
            for f in &win.frames {
                r.crop(&f.color, &mut v);
                for a in &f.aovs {
                    r.crop(a, &mut v);
                }
                if let Some(a) = &f.alpha {
                    r.crop(a, &mut v);
                }
            }
            v
        };
        // colour and every RGB AOV are demodulated by albedo when the model asks for it
        let mut rgb = vec![0];
        let mut at = 3;
        for &n in &aov_ch {
            if n == 3 {
                rgb.push(at);
            }
            at += n;
        }
        let eps = self.denoiser.config.demodulate;
        let inputs = &self.denoiser.config.inputs;
        let learned = self.recipe.guide_mix.learned && self.denoiser.config.guide_mix_head;
        let inv_exposure = if inputs.exposure {
            1.0 / scales.exposure
        } else {
            1.0
        };
        let out = self.run_tiled(
            win,
            stems,
            scales,
            rows,
            values,
            chans,
            |p, guides, v, x| {
                let demod = eps.map(|eps| Demodulation::new(x, eps, rgb.clone(), chans));
                let v = match guides.blend {
                    Some(beta) => GuideBlend::new(x, beta, inputs, rgb.clone(), chans).apply(v),
                    None => v,
                };
                let filtered = filter(p, v, demod.as_ref());
                if !learned {
                    return filtered;
                }
                // the mix weights travel as one more channel of the tiles' result
                let w = match (guides.mix, guides.mix_features) {
                    (Some(w), _) => w,
                    (None, Some(features)) => {
                        let b = features.dims()[0];
                        self.denoiser.mix_weight_of_result(
                            features,
                            filtered.clone().narrow(1, 0, 3),
                            Tensor::full([b, 1, 1, 1], inv_exposure, &self.device),
                            x,
                        )
                    }
                    (None, None) => {
                        unreachable!("a network with the guide mix predicts its weights")
                    }
                };
                Tensor::cat(vec![filtered, w], 1)
            },
        );
        if learned {
            let w = out.select_channels(chans, 1);
            (out.select_channels(0, chans), Some(w))
        } else {
            (out, None)
        }
    }
}

/// The centre frame's signals at rows `rows`, stacked as [`NetworkDenoiser`] filters them:
/// colour, then each AOV, then alpha.
fn centre_values(win: &AlignedWindow, rows: Range<usize>) -> Plane {
    let c = win.centre();
    let mut planes = vec![c.color.rows(rows.clone())];
    planes.extend(c.aovs.iter().map(|a| a.rows(rows.clone())));
    planes.extend(c.alpha.iter().map(|a| a.rows(rows.clone())));
    Plane::concat(&planes.iter().collect::<Vec<_>>())
}
