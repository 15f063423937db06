//! Inference fast paths for the CPU: the network's convolutions ([`conv`]), the Robust Average
//! blocks ([`ra`]), the kernel activation ([`eta`]), the multi-scale
//! pooling ([`pool`]) and the kernel application ([`apply`]) computed directly on `f32` slices, where burn's `flex` backend
//! spends most of a denoising run outside its GEMM kernels (serial layout conversions,
//! allocations of unfolded patches). They compute the same functions as the burn operations
//! they replace (tested against them) and run only on the `flex` device without autodiff:
//! training, which needs burn's graph, and other backends keep burn's operations.

pub mod apply;
pub mod conv;
pub mod direct;
pub mod eta;
pub mod pool;
pub mod ra;

use burn::tensor::Device;

/// Whether tensors on `device` take the CPU fast paths: burn's `flex` CPU device, without
/// autodiff.
pub fn is_cpu_inference(device: &Device) -> bool {
    !device.is_autodiff() && *device == Device::flex()
}

/// A raw pointer that rayon jobs may share; each job writes only its own disjoint elements.
#[derive(Clone, Copy)]
pub(crate) struct SendPtr(pub(crate) *mut f32);

impl SendPtr {
    /// The pointer (a method, so closures capture the whole `Send` wrapper).
    pub(crate) fn get(self) -> *mut f32 {
        self.0
    }
}

// SAFETY: every user writes through the pointer only elements no other job touches.
unsafe impl Send for SendPtr {}
unsafe impl Sync for SendPtr {}
