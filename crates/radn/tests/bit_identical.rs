//! Outputs stay bit-identical across restructurings: every shipped path (unguided, guided over
//! OIDN, classic, several passes, band by band, AOVs) is run on the sample and hashed (every
//! channel's samples, bit for bit), and the hashes are compared with the ones stored in
//! `tests/golden/` before the change.
//!
//! `RADN_GOLDEN_WRITE=1` records the hashes instead of comparing (only for a change that is
//! meant to change outputs: say so in its commit). The 1080p variant is slow on two cores and
//! runs with `-- --ignored` (`scripts/golden`).

mod common;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use common::{radn_ok, sample, with_aovs};
use radn_core::io::exr_file::{ExrFile, SampleKind};

/// 64-bit FNV-1a: a hash whose value is fixed by its definition, so stored hashes stay valid
/// across Rust releases (std's `DefaultHasher` makes no such promise).
struct Fnv(u64);

impl Fnv {
    fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
    fn bytes(&mut self, b: &[u8]) {
        for &x in b {
            self.0 ^= u64::from(x);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

/// The hash of every output frame in `dir` (sorted by name): each channel's name, storage
/// type and samples' bits.
fn hash_outputs(dir: &Path) -> String {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "exr"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no output in {}", dir.display());
    let mut h = Fnv::new();
    for f in &files {
        let file = ExrFile::read(f).unwrap();
        h.bytes(f.file_name().unwrap().as_encoded_bytes());
        for name in file.channel_names() {
            h.bytes(name.as_bytes());
            h.bytes(&[match file.channel_kind(&name) {
                Some(SampleKind::F16) => 1,
                Some(SampleKind::F32) => 2,
                _ => 3,
            }]);
            for v in file.channel_f32(&name).unwrap() {
                h.bytes(&v.to_bits().to_le_bytes());
            }
        }
    }
    format!("{:016x} ({} frames)", h.0, files.len())
}

/// The paths whose outputs are pinned: a name and the `radn denoise` options (the input and
/// output are added). `--guide none` and `--guide oidn` name the path whatever the default is.
const CASES: &[(&str, &[&str])] = &[
    ("unguided", &["--guide", "none"]),
    ("guided", &["--guide", "oidn"]),
    ("classic", &["--method", "classic"]),
    ("unguided-2-passes", &["--guide", "none", "--passes", "2"]),
    (
        "unguided-banded",
        &["--guide", "none", "--bands", "always", "--tile", "64"],
    ),
    (
        "guided-banded",
        &["--guide", "oidn", "--bands", "always", "--tile", "64"],
    ),
    // the previous compiled-in guided model, from its file (tests run in crates/radn): its
    // outputs are pinned to what they were when it was compiled in
    (
        "guided-lean-file",
        &[
            "--guide",
            "oidn",
            "--model",
            "../../models/guided-lean.safetensors",
        ],
    ),
];

/// Runs every case on `input` (a pattern) with `extra` options, and returns `name hash` lines.
fn run_cases(input: &str, extra: &[&str], work: &Path, prefix: &str) -> String {
    let mut out = String::new();
    for (name, opts) in CASES {
        let dir = work.join(name);
        let pattern = format!("{}/frame_####.exr", dir.display());
        let mut args = vec!["denoise", "-i", input, "-o", &pattern];
        args.extend_from_slice(opts);
        args.extend_from_slice(extra);
        radn_ok(&args);
        writeln!(out, "{prefix}{name} {}", hash_outputs(&dir)).unwrap();
    }
    out
}

/// The sample's golden file for this CPU: `sample.txt` where OIDN runs its AVX-512 kernels,
/// `sample-avx2.txt` elsewhere.
fn golden_name() -> &'static str {
    #[cfg(target_arch = "x86_64")]
    if !std::is_x86_feature_detected!("avx512f") {
        return "sample-avx2.txt";
    }
    "sample.txt"
}

/// Compares `got` with the stored file `name` in `tests/golden/`, or records it.
fn check_golden(name: &str, got: &str) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/golden")
        .join(name);
    if std::env::var_os("RADN_GOLDEN_WRITE").is_some() {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, got).unwrap();
        eprintln!("recorded {}", path.display());
        return;
    }
    let want = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e} (record it with RADN_GOLDEN_WRITE=1)",
            path.display()
        )
    });
    assert_eq!(
        got,
        want,
        "outputs changed against {} (left: now, right: stored)",
        path.display()
    );
}

/// Skips (or, with `RADN_REQUIRE_OIDN`, fails) where OIDN is missing: the guided cases need it.
fn oidn_here() -> bool {
    common::oidn_or_skip(1).is_some()
}

#[test]
fn every_path_is_bit_identical_on_the_sample() {
    if !oidn_here() {
        return;
    }
    let work = tempfile::tempdir().unwrap();
    let input = format!("{}/low/frame_####.exr", sample().display());
    let mut got = run_cases(&input, &[], work.path(), "");
    // AOVs and alpha through the guided path and the unguided one
    let aovs_in = with_aovs(work.path(), 0.25);
    for (name, opts) in [
        ("guided-aovs", ["--guide", "oidn"]),
        ("unguided-aovs", ["--guide", "none"]),
    ] {
        let dir = work.path().join(name);
        let pattern = format!("{}/frame_####.exr", dir.display());
        let mut args = vec!["denoise", "-i", &aovs_in, "-o", &pattern];
        args.extend_from_slice(&opts);
        args.extend_from_slice(&["--aovs", "diffuse,specular"]);
        radn_ok(&args);
        writeln!(got, "{name} {}", hash_outputs(&dir)).unwrap();
    }
    // OIDN's own kernels round differently with and without AVX-512, so the guided paths'
    // hashes are kept per instruction set (the unguided and classic ones are the same in both)
    check_golden(golden_name(), &got);
}

/// The sample's low level upscaled (nearest) to 1920×1080, motion vectors scaled with it, in
/// `dir`; returns its pattern.
fn sample_at_1080p(dir: &Path) -> String {
    let (w, h) = (1920usize, 1080usize);
    for f in 1..=9 {
        let src = ExrFile::read(sample().join(format!("low/frame_{f:04}.exr"))).unwrap();
        let (sw, sh) = (src.width(), src.height());
        let (fx, fy) = (w as f32 / sw as f32, h as f32 / sh as f32);
        let channels = src
            .channel_names()
            .into_iter()
            .map(|name| {
                let v = src.channel_f32(&name).unwrap();
                let scale = if name.contains(".Vector.") {
                    if name.ends_with('X') || name.ends_with('Z') {
                        fx
                    } else {
                        fy
                    }
                } else {
                    1.0
                };
                let up: Vec<f32> = (0..w * h)
                    .map(|i| {
                        let (x, y) = (i % w, i / w);
                        v[(y * sh / h) * sw + x * sw / w] * scale
                    })
                    .collect();
                (name, up)
            })
            .collect();
        let p = dir.join(format!("frame_{f:04}.exr"));
        ExrFile::from_channels(&p, w, h, channels, SampleKind::F16)
            .write_atomic(&p)
            .unwrap();
    }
    format!("{}/frame_####.exr", dir.display())
}

#[test]
#[ignore = "slow on two cores: run by scripts/golden"]
fn every_path_is_bit_identical_at_1080p() {
    if !oidn_here() {
        return;
    }
    let work = tempfile::tempdir().unwrap();
    let src = work.path().join("in");
    std::fs::create_dir_all(&src).unwrap();
    let input = sample_at_1080p(&src);
    // the middle frame only (its window and, for the temporal pass, its neighbours' are read)
    let got = run_cases(&input, &["--frames", "5-5"], work.path(), "1080p-");
    check_golden("1080p.txt", &got);
}
