//! Tests of `mod`.

use super::*;
use crate::model::config::INPUT_CHANNELS;
use burn::tensor::TensorData;

#[test]
fn flop_counts_come_from_the_layers_the_network_has() {
    let device = Device::flex();
    let small = NetConfig::preset("small").unwrap();
    let d = Denoiser::new(small.clone(), &device);
    let f = d.forward_flops(32, 32, 3);
    // the ResNet by hand: input conv, 2 convs per block, RA predictors, head, application
    let crate::model::config::Backbone::Resnet {
        blocks,
        width,
        ra_after,
        skips_from,
    } = &small.backbone
    else {
        panic!("small is a ResNet")
    };
    let px = 32.0 * 32.0;
    let conv = |cin: usize, cout: usize| 2.0 * (cin * cout * 9) as f64 * px;
    let (t, k2) = (
        small.frames as f64,
        (small.kernel_size * small.kernel_size) as f64,
    );
    let hidden = (width / 2).max(8);
    let by_hand = t
        * (conv(INPUT_CHANNELS, *width)
            + *blocks as f64 * 2.0 * conv(*width, *width)
            + ra_after.len() as f64 * (2.0 * conv(*width, hidden) + conv(hidden, 1))
            + conv(width * (1 + skips_from.len()), k2 as usize))
        + 2.0 * t * k2 * 3.0 * px;
    assert!((f - by_hand).abs() < 1e-6 * by_hand, "{f} vs {by_hand}");
    // it follows the network: area scales it, one more block adds its two convolutions
    assert!((d.forward_flops(64, 32, 3) - 2.0 * f).abs() < 1e-6 * f);
    let mut deeper = small.clone();
    if let crate::model::config::Backbone::Resnet { blocks, .. } = &mut deeper.backbone {
        *blocks += 1;
    }
    let g = Denoiser::new(deeper, &device).forward_flops(32, 32, 3);
    assert!((g - f - t * 2.0 * conv(*width, *width)).abs() < 1e-6 * f);
    // a UNet's coarse scales cost a quarter per level
    let unet = Denoiser::new(NetConfig::preset("unet").unwrap(), &device);
    let (a, b) = (unet.forward_flops(32, 32, 3), unet.forward_flops(64, 64, 3));
    assert!((b / a - 4.0).abs() < 0.05, "{a} {b}");
}

fn window(b: usize, t: usize, h: usize, w: usize, device: &Device) -> Tensor<5> {
    let n = b * t * INPUT_CHANNELS * h * w;
    Tensor::from_data(
        TensorData::new(
            (0..n)
                .map(|i| ((i * 2654435761usize) % 1000) as f32 / 1000.0)
                .collect::<Vec<f32>>(),
            [b, t, INPUT_CHANNELS, h, w],
        ),
        device,
    )
}

#[test]
fn shapes_for_five_and_three_frames_and_every_family() {
    let device = Device::flex();
    for name in ["small", "unet", "unet-ms", "tkpcn", "spatial"] {
        for frames in [5usize, 3] {
            let mut cfg = NetConfig::preset(name).unwrap();
            cfg.frames = frames;
            let d = Denoiser::new(cfg.clone(), &device);
            let (h, w) = (16, 20);
            let p = d.predict(window(2, frames, h, w, &device), cfg.default_threshold());
            let values = Tensor::<5>::from_data(
                TensorData::new(vec![1.0f32; 2 * frames * 3 * h * w], [2, frames, 3, h, w]),
                &device,
            );
            let out = p.apply(values);
            assert_eq!(out.dims(), [2, 3, h, w], "{name} T={frames}");
            let mass = p.frame_mass(frames);
            assert_eq!(mass.dims(), [2, frames, h, w]);
            // the box-initialised kernels sum to 1 per pixel: a constant image stays constant
            // (away from the zero-padded border)
            let v = out.to_data().try_to_vec::<f32>().unwrap();
            let centre = v[(h / 2) * w + w / 2];
            assert!((centre - 1.0).abs() < 1e-4, "{name} T={frames}: {centre}");
        }
    }
}

#[test]
fn a_multi_scale_network_with_no_blend_weight_is_exactly_its_single_scale_network() {
    let device = Device::flex();
    let single = Denoiser::new(NetConfig::preset("small").unwrap(), &device);
    let multi = single.clone().with_kernel_scales(3, &device).unwrap();
    assert_eq!(multi.config.scales(), 3);
    let (h, w) = (16, 20);
    let x = window(1, 5, h, w, &device);
    let t = single.config.default_threshold();
    let values = Tensor::<5>::from_data(
        TensorData::new(
            (0..5 * 3 * h * w)
                .map(|i| ((i * 7919) % 113) as f32 / 50.0)
                .collect::<Vec<f32>>(),
            [1, 5, 3, h, w],
        ),
        &device,
    );
    let want = single.predict(x.clone(), t).apply(values.clone());
    let Prediction::MultiScale(mut m) = multi.predict(x, t) else {
        panic!("three scales predict multi-scale kernels")
    };
    assert_eq!(m.scales.len(), 3);
    assert_eq!(m.scales[2].weights.dims(), [1, 5 * 25, h / 4, w / 4]);
    let blended = m.apply(values.clone());
    m.blend = m.blend.iter().map(|a| a.clone().zeros_like()).collect();
    let got = m.apply(values);
    assert_eq!(
        got.to_data().try_to_vec::<f32>().unwrap(),
        want.to_data().try_to_vec::<f32>().unwrap()
    );
    // the grown network's blend starts small but not at zero: the coarse scales take part
    let diff: f32 = (blended - got).abs().max().into_scalar();
    assert!(diff > 0.0, "{diff}");
}

#[test]
fn a_network_grown_to_read_the_noise_estimate_first_computes_what_it_did() {
    let device = Device::flex();
    let (h, w) = (8, 12);
    for preset in ["small", "unet"] {
        let old = Denoiser::new(NetConfig::preset(preset).unwrap(), &device);
        let inputs = InputConfig {
            exposure: false,
            noise: true,
            guide: false,
        };
        let grown = old.clone().with_inputs(inputs, &device);
        assert_eq!(grown.config.input_channels(), INPUT_CHANNELS + 1);
        let x = window(1, 5, h, w, &device);
        // any noise channel: its weights start at zero
        let noise = Tensor::<5>::ones([1, 5, 1, h, w], &device) * 0.3;
        let x_grown = Tensor::cat(vec![x.clone(), noise], 2);
        let values = Tensor::<5>::ones([1, 5, 3, h, w], &device) + x.clone().narrow(2, 0, 3);
        let t = old.config.default_threshold();
        let want = old.predict(x, t).apply(values.clone());
        let got = grown.predict(x_grown, t).apply(values);
        assert_eq!(
            got.to_data().try_to_vec::<f32>().unwrap(),
            want.to_data().try_to_vec::<f32>().unwrap(),
            "{preset}"
        );
        // and back: dropping the channel gives the old network
        let back = grown.with_inputs(InputConfig::default(), &device);
        assert_eq!(back.config, old.config);
    }
    // a fine-tune grows a network on the training (autodiff) device
    #[cfg(feature = "autodiff")]
    {
        let train = Device::flex().autodiff();
        let grown = Denoiser::new(NetConfig::preset("small").unwrap(), &train).with_inputs(
            InputConfig {
                exposure: true,
                noise: true,
                guide: false,
            },
            &train,
        );
        grown.materialize();
    }
}

#[test]
fn a_unet_places_ra_blocks_at_the_scales_it_names() {
    let device = Device::flex();
    let all = NetConfig::preset("unet").unwrap();
    let mut coarse = all.clone();
    coarse.backbone = crate::model::config::Backbone::Unet {
        widths: vec![32, 48, 64],
        ra_scales: Some(vec![1, 2]),
    };
    coarse.validate().unwrap();
    let (a, c) = (
        Denoiser::new(all, &device),
        Denoiser::new(coarse.clone(), &device),
    );
    assert_eq!(a.ra_blocks().len(), 3);
    assert_eq!(c.ra_blocks().len(), 2);
    // the full-resolution RA block is the one left out: its cost is gone
    let full_ra = a.ra_blocks()[0].flops(64 * 64);
    let saved = a.forward_flops(64, 64, 3) - c.forward_flops(64, 64, 3);
    assert!(
        (saved - full_ra).abs() < 1e-6 * full_ra,
        "{saved} vs {full_ra}"
    );
    let names: Vec<String> = c.layer_weights().into_iter().map(|(n, _)| n).collect();
    assert!(
        names.iter().any(|n| n.starts_with("backbone.ra1")),
        "{names:?}"
    );
    assert!(
        !names.iter().any(|n| n.starts_with("backbone.ra0")),
        "{names:?}"
    );
    let out = c
        .predict(window(1, 5, 8, 8, &device), 0.004)
        .apply(Tensor::ones([1, 5, 3, 8, 8], &device));
    assert_eq!(out.dims(), [1, 3, 8, 8]);
    // scales must exist and increase
    for bad in [vec![3], vec![2, 1]] {
        coarse.backbone = crate::model::config::Backbone::Unet {
            widths: vec![32, 48, 64],
            ra_scales: Some(bad),
        };
        assert!(coarse.validate().is_err());
    }
}

#[test]
fn paper_preset_parameter_count() {
    let d = Denoiser::new(NetConfig::preset("paper").unwrap(), &Device::flex());
    // 24 residual blocks of two 80→80 3×3 convs, 6 RA blocks, input conv, head over
    // 80·(1 + 4 skips) channels: see docs/research/benchmarks.md for the breakdown
    let n = d.num_params();
    assert!(n > 3_000_000 && n < 4_000_000, "{n}");
}
