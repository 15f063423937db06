//! On the Cycles sample that ships in the repository: EXR round trips are bit-exact for every
//! channel radn does not change, and warping side frames onto the centre frame brings them
//! closer to the centre frame's high-sample reference.

use std::path::PathBuf;

use radn_core::align::{align_window, AlignParams};
use radn_core::exr_file::{ExrFile, SampleKind};
use radn_core::frame::{Frame, FrameReader, Requirements};
use radn_core::mapping::ChannelMapping;
use radn_core::metrics::{mse, tonemap_plane};

fn sample(level: &str, frame: i64) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!(
        "../../samples/cycles-sample/{level}/frame_{frame:04}.exr"
    ))
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
        assert_eq!(bits(&back, &n), bits(&src, &n), "{n}");
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
            let want: Vec<f32> = src
                .channel_f32(&n)
                .unwrap()
                .iter()
                .map(|x| x * 0.5)
                .collect();
            // halving a half-float is exact
            assert_eq!(back.channel_f32(&n).unwrap(), want, "{n}");
        } else {
            assert_eq!(bits(&back, &n), bits(&src, &n), "{n} changed");
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
    for k in [0usize, 1, 3, 4] {
        let unwarped = mse(&tonemap_plane(&frames[k].color), &reference);
        let warped = mse(&tonemap_plane(&raw.frames[k].color), &reference);
        let with_mix = mse(&tonemap_plane(&mixed.frames[k].color), &reference);
        eprintln!(
            "offset {:+}: unwarped {unwarped:.6}  warped {warped:.6}  warped+mixed {with_mix:.6}",
            raw.frames[k].offset
        );
        assert!(
            warped < 0.5 * unwarped,
            "offset {}: warped {warped} vs unwarped {unwarped}",
            raw.frames[k].offset
        );
        assert!(
            with_mix <= warped * 1.05,
            "offset {}: mixing made it worse",
            raw.frames[k].offset
        );
    }
}
