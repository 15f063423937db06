//! Running an imported U-Net over a frame on the CPU, as OIDN's RT filter does: the inputs
//! processed into the network's range (the HDR beauty at the frame's exposure, from OIDN's
//! autoexposure unless a scale is given), the frame padded with zeros to a multiple of 16,
//! split into tiles whose origins keep that alignment and which overlap by the network's reach
//! so that tiled output equals whole-frame output exactly, and the output mapped back.

use radn_core::guide::exposure::ExposureBins;
use radn_core::image::plane::Plane;
use rayon::prelude::*;

use crate::oidn_unet::config::{After, Input, Skip, UnetConfig, ALIGNMENT};
use crate::oidn_unet::cpu::blocked::{Blocked, Scratch, LANES};
use crate::oidn_unet::cpu::conv::{Fused, PackedConv};
use crate::oidn_unet::transfer::{Processing, Transfer, AUX_ALBEDO, AUX_NORMAL, HDR_BEAUTY};
use crate::oidn_unet::OidnUnet;

/// The images one run reads: what the model's [`Input`] names, each an RGB (XYZ) plane of the
/// frame's size.
#[derive(Clone, Copy, Debug)]
pub struct UnetImages<'a> {
    /// The beauty (beauty models).
    pub color: Option<&'a Plane>,
    /// The albedo (beauty models with auxiliaries, and the albedo prefilter's input).
    pub albedo: Option<&'a Plane>,
    /// The normal (beauty models with normals, and the normal prefilter's input).
    pub normal: Option<&'a Plane>,
}

/// The U-Net's weights packed for the CPU kernels, ready to run on frames.
pub struct UnetFilter {
    config: UnetConfig,
    convs: Vec<PackedConv>,
    max_tile_pixels: usize,
    scratch: std::sync::Arc<Scratch>,
}

/// What is wrong with a run's inputs.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FilterError {
    /// An image the model reads was not given.
    #[error("the {model} model needs a{an} {image} image")]
    Missing {
        /// The OIDN model name.
        model: String,
        /// "n" or "", for the article.
        an: &'static str,
        /// Which image.
        image: &'static str,
    },
    /// Images of different sizes, or not three channels.
    #[error("the input images must be 3-channel and of one size ({0})")]
    Shape(String),
}

/// Tile sides are at most this many pixels when no budget is set: a 1080p frame runs as one
/// tile and a 4K one in a few.
pub const DEFAULT_MAX_TILE_PIXELS: usize = 2176 * 1152;

impl UnetFilter {
    /// Packs `net`'s weights for the CPU.
    pub fn new(net: &OidnUnet) -> Self {
        let config = net.config().clone();
        let convs = config
            .conv_inputs()
            .iter()
            .zip(&config.convs)
            .zip(net.host_weights())
            .map(|((parts, shape), (w, b))| PackedConv::new(&w, &b, shape.cout, parts))
            .collect();
        Self {
            config,
            convs,
            max_tile_pixels: DEFAULT_MAX_TILE_PIXELS,
            scratch: Default::default(),
        }
    }

    /// The network's configuration.
    pub fn config(&self) -> &UnetConfig {
        &self.config
    }

    /// Caps a tile's pixels (overlap included), trading speed for memory.
    pub fn with_max_tile_pixels(mut self, pixels: usize) -> Self {
        self.max_tile_pixels = pixels.max(ALIGNMENT * ALIGNMENT);
        self
    }

    /// Shares `scratch` with other filters that run one after another (a prefiltered frame's
    /// three networks), so that they keep one set of feature maps, not three.
    pub fn with_scratch(mut self, scratch: std::sync::Arc<Scratch>) -> Self {
        self.scratch = scratch;
        self
    }

    /// The filter's feature-map storage.
    pub fn scratch(&self) -> std::sync::Arc<Scratch> {
        self.scratch.clone()
    }

    /// The input scale OIDN's autoexposure gives `color` (1 for models that are not HDR).
    pub fn autoexposure(&self, color: &Plane) -> f32 {
        let mut bins = ExposureBins::new(color.width(), color.height());
        bins.add_rows(0, color);
        self.exposure_of(&bins)
    }

    /// The input scale for a frame whose autoexposure bins are `bins` (gathered band by band,
    /// so that every band runs at the whole frame's exposure); 1 for models that are not HDR.
    pub fn exposure_of(&self, bins: &ExposureBins) -> f32 {
        if matches!(self.config.input, Input::Beauty { hdr: true, .. }) {
            bins.exposure()
        } else {
            1.0
        }
    }

    /// How the model's main input is processed.
    fn main_processing(&self) -> Processing {
        match self.config.input {
            Input::Beauty { hdr: true, .. } => HDR_BEAUTY,
            Input::Beauty { hdr: false, .. } | Input::Albedo => Processing {
                transfer: Transfer::Srgb,
                signed: false,
                hdr: false,
            },
            Input::Normal => Processing {
                transfer: Transfer::Linear,
                signed: true,
                hdr: false,
            },
        }
    }

    /// The planes the network reads, in order, with their processing.
    pub(crate) fn planes<'a>(
        &self,
        images: &UnetImages<'a>,
    ) -> Result<Vec<(&'a Plane, Processing)>, FilterError> {
        let missing = |an, image| FilterError::Missing {
            model: self.config.weights.clone(),
            an,
            image,
        };
        let main = self.main_processing();
        let planes = match self.config.input {
            Input::Beauty { albedo, normal, .. } => {
                let mut v = vec![(images.color.ok_or(missing("", "colour"))?, main)];
                if albedo {
                    v.push((images.albedo.ok_or(missing("n", "albedo"))?, AUX_ALBEDO));
                }
                if normal {
                    v.push((images.normal.ok_or(missing("", "normal"))?, AUX_NORMAL));
                }
                v
            }
            Input::Albedo => vec![(images.albedo.ok_or(missing("n", "albedo"))?, main)],
            Input::Normal => vec![(images.normal.ok_or(missing("", "normal"))?, main)],
        };
        let (w, h) = (planes[0].0.width(), planes[0].0.height());
        if planes
            .iter()
            .any(|(p, _)| p.width() != w || p.height() != h || p.channels() != 3)
        {
            return Err(FilterError::Shape(
                planes
                    .iter()
                    .map(|(p, _)| format!("{}×{}×{}", p.width(), p.height(), p.channels()))
                    .collect::<Vec<_>>()
                    .join(", "),
            ));
        }
        Ok(planes)
    }

    /// Denoises one frame at input scale `scale` (OIDN's autoexposure when `None`): the model's
    /// output as an RGB (XYZ for normals) plane of the frame's size.
    pub fn run(&self, images: &UnetImages, scale: Option<f32>) -> Result<Plane, FilterError> {
        self.run_within(images, scale, self.max_tile_pixels)
    }

    /// [`UnetFilter::run`] in tiles of at most `budget` pixels ([`UnetFilter::tiles_within`]).
    pub fn run_within(
        &self,
        images: &UnetImages,
        scale: Option<f32>,
        budget: usize,
    ) -> Result<Plane, FilterError> {
        let planes = self.planes(images)?;
        let (w, h) = (planes[0].0.width(), planes[0].0.height());
        let scale = match scale {
            Some(s) => s,
            None => match images.color {
                Some(c) if self.main_processing().hdr => self.autoexposure(c),
                _ => 1.0,
            },
        };
        let mut out = Plane::zeros(w, h, 3);
        // largest first, so that the smaller tiles' maps fit in its buffers
        let mut tiles = self.tiles_within(w, h, budget);
        tiles.sort_by_key(|t| std::cmp::Reverse(t.pixels()));
        if let Some(t) = tiles.first() {
            self.scratch.prepare_for(t.pixels());
        }
        for tile in tiles {
            let t0 = std::time::Instant::now();
            let input = self.tile_input(&planes, &tile, scale);
            let t1 = std::time::Instant::now();
            let result = self.forward(input);
            let t2 = std::time::Instant::now();
            self.tile_output(&result, &tile, scale, &mut out);
            self.scratch.recycle(result);
            tracing::debug!(
                "tile {:?}: {} MB of feature maps kept",
                tile.buffer,
                self.scratch.kept_bytes() >> 20
            );
            tracing::trace!(
                "tile {:?}: input {:.1} ms, network {:.1} ms, output {:.1} ms",
                tile.buffer,
                (t1 - t0).as_secs_f64() * 1e3,
                (t2 - t1).as_secs_f64() * 1e3,
                t2.elapsed().as_secs_f64() * 1e3
            );
        }
        self.scratch.trim();
        Ok(out)
    }

    /// The tiles that cover a `w × h` frame within the filter's tile budget.
    pub fn tiles(&self, w: usize, h: usize) -> Vec<Tile> {
        self.tiles_within(w, h, self.max_tile_pixels)
    }

    /// The tiles that cover a `w × h` frame, each of at most `budget` pixels where the
    /// overlap allows: the whole padded frame when it fits, else whichever of square tiles,
    /// tiles as tall as the frame (a band) or as wide as it computes the fewest pixels.
    pub fn tiles_within(&self, w: usize, h: usize, budget: usize) -> Vec<Tile> {
        self.tiles_overlapping(w, h, budget, self.config.layers.overlap())
    }

    /// [`UnetFilter::tiles_within`] with tiles that overlap by `ov` pixels (a multiple of
    /// [`ALIGNMENT`], at least the network's overlap): for networks that read further than
    /// the U-Net alone (the converted network's blocks).
    pub fn tiles_overlapping(&self, w: usize, h: usize, budget: usize, ov: usize) -> Vec<Tile> {
        debug_assert!(ov.is_multiple_of(ALIGNMENT) && ov >= self.config.layers.overlap());
        let (pw, ph) = (w.next_multiple_of(ALIGNMENT), h.next_multiple_of(ALIGNMENT));
        let grid = |v: usize| (v / ALIGNMENT * ALIGNMENT).max(ALIGNMENT);
        let layout = |cx: usize, cy: usize| -> Vec<Tile> {
            let spans = |n: usize, padded: usize, core: usize| {
                (0..padded)
                    .step_by(core)
                    .map(|a| {
                        let b = (a + core).min(padded);
                        (a.saturating_sub(ov), a, b.min(n), (b + ov).min(padded))
                    })
                    .filter(|&(_, a, b, _)| a < b)
                    .collect::<Vec<_>>()
            };
            let (xs, ys) = (spans(w, pw, cx), spans(h, ph, cy));
            ys.iter()
                .flat_map(|&(y0, ya, yb, y1)| {
                    xs.iter().map(move |&(x0, xa, xb, x1)| Tile {
                        buffer: [x0, y0, x1, y1],
                        core: [xa, ya, xb, yb],
                    })
                })
                .collect()
        };
        if pw * ph <= budget {
            return layout(pw, ph);
        }
        let side = (budget as f64).sqrt() as usize;
        let square = grid(side.saturating_sub(2 * ov));
        let mut candidates = vec![layout(square, square)];
        if ph * (2 * ov + ALIGNMENT) <= budget {
            candidates.push(layout(grid((budget / ph).saturating_sub(2 * ov)), ph));
        }
        if pw * (2 * ov + ALIGNMENT) <= budget {
            candidates.push(layout(pw, grid((budget / pw).saturating_sub(2 * ov))));
        }
        let area = |tiles: &Vec<Tile>| -> usize { tiles.iter().map(Tile::pixels).sum() };
        candidates
            .into_iter()
            .min_by_key(area)
            .expect("square tiles are a candidate")
    }

    /// A tile's processed input: the frame's values inside the frame, zeros in its padding.
    pub(crate) fn tile_input(
        &self,
        planes: &[(&Plane, Processing)],
        tile: &Tile,
        scale: f32,
    ) -> Blocked {
        let [x0, y0, x1, y1] = tile.buffer;
        let (tw, th) = (x1 - x0, y1 - y0);
        let mut m = Blocked::bordered_in(&self.scratch, 3 * planes.len(), th, tw);
        let (rs, bs) = (m.row_stride(), m.block_stride());
        m.data_mut()
            .par_chunks_mut(bs)
            .enumerate()
            .for_each(|(b, block)| {
                block.fill(0.0);
                for lane in 0..LANES {
                    let c = b * LANES + lane;
                    let Some(&(plane, proc_)) = planes.get(c / 3) else {
                        break;
                    };
                    let src = plane.channel(c % 3);
                    let (fw, fh) = (plane.width(), plane.height());
                    for y in y0..y1.min(fh) {
                        let row = &mut block[(y - y0 + 1) * rs..];
                        for x in x0..x1.min(fw) {
                            row[(x - x0 + 1) * LANES + lane] = proc_.input(src[y * fw + x], scale);
                        }
                    }
                }
            });
        m
    }

    /// Copies a tile's core from the network's output into the frame, mapped back to linear.
    pub(crate) fn tile_output(&self, result: &Blocked, tile: &Tile, scale: f32, out: &mut Plane) {
        let [x0, y0, _, _] = tile.buffer;
        let [xa, ya, xb, yb] = tile.core;
        let proc_ = self.main_processing();
        let w = out.width();
        for c in 0..3 {
            let dst = out.channel_mut(c);
            dst.par_chunks_mut(w)
                .enumerate()
                .skip(ya)
                .take(yb - ya)
                .for_each(|(y, row)| {
                    for (x, v) in row.iter_mut().enumerate().take(xb).skip(xa) {
                        *v = proc_.output(result.get(c, y - y0, x - x0), scale);
                    }
                });
        }
    }

    /// The network on one processed tile (sides multiples of 16): its 3 output channels. Every
    /// map it makes comes from and goes back to the filter's scratch, except the result.
    pub fn forward(&self, input: Blocked) -> Blocked {
        self.decode(self.encode(input))
    }

    /// The encoder on one processed tile: the levels the decoder reads, finest first (the
    /// input, the three pooled skip maps, the bottleneck's output), as
    /// [`OidnUnet::encode`](crate::oidn_unet::OidnUnet::encode) gives them. A converted
    /// network runs it once per frame.
    pub fn encode(&self, input: Blocked) -> Vec<Blocked> {
        let scratch = &self.scratch;
        let n = self.config.layers.encoder_steps();
        let mut pools: Vec<Blocked> = Vec::new();
        // the previous step's output, when it is neither the input nor the last pool
        let mut x: Option<Blocked> = None;
        for (step, conv) in self.config.layers.steps()[..n].iter().zip(&self.convs) {
            let started = std::time::Instant::now();
            let fused = Fused {
                upsample_first: false,
                pool: step.after == After::Pool,
            };
            let y = {
                let prev = x.as_ref().or(pools.last()).unwrap_or(&input);
                conv.run_fused(&[prev], scratch, fused)
            };
            trace_step(step.conv, &y, started);
            if let Some(old) = x.take() {
                scratch.recycle(old);
            }
            match step.after {
                After::Pool => pools.push(y),
                After::Nothing | After::Upsample => x = Some(y),
            }
        }
        // the last pooling fed only the bottleneck
        if let Some(last) = pools.pop() {
            scratch.recycle(last);
        }
        let mut levels = vec![input];
        levels.extend(pools);
        levels.push(x.expect("the encoder ends with the bottleneck"));
        levels
    }

    /// The decoder on one tile's levels ([`UnetFilter::encode`]'s, or a window's blended
    /// ones): the network's 3 output channels. The levels go back to the scratch.
    pub fn decode(&self, mut levels: Vec<Blocked>) -> Blocked {
        let scratch = &self.scratch;
        let n = self.config.layers.encoder_steps();
        let mut x = levels.pop().expect("the bottleneck level");
        // the bottleneck's output is upsampled: the first decoder convolution reads it so
        let mut upsampled = true;
        for (step, conv) in self.config.layers.steps()[n..].iter().zip(&self.convs[n..]) {
            let started = std::time::Instant::now();
            let fused = Fused {
                upsample_first: upsampled,
                pool: false,
            };
            let y = match step.skip {
                None => conv.run_fused(&[&x], scratch, fused),
                Some(Skip::Input) => conv.run_fused(&[&x, &levels[0]], scratch, fused),
                Some(Skip::Pool(k)) => conv.run_fused(&[&x, &levels[k]], scratch, fused),
            };
            trace_step(step.conv, &y, started);
            scratch.recycle(std::mem::replace(&mut x, y));
            upsampled = step.after == After::Upsample;
        }
        for l in levels {
            scratch.recycle(l);
        }
        x
    }
}

/// Logs one step's time (`RUST_LOG=radn_nn=trace`).
fn trace_step(conv: &str, y: &Blocked, started: std::time::Instant) {
    tracing::trace!(
        "{conv} to {}x{}: {:.1} ms",
        y.width(),
        y.height(),
        started.elapsed().as_secs_f64() * 1e3
    );
}

/// One tile: the buffer the network runs on and the core it writes, as `[x0, y0, x1, y1]` in
/// frame pixels (the buffer may pass the frame into its zero padding).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tile {
    /// The region the network reads.
    pub buffer: [usize; 4],
    /// The region whose output is kept.
    pub core: [usize; 4],
}

impl Tile {
    /// Pixels of its buffer.
    pub fn pixels(&self) -> usize {
        (self.buffer[2] - self.buffer[0]) * (self.buffer[3] - self.buffer[1])
    }
}
