//! `radn eval` on sequences with known errors.

use std::path::Path;
use std::process::Command;

use radn_core::exr_file::{ExrFile, SampleKind};

fn write_seq(dir: &Path, frames: &[i64], value: impl Fn(i64, usize) -> f32) {
    std::fs::create_dir_all(dir).unwrap();
    for &f in frames {
        let ch = ["R", "G", "B"]
            .iter()
            .map(|c| (c.to_string(), (0..16 * 8).map(|i| value(f, i)).collect()))
            .collect();
        let p = dir.join(format!("img.{f:04}.exr"));
        ExrFile::from_channels(&p, 16, 8, ch, SampleKind::F32)
            .write_atomic(&p)
            .unwrap();
    }
}

/// The linear value whose tonemapped value is `t`.
fn untonemap(t: f32) -> f32 {
    let l = t.powf(2.2);
    l / (1.0 - l)
}

#[test]
fn eval_reports_known_psnr_flicker_and_writes_json_and_csv() {
    let d = tempfile::tempdir().unwrap();
    let reference = d.path().join("ref");
    let result = d.path().join("res");
    write_seq(&reference, &[1, 2, 3], |_, _| untonemap(0.5));
    // tonemapped error 0.1 on every frame -> PSNR 20 dB; it alternates in sign -> flicker
    write_seq(&result, &[1, 2, 3], |f, _| {
        untonemap(if f % 2 == 0 { 0.6 } else { 0.4 })
    });
    let json = d.path().join("m/metrics.json");
    let csv = d.path().join("m/metrics.csv");
    let out = Command::new(env!("CARGO_BIN_EXE_radn"))
        .args([
            "eval",
            "--result",
            result.to_str().unwrap(),
            "--reference",
            reference.to_str().unwrap(),
        ])
        .args([
            "--json",
            json.to_str().unwrap(),
            "--csv",
            csv.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("mean"), "{stdout}");
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let mean = &v["mean"];
    assert!(
        (mean["psnr"].as_f64().unwrap() - 20.0).abs() < 0.01,
        "{mean}"
    );
    // frame-to-frame change of the result is ±0.2 where the reference does not change
    let tmae = mean["tmae"].as_f64().unwrap();
    assert!((tmae - 0.2).abs() < 1e-3, "{tmae}");
    assert!(
        v["frames"][0]["tmae"].is_null(),
        "the first frame has no predecessor"
    );
    assert_eq!(v["frames"].as_array().unwrap().len(), 3);
    let text = std::fs::read_to_string(&csv).unwrap();
    assert_eq!(text.lines().count(), 4, "{text}");
    assert!(
        text.starts_with("frame,psnr,ssim,relmse,tmae,tpsnr"),
        "{text}"
    );
}

#[test]
fn eval_without_common_frames_is_an_error() {
    let d = tempfile::tempdir().unwrap();
    write_seq(&d.path().join("a"), &[1, 2], |_, _| 0.5);
    write_seq(&d.path().join("b"), &[5, 6], |_, _| 0.5);
    let out = Command::new(env!("CARGO_BIN_EXE_radn"))
        .args([
            "eval",
            "--result",
            d.path().join("a").to_str().unwrap(),
            "--reference",
            d.path().join("b").to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no frame number is in both"));
}
