//! Intel Open Image Denoise guides (`--guide oidn`) on the Cycles sample: the library opens
//! (from the `pyoidn` wheel `scripts/setup` installs), its prefiltered estimate is far closer
//! to the 1024-spp reference than the noisy frame, and a missing library is a clear error.
//!
//! Without OIDN the quality tests say so and pass, unless `RADN_REQUIRE_OIDN=1` (which
//! `scripts/test` sets, so CI always runs them).

use std::path::PathBuf;
use std::process::Command;

use radn_core::eval::metrics::psnr;
use radn_core::guide::{GuideFilters, OidnDenoiser, OidnDevice, OidnGuides, OidnSettings};
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

/// OIDN's final-frame guide of frame `f` (prefiltered auxiliaries, then the beauty).
fn final_frame(d: &mut OidnDenoiser, f: &radn_core::io::frame::Frame) -> radn_core::Plane {
    d.denoise_frame(
        &f.color,
        f.albedo.as_ref(),
        f.normal.as_ref(),
        &OidnSettings::default(),
    )
    .unwrap()
    .0
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

/// The sample's frame 5 stacked `k` times vertically (beauty, albedo, normal): a frame tall
/// enough for guide bands with OIDN's halo.
fn tall_frame(k: usize) -> radn_core::Frame {
    let (mut f, _) = reader().read(&sample("low", 5)).unwrap();
    let stack = |p: &radn_core::Plane| {
        radn_core::Plane::from_fn(p.width(), p.height() * k, p.channels(), |x, y, c| {
            p.get(x, y % p.height(), c)
        })
    };
    f.albedo = f.albedo.as_ref().map(stack);
    f.normal = f.normal.as_ref().map(stack);
    f.color = stack(&f.color);
    // only the guide's inputs are stacked
    f.alpha = None;
    f.depth = None;
    f.motion_prev = None;
    f.motion_next = None;
    f.aovs.clear();
    f
}

#[test]
fn a_guide_made_in_bands_matches_the_whole_frames() {
    let Some(g) = oidn() else { return };
    let f = tall_frame(6);
    let (w, h) = (f.color.width(), f.color.height());
    let path = sample("low", 5);
    let whole = g.of_frame(&f, &path).unwrap();
    let mut bands: Vec<(usize, radn_core::Plane)> = Vec::new();
    g.of_rows_in(
        &path,
        (w, h),
        64,
        &mut |rows| Ok(f.rows(rows)),
        &mut |y0, band| {
            bands.push((y0, band.clone()));
            Ok(())
        },
    )
    .unwrap();
    assert_eq!(bands.len(), h.div_ceil(64));
    let banded = radn_core::Plane::from_fn(w, h, 3, |x, y, c| {
        let (y0, b) = &bands[y / 64];
        b.get(x, y - y0, c)
    });
    // OIDN's own tiles differ from one whole-image pass by this much; a band filtered at its
    // own exposure or without the halo would differ by far more (tens of dB lower)
    if std::env::var_os("RADN_DEBUG_ROWS").is_some() {
        for y in 0..h {
            let m = (0..w)
                .map(|x| (banded.get(x, y, 0) - whole.get(x, y, 0)).abs())
                .fold(0.0f32, f32::max);
            eprintln!("row {y}: {m}");
        }
    }
    let p = psnr(&banded, &whole).unwrap();
    eprintln!("banded vs whole guide: {p:.1} dB");
    assert!(p > 60.0, "banded guide {p:.1} dB from the whole frame's");
    // and the next whole-frame guide is OIDN's own again (exposure and memory reset)
    assert_eq!(g.of_frame(&f, &path).unwrap().data(), whole.data());
}

#[test]
fn cheaper_guide_settings_change_the_guide_and_stay_far_better_than_the_noisy_frame() {
    use radn_core::guide::{OidnQuality, OidnSettings, Prefilter};
    let Some(g) = oidn() else { return };
    let r = reader();
    let path = sample("low", 5);
    let (frame, _) = r.read(&path).unwrap();
    let reference = reference(5);
    let full = g.of_frame(&frame, &path).unwrap();
    let p_noisy = psnr(&frame.color, &reference).unwrap();
    for settings in [
        OidnSettings {
            quality: OidnQuality::High,
            prefilter: Prefilter::Off,
        },
        OidnSettings {
            quality: OidnQuality::Balanced,
            prefilter: Prefilter::Balanced,
        },
    ] {
        g.configure(settings);
        let cheap = g.of_frame(&frame, &path).unwrap();
        assert_ne!(cheap.data(), full.data(), "{settings}");
        let p = psnr(&cheap, &reference).unwrap();
        eprintln!("{settings}: {p:.2} dB (noisy {p_noisy:.2} dB)");
        assert!(p > p_noisy + 6.0, "{settings}: {p:.2} dB");
    }
    g.configure(OidnSettings::default());
    assert_eq!(g.of_frame(&frame, &path).unwrap().data(), full.data());
}

#[test]
fn images_copied_through_oidn_buffers_give_the_shared_images_result() {
    // a GPU that cannot read the process's memory gets its images through OIDN buffers; on
    // the CPU both ways must give the same guide, bit for bit
    if oidn().is_none() {
        return;
    }
    let mut d = OidnDenoiser::new(2).unwrap();
    let (f, _) = reader().read(&sample("low", 5)).unwrap();
    let shared = final_frame(&mut d, &f);
    d.copy_images(true);
    let copied = final_frame(&mut d, &f);
    assert_eq!(copied.data(), shared.data());
    assert!(psnr(&copied, &reference(5)).unwrap() > psnr(&f.color, &reference(5)).unwrap() + 6.0);
}

#[test]
fn oidn_on_a_gpu_agrees_with_the_cpu_or_says_why_it_cannot_run() {
    if oidn().is_none() {
        return;
    }
    let (f, _) = reader().read(&sample("low", 5)).unwrap();
    match OidnDenoiser::on(OidnDevice::Cuda(0), 0) {
        Ok(mut gpu) => {
            // a machine with an NVIDIA GPU: the same estimate within OIDN's GPU/CPU tolerance
            let on_gpu = final_frame(&mut gpu, &f);
            let on_cpu = final_frame(&mut OidnDenoiser::new(2).unwrap(), &f);
            let agree = psnr(&on_gpu, &on_cpu).unwrap();
            eprintln!("OIDN on the GPU against the CPU: {agree:.1} dB");
            assert!(agree > 45.0, "GPU and CPU guides differ: {agree:.1} dB");
        }
        Err(e) => {
            // without one (CI): a clear error naming the device and what it needs
            let text = e.to_string();
            eprintln!("no GPU here: {text}");
            for needed in ["CUDA GPU 0", "libOpenImageDenoise_device_cuda", "driver"] {
                assert!(text.contains(needed), "'{needed}' missing from: {text}");
            }
        }
    }
}
