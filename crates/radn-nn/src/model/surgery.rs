//! Model surgery: a trained network grown or changed in shape (more kernel scales, a
//! frame-local stem, a guide blend, other inputs) so that it
//! fine-tunes from where it was instead of from scratch.

use super::*;

impl Denoiser {
    /// The same network with `scales` kernel scales: the heads it lacks are added, each
    /// coarse kernel head starting as a copy of the full-resolution head (the same features,
    /// averaged, then give the same kernels at the coarser scale) and each blend head at
    /// [`BLEND_INIT_BIAS`], so a fine-tune of a single-scale model starts close to it. Fewer
    /// scales than the network has drop the coarsest heads. Only the RA network has scales.
    pub fn with_kernel_scales(mut self, scales: usize, device: &Device) -> Result<Self, String> {
        let Network::Ra(n) = &mut self.net else {
            return Err("only arch = \"ra\" has multi-scale kernels".into());
        };
        let c = n.backbone.out_channels();
        let k2 = self.config.kernel_size * self.config.kernel_size;
        n.coarse_heads.truncate(scales.saturating_sub(1));
        n.blend_heads.truncate(scales.saturating_sub(1));
        while n.coarse_heads.len() + 1 < scales {
            let mut h = box_head(c, k2, 0.0, 1.0, device);
            h.weight = Param::from_tensor(n.head.weight.val());
            h.bias = n.head.bias.as_ref().map(|b| Param::from_tensor(b.val()));
            n.coarse_heads.push(h);
            n.blend_heads.push(blend_head(c, device));
        }
        self.config.kernel_scales = (scales > 1).then_some(scales);
        Ok(self)
    }

    /// The same network with a frame-local stem ([`NetConfig::frame_local_stem`]): the input
    /// layer's weights of the window's own channels leave it (their value where a frame is fully
    /// trusted — confidence 1, noise estimate 0 — folded into its bias) and come back after the
    /// stem through a 1×1 convolution that starts at zero. A fine-tune from a model without the
    /// split starts close to it. Only an RA network with a ResNet backbone has the split.
    pub fn with_frame_local_stem(mut self, device: &Device) -> Result<Self, String> {
        if self.config.frame_local_stem {
            return Ok(self);
        }
        let mut config = self.config.clone();
        config.frame_local_stem = true;
        config.validate().map_err(|e| e.to_string())?;
        let Network::Ra(n) = &mut self.net else {
            return Err("only arch = \"ra\" has a frame-local stem".into());
        };
        split_stem(&mut n.backbone, &self.config.inputs, device);
        self.config = config;
        Ok(self)
    }

    /// The same network with the guide blend on or off (`blend`): a new blend head starts at
    /// [`GUIDE_BLEND_INIT_BIAS`], so a fine-tune that adds it starts close to the model it
    /// grows. Only the RA network blends, and only with a guide in its inputs.
    pub fn with_guide_blend(mut self, blend: bool, device: &Device) -> Result<Self, String> {
        let Network::Ra(n) = &mut self.net else {
            return Err("only arch = \"ra\" has the guide blend".into());
        };
        if blend && !self.config.inputs.guide {
            return Err("the guide blend needs [inputs] guide = true".into());
        }
        if !blend {
            n.guide_heads.clear();
        } else if n.guide_heads.is_empty() {
            let c = n.backbone.out_channels();
            n.guide_heads
                .push(blend_head_with(c, GUIDE_BLEND_INIT_BIAS, device));
        }
        self.config.guide_blend = blend;
        Ok(self)
    }

    /// The same network reading the input features `inputs`: the first layer gains (or drops)
    /// the channels that differ, new ones with zero weights, so the grown network first
    /// computes what the old one did on the features both share. A fine-tune that adds the
    /// noise estimate starts from the model it grows.
    pub fn with_inputs(mut self, inputs: InputConfig, device: &Device) -> Self {
        let cin = inputs.channels();
        match &mut self.net {
            Network::Ra(n) => n.backbone.widen_input(cin, device),
            Network::Tkpcn(n) => n.backbone.widen_input(cin, device),
            Network::Spatial(n) => n.backbone.widen_input(cin, device),
        }
        self.config.inputs = inputs;
        self
    }
}
