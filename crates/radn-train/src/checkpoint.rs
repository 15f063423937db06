//! A run's files on disk: checkpoints named by their step, the kept weights of each
//! validation point, and metrics rows trimmed back to the last checkpoint on resumption.

use std::path::{Path, PathBuf};

use burn::module::Module;
use burn::store::ModuleSnapshot;
use radn_core::io::output::{write_atomically_with, write_bytes_atomically};
use radn_nn::error::{NnError, Result};

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

/// Writes a checkpoint of step `step` into `out`: `net`'s weights (Burnpack, with parameter
/// ids) and each optimizer's state to its file (the first to [`checkpoint_files`]' optimizer
/// file), then `state` as `state.json` — the commit: a run killed at any point resumes from
/// the last checkpoint whose `state.json` was written — then removes every older checkpoint.
pub(crate) fn write_checkpoint<M: Module>(
    out: &Path,
    step: usize,
    net: &M,
    optimizers: &[(PathBuf, &burn::optim::ModuleOptimizer)],
    state: &impl serde::Serialize,
) -> Result<()> {
    let save = |path: &Path, e: String| NnError::Save {
        path: path.to_path_buf(),
        detail: e,
    };
    let [weights, _] = checkpoint_files(out, step);
    write_atomically_with(&weights, |_, tmp| {
        let mut bp = burn::store::BurnpackStore::from_file(tmp).overwrite(true);
        net.save_into(&mut bp)
            .map_err(|e| save(tmp, format!("{e:?}")))
    })?;
    for (path, optim) in optimizers {
        write_atomically_with(path, |_, tmp| {
            optim.save(tmp).map_err(|e| save(tmp, format!("{e:?}")))
        })?;
    }
    let st = serde_json::to_string_pretty(state).expect("state serialises");
    write_bytes_atomically(&out.join("state.json"), st.as_bytes())?;
    remove_other_checkpoints(out, step);
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
