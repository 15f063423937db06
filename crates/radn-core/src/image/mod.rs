//! Image planes and the operations on them: the plane type, box filters and luminance, a frame's noise level.

pub mod noise_level;
pub mod ops;
pub mod plane;
pub mod stats;
