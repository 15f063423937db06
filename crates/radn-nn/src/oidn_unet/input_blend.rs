//! A learned average of the window's input at the centre frame, before the U-Net's encoder
//! ([`TemporalConfig::input_blend`](crate::oidn_unet::temporal::TemporalConfig)): the paper's
//! Robust Average moved to the input, where the window's samples are still unbiased. A small
//! convolution stack reads each aligned frame's processed input beside the centre's and
//! predicts how much of that frame to take at each pixel; the blend is taken in linear colour
//! (averaging Monte Carlo noise in the transfer curve's space would bias it), with the centre
//! at weight one, and enters through a gate that starts closed, so the converted network
//! starts as the per-frame U-Net. Unlike a fixed mean it can leave out a frame that disagrees
//! and take less where the input is already clean. AOVs take the beauty's weights, so they
//! still sum to it.

use burn::module::{Module, Param};
use burn::nn::conv::Conv2d;
use burn::tensor::activation::{relu, sigmoid};
use burn::tensor::{Device, Tensor, TensorData};

use radn_core::Plane;

use crate::model::cpu::conv::HostConv;
use crate::model::layers::conv3;
use crate::oidn_unet::transfer::Transfer;

/// Hidden channels of the weight predictor.
const HIDDEN: usize = 16;

/// Rows of a frame whose weights are predicted at once on the host (plus the stack's reach
/// above and below): bounds the predictor's memory at any frame size.
const HOST_ROWS: usize = 64;

/// The learned input average: a three-layer weight predictor and its gate.
#[derive(Module, Debug)]
pub struct InputBlend {
    hidden: Conv2d,
    hidden2: Conv2d,
    weight: Conv2d,
    pub(crate) gate: Param<Tensor<1>>,
}

impl InputBlend {
    /// A closed blend for processed frames of `channels` channels (the U-Net's input).
    pub fn new(channels: usize, device: &Device) -> Self {
        Self {
            hidden: conv3(2 * channels, HIDDEN, device),
            hidden2: conv3(HIDDEN, HIDDEN, device),
            weight: conv3(HIDDEN, 1, device),
            gate: Param::from_tensor(Tensor::zeros([1], device)),
        }
    }

    /// How far beyond a pixel its weights read (three 3×3 convolutions).
    pub fn reach() -> usize {
        3
    }

    /// How open the gate is (0: the centre as rendered).
    pub fn openness(&self) -> f32 {
        self.gate.val().abs().into_scalar::<f32>()
    }

    /// The gate set to `value` (for tests of the paths that run an open blend).
    pub fn with_gate(mut self, value: f32) -> Self {
        let device = self.gate.val().device();
        self.gate = Param::from_tensor(Tensor::full([1], value, &device));
        self
    }

    /// Each frame's share of the centre's blended input, `[batch, frames, 1, h, w]`, from the
    /// processed windows `[batch · frames, channels, h, w]`; the shares sum to one.
    pub fn coefficients(&self, window: Tensor<4>, frames: usize) -> Tensor<5> {
        let [bt, c, h, w] = window.dims();
        let (b, t) = (bt / frames, frames);
        let device = window.device();
        let x = window.reshape([b, t, c, h, w]);
        let centre = x.clone().narrow(1, t / 2, 1).repeat_dim(1, t);
        let pair = Tensor::cat(vec![x, centre], 2).reshape([bt, 2 * c, h, w]);
        let hidden = relu(self.hidden2.forward(relu(self.hidden.forward(pair))));
        let sides = sigmoid(self.weight.forward(hidden)).reshape([b, t, 1, h, w]);
        let is_centre = |v_centre: f32, v_side: f32| -> Tensor<5> {
            let v: Vec<f32> = (0..t)
                .map(|k| if k == t / 2 { v_centre } else { v_side })
                .collect();
            Tensor::from_data(TensorData::new(v, [1, t, 1, 1, 1]), &device)
        };
        let weights = sides * is_centre(0.0, 1.0) + is_centre(1.0, 0.0);
        let shares = weights.clone() / weights.sum_dim(1);
        let gate = self.gate.val().reshape([1, 1, 1, 1, 1]);
        shares * gate.clone() + is_centre(1.0, 0.0) * (gate.neg() + 1.0)
    }

    /// The processed windows with the centre slot's colour (its first three channels, HDR
    /// through the PU curve) replaced by the blend of the window's colours; the rest as given.
    /// A closed gate returns the windows unchanged, bit for bit.
    pub fn forward(&self, window: Tensor<4>, frames: usize) -> Tensor<4> {
        let [bt, c, h, w] = window.dims();
        let (b, t) = (bt / frames, frames);
        let shares = self.coefficients(window.clone(), t);
        let x = window.reshape([b, t, c, h, w]);
        let processed = x.clone().narrow(2, 0, 3);
        let linear = Transfer::Pu.inverse_tensor(processed.clone().reshape([bt, 3, h, w]));
        let linear = linear.reshape([b, t, 3, h, w]);
        let blended = (linear.clone() * shares).sum_dim(1).reshape([b, 3, h, w]);
        let own = linear.narrow(1, t / 2, 1).reshape([b, 3, h, w]);
        // the centre's own processed value plus the blend's change in the curve's space: the
        // same as the curve of the blend, and exactly the centre's value while the gate is shut
        let change = Transfer::Pu.forward_tensor(blended) - Transfer::Pu.forward_tensor(own);
        let centre = x.clone().narrow(1, t / 2, 1);
        let colour = centre.clone().narrow(2, 0, 3) + change.reshape([b, 1, 3, h, w]);
        let centre = if c > 3 {
            Tensor::cat(vec![colour, centre.narrow(2, 3, c - 3)], 2)
        } else {
            colour
        };
        Tensor::cat(
            vec![
                x.clone().narrow(1, 0, t / 2),
                centre,
                x.narrow(1, t / 2 + 1, t - t / 2 - 1),
            ],
            1,
        )
        .reshape([bt, c, h, w])
    }

    /// The blend's weights copied to the host for CPU inference.
    pub fn host(&self) -> HostInputBlend {
        HostInputBlend {
            convs: [
                HostConv::of(&self.hidden),
                HostConv::of(&self.hidden2),
                HostConv::of(&self.weight),
            ],
            gate: self.gate.val().into_scalar::<f32>(),
        }
    }
}

/// [`InputBlend`] on the CPU kernels.
pub struct HostInputBlend {
    convs: [HostConv; 3],
    gate: f32,
}

impl HostInputBlend {
    /// Each frame's share of the centre's blended input (`[h · w]` per frame), from the
    /// window's processed frames (each `[channels, h, w]`, the centre in the middle); the
    /// predictor runs on bands of rows, so its memory stays flat at any frame size.
    pub fn shares(&self, processed: &[Vec<f32>], w: usize, h: usize) -> Vec<Vec<f32>> {
        let t = processed.len();
        let r = t / 2;
        let n = w * h;
        let c = processed[r].len() / n;
        let halo = InputBlend::reach();
        let mut weights = vec![vec![1.0f32; n]; t];
        for (k, wk) in weights.iter_mut().enumerate() {
            if k == r {
                continue;
            }
            for y0 in (0..h).step_by(HOST_ROWS) {
                let y1 = (y0 + HOST_ROWS).min(h);
                let (a, b) = (y0.saturating_sub(halo), (y1 + halo).min(h));
                let rows = b - a;
                let mut pair = Vec::with_capacity(2 * c * rows * w);
                for frame in [&processed[k], &processed[r]] {
                    for ch in 0..c {
                        pair.extend_from_slice(&frame[ch * n + a * w..ch * n + b * w]);
                    }
                }
                let hidden = self.convs[0].run(&pair, 1, rows, w, true);
                let hidden = self.convs[1].run(&hidden, 1, rows, w, true);
                let logit = self.convs[2].run(&hidden, 1, rows, w, false);
                for y in y0..y1 {
                    for x in 0..w {
                        let z = logit[(y - a) * w + x];
                        wk[y * w + x] = 1.0 / (1.0 + (-z).exp());
                    }
                }
            }
        }
        let g = self.gate;
        let mut shares = vec![vec![0.0f32; n]; t];
        for i in 0..n {
            let sum: f32 = weights.iter().map(|wk| wk[i]).sum();
            for k in 0..t {
                let own = if k == r { 1.0 - g } else { 0.0 };
                shares[k][i] = g * (weights[k][i] / sum) + own;
            }
        }
        shares
    }

    /// The blend of `planes` (one per frame, of one size and channel count) with `shares`.
    pub fn apply(planes: &[&Plane], shares: &[Vec<f32>]) -> Plane {
        let mut out = Plane::zeros(planes[0].width(), planes[0].height(), planes[0].channels());
        for (p, s) in planes.iter().zip(shares) {
            for c in 0..p.channels() {
                for ((o, v), a) in out.channel_mut(c).iter_mut().zip(p.channel(c)).zip(s) {
                    *o += a * v;
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On a network that reads the beauty alone (no auxiliaries), the blend moves the centre's
    /// colour towards its neighbours' where open and returns the window as given where shut.
    #[test]
    fn a_beauty_only_window_blends_its_colour() {
        let device = Device::flex();
        let (t, h, w) = (3, 8, 8);
        let values: Vec<f32> = (0..t * 3 * h * w)
            .map(|i| 0.2 + 0.6 * ((i / (3 * h * w)) as f32) / t as f32)
            .collect();
        let x: Tensor<4> = Tensor::from_data(TensorData::new(values, [t, 3, h, w]), &device);
        let shut = InputBlend::new(3, &device);
        let same = shut
            .forward(x.clone(), t)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        assert_eq!(same, x.clone().into_data().try_to_vec::<f32>().unwrap());
        let open = shut.with_gate(1.0).forward(x.clone(), t);
        let centre = |y: Tensor<4>| -> f32 { y.narrow(0, 1, 1).mean().into_scalar::<f32>() };
        let (before, after) = (centre(x.clone()), centre(open.clone()));
        // the first frame is darker, the last brighter: the centre moves, the sides stay
        assert!((after - before).abs() > 1e-3, "{before} -> {after}");
        let side = |y: Tensor<4>| y.narrow(0, 0, 1).into_data().try_to_vec::<f32>().unwrap();
        assert_eq!(side(open), side(x));
    }
}
