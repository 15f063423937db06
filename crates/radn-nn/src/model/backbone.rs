//! Per-frame backbones: frames are a batch axis (weights shared across the window); the only
//! connections between frames are the Robust Average blocks.

use burn::module::Module;
use burn::nn::conv::Conv2d;
use burn::tensor::module::{avg_pool2d, interpolate};
use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
use burn::tensor::{Device, Tensor, TensorData};

use crate::model::config::Backbone;
use crate::model::cpu::conv::{conv2d, HostConv};
use crate::model::layers::{conv3, conv_flops, widen_conv_input, DoubleConv, ResBlock};
use crate::model::ra_block::RobustAverage;
use crate::profile::{timed, Stage};

/// The paper's ResNet (Fig. 1), with RA blocks after chosen residual blocks and skip
/// connections from chosen RA blocks to the head.
#[derive(Module, Debug)]
pub struct ResNet {
    input: Conv2d,
    blocks: Vec<ResBlock>,
    ra: Vec<RobustAverage>,
    ra_after: Vec<usize>,
    skips_from: Vec<usize>,
    width: usize,
}

impl ResNet {
    /// Builds the network over `cin` input channels per frame; `frames = 0` builds it without
    /// RA blocks.
    pub fn new(
        cin: usize,
        blocks: usize,
        width: usize,
        ra_after: &[usize],
        skips_from: &[usize],
        frames: usize,
        device: &Device,
    ) -> Self {
        Self {
            input: conv3(cin, width, device),
            blocks: (0..blocks).map(|_| ResBlock::new(width, device)).collect(),
            ra: ra_after
                .iter()
                .map(|_| RobustAverage::new(width, frames, device))
                .collect(),
            ra_after: ra_after.to_vec(),
            skips_from: skips_from.to_vec(),
            width,
        }
    }

    /// Channels of the features handed to the head.
    pub fn out_channels(&self) -> usize {
        self.width * (1 + self.skips_from.len())
    }

    /// Forward FLOPs for one window of `frames` frames of `h × w` pixels.
    pub fn flops(&self, h: usize, w: usize, frames: usize) -> f64 {
        let px = h * w;
        let per_frame =
            conv_flops(&self.input, px) + self.blocks.iter().map(|b| b.flops(px)).sum::<f64>();
        frames as f64 * per_frame + self.ra.iter().map(|r| r.flops(px)).sum::<f64>()
    }

    /// Every convolution weight by layer name, in forward order.
    pub fn weights(&self) -> Vec<(String, Tensor<4>)> {
        let mut v = vec![("input".to_string(), self.input.weight.val())];
        let mut next_ra = 0;
        for (i, block) in self.blocks.iter().enumerate() {
            v.extend(block.weights(&format!("block{}", i + 1)));
            if next_ra < self.ra_after.len() && self.ra_after[next_ra] == i + 1 {
                v.extend(self.ra[next_ra].named_weights(&format!("ra{}", next_ra + 1)));
                next_ra += 1;
            }
        }
        v
    }

    /// `[batch · frames, input channels, H, W]` → head features.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        if HostConv::applies(&self.input, &x.device()) {
            return self.forward_on_host(x);
        }
        self.forward_with_burn(x)
    }

    /// [`ResNet::forward`] as burn operations (training, other backends).
    fn forward_with_burn(&self, x: Tensor<4>) -> Tensor<4> {
        let mut h = conv2d(&self.input, x, true);
        let mut skips = Vec::new();
        let mut next_ra = 0;
        for (i, block) in self.blocks.iter().enumerate() {
            h = block.forward(h);
            if next_ra < self.ra_after.len() && self.ra_after[next_ra] == i + 1 {
                h = self.ra[next_ra].forward(h);
                if self.skips_from.contains(&(next_ra + 1)) {
                    skips.push(h.clone());
                }
                next_ra += 1;
            }
        }
        skips.push(h);
        Tensor::cat(skips, 1)
    }
}

impl ResNet {
    /// [`ResNet::forward`] on `f32` slices for CPU inference: the latent maps stay on the host
    /// from the input layer to the head, each residual add fused into its second
    /// convolution, instead of a tensor round trip and a separate add per convolution.
    fn forward_on_host(&self, x: Tensor<4>) -> Tensor<4> {
        let device = x.device();
        let [n, _, hh, ww] = x.dims();
        let input = x.into_data();
        let input = input.as_slice::<f32>().expect("f32 input");
        let mut h = HostConv::of(&self.input).run(input, n, hh, ww, true);
        let mut skips = Vec::new();
        let mut next_ra = 0;
        for (i, block) in self.blocks.iter().enumerate() {
            block.forward_on_host(&mut h, [n, hh, ww]);
            if next_ra < self.ra_after.len() && self.ra_after[next_ra] == i + 1 {
                h = self.ra[next_ra].forward_on_host(&h, [n, self.width, hh, ww]);
                if self.skips_from.contains(&(next_ra + 1)) {
                    skips.push(h.clone());
                }
                next_ra += 1;
            }
        }
        skips.push(h);
        // per image, the maps of every skip then the last, along channels
        let per_map = self.width * hh * ww;
        let out = if skips.len() == 1 {
            skips.pop().expect("one map")
        } else {
            let mut out = Vec::with_capacity(n * per_map * skips.len());
            for image in 0..n {
                for map in &skips {
                    out.extend_from_slice(&map[image * per_map..][..per_map]);
                }
            }
            out
        };
        let c = self.width * (self.skips_from.len() + 1);
        Tensor::from_data(TensorData::new(out, [n, c, hh, ww]), &device)
    }
}

/// A UNet with an RA block after the encoder block of chosen scales.
#[derive(Module, Debug)]
pub struct UNet {
    down: Vec<DoubleConv>,
    ra: Vec<RobustAverage>,
    /// The scale each RA block follows.
    ra_at: Vec<usize>,
    up: Vec<DoubleConv>,
    widths: Vec<usize>,
}

impl UNet {
    /// Builds the network over `cin` input channels and `frames` frames, with RA blocks after
    /// the encoder blocks of scales `ra_at` (none when `frames = 0`).
    pub fn new(
        cin: usize,
        widths: &[usize],
        ra_at: &[usize],
        frames: usize,
        device: &Device,
    ) -> Self {
        let mut down = Vec::new();
        let mut cin = cin;
        for &w in widths {
            down.push(DoubleConv::new(cin, w, device));
            cin = w;
        }
        let ra_at = if frames > 0 {
            ra_at.to_vec()
        } else {
            Vec::new()
        };
        let ra = ra_at
            .iter()
            .map(|&s| RobustAverage::new(widths[s], frames, device))
            .collect();
        // decoder: from scale s+1 up to s, concatenating the encoder's features of scale s
        let up = (0..widths.len() - 1)
            .rev()
            .map(|s| DoubleConv::new(widths[s + 1] + widths[s], widths[s], device))
            .collect();
        Self {
            down,
            ra,
            ra_at,
            up,
            widths: widths.to_vec(),
        }
    }

    /// Channels of the features handed to the head.
    pub fn out_channels(&self) -> usize {
        self.widths[0]
    }

    /// The RA block after scale `s`'s encoder block, if it has one.
    fn ra_of(&self, s: usize) -> Option<&RobustAverage> {
        self.ra_at.iter().position(|&a| a == s).map(|i| &self.ra[i])
    }

    /// Forward FLOPs for one window of `frames` frames of `h × w` pixels (scale s works on
    /// `h / 2^s × w / 2^s`).
    pub fn flops(&self, h: usize, w: usize, frames: usize) -> f64 {
        let px = |s: usize| (h >> s) * (w >> s);
        let t = frames as f64;
        let down: f64 = self
            .down
            .iter()
            .enumerate()
            .map(|(s, b)| t * b.flops(px(s)) + self.ra_of(s).map_or(0.0, |r| r.flops(px(s))))
            .sum();
        let up: f64 = self
            .up
            .iter()
            .enumerate()
            .map(|(k, b)| t * b.flops(px(self.widths.len() - 2 - k)))
            .sum();
        down + up
    }

    /// Every convolution weight by layer name, in forward order.
    pub fn weights(&self) -> Vec<(String, Tensor<4>)> {
        let mut v = Vec::new();
        for (s, block) in self.down.iter().enumerate() {
            v.extend(block.weights(&format!("down{s}")));
            if let Some(ra) = self.ra_of(s) {
                v.extend(ra.named_weights(&format!("ra{s}")));
            }
        }
        for (k, block) in self.up.iter().enumerate() {
            v.extend(block.weights(&format!("up{}", self.widths.len() - 2 - k)));
        }
        v
    }

    /// Input sizes must be divisible by 2^(scales − 1).
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let mut skips = Vec::new();
        let mut h = x;
        for (s, block) in self.down.iter().enumerate() {
            if s > 0 {
                h = avg_pool2d(h, burn::tensor::ops::AvgPoolOptions::new([2, 2]));
            }
            h = block.forward(h);
            if let Some(ra) = self.ra_of(s) {
                h = ra.forward(h);
            }
            skips.push(h.clone());
        }
        for (k, block) in self.up.iter().enumerate() {
            let s = self.widths.len() - 2 - k;
            let [_, _, hh, ww] = skips[s].dims();
            let up = interpolate(
                h,
                InterpolateOptions::new(InterpolateMode::Bilinear).with_output_size([hh, ww]),
            );
            h = block.forward(Tensor::cat(vec![up, skips[s].clone()], 1));
        }
        h
    }
}

/// Either backbone.
// one value per model, built once: the variants' size difference does not matter
#[allow(clippy::large_enum_variant)]
#[derive(Module, Debug)]
pub enum FrameNet {
    /// ResNet.
    ResNet(ResNet),
    /// UNet.
    UNet(UNet),
}

impl FrameNet {
    /// Builds the configured backbone over `cin` input channels per frame; `with_ra = false`
    /// leaves the RA blocks out.
    pub fn new(cfg: &Backbone, cin: usize, frames: usize, with_ra: bool, device: &Device) -> Self {
        let f = if with_ra { frames } else { 0 };
        match cfg {
            Backbone::Resnet {
                blocks,
                width,
                ra_after,
                skips_from,
            } => {
                let (ra, skips): (&[usize], &[usize]) = if with_ra {
                    (ra_after, skips_from)
                } else {
                    (&[], &[])
                };
                FrameNet::ResNet(ResNet::new(cin, *blocks, *width, ra, skips, f, device))
            }
            Backbone::Unet { widths, ra_scales } => {
                let all: Vec<usize> = (0..widths.len()).collect();
                let at = ra_scales.as_deref().unwrap_or(&all);
                FrameNet::UNet(UNet::new(cin, widths, at, f, device))
            }
        }
    }

    /// The RA blocks, in order.
    pub fn ra_blocks(&self) -> Vec<&RobustAverage> {
        match self {
            FrameNet::ResNet(n) => n.ra.iter().collect(),
            FrameNet::UNet(n) => n.ra.iter().collect(),
        }
    }

    /// Channels of the head's input.
    pub fn out_channels(&self) -> usize {
        match self {
            FrameNet::ResNet(n) => n.out_channels(),
            FrameNet::UNet(n) => n.out_channels(),
        }
    }

    /// The size multiple inputs must have (UNets downsample).
    pub fn size_multiple(&self) -> usize {
        match self {
            FrameNet::ResNet(_) => 1,
            FrameNet::UNet(n) => 1 << (n.widths.len() - 1),
        }
    }

    /// Forward FLOPs for one window of `frames` frames of `h × w` pixels.
    pub fn flops(&self, h: usize, w: usize, frames: usize) -> f64 {
        match self {
            FrameNet::ResNet(n) => n.flops(h, w, frames),
            FrameNet::UNet(n) => n.flops(h, w, frames),
        }
    }

    /// Every convolution weight by layer name, in forward order.
    pub fn weights(&self) -> Vec<(String, Tensor<4>)> {
        match self {
            FrameNet::ResNet(n) => n.weights(),
            FrameNet::UNet(n) => n.weights(),
        }
    }

    /// Per-frame features.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        match self {
            FrameNet::ResNet(n) => timed(Stage::Backbone, || n.forward(x)),
            FrameNet::UNet(n) => timed(Stage::Backbone, || n.forward(x)),
        }
    }

    /// Gives the first layer `cin` input channels, the new ones with zero weights
    /// ([`widen_conv_input`]).
    pub fn widen_input(&mut self, cin: usize, device: &Device) {
        match self {
            FrameNet::ResNet(n) => widen_conv_input(&mut n.input, cin, device),
            FrameNet::UNet(n) => n.down[0].widen_input(cin, device),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_resnet_on_host_equals_its_tensor_path_with_skips_and_ra_blocks() {
        let device = Device::flex();
        // two RA blocks, a skip from the first: the host path's concatenation is exercised
        let net = ResNet::new(7, 3, 16, &[1, 3], &[1], 5, &device);
        let (n, h, w) = (10, 11, 19);
        let x = Tensor::<4>::from_data(
            TensorData::new(
                (0..n * 7 * h * w)
                    .map(|i| ((i * 7919) % 211) as f32 / 60.0 - 1.5)
                    .collect::<Vec<f32>>(),
                [n, 7, h, w],
            ),
            &device,
        );
        let host = net.forward(x.clone());
        assert_eq!(host.dims(), [n, 32, h, w]);
        let host = host.into_data().try_into_vec::<f32>().unwrap();
        let burn = net
            .forward_with_burn(x)
            .into_data()
            .try_into_vec::<f32>()
            .unwrap();
        let scale = burn.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(scale > 0.1, "a test output of real size ({scale})");
        let worst = host
            .iter()
            .zip(&burn)
            .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(
            worst <= 1e-5 * scale,
            "host and tensor paths differ by {worst}"
        );
    }
}
