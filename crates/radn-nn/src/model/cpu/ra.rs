//! A Robust Average block's inference on the CPU (paper section 3, Fig. 2), fused: each step's
//! robust mean, predictor and blend run as single parallel passes over `f32` slices instead of
//! a dozen burn operations that each allocate a frame-sized tensor (in burn's `flex` backend
//! these element-wise passes ran on one core and took about a fifth of a denoising run).
//! Computes what [`crate::model::ra_block::RobustAverage::forward`] does, in the same order of
//! operations (tested against it).

use rayon::prelude::*;

use crate::model::cpu::conv::HostConv;

/// Elements per parallel job of the element-wise passes.
const CHUNK: usize = 16 * 1024;

/// The three convolutions of a block's weight predictor.
pub struct RobustAverageConvs {
    /// Over `h_i`, for every frame at once (with the predictor's hidden bias).
    pub hidden_self: HostConv,
    /// Over the robust average of the other frames (no bias).
    pub hidden_avg: HostConv,
    /// Hidden features → one blend weight per pixel (before the sigmoid).
    pub weight: HostConv,
}

/// The block applied to `h` (`[b, t, c, hh, ww]`, the latent maps of `t` frames per batch
/// item): for each frame in turn, the robust average of the other frames (the mean without the
/// minimum and maximum, from three frames on; the maps the earlier steps updated) is blended
/// into it with the predicted per-pixel weight.
pub fn robust_average(h: &[f32], dims: [usize; 5], convs: &RobustAverageConvs) -> Vec<f32> {
    robust_average_steps(h, dims, convs, dims[1])
}

/// [`robust_average`] for only the first `steps` frames of each batch item: the later frames
/// are returned as given. A step reads only the frames before it as updated, so the first
/// `steps` frames equal the whole block's (a window's centre needs the steps up to its own).
pub fn robust_average_steps(
    h: &[f32],
    [b, t, c, hh, ww]: [usize; 5],
    convs: &RobustAverageConvs,
    steps: usize,
) -> Vec<f32> {
    let plane = hh * ww;
    let map = c * plane;
    assert_eq!(h.len(), b * t * map, "latent maps size");
    assert!(steps <= t, "at most one step per frame");
    let hc = convs.hidden_self.out_channels();
    // the h_i half of the predictor for the frames that are stepped
    let pre: Vec<f32> = if steps == t {
        convs.hidden_self.run(h, b * t, hh, ww, false)
    } else {
        (0..b)
            .flat_map(|item| {
                let first = &h[item * t * map..][..steps * map];
                convs.hidden_self.run(first, steps, hh, ww, false)
            })
            .collect()
    };
    let mut frames = h.to_vec();
    let mut avg = vec![0.0f32; map];
    for item in 0..b {
        let base = item * t * map;
        for i in 0..steps {
            robust_mean_into(&frames[base..base + t * map], t, map, i, &mut avg);
            // relu(pre_i + conv(avg)), then the blend weight
            let mut hidden = convs.hidden_avg.run(&avg, 1, hh, ww, false);
            let pre_i = &pre[(item * steps + i) * hc * plane..][..hc * plane];
            hidden
                .par_chunks_mut(CHUNK)
                .zip(pre_i.par_chunks(CHUNK))
                .for_each(|(d, p)| {
                    for (d, &p) in d.iter_mut().zip(p) {
                        *d = (p + *d).max(0.0);
                    }
                });
            let weight = convs.weight.run(&hidden, 1, hh, ww, false);
            let weight: Vec<f32> = weight.par_iter().map(|&x| sigmoid(x)).collect();
            let frame = &mut frames[base + i * map..][..map];
            frame
                .par_chunks_mut(plane)
                .zip(avg.par_chunks(plane))
                .for_each(|(f, a)| {
                    for ((f, &a), &w) in f.iter_mut().zip(a).zip(&weight) {
                        *f = *f * (1.0 - w) + a * w;
                    }
                });
        }
    }
    frames
}

/// The robust mean of the `t` maps of `window` (each `map` long) other than map `skip`, into
/// `out`: the sum in frame order, less the maximum and the minimum, over `n − 2` (the plain
/// mean below three maps), as [`crate::model::ra_block::robust_mean`] computes it.
fn robust_mean_into(window: &[f32], t: usize, map: usize, skip: usize, out: &mut [f32]) {
    let others: Vec<&[f32]> = (0..t)
        .filter(|&j| j != skip)
        .map(|j| &window[j * map..][..map])
        .collect();
    let n = others.len();
    out.par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(chunk, dst)| {
            let at = chunk * CHUNK;
            for (e, d) in dst.iter_mut().enumerate() {
                let first = others[0][at + e];
                let (mut sum, mut hi, mut lo) = (first, first, first);
                for o in &others[1..] {
                    let v = o[at + e];
                    sum += v;
                    hi = hi.max(v);
                    lo = lo.min(v);
                }
                *d = if n >= 3 {
                    (sum - hi - lo) / (n - 2) as f32
                } else {
                    sum / n as f32
                };
            }
        });
}

/// The logistic function, computed as burn's CPU backend does.
fn sigmoid(x: f32) -> f32 {
    if x >= 0.0 {
        1.0 / (1.0 + (-x).exp())
    } else {
        let e = x.exp();
        e / (1.0 + e)
    }
}
