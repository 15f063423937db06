//! `radn denoise --method network` end to end, with a freshly initialised model file (these
//! tests check the plumbing — tiling, AOVs, alpha, passes, threshold — not image quality).

mod common;

use std::path::{Path, PathBuf};

use common::{assert_aovs_sum_to_beauty, beauty_rgb, radn, radn_ok, sample, tall, with_aovs};
use radn_core::io::exr_file::ExrFile;
use radn_nn::burn::tensor::Device;
use radn_nn::model::config::InputConfig;
use radn_nn::{Denoiser, NetConfig};

fn model(dir: &Path) -> PathBuf {
    model_with(dir, None)
}

/// A fresh `small` model, with albedo demodulation ε when given.
fn model_with(dir: &Path, demodulate: Option<f32>) -> PathBuf {
    model_reading(dir, demodulate, InputConfig::default())
}

/// A fresh `small` model with albedo demodulation ε when given, reading `inputs`.
fn model_reading(dir: &Path, demodulate: Option<f32>, inputs: InputConfig) -> PathBuf {
    let p = dir.join(format!("m-{demodulate:?}-{inputs:?}.safetensors"));
    let mut config = NetConfig::preset("small").unwrap();
    config.demodulate = demodulate;
    config.inputs = inputs;
    let d = Denoiser::new(config, &Device::flex());
    radn_nn::model::store::save(&d, &p).unwrap();
    p
}

#[test]
fn network_denoise_applies_one_kernel_to_beauty_aovs_and_alpha() {
    // plain kernels, kernels on albedo-demodulated colour and AOVs (alpha stays plain), and
    // the result blended with the input by one per-pixel weight (`--tune input-blend=2`)
    for (demodulate, blend) in [(None, false), (Some(0.25), false), (Some(0.25), true)] {
        one_kernel_for_beauty_aovs_and_alpha(demodulate, blend);
    }
}

fn one_kernel_for_beauty_aovs_and_alpha(demodulate: Option<f32>, input_blend: bool) {
    let d = tempfile::tempdir().unwrap();
    let m = model_with(d.path(), demodulate);
    let input = with_aovs(d.path(), 0.25);
    let out = format!("{}/out/f_####.exr", d.path().display());
    let mut args = vec![
        "denoise",
        "--method",
        "network",
        "--model",
        m.to_str().unwrap(),
        "-i",
        &input,
        "-o",
        &out,
        "--frames",
        "4-5",
        "--aovs",
        "diffuse,specular",
        "--tile",
        "40",
        "--bands",
        "always",
    ];
    if input_blend {
        args.extend(["--tune", "input-blend=2"]);
    }
    let res = radn(&args);
    assert!(
        res.status.success(),
        "{}",
        String::from_utf8_lossy(&res.stderr)
    );
    let r = ExrFile::read(d.path().join("out/f_0005.exr")).unwrap();
    let src = ExrFile::read(d.path().join("in/frame_0005.exr")).unwrap();
    assert_aovs_sum_to_beauty(&r, &src);
    let a = r.channel_f32("ViewLayer.Combined.A").unwrap();
    assert_ne!(
        a,
        src.channel_f32("ViewLayer.Combined.A").unwrap(),
        "alpha was not denoised"
    );
    // a box-like kernel keeps alpha within its input range
    assert!(a.iter().all(|v| (0.24..=1.01).contains(v)));
}

#[test]
fn passes_threshold_and_resume() {
    let d = tempfile::tempdir().unwrap();
    let m = model(d.path());
    let input = format!("{}/low/frame_####.exr", sample().display());
    let one = format!("{}/p1/f_####.exr", d.path().display());
    let two = format!("{}/p2/f_####.exr", d.path().display());
    let ms = m.to_str().unwrap();
    assert!(radn(&[
        "denoise", "--method", "network", "--model", ms, "-i", &input, "-o", &one, "--frames",
        "3-7"
    ])
    .status
    .success());
    radn_ok(&[
        "denoise", "--method", "network", "--model", ms, "-i", &input, "-o", &two, "--frames",
        "3-7", "--passes", "2",
    ]);
    let green = |dir: &str| {
        ExrFile::read(d.path().join(dir).join("f_0005.exr"))
            .unwrap()
            .channel_f32("ViewLayer.Combined.G")
            .unwrap()
    };
    let (a, b) = (green("p1"), green("p2"));
    assert_ne!(a, b, "a second pass changed nothing");
    // no scratch folder of the passes is left behind
    assert_eq!(std::fs::read_dir(d.path().join("p2")).unwrap().count(), 5);
    // resumption: nothing to do the second time
    let res = radn(&[
        "denoise", "--method", "network", "--model", ms, "-i", &input, "-o", &two, "--frames",
        "3-7", "--passes", "2",
    ]);
    assert!(String::from_utf8_lossy(&res.stdout).contains("denoised 0 frames (5 already done"));
    // thresholds outside [0, 1/K) are refused with the range
    let res = radn(&[
        "denoise",
        "--method",
        "network",
        "--model",
        ms,
        "-i",
        &input,
        "-o",
        &one,
        "--tune",
        "threshold=0.5",
        "--overwrite",
    ]);
    assert!(!res.status.success());
    assert!(String::from_utf8_lossy(&res.stderr).contains("must be in [0, 1/K)"));
    // without --model (and without --method) the built-in unguided model runs
    let dflt = format!("{}/pd/f_####.exr", d.path().display());
    radn_ok(&[
        "denoise", "-i", &input, "-o", &dflt, "--frames", "5-5", "--guide", "none",
    ]);
    assert_ne!(a, green("pd"), "the default model is not the test's model");
}

#[test]
fn utilization_table_sums_to_one_and_writes_heat_maps() {
    let d = tempfile::tempdir().unwrap();
    let m = model(d.path());
    let input = format!("{}/low/frame_####.exr", sample().display());
    let json = d.path().join("u/u.json");
    let maps = d.path().join("maps");
    let res = radn(&[
        "eval",
        "--utilization",
        "--model",
        m.to_str().unwrap(),
        "-i",
        &input,
        "--frames",
        "4-5",
        "--json",
        json.to_str().unwrap(),
        "--heatmaps",
        maps.to_str().unwrap(),
    ]);
    assert!(
        res.status.success(),
        "{}",
        String::from_utf8_lossy(&res.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let avg: Vec<f64> = v["avg"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    assert_eq!(avg.len(), 5);
    assert!((avg.iter().sum::<f64>() - 1.0).abs() < 1e-4, "{avg:?}");
    // a freshly initialised kernel is close to a box filter: every frame carries ~1/5
    assert!(avg.iter().all(|a| (a - 0.2).abs() < 0.05), "{avg:?}");
    for f in [4, 5] {
        let png = std::fs::read(maps.join(format!("centre_share_{f:04}.png"))).unwrap();
        assert_eq!(&png[1..4], b"PNG");
    }
}

#[test]
fn banded_denoising_equals_whole_frame_denoising() {
    // `--tile N` reads and denoises each frame in bands of N rows, each band from only the rows
    // of its window it reaches; `--tile 0` aligns and denoises whole frames. The network
    // normalises by the frame's exposure and reads the noise estimate: bands use the whole
    // frame's exposure. The result is blended with the input (`--tune input-blend=2`), whose boxes
    // read rows beyond each band (with `auto`, bands also get the whole frame's noise level:
    // radn-core's real_cycles test).
    let d = tempfile::tempdir().unwrap();
    let inputs = InputConfig {
        exposure: true,
        noise: true,
        guide: false,
    };
    let m = model_reading(d.path(), Some(0.5), inputs);
    let input = tall(d.path());
    let run = |tile: &str, bands: &str| {
        let out = format!("{}/t{tile}-{bands}/f_####.exr", d.path().display());
        let args = [
            "--method",
            "network",
            "--tile",
            tile,
            "--bands",
            bands,
            "--tune",
            "input-blend=2",
        ];
        denoise_frames_3_to_7(&m, &input, &out, &args)
    };
    let whole = run("0", "always");
    // bands of one tile's rows, and bands shorter than a tile (`--bands ROWS`, what wide
    // frames get): tiles then span a band's rows only
    for bands in ["always", "24"] {
        let banded = run("64", bands);
        let mut compared = 0;
        for_each_channel(&whole, &banded, |name, x, y| {
            for (i, (u, v)) in x.iter().zip(y).enumerate() {
                assert!(
                    (u - v).abs() <= 1e-5 * u.abs().max(1.0),
                    "--bands {bands}: {name} pixel {i} (row {}): whole frame {u}, banded {v}",
                    i / 176
                );
            }
            compared += x.len();
        });
        assert!(compared >= 3 * 10 * 176 * 300, "{compared}");
    }
}

#[test]
fn the_colour_confidence_changes_clean_frames_and_bands_still_equal_whole_frames() {
    // the compiled-in default model on the 32-spp sample, a frame clean enough for the colour
    // term (the recipe's `confidence.color`): it changes the result, and bands of 32 rows (whose
    // alignment sees only their rows and gets the frame's noise level from the statistics pass)
    // equal whole frames
    let d = tempfile::tempdir().unwrap();
    let input = format!("{}/high/frame_####.exr", sample().display());
    let run = |name: &str, extra: &[&str]| {
        let out = format!("{}/{name}/f_####.exr", d.path().display());
        let mut args = vec![
            "denoise", "-i", &input, "-o", &out, "--frames", "4-5", "--guide", "none",
        ];
        args.extend(extra);
        radn_ok(&args);
        [4, 5].map(|f| beauty_rgb(&ExrFile::read(out.replace("####", &format!("{f:04}"))).unwrap()))
    };
    let whole = run("whole", &["--tile", "0"]);
    let banded = run("banded", &["--tile", "32", "--bands", "always"]);
    let off = run("off", &["--tile", "0", "--tune", "confidence.color=off"]);
    let mut changed = 0;
    for ((w, b), o) in whole.iter().zip(&banded).zip(&off) {
        for ((u, v), x) in w.data().iter().zip(b.data()).zip(o.data()) {
            assert!(
                (u - v).abs() <= 1e-5 * u.abs().max(1.0),
                "whole {u}, banded {v}"
            );
            changed += usize::from((u - x).abs() > 1e-3 * u.abs().max(0.1));
        }
    }
    assert!(changed > 100, "the colour term changed {changed} samples");
}

#[test]
fn the_automatic_input_blend_follows_each_frames_noise_level() {
    // the default (`input-blend=auto`): the noise scale follows the frame's
    // noise level, and a frame as noisy as the 4-spp sample is left unblended while the 32-spp
    // one is blended
    let d = tempfile::tempdir().unwrap();
    let m = model(d.path());
    let ms = m.to_str().unwrap();
    for (level, blended) in [("low", false), ("high", true)] {
        let input = format!("{}/{level}/frame_####.exr", sample().display());
        let green = |name: &str, blend: &[&str]| {
            let out = format!("{}/{level}-{name}/f_####.exr", d.path().display());
            let mut args = vec![
                "denoise", "--method", "network", "--model", ms, "-i", &input, "-o", &out,
                "--frames", "5-5",
            ];
            args.extend(blend);
            radn_ok(&args);
            ExrFile::read(out.replace("####", "0005"))
                .unwrap()
                .channel_f32("ViewLayer.Combined.G")
                .unwrap()
        };
        let off = green("off", &["--tune", "input-blend=off"]);
        let default = green("default", &[]);
        let auto = green("auto", &["--tune", "input-blend=auto"]);
        let fixed = green(
            "fixed",
            &["--tune", "input-blend=5", "--tune", "input-blend.radius=1"],
        );
        assert!(off != fixed, "{level}: a fixed blend changed nothing");
        assert!(default == auto, "{level}: the default is not auto");
        assert_eq!(off != auto, blended, "{level}: blended by auto");
    }
}

#[test]
fn a_frame_local_stem_model_runs_tiled_as_whole_with_aovs_summing_to_the_beauty() {
    // the shipped default with its stem split (issue 20, point 1): the job computes each
    // frame's stem once and warps its features into the five windows the frame belongs to:
    // whole frames (`--tile 0`, or tiles of 48 with `--bands never`) keep every frame's stem
    // in memory; band by band (48 rows), each frame's stem is computed band by band into a
    // scratch file and read back band by band
    let d = tempfile::tempdir().unwrap();
    let device = Device::flex();
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/default.safetensors");
    let fw = radn_nn::model::store::load(&shipped, &device)
        .unwrap()
        .with_frame_local_stem(&device)
        .unwrap();
    let m = d.path().join("fw.safetensors");
    radn_nn::model::store::save(&fw, &m).unwrap();
    let input = with_aovs(d.path(), 0.25);
    let run = |name: &str, extra: &[&str]| {
        let out = format!("{}/{name}/f_####.exr", d.path().display());
        denoise_frames_3_to_7(&m, &input, &out, extra)
    };
    let whole = run("whole", &["--tile", "0"]);
    let tiled = run("tiled", &["--tile", "48", "--bands", "never"]);
    let banded = run("banded", &["--tile", "48", "--bands", "always"]);
    let aligned = run("aligned", &["--tile", "0", "--tune", "stem-per-window=on"]);
    let (mut worst, mut apart) = (0.0f32, 0.0f32);
    for other in [&tiled, &banded] {
        for_each_channel(&whole, other, |_, x, y| {
            for (u, v) in x.iter().zip(y) {
                worst = worst.max((u - v).abs() / u.abs().max(1.0));
            }
        });
    }
    for_each_channel(&whole, &aligned, |_, x, z| {
        for (u, w) in x.iter().zip(z) {
            apart = apart.max((u - w).abs());
        }
    });
    assert!(worst <= 1e-5, "tiled or banded and whole differ by {worst}");
    // the stem on the aligned frames is another computation (features warped, not inputs)
    assert!(
        apart > 1e-3,
        "warped features gave the aligned frames' result ({apart})"
    );
    let src = ExrFile::read(d.path().join("in/frame_0005.exr")).unwrap();
    assert_aovs_sum_to_beauty(&whole[1], &src);
}

/// `radn denoise` of frames 3–7 of `input` (made by [`with_aovs`]) with model `m` into `out`,
/// the diffuse and specular AOVs with the beauty's kernels, and `extra` options: the results
/// of frames 3, 5 and 7 (the first and last with windows clamped at the sequence's ends).
fn denoise_frames_3_to_7(m: &Path, input: &str, out: &str, extra: &[&str]) -> [ExrFile; 3] {
    let mut args = vec![
        "denoise",
        "--model",
        m.to_str().unwrap(),
        "-i",
        input,
        "-o",
        out,
        "--frames",
        "3-7",
        "--aovs",
        "diffuse,specular",
    ];
    args.extend_from_slice(extra);
    radn_ok(&args);
    [3, 5, 7].map(|f| ExrFile::read(out.replace("####", &format!("{f:04}"))).unwrap())
}

/// `f(name, a's values, b's values)` for every channel of the beauty, the two AOVs and alpha
/// that both results of every frame have.
fn for_each_channel(a: &[ExrFile], b: &[ExrFile], mut f: impl FnMut(&str, &[f32], &[f32])) {
    for (a, b) in a.iter().zip(b) {
        for layer in ["Combined", "diffuse", "specular"] {
            for c in ["R", "G", "B", "A"] {
                let name = format!("ViewLayer.{layer}.{c}");
                if let (Some(x), Some(y)) = (a.channel_f32(&name), b.channel_f32(&name)) {
                    f(&name, &x, &y);
                }
            }
        }
    }
}
