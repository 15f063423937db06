//! Tests of the network denoiser: tiling, bands, the recipe's stages, the guide mix.

use super::*;
use crate::infer::input_blend::InputBlend;
use crate::infer::tiles::batches;
use crate::model::config::NetConfig;
use burn::tensor::{Tensor, TensorData};
use radn_core::align::AlignedFrame;
use radn_core::run::denoiser::{BandDenoiser, WindowDenoiser};
use radn_core::Plane;

/// A denoiser of `d` running its kernels alone: every stage of its recipe off.
fn bare(d: Denoiser, device: Device) -> NetworkDenoiser {
    let mut n = NetworkDenoiser::new(d, device);
    n.recipe = n.recipe.without_stages();
    n
}

fn window(w: usize, h: usize) -> AlignedWindow {
    let plane = |c: usize, k: usize| {
        Plane::from_fn(w, h, c, |x, y, ch| {
            (((x * 7 + y * 13 + ch * 3 + k * 11) % 23) as f32) / 23.0
        })
    };
    AlignedWindow {
        frames: (0..5)
            .map(|k| AlignedFrame {
                offset: k as i32 - 2,
                color: plane(3, k),
                alpha: Some(plane(1, k + 1)),
                albedo: Some(plane(3, k + 2)),
                normal: Some(plane(3, k + 3)),
                depth: Some(Plane::filled(w, h, 1, 3.0)),
                aovs: vec![plane(3, k + 4)],
                guide: None,
                variance: None,
                confidence: Plane::filled(w, h, 1, 0.9),
                flow: Plane::zeros(w, h, 2),
            })
            .collect(),
    }
}

/// The largest difference between two results over colour, the first AOV and alpha.
fn worst_difference(whole: &Denoised, tiled: &Denoised) -> f32 {
    [
        (&whole.color, &tiled.color),
        (&whole.aovs[0], &tiled.aovs[0]),
        (whole.alpha.as_ref().unwrap(), tiled.alpha.as_ref().unwrap()),
    ]
    .iter()
    .flat_map(|(a, b)| a.data().iter().zip(b.data()).map(|(x, y)| (x - y).abs()))
    .fold(0.0f32, f32::max)
}

/// The shipped default model (trained: its kernels depend strongly on the features).
fn shipped(device: &Device) -> Denoiser {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/default.safetensors");
    crate::model::store::load(&path, device).unwrap()
}

/// `n` frames of a noisy textured surface moving by a sub-pixel step per frame, with albedo,
/// normal, depth and motion both ways, named `frame0`, `frame1`, …
fn moving_frames(w: usize, h: usize, n: usize) -> Vec<Frame> {
    let (vx, vy) = (0.6f32, -0.35f32);
    let texture = |u: f32, v: f32, c: usize| {
        0.5 + 0.4 * (u * 0.7 + c as f32).sin() * (v * 0.45 + 0.3 * c as f32).cos()
    };
    (0..n)
        .map(|t| {
            let at = |x: usize, y: usize| (x as f32 - vx * t as f32, y as f32 - vy * t as f32);
            let grain = |x: usize, y: usize, c: usize| {
                let k = (x * 73 + y * 151 + c * 29 + t * 977) as u32;
                let k = k.wrapping_mul(2_654_435_761) >> 16;
                (k % 1000) as f32 / 1000.0 - 0.5
            };
            let mut f = Frame::synthetic(Plane::from_fn(w, h, 3, |x, y, c| {
                let (u, v) = at(x, y);
                texture(u, v, c) * (1.0 + 0.8 * grain(x, y, c))
            }));
            f.albedo = Some(Plane::from_fn(w, h, 3, |x, y, c| {
                let (u, v) = at(x, y);
                texture(u, v, c)
            }));
            f.normal = Some(Plane::from_fn(w, h, 3, |_, _, c| f32::from(c == 2)));
            f.depth = Some(Plane::filled(w, h, 1, 4.0));
            // content moves by +v per frame: a point was at p − v one frame earlier
            f.motion_prev = Some(Plane::from_fn(
                w,
                h,
                2,
                |_, _, c| if c == 0 { -vx } else { -vy },
            ));
            f.motion_next = Some(Plane::from_fn(
                w,
                h,
                2,
                |_, _, c| if c == 0 { vx } else { vy },
            ));
            f.path = format!("frame{t}").into();
            f
        })
        .collect()
}

#[test]
fn frame_layers_computed_once_equal_recomputing_them_in_every_window() {
    let device = Device::flex();
    let d = shipped(&device).with_frame_local_stem(&device).unwrap();
    let halo = d.receptive_radius().unwrap();
    let frames = moving_frames(2 * halo + 70, 44, 7);
    let mut n = NetworkDenoiser::new(d, device);
    assert!(n.has_frame_features() && n.band_features().is_some());
    // each frame's stem once, in tiles of 16 px (its halo is 7 px)
    n.tile = 16;
    let prepared: Vec<Frame> = frames
        .iter()
        .map(|f| {
            let mut p = f.clone();
            p.features = n.frame_features(f);
            p
        })
        .collect();
    let stem = |k: usize| prepared[k].features.as_ref().expect("prepared").clone();
    assert_eq!(stem(0).channels(), n.denoiser.stem_channels());
    assert_ne!(
        stem(0).data(),
        stem(1).data(),
        "frames differ, so do their features"
    );
    let len = frames.len();
    for pos in 0..len {
        let idx = radn_core::align::window_indices(pos, len, 2);
        fn pick<'a>(idx: &[Option<usize>], set: &'a [Frame]) -> Vec<Option<&'a Frame>> {
            idx.iter().map(|i| i.map(|i| &set[i])).collect()
        }
        // reused: the prepared features, windows in tiles of 32 px; recomputed: every frame's
        // stem again for this window, whole frames at once
        n.tile = 32;
        let reused = n.denoise(&pick(&idx, &prepared)).unwrap();
        n.tile = 0;
        let recomputed = n.denoise(&pick(&idx, &frames)).unwrap();
        let worst = reused
            .color
            .data()
            .iter()
            .zip(recomputed.color.data())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(
            worst < 1e-5,
            "frame {pos}: reused and recomputed differ by {worst}"
        );
    }
}

#[test]
fn splitting_the_stem_keeps_a_trusted_frames_kernels() {
    let device = Device::flex();
    let whole = shipped(&device);
    let split = whole.clone().with_frame_local_stem(&device).unwrap();
    let halo = whole.receptive_radius().unwrap();
    let (b, t, c, s) = (1, 5, whole.config.input_channels(), 2 * halo + 12);
    // inputs in their usual ranges, confidence 1 and noise estimate 0: what the split folds
    let (conf, count) = whole.config.inputs.window_channels();
    let x = Tensor::<5>::from_data(
        TensorData::new(
            (0..b * t * c * s * s)
                .map(|i| {
                    let ch = (i / (s * s)) % c;
                    match ch {
                        _ if ch == conf => 1.0,
                        _ if ch > conf && ch < conf + count => 0.0,
                        _ => ((i * 7919 % 1000) as f32 / 1000.0) * 0.8,
                    }
                })
                .collect::<Vec<f32>>(),
            [b, t, c, s, s],
        ),
        &device,
    );
    let values = Tensor::<5>::from_data(
        TensorData::new(
            (0..b * t * 3 * s * s)
                .map(|i| (i * 613 % 997) as f32 / 997.0)
                .collect::<Vec<f32>>(),
            [b, t, 3, s, s],
        ),
        &device,
    );
    let out = |d: &Denoiser| {
        let p = d.predict(x.clone(), d.config.default_threshold());
        p.apply(values.clone())
            .into_data()
            .try_into_vec::<f32>()
            .unwrap()
    };
    let (a, bb) = (out(&whole), out(&split));
    // pixels farther than the receptive field from the edges (the zero padding at the
    // edges reads no confidence; the folded bias does)
    let mut worst = 0.0f32;
    for ch in 0..3 {
        for y in halo..s - halo {
            for xx in halo..s - halo {
                let i = (ch * s + y) * s + xx;
                worst = worst.max((a[i] - bb[i]).abs());
            }
        }
    }
    assert!(
        worst < 1e-4,
        "split and whole stems differ by {worst} inside"
    );
    // and the window's channels still reach the kernels through the new 1×1 layer's place
    assert!(split.config.frame_local_stem && split.stem_channels() > 0);
}

#[test]
fn the_automatic_tile_doubles_only_for_narrow_networks() {
    let narrow = Denoiser::new(NetConfig::preset("guided-lean").unwrap(), &Device::flex());
    // 5 frames × 16 channels × (512 + 2 · 36)² px × 4 B = 109 MB: 512; 1024 would be 384 MB
    assert_eq!(auto_tile(&narrow), 512);
    // the default model's width (32, 96 head channels with its skips) keeps 256
    let wide = Denoiser::new(NetConfig::preset("small").unwrap(), &Device::flex());
    assert_eq!(auto_tile(&wide), 256);
    assert_eq!(NetworkDenoiser::new(wide, Device::flex()).tile, 256);
}

#[test]
fn the_colour_term_loosens_with_the_noise_level_and_stops_at_noisy_frames() {
    let d = Denoiser::new(NetConfig::preset("small").unwrap(), &Device::flex());
    let mut n = bare(d, Device::flex());
    let tol = |n: &NetworkDenoiser, level: Option<f32>| n.align_params_for(level).confidence.color;
    // unset: alignment's own setting at every level
    assert_eq!(tol(&n, Some(0.01)), None);
    n.recipe.confidence.color = Some(0.5);
    // the cleanest frames get the base, twice the lowest level's noise twice the base
    let lowest = n.recipe.schedule.level_at_min;
    assert_eq!(tol(&n, Some(0.01)), Some(0.5));
    assert_eq!(tol(&n, Some(lowest)), Some(0.5));
    assert!((tol(&n, Some(2.0 * lowest)).unwrap() - 1.0).abs() < 1e-6);
    // as noisy as the input blend's end (4 spp): off; a black frame has no level: off
    let edge = n.recipe.schedule.noisiest_level();
    assert!((tol(&n, Some(edge)).unwrap() - 2.0).abs() < 1e-6);
    assert_eq!(tol(&n, Some(1.01 * edge)), None);
    assert_eq!(tol(&n, None), None);
    // the other terms are alignment's own
    assert_eq!(
        n.align_params_for(Some(0.01)).confidence.albedo,
        n.align_base().confidence.albedo
    );
}

#[test]
fn the_sampled_buffers_terms_loosen_with_the_noise_level_up_to_the_most() {
    let d = Denoiser::new(NetConfig::preset("small").unwrap(), &Device::flex());
    let mut n = bare(d, Device::flex());
    let albedo = |n: &NetworkDenoiser, level| n.align_params_for(level).confidence.albedo;
    let strict = n.align_base().confidence.albedo;
    // unset: the strict tolerance at every level, 4 spp included
    assert_eq!(albedo(&n, Some(10.0)), strict);
    n.recipe.confidence.loosen_sampled = Some(4.0);
    let lowest = n.recipe.schedule.level_at_min;
    let edge = n.recipe.schedule.noisiest_level();
    // the cleanest frames keep it, twice the lowest level's noise doubles it, and frames as
    // noisy as 4 spp (or without a level) get the most
    assert_eq!(albedo(&n, Some(0.01)), strict);
    assert!((albedo(&n, Some(2.0 * lowest)) - 2.0 * strict).abs() < 1e-6);
    assert!((albedo(&n, Some(1.01 * edge)) - 4.0 * strict).abs() < 1e-6);
    assert!((albedo(&n, None) - 4.0 * strict).abs() < 1e-6);
    // never past the most, and the motion term is left alone
    n.recipe.confidence.loosen_sampled = Some(1.5);
    assert!((albedo(&n, Some(2.0 * lowest)) - 1.5 * strict).abs() < 1e-6);
    assert_eq!(
        n.align_params_for(Some(10.0)).confidence.motion_px,
        n.align_base().confidence.motion_px
    );
    // a guide's term does not loosen with them
    n.recipe.confidence.guide = Some(0.6);
    assert_eq!(n.align_params_for(Some(10.0)).confidence.guide, Some(0.6));
}

#[test]
fn the_input_blend_keeps_a_noise_free_input_and_follows_a_noisy_one() {
    let d = Denoiser::new(NetConfig::preset("small").unwrap(), &Device::flex());
    let mut n = bare(d, Device::flex());
    n.recipe.input_blend = Some(InputBlend {
        radius: 1,
        noise_scale: Some(2.0),
        variance_radius: Some(4),
        variance_scale: None,
    });
    // five identical frames: no noise, so nothing the kernels change is explained by it
    let mut still = window(24, 20);
    let centre = still.frames[2].clone();
    for (k, f) in still.frames.iter_mut().enumerate() {
        *f = AlignedFrame {
            offset: k as i32 - 2,
            ..centre.clone()
        };
    }
    let out = n.denoise_aligned(&still);
    let off = |a: &Plane, b: &Plane| {
        a.data()
            .iter()
            .zip(b.data())
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max)
    };
    // the input, up to rounding (the frames' spread is not exactly 0 in floats) ...
    assert!(off(&out.color, &centre.color) < 1e-6);
    assert!(off(&out.aovs[0], &centre.aovs[0]) < 1e-6);
    assert!(off(out.alpha.as_ref().unwrap(), centre.alpha.as_ref().unwrap()) < 1e-6);
    // ... where the kernels alone change it
    let unblended = bare(n.denoiser.clone(), Device::flex());
    assert!(off(&unblended.denoise_aligned(&still).color, &centre.color) > 0.05);
    // frames that differ: their spread is noise, and the kernels' result is kept where
    // its change is no larger
    let noisy = window(24, 20);
    let plain = unblended.denoise_aligned(&noisy);
    let blended = n.denoise_aligned(&noisy);
    let input = noisy.centre().color.data();
    let kept = blended
        .color
        .data()
        .iter()
        .zip(plain.color.data())
        .zip(input)
        .filter(|((b, p), x)| (*b - *p).abs() < 1e-6 && (*p - *x).abs() > 1e-3)
        .count();
    assert!(kept > input.len() / 4, "{kept} of {}", input.len());
}

#[test]
fn the_mix_range_follows_the_noise_level_and_takes_the_window_guide_at_every_level() {
    use guide_mix::MixGuide;
    let d = Denoiser::new(NetConfig::preset("small").unwrap(), &Device::flex());
    let mut n = bare(d, Device::flex());
    let clean = Some(0.01);
    let twice = Some(2.0 * n.recipe.schedule.level_at_min);
    let noisy = Some(10.0 * n.recipe.schedule.noisiest_level());
    // without a range: the centre's guide on clean frames, the window's on noisy ones
    assert_eq!(n.guide_mix_range_for(clean), None);
    assert_eq!(n.guide_mix_range_for(noisy), Some(None));
    n.recipe.guide_mix.range = Some(0.02);
    // σ on the cleanest frames, twice σ at twice the level of the smallest scale, none on
    // frames the input blend leaves alone
    assert_eq!(n.guide_mix_range_for(clean), Some(Some(0.02)));
    let mid = n.guide_mix_range_for(twice).unwrap().unwrap();
    assert!((mid - 0.04).abs() < 1e-6, "{mid}");
    assert_eq!(n.guide_mix_range_for(noisy), Some(None));
    assert_eq!(n.guide_mix_range_for(None), Some(None));
    // the centre's guide stays the centre's guide
    n.recipe.guide_mix.from = MixGuide::Centre;
    assert_eq!(n.guide_mix_range_for(clean), None);
    n.recipe.guide_mix.from = MixGuide::Window;
    assert_eq!(n.guide_mix_range_for(clean), Some(Some(0.02)));
}

#[test]
fn only_tiles_of_one_size_share_a_call() {
    let d = Denoiser::new(NetConfig::preset("small").unwrap(), &Device::flex());
    let mut n = NetworkDenoiser::new(d, Device::flex());
    n.tile = 16;
    // 70×52 with a 46-pixel halo: in each row of tiles, the tiles at x = 16 and 32 read
    // the full width; the others read less
    let tiles = n.tiles(&window(70, 52), 0..52, false);
    assert_eq!(tiles.len(), 5 * 4);
    for batch in [1, 2, 3, 8] {
        let calls = batches(&tiles, batch);
        assert_eq!(calls.iter().map(|c| c.len()).sum::<usize>(), tiles.len());
        for c in &calls {
            assert!(c.len() <= batch);
            let size = tiles[c.start].region.size();
            assert!(tiles[c.clone()].iter().all(|t| t.region.size() == size));
        }
        let most = calls.iter().map(|c| c.len()).max().unwrap();
        assert_eq!(most, batch.min(2), "batch {batch}: {calls:?}");
    }
}

#[test]
fn tiled_and_whole_frame_results_agree_with_multi_scale_kernels() {
    let device = Device::flex();
    // the shipped model grown to three scales: trained kernels depend strongly on the
    // features, so a halo too small shows (a fresh network is nearly a box filter whose
    // output hardly depends on what a tile sees)
    let shipped =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/default.safetensors");
    let d = crate::model::store::load(&shipped, &device)
        .unwrap()
        .with_kernel_scales(3, &device)
        .unwrap();
    d.materialize();
    let halo = d.receptive_radius().expect("a ResNet's reach is bounded");
    assert_eq!(halo % 4, 0);
    // wide enough that inner tiles read less than the whole frame (across: the tiles of
    // one row differ only in x)
    let (w, h) = (2 * halo + 70, 30);
    let win = window(w, h);
    let mut n = NetworkDenoiser::new(d, device.clone());
    n.tile = 0;
    let whole = n.denoise_aligned(&win);
    // 30 is rounded down to 28, the grid's multiple
    for tile in [32usize, 30] {
        n.tile = tile;
        assert!(n
            .tiles(&win, 0..h, false)
            .iter()
            .any(|t| t.region.size() != (w, h)));
        let worst = worst_difference(&whole, &n.denoise_aligned(&win));
        // float rounding: 2e-7; a halo of 8 px instead of the bound: 1e-5
        assert!(
            worst < 1e-6,
            "tile {tile}: tiled and whole differ by {worst}"
        );
    }
}

#[test]
fn tiled_and_whole_frame_results_agree() {
    let device = Device::flex();
    for (preset, demodulate) in [("small", None), ("tkpcn", None), ("small", Some(0.25))] {
        let mut config = NetConfig::preset(preset).unwrap();
        config.demodulate = demodulate;
        let d = Denoiser::new(config, &device);
        d.materialize();
        let win = window(70, 52);
        let mut n = NetworkDenoiser::new(d, device.clone());
        n.tile = 0;
        let whole = n.denoise_aligned(&win);
        // tile 16 with batches of 3: tiles of equal regions share calls, the frame-edge
        // tiles (smaller regions) run apart
        for (tile, batch) in [(16usize, 1usize), (33, 1), (16, 3)] {
            n.tile = tile;
            n.batch = batch;
            let worst = worst_difference(&whole, &n.denoise_aligned(&win));
            assert!(
                worst < 1e-5,
                "{preset} {demodulate:?}, tile {tile} batch {batch}: tiled and whole \
                 differ by {worst}"
            );
        }
    }
}
