//! Fine-tuning the converted OIDN U-Net: a run starts from the per-frame U-Net's quality,
//! training moves it, and a run stopped and resumed ends with exactly the weights of one that
//! ran straight through.

use std::path::{Path, PathBuf};

use burn::tensor::{Device, Tensor, TensorData};
use radn_train::dataset::{prepare, PrepareOptions};
use radn_train::unet_finetune::{Finetune, FinetuneConfig};

fn sample() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../samples/cycles-sample")
}

fn config(steps: usize, trained: &str) -> FinetuneConfig {
    FinetuneConfig::parse(&format!(
        "network = \"oidn-temporal\"\ninit = \"{}/../../models/oidn-rt_hdr_alb_nrm.safetensors\"\ntrain = \"train\"\n\
         val = \"val\"\nlevels = [2, 4]\ntrained = \"{trained}\"\nbatch = 2\ncrop = 32\n\
         steps = {steps}\nlr = 1e-3\nseed = 3\nvalidate_every = 2\nval_tiles = 2\n",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap()
}

/// A digest of the network's output on a fixed window, bit for bit: a function of every weight.
fn output(run: &Finetune) -> u64 {
    use std::hash::{Hash, Hasher};
    let device = Device::flex();
    let n = 5 * 9 * 32 * 32;
    let x = Tensor::<4>::from_data(
        TensorData::new(
            (0..n)
                .map(|i| ((i * 7919) % 101) as f32 / 101.0)
                .collect::<Vec<_>>(),
            [5, 9, 32, 32],
        ),
        &device,
    );
    use burn::module::Module;
    let net = run.net().valid().fork(&device);
    let mut h = std::collections::hash_map::DefaultHasher::new();
    net.forward(x, None)
        .into_data()
        .try_to_vec::<f32>()
        .unwrap()
        .iter()
        .map(|v| v.to_bits())
        .collect::<Vec<_>>()
        .hash(&mut h);
    h.finish()
}

fn tiles(dir: &Path) {
    prepare(
        &sample(),
        &dir.join("train"),
        &PrepareOptions::new(32, 2, 1),
        |_, _| {},
    )
    .unwrap();
    prepare(
        &sample(),
        &dir.join("val"),
        &PrepareOptions::new(32, 1, 2),
        |_, _| {},
    )
    .unwrap();
}

#[test]
fn a_resumed_fine_tune_equals_one_run_straight_through_and_training_moves_it() {
    let d = tempfile::tempdir().unwrap();
    tiles(d.path());
    let device = Device::flex().autodiff();
    for trained in ["temporal", "all"] {
        let cfg = config(4, trained);
        let mut straight = Finetune::new(
            cfg.clone(),
            d.path(),
            &d.path().join(format!("a-{trained}")),
            true,
            &device,
        )
        .unwrap();
        let before = output(&straight);
        straight.run(None, |_, _| {}).unwrap();
        assert_eq!(straight.state.step, 4);
        let after = output(&straight);
        assert_ne!(before, after, "{trained}: training changed nothing");
        // the run starts at the converted network's quality: OIDN's U-Net
        assert!(straight.state.start_val.is_some());

        let out = d.path().join(format!("b-{trained}"));
        let mut first = Finetune::new(config(2, trained), d.path(), &out, true, &device).unwrap();
        first.run(None, |_, _| {}).unwrap();
        assert_eq!(first.state.step, 2);
        drop(first);
        let mut resumed = Finetune::new(cfg, d.path(), &out, true, &device).unwrap();
        assert_eq!(resumed.state.step, 2);
        resumed.run(None, |_, _| {}).unwrap();
        assert_eq!(
            output(&resumed),
            after,
            "{trained}: resumed differs from straight"
        );
    }
}

#[test]
fn bad_settings_are_refused_with_a_reason() {
    let bad = |text: &str| FinetuneConfig::parse(text).unwrap_err().to_string();
    let base = "network = \"oidn-temporal\"\ninit = \"m\"\ntrain = \"t\"\nval = \"v\"\nlevels = [2]\nbatch = 2\nsteps = 1\n\
                lr = 1e-3\nseed = 1\nvalidate_every = 1\nval_tiles = 1\n";
    assert!(bad(&format!("{base}crop = 40\n")).contains("multiple of 16"));
    assert!(bad(&format!("{base}crop = 32\nfoo = 1\n")).contains("foo"));
}

/// OIDN's standard albedo and normal prefilters, from the model files radn compiles in.
fn standard_prefilters() -> radn_nn::oidn_unet::prefilter::AuxPrefilter {
    use radn_nn::oidn_unet::{filter::UnetFilter, store};
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models");
    let load =
        |name: &str| UnetFilter::new(&store::load(&models.join(name), &Device::flex()).unwrap());
    radn_nn::oidn_unet::prefilter::AuxPrefilter::new(
        load("oidn-rt_alb.safetensors"),
        load("oidn-rt_nrm.safetensors"),
    )
}

#[test]
fn prefiltered_tiles_hold_each_frames_cleaned_auxiliaries_and_convert_a_clean_auxiliary_network() {
    use radn_core::io::frame::{FrameReader, Requirements};
    use radn_core::io::mapping::ChannelMapping;
    use radn_train::dataset::TileDataset;
    let d = tempfile::tempdir().unwrap();
    let prefilter = std::sync::Arc::new(standard_prefilters());
    let with = |seed| PrepareOptions {
        aux_prefilter: Some(prefilter.clone()),
        ..PrepareOptions::new(32, 1, seed)
    };
    prepare(
        &sample(),
        &d.path().join("rendered"),
        &PrepareOptions::new(32, 1, 1),
        |_, _| {},
    )
    .unwrap();
    prepare(&sample(), &d.path().join("train"), &with(1), |_, _| {}).unwrap();
    let rendered = TileDataset::open(&d.path().join("rendered")).unwrap();
    let cleaned = TileDataset::open(&d.path().join("train")).unwrap();
    assert_eq!(cleaned.manifest.aux_prefilters, Some(prefilter.names()));
    assert_eq!(rendered.manifest.aux_prefilters, None);

    // record k: the window around frame k of the sample, the same tile position in both sets;
    // the centre frame (slot 2 of 5) is not warped, so its features are the frame's own
    let frame_files: Vec<PathBuf> = {
        let mut v: Vec<PathBuf> = std::fs::read_dir(sample().join("low"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "exr"))
            .collect();
        v.sort();
        v
    };
    let (low, s, c) = (2, 32, 11);
    let plane = |tile: &[f32], channel: usize| -> Vec<f32> {
        tile[(2 * c + channel) * s * s..(2 * c + channel + 1) * s * s].to_vec()
    };
    for k in [0, 4, 8] {
        let (a, b) = (rendered.get(k).unwrap(), cleaned.get(k).unwrap());
        // the beauty is untouched: it locates the tile in the frame
        assert_eq!(plane(&a.features[low], 0), plane(&b.features[low], 0));
        assert_ne!(plane(&a.features[low], 3), plane(&b.features[low], 3));
        let names = radn_core::io::exr_file::ExrFile::read_rows(&frame_files[k], 0..1)
            .unwrap()
            .channel_names();
        let mapping = ChannelMapping::detect(&names).unwrap();
        let (frame, _) = FrameReader::new(mapping, Requirements::DENOISE)
            .read(&frame_files[k])
            .unwrap();
        let (albedo, normal) = prefilter.clean(&frame, None).unwrap();
        let (albedo, normal) = (albedo.unwrap(), normal.unwrap());
        let log = plane(&b.features[low], 0);
        let (w, h) = (frame.width(), frame.height());
        let at = (0..=h - s)
            .flat_map(|y| (0..=w - s).map(move |x| (x, y)))
            .find(|&(x, y)| {
                (0..s).all(|j| {
                    (0..s).all(|i| {
                        let v = frame.color.get(x + i, y + j, 0).max(0.0).ln_1p();
                        (v - log[j * s + i]).abs() <= 2e-3 * v.abs().max(1e-2)
                    })
                })
            })
            .expect("the tile's beauty is found in its centre frame");
        for (ch, buffer, lo, hi) in [(3, &albedo, 0.0, 2.0), (6, &normal, -1.0, 1.0)] {
            for k3 in 0..3 {
                let got = plane(&b.features[low], ch + k3);
                let worst = (0..s * s)
                    .map(|p| {
                        let want = buffer.get(at.0 + p % s, at.1 + p / s, k3).clamp(lo, hi);
                        (got[p] - want).abs()
                    })
                    .fold(0.0f32, f32::max);
                // stored as half floats
                assert!(worst <= 2e-3, "frame {k}, channel {}: {worst}", ch + k3);
            }
        }
    }

    // a fine-tune reads them as a clean-auxiliary network does, and refuses mixed sets
    prepare(&sample(), &d.path().join("val"), &with(2), |_, _| {}).unwrap();
    let cfg = FinetuneConfig::parse(&format!(
        "network = \"oidn-temporal\"\ninit = \"{}/../../models/oidn-rt_hdr_calb_cnrm_large.safetensors\"\n\
         train = \"train\"\nval = \"val\"\nlevels = [0]\nbatch = 1\ncrop = 32\nsteps = 1\nlr = 1e-4\n\
         seed = 3\nvalidate_every = 1\nval_tiles = 1\n",
        env!("CARGO_MANIFEST_DIR")
    ))
    .unwrap();
    let device = Device::flex().autodiff();
    let run = Finetune::new(cfg.clone(), d.path(), &d.path().join("run"), false, &device).unwrap();
    assert_eq!(
        run.net().config().aux,
        radn_nn::oidn_unet::temporal::AuxSource::Prefiltered
    );
    let mixed = FinetuneConfig {
        val: "rendered".into(),
        ..cfg
    };
    let err = Finetune::new(mixed, d.path(), &d.path().join("run2"), false, &device)
        .err()
        .expect("mixed auxiliaries are refused")
        .to_string();
    assert!(err.contains("--aux"), "{err}");
}

/// A fine-tune whose centre input is averaged over 3 frames: the model it converts carries
/// the setting for inference, and its windows' centre slot reads the aligned mean, which
/// already brings the untrained network closer to the validation targets. The mean is of
/// nearest-pixel samples at inference, so tiles aligned otherwise are refused.
#[test]
fn an_input_mean_is_carried_into_the_model_and_brings_the_start_closer() {
    use radn_core::align::warp::Resampling;
    let d = tempfile::tempdir().unwrap();
    let nearest = |name: &str, per_window: usize, seed: u64| {
        let mut o = PrepareOptions::new(32, per_window, seed);
        o.resampling = Resampling::Nearest;
        prepare(&sample(), &d.path().join(name), &o, |_, _| {}).unwrap();
    };
    nearest("train", 2, 1);
    nearest("val", 1, 2);
    let device = Device::flex().autodiff();
    let start = |input_frames: usize| {
        let mut cfg = config(1, "temporal");
        cfg.input_frames = input_frames;
        let run = Finetune::new(
            cfg,
            d.path(),
            &d.path().join(format!("in{input_frames}")),
            false,
            &device,
        )
        .unwrap();
        assert_eq!(run.net().config().input_frames, input_frames);
        run.validation().unwrap()
    };
    let ((l1_alone, psnr_alone), (l1_mean, psnr_mean)) = (start(1), start(3));
    assert!(
        l1_mean < l1_alone && psnr_mean > psnr_alone + 0.05,
        "alone: L1 {l1_alone:.5}, {psnr_alone:.2} dB; averaged: L1 {l1_mean:.5}, {psnr_mean:.2} dB"
    );
    let refused = |cfg: FinetuneConfig, base: &Path| {
        Finetune::new(cfg, base, &base.join("bad"), false, &device)
            .err()
            .expect("refused")
            .to_string()
    };
    let mut cfg = config(1, "temporal");
    cfg.input_frames = 2;
    let e = refused(cfg, d.path());
    assert!(e.contains("input mean over 2 frames"), "{e}");
    let bilinear = tempfile::tempdir().unwrap();
    tiles(bilinear.path());
    let mut cfg = config(1, "temporal");
    cfg.input_frames = 3;
    let e = refused(cfg, bilinear.path());
    assert!(e.contains("--resampling nearest"), "{e}");
}

/// A fine-tune with a learned input average: the model it converts carries the average, whose
/// gate starts shut and opens with training, and tiles aligned with anything but nearest-pixel
/// samples (what inference aligns with for it) are refused.
#[test]
fn a_learned_input_average_opens_with_training_and_needs_nearest_tiles() {
    use radn_core::align::warp::Resampling;
    let d = tempfile::tempdir().unwrap();
    for (name, per_window, seed) in [("train", 2, 1), ("val", 1, 2)] {
        let mut o = PrepareOptions::new(32, per_window, seed);
        o.resampling = Resampling::Nearest;
        prepare(&sample(), &d.path().join(name), &o, |_, _| {}).unwrap();
    }
    let device = Device::flex().autodiff();
    let mut cfg = config(3, "temporal");
    cfg.input_blend = true;
    let mut run =
        Finetune::new(cfg.clone(), d.path(), &d.path().join("run"), false, &device).unwrap();
    assert!(run.net().config().input_blend);
    assert_eq!(run.net().temporal.input_openness(), Some(0.0));
    for _ in 0..3 {
        run.step().unwrap();
    }
    let open = run.net().temporal.input_openness().unwrap();
    assert!(open > 1e-4, "the input gate stayed shut ({open})");
    let bilinear = tempfile::tempdir().unwrap();
    tiles(bilinear.path());
    let e = Finetune::new(
        cfg,
        bilinear.path(),
        &bilinear.path().join("bad"),
        false,
        &device,
    )
    .err()
    .expect("refused")
    .to_string();
    assert!(
        e.contains("input_blend") && e.contains("--resampling nearest"),
        "{e}"
    );
}
