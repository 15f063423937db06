//! The classic denoiser end to end, for one window: align → robust temporal average →
//! (albedo-demodulated) joint NLM → guided filter → remodulate. Every stage is a linear
//! operator on the signals for weights computed from the beauty and the features, so AOVs and
//! alpha receive exactly the beauty's operator, and AOVs that sum to the beauty still do.

use rayon::prelude::*;

use super::guided::{guided_filter, GuidedParams};
use super::nlm::{nlm, NlmGuide, NlmParams};
use super::refine::{refine_motion, RefineParams};
use super::temporal::{apply_weights, robust_weights, temporal_variance};
use crate::align::confidence::box3;
use crate::align::motion::invert;
use crate::align::{align_window, AlignParams};
use crate::image::ops::box_mean;
use crate::image::plane::Plane;
use crate::io::frame::Frame;
use crate::post::wiener::{
    blend, blend_weight, local_variance, variance_blend_weight, BlendParams, VarianceBlend,
};

/// All options of the classic denoiser.
#[derive(Clone, Copy, Debug)]
pub struct ClassicParams {
    /// Alignment and confidence.
    pub align: AlignParams,
    /// Optical-flow refinement of the renderer's motion (None: renderer motion only).
    pub flow_refine: Option<RefineParams>,
    /// Non-local means.
    pub nlm: NlmParams,
    /// Guided filter (None: skip).
    pub guided: Option<GuidedParams>,
    /// Blend of the guided filter's output with its input by the remaining noise (None: take
    /// the guided filter's output everywhere, whatever the noise level).
    pub guided_blend: Option<BlendParams>,
    /// Filter colour divided by albedo (texture detail is then kept by remodulation).
    pub demodulate: bool,
    /// The last stage, where the centre frame carries the renderer's per-pixel variance: the
    /// result blended back towards the centre's input where it changed it by more than that
    /// noise explains (None: the result as it is).
    pub variance_blend: Option<VarianceBlend>,
}

impl Default for ClassicParams {
    fn default() -> Self {
        Self {
            align: AlignParams::default(),
            flow_refine: Some(RefineParams::default()),
            nlm: NlmParams::default(),
            guided: Some(GuidedParams::default()),
            guided_blend: Some(BlendParams::default()),
            demodulate: true,
            // chosen on the Mitsuba validation split (docs/research/transfer.md)
            variance_blend: Some(VarianceBlend::new(4)),
        }
    }
}

/// The denoised centre frame of a window.
#[derive(Clone, Debug)]
pub struct ClassicResult {
    /// Denoised beauty.
    pub color: Plane,
    /// Denoised alpha, if the frames have alpha.
    pub alpha: Option<Plane>,
    /// Denoised AOVs, in the frames' order.
    pub aovs: Vec<Plane>,
    /// Per-pixel weight of each window slot in the temporal average (sums to 1).
    pub temporal_weights: Vec<Plane>,
}

/// Replaces a frame's renderer motion by refined motion towards its neighbours (each `None`
/// at a sequence end). Call once per frame of a sequence, before its windows are aligned.
pub fn refine_frame_motion(
    frame: &mut Frame,
    prev: Option<&Frame>,
    next: Option<&Frame>,
    p: &RefineParams,
    invert_iterations: usize,
) {
    if let Some(prev) = prev {
        let init = frame.motion_prev.clone().or_else(|| {
            prev.motion_next
                .as_ref()
                .map(|m| invert(m, invert_iterations))
        });
        if let Some(init) = init {
            frame.motion_prev = Some(refine_motion(&frame.color, &prev.color, &init, p).flow);
        }
    }
    if let Some(next) = next {
        let init = frame.motion_next.clone().or_else(|| {
            next.motion_prev
                .as_ref()
                .map(|m| invert(m, invert_iterations))
        });
        if let Some(init) = init {
            frame.motion_next = Some(refine_motion(&frame.color, &next.color, &init, p).flow);
        }
    }
}

/// Denoises the centre of a window of (already motion-refined) frames; `None` marks frames
/// beyond the sequence ends.
pub fn denoise_window(window: &[Option<&Frame>], p: &ClassicParams) -> ClassicResult {
    let aligned = align_window(window, &p.align);
    let centre = aligned.centre();
    let (w, h) = (centre.color.width(), centre.color.height());
    let weights = robust_weights(&aligned);
    let colors: Vec<&Plane> = aligned.frames.iter().map(|f| &f.color).collect();
    let t_color = apply_weights(&weights, &colors);
    let t_alpha = centre.alpha.as_ref().map(|_| {
        let a: Vec<&Plane> = aligned
            .frames
            .iter()
            .map(|f| f.alpha.as_ref().expect("alpha in every slot"))
            .collect();
        apply_weights(&weights, &a)
    });
    let t_aovs: Vec<Plane> = (0..centre.aovs.len())
        .map(|j| {
            let a: Vec<&Plane> = aligned.frames.iter().map(|f| &f.aovs[j]).collect();
            apply_weights(&weights, &a)
        })
        .collect();

    // noise variance of the temporal average: from the window's spread where several frames
    // contribute, else from the centre frame's local spread
    let (mut var, _) = temporal_variance(&weights, &colors, &t_color);
    let spatial = local_variance(&centre.color);
    var.data_mut()
        .par_iter_mut()
        .zip(spatial.data())
        .for_each(|(v, s)| {
            if !v.is_finite() {
                *v = *s;
            }
        });
    let var = box_mean(&var, 1);

    // demodulation by the centre albedo (a per-pixel scale: still one linear operator)
    let scale: Option<Plane> = match (&centre.albedo, p.demodulate) {
        (Some(a), true) => {
            let mut s = box3(a);
            s.data_mut().iter_mut().for_each(|v| *v = v.max(0.0) + 0.02);
            Some(s)
        }
        _ => None,
    };
    let demod = |x: &Plane| match &scale {
        Some(s) => {
            let mut y = x.clone();
            for c in 0..y.channels() {
                let sc = s.channel(c.min(2));
                y.channel_mut(c)
                    .iter_mut()
                    .zip(sc)
                    .for_each(|(v, k)| *v /= k);
            }
            y
        }
        None => x.clone(),
    };
    let d_color = demod(&t_color);
    let d_var = match &scale {
        Some(s) => {
            let mut v = var.clone();
            v.data_mut()
                .iter_mut()
                .zip(s.data())
                .for_each(|(v, k)| *v /= k * k);
            v
        }
        None => var,
    };
    let d_aovs: Vec<Plane> = t_aovs
        .iter()
        .map(|a| {
            if a.channels() == 3 {
                demod(a)
            } else {
                a.clone()
            }
        })
        .collect();

    let albedo_f = centre.albedo.as_ref().map(box3);
    let normal_f = centre.normal.as_ref().map(box3);
    let guide = NlmGuide {
        color: &d_color,
        variance: &d_var,
        albedo: albedo_f.as_ref(),
        normal: normal_f.as_ref(),
        depth: centre.depth.as_ref(),
    };
    let mut signals: Vec<&Plane> = vec![&d_color];
    signals.extend(d_aovs.iter());
    if let Some(a) = &t_alpha {
        signals.push(a);
    }
    let nlm_out = nlm(&guide, &signals, &p.nlm);
    let mut filtered = nlm_out.signals;
    if let (Some(gp), Some(feat)) = (&p.guided, features(albedo_f.as_ref(), normal_f.as_ref())) {
        // alpha keeps only the convex stages (temporal average, NLM), which cannot leave its
        // range; the guided filter is a local regression and may overshoot at edges
        let colour_and_aovs = 1 + d_aovs.len();
        let refs: Vec<&Plane> = filtered[..colour_and_aovs].iter().collect();
        let mut guided = guided_filter(&feat, &refs, gp);
        if let Some(bp) = &p.guided_blend {
            // the noise left after NLM: its input's variance times what NLM divided it by
            let mut left = d_var.clone();
            let n = left.pixels();
            left.data_mut().par_chunks_mut(n).for_each(|ch| {
                ch.iter_mut()
                    .zip(nlm_out.variance_ratio.data())
                    .for_each(|(v, r)| *v *= r)
            });
            let weight = blend_weight(&filtered[0], &guided[0], &left, bp);
            guided = guided
                .iter()
                .zip(&filtered)
                .map(|(g, f)| blend(f, g, &weight))
                .collect();
        }
        filtered.splice(..colour_and_aovs, guided);
    }
    let remod = |mut x: Plane| {
        if let Some(s) = &scale {
            for c in 0..x.channels() {
                let sc = s.channel(c.min(2));
                x.channel_mut(c)
                    .iter_mut()
                    .zip(sc)
                    .for_each(|(v, k)| *v *= k);
            }
        }
        x
    };
    let mut it = filtered.into_iter();
    let color = remod(it.next().expect("colour is the first signal"));
    let aovs: Vec<Plane> = t_aovs
        .iter()
        .map(|a| {
            if a.channels() == 3 {
                remod(it.next().expect("one per AOV"))
            } else {
                it.next().expect("one per AOV")
            }
        })
        .collect();
    let mut alpha = t_alpha.map(|_| it.next().expect("alpha is the last signal"));
    let (mut color, mut aovs) = (color, aovs);
    if let (Some(vb), Some(var)) = (&p.variance_blend, &centre.variance) {
        // the Wiener gain against the renderer's noise, one weight for every signal
        let weight = variance_blend_weight(&centre.color, &color, var, vb);
        color = blend(&centre.color, &color, &weight);
        aovs = aovs
            .iter()
            .zip(&centre.aovs)
            .map(|(a, c)| blend(c, a, &weight))
            .collect();
        if let (Some(a), Some(c)) = (alpha.as_mut(), centre.alpha.as_ref()) {
            *a = blend(c, a, &weight);
        }
    }
    debug_assert!(color.width() == w && color.height() == h);
    ClassicResult {
        color,
        alpha,
        aovs,
        temporal_weights: weights,
    }
}

/// The guided filter's guide: prefiltered albedo and normal stacked.
fn features(albedo: Option<&Plane>, normal: Option<&Plane>) -> Option<Plane> {
    // the guide describes edges; renderers write albedo far above 1 on emitters and some
    // shaders, which makes the guided filter's local regressions ill-conditioned: clamp it
    let clamped = albedo.map(|a| {
        let mut a = a.clone();
        a.data_mut().iter_mut().for_each(|v| {
            *v = if v.is_finite() {
                v.clamp(0.0, 1.0)
            } else {
                0.0
            }
        });
        a
    });
    let albedo = clamped.as_ref();
    match (albedo, normal) {
        (Some(a), Some(n)) => Some(Plane::concat(&[a, n])),
        (Some(a), None) => Some(a.clone()),
        (None, Some(n)) => Some(n.clone()),
        (None, None) => None,
    }
}

/// The classic denoiser as a sequence method: refines each frame's motion once, then denoises
/// windows.
#[derive(Clone, Debug)]
pub struct ClassicDenoiser {
    /// Options.
    pub params: ClassicParams,
    /// Frames on each side of the centre.
    pub radius: usize,
}

impl Default for ClassicDenoiser {
    fn default() -> Self {
        Self {
            params: ClassicParams::default(),
            radius: 2,
        }
    }
}

impl crate::run::denoiser::WindowDenoiser for ClassicDenoiser {
    fn radius(&self) -> usize {
        self.radius
    }

    fn prepares_frames(&self) -> bool {
        self.params.flow_refine.is_some()
    }

    fn prepare_needs_neighbours(&self) -> bool {
        self.params.flow_refine.is_some()
    }

    fn prepare(&self, frame: &mut Frame, prev: Option<&Frame>, next: Option<&Frame>) {
        if let Some(rp) = &self.params.flow_refine {
            refine_frame_motion(frame, prev, next, rp, self.params.align.invert_iterations);
        }
    }

    fn denoise(&self, window: &[Option<&Frame>]) -> crate::Result<crate::run::denoiser::Denoised> {
        let r = denoise_window(window, &self.params);
        Ok(crate::run::denoiser::Denoised {
            color: r.color,
            alpha: r.alpha,
            aovs: r.aovs,
        })
    }
}
