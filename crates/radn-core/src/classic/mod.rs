//! The classic (non-neural) temporal denoiser: optical-flow refinement of the renderer's
//! motion, robust temporal averaging, joint non-local means and a guided filter. It makes the
//! pseudo-references for training (paper section 6) and is `radn denoise --method classic`.

pub mod guided;
pub mod nlm;
pub mod pipeline;
pub mod refine;
pub mod temporal;
pub mod tvl1;
pub mod wiener;
