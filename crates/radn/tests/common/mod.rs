//! Helpers shared by the end-to-end tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

use radn_core::exr_file::{ExrFile, SampleKind};

/// The Cycles sample that ships in the repository.
pub fn sample() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../samples/cycles-sample")
}

/// Runs the `radn` binary.
pub fn radn(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_radn"))
        .args(args)
        .output()
        .unwrap()
}

/// Copies the sample's low level into `dir/in/`, with float beauty, two AOVs (`diffuse`,
/// `specular`) that sum to it exactly, and an alpha that varies between 1 and `low_alpha`.
pub fn with_aovs(dir: &Path, low_alpha: f32) -> String {
    for f in 1..=9 {
        let mut file = ExrFile::read(sample().join(format!("low/frame_{f:04}.exr"))).unwrap();
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
