//! The learned guide mix of a guided network ([`crate::model::config::NetConfig::guide_mix_head`])
//! as training sees it: the kernels' colour result `r` mixed with the centre frame's guide `g`
//! by the weight `w` the network predicts per pixel, `(1 − w)·r + w·g`. Inference mixes every
//! RGB signal with the same weights as a gain ([`crate::infer::guide_mix`]), which equals this
//! on the beauty.

use burn::tensor::Tensor;

use crate::model::Denoiser;

/// The mix of one batch: weights and guides of the centre frames.
#[derive(Clone, Debug)]
pub struct LearnedMix<'a> {
    /// Where `w` comes from.
    pub weight: MixWeights<'a>,
    /// The centre frame's guide (linear colour, as rendered), `[B, 3, H, W]`.
    pub guide: Tensor<4>,
}

/// The weights of a [`LearnedMix`].
// one value per batch, holding tensor handles: its size does not matter
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
pub enum MixWeights<'a> {
    /// `w` per pixel, `[B, 1, H, W]`, in (0, 1), predicted from the features alone.
    Given(Tensor<4>),
    /// `w` from the result being mixed ([`crate::model::config::NetConfig::guide_mix_reads_result`]):
    /// each term of the loss mixes its own result by weights computed from it.
    OfResult {
        /// The network whose head computes them.
        denoiser: &'a Denoiser,
        /// The centre frame's features ([`crate::model::GuideWeights::mix_features`]).
        features: Tensor<4>,
        /// The network's input, `[B, T, C, H, W]` (the head reads the centre frame's guide).
        input: Tensor<5>,
        /// Per batch item, the reciprocal of the exposure the inputs were divided by
        /// (`[B, 1, 1, 1]`; 1 without exposure normalisation).
        inv_exposure: Tensor<4>,
    },
}

impl LearnedMix<'_> {
    /// The weights for a colour result `r` (`[B, 3, H, W]`).
    pub fn weights(&self, result: &Tensor<4>) -> Tensor<4> {
        match &self.weight {
            MixWeights::Given(w) => w.clone(),
            MixWeights::OfResult {
                denoiser,
                features,
                input,
                inv_exposure,
            } => denoiser.mix_weight_of_result(
                features.clone(),
                result.clone(),
                inv_exposure.clone(),
                input,
            ),
        }
    }

    /// `(1 − w)·r + w·g` for a colour result `r` (`[B, 3, H, W]`, or as many channels as the
    /// guide has).
    pub fn apply(&self, result: Tensor<4>) -> Tensor<4> {
        let w = self.weights(&result).repeat_dim(1, result.dims()[1]);
        result * (w.clone().neg() + 1.0) + w * self.guide.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, TensorData};

    #[test]
    fn the_result_moves_toward_the_guide_by_the_weight_of_each_pixel() {
        let d = Device::default();
        let t = |v: Vec<f32>, c| Tensor::<4>::from_data(TensorData::new(v, [1, c, 1, 2]), &d);
        let mix = LearnedMix {
            weight: MixWeights::Given(t(vec![0.25, 1.0], 1)),
            guide: t(vec![2.0, 4.0, 2.0, 4.0, 2.0, 4.0], 3),
        };
        let out = mix
            .apply(t(vec![1.0, 1.0, 0.0, 1.0, 6.0, 1.0], 3))
            .to_data()
            .try_to_vec::<f32>()
            .unwrap();
        let want = [1.25, 4.0, 0.5, 4.0, 5.0, 4.0];
        for (o, w) in out.iter().zip(want) {
            assert!((o - w).abs() < 1e-6, "{out:?} vs {want:?}");
        }
    }
}
