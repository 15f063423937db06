//! One module per subcommand.

pub mod bench;
pub mod denoise;
pub mod eval;
pub mod inspect;
pub mod model;
pub mod prepare;
pub mod pseudoref;
pub mod train;
pub mod warp;
