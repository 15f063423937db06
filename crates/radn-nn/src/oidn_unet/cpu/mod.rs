//! The U-Net's CPU kernels: channel-blocked feature maps with pooling and upsampling
//! ([`blocked`]) and the direct 3×3 convolutions ([`conv`]).

pub mod blocked;
pub mod conv;
