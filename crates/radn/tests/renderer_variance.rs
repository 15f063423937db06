//! The renderer's per-pixel variance (`variance.R/G/B` in the generic layout): where the files
//! carry it, the fallbacks (the classic denoiser and the unguided model) blend back towards
//! their input where they changed it by more than that noise explains, so a clean render keeps
//! detail they would have averaged away, and a noisy one is still denoised.

mod common;

use std::path::Path;

use common::radn_ok;
use radn_core::io::exr_file::{ExrFile, SampleKind};

const W: usize = 64;
const H: usize = 48;
/// The height of the sequence that is denoised in bands.
const TALL: usize = 320;
const CENTRE: usize = 3;

/// Shading stripes that move one pixel per frame with no motion vector to say so (a fence's
/// shadow sweeping over a flat wall): detail neither the albedo nor the normal describes, which
/// a temporal or feature-guided filter averages away.
fn clean(x: usize, frame: usize) -> f32 {
    if ((x + frame) / 2).is_multiple_of(2) {
        0.5
    } else {
        0.2
    }
}

/// Standard normal noise, a pure function of its arguments (Box–Muller over a hash).
fn gauss(x: usize, y: usize, c: usize, frame: usize) -> f32 {
    let u = |salt: u64| {
        let mut h = (x as u64) << 40 ^ (y as u64) << 24 ^ (c as u64) << 16 ^ (frame as u64) << 8;
        h ^= salt;
        h = h.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        h ^= h >> 31;
        h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 29;
        ((h >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let (a, b) = (u(1), u(2));
    ((-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()) as f32
}

/// Writes frames 1–5 of the sequence with noise of standard deviation `sigma`, in the generic
/// layout, with the renderer's variance (`sigma²`) where `with_variance`.
fn write_sequence(dir: &Path, sigma: f32, with_variance: bool) {
    write_frames(dir, H, sigma, with_variance.then_some(1.0));
}

/// [`write_sequence`] `h` rows tall, its variance channels `overstated` times `sigma²` (a
/// stratified sampler's variance AOV overstates its error), none where `None`.
fn write_frames(dir: &Path, h: usize, sigma: f32, overstated: Option<f32>) {
    write_frames_moving(dir, h, sigma, overstated, false);
}

/// [`write_frames`], with motion vectors that follow the stripes where `vectors`.
fn write_frames_moving(dir: &Path, h: usize, sigma: f32, overstated: Option<f32>, vectors: bool) {
    std::fs::create_dir_all(dir).unwrap();
    let n = W * h;
    let filled = |v: f32| vec![v; n];
    for f in 1..=5 {
        let mut ch: Vec<(String, Vec<f32>)> = Vec::new();
        for (c, name) in ["R", "G", "B"].iter().enumerate() {
            let beauty = (0..n)
                .map(|i| clean(i % W, f) + sigma * gauss(i % W, i / W, c, f))
                .collect();
            ch.push((name.to_string(), beauty));
            ch.push((format!("albedo.{name}"), filled(0.5)));
            if let Some(k) = overstated {
                ch.push((format!("variance.{name}"), filled(k * sigma * sigma)));
            }
        }
        for (name, v) in [
            ("A", 1.0),
            ("N.X", 0.0),
            ("N.Y", 0.0),
            ("N.Z", 1.0),
            ("Z", 3.0),
            // the stripes move one pixel left per frame: a pixel's surface point was one
            // pixel to its right in the frame before
            ("motion.X", if vectors { 1.0 } else { 0.0 }),
            ("motion.Y", 0.0),
        ] {
            ch.push((name.to_string(), filled(v)));
        }
        let p = dir.join(format!("f.{f:04}.exr"));
        ExrFile::from_channels(&p, W, h, ch, SampleKind::F32)
            .write_atomic(&p)
            .unwrap();
    }
}

/// Mean squared error of frame [`CENTRE`]'s beauty in `dir` against the clean image.
fn error(dir: &Path) -> f32 {
    let f = ExrFile::read(dir.join(format!("f.{CENTRE:04}.exr"))).unwrap();
    let mut sum = 0.0;
    for c in ["R", "G", "B"] {
        let v = f.channel_f32(c).unwrap();
        sum += v
            .iter()
            .enumerate()
            .map(|(i, v)| (v - clean(i % W, CENTRE)).powi(2))
            .sum::<f32>();
    }
    sum / (3 * W * H) as f32
}

/// Runs `radn denoise` on the sequence in `input`, writing into `out`, with `extra` arguments.
fn denoise(input: &Path, out: &Path, extra: &[&str]) {
    let pattern = format!("{}/f.####.exr", out.display());
    let mut args = vec![
        "--progress",
        "off",
        "denoise",
        "-i",
        input.to_str().unwrap(),
    ];
    args.extend(["-o", &pattern]);
    args.extend_from_slice(extra);
    radn_ok(&args);
}

/// The input's error and each method's, without and with the variance channels.
fn errors(root: &Path, sigma: f32, method: &[&str]) -> (f32, f32, f32) {
    let mut out = [0.0; 2];
    for (k, with) in [false, true].into_iter().enumerate() {
        let input = root.join(format!("in-{with}"));
        write_sequence(&input, sigma, with);
        let result = root.join(format!("out-{with}"));
        denoise(&input, &result, method);
        out[k] = error(&result);
    }
    (error(&root.join("in-false")), out[0], out[1])
}

#[test]
fn with_the_renderers_variance_the_fallbacks_keep_a_clean_renders_detail_and_still_denoise() {
    // the files' motion is all zero (the wall does not move): the renderer's word, not motion
    // estimated from the moving shading
    for method in [
        &["--method", "classic", "--motion", "renderer"][..],
        &["--guide", "none", "--motion", "renderer"][..],
    ] {
        let d = tempfile::tempdir().unwrap();
        // a clean render (noise 0.01 against stripes of 0.3): with the variance neither ends
        // below its input, and both keep more of the stripes than without it (the unguided
        // model without it: about 200 times the input's error)
        let (input, without, with) = errors(&d.path().join("clean"), 0.01, method);
        assert!(with <= input, "{method:?}: {with} vs input {input}");
        assert!(
            with <= 0.7 * without,
            "{method:?}: {with} vs {without} without"
        );
        // a noisy render (noise 0.2): with the variance they still remove most of it, no
        // less than without
        let (input, without, with) = errors(&d.path().join("noisy"), 0.2, method);
        assert!(with < 0.5 * input, "{method:?}: {with} vs input {input}");
        assert!(
            with <= 1.05 * without,
            "{method:?}: {with} vs {without} without"
        );
    }
}

#[test]
fn a_variance_that_overstates_the_noise_is_checked_against_the_frames_and_scaled_to_it() {
    // a clean render whose variance channels say 30 times its noise, as a low-discrepancy
    // sampler's variance AOV can, its motion vectors right this time: radn measures the
    // overstatement frame against frame and scales it away. The unguided model then ends as
    // with the true variance, and multiplied back (`input-blend.variance-scale=30`) it reads
    // the stripes as noise (twice the error); the classic denoiser keeps them by its temporal
    // average either way and stays far below the input's error
    let d = tempfile::tempdir().unwrap();
    let honest = d.path().join("honest");
    write_frames_moving(&honest, H, 0.01, Some(1.0), true);
    let overstated = d.path().join("overstated");
    write_frames_moving(&overstated, H, 0.01, Some(30.0), true);
    let input = error(&honest);
    let run = |name: &str, data: &Path, args: &[&str]| {
        let out = d.path().join(name);
        denoise(data, &out, args);
        error(&out)
    };
    let classic = run("classic", &overstated, &["--method", "classic"]);
    assert!(
        classic <= 0.1 * input,
        "classic: {classic} vs input {input}"
    );
    let unguided = ["--guide", "none"];
    let truth = run("truth", &honest, &unguided);
    let checked = run("checked", &overstated, &unguided);
    let undone = run(
        "undone",
        &overstated,
        &["--guide", "none", "--tune", "input-blend.variance-scale=30"],
    );
    assert!(checked <= input, "{checked} vs input {input}");
    assert!(
        checked <= 1.1 * truth,
        "{checked} vs {truth} with the true variance"
    );
    assert!(
        undone >= 1.5 * checked,
        "{undone} with the variance as written, {checked} checked"
    );
}

#[test]
fn with_the_renderers_variance_bands_still_equal_whole_frames() {
    // the variance blend's boxes read rows beyond each band: with a radius beyond the network's
    // own reach (its receptive field), the band halo has to grow for the blend
    let d = tempfile::tempdir().unwrap();
    let input = d.path().join("in");
    // overstated, so that each band reads the variance as scaled by the whole frame's check
    write_frames_moving(&input, TALL, 0.05, Some(30.0), true);
    let run = |tile: &str| {
        let out = d.path().join(format!("t{tile}"));
        let radius = "input-blend.variance-radius=150";
        let args = [
            "--guide", "none", "--tune", radius, "--tile", tile, "--bands", "always",
        ];
        denoise(&input, &out, &args);
        out
    };
    let (whole, banded) = (run("0"), run("64"));
    for f in 1..=5 {
        let read = |dir: &Path| ExrFile::read(dir.join(format!("f.{f:04}.exr"))).unwrap();
        let (a, b) = (read(&whole), read(&banded));
        for c in ["R", "G", "B"] {
            let (x, y) = (a.channel_f32(c).unwrap(), b.channel_f32(c).unwrap());
            for (i, (u, v)) in x.iter().zip(&y).enumerate() {
                assert!(
                    (u - v).abs() <= 1e-5 * u.abs().max(1.0),
                    "frame {f} {c} row {}: whole {u}, banded {v}",
                    i / W
                );
            }
        }
    }
}
