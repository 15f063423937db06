//! radn-nn: the Robust Average network (paper sections 3 and 4), its baselines, kernel
//! application, losses and training, on burn.

pub mod backbone;
pub mod bench;
pub mod config;
pub mod dataset;
pub mod demod;
pub mod error;
pub mod infer;
pub mod input;
pub mod kernel;
pub mod layers;
pub mod loss;
pub mod model;
pub mod objective;
pub mod plot;
pub mod ra_block;
pub mod store;
pub mod train;
pub mod vgg;

pub use config::NetConfig;
pub use error::{NnError, Result};
pub use model::{Denoiser, Prediction};

/// The burn version radn-nn is built on, re-exported so callers use the same one.
pub use burn;
