//! Files of every EXR layout radn reads, written for tests across the crate.

use super::*;

/// A two-part file: a tiled f16 "beauty" part with RGB and a scanline f32 "aux" part.
pub(crate) fn multipart(path: &Path) {
    let size = Vec2(40, 24);
    let rgb = |k: f32| -> SmallVecChannels {
        ["B", "G", "R"]
            .iter()
            .enumerate()
            .map(|(i, n)| {
                let v: Vec<f16> = (0..40 * 24)
                    .map(|p| f16::from_f32(k * (p % 13) as f32 + i as f32))
                    .collect();
                AnyChannel::new(Text::from(*n), FlatSamples::F16(v))
            })
            .collect()
    };
    let beauty = Layer::new(
        size,
        LayerAttributes::named("beauty"),
        Encoding {
            compression: Compression::PIZ,
            blocks: Blocks::Tiles(Vec2(16, 16)),
            line_order: LineOrder::Unspecified,
        },
        AnyChannels::sort(rgb(0.5)),
    );
    let z: Vec<f32> = (0..40 * 24).map(|p| 1.0 + p as f32).collect();
    let aux = Layer::new(
        size,
        LayerAttributes::named("aux"),
        Encoding {
            compression: Compression::ZIP16,
            blocks: Blocks::ScanLines,
            line_order: LineOrder::Increasing,
        },
        AnyChannels::sort(
            std::iter::once(AnyChannel::new(Text::from("Z"), FlatSamples::F32(z))).collect(),
        ),
    );
    let image: FlatImage = Image {
        attributes: ImageAttributes::new(IntegerBounds::from_dimensions(size)),
        layer_data: [beauty, aux].into_iter().collect(),
    };
    image.write().to_file(path).unwrap();
}

type SmallVecChannels = exr::prelude::SmallVec<[AnyChannel<FlatSamples>; 4]>;

#[test]
fn reading_rows_gives_those_rows_of_every_part() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("mp.exr");
    multipart(&p);
    let whole = ExrFile::read(&p).unwrap();
    // bands that cut 16-pixel tiles and 16-line ZIP blocks in the middle, and the last row
    for rows in [0..24, 5..21, 15..17, 23..24] {
        let band = ExrFile::read_rows(&p, rows.clone()).unwrap();
        assert_eq!((band.width(), band.height()), (40, rows.len()));
        assert_eq!(band.channel_names(), whole.channel_names());
        for name in whole.channel_names() {
            assert_eq!(band.channel_kind(&name), whole.channel_kind(&name));
            let all = whole.channel_f32(&name).unwrap();
            assert_eq!(
                band.channel_f32(&name).unwrap(),
                all[rows.start * 40..rows.end * 40],
                "{name} rows {rows:?}"
            );
        }
    }
    let err = ExrFile::read_rows(&p, 20..30).unwrap_err().to_string();
    assert!(err.contains("mp.exr") && err.contains("20..30"), "{err}");
}

#[test]
fn multipart_tiled_half_and_scanline_float_read_and_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("mp.exr");
    multipart(&p);
    let f = ExrFile::read(&p).unwrap();
    assert_eq!(
        f.channel_names(),
        vec!["aux.Z", "beauty.B", "beauty.G", "beauty.R"]
    );
    assert_eq!(f.channel_kind("beauty.R"), Some(SampleKind::F16));
    assert_eq!(f.channel_kind("aux.Z"), Some(SampleKind::F32));
    assert_eq!(f.channel_f32("beauty.B").unwrap()[5], 2.5);
    assert_eq!(f.channel_f32("aux.Z").unwrap()[7], 8.0);
    let parts = f.parts();
    assert_eq!(parts[0].tiles, Some((16, 16)));
    assert_eq!(parts[1].tiles, None);
    // replace one channel, add one to a named part: parts and block layout survive
    let mut g = f.clone();
    g.set_channel("beauty.G", &vec![0.25; 40 * 24], SampleKind::F32);
    g.set_channel("aux.confidence", &vec![1.0; 40 * 24], SampleKind::F32);
    let q = dir.path().join("out.exr");
    g.write_atomic(&q).unwrap();
    let h = ExrFile::read(&q).unwrap();
    assert_eq!(
        h.channel_names(),
        vec![
            "aux.Z",
            "aux.confidence",
            "beauty.B",
            "beauty.G",
            "beauty.R"
        ]
    );
    assert_eq!(h.parts()[0].tiles, Some((16, 16)));
    assert_eq!(h.channel_f32("beauty.G").unwrap()[0], 0.25);
    assert_eq!(h.channel_kind("beauty.G"), Some(SampleKind::F16));
    assert_eq!(
        h.channel_f32("beauty.R").unwrap(),
        f.channel_f32("beauty.R").unwrap()
    );
    assert_eq!(
        h.channel_f32("aux.Z").unwrap(),
        f.channel_f32("aux.Z").unwrap()
    );
}
