//! The model compiled into `radn` (models/default.safetensors) against its input and the
//! classic denoiser on the shipped Cycles sample, so a weaker model cannot be shipped by
//! mistake. The classic denoiser's guided filter follows the noise (issue 18); at 32 spp it is
//! 1.1 dB behind (33.85 vs 34.97 dB for the shipped model with its default input blend).

mod common;

use common::{beauty_rgb, radn_ok, sample};
use radn_core::exr_file::ExrFile;
use radn_core::metrics::psnr;

fn rgb(path: &std::path::Path) -> radn_core::Plane {
    beauty_rgb(&ExrFile::read(path).unwrap())
}

/// Mean PSNR over the frames with a reference (3–7) of `dir/name_####.exr` against the
/// sample's reference.
fn mean_psnr(dir: &std::path::Path, name: &str) -> f64 {
    mean_psnr_against(dir, name, "ref")
}

/// [`mean_psnr`] against the sample's folder `against` (`ref`, or an input level).
fn mean_psnr_against(dir: &std::path::Path, name: &str, against: &str) -> f64 {
    let frames = 3..=7;
    let n = frames.clone().count() as f64;
    frames
        .map(|f| {
            let reference = rgb(&sample().join(format!("{against}/frame_{f:04}.exr")));
            psnr(&rgb(&dir.join(format!("{name}_{f:04}.exr"))), &reference).unwrap()
        })
        .sum::<f64>()
        / n
}

#[test]
fn default_model_beats_its_input_and_the_classic_denoiser_at_4_spp_on_the_sample() {
    let d = tempfile::tempdir().unwrap();
    // measured with the shipped model (stage 6, models/README.md) and `--input-blend auto`:
    // 31.25 vs classic 30.30 dB at 4 spp, 35.03 vs 33.85 dB at 32 spp (inputs 19.29 and
    // 28.82 dB); stage 5 scored 31.04 and 34.97 and passed the margins before this stage (0.7
    // and 0.5 dB), stage 4 (no blend) 31.20 and 33.66
    for (level, margin) in [("low", 0.8), ("high", 1.0)] {
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

#[test]
fn raising_the_threshold_moves_the_default_models_result_toward_its_input() {
    // the paper's strength control (its Fig. 3): the shipped model's kernels are normalised
    // before η_t (`norm_eta`), so t drops the weak taps. This tests the kernels' threshold, so
    // without the input blend (which pulls toward the input itself). From the model's default
    // t = 1/(2K) to 0.94/K, near the top of the allowed [0, 1/K) (K: the kernel's taps, 125
    // for 5×5×5 kernels, 45 for 3×3×5). Measured at 32 spp with the stage-6 default (K = 125,
    // 0.004 → 0.0075): PSNR against the input 28.53 → 28.84 dB (against the reference
    // 34.46 → 34.77; stage 5: 28.42 → 28.76); stage 4's raw-weight η moved by 0.04 dB over the
    // same range.
    let model =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/default.safetensors");
    let config = radn_nn::model::store::read_config(&model).unwrap();
    let taps = config.kernel_taps() as f32;
    let d = tempfile::tempdir().unwrap();
    let input = format!("{}/high/frame_####.exr", sample().display());
    let mut closeness = Vec::new();
    let thresholds = [config.default_threshold(), 0.94 / taps];
    for t in thresholds {
        let t = format!("{t}");
        let out = format!("{}/t{t}/dn_####.exr", d.path().display());
        radn_ok(&[
            "denoise",
            "-i",
            &input,
            "-o",
            &out,
            "--frames",
            "3-7",
            "--threshold",
            &t,
            "--input-blend",
            "off",
        ]);
        closeness.push(mean_psnr_against(
            &d.path().join(format!("t{t}")),
            "dn",
            "high",
        ));
    }
    assert!(
        closeness[1] > closeness[0] + 0.2,
        "PSNR against the input at t = {thresholds:?}: {closeness:?}"
    );
}
