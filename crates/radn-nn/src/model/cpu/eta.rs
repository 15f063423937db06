//! The kernel activation η_t with its identity fallback (paper eq. 3) on the CPU, one parallel
//! pass per block of pixels instead of about ten whole-tensor burn operations over the
//! `frames · k²` weight planes (those ran on one core and were most of the heads' time).
//! Computes what [`crate::model::kernel::eta`] does (tested against it).

use rayon::prelude::*;

use crate::model::config::Activation;
use crate::model::cpu::SendPtr;

/// Pixels per parallel job.
const BLOCK: usize = 2048;

/// η_t over dimension 1 of raw weights `[b, k, h, w]` after `activation`'s normalisation;
/// pixels whose weights are all at most `t` get the identity (all weight on `identity_tap`).
pub fn eta(
    raw: &[f32],
    [b, k, h, w]: [usize; 4],
    t: f32,
    activation: Activation,
    identity_tap: usize,
) -> Vec<f32> {
    let plane = h * w;
    assert_eq!(raw.len(), b * k * plane, "raw weights size");
    assert!(identity_tap < k, "identity tap {identity_tap} of {k}");
    let mut out = vec![0.0f32; raw.len()];
    let blocks = plane.div_ceil(BLOCK);
    let out_ptr = SendPtr(out.as_mut_ptr());
    (0..b * blocks).into_par_iter().for_each(|job| {
        let (image, block) = (job / blocks, job % blocks);
        let p0 = block * BLOCK;
        let n = BLOCK.min(plane - p0);
        let src = |tap: usize| &raw[(image * k + tap) * plane + p0..][..n];
        // SAFETY: job (image, block) writes only pixels p0..p0 + n of its image's k planes,
        // which no other job touches, and they lie within `out`.
        let dst = |tap: usize| unsafe {
            std::slice::from_raw_parts_mut(out_ptr.get().add((image * k + tap) * plane + p0), n)
        };
        // the activation's normalisation: per pixel a shift and a scale of each weight
        let mut scale = vec![1.0f32; n];
        let mut shift = vec![0.0f32; n];
        match activation {
            Activation::Eta => {}
            Activation::NormEta => {
                let mut sum = vec![0.0f32; n];
                for tap in 0..k {
                    for (s, &v) in sum.iter_mut().zip(src(tap)) {
                        *s += v.max(0.0);
                    }
                }
                for (sc, s) in scale.iter_mut().zip(&sum) {
                    *sc = s.max(1e-12);
                }
            }
            Activation::SoftmaxEta => {
                let mut max = vec![f32::NEG_INFINITY; n];
                for tap in 0..k {
                    for (m, &v) in max.iter_mut().zip(src(tap)) {
                        *m = m.max(v);
                    }
                }
                let mut sum = vec![0.0f32; n];
                for tap in 0..k {
                    for ((s, &v), &m) in sum.iter_mut().zip(src(tap)).zip(&max) {
                        *s += (v - m).exp();
                    }
                }
                shift = max;
                scale = sum;
            }
        }
        // kept = max(0, w − t), and its sum
        let mut kept_sum = vec![0.0f32; n];
        for tap in 0..k {
            let d = dst(tap);
            for (i, &v) in src(tap).iter().enumerate() {
                let wgt = match activation {
                    Activation::Eta => v,
                    Activation::NormEta => v.max(0.0) / scale[i],
                    Activation::SoftmaxEta => (v - shift[i]).exp() / scale[i],
                };
                let kept = (wgt - t).max(0.0);
                d[i] = kept;
                kept_sum[i] += kept;
            }
        }
        for tap in 0..k {
            let d = dst(tap);
            for (i, v) in d.iter_mut().enumerate() {
                let s = kept_sum[i];
                *v = if s <= 0.0 {
                    if tap == identity_tap {
                        1.0
                    } else {
                        0.0
                    }
                } else {
                    *v / s.max(1e-12)
                };
            }
        }
    });
    out
}
