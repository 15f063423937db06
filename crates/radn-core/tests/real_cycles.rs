//! On the Cycles sample that ships in the repository: EXR round trips are bit-exact for every
//! channel radn does not change, and warping side frames onto the centre frame brings them
//! closer to the centre frame's high-sample reference.

use std::path::PathBuf;

use radn_core::align::{align_window, AlignParams};
use radn_core::eval::metrics::{mse, tonemap_plane};
use radn_core::image::noise_level::NoiseLevelHistogram;
use radn_core::io::exr_file::{ExrFile, SampleKind};
use radn_core::io::frame::{Frame, FrameReader, Requirements};
use radn_core::io::mapping::ChannelMapping;
use radn_core::run::banding::{FrameStats, STATS_ROWS};

fn sample(level: &str, frame: i64) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!(
        "../../samples/cycles-sample/{level}/frame_{frame:04}.exr"
    ))
}

/// Asserts two sample vectors are identical, naming the first difference (not dumping both).
fn assert_same(a: &[u32], b: &[u32], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: lengths differ");
    if let Some(i) = a.iter().zip(b).position(|(x, y)| x != y) {
        panic!(
            "{what}: sample {i} differs ({} vs {})",
            f32::from_bits(a[i]),
            f32::from_bits(b[i])
        );
    }
}

fn bits(f: &ExrFile, name: &str) -> Vec<u32> {
    f.channel_f32(name)
        .unwrap()
        .iter()
        .map(|v| v.to_bits())
        .collect()
}

#[test]
fn round_trip_keeps_every_unchanged_channel_bit_exact() {
    let src = ExrFile::read(sample("low", 5)).unwrap();
    let dir = tempfile::tempdir().unwrap();
    // untouched round trip
    let plain = dir.path().join("plain.exr");
    src.write_atomic(&plain).unwrap();
    let back = ExrFile::read(&plain).unwrap();
    assert_eq!(back.channel_names(), src.channel_names());
    assert_eq!(back.custom_attribute_names(), src.custom_attribute_names());
    for n in src.channel_names() {
        assert_eq!(back.channel_kind(&n), src.channel_kind(&n), "{n}");
        assert_same(&bits(&back, &n), &bits(&src, &n), &n);
    }
    // replace the beauty and add a channel, as denoising does
    let mut edited = src.clone();
    let replaced = [
        "ViewLayer.Combined.R",
        "ViewLayer.Combined.G",
        "ViewLayer.Combined.B",
    ];
    for r in replaced {
        let v: Vec<f32> = src
            .channel_f32(r)
            .unwrap()
            .iter()
            .map(|x| x * 0.5)
            .collect();
        edited.set_channel(r, &v, SampleKind::F32);
    }
    let extra = vec![0.25f32; src.width() * src.height()];
    edited.set_channel("ViewLayer.radn.confidence", &extra, SampleKind::F32);
    let out = dir.path().join("edited.exr");
    edited.write_atomic(&out).unwrap();
    let back = ExrFile::read(&out).unwrap();
    assert_eq!(back.custom_attribute_names(), src.custom_attribute_names());
    for n in src.channel_names() {
        assert_eq!(
            back.channel_kind(&n),
            src.channel_kind(&n),
            "{n} changed type"
        );
        if replaced.contains(&n.as_str()) {
            // the new values, rounded to the channel's own storage type (half)
            let want: Vec<u32> = src
                .channel_f32(&n)
                .unwrap()
                .iter()
                .map(|x| half::f16::from_f32(x * 0.5).to_f32().to_bits())
                .collect();
            assert_same(&bits(&back, &n), &want, &n);
        } else {
            assert_same(&bits(&back, &n), &bits(&src, &n), &n);
        }
    }
    assert_eq!(
        back.channel_f32("ViewLayer.radn.confidence").unwrap(),
        extra
    );
}

fn read_window(level: &str, centre: i64) -> Vec<Frame> {
    let reader = FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::DENOISE,
    );
    (centre - 2..=centre + 2)
        .map(|f| reader.read(&sample(level, f)).unwrap().0)
        .collect()
}

#[test]
fn warping_brings_side_frames_closer_to_the_centre_reference() {
    let reference = FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::COLOR_ONLY,
    )
    .read(&sample("ref", 5))
    .unwrap()
    .0;
    let reference = tonemap_plane(&reference.color);
    let frames = read_window("high", 5);
    let window: Vec<Option<&Frame>> = frames.iter().map(Some).collect();
    let raw = align_window(
        &window,
        &AlignParams {
            mix_centre: false,
            ..AlignParams::default()
        },
    );
    let mixed = align_window(&window, &AlignParams::default());
    let n = reference.pixels();
    // the centre frame's own error: its render noise
    let noise = mse(&tonemap_plane(&frames[2].color), &reference);
    for k in [0usize, 1, 3, 4] {
        let offset = raw.frames[k].offset;
        let unwarped = mse(&tonemap_plane(&frames[k].color), &reference);
        let warped_tm = tonemap_plane(&raw.frames[k].color);
        let warped = mse(&warped_tm, &reference);
        let with_mix = mse(&tonemap_plane(&mixed.frames[k].color), &reference);
        // where confidence is high, the warped frame is as good as a render of the centre frame
        let conf = raw.frames[k].confidence.data();
        let (mut e, mut m) = (0.0f64, 0usize);
        for i in (0..n).filter(|&i| conf[i] > 0.9) {
            for c in 0..3 {
                e += ((warped_tm.data()[c * n + i] - reference.data()[c * n + i]) as f64).powi(2);
            }
            m += 3;
        }
        let confident = e / m as f64;
        eprintln!(
            "offset {offset:+}: unwarped {unwarped:.5} warped {warped:.5} mixed {with_mix:.5}; on {:.0}% confident pixels {confident:.5} (centre noise {noise:.5})",
            100.0 * m as f64 / (3 * n) as f64
        );
        // glass and mirrors (large on this sample) do not move with their surface: over all
        // pixels the gain is modest, on trusted pixels it is complete
        assert!(
            warped < 0.85 * unwarped,
            "offset {offset}: warped {warped} vs unwarped {unwarped}"
        );
        assert!(
            m > n,
            "offset {offset}: fewer than a third of the pixels are trusted"
        );
        assert!(
            confident < 1.25 * noise,
            "offset {offset}: trusted pixels {confident} vs centre noise {noise}"
        );
        assert!(
            with_mix < warped,
            "offset {offset}: centre mixing made it worse"
        );
    }
}

#[test]
fn the_noise_level_falls_with_the_sample_count_and_bands_see_the_whole_frames() {
    let reader = FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::DENOISE,
    );
    let mut last = f32::INFINITY;
    for level in ["low", "half", "high"] {
        let path = sample(level, 5);
        let (frame, _) = reader.read(&path).unwrap();
        let whole = NoiseLevelHistogram::of_frame(&frame.color, frame.albedo.as_ref())
            .level()
            .unwrap();
        // the statistics pass reads 64-row bands (and the sample is 100 rows: one partial)
        let banded = FrameStats::gather(&reader, &path, frame.height(), STATS_ROWS, |_, _| Ok(()))
            .unwrap()
            .noise_level()
            .unwrap();
        assert_eq!(whole, banded, "{level}");
        eprintln!("{level}: noise level {whole:.5}");
        // 4, 11 and 32 spp: each level at least twice below the last
        assert!(whole < 0.5 * last, "{level}: {whole} after {last}");
        last = whole;
    }
}
