//! `radn eval` on sequences with known errors.

mod common;

use std::path::Path;

use common::{radn, radn_ok, sample};

use radn_core::io::exr_file::{ExrFile, SampleKind};

fn write_seq(dir: &Path, frames: &[i64], value: impl Fn(i64, usize) -> f32) {
    std::fs::create_dir_all(dir).unwrap();
    for &f in frames {
        let ch = ["R", "G", "B"]
            .iter()
            .map(|c| (c.to_string(), (0..16 * 8).map(|i| value(f, i)).collect()))
            .collect();
        let p = dir.join(format!("img.{f:04}.exr"));
        ExrFile::from_channels(&p, 16, 8, ch, SampleKind::F32)
            .write_atomic(&p)
            .unwrap();
    }
}

/// The linear value whose tonemapped value is `t`.
fn untonemap(t: f32) -> f32 {
    let l = t.powf(2.2);
    l / (1.0 - l)
}

#[test]
fn eval_reports_known_psnr_flicker_and_writes_json_and_csv() {
    let d = tempfile::tempdir().unwrap();
    let reference = d.path().join("ref");
    let result = d.path().join("res");
    write_seq(&reference, &[1, 2, 3], |_, _| untonemap(0.5));
    // tonemapped error 0.1 on every frame -> PSNR 20 dB; it alternates in sign -> flicker
    write_seq(&result, &[1, 2, 3], |f, _| {
        untonemap(if f % 2 == 0 { 0.6 } else { 0.4 })
    });
    let json = d.path().join("m/metrics.json");
    let csv = d.path().join("m/metrics.csv");
    let out = radn_ok(&[
        "eval",
        "--result",
        result.to_str().unwrap(),
        "--reference",
        reference.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
        "--csv",
        csv.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("mean"), "{stdout}");
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let mean = &v["mean"];
    assert!(
        (mean["psnr"].as_f64().unwrap() - 20.0).abs() < 0.01,
        "{mean}"
    );
    // frame-to-frame change of the result is ±0.2 where the reference does not change
    let tmae = mean["tmae"].as_f64().unwrap();
    assert!((tmae - 0.2).abs() < 1e-3, "{tmae}");
    assert!(
        v["frames"][0]["tmae"].is_null(),
        "the first frame has no predecessor"
    );
    assert_eq!(v["frames"].as_array().unwrap().len(), 3);
    let text = std::fs::read_to_string(&csv).unwrap();
    assert_eq!(text.lines().count(), 4, "{text}");
    assert!(
        text.starts_with("frame,psnr,ssim,relmse,tmae,tpsnr"),
        "{text}"
    );
}

/// `--second-reference`: two references whose noise is independent (here: orthogonal
/// patterns) give the error against the noise-free image, which one alone hides.
#[test]
fn a_second_reference_takes_the_references_noise_out_of_the_metrics() {
    let d = tempfile::tempdir().unwrap();
    let (a, b, result) = (d.path().join("a"), d.path().join("b"), d.path().join("r"));
    // the truth is 0.5 (tonemapped) everywhere and still; A's noise is ±0.1 in a pattern that
    // flips every frame, B's is ±0.1 in another pattern (orthogonal to A's), the same in every
    // frame; the result is off by a constant 0.05
    let sign = |k: bool| if k { 1.0 } else { -1.0 };
    write_seq(&a, &[1, 2, 3], |f, i| {
        untonemap(0.5 + 0.1 * sign(i % 2 == 0) * sign(f % 2 == 0))
    });
    write_seq(&b, &[1, 2, 3], |_, i| {
        untonemap(0.5 + 0.1 * sign(i / 2 % 2 == 0))
    });
    write_seq(&result, &[1, 2, 3], |_, _| untonemap(0.55));
    let json = d.path().join("m.json");
    let out = radn_ok(&[
        "eval",
        "--result",
        result.to_str().unwrap(),
        "--reference",
        a.to_str().unwrap(),
        "--second-reference",
        b.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("PSNR*"), "{stdout}");
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let close = |x: &serde_json::Value, want: f64, tol: f64| {
        let x = x.as_f64().unwrap();
        assert!((x - want).abs() < tol, "{x} vs {want}");
    };
    // against A alone: MSE 0.05² + 0.1² -> 19.03 dB, and A's flicker is charged to the result
    close(&v["mean"]["psnr"], 19.03, 0.01);
    close(&v["mean"]["tmae"], 0.2, 1e-3);
    // without the references' noise: MSE 0.05² -> 26.02 dB, and a still result is exactly still
    let nf = &v["noise_free"]["mean"];
    close(&nf["psnr"], 26.02, 0.01);
    close(&nf["trmse"], 0.0, 1e-4);
    // how far the two references differ: mean square of ±0.1 ∓ 0.1 is 0.02 (17.0 dB)
    close(&nf["reference_psnr"], 16.99, 0.01);
    close(&nf["reference_tmae"], 0.2, 1e-3);
    assert_eq!(v["second_reference"].as_str(), b.to_str());

    // every evaluated frame must be in the second reference
    std::fs::remove_file(b.join("img.0002.exr")).unwrap();
    let out = radn(&[
        "eval",
        "--result",
        result.to_str().unwrap(),
        "--reference",
        a.to_str().unwrap(),
        "--second-reference",
        b.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("has no frame 2"), "{err}");
}

#[test]
fn eval_without_common_frames_is_an_error() {
    let d = tempfile::tempdir().unwrap();
    write_seq(&d.path().join("a"), &[1, 2], |_, _| 0.5);
    write_seq(&d.path().join("b"), &[5, 6], |_, _| 0.5);
    let out = radn(&[
        "eval",
        "--result",
        d.path().join("a").to_str().unwrap(),
        "--reference",
        d.path().join("b").to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no frame number is in both"));
}

#[test]
fn html_report_shows_every_sequence_with_crops_weights_and_the_metric_table() {
    let d = tempfile::tempdir().unwrap();
    let sample = sample();
    let sample = sample.to_str().unwrap();
    let report = d.path().join("report");
    let out = radn_ok(&[
        "eval",
        "--html",
        report.to_str().unwrap(),
        "--result",
        &format!("{sample}/high"),
        "--name",
        "thirty-two",
        "--compare",
        &format!("four={sample}/low"),
        "--reference",
        &format!("{sample}/ref"),
        "--input",
        &format!("{sample}/low/frame_####.exr"),
        "--frames",
        "3-7",
    ]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("index.html"));
    let html = std::fs::read_to_string(report.join("index.html")).unwrap();
    for needle in ["thirty-two", "four", "<svg", "PSNR", "tMAE", "weight_4.png"] {
        assert!(html.contains(needle), "{needle} missing from the report");
    }
    // the 32-spp render is closer to the reference than the 4-spp one: its PSNR cell is the best
    let row = |name: &str| {
        let i = html.find(&format!(">{name}</td>")).unwrap();
        html[i..].split("</tr>").next().unwrap().to_string()
    };
    assert!(row("thirty-two").contains("class=\"best\""));
    assert!(!row("four").contains("class=\"best\""));
    // every image the page names exists and decodes as PNG
    let mut n = 0;
    for part in html.split("src=\"").skip(1) {
        let src = part.split('"').next().unwrap();
        let bytes = std::fs::read(report.join(src)).unwrap();
        let dec = png::Decoder::new(std::io::Cursor::new(bytes));
        let info = dec.read_info().unwrap();
        assert!(info.info().width > 0, "{src}");
        n += 1;
    }
    // full reference + 2 crops × (2 sequences + reference) + 5 weight maps
    assert_eq!(n, 1 + 2 * 3 + 5);
}
