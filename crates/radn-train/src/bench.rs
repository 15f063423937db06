//! Training throughput: steps of a network, and of a bare 3×3 convolution stack of the same
//! width and depth measured the same way, so the cost of the RA blocks and of kernel
//! application shows. FLOP counts come from the networks' own layers.

use std::time::Instant;

use burn::module::Module;
use burn::nn::conv::Conv2d;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Distribution, Tensor};

use radn_nn::bench::{median, random_windows, StepTiming};
use radn_nn::model::config::NetConfig;
use radn_nn::model::layers::{conv3, conv_flops};
use radn_nn::model::Denoiser;

use crate::loss::smape;

/// Times training steps of a network on batches of random `tile × tile` windows. The target is
/// the centre frame's own colour: kernels that keep the centre pixel reach it exactly, so every
/// working step lowers the loss from the box filter the network starts as. (Against a random
/// target unrelated to the window, 5 steps at this learning rate moved the loss by ±1e-4 on a
/// CPU and on a GPU alike, and "the loss falls" was a coin toss.)
pub fn time_network(
    cfg: &NetConfig,
    tile: usize,
    batch: usize,
    steps: usize,
    device: &Device,
) -> StepTiming {
    let mut d = Denoiser::new(cfg.clone(), device);
    let (x, v) = random_windows(cfg, batch, tile, device);
    let y = v
        .clone()
        .narrow(1, cfg.frames / 2, 1)
        .reshape([batch, 3, tile, tile]);
    let mut optim = AdamConfig::new().init();
    let thr = cfg.default_threshold();
    let mut times = Vec::new();
    let mut losses = Vec::new();
    for i in 0..steps + 1 {
        let start = Instant::now();
        let loss = smape(d.predict(x.clone(), thr).apply(v.clone()), y.clone());
        losses.push(loss.clone().into_scalar::<f32>() as f64);
        let grads = GradientsParams::from_grads(loss.backward(), &d.net);
        d.net = optim.step(1e-4, d.net, grads);
        // a GPU runs asynchronously: the step is done when the device has finished it
        device
            .sync()
            .expect("the device failed during the training step");
        if i > 0 {
            times.push(start.elapsed().as_secs_f64() * 1e3); // first step warms up
        }
    }
    StepTiming {
        ms: median(times),
        forward_flops: batch as f64 * d.forward_flops(tile, tile, 3),
        losses,
    }
}

/// A bare stack of `convs` 3×3 convolutions at `width` channels.
#[derive(Module, Debug)]
struct Stack {
    convs: Vec<Conv2d>,
}

/// Times training steps of a bare conv stack on `frames` maps of `tile × tile`: the ceiling
/// the network's convolutions could reach.
pub fn time_conv_stack(
    width: usize,
    convs: usize,
    frames: usize,
    tile: usize,
    steps: usize,
    device: &Device,
) -> StepTiming {
    let mut s = Stack {
        convs: (0..convs).map(|_| conv3(width, width, device)).collect(),
    };
    let x = Tensor::<4>::random(
        [frames, width, tile, tile],
        Distribution::Uniform(0.0, 1.0),
        device,
    );
    let mut optim = AdamConfig::new().init();
    let mut times = Vec::new();
    for i in 0..steps + 1 {
        let start = Instant::now();
        let mut h = x.clone();
        for c in &s.convs {
            h = relu(c.forward(h));
        }
        let loss = h.mean();
        let grads = GradientsParams::from_grads(loss.backward(), &s);
        s = optim.step(1e-4, s, grads);
        device
            .sync()
            .expect("the device failed during the training step");
        if i > 0 {
            times.push(start.elapsed().as_secs_f64() * 1e3);
        }
    }
    let flops = frames as f64
        * s.convs
            .iter()
            .map(|c| conv_flops(c, tile * tile))
            .sum::<f64>();
    StepTiming {
        ms: median(times),
        forward_flops: flops,
        losses: Vec::new(),
    }
}
