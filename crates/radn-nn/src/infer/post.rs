//! A window's result: the kernels' result, then the chain of stages after the network, in
//! order, each in its own module and each over the same stacking of signals ([`Signals`]):
//!
//! 1. the input blend ([`input_blend`]): back towards the input where the change is more than
//!    the noise explains;
//! 2. the guide mix ([`guide_mix`], guided models): towards the window's aligned guides.
//!
//! The temporal pass over the results ([`radn_core::post::stabilize`]) follows at the
//! sequence level, once every frame's result exists. Which stages run, and how, is the
//! model's recipe for the frame's noise level ([`PostChain`]).

use std::ops::Range;

use radn_core::align::AlignedWindow;
use radn_core::run::denoiser::Denoised;
use radn_core::Plane;

use crate::infer::input::{FeatureScales, Region};
use crate::infer::signals::Signals;
use crate::infer::stems::WindowStems;
use crate::model::demod::{filter, Demodulation};
use crate::model::guide_blend::GuideBlend;
use crate::profile::{timed, Stage};

use super::{guide_mix, input_blend, NetworkDenoiser};

/// The stages after the kernels for one frame, as its model's recipe sets them at the frame's
/// noise level.
#[derive(Clone, Debug)]
pub struct PostChain {
    /// The input blend; `None` where the frame keeps the kernels' result.
    pub input_blend: Option<input_blend::BlendStage>,
    /// The guide mix; `None` for a model that reads no guide.
    pub guide_mix: Option<guide_mix::MixStage>,
}

impl PostChain {
    /// Rows beyond a result's own that the chain reads from the kernels' result.
    pub fn margin(&self) -> usize {
        self.input_blend.map_or(0, |p| p.radius())
    }

    /// The chain's result over rows `rows` of `win`, from the kernels' result `kernels` over
    /// rows `read` (`rows` and the chain's margin, clipped to the frame).
    pub fn run(
        &self,
        win: &AlignedWindow,
        signals: &Signals,
        kernels: Plane,
        read: Range<usize>,
        rows: Range<usize>,
    ) -> Plane {
        let inside = rows.start - read.start..rows.end - read.start;
        let whole = inside == (0..kernels.height());
        let mut out = match &self.input_blend {
            Some(p) => timed(Stage::InputBlend, || {
                input_blend::apply(win, &kernels, read, p).rows(inside)
            }),
            None if whole => kernels,
            None => kernels.rows(inside),
        };
        if let Some(mix) = &self.guide_mix {
            timed(Stage::GuideMix, || mix.apply(win, signals, &mut out, rows));
        }
        out
    }
}

impl NetworkDenoiser {
    /// The stages after the kernels for a frame of noise level `level` (`renderer_variance`:
    /// whether the frame carries the renderer's per-pixel variance, which a model with an
    /// input blend then blends against on every frame).
    pub fn post_chain(&self, level: Option<f32>, renderer_variance: bool) -> PostChain {
        let mix = &self.recipe.guide_mix;
        PostChain {
            input_blend: self
                .recipe
                .input_blend
                .and_then(|b| b.stage(level, &self.recipe.schedule, renderer_variance)),
            guide_mix: self
                .denoiser
                .config
                .inputs
                .guide
                .then(|| guide_mix::MixStage {
                    weight: mix.weight,
                    outliers: mix.outliers,
                    window: self.guide_mix_range_for(level),
                }),
        }
    }

    /// Denoises rows `rows` of an aligned window (a band of a frame whose whole-frame feature
    /// scales are `scales`): the kernels, then the [`PostChain`]. Rows beyond the window's own
    /// are never read, so a band must carry the receptive field's rows around `rows` unless
    /// they are the frame's edge.
    pub fn denoise_rows(
        &self,
        win: &AlignedWindow,
        stems: Option<&WindowStems>,
        scales: FeatureScales,
        rows: Range<usize>,
    ) -> Denoised {
        let chain = self.post_chain(scales.noise_level, win.centre().variance.is_some());
        let h = win.centre().color.height();
        let m = chain.margin();
        let read = rows.start.saturating_sub(m)..(rows.end + m).min(h);
        let signals = Signals::of(win);
        let kernels = self.filtered_rows(win, stems, scales, read.clone());
        signals.split(&chain.run(win, &signals, kernels, read, rows))
    }

    /// The kernels' result for rows `rows` of an aligned window, every signal stacked along
    /// channels: colour, then each AOV, then alpha.
    fn filtered_rows(
        &self,
        win: &AlignedWindow,
        stems: Option<&WindowStems>,
        scales: FeatureScales,
        rows: Range<usize>,
    ) -> Plane {
        let t = win.frames.len();
        // every signal stacked along channels: colour, AOVs, alpha
        let signals = Signals::of(win);
        let chans = signals.channels();
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
        let rgb = signals.rgb_groups();
        let eps = self.denoiser.config.demodulate;
        let inputs = &self.denoiser.config.inputs;
        self.run_tiled(
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
                filter(p, v, demod.as_ref())
            },
        )
    }
}
