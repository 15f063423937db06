//! Importing one of OIDN's trained models from an OIDN 2.x core library into a radn U-Net.

use std::path::Path;

use burn::tensor::Device;

use crate::oidn_unet::config::UnetConfig;
use crate::oidn_unet::library::{LibraryError, WeightsLibrary};
use crate::oidn_unet::OidnUnet;

/// OIDN's model for a noisy beauty with noisy albedo and normal: what `import-oidn` takes when
/// no name is given, and what `--method spatial` runs by default.
pub const DEFAULT_WEIGHTS: &str = "rt_hdr_alb_nrm";

/// What can go wrong importing.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// The library or its blob.
    #[error(transparent)]
    Library(#[from] LibraryError),
    /// The blob's tensors do not make one of OIDN's U-Nets.
    #[error("the weights '{name}' in '{path}' are not a U-Net radn can run: {detail}")]
    Shape {
        /// The model name.
        name: String,
        /// The library.
        path: std::path::PathBuf,
        /// What does not fit.
        detail: String,
    },
}

/// Reads OIDN's model `name` from `library` into a U-Net on `device`.
pub fn import(
    library: &WeightsLibrary,
    name: &str,
    device: &Device,
) -> Result<OidnUnet, ImportError> {
    let tensors = library.tensors(name)?;
    let version = library.version().unwrap_or_else(|| "unknown".into());
    let shape = |detail| ImportError::Shape {
        name: name.to_string(),
        path: library.path().to_path_buf(),
        detail,
    };
    let config = UnetConfig::from_tensors(name, &version, &tensors).map_err(shape)?;
    let weights: Vec<(Vec<f32>, Vec<f32>)> = config
        .convs
        .iter()
        .map(|c| {
            (
                tensors[&format!("{}.weight", c.name)].values.clone(),
                tensors[&format!("{}.bias", c.name)].values.clone(),
            )
        })
        .collect();
    Ok(OidnUnet::from_weights(config, &weights, device))
}

/// Opens `library` and imports `name` from it.
pub fn import_from(path: &Path, name: &str, device: &Device) -> Result<OidnUnet, ImportError> {
    import(&WeightsLibrary::open(path)?, name, device)
}
