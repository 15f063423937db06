//! Stages after a denoiser, shared by the network and the classic method: the Wiener blend
//! back towards the input where the change is more than the noise explains ([`wiener`]), with
//! the renderer's variance checked against the frames first ([`variance_check`]), and the
//! temporal pass over a sequence's results ([`stabilize`]).

pub mod stabilize;
pub mod variance_check;
pub mod wiener;
