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
