//! The U-Net's 3×3 convolutions on the CPU, computed directly on channel-blocked maps: each
//! micro-kernel keeps a few blocks of 8 output channels for a row of neighbouring pixels in
//! vector registers and, for every input channel and tap, loads the blocks' weight vectors once
//! and broadcasts each pixel's input value against them. The kernels are per-ISA twins
//! (`conv_avx2`: two blocks in 8-float registers; `conv_avx512`: four blocks
//! in 16-float registers, two blocks a register), with a plain loop elsewhere; every one does
//! each output lane's multiply-adds in the same order, so all give the same bits. A
//! concatenation is two sources read one after the other, never copied. Bias and ReLU are
//! applied while the accumulators are in registers.
//!
//! Why direct and blocked: with 32–384 input channels a 3×3 layer is compute-bound, and
//! vectorising along output channels makes every loaded weight vector serve `PX` pixels and
//! every broadcast input serve `OB` vectors, with no im2col copy and no GEMM packing. The
//! zero border of [`Blocked`] is the convolution's padding.

use rayon::prelude::*;

use crate::model::cpu::direct::{self, Isa};
use crate::model::cpu::SendPtr;
use crate::oidn_unet::cpu::blocked::{Blocked, Scratch, LANES};

/// Output lanes of a packed weight tap: a pair of output blocks, interleaved so that one
/// AVX-512 register holds both and an AVX2 register either half.
pub(super) const PAIR: usize = 2 * LANES;
/// Floats of one packed weight tap (8 input lanes × a pair of output blocks).
pub(super) const TAP: usize = LANES * PAIR;
/// Output columns per parallel job: a job's input rows (3 rows of every input block) stay
/// within a core's L2 cache at the widest layers.
const COLUMNS_PER_JOB: usize = 240;

/// A convolution's weights packed for the kernels: `[out block pair][in block][tap][in
/// lane][out lane of the pair]`, zero where a block's lanes pass the real channel counts (and
/// in the second half of a last, unpaired block), and its bias per output block.
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
        let pairs = out_blocks.div_ceil(2);
        let in_blocks: usize = parts.iter().map(|p| p.div_ceil(LANES)).sum();
        let mut weights = vec![0.0; pairs * in_blocks * 9 * TAP];
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
                    let at = (((o / PAIR) * in_blocks + ib) * 9 + tap) * TAP + il * PAIR + o % PAIR;
                    weights[at] = weight[(o * cin + i) * 9 + tap];
                }
            }
        }
        let mut b = vec![0.0; pairs * PAIR];
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
        self.run_with(sources, scratch, fused, isa())
    }

    /// [`PackedConv::run_fused`] with the kernels of `isa` (`None`: the plain loop), which the
    /// CPU must have.
    fn run_with(
        &self,
        sources: &[&Blocked],
        scratch: &Scratch,
        fused: Fused,
        isa: Option<Isa>,
    ) -> Blocked {
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
        let per_group = blocks_per_job(isa);
        let groups = out_blocks.div_ceil(per_group);
        let chunks = w.div_ceil(COLUMNS_PER_JOB);
        let (rs, bs) = (out.row_stride(), out.block_stride());
        let dst = SendPtr(out.data_mut().as_mut_ptr());
        // a job's rows: one output row, or the two conv rows of one pooled row
        let rows = if fused.pool { h / 2 } else { h };
        (0..rows * chunks * groups).into_par_iter().for_each(|job| {
            let g = job % groups;
            let chunk = (job / groups) % chunks;
            let row = job / (groups * chunks);
            let ob = per_group * g;
            let nb = per_group.min(out_blocks - ob);
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
                // SAFETY: each job writes only output row `row`, columns x0..x1, of blocks
                // ob..ob+nb, which no other job writes; all reads are within the sources'
                // padded storage.
                unsafe { task(row, dst_row, bs, 0).columns(x0, x1, nb, isa) };
                return;
            }
            // the two conv rows into a job-local buffer ([block][row][column] of 8 lanes),
            // then their 2×2 maxima into the pooled row
            let cols = x1 - x0;
            let mut local = vec![0.0f32; nb * 2 * cols * LANES];
            let lbs = 2 * cols * LANES;
            for r in 0..2 {
                let dst_row = local.as_mut_ptr().wrapping_add(r * cols * LANES);
                // SAFETY: the local buffer holds both rows of the job's blocks for columns
                // x0..x1
                unsafe { task(2 * row + r, dst_row, lbs, x0).columns(x0, x1, nb, isa) };
            }
            for o in 0..nb {
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

/// One job: output row `y`, output blocks from `ob` (even: the first of a packed pair).
#[derive(Clone, Copy)]
pub(super) struct Task<'a> {
    pub(super) conv: &'a PackedConv,
    pub(super) ins: &'a [(&'a Blocked, usize, bool)],
    pub(super) y: usize,
    pub(super) ob: usize,
    /// Where column `x_origin` of the row is written, for block `ob` (block `ob + k`: `k × bs`
    /// floats on).
    pub(super) dst_row: *mut f32,
    pub(super) bs: usize,
    pub(super) x_origin: usize,
}

/// Pixel offsets (in pixels) of the `PX` pixels a micro-kernel reads from a source at one
/// tap: consecutive for a plain source; for one read upsampled, each low-resolution pixel
/// twice, starting with a pair or a single one by the tap's column parity.
pub(super) const PLAIN: [usize; 12] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11];
pub(super) const UP_PAIR: [usize; 12] = [0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5];
pub(super) const UP_SINGLE: [usize; 12] = [0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6];

/// Runs `$lanes!(p, wt, OFFSETS)` for every input block and tap of task `$task` at column `$x`
/// (`p` the tap's input pixels, `wt` its packed weights, `OFFSETS` the pattern its pixels
/// follow): the loop every wide micro-kernel runs around its own register block.
macro_rules! for_each_tap {
    ($task:expr, $x:expr, $lanes:ident) => {
        for ib in 0..$task.ins.len() {
            for tap in 0..9 {
                let (p, wt, offsets) = $task.tap(ib, tap, $x);
                match offsets {
                    Offsets::Plain => $lanes!(p, wt, PLAIN),
                    Offsets::UpPair => $lanes!(p, wt, UP_PAIR),
                    Offsets::UpSingle => $lanes!(p, wt, UP_SINGLE),
                }
            }
        }
    };
}
#[cfg(target_arch = "x86_64")]
pub(super) use for_each_tap;

/// Which of the offset patterns a tap's pixels follow.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Offsets {
    /// [`PLAIN`].
    Plain,
    /// [`UP_PAIR`].
    UpPair,
    /// [`UP_SINGLE`].
    UpSingle,
}

/// The vector instructions the kernels run with: the CPU's widest, detected once (shared with
/// radn's own networks: `RADN_CPU_CONV=avx2` keeps AVX2 on a CPU with AVX-512); `None` runs
/// the plain loop.
fn isa() -> Option<Isa> {
    direct::isa()
}

/// Output blocks per parallel job: as many as one micro-kernel keeps in registers.
fn blocks_per_job(isa: Option<Isa>) -> usize {
    match isa {
        Some(Isa::Avx512) => 4,
        _ => 2,
    }
}

impl Task<'_> {
    /// Output columns `x0..x1` of the task's row and its `nb` blocks (at most
    /// [`blocks_per_job`]).
    ///
    /// # Safety
    /// `dst_row` must be the output's storage, with the layout of `bs`, for every block and
    /// column written.
    pub(super) unsafe fn columns(&self, x0: usize, x1: usize, nb: usize, isa: Option<Isa>) {
        #[cfg(target_arch = "x86_64")]
        match isa {
            Some(Isa::Avx512) => return self.columns_avx512(x0, x1, nb),
            Some(Isa::Avx2) => return self.columns_avx2(x0, x1, nb),
            None => {}
        }
        let _ = isa;
        self.plain(x0, x1, nb);
    }

    /// The same task for its blocks from `ob + k` (`k` even), written where those go.
    pub(super) fn with_blocks_from(&self, k: usize) -> Self {
        Self {
            ob: self.ob + k,
            dst_row: self.dst_row.wrapping_add(k * self.bs),
            ..*self
        }
    }

    /// Where the kernels read input block `ib`'s tap `tap` for the pixels from column `x` (8
    /// lanes each), that block and tap's packed weights for the task's first pair of output
    /// blocks (the next pair: [`Self::pair_stride`] floats on), and which pixel offsets the
    /// following pixels are at ([`PLAIN`], [`UP_PAIR`] or [`UP_SINGLE`]).
    #[inline(always)]
    pub(super) unsafe fn tap(
        &self,
        ib: usize,
        tap: usize,
        x: usize,
    ) -> (*const f32, *const f32, Offsets) {
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
            .add((((self.ob / 2) * c.in_blocks + ib) * 9 + tap) * TAP);
        (input, weights, offsets)
    }

    /// Floats from one pair of output blocks' packed weights to the next's.
    #[inline(always)]
    pub(super) fn pair_stride(&self) -> usize {
        self.conv.in_blocks * 9 * TAP
    }

    /// The bias of the task's output block `ob + o`.
    #[inline(always)]
    pub(super) unsafe fn bias(&self, o: usize) -> *const f32 {
        self.conv.bias.as_ptr().add((self.ob + o) * LANES)
    }

    /// The task's output at column `x` of its first output block.
    #[inline(always)]
    pub(super) unsafe fn out(&self, x: usize) -> *mut f32 {
        self.dst_row.add((x - self.x_origin) * LANES)
    }

    /// The same computation without vector instructions.
    unsafe fn plain(&self, x0: usize, x1: usize, blocks: usize) {
        let c = self.conv;
        for o in 0..blocks {
            for x in x0..x1 {
                let mut acc: [f32; LANES] =
                    c.bias[(self.ob + o) * LANES..][..LANES].try_into().unwrap();
                for ib in 0..self.ins.len() {
                    for tap in 0..9 {
                        let (p, wt, _) = self.tap(ib, tap, x);
                        let wt = wt.add((o / 2) * self.pair_stride() + (o % 2) * LANES);
                        for l in 0..LANES {
                            let s = *p.add(l);
                            for (ol, a) in acc.iter_mut().enumerate() {
                                *a = (*wt.add(l * PAIR + ol)).mul_add(s, *a);
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
    fn every_kernel_set_gives_the_plain_loops_bits() {
        // 1 to 7 output blocks (every remainder of the 2- and 4-block jobs), widths that leave
        // remainders for the one-pixel kernels, a concatenation, folded upsampling and pooling
        let scratch = Scratch::default();
        let mut kernels = vec![None];
        if direct::isa().is_some() {
            kernels.push(Some(Isa::Avx2));
        }
        if direct::isa() == Some(Isa::Avx512) {
            kernels.push(Some(Isa::Avx512));
        }
        for cout in [3, 16, 24, 32, 40, 48, 56] {
            for (up, pool) in [(false, false), (true, false), (false, true), (true, true)] {
                let (c_low, c_skip, h, w) = (13, 8, 3, 13);
                let low = Blocked::from_planar(&values(c_low * h * w, 11), c_low, h, w);
                let skip =
                    Blocked::from_planar(&values(c_skip * 4 * h * w, 12), c_skip, 2 * h, 2 * w);
                let big = low.upsample(&scratch);
                let first = if up { &low } else { &big };
                let packed = PackedConv::new(
                    &values(cout * (c_low + c_skip) * 9, 13),
                    &values(cout, 14),
                    cout,
                    &[c_low, c_skip],
                );
                let fused = Fused {
                    upsample_first: up,
                    pool,
                };
                let outputs: Vec<Blocked> = kernels
                    .iter()
                    .map(|&isa| packed.run_with(&[first, &skip], &scratch, fused, isa))
                    .collect();
                for (isa, out) in kernels.iter().zip(&outputs).skip(1) {
                    assert_eq!(
                        outputs[0].data(),
                        out.data(),
                        "{isa:?}, {cout} channels, upsampled {up}, pooled {pool}"
                    );
                }
            }
        }
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
