//! The U-Net's CPU kernels: channel-blocked feature maps with pooling and upsampling
//! ([`blocked`]), the direct 3×3 convolutions ([`conv`], with their AVX2 and AVX-512 twins) and
//! the converted network's feature warp ([`feature_warp`]).

pub mod blocked;
pub mod conv;
#[cfg(target_arch = "x86_64")]
mod conv_avx2;
#[cfg(target_arch = "x86_64")]
mod conv_avx512;
pub mod feature_warp;
