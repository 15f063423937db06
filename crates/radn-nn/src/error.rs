//! Errors of `radn-nn`.

use std::path::PathBuf;

/// Result alias for `radn-nn`.
pub type Result<T, E = NnError> = std::result::Result<T, E>;

/// What can go wrong building, loading or running a network.
#[derive(Debug, thiserror::Error)]
// each variant's fields are what its message names, in the message's words
#[allow(missing_docs)]
pub enum NnError {
    /// A network configuration is inconsistent.
    #[error("invalid network configuration: {0}")]
    Config(String),
    /// A model file cannot be read or is not a radn model.
    #[error("cannot load model '{path}': {detail}")]
    Load { path: PathBuf, detail: String },
    /// A prepared tile folder cannot be read or does not fit the network.
    #[error("cannot use the training tiles in '{path}': {detail}")]
    Tiles { path: PathBuf, detail: String },
    /// A model file cannot be written.
    #[error("cannot save model '{path}': {detail}")]
    Save { path: PathBuf, detail: String },
    /// The device asked for (`--device`) cannot be used.
    #[error("cannot use device '{device}': {detail}")]
    Device { device: String, detail: String },
    /// Errors from the frame side.
    #[error(transparent)]
    Core(#[from] radn_core::Error),
}
