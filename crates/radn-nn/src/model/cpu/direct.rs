//! Same-size convolutions computed directly with AVX2 and FMA, or AVX-512: each output
//! vector of pixels is accumulated in registers over every input channel and kernel tap, reading
//! the input rows in place (through a zero-padded slab of a few rows per job), with no im2col
//! copy and no GEMM packing.
//!
//! Why: at the guided models' width (16 channels) a 3×3 layer has K = 144 and 16 output rows,
//! too small for the GEMM to amortise its im2col columns (144 floats written and read per pixel)
//! and its packing, and the blocked im2col + GEMM path of [`super::conv`] runs far below its
//! speed at width 32 (`docs/research/benchmarks.md`). Computing in registers needs one load per
//! input value and tap, shared by [`CHANNELS`] output channels. The result is the same function
//! (equal to the GEMM path's to float rounding, tested); it runs where the CPU has AVX2 and FMA
//! or AVX-512F (the wider where both), and [`super::conv`] chooses it (measured by
//! `radn bench --convs`).

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

use rayon::prelude::*;

use crate::model::cpu::SendPtr;

/// Output channels that share each loaded input vector (one register of accumulators each per
/// pixel vector).
pub const CHANNELS: usize = 4;
/// Pixel vectors per micro-kernel call: with 8-float AVX2 vectors, 16 pixels of [`CHANNELS`]
/// channels are 8 accumulator registers, leaving room for the loads and the broadcast weight;
/// with 16-float AVX-512 vectors the same 8 registers hold 32 pixels.
const VECTORS: usize = 2;
/// Most pixels per micro-kernel call (AVX-512's).
const MAX_PIXELS: usize = VECTORS * 16;
/// Output rows per parallel job: the job's padded slab (its rows plus the kernel's reach above
/// and below, every input channel) stays within a core's L2 cache for the narrow layers.
const ROWS_PER_JOB: usize = 4;

/// The vector instructions the direct path runs with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Isa {
    /// 8-float vectors (AVX2 and FMA).
    Avx2,
    /// 16-float vectors (AVX-512F).
    Avx512,
}

impl Isa {
    /// Pixels per micro-kernel call.
    fn pixels(self) -> usize {
        match self {
            Isa::Avx2 => VECTORS * 8,
            Isa::Avx512 => VECTORS * 16,
        }
    }
}

/// The widest vector instructions this CPU has for the direct path (detected once at run time):
/// AVX-512F where present, else AVX2 with FMA, else none. `RADN_CPU_CONV=avx2` keeps AVX2 on a
/// CPU with AVX-512 (to compare, or where AVX-512 lowers the clock).
pub fn isa() -> Option<Isa> {
    static ISA: std::sync::OnceLock<Option<Isa>> = std::sync::OnceLock::new();
    *ISA.get_or_init(|| {
        #[cfg(target_arch = "x86_64")]
        {
            let forced_avx2 = std::env::var("RADN_CPU_CONV").is_ok_and(|v| v == "avx2");
            if std::is_x86_feature_detected!("avx512f") && !forced_avx2 {
                return Some(Isa::Avx512);
            }
            if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
                return Some(Isa::Avx2);
            }
            None
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            None
        }
    })
}

/// Whether this CPU runs the direct path (x86-64 with AVX2 and FMA, or AVX-512F).
pub fn available() -> bool {
    isa().is_some()
}

/// A convolution's weights in the micro-kernel's order: per block of [`CHANNELS`] output
/// channels, `[cin][kh][kw][CHANNELS]` (zero beyond `cout`), and the bias per block.
pub struct PackedWeights {
    weights: Vec<f32>,
    bias: Vec<f32>,
    cout: usize,
    cin: usize,
    kernel: [usize; 2],
}

impl PackedWeights {
    /// Packs `weight` (`[cout, cin, kh, kw]`, row-major, odd sizes) and `bias` (`[cout]`).
    pub fn new(weight: &[f32], bias: Option<&[f32]>, [cout, cin, kh, kw]: [usize; 4]) -> Self {
        assert_eq!(weight.len(), cout * cin * kh * kw, "weight size");
        assert!(kh % 2 == 1 && kw % 2 == 1, "odd kernel sizes");
        let blocks = cout.div_ceil(CHANNELS);
        let per_block = cin * kh * kw * CHANNELS;
        let mut weights = vec![0.0f32; blocks * per_block];
        for co in 0..cout {
            let (block, lane) = (co / CHANNELS, co % CHANNELS);
            for ci in 0..cin {
                for t in 0..kh * kw {
                    weights[block * per_block + (ci * kh * kw + t) * CHANNELS + lane] =
                        weight[(co * cin + ci) * kh * kw + t];
                }
            }
        }
        let mut padded_bias = vec![0.0f32; blocks * CHANNELS];
        if let Some(b) = bias {
            assert_eq!(b.len(), cout, "bias size");
            padded_bias[..cout].copy_from_slice(b);
        }
        Self {
            weights,
            bias: padded_bias,
            cout,
            cin,
            kernel: [kh, kw],
        }
    }
}

/// What the direct path does with each result value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Write {
    /// Stores it, after a ReLU when `relu` is set.
    Set {
        /// Whether a ReLU follows the convolution.
        relu: bool,
    },
    /// Adds it to the value already there (a residual block's `x + conv(...)`).
    Add,
}

/// The convolution of `b` images `x` (`[b, cin, h, w]`) with zero padding that keeps the size,
/// then a ReLU when `relu_after`: `[b, cout, h, w]`.
///
/// # Panics
/// When the CPU lacks AVX2 or FMA ([`available`]) or the sizes do not match.
pub fn conv_same_direct(
    x: &[f32],
    dims: [usize; 4],
    packed: &PackedWeights,
    relu_after: bool,
) -> Vec<f32> {
    let [b, _, h, w] = dims;
    let len = b * packed.cout * h * w;
    let mut out = Vec::with_capacity(len);
    // SAFETY: `out` has room for `len` floats, and the convolution writes every one of them
    // (every row of every output channel of every image) before the length is set.
    unsafe {
        conv_same_direct_into(
            direct_isa(),
            x,
            dims,
            packed,
            Write::Set { relu: relu_after },
            out.as_mut_ptr(),
        );
        out.set_len(len);
    }
    out
}

/// This CPU's ISA for the direct path.
///
/// # Panics
/// When it has none ([`available`]).
fn direct_isa() -> Isa {
    isa().expect("the direct convolution needs AVX2 and FMA, or AVX-512")
}

/// `out += conv(x)` for `b` images `x` (`[b, cin, h, w]`) and `out` (`[b, cout, h, w]`): the
/// residual add fused into the convolution's stores.
///
/// # Panics
/// When the CPU lacks AVX2 or FMA ([`available`]) or the sizes do not match.
pub fn conv_same_direct_add(x: &[f32], dims: [usize; 4], packed: &PackedWeights, out: &mut [f32]) {
    let [b, _, h, w] = dims;
    assert_eq!(out.len(), b * packed.cout * h * w, "output size");
    // SAFETY: `out` holds exactly the `[b, cout, h, w]` values the convolution adds to.
    unsafe { conv_same_direct_into(direct_isa(), x, dims, packed, Write::Add, out.as_mut_ptr()) }
}

/// The convolution written through `out` by `write`, with the instructions of `isa`.
///
/// # Safety
/// `isa` must be one this CPU has; `out` must be valid for writes (and, for [`Write::Add`],
/// reads of initialised values) of `b · cout · h · w` floats that nothing else accesses during
/// the call.
unsafe fn conv_same_direct_into(
    isa: Isa,
    x: &[f32],
    [b, cin, h, w]: [usize; 4],
    packed: &PackedWeights,
    write: Write,
    out: *mut f32,
) {
    let pixels = isa.pixels();
    assert_eq!(cin, packed.cin, "input channels");
    assert_eq!(x.len(), b * cin * h * w, "input size");
    let cout = packed.cout;
    if h == 0 || w == 0 || cout == 0 || b == 0 {
        return;
    }
    let [kh, kw] = packed.kernel;
    let (ry, rx) = (kh / 2, kw / 2);
    // slab columns: the kernel's reach left, the row, and enough beyond it that every vector
    // load of the last (partial) pixel block stays inside
    let slab_w = w.div_ceil(pixels) * pixels + 2 * rx;
    let slab_rows = ROWS_PER_JOB + 2 * ry;
    let jobs_per_image = h.div_ceil(ROWS_PER_JOB);
    let plane = h * w;
    let out_ptr = SendPtr(out);
    (0..b * jobs_per_image)
        .into_par_iter()
        .for_each_init(Vec::new, |slab: &mut Vec<f32>, job| {
            let (image, chunk) = (job / jobs_per_image, job % jobs_per_image);
            let y0 = chunk * ROWS_PER_JOB;
            let y1 = (y0 + ROWS_PER_JOB).min(h);
            let src = &x[image * cin * plane..][..cin * plane];
            fill_slab(slab, src, [cin, h, w], [ry, rx], slab_w, slab_rows, y0);
            let dst = out_ptr.get().wrapping_add(image * cout * plane);
            for y in y0..y1 {
                // SAFETY: `available()` was checked; the slab holds rows y - ry ..= y + ry of
                // every channel (zero beyond the image) at row `y - y0 + ry`, each `slab_w`
                // floats with every load of a pixel block in range; the jobs write disjoint
                // rows of each output plane, all within `out` (the caller's promise).
                unsafe {
                    conv_row(
                        isa,
                        slab.as_ptr().add((y - y0) * slab_w),
                        [slab_rows * slab_w, slab_w],
                        packed,
                        write,
                        dst.add(y * w),
                        [plane, w],
                    );
                }
            }
        });
}

/// Copies the rows `y0 - ry .. y0 + ROWS_PER_JOB + ry` of every channel of `src` into `slab`
/// (`cin` planes of `slab_rows × slab_w`), shifted right by `rx` and zero outside the image.
fn fill_slab(
    slab: &mut Vec<f32>,
    src: &[f32],
    [cin, h, w]: [usize; 3],
    [ry, rx]: [usize; 2],
    slab_w: usize,
    slab_rows: usize,
    y0: usize,
) {
    slab.clear();
    slab.resize(cin * slab_rows * slab_w, 0.0);
    for c in 0..cin {
        for sy in 0..slab_rows {
            let y = (y0 + sy) as isize - ry as isize;
            if y < 0 || y >= h as isize {
                continue;
            }
            let from = &src[(c * h + y as usize) * w..][..w];
            slab[(c * slab_rows + sy) * slab_w + rx..][..w].copy_from_slice(from);
        }
    }
}

/// One output row of every output channel: `src` points at the slab row `kh/2` above the output
/// row, channels `src_stride[0]` floats apart and rows `src_stride[1]`; `dst` at the output row
/// of channel 0, channels `dst_stride[0]` apart, `dst_stride[1]` (the width) pixels written.
///
/// # Safety
/// `isa` must be one this CPU has ([`isa`]); the slab must hold `kh` rows of every channel with
/// `ceil(w / p) · p + kw − 1` readable floats each (`p` the ISA's pixels per call), and `dst`
/// must be valid for the row of every output channel.
#[cfg(target_arch = "x86_64")]
unsafe fn conv_row(
    isa: Isa,
    src: *const f32,
    src_stride: [usize; 2],
    packed: &PackedWeights,
    write: Write,
    dst: *mut f32,
    [dst_plane, w]: [usize; 2],
) {
    let relu_after = write == Write::Set { relu: true };
    let blocks = packed.cout.div_ceil(CHANNELS);
    let per_block = packed.cin * packed.kernel[0] * packed.kernel[1] * CHANNELS;
    let pixels = isa.pixels();
    for x0 in (0..w).step_by(pixels) {
        for block in 0..blocks {
            let mut acc = [[0.0f32; MAX_PIXELS]; CHANNELS];
            let args = (
                // SAFETY (of the offsets): within the slab row and the packed weights
                unsafe { src.add(x0) },
                src_stride,
                packed.cin,
                packed.kernel,
                unsafe { packed.weights.as_ptr().add(block * per_block) },
                unsafe { packed.bias.as_ptr().add(block * CHANNELS) },
                relu_after,
            );
            // SAFETY: the caller's promise (the ISA is this CPU's, from `isa()`); the block's
            // weights and bias are in range.
            unsafe {
                match isa {
                    Isa::Avx2 => micro_kernel_avx2(args, &mut acc),
                    Isa::Avx512 => micro_kernel_avx512(args, &mut acc),
                }
            }
            let n = pixels.min(w - x0);
            let channels = CHANNELS.min(packed.cout - block * CHANNELS);
            for (lane, values) in acc.iter().enumerate().take(channels) {
                let co = block * CHANNELS + lane;
                // SAFETY: output row of channel `co`, pixels x0 .. x0 + n <= w.
                unsafe {
                    let to = dst.add(co * dst_plane + x0);
                    if write == Write::Add {
                        for (i, v) in values[..n].iter().enumerate() {
                            *to.add(i) += v;
                        }
                    } else {
                        std::ptr::copy_nonoverlapping(values.as_ptr(), to, n);
                    }
                }
            }
        }
    }
}

#[cfg(not(target_arch = "x86_64"))]
unsafe fn conv_row(
    _isa: Isa,
    _src: *const f32,
    _src_stride: [usize; 2],
    _packed: &PackedWeights,
    _write: Write,
    _dst: *mut f32,
    _dst_stride: [usize; 2],
) {
    unreachable!("the direct convolution runs only on x86-64 ([`available`])");
}

/// A micro-kernel call's arguments: the slab at the block's first pixel, the slab's channel and
/// row strides, input channels, kernel size, the block's packed weights and bias, and whether a
/// ReLU follows.
type KernelArgs = (
    *const f32,
    [usize; 2],
    usize,
    [usize; 2],
    *const f32,
    *const f32,
    bool,
);

/// Defines a micro-kernel: `$lanes` × [`VECTORS`] consecutive output pixels of [`CHANNELS`]
/// output channels, accumulated in `$vector` registers over every input channel and tap, plus
/// the bias, then the optional ReLU. One body for both ISAs, so that they stay the same
/// multiply-adds in the same order (bit-identical results, tested).
macro_rules! micro_kernel {
    ($(#[$doc:meta])* $name:ident, $feature:literal, $vector:ty, $lanes:literal,
     zero: $zero:ident, splat: $splat:ident, load: $load:ident, fmadd: $fmadd:ident,
     max: $max:ident, store: $store:ident) => {
        $(#[$doc])*
        ///
        /// # Safety
        /// The ISA must be available; `src` must be readable for `kh` rows (`src_stride[1]`
        /// apart) of `cin` channels (`src_stride[0]` apart), `lanes · VECTORS + kw − 1` floats
        /// each; `weights` for `cin · kh · kw · CHANNELS` floats and `bias` for `CHANNELS`.
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = $feature)]
        unsafe fn $name(
            (src, [channel_stride, row_stride], cin, [kh, kw], weights, bias, relu_after): KernelArgs,
            out: &mut [[f32; MAX_PIXELS]; CHANNELS],
        ) {
            // SAFETY: every pointer offset below stays within the ranges the caller promises.
            unsafe {
                let mut acc: [[$vector; VECTORS]; CHANNELS] = [[$zero(); VECTORS]; CHANNELS];
                for (lane, row) in acc.iter_mut().enumerate() {
                    *row = [$splat(*bias.add(lane)); VECTORS];
                }
                let mut wp = weights;
                for ci in 0..cin {
                    for ky in 0..kh {
                        let row = src.add(ci * channel_stride + ky * row_stride);
                        for kx in 0..kw {
                            let p = row.add(kx);
                            let mut v = [$zero(); VECTORS];
                            for (j, vj) in v.iter_mut().enumerate() {
                                *vj = $load(p.add($lanes * j));
                            }
                            for (lane, a) in acc.iter_mut().enumerate() {
                                let wv = $splat(*wp.add(lane));
                                for j in 0..VECTORS {
                                    a[j] = $fmadd(wv, v[j], a[j]);
                                }
                            }
                            wp = wp.add(CHANNELS);
                        }
                    }
                }
                let zero = $zero();
                for (lane, a) in acc.iter().enumerate() {
                    for (j, &v) in a.iter().enumerate() {
                        let v = if relu_after { $max(v, zero) } else { v };
                        $store(out[lane].as_mut_ptr().add($lanes * j), v);
                    }
                }
            }
        }
    };
}

micro_kernel!(
    /// 16 pixels per call in AVX2 registers.
    micro_kernel_avx2, "avx2,fma", __m256, 8,
    zero: _mm256_setzero_ps, splat: _mm256_set1_ps, load: _mm256_loadu_ps,
    fmadd: _mm256_fmadd_ps, max: _mm256_max_ps, store: _mm256_storeu_ps
);

micro_kernel!(
    /// 32 pixels per call in AVX-512 registers.
    micro_kernel_avx512, "avx512f", __m512, 16,
    zero: _mm512_setzero_ps, splat: _mm512_set1_ps, load: _mm512_loadu_ps,
    fmadd: _mm512_fmadd_ps, max: _mm512_max_ps, store: _mm512_storeu_ps
);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn avx2_and_avx512_compute_the_same_values() {
        #[cfg(target_arch = "x86_64")]
        {
            if !(std::is_x86_feature_detected!("avx512f")
                && std::is_x86_feature_detected!("avx2")
                && std::is_x86_feature_detected!("fma"))
            {
                eprintln!("SKIPPED: this CPU lacks AVX-512F or AVX2");
                return;
            }
            // widths around both ISAs' pixel blocks (16 and 32), a residual add, a ReLU
            for (cin, cout, h, w) in [(16, 16, 9, 47), (7, 5, 5, 16), (3, 9, 4, 33), (4, 2, 3, 1)] {
                let x: Vec<f32> = (0..2 * cin * h * w)
                    .map(|i| ((i * 7919) % 1000) as f32 / 500.0 - 1.0)
                    .collect();
                let weight: Vec<f32> = (0..cout * cin * 9)
                    .map(|i| ((i * 104_729) % 1000) as f32 / 700.0 - 0.7)
                    .collect();
                let bias: Vec<f32> = (0..cout).map(|i| i as f32 * 0.1 - 0.2).collect();
                let packed = PackedWeights::new(&weight, Some(&bias), [cout, cin, 3, 3]);
                for write in [
                    Write::Set { relu: true },
                    Write::Set { relu: false },
                    Write::Add,
                ] {
                    let run = |isa| {
                        let mut out = vec![0.5f32; 2 * cout * h * w];
                        // SAFETY: both ISAs were detected above; `out` has the output's size.
                        unsafe {
                            conv_same_direct_into(
                                isa,
                                &x,
                                [2, cin, h, w],
                                &packed,
                                write,
                                out.as_mut_ptr(),
                            )
                        };
                        out
                    };
                    // the same multiply-adds in the same order per pixel: equal bit for bit
                    assert_eq!(
                        run(Isa::Avx2),
                        run(Isa::Avx512),
                        "{cin}→{cout} {w}×{h} {write:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn packed_weights_put_each_output_channel_in_its_lane() {
        // cout 5 = one full block and one with a single channel; cin 2, 1×1 kernels
        let weight: Vec<f32> = (0..10).map(|i| i as f32).collect();
        let p = PackedWeights::new(&weight, Some(&[1.0, 2.0, 3.0, 4.0, 5.0]), [5, 2, 1, 1]);
        // block 0: [ci][lane] = weight[co][ci]
        assert_eq!(&p.weights[..8], &[0.0, 2.0, 4.0, 6.0, 1.0, 3.0, 5.0, 7.0]);
        // block 1: channel 4 in lane 0, the rest zero
        assert_eq!(&p.weights[8..], &[8.0, 0.0, 0.0, 0.0, 9.0, 0.0, 0.0, 0.0]);
        assert_eq!(p.bias, vec![1.0, 2.0, 3.0, 4.0, 5.0, 0.0, 0.0, 0.0]);
    }
}
