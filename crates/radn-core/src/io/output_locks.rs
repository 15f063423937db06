//! Runs that share an output folder: advisory locks (`flock`) on what a run is writing, so that
//! a killed run's leftovers can be told from a live run's work, and claims that let two runs on
//! the same output (a farm retry racing the original) write each frame once, whole.
//!
//! - Every temporary file radn writes (`.radn-XXXXXX.EXT.tmp`) and every scratch folder
//!   (`.radn-passes-XXXXXX`) is locked by its writer for as long as it exists. The kernel drops
//!   the lock when the process ends, however it ends (`kill -9` included), so an unlocked one is
//!   debris: [`remove_stale`] removes those and leaves the locked ones alone.
//! - [`OutputClaim`] is an exclusive lock per output file, on a lock file beside it
//!   (`.radn-NAME.lock`), held from the check "is this frame done?" to its rename into place.
//!   A second run that reaches the frame waits for the first, then finds it done (or, if the
//!   first died, denoises it itself).
//!
//! The locks are `flock(2)` locks on Unix (on NFS, Linux maps them to NFS byte-range locks) and
//! `LockFileEx` on Windows, through `std::fs::File::lock`.

use std::fs::{File, OpenOptions};
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// The name prefix of every file and folder radn writes temporarily.
pub const TEMP_PREFIX: &str = ".radn-";

/// Whether `name` is one of radn's temporary files, lock files or scratch folders.
pub fn is_radn_temporary(name: &str) -> bool {
    name.starts_with(TEMP_PREFIX)
        && (name.ends_with(".tmp") || name.ends_with(".lock") || name.starts_with(".radn-passes-"))
}

/// Whether the open `file` is still the one at `path` (it was not removed or replaced between
/// opening and locking it).
fn still_at(file: &File, path: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (file.metadata(), std::fs::metadata(path)) {
            (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        let _ = file;
        path.exists()
    }
}

/// Locks a file or folder just created at `path` through `handle` (which it keeps open) and
/// checks that it is still there: [`remove_stale`] in another run may have taken it for debris
/// in the moment between creation and lock. `false` means it was removed; make another.
pub fn lock_created(handle: &File, path: &Path) -> std::io::Result<bool> {
    match handle.try_lock() {
        Ok(()) => Ok(still_at(handle, path)),
        // someone else holds it: only the cleaner does, briefly, before removing it
        Err(std::fs::TryLockError::WouldBlock) => Ok(false),
        Err(std::fs::TryLockError::Error(e)) => Err(e),
    }
}

/// Opens a folder so that it can be locked (Unix: a read-only descriptor of the folder).
pub fn open_folder(path: &Path) -> std::io::Result<File> {
    File::open(path)
}

/// A scratch folder (`.radn-passes-XXXXXX` in the output's folder) for a run's intermediate
/// files, locked while the run lives and removed, with what it holds, when dropped.
#[derive(Debug)]
pub struct ScratchFolder {
    // declared first: dropped (removed) before the lock is let go
    dir: tempfile::TempDir,
    _lock: File,
}

impl ScratchFolder {
    /// Creates and locks a scratch folder named `PREFIX` and random characters in `parent`.
    pub fn create(parent: &Path, prefix: &str) -> std::io::Result<Self> {
        loop {
            let dir = tempfile::Builder::new().prefix(prefix).tempdir_in(parent)?;
            let lock = open_folder(dir.path())?;
            if lock_created(&lock, dir.path())? {
                return Ok(Self { dir, _lock: lock });
            }
        }
    }

    /// Where it is.
    pub fn path(&self) -> &Path {
        self.dir.path()
    }
}

/// Removes radn's temporary files, lock files and scratch folders in `dir` that no running
/// process holds: what runs killed while writing left behind. Returns how many were removed.
/// Entries a live run holds are left alone; one that cannot be removed is logged and kept.
pub fn remove_stale(dir: &Path) -> Result<usize> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(source) => {
            return Err(Error::Write {
                path: dir.to_path_buf(),
                source,
            })
        }
    };
    let mut removed = 0;
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(name) = name.to_str() else { continue };
        if !is_radn_temporary(name) {
            continue;
        }
        let path = entry.path();
        let is_dir = entry.file_type().is_ok_and(|t| t.is_dir());
        let handle = if is_dir {
            open_folder(&path)
        } else {
            OpenOptions::new().read(true).open(&path)
        };
        let Ok(handle) = handle else { continue }; // removed meanwhile, or not ours to open
        match handle.try_lock() {
            Ok(()) => {}
            Err(_) => continue, // a live run is writing it (or locks are unsupported here)
        }
        if !still_at(&handle, &path) {
            continue;
        }
        let gone = if is_dir {
            std::fs::remove_dir_all(&path)
        } else {
            std::fs::remove_file(&path)
        };
        match gone {
            Ok(()) => {
                tracing::info!(
                    "removed {} (left by a run that was stopped)",
                    path.display()
                );
                removed += 1;
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => tracing::warn!("could not remove {}: {e}", path.display()),
        }
    }
    Ok(removed)
}

/// An exclusive claim on one output file, held while it is computed and written: two runs
/// writing the same output never work on the same file at once. Dropping it releases it and
/// removes its lock file.
#[derive(Debug)]
pub struct OutputClaim {
    lock: PathBuf,
    file: File,
}

impl OutputClaim {
    /// The lock file of `output`: `.radn-NAME.lock` in its folder.
    pub fn lock_path(output: &Path) -> PathBuf {
        let name = output
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        output.with_file_name(format!("{TEMP_PREFIX}{name}.lock"))
    }

    /// Claims `output`, waiting while another run holds it (`waiting` is called once, before
    /// the wait, so the caller can say why it pauses).
    pub fn acquire(output: &Path, waiting: impl FnOnce()) -> Result<Self> {
        let lock = Self::lock_path(output);
        let err = |source| Error::Write {
            path: lock.clone(),
            source,
        };
        if let Some(dir) = lock.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|source| Error::Write {
                path: dir.to_path_buf(),
                source,
            })?;
        }
        let mut waiting = Some(waiting);
        loop {
            let file = OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&lock)
                .map_err(err)?;
            match file.try_lock() {
                Ok(()) => {}
                Err(std::fs::TryLockError::WouldBlock) => {
                    if let Some(w) = waiting.take() {
                        w();
                    }
                    file.lock().map_err(err)?;
                }
                Err(std::fs::TryLockError::Error(e)) => return Err(err(e)),
            }
            // the holder we waited for removes the lock file as it lets go: a lock on that
            // file is no claim any more, so claim the one at the path now
            if still_at(&file, &lock) {
                return Ok(Self { lock, file });
            }
        }
    }
}

impl Drop for OutputClaim {
    fn drop(&mut self) {
        // removed while still locked, so that no one can take the old file for a live claim
        let _ = std::fs::remove_file(&self.lock);
        let _ = self.file.unlock();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    use std::time::Duration;

    #[test]
    fn only_unlocked_temporaries_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let stale = d.join(".radn-abc123.exr.tmp");
        let live = d.join(".radn-def456.exr.tmp");
        let stale_dir = d.join(".radn-passes-xyz");
        let stale_lock = d.join(".radn-frame_0001.exr.lock");
        let users = [
            d.join("frame_0001.exr"),
            d.join(".radn-notes.txt"),
            d.join("x.tmp"),
        ];
        for p in [&stale, &live, &stale_lock].into_iter().chain(&users) {
            std::fs::write(p, b"x").unwrap();
        }
        std::fs::create_dir(&stale_dir).unwrap();
        std::fs::write(stale_dir.join("frame_0001.exr"), b"x").unwrap();
        // a live writer: another open file description holding the lock
        let holder = File::open(&live).unwrap();
        holder.lock().unwrap();
        assert_eq!(remove_stale(d).unwrap(), 3);
        assert!(!stale.exists() && !stale_dir.exists() && !stale_lock.exists());
        assert!(
            live.exists(),
            "a temporary file a live run holds was removed"
        );
        for u in &users {
            assert!(u.exists(), "{} is the user's, not radn's", u.display());
        }
        drop(holder);
        assert_eq!(remove_stale(d).unwrap(), 1, "released: now it is debris");
        assert!(remove_stale(&d.join("missing")).unwrap() == 0);
    }

    #[test]
    fn a_claim_waits_for_the_holder_and_then_holds_alone() {
        let dir = tempfile::tempdir().unwrap();
        // in a folder not made yet: the claim comes before the write that would make it
        let out = dir.path().join("new/frame_0007.exr");
        let first = OutputClaim::acquire(&out, || panic!("nothing held it")).unwrap();
        assert!(OutputClaim::lock_path(&out).exists());
        let waited = Arc::new(AtomicBool::new(false));
        let released = Arc::new(AtomicBool::new(false));
        let second = {
            let (out, waited, released) = (out.clone(), waited.clone(), released.clone());
            std::thread::spawn(move || {
                let c =
                    OutputClaim::acquire(&out, || waited.store(true, Ordering::SeqCst)).unwrap();
                assert!(
                    released.load(Ordering::SeqCst),
                    "claimed while the first run held it"
                );
                // a third claimant must wait for this one in turn: the lock file it holds is
                // the one at the path, not the removed one of the first claim
                let f = File::open(OutputClaim::lock_path(&out)).unwrap();
                assert!(
                    f.try_lock().is_err(),
                    "the second claim is not on the path's file"
                );
                drop(c);
            })
        };
        std::thread::sleep(Duration::from_millis(200));
        assert!(
            waited.load(Ordering::SeqCst),
            "the second claimant did not wait"
        );
        released.store(true, Ordering::SeqCst);
        drop(first);
        second.join().unwrap();
        assert!(
            !OutputClaim::lock_path(&out).exists(),
            "a released claim leaves its lock file behind"
        );
        // a live claim survives the cleaner; a released one is not there to clean
        let c = OutputClaim::acquire(&out, || {}).unwrap();
        assert_eq!(remove_stale(out.parent().unwrap()).unwrap(), 0);
        assert!(OutputClaim::lock_path(&out).exists());
        drop(c);
    }
}
