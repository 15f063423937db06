//! The optional network inputs of issue 18 (point 5) on the shipped sample: the noise estimate
//! follows the input's noise level, exposure normalisation makes the denoised result scale
//! with the shot's HDR scale, and prepared tiles record the exposure inference uses.

use std::path::PathBuf;

use burn::tensor::Device;
use radn_core::align::{align_window, AlignParams, AlignedWindow};
use radn_core::io::frame::{Frame, FrameReader, Requirements};
use radn_core::io::mapping::ChannelMapping;
use radn_nn::infer::input::{network_input, FeatureScales, Region};
use radn_nn::infer::NetworkDenoiser;
use radn_nn::model::config::{InputConfig, INPUT_CHANNELS};
use radn_nn::{Denoiser, NetConfig};
use radn_train::dataset::{prepare, PrepareOptions, TileDataset};

fn sample_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../samples/cycles-sample")
}

/// The sample's aligned window of `level` around frame `centre`.
fn window(level: &str, centre: i64) -> AlignedWindow {
    let r = FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::DENOISE,
    );
    let frames: Vec<Frame> = (centre - 2..=centre + 2)
        .map(|f| {
            r.read(&sample_dir().join(format!("{level}/frame_{f:04}.exr")))
                .unwrap()
                .0
        })
        .collect();
    align_window(
        &frames.iter().map(Some).collect::<Vec<_>>(),
        &AlignParams::default(),
    )
}

const BOTH: InputConfig = InputConfig {
    exposure: true,
    noise: true,
    guide: false,
};

#[test]
fn the_noise_estimate_falls_with_the_sample_count() {
    // the sample's levels are 4, 11 and 32 spp: the spread should fall about as 1/√spp
    let mean_noise = |level: &str| {
        let win = window(level, 5);
        let (w, h) = (win.centre().color.width(), win.centre().color.height());
        let feats = network_input(&win, FeatureScales::of(&win), Region::whole(w, h), &BOTH);
        let n = w * h;
        let noise = &feats[INPUT_CHANNELS * n..(INPUT_CHANNELS + 1) * n];
        noise.iter().map(|&v| v as f64).sum::<f64>() / n as f64
    };
    let (low, half, high) = (mean_noise("low"), mean_noise("half"), mean_noise("high"));
    eprintln!("mean noise estimate: low {low:.4}, half {half:.4}, high {high:.4}");
    assert!(
        low > 1.25 * half && half > 1.25 * high,
        "{low} {half} {high}"
    );
    assert!(low > 1.8 * high, "{low} vs {high}");
}

/// Largest difference between `8 × denoise(window)` and `denoise(8 × window)`, relative to the
/// largest output value.
fn scale_error(denoiser: Denoiser) -> f32 {
    let net = NetworkDenoiser::new(denoiser, Device::flex());
    let win = window("low", 5);
    let mut brighter = win.clone();
    for f in &mut brighter.frames {
        f.color.data_mut().iter_mut().for_each(|v| *v *= 8.0);
    }
    let a = net.denoise_aligned(&win).color;
    let b = net.denoise_aligned(&brighter).color;
    let top = a.data().iter().fold(0.0f32, |m, v| m.max(v.abs()));
    a.data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| (8.0 * x - y).abs())
        .fold(0.0f32, f32::max)
        / top
}

#[test]
fn an_exposure_normalised_network_scales_with_the_shot() {
    let device = Device::flex();
    let mut cfg = NetConfig::preset("small").unwrap();
    device.seed(3);
    let plain = Denoiser::new(cfg.clone(), &device);
    cfg.inputs = BOTH;
    device.seed(3);
    let normalised = Denoiser::new(cfg, &device);
    let (e_plain, e_norm) = (scale_error(plain), scale_error(normalised));
    eprintln!("relative scale error: plain {e_plain:.2e}, exposure-normalised {e_norm:.2e}");
    assert!(e_norm < 1e-4, "{e_norm}");
    assert!(e_plain > 100.0 * e_norm, "{e_plain} vs {e_norm}");
}

#[test]
fn prepared_tiles_record_the_exposure_inference_uses() {
    let d = tempfile::tempdir().unwrap();
    let opts = PrepareOptions::new(32, 1, 1);
    prepare(&sample_dir(), d.path(), &opts, |_, _| {}).unwrap();
    let ds = TileDataset::open(d.path()).unwrap();
    assert_eq!(ds.manifest.format, radn_train::dataset::TILE_FORMAT);
    // record k is the window around frame k + 1 (one tile per window, one scene)
    let tile = ds.get(4).unwrap();
    for (l, level) in ["high", "half", "low"].iter().enumerate() {
        let e = FeatureScales::of(&window(level, 5)).exposure;
        assert_eq!(tile.exposure[l], Some(e), "{level}");
        assert!(e > 1e-3 && e < 10.0, "{level}: {e}");
    }
}

#[test]
fn inference_builds_exactly_the_features_training_derives_from_stored_tiles() {
    // inference (`network_input`: one parallel pass, one logarithm per sample) and training
    // (`network_features` of the base features tiles store, plus the colour and guide) must
    // feed the network the same numbers, bit for bit, for every input option
    use radn_nn::infer::input::{features_in, network_features};
    let mut win = window("half", 4);
    // a guide of its own (the half-spp colour scaled), so the guide channels differ from colour
    for f in &mut win.frames {
        let mut g = f.color.clone();
        g.data_mut().iter_mut().for_each(|v| *v = 0.5 * *v + 0.01);
        f.guide = Some(g);
    }
    let scales = FeatureScales::of(&win);
    let (w, h) = (win.centre().color.width(), win.centre().color.height());
    let regions = [
        Region::whole(w, h),
        Region {
            x0: 7,
            y0: 3,
            x1: w - 11,
            y1: h / 2 + 5,
        },
    ];
    for region in regions {
        let crop = |pick: &dyn Fn(&radn_core::align::AlignedFrame) -> &radn_core::Plane| {
            let mut v = Vec::new();
            for f in &win.frames {
                region.crop(pick(f), &mut v);
            }
            v
        };
        let colour = crop(&|f| &f.color);
        let guide = crop(&|f| f.guide.as_ref().unwrap());
        for (exposure, noise, guided) in [
            (false, false, false),
            (true, false, false),
            (false, true, false),
            (true, true, false),
            (true, true, true),
            (false, false, true),
        ] {
            let inputs = InputConfig {
                exposure,
                noise,
                guide: guided,
            };
            let trained = network_features(
                features_in(&win, scales.depth, region),
                &colour,
                Some(&guide),
                win.frames.len(),
                region.pixels(),
                &inputs,
                scales.exposure,
            );
            let inferred = network_input(&win, scales, region, &inputs);
            assert_eq!(trained.len(), inferred.len(), "{inputs:?}");
            let differing = trained
                .iter()
                .zip(&inferred)
                .filter(|(a, b)| a.to_bits() != b.to_bits())
                .count();
            assert_eq!(differing, 0, "{inputs:?} over {region:?}");
        }
    }
}
