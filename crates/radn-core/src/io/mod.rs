//! EXR in and out: files, frames and their channel presets, frame patterns, NaN/Inf repair, atomic
//! writes, runs sharing a folder, and denoised results written into copies of their inputs.

pub mod denoised_output;
pub mod exr_file;
pub mod frame;
pub mod hygiene;
pub mod mapping;
pub mod output;
pub mod output_locks;
pub mod sequence;
