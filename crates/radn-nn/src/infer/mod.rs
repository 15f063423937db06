//! Denoising with a network: windows aligned by radn-core, kernels predicted tile by tile with a
//! halo of the network's receptive field (so the result does not depend on the tile size and
//! the network's memory does not grow with the frame), applied to colour, AOVs and alpha.
//! The network's inputs are built in [`input`]; temporal utilisation (paper Table 1) is
//! measured in [`utilization`].

pub mod guide_mix;
pub mod input;
pub mod input_blend;
pub mod stems;
pub mod utilization;

use burn::tensor::{Device, Tensor, TensorData};
use std::ops::Range;

use radn_core::align::{align_bands, align_window, AlignParams, AlignedWindow};
use radn_core::banding::{FrameBand, FrameStats, ALIGNMENT_EDGE_ROWS};
use radn_core::classic::wiener::{
    blend, blend_weight, window_noise_variance, LOCAL_VARIANCE_RADIUS,
};
use radn_core::denoiser::{BandDenoiser, BandFeatures, Denoised, WindowDenoiser};
use radn_core::frame::Frame;
use radn_core::Plane;

use crate::infer::input::{network_input, FeatureScales, Region};
use crate::infer::input_blend::InputBlend;
use crate::infer::stems::WindowStems;
use crate::model::demod::{filter, Demodulation};
use crate::model::guide_blend::GuideBlend;
use crate::model::{Denoiser, GuideWeights};
use crate::profile::{self, timed, Stage};

/// A trained network as a sequence method.
pub struct NetworkDenoiser {
    /// The network.
    pub denoiser: Denoiser,
    /// Kernel threshold t (paper eq. 3).
    pub threshold: f32,
    /// Output tile side in pixels (0: the whole frame at once).
    pub tile: usize,
    /// Tiles of equal size per network call (1: one at a time, the fastest on a CPU; larger
    /// batches can pay where a call has fixed overhead, e.g. on a GPU).
    pub batch: usize,
    /// Where the network runs.
    pub device: Device,
    /// Alignment options.
    pub align: AlignParams,
    /// The colour term of alignment's confidence at the cleanest frames
    /// ([`radn_core::confidence::ConfidenceParams::color`]), loosened with the centre frame's
    /// noise level by the input blend's noise scale ([`NetworkDenoiser::align_params_for`]) and
    /// left out for frames the input blend leaves alone. `None`: `align`'s own setting.
    pub color_confidence: Option<f32>,
    /// The most the confidence terms that compare sampled buffers (albedo, normal and depth) are
    /// loosened, by the centre frame's noise level ([`sampled_terms_loosening`]):
    /// a noisy frame's buffers differ from frame to frame where one pixel covers several
    /// surfaces (fur, grass, foliage), and at the strict tolerances its side frames count for
    /// little there, which leaves the window's average to flicker. `None`: `align`'s own
    /// tolerances at every level.
    pub loosen_sampled_terms: Option<f32>,
    /// The input blend ([`input_blend`]): per pixel, the network's result is blended with the
    /// input by the classic denoiser's Wiener gain, so that it keeps only the change the
    /// input's noise explains and does not average a clean input's detail away. The weight is
    /// computed from the beauty and applied to every signal (still one linear operator per
    /// signal; alpha stays in range). `None`: the kernels' result as it is.
    pub refine: Option<InputBlend>,
    /// For a network with a frame-local stem: run the stem once per frame as rendered and warp
    /// its features into each window (true, the default), or run it in every window on the
    /// aligned frames as training does (false: five times the stem's work, for measuring what
    /// warping features instead of inputs changes). Ignored by other networks.
    pub warp_stem_features: bool,
    /// For a guided network, the guide mix ([`guide_mix`]): the weight in [0, 1] of the
    /// centre frame's own guide in the result, after the input blend (0: the network's result
    /// as it is). Ignored by networks without a guide.
    pub guide_mix: f32,
    /// Which guide the guide mix uses: the centre frame's, the window's aligned guides
    /// averaged, or by the frame's noise level ([`guide_mix::MixGuide`]).
    pub guide_mix_from: guide_mix::MixGuide,
    /// For the window's guide in the guide mix: the range term's σ ([`guide_mix::window_guide`]),
    /// which keeps each side frame's guide out where it differs from the centre's by more than
    /// a spatial denoiser's frame-to-frame error. `None`: confidence alone.
    pub guide_mix_range: Option<f32>,
    /// Where the guide mix takes the guide alone, pixel by pixel: outliers of the result
    /// against the guide ([`guide_mix::OutlierRamp`]). `None`: the mix's weight everywhere.
    pub guide_mix_outliers: Option<guide_mix::OutlierRamp>,
    /// For a network with a learned guide mix ([`crate::model::config::NetConfig::guide_mix_head`]):
    /// mix by the weight it predicts per pixel (true, the default for such a network) instead of
    /// [`NetworkDenoiser::guide_mix`]. Ignored by other networks.
    pub guide_mix_learned: bool,
}

/// How many times [`NetworkDenoiser::align_params_for`] loosens the confidence terms that compare
/// sampled buffers ([`radn_core::confidence::ConfidenceParams::loosened`]) for a centre frame of
/// noise level `level`: the input blend's noise scale over its smallest, as for the colour term
/// (1 at the cleanest frames, 2 at twice the lowest level's noise), at most `most`, and `most`
/// for frames noisier than the input blend's range or without a level.
pub fn sampled_terms_loosening(level: Option<f32>, most: f32) -> f32 {
    input_blend::loosening_for_level(level)
        .unwrap_or(most)
        .clamp(1.0, most.max(1.0))
}

/// `base` with the confidence terms that compare sampled buffers loosened for a centre frame of
/// noise level `level` by [`sampled_terms_loosening`] up to `most` (`None`: `base` as it is).
/// One rule for inference ([`NetworkDenoiser::align_params_for`]) and for the tiles a network
/// trains on ([`crate::train::dataset::PrepareOptions::loosen_sampled_terms`]), so a network
/// sees its training's windows at inference.
pub fn align_params_loosened(
    base: AlignParams,
    most: Option<f32>,
    level: Option<f32>,
) -> AlignParams {
    let mut p = base;
    if let Some(most) = most {
        p.confidence = p.confidence.loosened(sampled_terms_loosening(level, most));
    }
    p
}

/// The `most` of [`sampled_terms_loosening`] that `radn denoise` uses for runs with a guide:
/// chosen among 1 (off), 2, 3, 4 and 8 on five validation sets (docs/guided.md, "Confidence
/// on fur: the sampled buffers' terms loosen with the noise level").
pub const DEFAULT_SAMPLED_TERMS_LOOSENING: f32 = 4.0;

/// Smallest tile [`auto_tile`] picks (the tile every model ran with before it existed).
const MIN_AUTO_TILE: usize = 256;
/// Largest tile [`auto_tile`] picks.
const MAX_AUTO_TILE: usize = 1024;
/// Bytes the widest per-tile map (features of every frame, or the kernel weights) may take
/// for [`auto_tile`] to double the tile: a few such maps are alive at once.
const AUTO_TILE_MAP_BYTES: usize = 128 << 20;

/// The output tile for `denoiser` when the user does not choose one: the largest of 256, 512
/// and 1024 pixels whose widest map (all frames' head features, or the kernel weights, over the
/// tile and its halo) stays within 128 MiB, and 256 at least. A tile computes its halo again,
/// so larger tiles do less work: measured on guided-lean at 1080p, 512-pixel tiles took 19.6 s
/// per window against 24.8 s with 256 (docs/benchmarks.md), where the default model's widest
/// map at 512 would be several hundred MB.
pub fn auto_tile(denoiser: &Denoiser) -> usize {
    let Some(halo) = denoiser.receptive_radius() else {
        return MIN_AUTO_TILE; // a UNet runs whole frames whatever the tile
    };
    let per_pixel = (denoiser.config.frames * denoiser.feature_channels())
        .max(denoiser.config.kernel_taps())
        * std::mem::size_of::<f32>();
    let mut tile = MIN_AUTO_TILE;
    while tile * 2 <= MAX_AUTO_TILE {
        let side = tile * 2 + 2 * halo;
        if side * side * per_pixel > AUTO_TILE_MAP_BYTES {
            break;
        }
        tile *= 2;
    }
    tile
}

impl NetworkDenoiser {
    /// The alignment options for a window whose centre frame has noise level `level`: with
    /// [`NetworkDenoiser::color_confidence`] set, the colour term's tolerance is that base times
    /// the input blend's noise scale over its smallest (1 at the cleanest frames, up to 4), and
    /// off for frames noisier than that, whose colour is too noisy to compare. With
    /// [`NetworkDenoiser::loosen_sampled_terms`] set, the terms that compare sampled buffers are
    /// loosened by [`sampled_terms_loosening`].
    pub fn align_params_for(&self, level: Option<f32>) -> AlignParams {
        let mut p = align_params_loosened(self.align, self.loosen_sampled_terms, level);
        if let Some(base) = self.color_confidence {
            p.confidence.color = input_blend::loosening_for_level(level).map(|k| base * k);
        }
        p
    }

    /// Whether the guide mix of a frame of noise level `level` uses the window's guide, and if
    /// so with which range term ([`guide_mix::window_guide`]): `None` for the centre's guide,
    /// `Some(None)` for the window's by confidence alone, `Some(Some(σ))` with the range term.
    /// Like the colour confidence, the range σ of [`NetworkDenoiser::guide_mix_range`] holds
    /// for the cleanest frames and loosens with the input blend's noise scale; frames the input
    /// blend leaves alone (their guides differ by more than any tight range) get the window's
    /// guide without it. With a range, [`guide_mix::MixGuide::FollowLevel`] takes the window's
    /// guide at every level: the range keeps the centre's detail that made clean frames use
    /// the centre's guide before.
    pub fn guide_mix_range_for(&self, level: Option<f32>) -> Option<Option<f32>> {
        let loosening = input_blend::loosening_for_level(level);
        let range = self
            .guide_mix_range
            .and_then(|sigma| loosening.map(|k| sigma * k));
        let window = self.guide_mix_from.uses_window(level)
            || (self.guide_mix_range.is_some()
                && self.guide_mix_from == guide_mix::MixGuide::FollowLevel);
        window.then_some(range)
    }

    /// The window of frames `window` aligned for its centre frame's scales, and those scales
    /// (computed once, before aligning, from the frame as rendered).
    fn align_for_centre(&self, window: &[Option<&Frame>]) -> (AlignedWindow, FeatureScales) {
        let c = window[window.len() / 2].expect("the centre frame of a window must exist");
        let scales = FeatureScales::of_centre(&c.color, c.albedo.as_ref(), c.depth.as_ref());
        let params = self.align_params_for(scales.noise_level);
        (align_window(window, &params), scales)
    }

    /// A denoiser with the model's default threshold and its [`auto_tile`].
    pub fn new(denoiser: Denoiser, device: Device) -> Self {
        let threshold = denoiser.config.default_threshold();
        let tile = auto_tile(&denoiser);
        let resampling = denoiser.config.resampling;
        Self {
            denoiser,
            threshold,
            tile,
            batch: 1,
            device,
            align: AlignParams {
                resampling,
                ..AlignParams::default()
            },
            color_confidence: None,
            refine: None,
            warp_stem_features: true,
            guide_mix: 0.0,
            guide_mix_from: guide_mix::MixGuide::FollowLevel,
            guide_mix_range: None,
            guide_mix_outliers: None,
            guide_mix_learned: true,
            loosen_sampled_terms: None,
        }
    }

    /// Denoises an aligned window: colour, then every AOV and alpha with the same kernels. A
    /// network with a frame-local stem runs it here on the aligned frames, as in training;
    /// [`WindowDenoiser::denoise`] runs it on the frames as rendered and warps its features.
    pub fn denoise_aligned(&self, win: &AlignedWindow) -> Denoised {
        self.denoise_aligned_with(win, None)
    }

    /// [`NetworkDenoiser::denoise_aligned`] with every window frame's stem features warped onto
    /// the centre frame (`stems`) for a network with a frame-local stem.
    pub fn denoise_aligned_with(
        &self,
        win: &AlignedWindow,
        stems: Option<&WindowStems>,
    ) -> Denoised {
        let h = win.centre().color.height();
        self.denoise_rows(win, stems, FeatureScales::of(win), 0..h)
    }

    /// The stem features of a frame-local network ([`crate::model::config::NetConfig::frame_local_stem`])
    /// for a whole frame as rendered, normalised by the frame's own exposure and depth: computed
    /// tile by tile with the stem's halo, so only one tile's maps exist at a time besides the
    /// result.
    pub fn frame_stem(&self, frame: &Frame) -> Plane {
        let scales =
            FeatureScales::of_centre(&frame.color, frame.albedo.as_ref(), frame.depth.as_ref());
        self.frame_stem_rows(frame, scales, 0..frame.height())
    }

    /// [`NetworkDenoiser::frame_stem`] of rows `out` of `frame` (a whole frame, or a band of
    /// one holding the stem's halo of rows beyond `out` where the frame has them) whose
    /// whole-frame scales are `scales`: the same tiles' regions as on the whole frame, so the
    /// same values.
    fn frame_stem_rows(&self, frame: &Frame, scales: FeatureScales, out: Range<usize>) -> Plane {
        let (w, h) = (frame.width(), frame.height());
        let alone = AlignedWindow {
            frames: vec![radn_core::align::AlignedFrame {
                offset: 0,
                color: frame.color.clone(),
                alpha: None,
                albedo: frame.albedo.clone(),
                normal: frame.normal.clone(),
                depth: frame.depth.clone(),
                aovs: Vec::new(),
                guide: frame.guide.clone(),
                confidence: Plane::filled(w, h, 1, 1.0),
                flow: Plane::zeros(w, h, 2),
            }],
        };
        let halo = self.denoiser.stem_radius();
        let side = if self.tile == 0 { w.max(h) } else { self.tile };
        let c = self.denoiser.stem_channels();
        let mut result = Plane::zeros(w, out.len(), c);
        for y0 in out.clone().step_by(side) {
            for x0 in (0..w).step_by(side) {
                let (x1, y1) = ((x0 + side).min(w), (y0 + side).min(out.end));
                let r = Region {
                    x0: x0.saturating_sub(halo),
                    y0: y0.saturating_sub(halo),
                    x1: (x1 + halo).min(w),
                    y1: (y1 + halo).min(h),
                };
                let (rw, rh) = r.size();
                let input = timed(Stage::Inputs, || {
                    network_input(&alone, scales, r, &self.denoiser.config.inputs)
                });
                let x = Tensor::<4>::from_data(
                    TensorData::new(input, [1, self.denoiser.config.input_channels(), rh, rw]),
                    &self.device,
                );
                let stem = self.denoiser.stem(x).to_data();
                let stem = stem.as_slice::<f32>().expect("f32 features");
                for ch in 0..c {
                    for y in y0..y1 {
                        let src = &stem[ch * rw * rh + (y - r.y0) * rw + (x0 - r.x0)..][..x1 - x0];
                        let at = (y - out.start) * w;
                        result.channel_mut(ch)[at + x0..at + x1].copy_from_slice(src);
                    }
                }
            }
        }
        result
    }

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
        let blend_params = self.refine.and_then(|b| b.params(scales.noise_level));
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
        let mixes = self.guide_mix > 0.0 || self.guide_mix_outliers.is_some() || learned.is_some();
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
                    None => guide_mix::MixWeight::Uniform(self.guide_mix),
                };
                guide_mix::mix_with_guide(
                    &mut out,
                    &g,
                    weight,
                    self.guide_mix_outliers,
                    &rgb_groups,
                )
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
    /// over those rows where the network has one and [`NetworkDenoiser::guide_mix_learned`]
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
        let learned = self.guide_mix_learned && self.denoiser.config.guide_mix_head;
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

impl NetworkDenoiser {
    /// Per-pixel kernel weight of each window frame (temporal utilisation, paper Table 1 and
    /// Fig. 6): `frames` planes summing to 1 at every pixel. A network with a frame-local stem
    /// runs it on the aligned frames here, as in training; [`NetworkDenoiser::window_utilization`]
    /// measures what `denoise` computes.
    pub fn utilization(&self, win: &AlignedWindow) -> Vec<Plane> {
        self.utilization_with(win, None, FeatureScales::of(win))
    }

    /// [`NetworkDenoiser::utilization`] of the window of frames `window` (`None` beyond the
    /// sequence ends), aligned here, with the stem features warped as
    /// [`WindowDenoiser::denoise`] warps them.
    pub fn window_utilization(&self, window: &[Option<&Frame>]) -> Vec<Plane> {
        let (win, scales) = self.align_for_centre(window);
        let stems = self
            .reuses_frame_layers()
            .then(|| WindowStems::new(window, &win, self.align.resampling, |f| self.frame_stem(f)));
        self.utilization_with(&win, stems.as_ref(), scales)
    }

    fn utilization_with(
        &self,
        win: &AlignedWindow,
        stems: Option<&WindowStems>,
        scales: FeatureScales,
    ) -> Vec<Plane> {
        let t = win.frames.len();
        let zeros = |r: Region| vec![0.0f32; t * r.pixels()];
        let h = win.centre().color.height();
        let mass = self.run_tiled(win, stems, scales, 0..h, zeros, 1, |p, _, _, _| {
            p.frame_mass(t)
        });
        (0..t).map(|k| mass.select_channels(k, 1)).collect()
    }

    /// Runs the network tile by tile over rows `rows` (each tile with a halo of the receptive
    /// field, clamped to the window, so the result does not depend on the tiling) and assembles
    /// the planes of `f(prediction, guide weights, values, features)`, `values` being `[B, T, chans, h, w]`
    /// from `values(region)` and `features` the network input of the regions. Consecutive tiles
    /// whose regions have the same size share one network call, up to `batch` of them. Features
    /// and values exist for one call's tiles at a time, never for the whole frame.
    #[allow(clippy::too_many_arguments)]
    fn run_tiled(
        &self,
        win: &AlignedWindow,
        stems: Option<&WindowStems>,
        scales: FeatureScales,
        rows: Range<usize>,
        values: impl Fn(Region) -> Vec<f32>,
        chans: usize,
        f: impl Fn(&crate::model::Prediction, GuideWeights, Tensor<5>, &Tensor<5>) -> Tensor<4>,
    ) -> Plane {
        let w = win.centre().color.width();
        let tiles = self.tiles(win, rows.clone(), stems.is_some());
        let mut out: Option<Plane> = None;
        for call in batches(&tiles, self.batch) {
            let group = &tiles[call];
            self.run_group(
                win, stems, scales, group, &values, chans, &f, &mut out, w, &rows,
            );
        }
        out.expect("at least one tile")
    }

    /// The tiles covering rows `rows` of the window, row of tiles by row of tiles, each with its
    /// output rectangle and the region (output plus halo, clamped to the window) it reads; with
    /// `stem_given` (a frame-local stem's features computed on whole frames) the halo leaves out
    /// the stem's reach.
    fn tiles(&self, win: &AlignedWindow, rows: Range<usize>, stem_given: bool) -> Vec<Tile> {
        let c = win.centre();
        let (w, h) = (c.color.width(), c.color.height());
        // with a frame-local stem's features given, the stem's reach is already computed
        let halo = if stem_given {
            self.denoiser.receptive_radius_after_stem()
        } else {
            self.denoiser.receptive_radius()
        };
        // multi-scale kernels: regions on the coarsest scale's grid
        let g = self.denoiser.tile_grid();
        let (tw, th) = match (halo, self.tile) {
            (Some(_), tile) if tile > 0 => {
                let tile = (tile / g * g).max(g);
                (tile.min(w), tile.min(h))
            }
            _ => (w, h), // whole frame: UNets, or tiling switched off
        };
        let halo = halo.unwrap_or(0);
        let mut tiles = Vec::new();
        for y0 in rows.clone().step_by(th) {
            let y1 = (y0 + th).min(rows.end);
            for x0 in (0..w).step_by(tw) {
                let x1 = (x0 + tw).min(w);
                // rows that start or end off the grid (a band's, or the input blend's wider
                // rows) read from the grid row before and to the one after: the same region a
                // whole frame's tile reads there (the halo is a multiple of the grid)
                tiles.push(Tile {
                    x: x0..x1,
                    y: y0..y1,
                    region: Region {
                        x0: x0.saturating_sub(halo),
                        y0: (y0 / g * g).saturating_sub(halo),
                        x1: (x1 + halo).min(w),
                        y1: (y1.div_ceil(g) * g + halo).min(h),
                    },
                });
            }
        }
        tiles
    }

    /// One network call on tiles whose regions have the same size; their output rectangles
    /// are written into `out` (rows relative to `rows.start`, created on first use).
    #[allow(clippy::too_many_arguments)]
    fn run_group(
        &self,
        win: &AlignedWindow,
        stems: Option<&WindowStems>,
        scales: FeatureScales,
        group: &[Tile],
        values: &impl Fn(Region) -> Vec<f32>,
        chans: usize,
        f: &impl Fn(&crate::model::Prediction, GuideWeights, Tensor<5>, &Tensor<5>) -> Tensor<4>,
        out: &mut Option<Plane>,
        w: usize,
        rows: &Range<usize>,
    ) {
        let t = win.frames.len();
        let b = group.len();
        let (rw, rh) = group[0].region.size();
        let (feats, vals, stem) = timed(Stage::Inputs, || {
            let mut feats = Vec::new();
            let mut vals = Vec::new();
            let mut stem = Vec::new();
            for tile in group {
                if let Some(stems) = stems {
                    // the region's rows of every frame's warped features
                    let r = tile.region;
                    let band = timed(Stage::Align, || stems.rows(r.y0..r.y1));
                    let local = Region {
                        y0: 0,
                        y1: r.y1 - r.y0,
                        ..r
                    };
                    for plane in band.iter() {
                        local.crop(plane, &mut stem);
                    }
                }
                feats.extend(network_input(
                    win,
                    scales,
                    tile.region,
                    &self.denoiser.config.inputs,
                ));
                vals.extend(values(tile.region));
            }
            (feats, vals, stem)
        });
        let x = Tensor::<5>::from_data(
            TensorData::new(feats, [b, t, self.denoiser.config.input_channels(), rh, rw]),
            &self.device,
        );
        let v = Tensor::<5>::from_data(TensorData::new(vals, [b, t, chans, rh, rw]), &self.device);
        let (prediction, guides) = match stems {
            Some(_) => {
                let c = self.denoiser.stem_channels();
                let stem =
                    Tensor::<5>::from_data(TensorData::new(stem, [b, t, c, rh, rw]), &self.device);
                self.denoiser
                    .predict_with_stem(x.clone(), stem, self.threshold)
            }
            None => self.denoiser.predict_guided(x.clone(), self.threshold),
        };
        let res = timed(Stage::Kernels, || f(&prediction, guides, v, &x));
        let oc = res.dims()[1];
        let res = res.to_data().try_to_vec::<f32>().expect("f32 output");
        let out = out.get_or_insert_with(|| Plane::zeros(w, rows.len(), oc));
        for (i, tile) in group.iter().enumerate() {
            let r = tile.region;
            let res = &res[i * oc * rw * rh..][..oc * rw * rh];
            for ch in 0..oc {
                for y in tile.y.clone() {
                    let src = &res[ch * rw * rh + (y - r.y0) * rw + (tile.x.start - r.x0)..]
                        [..tile.x.len()];
                    let at = (y - rows.start) * w;
                    out.channel_mut(ch)[at + tile.x.start..at + tile.x.end].copy_from_slice(src);
                }
            }
        }
    }
}

/// Splits `tiles` into runs of consecutive tiles whose regions have the same size, at most
/// `batch` long: the tiles that can share one network call.
fn batches(tiles: &[Tile], batch: usize) -> Vec<Range<usize>> {
    let mut out: Vec<Range<usize>> = Vec::new();
    for (i, tile) in tiles.iter().enumerate() {
        match out.last_mut() {
            Some(r)
                if r.len() < batch.max(1) && tiles[r.start].region.size() == tile.region.size() =>
            {
                r.end = i + 1
            }
            _ => out.push(i..i + 1),
        }
    }
    out
}

/// One tile of a tiled run: the output rectangle it produces and the region it reads.
struct Tile {
    x: Range<usize>,
    y: Range<usize>,
    region: Region,
}

impl NetworkDenoiser {
    /// Whether the network's per-frame layers run once per frame as rendered and their
    /// features are warped into each window ([`crate::model::config::NetConfig::frame_local_stem`]).
    pub fn reuses_frame_layers(&self) -> bool {
        self.denoiser.config.frame_local_stem && self.warp_stem_features
    }

    /// A guided network needs every frame's guide: an error naming the first frame without
    /// one. A network that reads no guide ignores guides.
    fn check_guides<'f>(&self, frames: impl Iterator<Item = &'f Frame>) -> radn_core::Result<()> {
        if !self.denoiser.config.inputs.guide {
            return Ok(());
        }
        match frames.into_iter().find(|f| f.guide.is_none()) {
            Some(f) => Err(radn_core::Error::Guide {
                path: f.path.clone(),
                detail: "the model reads a guide and this frame has none (give one with \
                         --guide oidn, --guide denoised or --guide LAYER)"
                    .into(),
            }),
            None => Ok(()),
        }
    }
}

impl WindowDenoiser for NetworkDenoiser {
    fn radius(&self) -> usize {
        self.denoiser.config.frames / 2
    }

    fn frame_features(&self, frame: &Frame) -> Option<Plane> {
        self.reuses_frame_layers().then(|| self.frame_stem(frame))
    }

    fn has_frame_features(&self) -> bool {
        self.reuses_frame_layers()
    }

    fn denoise(&self, window: &[Option<&Frame>]) -> radn_core::Result<Denoised> {
        self.check_guides(window.iter().flatten().copied())?;
        let (win, scales) = timed(Stage::Align, || self.align_for_centre(window));
        let stems = self
            .reuses_frame_layers()
            .then(|| WindowStems::new(window, &win, self.align.resampling, |f| self.frame_stem(f)));
        let h = win.centre().color.height();
        let out = self.denoise_rows(&win, stems.as_ref(), scales, 0..h);
        log_stages(
            window
                .get(window.len() / 2)
                .copied()
                .flatten()
                .map(|f| f.path.as_path()),
        );
        Ok(out)
    }

    fn banded(&self) -> Option<&dyn BandDenoiser> {
        // tiles of a receptive field's halo make bands possible; UNets and `--tile 0` need
        // whole frames (multi-scale kernels are banded on their grid: `band_rows`, `halo`)
        (self.tile > 0 && self.denoiser.receptive_radius().is_some()).then_some(self as _)
    }
}

impl BandDenoiser for NetworkDenoiser {
    fn band_rows(&self) -> usize {
        // whole tiles of the coarsest kernel scale's grid, so every band starts on it
        let g = self.denoiser.tile_grid();
        (self.tile / g * g).max(g)
    }

    fn halo(&self) -> usize {
        // the network's receptive field (after the stem, where each frame's stem features are
        // computed once and given), and the rows banded alignment gets wrong at a cut; the
        // refine blend reads the result `p.radius` rows further, and the window's noise
        // `LOCAL_VARIANCE_RADIUS` beyond those. With multi-scale kernels the tiles' regions
        // start and end on the coarsest grid (`tiles`), and the halo is a multiple of it, so
        // a band (its first row `band_rows` · i − halo) starts on the frame's grid too.
        let g = self.denoiser.tile_grid();
        let network = if self.reuses_frame_layers() {
            self.denoiser.receptive_radius_after_stem()
        } else {
            self.denoiser.receptive_radius()
        };
        let refine = self
            .refine
            .map_or(0, |p| p.radius.div_ceil(g) * g + LOCAL_VARIANCE_RADIUS);
        (network.unwrap_or(0) + refine + ALIGNMENT_EDGE_ROWS).div_ceil(g) * g
    }

    fn band_features(&self) -> Option<BandFeatures> {
        self.reuses_frame_layers().then(|| BandFeatures {
            channels: self.denoiser.stem_channels(),
            halo: self.denoiser.stem_radius(),
        })
    }

    fn frame_band_features(
        &self,
        band: FrameBand,
        out: Range<usize>,
        stats: &FrameStats,
    ) -> Option<Plane> {
        self.reuses_frame_layers()
            .then(|| self.frame_stem_rows(band.frame, FeatureScales::of_stats(stats), out))
    }

    fn denoise_band(
        &self,
        window: &[Option<FrameBand>],
        out: Range<usize>,
        centre: &FrameStats,
    ) -> radn_core::Result<Denoised> {
        self.check_guides(window.iter().flatten().map(|b| b.frame))?;
        let params = self.align_params_for(centre.noise_level());
        let win = timed(Stage::Align, || align_bands(window, &params));
        let scales = FeatureScales::of_stats(centre);
        if out.start == 0 {
            if let Some(b) = self.refine {
                tracing::debug!(
                    frame = %centre.names.path.display(),
                    noise_level = ?scales.noise_level,
                    noise_scale = ?b.params(scales.noise_level).map(|p| p.noise_scale),
                    "input blend"
                );
            }
        }
        let stems = self
            .reuses_frame_layers()
            .then(|| WindowStems::of_bands(window, &win, self.align.resampling));
        let band = out.clone();
        let result = self.denoise_rows(&win, stems.as_ref(), scales, out);
        tracing::debug!(
            frame = %centre.names.path.display(),
            rows = ?band,
            "network stages: {}",
            profile::take()
        );
        Ok(result)
    }
}

/// Logs where the time of the frame just denoised went (`radn denoise -v`), and clears the
/// tally for the next frame.
fn log_stages(frame: Option<&std::path::Path>) {
    let times = profile::take();
    match frame {
        Some(p) => tracing::debug!(frame = %p.display(), "network stages: {times}"),
        None => tracing::debug!("network stages: {times}"),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::infer::input_blend::BlendStrength;
    use crate::model::config::NetConfig;
    use radn_core::align::AlignedFrame;

    fn window(w: usize, h: usize) -> AlignedWindow {
        let plane = |c: usize, k: usize| {
            Plane::from_fn(w, h, c, |x, y, ch| {
                (((x * 7 + y * 13 + ch * 3 + k * 11) % 23) as f32) / 23.0
            })
        };
        AlignedWindow {
            frames: (0..5)
                .map(|k| AlignedFrame {
                    offset: k as i32 - 2,
                    color: plane(3, k),
                    alpha: Some(plane(1, k + 1)),
                    albedo: Some(plane(3, k + 2)),
                    normal: Some(plane(3, k + 3)),
                    depth: Some(Plane::filled(w, h, 1, 3.0)),
                    aovs: vec![plane(3, k + 4)],
                    guide: None,
                    confidence: Plane::filled(w, h, 1, 0.9),
                    flow: Plane::zeros(w, h, 2),
                })
                .collect(),
        }
    }

    /// The largest difference between two results over colour, the first AOV and alpha.
    fn worst_difference(whole: &Denoised, tiled: &Denoised) -> f32 {
        [
            (&whole.color, &tiled.color),
            (&whole.aovs[0], &tiled.aovs[0]),
            (whole.alpha.as_ref().unwrap(), tiled.alpha.as_ref().unwrap()),
        ]
        .iter()
        .flat_map(|(a, b)| a.data().iter().zip(b.data()).map(|(x, y)| (x - y).abs()))
        .fold(0.0f32, f32::max)
    }

    /// The shipped default model (trained: its kernels depend strongly on the features).
    fn shipped(device: &Device) -> Denoiser {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../models/default.safetensors");
        crate::model::store::load(&path, device).unwrap()
    }

    /// `n` frames of a noisy textured surface moving by a sub-pixel step per frame, with albedo,
    /// normal, depth and motion both ways, named `frame0`, `frame1`, …
    fn moving_frames(w: usize, h: usize, n: usize) -> Vec<Frame> {
        let (vx, vy) = (0.6f32, -0.35f32);
        let texture = |u: f32, v: f32, c: usize| {
            0.5 + 0.4 * (u * 0.7 + c as f32).sin() * (v * 0.45 + 0.3 * c as f32).cos()
        };
        (0..n)
            .map(|t| {
                let at = |x: usize, y: usize| (x as f32 - vx * t as f32, y as f32 - vy * t as f32);
                let grain = |x: usize, y: usize, c: usize| {
                    let k = (x * 73 + y * 151 + c * 29 + t * 977) as u32;
                    let k = k.wrapping_mul(2_654_435_761) >> 16;
                    (k % 1000) as f32 / 1000.0 - 0.5
                };
                let mut f = Frame::synthetic(Plane::from_fn(w, h, 3, |x, y, c| {
                    let (u, v) = at(x, y);
                    texture(u, v, c) * (1.0 + 0.8 * grain(x, y, c))
                }));
                f.albedo = Some(Plane::from_fn(w, h, 3, |x, y, c| {
                    let (u, v) = at(x, y);
                    texture(u, v, c)
                }));
                f.normal = Some(Plane::from_fn(w, h, 3, |_, _, c| f32::from(c == 2)));
                f.depth = Some(Plane::filled(w, h, 1, 4.0));
                // content moves by +v per frame: a point was at p − v one frame earlier
                f.motion_prev = Some(Plane::from_fn(
                    w,
                    h,
                    2,
                    |_, _, c| if c == 0 { -vx } else { -vy },
                ));
                f.motion_next = Some(Plane::from_fn(
                    w,
                    h,
                    2,
                    |_, _, c| if c == 0 { vx } else { vy },
                ));
                f.path = format!("frame{t}").into();
                f
            })
            .collect()
    }

    #[test]
    fn frame_layers_computed_once_equal_recomputing_them_in_every_window() {
        let device = Device::flex();
        let d = shipped(&device).with_frame_local_stem(&device).unwrap();
        let halo = d.receptive_radius().unwrap();
        let frames = moving_frames(2 * halo + 70, 44, 7);
        let mut n = NetworkDenoiser::new(d, device);
        assert!(n.has_frame_features() && n.band_features().is_some());
        // each frame's stem once, in tiles of 16 px (its halo is 7 px)
        n.tile = 16;
        let prepared: Vec<Frame> = frames
            .iter()
            .map(|f| {
                let mut p = f.clone();
                p.features = n.frame_features(f);
                p
            })
            .collect();
        let stem = |k: usize| prepared[k].features.as_ref().expect("prepared").clone();
        assert_eq!(stem(0).channels(), n.denoiser.stem_channels());
        assert_ne!(
            stem(0).data(),
            stem(1).data(),
            "frames differ, so do their features"
        );
        let len = frames.len();
        for pos in 0..len {
            let idx = radn_core::align::window_indices(pos, len, 2);
            fn pick<'a>(idx: &[Option<usize>], set: &'a [Frame]) -> Vec<Option<&'a Frame>> {
                idx.iter().map(|i| i.map(|i| &set[i])).collect()
            }
            // reused: the prepared features, windows in tiles of 32 px; recomputed: every frame's
            // stem again for this window, whole frames at once
            n.tile = 32;
            let reused = n.denoise(&pick(&idx, &prepared)).unwrap();
            n.tile = 0;
            let recomputed = n.denoise(&pick(&idx, &frames)).unwrap();
            let worst = reused
                .color
                .data()
                .iter()
                .zip(recomputed.color.data())
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(
                worst < 1e-5,
                "frame {pos}: reused and recomputed differ by {worst}"
            );
        }
    }

    #[test]
    fn splitting_the_stem_keeps_a_trusted_frames_kernels() {
        let device = Device::flex();
        let whole = shipped(&device);
        let split = whole.clone().with_frame_local_stem(&device).unwrap();
        let halo = whole.receptive_radius().unwrap();
        let (b, t, c, s) = (1, 5, whole.config.input_channels(), 2 * halo + 12);
        // inputs in their usual ranges, confidence 1 and noise estimate 0: what the split folds
        let (conf, count) = whole.config.inputs.window_channels();
        let x = Tensor::<5>::from_data(
            TensorData::new(
                (0..b * t * c * s * s)
                    .map(|i| {
                        let ch = (i / (s * s)) % c;
                        match ch {
                            _ if ch == conf => 1.0,
                            _ if ch > conf && ch < conf + count => 0.0,
                            _ => ((i * 7919 % 1000) as f32 / 1000.0) * 0.8,
                        }
                    })
                    .collect::<Vec<f32>>(),
                [b, t, c, s, s],
            ),
            &device,
        );
        let values = Tensor::<5>::from_data(
            TensorData::new(
                (0..b * t * 3 * s * s)
                    .map(|i| (i * 613 % 997) as f32 / 997.0)
                    .collect::<Vec<f32>>(),
                [b, t, 3, s, s],
            ),
            &device,
        );
        let out = |d: &Denoiser| {
            let p = d.predict(x.clone(), d.config.default_threshold());
            p.apply(values.clone())
                .into_data()
                .try_into_vec::<f32>()
                .unwrap()
        };
        let (a, bb) = (out(&whole), out(&split));
        // pixels farther than the receptive field from the edges (the zero padding at the
        // edges reads no confidence; the folded bias does)
        let mut worst = 0.0f32;
        for ch in 0..3 {
            for y in halo..s - halo {
                for xx in halo..s - halo {
                    let i = (ch * s + y) * s + xx;
                    worst = worst.max((a[i] - bb[i]).abs());
                }
            }
        }
        assert!(
            worst < 1e-4,
            "split and whole stems differ by {worst} inside"
        );
        // and the window's channels still reach the kernels through the new 1×1 layer's place
        assert!(split.config.frame_local_stem && split.stem_channels() > 0);
    }

    #[test]
    fn the_automatic_tile_doubles_only_for_narrow_networks() {
        let auto = |toml: &str| {
            let cfg = NetConfig::parse(toml).unwrap();
            auto_tile(&Denoiser::new(cfg, &Device::flex()))
        };
        let narrow = include_str!("../../../../configs/nets/guided-lean.toml");
        // 5 frames × 16 channels × (512 + 2 · 36)² px × 4 B = 109 MB: 512; 1024 would be 384 MB
        assert_eq!(auto(narrow), 512);
        // the default model's width (32, 96 head channels with its skips) keeps 256
        let wide = Denoiser::new(NetConfig::preset("small").unwrap(), &Device::flex());
        assert_eq!(auto_tile(&wide), 256);
        assert_eq!(NetworkDenoiser::new(wide, Device::flex()).tile, 256);
    }

    #[test]
    fn the_colour_term_loosens_with_the_noise_level_and_stops_at_noisy_frames() {
        let d = Denoiser::new(NetConfig::preset("small").unwrap(), &Device::flex());
        let mut n = NetworkDenoiser::new(d, Device::flex());
        let tol =
            |n: &NetworkDenoiser, level: Option<f32>| n.align_params_for(level).confidence.color;
        // unset: alignment's own setting at every level
        assert_eq!(tol(&n, Some(0.01)), None);
        n.color_confidence = Some(0.5);
        // the cleanest frames get the base, twice the lowest level's noise twice the base
        let lowest = input_blend::LEVEL_AT_MIN_SCALE;
        assert_eq!(tol(&n, Some(0.01)), Some(0.5));
        assert_eq!(tol(&n, Some(lowest)), Some(0.5));
        assert!((tol(&n, Some(2.0 * lowest)).unwrap() - 1.0).abs() < 1e-6);
        // as noisy as the input blend's end (4 spp): off; a black frame has no level: off
        let edge = lowest * input_blend::MAX_NOISE_SCALE / input_blend::MIN_NOISE_SCALE;
        assert!((tol(&n, Some(edge)).unwrap() - 2.0).abs() < 1e-6);
        assert_eq!(tol(&n, Some(1.01 * edge)), None);
        assert_eq!(tol(&n, None), None);
        // the other terms are alignment's own
        assert_eq!(
            n.align_params_for(Some(0.01)).confidence.albedo,
            n.align.confidence.albedo
        );
    }

    #[test]
    fn the_sampled_buffers_terms_loosen_with_the_noise_level_up_to_the_most() {
        let d = Denoiser::new(NetConfig::preset("small").unwrap(), &Device::flex());
        let mut n = NetworkDenoiser::new(d, Device::flex());
        let albedo = |n: &NetworkDenoiser, level| n.align_params_for(level).confidence.albedo;
        let strict = n.align.confidence.albedo;
        // unset: the strict tolerance at every level, 4 spp included
        assert_eq!(albedo(&n, Some(10.0)), strict);
        n.loosen_sampled_terms = Some(4.0);
        let lowest = input_blend::LEVEL_AT_MIN_SCALE;
        let edge = lowest * input_blend::MAX_NOISE_SCALE / input_blend::MIN_NOISE_SCALE;
        // the cleanest frames keep it, twice the lowest level's noise doubles it, and frames as
        // noisy as 4 spp (or without a level) get the most
        assert_eq!(albedo(&n, Some(0.01)), strict);
        assert!((albedo(&n, Some(2.0 * lowest)) - 2.0 * strict).abs() < 1e-6);
        assert!((albedo(&n, Some(1.01 * edge)) - 4.0 * strict).abs() < 1e-6);
        assert!((albedo(&n, None) - 4.0 * strict).abs() < 1e-6);
        // never past the most, and the motion term is left alone
        n.loosen_sampled_terms = Some(1.5);
        assert!((albedo(&n, Some(2.0 * lowest)) - 1.5 * strict).abs() < 1e-6);
        assert_eq!(
            n.align_params_for(Some(10.0)).confidence.motion_px,
            n.align.confidence.motion_px
        );
        // a guide's term does not loosen with them
        n.align.confidence.guide = Some(0.6);
        assert_eq!(n.align_params_for(Some(10.0)).confidence.guide, Some(0.6));
    }

    #[test]
    fn the_input_blend_keeps_a_noise_free_input_and_follows_a_noisy_one() {
        let d = Denoiser::new(NetConfig::preset("small").unwrap(), &Device::flex());
        let mut n = NetworkDenoiser::new(d, Device::flex());
        n.refine = Some(InputBlend {
            radius: 1,
            strength: BlendStrength::Fixed(2.0),
        });
        // five identical frames: no noise, so nothing the kernels change is explained by it
        let mut still = window(24, 20);
        let centre = still.frames[2].clone();
        for (k, f) in still.frames.iter_mut().enumerate() {
            *f = AlignedFrame {
                offset: k as i32 - 2,
                ..centre.clone()
            };
        }
        let out = n.denoise_aligned(&still);
        let off = |a: &Plane, b: &Plane| {
            a.data()
                .iter()
                .zip(b.data())
                .map(|(x, y)| (x - y).abs())
                .fold(0.0f32, f32::max)
        };
        // the input, up to rounding (the frames' spread is not exactly 0 in floats) ...
        assert!(off(&out.color, &centre.color) < 1e-6);
        assert!(off(&out.aovs[0], &centre.aovs[0]) < 1e-6);
        assert!(off(out.alpha.as_ref().unwrap(), centre.alpha.as_ref().unwrap()) < 1e-6);
        // ... where the kernels alone change it
        let mut unblended = NetworkDenoiser::new(n.denoiser.clone(), Device::flex());
        unblended.refine = None;
        assert!(off(&unblended.denoise_aligned(&still).color, &centre.color) > 0.05);
        // frames that differ: their spread is noise, and the kernels' result is kept where
        // its change is no larger
        let noisy = window(24, 20);
        let plain = unblended.denoise_aligned(&noisy);
        let blended = n.denoise_aligned(&noisy);
        let input = noisy.centre().color.data();
        let kept = blended
            .color
            .data()
            .iter()
            .zip(plain.color.data())
            .zip(input)
            .filter(|((b, p), x)| (*b - *p).abs() < 1e-6 && (*p - *x).abs() > 1e-3)
            .count();
        assert!(kept > input.len() / 4, "{kept} of {}", input.len());
    }

    #[test]
    fn the_mix_range_follows_the_noise_level_and_takes_the_window_guide_at_every_level() {
        use guide_mix::MixGuide;
        use input_blend::{LEVEL_AT_MIN_SCALE, MAX_NOISE_SCALE, MIN_NOISE_SCALE};
        let d = Denoiser::new(NetConfig::preset("small").unwrap(), &Device::flex());
        let mut n = NetworkDenoiser::new(d, Device::flex());
        let clean = Some(0.01);
        let twice = Some(2.0 * LEVEL_AT_MIN_SCALE);
        let noisy = Some(10.0 * LEVEL_AT_MIN_SCALE * MAX_NOISE_SCALE / MIN_NOISE_SCALE);
        // without a range: the centre's guide on clean frames, the window's on noisy ones
        assert_eq!(n.guide_mix_range_for(clean), None);
        assert_eq!(n.guide_mix_range_for(noisy), Some(None));
        n.guide_mix_range = Some(0.02);
        // σ on the cleanest frames, twice σ at twice the level of the smallest scale, none on
        // frames the input blend leaves alone
        assert_eq!(n.guide_mix_range_for(clean), Some(Some(0.02)));
        let mid = n.guide_mix_range_for(twice).unwrap().unwrap();
        assert!((mid - 0.04).abs() < 1e-6, "{mid}");
        assert_eq!(n.guide_mix_range_for(noisy), Some(None));
        assert_eq!(n.guide_mix_range_for(None), Some(None));
        // the centre's guide stays the centre's guide
        n.guide_mix_from = MixGuide::Centre;
        assert_eq!(n.guide_mix_range_for(clean), None);
        n.guide_mix_from = MixGuide::Window;
        assert_eq!(n.guide_mix_range_for(clean), Some(Some(0.02)));
    }

    #[test]
    fn only_tiles_of_one_size_share_a_call() {
        let d = Denoiser::new(NetConfig::preset("small").unwrap(), &Device::flex());
        let mut n = NetworkDenoiser::new(d, Device::flex());
        n.tile = 16;
        // 70×52 with a 46-pixel halo: in each row of tiles, the tiles at x = 16 and 32 read
        // the full width; the others read less
        let tiles = n.tiles(&window(70, 52), 0..52, false);
        assert_eq!(tiles.len(), 5 * 4);
        for batch in [1, 2, 3, 8] {
            let calls = batches(&tiles, batch);
            assert_eq!(calls.iter().map(|c| c.len()).sum::<usize>(), tiles.len());
            for c in &calls {
                assert!(c.len() <= batch);
                let size = tiles[c.start].region.size();
                assert!(tiles[c.clone()].iter().all(|t| t.region.size() == size));
            }
            let most = calls.iter().map(|c| c.len()).max().unwrap();
            assert_eq!(most, batch.min(2), "batch {batch}: {calls:?}");
        }
    }

    #[test]
    fn tiled_and_whole_frame_results_agree_with_multi_scale_kernels() {
        let device = Device::flex();
        // the shipped model grown to three scales: trained kernels depend strongly on the
        // features, so a halo too small shows (a fresh network is nearly a box filter whose
        // output hardly depends on what a tile sees)
        let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../models/default.safetensors");
        let d = crate::model::store::load(&shipped, &device)
            .unwrap()
            .with_kernel_scales(3, &device)
            .unwrap();
        d.materialize();
        let halo = d.receptive_radius().expect("a ResNet's reach is bounded");
        assert_eq!(halo % 4, 0);
        // wide enough that inner tiles read less than the whole frame (across: the tiles of
        // one row differ only in x)
        let (w, h) = (2 * halo + 70, 30);
        let win = window(w, h);
        let mut n = NetworkDenoiser::new(d, device.clone());
        n.tile = 0;
        let whole = n.denoise_aligned(&win);
        // 30 is rounded down to 28, the grid's multiple
        for tile in [32usize, 30] {
            n.tile = tile;
            assert!(n
                .tiles(&win, 0..h, false)
                .iter()
                .any(|t| t.region.size() != (w, h)));
            let worst = worst_difference(&whole, &n.denoise_aligned(&win));
            // float rounding: 2e-7; a halo of 8 px instead of the bound: 1e-5
            assert!(
                worst < 1e-6,
                "tile {tile}: tiled and whole differ by {worst}"
            );
        }
    }

    #[test]
    fn a_learned_guide_mix_weighs_each_pixel_and_tiles_equal_the_whole_frame() {
        // both heads: on the features alone, and reading the kernels' result and the guide
        for reads_result in [false, true] {
            learned_mix_weighs_each_pixel(reads_result);
        }
    }

    fn learned_mix_weighs_each_pixel(reads_result: bool) {
        let device = Device::flex();
        let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../models/guided-lean.safetensors");
        let mut d = crate::model::store::load(&shipped, &device).unwrap();
        d.config.guide_mix_reads_result = reads_result;
        let mut d = d.with_guide_mix_head(true, &device).unwrap();
        // a head far from its start (w = 0.5 everywhere): weights that vary over the frame
        let c = d.feature_channels() + if reads_result { 9 } else { 0 };
        // (fixed weights, not random ones: the test sees the same weights every run)
        let mut head = burn::nn::conv::Conv2dConfig::new([c, 1], [3, 3])
            .with_padding(burn::nn::PaddingConfig2d::Same)
            .init(&device);
        let weights: Vec<f32> = (0..c * 9).map(|i| 0.3 * (i as f32 * 1.7).sin()).collect();
        head.weight = burn::module::Param::from_tensor(Tensor::from_data(
            TensorData::new(weights, [1, c, 3, 3]),
            &device,
        ));
        head.bias = Some(burn::module::Param::from_tensor(Tensor::zeros(
            [1],
            &device,
        )));
        d.set_guide_mix_head(head);
        d.materialize();
        let halo = d.receptive_radius().unwrap();
        let (w, h) = (2 * halo + 70, 30);
        let mut win = window(w, h);
        for (k, f) in win.frames.iter_mut().enumerate() {
            f.guide = Some(Plane::from_fn(w, h, 3, |x, y, ch| {
                0.2 + (((x * 5 + y * 3 + ch + k) % 17) as f32) / 20.0
            }));
        }
        let mut n = NetworkDenoiser::new(d, device.clone());
        n.tile = 0;
        n.guide_mix_from = guide_mix::MixGuide::Centre;
        let learned = n.denoise_aligned(&win);
        // the kernels' result alone, and the guide alone, by fixed weights
        n.guide_mix_learned = false;
        n.guide_mix = 0.0;
        let r = n.denoise_aligned(&win).color;
        n.guide_mix = 1.0;
        let g = n.denoise_aligned(&win).color;
        // each pixel is (1 − w)·r + w·g with one w in [0, 1] for its three channels
        let mut weights = Vec::new();
        for i in 0..w * h {
            let solve = |ch: usize| {
                let (r, g, m) = (
                    r.channel(ch)[i],
                    g.channel(ch)[i],
                    learned.color.channel(ch)[i],
                );
                ((g - r).abs() > 0.05).then(|| (m - r) / (g - r))
            };
            let ws: Vec<f32> = (0..3).filter_map(solve).collect();
            if let Some(&first) = ws.first() {
                assert!((-1e-3..=1.001).contains(&first), "pixel {i}: w = {first}");
                assert!(ws.iter().all(|x| (x - first).abs() < 1e-3), "{ws:?}");
                weights.push(first);
            }
        }
        assert!(weights.len() > w * h / 2);
        let (lo, hi) = weights
            .iter()
            .fold((1.0f32, 0.0f32), |(lo, hi), &x| (lo.min(x), hi.max(x)));
        assert!(
            hi - lo > 0.3,
            "reads result {reads_result}: the weights vary: {lo} to {hi}"
        );
        // tile by tile, the weights travel with the kernels' result
        n.guide_mix_learned = true;
        for tile in [32usize, 16] {
            n.tile = tile;
            let worst = worst_difference(&learned, &n.denoise_aligned(&win));
            assert!(
                worst < 1e-5,
                "tile {tile}: tiled and whole differ by {worst}"
            );
        }
    }

    #[test]
    fn tiled_and_whole_frame_results_agree() {
        let device = Device::flex();
        for (preset, demodulate) in [("small", None), ("tkpcn", None), ("small", Some(0.25))] {
            let mut config = NetConfig::preset(preset).unwrap();
            config.demodulate = demodulate;
            let d = Denoiser::new(config, &device);
            d.materialize();
            let win = window(70, 52);
            let mut n = NetworkDenoiser::new(d, device.clone());
            n.tile = 0;
            let whole = n.denoise_aligned(&win);
            // tile 16 with batches of 3: tiles of equal regions share calls, the frame-edge
            // tiles (smaller regions) run apart
            for (tile, batch) in [(16usize, 1usize), (33, 1), (16, 3)] {
                n.tile = tile;
                n.batch = batch;
                let worst = worst_difference(&whole, &n.denoise_aligned(&win));
                assert!(
                    worst < 1e-5,
                    "{preset} {demodulate:?}, tile {tile} batch {batch}: tiled and whole \
                     differ by {worst}"
                );
            }
        }
    }
}
