//! Writing outputs safely: never over an input, folders proven writable before any work, and
//! every file (EXR, model, checkpoint, report, PNG) written through a temporary file renamed
//! into place, so a failed or killed write leaves nothing under the output's name.

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
/// It is locked for as long as it is open ([`crate::io::output_locks`]), so that a run starting on
/// the same folder can tell it from the debris of a killed run.
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
    loop {
        let tmp = b.tempfile_in(dir)?;
        if crate::io::output_locks::lock_created(tmp.as_file(), tmp.path())? {
            return Ok(tmp);
        }
        // another run's cleaner took it for debris before it was locked: make another
        drop(tmp);
    }
}

/// The temporary file's suffix for an output: its extension and `.tmp` (`.exr.tmp` for an EXR),
/// so a leftover one is recognisable as radn's and as what it was to become.
fn temp_suffix(path: &Path) -> String {
    match path.extension() {
        Some(e) => format!(".{}.tmp", e.to_string_lossy()),
        None => ".tmp".into(),
    }
}

/// Writes `path` through a temporary file in its folder (`.radn-XXXXXX.EXT.tmp`), which
/// `write` fills — through the open file, or by its path for writers that take one (model and
/// checkpoint stores) — and which is renamed into place only once `write` succeeded. A failed
/// write removes it, so nothing partial is left under the output's name nor beside it.
pub fn write_atomically_with<E: From<Error>>(
    path: &Path,
    write: impl FnOnce(&std::fs::File, &Path) -> std::result::Result<(), E>,
) -> std::result::Result<(), E> {
    let dir = create_parent(path)?;
    let tmp =
        output_tempfile(&dir, ".radn-", &temp_suffix(path)).map_err(|source| Error::Write {
            path: dir.clone(),
            source,
        })?;
    write(tmp.as_file(), tmp.path())?;
    // on the disk before it gets the output's name: a full disk or a failing network share
    // reports here at the latest (some file systems only at flush), and a machine that loses
    // power after the rename finds the whole file, not an empty one
    tmp.as_file().sync_all().map_err(|source| Error::Write {
        path: path.to_path_buf(),
        source,
    })?;
    tmp.persist(path).map_err(|e| Error::Write {
        path: path.to_path_buf(),
        source: e.error,
    })?;
    sync_folder(&dir);
    Ok(())
}

/// Makes a rename in `dir` durable (best effort: not every platform or file system can sync a
/// folder, and the file itself is already on the disk).
fn sync_folder(dir: &Path) {
    #[cfg(unix)]
    if let Ok(d) = std::fs::File::open(dir) {
        let _ = d.sync_all();
    }
    #[cfg(not(unix))]
    let _ = dir;
}

/// [`write_atomically_with`] through a buffered writer, flushed before the rename.
pub fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut std::io::BufWriter<&std::fs::File>) -> Result<()>,
) -> Result<()> {
    write_atomically_with(path, |file, _| {
        let mut writer = std::io::BufWriter::new(file);
        write(&mut writer)?;
        use std::io::Write;
        writer.flush().map_err(|source| Error::Write {
            path: path.to_path_buf(),
            source,
        })
    })
}

/// Writes `bytes` to `path` atomically (reports, manifests, logs).
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically(path, |w| {
        use std::io::Write;
        w.write_all(bytes).map_err(|source| Error::Write {
            path: path.to_path_buf(),
            source,
        })
    })
}

/// Pixel layout of an 8-bit PNG.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PngColor {
    /// One grey byte per pixel.
    Grey,
    /// Three bytes (R, G, B) per pixel.
    Rgb,
}

/// Encodes 8-bit pixels (rows top to bottom) as PNG bytes.
pub fn encode_png(pixels: &[u8], width: usize, height: usize, color: PngColor) -> Vec<u8> {
    let per_pixel = match color {
        PngColor::Grey => 1,
        PngColor::Rgb => 3,
    };
    assert_eq!(
        pixels.len(),
        width * height * per_pixel,
        "PNG pixels and size disagree"
    );
    let mut buf = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut buf, width as u32, height as u32);
        enc.set_color(match color {
            PngColor::Grey => png::ColorType::Grayscale,
            PngColor::Rgb => png::ColorType::Rgb,
        });
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header().expect("in-memory PNG header");
        w.write_image_data(pixels)
            .expect("in-memory PNG data of the checked size");
    }
    buf
}

/// Writes 8-bit pixels as a PNG file, atomically (heat maps, crops, training curves).
pub fn write_png(
    path: &Path,
    pixels: &[u8],
    width: usize,
    height: usize,
    color: PngColor,
) -> Result<()> {
    write_bytes_atomically(path, &encode_png(pixels, width, height, color))
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
/// temporary file in it, so a run fails before any work instead of after it. Then removes what
/// runs killed while writing there left behind ([`crate::io::output_locks::remove_stale`]).
pub fn ensure_writable_dir(output: &Path) -> Result<()> {
    let dir = create_parent(output)?;
    tempfile::Builder::new()
        .prefix(".radn-probe-")
        .suffix(".tmp")
        .tempfile_in(&dir)
        .map(drop)
        .map_err(|source| Error::Write {
            path: dir.clone(),
            source,
        })?;
    crate::io::output_locks::remove_stale(&dir)?;
    Ok(())
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

    #[test]
    fn atomic_writes_leave_the_file_whole_or_untouched_and_no_temporary_behind() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("sub/report.json");
        write_bytes_atomically(&p, b"{}").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"{}");
        // a writer that fails keeps the earlier file and removes its temporary file
        let failed: Result<()> = write_atomically_with(&p, |_, tmp| {
            assert!(
                tmp.to_string_lossy().ends_with(".json.tmp"),
                "{}",
                tmp.display()
            );
            std::fs::write(tmp, b"partial").unwrap();
            Err(Error::Unsupported {
                path: p.clone(),
                detail: "stopped".into(),
            })
        });
        assert!(failed.is_err());
        assert_eq!(std::fs::read(&p).unwrap(), b"{}");
        let names: Vec<_> = std::fs::read_dir(p.parent().unwrap()).unwrap().collect();
        assert_eq!(names.len(), 1, "only the report remains");
    }

    #[test]
    fn png_files_decode_to_the_pixels_written() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.png");
        let px: Vec<u8> = (0..2 * 3 * 3).map(|i| (i * 13) as u8).collect();
        write_png(&p, &px, 2, 3, PngColor::Rgb).unwrap();
        let mut r = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&p).unwrap()))
            .read_info()
            .unwrap();
        let mut buf = vec![0; r.output_buffer_size().unwrap()];
        let info = r.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (2, 3));
        assert_eq!(&buf[..info.buffer_size()], &px[..]);
    }
}
