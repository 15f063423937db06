//! The classic (non-neural) temporal denoiser: optical-flow refinement of the renderer's
//! motion, robust temporal averaging, joint non-local means and a guided filter. It makes the
//! pseudo-references for training (paper section 6) and is `radn denoise --method classic`.

pub mod guided;
pub mod keys;
pub mod nlm;
pub mod pipeline;
pub mod refine;
pub mod temporal;
pub mod tvl1;

/// Deterministic white noise in −0.5..0.5 per pixel and channel, for the stages' tests.
#[cfg(test)]
pub(crate) fn test_noise(x: usize, y: usize, c: usize) -> f32 {
    let s = ((x * 73856093) ^ (y * 19349663) ^ (c * 83492791)) as u32;
    let s = s.wrapping_mul(2654435761) ^ (s >> 13);
    let s = s.wrapping_mul(2246822519);
    (s >> 8) as f32 / (1u32 << 24) as f32 - 0.5
}
