//! OIDN's pretrained U-Net as a radn network: imported from an OIDN 2.x library's weights
//! ([`library`], [`tza`], [`import`]), described by its [`config`], saved in radn model files
//! ([`store`]), and run two ways from one layer list: through burn ([`OidnUnet::forward`], so it
//! can be trained and built for CUDA) and on radn's CPU kernels ([`filter`], with OIDN's input
//! and output processing in [`transfer`]).

pub mod config;
pub mod cpu;
pub mod denoiser;
pub mod feature_warp;
pub mod filter;
pub mod guide_filters;
pub mod import;
pub mod input_blend;
pub mod input_mean;
pub mod library;
pub mod prefilter;
pub mod store;
pub mod temporal;
pub mod temporal_filter;
pub mod temporal_store;
pub mod transfer;
pub mod tza;
pub mod window_denoiser;

use burn::module::{Module, Param};
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::PaddingConfig2d;
use burn::tensor::activation::relu;
use burn::tensor::module::{interpolate, max_pool2d};
use burn::tensor::ops::{InterpolateMode, InterpolateOptions, MaxPoolOptions};
use burn::tensor::{Device, Tensor, TensorData};

use config::{After, Skip, UnetConfig};

/// The U-Net's trainable layers: one 3×3 convolution per step of its layer list.
#[derive(Module, Debug)]
pub struct UnetLayers {
    convs: Vec<Conv2d>,
}

impl UnetLayers {
    /// The layers with the first `steps` convolutions not trained (a fine-tune that keeps
    /// the encoder as OIDN trained it).
    pub fn frozen_below(mut self, steps: usize) -> Self {
        for conv in self.convs.iter_mut().take(steps) {
            *conv = conv.clone().no_grad();
        }
        self
    }
}

/// An imported OIDN U-Net: its configuration and its layers.
#[derive(Module, Debug)]
pub struct OidnUnet {
    #[module(skip)]
    config: UnetConfig,
    /// The layers (burn parameters).
    pub layers: UnetLayers,
}

impl OidnUnet {
    /// A network of `config`'s shape with burn's initial weights (to be loaded or trained).
    pub fn new(config: UnetConfig, device: &Device) -> Self {
        let convs = config
            .convs
            .iter()
            .map(|c| {
                Conv2dConfig::new([c.cin, c.cout], [3, 3])
                    .with_padding(PaddingConfig2d::Same)
                    .init(device)
            })
            .collect();
        Self {
            config,
            layers: UnetLayers { convs },
        }
    }

    /// A network of `config`'s shape with the given weights (`oihw`) and biases, in step order.
    pub fn from_weights(
        config: UnetConfig,
        weights: &[(Vec<f32>, Vec<f32>)],
        device: &Device,
    ) -> Self {
        assert_eq!(weights.len(), config.convs.len());
        let convs = config
            .convs
            .iter()
            .zip(weights)
            .map(|(c, (w, b))| {
                let mut conv = Conv2dConfig::new([c.cin, c.cout], [3, 3])
                    .with_padding(PaddingConfig2d::Same)
                    .init(device);
                conv.weight = Param::from_tensor(Tensor::from_data(
                    TensorData::new(w.clone(), [c.cout, c.cin, 3, 3]),
                    device,
                ));
                conv.bias = Some(Param::from_tensor(Tensor::from_data(
                    TensorData::new(b.clone(), [c.cout]),
                    device,
                )));
                conv
            })
            .collect();
        Self {
            config,
            layers: UnetLayers { convs },
        }
    }

    /// The network's configuration.
    pub fn config(&self) -> &UnetConfig {
        &self.config
    }

    /// Every convolution's weights (`oihw`) and bias copied to the host, in step order.
    pub fn host_weights(&self) -> Vec<(Vec<f32>, Vec<f32>)> {
        self.layers
            .convs
            .iter()
            .map(|c| {
                let w = c
                    .weight
                    .val()
                    .into_data()
                    .try_to_vec::<f32>()
                    .expect("f32 weights");
                let b = c
                    .bias
                    .as_ref()
                    .map(|b| b.val().into_data().try_to_vec::<f32>().expect("f32 bias"))
                    .unwrap_or_else(|| vec![0.0; c.weight.dims()[0]]);
                (w, b)
            })
            .collect()
    }

    /// The network on processed inputs `[batch, channels, h, w]` (sides multiples of 16),
    /// through burn's operations: the output before OIDN's output processing.
    pub fn forward(&self, input: Tensor<4>) -> Tensor<4> {
        self.decode(self.encode(input))
    }

    /// Steps of the encoder: up to the first convolution whose output is upsampled (the
    /// bottleneck).
    pub fn encoder_steps(&self) -> usize {
        self.config.layers.encoder_steps()
    }

    /// Channels of each of [`OidnUnet::encode`]'s levels, finest first.
    pub fn level_channels(&self) -> Vec<usize> {
        let n = self.encoder_steps();
        let steps = &self.config.layers.steps()[..n];
        let mut channels = vec![self.config.input.channels()];
        for (step, conv) in steps.iter().zip(&self.config.convs) {
            if step.after == After::Pool {
                channels.push(conv.cout);
            }
        }
        channels.pop();
        channels.push(self.config.convs[n - 1].cout);
        channels
    }

    /// The encoder on processed inputs: what the decoder reads of one frame, at every scale.
    pub fn encode(&self, input: Tensor<4>) -> EncoderLevels {
        let n = self.encoder_steps();
        let mut levels = vec![input.clone()];
        let mut x = input;
        for (step, conv) in self.config.layers.steps()[..n]
            .iter()
            .zip(&self.layers.convs)
        {
            let y = relu(conv.forward(x));
            x = match step.after {
                After::Pool => {
                    let p = max_pool2d(y, MaxPoolOptions::new([2, 2]));
                    levels.push(p.clone());
                    p
                }
                After::Nothing | After::Upsample => y,
            };
        }
        // the last pooling feeds only the bottleneck; the bottleneck's output replaces it
        levels.pop();
        levels.push(x);
        EncoderLevels(levels)
    }

    /// The decoder on one frame's (or a window's mixed) encoder levels.
    pub fn decode(&self, levels: EncoderLevels) -> Tensor<4> {
        let n = self.encoder_steps();
        let mut levels = levels.0;
        let bottleneck = levels.pop().expect("the bottleneck level");
        let mut x = upsample(bottleneck);
        for (step, conv) in self.config.layers.steps()[n..]
            .iter()
            .zip(&self.layers.convs[n..])
        {
            let src = match step.skip {
                None => x,
                Some(Skip::Input) => Tensor::cat(vec![x, levels[0].clone()], 1),
                Some(Skip::Pool(k)) => Tensor::cat(vec![x, levels[k].clone()], 1),
            };
            let y = relu(conv.forward(src));
            x = match step.after {
                After::Nothing => y,
                After::Pool => unreachable!("the decoder does not pool"),
                After::Upsample => upsample(y),
            };
        }
        x
    }
}

/// What the U-Net's decoder reads of a frame, finest first: level 0 is the processed input
/// (full resolution), level k the k-th pooled encoder map (1/2^k), and the last the
/// bottleneck's output (1/16). Each is `[batch, channels, h, w]`.
#[derive(Clone, Debug)]
pub struct EncoderLevels(pub Vec<Tensor<4>>);

/// Nearest-neighbour upsampling by 2.
fn upsample(y: Tensor<4>) -> Tensor<4> {
    let [_, _, h, w] = y.dims();
    interpolate(
        y,
        InterpolateOptions::new(InterpolateMode::Nearest).with_output_size([2 * h, 2 * w]),
    )
}
