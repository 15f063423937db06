//! The error type of `radn-core`: every failure names the file (and channel) it concerns.

use std::path::PathBuf;

/// Result alias for `radn-core`.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong reading, checking, aligning or writing frames.
#[derive(Debug, thiserror::Error)]
// each variant's fields are what its message names, in the message's words
#[allow(missing_docs)]
pub enum Error {
    /// The file does not exist or cannot be opened.
    #[error("cannot open '{path}': {source}")]
    Open {
        path: PathBuf,
        source: std::io::Error,
    },

    /// The file exists but is not an OpenEXR file.
    #[error("'{path}' is not an OpenEXR file (its first bytes are not the EXR magic number)")]
    NotExr { path: PathBuf },

    /// The file is an EXR but could not be decoded (truncated, corrupt, or unsupported).
    #[error("cannot decode EXR '{path}': {detail}")]
    Decode { path: PathBuf, detail: String },

    /// A channel the preset needs is not in the file.
    #[error("'{path}' has no {what} channels for preset '{preset}' (looked for {looked_for}); channels present: {present}")]
    MissingChannel {
        path: PathBuf,
        what: String,
        preset: String,
        looked_for: String,
        present: String,
    },

    /// Several view layers hold the channels and none was chosen.
    #[error(
        "'{path}': {what} channels exist in several layers ({layers}); choose one with --layer"
    )]
    AmbiguousLayer {
        path: PathBuf,
        what: String,
        layers: String,
    },

    /// A frame's guide could not be read or computed (`path` empty where no file is at fault,
    /// e.g. Intel Open Image Denoise is not installed).
    #[error("{}", guide_message(.path, .detail))]
    Guide { path: PathBuf, detail: String },

    /// A file of a sequence differs in size from the others.
    #[error("'{path}' is {found_w}x{found_h} but the sequence is {expected_w}x{expected_h}")]
    SizeMismatch {
        path: PathBuf,
        expected_w: usize,
        expected_h: usize,
        found_w: usize,
        found_h: usize,
    },

    /// The layers inside one file differ in size or use subsampling, which radn does not support.
    #[error("'{path}': {detail}")]
    Unsupported { path: PathBuf, detail: String },

    /// A frame inside the requested range does not exist on disk.
    #[error("frame {frame} of the sequence is missing: '{path}' does not exist")]
    MissingFrame { frame: i64, path: PathBuf },

    /// No frame of a sequence pattern exists.
    #[error("no file matches the sequence pattern '{pattern}'")]
    EmptySequence { pattern: String },

    /// NaN or infinite samples, when the policy says to refuse them.
    #[error("'{path}': channel '{channel}' has {count} NaN/Inf samples (use --nonfinite repair to repair them)")]
    NonFinite {
        path: PathBuf,
        channel: String,
        count: usize,
    },

    /// A sequence pattern or frame range cannot be parsed.
    #[error("invalid {what} '{text}': {detail}")]
    Parse {
        what: &'static str,
        text: String,
        detail: String,
    },

    /// A channel mapping file is malformed.
    #[error("invalid channel mapping '{path}': {detail}")]
    Mapping { path: PathBuf, detail: String },

    /// Writing would replace one of the inputs.
    #[error("refusing to write '{path}': it is one of the input files")]
    OverwritesInput { path: PathBuf },

    /// The output folder cannot be created or written to.
    #[error("cannot write to '{path}': {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },

    /// A temporary file of the run (a frame's per-frame features kept on disk) failed.
    #[error("'{path}': {detail}: {source}")]
    Scratch {
        path: PathBuf,
        detail: String,
        source: std::io::Error,
    },

    /// Encoding the output EXR failed.
    #[error("cannot encode EXR '{path}': {detail}")]
    Encode { path: PathBuf, detail: String },

    /// Two images that must match in size do not.
    #[error("{what}: sizes differ ({a_w}x{a_h} vs {b_w}x{b_h})")]
    Incompatible {
        what: String,
        a_w: usize,
        a_h: usize,
        b_w: usize,
        b_h: usize,
    },

    /// Two sequences to compare share no frame number.
    #[error("no frame number is in both '{result}' and '{reference}'")]
    NoCommonFrames { result: String, reference: String },

    /// A dataset folder holds no scene of the expected layout.
    #[error("'{path}' holds no scene with a '{level}' folder")]
    NoScenes { path: PathBuf, level: String },

    /// The output pattern names the input sequence.
    #[error("refusing to write: the output pattern '{pattern}' is the input pattern")]
    OutputIsInput { pattern: String },

    /// The run was asked to stop (Ctrl-C, SIGTERM, or a host application's cancel).
    #[error("cancelled: the frames finished before are kept, the one in progress was discarded")]
    Cancelled,
}

fn guide_message(path: &std::path::Path, detail: &str) -> String {
    if path.as_os_str().is_empty() {
        detail.to_string()
    } else {
        format!("'{}': guide: {detail}", path.display())
    }
}
