//! Applying per-pixel kernels to a window's values on the CPU, row by row in parallel, reading
//! each neighbour directly instead of unfolding every pixel's k×k×frames neighbourhood into
//! memory (for a 5×5×5 kernel that is 125 copies of every value, and most of the kernel
//! application's time in burn).

use rayon::prelude::*;

use crate::model::cpu::SendPtr;

/// `Σ_t Σ_(dy,dx) weights[b, t·k² + (dy·k + dx), y, x] · values[b, t, c, y + dy − k/2,
/// x + dx − k/2]`, the edge pixels repeating beyond the image (the same as
/// [`crate::model::kernel::Kernels::apply`]): `weights` is `[b, t·k², h, w]`, `values`
/// `[b, t, c, h, w]`, the result `[b, c, h, w]`.
pub fn apply_kernels(
    weights: &[f32],
    values: &[f32],
    [b, t, c, h, w]: [usize; 5],
    k: usize,
) -> Vec<f32> {
    let k2 = k * k;
    let plane = h * w;
    assert_eq!(weights.len(), b * t * k2 * plane, "kernel weights size");
    assert_eq!(values.len(), b * t * c * plane, "values size");
    let mut out = vec![0.0f32; b * c * plane];
    if plane == 0 || c == 0 {
        return out;
    }
    let r = (k / 2) as isize;
    let out_ptr = SendPtr(out.as_mut_ptr());
    (0..b * h).into_par_iter().for_each(|job| {
        let (image, y) = (job / h, job % h);
        for ch in 0..c {
            // SAFETY: job (image, y) writes only row y of each of the image's channels, so no
            // two jobs write the same elements, and the row lies within `out`.
            let dst = unsafe {
                std::slice::from_raw_parts_mut(
                    out_ptr.get().add((image * c + ch) * plane + y * w),
                    w,
                )
            };
            for frame in 0..t {
                let src = &values[((image * t + frame) * c + ch) * plane..][..plane];
                for dy in 0..k {
                    let sy = (y as isize + dy as isize - r).clamp(0, h as isize - 1) as usize;
                    let src_row = &src[sy * w..][..w];
                    for dx in 0..k {
                        let tap = (frame * k2 + dy * k + dx) * plane;
                        let wrow = &weights[(image * t * k2) * plane + tap + y * w..][..w];
                        accumulate_shifted(dst, wrow, src_row, dx as isize - r);
                    }
                }
            }
        }
    });
    out
}

/// `dst[x] += weight[x] · src[clamp(x + shift)]` over a row.
fn accumulate_shifted(dst: &mut [f32], weight: &[f32], src: &[f32], shift: isize) {
    let w = dst.len();
    // the interior, where x + shift stays within the row
    let lo = (-shift).max(0) as usize;
    let hi = (w as isize - shift.max(0)).max(lo as isize) as usize;
    if lo < hi {
        let s0 = (lo as isize + shift) as usize;
        for ((d, &wt), &v) in dst[lo..hi]
            .iter_mut()
            .zip(&weight[lo..hi])
            .zip(&src[s0..s0 + (hi - lo)])
        {
            *d += wt * v;
        }
    }
    // the clamped edges
    for x in (0..lo.min(w)).chain(hi.max(lo)..w) {
        let sx = (x as isize + shift).clamp(0, w as isize - 1) as usize;
        dst[x] += weight[x] * src[sx];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The formula, one output at a time.
    fn naive(weights: &[f32], values: &[f32], [b, t, c, h, w]: [usize; 5], k: usize) -> Vec<f32> {
        let k2 = k * k;
        let r = (k / 2) as isize;
        let mut out = vec![0.0f32; b * c * h * w];
        for i in 0..b {
            for ch in 0..c {
                for y in 0..h {
                    for x in 0..w {
                        let mut s = 0.0;
                        for f in 0..t {
                            for dy in 0..k {
                                for dx in 0..k {
                                    let sy = (y as isize + dy as isize - r).clamp(0, h as isize - 1)
                                        as usize;
                                    let sx = (x as isize + dx as isize - r).clamp(0, w as isize - 1)
                                        as usize;
                                    let wt = weights
                                        [((i * t * k2 + f * k2 + dy * k + dx) * h + y) * w + x];
                                    s += wt * values[(((i * t + f) * c + ch) * h + sy) * w + sx];
                                }
                            }
                        }
                        out[((i * c + ch) * h + y) * w + x] = s;
                    }
                }
            }
        }
        out
    }

    #[test]
    fn row_by_row_application_equals_the_formula_including_the_edges() {
        // rows narrower than the kernel, a single row, and an ordinary tile
        for (dims, k) in [
            ([2, 5, 3, 9, 11], 5),
            ([1, 3, 1, 1, 2], 5),
            ([1, 1, 4, 6, 3], 3),
        ] {
            let [b, t, c, h, w] = dims;
            let wts: Vec<f32> = (0..b * t * k * k * h * w)
                .map(|i| ((i * 37) % 101) as f32 / 101.0)
                .collect();
            let vals: Vec<f32> = (0..b * t * c * h * w)
                .map(|i| ((i * 53) % 97) as f32 / 9.7 - 3.0)
                .collect();
            let got = apply_kernels(&wts, &vals, dims, k);
            let want = naive(&wts, &vals, dims, k);
            let worst = got
                .iter()
                .zip(&want)
                .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
            assert!(worst < 1e-4, "{dims:?} k={k}: worst difference {worst}");
        }
    }
}
