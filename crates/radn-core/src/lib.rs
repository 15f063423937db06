//! radn-core: everything in radn that has no network in it.
//!
//! EXR files in ([`exr_file`], [`frame`], [`mapping`], [`sequence`]), inputs checked and
//! repaired ([`hygiene`]), 5-frame windows aligned onto their centre frame with per-pixel
//! confidence ([`motion`], [`warp`], [`confidence`], [`align`]), metrics ([`metrics`]) and
//! safe outputs ([`output`]).

pub mod align;
pub mod band_write;
pub mod confidence;
pub mod error;
pub mod exr_file;
pub mod frame;
pub mod hygiene;
pub mod image_ops;
pub mod mapping;
pub mod metrics;
pub mod motion;
pub mod output;
pub mod plane;
pub mod sequence;
pub mod warp;

pub use error::{Error, Result};
pub use plane::Plane;
pub mod classic;
pub mod job;
