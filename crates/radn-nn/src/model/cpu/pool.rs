//! The 2×2 box average of the multi-scale kernels on the CPU, plane by plane in parallel
//! (burn's `flex` pooling runs on one core, and the multi-scale heads pool the 96-channel
//! features of every frame twice per tile).

use rayon::prelude::*;

/// The 2×2 box average of `[n, h, w]` planes (`h`, `w` even): `[n, h/2, w/2]`, each value
/// `(a + b + c + d) / 4` of its block, summed row by row as burn's average pooling does.
pub fn box_downsample(x: &[f32], [n, h, w]: [usize; 3]) -> Vec<f32> {
    assert!(h % 2 == 0 && w % 2 == 0, "even sizes, got {w}×{h}");
    assert_eq!(x.len(), n * h * w, "planes size");
    let (oh, ow) = (h / 2, w / 2);
    let mut out = vec![0.0f32; n * oh * ow];
    if out.is_empty() {
        return out;
    }
    out.par_chunks_mut(ow).enumerate().for_each(|(row, dst)| {
        let (plane, y) = (row / oh, row % oh);
        let top = &x[(plane * h + 2 * y) * w..][..w];
        let bottom = &x[(plane * h + 2 * y + 1) * w..][..w];
        for (i, d) in dst.iter_mut().enumerate() {
            *d = (top[2 * i] + top[2 * i + 1] + bottom[2 * i] + bottom[2 * i + 1]) / 4.0;
        }
    });
    out
}
