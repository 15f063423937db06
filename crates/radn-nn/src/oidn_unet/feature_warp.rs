//! Pre-warping a window's encoder features to its centre frame (paper §3, applied per level):
//! each frame's features at scale 1/2^k are resampled along the motion to the centre, scaled
//! to that level, and mixed with the centre's own features where alignment is unsure. The
//! encoder then runs once per frame, as rendered, and serves every window the frame is in.

use burn::tensor::module::avg_pool2d;
use burn::tensor::ops::{
    AvgPoolOptions, GridSampleOptions, GridSamplePaddingMode, InterpolateMode,
};
use burn::tensor::{Tensor, TensorData};

/// How a window's frames map onto its centre, at full resolution, for `[batch · frames]`
/// frames (frames consecutive within each batch item).
#[derive(Clone, Debug)]
pub struct WindowMotion {
    /// `[batch · frames, 2, H, W]`: for each pixel of the centre frame, where that point lies in
    /// the window frame, as (dx, dy) pixels from the same pixel (x right, y down); zero for
    /// the centre frame itself.
    pub offsets: Tensor<4>,
    /// `[batch · frames, 1, H, W]`: how far to trust each warped pixel, in [0, 1] (radn's
    /// per-pixel alignment confidence); the centre's features fill in the rest.
    pub confidence: Tensor<4>,
}

impl WindowMotion {
    /// The motion at pyramid level `level` (scale 1/2^level): offsets averaged over each
    /// 2^level block and divided by 2^level; confidence averaged.
    pub fn at_level(&self, level: usize) -> WindowMotion {
        if level == 0 {
            return self.clone();
        }
        let k = 1 << level;
        let pool = |t: Tensor<4>| avg_pool2d(t, AvgPoolOptions::new([k, k]));
        WindowMotion {
            offsets: pool(self.offsets.clone()) / k as f32,
            confidence: pool(self.confidence.clone()),
        }
    }
}

/// Bilinear resampling of `features` (`[n, c, h, w]`) at each pixel plus `offsets`
/// (`[n, 2, h, w]`, in pixels), clamped to the map's edges.
pub fn warp(features: Tensor<4>, offsets: Tensor<4>) -> Tensor<4> {
    let [n, _, h, w] = features.dims();
    let device = features.device();
    // pixel centres in grid_sample's coordinates (align_corners: -1 and 1 are the corner
    // pixels' centres); a side of one pixel has a single position
    let norm = |size: usize| {
        if size > 1 {
            2.0 / (size - 1) as f32
        } else {
            0.0
        }
    };
    let coords = |n: usize, shape: [usize; 4]| -> Tensor<4> {
        Tensor::from_data(
            TensorData::new((0..n).map(|i| i as f32).collect::<Vec<_>>(), shape),
            &device,
        )
    };
    let (xs, ys) = (coords(w, [1, 1, 1, w]), coords(h, [1, 1, h, 1]));
    let gx = (offsets.clone().narrow(1, 0, 1) + xs) * norm(w) - 1.0;
    let gy = (offsets.narrow(1, 1, 1) + ys) * norm(h) - 1.0;
    // [n, 2, h, w] -> [n, h, w, 2]
    let grid = Tensor::cat(vec![gx, gy], 1).permute([0, 2, 3, 1]);
    let _ = n;
    features.grid_sample_2d(
        grid,
        GridSampleOptions::new(InterpolateMode::Bilinear)
            .with_padding_mode(GridSamplePaddingMode::Border)
            .with_align_corners(true),
    )
}

/// A window's features (`[batch · frames, c, h, w]`, one level) warped to its centre frame and
/// mixed with the centre's features by the confidence (`motion` at that level): where the
/// confidence is 0 a side frame contributes the centre's own features.
pub fn to_centre(features: Tensor<4>, frames: usize, motion: &WindowMotion) -> Tensor<4> {
    let [bt, c, h, w] = features.dims();
    let b = bt / frames;
    let centre: Tensor<4> = features
        .clone()
        .reshape([b, frames, c, h, w])
        .narrow(1, frames / 2, 1)
        .repeat_dim(1, frames)
        .reshape([bt, c, h, w]);
    let warped = warp(features, motion.offsets.clone());
    let conf = motion.confidence.clone();
    warped * conf.clone() + centre * (conf.neg() + 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Device;

    fn t4(v: Vec<f32>, shape: [usize; 4]) -> Tensor<4> {
        Tensor::from_data(TensorData::new(v, shape), &Device::flex())
    }

    fn vec(t: Tensor<4>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().unwrap()
    }

    #[test]
    fn an_integer_offset_moves_features_by_that_many_pixels() {
        // a 2-channel 6×7 map sampled 2 right and 1 down: interior pixels read (x + 2, y + 1),
        // those past the edge the edge's value
        let (h, w) = (6, 7);
        let f = |c: usize, x: usize, y: usize| (c * 100 + y * 10 + x) as f32;
        let features = t4(
            (0..2 * h * w)
                .map(|i| f(i / (h * w), i % w, (i / w) % h))
                .collect(),
            [1, 2, h, w],
        );
        let offsets = t4(
            (0..2 * h * w)
                .map(|i| if i < h * w { 2.0 } else { 1.0 })
                .collect(),
            [1, 2, h, w],
        );
        let out = vec(warp(features, offsets));
        for c in 0..2 {
            for y in 0..h {
                for x in 0..w {
                    let want = f(c, (x + 2).min(w - 1), (y + 1).min(h - 1));
                    let got = out[(c * h + y) * w + x];
                    assert!(
                        (got - want).abs() < 1e-4,
                        "({c}, {x}, {y}): {got} vs {want}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_half_pixel_offset_interpolates_and_levels_scale_the_motion() {
        let (h, w) = (4, 8);
        let features = t4((0..h * w).map(|i| (i % w) as f32).collect(), [1, 1, h, w]);
        let offsets = t4(
            (0..2 * h * w)
                .map(|i| if i < h * w { 0.5 } else { 0.0 })
                .collect(),
            [1, 2, h, w],
        );
        let out = vec(warp(features, offsets.clone()));
        assert!((out[3] - 3.5).abs() < 1e-5, "{}", out[3]);
        // 4 pixels of motion at full resolution are 1 at level 2
        let m = WindowMotion {
            offsets: offsets * 8.0,
            confidence: t4(vec![0.5; h * w], [1, 1, h, w]),
        }
        .at_level(2);
        assert_eq!(vec(m.offsets)[0], 1.0);
        assert_eq!(vec(m.confidence)[0], 0.5);
    }

    #[test]
    fn zero_confidence_gives_the_centres_features() {
        let (t, c, h, w) = (3, 2, 4, 5);
        let n = t * c * h * w;
        let features = t4((0..n).map(|i| i as f32).collect(), [t, c, h, w]);
        let motion = WindowMotion {
            offsets: t4(vec![1.5; t * 2 * h * w], [t, 2, h, w]),
            confidence: t4(vec![0.0; t * h * w], [t, 1, h, w]),
        };
        let out = vec(to_centre(features.clone(), t, &motion));
        let src = vec(features);
        for k in 0..t {
            for i in 0..c * h * w {
                assert_eq!(out[k * c * h * w + i], src[c * h * w + i]);
            }
        }
    }
}
