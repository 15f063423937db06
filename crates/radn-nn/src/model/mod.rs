//! The model: the paper's RA network and the two baselines, behind one interface that
//! predicts kernels for a window and applies them to any planes, with everything a network is
//! built from — its configuration ([`config`]), layers ([`layers`]), Robust Average blocks
//! ([`ra_block`]), per-frame backbones ([`backbone`]), kernels and their activation
//! ([`kernel`]) and their multi-scale reconstruction ([`multiscale`]), albedo demodulation
//! ([`demod`]) — and its files ([`store`]).

pub mod backbone;
pub mod config;
pub mod cpu;
pub mod demod;
pub mod guide_blend;
mod introspect;
pub mod kernel;
pub mod layers;
pub mod multiscale;
pub mod ra_block;
pub mod store;
mod surgery;

use burn::module::{Module, Param};
use burn::nn::conv::Conv2d;
use burn::nn::Initializer;
use burn::tensor::activation::{sigmoid, softmax};
use burn::tensor::{Device, Tensor};

use crate::model::backbone::FrameNet;
use crate::model::config::{Arch, InputConfig, NetConfig};
use crate::model::cpu::conv::conv2d;
use crate::model::kernel::{eta, Kernels};
use crate::model::layers::{conv3, conv_flops};
use crate::model::multiscale::{downsample, pad_to, padded_size, MultiScaleKernels};
use crate::profile::{timed, Stage};

/// Initial bias of the multi-scale blend heads: `α = sigmoid(−2) ≈ 0.12`, so a new network
/// starts close to its full-resolution kernels and learns how much of the coarse scales to use.
pub const BLEND_INIT_BIAS: f32 = -2.0;

/// The head's default initial scale ([`NetConfig::head_init`]).
pub const DEFAULT_HEAD_INIT: f32 = 1e-3;

/// A kernel head whose first kernels are close to a box filter: equal biases (`bias`, above
/// the default threshold, so η passes gradient everywhere) and weights so small that the raw
/// outputs vary by about `scale` (1e-3 by default), but not zero (a zero head would block all
/// gradient to the backbone).
fn box_head(cin: usize, taps: usize, bias: f32, scale: f32, device: &Device) -> Conv2d {
    let std = scale as f64 / ((cin * 9) as f64).sqrt();
    let mut head = burn::nn::conv::Conv2dConfig::new([cin, taps], [3, 3])
        .with_padding(burn::nn::PaddingConfig2d::Same)
        .with_initializer(Initializer::Normal { mean: 0.0, std })
        .init(device);
    head.bias = Some(Param::from_tensor(Tensor::full([taps], bias, device)));
    head
}

/// The guide-blend head's initial bias: β ≈ 0.018, so a network that gains the blend first
/// computes almost what it did without it.
pub const GUIDE_BLEND_INIT_BIAS: f32 = -4.0;

/// A blend-weight head (one channel, before the sigmoid) with small weights and a bias of
/// [`BLEND_INIT_BIAS`].
fn blend_head(cin: usize, device: &Device) -> Conv2d {
    blend_head_with(cin, BLEND_INIT_BIAS, device)
}

/// A one-channel head with small weights and bias `bias`.
fn blend_head_with(cin: usize, bias: f32, device: &Device) -> Conv2d {
    let std = 1e-2 / ((cin * 9) as f64).sqrt();
    let mut head = burn::nn::conv::Conv2dConfig::new([cin, 1], [3, 3])
        .with_padding(burn::nn::PaddingConfig2d::Same)
        .with_initializer(Initializer::Normal { mean: 0.0, std })
        .init(device);
    head.bias = Some(Param::from_tensor(Tensor::full([1], bias, device)));
    head
}

/// The paper's network: per-frame backbone with RA blocks, a per-frame head of k² weights,
/// the frames' weights joined into one k×k×T kernel and activated together. With several
/// kernel scales, the backbone's features are also averaged down to 1/2, 1/4 … resolution,
/// where further heads predict that scale's kernels, and the centre frame's features at each
/// scale but the coarsest predict the blend weight of the coarser result.
#[derive(Module, Debug)]
pub struct RaNet {
    backbone: FrameNet,
    head: Conv2d,
    coarse_heads: Vec<Conv2d>,
    blend_heads: Vec<Conv2d>,
    /// With `guide_blend`: one per-frame head of the guide-blend weight β (before the sigmoid).
    guide_heads: Vec<Conv2d>,
}

/// tKPCN (Vogels et al. 2018): per-frame spatial kernels, then a temporal kernel over the
/// spatially denoised frames predicted from all frames' features. No RA blocks.
#[derive(Module, Debug)]
pub struct TKpcn {
    backbone: FrameNet,
    spatial_head: Conv2d,
    temporal_a: Conv2d,
    temporal_b: Conv2d,
    temporal_head: Conv2d,
}

/// A spatial-only KPCN on the centre frame.
#[derive(Module, Debug)]
pub struct SpatialKpcn {
    backbone: FrameNet,
    head: Conv2d,
}

/// Any of the networks.
// one value per model, built once: the variants' size difference does not matter
#[allow(clippy::large_enum_variant)]
#[derive(Module, Debug)]
pub enum Network {
    /// The RA network.
    Ra(RaNet),
    /// tKPCN.
    Tkpcn(TKpcn),
    /// Spatial KPCN.
    Spatial(SpatialKpcn),
}

/// A network with its configuration and recipe: everything needed to denoise.
#[derive(Debug, Clone)]
pub struct Denoiser {
    /// The trainable part.
    pub net: Network,
    /// Its description.
    pub config: NetConfig,
    /// Its tuned inference settings (saved beside the configuration in its file).
    pub recipe: crate::recipe::Recipe,
}

/// What a guided network predicts besides its kernels.
#[derive(Clone, Debug, Default)]
pub struct GuideWeights {
    /// β of the guide blend per frame and pixel, `[B, T, 1, H, W]`
    /// ([`crate::model::guide_blend::GuideBlend`]); `None` without the blend.
    pub blend: Option<Tensor<5>>,
}

/// Kernels predicted for a batch of windows.
// one value per forward pass, holding tensor handles: its size does not matter
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
pub enum Prediction {
    /// One k×k×T kernel per pixel (RA network), or k×k on the centre frame (spatial: T = 1).
    Single(Kernels),
    /// k×k×T kernels at several scales, combined coarse to fine (RA network with
    /// `kernel_scales` > 1).
    MultiScale(MultiScaleKernels),
    /// tKPCN: spatial kernels per frame (`[B·T, k², H, W]`), then a temporal k×k×T kernel.
    TwoStage {
        /// Per-frame spatial kernels.
        spatial: Kernels,
        /// The temporal combination.
        temporal: Kernels,
    },
}

impl Denoiser {
    /// A freshly initialised network.
    pub fn new(config: NetConfig, device: &Device) -> Self {
        let k2 = config.kernel_size * config.kernel_size;
        let t = config.frames;
        let cin = config.input_channels();
        let scale = config.head_init.unwrap_or(DEFAULT_HEAD_INIT);
        // raw weights all 2/K: above the default threshold 1/(2K), so η gives a box
        let box_bias = 2.0 / config.kernel_taps() as f32;
        let kernel_head =
            |backbone: &FrameNet| box_head(backbone.out_channels(), k2, box_bias, scale, device);
        let net = match config.arch {
            Arch::Ra => {
                let mut backbone = FrameNet::new(&config.backbone, cin, t, true, device);
                if config.frame_local_stem {
                    split_stem(&mut backbone, &config.inputs, device);
                }
                let head = kernel_head(&backbone);
                let scales = config.scales();
                let coarse_heads = (1..scales).map(|_| kernel_head(&backbone)).collect();
                let blend_heads = (1..scales)
                    .map(|_| blend_head(backbone.out_channels(), device))
                    .collect();
                let guide_heads = config
                    .guide_blend
                    .then(|| {
                        blend_head_with(backbone.out_channels(), GUIDE_BLEND_INIT_BIAS, device)
                    })
                    .into_iter()
                    .collect();
                Network::Ra(RaNet {
                    backbone,
                    head,
                    coarse_heads,
                    blend_heads,
                    guide_heads,
                })
            }
            Arch::Tkpcn => {
                let backbone = FrameNet::new(&config.backbone, cin, t, false, device);
                let c = backbone.out_channels();
                Network::Tkpcn(TKpcn {
                    spatial_head: box_head(c, k2, 0.0, scale, device),
                    temporal_a: conv3(t * c, c, device),
                    temporal_b: conv3(c, c, device),
                    temporal_head: box_head(c, t * k2, box_bias, scale, device),
                    backbone,
                })
            }
            Arch::Spatial => {
                let backbone = FrameNet::new(&config.backbone, cin, t, false, device);
                let head = kernel_head(&backbone);
                Network::Spatial(SpatialKpcn { backbone, head })
            }
        };
        let recipe = crate::recipe::Recipe::tuned_for(&config);
        Self {
            net,
            config,
            recipe,
        }
    }

    /// The stem of a frame-local network ([`NetConfig::frame_local_stem`]) for frames `[n, C,
    /// H, W]` (`C` = [`NetConfig::input_channels`]; the window's own channels are not read):
    /// `[n, width, H, W]`, what [`Denoiser::predict_with_stem`] takes instead of computing it.
    pub fn stem(&self, frames: Tensor<4>) -> Tensor<4> {
        let (Network::Ra(n), true) = (&self.net, self.config.frame_local_stem) else {
            panic!("only a network with a frame-local stem has a stem of its own");
        };
        let resnet = n.backbone.resnet().expect("validated: a ResNet backbone");
        timed(Stage::Backbone, || {
            resnet.stem(frame_channels(frames, &self.config.inputs))
        })
    }

    /// Predicts kernels for windows `[B, T, C, H, W]` (`C` = [`NetConfig::input_channels`],
    /// made by [`crate::infer::input::network_features`]) with threshold `t`.
    pub fn predict(&self, input: Tensor<5>, t: f32) -> Prediction {
        self.predict_guided(input, t).0
    }

    /// [`Denoiser::predict`], and for a guided network the weights of its guide blend.
    pub fn predict_guided(&self, input: Tensor<5>, t: f32) -> (Prediction, GuideWeights) {
        timed(Stage::Heads, || self.predict_untimed(input, t, None))
    }

    /// [`Denoiser::predict_guided`] for a frame-local network given every window frame's stem
    /// features `[B, T, width, H, W]` (computed once per frame with [`Denoiser::stem`] and
    /// warped onto the centre frame): the input's frame channels are then not read again.
    pub fn predict_with_stem(
        &self,
        input: Tensor<5>,
        stem: Tensor<5>,
        t: f32,
    ) -> (Prediction, GuideWeights) {
        timed(Stage::Heads, || self.predict_untimed(input, t, Some(stem)))
    }

    /// The RA network's head features of the frames `x` (`[B·T, C, H, W]`, padded to `(ph,
    /// pw)`): the backbone's, or for a frame-local network the stem's (given, or computed on
    /// the unpadded frames) padded and then the rest of the backbone.
    fn backbone_features(
        &self,
        n: &RaNet,
        x: Tensor<4>,
        stem: Option<Tensor<5>>,
        (ph, pw): (usize, usize),
    ) -> Tensor<4> {
        if !self.config.frame_local_stem {
            return n.backbone.forward(pad_to(x, ph, pw));
        }
        let resnet = n.backbone.resnet().expect("validated: a ResNet backbone");
        let [bt, _, h, w] = x.dims();
        let (first, count) = self.config.inputs.window_channels();
        let window = pad_to(x.clone().narrow(1, first, count), ph, pw);
        let stem = match stem {
            Some(s) => s.reshape([bt, resnet.width(), h, w]),
            None => timed(Stage::Backbone, || {
                resnet.stem(frame_channels(x, &self.config.inputs))
            }),
        };
        timed(Stage::Backbone, || {
            resnet.after_stem(pad_to(stem, ph, pw), Some(window))
        })
    }

    /// β of the guide blend from per-frame features
    /// `[B·T, C, H', W']` (cropped to `h × w`), where the network has them.
    fn guide_weights(
        &self,
        n: &RaNet,
        feats: &Tensor<4>,
        b: usize,
        h: usize,
        w: usize,
    ) -> GuideWeights {
        let [bt, ..] = feats.dims();
        let blend = n.guide_heads.first().map(|head| {
            let beta = sigmoid(conv2d(head, feats.clone(), false));
            let beta = beta.slice([0..bt, 0..1, 0..h, 0..w]);
            beta.reshape([b, bt / b, 1, h, w])
        });
        GuideWeights { blend }
    }

    fn predict_untimed(
        &self,
        input: Tensor<5>,
        t: f32,
        stem: Option<Tensor<5>>,
    ) -> (Prediction, GuideWeights) {
        let [b, frames, c, h, w] = input.dims();
        assert_eq!(
            frames, self.config.frames,
            "the window has {frames} frames, the network expects {}",
            self.config.frames
        );
        assert_eq!(
            c,
            self.config.input_channels(),
            "expected {} input channels",
            self.config.input_channels()
        );
        let k = self.config.kernel_size;
        let k2 = k * k;
        let act = self.config.activation;
        let centre = frames / 2;
        match &self.net {
            Network::Ra(n) if self.config.scales() == 1 => {
                let x = input.reshape([b * frames, c, h, w]);
                let feats = self.backbone_features(n, x, stem, (h, w));
                let guides = self.guide_weights(n, &feats, b, h, w);
                let raw = conv2d(&n.head, feats, false).reshape([b, frames * k2, h, w]);
                let weights = eta(raw, t, act, centre * k2 + k2 / 2);
                (
                    Prediction::Single(Kernels {
                        weights,
                        frames,
                        size: k,
                    }),
                    guides,
                )
            }
            Network::Ra(n) => {
                let scales = self.config.scales();
                let padded = padded_size(h, w, scales);
                let x = input.reshape([b * frames, c, h, w]);
                let mut feats = self.backbone_features(n, x, stem, padded);
                let guides = self.guide_weights(n, &feats, b, h, w);
                let mut kernels = Vec::with_capacity(scales);
                let mut blend = Vec::with_capacity(scales - 1);
                for s in 0..scales {
                    if s > 0 {
                        feats = downsample(feats);
                    }
                    let [_, fc, hs, ws] = feats.dims();
                    let head = if s == 0 {
                        &n.head
                    } else {
                        &n.coarse_heads[s - 1]
                    };
                    let raw = conv2d(head, feats.clone(), false).reshape([b, frames * k2, hs, ws]);
                    kernels.push(Kernels {
                        weights: eta(raw, t, act, centre * k2 + k2 / 2),
                        frames,
                        size: k,
                    });
                    if s + 1 < scales {
                        let centre_feats = feats
                            .clone()
                            .reshape([b, frames, fc, hs, ws])
                            .narrow(1, centre, 1)
                            .reshape([b, fc, hs, ws]);
                        blend.push(sigmoid(conv2d(&n.blend_heads[s], centre_feats, false)));
                    }
                }
                (
                    Prediction::MultiScale(MultiScaleKernels {
                        scales: kernels,
                        blend,
                        size: (h, w),
                    }),
                    guides,
                )
            }
            Network::Spatial(n) => {
                let x = input.narrow(1, centre, 1).reshape([b, c, h, w]);
                let raw = conv2d(&n.head, n.backbone.forward(x), false);
                (
                    Prediction::Single(Kernels {
                        weights: eta(raw, t, act, k2 / 2),
                        frames: 1,
                        size: k,
                    }),
                    GuideWeights::default(),
                )
            }
            Network::Tkpcn(n) => {
                let feats = n.backbone.forward(input.reshape([b * frames, c, h, w]));
                let fc = feats.dims()[1];
                let spatial = softmax(conv2d(&n.spatial_head, feats.clone(), false), 1);
                let joined = feats.reshape([b, frames * fc, h, w]);
                let tfeat = conv2d(&n.temporal_b, conv2d(&n.temporal_a, joined, true), true);
                let raw = conv2d(&n.temporal_head, tfeat, false);
                let temporal = eta(raw, t, act, centre * k2 + k2 / 2);
                (
                    Prediction::TwoStage {
                        spatial: Kernels {
                            weights: spatial,
                            frames: 1,
                            size: k,
                        },
                        temporal: Kernels {
                            weights: temporal,
                            frames,
                            size: k,
                        },
                    },
                    GuideWeights::default(),
                )
            }
        }
    }
}

/// The frame-local channels ([`InputConfig::frame_channels`]) of frames `[n, C, H, W]`.
fn frame_channels(x: Tensor<4>, inputs: &InputConfig) -> Tensor<4> {
    let parts: Vec<Tensor<4>> = inputs
        .frame_channels()
        .into_iter()
        .map(|r| x.clone().narrow(1, r.start, r.len()))
        .collect();
    Tensor::cat(parts, 1)
}

/// Splits a ResNet's stem into its frame-local part and the window's own inputs
/// ([`crate::model::backbone::ResNet::split_window_inputs`]), their at-rest values being a
/// trusted frame's: confidence 1, noise estimate 0.
fn split_stem(backbone: &mut FrameNet, inputs: &InputConfig, device: &Device) {
    let resnet = backbone
        .resnet_mut()
        .expect("validated: a frame-local stem has a ResNet backbone");
    let (first, count) = inputs.window_channels();
    let mut at_rest = vec![0.0; count];
    at_rest[0] = 1.0; // confidence
    resnet.split_window_inputs(
        &inputs.frame_channels(),
        first..first + count,
        &at_rest,
        device,
    );
}

impl Prediction {
    /// Applies the kernels to the window's values `[B, T, C, H, W]` (linear, warped).
    pub fn apply(&self, values: Tensor<5>) -> Tensor<4> {
        let [b, t, c, h, w] = values.dims();
        match self {
            Prediction::Single(k) if k.frames == 1 => k.apply(values.narrow(1, t / 2, 1)),
            Prediction::Single(k) => k.apply(values),
            Prediction::MultiScale(m) => m.apply(values),
            Prediction::TwoStage { spatial, temporal } => {
                let per_frame = spatial.apply(values.reshape([b * t, 1, c, h, w]));
                temporal.apply(per_frame.reshape([b, t, c, h, w]))
            }
        }
    }

    /// The prediction restricted to a subset of the window's frames, renormalised (paper
    /// section 5). `None` for a spatial network asked to do without its only frame.
    pub fn subset(&self, mask: &[bool]) -> Option<Prediction> {
        match self {
            Prediction::Single(k) if k.frames == 1 => mask[mask.len() / 2].then(|| self.clone()),
            Prediction::Single(k) => Some(Prediction::Single(k.subset(mask))),
            Prediction::MultiScale(m) => Some(Prediction::MultiScale(m.subset(mask))),
            Prediction::TwoStage { spatial, temporal } => Some(Prediction::TwoStage {
                spatial: spatial.clone(),
                temporal: temporal.subset(mask),
            }),
        }
    }

    /// Per-pixel weight of each window frame `[B, T, H, W]` (temporal utilisation).
    pub fn frame_mass(&self, frames: usize) -> Tensor<4> {
        match self {
            Prediction::Single(k) if k.frames == 1 => {
                let [b, _, h, w] = k.weights.dims();
                let device = k.weights.device();
                let mut v = vec![0.0f32; frames];
                v[frames / 2] = 1.0;
                Tensor::<1>::from_floats(v.as_slice(), &device)
                    .reshape([1, frames, 1, 1])
                    .expand([b, frames, h, w])
            }
            Prediction::Single(k) => k.frame_mass(),
            Prediction::MultiScale(m) => m.frame_mass(),
            Prediction::TwoStage { temporal, .. } => temporal.frame_mass(),
        }
    }
}

#[cfg(test)]
mod tests;
