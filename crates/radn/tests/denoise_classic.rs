//! `radn denoise --method classic` end to end on the shipped Cycles sample.

use std::path::{Path, PathBuf};
use std::process::Command;

use radn_core::exr_file::{ExrFile, SampleKind};
use radn_core::metrics::psnr;
use radn_core::Plane;

fn sample() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../samples/cycles-sample")
}

fn radn(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_radn"))
        .args(args)
        .output()
        .unwrap()
}

fn rgb(f: &ExrFile) -> Plane {
    let c: Vec<Vec<f32>> = ["R", "G", "B"]
        .iter()
        .map(|c| f.channel_f32(&format!("ViewLayer.Combined.{c}")).unwrap())
        .collect();
    Plane::from_channels(f.width(), f.height(), &[&c[0], &c[1], &c[2]])
}

#[test]
fn denoises_keeps_other_channels_and_resumes() {
    let d = tempfile::tempdir().unwrap();
    let input = format!("{}/low/frame_####.exr", sample().display());
    let output = format!("{}/out/dn_####.exr", d.path().display());
    let out = radn(&["denoise", "-i", &input, "-o", &output, "--frames", "4-6"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("denoised 3 frames"), "{stdout}");
    for f in 4..=6 {
        let src = ExrFile::read(sample().join(format!("low/frame_{f:04}.exr"))).unwrap();
        let res = ExrFile::read(d.path().join(format!("out/dn_{f:04}.exr"))).unwrap();
        let reference = ExrFile::read(sample().join(format!("ref/frame_{f:04}.exr"))).unwrap();
        let (pn, pd) = (
            psnr(&rgb(&src), &rgb(&reference)).unwrap(),
            psnr(&rgb(&res), &rgb(&reference)).unwrap(),
        );
        assert!(pd > pn + 4.0, "frame {f}: {pn:.2} dB -> {pd:.2} dB");
        assert_eq!(res.channel_names(), src.channel_names());
        assert_eq!(res.custom_attribute_names(), src.custom_attribute_names());
        for n in src
            .channel_names()
            .iter()
            .filter(|n| !n.starts_with("ViewLayer.Combined."))
        {
            assert_eq!(res.channel_f32(n), src.channel_f32(n), "{n} changed");
        }
        assert_eq!(
            res.channel_kind("ViewLayer.Combined.R"),
            src.channel_kind("ViewLayer.Combined.R")
        );
    }
    // a second run finds every output and skips it, leaving the files alone
    let before = std::fs::read(d.path().join("out/dn_0005.exr")).unwrap();
    let out = radn(&["denoise", "-i", &input, "-o", &output, "--frames", "4-6"]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("denoised 0 frames (3 already done"));
    assert_eq!(
        std::fs::read(d.path().join("out/dn_0005.exr")).unwrap(),
        before
    );
}

/// Copies the sample's low level adding AOVs that sum to the beauty, and a varying alpha.
fn with_aovs(dir: &Path) -> String {
    for f in 1..=9 {
        let mut file = ExrFile::read(sample().join(format!("low/frame_{f:04}.exr"))).unwrap();
        let n = file.width() * file.height();
        for c in ["R", "G", "B"] {
            // float beauty, so "sums to" holds exactly in the file
            file.convert_channel(&format!("ViewLayer.Combined.{c}"), SampleKind::F32);
            let beauty = file
                .channel_f32(&format!("ViewLayer.Combined.{c}"))
                .unwrap();
            // a split that varies per pixel, like diffuse vs specular
            let diffuse: Vec<f32> = beauty
                .iter()
                .enumerate()
                .map(|(i, v)| v * (0.3 + 0.5 * ((i % 7) as f32 / 6.0)))
                .collect();
            let specular: Vec<f32> = beauty.iter().zip(&diffuse).map(|(b, d)| b - d).collect();
            file.set_channel(&format!("ViewLayer.diffuse.{c}"), &diffuse, SampleKind::F32);
            file.set_channel(
                &format!("ViewLayer.specular.{c}"),
                &specular,
                SampleKind::F32,
            );
            // make the beauty exactly the sum as stored (f32)
            let sum: Vec<f32> = diffuse.iter().zip(&specular).map(|(a, b)| a + b).collect();
            file.set_channel(&format!("ViewLayer.Combined.{c}"), &sum, SampleKind::F32);
        }
        let alpha: Vec<f32> = (0..n)
            .map(|i| if (i / 176) % 20 < 10 { 1.0 } else { 0.5 })
            .collect();
        file.set_channel("ViewLayer.Combined.A", &alpha, SampleKind::F32);
        let p = dir.join(format!("in/frame_{f:04}.exr"));
        file.write_atomic(&p).unwrap();
    }
    format!("{}/in/frame_####.exr", dir.display())
}

#[test]
fn aovs_that_sum_to_the_beauty_still_do_and_alpha_is_denoised() {
    let d = tempfile::tempdir().unwrap();
    let input = with_aovs(d.path());
    let output = format!("{}/out/frame_####.exr", d.path().display());
    let out = radn(&[
        "denoise",
        "-i",
        &input,
        "-o",
        &output,
        "--frames",
        "5-5",
        "--aovs",
        "diffuse,specular",
        "--no-refine",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let res = ExrFile::read(d.path().join("out/frame_0005.exr")).unwrap();
    let src = ExrFile::read(d.path().join("in/frame_0005.exr")).unwrap();
    for c in ["R", "G", "B"] {
        let b = res.channel_f32(&format!("ViewLayer.Combined.{c}")).unwrap();
        let di = res.channel_f32(&format!("ViewLayer.diffuse.{c}")).unwrap();
        let sp = res.channel_f32(&format!("ViewLayer.specular.{c}")).unwrap();
        let worst = b
            .iter()
            .zip(di.iter().zip(&sp))
            .map(|(b, (d, s))| ((d + s) - b).abs() / b.abs().max(1e-3))
            .fold(0.0f32, f32::max);
        assert!(
            worst < 1e-4,
            "channel {c}: AOV sum differs from the beauty by {worst} (relative)"
        );
        // and the AOVs were really filtered
        assert_ne!(
            di,
            src.channel_f32(&format!("ViewLayer.diffuse.{c}")).unwrap()
        );
    }
    let a = res.channel_f32("ViewLayer.Combined.A").unwrap();
    assert_ne!(
        a,
        src.channel_f32("ViewLayer.Combined.A").unwrap(),
        "alpha was not denoised"
    );
    assert!(
        a.iter().all(|v| (0.49..=1.01).contains(v)),
        "alpha left its range"
    );
}

#[test]
fn refuses_output_pattern_equal_to_input() {
    let d = tempfile::tempdir().unwrap();
    let input = with_aovs(d.path());
    let out = radn(&["denoise", "-i", &input, "-o", &input]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("refusing"));
}
