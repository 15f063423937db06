//! A seeded fuzz test: mutations of the shipped sample's frames (bit flips, random bytes,
//! truncation, header damage, zeroed and duplicated blocks), of a model file and of a channel
//! mapping file, through radn's readers in this process and through `radn inspect`,
//! `radn warp` and `radn denoise`. Every case must end in a clean error that names the file or
//! in a valid result: no panic, no hang, no allocation past a fixed bound.
//!
//! The cases that once failed are kept in `tests/fuzz-corpus/` (frames/, models/, mappings/)
//! and replayed first. A longer campaign, keeping what fails for the corpus:
//! `RADN_FUZZ_CASES=5000 RADN_FUZZ_SEED=7 RADN_FUZZ_KEEP=/tmp/failed cargo test --release
//! -p radn --test fuzz -- --nocapture`.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::sample;

/// Address-space limit of every radn process the test starts (KiB): a denoise of the sample
/// needs about 0.2 GiB of it; a file that makes radn allocate past this aborts it, which fails.
const MEMORY_LIMIT_KIB: u64 = 1 << 20;
/// Longest a case may take before it counts as a hang.
const TIMEOUT: Duration = Duration::from_secs(20);

/// SplitMix64: a seeded, portable stream of random numbers.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// One mutation of `base`, and what it was. `header` is how many leading bytes count as the
/// file's header (where damage is aimed for the "header" kind).
fn mutate(base: &[u8], header: usize, rng: &mut Rng) -> (String, Vec<u8>) {
    let mut b = base.to_vec();
    let n = b.len();
    let what = match rng.below(7) {
        0 => {
            let k = 1 + rng.below(8);
            for _ in 0..k {
                let i = rng.below(n);
                b[i] ^= 1 << rng.below(8);
            }
            format!("{k} bit flips")
        }
        1 => {
            let at = rng.below(n);
            let len = (1 + rng.below(64)).min(n - at);
            for x in &mut b[at..at + len] {
                *x = rng.next() as u8;
            }
            format!("{len} random bytes at {at}")
        }
        2 => {
            let at = rng.below(n);
            b.truncate(at);
            format!("truncated to {at} bytes")
        }
        3 => {
            // damage where sizes, counts, types and names live; often a value pushed to an
            // extreme (a huge data window, a negative count)
            let at = rng.below(header.min(n));
            let v = match rng.below(4) {
                0 => 0xFF,
                1 => 0x00,
                2 => 0x7F,
                _ => rng.next() as u8,
            };
            let len = (1 + rng.below(4)).min(n - at);
            for x in &mut b[at..at + len] {
                *x = v;
            }
            format!("header: {len} bytes at {at} set to {v:#04x}")
        }
        4 if n >= 4 => {
            // a 32-bit field of the header (a size, a count, a window corner) made extreme
            let at = rng.below(header.min(n) - 3);
            let v: i32 = [i32::MAX, i32::MIN, -1, 0, 99_999, 1 << 20][rng.below(6)];
            b[at..at + 4].copy_from_slice(&v.to_le_bytes());
            format!("header: int32 at {at} set to {v}")
        }
        5 => {
            let at = rng.below(n);
            let len = (1 + rng.below(4096)).min(n - at);
            b[at..at + len].fill(0);
            format!("{len} bytes zeroed at {at}")
        }
        _ => {
            let from = rng.below(n);
            let len = (1 + rng.below(4096)).min(n - from);
            let to = rng.below(n - len + 1);
            let block = b[from..from + len].to_vec();
            b[to..to + len].copy_from_slice(&block);
            format!("{len} bytes from {from} copied to {to}")
        }
    };
    (what, b)
}

/// Runs `f` on a thread of its own, catching panics and giving up after [`TIMEOUT`].
fn in_process<T: Send + 'static>(
    f: impl FnOnce() -> Result<T, String> + Send + 'static,
) -> Result<Result<T, String>, String> {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
        let _ = tx.send(r);
    });
    match rx.recv_timeout(TIMEOUT) {
        Ok(Ok(r)) => Ok(r),
        Ok(Err(p)) => {
            let msg = p
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default();
            Err(format!("panicked: {msg}"))
        }
        Err(_) => Err(format!("no answer within {TIMEOUT:?} (a hang)")),
    }
}

/// Runs the radn binary under the memory limit and the timeout; `Ok(true)` for success,
/// `Ok(false)` for a clean error whose message names `file`, `Err` for anything else.
fn radn_limited(args: &[&str], file: &Path) -> Result<bool, String> {
    radn_limited_naming(args, &[file])
}

/// [`radn_limited`] where the error may name any of `files`.
fn radn_limited_naming(args: &[&str], files: &[&Path]) -> Result<bool, String> {
    let mut child = Command::new("sh")
        .arg("-c")
        .arg(format!(
            "ulimit -v {MEMORY_LIMIT_KIB} && exec \"$0\" \"$@\""
        ))
        .arg(env!("CARGO_BIN_EXE_radn"))
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t.elapsed() > TIMEOUT {
            let _ = child.kill();
            let _ = child.wait();
            return Err(format!("radn {} hung", args[0]));
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let mut err = String::new();
    use std::io::Read;
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    match status.code() {
        Some(0) => Ok(true),
        Some(1) => {
            let names: Vec<String> = files
                .iter()
                .map(|f| f.file_name().unwrap().to_string_lossy().into_owned())
                .collect();
            if err.contains("panicked") {
                Err(format!("radn {} panicked: {err}", args[0]))
            } else if !names.iter().any(|n| err.contains(n.as_str())) {
                Err(format!(
                    "radn {}: the error names none of {names:?}: {err}",
                    args[0]
                ))
            } else {
                Ok(false)
            }
        }
        c => Err(format!(
            "radn {} ended with {c:?} (a panic, an abort or a signal): {err}",
            args[0]
        )),
    }
}

/// An in-process result that must be Ok or an error naming `file`.
fn clean<T>(r: Result<Result<T, String>, String>, file: &Path, what: &str) -> Result<bool, String> {
    let name = file.file_name().unwrap().to_string_lossy().into_owned();
    match r? {
        Ok(_) => Ok(true),
        Err(e) if e.contains(&name) => Ok(false),
        Err(e) => Err(format!("{what}: the error does not name {name}: {e}")),
    }
}

/// [`clean`] of `read(path)` run by [`in_process`]: the in-process half of every case.
fn read_check(
    path: &Path,
    what: &str,
    read: impl FnOnce(&Path) -> Result<(), String> + Send + 'static,
) -> Result<bool, String> {
    let q = path.to_path_buf();
    clean(in_process(move || read(&q)), path, what)
}

/// A folder with the sample's frames 1-5 (4 spp), frame 3 replaced by `bytes`; returns the
/// path of frame 3.
fn sequence_with(dir: &Path, bytes: &[u8]) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    for f in [1, 2, 4, 5] {
        let name = format!("frame_{f:04}.exr");
        let dst = dir.join(&name);
        if !dst.exists() {
            std::fs::copy(sample().join("low").join(&name), dst).unwrap();
        }
    }
    let p = dir.join("frame_0003.exr");
    std::fs::write(&p, bytes).unwrap();
    p
}

/// One frame case: the EXR reader and the Cycles frame reader in process, `radn inspect`, and
/// (when `denoise`) `radn warp` and `radn denoise` on a window centred on it. Returns whether
/// the file was read as valid.
fn frame_case(dir: &Path, bytes: &[u8], denoise: bool) -> Result<bool, String> {
    let p = sequence_with(dir, bytes);
    let read = read_check(&p, "ExrFile::read", |q| {
        radn_core::io::exr_file::ExrFile::read(q)
            .map(|_| ())
            .map_err(|e| e.to_string())
    })?;
    read_check(&p, "FrameReader::read", |q| {
        let mapping = radn_core::io::mapping::ChannelMapping::builtin("cycles").unwrap();
        let reader = radn_core::io::frame::FrameReader::new(
            mapping,
            radn_core::io::frame::Requirements {
                albedo: true,
                normal: true,
                depth: false,
                motion: true,
            },
        );
        reader.read(q).map(|_| ()).map_err(|e| e.to_string())
    })?;
    let ps = p.to_str().unwrap();
    radn_limited(&["inspect", ps], &p)?;
    if denoise {
        let pattern = format!("{}/frame_####.exr", dir.display());
        let out = dir.join("out");
        let w = out.join("w.exr");
        radn_limited(
            &[
                "warp",
                "-i",
                &pattern,
                "--frame",
                "3",
                "-o",
                w.to_str().unwrap(),
            ],
            &p,
        )?;
        let o = format!("{}/frame_####.exr", out.display());
        let ok = radn_limited(
            &[
                "denoise",
                "-i",
                &pattern,
                "-o",
                &o,
                "--frames",
                "3-3",
                "--overwrite",
                "--guide",
                "none",
            ],
            &p,
        )?;
        if ok {
            let res = out.join("frame_0003.exr");
            radn_core::io::exr_file::ExrFile::read(&res)
                .map_err(|e| format!("denoise succeeded, its output does not read back: {e}"))?;
        }
    }
    Ok(read)
}

/// One model case: the model reader in process, and `radn denoise --model` where the file
/// is refused (a clean error, fast) — a loadable one would only denoise with odd weights.
fn model_case(dir: &Path, bytes: &[u8]) -> Result<bool, String> {
    std::fs::create_dir_all(dir).unwrap();
    let p = dir.join("mutated.safetensors");
    std::fs::write(&p, bytes).unwrap();
    let loads = read_check(&p, "store::load", |q| {
        radn_nn::model::store::load(q, &radn_nn::burn::tensor::Device::flex())
            .map(|_| ())
            .map_err(|e| e.to_string())
    })?;
    if !loads {
        let seq = dir.join("seq");
        sequence_with(
            &seq,
            &std::fs::read(sample().join("low/frame_0003.exr")).unwrap(),
        );
        let pattern = format!("{}/frame_####.exr", seq.display());
        let o = format!("{}/out/frame_####.exr", dir.display());
        let ok = radn_limited(
            &[
                "denoise",
                "-i",
                &pattern,
                "-o",
                &o,
                "--frames",
                "3-3",
                "--model",
                p.to_str().unwrap(),
            ],
            &p,
        )?;
        if ok {
            return Err("radn denoise accepted a model file its reader refuses".into());
        }
    }
    Ok(loads)
}

/// One mapping case: the mapping reader in process and `radn warp --mapping`.
fn mapping_case(dir: &Path, bytes: &[u8]) -> Result<bool, String> {
    let seq = dir.join("seq");
    sequence_with(
        &seq,
        &std::fs::read(sample().join("low/frame_0003.exr")).unwrap(),
    );
    let p = dir.join("mutated.toml");
    std::fs::write(&p, bytes).unwrap();
    let parses = read_check(&p, "ChannelMapping::from_file", |q| {
        radn_core::io::mapping::ChannelMapping::from_file(q)
            .map(|_| ())
            .map_err(|e| e.to_string())
    })?;
    let pattern = format!("{}/frame_####.exr", seq.display());
    let w = dir.join("w.exr");
    let args = [
        "warp",
        "-i",
        &pattern,
        "--frame",
        "3",
        "-o",
        w.to_str().unwrap(),
        "--mapping",
        p.to_str().unwrap(),
    ];
    // a mapping that parses may still name channels the frames lack: then the error names a
    // frame of the window rather than the mapping
    let frames: Vec<PathBuf> = (1..=5)
        .map(|f| seq.join(format!("frame_{f:04}.exr")))
        .collect();
    let mut names: Vec<&Path> = vec![&p];
    if parses {
        names.extend(frames.iter().map(PathBuf::as_path));
    }
    radn_limited_naming(&args, &names)?;
    Ok(parses)
}

fn env_or(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Keeps a failing case's bytes where `RADN_FUZZ_KEEP` says, for the corpus.
fn keep(kind: &str, case: usize, bytes: &[u8]) {
    if let Ok(dir) = std::env::var("RADN_FUZZ_KEEP") {
        let d = Path::new(&dir).join(kind);
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join(format!("case-{case}")), bytes).unwrap();
    }
}

fn corpus(kind: &str) -> Vec<(PathBuf, Vec<u8>)> {
    let d = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fuzz-corpus")
        .join(kind);
    let mut v: Vec<(PathBuf, Vec<u8>)> = std::fs::read_dir(&d)
        .map(|r| {
            r.flatten()
                .map(|e| e.path())
                .filter(|p| p.extension().is_none_or(|e| e != "md"))
                .map(|p| {
                    let b = std::fs::read(&p).unwrap();
                    (p, b)
                })
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// Runs the corpus and `cases` seeded mutations of `base` through `run`; panics listing every
/// failing case. `run(dir, bytes, i)` gets a scratch folder of its own.
fn campaign(
    kind: &str,
    base: &[u8],
    header: usize,
    cases: usize,
    mut run: impl FnMut(&Path, &[u8], usize) -> Result<bool, String>,
) -> (usize, usize) {
    let d = tempfile::tempdir().unwrap();
    let seed = env_or("RADN_FUZZ_SEED", 1);
    let mut failures = Vec::new();
    for (p, bytes) in corpus(kind) {
        if let Err(e) = run(&d.path().join("corpus"), &bytes, usize::MAX) {
            failures.push(format!("corpus {}: {e}", p.display()));
        }
    }
    let mut valid = 0;
    for i in 0..cases {
        let mut rng = Rng(seed.wrapping_mul(0x1000_0001) ^ (i as u64).wrapping_mul(0x9E37));
        let (what, bytes) = mutate(base, header, &mut rng);
        match run(&d.path().join(format!("{}", i % 8)), &bytes, i) {
            Ok(v) => valid += usize::from(v),
            Err(e) => {
                keep(kind, i, &bytes);
                failures.push(format!("{kind} case {i} ({what}): {e}"));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {cases} {kind} cases failed (seed {seed}):\n{}",
        failures.len(),
        failures.join("\n")
    );
    (valid, cases)
}

#[test]
fn mutated_frames_give_a_clean_error_or_a_valid_result() {
    let base = std::fs::read(sample().join("low/frame_0003.exr")).unwrap();
    let cases = env_or("RADN_FUZZ_CASES", 300) as usize;
    // the header (attributes and channel list) and the chunk offset table: before the first
    // chunk, whose offset is the table's first entry
    let header = first_chunk_offset(&base);
    // the windows also go through warp and denoise for some cases, the valid ones most
    // (decoding is where a mutation usually ends; past it, the denoiser must cope with
    // whatever values the file holds)
    let mut denoised_valid = 0;
    let (valid, n) = campaign("frames", &base, header, cases, |dir, bytes, i| {
        let read = frame_case(dir, bytes, false)?;
        let denoise = if read {
            denoised_valid < 6 || i == usize::MAX
        } else {
            i % 25 == 0 || i == usize::MAX
        };
        if denoise {
            denoised_valid += usize::from(read);
            frame_case(dir, bytes, true)?;
        }
        Ok(read)
    });
    eprintln!("{valid} of {n} mutated frames still read as valid EXRs");
}

/// The byte offset of an EXR file's first chunk (the first entry of its offset table), found
/// by looking for the table: the first position after the header's end from which eight
/// increasing little-endian offsets point inside the file.
fn first_chunk_offset(b: &[u8]) -> usize {
    let read = |i: usize| u64::from_le_bytes(b[i..i + 8].try_into().unwrap()) as usize;
    (8..b.len() - 64)
        .find(|&i| {
            let first = read(i);
            first > i && first < b.len() && (1..4).all(|k| read(i + 8 * k) > read(i + 8 * (k - 1)))
        })
        .unwrap_or(1024)
}

#[test]
fn mutated_model_files_give_a_clean_error_or_load() {
    let base = std::fs::read(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models/default.safetensors"),
    )
    .unwrap();
    let header = 8 + u64::from_le_bytes(base[..8].try_into().unwrap()) as usize;
    let cases = (env_or("RADN_FUZZ_CASES", 300) / 5) as usize;
    let (valid, n) = campaign("models", &base, header, cases, |dir, bytes, _| {
        model_case(dir, bytes)
    });
    eprintln!("{valid} of {n} mutated model files still loaded");
}

#[test]
fn mutated_mapping_files_give_a_clean_error_or_work() {
    let base = std::fs::read(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../radn-core/presets/cycles.toml"),
    )
    .unwrap();
    let cases = (env_or("RADN_FUZZ_CASES", 300) / 5) as usize;
    let (valid, n) = campaign("mappings", &base, base.len(), cases, |dir, bytes, _| {
        mapping_case(dir, bytes)
    });
    eprintln!("{valid} of {n} mutated mapping files still parsed");
}
