//! Per-frame backbones: frames are a batch axis (weights shared across the window); the only
//! connections between frames are the Robust Average blocks.

use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::PaddingConfig2d;
use burn::tensor::module::{avg_pool2d, interpolate};
use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
use burn::tensor::{Device, Tensor, TensorData};

use crate::model::config::Backbone;
use crate::model::cpu::conv::{conv2d, HostConv};
use crate::model::cpu::is_cpu_inference;
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
    /// With a frame-local stem ([`crate::model::config::NetConfig::frame_local_stem`]): the 1×1
    /// convolution that adds the window's own input channels to the stem's features before the
    /// first RA block.
    window_in: Option<Conv2d>,
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
            window_in: None,
        }
    }

    /// Residual blocks before the first RA block (all of them without one): with the input
    /// layer, the layers that see one frame only.
    pub fn stem_blocks(&self) -> usize {
        self.ra_after.first().copied().unwrap_or(self.blocks.len())
    }

    /// The radius in pixels of what one stem feature reads: the input layer and two 3×3
    /// convolutions per stem block.
    pub fn stem_radius(&self) -> usize {
        1 + 2 * self.stem_blocks()
    }

    /// Channels of the stem's features.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Makes the stem frame-local: the input layer keeps the weights of the frame's own channels
    /// `keep` (ranges of its current inputs) and drops those of the window's channels, whose
    /// value where a frame is fully trusted (`window_at_rest`, one per dropped channel, in order)
    /// is folded into its bias; a 1×1 convolution from the `window` dropped channels, starting at
    /// zero, adds them back after the stem. A fine-tune from a model without the split starts
    /// near it.
    pub fn split_window_inputs(
        &mut self,
        keep: &[std::ops::Range<usize>],
        dropped: std::ops::Range<usize>,
        window_at_rest: &[f32],
        device: &Device,
    ) {
        let w = self.input.weight.val();
        let [cout, _, _, _] = w.dims();
        let kept = keep
            .iter()
            .map(|r| w.clone().narrow(1, r.start, r.len()))
            .collect();
        let rest = w.narrow(1, dropped.start, dropped.len());
        // the dropped channels' contribution at rest, summed over the taps, joins the bias
        let at_rest =
            Tensor::<1>::from_floats(window_at_rest, device).reshape([1, dropped.len(), 1, 1]);
        let folded = (rest * at_rest)
            .sum_dim(3)
            .sum_dim(2)
            .sum_dim(1)
            .reshape([cout]);
        let bias = match &self.input.bias {
            Some(b) => b.val() + folded,
            None => folded,
        };
        self.input.weight = burn::module::Param::from_tensor(Tensor::cat(kept, 1).detach());
        self.input.bias = Some(burn::module::Param::from_tensor(bias.detach()));
        let mut conv = Conv2dConfig::new([dropped.len(), self.width], [1, 1])
            .with_padding(PaddingConfig2d::Same)
            .init(device);
        conv.weight = burn::module::Param::from_tensor(Tensor::zeros(
            [self.width, dropped.len(), 1, 1],
            device,
        ));
        conv.bias = Some(burn::module::Param::from_tensor(Tensor::zeros(
            [self.width],
            device,
        )));
        self.window_in = Some(conv);
    }

    /// Channels of the features handed to the head.
    pub fn out_channels(&self) -> usize {
        self.width * (1 + self.skips_from.len())
    }

    /// Forward FLOPs for one window of `frames` frames of `h × w` pixels.
    pub fn flops(&self, h: usize, w: usize, frames: usize) -> f64 {
        let px = h * w;
        let per_frame = conv_flops(&self.input, px)
            + self.blocks.iter().map(|b| b.flops(px)).sum::<f64>()
            + self.window_in.as_ref().map_or(0.0, |c| conv_flops(c, px));
        frames as f64 * per_frame + self.ra.iter().map(|r| r.flops(px)).sum::<f64>()
    }

    /// Every convolution weight by layer name, in forward order.
    pub fn weights(&self) -> Vec<(String, Tensor<4>)> {
        let mut v = vec![("input".to_string(), self.input.weight.val())];
        if let Some(c) = &self.window_in {
            v.push(("window_in".to_string(), c.weight.val()));
        }
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
            // the maps stay on the host from the input layer to the head features
            let device = x.device();
            let [n, _, hh, ww] = x.dims();
            let input = x.into_data();
            let input = input.as_slice::<f32>().expect("f32 input");
            let stem = self.stem_on_host(input, [n, hh, ww]);
            let out = self.rest_on_host(stem, [n, hh, ww]);
            let c = self.out_channels();
            return Tensor::from_data(TensorData::new(out, [n, c, hh, ww]), &device);
        }
        self.forward_with_burn(x)
    }

    /// The stem: the input layer and the blocks before the first RA block, frame by frame
    /// (`[n, input channels, H, W]` → `[n, width, H, W]`).
    pub fn stem(&self, x: Tensor<4>) -> Tensor<4> {
        if HostConv::applies(&self.input, &x.device()) {
            let device = x.device();
            let [n, _, hh, ww] = x.dims();
            let input = x.into_data();
            let input = input.as_slice::<f32>().expect("f32 input");
            let h = self.stem_on_host(input, [n, hh, ww]);
            return Tensor::from_data(TensorData::new(h, [n, self.width, hh, ww]), &device);
        }
        self.stem_with_burn(x)
    }

    /// [`ResNet::stem`] as burn operations (training, other backends).
    fn stem_with_burn(&self, x: Tensor<4>) -> Tensor<4> {
        let mut h = conv2d(&self.input, x, true);
        for block in &self.blocks[..self.stem_blocks()] {
            h = block.forward(h);
        }
        h
    }

    /// [`ResNet::forward`] as burn operations (training, other backends).
    fn forward_with_burn(&self, x: Tensor<4>) -> Tensor<4> {
        self.after_stem_with_burn(self.stem_with_burn(x), None)
    }

    /// The rest of the backbone from the stem's features `[n, width, H, W]`: the window's
    /// own inputs `window` (`[n, c, H, W]`, for a frame-local stem) added through their 1×1
    /// convolution, then the RA blocks and the blocks between them → head features.
    pub fn after_stem(&self, h: Tensor<4>, window: Option<Tensor<4>>) -> Tensor<4> {
        let device = h.device();
        if is_cpu_inference(&device) {
            let [n, _, hh, ww] = h.dims();
            let mut h = h.into_data().try_into_vec::<f32>().expect("f32 maps");
            if let (Some(conv), Some(x)) = (&self.window_in, window) {
                let x = x.into_data();
                let x = x.as_slice::<f32>().expect("f32 input");
                HostConv::of(conv).run_add(x, n, hh, ww, &mut h);
            }
            let out = self.rest_on_host(h, [n, hh, ww]);
            let c = self.out_channels();
            return Tensor::from_data(TensorData::new(out, [n, c, hh, ww]), &device);
        }
        self.after_stem_with_burn(h, window)
    }

    /// [`ResNet::after_stem`] as burn operations (training, other backends).
    fn after_stem_with_burn(&self, h: Tensor<4>, window: Option<Tensor<4>>) -> Tensor<4> {
        let mut h = h;
        if let (Some(conv), Some(x)) = (&self.window_in, window) {
            h = h + conv2d(conv, x, false);
        }
        let mut skips = Vec::new();
        let mut next_ra = 0;
        let s = self.stem_blocks();
        for i in s..=self.blocks.len() {
            if i > s {
                h = self.blocks[i - 1].forward(h);
            }
            if next_ra < self.ra_after.len() && self.ra_after[next_ra] == i {
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
    /// [`ResNet::stem`] on `f32` slices for CPU inference: the maps stay on the host, each
    /// residual add fused into its second convolution.
    fn stem_on_host(&self, input: &[f32], [n, hh, ww]: [usize; 3]) -> Vec<f32> {
        let mut h = HostConv::of(&self.input).run(input, n, hh, ww, true);
        for block in &self.blocks[..self.stem_blocks()] {
            block.forward_on_host(&mut h, [n, hh, ww]);
        }
        h
    }

    /// [`ResNet::after_stem`]'s RA blocks and later blocks on the host, and the head features
    /// (per image, the maps of every skip then the last, along channels).
    fn rest_on_host(&self, mut h: Vec<f32>, [n, hh, ww]: [usize; 3]) -> Vec<f32> {
        let mut skips = Vec::new();
        let mut next_ra = 0;
        let s = self.stem_blocks();
        for i in s..=self.blocks.len() {
            if i > s {
                self.blocks[i - 1].forward_on_host(&mut h, [n, hh, ww]);
            }
            if next_ra < self.ra_after.len() && self.ra_after[next_ra] == i {
                h = self.ra[next_ra].forward_on_host(&h, [n, self.width, hh, ww]);
                if self.skips_from.contains(&(next_ra + 1)) {
                    skips.push(h.clone());
                }
                next_ra += 1;
            }
        }
        skips.push(h);
        let per_map = self.width * hh * ww;
        if skips.len() == 1 {
            return skips.pop().expect("one map");
        }
        let mut out = Vec::with_capacity(n * per_map * skips.len());
        for image in 0..n {
            for map in &skips {
                out.extend_from_slice(&map[image * per_map..][..per_map]);
            }
        }
        out
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

    /// The ResNet, for the operations only it has (a frame-local stem); `None` for a UNet.
    pub fn resnet(&self) -> Option<&ResNet> {
        match self {
            FrameNet::ResNet(n) => Some(n),
            FrameNet::UNet(_) => None,
        }
    }

    /// [`FrameNet::resnet`], mutable.
    pub fn resnet_mut(&mut self) -> Option<&mut ResNet> {
        match self {
            FrameNet::ResNet(n) => Some(n),
            FrameNet::UNet(_) => None,
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
