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
pub mod kernel;
pub mod layers;
pub mod learned_mix;
pub mod multiscale;
pub mod ra_block;
pub mod store;

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

/// The learned guide mix head's initial bias: `w = sigmoid(0) = 0.5`, the fixed weight the
/// guided models are mixed with at inference (`radn denoise --guide-mix auto`), so a network
/// that gains the head first computes what the fixed mix gave.
pub const GUIDE_MIX_INIT_BIAS: f32 = 0.0;

/// The scale of the learned guide mix head's difference input: `|ln(1 + r) − ln(1 + g)|` is
/// multiplied by it, so a difference of 0.05 (where the outlier ramp of
/// [`crate::infer::guide_mix`] starts to act) reads as 1. Its weights then need to move by about
/// one unit, not twenty, before the head tells outliers from detail: a fine-tune of a few hundred
/// steps at 2e-4 moves a weight by at most about 0.1.
pub const MIX_DIFF_SCALE: f32 = 20.0;

/// Input channels of the learned guide mix's head: the backbone's features, and with
/// [`NetConfig::guide_mix_reads_result`] the result's and the guide's log colour and their
/// absolute difference.
fn mix_head_inputs(config: &NetConfig, features: usize) -> usize {
    features + if config.guide_mix_reads_result { 9 } else { 0 }
}

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
    /// With `guide_mix_head`: one head on the centre frame's features of the guide mix weight
    /// `w` (before the sigmoid).
    mix_heads: Vec<Conv2d>,
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

/// A network with its configuration: everything needed to denoise.
#[derive(Debug, Clone)]
pub struct Denoiser {
    /// The trainable part.
    pub net: Network,
    /// Its description.
    pub config: NetConfig,
}

/// What a guided network predicts besides its kernels.
#[derive(Clone, Debug, Default)]
pub struct GuideWeights {
    /// β of the guide blend per frame and pixel, `[B, T, 1, H, W]`
    /// ([`crate::model::guide_blend::GuideBlend`]); `None` without the blend.
    pub blend: Option<Tensor<5>>,
    /// `w` of the learned guide mix per pixel, `[B, 1, H, W]`
    /// ([`NetConfig::guide_mix_head`]); `None` without it, and for a head that reads the
    /// kernels' result, which gives [`GuideWeights::mix_features`] instead.
    pub mix: Option<Tensor<4>>,
    /// For a learned guide mix that reads the kernels' result: the centre frame's features
    /// `[B, C, H, W]` its head reads with them ([`Denoiser::mix_weight_of_result`]).
    pub mix_features: Option<Tensor<4>>,
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
                let mix_heads = config
                    .guide_mix_head
                    .then(|| {
                        blend_head_with(
                            mix_head_inputs(&config, backbone.out_channels()),
                            GUIDE_MIX_INIT_BIAS,
                            device,
                        )
                    })
                    .into_iter()
                    .collect();
                Network::Ra(RaNet {
                    backbone,
                    head,
                    coarse_heads,
                    blend_heads,
                    guide_heads,
                    mix_heads,
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
        Self { net, config }
    }

    /// The same network with `scales` kernel scales: the heads it lacks are added, each
    /// coarse kernel head starting as a copy of the full-resolution head (the same features,
    /// averaged, then give the same kernels at the coarser scale) and each blend head at
    /// [`BLEND_INIT_BIAS`], so a fine-tune of a single-scale model starts close to it. Fewer
    /// scales than the network has drop the coarsest heads. Only the RA network has scales.
    pub fn with_kernel_scales(mut self, scales: usize, device: &Device) -> Result<Self, String> {
        let Network::Ra(n) = &mut self.net else {
            return Err("only arch = \"ra\" has multi-scale kernels".into());
        };
        let c = n.backbone.out_channels();
        let k2 = self.config.kernel_size * self.config.kernel_size;
        n.coarse_heads.truncate(scales.saturating_sub(1));
        n.blend_heads.truncate(scales.saturating_sub(1));
        while n.coarse_heads.len() + 1 < scales {
            let mut h = box_head(c, k2, 0.0, 1.0, device);
            h.weight = Param::from_tensor(n.head.weight.val());
            h.bias = n.head.bias.as_ref().map(|b| Param::from_tensor(b.val()));
            n.coarse_heads.push(h);
            n.blend_heads.push(blend_head(c, device));
        }
        self.config.kernel_scales = (scales > 1).then_some(scales);
        Ok(self)
    }

    /// The same network with a frame-local stem ([`NetConfig::frame_local_stem`]): the input
    /// layer's weights of the window's own channels leave it (their value where a frame is fully
    /// trusted — confidence 1, noise estimate 0 — folded into its bias) and come back after the
    /// stem through a 1×1 convolution that starts at zero. A fine-tune from a model without the
    /// split starts close to it. Only an RA network with a ResNet backbone has the split.
    pub fn with_frame_local_stem(mut self, device: &Device) -> Result<Self, String> {
        if self.config.frame_local_stem {
            return Ok(self);
        }
        let mut config = self.config.clone();
        config.frame_local_stem = true;
        config.validate().map_err(|e| e.to_string())?;
        let Network::Ra(n) = &mut self.net else {
            return Err("only arch = \"ra\" has a frame-local stem".into());
        };
        split_stem(&mut n.backbone, &self.config.inputs, device);
        self.config = config;
        Ok(self)
    }

    /// The same network with the guide blend on or off (`blend`): a new blend head starts at
    /// [`GUIDE_BLEND_INIT_BIAS`], so a fine-tune that adds it starts close to the model it
    /// grows. Only the RA network blends, and only with a guide in its inputs.
    pub fn with_guide_blend(mut self, blend: bool, device: &Device) -> Result<Self, String> {
        let Network::Ra(n) = &mut self.net else {
            return Err("only arch = \"ra\" has the guide blend".into());
        };
        if blend && !self.config.inputs.guide {
            return Err("the guide blend needs [inputs] guide = true".into());
        }
        if !blend {
            n.guide_heads.clear();
        } else if n.guide_heads.is_empty() {
            let c = n.backbone.out_channels();
            n.guide_heads
                .push(blend_head_with(c, GUIDE_BLEND_INIT_BIAS, device));
        }
        self.config.guide_blend = blend;
        Ok(self)
    }

    /// The same network with the learned guide mix on or off (`mix`): a new mix head starts at
    /// [`GUIDE_MIX_INIT_BIAS`], the fixed mix's weight, so a fine-tune that adds it starts from
    /// what the model it grows gave with the fixed mix. Only the RA network mixes, and only with
    /// a guide in its inputs.
    pub fn with_guide_mix_head(mut self, mix: bool, device: &Device) -> Result<Self, String> {
        let Network::Ra(n) = &mut self.net else {
            return Err("only arch = \"ra\" has the learned guide mix".into());
        };
        if mix && !self.config.inputs.guide {
            return Err("the learned guide mix needs [inputs] guide = true".into());
        }
        self.config.guide_mix_head = mix;
        let cin = mix_head_inputs(&self.config, n.backbone.out_channels());
        let fits = |h: &Conv2d| h.weight.dims()[1] == cin;
        if !mix {
            n.mix_heads.clear();
        } else if !n.mix_heads.first().is_some_and(fits) {
            n.mix_heads = vec![blend_head_with(cin, GUIDE_MIX_INIT_BIAS, device)];
        }
        Ok(self)
    }

    /// The learned guide mix's weight `[B, 1, H, W]` for a head that reads the kernels' result
    /// ([`NetConfig::guide_mix_reads_result`]): from the centre frame's features
    /// ([`GuideWeights::mix_features`]), the result's colour `result` (linear, `[B, 3, H, W]`)
    /// as log colour `ln(1 + max(0, r)·inv_exposure)` like the inputs' (`inv_exposure`
    /// `[B, 1, 1, 1]`: the reciprocal of what the inputs were divided by), and the centre
    /// frame's guide as the network `input` (`[B, T, C, H, W]`) holds it.
    pub fn mix_weight_of_result(
        &self,
        features: Tensor<4>,
        result: Tensor<4>,
        inv_exposure: Tensor<4>,
        input: &Tensor<5>,
    ) -> Tensor<4> {
        let Network::Ra(n) = &self.net else {
            panic!("only the RA network has the learned guide mix");
        };
        let head = n.mix_heads.first().expect("a learned guide mix head");
        let scale = inv_exposure.expand(result.dims());
        let result_log = (result.clamp_min(0.0) * scale + 1.0).log();
        let guide_log = self.centre_guide_log(input);
        let diff = (result_log.clone() - guide_log.clone()).abs() * MIX_DIFF_SCALE;
        sigmoid(conv2d(
            head,
            Tensor::cat(vec![features, result_log, guide_log, diff], 1),
            false,
        ))
    }

    /// The centre frame's guide as the network reads it (log colour, `[B, 3, H, W]`) from its
    /// input `[B, T, C, H, W]`.
    fn centre_guide_log(&self, input: &Tensor<5>) -> Tensor<4> {
        let [b, t, _, h, w] = input.dims();
        input
            .clone()
            .narrow(1, t / 2, 1)
            .narrow(2, self.config.inputs.guide_offset(), 3)
            .reshape([b, 3, h, w])
    }

    /// Replaces the learned guide mix's head (tests: a head far from its start, whose weights
    /// vary across the frame).
    #[cfg(test)]
    pub(crate) fn set_guide_mix_head(&mut self, head: Conv2d) {
        let Network::Ra(n) = &mut self.net else {
            panic!("only the RA network has the learned guide mix");
        };
        n.mix_heads = vec![head];
    }

    /// The same network reading the input features `inputs`: the first layer gains (or drops)
    /// the channels that differ, new ones with zero weights, so the grown network first
    /// computes what the old one did on the features both share. A fine-tune that adds the
    /// noise estimate starts from the model it grows.
    pub fn with_inputs(mut self, inputs: InputConfig, device: &Device) -> Self {
        let cin = inputs.channels();
        match &mut self.net {
            Network::Ra(n) => n.backbone.widen_input(cin, device),
            Network::Tkpcn(n) => n.backbone.widen_input(cin, device),
            Network::Spatial(n) => n.backbone.widen_input(cin, device),
        }
        self.config.inputs = inputs;
        self
    }

    /// Draws every parameter's initial value now. burn initialises parameters lazily, on first
    /// use, so without this the random draws would happen in whatever order the parameters are
    /// first touched, interleaved with other random work.
    pub fn materialize(&self) {
        use burn::store::ModuleSnapshot;
        let mut store = burn::store::SafetensorsStore::from_bytes(None);
        self.net
            .save_into(&mut store)
            .expect("collecting parameters into memory cannot fail");
    }

    /// Channels per frame of the features the heads read (the backbone's output).
    pub fn feature_channels(&self) -> usize {
        match &self.net {
            Network::Ra(n) => n.backbone.out_channels(),
            Network::Tkpcn(n) => n.backbone.out_channels(),
            Network::Spatial(n) => n.backbone.out_channels(),
        }
    }

    /// The RA blocks of the network (none for the baselines).
    pub fn ra_blocks(&self) -> Vec<&crate::model::ra_block::RobustAverage> {
        match &self.net {
            Network::Ra(n) => n.backbone.ra_blocks(),
            _ => Vec::new(),
        }
    }

    /// Every convolution weight of the network by layer name, in forward order (backbone
    /// layers prefixed `backbone.`, then the heads): what training reports layer by layer.
    pub fn layer_weights(&self) -> Vec<(String, Tensor<4>)> {
        let backbone = |b: &FrameNet| {
            b.weights()
                .into_iter()
                .map(|(n, w)| (format!("backbone.{n}"), w))
                .collect::<Vec<_>>()
        };
        match &self.net {
            Network::Ra(n) => {
                let mut v = backbone(&n.backbone);
                v.push(("head".into(), n.head.weight.val()));
                for (s, h) in n.coarse_heads.iter().enumerate() {
                    v.push((format!("head.scale{}", s + 1), h.weight.val()));
                }
                for (s, h) in n.blend_heads.iter().enumerate() {
                    v.push((format!("blend.scale{s}"), h.weight.val()));
                }
                for h in &n.guide_heads {
                    v.push(("guide_blend".into(), h.weight.val()));
                }
                for h in &n.mix_heads {
                    v.push(("guide_mix".into(), h.weight.val()));
                }
                v
            }
            Network::Spatial(n) => {
                let mut v = backbone(&n.backbone);
                v.push(("head".into(), n.head.weight.val()));
                v
            }
            Network::Tkpcn(n) => {
                let mut v = backbone(&n.backbone);
                v.push(("spatial_head".into(), n.spatial_head.weight.val()));
                v.push(("temporal_a".into(), n.temporal_a.weight.val()));
                v.push(("temporal_b".into(), n.temporal_b.weight.val()));
                v.push(("temporal_head".into(), n.temporal_head.weight.val()));
                v
            }
        }
    }

    /// Trainable parameters.
    pub fn num_params(&self) -> usize {
        self.net.num_params()
    }

    /// How far (in pixels) an output pixel's value can depend on the input: the halo a tile
    /// needs so that tiled and whole-frame results agree. Each 3×3 convolution adds 1, each RA
    /// block adds 2 per recurrent step, kernel application adds k/2 (twice for tKPCN). `None`
    /// for a UNet, whose pooling grid makes tiles depend on their position.
    pub fn receptive_radius(&self) -> Option<usize> {
        self.reach_beyond(0)
    }

    /// [`Denoiser::receptive_radius`] once the stem's features are given
    /// ([`Denoiser::predict_with_stem`], computed on whole frames): the stem's own reach is then
    /// not needed around a tile.
    pub fn receptive_radius_after_stem(&self) -> Option<usize> {
        self.reach_beyond(self.stem_radius())
    }

    /// The receptive radius less `given` pixels of the backbone's reach that are already
    /// computed.
    fn reach_beyond(&self, given: usize) -> Option<usize> {
        let k = self.config.kernel_size / 2;
        if self.config.scales() > 1 {
            // a coarse kernel at scale s reaches k coarse pixels, its head one more, the box
            // averages one more: (k + 3)·2^s pixels beyond the backbone's reach. Tiles must then
            // start on the coarsest scale's grid ([`Denoiser::tile_grid`]), so the halo is a
            // multiple of it.
            let crate::model::config::Backbone::Resnet {
                blocks, ra_after, ..
            } = &self.config.backbone
            else {
                return None; // a UNet's own pooling grid
            };
            let m = self.tile_grid();
            let backbone = 1 + 2 * blocks + ra_after.len() * 2 * self.config.frames - given;
            return Some((backbone + 1 + k + m * (k + 3)).div_ceil(m) * m);
        }
        match &self.config.backbone {
            crate::model::config::Backbone::Resnet {
                blocks, ra_after, ..
            } => {
                let ra = if self.config.arch == Arch::Ra {
                    ra_after.len() * 2 * self.config.frames
                } else {
                    0
                };
                let backbone = 1 + 2 * blocks + ra - given;
                Some(match self.config.arch {
                    Arch::Ra | Arch::Spatial => backbone + 1 + k,
                    Arch::Tkpcn => backbone + 3 + k + k,
                })
            }
            crate::model::config::Backbone::Unet { .. } => None,
        }
    }

    /// Forward FLOPs of predicting kernels for one `h × w` window and applying them to
    /// `channels` channels (multiply-adds count 2), counted from the network's own layers, so
    /// the count follows whatever the network is.
    pub fn forward_flops(&self, h: usize, w: usize, channels: usize) -> f64 {
        let px = h * w;
        let t = self.config.frames;
        let k2 = self.config.kernel_size * self.config.kernel_size;
        // a k×k×frames kernel applied to every channel of every pixel
        let apply = |frames: usize| 2.0 * (frames * k2 * channels * px) as f64;
        match &self.net {
            Network::Ra(n) => {
                let scale_px = |s: usize| (h >> s) * (w >> s);
                let coarse: f64 = (1..self.config.scales())
                    .map(|s| {
                        let p = scale_px(s);
                        t as f64 * conv_flops(&n.coarse_heads[s - 1], p)
                            + conv_flops(&n.blend_heads[s - 1], scale_px(s - 1))
                            + 2.0 * (t * k2 * channels * p) as f64
                    })
                    .sum();
                n.backbone.flops(h, w, t) + t as f64 * conv_flops(&n.head, px) + apply(t) + coarse
            }
            Network::Spatial(n) => n.backbone.flops(h, w, 1) + conv_flops(&n.head, px) + apply(1),
            Network::Tkpcn(n) => {
                n.backbone.flops(h, w, t)
                    + t as f64 * conv_flops(&n.spatial_head, px)
                    + conv_flops(&n.temporal_a, px)
                    + conv_flops(&n.temporal_b, px)
                    + conv_flops(&n.temporal_head, px)
                    + t as f64 * apply(1)
                    + apply(t)
            }
        }
    }

    /// The grid tiles must start on and their sizes be multiples of, so that a tiled result
    /// equals the whole frame's: 2^(scales − 1) (1 for single-scale kernels).
    pub fn tile_grid(&self) -> usize {
        1 << (self.config.scales() - 1)
    }

    /// The multiple that tile sizes must have.
    pub fn size_multiple(&self) -> usize {
        match &self.net {
            Network::Ra(n) => n.backbone.size_multiple(),
            Network::Tkpcn(n) => n.backbone.size_multiple(),
            Network::Spatial(n) => n.backbone.size_multiple(),
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

    /// Channels of a frame-local network's stem features (0 for any other network).
    pub fn stem_channels(&self) -> usize {
        match (&self.net, self.config.frame_local_stem) {
            (Network::Ra(n), true) => n.backbone.resnet().map_or(0, |r| r.width()),
            _ => 0,
        }
    }

    /// The radius in pixels of what one of a frame-local network's stem features reads.
    pub fn stem_radius(&self) -> usize {
        match &self.net {
            Network::Ra(n) => n.backbone.resnet().map_or(0, |r| r.stem_radius()),
            _ => 0,
        }
    }

    /// Predicts kernels for windows `[B, T, C, H, W]` (`C` = [`NetConfig::input_channels`],
    /// made by [`crate::infer::input::network_features`]) with threshold `t`.
    pub fn predict(&self, input: Tensor<5>, t: f32) -> Prediction {
        self.predict_guided(input, t).0
    }

    /// [`Denoiser::predict`], and for a guided network the weights of its guide blend and of its
    /// learned guide mix.
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

    /// β of the guide blend and `w` of the learned guide mix from per-frame features
    /// `[B·T, C, H', W']` (cropped to `h × w`), where the network has them.
    fn guide_weights(
        &self,
        n: &RaNet,
        feats: &Tensor<4>,
        b: usize,
        h: usize,
        w: usize,
    ) -> GuideWeights {
        let [bt, fc, hp, wp] = feats.dims();
        let blend = n.guide_heads.first().map(|head| {
            let beta = sigmoid(conv2d(head, feats.clone(), false));
            let beta = beta.slice([0..bt, 0..1, 0..h, 0..w]);
            beta.reshape([b, bt / b, 1, h, w])
        });
        let centre = || {
            let frames = bt / b;
            feats
                .clone()
                .reshape([b, frames, fc, hp, wp])
                .narrow(1, frames / 2, 1)
                .reshape([b, fc, hp, wp])
        };
        let reads_result = self.config.guide_mix_reads_result;
        let mix = n
            .mix_heads
            .first()
            .filter(|_| !reads_result)
            .map(|head| sigmoid(conv2d(head, centre(), false)).slice([0..b, 0..1, 0..h, 0..w]));
        let mix_features = (reads_result && !n.mix_heads.is_empty())
            .then(|| centre().slice([0..b, 0..fc, 0..h, 0..w]));
        GuideWeights {
            blend,
            mix,
            mix_features,
        }
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

/// The frame-local channels ([`InputConfig::frame_channels`]) of frames `[n, C, H, W]`.
fn frame_channels(x: Tensor<4>, inputs: &InputConfig) -> Tensor<4> {
    let parts: Vec<Tensor<4>> = inputs
        .frame_channels()
        .into_iter()
        .map(|r| x.clone().narrow(1, r.start, r.len()))
        .collect();
    Tensor::cat(parts, 1)
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
mod tests {
    use super::*;
    use crate::model::config::INPUT_CHANNELS;
    use burn::tensor::TensorData;

    #[test]
    fn flop_counts_come_from_the_layers_the_network_has() {
        let device = Device::flex();
        let small = NetConfig::preset("small").unwrap();
        let d = Denoiser::new(small.clone(), &device);
        let f = d.forward_flops(32, 32, 3);
        // the ResNet by hand: input conv, 2 convs per block, RA predictors, head, application
        let crate::model::config::Backbone::Resnet {
            blocks,
            width,
            ra_after,
            skips_from,
        } = &small.backbone
        else {
            panic!("small is a ResNet")
        };
        let px = 32.0 * 32.0;
        let conv = |cin: usize, cout: usize| 2.0 * (cin * cout * 9) as f64 * px;
        let (t, k2) = (
            small.frames as f64,
            (small.kernel_size * small.kernel_size) as f64,
        );
        let hidden = (width / 2).max(8);
        let by_hand = t
            * (conv(INPUT_CHANNELS, *width)
                + *blocks as f64 * 2.0 * conv(*width, *width)
                + ra_after.len() as f64 * (2.0 * conv(*width, hidden) + conv(hidden, 1))
                + conv(width * (1 + skips_from.len()), k2 as usize))
            + 2.0 * t * k2 * 3.0 * px;
        assert!((f - by_hand).abs() < 1e-6 * by_hand, "{f} vs {by_hand}");
        // it follows the network: area scales it, one more block adds its two convolutions
        assert!((d.forward_flops(64, 32, 3) - 2.0 * f).abs() < 1e-6 * f);
        let mut deeper = small.clone();
        if let crate::model::config::Backbone::Resnet { blocks, .. } = &mut deeper.backbone {
            *blocks += 1;
        }
        let g = Denoiser::new(deeper, &device).forward_flops(32, 32, 3);
        assert!((g - f - t * 2.0 * conv(*width, *width)).abs() < 1e-6 * f);
        // a UNet's coarse scales cost a quarter per level
        let unet = Denoiser::new(NetConfig::preset("unet").unwrap(), &device);
        let (a, b) = (unet.forward_flops(32, 32, 3), unet.forward_flops(64, 64, 3));
        assert!((b / a - 4.0).abs() < 0.05, "{a} {b}");
    }

    fn window(b: usize, t: usize, h: usize, w: usize, device: &Device) -> Tensor<5> {
        let n = b * t * INPUT_CHANNELS * h * w;
        Tensor::from_data(
            TensorData::new(
                (0..n)
                    .map(|i| ((i * 2654435761usize) % 1000) as f32 / 1000.0)
                    .collect::<Vec<f32>>(),
                [b, t, INPUT_CHANNELS, h, w],
            ),
            device,
        )
    }

    #[test]
    fn shapes_for_five_and_three_frames_and_every_family() {
        let device = Device::flex();
        for name in ["small", "unet", "unet-ms", "tkpcn", "spatial"] {
            for frames in [5usize, 3] {
                let mut cfg = NetConfig::preset(name).unwrap();
                cfg.frames = frames;
                let d = Denoiser::new(cfg.clone(), &device);
                let (h, w) = (16, 20);
                let p = d.predict(window(2, frames, h, w, &device), cfg.default_threshold());
                let values = Tensor::<5>::from_data(
                    TensorData::new(vec![1.0f32; 2 * frames * 3 * h * w], [2, frames, 3, h, w]),
                    &device,
                );
                let out = p.apply(values);
                assert_eq!(out.dims(), [2, 3, h, w], "{name} T={frames}");
                let mass = p.frame_mass(frames);
                assert_eq!(mass.dims(), [2, frames, h, w]);
                // the box-initialised kernels sum to 1 per pixel: a constant image stays constant
                // (away from the zero-padded border)
                let v = out.to_data().try_to_vec::<f32>().unwrap();
                let centre = v[(h / 2) * w + w / 2];
                assert!((centre - 1.0).abs() < 1e-4, "{name} T={frames}: {centre}");
            }
        }
    }

    #[test]
    fn a_multi_scale_network_with_no_blend_weight_is_exactly_its_single_scale_network() {
        let device = Device::flex();
        let single = Denoiser::new(NetConfig::preset("small").unwrap(), &device);
        let multi = single.clone().with_kernel_scales(3, &device).unwrap();
        assert_eq!(multi.config.scales(), 3);
        let (h, w) = (16, 20);
        let x = window(1, 5, h, w, &device);
        let t = single.config.default_threshold();
        let values = Tensor::<5>::from_data(
            TensorData::new(
                (0..5 * 3 * h * w)
                    .map(|i| ((i * 7919) % 113) as f32 / 50.0)
                    .collect::<Vec<f32>>(),
                [1, 5, 3, h, w],
            ),
            &device,
        );
        let want = single.predict(x.clone(), t).apply(values.clone());
        let Prediction::MultiScale(mut m) = multi.predict(x, t) else {
            panic!("three scales predict multi-scale kernels")
        };
        assert_eq!(m.scales.len(), 3);
        assert_eq!(m.scales[2].weights.dims(), [1, 5 * 25, h / 4, w / 4]);
        let blended = m.apply(values.clone());
        m.blend = m.blend.iter().map(|a| a.clone().zeros_like()).collect();
        let got = m.apply(values);
        assert_eq!(
            got.to_data().try_to_vec::<f32>().unwrap(),
            want.to_data().try_to_vec::<f32>().unwrap()
        );
        // the grown network's blend starts small but not at zero: the coarse scales take part
        let diff: f32 = (blended - got).abs().max().into_scalar();
        assert!(diff > 0.0, "{diff}");
    }

    #[test]
    fn a_network_grown_to_read_the_noise_estimate_first_computes_what_it_did() {
        let device = Device::flex();
        let (h, w) = (8, 12);
        for preset in ["small", "unet"] {
            let old = Denoiser::new(NetConfig::preset(preset).unwrap(), &device);
            let inputs = InputConfig {
                exposure: false,
                noise: true,
                guide: false,
            };
            let grown = old.clone().with_inputs(inputs, &device);
            assert_eq!(grown.config.input_channels(), INPUT_CHANNELS + 1);
            let x = window(1, 5, h, w, &device);
            // any noise channel: its weights start at zero
            let noise = Tensor::<5>::ones([1, 5, 1, h, w], &device) * 0.3;
            let x_grown = Tensor::cat(vec![x.clone(), noise], 2);
            let values = Tensor::<5>::ones([1, 5, 3, h, w], &device) + x.clone().narrow(2, 0, 3);
            let t = old.config.default_threshold();
            let want = old.predict(x, t).apply(values.clone());
            let got = grown.predict(x_grown, t).apply(values);
            assert_eq!(
                got.to_data().try_to_vec::<f32>().unwrap(),
                want.to_data().try_to_vec::<f32>().unwrap(),
                "{preset}"
            );
            // and back: dropping the channel gives the old network
            let back = grown.with_inputs(InputConfig::default(), &device);
            assert_eq!(back.config, old.config);
        }
        // a fine-tune grows a network on the training (autodiff) device
        let train = Device::flex().autodiff();
        let grown = Denoiser::new(NetConfig::preset("small").unwrap(), &train).with_inputs(
            InputConfig {
                exposure: true,
                noise: true,
                guide: false,
            },
            &train,
        );
        grown.materialize();
    }

    #[test]
    fn a_unet_places_ra_blocks_at_the_scales_it_names() {
        let device = Device::flex();
        let all = NetConfig::preset("unet").unwrap();
        let mut coarse = all.clone();
        coarse.backbone = crate::model::config::Backbone::Unet {
            widths: vec![32, 48, 64],
            ra_scales: Some(vec![1, 2]),
        };
        coarse.validate().unwrap();
        let (a, c) = (
            Denoiser::new(all, &device),
            Denoiser::new(coarse.clone(), &device),
        );
        assert_eq!(a.ra_blocks().len(), 3);
        assert_eq!(c.ra_blocks().len(), 2);
        // the full-resolution RA block is the one left out: its cost is gone
        let full_ra = a.ra_blocks()[0].flops(64 * 64);
        let saved = a.forward_flops(64, 64, 3) - c.forward_flops(64, 64, 3);
        assert!(
            (saved - full_ra).abs() < 1e-6 * full_ra,
            "{saved} vs {full_ra}"
        );
        let names: Vec<String> = c.layer_weights().into_iter().map(|(n, _)| n).collect();
        assert!(
            names.iter().any(|n| n.starts_with("backbone.ra1")),
            "{names:?}"
        );
        assert!(
            !names.iter().any(|n| n.starts_with("backbone.ra0")),
            "{names:?}"
        );
        let out = c
            .predict(window(1, 5, 8, 8, &device), 0.004)
            .apply(Tensor::ones([1, 5, 3, 8, 8], &device));
        assert_eq!(out.dims(), [1, 3, 8, 8]);
        // scales must exist and increase
        for bad in [vec![3], vec![2, 1]] {
            coarse.backbone = crate::model::config::Backbone::Unet {
                widths: vec![32, 48, 64],
                ra_scales: Some(bad),
            };
            assert!(coarse.validate().is_err());
        }
    }

    #[test]
    fn paper_preset_parameter_count() {
        let d = Denoiser::new(NetConfig::preset("paper").unwrap(), &Device::flex());
        // 24 residual blocks of two 80→80 3×3 convs, 6 RA blocks, input conv, head over
        // 80·(1 + 4 skips) channels: see docs/benchmarks.md for the breakdown
        let n = d.num_params();
        assert!(n > 3_000_000 && n < 4_000_000, "{n}");
    }
}
