//! radn-core: everything in radn that has no network in it, grouped by stage in the order of
//! the data path.
//!
//! - [`io`]: EXR files in and out, frames and their channel presets, frame patterns, NaN/Inf
//!   repair, atomic writes, runs sharing a folder, results written into copies of the inputs.
//! - [`image`]: image planes, the operations on them, a frame's noise level.
//! - [`guide`]: per-frame guides for guided networks (Intel Open Image Denoise at run time, the
//!   renderer's denoised layer).
//! - [`align`]: windows aligned onto their centre frame with per-pixel confidence.
//! - [`run`]: the method contract, windows read from disk, bands, sequence jobs, several passes.
//! - [`classic`]: the non-neural denoiser.
//! - [`post`]: stages after a denoiser that both methods use (the Wiener blend, the temporal
//!   pass over the results).
//! - [`eval`]: metrics, sequence evaluation, the HTML report, throughput.
//! - [`setting`]: the `auto|off|VALUE` parser every setting shares.
//!
//! The types callers use most are re-exported here.

#![deny(missing_docs)]

pub mod align;
pub mod classic;
pub mod error;
pub mod eval;
pub mod guide;
pub mod image;
pub mod io;
pub mod post;
pub mod run;
pub mod setting;

pub use align::{align_window, AlignParams, AlignedWindow};
pub use classic::pipeline::ClassicDenoiser;
pub use error::{Error, Result};
pub use guide::{GuideChoice, OidnGuides};
pub use image::plane::Plane;
pub use io::exr_file::{ExrFile, SampleKind};
pub use io::frame::{Frame, FrameReader};
pub use io::mapping::ChannelMapping;
pub use io::sequence::SequencePattern;
pub use post::stabilize::TemporalStabilizer;
pub use run::denoiser::{Denoised, WindowDenoiser};
pub use run::passes::DenoiseRun;
pub use setting::Setting;
