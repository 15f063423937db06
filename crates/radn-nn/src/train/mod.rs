//! Training (paper sections 5 and 6): tile datasets cut from rendered sequences
//! ([`dataset`]), Noise2Noise pairs and the spatial-to-temporal objective ([`objective`]),
//! per-pixel and perceptual losses ([`loss`], [`vgg`]), a run's settings ([`config`]), its
//! batches ([`batch`]), the trainer with validation ([`trainer`]) and its files ([`checkpoint`]), the per-layer training signal it logs ([`layer_stats`]) and its
//! curves ([`curves`]).

pub mod batch;
pub mod checkpoint;
pub mod config;
pub mod curves;
pub mod dataset;
pub mod layer_stats;
pub mod loss;
pub mod objective;
pub mod trainer;
pub mod vgg;
