//! The U-Net's CPU kernels: channel-blocked feature maps with pooling and upsampling
//! ([`blocked`]), the direct 3×3 convolutions ([`conv`]) and the converted network's feature
//! warp ([`feature_warp`]).

pub mod blocked;
pub mod conv;
pub mod feature_warp;
