//! radn-nn: the Robust Average network (paper sections 3 and 4) and its baselines on burn, in
//! three stages: the model ([`model`]: configuration, layers, RA blocks, backbones, kernels,
//! demodulation, model files), inference ([`infer`]: the tiled network denoiser, its inputs,
//! temporal utilisation) and training ([`train`]: tile datasets, objective, losses, trainer,
//! curves). [`device`] says where it runs (CPU or CUDA). [`mod@bench`] measures the network's throughput, [`profile`] where a denoising run's
//! time goes.

#![deny(missing_docs)]

pub mod bench;
pub mod device;
pub mod error;
pub mod infer;
pub mod model;
pub mod profile;
pub mod recipe;
pub mod train;

pub use error::{NnError, Result};
pub use model::config::NetConfig;
pub use model::{Denoiser, Prediction};
pub use recipe::Recipe;

/// The burn version radn-nn is built on, re-exported so callers use the same one.
pub use burn;
