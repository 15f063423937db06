//! Motion without the renderer's vectors: `--motion estimate` (and `auto` on files without
//! vectors) finds motion from the frames and scores near the renderer's vectors; a cut is
//! found, said, and no window reaches across it; bands equal whole frames; `--motion renderer`
//! on files without vectors is an error naming the file.

mod common;

use std::path::Path;

use radn_core::eval::metrics::psnr;
use radn_core::io::exr_file::{ExrFile, SampleKind};

/// What a test sequence keeps of the renderer's motion vectors.
#[derive(Clone, Copy, PartialEq)]
enum Vectors {
    Kept,
    Dropped,
    /// All zero, as Cycles writes them with motion blur on.
    Zeroed,
}

/// Writes `dir/frame_{i+1:04}.exr` for each `(sample frame, mirrored)` of `frames`: the
/// sample's 4-spp frame, mirrored left to right where asked (motion's x components negated),
/// its motion vectors as `vectors` says.
fn sequence(dir: &Path, frames: &[(usize, bool)], vectors: Vectors) {
    for (i, &(src, mirror)) in frames.iter().enumerate() {
        let f = ExrFile::read(common::sample().join(format!("low/frame_{src:04}.exr"))).unwrap();
        write_frame(
            &f,
            &dir.join(format!("frame_{:04}.exr", i + 1)),
            mirror,
            vectors,
        );
    }
}

/// The sample's reference of `src`, mirrored where asked.
fn reference(src: usize, mirror: bool) -> radn_core::Plane {
    let f = ExrFile::read(common::sample().join(format!("ref/frame_{src:04}.exr"))).unwrap();
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("r.exr");
    write_frame(&f, &p, mirror, Vectors::Kept);
    common::beauty_rgb(&ExrFile::read(&p).unwrap())
}

fn write_frame(f: &ExrFile, path: &Path, mirror: bool, vectors: Vectors) {
    let (w, h) = (f.width(), f.height());
    let channels = f
        .channel_names()
        .into_iter()
        .filter(|n| vectors != Vectors::Dropped || !n.contains(".Vector."))
        .map(|n| {
            let mut v = f.channel_f32(&n).unwrap();
            if vectors == Vectors::Zeroed && n.contains(".Vector.") {
                v.iter_mut().for_each(|x| *x = 0.0);
            }
            if mirror {
                for row in v.chunks_mut(w) {
                    row.reverse();
                }
                // x components of motion and normals change sign in a mirror image
                if n.ends_with("Vector.X") || n.ends_with("Vector.Z") || n.ends_with("Normal.X") {
                    v.iter_mut().for_each(|x| *x = -*x);
                }
            }
            (n, v)
        })
        .collect();
    ExrFile::from_channels(path, w, h, channels, SampleKind::F32)
        .write_atomic(path)
        .unwrap();
}

/// `radn denoise` of every frame of `input` into `out`, with `extra` arguments; its stderr.
fn denoise(input: &Path, out: &Path, extra: &[&str]) -> String {
    denoise_with_progress("off", input, out, extra)
}

/// [`denoise`] with `--progress STYLE`.
fn denoise_with_progress(style: &str, input: &Path, out: &Path, extra: &[&str]) -> String {
    let i = input.join("frame_####.exr");
    let o = out.join("frame_####.exr");
    let mut args = vec!["--progress", style, "denoise", "-i"];
    args.push(i.to_str().unwrap());
    args.extend(["-o", o.to_str().unwrap()]);
    args.extend(extra);
    String::from_utf8_lossy(&common::radn_ok(&args).stderr).into_owned()
}

fn beauty(dir: &Path, frame: usize) -> radn_core::Plane {
    common::beauty_rgb(&ExrFile::read(dir.join(format!("frame_{frame:04}.exr"))).unwrap())
}

#[test]
fn estimated_motion_scores_near_the_renderers_vectors_and_says_which_it_used() {
    let d = tempfile::tempdir().unwrap();
    let (with, without, zeroed) = (
        d.path().join("with"),
        d.path().join("without"),
        d.path().join("zeroed"),
    );
    let frames: Vec<(usize, bool)> = (1..=9).map(|f| (f, false)).collect();
    sequence(&with, &frames, Vectors::Kept);
    sequence(&without, &frames, Vectors::Dropped);
    sequence(&zeroed, &frames, Vectors::Zeroed);
    let runs = [
        ("renderer", &with, vec![], "motion: the renderer's vectors"),
        (
            "estimate",
            &with,
            vec!["--motion", "estimate"],
            "motion: estimated from the frames (--motion estimate)",
        ),
        (
            "auto",
            &without,
            vec![],
            "motion: estimated from the frames (the files have no motion vectors)",
        ),
        (
            "auto-zero",
            &zeroed,
            vec![],
            "motion: estimated from the frames (the files' motion vectors are all zero",
        ),
    ];
    let mut scores = Vec::new();
    for (name, input, extra, said) in runs {
        let out = d.path().join(name);
        let log = denoise(input, &out, &extra);
        assert!(log.contains(said), "{name}: {log}");
        let mean = (3..=7)
            .map(|f| psnr(&beauty(&out, f), &reference(f, false)).unwrap())
            .sum::<f64>()
            / 5.0;
        scores.push(mean);
    }
    let noisy = (3..=7)
        .map(|f| psnr(&beauty(&with, f), &reference(f, false)).unwrap())
        .sum::<f64>()
        / 5.0;
    let (renderer, estimated, auto, zero) = (scores[0], scores[1], scores[2], scores[3]);
    assert!(renderer > noisy + 10.0, "{renderer} vs noisy {noisy}");
    assert!(
        (estimated - renderer).abs() < 0.3,
        "estimated {estimated} dB, renderer's vectors {renderer} dB"
    );
    assert_eq!(
        estimated, auto,
        "the same motion whether the vectors are ignored or absent"
    );
    assert_eq!(estimated, zero, "... or all zero");
}

#[test]
fn a_cut_is_found_and_the_frames_beside_it_equal_sequences_that_end_there() {
    let d = tempfile::tempdir().unwrap();
    // shot A: sample frames 1-5; shot B: frames 5-9 mirrored (another view)
    let a: Vec<(usize, bool)> = (1..=5).map(|f| (f, false)).collect();
    let b: Vec<(usize, bool)> = (5..=9).map(|f| (f, true)).collect();
    let joined: Vec<(usize, bool)> = a.iter().chain(&b).copied().collect();
    for vectors in [Vectors::Dropped, Vectors::Kept] {
        let tag = if vectors == Vectors::Kept {
            "vectors"
        } else {
            "estimated"
        };
        let dir = |n: &str| d.path().join(format!("{tag}-{n}"));
        sequence(&dir("a"), &a, vectors);
        sequence(&dir("b"), &b, vectors);
        sequence(&dir("ab"), &joined, vectors);
        let log = denoise_with_progress("json", &dir("ab"), &dir("ab-out"), &[]);
        denoise(&dir("a"), &dir("a-out"), &[]);
        denoise(&dir("b"), &dir("b-out"), &[]);
        let (joined_a, alone_a) = (beauty(&dir("ab-out"), 5), beauty(&dir("a-out"), 5));
        let (joined_b, alone_b) = (beauty(&dir("ab-out"), 6), beauty(&dir("b-out"), 1));
        if vectors == Vectors::Kept {
            // the renderer's vectors lead across the cut; confidence keeps it out
            let ra = reference(5, false);
            let rb = reference(5, true);
            for (joined, alone, r) in [(joined_a, alone_a, ra), (joined_b, alone_b, rb)] {
                let (j, s) = (psnr(&joined, &r).unwrap(), psnr(&alone, &r).unwrap());
                assert!((j - s).abs() < 0.1, "{j} dB joined, {s} dB alone");
            }
        } else {
            assert!(
                log.contains("cut between frame_0005.exr and frame_0006.exr"),
                "{log}"
            );
            // an event line starts with its name (what the Python package reads)
            let events: Vec<serde_json::Value> = log
                .lines()
                .filter(|l| l.starts_with("{\"event\""))
                .filter_map(|l| serde_json::from_str(l).ok())
                .collect();
            assert!(
                events
                    .iter()
                    .any(|e| e["event"] == "cut" && e["frames"] == serde_json::json!([5, 6])),
                "{log}"
            );
            assert_eq!(joined_a, alone_a, "the last frame before the cut");
            assert_eq!(joined_b, alone_b, "the first frame after it");
        }
    }
}

#[test]
fn bands_equal_whole_frames_with_estimated_motion() {
    let d = tempfile::tempdir().unwrap();
    let input = d.path().join("in");
    sequence(
        &input,
        &(1..=6).map(|f| (f, false)).collect::<Vec<_>>(),
        Vectors::Dropped,
    );
    let whole = d.path().join("whole");
    let banded = d.path().join("banded");
    let frames = ["--frames", "2-4"];
    denoise(
        &input,
        &whole,
        &[&frames[..], &["--bands", "never"]].concat(),
    );
    let log = denoise(
        &input,
        &banded,
        &[&frames[..], &["--bands", "32", "-v"]].concat(),
    );
    assert!(log.contains("band by band"), "{log}");
    for f in 2..=4 {
        let (a, b) = (beauty(&whole, f), beauty(&banded, f));
        let worst = a
            .data()
            .iter()
            .zip(b.data())
            .fold(0f32, |m, (x, y)| m.max((x - y).abs()));
        assert_eq!(worst, 0.0, "frame {f}: bands differ by up to {worst}");
    }
}

#[test]
fn the_renderers_motion_alone_needs_files_with_vectors() {
    let d = tempfile::tempdir().unwrap();
    let input = d.path().join("in");
    sequence(
        &input,
        &[(1, false), (2, false), (3, false)],
        Vectors::Dropped,
    );
    let i = input.join("frame_####.exr");
    let o = d.path().join("out/frame_####.exr");
    let out = common::radn(&[
        "--progress",
        "off",
        "denoise",
        "-i",
        i.to_str().unwrap(),
        "-o",
        o.to_str().unwrap(),
        "--motion",
        "renderer",
    ]);
    assert!(!out.status.success());
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(
        e.contains("frame_0001.exr") && e.contains("no motion vector"),
        "{e}"
    );
    assert!(!d.path().join("out/frame_0001.exr").exists());
}

/// A flash frame (the same geometry under 16 times the light) is left out of its neighbours'
/// windows rather than blended in: with estimated motion, the frames beside it stay within
/// 0.3 dB of the same frames denoised in the sequence without the flash (blending a
/// sixteen-fold brighter frame in would cost them several dB).
#[test]
fn a_flash_frame_does_not_brighten_its_neighbours() {
    let d = tempfile::tempdir().unwrap();
    let (plain, flash) = (d.path().join("plain"), d.path().join("flash"));
    let frames: Vec<(usize, bool)> = (1..=9).map(|f| (f, false)).collect();
    sequence(&plain, &frames, Vectors::Dropped);
    sequence(&flash, &frames, Vectors::Dropped);
    let lit = flash.join("frame_0005.exr");
    let f = ExrFile::read(&lit).unwrap();
    let channels = f
        .channel_names()
        .into_iter()
        .map(|n| {
            let mut v = f.channel_f32(&n).unwrap();
            if n.contains(".Combined.") && !n.ends_with(".A") {
                v.iter_mut().for_each(|x| *x *= 16.0);
            }
            (n, v)
        })
        .collect();
    ExrFile::from_channels(&lit, f.width(), f.height(), channels, SampleKind::F32)
        .write_atomic(&lit)
        .unwrap();
    let (a, b) = (d.path().join("a"), d.path().join("b"));
    denoise(&plain, &a, &["--frames", "4-6"]);
    denoise(&flash, &b, &["--frames", "4-6"]);
    for frame in [4, 6] {
        let r = reference(frame, false);
        let without = psnr(&beauty(&a, frame), &r).unwrap();
        let with = psnr(&beauty(&b, frame), &r).unwrap();
        assert!(
            with > without - 0.3,
            "frame {frame}: {with:.2} dB beside the flash, {without:.2} dB without it"
        );
    }
    // the flash frame itself is denoised as lit
    let lit_out = beauty(&b, 5);
    let plain_out = beauty(&a, 5);
    let ratio = lit_out.data().iter().sum::<f32>() / plain_out.data().iter().sum::<f32>();
    assert!(
        (ratio - 16.0).abs() < 1.6,
        "flash frame's brightness ratio {ratio}"
    );
}
