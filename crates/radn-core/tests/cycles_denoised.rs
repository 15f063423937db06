//! A Cycles render with denoising on and its denoising data stored
//! (`samples/cycles-denoised`, made by `python3 -m radn_datagen scene --seed 7 --out
//! samples/cycles-denoised --frames 1-3 --res 64x48 --levels low --half --cycles-denoise` in
//! `tools/datagen`): the file holds the noisy beauty as `Noisy Image` and Cycles' own OIDN result
//! as `Combined`. radn denoises the noisy one and reads the other as the guide, never the
//! reverse; results are written into both.

use std::path::PathBuf;

use radn_core::io::exr_file::ExrFile;
use radn_core::io::frame::{FrameReader, GuideLayer, Requirements};
use radn_core::io::mapping::ChannelMapping;
use radn_core::Error;

fn denoised_sample(frame: i64) -> PathBuf {
    PathBuf::from(format!(
        "../../samples/cycles-denoised/low/frame_{frame:04}.exr"
    ))
}

fn reader(guide: GuideLayer) -> FrameReader {
    let mut r = FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::DENOISE,
    );
    r.guide = guide;
    r
}

/// Mean absolute difference between horizontally neighbouring pixels: how grainy a plane is.
fn roughness(p: &radn_core::Plane) -> f64 {
    let (w, h) = (p.width(), p.height());
    let mut s = 0.0;
    for c in 0..p.channels() {
        for y in 0..h {
            for x in 1..w {
                s += (p.get(x, y, c) - p.get(x - 1, y, c)).abs() as f64;
            }
        }
    }
    s / (p.channels() * h * (w - 1)) as f64
}

#[test]
fn the_noisy_image_is_denoised_and_cycles_combined_is_the_guide() {
    let path = denoised_sample(2);
    let file = ExrFile::read(&path).unwrap();
    let (frame, _) = reader(GuideLayer::Denoised).read(&path).unwrap();
    assert_eq!(
        frame.color_channels,
        ["R", "G", "B"].map(|c| format!("ViewLayer.Noisy Image.{c}"))
    );
    assert_eq!(
        frame.denoised_channels.as_deref().unwrap(),
        ["R", "G", "B"].map(|c| format!("ViewLayer.Combined.{c}"))
    );
    let guide = frame
        .guide
        .as_ref()
        .expect("the denoised layer is read as the guide");
    for c in 0..3 {
        let rgb = ["R", "G", "B"][c];
        let noisy = file
            .channel_f32(&format!("ViewLayer.Noisy Image.{rgb}"))
            .unwrap();
        let combined = file
            .channel_f32(&format!("ViewLayer.Combined.{rgb}"))
            .unwrap();
        assert_eq!(frame.color.channel(c), noisy.as_slice());
        assert_eq!(guide.channel(c), combined.as_slice());
    }
    // Cycles' OIDN result is the smooth one: the 4-spp noisy beauty is several times grainier
    let (noisy, smooth) = (roughness(&frame.color), roughness(guide));
    assert!(
        noisy > 2.0 * smooth,
        "noisy {noisy:.4} vs denoised {smooth:.4}"
    );
    // without asking for a guide nothing more is read, but results still go to both layers
    let (plain, _) = reader(GuideLayer::None).read(&path).unwrap();
    assert!(plain.guide.is_none());
    assert_eq!(plain.denoised_channels, frame.denoised_channels);
}

#[test]
fn a_named_guide_layer_is_read_and_the_beauty_itself_is_refused() {
    let path = denoised_sample(1);
    let (frame, _) = reader(GuideLayer::Layer("Combined".into()))
        .read(&path)
        .unwrap();
    let file = ExrFile::read(&path).unwrap();
    assert_eq!(
        frame.guide.unwrap().channel(0),
        file.channel_f32("ViewLayer.Combined.R").unwrap().as_slice()
    );
    let e = reader(GuideLayer::Layer("Noisy Image".into()))
        .read(&path)
        .unwrap_err();
    assert!(
        matches!(e, Error::Unsupported { .. }) && e.to_string().contains("frame_0001.exr"),
        "{e}"
    );
    let e = reader(GuideLayer::Layer("NoSuchLayer".into()))
        .read(&path)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("frame_0001.exr") && e.contains("NoSuchLayer"),
        "{e}"
    );
}

#[test]
fn a_file_without_denoising_data_has_no_denoised_guide_and_says_so() {
    let path = PathBuf::from("../../samples/cycles-sample/low/frame_0003.exr");
    let (frame, _) = reader(GuideLayer::None).read(&path).unwrap();
    // Combined is the noisy beauty here, and no other layer is a denoised one
    assert!(frame.color_channels[0].contains("Combined"));
    assert!(frame.denoised_channels.is_none());
    let e = reader(GuideLayer::Denoised)
        .read(&path)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("frame_0003.exr") && e.contains("denoised beauty") && e.contains("Combined"),
        "{e}"
    );
}
