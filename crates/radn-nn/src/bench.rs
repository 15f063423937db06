//! Throughput of a network (training steps, and inference per tile) and of a bare 3×3
//! convolution stack of the same width and depth, measured the same way: how much the RA blocks
//! and kernel application cost. FLOP counts come from the networks' own layers.

use std::time::Instant;

use burn::module::Module;
use burn::nn::conv::Conv2d;
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Distribution, Tensor};

use crate::model::config::NetConfig;
use crate::model::cpu::conv::{conv_same_nchw_by, preferred_path, ConvPath};
use crate::model::layers::{conv3, conv_flops};
use crate::model::Denoiser;
use crate::train::loss::smape;

/// One measurement.
#[derive(Clone, Debug)]
pub struct StepTiming {
    /// Median milliseconds per step (forward + backward + Adam) on one batch.
    pub ms: f64,
    /// Forward FLOPs of the measured computation per batch (multiply-adds count 2).
    pub forward_flops: f64,
    /// Training only: the loss of every step on the same batch, the warm-up step first (so a
    /// falling sequence shows that the steps train, on whichever device ran them).
    pub losses: Vec<f64>,
}

impl StepTiming {
    /// Achieved GFLOP/s, counting a training step as 3× the forward FLOPs.
    pub fn gflops(&self) -> f64 {
        3.0 * self.forward_flops / (self.ms * 1e-3) / 1e9
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// A batch of random `tile × tile` windows: network inputs and the colour the kernels filter.
fn random_windows(
    cfg: &NetConfig,
    batch: usize,
    tile: usize,
    device: &Device,
) -> (Tensor<5>, Tensor<5>) {
    let random = |channels: usize| {
        Tensor::<5>::random(
            [batch, cfg.frames, channels, tile, tile],
            Distribution::Uniform(0.0, 1.0),
            device,
        )
    };
    (random(cfg.input_channels()), random(3))
}

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

/// Times inference (prediction and kernel application, no gradients) of a network on batches
/// of random `tile × tile` windows: what `radn denoise` spends per tile, and whether stacking
/// tiles into one call (batching) would pay on this machine. `forward_flops` is per batch.
pub fn time_inference(
    cfg: &NetConfig,
    tile: usize,
    batch: usize,
    repeats: usize,
    device: &Device,
) -> StepTiming {
    let d = Denoiser::new(cfg.clone(), device);
    d.materialize();
    let (x, v) = random_windows(cfg, batch, tile, device);
    let thr = cfg.default_threshold();
    let mut times = Vec::new();
    for i in 0..repeats + 1 {
        let start = Instant::now();
        let out = d.predict(x.clone(), thr).apply(v.clone());
        let _ = out.into_data(); // waits for the result
        if i > 0 {
            times.push(start.elapsed().as_secs_f64() * 1e3); // the first call warms up
        }
    }
    StepTiming {
        ms: median(times),
        forward_flops: batch as f64 * d.forward_flops(tile, tile, 3),
        losses: Vec::new(),
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

/// Inference throughput of one convolution shape, through radn's CPU path and through burn's.
#[derive(Clone, Debug)]
pub struct ConvTiming {
    /// Input channels.
    pub cin: usize,
    /// Output channels.
    pub cout: usize,
    /// Median milliseconds per call of radn's CPU convolution ([`crate::model::cpu::conv`]).
    pub radn_ms: f64,
    /// Median milliseconds per call of burn's own convolution on the same device.
    pub burn_ms: f64,
    /// Median milliseconds of the im2col + GEMM path alone, on host data
    /// ([`crate::model::cpu::conv::ConvPath::Gemm`]).
    pub gemm_ms: f64,
    /// Median milliseconds of the direct AVX2 path alone, on host data
    /// ([`crate::model::cpu::conv::ConvPath::Direct`]); `None` where the CPU lacks it.
    pub direct_ms: Option<f64>,
    /// The path radn's convolution takes for this shape on this CPU.
    pub chosen: crate::model::cpu::conv::ConvPath,
    /// FLOPs of one call (multiply-adds count 2).
    pub flops: f64,
}

impl ConvTiming {
    /// GFLOP/s of radn's path.
    pub fn radn_gflops(&self) -> f64 {
        self.flops / (self.radn_ms * 1e-3) / 1e9
    }

    /// GFLOP/s of the GEMM path alone.
    pub fn gemm_gflops(&self) -> f64 {
        self.flops / (self.gemm_ms * 1e-3) / 1e9
    }

    /// GFLOP/s of the direct path alone, where the CPU has it.
    pub fn direct_gflops(&self) -> Option<f64> {
        self.direct_ms.map(|ms| self.flops / (ms * 1e-3) / 1e9)
    }

    /// GFLOP/s of burn's path.
    pub fn burn_gflops(&self) -> f64 {
        self.flops / (self.burn_ms * 1e-3) / 1e9
    }
}

/// Times 3×3 convolutions of the given `(cin, cout)` shapes on `batch` maps of `tile × tile`
/// (for a denoising tile, `batch` = the window's 5 frames), inference only, on `device` (the
/// `flex` CPU device for radn's path to apply).
pub fn time_convs(
    shapes: &[(usize, usize)],
    batch: usize,
    tile: usize,
    repeats: usize,
    device: &Device,
) -> Vec<ConvTiming> {
    let time = |f: &dyn Fn()| {
        let mut times = Vec::new();
        for i in 0..repeats + 1 {
            let start = Instant::now();
            f();
            if i > 0 {
                times.push(start.elapsed().as_secs_f64() * 1e3);
            }
        }
        median(times)
    };
    shapes
        .iter()
        .map(|&(cin, cout)| {
            let conv = conv3(cin, cout, device);
            let x = Tensor::<4>::random(
                [batch, cin, tile, tile],
                Distribution::Uniform(0.0, 1.0),
                device,
            );
            let radn_ms = time(&|| {
                let _ = crate::model::cpu::conv::conv2d(&conv, x.clone(), false).into_data();
            });
            let burn_ms = time(&|| {
                let _ = conv.forward(x.clone()).into_data();
            });
            let host = x
                .clone()
                .into_data()
                .try_into_vec::<f32>()
                .expect("f32 input");
            let weight = conv
                .weight
                .val()
                .into_data()
                .try_into_vec::<f32>()
                .expect("f32 weights");
            let by = |path| {
                time(&|| {
                    let _ = conv_same_nchw_by(
                        path,
                        &host,
                        [batch, cin, tile, tile],
                        &weight,
                        [cout, 3, 3],
                        None,
                        false,
                    );
                })
            };
            ConvTiming {
                cin,
                cout,
                radn_ms,
                burn_ms,
                gemm_ms: by(ConvPath::Gemm),
                direct_ms: crate::model::cpu::direct::available().then(|| by(ConvPath::Direct)),
                chosen: preferred_path(),
                flops: batch as f64 * conv_flops(&conv, tile * tile),
            }
        })
        .collect()
}

/// GFLOP/s of one large square `n × n` single-precision GEMM (the `gemm` crate, all threads):
/// the practical ceiling of this machine's convolutions, to read [`time_convs`] against.
pub fn gemm_ceiling(n: usize, repeats: usize) -> f64 {
    let a = vec![1.0f32; n * n];
    let b = vec![0.5f32; n * n];
    let mut c = vec![0.0f32; n * n];
    let mut times = Vec::new();
    for i in 0..repeats + 1 {
        let start = Instant::now();
        // SAFETY: three row-major n × n buffers, each n · n floats long.
        unsafe {
            crate::model::cpu::conv::matmul_into(
                [n, n, n],
                c.as_mut_ptr(),
                n,
                &a,
                &b,
                gemm::Parallelism::Rayon(0),
            );
        }
        if i > 0 {
            times.push(start.elapsed().as_secs_f64());
        }
    }
    assert!(
        (c[0] - 0.5 * n as f32).abs() < 1e-3 * n as f32,
        "the GEMM computed"
    );
    2.0 * (n * n * n) as f64 / median(times) / 1e9
}
