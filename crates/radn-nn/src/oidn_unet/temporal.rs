//! The paper's conversion of a spatial network into a spatio-temporal one (§3), applied to
//! OIDN's U-Net: every frame of a window goes through the U-Net's encoder once; at the levels
//! the configuration names, the window's features are warped to the centre frame
//! ([`feature_warp`](super::feature_warp)) and a Robust Average block
//! ([`RobustAverage`]) blends them; the decoder then runs once, on the centre frame's blended
//! levels. Each blend enters through a per-channel gate that starts at zero, so the converted
//! network, before training, is exactly the per-frame U-Net on the centre frame, and
//! training starts from OIDN's quality.

use burn::module::{Module, Param};
use burn::tensor::{Device, Tensor};
use serde::{Deserialize, Serialize};

use radn_core::post::stabilize::StabilizeSettings;

use crate::model::ra_block::RobustAverage;
use crate::oidn_unet::config::Input;
use crate::oidn_unet::feature_warp::{to_centre, WindowMotion};
use crate::oidn_unet::input_blend::InputBlend;
use crate::oidn_unet::{EncoderLevels, OidnUnet};

/// Where the converted network blends its window: the window's length and the encoder levels
/// (0: the processed input, k: 1/2^k, the last: the bottleneck) that get a Robust Average block.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TemporalConfig {
    /// Frames per window (odd; the paper's 5).
    pub frames: usize,
    /// Encoder levels with a Robust Average block, in increasing order.
    pub levels: Vec<usize>,
    /// Tolerance of alignment's colour term for the windows the network runs on at inference
    /// ([`radn_core::align::confidence::ConfidenceParams::color`]): the motion vectors follow
    /// surfaces, so only the colour shows a shading change (a moving light or shadow) that the
    /// blocks would otherwise average in; `None` leaves the term out.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color_confidence: Option<f32>,
    /// Where the window is moved onto its centre frame at inference.
    #[serde(default)]
    pub warp: WarpSpace,
    /// Which albedo and normal the U-Net reads.
    #[serde(default, skip_serializing_if = "AuxSource::is_rendered")]
    pub aux: AuxSource,
    /// Frames of the aligned window (odd, centred) whose colour is averaged into the centre
    /// frame's input before the encoder ([`input_mean`](super::input_mean)); 1: the centre
    /// as rendered. Applied at inference; the blocks train on windows as rendered.
    #[serde(default = "one_frame", skip_serializing_if = "is_one_frame")]
    pub input_frames: usize,
    /// The temporal pass over the network's results (each frame's result averaged with its
    /// aligned neighbours' where they agree within its render noise); `None`: off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stabilize: Option<StabilizeSettings>,
    /// A learned average of the window's input at the centre frame ([`InputBlend`]) in place
    /// of the fixed mean of [`TemporalConfig::input_frames`]; trained with the blocks.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub input_blend: bool,
}

/// [`TemporalConfig::input_frames`] of model files that do not name it: the centre alone.
fn one_frame() -> usize {
    1
}

/// Whether `n` is [`one_frame`] (left out of model files).
fn is_one_frame(n: &usize) -> bool {
    *n == 1
}

/// The albedo and normal a converted network reads with each frame of its window.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AuxSource {
    /// Each frame's auxiliaries as rendered (what OIDN's noisy-auxiliary weights expect).
    #[default]
    Rendered,
    /// Each frame's auxiliaries cleaned first by OIDN's standard albedo and normal prefilters
    /// (`rt_alb`, `rt_nrm`), what the clean-auxiliary weights (`calb_cnrm`) expect: within
    /// 0.1 dB of OIDN's large prefilters at well under half their cost.
    Prefiltered,
}

impl AuxSource {
    /// True for [`AuxSource::Rendered`] (the default, left out of model files).
    pub fn is_rendered(&self) -> bool {
        *self == AuxSource::Rendered
    }
}

/// Where a converted network's window is moved onto its centre frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WarpSpace {
    /// The frames are aligned as images (radn's alignment with confidence and centre mixing)
    /// and every aligned frame goes through the encoder: what the training tiles hold.
    #[default]
    Images,
    /// Each frame goes through the encoder as rendered and its levels are warped to the centre
    /// by the same motion and confidence (the paper's pre-warping per level).
    Features,
}

impl TemporalConfig {
    /// The configuration as TOML (what model files keep).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a temporal configuration serialises")
    }
}

/// One level's temporal blend: a Robust Average block over the window's warped features and
/// the per-channel gate through which its result enters the centre frame's.
#[derive(Module, Debug)]
pub struct LevelBlend {
    ra: RobustAverage,
    gate: Param<Tensor<1>>,
}

impl LevelBlend {
    /// A blend of `channels` features over `frames` frames, closed (the identity).
    pub fn new(channels: usize, frames: usize, device: &Device) -> Self {
        Self {
            ra: RobustAverage::new(channels, frames, device),
            gate: Param::from_tensor(Tensor::zeros([channels], device)),
        }
    }

    /// The centre frame's features (`[batch, c, h, w]`) with the block's result over the
    /// window's `warped` features (`[batch · frames, c, h, w]`) let in through the gate.
    fn forward(&self, centre: Tensor<4>, warped: Tensor<4>, frames: usize) -> Tensor<4> {
        let [bt, c, h, w] = warped.dims();
        let averaged: Tensor<4> = self
            .ra
            .forward(warped)
            .reshape([bt / frames, frames, c, h, w])
            .narrow(1, frames / 2, 1)
            .reshape([bt / frames, c, h, w]);
        let gate = self.gate.val().reshape([1, c, 1, 1]);
        centre.clone() + (averaged - centre) * gate
    }
}

/// The trainable temporal layers: one blend per configured level, and the learned input
/// average where the configuration asks for it.
#[derive(Module, Debug)]
pub struct TemporalLayers {
    blends: Vec<LevelBlend>,
    input: Option<InputBlend>,
}

impl TemporalLayers {
    /// How open each blend's gate is: the mean absolute gate over its channels (0: closed,
    /// the per-frame U-Net at that level).
    pub fn openness(&self) -> Vec<f32> {
        self.blends
            .iter()
            .map(|b| b.gate.val().abs().mean().into_scalar::<f32>())
            .collect()
    }

    /// How open the learned input average's gate is, where there is one.
    pub fn input_openness(&self) -> Option<f32> {
        self.input.as_ref().map(InputBlend::openness)
    }
}

/// OIDN's U-Net converted into a spatio-temporal network.
#[derive(Module, Debug)]
pub struct TemporalUnet {
    /// The U-Net (its encoder runs per frame, its decoder per window).
    pub unet: OidnUnet,
    /// The temporal blends.
    pub temporal: TemporalLayers,
    #[module(skip)]
    config: TemporalConfig,
}

/// What is wrong with a temporal configuration for a U-Net.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TemporalError {
    /// The window is not odd and at least 3 frames long.
    #[error("a window of {0} frames: it must be odd and at least 3")]
    Frames(usize),
    /// A level the encoder does not have, or levels out of order.
    #[error("levels {levels:?}: the encoder has levels 0 to {last}, each named once in order")]
    Levels {
        /// The levels asked for.
        levels: Vec<usize>,
        /// The encoder's deepest level.
        last: usize,
    },
    /// A learned input average on a network whose input is not an HDR beauty.
    #[error("a learned input average blends HDR colour, and {0} does not read an HDR beauty")]
    InputBlendNotHdr(String),
    /// Both a fixed input mean and a learned input average.
    #[error("an input mean over {0} frames and a learned input average: choose one")]
    TwoInputAverages(usize),
    /// The input mean's frames are not odd or not within the window.
    #[error("an input mean over {input} frames: it must be odd and at most the window's {frames}")]
    InputFrames {
        /// The frames asked for.
        input: usize,
        /// The window's length.
        frames: usize,
    },
}

impl TemporalUnet {
    /// Converts `unet`: a closed blend at each of `config.levels`, so that the result equals
    /// the per-frame U-Net on the centre frame until training opens them.
    pub fn convert(
        unet: OidnUnet,
        config: TemporalConfig,
        device: &Device,
    ) -> Result<Self, TemporalError> {
        if config.frames < 3 || config.frames.is_multiple_of(2) {
            return Err(TemporalError::Frames(config.frames));
        }
        if config.input_frames.is_multiple_of(2) || config.input_frames > config.frames {
            return Err(TemporalError::InputFrames {
                input: config.input_frames,
                frames: config.frames,
            });
        }
        if config.input_blend && config.input_frames > 1 {
            return Err(TemporalError::TwoInputAverages(config.input_frames));
        }
        if config.input_blend && !matches!(unet.config().input, Input::Beauty { hdr: true, .. }) {
            return Err(TemporalError::InputBlendNotHdr(
                unet.config().weights.clone(),
            ));
        }
        let channels = unet.level_channels();
        let last = channels.len() - 1;
        if config.levels.iter().any(|&l| l > last) || !config.levels.windows(2).all(|p| p[0] < p[1])
        {
            return Err(TemporalError::Levels {
                levels: config.levels.clone(),
                last,
            });
        }
        let blends = config
            .levels
            .iter()
            .map(|&l| LevelBlend::new(channels[l], config.frames, device))
            .collect();
        let input = config
            .input_blend
            .then(|| InputBlend::new(channels[0], device));
        Ok(Self {
            unet,
            temporal: TemporalLayers { blends, input },
            config,
        })
    }

    /// The network with every gate set to `value` (a converted network whose blocks count
    /// before any training, for tests of the paths that run it).
    pub fn with_gates(mut self, value: f32) -> Self {
        for b in &mut self.temporal.blends {
            let device = b.gate.val().device();
            let c = b.gate.val().dims()[0];
            b.gate = Param::from_tensor(Tensor::full([c], value, &device));
        }
        self.temporal.input = self.temporal.input.map(|i| i.with_gate(value));
        self
    }

    /// The learned input average, where the configuration has one.
    pub fn input_blend(&self) -> Option<&InputBlend> {
        self.temporal.input.as_ref()
    }

    /// Each blended level with its block and its gate's values (for the CPU path).
    pub fn blends(&self) -> Vec<(usize, &RobustAverage, Vec<f32>)> {
        self.config
            .levels
            .iter()
            .zip(&self.temporal.blends)
            .map(|(&l, b)| {
                let gate = b
                    .gate
                    .val()
                    .into_data()
                    .try_to_vec::<f32>()
                    .expect("f32 gates");
                (l, &b.ra, gate)
            })
            .collect()
    }

    /// Where the network blends its window.
    pub fn config(&self) -> &TemporalConfig {
        &self.config
    }

    /// The per-frame encoder on processed frames `[n, channels, h, w]` (sides multiples of 16).
    pub fn encode(&self, frames: Tensor<4>) -> EncoderLevels {
        self.unet.encode(frames)
    }

    /// A window's encoder levels (`[batch · frames, …]`, frames consecutive within each batch
    /// item) blended into its centre frame's (`[batch, …]`), each configured level's features
    /// first warped to the centre by `motion` (already aligned windows: `None`).
    pub fn blend(&self, levels: EncoderLevels, motion: Option<&WindowMotion>) -> EncoderLevels {
        let t = self.config.frames;
        let mut blends = self
            .config
            .levels
            .iter()
            .zip(&self.temporal.blends)
            .peekable();
        let out = levels
            .0
            .into_iter()
            .enumerate()
            .map(|(l, f)| {
                let [bt, c, h, w] = f.dims();
                let centre: Tensor<4> = f
                    .clone()
                    .reshape([bt / t, t, c, h, w])
                    .narrow(1, t / 2, 1)
                    .reshape([bt / t, c, h, w]);
                match blends.next_if(|(&level, _)| level == l) {
                    Some((_, blend)) => {
                        let warped = match motion {
                            Some(m) => to_centre(f, t, &m.at_level(l)),
                            None => f,
                        };
                        blend.forward(centre, warped, t)
                    }
                    None => centre,
                }
            })
            .collect();
        EncoderLevels(out)
    }

    /// The network on a window of processed frames `[batch · frames, channels, h, w]`: the
    /// centre frame's output `[batch, 3, h, w]` before OIDN's output processing.
    pub fn forward(&self, window: Tensor<4>, motion: Option<&WindowMotion>) -> Tensor<4> {
        let window = match &self.temporal.input {
            Some(input) => input.forward(window, self.config.frames),
            None => window,
        };
        self.unet.decode(self.blend(self.encode(window), motion))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::TensorData;

    /// OIDN's standard U-Net with its trained weights (shipped in `models/`).
    fn unet(device: &Device) -> OidnUnet {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../models/oidn-rt_hdr_alb_nrm.safetensors");
        crate::oidn_unet::store::load(&path, device).unwrap()
    }

    fn window(t: usize, h: usize, w: usize, device: &Device) -> Tensor<4> {
        let n = t * 9 * h * w;
        Tensor::from_data(
            TensorData::new(
                (0..n)
                    .map(|i| ((i * 7919) % 997) as f32 / 997.0)
                    .collect::<Vec<_>>(),
                [t, 9, h, w],
            ),
            device,
        )
    }

    #[test]
    fn the_converted_network_is_the_per_frame_unet_until_its_gates_open() {
        for input_blend in [false, true] {
            is_the_per_frame_unet_until_its_gates_open(input_blend);
        }
    }

    fn is_the_per_frame_unet_until_its_gates_open(input_blend: bool) {
        let device = Device::flex();
        let (t, h, w) = (5, 32, 48);
        let x = window(t, h, w, &device);
        let centre = x.clone().narrow(0, t / 2, 1);
        let net = TemporalUnet::convert(
            unet(&device),
            TemporalConfig {
                frames: t,
                levels: vec![1, 2, 3, 4],
                color_confidence: None,
                warp: Default::default(),
                aux: Default::default(),
                input_frames: 1,
                stabilize: None,
                input_blend,
            },
            &device,
        )
        .unwrap();
        let want = net
            .unet
            .forward(centre)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        // with motion: warping moves the side frames, and still nothing passes a closed gate
        let motion = WindowMotion {
            offsets: Tensor::full([t, 2, h, w], 1.25, &device),
            confidence: Tensor::full([t, 1, h, w], 0.8, &device),
        };
        for m in [None, Some(&motion)] {
            let got = net
                .forward(x.clone(), m)
                .into_data()
                .try_to_vec::<f32>()
                .unwrap();
            assert_eq!(got, want, "motion {:?}", m.is_some());
        }
        // open gates change the result (the input average's alone, where there is one)
        let mut open = net;
        if input_blend {
            let only_input = TemporalUnet {
                unet: open.unet.clone(),
                temporal: TemporalLayers {
                    blends: open.temporal.blends.clone(),
                    input: open.temporal.input.clone().map(|i| i.with_gate(0.5)),
                },
                config: open.config.clone(),
            };
            let got = only_input.forward(x.clone(), None).into_data();
            let diff = got
                .try_to_vec::<f32>()
                .unwrap()
                .iter()
                .zip(&want)
                .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
            assert!(
                diff > 1e-4,
                "the open input average changed nothing ({diff})"
            );
        }
        for b in &mut open.temporal.blends {
            let c = b.gate.dims()[0];
            b.gate = Param::from_tensor(Tensor::full([c], 0.5, &device));
        }
        let moved = open
            .forward(x, Some(&motion))
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        let diff = moved
            .iter()
            .zip(&want)
            .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(diff > 1e-4, "{diff}");
    }

    #[test]
    fn bad_configurations_are_refused() {
        let device = Device::flex();
        let bad_mean = |frames, levels: Vec<usize>, input_frames| {
            TemporalUnet::convert(
                unet(&device),
                TemporalConfig {
                    frames,
                    levels,
                    color_confidence: None,
                    warp: Default::default(),
                    aux: Default::default(),
                    input_frames,
                    stabilize: None,
                    input_blend: false,
                },
                &device,
            )
            .unwrap_err()
            .to_string()
        };
        let bad = |frames, levels| bad_mean(frames, levels, 1);
        assert!(bad(4, vec![1]).contains("odd"));
        assert!(bad_mean(5, vec![1], 2).contains("input mean over 2 frames"));
        assert!(bad_mean(3, vec![1], 5).contains("at most the window's 3"));
        assert!(bad(5, vec![5]).contains("levels 0 to 4"));
        assert!(bad(5, vec![2, 1]).contains("in order"));
        let both = TemporalUnet::convert(
            unet(&device),
            TemporalConfig {
                input_blend: true,
                ..toml::from_str("frames = 5\nlevels = [1]\ninput_frames = 3\n").unwrap()
            },
            &device,
        )
        .unwrap_err()
        .to_string();
        assert!(both.contains("choose one"), "{both}");
        // model files written before the field existed read as rendered auxiliaries
        let old: TemporalConfig = toml::from_str("frames = 5\nlevels = [1]\n").unwrap();
        assert_eq!(old.aux, AuxSource::Rendered);
        assert_eq!(old.input_frames, 1);
        assert!(!old.to_toml().contains("input_frames"));
        let cleaned = TemporalConfig {
            aux: AuxSource::Prefiltered,
            input_frames: 3,
            stabilize: None,
            ..old
        };
        assert_eq!(
            toml::from_str::<TemporalConfig>(&cleaned.to_toml()).unwrap(),
            cleaned
        );
    }

    #[cfg(feature = "autodiff")]
    #[test]
    fn the_gates_get_a_gradient_at_the_identity() {
        // the gates start at zero, where the blocks' own weights get no gradient; the gates'
        // gradient is the blocks' result against the centre's, so training opens them
        let device = Device::flex().autodiff();
        let (t, h, w) = (3, 32, 32);
        let x = window(t, h, w, &device);
        let net = TemporalUnet::convert(
            unet(&device),
            TemporalConfig {
                frames: t,
                levels: vec![2, 4],
                color_confidence: None,
                warp: Default::default(),
                aux: Default::default(),
                input_frames: 1,
                stabilize: None,
                input_blend: true,
            },
            &device,
        )
        .unwrap();
        let target = x.clone().narrow(0, 0, 1).narrow(1, 0, 3);
        let loss = (net.forward(x, None) - target).powi_scalar(2).mean();
        let grads = loss.backward();
        for b in &net.temporal.blends {
            let g = b.gate.val().grad(&grads).expect("the gate is trained");
            let g = g.into_data().try_to_vec::<f32>().unwrap();
            assert!(g.iter().any(|v| v.abs() > 1e-9), "{g:?}");
        }
        let input = net.temporal.input.as_ref().expect("an input average");
        let g = input
            .gate
            .val()
            .grad(&grads)
            .expect("the input gate is trained");
        let g = g.into_data().try_to_vec::<f32>().unwrap();
        assert!(g[0].abs() > 1e-9, "{g:?}");
    }
}
