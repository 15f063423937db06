//! OIDN's U-Net imported from the installed OIDN library and run on radn's own kernels equals
//! OIDN's own filter: the noisy-auxiliary beauty model, the large clean-auxiliary one and the
//! large albedo and normal prefilters, at OIDN's autoexposure and at a fixed input scale, on
//! the Cycles sample and on a frame of another layout; tiled runs equal whole frames exactly;
//! the burn forward pass equals the CPU kernels.
//!
//! They need an OIDN 2.x library (`scripts/setup` installs the `pyoidn` wheel); without one
//! they say so and pass, unless `RADN_REQUIRE_OIDN=1` (set by `scripts/test`).

use std::path::PathBuf;

use radn_core::eval::metrics::psnr;
use radn_core::guide::{Aux, OidnDenoiser, OidnQuality};
use radn_core::io::frame::{FrameReader, Requirements};
use radn_core::io::mapping::ChannelMapping;
use radn_core::Plane;
use radn_nn::burn::tensor::{Device, Tensor, TensorData};
use radn_nn::oidn_unet::filter::{UnetFilter, UnetImages};
use radn_nn::oidn_unet::import::import;
use radn_nn::oidn_unet::library::WeightsLibrary;

/// The least PSNR (dB) between radn's port and OIDN's own output.
const EQUAL_DB: f64 = 60.0;

/// OIDN and its weights library, or `None` (with a message) where it is not installed and the
/// run does not require it.
fn oidn() -> Option<(OidnDenoiser, WeightsLibrary)> {
    match OidnDenoiser::new(2) {
        Ok(d) => {
            let lib = WeightsLibrary::open(d.library()).expect("the OIDN library's weights open");
            Some((d, lib))
        }
        Err(e) if std::env::var_os("RADN_REQUIRE_OIDN").is_none() => {
            eprintln!("SKIPPED: Intel Open Image Denoise is not installed here: {e}");
            None
        }
        Err(e) => panic!("RADN_REQUIRE_OIDN is set but OIDN does not open: {e}"),
    }
}

/// Colour, albedo and normal of a Cycles sample frame.
fn sample(level: &str, frame: i64) -> (Plane, Plane, Plane) {
    let path = PathBuf::from(format!(
        "../../samples/cycles-sample/{level}/frame_{frame:04}.exr"
    ));
    let f = FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::DENOISE,
    )
    .read(&path)
    .unwrap()
    .0;
    (f.color, f.albedo.unwrap(), f.normal.unwrap())
}

/// A frame of another size and content than the sample: a wide, bright HDR frame whose sides
/// are not multiples of 16, with smooth auxiliaries (as a generic-layout renderer writes).
fn synthetic() -> (Plane, Plane, Plane) {
    synthetic_of(203, 77)
}

/// [`synthetic`] at another size.
fn synthetic_of(w: usize, h: usize) -> (Plane, Plane, Plane) {
    let noise = |x: usize, y: usize, c: usize| {
        let v = ((x * 73856093) ^ (y * 19349663) ^ (c * 83492791)) % 1000;
        v as f32 / 1000.0
    };
    let color = Plane::from_fn(w, h, 3, |x, y, c| {
        let base = if (x / 23 + y / 17) % 2 == 0 { 8.0 } else { 0.4 };
        base * (0.2 + 1.6 * noise(x, y, c)) * (1.0 + c as f32 * 0.1)
    });
    let albedo = Plane::from_fn(w, h, 3, |x, y, c| {
        if (x / 23 + y / 17) % 2 == 0 {
            0.8
        } else {
            0.3 + 0.1 * c as f32
        }
    });
    let normal = Plane::from_fn(w, h, 3, |x, _, c| match c {
        0 => (x as f32 / w as f32 - 0.5) * 1.2,
        1 => 0.3,
        _ => 0.9,
    });
    (color, albedo, normal)
}

/// PSNR of two auxiliary images of range `span` (1 for albedo, 2 for normals).
fn aux_psnr(a: &Plane, b: &Plane, span: f64) -> f64 {
    let mse = a
        .data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| ((x - y) as f64 / span).powi(2))
        .sum::<f64>()
        / a.data().len() as f64;
    if mse == 0.0 {
        200.0
    } else {
        -10.0 * mse.log10()
    }
}

fn largest_difference(a: &Plane, b: &Plane) -> f32 {
    a.data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

fn mean(a: &Plane) -> f64 {
    a.data().iter().map(|&v| v as f64).sum::<f64>() / a.data().len() as f64
}

fn filter(lib: &WeightsLibrary, name: &str) -> UnetFilter {
    UnetFilter::new(&import(lib, name, &Device::flex()).unwrap())
}

#[test]
fn the_noisy_auxiliary_beauty_model_equals_oidn() {
    let Some((mut oidn, lib)) = oidn() else {
        return;
    };
    let f = filter(&lib, "rt_hdr_alb_nrm");
    for (label, (c, a, n)) in [("sample", sample("low", 5)), ("synthetic", synthetic())] {
        for scale in [None, Some(1.0)] {
            oidn.set_input_scale(scale);
            let want = oidn
                .beauty(&c, Some(&a), Some(&n), OidnQuality::High, false)
                .unwrap();
            let images = UnetImages {
                color: Some(&c),
                albedo: Some(&a),
                normal: Some(&n),
            };
            let got = f.run(&images, scale).unwrap();
            let db = psnr(&got, &want).unwrap();
            eprintln!(
                "rt_hdr_alb_nrm {label} scale {scale:?}: {db:.1} dB, largest difference {:.2e}, mean {:.4} (input {:.4})",
                largest_difference(&got, &want),
                mean(&got),
                mean(&c)
            );
            assert!(db >= EQUAL_DB, "{label} {scale:?}: {db:.1} dB");
        }
    }
}

#[test]
fn the_large_prefilters_and_clean_auxiliary_model_equal_oidn_prefiltered() {
    let Some((mut oidn, lib)) = oidn() else {
        return;
    };
    oidn.set_input_scale(None);
    let (alb, nrm, beauty) = (
        filter(&lib, "rt_alb_large"),
        filter(&lib, "rt_nrm_large"),
        filter(&lib, "rt_hdr_calb_cnrm_large"),
    );
    for (label, (c, a, n)) in [("sample", sample("low", 3)), ("synthetic", synthetic())] {
        let want_a = oidn.prefilter(&a, Aux::Albedo, OidnQuality::High).unwrap();
        let want_n = oidn.prefilter(&n, Aux::Normal, OidnQuality::High).unwrap();
        let got_a = alb
            .run(
                &UnetImages {
                    color: None,
                    albedo: Some(&a),
                    normal: None,
                },
                None,
            )
            .unwrap();
        let got_n = nrm
            .run(
                &UnetImages {
                    color: None,
                    albedo: None,
                    normal: Some(&n),
                },
                None,
            )
            .unwrap();
        let (da, dn) = (
            aux_psnr(&got_a, &want_a, 1.0),
            aux_psnr(&got_n, &want_n, 2.0),
        );
        eprintln!(
            "{label}: rt_alb_large {da:.1} dB (largest difference {:.1e}, mean {:.4}), rt_nrm_large {dn:.1} dB (largest difference {:.1e}, mean {:.4})",
            largest_difference(&got_a, &want_a),
            mean(&got_a),
            largest_difference(&got_n, &want_n),
            mean(&got_n)
        );
        assert!(
            da >= EQUAL_DB && dn >= EQUAL_DB,
            "{label}: {da:.1} / {dn:.1} dB"
        );
        // the beauty on OIDN's own prefiltered auxiliaries, as OIDN-prefiltered runs it
        let want = oidn
            .beauty(&c, Some(&want_a), Some(&want_n), OidnQuality::High, true)
            .unwrap();
        let got = beauty
            .run(
                &UnetImages {
                    color: Some(&c),
                    albedo: Some(&want_a),
                    normal: Some(&want_n),
                },
                None,
            )
            .unwrap();
        let db = psnr(&got, &want).unwrap();
        eprintln!(
            "{label}: rt_hdr_calb_cnrm_large {db:.1} dB, largest difference {:.2e}",
            largest_difference(&got, &want)
        );
        assert!(db >= EQUAL_DB, "{label}: {db:.1} dB");
    }
}

#[test]
fn tiles_equal_the_whole_frame_exactly_and_burn_equals_the_cpu_kernels() {
    let Some((_, lib)) = oidn() else { return };
    let (c, a, n) = synthetic_of(523, 371);
    let images = UnetImages {
        color: Some(&c),
        albedo: Some(&a),
        normal: Some(&n),
    };
    for name in ["rt_hdr_alb_nrm", "rt_nrm_large"] {
        let whole = filter(&lib, name);
        let images = if name == "rt_nrm_large" {
            UnetImages {
                color: None,
                albedo: None,
                normal: Some(&n),
            }
        } else {
            images
        };
        let full = whole.run(&images, Some(0.7)).unwrap();
        // tiles that split the frame one way (as tall or as wide as it), and (the standard
        // model; the large one takes long in tiles that small) both ways
        let budgets: &[(usize, bool)] = if name == "rt_nrm_large" {
            &[(400 * 400, false)]
        } else {
            &[(400 * 400, false), (270 * 270, true)]
        };
        for &(budget, both) in budgets {
            let tiled = filter(&lib, name).with_max_tile_pixels(budget);
            let tiles = tiled.tiles(c.width(), c.height());
            assert!(tiles.len() > 1);
            let split = |i: usize| tiles.iter().any(|t| t.core[i] > 0);
            assert_eq!(split(0) && split(1), both, "{budget}: {tiles:?}");
            assert_eq!(
                tiled.run(&images, Some(0.7)).unwrap().data(),
                full.data(),
                "{name} in tiles of {budget} pixels"
            );
        }
    }
    // burn's forward pass on one processed 64×48 tile against the kernels'
    let net = import(&lib, "rt_hdr_alb_nrm", &Device::flex()).unwrap();
    let f = UnetFilter::new(&net);
    let (w, h) = (64, 48);
    let x: Vec<f32> = (0..9 * w * h)
        .map(|i| ((i * 7919) % 1000) as f32 / 1000.0)
        .collect();
    let cpu = f
        .forward(radn_nn::oidn_unet::cpu::blocked::Blocked::from_planar(
            &x, 9, h, w,
        ))
        .to_planar();
    let burn = net
        .forward(Tensor::from_data(
            TensorData::new(x.clone(), [1, 9, h, w]),
            &Device::flex(),
        ))
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    let worst = cpu
        .iter()
        .zip(&burn)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(worst < 1e-4, "burn and the CPU kernels differ by {worst}");
    // and the encoder's levels alone, which a converted network keeps per frame
    let blocked = radn_nn::oidn_unet::cpu::blocked::Blocked::from_planar(&x, 9, h, w);
    let cpu_levels = f.encode(blocked);
    let burn_levels = net.encode(Tensor::from_data(
        TensorData::new(x, [1, 9, h, w]),
        &Device::flex(),
    ));
    assert_eq!(cpu_levels.len(), burn_levels.0.len());
    assert_eq!(cpu_levels.len(), net.level_channels().len());
    for (k, (c, b)) in cpu_levels.iter().zip(burn_levels.0).enumerate() {
        assert_eq!(
            [1, c.channels(), c.height(), c.width()],
            b.dims(),
            "level {k}"
        );
        let b = b.into_data().try_to_vec::<f32>().unwrap();
        let worst = c
            .to_planar()
            .iter()
            .zip(&b)
            .fold(0.0f32, |m, (p, q)| m.max((p - q).abs()));
        assert!(
            worst < 1e-4,
            "level {k}: burn and the CPU kernels differ by {worst}"
        );
    }
}
