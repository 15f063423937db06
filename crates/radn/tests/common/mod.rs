//! Helpers shared by the end-to-end tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

use radn_core::io::exr_file::{ExrFile, SampleKind};

/// The Cycles sample that ships in the repository.
pub fn sample() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../samples/cycles-sample")
}

/// The beauty (`ViewLayer.Combined` RGB) of a Cycles file, for scoring against a reference.
pub fn beauty_rgb(f: &ExrFile) -> radn_core::Plane {
    let c: Vec<Vec<f32>> = ["R", "G", "B"]
        .iter()
        .map(|c| f.channel_f32(&format!("ViewLayer.Combined.{c}")).unwrap())
        .collect();
    radn_core::Plane::from_channels(f.width(), f.height(), &[&c[0], &c[1], &c[2]])
}

/// Runs the `radn` binary.
pub fn radn(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_radn"))
        .args(args)
        .output()
        .unwrap()
}

/// Runs the `radn` binary and asserts it succeeded, showing its stderr if not.
pub fn radn_ok(args: &[&str]) -> std::process::Output {
    let out = radn(args);
    assert!(
        out.status.success(),
        "radn {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// Copies the sample's low level into `dir/in/`, with float beauty, two AOVs (`diffuse`,
/// `specular`) that sum to it exactly, and an alpha that varies between 1 and `low_alpha`.
pub fn with_aovs(dir: &Path, low_alpha: f32) -> String {
    level_with_aovs(dir, "low", low_alpha)
}

/// [`with_aovs`] for the sample's level `level` (`low`, `half` or `high`).
pub fn level_with_aovs(dir: &Path, level: &str, low_alpha: f32) -> String {
    for f in 1..=9 {
        let mut file = ExrFile::read(sample().join(format!("{level}/frame_{f:04}.exr"))).unwrap();
        let n = file.width() * file.height();
        for c in ["R", "G", "B"] {
            let name = format!("ViewLayer.Combined.{c}");
            // float beauty, so "sums to" holds exactly in the file
            file.convert_channel(&name, SampleKind::F32);
            let beauty = file.channel_f32(&name).unwrap();
            // a split that varies per pixel, like diffuse vs specular
            let diffuse: Vec<f32> = beauty
                .iter()
                .enumerate()
                .map(|(i, v)| v * (0.2 + 0.6 * ((i % 7) as f32 / 6.0)))
                .collect();
            let specular: Vec<f32> = beauty.iter().zip(&diffuse).map(|(b, d)| b - d).collect();
            let sum: Vec<f32> = diffuse.iter().zip(&specular).map(|(a, b)| a + b).collect();
            file.set_channel(&format!("ViewLayer.diffuse.{c}"), &diffuse, SampleKind::F32);
            file.set_channel(
                &format!("ViewLayer.specular.{c}"),
                &specular,
                SampleKind::F32,
            );
            file.set_channel(&name, &sum, SampleKind::F32);
        }
        let alpha: Vec<f32> = (0..n)
            .map(|i| if (i / 176) % 20 < 10 { 1.0 } else { low_alpha })
            .collect();
        file.set_channel("ViewLayer.Combined.A", &alpha, SampleKind::F32);
        let p = dir.join(format!("in/frame_{f:04}.exr"));
        file.write_atomic(&p).unwrap();
    }
    format!("{}/in/frame_####.exr", dir.display())
}

/// Asserts that the denoised `diffuse` and `specular` AOVs of `res` still sum to its denoised
/// beauty (1e-4, relative to the magnitude of the terms summed: where AOVs of opposite sign
/// cancel, f32 rounding is relative to them, not to their small sum), and that the beauty and
/// the AOVs were really filtered (they differ from `src`).
pub fn assert_aovs_sum_to_beauty(res: &ExrFile, src: &ExrFile) {
    for c in ["R", "G", "B"] {
        let get =
            |f: &ExrFile, layer: &str| f.channel_f32(&format!("ViewLayer.{layer}.{c}")).unwrap();
        let (b, di, sp) = (
            get(res, "Combined"),
            get(res, "diffuse"),
            get(res, "specular"),
        );
        let worst = b
            .iter()
            .zip(di.iter().zip(&sp))
            .map(|(b, (d, s))| ((d + s) - b).abs() / (d.abs() + s.abs()).max(b.abs()).max(1e-3))
            .fold(0.0f32, f32::max);
        assert!(
            worst < 1e-4,
            "channel {c}: the denoised AOVs no longer sum to the denoised beauty ({worst})"
        );
        assert_ne!(
            b,
            get(src, "Combined"),
            "channel {c}: the beauty was not denoised"
        );
        assert_ne!(
            di,
            get(src, "diffuse"),
            "channel {c}: the AOVs were not denoised"
        );
    }
}

/// Intel Open Image Denoise with `threads` threads, or `None` (saying so) where it is not
/// installed; where `RADN_REQUIRE_OIDN` is set (as `scripts/test` does) its absence fails.
pub fn oidn_or_skip(threads: usize) -> Option<radn_core::guide::OidnGuides> {
    match radn_core::guide::OidnGuides::new(threads) {
        Ok(g) => Some(g),
        Err(e) if std::env::var_os("RADN_REQUIRE_OIDN").is_none() => {
            eprintln!("SKIPPED: Intel Open Image Denoise is not installed here: {e}");
            None
        }
        Err(e) => panic!("RADN_REQUIRE_OIDN is set but OIDN does not open: {e}"),
    }
}

/// The sample stacked three times vertically (176×300), with the AOVs and alpha of
/// [`with_aovs`]: tall enough that bands of 64 rows and the network's halo leave most of a
/// frame unread per band.
pub fn tall(dir: &Path) -> String {
    let src = with_aovs(dir, 0.25);
    for f in 3..=7 {
        let file = ExrFile::read(src.replace("####", &format!("{f:04}"))).unwrap();
        let (w, h) = (file.width(), file.height());
        let channels = file
            .channel_names()
            .into_iter()
            .map(|name| {
                let v = file.channel_f32(&name).unwrap();
                let mut t = Vec::with_capacity(3 * v.len());
                for k in 0..3 {
                    // the copies are shifted sideways so no two bands look alike
                    for y in 0..h {
                        let row = &v[y * w..(y + 1) * w];
                        t.extend(row[k * 11..].iter().chain(&row[..k * 11]));
                    }
                }
                (name, t)
            })
            .collect();
        let p = dir.join(format!("tall/frame_{f:04}.exr"));
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        ExrFile::from_channels(&p, w, 3 * h, channels, SampleKind::F32)
            .write_atomic(&p)
            .unwrap();
    }
    format!("{}/tall/frame_####.exr", dir.display())
}
