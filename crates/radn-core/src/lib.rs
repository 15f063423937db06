//! radn-core: everything in radn that has no network in it, in the order of the data path.
//!
//! - EXR files in and out: [`exr_file`], [`frame`], [`mapping`], [`sequence`], inputs checked
//!   and repaired ([`hygiene`]), safe outputs ([`output`]: atomic writes, PNG; [`output_locks`]: runs sharing a
//!   folder, debris of killed runs), denoised
//!   frames written into copies of their inputs ([`denoised_output`]).
//! - Windows: read ([`window`]) and aligned onto their centre frame with per-pixel confidence
//!   ([`motion`], [`warp`], [`confidence`], [`align`]), whole or band by band ([`banding`]).
//! - Guides for guided networks: the renderer's denoised layer or Intel Open Image Denoise
//!   per frame ([`guide`]).
//! - Denoising: the contract every method implements ([`denoiser`]), the classic denoiser
//!   ([`classic`]), whole sequences ([`job`]; band by band, decoded frames and per-frame
//!   features kept on disk between a frame's windows: [`row_store`]) and runs of several
//!   passes ([`passes`]).
//! - Judging results: [`metrics`], sequence evaluation ([`evaluation`]), metrics with the
//!   reference's own noise taken out ([`reference_noise`]) and the HTML report ([`report`]);
//!   throughput of the data path ([`mod@bench`]).

#![deny(missing_docs)]

pub mod align;
pub mod banding;
pub mod bench;
pub mod classic;
pub mod confidence;
pub mod denoised_output;
pub mod denoiser;
pub mod error;
pub mod evaluation;
pub mod exr_file;
pub mod frame;
pub mod guide;
pub mod hygiene;
pub mod image_ops;
pub mod job;
pub mod mapping;
pub mod metrics;
pub mod motion;
pub mod noise_level;
pub mod output;
pub mod output_locks;
pub mod passes;
pub mod plane;
pub mod post;
pub mod reference_noise;
pub mod report;
pub mod row_store;
pub mod sequence;
pub mod setting;
pub mod warp;
pub mod window;

pub use error::{Error, Result};
pub use plane::Plane;
