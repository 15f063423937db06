//! `radn inspect`, and a user channel-mapping file for a renderer radn has no preset for.

use std::process::Command;

use radn_core::io::exr_file::{ExrFile, SampleKind};

#[test]
fn inspect_reports_channels_statistics_and_nonfinite_counts() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("i.exr");
    let mut r: Vec<f32> = (0..64).map(|i| i as f32).collect();
    r[3] = f32::NAN;
    r[4] = f32::INFINITY;
    ExrFile::from_channels(
        &p,
        8,
        8,
        vec![
            ("R".into(), r),
            ("G".into(), vec![0.5; 64]),
            ("B".into(), vec![0.25; 64]),
        ],
        SampleKind::F32,
    )
    .write_atomic(&p)
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_radn"))
        .args(["inspect", p.to_str().unwrap(), "--json"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["width"], 8);
    let r = v["channels"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == "R")
        .unwrap();
    assert_eq!(r["nan"], 1);
    assert_eq!(r["inf"], 1);
    assert_eq!(r["max"], 63.0);
    assert_eq!(r["kind"], "float");
    let text = Command::new(env!("CARGO_BIN_EXE_radn"))
        .args(["inspect", p.to_str().unwrap()])
        .output()
        .unwrap();
    let t = String::from_utf8_lossy(&text.stdout);
    assert!(t.contains("8x8") && t.contains("NaN"), "{t}");
}

#[test]
fn a_user_mapping_file_reads_an_unknown_renderer() {
    let d = tempfile::tempdir().unwrap();
    let (w, h) = (24usize, 16usize);
    // "studio renderer": beauty in rgba.*, albedo in diff_albedo.*, normal in nrm.*,
    // motion towards the NEXT frame only, in UV units (fractions of the image), +Y up
    for f in 1..=3 {
        let mut ch: Vec<(String, Vec<f32>)> = Vec::new();
        for c in ["r", "g", "b"] {
            ch.push((
                format!("rgba.{c}"),
                (0..w * h)
                    .map(|i| ((i + 2 * f) % 5) as f32 * 0.1 + 0.2)
                    .collect(),
            ));
            ch.push((format!("diff_albedo.{c}"), vec![0.5; w * h]));
        }
        for (c, v) in [("x", 0.0), ("y", 0.0), ("z", 1.0)] {
            ch.push((format!("nrm.{c}"), vec![v; w * h]));
        }
        // the image content moves 2 px right per frame: 2/24 of the width
        ch.push(("mv.u".into(), vec![2.0 / w as f32; w * h]));
        ch.push(("mv.v".into(), vec![0.0; w * h]));
        let p = d.path().join(format!("shot.{f:03}.exr"));
        ExrFile::from_channels(&p, w, h, ch, SampleKind::F32)
            .write_atomic(&p)
            .unwrap();
    }
    let mapping = d.path().join("studio.toml");
    std::fs::write(
        &mapping,
        r#"
name = "studio"
[color]
layer = ["rgba"]
channels = ["R", "G", "B"]
[albedo]
layer = ["diff_albedo"]
channels = ["R", "G", "B"]
[normal]
layer = ["nrm"]
channels = ["X", "Y", "Z"]
[motion_next]
layer = ["mv"]
channels = ["U", "V"]
units = "uv"
scale = [1.0, -1.0]
"#,
    )
    .unwrap();
    let out = d.path().join("w.exr");
    let res = Command::new(env!("CARGO_BIN_EXE_radn"))
        .args([
            "warp",
            "-i",
            &format!("{}/shot.%03d.exr", d.path().display()),
            "--frame",
            "2",
            "-o",
            out.to_str().unwrap(),
        ])
        .args(["--mapping", mapping.to_str().unwrap(), "--no-mix"])
        .output()
        .unwrap();
    assert!(
        res.status.success(),
        "{}",
        String::from_utf8_lossy(&res.stderr)
    );
    let f = ExrFile::read(&out).unwrap();
    // the next frame's content is found 2 px to the right; the previous frame's (derived by
    // inverting its forward motion) 2 px to the left
    let (fx_next, fx_prev) = (
        f.channel_f32("w+1.flow.X").unwrap(),
        f.channel_f32("w-1.flow.X").unwrap(),
    );
    let mid = 8 * w + 12;
    assert!((fx_next[mid] - 2.0).abs() < 1e-3, "{}", fx_next[mid]);
    assert!((fx_prev[mid] + 2.0).abs() < 1e-3, "{}", fx_prev[mid]);
    // a mapping file with a typo is rejected with its name
    std::fs::write(
        &mapping,
        "name = \"x\"\n[colour]\nlayer=[\"\"]\nchannels=[\"R\",\"G\",\"B\"]\n",
    )
    .unwrap();
    let res = Command::new(env!("CARGO_BIN_EXE_radn"))
        .args([
            "warp",
            "-i",
            &format!("{}/shot.%03d.exr", d.path().display()),
            "--frame",
            "2",
            "-o",
            out.to_str().unwrap(),
        ])
        .args(["--mapping", mapping.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!res.status.success());
    let e = String::from_utf8_lossy(&res.stderr);
    assert!(e.contains("studio.toml") && e.contains("colour"), "{e}");
}

#[test]
fn a_generic_layout_file_is_detected_as_generic_and_denoises_without_a_preset() {
    // R,G,B,A; albedo.*; N.*; Z; motion.X/Y: the generic preset's layout, which Arnold's
    // preset also half fits (it lacks Arnold's motionvector channels)
    let d = tempfile::tempdir().unwrap();
    let (w, h) = (24, 16);
    let n = w * h;
    let ramp = |k: f32| {
        (0..n)
            .map(|i| 0.2 + k * (i % 7) as f32)
            .collect::<Vec<f32>>()
    };
    for f in 1..=3 {
        let p = d.path().join(format!("g.{f:04}.exr"));
        let mut ch = Vec::new();
        for (name, v) in [
            ("R", ramp(0.05)),
            ("G", ramp(0.04)),
            ("B", ramp(0.03)),
            ("A", vec![1.0; n]),
            ("albedo.R", vec![0.5; n]),
            ("albedo.G", vec![0.5; n]),
            ("albedo.B", vec![0.5; n]),
            ("N.X", vec![0.0; n]),
            ("N.Y", vec![0.0; n]),
            ("N.Z", vec![1.0; n]),
            ("Z", vec![3.0; n]),
            ("motion.X", vec![0.0; n]),
            ("motion.Y", vec![0.0; n]),
        ] {
            ch.push((name.to_string(), v));
        }
        ExrFile::from_channels(&p, w, h, ch, SampleKind::F32)
            .write_atomic(&p)
            .unwrap();
    }
    let first = d.path().join("g.0001.exr");
    let out = Command::new(env!("CARGO_BIN_EXE_radn"))
        .args(["inspect", first.to_str().unwrap(), "--json"])
        .output()
        .unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["preset"], "generic");
    let pattern = format!("{}/g.####.exr", d.path().display());
    let o = format!("{}/o/g.####.exr", d.path().display());
    let res = Command::new(env!("CARGO_BIN_EXE_radn"))
        .args(["denoise", "-i", &pattern, "-o", &o, "--guide", "none"])
        .output()
        .unwrap();
    assert!(
        res.status.success(),
        "{}",
        String::from_utf8_lossy(&res.stderr)
    );
    assert!(d.path().join("o/g.0002.exr").exists());
}

#[test]
fn denoise_help_fits_a_screen_under_headings_and_tune_help_lists_the_recipe() {
    let out = Command::new(env!("CARGO_BIN_EXE_radn"))
        .args(["denoise", "--help"])
        .output()
        .unwrap();
    let help = String::from_utf8_lossy(&out.stdout);
    let lines = help.lines().count();
    assert!(lines <= 80, "{lines} lines:\n{help}");
    for heading in ["Input and output:", "Quality:", "Performance:", "Advanced:"] {
        assert!(help.contains(heading), "no '{heading}' in:\n{help}");
    }
    // one line per option, and no measurements, documents or issue numbers in the help
    assert!(help.lines().all(|l| l.len() <= 110), "{help}");
    for banned in [" dB", "docs/", "issue", "2026-"] {
        assert!(!help.contains(banned), "'{banned}' in:\n{help}");
    }
    let out = Command::new(env!("CARGO_BIN_EXE_radn"))
        .args(["denoise", "--tune", "help"])
        .output()
        .unwrap();
    let tune = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // the guided model's recipe beside the unguided one's, and the classic keys
    let line = |key: &str| {
        tune.lines()
            .find(|l| l.split_whitespace().next() == Some(key))
            .unwrap_or_else(|| panic!("no {key} in:\n{tune}"))
            .split_whitespace()
            .map(str::to_string)
            .collect::<Vec<_>>()
    };
    assert_eq!(line("mix.weight")[1..3], ["0.7", "0"]);
    assert_eq!(line("stabilize")[1..3], ["off", "off"]);
    assert_eq!(line("input-blend")[1..3], ["off", "auto"]);
    assert_eq!(line("confidence.color")[1..3], ["off", "0.5"]);
    assert_eq!(line("classic.nlm-strength")[1], "0.45");
}
