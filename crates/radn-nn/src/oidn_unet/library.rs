//! Reading OIDN's trained weights out of an OIDN 2.x core library: every such library carries
//! each model as a TZA blob in its read-only data under a symbol `oidn::blobs::weights::NAME`,
//! listed in the static symbol table, the dynamic one, or both (the `pyoidn` wheel's has both,
//! Blender's only the dynamic one). A symbol's file offset is its address less its section's
//! address plus the section's file offset; the blob's length is the symbol's size where the
//! format records one, else the span of the archive's own table.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use object::{Object, ObjectSection, ObjectSymbol};

use crate::oidn_unet::tza;

/// What can go wrong finding a model's weights in a library.
#[derive(Debug, thiserror::Error)]
// each variant's fields are what its message names
#[allow(missing_docs)]
pub enum LibraryError {
    /// The file cannot be read.
    #[error("cannot read '{path}': {detail}")]
    Read { path: PathBuf, detail: String },
    /// The file is not a shared library radn can read, or carries no OIDN weights.
    #[error("'{path}' is not an OIDN 2.x core library: {detail}")]
    NotOidn { path: PathBuf, detail: String },
    /// The library has no model of that name.
    #[error("'{path}' has no OIDN weights named '{name}' (it has: {have})")]
    NoSuchWeights {
        path: PathBuf,
        name: String,
        have: String,
    },
    /// The blob is there but unreadable.
    #[error("the weights '{name}' in '{path}' are corrupt: {source}")]
    Blob {
        path: PathBuf,
        name: String,
        source: tza::TzaError,
    },
}

/// An OIDN core library opened for its weights.
pub struct WeightsLibrary {
    path: PathBuf,
    bytes: Vec<u8>,
    /// Model name → (file offset, size where the symbol records one).
    blobs: BTreeMap<String, (usize, Option<usize>)>,
}

impl WeightsLibrary {
    /// Opens `path`: an OIDN core library (`libOpenImageDenoise_core.so.2.x.y` or its kin on
    /// other systems), or the main OIDN library or a folder beside which the core library lies.
    pub fn open(path: &Path) -> Result<Self, LibraryError> {
        let file = core_library(path)?;
        let bytes = std::fs::read(&file).map_err(|e| LibraryError::Read {
            path: file.clone(),
            detail: e.to_string(),
        })?;
        let blobs = weight_symbols(&bytes).map_err(|detail| LibraryError::NotOidn {
            path: file.clone(),
            detail,
        })?;
        if blobs.is_empty() {
            return Err(LibraryError::NotOidn {
                path: file,
                detail: "it has no oidn::blobs::weights symbols".into(),
            });
        }
        Ok(Self {
            path: file,
            bytes,
            blobs,
        })
    }

    /// The library file the weights are read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The names of the models the library carries, sorted.
    pub fn names(&self) -> Vec<String> {
        self.blobs.keys().cloned().collect()
    }

    /// OIDN's version, from the library's file name (`…so.2.5.1`, `…2.3.3.dylib`), where it
    /// has one.
    pub fn version(&self) -> Option<String> {
        version_in_name(&self.path)
    }

    /// The raw TZA blob of model `name`.
    pub fn blob(&self, name: &str) -> Result<&[u8], LibraryError> {
        let &(offset, size) = self
            .blobs
            .get(name)
            .ok_or_else(|| LibraryError::NoSuchWeights {
                path: self.path.clone(),
                name: name.to_string(),
                have: self.names().join(", "),
            })?;
        let corrupt = |source| LibraryError::Blob {
            path: self.path.clone(),
            name: name.to_string(),
            source,
        };
        let rest = self
            .bytes
            .get(offset..)
            .ok_or(corrupt(tza::TzaError::Truncated("library")))?;
        let len = match size {
            Some(n) if n > 0 => n,
            _ => tza::extent(rest).map_err(corrupt)?,
        };
        rest.get(..len)
            .ok_or(corrupt(tza::TzaError::Truncated("library")))
    }

    /// Model `name`'s tensors.
    pub fn tensors(&self, name: &str) -> Result<BTreeMap<String, tza::TzaTensor>, LibraryError> {
        tza::parse(self.blob(name)?).map_err(|source| LibraryError::Blob {
            path: self.path.clone(),
            name: name.to_string(),
            source,
        })
    }
}

/// The core library for `path`: itself when it carries weights symbols by name, else the
/// `OpenImageDenoise_core` library in its folder (following a link to the main library).
fn core_library(path: &Path) -> Result<PathBuf, LibraryError> {
    let not_found = |detail: String| LibraryError::Read {
        path: path.to_path_buf(),
        detail,
    };
    let meta = std::fs::metadata(path).map_err(|e| not_found(e.to_string()))?;
    let is_core = |p: &Path| {
        p.file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.contains("OpenImageDenoise_core"))
    };
    if meta.is_file() && (is_core(path) || !is_oidn_named(path)) {
        return Ok(path.to_path_buf());
    }
    let dir = if meta.is_dir() {
        path.to_path_buf()
    } else {
        let real = std::fs::canonicalize(path).map_err(|e| not_found(e.to_string()))?;
        real.parent().map(Path::to_path_buf).unwrap_or_default()
    };
    let mut found: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map_err(|e| not_found(e.to_string()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| is_core(p) && p.is_file())
        .collect();
    // the most specific name (the versioned file, not its links) first
    found.sort_by_key(|p| std::cmp::Reverse(p.as_os_str().len()));
    found
        .into_iter()
        .next()
        .ok_or_else(|| LibraryError::NotOidn {
            path: path.to_path_buf(),
            detail: format!(
                "no OpenImageDenoise_core library beside it in '{}'",
                dir.display()
            ),
        })
}

/// Whether a file is named like one of OIDN's libraries.
fn is_oidn_named(p: &Path) -> bool {
    p.file_name()
        .and_then(|n| n.to_str())
        .is_some_and(|n| n.contains("OpenImageDenoise"))
}

/// The `major.minor.patch` in a library's file name.
fn version_in_name(p: &Path) -> Option<String> {
    let name = p.file_name()?.to_str()?;
    name.split(|c: char| !(c.is_ascii_digit() || c == '.'))
        .map(|s| s.trim_matches('.'))
        .find(|s| s.split('.').count() == 3 && s.split('.').all(|d| !d.is_empty()))
        .map(str::to_string)
}

/// The OIDN model name a symbol names, if it is one of the weights blobs: Itanium mangling
/// (`_ZN4oidn5blobs7weights14rt_hdr_alb_nrmE`, with a leading `_` on macOS) or MSVC's
/// (`?rt_hdr_alb_nrm@weights@blobs@oidn@@…`).
fn model_name(symbol: &str) -> Option<String> {
    let s = symbol.trim_start_matches('_');
    if let Some(rest) = s.strip_prefix("ZN4oidn5blobs7weights") {
        let digits = rest.chars().take_while(char::is_ascii_digit).count();
        let len: usize = rest[..digits].parse().ok()?;
        let name = rest.get(digits..digits + len)?;
        return (rest.get(digits + len..)? == "E").then(|| name.to_string());
    }
    let rest = symbol.strip_prefix('?')?;
    let (name, tail) = rest.split_once('@')?;
    tail.starts_with("weights@blobs@oidn@@")
        .then(|| name.to_string())
}

/// Every weights symbol of an object file: model name → (file offset, recorded size).
fn weight_symbols(bytes: &[u8]) -> Result<BTreeMap<String, (usize, Option<usize>)>, String> {
    let file = object::File::parse(bytes).map_err(|e| format!("not a shared library ({e})"))?;
    let mut out = BTreeMap::new();
    for sym in file.symbols().chain(file.dynamic_symbols()) {
        let Some(name) = sym.name().ok().and_then(model_name) else {
            continue;
        };
        if out.contains_key(&name) {
            continue;
        }
        let Some(index) = sym.section_index() else {
            continue;
        };
        let section = file
            .section_by_index(index)
            .map_err(|e| format!("symbol {name}: {e}"))?;
        let Some((file_start, file_len)) = section.file_range() else {
            continue;
        };
        let within = sym
            .address()
            .checked_sub(section.address())
            .filter(|&o| o < file_len)
            .ok_or_else(|| format!("symbol {name} lies outside its section"))?;
        let offset = usize::try_from(file_start + within).map_err(|e| e.to_string())?;
        let size = usize::try_from(sym.size()).ok().filter(|&s| s > 0);
        out.insert(name, (offset, size));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_symbols_are_recognised_in_both_manglings() {
        assert_eq!(
            model_name("_ZN4oidn5blobs7weights14rt_hdr_alb_nrmE").as_deref(),
            Some("rt_hdr_alb_nrm")
        );
        assert_eq!(
            model_name("__ZN4oidn5blobs7weights6rt_albE").as_deref(),
            Some("rt_alb")
        );
        assert_eq!(
            model_name("?rt_nrm_large@weights@blobs@oidn@@3QBEB").as_deref(),
            Some("rt_nrm_large")
        );
        assert_eq!(model_name("_ZN4oidn5blobs7weights14rt_hdrE"), None);
        assert_eq!(model_name("_ZN4oidn6Device6commitEv"), None);
    }

    #[test]
    fn the_version_comes_from_the_file_name() {
        let v = |n: &str| version_in_name(Path::new(n));
        assert_eq!(
            v("/x/libOpenImageDenoise_core.so.2.5.1").as_deref(),
            Some("2.5.1")
        );
        assert_eq!(
            v("libOpenImageDenoise_core.2.3.3.dylib").as_deref(),
            Some("2.3.3")
        );
        assert_eq!(v("OpenImageDenoise_core.dll"), None);
    }

    #[test]
    fn files_that_are_not_oidn_libraries_are_refused_with_a_reason() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("libfoo.so");
        std::fs::write(&p, b"\x7fELF not really").unwrap();
        let e = WeightsLibrary::open(&p).err().unwrap().to_string();
        assert!(e.contains("not an OIDN 2.x core library"), "{e}");
        let e = WeightsLibrary::open(&d.path().join("missing.so"))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("cannot read"), "{e}");
        // a folder without a core library
        let e = WeightsLibrary::open(d.path()).err().unwrap().to_string();
        assert!(e.contains("no OpenImageDenoise_core library"), "{e}");
    }
}
