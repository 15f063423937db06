//! Batches: tiles cropped and stacked with their chosen input and target levels, as the
//! tensors a training step feeds the network.

use burn::tensor::{Device, Tensor, TensorData};

use crate::dataset::Tile;
use radn_nn::infer::input::network_features;
use radn_nn::model::config::{InputConfig, NetConfig, INPUT_CHANNELS};

/// A batch as tensors: features `[B,T,C,S,S]`, values `[B,T,3,S,S]`, target `[B,3,S,S]`.
pub struct Batch {
    /// Network input.
    pub features: Tensor<5>,
    /// Linear colour the kernels are applied to.
    pub values: Tensor<5>,
    /// Centre target.
    pub target: Tensor<4>,
    /// The centre frame's guide (linear colour) `[B, 3, S, S]`, for a network that reads one.
    pub guide: Option<Tensor<4>>,
    /// Per tile, the reciprocal of the exposure its colour features were divided by
    /// (`[B, 1, 1, 1]`; 1 without exposure normalisation).
    pub inv_exposure: Tensor<4>,
}

/// Crops and stacks tiles with their chosen (input, target) levels, with the input features
/// a network configured with `inputs` reads (tiles of format 2 when it asks for exposure
/// normalisation: [`crate::trainer::Trainer::new`] checks).
pub fn make_batch(
    tiles: &[(Tile, usize, usize, usize, usize)],
    frames: usize,
    tile: usize,
    crop: usize,
    inputs: &InputConfig,
    device: &Device,
) -> Batch {
    let b = tiles.len();
    let (mut f, mut v, mut t) = (Vec::new(), Vec::new(), Vec::new());
    let mut centre_guides = Vec::new();
    let mut inv_exposure = Vec::new();
    let cut = |data: &[f32], planes: usize, x0: usize, y0: usize, out: &mut Vec<f32>| {
        for p in 0..planes {
            for y in y0..y0 + crop {
                out.extend_from_slice(
                    &data[p * tile * tile + y * tile + x0..p * tile * tile + y * tile + x0 + crop],
                );
            }
        }
    };
    for (tl, input, target, x0, y0) in tiles {
        let mut base = Vec::with_capacity(frames * INPUT_CHANNELS * crop * crop);
        cut(
            &tl.features[*input],
            frames * INPUT_CHANNELS,
            *x0,
            *y0,
            &mut base,
        );
        let mut colour = Vec::with_capacity(frames * 3 * crop * crop);
        cut(&tl.values[*input], frames * 3, *x0, *y0, &mut colour);
        let guide = inputs.guide.then(|| {
            let mut g = Vec::with_capacity(frames * 3 * crop * crop);
            let stored = tl.guides[*input]
                .as_ref()
                .expect("a guided network trains on guided tiles (checked by Trainer::new)");
            cut(stored, frames * 3, *x0, *y0, &mut g);
            let centre = frames / 2 * 3 * crop * crop;
            centre_guides.extend_from_slice(&g[centre..centre + 3 * crop * crop]);
            g
        });
        let exposure = match tl.exposure[*input] {
            Some(e) => e,
            None if inputs.exposure => panic!("exposure normalisation needs format-2 tiles"),
            None => 1.0,
        };
        inv_exposure.push(if inputs.exposure { 1.0 / exposure } else { 1.0 });
        f.extend(network_features(
            base,
            &colour,
            guide.as_deref(),
            frames,
            crop * crop,
            inputs,
            exposure,
        ));
        v.extend(colour);
        cut(
            tl.targets[*target].as_ref().expect("sampled targets exist"),
            3,
            *x0,
            *y0,
            &mut t,
        );
    }
    Batch {
        features: Tensor::from_data(
            TensorData::new(f, [b, frames, inputs.channels(), crop, crop]),
            device,
        ),
        values: Tensor::from_data(TensorData::new(v, [b, frames, 3, crop, crop]), device),
        target: Tensor::from_data(TensorData::new(t, [b, 3, crop, crop]), device),
        guide: inputs
            .guide
            .then(|| Tensor::from_data(TensorData::new(centre_guides, [b, 3, crop, crop]), device)),
        inv_exposure: Tensor::from_data(TensorData::new(inv_exposure, [b, 1, 1, 1]), device),
    }
}

/// A batch's colour values `[B, T, 3, S, S]` blended toward their guides by `beta`, for a
/// network with the guide blend (`beta` is `None` without one: the values as they are).
pub(crate) fn blend_values(
    config: &NetConfig,
    features: &Tensor<5>,
    beta: Option<Tensor<5>>,
    values: Tensor<5>,
) -> Tensor<5> {
    match beta {
        Some(beta) => {
            radn_nn::model::guide_blend::GuideBlend::new(features, beta, &config.inputs, vec![0], 3)
                .apply(values)
        }
        None => values,
    }
}
