//! The convolutions of inference on the CPU, as blocked im2col + GEMM straight into the
//! NCHW output (the `gemm` crate's kernels, rows of the image in parallel with rayon), with the
//! bias and an optional ReLU applied while the block is in cache.
//!
//! Why: burn's `flex` backend converts every convolution's input to NHWC on one thread and
//! scatters the GEMM result back pixel by pixel; on 2 cores that left the GEMM kernels about a
//! third of a denoising run (docs/research/benchmarks.md, "Convolutions on the CPU"). This path computes
//! the same function (equal to burn's to float rounding, tested) and is used only where it
//! applies: the `flex` device without autodiff, stride 1, no dilation, one group, odd kernels
//! with same-size padding. Everything else — training, other backends, other shapes — runs
//! burn's own convolution.

use burn::nn::conv::Conv2d;
use burn::nn::PaddingConfig2d;
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor, TensorData};
use rayon::prelude::*;

use crate::model::cpu::{direct, is_cpu_inference, SendPtr};

/// Floats of one im2col block (1 MiB): its columns stay within a core's L2 cache while the GEMM
/// packs them. The block's pixel count follows from the layer's K = cin · kh · kw, within
/// [`MIN_BLOCK_PIXELS`, `MAX_BLOCK_PIXELS`] (faster than a fixed block: `radn bench --convs`,
/// `docs/research/benchmarks.md`).
const BLOCK_FLOATS: usize = 256 * 1024;
/// Fewest output pixels per block, so that the GEMM's pixel dimension keeps its kernels busy.
const MIN_BLOCK_PIXELS: usize = 256;
/// Most output pixels per block, so that a tile's rows still split into jobs for every core.
const MAX_BLOCK_PIXELS: usize = 2048;

/// `conv(x)`, followed by a ReLU when `relu_after`; the fast CPU path where it applies.
pub fn conv2d(conv: &Conv2d, x: Tensor<4>, relu_after: bool) -> Tensor<4> {
    if applies(conv, &x.device()) {
        return fast_conv2d(conv, x, relu_after);
    }
    let y = conv.forward(x);
    if relu_after {
        relu(y)
    } else {
        y
    }
}

/// Whether the fast path computes `conv` on `device`.
fn applies(conv: &Conv2d, device: &Device) -> bool {
    let [kh, kw] = conv.kernel_size;
    is_cpu_inference(device)
        && conv.stride == [1, 1]
        && conv.dilation == [1, 1]
        && conv.groups == 1
        && kh % 2 == 1
        && kw % 2 == 1
        && matches!(conv.padding, PaddingConfig2d::Same)
}

fn fast_conv2d(conv: &Conv2d, x: Tensor<4>, relu_after: bool) -> Tensor<4> {
    let device = x.device();
    let [b, cin, h, w] = x.dims();
    let weight = conv.weight.val();
    let [cout, wcin, kh, kw] = weight.dims();
    assert_eq!(
        cin, wcin,
        "the input has {cin} channels, the convolution expects {wcin}"
    );
    let weight = weight.into_data();
    let bias = conv.bias.as_ref().map(|b| b.val().into_data());
    let input = x.into_data();
    let out = conv_same_nchw(
        input.as_slice::<f32>().expect("f32 input"),
        [b, cin, h, w],
        weight.as_slice::<f32>().expect("f32 weights"),
        [cout, kh, kw],
        bias.as_ref()
            .map(|b| b.as_slice::<f32>().expect("f32 bias")),
        relu_after,
    );
    Tensor::from_data(TensorData::new(out, [b, cout, h, w]), &device)
}

/// A convolution's weights copied to the host once, for CPU paths that run it several times
/// (a Robust Average block's predictor runs once per frame of the window).
pub struct HostConv {
    weight: Vec<f32>,
    bias: Option<Vec<f32>>,
    cout: usize,
    cin: usize,
    kernel: [usize; 2],
    /// The weights packed for the direct path, where this CPU takes it.
    packed: Option<direct::PackedWeights>,
}

impl HostConv {
    /// The weights of `conv`, which must be a convolution the fast path computes
    /// ([`HostConv::applies`]).
    pub fn of(conv: &Conv2d) -> Self {
        let weight = conv.weight.val();
        let [cout, cin, kh, kw] = weight.dims();
        let data = |t: TensorData| t.try_into_vec::<f32>().expect("f32 weights");
        let weight = data(weight.into_data());
        let bias = conv.bias.as_ref().map(|b| data(b.val().into_data()));
        let packed = (preferred_path() == ConvPath::Direct)
            .then(|| direct::PackedWeights::new(&weight, bias.as_deref(), [cout, cin, kh, kw]));
        Self {
            weight,
            bias,
            cout,
            cin,
            kernel: [kh, kw],
            packed,
        }
    }

    /// Whether the fast path computes `conv` on `device` (then [`HostConv::of`] may be used).
    pub fn applies(conv: &Conv2d, device: &Device) -> bool {
        applies(conv, device)
    }

    /// Output channels.
    pub fn out_channels(&self) -> usize {
        self.cout
    }

    /// The convolution of `b` images `[b, cin, h, w]`, then a ReLU when `relu_after`.
    pub fn run(&self, x: &[f32], b: usize, h: usize, w: usize, relu_after: bool) -> Vec<f32> {
        if let Some(packed) = &self.packed {
            return direct::conv_same_direct(x, [b, self.cin, h, w], packed, relu_after);
        }
        let [kh, kw] = self.kernel;
        conv_same_nchw(
            x,
            [b, self.cin, h, w],
            &self.weight,
            [self.cout, kh, kw],
            self.bias.as_deref(),
            relu_after,
        )
    }
}

impl HostConv {
    /// `out += conv(x)` for `b` images `x` (`[b, cin, h, w]`) and `out` (`[b, cout, h, w]`):
    /// a residual block's add, fused into the convolution's stores on the direct path.
    pub fn run_add(&self, x: &[f32], b: usize, h: usize, w: usize, out: &mut [f32]) {
        assert_eq!(out.len(), b * self.cout * h * w, "output size");
        match &self.packed {
            Some(packed) => direct::conv_same_direct_add(x, [b, self.cin, h, w], packed, out),
            None => {
                let y = self.run(x, b, h, w, false);
                out.par_iter_mut().zip(&y).for_each(|(o, v)| *o += v);
            }
        }
    }
}

/// A stride-1 convolution with zero padding that keeps the size, on NCHW data: `x` is
/// `[b, cin, h, w]`, `weight` `[cout, cin, kh, kw]` (odd sizes), the result `[b, cout, h, w]`.
pub fn conv_same_nchw(
    x: &[f32],
    [b, cin, h, w]: [usize; 4],
    weight: &[f32],
    [cout, kh, kw]: [usize; 3],
    bias: Option<&[f32]>,
    relu_after: bool,
) -> Vec<f32> {
    conv_same_nchw_by(
        preferred_path(),
        x,
        [b, cin, h, w],
        weight,
        [cout, kh, kw],
        bias,
        relu_after,
    )
}

/// How a convolution is computed on the CPU.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConvPath {
    /// Blocked im2col + one GEMM per block (any CPU).
    Gemm,
    /// Accumulated in registers with AVX2 and FMA, or AVX-512 ([`super::direct`]).
    Direct,
}

/// The path for every layer on this CPU: the direct one wherever the CPU has AVX2 and FMA, or
/// AVX-512. `radn bench --convs` times both on every layer shape of the shipped
/// models; the direct path was the faster on each (docs/research/benchmarks.md). The environment
/// variable `RADN_CPU_CONV=gemm` keeps the GEMM path everywhere (to compare whole runs, or for
/// a CPU where it measures faster).
pub fn preferred_path() -> ConvPath {
    static DIRECT: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    let direct = *DIRECT.get_or_init(|| {
        direct::available() && std::env::var("RADN_CPU_CONV").map_or(true, |v| v != "gemm")
    });
    if direct {
        ConvPath::Direct
    } else {
        ConvPath::Gemm
    }
}

/// [`conv_same_nchw`] by the given path ([`ConvPath::Direct`] only where
/// [`direct::available`]).
pub fn conv_same_nchw_by(
    path: ConvPath,
    x: &[f32],
    [b, cin, h, w]: [usize; 4],
    weight: &[f32],
    [cout, kh, kw]: [usize; 3],
    bias: Option<&[f32]>,
    relu_after: bool,
) -> Vec<f32> {
    assert_eq!(x.len(), b * cin * h * w, "input size");
    assert_eq!(weight.len(), cout * cin * kh * kw, "weight size");
    if path == ConvPath::Direct {
        let packed = direct::PackedWeights::new(weight, bias, [cout, cin, kh, kw]);
        return direct::conv_same_direct(x, [b, cin, h, w], &packed, relu_after);
    }
    let k = cin * kh * kw;
    let plane = h * w;
    let mut out = vec![0.0f32; b * cout * plane];
    if plane == 0 || cout == 0 {
        return out;
    }
    let block_pixels = (BLOCK_FLOATS / k.max(1)).clamp(MIN_BLOCK_PIXELS, MAX_BLOCK_PIXELS);
    let rows_per_block = (block_pixels / w.max(1)).clamp(1, h);
    let blocks_per_image = h.div_ceil(rows_per_block);
    let out_ptr = SendPtr(out.as_mut_ptr());
    (0..b * blocks_per_image).into_par_iter().for_each_init(
        Vec::new,
        |cols: &mut Vec<f32>, job| {
            let (image, block) = (job / blocks_per_image, job % blocks_per_image);
            let y0 = block * rows_per_block;
            let y1 = (y0 + rows_per_block).min(h);
            let n = (y1 - y0) * w;
            cols.clear();
            cols.resize(k * n, 0.0);
            im2col_rows(
                &x[image * cin * plane..][..cin * plane],
                [cin, h, w],
                [kh, kw],
                y0..y1,
                cols,
            );
            // this block's pixels of every output channel: row stride one plane
            let dst = out_ptr.get().wrapping_add(image * cout * plane + y0 * w);
            // SAFETY: the blocks of one image cover disjoint pixel ranges of each output
            // plane, and images disjoint ranges of `out`, so no two jobs write the same element;
            // every index stays within `out` (cout planes of `plane` floats from the image's
            // start, `y0 * w + n <= plane`). `weight` is [cout, k] row-major and `cols`
            // [k, n] row-major.
            unsafe {
                matmul_into(
                    [cout, n, k],
                    dst,
                    plane,
                    &weight[..cout * k],
                    &cols[..k * n],
                    gemm::Parallelism::None,
                );
                for co in 0..cout {
                    let row = std::slice::from_raw_parts_mut(dst.add(co * plane), n);
                    let add = bias.map_or(0.0, |b| b[co]);
                    if relu_after {
                        row.iter_mut().for_each(|v| *v = (*v + add).max(0.0));
                    } else if add != 0.0 {
                        row.iter_mut().for_each(|v| *v += add);
                    }
                }
            }
        },
    );
    out
}

/// `dst = lhs · rhs` for row-major `lhs` (`[m, k]`) and `rhs` (`[k, n]`), `dst` being `m` rows
/// of `n` floats, `dst_stride` floats apart (the one GEMM call of the CPU paths).
///
/// # Safety
/// `dst` must be valid for writes of `m` rows of `n` floats spaced `dst_stride` apart, and no
/// other thread may access those elements during the call.
pub(crate) unsafe fn matmul_into(
    [m, n, k]: [usize; 3],
    dst: *mut f32,
    dst_stride: usize,
    lhs: &[f32],
    rhs: &[f32],
    parallelism: gemm::Parallelism,
) {
    assert!(lhs.len() >= m * k && rhs.len() >= k * n, "operand sizes");
    // SAFETY: the operands are checked above; `dst` is the caller's promise.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst,
            1,
            dst_stride as isize,
            false,
            lhs.as_ptr(),
            1,
            k as isize,
            rhs.as_ptr(),
            1,
            n as isize,
            0.0,
            1.0,
            false,
            false,
            false,
            parallelism,
        );
    }
}

/// Fills `cols` (`[cin · kh · kw, pixels of rows]`, row-major, zeroed) with the input values
/// each output pixel of rows `rows` sees through each kernel tap, zero beyond the image: row
/// `(c, ky, kx)` holds `x[c, y + ky − kh/2, x + kx − kw/2]`.
fn im2col_rows(
    x: &[f32],
    [cin, h, w]: [usize; 3],
    [kh, kw]: [usize; 2],
    rows: std::ops::Range<usize>,
    cols: &mut [f32],
) {
    let n = rows.len() * w;
    let (ry, rx) = ((kh / 2) as isize, (kw / 2) as isize);
    for c in 0..cin {
        let src = &x[c * h * w..][..h * w];
        for ky in 0..kh {
            for kx in 0..kw {
                let dst = &mut cols[((c * kh + ky) * kw + kx) * n..][..n];
                let dx = kx as isize - rx;
                for (i, y) in rows.clone().enumerate() {
                    let sy = y as isize + ky as isize - ry;
                    if sy < 0 || sy >= h as isize {
                        continue; // zero padding (the buffer starts zeroed)
                    }
                    let src_row = &src[sy as usize * w..][..w];
                    let dst_row = &mut dst[i * w..][..w];
                    // dst[x] = src[x + dx] where 0 <= x + dx < w
                    let lo = (-dx).max(0) as usize;
                    let hi = (w as isize - dx).min(w as isize).max(0) as usize;
                    if lo < hi {
                        let s0 = (lo as isize + dx) as usize;
                        dst_row[lo..hi].copy_from_slice(&src_row[s0..s0 + (hi - lo)]);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::conv::Conv2dConfig;

    fn values(n: usize, seed: usize) -> Vec<f32> {
        (0..n)
            .map(|i| ((i * 7919 + seed * 104_729) % 1000) as f32 / 500.0 - 1.0)
            .collect()
    }

    /// The largest difference between burn's convolution and the fast path, relative to the
    /// largest output magnitude.
    fn worst_relative_difference(
        cin: usize,
        cout: usize,
        k: usize,
        h: usize,
        w: usize,
        relu_after: bool,
    ) -> f32 {
        let device = Device::flex();
        let conv = Conv2dConfig::new([cin, cout], [k, k])
            .with_padding(PaddingConfig2d::Same)
            .init(&device);
        let x = Tensor::<4>::from_data(
            TensorData::new(values(2 * cin * h * w, 3), [2, cin, h, w]),
            &device,
        );
        let want = conv.forward(x.clone());
        let want = if relu_after { relu(want) } else { want };
        let want = want.into_data().try_into_vec::<f32>().unwrap();
        assert!(applies(&conv, &device));
        let got = conv2d(&conv, x, relu_after)
            .into_data()
            .try_into_vec::<f32>()
            .unwrap();
        assert_eq!(got.len(), want.len());
        let scale = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(scale > 0.1, "a test output of real size");
        got.iter()
            .zip(&want)
            .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()))
            / scale
    }

    #[test]
    fn the_fast_convolution_equals_burns_on_the_networks_shapes() {
        // the backbone's, the RA predictor's, a head's and an input convolution's shapes, on
        // sizes that are not multiples of the block (one row of 1 pixel, odd sizes)
        for (cin, cout, k, h, w, r) in [
            (32, 32, 3, 37, 45, true),
            (32, 16, 3, 20, 71, false),
            (16, 1, 3, 9, 13, false),
            (96, 25, 3, 17, 19, false),
            (13, 32, 3, 1, 1, true),
            (5, 7, 5, 11, 6, false),
            (8, 8, 1, 7, 9, true),
        ] {
            let d = worst_relative_difference(cin, cout, k, h, w, r);
            assert!(
                d < 1e-5,
                "{cin}→{cout} {k}×{k} on {w}×{h}: relative difference {d}"
            );
        }
    }

    #[test]
    fn the_direct_convolution_equals_the_gemm_path() {
        if !direct::available() {
            eprintln!("SKIPPED: this CPU has no AVX2 and FMA");
            return;
        }
        // the guided models' shapes and odd ones: widths that leave a partial pixel block,
        // output channels that leave a partial channel block, 1×1 and 5×5 kernels, a 1×1 map,
        // maps lower than the kernel's reach and than a job's rows
        for (b, cin, cout, k, h, w, relu_after, bias) in [
            (5, 16, 16, 3, 23, 37, true, true),
            (2, 19, 16, 3, 9, 16, true, true),
            (2, 16, 8, 3, 5, 33, false, false),
            (3, 8, 1, 3, 7, 21, false, true),
            (2, 16, 9, 3, 6, 50, false, true),
            (1, 13, 3, 3, 1, 1, true, true),
            (2, 5, 7, 5, 11, 6, false, true),
            (1, 8, 6, 1, 7, 9, true, false),
            (1, 4, 5, 3, 2, 3, false, true),
        ] {
            let x = values(b * cin * h * w, 3);
            let weight = values(cout * cin * k * k, 5);
            let bias = bias.then(|| values(cout, 7));
            let run = |path| {
                conv_same_nchw_by(
                    path,
                    &x,
                    [b, cin, h, w],
                    &weight,
                    [cout, k, k],
                    bias.as_deref(),
                    relu_after,
                )
            };
            let (want, got) = (run(ConvPath::Gemm), run(ConvPath::Direct));
            assert_eq!(got.len(), want.len());
            let scale = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            assert!(scale > 0.1, "a test output of real size");
            let worst = got
                .iter()
                .zip(&want)
                .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()))
                / scale;
            assert!(
                worst < 1e-5,
                "{b}×{cin}→{cout} {k}×{k} on {w}×{h}: relative difference {worst}"
            );
        }
    }

    #[test]
    fn training_devices_and_strided_convolutions_keep_burns_path() {
        let device = Device::flex();
        let conv = Conv2dConfig::new([4, 4], [3, 3])
            .with_padding(PaddingConfig2d::Same)
            .init(&device);
        // radn's path applies to this shape, but not on a training device
        assert!(applies(&conv, &device));
        #[cfg(feature = "autodiff")]
        assert!(!applies(&conv, &device.clone().autodiff()));
        let strided = Conv2dConfig::new([4, 4], [3, 3])
            .with_stride([2, 2])
            .with_padding(PaddingConfig2d::Same)
            .init(&device);
        assert!(!applies(&strided, &device));
        let valid = Conv2dConfig::new([4, 4], [3, 3]).init(&device);
        assert!(!applies(&valid, &device));
    }
}
