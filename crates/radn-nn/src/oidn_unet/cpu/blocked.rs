//! The feature maps of the U-Net's CPU path: channels in blocks of [`LANES`] (one vector
//! register), each block an image of pixels of [`LANES`] floats, with a one-pixel zero border
//! so that a 3×3 convolution reads its padding without a branch. Pooling and upsampling work on
//! this layout in place of burn's.

use rayon::prelude::*;

/// Channels per block: one AVX2 register of f32.
pub const LANES: usize = 8;

/// A feature map in channel blocks with a zero border.
#[derive(Clone, Debug)]
pub struct Blocked {
    channels: usize,
    height: usize,
    width: usize,
    data: Vec<f32>,
}

impl Blocked {
    /// A zero map of `channels × height × width` (border included).
    pub fn zeros(channels: usize, height: usize, width: usize) -> Self {
        let blocks = channels.div_ceil(LANES);
        Self {
            channels,
            height,
            width,
            data: vec![0.0; blocks * (height + 2) * (width + 2) * LANES],
        }
    }

    /// Real channels (the last block may be padded with zeros).
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Channel blocks.
    pub fn blocks(&self) -> usize {
        self.channels.div_ceil(LANES)
    }

    /// Rows, border excluded.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Columns, border excluded.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Floats from one padded row to the next.
    pub fn row_stride(&self) -> usize {
        (self.width + 2) * LANES
    }

    /// Floats from one block to the next.
    pub fn block_stride(&self) -> usize {
        (self.height + 2) * self.row_stride()
    }

    /// Offset of interior pixel `(x, y)` of block `b` (its first lane).
    pub fn offset(&self, b: usize, y: usize, x: usize) -> usize {
        b * self.block_stride() + (y + 1) * self.row_stride() + (x + 1) * LANES
    }

    /// The storage, border and padded lanes included.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// The storage, mutable: writers keep the border and padded lanes zero.
    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }

    /// Value of channel `c` at interior pixel `(x, y)`.
    pub fn get(&self, c: usize, y: usize, x: usize) -> f32 {
        self.data[self.offset(c / LANES, y, x) + c % LANES]
    }

    /// Sets channel `c` at interior pixel `(x, y)`.
    pub fn set(&mut self, c: usize, y: usize, x: usize, v: f32) {
        let o = self.offset(c / LANES, y, x) + c % LANES;
        self.data[o] = v;
    }

    /// 2×2 max pooling with stride 2 (sizes must be even).
    pub fn max_pool(&self) -> Blocked {
        assert!(
            self.height.is_multiple_of(2) && self.width.is_multiple_of(2),
            "even sizes"
        );
        let mut out = Blocked::zeros(self.channels, self.height / 2, self.width / 2);
        let (oh, ow) = (out.height, out.width);
        let (ors, obs) = (out.row_stride(), out.block_stride());
        let src = self;
        out.data
            .par_chunks_mut(obs)
            .enumerate()
            .for_each(|(b, block)| {
                for y in 0..oh {
                    let row = &mut block[(y + 1) * ors..(y + 2) * ors];
                    let top = src.offset(b, 2 * y, 0);
                    let bottom = src.offset(b, 2 * y + 1, 0);
                    for x in 0..ow {
                        for l in 0..LANES {
                            let a = src.data[top + 2 * x * LANES + l];
                            let b_ = src.data[top + (2 * x + 1) * LANES + l];
                            let c = src.data[bottom + 2 * x * LANES + l];
                            let d = src.data[bottom + (2 * x + 1) * LANES + l];
                            row[(x + 1) * LANES + l] = a.max(b_).max(c.max(d));
                        }
                    }
                }
            });
        out
    }

    /// Nearest-neighbour upsampling by 2.
    pub fn upsample(&self) -> Blocked {
        let mut out = Blocked::zeros(self.channels, self.height * 2, self.width * 2);
        let (oh, ow) = (out.height, out.width);
        let (ors, obs) = (out.row_stride(), out.block_stride());
        let src = self;
        out.data
            .par_chunks_mut(obs)
            .enumerate()
            .for_each(|(b, block)| {
                for y in 0..oh {
                    let row = &mut block[(y + 1) * ors..(y + 2) * ors];
                    let from = src.offset(b, y / 2, 0);
                    for x in 0..ow {
                        let s = from + (x / 2) * LANES;
                        row[(x + 1) * LANES..(x + 2) * LANES]
                            .copy_from_slice(&src.data[s..s + LANES]);
                    }
                }
            });
        out
    }

    /// The map as planar `channels × height × width` floats (NCHW of one image).
    pub fn to_planar(&self) -> Vec<f32> {
        let (h, w) = (self.height, self.width);
        let mut out = vec![0.0; self.channels * h * w];
        out.par_chunks_mut(h * w)
            .enumerate()
            .for_each(|(c, plane)| {
                for y in 0..h {
                    let o = self.offset(c / LANES, y, 0) + c % LANES;
                    for x in 0..w {
                        plane[y * w + x] = self.data[o + x * LANES];
                    }
                }
            });
        out
    }

    /// A map from planar `channels × height × width` floats.
    pub fn from_planar(planar: &[f32], channels: usize, height: usize, width: usize) -> Blocked {
        assert_eq!(planar.len(), channels * height * width);
        let mut out = Blocked::zeros(channels, height, width);
        for c in 0..channels {
            for y in 0..height {
                let o = out.offset(c / LANES, y, 0) + c % LANES;
                for x in 0..width {
                    out.data[o + x * LANES] = planar[(c * height + y) * width + x];
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pooling_and_upsampling_keep_channels_apart_and_the_border_zero() {
        let (c, h, w) = (11, 4, 6);
        let planar: Vec<f32> = (0..c * h * w)
            .map(|i| (i * 37 % 101) as f32 - 50.0)
            .collect();
        let m = Blocked::from_planar(&planar, c, h, w);
        assert_eq!(m.to_planar(), planar);
        let p = m.max_pool();
        for ch in 0..c {
            for y in 0..h / 2 {
                for x in 0..w / 2 {
                    let want = [(0, 0), (0, 1), (1, 0), (1, 1)]
                        .iter()
                        .map(|&(dy, dx)| planar[(ch * h + 2 * y + dy) * w + 2 * x + dx])
                        .fold(f32::MIN, f32::max);
                    assert_eq!(p.get(ch, y, x), want);
                }
            }
        }
        let u = p.upsample();
        assert_eq!((u.height(), u.width()), (h, w));
        for ch in 0..c {
            for y in 0..h {
                for x in 0..w {
                    assert_eq!(u.get(ch, y, x), p.get(ch, y / 2, x / 2));
                }
            }
        }
        // padded lanes and the border stay zero
        let inside: f32 = u.to_planar().iter().map(|v| v.abs()).sum();
        let all: f32 = u.data().iter().map(|v| v.abs()).sum();
        assert_eq!(inside, all);
    }
}
