//! Tests of `frame`.

use super::*;
use crate::io::exr_file::SampleKind;

fn cycles_file(dir: &Path, with_albedo: bool) -> PathBuf {
    let (w, h) = (8, 4);
    let mut ch: Vec<(String, Vec<f32>)> = Vec::new();
    for (layer, comps) in [
        ("Combined", vec!["R", "G", "B", "A"]),
        ("Denoising Normal", vec!["X", "Y", "Z"]),
        ("Vector", vec!["X", "Y", "Z", "W"]),
        ("Depth", vec!["Z"]),
        ("Emit", vec!["R", "G", "B"]),
    ] {
        for (i, c) in comps.iter().enumerate() {
            ch.push((
                format!("ViewLayer.{layer}.{c}"),
                vec![i as f32 + 1.0; w * h],
            ));
        }
    }
    if with_albedo {
        for c in ["R", "G", "B"] {
            ch.push((format!("ViewLayer.Denoising Albedo.{c}"), vec![0.5; w * h]));
        }
    }
    let p = dir.join(if with_albedo {
        "full.exr"
    } else {
        "noalbedo.exr"
    });
    ExrFile::from_channels(&p, w, h, ch, SampleKind::F16)
        .write_atomic(&p)
        .unwrap();
    p
}

#[test]
fn cycles_frame_is_converted_to_internal_motion() {
    let dir = tempfile::tempdir().unwrap();
    let p = cycles_file(dir.path(), true);
    let mut r = FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::DENOISE,
    );
    r.aovs = vec!["Emit".into()];
    let (f, _) = r.read(&p).unwrap();
    // Vector = (1, 2, 3, 4): prev = (X, -Y), next = (-Z, W)
    let mp = f.motion_prev.unwrap();
    let mn = f.motion_next.unwrap();
    assert_eq!((mp.get(0, 0, 0), mp.get(0, 0, 1)), (1.0, -2.0));
    assert_eq!((mn.get(0, 0, 0), mn.get(0, 0, 1)), (-3.0, 4.0));
    assert_eq!(f.alpha.unwrap().get(3, 3, 0), 4.0);
    assert_eq!(
        f.aovs[0].channels,
        vec!["ViewLayer.Emit.R", "ViewLayer.Emit.G", "ViewLayer.Emit.B"]
    );
}

#[test]
fn missing_albedo_names_file_and_preset() {
    let dir = tempfile::tempdir().unwrap();
    let p = cycles_file(dir.path(), false);
    let r = FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::DENOISE,
    );
    let e = r.read(&p).unwrap_err().to_string();
    assert!(
        e.contains("noalbedo.exr") && e.contains("albedo") && e.contains("cycles"),
        "{e}"
    );
    // without the requirement the same file reads
    let r = FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::COLOR_ONLY,
    );
    assert!(r.read(&p).unwrap().0.albedo.is_none());
}
