//! The model compiled into `radn` (models/default.safetensors) against its input and the
//! classic denoiser on the shipped Cycles sample, so a weaker model cannot be shipped by
//! mistake. The classic denoiser's guided filter follows the noise (issue 18); at 32 spp it is
//! 1.1 dB behind (33.85 vs 34.97 dB for the shipped model with its default input blend).

mod common;

use common::{beauty_rgb, radn_ok, sample};
use radn_core::eval::metrics::psnr;
use radn_core::io::exr_file::ExrFile;

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
    // the shipped unguided model with its recipe (measurements: models/default.md)
    for (level, margin) in [("low", 0.8), ("high", 1.0)] {
        let input = format!("{}/{level}/frame_####.exr", sample().display());
        for method in ["network", "classic"] {
            let out = format!("{}/{level}-{method}/dn_####.exr", d.path().display());
            radn_ok(&[
                "denoise", "--method", method, "-i", &input, "-o", &out, "--frames", "3-7",
                "--guide", "none",
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
fn raising_the_threshold_or_lowering_the_strength_moves_the_result_toward_its_input() {
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
    let t0 = config.default_threshold();
    // the same t given directly, and as `--strength` (t = t0 / S)
    let runs = [
        ("default", vec![]),
        (
            "tuned",
            vec!["--tune".to_string(), format!("threshold={}", 0.94 / taps)],
        ),
        (
            "strength",
            vec!["--strength".to_string(), format!("{}", t0 * taps / 0.94)],
        ),
    ];
    for (name, extra) in &runs {
        let out = format!("{}/{name}/dn_####.exr", d.path().display());
        let mut args = vec![
            "denoise",
            "-i",
            &input,
            "-o",
            &out,
            "--frames",
            "3-7",
            "--guide",
            "none",
            "--tune",
            "input-blend=off",
        ];
        args.extend(extra.iter().map(String::as_str));
        radn_ok(&args);
        closeness.push(mean_psnr_against(&d.path().join(name), "dn", "high"));
    }
    assert!(
        closeness[1] > closeness[0] + 0.2 && (closeness[2] - closeness[1]).abs() < 0.01,
        "PSNR against the input at t = {t0}, 0.94/K, and by --strength: {closeness:?}"
    );
}
