//! Small building blocks shared by the backbones.

use crate::model::cpu::conv::{conv2d, HostConv};
use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::PaddingConfig2d;
use burn::tensor::{Device, Tensor};

/// A 3×3 convolution that keeps the image size.
pub fn conv3(cin: usize, cout: usize, device: &Device) -> Conv2d {
    Conv2dConfig::new([cin, cout], [3, 3])
        .with_padding(PaddingConfig2d::Same)
        .init(device)
}

/// Gives `conv` `cin` input channels: the ones it has keep their weights, the new ones start
/// at zero, so the layer computes exactly what it did until training moves them (a fine-tune
/// that adds input features starts from the model it grows). Fewer channels drop the last.
pub fn widen_conv_input(conv: &mut Conv2d, cin: usize, device: &Device) {
    let w = conv.weight.val();
    let [cout, have, kh, kw] = w.dims();
    let w = if cin >= have {
        Tensor::cat(
            vec![w, Tensor::zeros([cout, cin - have, kh, kw], device)],
            1,
        )
    } else {
        w.narrow(1, 0, cin)
    };
    // a new leaf: a parameter of a training (autodiff) network must not carry a graph
    conv.weight = burn::module::Param::from_tensor(w.detach());
}

/// Forward FLOPs of a stride-1, same-size convolution on a map of `pixels` pixels
/// (multiply-adds count 2), from the shape of its weights (read without initialising them).
pub fn conv_flops(conv: &Conv2d, pixels: usize) -> f64 {
    2.0 * conv.weight.lazy_shape().num_elements() as f64 * pixels as f64
}

/// FLOPs of a block's two convolutions `a` and `b` on a map of `pixels` pixels.
fn pair_flops(a: &Conv2d, b: &Conv2d, pixels: usize) -> f64 {
    conv_flops(a, pixels) + conv_flops(b, pixels)
}

/// A block's two convolution weights, named `prefix.a` and `prefix.b`.
fn pair_weights(prefix: &str, a: &Conv2d, b: &Conv2d) -> Vec<(String, Tensor<4>)> {
    vec![
        (format!("{prefix}.a"), a.weight.val()),
        (format!("{prefix}.b"), b.weight.val()),
    ]
}

/// A residual block: `x + conv(relu(conv(x)))`.
#[derive(Module, Debug)]
pub struct ResBlock {
    a: Conv2d,
    b: Conv2d,
}

impl ResBlock {
    /// A block of the given width.
    pub fn new(width: usize, device: &Device) -> Self {
        Self {
            a: conv3(width, width, device),
            b: conv3(width, width, device),
        }
    }

    /// Applies the block.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        x.clone() + conv2d(&self.b, conv2d(&self.a, x, true), false)
    }

    /// [`ResBlock::forward`] in place on `n` host maps `h` (`[n, width, hh, ww]`) for CPU
    /// inference, where both convolutions take the CPU path ([`HostConv::applies`]); the
    /// residual add is fused into the second convolution.
    pub fn forward_on_host(&self, h: &mut [f32], [n, hh, ww]: [usize; 3]) {
        let a = HostConv::of(&self.a).run(h, n, hh, ww, true);
        HostConv::of(&self.b).run_add(&a, n, hh, ww, h);
    }

    /// Forward FLOPs on a map of `pixels` pixels.
    pub fn flops(&self, pixels: usize) -> f64 {
        pair_flops(&self.a, &self.b, pixels)
    }

    /// The weights of its two convolutions, named `prefix.a` and `prefix.b`.
    pub fn weights(&self, prefix: &str) -> Vec<(String, Tensor<4>)> {
        pair_weights(prefix, &self.a, &self.b)
    }
}

/// Two 3×3 convolutions with ReLUs (the UNet's per-scale block).
#[derive(Module, Debug)]
pub struct DoubleConv {
    a: Conv2d,
    b: Conv2d,
}

impl DoubleConv {
    /// From `cin` to `cout` channels.
    pub fn new(cin: usize, cout: usize, device: &Device) -> Self {
        Self {
            a: conv3(cin, cout, device),
            b: conv3(cout, cout, device),
        }
    }

    /// Applies the block.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        conv2d(&self.b, conv2d(&self.a, x, true), true)
    }

    /// Gives the block `cin` input channels ([`widen_conv_input`]).
    pub fn widen_input(&mut self, cin: usize, device: &Device) {
        widen_conv_input(&mut self.a, cin, device);
    }

    /// Forward FLOPs on a map of `pixels` pixels.
    pub fn flops(&self, pixels: usize) -> f64 {
        pair_flops(&self.a, &self.b, pixels)
    }

    /// The weights of its two convolutions, named `prefix.a` and `prefix.b`.
    pub fn weights(&self, prefix: &str) -> Vec<(String, Tensor<4>)> {
        pair_weights(prefix, &self.a, &self.b)
    }
}
