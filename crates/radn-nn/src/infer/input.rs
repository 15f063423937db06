//! From aligned windows (radn-core) to network tensors: the per-frame input features and the
//! linear values kernels are applied to.

use radn_core::align::AlignedWindow;
use radn_core::image::noise_level::NoiseLevelHistogram;
use radn_core::image::stats::{
    add_geometry_depths, add_log_luminance, log_average_luminance, mean_geometry_depth, FAR_DEPTH,
};
use rayon::prelude::*;

use crate::model::config::{InputConfig, INPUT_CHANNELS};

/// Largest magnitude of the log depth ratio fed to the network.
const DEPTH_CLAMP: f32 = 3.0;

/// A pixel rectangle `[x0, x1) × [y0, y1)` of a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Region {
    /// First column.
    pub x0: usize,
    /// First row.
    pub y0: usize,
    /// One past the last column.
    pub x1: usize,
    /// One past the last row.
    pub y1: usize,
}

impl Region {
    /// The whole `w × h` frame.
    pub fn whole(w: usize, h: usize) -> Self {
        Self {
            x0: 0,
            y0: 0,
            x1: w,
            y1: h,
        }
    }

    /// Width and height: regions of one size can share a network call.
    pub fn size(&self) -> (usize, usize) {
        (self.x1 - self.x0, self.y1 - self.y0)
    }

    /// Pixels in the region.
    pub fn pixels(&self) -> usize {
        (self.x1 - self.x0) * (self.y1 - self.y0)
    }

    /// The region's part of every channel of `plane`, channel-major.
    pub fn crop(&self, plane: &radn_core::Plane, out: &mut Vec<f32>) {
        let w = plane.width();
        for c in 0..plane.channels() {
            let ch = plane.channel(c);
            for y in self.y0..self.y1 {
                out.extend_from_slice(&ch[y * w + self.x0..y * w + self.x1]);
            }
        }
    }
}

/// The per-frame numbers a window's features are normalised by, and its input blend is set by.
/// They are statistics of the whole centre frame, so that its tiles and bands see the same
/// features (and blend) as the whole frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FeatureScales {
    /// The centre frame's mean geometry depth (1 without depth).
    pub depth: f32,
    /// The centre frame's exposure: its log-average luminance (1 for a black frame).
    pub exposure: f32,
    /// The centre frame's noise level ([`radn_core::image::noise_level`]; `None` for a black frame).
    pub noise_level: Option<f32>,
}

impl FeatureScales {
    /// The scales of a whole window.
    pub fn of(win: &AlignedWindow) -> Self {
        let c = win.centre();
        Self::of_centre(&c.color, c.albedo.as_ref(), c.depth.as_ref())
    }

    /// The scales of a window whose centre frame has these planes: the window's centre is the
    /// frame as rendered, so they can be known before the window is aligned (and set how it
    /// is aligned: [`crate::infer::NetworkDenoiser::align_params_for`]).
    pub fn of_centre(
        color: &radn_core::Plane,
        albedo: Option<&radn_core::Plane>,
        depth: Option<&radn_core::Plane>,
    ) -> Self {
        Self {
            depth: depth.map_or(1.0, |d| {
                mean_geometry_depth(add_geometry_depths(d, (0.0, 0)))
            }),
            exposure: log_average_luminance(add_log_luminance(color, (0.0, 0))),
            noise_level: NoiseLevelHistogram::of_frame(color, albedo).level(),
        }
    }

    /// The scales of a window whose centre frame's whole-frame statistics are `stats` (a
    /// frame denoised band by band, [`radn_core::run::banding::FrameStats`]).
    pub fn of_stats(stats: &radn_core::run::banding::FrameStats) -> Self {
        Self {
            depth: stats.mean_depth(),
            exposure: stats.exposure(),
            noise_level: stats.noise_level(),
        }
    }
}

/// Base network features of a window, `[T, INPUT_CHANNELS, H, W]` row-major: log colour,
/// albedo, normal, depth relative to the centre frame's mean (log), confidence. Tiles store
/// these; [`network_features`] derives what a given network reads.
pub fn features(win: &AlignedWindow) -> Vec<f32> {
    let c = win.centre();
    let region = Region::whole(c.color.width(), c.color.height());
    features_in(win, FeatureScales::of(win).depth, region)
}

/// The base features of [`features`] for one region of the frame, `[T, INPUT_CHANNELS, h, w]`
/// (tiled inference computes them tile by tile instead of holding the whole frame's). The
/// frames are filled in parallel.
pub fn features_in(win: &AlignedWindow, depth_ref: f32, region: Region) -> Vec<f32> {
    let n = region.pixels();
    let mut out = vec![0.0; win.frames.len() * INPUT_CHANNELS * n];
    out.par_chunks_mut(INPUT_CHANNELS * n)
        .zip(&win.frames)
        .for_each(|(dst, f)| frame_base_into(f, depth_ref, region, 1.0, dst));
    out
}

/// `region` of every channel of `plane`, mapped by `map`, into `dst` (channel-major).
fn crop_map(region: Region, plane: &radn_core::Plane, dst: &mut [f32], map: impl Fn(f32) -> f32) {
    let (w, rw) = (plane.width(), region.x1 - region.x0);
    let mut rows = dst.chunks_exact_mut(rw);
    for c in 0..plane.channels() {
        let ch = plane.channel(c);
        for y in region.y0..region.y1 {
            let src = &ch[y * w + region.x0..y * w + region.x1];
            let row = rows.next().expect("dst holds every channel's region");
            for (d, &v) in row.iter_mut().zip(src) {
                *d = map(v);
            }
        }
    }
}

/// One frame's base features for `region` into `dst` (`[INPUT_CHANNELS, n]`, zeros where the
/// frame lacks a buffer), with its log colour `ln(1 + max(0, c)·inv_exposure)`: `inv_exposure`
/// is 1 for the base features tiles store, and the reciprocal of the centre frame's exposure
/// for a network that normalises it — one logarithm per sample either way.
fn frame_base_into(
    f: &radn_core::align::AlignedFrame,
    depth_ref: f32,
    region: Region,
    inv_exposure: f32,
    dst: &mut [f32],
) {
    let n = region.pixels();
    let (colour, rest) = dst.split_at_mut(3 * n);
    crop_map(region, &f.color, colour, |v| {
        (v.max(0.0) * inv_exposure).ln_1p()
    });
    let (albedo, rest) = rest.split_at_mut(3 * n);
    match &f.albedo {
        Some(a) => crop_map(region, a, albedo, |v| v.clamp(0.0, 2.0)),
        None => albedo.fill(0.0),
    }
    let (normal, rest) = rest.split_at_mut(3 * n);
    match &f.normal {
        Some(nm) => crop_map(region, nm, normal, |v| v.clamp(-1.0, 1.0)),
        None => normal.fill(0.0),
    }
    let (depth, confidence) = rest.split_at_mut(n);
    match &f.depth {
        Some(d) => crop_map(region, d, depth, |z| {
            if z >= 0.5 * FAR_DEPTH || !z.is_finite() {
                DEPTH_CLAMP
            } else {
                (z.max(1e-6) / depth_ref)
                    .ln()
                    .clamp(-DEPTH_CLAMP, DEPTH_CLAMP)
            }
        }),
        None => depth.fill(0.0),
    }
    crop_map(region, &f.confidence, &mut confidence[..n], |v| v);
}

/// The input a network configured with `inputs` reads for one region, `[T, C, h, w]`: the
/// base features, colour divided by the exposure where asked, the noise estimate and the
/// guide. A network that reads a guide needs one in every frame of the window. Equal to
/// [`network_features`] of [`features_in`] (tested), built in one parallel pass per frame.
pub fn network_input(
    win: &AlignedWindow,
    scales: FeatureScales,
    region: Region,
    inputs: &InputConfig,
) -> Vec<f32> {
    let n = region.pixels();
    let c = inputs.channels();
    let frames = win.frames.len();
    let inv = if inputs.exposure {
        1.0 / scales.exposure
    } else {
        1.0
    };
    let guide_at = INPUT_CHANNELS + usize::from(inputs.noise);
    let mut out = vec![0.0; frames * c * n];
    out.par_chunks_mut(c * n)
        .zip(&win.frames)
        .for_each(|(dst, f)| {
            frame_base_into(f, scales.depth, region, inv, &mut dst[..INPUT_CHANNELS * n]);
            if inputs.guide {
                let plane = f
                    .guide
                    .as_ref()
                    .expect("a guided network's windows carry guides (checked by its denoiser)");
                crop_map(region, plane, &mut dst[guide_at * n..][..3 * n], |v| {
                    (v.max(0.0) * inv).ln_1p()
                });
            }
        });
    if inputs.noise {
        fill_noise(&mut out, frames, c, n);
    }
    out
}

/// The features a network configured with `inputs` reads, from the base features `base`
/// (`[T, INPUT_CHANNELS, n]`, as [`features_in`] makes and tiles store), the linear colour
/// `colour` (`[T, 3, n]`) of the same pixels and, for a guided network, their linear guide
/// `guide` (`[T, 3, n]`); `exposure` is the centre frame's ([`FeatureScales::exposure`]).
/// Training builds its input here; inference builds the same values with [`network_input`].
///
/// - `exposure`: the log colour becomes `ln(1 + max(0, c) / exposure)`.
/// - `noise`: one more channel per frame, the same in every frame: at each pixel, the spread
///   of the frames' log luminance `ℓ` (mean of the three log-colour channels), weighted by
///   their confidence `c_k`: `sqrt(Σ c_k (ℓ_k − ℓ̄)² / Σ c_k · n/(n − 1))` with `n = (Σ c_k)² /
///   Σ c_k²` the effective number of frames (0 where fewer than about one frame besides the
///   centre is trusted).
/// - `guide`: three more channels per frame, after the others: the guide transformed as the
///   log colour is (`ln(1 + max(0, g) / exposure)`, without the division where `exposure` is
///   off).
pub fn network_features(
    base: Vec<f32>,
    colour: &[f32],
    guide: Option<&[f32]>,
    frames: usize,
    pixels: usize,
    inputs: &InputConfig,
    exposure: f32,
) -> Vec<f32> {
    if inputs.is_base() {
        return base;
    }
    let n = pixels;
    let c = inputs.channels();
    debug_assert_eq!(base.len(), frames * INPUT_CHANNELS * n);
    debug_assert_eq!(colour.len(), frames * 3 * n);
    let mut out = Vec::with_capacity(frames * c * n);
    let inv = if inputs.exposure { 1.0 / exposure } else { 1.0 };
    let guide_at = INPUT_CHANNELS + usize::from(inputs.noise);
    if inputs.guide {
        let g = guide.expect("a guided network's input needs the guide");
        assert_eq!(g.len(), frames * 3 * n, "the guide is [T, 3, n]");
    }
    for k in 0..frames {
        let b = &base[k * INPUT_CHANNELS * n..(k + 1) * INPUT_CHANNELS * n];
        if inputs.exposure {
            let col = &colour[k * 3 * n..(k + 1) * 3 * n];
            out.extend(col.iter().map(|&v| (v.max(0.0) * inv).ln_1p()));
            out.extend_from_slice(&b[3 * n..]);
        } else {
            out.extend_from_slice(b);
        }
        if inputs.noise {
            out.extend(std::iter::repeat_n(0.0, n));
        }
        if let (true, Some(g)) = (inputs.guide, guide) {
            let g = &g[k * 3 * n..(k + 1) * 3 * n];
            out.extend(g.iter().map(|&v| (v.max(0.0) * inv).ln_1p()));
        }
    }
    debug_assert_eq!(guide_at + 3 * usize::from(inputs.guide), c);
    if inputs.noise {
        fill_noise(&mut out, frames, c, n);
    }
    out
}

/// Fills channel [`INPUT_CHANNELS`] of every frame of `out` (`[T, c, n]`) with the noise
/// estimate of [`network_features`], from the log colour (channels 0–2) and the confidence
/// (channel `INPUT_CHANNELS − 1`); pixels in parallel, each pixel's sums in frame order.
fn fill_noise(out: &mut [f32], frames: usize, c: usize, n: usize) {
    const CHUNK: usize = 4096;
    let at = |k: usize, ch: usize, p: usize| (k * c + ch) * n + p;
    let read: &[f32] = out;
    let mut sds = vec![0.0f32; n];
    sds.par_chunks_mut(CHUNK).enumerate().for_each(|(i, sds)| {
        // per frame: (log luminance, confidence) of the pixel
        let mut lw = vec![(0.0f32, 0.0f32); frames];
        for (j, sd) in sds.iter_mut().enumerate() {
            let p = i * CHUNK + j;
            let (mut sw, mut sww, mut swl) = (0.0f32, 0.0f32, 0.0f32);
            for (k, lw) in lw.iter_mut().enumerate() {
                let l = (read[at(k, 0, p)] + read[at(k, 1, p)] + read[at(k, 2, p)]) / 3.0;
                let w = read[at(k, INPUT_CHANNELS - 1, p)].clamp(0.0, 1.0);
                *lw = (l, w);
                sw += w;
                sww += w * w;
                swl += w * l;
            }
            *sd = 0.0;
            if sw > 0.0 {
                let mean = swl / sw;
                let spread = lw.iter().map(|&(l, w)| w * (l - mean).powi(2)).sum::<f32>() / sw;
                let n_eff = sw * sw / sww.max(f32::MIN_POSITIVE);
                if n_eff > 1.5 {
                    *sd = (spread * n_eff / (n_eff - 1.0)).sqrt();
                }
            }
        }
    });
    for k in 0..frames {
        out[at(k, INPUT_CHANNELS, 0)..][..n].copy_from_slice(&sds);
    }
}

/// The linear beauty of every frame, `[T, 3, H, W]`.
pub fn color_values(win: &AlignedWindow) -> Vec<f32> {
    win.frames
        .iter()
        .flat_map(|f| f.color.data().iter().copied())
        .collect()
}

/// Any per-frame plane of the window (an AOV by index, or alpha), `[T, C, H, W]`.
pub fn plane_values(
    win: &AlignedWindow,
    pick: impl Fn(&radn_core::align::AlignedFrame) -> &radn_core::Plane,
) -> Vec<f32> {
    win.frames
        .iter()
        .flat_map(|f| pick(f).data().iter().copied())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Standard normal draws from a fixed seed (Box–Muller on a 64-bit LCG's high bits).
    fn normals(seed: u64, n: usize) -> Vec<f32> {
        let mut state = seed;
        let mut uniform = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        (0..n)
            .map(|_| {
                let (a, b) = (uniform(), uniform());
                ((-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()) as f32
            })
            .collect()
    }

    /// Base features (zero but for confidence `conf(frame)`) and grey colour whose
    /// exposure-normalised log luminance is `mu + sigma·z` per frame and pixel.
    fn window(
        frames: usize,
        n: usize,
        mu: f32,
        sigma: f32,
        exposure: f32,
        conf: impl Fn(usize) -> f32,
    ) -> (Vec<f32>, Vec<f32>) {
        let z = normals(7, frames * n);
        let mut base = vec![0.0; frames * INPUT_CHANNELS * n];
        let mut colour = Vec::with_capacity(frames * 3 * n);
        for k in 0..frames {
            base[(k * INPUT_CHANNELS + INPUT_CHANNELS - 1) * n..][..n].fill(conf(k));
            for _ in 0..3 {
                colour.extend((0..n).map(|p| exposure * ((mu + sigma * z[k * n + p]).exp() - 1.0)));
            }
        }
        (base, colour)
    }

    const BOTH: InputConfig = InputConfig {
        exposure: true,
        noise: true,
        guide: false,
    };

    /// The noise channel (the same in every frame) of `network_features`' output.
    fn noise_channel(out: &[f32], n: usize) -> &[f32] {
        &out[INPUT_CHANNELS * n..(INPUT_CHANNELS + 1) * n]
    }

    #[test]
    fn the_noise_estimate_is_the_spread_of_the_trusted_frames() {
        let n = 4096;
        let (sigma, mu) = (0.2f32, 1.0f32);
        let (base, colour) = window(5, n, mu, sigma, 0.5, |_| 1.0);
        let out = network_features(base, &colour, None, 5, n, &BOTH, 0.5);
        assert_eq!(out.len(), 5 * 12 * n);
        let mean = noise_channel(&out, n).iter().sum::<f32>() / n as f32;
        // E[s] of 5 normal samples is c4(5)·σ = 0.9400·σ
        let expected = 0.9400 * sigma;
        assert!(
            (mean - expected).abs() < 0.03 * expected,
            "{mean} vs {expected}"
        );
        for k in 1..5 {
            assert_eq!(
                &out[(k * 12 + 11) * n..(k * 12 + 12) * n],
                noise_channel(&out, n),
                "every frame carries the window's estimate"
            );
        }
        // without noise the estimate is zero
        let (base, colour) = window(5, 64, mu, 0.0, 0.5, |_| 1.0);
        let out = network_features(base, &colour, None, 5, 64, &BOTH, 0.5);
        assert!(noise_channel(&out, 64).iter().all(|&s| s < 1e-6));
    }

    #[test]
    fn untrusted_frames_do_not_count() {
        let n = 256;
        // frame 0 is misaligned (confidence 0) and wildly different
        let (base, mut colour) = window(5, n, 1.0, 0.2, 1.0, |k| if k == 0 { 0.0 } else { 1.0 });
        colour[..3 * n].fill(1000.0);
        let out = network_features(base.clone(), &colour, None, 5, n, &BOTH, 1.0);
        // the same as the four trusted frames alone
        let four = network_features(
            base[INPUT_CHANNELS * n..].to_vec(),
            &colour[3 * n..],
            None,
            4,
            n,
            &BOTH,
            1.0,
        );
        for (a, b) in noise_channel(&out, n).iter().zip(noise_channel(&four, n)) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
        // only the centre trusted: nothing to estimate from, zero
        let (base, colour) = window(5, n, 1.0, 0.2, 1.0, |k| if k == 2 { 1.0 } else { 0.0 });
        let out = network_features(base, &colour, None, 5, n, &BOTH, 1.0);
        assert!(noise_channel(&out, n).iter().all(|&s| s == 0.0));
    }

    #[test]
    fn exposure_normalised_features_do_not_see_the_hdr_scale() {
        let n = 512;
        let (base, colour) = window(5, n, 0.7, 0.3, 0.25, |k| 0.5 + 0.1 * k as f32);
        let brighter: Vec<f32> = colour.iter().map(|v| v * 8.0).collect();
        let a = network_features(base.clone(), &colour, None, 5, n, &BOTH, 0.25);
        let b = network_features(base.clone(), &brighter, None, 5, n, &BOTH, 2.0);
        for (i, (x, y)) in a.iter().zip(&b).enumerate() {
            assert!((x - y).abs() < 1e-5, "feature {i}: {x} vs {y}");
        }
        // the base log colour does see it
        let log = |c: &[f32]| c.iter().map(|v| v.ln_1p()).collect::<Vec<f32>>();
        let moved = log(&colour)
            .iter()
            .zip(log(&brighter))
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max);
        assert!(moved > 1.0, "{moved}");
        // base features pass through untouched
        let plain = network_features(
            base.clone(),
            &colour,
            None,
            5,
            n,
            &InputConfig::default(),
            0.25,
        );
        assert_eq!(plain, base);
    }

    #[test]
    fn exposure_is_the_log_average_luminance() {
        let win_colour =
            |v: f32| radn_core::Plane::from_fn(4, 2, 3, move |x, _, _| v * (1 + x) as f32);
        let key = |p: &radn_core::Plane| log_average_luminance(add_log_luminance(p, (0.0, 0)));
        // geometric mean of 1, 2, 3, 4 (twice): 24^(1/4)
        let e = key(&win_colour(1.0));
        assert!((e - 24f32.powf(0.25)).abs() < 1e-5, "{e}");
        // it scales with the frame, exactly for a power of two
        assert!((key(&win_colour(8.0)) - 8.0 * e).abs() < 1e-5 * e);
        // black frames have exposure 1
        assert_eq!(key(&win_colour(0.0)), 1.0);
    }

    #[test]
    fn the_guide_follows_the_other_features_transformed_as_the_colour() {
        let n = 6;
        let (base, colour) = window(5, n, 1.0, 0.2, 1.0, |_| 1.0);
        let guide: Vec<f32> = (0..5 * 3 * n).map(|i| 0.1 * i as f32).collect();
        let guided = InputConfig {
            guide: true,
            ..BOTH
        };
        let exposure = 0.5;
        let out = network_features(base.clone(), &colour, Some(&guide), 5, n, &guided, exposure);
        let c = guided.channels();
        assert_eq!(c, 15);
        let plain = network_features(base, &colour, None, 5, n, &BOTH, exposure);
        for k in 0..5 {
            // the other features are untouched, the guide comes last
            assert_eq!(
                &out[k * c * n..(k * c + 12) * n],
                &plain[k * 12 * n..(k + 1) * 12 * n]
            );
            for ch in 0..3 {
                for p in 0..n {
                    let g = guide[(k * 3 + ch) * n + p];
                    let got = out[(k * c + 12 + ch) * n + p];
                    assert!((got - (g / exposure).ln_1p()).abs() < 1e-6);
                }
            }
        }
    }
}
