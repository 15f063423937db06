//! Inference throughput: a network per tile, single convolution shapes through radn's CPU path
//! and burn's, and the machine's GEMM ceiling. FLOP counts come from the networks' own layers.
//! Training throughput is `radn_train::bench`.

use std::time::Instant;

use burn::tensor::{Device, Distribution, Tensor};

use crate::model::config::NetConfig;
use crate::model::cpu::conv::{conv_same_nchw_by, preferred_path, ConvPath};
use crate::model::layers::{conv3, conv_flops};
use crate::model::Denoiser;

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

/// The median of `v` (timings of repeated runs).
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// A batch of random `tile × tile` windows: network inputs and the colour the kernels filter.
pub fn random_windows(
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
