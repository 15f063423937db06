//! The model compiled into `radn` (models/default.safetensors) against its input and the
//! classic denoiser on the shipped Cycles sample, so a weaker model cannot be shipped by
//! mistake. Since the classic denoiser's guided filter follows the noise (issue 18), it leads
//! the shipped model at 32 spp (33.85 vs 33.66 dB): there the test bounds the gap.

mod common;

use common::{beauty_rgb, radn_ok, sample};
use radn_core::exr_file::ExrFile;
use radn_core::metrics::psnr;

fn rgb(path: &std::path::Path) -> radn_core::Plane {
    beauty_rgb(&ExrFile::read(path).unwrap())
}

/// Mean PSNR over the frames with a reference (3–7) of `dir/name_####.exr`.
fn mean_psnr(dir: &std::path::Path, name: &str) -> f64 {
    let frames = 3..=7;
    let n = frames.clone().count() as f64;
    frames
        .map(|f| {
            let reference = rgb(&sample().join(format!("ref/frame_{f:04}.exr")));
            psnr(&rgb(&dir.join(format!("{name}_{f:04}.exr"))), &reference).unwrap()
        })
        .sum::<f64>()
        / n
}

#[test]
fn default_model_beats_its_input_and_the_classic_denoiser_at_4_spp_on_the_sample() {
    let d = tempfile::tempdir().unwrap();
    // measured with the shipped model (stage 4, models/README.md): 31.20 vs classic 30.30 dB
    // at 4 spp, 33.66 vs 33.85 dB at 32 spp (inputs 19.29 and 28.82 dB); the previous default
    // scored 31.04 and 33.68
    for (level, margin) in [("low", 0.7), ("high", -0.5)] {
        let input = format!("{}/{level}/frame_####.exr", sample().display());
        for method in ["network", "classic"] {
            let out = format!("{}/{level}-{method}/dn_####.exr", d.path().display());
            radn_ok(&[
                "denoise", "--method", method, "-i", &input, "-o", &out, "--frames", "3-7",
            ]);
        }
        let noisy = mean_psnr(&sample().join(level), "frame");
        let network = mean_psnr(&d.path().join(format!("{level}-network")), "dn");
        let classic = mean_psnr(&d.path().join(format!("{level}-classic")), "dn");
        assert!(
            network > classic + margin && network > noisy + 4.0,
            "{level}: noisy {noisy:.2} dB, classic {classic:.2} dB, default model {network:.2} dB"
        );
    }
}
