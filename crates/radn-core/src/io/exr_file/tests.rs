//! Tests of `exr_file`.

use super::*;

fn ramp(n: usize, k: f32) -> Vec<f32> {
    (0..n).map(|i| i as f32 * k).collect()
}

#[test]
fn a_header_claiming_more_pixels_than_the_file_can_hold_is_refused_before_decoding() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("a.exr");
    let n = 64 * 32;
    ExrFile::from_channels(
        &p,
        64,
        32,
        vec![("Y".into(), ramp(n, 0.5))],
        SampleKind::F32,
    )
    .write_atomic(&p)
    .unwrap();
    assert!(ExrFile::read(&p).is_ok());
    // the data window's maximum corner (x, y) set to 99 999: 10^10 pixels in ~1 kB
    let mut b = std::fs::read(&p).unwrap();
    let key = b"dataWindow\0box2i\0";
    let at = b.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
    for k in [8, 12] {
        b[at + k..at + k + 4].copy_from_slice(&99_999i32.to_le_bytes());
    }
    let q = d.path().join("damaged.exr");
    std::fs::write(&q, &b).unwrap();
    for e in [
        ExrFile::read(&q).err().unwrap(),
        ExrFile::read_size(&q).err().unwrap(),
        ExrFile::read_rows(&q, 0..4).err().unwrap(),
    ] {
        let e = e.to_string();
        assert!(
            e.contains("damaged.exr") && e.contains("header claims 100000x100000"),
            "{e}"
        );
    }
}

#[test]
fn set_channel_adds_and_replaces() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("a.exr");
    let mut f =
        ExrFile::from_channels(&p, 4, 3, vec![("R".into(), ramp(12, 1.0))], SampleKind::F16);
    f.set_channel("R", &ramp(12, 0.5), SampleKind::F32);
    f.set_channel("denoised.R", &ramp(12, 2.0), SampleKind::F32);
    assert_eq!(f.channel_kind("R"), Some(SampleKind::F16));
    assert_eq!(f.channel_kind("denoised.R"), Some(SampleKind::F32));
    f.write_atomic(&p).unwrap();
    let g = ExrFile::read(&p).unwrap();
    assert_eq!(
        g.channel_names(),
        vec!["R".to_string(), "denoised.R".to_string()]
    );
    assert_eq!(g.channel_f32("R").unwrap()[3], 1.5);
    assert_eq!(g.channel_f32("denoised.R").unwrap()[11], 22.0);
    // no temporary file is left behind
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[cfg(unix)]
#[test]
fn written_files_get_the_permissions_of_a_plainly_created_file() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let plain = dir.path().join("plain");
    std::fs::write(&plain, b"x").unwrap();
    let p = dir.path().join("a.exr");
    ExrFile::from_channels(&p, 2, 2, vec![("R".into(), ramp(4, 1.0))], SampleKind::F32)
        .write_atomic(&p)
        .unwrap();
    let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    // not tempfile's private 0600: other users of a farm must read the result
    assert_eq!(mode(&p), mode(&plain));
}

#[test]
fn not_an_exr_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("x.exr");
    std::fs::write(&p, b"hello world, not an image").unwrap();
    let e = ExrFile::read(&p).unwrap_err().to_string();
    assert!(e.contains("x.exr") && e.contains("not an OpenEXR"), "{e}");
}

#[test]
fn truncated_exr_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("t.exr");
    ExrFile::from_channels(
        &p,
        64,
        64,
        vec![("R".into(), ramp(4096, 0.1))],
        SampleKind::F32,
    )
    .write_atomic(&p)
    .unwrap();
    let bytes = std::fs::read(&p).unwrap();
    std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
    let e = ExrFile::read(&p).unwrap_err().to_string();
    assert!(
        e.contains("t.exr") && (e.contains("truncated") || e.contains("corrupt")),
        "{e}"
    );
}
