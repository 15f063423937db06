//! Intel Open Image Denoise guides (`--guide oidn`) on the Cycles sample: the library opens
//! (from the `pyoidn` wheel `scripts/setup` installs), its prefiltered estimate is far closer
//! to the 1024-spp reference than the noisy frame, and a missing library is a clear error.
//!
//! Without OIDN the quality tests say so and pass, unless `RADN_REQUIRE_OIDN=1` (which
//! `scripts/test` sets, so CI always runs them).

use std::path::PathBuf;
use std::process::Command;

use radn_core::eval::metrics::psnr;
use radn_core::guide::OidnGuides;
use radn_core::io::frame::{FrameReader, Requirements};
use radn_core::io::mapping::ChannelMapping;

fn sample(level: &str, frame: i64) -> PathBuf {
    PathBuf::from(format!(
        "../../samples/cycles-sample/{level}/frame_{frame:04}.exr"
    ))
}

/// The reference's beauty (its files hold only that).
fn reference(frame: i64) -> radn_core::Plane {
    FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::COLOR_ONLY,
    )
    .read(&sample("ref", frame))
    .unwrap()
    .0
    .color
}

fn reader() -> FrameReader {
    FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::DENOISE,
    )
}

/// OIDN with two threads, or `None` (with a message) where it is not installed and the run
/// does not require it.
fn oidn() -> Option<OidnGuides> {
    match OidnGuides::new(2) {
        Ok(g) => Some(g),
        Err(e) if std::env::var_os("RADN_REQUIRE_OIDN").is_none() => {
            eprintln!("SKIPPED: Intel Open Image Denoise is not installed here: {e}");
            None
        }
        Err(e) => panic!("RADN_REQUIRE_OIDN is set but OIDN does not open: {e}"),
    }
}

#[test]
fn the_oidn_guide_is_far_closer_to_the_reference_than_the_noisy_frame() {
    let Some(g) = oidn() else { return };
    let r = reader();
    let reference = reference(5);
    for (level, margin) in [("low", 6.0), ("high", 2.0)] {
        let path = sample(level, 5);
        let noisy = r.read(&path).unwrap().0.color;
        let guide = g.of_file(&r, &path).unwrap();
        assert!(guide.same_size(&noisy) && guide.channels() == 3);
        let (p_noisy, p_guide) = (
            psnr(&noisy, &reference).unwrap(),
            psnr(&guide, &reference).unwrap(),
        );
        eprintln!("{level}: noisy {p_noisy:.2} dB, OIDN guide {p_guide:.2} dB");
        assert!(
            p_guide > p_noisy + margin,
            "{level}: OIDN guide {p_guide:.2} dB vs noisy {p_noisy:.2} dB"
        );
        // the same frame twice gives the same guide (one device, filters kept)
        assert_eq!(g.of_file(&r, &path).unwrap().data(), guide.data());
    }
}

#[test]
fn a_frame_without_auxiliaries_is_still_guided_by_its_beauty_alone() {
    let Some(g) = oidn() else { return };
    let r = reader();
    let (mut frame, _) = r.read(&sample("low", 5)).unwrap();
    frame.albedo = None;
    frame.normal = None;
    let guide = g.of_frame(&frame, &sample("low", 5)).unwrap();
    let reference = reference(5);
    assert!(psnr(&guide, &reference).unwrap() > psnr(&frame.color, &reference).unwrap() + 3.0);
}

#[test]
fn a_missing_oidn_library_is_a_clear_error_saying_what_to_install() {
    // in a child process, so the environment variable is this test's alone
    if std::env::var_os("RADN_OIDN_CHILD").is_some() {
        let e = OidnGuides::new(1)
            .err()
            .expect("the library does not exist");
        println!("ERROR: {e}");
        return;
    }
    let exe = std::env::current_exe().unwrap();
    let out = Command::new(exe)
        .args([
            "a_missing_oidn_library_is_a_clear_error_saying_what_to_install",
            "--exact",
            "--nocapture",
        ])
        .env("RADN_OIDN_CHILD", "1")
        .env("RADN_OIDN_LIBRARY", "/nonexistent/libOpenImageDenoise.so.2")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    let line = text
        .lines()
        .find(|l| l.starts_with("ERROR: "))
        .unwrap_or_else(|| panic!("no error printed: {text}"));
    for needed in [
        "/nonexistent/libOpenImageDenoise.so.2",
        "pyoidn==2.5.1.0",
        "scripts/setup",
        "RADN_OIDN_LIBRARY",
    ] {
        assert!(line.contains(needed), "'{needed}' missing from: {line}");
    }
}
