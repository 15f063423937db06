//! radn-train: training (paper sections 5 and 6), a crate of its own so that inference
//! (`radn-nn`) compiles neither automatic differentiation nor the optimizer.
//!
//! Tile datasets cut from rendered sequences ([`dataset`]), Noise2Noise pairs and the
//! spatial-to-temporal objective ([`objective`]), per-pixel and perceptual losses ([`loss`],
//! [`vgg`]), a run's settings ([`config`]), its batches ([`batch`]), the trainer with validation
//! ([`trainer`]) and its files ([`checkpoint`]), the per-layer training signal it logs
//! ([`layer_stats`]), its curves ([`curves`]), and training throughput ([`mod@bench`]).

#![deny(missing_docs)]

pub mod batch;
pub mod bench;
pub mod checkpoint;
pub mod config;
pub mod curves;
pub mod dataset;
pub mod layer_stats;
pub mod loss;
pub mod objective;
pub mod tile_manifest;
pub mod trainer;
pub mod unet_finetune;
pub mod vgg;

/// The error type training shares with inference.
pub use radn_nn::{NnError, Result};
