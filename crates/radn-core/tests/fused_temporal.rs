//! The temporal pass fused with a whole-frame denoising pass ([`radn_core::run::fused`]) writes
//! what the two passes write one after the other, bit for bit, on the Cycles sample (every
//! channel of every output, AOVs and alpha included); a resumed fused run makes the missing
//! outputs as a whole run does; and a frame range reads the neighbours beyond it.

use std::path::{Path, PathBuf};

use radn_core::io::exr_file::{ExrFile, SampleKind};
use radn_core::io::frame::{Frame, FrameReader, Requirements};
use radn_core::io::mapping::ChannelMapping;
use radn_core::io::sequence::SequencePattern;
use radn_core::run::denoiser::{Denoised, WindowDenoiser};
use radn_core::run::job::Bands;
use radn_core::{DenoiseRun, Plane, TemporalStabilizer};

/// A stand-in for the network: the mean of the window's frames as they are (unaligned), so
/// each result depends on every frame of its window.
struct WindowMean;

impl WindowDenoiser for WindowMean {
    fn radius(&self) -> usize {
        2
    }

    fn denoise(&self, window: &[Option<&Frame>]) -> radn_core::Result<Denoised> {
        let frames: Vec<&Frame> = window.iter().flatten().copied().collect();
        let mean = |pick: &dyn Fn(&Frame) -> &Plane| {
            let first = pick(frames[0]);
            Plane::from_fn(
                first.width(),
                first.height(),
                first.channels(),
                |x, y, c| {
                    frames.iter().map(|f| pick(f).get(x, y, c)).sum::<f32>() / frames.len() as f32
                },
            )
        };
        let centre = window[self.radius()].expect("a centre");
        Ok(Denoised {
            color: mean(&|f| &f.color),
            alpha: centre.alpha.clone(),
            aovs: (0..centre.aovs.len())
                .map(|k| mean(&|f| &f.aovs[k].plane))
                .collect(),
        })
    }
}

/// The sample's 4-spp frames 1-9 in `dir`, each with an AOV layer of its own (`DiffCol`, a
/// tinted copy of the beauty) beside the renderer's.
fn sequence(dir: &Path) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    for f in 1..=9 {
        let mut file =
            ExrFile::read(format!("../../samples/cycles-sample/low/frame_{f:04}.exr")).unwrap();
        for (c, tint) in [("R", 0.5f32), ("G", 0.7), ("B", 0.9)] {
            let v: Vec<f32> = file
                .channel_f32(&format!("ViewLayer.Combined.{c}"))
                .unwrap()
                .iter()
                .map(|x| x * tint)
                .collect();
            file.set_channel(&format!("ViewLayer.DiffCol.{c}"), &v, SampleKind::F16);
        }
        file.write_atomic(dir.join(format!("frame_{f:04}.exr")))
            .unwrap();
    }
    dir.join("frame_####.exr")
}

fn run(out: &Path, frames: Vec<i64>, fuse: bool) {
    run_in(out, frames, fuse, Bands::Never)
}

fn run_in(out: &Path, frames: Vec<i64>, fuse: bool, bands: Bands) {
    let mut reader = FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::DENOISE,
    );
    reader.aovs = vec!["DiffCol".into()];
    let run = DenoiseRun {
        input: SequencePattern::parse(
            sequence(&out.parent().unwrap().join("in"))
                .to_str()
                .unwrap(),
        )
        .unwrap(),
        output: SequencePattern::parse(out.join("f_####.exr").to_str().unwrap()).unwrap(),
        frames,
        reader,
        overwrite: false,
        output_kind: None,
        passes: 1,
        oidn: None,
        bands,
        stabilize: Some(TemporalStabilizer {
            band_rows: 16,
            ..TemporalStabilizer::new(0.3, 0.0005, 2)
        }),
        fuse_temporal: fuse,
        motion: radn_core::run::motion::MotionChoice::Auto,
    };
    let report = run.run(&WindowMean, |_| {}).unwrap();
    assert!(report.written > 0);
}

/// Every channel of every part of `path`, by name.
fn channels(path: &Path) -> Vec<(String, Vec<f32>)> {
    let f = ExrFile::read(path).unwrap();
    f.channel_names()
        .into_iter()
        .map(|n| {
            let v = f.channel_f32(&n).unwrap_or_else(|| panic!("{n}"));
            (n, v)
        })
        .collect()
}

fn outputs(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "exr"))
        .collect();
    v.sort();
    v
}

#[test]
fn a_fused_temporal_pass_writes_what_two_passes_write() {
    let d = tempfile::tempdir().unwrap();
    let (fused, passes) = (d.path().join("fused"), d.path().join("passes"));
    run(&fused, (3..=7).collect(), true);
    run(&passes, (3..=7).collect(), false);
    let (a, b) = (outputs(&fused), outputs(&passes));
    assert_eq!(a.len(), 5);
    assert_eq!(
        a.iter().map(|p| p.file_name()).collect::<Vec<_>>(),
        b.iter().map(|p| p.file_name()).collect::<Vec<_>>()
    );
    for (x, y) in a.iter().zip(&b) {
        let (cx, cy) = (channels(x), channels(y));
        assert!(
            cx.iter().any(|(n, _)| n.contains("DiffCol")),
            "the AOV is written"
        );
        assert_eq!(cx.len(), cy.len(), "{}", x.display());
        for ((n, u), (m, v)) in cx.iter().zip(&cy) {
            assert_eq!(n, m);
            assert!(
                u.iter().zip(v).all(|(p, q)| p.to_bits() == q.to_bits()),
                "{}: channel {n} differs",
                x.display()
            );
        }
    }
    // the temporal pass did something: the result is not the window mean alone
    let unstabilized = d.path().join("plain");
    let mut reader = FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::DENOISE,
    );
    reader.aovs = vec!["DiffCol".into()];
    DenoiseRun {
        input: SequencePattern::parse(d.path().join("in/frame_####.exr").to_str().unwrap())
            .unwrap(),
        output: SequencePattern::parse(unstabilized.join("f_####.exr").to_str().unwrap()).unwrap(),
        frames: vec![5],
        reader,
        overwrite: false,
        output_kind: None,
        passes: 1,
        oidn: None,
        bands: Bands::Never,
        stabilize: None,
        fuse_temporal: true,
        motion: radn_core::run::motion::MotionChoice::Auto,
    }
    .run(&WindowMean, |_| {})
    .unwrap();
    let key = |c: &[(String, Vec<f32>)]| {
        c.iter()
            .find(|(n, _)| n.ends_with("Combined.R"))
            .unwrap()
            .1
            .clone()
    };
    assert_ne!(
        key(&channels(&unstabilized.join("f_0005.exr"))),
        key(&channels(&fused.join("f_0005.exr")))
    );
}

#[test]
fn a_resumed_fused_run_makes_the_missing_outputs_as_a_whole_run_does() {
    let d = tempfile::tempdir().unwrap();
    let whole = d.path().join("whole");
    run(&whole, (2..=8).collect(), true);
    let resumed = d.path().join("resumed");
    run(&resumed, (2..=8).collect(), true);
    for f in [2, 5, 6, 8] {
        std::fs::remove_file(resumed.join(format!("f_{f:04}.exr"))).unwrap();
    }
    run(&resumed, (2..=8).collect(), true);
    // and a range alone reads its neighbours: frames 5-6 as in the whole run
    let range = d.path().join("range");
    run(&range, vec![5, 6], true);
    for (dir, frames) in [(&resumed, vec![2, 5, 6, 8]), (&range, vec![5, 6])] {
        for f in frames {
            let name = format!("f_{f:04}.exr");
            assert_eq!(
                channels(&dir.join(&name)),
                channels(&whole.join(&name)),
                "{}",
                dir.join(&name).display()
            );
        }
    }
}

#[test]
fn the_temporal_pass_band_by_band_equals_it_on_whole_frames() {
    let d = tempfile::tempdir().unwrap();
    let (banded, whole) = (d.path().join("banded"), d.path().join("whole"));
    // pass after pass: the stand-in pass runs whole frames, the temporal pass band by band
    run_in(&banded, (3..=7).collect(), false, Bands::Always);
    assert!(
        radn_core::run::timing::take()
            .iter()
            .any(|(stage, _)| *stage == "reading bands"),
        "the temporal pass ran band by band"
    );
    run(&whole, (3..=7).collect(), true);
    for f in 3..=7 {
        let name = format!("f_{f:04}.exr");
        for ((n, u), (m, v)) in channels(&banded.join(&name))
            .iter()
            .zip(&channels(&whole.join(&name)))
        {
            assert_eq!(n, m);
            let worst = u
                .iter()
                .zip(v)
                .map(|(p, q)| (p - q).abs() / q.abs().max(1.0))
                .fold(0.0f32, f32::max);
            assert!(worst < 1e-3, "{name} {n}: {worst}");
        }
    }
}
