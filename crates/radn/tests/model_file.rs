//! `radn model`: a model file's network and recipe shown, and a copy written with its recipe
//! tuned that denoises exactly as `--tune` does, without touching the original.

mod common;

use common::{beauty_rgb, radn, radn_ok, sample};
use radn_core::io::exr_file::ExrFile;

const DEFAULT: &str = "../../models/default.safetensors";

fn stdout(args: &[&str]) -> String {
    String::from_utf8(radn_ok(args).stdout).unwrap()
}

#[test]
fn the_shipped_guided_model_shows_its_recipe() {
    let shown = stdout(&["model", "../../models/guided-mix.safetensors"]);
    assert!(shown.contains("guide_blend = true"), "{shown}");
    assert!(
        shown.contains("[guide_mix]") && shown.contains("weight = 0.7"),
        "{shown}"
    );
    assert!(
        !shown.contains("[stabilize]") && !shown.contains("[input_blend]"),
        "{shown}"
    );
    // the previous one has the recipe of its kind, temporal pass included
    assert!(stdout(&["model", "../../models/guided-lean.safetensors"]).contains("[stabilize]"));
}

#[test]
fn a_tuned_copy_denoises_as_the_same_tune_does_and_the_original_stays() {
    let d = tempfile::tempdir().unwrap();
    let tuned = d.path().join("tuned.safetensors");
    let tuned = tuned.to_str().unwrap();
    let before = std::fs::read(DEFAULT).unwrap();
    let shown = stdout(&["model", DEFAULT, "--tune", "threshold=0.005", "-o", tuned]);
    assert!(shown.contains("threshold = 0.005"), "{shown}");
    assert_eq!(
        std::fs::read(DEFAULT).unwrap(),
        before,
        "the original is untouched"
    );
    // a second write to the same file is refused, and the copy stays as it was
    let copy = std::fs::read(tuned).unwrap();
    let again = radn(&["model", DEFAULT, "--tune", "input-blend=2", "-o", tuned]);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("exists"));
    assert_eq!(std::fs::read(tuned).unwrap(), copy);
    // a threshold past the kernel's 1/K is refused, as denoise refuses it
    let past = radn(&[
        "model",
        DEFAULT,
        "--tune",
        "threshold=0.01",
        "-o",
        &format!("{tuned}3"),
    ]);
    assert!(String::from_utf8_lossy(&past.stderr).contains("1/K"));
    // a key the recipe does not have is named
    let bad = radn(&[
        "model",
        DEFAULT,
        "--tune",
        "no.such=1",
        "-o",
        &format!("{tuned}2"),
    ]);
    assert!(String::from_utf8_lossy(&bad.stderr).contains("no.such"));
    // the copy runs as the original with the same --tune
    let input = format!("{}/low/frame_####.exr", sample().display());
    let run = |name: &str, extra: &[&str]| {
        let out = format!("{}/{name}/f_####.exr", d.path().display());
        let mut args = vec!["denoise", "-i", &input, "-o", &out, "--frames", "4-4"];
        args.extend_from_slice(&["--guide", "none"]);
        args.extend_from_slice(extra);
        radn_ok(&args);
        beauty_rgb(&ExrFile::read(d.path().join(name).join("f_0004.exr")).unwrap())
    };
    let by_file = run("file", &["--model", tuned]);
    let by_flag = run("flag", &["--model", DEFAULT, "--tune", "threshold=0.005"]);
    let as_shipped = run("shipped", &["--model", DEFAULT]);
    assert!(
        by_file.data() == by_flag.data(),
        "the copy runs as --tune does"
    );
    assert!(
        by_file.data() != as_shipped.data(),
        "the threshold changes the sample"
    );
}
