//! The U-Net's 3×3 convolutions on the CPU, computed directly on channel-blocked maps: each
//! micro-kernel keeps `OB` blocks of 8 output channels for `PX` neighbouring pixels in vector
//! registers and, for every input channel and tap, loads the `OB` weight vectors once and
//! broadcasts each pixel's input value against them (AVX2 and FMA; a plain loop elsewhere).
//! A concatenation is two sources read one after the other, never copied. Bias and ReLU are
//! applied while the accumulators are in registers.
//!
//! Why direct and blocked: with 32–384 input channels a 3×3 layer is compute-bound, and
//! vectorising along output channels makes every loaded weight vector serve `PX` pixels and
//! every broadcast input serve `OB` vectors, with no im2col copy and no GEMM packing. The
//! zero border of [`Blocked`] is the convolution's padding.

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

use rayon::prelude::*;

use crate::model::cpu::SendPtr;
use crate::oidn_unet::cpu::blocked::{Blocked, Scratch, LANES};

/// Floats of one packed weight tap (8 input lanes × 8 output lanes).
const TAP: usize = LANES * LANES;
/// Output columns per parallel job: a job's input rows (3 rows of every input block) stay
/// within a core's L2 cache at the widest layers.
const COLUMNS_PER_JOB: usize = 240;

/// A convolution's weights packed for the kernels: `[out block][in block][tap][in lane][out
/// lane]`, zero where a block's lanes pass the real channel counts, and its bias per output
/// block.
#[derive(Clone, Debug)]
pub struct PackedConv {
    cout: usize,
    in_blocks: usize,
    weights: Vec<f32>,
    bias: Vec<f32>,
}

impl PackedConv {
    /// Packs OIDN-layout (`oihw`) 3×3 weights whose input channels are the concatenation of
    /// sources with `parts` channels each (one part for a plain convolution).
    pub fn new(weight: &[f32], bias: &[f32], cout: usize, parts: &[usize]) -> Self {
        let cin: usize = parts.iter().sum();
        assert_eq!(weight.len(), cout * cin * 9, "3×3 weights of {cout}×{cin}");
        assert_eq!(bias.len(), cout);
        let out_blocks = cout.div_ceil(LANES);
        let in_blocks: usize = parts.iter().map(|p| p.div_ceil(LANES)).sum();
        let mut weights = vec![0.0; out_blocks * in_blocks * 9 * TAP];
        // the packed input block and lane of every input channel
        let mut slots = Vec::with_capacity(cin);
        let mut first_block = 0;
        for &p in parts {
            for c in 0..p {
                slots.push((first_block + c / LANES, c % LANES));
            }
            first_block += p.div_ceil(LANES);
        }
        for o in 0..cout {
            for (i, &(ib, il)) in slots.iter().enumerate() {
                for tap in 0..9 {
                    let at =
                        (((o / LANES) * in_blocks + ib) * 9 + tap) * TAP + il * LANES + o % LANES;
                    weights[at] = weight[(o * cin + i) * 9 + tap];
                }
            }
        }
        let mut b = vec![0.0; out_blocks * LANES];
        b[..cout].copy_from_slice(bias);
        Self {
            cout,
            in_blocks,
            weights,
            bias: b,
        }
    }

    /// Output channels.
    pub fn out_channels(&self) -> usize {
        self.cout
    }

    /// `relu(conv(concat(sources)) + bias)` into a map of the sources' size from `scratch`.
    pub fn run(&self, sources: &[&Blocked], scratch: &Scratch) -> Blocked {
        self.run_fused(sources, scratch, Fused::default())
    }

    /// [`PackedConv::run`] with the neighbouring resampling steps folded in, so that the
    /// full-resolution map between them is never stored: the first source read upsampled
    /// (nearest, by 2) and the output max-pooled (2×2), as [`Fused`] says. The result is the
    /// same as running the steps one after another.
    pub fn run_fused(&self, sources: &[&Blocked], scratch: &Scratch, fused: Fused) -> Blocked {
        let up = |i: usize| fused.upsample_first && i == 0;
        let size = |i: usize, s: &Blocked| {
            let k = if up(i) { 2 } else { 1 };
            (s.height() * k, s.width() * k)
        };
        let (h, w) = size(0, sources[0]);
        let blocks: usize = sources.iter().map(|s| s.blocks()).sum();
        assert_eq!(
            blocks, self.in_blocks,
            "the sources' channels match the weights"
        );
        assert!(sources
            .iter()
            .enumerate()
            .all(|(i, s)| size(i, s) == (h, w)));
        let mut out = if fused.pool {
            assert!(h % 2 == 0 && w % 2 == 0, "even sizes to pool");
            Blocked::bordered_in(scratch, self.cout, h / 2, w / 2)
        } else {
            Blocked::bordered_in(scratch, self.cout, h, w)
        };
        // the input blocks in order, as (source, block within it, read upsampled)
        let ins: Vec<(&Blocked, usize, bool)> = sources
            .iter()
            .enumerate()
            .flat_map(|(i, s)| (0..s.blocks()).map(move |b| (*s, b, up(i))))
            .collect();
        let out_blocks = out.blocks();
        let groups = out_blocks.div_ceil(2);
        let chunks = w.div_ceil(COLUMNS_PER_JOB);
        let (rs, bs) = (out.row_stride(), out.block_stride());
        let dst = SendPtr(out.data_mut().as_mut_ptr());
        let isa = avx2();
        // a job's rows: one output row, or the two conv rows of one pooled row
        let rows = if fused.pool { h / 2 } else { h };
        (0..rows * chunks * groups).into_par_iter().for_each(|job| {
            let g = job % groups;
            let chunk = (job / groups) % chunks;
            let row = job / (groups * chunks);
            let ob = 2 * g;
            let two = ob + 1 < out_blocks;
            let x0 = chunk * COLUMNS_PER_JOB;
            let x1 = (x0 + COLUMNS_PER_JOB).min(w);
            let task = |y: usize, dst_row: *mut f32, out_bs: usize, x_origin: usize| Task {
                conv: self,
                ins: &ins,
                y,
                ob,
                dst_row,
                bs: out_bs,
                x_origin,
            };
            if !fused.pool {
                let dst_row = dst.get().wrapping_add(ob * bs + (row + 1) * rs + LANES);
                // SAFETY: each job writes only output row `row`, columns x0..x1, of blocks ob
                // and ob+1, which no other job writes; all reads are within the sources'
                // padded storage.
                unsafe { task(row, dst_row, bs, 0).columns(x0, x1, two, isa) };
                return;
            }
            // the two conv rows into a job-local buffer ([block][row][column] of 8 lanes),
            // then their 2×2 maxima into the pooled row
            let cols = x1 - x0;
            let mut local = vec![0.0f32; 2 * 2 * cols * LANES];
            let lbs = 2 * cols * LANES;
            for r in 0..2 {
                let dst_row = local.as_mut_ptr().wrapping_add(r * cols * LANES);
                // SAFETY: the local buffer holds both rows of both blocks for columns x0..x1
                unsafe { task(2 * row + r, dst_row, lbs, x0).columns(x0, x1, two, isa) };
            }
            for o in 0..if two { 2 } else { 1 } {
                let at = |r: usize, x: usize| (o * 2 + r) * cols * LANES + (x - x0) * LANES;
                let base = (ob + o) * bs + (row + 1) * rs;
                for xp in x0 / 2..x1 / 2 {
                    let (a, b) = (at(0, 2 * xp), at(1, 2 * xp));
                    for l in 0..LANES {
                        let m = local[a + l]
                            .max(local[a + LANES + l])
                            .max(local[b + l].max(local[b + LANES + l]));
                        // SAFETY: pooled row `row`, column xp, of block ob+o: written by this
                        // job alone
                        unsafe { *dst.get().add(base + (xp + 1) * LANES + l) = m };
                    }
                }
            }
        });
        out
    }
}

/// Which neighbouring steps a convolution folds in ([`PackedConv::run_fused`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Fused {
    /// Its first source is read upsampled by 2 (the step before it upsampled).
    pub upsample_first: bool,
    /// Its output is max-pooled 2×2 (the step after it pools).
    pub pool: bool,
}

/// One job: output row `y`, output blocks `ob` (and `ob + 1`).
struct Task<'a> {
    conv: &'a PackedConv,
    ins: &'a [(&'a Blocked, usize, bool)],
    y: usize,
    ob: usize,
    /// Where column `x_origin` of the row is written, for block `ob` (block `ob + 1`: `bs`
    /// floats on).
    dst_row: *mut f32,
    bs: usize,
    x_origin: usize,
}

/// Pixel offsets (in pixels) of the `PX` pixels a micro-kernel reads from a source at one
/// tap: consecutive for a plain source; for one read upsampled, each low-resolution pixel
/// twice, starting with a pair or a single one by the tap's column parity.
const PLAIN: [usize; 12] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11];
const UP_PAIR: [usize; 12] = [0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5];
const UP_SINGLE: [usize; 12] = [0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6];

/// Which of the offset patterns a tap's pixels follow.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Offsets {
    /// [`PLAIN`].
    Plain,
    /// [`UP_PAIR`].
    UpPair,
    /// [`UP_SINGLE`].
    UpSingle,
}

/// Whether the CPU runs the AVX2 and FMA kernels (detected once).
fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        static HAS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
        *HAS.get_or_init(|| is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma"))
    }
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// Pixels per AVX2 micro-kernel call with two output blocks (12 accumulators, 2 weight
/// registers and a broadcast: 15 of the 16).
const PX2: usize = 6;
/// Pixels per call with one output block.
const PX1: usize = 12;

impl Task<'_> {
    /// Output columns `x0..x1` of the task's row and blocks.
    ///
    /// # Safety
    /// `dst` must be the output map's storage, with the layout of `rs` and `bs`.
    unsafe fn columns(&self, x0: usize, x1: usize, two: bool, isa: bool) {
        #[cfg(target_arch = "x86_64")]
        if isa {
            let mut x = x0;
            if two {
                while x + PX2 <= x1 {
                    self.kernel_2x6(x);
                    x += PX2;
                }
                while x < x1 {
                    self.kernel::<2>(x);
                    x += 1;
                }
            } else {
                while x + PX1 <= x1 {
                    self.kernel_1x12(x);
                    x += PX1;
                }
                while x < x1 {
                    self.kernel::<1>(x);
                    x += 1;
                }
            }
            return;
        }
        let _ = isa;
        self.plain(x0, x1, if two { 2 } else { 1 });
    }

    /// Where the kernels read input block `ib`'s tap `tap` for the pixels from column `x` (8
    /// lanes each), that block and tap's packed weights for the task's first output block, and
    /// which pixel offsets the following pixels are at ([`PLAIN`], [`UP_PAIR`] or
    /// [`UP_SINGLE`]).
    #[inline(always)]
    unsafe fn tap(&self, ib: usize, tap: usize, x: usize) -> (*const f32, *const f32, Offsets) {
        let (src, sb, up) = self.ins[ib];
        let (ky, kx) = (tap / 3, tap % 3);
        // padded coordinates: output pixel x's tap kx reads column x + kx of the padded map;
        // of a map read upsampled, column (x + kx + 1) / 2 of the padded low-resolution one
        let (row, col, offsets) = if up {
            let c = x + kx + 1;
            let offsets = if c.is_multiple_of(2) {
                Offsets::UpPair
            } else {
                Offsets::UpSingle
            };
            ((self.y + ky).div_ceil(2), c / 2, offsets)
        } else {
            (self.y + ky, x + kx, Offsets::Plain)
        };
        let input = src
            .data()
            .as_ptr()
            .add(sb * src.block_stride() + row * src.row_stride() + col * LANES);
        let c = self.conv;
        let weights = c
            .weights
            .as_ptr()
            .add(((self.ob * c.in_blocks + ib) * 9 + tap) * TAP);
        (input, weights, offsets)
    }

    /// The task's output at column `x` of its first output block.
    #[inline(always)]
    unsafe fn out(&self, x: usize) -> *mut f32 {
        self.dst_row.add((x - self.x_origin) * LANES)
    }

    /// The micro-kernel for one pixel at column `x` and `OB` output blocks (the columns left
    /// over by the wide kernels).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn kernel<const OB: usize>(&self, x: usize) {
        let c = self.conv;
        let out = self.out(x);
        let mut acc = [_mm256_setzero_ps(); OB];
        for (o, a) in acc.iter_mut().enumerate() {
            *a = _mm256_loadu_ps(c.bias.as_ptr().add((self.ob + o) * LANES));
        }
        let wstride = c.in_blocks * 9 * TAP;
        for ib in 0..self.ins.len() {
            for tap in 0..9 {
                let (p, wt, _) = self.tap(ib, tap, x);
                for l in 0..LANES {
                    let s = _mm256_broadcast_ss(&*p.add(l));
                    for (o, a) in acc.iter_mut().enumerate() {
                        let w = _mm256_loadu_ps(wt.add(o * wstride + l * LANES));
                        *a = _mm256_fmadd_ps(w, s, *a);
                    }
                }
            }
        }
        let zero = _mm256_setzero_ps();
        for (o, a) in acc.iter().enumerate() {
            _mm256_storeu_ps(out.add(o * self.bs), _mm256_max_ps(*a, zero));
        }
    }

    /// The main micro-kernel: 2 output blocks × 6 pixels from column `x`, its 12
    /// accumulators named so that they stay in registers (the compiler keeps an array of them
    /// on the stack).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn kernel_2x6(&self, x: usize) {
        let c = self.conv;
        let out = self.out(x);
        let o1 = out.add(self.bs);
        let bias = |o: usize| _mm256_loadu_ps(c.bias.as_ptr().add((self.ob + o) * LANES));
        let (a, b) = (bias(0), bias(1));
        let (mut a0, mut a1, mut a2, mut a3, mut a4, mut a5) = (a, a, a, a, a, a);
        let (mut b0, mut b1, mut b2, mut b3, mut b4, mut b5) = (b, b, b, b, b, b);
        let wstride = c.in_blocks * 9 * TAP;
        macro_rules! px {
            ($p:ident, $offs:ident, $l:ident, $w0:ident, $w1:ident, $i:literal, $a:ident, $b:ident) => {
                let s = _mm256_broadcast_ss(&*$p.add($offs[$i] * LANES + $l));
                $a = _mm256_fmadd_ps($w0, s, $a);
                $b = _mm256_fmadd_ps($w1, s, $b);
            };
        }
        macro_rules! lanes {
            ($p:ident, $wt:ident, $offs:ident) => {
                for l in 0..LANES {
                    let w0 = _mm256_loadu_ps($wt.add(l * LANES));
                    let w1 = _mm256_loadu_ps($wt.add(wstride + l * LANES));
                    px!($p, $offs, l, w0, w1, 0, a0, b0);
                    px!($p, $offs, l, w0, w1, 1, a1, b1);
                    px!($p, $offs, l, w0, w1, 2, a2, b2);
                    px!($p, $offs, l, w0, w1, 3, a3, b3);
                    px!($p, $offs, l, w0, w1, 4, a4, b4);
                    px!($p, $offs, l, w0, w1, 5, a5, b5);
                }
            };
        }
        for ib in 0..self.ins.len() {
            for tap in 0..9 {
                let (p, wt, offsets) = self.tap(ib, tap, x);
                match offsets {
                    Offsets::Plain => lanes!(p, wt, PLAIN),
                    Offsets::UpPair => lanes!(p, wt, UP_PAIR),
                    Offsets::UpSingle => lanes!(p, wt, UP_SINGLE),
                }
            }
        }
        let zero = _mm256_setzero_ps();
        let st = |p: *mut f32, px: usize, v: __m256| {
            _mm256_storeu_ps(p.add(px * LANES), _mm256_max_ps(v, zero));
        };
        for (px, v) in [a0, a1, a2, a3, a4, a5].into_iter().enumerate() {
            st(out, px, v);
        }
        for (px, v) in [b0, b1, b2, b3, b4, b5].into_iter().enumerate() {
            st(o1, px, v);
        }
    }

    /// The micro-kernel for a single output block: 12 pixels from column `x`, accumulators
    /// named as in [`Self::kernel_2x6`].
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn kernel_1x12(&self, x: usize) {
        let c = self.conv;
        let out = self.out(x);
        let a = _mm256_loadu_ps(c.bias.as_ptr().add(self.ob * LANES));
        let (mut a0, mut a1, mut a2, mut a3, mut a4, mut a5) = (a, a, a, a, a, a);
        let (mut a6, mut a7, mut a8, mut a9, mut a10, mut a11) = (a, a, a, a, a, a);
        macro_rules! px {
            ($p:ident, $offs:ident, $l:ident, $w:ident, $i:literal, $a:ident) => {
                let s = _mm256_broadcast_ss(&*$p.add($offs[$i] * LANES + $l));
                $a = _mm256_fmadd_ps($w, s, $a);
            };
        }
        macro_rules! lanes {
            ($p:ident, $wt:ident, $offs:ident) => {
                for l in 0..LANES {
                    let w = _mm256_loadu_ps($wt.add(l * LANES));
                    px!($p, $offs, l, w, 0, a0);
                    px!($p, $offs, l, w, 1, a1);
                    px!($p, $offs, l, w, 2, a2);
                    px!($p, $offs, l, w, 3, a3);
                    px!($p, $offs, l, w, 4, a4);
                    px!($p, $offs, l, w, 5, a5);
                    px!($p, $offs, l, w, 6, a6);
                    px!($p, $offs, l, w, 7, a7);
                    px!($p, $offs, l, w, 8, a8);
                    px!($p, $offs, l, w, 9, a9);
                    px!($p, $offs, l, w, 10, a10);
                    px!($p, $offs, l, w, 11, a11);
                }
            };
        }
        for ib in 0..self.ins.len() {
            for tap in 0..9 {
                let (p, wt, offsets) = self.tap(ib, tap, x);
                match offsets {
                    Offsets::Plain => lanes!(p, wt, PLAIN),
                    Offsets::UpPair => lanes!(p, wt, UP_PAIR),
                    Offsets::UpSingle => lanes!(p, wt, UP_SINGLE),
                }
            }
        }
        let zero = _mm256_setzero_ps();
        for (px, v) in [a0, a1, a2, a3, a4, a5, a6, a7, a8, a9, a10, a11]
            .into_iter()
            .enumerate()
        {
            _mm256_storeu_ps(out.add(px * LANES), _mm256_max_ps(v, zero));
        }
    }

    /// The same computation without vector instructions.
    unsafe fn plain(&self, x0: usize, x1: usize, blocks: usize) {
        let c = self.conv;
        let wstride = c.in_blocks * 9 * TAP;
        for o in 0..blocks {
            for x in x0..x1 {
                let mut acc: [f32; LANES] =
                    c.bias[(self.ob + o) * LANES..][..LANES].try_into().unwrap();
                for ib in 0..self.ins.len() {
                    for tap in 0..9 {
                        let (p, wt, _) = self.tap(ib, tap, x);
                        let wt = wt.add(o * wstride);
                        for l in 0..LANES {
                            let s = *p.add(l);
                            for (ol, a) in acc.iter_mut().enumerate() {
                                *a = (*wt.add(l * LANES + ol)).mul_add(s, *a);
                            }
                        }
                    }
                }
                let out = self.out(x).add(o * self.bs);
                for (ol, a) in acc.iter().enumerate() {
                    *out.add(ol) = a.max(0.0);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The convolution by its definition on planar data, in f64.
    fn reference(
        x: &[f32],
        cin: usize,
        h: usize,
        w: usize,
        weight: &[f32],
        bias: &[f32],
    ) -> Vec<f32> {
        let cout = bias.len();
        let mut out = vec![0.0; cout * h * w];
        for o in 0..cout {
            for y in 0..h {
                for xx in 0..w {
                    let mut s = bias[o] as f64;
                    for i in 0..cin {
                        for ky in 0..3 {
                            for kx in 0..3 {
                                let (sy, sx) =
                                    (y as isize + ky as isize - 1, xx as isize + kx as isize - 1);
                                if sy < 0 || sx < 0 || sy >= h as isize || sx >= w as isize {
                                    continue;
                                }
                                s += weight[((o * cin + i) * 3 + ky) * 3 + kx] as f64
                                    * x[(i * h + sy as usize) * w + sx as usize] as f64;
                            }
                        }
                    }
                    out[(o * h + y) * w + xx] = s.max(0.0) as f32;
                }
            }
        }
        out
    }

    fn values(n: usize, seed: usize) -> Vec<f32> {
        (0..n)
            .map(|i| (((i * 7919 + seed * 104729) % 1000) as f32 / 500.0 - 1.0) * 0.3)
            .collect()
    }

    #[test]
    fn the_blocked_convolution_equals_its_definition_with_and_without_a_concatenation() {
        // odd channel counts, a remainder of columns and an odd number of output blocks
        for (parts, cout, h, w) in [
            (vec![9], 32, 5, 19),
            (vec![13, 9], 3, 4, 7),
            (vec![16, 24], 24, 3, 14),
        ] {
            let cin: usize = parts.iter().sum();
            let x = values(cin * h * w, 1);
            let weight = values(cout * cin * 9, 2);
            let bias = values(cout, 3);
            let want = reference(&x, cin, h, w, &weight, &bias);
            let mut sources = Vec::new();
            let mut at = 0;
            for &p in &parts {
                sources.push(Blocked::from_planar(
                    &x[at * h * w..(at + p) * h * w],
                    p,
                    h,
                    w,
                ));
                at += p;
            }
            let packed = PackedConv::new(&weight, &bias, cout, &parts);
            let got = packed
                .run(&sources.iter().collect::<Vec<_>>(), &Scratch::default())
                .to_planar();
            let worst = got
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(worst < 1e-5, "{parts:?} → {cout}: worst difference {worst}");
        }
    }

    #[test]
    fn the_vector_kernels_equal_the_plain_loop() {
        if !avx2() {
            return;
        }
        let (cin, cout, h, w) = (24, 24, 3, 17);
        let x = Blocked::from_planar(&values(cin * h * w, 4), cin, h, w);
        let packed = PackedConv::new(&values(cout * cin * 9, 5), &values(cout, 6), cout, &[cin]);
        let fast = packed.run(&[&x], &Scratch::default());
        let mut slow = Blocked::zeros(cout, h, w);
        let ins = [(&x, 0, false), (&x, 1, false), (&x, 2, false)];
        let (rs, bs) = (slow.row_stride(), slow.block_stride());
        let dst = slow.data_mut().as_mut_ptr();
        for y in 0..h {
            for ob in [0, 2] {
                let t = Task {
                    conv: &packed,
                    ins: &ins,
                    y,
                    ob,
                    dst_row: dst.wrapping_add(ob * bs + (y + 1) * rs + LANES),
                    bs,
                    x_origin: 0,
                };
                unsafe { t.plain(0, w, if ob == 0 { 2 } else { 1 }) };
            }
        }
        let worst = fast
            .to_planar()
            .iter()
            .zip(slow.to_planar())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "{worst}");
    }

    #[test]
    fn folded_upsampling_and_pooling_equal_the_steps_run_apart() {
        // an upsampled first source beside a full-size one, pooled after; widths that leave
        // remainders for the narrow kernels, odd and even
        let scratch = Scratch::default();
        for (c_low, c_skip, cout, h, w) in [(24, 9, 24, 4, 18), (16, 8, 8, 6, 26), (8, 0, 16, 2, 4)]
        {
            let low = Blocked::from_planar(&values(c_low * h * w, 7), c_low, h, w);
            let skip = Blocked::from_planar(&values(c_skip * 4 * h * w, 8), c_skip, 2 * h, 2 * w);
            let mut parts = vec![c_low];
            if c_skip > 0 {
                parts.push(c_skip);
            }
            let cin: usize = parts.iter().sum();
            let packed =
                PackedConv::new(&values(cout * cin * 9, 9), &values(cout, 10), cout, &parts);
            let up = low.upsample(&scratch);
            let apart_sources: Vec<&Blocked> = if c_skip > 0 {
                vec![&up, &skip]
            } else {
                vec![&up]
            };
            let folded_sources: Vec<&Blocked> = if c_skip > 0 {
                vec![&low, &skip]
            } else {
                vec![&low]
            };
            let apart = packed.run(&apart_sources, &scratch);
            let folded = packed.run_fused(
                &folded_sources,
                &scratch,
                Fused {
                    upsample_first: true,
                    pool: false,
                },
            );
            assert_eq!(apart.data(), folded.data(), "upsampled {c_low}+{c_skip}");
            let pooled_apart = apart.max_pool(&scratch);
            let pooled = packed.run_fused(
                &folded_sources,
                &scratch,
                Fused {
                    upsample_first: true,
                    pool: true,
                },
            );
            assert_eq!(
                pooled_apart.data(),
                pooled.data(),
                "pooled {c_low}+{c_skip}"
            );
            let plain_pooled = packed.run_fused(
                &apart_sources,
                &scratch,
                Fused {
                    upsample_first: false,
                    pool: true,
                },
            );
            assert_eq!(pooled_apart.data(), plain_pooled.data());
        }
    }
}
