//! The fine-tune's windows: which tiles, levels, crops and frames a step or a validation
//! draws, and the processed window and PU target tensors they make.

use std::path::PathBuf;

use burn::tensor::{Device, Tensor, TensorData};

use radn_core::guide::exposure::ExposureBins;
use radn_core::Plane;
use radn_nn::oidn_unet::transfer::{AUX_ALBEDO, AUX_NORMAL, HDR_BEAUTY};
use radn_nn::{NnError, Result};

use crate::dataset::{Tile, TileDataset, TARGET_LEVELS};

/// One window of a batch: tile, input and target levels, crop corner, and which of the tile's
/// frames fills each window slot (all of them in order, or a pair without the centre).
#[derive(Clone, Debug)]
pub(super) struct Draw {
    pub(super) tile: usize,
    pub(super) input: usize,
    pub(super) target: usize,
    pub(super) corner: (usize, usize),
    pub(super) frames: Vec<usize>,
}

/// A batch as tensors: processed windows `[B · T, 9, S, S]` and targets in PU `[B, 3, S, S]`.
pub(super) struct Batch {
    pub(super) window: Tensor<4>,
    pub(super) target: Tensor<4>,
}

/// `term`: 0 the whole window in order; k ≥ 1 the pair (k − 1, k + t/2), one frame before
/// the centre and one after (for 5 frames: the first and fourth, the second and fifth, as
/// in the paper's Fig. 4), in alternate slots, the centre slot taking the earlier frame when
/// `earlier` and the later otherwise.
pub(super) fn window_frames(t: usize, term: usize, earlier: bool) -> Vec<usize> {
    if term == 0 {
        return (0..t).collect();
    }
    let (a, b) = (term - 1, term + t / 2);
    (0..t)
        .map(|slot| match slot {
            s if s == t / 2 => {
                if earlier {
                    a
                } else {
                    b
                }
            }
            s if s % 2 == 0 => a,
            _ => b,
        })
        .collect()
}

/// The first `n` validation tiles and the target each is scored against: the tiles with a
/// clean reference (the pseudo-reference slot, e.g. `radn prepare --pseudo ref`) against it
/// when the set has any, else the first tiles against their 32-spp render (itself noisy).
pub(super) fn validation_plan(val: &TileDataset, n: usize) -> Result<Vec<(usize, usize)>> {
    let clean = TARGET_LEVELS.len() - 1;
    let mut plan = Vec::new();
    if val.manifest.with_pseudo > 0 {
        for i in 0..val.len() {
            if plan.len() == n {
                break;
            }
            if val.get(i)?.targets[clean].is_some() {
                plan.push((i, clean));
            }
        }
    }
    if plan.is_empty() {
        plan = (0..n.min(val.len()).max(1)).map(|i| (i, 0)).collect();
    }
    Ok(plan)
}

/// The target level for an input level (indices into the tiles' `high`, `half`, `low` and
/// theirs): an independent render, the cleanest other one.
pub(super) fn target_for(input: usize) -> usize {
    if input == 0 {
        1
    } else {
        0
    }
}

/// Processed windows and PU targets of `plan` (tile, input level, target level, crop corner);
/// the centre slot of a whole window reads the mean of the middle `input_frames` frames (the
/// tiles' windows are aligned, as inference aligns them before averaging).
pub(super) fn batch(
    set: &TileDataset,
    plan: &[Draw],
    crop: usize,
    input_frames: usize,
    device: &Device,
) -> Result<Batch> {
    let m = &set.manifest;
    let (t, s) = (m.frames, m.tile);
    let mut window = Vec::with_capacity(plan.len() * t * 9 * crop * crop);
    let mut target = Vec::with_capacity(plan.len() * 3 * crop * crop);
    for d in plan {
        let (i, input, want, (x0, y0)) = (d.tile, d.input, d.target, d.corner);
        let tile: Tile = set.get(i)?;
        let at = |plane: usize, x: usize, y: usize| plane * s * s + (y0 + y) * s + x0 + x;
        let colour = &tile.values[input];
        let features = &tile.features[input];
        let channels = m.feature_channels;
        // the centre slot's OIDN autoexposure over the crop
        let centre = d.frames[t / 2];
        let mut rgb = Plane::zeros(crop, crop, 3);
        for c in 0..3 {
            for y in 0..crop {
                for x in 0..crop {
                    rgb.channel_mut(c)[y * crop + x] = colour[at(centre * 3 + c, x, y)];
                }
            }
        }
        let mut bins = ExposureBins::new(crop, crop);
        bins.add_rows(0, &rgb);
        let scale = bins.exposure();
        let whole = d.frames.iter().copied().eq(0..t);
        let averaged: Vec<usize> = (t / 2 - input_frames / 2..=t / 2 + input_frames / 2).collect();
        for (slot, &k) in d.frames.iter().enumerate() {
            // the frames whose colour this slot reads (their mean)
            let sources = if whole && slot == t / 2 {
                averaged.as_slice()
            } else {
                std::slice::from_ref(&k)
            };
            for c in 0..3 {
                for y in 0..crop {
                    for x in 0..crop {
                        let sum: f32 = sources.iter().map(|&j| colour[at(j * 3 + c, x, y)]).sum();
                        window.push(HDR_BEAUTY.input(sum / sources.len() as f32, scale));
                    }
                }
            }
            let planes = [
                (k * channels + 3, AUX_ALBEDO),
                (k * channels + 6, AUX_NORMAL),
            ];
            for (first, processing) in planes {
                for c in 0..3 {
                    for y in 0..crop {
                        for x in 0..crop {
                            window.push(processing.input(features[at(first + c, x, y)], scale));
                        }
                    }
                }
            }
        }
        // the wanted target, else the cleanest other render the tile has (never the input's
        // own, which is not independent of it)
        let levels = tile.targets.len();
        let goal = std::iter::once(want)
            .chain(0..levels)
            .filter(|&l| l != input)
            .find_map(|l| tile.targets[l].as_ref())
            .ok_or_else(|| NnError::Tiles {
                path: PathBuf::from("(tile)"),
                detail: format!("tile {i} has no target"),
            })?;
        for c in 0..3 {
            for y in 0..crop {
                for x in 0..crop {
                    target.push(HDR_BEAUTY.input(goal[at(c, x, y)], scale));
                }
            }
        }
    }
    let b = plan.len();
    Ok(Batch {
        window: Tensor::from_data(TensorData::new(window, [b * t, 9, crop, crop]), device),
        target: Tensor::from_data(TensorData::new(target, [b, 3, crop, crop]), device),
    })
}

#[cfg(test)]
mod tests {
    use super::window_frames;

    #[test]
    fn the_temporal_terms_are_the_papers_pairs_without_the_centre() {
        assert_eq!(window_frames(5, 0, true), vec![0, 1, 2, 3, 4]);
        // first and fourth, second and fifth: never the centre frame
        assert_eq!(window_frames(5, 1, true), vec![0, 3, 0, 3, 0]);
        assert_eq!(window_frames(5, 1, false), vec![0, 3, 3, 3, 0]);
        assert_eq!(window_frames(5, 2, true), vec![1, 4, 1, 4, 1]);
        assert_eq!(window_frames(3, 1, false), vec![0, 2, 0]);
    }
}
