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
        let (h, w) = (sources[0].height(), sources[0].width());
        let blocks: usize = sources.iter().map(|s| s.blocks()).sum();
        assert_eq!(
            blocks, self.in_blocks,
            "the sources' channels match the weights"
        );
        assert!(sources.iter().all(|s| s.height() == h && s.width() == w));
        let mut out = Blocked::bordered_in(scratch, self.cout, h, w);
        // the input blocks in order, as (source, block within it)
        let ins: Vec<(&Blocked, usize)> = sources
            .iter()
            .flat_map(|s| (0..s.blocks()).map(move |b| (*s, b)))
            .collect();
        let out_blocks = out.blocks();
        let groups = out_blocks.div_ceil(2);
        let chunks = w.div_ceil(COLUMNS_PER_JOB);
        let (rs, bs) = (out.row_stride(), out.block_stride());
        let dst = SendPtr(out.data_mut().as_mut_ptr());
        let isa = avx2();
        (0..h * chunks * groups).into_par_iter().for_each(|job| {
            let g = job % groups;
            let chunk = (job / groups) % chunks;
            let y = job / (groups * chunks);
            let ob = 2 * g;
            let two = ob + 1 < out_blocks;
            let x0 = chunk * COLUMNS_PER_JOB;
            let x1 = (x0 + COLUMNS_PER_JOB).min(w);
            let task = Task {
                conv: self,
                ins: &ins,
                y,
                ob,
                dst: dst.get(),
                rs,
                bs,
            };
            // SAFETY: each job writes only output row y, columns x0..x1, of blocks ob and ob+1,
            // which no other job writes; all reads are within the sources' padded storage.
            unsafe { task.columns(x0, x1, two, isa) };
        });
        out
    }
}

/// One job: output row `y`, output blocks `ob` (and `ob + 1`).
struct Task<'a> {
    conv: &'a PackedConv,
    ins: &'a [(&'a Blocked, usize)],
    y: usize,
    ob: usize,
    dst: *mut f32,
    rs: usize,
    bs: usize,
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
    /// lanes each), and that block and tap's packed weights for the task's first output block.
    #[inline(always)]
    unsafe fn tap(&self, ib: usize, tap: usize, x: usize) -> (*const f32, *const f32) {
        let (src, sb) = self.ins[ib];
        let (ky, kx) = (tap / 3, tap % 3);
        let input = src
            .data()
            .as_ptr()
            .add(sb * src.block_stride() + (self.y + ky) * src.row_stride() + (x + kx) * LANES);
        let c = self.conv;
        let weights = c
            .weights
            .as_ptr()
            .add(((self.ob * c.in_blocks + ib) * 9 + tap) * TAP);
        (input, weights)
    }

    /// The task's output at column `x` of its first output block.
    #[inline(always)]
    unsafe fn out(&self, x: usize) -> *mut f32 {
        self.dst
            .add(self.ob * self.bs + (self.y + 1) * self.rs + (x + 1) * LANES)
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
                let (p, wt) = self.tap(ib, tap, x);
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
        for ib in 0..self.ins.len() {
            for tap in 0..9 {
                let (p, wt) = self.tap(ib, tap, x);
                for l in 0..LANES {
                    let w0 = _mm256_loadu_ps(wt.add(l * LANES));
                    let w1 = _mm256_loadu_ps(wt.add(wstride + l * LANES));
                    macro_rules! px {
                        ($i:expr, $a:ident, $b:ident) => {
                            let s = _mm256_broadcast_ss(&*p.add($i * LANES + l));
                            $a = _mm256_fmadd_ps(w0, s, $a);
                            $b = _mm256_fmadd_ps(w1, s, $b);
                        };
                    }
                    px!(0, a0, b0);
                    px!(1, a1, b1);
                    px!(2, a2, b2);
                    px!(3, a3, b3);
                    px!(4, a4, b4);
                    px!(5, a5, b5);
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
        for ib in 0..self.ins.len() {
            for tap in 0..9 {
                let (p, wt) = self.tap(ib, tap, x);
                for l in 0..LANES {
                    let w = _mm256_loadu_ps(wt.add(l * LANES));
                    macro_rules! px {
                        ($i:expr, $a:ident) => {
                            let s = _mm256_broadcast_ss(&*p.add($i * LANES + l));
                            $a = _mm256_fmadd_ps(w, s, $a);
                        };
                    }
                    px!(0, a0);
                    px!(1, a1);
                    px!(2, a2);
                    px!(3, a3);
                    px!(4, a4);
                    px!(5, a5);
                    px!(6, a6);
                    px!(7, a7);
                    px!(8, a8);
                    px!(9, a9);
                    px!(10, a10);
                    px!(11, a11);
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
                for (ib, &(src, sb)) in self.ins.iter().enumerate() {
                    let base = sb * src.block_stride() + self.y * src.row_stride() + x * LANES;
                    let wb = (self.ob + o) * wstride + ib * 9 * TAP;
                    for ky in 0..3 {
                        for kx in 0..3 {
                            let p = base + ky * src.row_stride() + kx * LANES;
                            let wt = wb + (ky * 3 + kx) * TAP;
                            for l in 0..LANES {
                                let s = src.data()[p + l];
                                for (ol, a) in acc.iter_mut().enumerate() {
                                    *a = c.weights[wt + l * LANES + ol].mul_add(s, *a);
                                }
                            }
                        }
                    }
                }
                let out = self
                    .dst
                    .add((self.ob + o) * self.bs + (self.y + 1) * self.rs + (x + 1) * LANES);
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
        let ins = [(&x, 0), (&x, 1), (&x, 2)];
        let (rs, bs) = (slow.row_stride(), slow.block_stride());
        let dst = slow.data_mut().as_mut_ptr();
        for y in 0..h {
            for ob in [0, 2] {
                let t = Task {
                    conv: &packed,
                    ins: &ins,
                    y,
                    ob,
                    dst,
                    rs,
                    bs,
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
}
