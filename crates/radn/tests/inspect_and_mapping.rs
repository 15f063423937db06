//! `radn inspect`, and a user channel-mapping file for a renderer radn has no preset for.

use std::process::Command;

use radn_core::exr_file::{ExrFile, SampleKind};

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
