//! What a network is, without running it: its layers and parameters, receptive field, grid,
//! cost in FLOPs, and the stem it can run per frame.

use super::*;

impl Denoiser {
    /// Draws every parameter's initial value now. burn initialises parameters lazily, on first
    /// use, so without this the random draws would happen in whatever order the parameters are
    /// first touched, interleaved with other random work.
    pub fn materialize(&self) {
        use burn::store::ModuleSnapshot;
        let mut store = burn::store::SafetensorsStore::from_bytes(None);
        self.net
            .save_into(&mut store)
            .expect("collecting parameters into memory cannot fail");
    }

    /// Channels per frame of the features the heads read (the backbone's output).
    pub fn feature_channels(&self) -> usize {
        match &self.net {
            Network::Ra(n) => n.backbone.out_channels(),
            Network::Tkpcn(n) => n.backbone.out_channels(),
            Network::Spatial(n) => n.backbone.out_channels(),
        }
    }

    /// The RA blocks of the network (none for the baselines).
    pub fn ra_blocks(&self) -> Vec<&crate::model::ra_block::RobustAverage> {
        match &self.net {
            Network::Ra(n) => n.backbone.ra_blocks(),
            _ => Vec::new(),
        }
    }

    /// Every convolution weight of the network by layer name, in forward order (backbone
    /// layers prefixed `backbone.`, then the heads): what training reports layer by layer.
    pub fn layer_weights(&self) -> Vec<(String, Tensor<4>)> {
        let backbone = |b: &FrameNet| {
            b.weights()
                .into_iter()
                .map(|(n, w)| (format!("backbone.{n}"), w))
                .collect::<Vec<_>>()
        };
        match &self.net {
            Network::Ra(n) => {
                let mut v = backbone(&n.backbone);
                v.push(("head".into(), n.head.weight.val()));
                for (s, h) in n.coarse_heads.iter().enumerate() {
                    v.push((format!("head.scale{}", s + 1), h.weight.val()));
                }
                for (s, h) in n.blend_heads.iter().enumerate() {
                    v.push((format!("blend.scale{s}"), h.weight.val()));
                }
                for h in &n.guide_heads {
                    v.push(("guide_blend".into(), h.weight.val()));
                }
                v
            }
            Network::Spatial(n) => {
                let mut v = backbone(&n.backbone);
                v.push(("head".into(), n.head.weight.val()));
                v
            }
            Network::Tkpcn(n) => {
                let mut v = backbone(&n.backbone);
                v.push(("spatial_head".into(), n.spatial_head.weight.val()));
                v.push(("temporal_a".into(), n.temporal_a.weight.val()));
                v.push(("temporal_b".into(), n.temporal_b.weight.val()));
                v.push(("temporal_head".into(), n.temporal_head.weight.val()));
                v
            }
        }
    }

    /// Trainable parameters.
    pub fn num_params(&self) -> usize {
        self.net.num_params()
    }

    /// How far (in pixels) an output pixel's value can depend on the input: the halo a tile
    /// needs so that tiled and whole-frame results agree. Each 3×3 convolution adds 1, each RA
    /// block adds 2 per recurrent step, kernel application adds k/2 (twice for tKPCN). `None`
    /// for a UNet, whose pooling grid makes tiles depend on their position.
    pub fn receptive_radius(&self) -> Option<usize> {
        self.reach_beyond(0)
    }

    /// [`Denoiser::receptive_radius`] once the stem's features are given
    /// ([`Denoiser::predict_with_stem`], computed on whole frames): the stem's own reach is then
    /// not needed around a tile.
    pub fn receptive_radius_after_stem(&self) -> Option<usize> {
        self.reach_beyond(self.stem_radius())
    }

    /// The receptive radius less `given` pixels of the backbone's reach that are already
    /// computed.
    fn reach_beyond(&self, given: usize) -> Option<usize> {
        let k = self.config.kernel_size / 2;
        if self.config.scales() > 1 {
            // a coarse kernel at scale s reaches k coarse pixels, its head one more, the box
            // averages one more: (k + 3)·2^s pixels beyond the backbone's reach. Tiles must then
            // start on the coarsest scale's grid ([`Denoiser::tile_grid`]), so the halo is a
            // multiple of it.
            let crate::model::config::Backbone::Resnet {
                blocks, ra_after, ..
            } = &self.config.backbone
            else {
                return None; // a UNet's own pooling grid
            };
            let m = self.tile_grid();
            let backbone = 1 + 2 * blocks + ra_after.len() * 2 * self.config.frames - given;
            return Some((backbone + 1 + k + m * (k + 3)).div_ceil(m) * m);
        }
        match &self.config.backbone {
            crate::model::config::Backbone::Resnet {
                blocks, ra_after, ..
            } => {
                let ra = if self.config.arch == Arch::Ra {
                    ra_after.len() * 2 * self.config.frames
                } else {
                    0
                };
                let backbone = 1 + 2 * blocks + ra - given;
                Some(match self.config.arch {
                    Arch::Ra | Arch::Spatial => backbone + 1 + k,
                    Arch::Tkpcn => backbone + 3 + k + k,
                })
            }
            crate::model::config::Backbone::Unet { .. } => None,
        }
    }

    /// Forward FLOPs of predicting kernels for one `h × w` window and applying them to
    /// `channels` channels (multiply-adds count 2), counted from the network's own layers, so
    /// the count follows whatever the network is.
    pub fn forward_flops(&self, h: usize, w: usize, channels: usize) -> f64 {
        let px = h * w;
        let t = self.config.frames;
        let k2 = self.config.kernel_size * self.config.kernel_size;
        // a k×k×frames kernel applied to every channel of every pixel
        let apply = |frames: usize| 2.0 * (frames * k2 * channels * px) as f64;
        match &self.net {
            Network::Ra(n) => {
                let scale_px = |s: usize| (h >> s) * (w >> s);
                let coarse: f64 = (1..self.config.scales())
                    .map(|s| {
                        let p = scale_px(s);
                        t as f64 * conv_flops(&n.coarse_heads[s - 1], p)
                            + conv_flops(&n.blend_heads[s - 1], scale_px(s - 1))
                            + 2.0 * (t * k2 * channels * p) as f64
                    })
                    .sum();
                n.backbone.flops(h, w, t) + t as f64 * conv_flops(&n.head, px) + apply(t) + coarse
            }
            Network::Spatial(n) => n.backbone.flops(h, w, 1) + conv_flops(&n.head, px) + apply(1),
            Network::Tkpcn(n) => {
                n.backbone.flops(h, w, t)
                    + t as f64 * conv_flops(&n.spatial_head, px)
                    + conv_flops(&n.temporal_a, px)
                    + conv_flops(&n.temporal_b, px)
                    + conv_flops(&n.temporal_head, px)
                    + t as f64 * apply(1)
                    + apply(t)
            }
        }
    }

    /// The grid tiles must start on and their sizes be multiples of, so that a tiled result
    /// equals the whole frame's: 2^(scales − 1) (1 for single-scale kernels).
    pub fn tile_grid(&self) -> usize {
        1 << (self.config.scales() - 1)
    }

    /// The multiple that tile sizes must have.
    pub fn size_multiple(&self) -> usize {
        match &self.net {
            Network::Ra(n) => n.backbone.size_multiple(),
            Network::Tkpcn(n) => n.backbone.size_multiple(),
            Network::Spatial(n) => n.backbone.size_multiple(),
        }
    }

    /// Channels of a frame-local network's stem features (0 for any other network).
    pub fn stem_channels(&self) -> usize {
        match (&self.net, self.config.frame_local_stem) {
            (Network::Ra(n), true) => n.backbone.resnet().map_or(0, |r| r.width()),
            _ => 0,
        }
    }

    /// The radius in pixels of what one of a frame-local network's stem features reads.
    pub fn stem_radius(&self) -> usize {
        match &self.net {
            Network::Ra(n) => n.backbone.resnet().map_or(0, |r| r.stem_radius()),
            _ => 0,
        }
    }
}
