//! `radn denoise --frames a-b` end to end: a range is denoised exactly as the same frames of a
//! run over the whole sequence (its windows read the neighbours beyond the range), so a shot
//! split into ranges — by hand or as farm tasks — gives the result of one run.

mod common;

use std::path::Path;

use common::{radn_ok, sample};
use radn_core::io::exr_file::ExrFile;

/// Runs `radn denoise` on the sample's 4-spp frames into `dir/name/`, returns the stdout.
fn denoise(dir: &Path, name: &str, extra: &[&str]) -> String {
    let input = format!("{}/low/frame_####.exr", sample().display());
    let out = format!("{}/{name}/f_####.exr", dir.display());
    // the unguided network (and classic): this file checks ranges, not the guide
    let mut args = vec!["denoise", "-i", &input, "-o", &out, "--guide", "none"];
    args.extend_from_slice(extra);
    String::from_utf8_lossy(&radn_ok(&args).stdout).into_owned()
}

/// Asserts frame `f` of runs `a` and `b` agree in every channel to 1e-6 (relative).
fn assert_same(dir: &Path, a: &str, b: &str, frames: impl IntoIterator<Item = i64>) {
    for f in frames {
        let read = |run: &str| ExrFile::read(dir.join(format!("{run}/f_{f:04}.exr"))).unwrap();
        let (x, y) = (read(a), read(b));
        let names = x.channel_names();
        assert_eq!(names, y.channel_names());
        for name in names {
            let (u, v) = (x.channel_f32(&name).unwrap(), y.channel_f32(&name).unwrap());
            let worst = u
                .iter()
                .zip(&v)
                .map(|(p, q)| (p - q).abs() / p.abs().max(1.0))
                .fold(0.0f32, f32::max);
            assert!(
                worst <= 1e-6,
                "frame {f} {name}: {a} and {b} differ by {worst}"
            );
        }
    }
}

#[test]
fn frame_ranges_denoise_as_the_whole_sequence_does() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    // the shipped network, band by band (bands of 48 rows); the 9-frame shot in two ranges
    let banded = |extra: &[&'static str]| [&["--tile", "48", "--bands", "always"], extra].concat();
    denoise(dir, "whole", &banded(&[]));
    let said = denoise(dir, "split", &banded(&["--frames", "1-4"]));
    assert!(said.contains("denoised 4 frames"), "{said}");
    denoise(dir, "split", &banded(&["--frames", "5-9"]));
    assert_same(dir, "whole", "split", 1..=9);
    // only the range is written, though its neighbours are read
    assert!(!dir.join("alone/f_0002.exr").exists());
    denoise(dir, "alone", &banded(&["--frames", "3-3"]));
    assert_same(dir, "whole", "alone", [3]);
    assert!(!dir.join("alone/f_0002.exr").exists() && !dir.join("alone/f_0004.exr").exists());

    // two passes: the first pass also denoises the neighbours the second pass's windows read
    denoise(dir, "whole2", &banded(&["--passes", "2"]));
    denoise(
        dir,
        "range2",
        &banded(&["--passes", "2", "--frames", "5-6"]),
    );
    assert_same(dir, "whole2", "range2", 5..=6);
    // whole frames (--tile 0) and a stepped range
    denoise(dir, "whole0", &["--tile", "0"]);
    denoise(dir, "step0", &["--tile", "0", "--frames", "2-8x3"]);
    assert_same(dir, "whole0", "step0", [2, 5, 8]);
    assert!(!dir.join("step0/f_0003.exr").exists());

    // the classic method, whose motion refinement reads one frame further
    denoise(dir, "classic", &["--method", "classic"]);
    denoise(
        dir,
        "classic-range",
        &["--method", "classic", "--frames", "6-7"],
    );
    assert_same(dir, "classic", "classic-range", 6..=7);

    // the temporal pass over the results: the network also denoises the frames the pass's
    // windows read, two beyond each end of the range, and the pass changes the result
    denoise(dir, "stab", &["--tile", "0", "--tune", "stabilize=0.3"]);
    denoise(
        dir,
        "stab-range",
        &["--tile", "0", "--tune", "stabilize=0.3", "--frames", "5-6"],
    );
    assert_same(dir, "stab", "stab-range", 5..=6);
    assert!(!dir.join("stab-range/f_0004.exr").exists());
    let beauty = |run: &str| {
        ExrFile::read(dir.join(format!("{run}/f_0005.exr")))
            .unwrap()
            .channel_f32("ViewLayer.Combined.R")
            .unwrap()
    };
    let moved = beauty("stab")
        .iter()
        .zip(beauty("whole0"))
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(moved > 1e-4, "the temporal pass changed nothing ({moved})");
}
