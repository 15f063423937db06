//! A run's files on disk: checkpoints named by their step, the kept weights of each
//! validation point, and metrics rows trimmed back to the last checkpoint on resumption.

use std::path::{Path, PathBuf};

use radn_core::io::output::write_bytes_atomically;
use radn_nn::error::Result;

/// Removes the rows logged after `step` from a run's metrics CSV (left by a run killed between
/// checkpoints), so a resumed run's curves have one row per step and kind.
pub(crate) fn drop_metrics_after(path: &Path, step: usize) -> Result<()> {
    drop_rows_from(path, step + 1)
}

/// Removes the rows of a run's CSV whose first column (a step) is `first` or later.
pub(crate) fn drop_rows_from(path: &Path, first: usize) -> Result<()> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Ok(()); // no metrics yet
    };
    // a last line without its newline is a row cut short by a kill in mid-append
    let whole = match text.rfind('\n') {
        Some(i) => &text[..=i],
        None => "",
    };
    let kept: String = whole
        .lines()
        .enumerate()
        .filter(|(i, l)| {
            *i == 0
                || l.split(',')
                    .next()
                    .and_then(|s| s.parse::<usize>().ok())
                    .is_none_or(|s| s < first)
        })
        .map(|(_, l)| format!("{l}\n"))
        .collect();
    if kept.len() == text.len() {
        return Ok(());
    }
    write_bytes_atomically(path, kept.as_bytes())?;
    Ok(())
}

/// A run's checkpoint files for `step`: the Burnpack weights and the optimizer state.
pub fn checkpoint_files(out: &Path, step: usize) -> [PathBuf; 2] {
    [
        out.join(format!("checkpoint-{step:07}.bpk")),
        out.join(format!("optimizer-{step:07}.bpk")),
    ]
}

/// Whether `name` is a checkpoint file of some step (or of a run from before checkpoint files
/// were named by step).
fn is_checkpoint_file(name: &str) -> bool {
    let numbered = |prefix: &str| {
        name.strip_prefix(prefix)
            .and_then(|r| r.strip_suffix(".bpk"))
            .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
    };
    numbered("checkpoint-")
        || numbered("optimizer-")
        || numbered("temporal-optimizer-")
        || name == "checkpoint.bpk"
        || name == "optimizer.bpk"
}

/// Removes the checkpoint files of every step but `keep` (an earlier checkpoint, or the
/// uncommitted one of a run killed before its `state.json`). A file that cannot be removed
/// is logged and left: it costs disk, not correctness.
pub(crate) fn remove_other_checkpoints(out: &Path, keep: usize) {
    let kept = checkpoint_files(out, keep);
    let Ok(entries) = std::fs::read_dir(out) else {
        return;
    };
    for e in entries.flatten() {
        let path = e.path();
        let name = e.file_name();
        let name = name.to_string_lossy();
        let kept_step = name.ends_with(&format!("-{keep:07}.bpk"));
        if is_checkpoint_file(&name) && !kept.contains(&path) && !kept_step {
            if let Err(err) = std::fs::remove_file(&path) {
                tracing::warn!("could not remove {}: {err}", path.display());
            }
        }
    }
}

/// Where a run keeps the weights of one validation point (`keep_steps`).
pub fn step_model_path(out: &Path, step: usize) -> PathBuf {
    out.join("steps").join(format!("step-{step}.safetensors"))
}
