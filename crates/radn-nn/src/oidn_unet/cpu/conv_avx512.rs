//! The U-Net convolution's AVX-512 micro-kernels ([`super::conv`]): a 16-float register holds a
//! packed pair of output blocks, so the main kernel keeps four blocks (two registers) × 12
//! pixels in 24 of the 32 zmm registers. Each output lane sees the same multiply-adds in the
//! same order as in the AVX2 kernels, so the results are bit-identical.

use std::arch::x86_64::*;

use super::blocked::LANES;
use super::conv::{for_each_tap, Offsets, Task, PAIR, PLAIN, UP_PAIR, UP_SINGLE};

/// Pixels per call of the wide kernels.
const PX: usize = 12;

/// Stores a pair's accumulator for pixel `px` with ReLU: its low half into the first block's
/// map at `out`, its high half `bs` floats on.
#[inline(always)]
unsafe fn store_pair(out: *mut f32, bs: usize, px: usize, v: __m512) {
    let v = _mm512_max_ps(v, _mm512_setzero_ps());
    let low = _mm512_castps512_ps256(v);
    let high = _mm256_castpd_ps(_mm512_extractf64x4_pd::<1>(_mm512_castps_pd(v)));
    _mm256_storeu_ps(out.add(px * LANES), low);
    _mm256_storeu_ps(out.add(bs + px * LANES), high);
}

impl Task<'_> {
    /// Output columns `x0..x1` of the task's row and its `nb` blocks (1 to 4): pairs of blocks
    /// in zmm registers, a last unpaired block by the AVX2 kernels.
    ///
    /// # Safety
    /// As [`Task::columns`]; the CPU has AVX-512F (and so AVX2 and FMA).
    pub(super) unsafe fn columns_avx512(&self, x0: usize, x1: usize, nb: usize) {
        let mut x = x0;
        match nb {
            4 => {
                while x + PX <= x1 {
                    self.kernel512_4x12(x);
                    x += PX;
                }
                while x < x1 {
                    self.kernel512_px::<2>(x);
                    x += 1;
                }
            }
            2 | 3 => {
                while x + PX <= x1 {
                    self.kernel512_2x12(x);
                    x += PX;
                }
                while x < x1 {
                    self.kernel512_px::<1>(x);
                    x += 1;
                }
                if nb == 3 {
                    self.with_blocks_from(2).columns_avx2(x0, x1, 1);
                }
            }
            _ => self.columns_avx2(x0, x1, nb),
        }
    }

    /// The kernel for one pixel at column `x` and `P` pairs of output blocks (the columns left
    /// over by the wide kernels).
    #[target_feature(enable = "avx512f")]
    unsafe fn kernel512_px<const P: usize>(&self, x: usize) {
        let out = self.out(x);
        let ps = self.pair_stride();
        let mut acc = [_mm512_setzero_ps(); P];
        for (q, a) in acc.iter_mut().enumerate() {
            *a = _mm512_loadu_ps(self.bias(2 * q));
        }
        for ib in 0..self.ins.len() {
            for tap in 0..9 {
                let (p, wt, _) = self.tap(ib, tap, x);
                for l in 0..LANES {
                    let s = _mm512_set1_ps(*p.add(l));
                    for (q, a) in acc.iter_mut().enumerate() {
                        let w = _mm512_loadu_ps(wt.add(q * ps + l * PAIR));
                        *a = _mm512_fmadd_ps(w, s, *a);
                    }
                }
            }
        }
        for (q, a) in acc.iter().enumerate() {
            store_pair(out.add(2 * q * self.bs), self.bs, 0, *a);
        }
    }

    /// The main kernel: 2 pairs of output blocks × 12 pixels from column `x`, its 24
    /// accumulators named so that they stay in registers.
    #[target_feature(enable = "avx512f")]
    unsafe fn kernel512_4x12(&self, x: usize) {
        let out = self.out(x);
        let ps = self.pair_stride();
        let (a, b) = (_mm512_loadu_ps(self.bias(0)), _mm512_loadu_ps(self.bias(2)));
        let (mut a0, mut a1, mut a2, mut a3, mut a4, mut a5) = (a, a, a, a, a, a);
        let (mut a6, mut a7, mut a8, mut a9, mut a10, mut a11) = (a, a, a, a, a, a);
        let (mut b0, mut b1, mut b2, mut b3, mut b4, mut b5) = (b, b, b, b, b, b);
        let (mut b6, mut b7, mut b8, mut b9, mut b10, mut b11) = (b, b, b, b, b, b);
        macro_rules! px {
            ($p:ident, $offs:ident, $l:ident, $w0:ident, $w1:ident, $i:literal, $a:ident, $b:ident) => {
                let s = _mm512_set1_ps(*$p.add($offs[$i] * LANES + $l));
                $a = _mm512_fmadd_ps($w0, s, $a);
                $b = _mm512_fmadd_ps($w1, s, $b);
            };
        }
        macro_rules! lanes {
            ($p:ident, $wt:ident, $offs:ident) => {
                for l in 0..LANES {
                    let w0 = _mm512_loadu_ps($wt.add(l * PAIR));
                    let w1 = _mm512_loadu_ps($wt.add(ps + l * PAIR));
                    px!($p, $offs, l, w0, w1, 0, a0, b0);
                    px!($p, $offs, l, w0, w1, 1, a1, b1);
                    px!($p, $offs, l, w0, w1, 2, a2, b2);
                    px!($p, $offs, l, w0, w1, 3, a3, b3);
                    px!($p, $offs, l, w0, w1, 4, a4, b4);
                    px!($p, $offs, l, w0, w1, 5, a5, b5);
                    px!($p, $offs, l, w0, w1, 6, a6, b6);
                    px!($p, $offs, l, w0, w1, 7, a7, b7);
                    px!($p, $offs, l, w0, w1, 8, a8, b8);
                    px!($p, $offs, l, w0, w1, 9, a9, b9);
                    px!($p, $offs, l, w0, w1, 10, a10, b10);
                    px!($p, $offs, l, w0, w1, 11, a11, b11);
                }
            };
        }
        for_each_tap!(self, x, lanes);
        let o2 = out.add(2 * self.bs);
        for (px, v) in [a0, a1, a2, a3, a4, a5, a6, a7, a8, a9, a10, a11]
            .into_iter()
            .enumerate()
        {
            store_pair(out, self.bs, px, v);
        }
        for (px, v) in [b0, b1, b2, b3, b4, b5, b6, b7, b8, b9, b10, b11]
            .into_iter()
            .enumerate()
        {
            store_pair(o2, self.bs, px, v);
        }
    }

    /// The kernel for one pair of output blocks: 12 pixels from column `x`.
    #[target_feature(enable = "avx512f")]
    unsafe fn kernel512_2x12(&self, x: usize) {
        let out = self.out(x);
        let a = _mm512_loadu_ps(self.bias(0));
        let (mut a0, mut a1, mut a2, mut a3, mut a4, mut a5) = (a, a, a, a, a, a);
        let (mut a6, mut a7, mut a8, mut a9, mut a10, mut a11) = (a, a, a, a, a, a);
        macro_rules! px {
            ($p:ident, $offs:ident, $l:ident, $w:ident, $i:literal, $a:ident) => {
                let s = _mm512_set1_ps(*$p.add($offs[$i] * LANES + $l));
                $a = _mm512_fmadd_ps($w, s, $a);
            };
        }
        macro_rules! lanes {
            ($p:ident, $wt:ident, $offs:ident) => {
                for l in 0..LANES {
                    let w = _mm512_loadu_ps($wt.add(l * PAIR));
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
        for_each_tap!(self, x, lanes);
        for (px, v) in [a0, a1, a2, a3, a4, a5, a6, a7, a8, a9, a10, a11]
            .into_iter()
            .enumerate()
        {
            store_pair(out, self.bs, px, v);
        }
    }
}
