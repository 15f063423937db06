//! `radn denoise --method spatial`: OIDN's U-Net run by radn from the compiled-in weights, with
//! no OIDN library (`RADN_OIDN_LIBRARY=/nonexistent`), equals OIDN's own result: the default
//! (noisy auxiliaries) equals OIDN's beauty filter on the rendered auxiliaries, and
//! `--prefilter` equals OIDN-prefiltered (its albedo and normal filters, then the clean-aux
//! beauty), at OIDN's autoexposure, on the Cycles sample. `radn model import-oidn` refuses bad
//! libraries and names without writing anything.
//!
//! The comparisons need an OIDN 2.x library; without one they say so and pass, unless
//! `RADN_REQUIRE_OIDN=1` (set by `scripts/test`).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{radn_ok, tall};
use radn_core::io::exr_file::ExrFile;

use radn_core::eval::metrics::psnr;
use radn_core::guide::{GuideFilters, OidnDenoiser, OidnSettings};
use radn_core::io::frame::{FrameReader, Requirements};
use radn_core::io::mapping::ChannelMapping;

fn sample(frame: i64) -> PathBuf {
    PathBuf::from(format!(
        "../../samples/cycles-sample/low/frame_{frame:04}.exr"
    ))
}

fn read(path: &Path) -> radn_core::io::frame::Frame {
    FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::DENOISE,
    )
    .read(path)
    .unwrap()
    .0
}

/// Runs `radn denoise --method spatial` on frames 3-4 of the sample without any OIDN library.
fn spatial(out: &Path, extra: &[&str]) {
    let r = Command::new(env!("CARGO_BIN_EXE_radn"))
        .env("RADN_OIDN_LIBRARY", "/nonexistent")
        .args([
            "denoise",
            "-i",
            "../../samples/cycles-sample/low/frame_####.exr",
            "-o",
        ])
        .arg(out.join("frame_####.exr"))
        .args(["--frames", "3-4", "--method", "spatial"])
        .args(extra)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(String::from_utf8_lossy(&r.stdout).contains("spatial path"));
}

#[test]
fn the_spatial_method_runs_without_a_library_and_equals_oidn() {
    let d = tempfile::tempdir().unwrap();
    let (plain, pre) = (d.path().join("plain"), d.path().join("pre"));
    spatial(&plain, &[]);
    spatial(&pre, &["--prefilter"]);
    let mut oidn = match OidnDenoiser::new(2) {
        Ok(o) => o,
        Err(e) if std::env::var_os("RADN_REQUIRE_OIDN").is_none() => {
            eprintln!("SKIPPED: no OIDN to compare with: {e}");
            return;
        }
        Err(e) => panic!("RADN_REQUIRE_OIDN is set but OIDN does not open: {e}"),
    };
    for frame in [3, 4] {
        let f = read(&sample(frame));
        let (a, n) = (f.albedo.as_ref(), f.normal.as_ref());
        let noisy_aux = oidn
            .beauty(&f.color, a, n, radn_core::guide::OidnQuality::High, false)
            .unwrap();
        let prefiltered = oidn
            .denoise_frame(&f.color, a, n, &OidnSettings::default())
            .unwrap()
            .0;
        for (dir, want, what) in [
            (&plain, noisy_aux, "noisy aux"),
            (&pre, prefiltered, "prefiltered"),
        ] {
            let got = read(&dir.join(format!("frame_{frame:04}.exr"))).color;
            let db = psnr(&got, &want).unwrap();
            eprintln!("frame {frame}, {what}: {db:.1} dB against OIDN");
            assert!(db >= 60.0, "frame {frame}, {what}: {db:.1} dB");
        }
    }
}

#[test]
fn band_by_band_equals_whole_frames_bit_for_bit() {
    // a 176×300 sequence with AOVs and alpha; bands of 16 and 64 rows cut it far inside the
    // networks' reach (96 and 112 rows), so each band reads only part of the frame; the
    // prefiltered path cleans the auxiliaries band by band before the beauty, with their own
    // halo. Every denoised channel must equal the whole frame's exactly.
    let d = tempfile::tempdir().unwrap();
    let input = tall(d.path());
    let run = |name: &str, extra: &[&str]| -> ExrFile {
        let out = format!("{}/{name}/f_####.exr", d.path().display());
        let mut args = vec![
            "denoise",
            "-i",
            &input,
            "-o",
            &out,
            "--frames",
            "4-4",
            "--method",
            "spatial",
            "--aovs",
            "diffuse,specular",
        ];
        args.extend(extra);
        radn_ok(&args);
        ExrFile::read(out.replace("####", "0004")).unwrap()
    };
    for (path, rows) in [(&[][..], "16"), (&["--prefilter"][..], "64")] {
        let whole = run(
            &format!("whole{}", path.len()),
            &[path, &["--bands", "never"]].concat(),
        );
        let banded = run(
            &format!("banded{}", path.len()),
            &[path, &["--bands", rows]].concat(),
        );
        let mut compared = 0;
        for layer in ["Combined", "diffuse", "specular"] {
            for c in ["R", "G", "B", "A"] {
                let name = format!("ViewLayer.{layer}.{c}");
                let (Some(x), Some(y)) = (whole.channel_f32(&name), banded.channel_f32(&name))
                else {
                    continue;
                };
                let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
                assert!(
                    bits(&x) == bits(&y),
                    "{path:?} --bands {rows}: {name} differs from the whole frame's"
                );
                compared += x.len();
            }
        }
        assert!(compared >= 9 * 176 * 300, "{compared}");
    }
}

#[test]
fn import_errors_are_one_line_and_write_nothing() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("m.safetensors");
    let not_oidn = d.path().join("libfoo.so");
    std::fs::write(&not_oidn, b"\x7fELF\x02\x01\x01 truncated").unwrap();
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec![not_oidn.display().to_string()],
            "not an OIDN 2.x core library",
        ),
        (vec!["/nonexistent/lib.so".into()], "cannot read"),
    ];
    for (args, want) in cases {
        let r = Command::new(env!("CARGO_BIN_EXE_radn"))
            .args(["model", "import-oidn"])
            .args(&args)
            .arg("-o")
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success() && err.contains(want), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(!err.contains("panicked"), "{err}");
        assert!(!out.exists());
    }
    // an unknown name in the real library, where there is one
    if OidnDenoiser::new(1).is_ok() {
        let r = Command::new(env!("CARGO_BIN_EXE_radn"))
            .args(["model", "import-oidn", "--weights", "rt_nothing", "-o"])
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(
            !r.status.success() && err.contains("no OIDN weights named 'rt_nothing'"),
            "{err}"
        );
        assert!(!out.exists());
        // and a good one, shown back by `radn model`
        let r = Command::new(env!("CARGO_BIN_EXE_radn"))
            .args(["model", "import-oidn", "--weights", "rt_nrm", "-o"])
            .arg(&out)
            .output()
            .unwrap();
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        let r = Command::new(env!("CARGO_BIN_EXE_radn"))
            .arg("model")
            .arg(&out)
            .output()
            .unwrap();
        let shown = String::from_utf8_lossy(&r.stdout);
        assert!(
            shown.contains("rt_nrm") && shown.contains("standard"),
            "{shown}"
        );
    }
}
