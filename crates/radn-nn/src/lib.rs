//! radn-nn: the Robust Average network (paper sections 3 and 4) and its baselines on burn,
//! and their inference: the model ([`model`]: configuration, layers, RA blocks, backbones,
//! kernels, demodulation, model files), its tuned settings ([`recipe`]), and inference
//! ([`infer`]: the tiled network denoiser, its inputs, the stages after the kernels, temporal
//! utilisation). [`device`] says where it runs (CPU or CUDA); [`mod@bench`] measures inference
//! throughput, [`profile`] where a denoising run's time goes. Training is the `radn-train`
//! crate: this one builds without automatic differentiation or an optimizer unless its
//! `autodiff` feature is on.

#![deny(missing_docs)]

pub mod bench;
pub mod device;
pub mod error;
pub mod infer;
pub mod model;
pub mod oidn_unet;
pub mod profile;
pub mod recipe;

pub use error::{NnError, Result};
pub use model::config::NetConfig;
pub use model::{Denoiser, Prediction};
pub use recipe::Recipe;

/// The burn version radn-nn is built on, re-exported so callers use the same one.
pub use burn;
