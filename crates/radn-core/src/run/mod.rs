//! Running a method over a sequence: the method contract, windows read from disk, band-by-band
//! processing with its scratch rows, sequence jobs and runs of several passes.

pub mod banding;
pub mod cancel;
pub mod denoiser;
pub mod fused;
pub mod job;
pub mod memory;
pub mod motion;
pub mod passes;
pub mod row_store;
pub mod sweep;
pub mod timing;
pub mod window;
