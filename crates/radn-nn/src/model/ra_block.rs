//! The Robust Average block (paper section 3, Fig. 2): for each frame of the window in turn,
//! the robust average of the other frames' latent maps is blended into it with per-pixel
//! weights predicted by a small convolution stack. Recurrent: each step sees the frames the
//! earlier steps updated.

use burn::module::{Module, Param};
use burn::nn::conv::Conv2d;
use burn::tensor::activation::{relu, sigmoid};
use burn::tensor::{Device, Tensor, TensorData};

use crate::model::cpu::conv::{conv2d, HostConv};
use crate::model::cpu::ra::{robust_average, robust_average_steps, RobustAverageConvs};
use crate::model::layers::{conv3, conv_flops};
use crate::profile::{timed, Stage};

/// Bias of the weight predictor at initialisation: sigmoid(−2) ≈ 0.12, so a new block starts
/// close to the identity (a ResNet-friendly start) but passes gradient to its averaging path.
const INITIAL_BIAS: f32 = -2.0;

/// Robust Average block over `frames` latent maps.
///
/// The weight predictor's first convolution over `[h_i, average]` is stored as its two halves:
/// the `h_i` half runs once, batched over all frames (step i still sees the original `h_i`,
/// since only earlier frames have been updated), and only the average's half runs per step.
/// Same function as one convolution over the concatenation, at a fraction of the cost of
/// batch-1 convolutions.
#[derive(Module, Debug)]
pub struct RobustAverage {
    hidden_self: Conv2d,
    hidden_avg: Conv2d,
    weight: Conv2d,
    frames: usize,
}

impl RobustAverage {
    /// A block for latent maps of `channels` channels over `frames` frames.
    pub fn new(channels: usize, frames: usize, device: &Device) -> Self {
        let hidden_channels = (channels / 2).max(8);
        let mut weight = conv3(hidden_channels, 1, device);
        weight.bias = Some(Param::from_tensor(Tensor::full([1], INITIAL_BIAS, device)));
        let hidden_avg = burn::nn::conv::Conv2dConfig::new([channels, hidden_channels], [3, 3])
            .with_padding(burn::nn::PaddingConfig2d::Same)
            .with_bias(false)
            .init(device);
        Self {
            hidden_self: conv3(channels, hidden_channels, device),
            hidden_avg,
            weight,
            frames,
        }
    }

    /// Sets the bias of the weight predictor (a large negative value turns interpolation off:
    /// the block is then the identity).
    pub fn with_weight_bias(mut self, bias: f32) -> Self {
        let device = self.weight.weight.val().device();
        self.weight.bias = Some(Param::from_tensor(Tensor::full([1], bias, &device)));
        self
    }

    /// The weight tensors of the block's convolutions (for inspecting gradients).
    pub fn conv_weights(&self) -> Vec<Tensor<4>> {
        vec![
            self.hidden_self.weight.val(),
            self.hidden_avg.weight.val(),
            self.weight.weight.val(),
        ]
    }

    /// [`RobustAverage::conv_weights`] named `prefix.hidden_self`, `prefix.hidden_avg` and
    /// `prefix.weight`.
    pub fn named_weights(&self, prefix: &str) -> Vec<(String, Tensor<4>)> {
        ["hidden_self", "hidden_avg", "weight"]
            .iter()
            .map(|n| format!("{prefix}.{n}"))
            .zip(self.conv_weights())
            .collect()
    }

    /// Forward FLOPs for one window (all its frames) of `pixels` pixels per frame: the
    /// predictor's first half once per frame, its second half and weight conv once per step.
    pub fn flops(&self, pixels: usize) -> f64 {
        let t = self.frames as f64;
        t * (conv_flops(&self.hidden_self, pixels)
            + conv_flops(&self.hidden_avg, pixels)
            + conv_flops(&self.weight, pixels))
    }

    /// `h`: `[batch · frames, C, H, W]`, frames consecutive within each batch item.
    pub fn forward(&self, h: Tensor<4>) -> Tensor<4> {
        timed(Stage::RobustAverage, || self.forward_untimed(h))
    }

    fn forward_untimed(&self, h: Tensor<4>) -> Tensor<4> {
        let [bt, c, hh, ww] = h.dims();
        let device = h.device();
        if [&self.hidden_self, &self.hidden_avg, &self.weight]
            .iter()
            .all(|conv| HostConv::applies(conv, &device))
        {
            let data = h.into_data();
            let out = self.fused(
                data.as_slice::<f32>().expect("f32 latent maps"),
                [bt, c, hh, ww],
            );
            return Tensor::from_data(TensorData::new(out, [bt, c, hh, ww]), &device);
        }
        self.forward_with_burn(h)
    }

    /// [`RobustAverage::forward`] on host latent maps `h` (`[batch · frames, c, hh, ww]`) for
    /// CPU inference, where its convolutions take the CPU path ([`HostConv::applies`]).
    pub fn forward_on_host(&self, h: &[f32], dims: [usize; 4]) -> Vec<f32> {
        timed(Stage::RobustAverage, || self.fused(h, dims))
    }

    /// The centre frame's map of [`RobustAverage::forward_on_host`] for one window `h`
    /// (`[frames, c, hh, ww]`), `[c, hh, ww]`: only the steps up to the centre's run, since
    /// no later step changes it.
    pub fn centre_on_host(&self, h: &[f32], [t, c, hh, ww]: [usize; 4]) -> Vec<f32> {
        assert_eq!(t, self.frames, "one window of the block's length");
        let centre = t / 2;
        let mut frames = timed(Stage::RobustAverage, || {
            robust_average_steps(h, [1, t, c, hh, ww], &self.host_convs(), centre + 1)
        });
        let map = c * hh * ww;
        frames.truncate((centre + 1) * map);
        frames.drain(..centre * map);
        frames
    }

    /// How many pixels (at the block's scale) beyond a pixel the centre frame's result reads:
    /// each step up to the centre's adds its predictor's reach (a convolution over the frames
    /// earlier steps updated, then the weight convolution).
    pub fn centre_reach(&self) -> usize {
        let reach = |conv: &Conv2d| conv.weight.val().dims()[2] / 2;
        let step = reach(&self.hidden_self).max(reach(&self.hidden_avg)) + reach(&self.weight);
        step * (self.frames / 2 + 1)
    }

    /// The block's convolutions in the CPU kernels' form.
    fn host_convs(&self) -> RobustAverageConvs {
        RobustAverageConvs {
            hidden_self: HostConv::of(&self.hidden_self),
            hidden_avg: HostConv::of(&self.hidden_avg),
            weight: HostConv::of(&self.weight),
        }
    }

    /// The fused CPU block ([`robust_average`]).
    fn fused(&self, h: &[f32], [bt, c, hh, ww]: [usize; 4]) -> Vec<f32> {
        let t = self.frames;
        robust_average(h, [bt / t, t, c, hh, ww], &self.host_convs())
    }

    /// [`RobustAverage::forward`] as burn operations (training, other backends).
    fn forward_with_burn(&self, h: Tensor<4>) -> Tensor<4> {
        let [bt, c, hh, ww] = h.dims();
        let t = self.frames;
        let b = bt / t;
        // the h_i half of the first predictor convolution, for every frame at once
        let pre = conv2d(&self.hidden_self, h.clone(), false);
        let hc = pre.dims()[1];
        let pre: Tensor<5> = pre.reshape([b, t, hc, hh, ww]);
        let h5: Tensor<5> = h.reshape([b, t, c, hh, ww]);
        let mut frames: Vec<Tensor<4>> = (0..t)
            .map(|i| h5.clone().narrow(1, i, 1).reshape([b, c, hh, ww]))
            .collect();
        for i in 0..t {
            let others: Vec<Tensor<4>> = frames
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, f)| f.clone())
                .collect();
            let avg = robust_mean(others);
            let pre_i = pre.clone().narrow(1, i, 1).reshape([b, hc, hh, ww]);
            let hidden = relu(pre_i + conv2d(&self.hidden_avg, avg.clone(), false));
            let w = sigmoid(conv2d(&self.weight, hidden, false));
            let keep = w.clone().neg().add_scalar(1.0);
            frames[i] = frames[i].clone() * keep + avg * w;
        }
        Tensor::stack::<5>(frames, 1).reshape([bt, c, hh, ww])
    }
}

/// The robust average of paper eq. 1, elementwise over a list of maps: mean without the
/// minimum and the maximum when there are at least three, the plain mean otherwise.
///
/// Folds with elementwise `max_pair`/`min_pair` rather than stacking and reducing over a new
/// axis: the same values, but a cheap elementwise backward pass (this is the hot path of
/// every RA block).
pub fn robust_mean(maps: Vec<Tensor<4>>) -> Tensor<4> {
    let n = maps.len();
    let mut it = maps.into_iter();
    let first = it.next().expect("at least one map");
    let (mut sum, mut hi, mut lo) = (first.clone(), first.clone(), first);
    for m in it {
        sum = sum + m.clone();
        hi = hi.max_pair(m.clone());
        lo = lo.min_pair(m);
    }
    if n >= 3 {
        (sum - hi - lo) / (n - 2) as f32
    } else {
        sum / n as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::TensorData;

    fn t4(v: Vec<f32>, shape: [usize; 4]) -> Tensor<4> {
        Tensor::from_data(TensorData::new(v, shape), &Device::flex())
    }

    #[test]
    fn robust_mean_matches_hand_computed_values_with_ties() {
        // four maps of two pixels: pixel 0 = (1, 5, 3, 100) -> (5 + 3) / 2; pixel 1 ties (2, 2, 2, 7) -> 2
        let maps = vec![
            t4(vec![1.0, 2.0], [1, 1, 1, 2]),
            t4(vec![5.0, 2.0], [1, 1, 1, 2]),
            t4(vec![3.0, 2.0], [1, 1, 1, 2]),
            t4(vec![100.0, 7.0], [1, 1, 1, 2]),
        ];
        let out = robust_mean(maps).to_data().try_to_vec::<f32>().unwrap();
        assert_eq!(out, vec![4.0, 2.0]);
        // two maps: the plain mean
        let out = robust_mean(vec![
            t4(vec![1.0], [1, 1, 1, 1]),
            t4(vec![3.0], [1, 1, 1, 1]),
        ])
        .to_data()
        .try_to_vec::<f32>()
        .unwrap();
        assert_eq!(out, vec![2.0]);
    }

    #[test]
    fn the_fused_cpu_block_equals_burns_operations() {
        let device = Device::flex();
        // an even bias, so that the predicted weights spread over (0, 1)
        let block = RobustAverage::new(16, 5, &device).with_weight_bias(0.0);
        let (b, t, c, h, w) = (2, 5, 16, 9, 13);
        let n = b * t * c * h * w;
        let x = t4(
            (0..n)
                .map(|i| ((i * 7919) % 211) as f32 / 40.0 - 2.5)
                .collect(),
            [b * t, c, h, w],
        );
        let fused = block
            .forward(x.clone())
            .into_data()
            .try_into_vec::<f32>()
            .unwrap();
        let burn = block
            .forward_with_burn(x.clone())
            .into_data()
            .try_into_vec::<f32>()
            .unwrap();
        let input = x.into_data().try_into_vec::<f32>().unwrap();
        let worst = fused
            .iter()
            .zip(&burn)
            .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
        let moved = burn
            .iter()
            .zip(&input)
            .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(moved > 0.1, "the block changes its input ({moved})");
        assert!(worst < 1e-5, "fused and burn differ by {worst}");
    }

    #[test]
    fn block_with_interpolation_switched_off_is_the_identity() {
        let device = Device::flex();
        for frames in [5usize, 3] {
            let block = RobustAverage::new(8, frames, &device).with_weight_bias(-1.0e4);
            let n = 2 * frames * 8 * 6 * 5;
            let x = t4(
                (0..n)
                    .map(|i| ((i * 7919) % 113) as f32 / 50.0 - 1.0)
                    .collect(),
                [2 * frames, 8, 6, 5],
            );
            let y = block.forward(x.clone());
            assert_eq!(y.dims(), [2 * frames, 8, 6, 5]);
            assert_eq!(
                y.to_data().try_to_vec::<f32>().unwrap(),
                x.to_data().try_to_vec::<f32>().unwrap()
            );
        }
    }

    /// The centre-only CPU path gives the whole block's centre map, and the centre reads
    /// exactly [`RobustAverage::centre_reach`] pixels: a change that far away can move it, one
    /// pixel further never does. Whether one random block passes a change along its longest
    /// path depends on its ReLUs, its gates and which frames the robust mean drops (about a third
    /// of random blocks do), so 32 blocks are drawn: none may read further, and one must read
    /// that far.
    #[test]
    fn the_centre_alone_equals_the_whole_block_and_reads_its_reach() {
        let device = Device::flex();
        let (t, c, h, w) = (5, 8, 1, 31);
        let input = |bump: Option<usize>| -> Vec<f32> {
            (0..t * c * h * w)
                .map(|i| {
                    let x = i % w;
                    let frame = i / (c * h * w);
                    let v = ((i * 7919) % 211) as f32 / 40.0 - 2.5;
                    // frames 0, 2 and 3 change at column `bump`, by different amounts
                    match (Some(x) == bump, frame) {
                        (true, 0) => v + 3.0,
                        (true, 2) => v - 2.0,
                        (true, 3) => v + 1.5,
                        _ => v,
                    }
                })
                .collect()
        };
        let x = input(None);
        let mut reached = 0;
        for _ in 0..32 {
            let block = RobustAverage::new(8, 5, &device).with_weight_bias(0.0);
            let all = block.forward_on_host(&x, [t, c, h, w]);
            let centre = block.centre_on_host(&x, [t, c, h, w]);
            assert_eq!(centre, all[2 * c * h * w..3 * c * h * w]);
            let reach = block.centre_reach();
            assert_eq!(reach, 6, "two 3×3 convolutions per step, three steps");
            // the centre's value at column 0, with a change `d` columns away
            let at_zero = |d: usize| -> Vec<f32> {
                let out = block.centre_on_host(&input(Some(d)), [t, c, h, w]);
                (0..c).map(|k| out[k * h * w]).collect()
            };
            let base: Vec<f32> = (0..c).map(|k| centre[k * h * w]).collect();
            assert_eq!(
                at_zero(reach + 1),
                base,
                "a change beyond the reach does not move the centre"
            );
            if at_zero(reach) != base {
                reached += 1;
            }
        }
        assert!(
            reached > 0,
            "a change at the reach moved the centre in none of 32 random blocks"
        );
    }
}
