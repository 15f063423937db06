//! Crash safety of `radn denoise` and `radn train` on a farm: runs killed at any point leave
//! only complete outputs and radn's own temporary files, which the next run removes; two runs on
//! one output write each frame once, whole; a full disk ends with an error naming the file and
//! nothing partial under an output's name.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use common::{radn_ok, sample};

/// The frames every test here writes: four, with their windows' neighbours read around them.
const FRAMES: &str = "3-6";

fn input() -> String {
    format!("{}/low/frame_####.exr", sample().display())
}

fn denoise_cmd(out: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_radn"));
    c.args([
        "--threads",
        "1",
        "denoise",
        "--guide",
        "none",
        "-i",
        &input(),
        "-o",
    ])
    .arg(out.join("frame_####.exr"))
    .args(["--frames", FRAMES]);
    c
}

/// The pixels of an EXR file: every channel's samples as bits, by channel name (the bytes of
/// two identical results may differ: chunks are written in the order they finish).
type Pixels = Vec<(String, Vec<u32>)>;

fn pixels(path: &Path) -> Pixels {
    let f = radn_core::io::exr_file::ExrFile::read(path)
        .unwrap_or_else(|e| panic!("{} is not a whole EXR: {e}", path.display()));
    f.channel_names()
        .into_iter()
        .map(|n| {
            let bits = f
                .channel_f32(&n)
                .unwrap()
                .iter()
                .map(|v| v.to_bits())
                .collect();
            (n, bits)
        })
        .collect()
}

/// An uninterrupted run's outputs (file name, pixels) and how long it took.
fn reference() -> &'static (Vec<(String, Pixels)>, Duration) {
    static REF: OnceLock<(Vec<(String, Pixels)>, Duration)> = OnceLock::new();
    REF.get_or_init(|| {
        let d = tempfile::tempdir().unwrap();
        let t = Instant::now();
        let out = denoise_cmd(d.path()).output().unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let took = t.elapsed();
        let files = listing(d.path())
            .into_iter()
            .map(|n| {
                let p = pixels(&d.path().join(&n));
                (n, p)
            })
            .collect();
        (files, took)
    })
}

/// The names in a folder, sorted.
fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn is_radn_temporary(name: &str) -> bool {
    radn_core::io::output_locks::is_radn_temporary(name)
}

/// Asserts that `dir` holds only outputs identical to the uninterrupted run's and radn's own
/// temporary files; returns how many outputs are there.
fn only_whole_outputs(dir: &Path, when: &str) -> usize {
    let (want, _) = reference();
    let mut whole = 0;
    for name in listing(dir) {
        if is_radn_temporary(&name) {
            continue;
        }
        let expected = want
            .iter()
            .find(|(n, _)| *n == name)
            .unwrap_or_else(|| panic!("{when}: unexpected file {name}"));
        assert!(
            pixels(&dir.join(&name)) == expected.1,
            "{when}: {name} differs from the uninterrupted run's"
        );
        whole += 1;
    }
    whole
}

#[test]
fn killed_runs_leave_only_whole_frames_and_the_next_run_removes_their_debris() {
    let (want, took) = reference();
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out");
    std::fs::create_dir(&out).unwrap();
    // what the issue found: a zero-byte temporary file of a run killed in mid-write
    std::fs::write(out.join(".radn-Qx81Zk.exr.tmp"), b"").unwrap();
    // kills spread over a run's length: while reading, while denoising, while writing
    let mut killed_in_write = 0;
    for (i, part) in [0.15, 0.4, 0.55, 0.7, 0.85].into_iter().enumerate() {
        let mut child = denoise_cmd(&out)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(took.mul_f64(part));
        let _ = child.kill(); // SIGKILL: no destructor, no cleanup runs
        let status = child.wait().unwrap();
        if status.success() {
            break; // finished before the kill: nothing left to interrupt
        }
        let names = listing(&out);
        killed_in_write += usize::from(names.iter().any(|n| n.ends_with(".exr.tmp")));
        only_whole_outputs(&out, &format!("after kill {i}"));
    }
    // the next run finishes, skips what is done, and leaves no debris behind
    let done = denoise_cmd(&out).output().unwrap();
    assert!(
        done.status.success(),
        "{}",
        String::from_utf8_lossy(&done.stderr)
    );
    let names = listing(&out);
    assert!(
        names.iter().all(|n| !is_radn_temporary(n)),
        "debris left after a complete run: {names:?} (runs killed while writing: {killed_in_write})"
    );
    assert_eq!(only_whole_outputs(&out, "after the last run"), want.len());
}

#[cfg(unix)]
#[test]
fn an_interrupted_run_stops_at_its_next_band_and_leaves_nothing_of_its_own() {
    use std::io::BufRead;
    let (want, _) = reference();
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out");
    let mut child = denoise_cmd(&out)
        .args(["--progress", "json"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // SIGTERM (what a host application's cancel and `kill` send) once the first output frame is
    // done, while the rest are in progress
    let mut lines = std::io::BufReader::new(child.stderr.take().unwrap()).lines();
    let mut log = Vec::new();
    for line in lines.by_ref() {
        let line = line.unwrap();
        let event: serde_json::Value = serde_json::from_str(&line).unwrap_or_default();
        log.push(line);
        if event["event"] == "progress"
            && event["stage"] == event["stages"]
            && event["stage_done"].as_f64().unwrap_or(0.0) >= 1.0
        {
            // SAFETY: kill(2) on our own child's pid
            unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
            break;
        }
    }
    log.extend(lines.map(|l| l.unwrap()));
    let status = child.wait().unwrap();
    let log = log.join("\n");
    assert_eq!(status.code(), Some(130), "{log}");
    assert!(log.contains("error: cancelled"), "{log}");
    let names = listing(&out);
    assert!(
        names.iter().all(|n| !is_radn_temporary(n)),
        "a stopped run cleans up after itself: {names:?}"
    );
    let kept = only_whole_outputs(&out, "after SIGTERM");
    assert!((1..want.len()).contains(&kept), "{names:?}");
    // resuming writes the rest
    let done = denoise_cmd(&out).output().unwrap();
    assert!(done.status.success());
    assert_eq!(only_whole_outputs(&out, "resumed"), want.len());
}

#[test]
fn two_runs_on_one_output_write_each_frame_once_and_whole() {
    let (want, _) = reference();
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out");
    let spawn = || {
        denoise_cmd(&out)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let (a, b) = (spawn(), spawn());
    let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
    let mut written = 0;
    for o in [&a, &b] {
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let said = String::from_utf8_lossy(&o.stdout);
        let line = said
            .lines()
            .find(|l| l.starts_with("denoised "))
            .unwrap_or_default();
        let n: usize = line
            .split_whitespace()
            .nth(1)
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| panic!("no frame count in {line:?}"));
        written += n;
    }
    assert_eq!(
        written,
        want.len(),
        "frames written by both runs together (each frame once):\n{}\n{}",
        String::from_utf8_lossy(&a.stdout),
        String::from_utf8_lossy(&b.stdout)
    );
    let names = listing(&out);
    assert!(names.iter().all(|n| !is_radn_temporary(n)), "{names:?}");
    assert_eq!(only_whole_outputs(&out, "after both runs"), want.len());
}

/// Runs `script` with `sh` in a private mount namespace (as root, or as a mapped root in a user
/// namespace), or returns `None` where this machine allows neither.
fn in_mount_namespace(script: &str, env: &[(&str, &Path)]) -> Option<std::process::Output> {
    for flags in [&["--mount"][..], &["--mount", "--map-root-user"][..]] {
        let mut c = Command::new("unshare");
        c.args(flags).arg("sh").arg("-c").arg(script);
        for (k, v) in env {
            c.env(k, v);
        }
        match c.output() {
            // 99: the namespace came up but mounting a tmpfs in it was refused
            Ok(o) if o.status.code() != Some(99) && !unshare_refused(&o) => return Some(o),
            _ => continue,
        }
    }
    None
}

fn unshare_refused(o: &std::process::Output) -> bool {
    let e = String::from_utf8_lossy(&o.stderr);
    e.starts_with("unshare:")
}

#[test]
fn a_full_disk_ends_with_an_error_naming_the_file_and_nothing_partial() {
    let (want, _) = reference();
    let d = tempfile::tempdir().unwrap();
    let (small, kept) = (d.path().join("small"), d.path().join("kept"));
    std::fs::create_dir_all(&small).unwrap();
    std::fs::create_dir_all(&kept).unwrap();
    // room for two and a half frames
    let frame = std::fs::metadata(sample().join("low/frame_0006.exr"))
        .unwrap()
        .len() as usize;
    let size = PathBuf::from(format!("{}", frame * 5 / 2));
    let radn = PathBuf::from(env!("CARGO_BIN_EXE_radn"));
    let inp = PathBuf::from(input());
    let frames = PathBuf::from(FRAMES);
    let script = r#"mount -t tmpfs -o size="$SIZE" tmpfs "$SMALL" || exit 99
"$RADN" --threads 1 denoise --guide none -i "$INPUT" -o "$SMALL/frame_####.exr" --frames "$FRAMES"
rc=$?
cp -a "$SMALL/." "$KEPT/"
exit $rc"#;
    let env = [
        ("SIZE", size.as_path()),
        ("SMALL", small.as_path()),
        ("KEPT", kept.as_path()),
        ("RADN", radn.as_path()),
        ("INPUT", inp.as_path()),
        ("FRAMES", frames.as_path()),
    ];
    let Some(o) = in_mount_namespace(script, &env) else {
        eprintln!(
            "SKIPPED a_full_disk_ends_with_an_error_naming_the_file_and_nothing_partial: \
             this machine allows no private mount namespace (unshare --mount) to mount a small \
             tmpfs in"
        );
        return;
    };
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success(),
        "radn filled the disk and succeeded: {err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    let whole = only_whole_outputs(&kept, "on the full disk");
    assert!(
        whole >= 1 && whole < want.len(),
        "{whole} frames fit: {err}"
    );
    let failed = want[whole].0.as_str(); // the frames are written in order
    assert!(
        err.contains(&format!("{}/{failed}", small.display())),
        "the error does not name {failed}: {err}"
    );
    assert!(err.contains("No space left on device"), "{err}");
    let names = listing(&kept);
    assert!(
        names.iter().all(|n| !is_radn_temporary(n)),
        "temporary files left on the full disk: {names:?}"
    );
}

/// Tiles of the sample and a short training config (checkpoint every step) in `dir`.
fn training_setup(dir: &Path) -> PathBuf {
    for (set, seed) in [("train", "1"), ("val", "2")] {
        radn_ok(&[
            "--threads",
            "1",
            "prepare",
            "--data",
            sample().to_str().unwrap(),
            "--out",
            dir.join(set).to_str().unwrap(),
            "--tile",
            "32",
            "--tiles-per-window",
            "1",
            "--seed",
            seed,
        ]);
    }
    let cfg = dir.join("run.toml");
    std::fs::write(
        &cfg,
        "model = \"small\"\ntrain = \"train\"\nval = \"val\"\nbatch = 2\nsteps = 8\nlr = 1e-3\n\
         warmup = 2\nvalidate_every = 1\nval_tiles = 2\nseed = 5\n",
    )
    .unwrap();
    cfg
}

fn train_cmd(cfg: &Path, out: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_radn"));
    c.args(["--threads", "1", "train", "--config"])
        .arg(cfg)
        .arg("--out")
        .arg(out)
        .arg("--resume");
    c
}

/// The step a run's `state.json` has committed, after checking that the checkpoint it names is
/// there.
fn committed_step(run: &Path) -> Option<usize> {
    let text = std::fs::read_to_string(run.join("state.json")).ok()?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .unwrap_or_else(|e| panic!("state.json is not whole ({e}): {text:?}"));
    let step = v["step"].as_u64().unwrap() as usize;
    for f in radn_train::trainer::checkpoint_files(run, step) {
        assert!(
            f.exists(),
            "state.json names step {step}, {} is missing",
            f.display()
        );
    }
    Some(step)
}

#[test]
fn a_killed_training_run_resumes_from_its_last_complete_checkpoint() {
    let d = tempfile::tempdir().unwrap();
    let cfg = training_setup(d.path());
    // uninterrupted, for the duration and the final weights
    let t = Instant::now();
    let whole = d.path().join("whole");
    let o = train_cmd(&cfg, &whole).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let took = t.elapsed();
    // killed at points spread over a run (a checkpoint is written after every step), resumed
    let run = d.path().join("killed");
    let mut last = 0;
    for part in [0.2, 0.3, 0.45, 0.6, 0.75, 0.9] {
        let mut child = train_cmd(&cfg, &run)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(took.mul_f64(part));
        let _ = child.kill();
        if child.wait().unwrap().success() {
            break;
        }
        if let Some(step) = committed_step(&run) {
            assert!(
                step >= last,
                "the committed step went back from {last} to {step}"
            );
            last = step;
        }
    }
    let o = train_cmd(&cfg, &run).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(committed_step(&run), Some(8));
    let names = listing(&run);
    assert!(names.iter().all(|n| !is_radn_temporary(n)), "{names:?}");
    let ck: Vec<&String> = names.iter().filter(|n| n.ends_with(".bpk")).collect();
    assert_eq!(
        ck.len(),
        2,
        "only the last checkpoint's files remain: {names:?}"
    );
    // the same steps on the same batches: the resumed run ends where the whole one did
    let (a, b) = (tensors(&run), tensors(&whole));
    assert_eq!(a.len(), b.len());
    for ((name, x), (_, y)) in a.iter().zip(&b) {
        assert!(
            x == y,
            "{name}: the resumed run's weights differ from the uninterrupted run's"
        );
    }
}

/// The tensors of a run's `model.safetensors` (name, bytes), by name: the header's metadata
/// order differs between two writes of the same weights.
fn tensors(run: &Path) -> Vec<(String, Vec<u8>)> {
    let bytes = std::fs::read(run.join("model.safetensors")).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Map<String, serde_json::Value> =
        serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let data = &bytes[8 + n..];
    let mut v: Vec<(String, Vec<u8>)> = header
        .iter()
        .filter(|(k, _)| *k != "__metadata__")
        .map(|(k, t)| {
            let o = &t["data_offsets"];
            let (a, b) = (
                o[0].as_u64().unwrap() as usize,
                o[1].as_u64().unwrap() as usize,
            );
            (k.clone(), data[a..b].to_vec())
        })
        .collect();
    v.sort();
    v
}
