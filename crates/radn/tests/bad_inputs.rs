//! Every bad input gives a clear error naming the file and the problem, a non-zero exit code,
//! and touches no file.

use std::path::{Path, PathBuf};
use std::process::Command;

use radn_core::io::exr_file::{ExrFile, SampleKind};

const W: usize = 32;
const H: usize = 24;

/// Writes a Cycles-style multilayer frame; `skip` names passes to leave out.
fn cycles_frame(path: &Path, frame: i64, w: usize, h: usize, skip: &[&str], poison: bool) {
    let mut ch: Vec<(String, Vec<f32>)> = Vec::new();
    for (pass, comps) in [
        ("Combined", vec!["R", "G", "B", "A"]),
        ("Denoising Albedo", vec!["R", "G", "B"]),
        ("Denoising Normal", vec!["X", "Y", "Z"]),
        ("Vector", vec!["X", "Y", "Z", "W"]),
        ("Depth", vec!["Z"]),
    ] {
        if skip.contains(&pass) {
            continue;
        }
        for (i, c) in comps.iter().enumerate() {
            let v: Vec<f32> = (0..w * h)
                .map(|p| match pass {
                    "Combined" => 0.2 + 0.1 * i as f32 + 0.01 * ((p + frame as usize) % 7) as f32,
                    "Denoising Albedo" => 0.5,
                    "Denoising Normal" => {
                        if i == 2 {
                            1.0
                        } else {
                            0.0
                        }
                    }
                    "Vector" => {
                        if i % 2 == 0 {
                            -1.0
                        } else {
                            0.0
                        }
                    }
                    _ => 4.0,
                })
                .collect();
            ch.push((format!("ViewLayer.{pass}.{c}"), v));
        }
    }
    if poison {
        let r = ch
            .iter_mut()
            .find(|(n, _)| n == "ViewLayer.Combined.G")
            .unwrap();
        r.1[5] = f32::NAN;
        r.1[6] = f32::INFINITY;
    }
    ExrFile::from_channels(path, w, h, ch, SampleKind::F32)
        .write_atomic(path)
        .unwrap();
}

fn sequence(dir: &Path, n: i64) -> String {
    for f in 1..=n {
        cycles_frame(&dir.join(format!("beauty.{f:04}.exr")), f, W, H, &[], false);
    }
    format!("{}/beauty.####.exr", dir.display())
}

/// Snapshot of a folder: names and contents, to prove nothing was touched.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut v: Vec<(PathBuf, Vec<u8>)> = walk(dir)
        .into_iter()
        .map(|p| {
            let b = std::fs::read(&p).unwrap();
            (p, b)
        })
        .collect();
    v.sort();
    v
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            out.extend(walk(&p))
        } else {
            out.push(p)
        }
    }
    out
}

/// Runs radn, expects failure, returns stderr; checks the folder is unchanged.
fn fails(dir: &Path, args: &[&str]) -> String {
    let before = snapshot(dir);
    let out = Command::new(env!("CARGO_BIN_EXE_radn"))
        .args(args)
        .output()
        .unwrap();
    assert!(!out.status.success(), "radn {args:?} should fail");
    assert_ne!(out.status.code(), Some(0));
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!err.contains("panicked"), "radn panicked: {err}");
    assert_eq!(snapshot(dir), before, "radn {args:?} touched files");
    err
}

fn warp_args<'a>(input: &'a str, out: &'a str) -> Vec<&'a str> {
    vec![
        "warp", "-i", input, "--frame", "3", "-o", out, "--preset", "cycles",
    ]
}

/// `radn denoise` (the unguided network) on the same input, writing `out` (a pattern).
fn denoise_args<'a>(input: &'a str, out: &'a str) -> Vec<&'a str> {
    vec![
        "denoise", "-i", input, "-o", out, "--preset", "cycles", "--guide", "none",
    ]
}

/// Runs `warp` and `denoise` on a bad input and returns both errors. Denoise writes to a
/// folder of its own: frames before the bad one may be finished; the input folder is checked.
fn both_fail(dir: &Path, input: &str, extra: &[&str]) -> [String; 2] {
    let w = dir.join("w.exr");
    let mut a = warp_args(input, w.to_str().unwrap());
    a.extend(extra);
    let e1 = fails(dir, &a);
    let o = tempfile::tempdir().unwrap();
    let pat = o.path().join("d.####.exr");
    let mut a = denoise_args(input, pat.to_str().unwrap());
    a.extend(extra);
    let e2 = fails(dir, &a);
    [e1, e2]
}

#[test]
fn truncated_exr() {
    let d = tempfile::tempdir().unwrap();
    let input = sequence(d.path(), 5);
    let victim = d.path().join("beauty.0002.exr");
    let bytes = std::fs::read(&victim).unwrap();
    std::fs::write(&victim, &bytes[..bytes.len() * 2 / 3]).unwrap();
    for e in both_fail(d.path(), &input, &[]) {
        assert!(
            e.contains("beauty.0002.exr") && (e.contains("truncated") || e.contains("corrupt")),
            "{e}"
        );
    }
}

#[test]
fn not_an_exr() {
    let d = tempfile::tempdir().unwrap();
    let input = sequence(d.path(), 5);
    std::fs::write(d.path().join("beauty.0004.exr"), b"P6\n32 24\n255\n").unwrap();
    for e in both_fail(d.path(), &input, &[]) {
        assert!(
            e.contains("beauty.0004.exr") && e.contains("not an OpenEXR file"),
            "{e}"
        );
    }
}

#[test]
fn missing_albedo_normal_or_motion() {
    for (pass, word) in [
        ("Denoising Albedo", "albedo"),
        ("Denoising Normal", "normal"),
        ("Vector", "motion"),
    ] {
        let d = tempfile::tempdir().unwrap();
        let input = sequence(d.path(), 5);
        cycles_frame(&d.path().join("beauty.0003.exr"), 3, W, H, &[pass], false);
        for e in both_fail(d.path(), &input, &[]) {
            assert!(
                e.contains("beauty.0003.exr") && e.contains(word) && e.contains("cycles"),
                "{pass}: {e}"
            );
        }
    }
}

#[test]
fn frames_of_different_sizes() {
    let d = tempfile::tempdir().unwrap();
    let input = sequence(d.path(), 5);
    cycles_frame(&d.path().join("beauty.0004.exr"), 4, W + 2, H, &[], false);
    for e in both_fail(d.path(), &input, &[]) {
        assert!(
            e.contains("beauty.0004.exr") && e.contains("34x24") && e.contains("32x24"),
            "{e}"
        );
    }
}

#[test]
fn missing_frame_in_range() {
    let d = tempfile::tempdir().unwrap();
    let input = sequence(d.path(), 5);
    std::fs::remove_file(d.path().join("beauty.0002.exr")).unwrap();
    for e in both_fail(d.path(), &input, &["--frames", "1-5"]) {
        assert!(
            e.contains("frame 2") && e.contains("beauty.0002.exr"),
            "{e}"
        );
    }
    // without an explicit range the gap is found too
    for e in both_fail(d.path(), &input, &[]) {
        assert!(e.contains("beauty.0002.exr"), "{e}");
    }
}

#[test]
fn nan_and_inf_pixels() {
    let d = tempfile::tempdir().unwrap();
    let input = sequence(d.path(), 5);
    cycles_frame(&d.path().join("beauty.0003.exr"), 3, W, H, &[], true);
    for e in both_fail(d.path(), &input, &["--nonfinite", "error"]) {
        assert!(
            e.contains("beauty.0003.exr")
                && e.contains("ViewLayer.Combined.G")
                && e.contains("2 NaN/Inf"),
            "{e}"
        );
    }
    let out = d.path().join("w.exr");
    // by default they are repaired, reported, and the output is finite
    let res = Command::new(env!("CARGO_BIN_EXE_radn"))
        .args(warp_args(&input, out.to_str().unwrap()))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&res.stderr);
    assert!(res.status.success(), "{err}");
    assert!(
        err.contains("repaired NaN/Inf") && err.contains("beauty.0003.exr"),
        "{err}"
    );
    let f = ExrFile::read(&out).unwrap();
    for n in f.channel_names() {
        assert!(
            f.channel_f32(&n).unwrap().iter().all(|v| v.is_finite()),
            "{n}"
        );
    }
}

#[test]
fn unwritable_output_folder() {
    let d = tempfile::tempdir().unwrap();
    let input = sequence(d.path(), 5);
    // a folder that cannot exist: its parent is a regular file
    let out = d.path().join("beauty.0001.exr/sub/w.exr");
    let e = fails(d.path(), &warp_args(&input, out.to_str().unwrap()));
    assert!(
        e.contains("cannot write") && e.contains("beauty.0001.exr"),
        "{e}"
    );
    let out = d.path().join("beauty.0001.exr/sub/d.####.exr");
    let e = fails(d.path(), &denoise_args(&input, out.to_str().unwrap()));
    assert!(
        e.contains("cannot write") && e.contains("beauty.0001.exr"),
        "{e}"
    );
}

#[test]
fn an_unusable_scratch_folder_is_named_and_nothing_is_written() {
    // band by band, each frame's decoded rows are kept in a temporary file in TMPDIR
    let d = tempfile::tempdir().unwrap();
    let input = sequence(d.path(), 5);
    let o = tempfile::tempdir().unwrap();
    let out = o.path().join("d.####.exr");
    let missing = d.path().join("no-such-folder");
    let res = Command::new(env!("CARGO_BIN_EXE_radn"))
        .args(denoise_args(&input, out.to_str().unwrap()))
        .args(["--tile", "8", "--bands", "always"])
        .env("TMPDIR", &missing)
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&res.stderr);
    assert!(!res.status.success() && !e.contains("panicked"), "{e}");
    assert!(
        e.contains("beauty.0001.exr")
            && e.contains("temporary file")
            && e.contains(missing.to_str().unwrap())
            && e.contains("TMPDIR"),
        "{e}"
    );
    assert_eq!(
        walk(o.path()),
        Vec::<PathBuf>::new(),
        "an output was written"
    );
}

#[test]
fn output_equal_to_input() {
    let d = tempfile::tempdir().unwrap();
    let input = sequence(d.path(), 5);
    let same = d.path().join("beauty.0003.exr");
    let e = fails(d.path(), &warp_args(&input, same.to_str().unwrap()));
    assert!(
        e.contains("refusing") && e.contains("beauty.0003.exr"),
        "{e}"
    );
    // the same file through another spelling of its path
    let other = format!("{}/./beauty.0002.exr", d.path().display());
    let e = fails(d.path(), &warp_args(&input, &other));
    assert!(e.contains("refusing"), "{e}");
    // denoise: the same pattern, or one that names the same files another way
    let e = fails(d.path(), &denoise_args(&input, &input));
    assert!(e.contains("refusing"), "{e}");
    let other = format!("{}/./beauty.####.exr", d.path().display());
    let e = fails(d.path(), &denoise_args(&input, &other));
    assert!(
        e.contains("refusing") && e.contains("beauty.0001.exr"),
        "{e}"
    );
}

#[test]
fn unknown_preset_and_bad_pattern_are_explained() {
    let d = tempfile::tempdir().unwrap();
    let input = sequence(d.path(), 5);
    let out = d.path().join("w.exr");
    let mut args = warp_args(&input, out.to_str().unwrap());
    args[8] = "vray";
    let e = fails(d.path(), &args);
    assert!(
        e.contains("unknown preset 'vray'") && e.contains("cycles"),
        "{e}"
    );
    let bad = format!("{}/beauty.exr", d.path().display());
    let e = fails(d.path(), &warp_args(&bad, out.to_str().unwrap()));
    assert!(e.contains("no frame-number field"), "{e}");
}

#[test]
fn warp_writes_a_window_and_clamps_at_the_start() {
    let d = tempfile::tempdir().unwrap();
    let input = sequence(d.path(), 5);
    let out = d.path().join("o/w.exr");
    let res = Command::new(env!("CARGO_BIN_EXE_radn"))
        .args([
            "warp",
            "-i",
            &input,
            "--frame",
            "1",
            "-o",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        res.status.success(),
        "{}",
        String::from_utf8_lossy(&res.stderr)
    );
    let f = ExrFile::read(&out).unwrap();
    for o in ["w-2", "w-1", "w+0", "w+1", "w+2"] {
        assert!(
            f.has_channel(&format!("{o}.R")) && f.has_channel(&format!("{o}.confidence.Y")),
            "{o}"
        );
    }
    // frames before the first do not exist: zero confidence
    assert!(f
        .channel_f32("w-1.confidence.Y")
        .unwrap()
        .iter()
        .all(|&c| c == 0.0));
    assert!(f
        .channel_f32("w+0.confidence.Y")
        .unwrap()
        .iter()
        .all(|&c| c == 1.0));
    // no temporary files left
    assert_eq!(std::fs::read_dir(d.path().join("o")).unwrap().count(), 1);
}

#[test]
fn repairs_in_the_inputs_are_reported_after_several_passes() {
    let d = tempfile::tempdir().unwrap();
    let input = sequence(d.path(), 5);
    cycles_frame(&d.path().join("beauty.0003.exr"), 3, W, H, &[], true);
    // the later passes read radn's own results, the temporal pass the inputs once more: the
    // count is the inputs' own, once
    for (name, extra) in [
        ("one", &["--guide", "none"][..]),
        ("two", &["--guide", "none", "--passes", "2"][..]),
        (
            "stabilized",
            &["--guide", "none", "--tune", "stabilize=0.3"][..],
        ),
    ] {
        let out = format!("{}/{name}/f_####.exr", d.path().display());
        let mut args = vec!["denoise", "-i", &input, "-o", &out];
        args.extend(extra);
        let res = Command::new(env!("CARGO_BIN_EXE_radn"))
            .args(&args)
            .output()
            .unwrap();
        let said = String::from_utf8_lossy(&res.stdout);
        assert!(
            res.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&res.stderr)
        );
        assert!(
            said.contains("repaired 2 NaN/Inf input samples"),
            "{name}: {said}"
        );
    }
}

#[test]
fn oidn_guide_settings_without_an_oidn_guide() {
    // `radn prepare --guide-prefilter off` without `--guide oidn` would make tiles with no such
    // guides: refused before any work, naming the flag it needs
    let d = tempfile::tempdir().unwrap();
    sequence(d.path(), 3);
    let out = d.path().join("tiles");
    let e = fails(
        d.path(),
        &[
            "prepare",
            "--data",
            d.path().to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--guide-prefilter",
            "off",
        ],
    );
    assert!(e.contains("--guide oidn"), "{e}");
    assert!(!out.exists());
}
