//! OIDN's pretrained U-Net as a radn network: imported from an OIDN 2.x library's weights
//! ([`library`], [`tza`], [`import`]), described by its [`config`], saved in radn model files
//! ([`store`]), and run two ways from one layer list: through burn ([`OidnUnet::forward`], so it
//! can be trained and built for CUDA) and on radn's CPU kernels ([`filter`], with OIDN's input
//! and output processing in [`transfer`]).

pub mod config;
pub mod cpu;
pub mod denoiser;
pub mod filter;
pub mod import;
pub mod library;
pub mod store;
pub mod transfer;
pub mod tza;

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

/// An imported OIDN U-Net: its configuration and its layers.
#[derive(Debug)]
pub struct OidnUnet {
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
        let mut pools: Vec<Tensor<4>> = Vec::new();
        let mut x = input.clone();
        for (step, conv) in self.config.layers.steps().iter().zip(&self.layers.convs) {
            let src = match step.skip {
                None => x,
                Some(Skip::Input) => Tensor::cat(vec![x, input.clone()], 1),
                Some(Skip::Pool(n)) => Tensor::cat(vec![x, pools[n - 1].clone()], 1),
            };
            let y = relu(conv.forward(src));
            x = match step.after {
                After::Nothing => y,
                After::Pool => {
                    let p = max_pool2d(y, MaxPoolOptions::new([2, 2]));
                    pools.push(p.clone());
                    p
                }
                After::Upsample => {
                    let [_, _, h, w] = y.dims();
                    interpolate(
                        y,
                        InterpolateOptions::new(InterpolateMode::Nearest)
                            .with_output_size([2 * h, 2 * w]),
                    )
                }
            };
        }
        x
    }
}
