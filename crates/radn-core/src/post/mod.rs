//! Stages after a denoiser, shared by the network and the classic method: the Wiener blend
//! back towards the input where the change is more than the noise explains ([`wiener`]), and
//! the temporal pass over a sequence's results ([`stabilize`]).

pub mod stabilize;
pub mod wiener;
