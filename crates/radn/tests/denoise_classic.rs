//! `radn denoise --method classic` end to end on the shipped Cycles sample.

mod common;

use common::{assert_aovs_sum_to_beauty, beauty_rgb as rgb, radn, sample, with_aovs};
use radn_core::eval::metrics::psnr;
use radn_core::io::exr_file::ExrFile;

#[test]
fn denoises_keeps_other_channels_and_resumes() {
    let d = tempfile::tempdir().unwrap();
    let input = format!("{}/low/frame_####.exr", sample().display());
    let output = format!("{}/out/dn_####.exr", d.path().display());
    let out = radn(&[
        "denoise", "--method", "classic", "-i", &input, "-o", &output, "--frames", "4-6",
    ]);
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
    let out = radn(&[
        "denoise", "--method", "classic", "-i", &input, "-o", &output, "--frames", "4-6",
    ]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("denoised 0 frames (3 already done"));
    assert_eq!(
        std::fs::read(d.path().join("out/dn_0005.exr")).unwrap(),
        before
    );
}

#[test]
fn aovs_that_sum_to_the_beauty_still_do_and_alpha_is_denoised() {
    let d = tempfile::tempdir().unwrap();
    let input = with_aovs(d.path(), 0.5);
    let output = format!("{}/out/frame_####.exr", d.path().display());
    let out = radn(&[
        "denoise",
        "--method",
        "classic",
        "-i",
        &input,
        "-o",
        &output,
        "--frames",
        "5-5",
        "--aovs",
        "diffuse,specular",
        "--tune",
        "classic.flow-refine=off",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let res = ExrFile::read(d.path().join("out/frame_0005.exr")).unwrap();
    let src = ExrFile::read(d.path().join("in/frame_0005.exr")).unwrap();
    assert_aovs_sum_to_beauty(&res, &src);
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
    let input = with_aovs(d.path(), 0.5);
    let out = radn(&["denoise", "-i", &input, "-o", &input]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("refusing"));
}
