//! The U-Net convolution's AVX2 micro-kernels ([`super::conv`]): two output blocks of 8
//! channels × 6 pixels, or one block × 12 pixels, in the 16 ymm registers.

use std::arch::x86_64::*;

use super::blocked::LANES;
use super::conv::{for_each_tap, Offsets, Task, PAIR, PLAIN, UP_PAIR, UP_SINGLE};

/// Pixels per call with two output blocks (12 accumulators, 2 weight registers and a
/// broadcast: 15 of the 16).
const PX2: usize = 6;
/// Pixels per call with one output block.
pub(super) const PX1: usize = 12;

impl Task<'_> {
    /// Output columns `x0..x1` of the task's row and its `nb` blocks (1 or 2).
    ///
    /// # Safety
    /// As [`Task::columns`]; the CPU has AVX2 and FMA.
    pub(super) unsafe fn columns_avx2(&self, x0: usize, x1: usize, nb: usize) {
        let mut x = x0;
        if nb == 2 {
            while x + PX2 <= x1 {
                self.kernel_2x6(x);
                x += PX2;
            }
            while x < x1 {
                self.kernel::<2>(x);
                x += 1;
            }
        } else {
            debug_assert_eq!(nb, 1);
            while x + PX1 <= x1 {
                self.kernel_1x12(x);
                x += PX1;
            }
            while x < x1 {
                self.kernel::<1>(x);
                x += 1;
            }
        }
    }

    /// The micro-kernel for one pixel at column `x` and `OB` output blocks (the columns left
    /// over by the wide kernels).
    #[target_feature(enable = "avx2,fma")]
    unsafe fn kernel<const OB: usize>(&self, x: usize) {
        let out = self.out(x);
        let mut acc = [_mm256_setzero_ps(); OB];
        for (o, a) in acc.iter_mut().enumerate() {
            *a = _mm256_loadu_ps(self.bias(o));
        }
        for ib in 0..self.ins.len() {
            for tap in 0..9 {
                let (p, wt, _) = self.tap(ib, tap, x);
                for l in 0..LANES {
                    let s = _mm256_broadcast_ss(&*p.add(l));
                    for (o, a) in acc.iter_mut().enumerate() {
                        let w = _mm256_loadu_ps(wt.add(l * PAIR + o * LANES));
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
    #[target_feature(enable = "avx2,fma")]
    unsafe fn kernel_2x6(&self, x: usize) {
        let out = self.out(x);
        let o1 = out.add(self.bs);
        let (a, b) = (_mm256_loadu_ps(self.bias(0)), _mm256_loadu_ps(self.bias(1)));
        let (mut a0, mut a1, mut a2, mut a3, mut a4, mut a5) = (a, a, a, a, a, a);
        let (mut b0, mut b1, mut b2, mut b3, mut b4, mut b5) = (b, b, b, b, b, b);
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
                    let w0 = _mm256_loadu_ps($wt.add(l * PAIR));
                    let w1 = _mm256_loadu_ps($wt.add(l * PAIR + LANES));
                    px!($p, $offs, l, w0, w1, 0, a0, b0);
                    px!($p, $offs, l, w0, w1, 1, a1, b1);
                    px!($p, $offs, l, w0, w1, 2, a2, b2);
                    px!($p, $offs, l, w0, w1, 3, a3, b3);
                    px!($p, $offs, l, w0, w1, 4, a4, b4);
                    px!($p, $offs, l, w0, w1, 5, a5, b5);
                }
            };
        }
        for_each_tap!(self, x, lanes);
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
    #[target_feature(enable = "avx2,fma")]
    unsafe fn kernel_1x12(&self, x: usize) {
        let out = self.out(x);
        let a = _mm256_loadu_ps(self.bias(0));
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
                    let w = _mm256_loadu_ps($wt.add(l * PAIR));
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
        let zero = _mm256_setzero_ps();
        for (px, v) in [a0, a1, a2, a3, a4, a5, a6, a7, a8, a9, a10, a11]
            .into_iter()
            .enumerate()
        {
            _mm256_storeu_ps(out.add(px * LANES), _mm256_max_ps(v, zero));
        }
    }
}
