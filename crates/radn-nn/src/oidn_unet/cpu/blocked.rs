//! The feature maps of the U-Net's CPU path: channels in blocks of [`LANES`] (one vector
//! register), each block an image of pixels of [`LANES`] floats, with a one-pixel zero border
//! so that a 3×3 convolution reads its padding without a branch. Pooling and upsampling work on
//! this layout in place of burn's.

use rayon::prelude::*;

/// Channels per block: one AVX2 register of f32.
pub const LANES: usize = 8;

/// Storage of feature maps kept for reuse between layers, tiles and frames: a map's buffer goes
/// back here when the network is done with it and serves the next map that fits in it (the
/// smallest that does), so a frame does not fault in fresh pages for every layer (at 1080p the
/// large U-Net's maps add up to several GB of first touches per frame). It holds about the most
/// one tile needed at once.
#[derive(Default, Debug)]
pub struct Scratch {
    /// The kept buffers, each with whether it served a map since the last [`Scratch::trim`].
    free: std::sync::Mutex<Vec<(Vec<f32>, bool)>>,
    /// The largest tile (in pixels) its buffers were made for.
    largest: std::sync::atomic::AtomicUsize,
}

impl Scratch {
    /// A buffer of `len` floats: the smallest kept one that holds them (old contents), else a
    /// zeroed one.
    fn take(&self, len: usize) -> (Vec<f32>, bool) {
        let mut free = self.free.lock().expect("no panic while held");
        let best = (0..free.len())
            .filter(|&i| free[i].0.capacity() >= len)
            .min_by_key(|&i| free[i].0.capacity());
        match best {
            Some(i) => {
                let (mut b, _) = free.swap_remove(i);
                b.resize(len, 0.0);
                (b, true)
            }
            None => (vec![0.0; len], false),
        }
    }

    /// Keeps `map`'s buffer for a later map of its size.
    pub fn recycle(&self, map: Blocked) {
        self.free
            .lock()
            .expect("no panic while held")
            .push((map.data, true));
    }

    /// Frees the kept buffers that served no map since the last trim (called after each run
    /// of a network over a frame or band, so a buffer no network used is not kept).
    pub fn trim(&self) {
        let mut free = self.free.lock().expect("no panic while held");
        free.retain(|(_, used)| *used);
        for (_, used) in free.iter_mut() {
            *used = false;
        }
    }

    /// Readies it for tiles of at most `pixels`: buffers made for smaller tiles are dropped
    /// when a larger one comes, so that the larger tile's maps are each made to measure
    /// (rather than some of them in buffers a little too small to serve the next tile's).
    /// Tiles run largest first.
    pub fn prepare_for(&self, pixels: usize) {
        use std::sync::atomic::Ordering;
        if pixels > self.largest.load(Ordering::Relaxed) {
            self.clear();
            self.largest.store(pixels, Ordering::Relaxed);
        }
    }

    /// Bytes of the buffers it keeps (all of its maps, between runs).
    pub fn kept_bytes(&self) -> usize {
        let free = self.free.lock().expect("no panic while held");
        free.iter().map(|(b, _)| b.capacity() * 4).sum()
    }

    /// Frees every kept buffer.
    pub fn clear(&self) {
        self.free.lock().expect("no panic while held").clear();
    }
}

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

    /// A map from `scratch` whose border is zero and whose interior (every lane of every block)
    /// the caller overwrites whole.
    pub fn bordered_in(scratch: &Scratch, channels: usize, height: usize, width: usize) -> Self {
        let blocks = channels.div_ceil(LANES);
        let (data, reused) = scratch.take(blocks * (height + 2) * (width + 2) * LANES);
        let mut m = Self {
            channels,
            height,
            width,
            data,
        };
        if reused {
            m.zero_border();
        }
        m
    }

    /// Zeroes the one-pixel border of every block.
    fn zero_border(&mut self) {
        let (rs, bs, w, h) = (
            self.row_stride(),
            self.block_stride(),
            self.width,
            self.height,
        );
        self.data.par_chunks_mut(bs).for_each(|block| {
            block[..rs].fill(0.0);
            block[(h + 1) * rs..].fill(0.0);
            for y in 1..=h {
                block[y * rs..y * rs + LANES].fill(0.0);
                block[y * rs + (w + 1) * LANES..(y + 1) * rs].fill(0.0);
            }
        });
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

    /// A map of `channels` from `scratch` of `height × width`, each interior row written by
    /// `row(block, y, lanes)` (the row's `width · LANES` floats), blocks in parallel.
    fn rows_from(
        scratch: &Scratch,
        channels: usize,
        (height, width): (usize, usize),
        row: impl Fn(usize, usize, &mut [f32]) + Sync,
    ) -> Blocked {
        let mut out = Blocked::bordered_in(scratch, channels, height, width);
        let (rs, bs) = (out.row_stride(), out.block_stride());
        out.data
            .par_chunks_mut(bs)
            .enumerate()
            .for_each(|(b, block)| {
                for y in 0..height {
                    row(b, y, &mut block[(y + 1) * rs + LANES..(y + 2) * rs - LANES]);
                }
            });
        out
    }

    /// 2×2 max pooling with stride 2 (sizes must be even), into a map from `scratch`.
    pub fn max_pool(&self, scratch: &Scratch) -> Blocked {
        assert!(
            self.height.is_multiple_of(2) && self.width.is_multiple_of(2),
            "even sizes"
        );
        let size = (self.height / 2, self.width / 2);
        Self::rows_from(scratch, self.channels, size, |b, y, row| {
            let top = &self.data[self.offset(b, 2 * y, 0)..];
            let bottom = &self.data[self.offset(b, 2 * y + 1, 0)..];
            for (x, px) in row.chunks_exact_mut(LANES).enumerate() {
                for (l, v) in px.iter_mut().enumerate() {
                    let (i, j) = (2 * x * LANES + l, (2 * x + 1) * LANES + l);
                    *v = top[i].max(top[j]).max(bottom[i].max(bottom[j]));
                }
            }
        })
    }

    /// Nearest-neighbour upsampling by 2, into a map from `scratch`.
    pub fn upsample(&self, scratch: &Scratch) -> Blocked {
        let size = (self.height * 2, self.width * 2);
        Self::rows_from(scratch, self.channels, size, |b, y, row| {
            let from = &self.data[self.offset(b, y / 2, 0)..];
            for (x, px) in row.chunks_exact_mut(LANES).enumerate() {
                px.copy_from_slice(&from[(x / 2) * LANES..(x / 2 + 1) * LANES]);
            }
        })
    }

    /// The map as planar `channels × height × width` floats (NCHW of one image). Each block's
    /// row is read once for all its channels (a pass per channel would read the whole map
    /// once per channel).
    pub fn to_planar(&self) -> Vec<f32> {
        let mut out = vec![0.0; self.channels * self.height * self.width];
        self.to_planar_into(&mut out);
        out
    }

    /// [`Blocked::to_planar`] into `out` (`channels × height × width` floats).
    pub fn to_planar_into(&self, out: &mut [f32]) {
        let (h, w) = (self.height, self.width);
        assert_eq!(
            out.len(),
            self.channels * h * w,
            "a planar map of the same size"
        );
        let mut planes: Vec<&mut [f32]> = out.chunks_mut(h * w).collect();
        for b in 0..self.channels.div_ceil(LANES) {
            let group: Vec<&mut [f32]> = planes
                .drain(..LANES.min(self.channels - b * LANES))
                .collect();
            // the block's rows, each with its channels' rows of the output
            let mut rows: Vec<Vec<&mut [f32]>> =
                (0..h).map(|_| Vec::with_capacity(LANES)).collect();
            for plane in group {
                for (y, row) in plane.chunks_mut(w).enumerate() {
                    rows[y].push(row);
                }
            }
            rows.into_par_iter().enumerate().for_each(|(y, mut lanes)| {
                let src = &self.data[self.offset(b, y, 0)..][..w * LANES];
                for (x, px) in src.chunks_exact(LANES).enumerate() {
                    for (lane, row) in lanes.iter_mut().enumerate() {
                        row[x] = px[lane];
                    }
                }
            });
        }
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
        let scratch = Scratch::default();
        let p = m.max_pool(&scratch);
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
        // a reused buffer, dirty: the border is still zeroed and the interior overwritten
        let mut dirty = Blocked::zeros(c, h, w);
        dirty.data_mut().fill(7.0);
        scratch.recycle(dirty);
        let u = p.upsample(&scratch);
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
