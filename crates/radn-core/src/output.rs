//! Safety checks for outputs: never overwrite an input, fail early on unwritable folders.

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// Refuses an output path that names one of the inputs (compared after resolving links and
/// relative paths).
pub fn ensure_not_input(output: &Path, inputs: &[PathBuf]) -> Result<()> {
    let out = normalize(output);
    for i in inputs {
        if normalize(i) == out {
            return Err(Error::OverwritesInput {
                path: output.to_path_buf(),
            });
        }
    }
    Ok(())
}

/// A temporary file in `dir` for an output that is renamed into place once complete. It gets
/// the permissions a plainly created file would (0666 less the umask) rather than tempfile's
/// private 0600, so results stay readable by the rest of a pipeline (compositors, other users).
pub fn output_tempfile(
    dir: &Path,
    prefix: &str,
    suffix: &str,
) -> std::io::Result<tempfile::NamedTempFile> {
    let mut b = tempfile::Builder::new();
    b.prefix(prefix).suffix(suffix);
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        b.permissions(std::fs::Permissions::from_mode(0o666));
    }
    b.tempfile_in(dir)
}

/// Writes `path` through a temporary file in its folder that is renamed into place only once
/// `write` succeeded and everything is flushed, so a failed or killed write never leaves a
/// partial file under the output's name (nor a temporary one: it is removed on failure).
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut std::io::BufWriter<&std::fs::File>) -> Result<()>,
) -> Result<()> {
    let dir = create_parent(path)?;
    let tmp = output_tempfile(&dir, ".radn-", ".exr.tmp").map_err(|source| Error::Write {
        path: dir.clone(),
        source,
    })?;
    {
        let mut writer = std::io::BufWriter::new(tmp.as_file());
        write(&mut writer)?;
        use std::io::Write;
        writer.flush().map_err(|source| Error::Write {
            path: path.to_path_buf(),
            source,
        })?;
    }
    tmp.persist(path).map_err(|e| Error::Write {
        path: path.to_path_buf(),
        source: e.error,
    })?;
    Ok(())
}

/// The folder a file is written into (`.` for a bare name), created if missing.
fn create_parent(path: &Path) -> Result<PathBuf> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&dir).map_err(|source| Error::Write {
        path: dir.clone(),
        source,
    })?;
    Ok(dir)
}

/// Creates the folder of `output` if needed and proves it writable by creating and removing a
/// temporary file in it, so a run fails before any work instead of after it.
pub fn ensure_writable_dir(output: &Path) -> Result<()> {
    let dir = create_parent(output)?;
    tempfile::Builder::new()
        .prefix(".radn-probe-")
        .tempfile_in(&dir)
        .map(drop)
        .map_err(|source| Error::Write { path: dir, source })
}

fn normalize(p: &Path) -> PathBuf {
    if let Ok(c) = p.canonicalize() {
        return c;
    }
    // the file does not exist yet: resolve its folder
    let abs = if p.is_absolute() {
        p.to_path_buf()
    } else {
        std::env::current_dir().unwrap_or_default().join(p)
    };
    match (
        abs.parent().and_then(|d| d.canonicalize().ok()),
        abs.file_name(),
    ) {
        (Some(d), Some(n)) => d.join(n),
        _ => abs,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_file_by_another_path_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a.exr");
        std::fs::write(&a, b"x").unwrap();
        let other = dir.path().join("sub/../a.exr");
        std::fs::create_dir(dir.path().join("sub")).unwrap();
        assert!(ensure_not_input(&other, std::slice::from_ref(&a)).is_err());
        assert!(ensure_not_input(&dir.path().join("b.exr"), &[a]).is_ok());
    }

    #[cfg(unix)]
    #[test]
    fn unwritable_folder_is_reported() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let ro = dir.path().join("ro");
        std::fs::create_dir(&ro).unwrap();
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
        // root ignores permission bits; only assert when the folder really is read-only
        if tempfile::tempfile_in(&ro).is_err() {
            let e = ensure_writable_dir(&ro.join("x.exr"))
                .unwrap_err()
                .to_string();
            assert!(e.contains("ro"), "{e}");
        }
        // a folder that is a file can never be created, even as root
        let file = dir.path().join("file");
        std::fs::write(&file, b"").unwrap();
        let e = ensure_writable_dir(&file.join("out.exr"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("file"), "{e}");
    }
}
