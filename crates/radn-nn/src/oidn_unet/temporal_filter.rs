//! Running a converted U-Net ([`TemporalUnet`]) over an aligned window on the CPU kernels:
//! per tile, each frame's processed input goes through the U-Net's encoder, each blended
//! level's Robust Average block runs over the window's maps and its result enters the centre
//! frame's through the gate, and the decoder runs once, on the centre's levels. The same
//! computation as [`TemporalUnet::forward`] with no motion (the window is aligned already).

use radn_core::image::plane::Plane;

use crate::model::ra_block::RobustAverage;
use crate::oidn_unet::config::ALIGNMENT;
use crate::oidn_unet::cpu::blocked::Blocked;
use crate::oidn_unet::cpu::feature_warp::HostMotion;
use crate::oidn_unet::filter::{FilterError, Tile, UnetFilter, UnetImages};
use crate::oidn_unet::input_blend::{HostInputBlend, InputBlend};
use crate::oidn_unet::temporal::TemporalUnet;

/// One blended level on the host: its block and its gate's per-channel values.
struct HostBlend {
    level: usize,
    ra: RobustAverage,
    gate: Vec<f32>,
}

/// One frame's encoder levels over the whole frame, for every window the frame is in.
pub struct FrameLevels {
    levels: Vec<Blocked>,
    width: usize,
    height: usize,
    scale: f32,
}

impl FrameLevels {
    /// The input scale the frame went through the encoder at.
    pub fn scale(&self) -> f32 {
        self.scale
    }

    /// Bytes its maps hold.
    pub fn bytes(&self) -> usize {
        self.levels.iter().map(|m| m.data().len() * 4).sum()
    }
}

/// A window's motion at the levels of a converted network's blocks
/// ([`TemporalFilter::motion_levels`]).
pub struct MotionLevels(Vec<Option<HostMotion>>);

impl MotionLevels {
    /// The motion at level `level`, where the network has a block there (or at level 0).
    fn at(&self, level: usize) -> Option<&HostMotion> {
        self.0.get(level).and_then(Option::as_ref)
    }
}

/// A converted U-Net's weights ready to run on aligned windows.
pub struct TemporalFilter {
    filter: UnetFilter,
    blends: Vec<HostBlend>,
    input: Option<HostInputBlend>,
    frames: usize,
}

impl TemporalFilter {
    /// Packs `net`'s U-Net for the CPU kernels and keeps its blocks and gates.
    pub fn new(net: &TemporalUnet) -> Self {
        Self {
            filter: UnetFilter::new(&net.unet),
            blends: net
                .blends()
                .into_iter()
                .map(|(level, ra, gate)| HostBlend {
                    level,
                    ra: ra.clone(),
                    gate,
                })
                .collect(),
            input: net.input_blend().map(InputBlend::host),
            frames: net.config().frames,
        }
    }

    /// Each frame's share of the centre's input where the network learned an input average
    /// ([`InputBlend`]): read from the window's images (aligned, of one size) processed at
    /// input scale `scale`; `None` when it reads the centre as rendered.
    pub fn input_shares(
        &self,
        window: &[UnetImages],
        scale: f32,
    ) -> Result<Option<Vec<Vec<f32>>>, FilterError> {
        let Some(blend) = &self.input else {
            return Ok(None);
        };
        let processed = window
            .iter()
            .map(|images| {
                let planes = self.filter.planes(images)?;
                let (w, h) = (planes[0].0.width(), planes[0].0.height());
                let mut out = Vec::with_capacity(3 * planes.len() * w * h);
                for (plane, processing) in planes {
                    for c in 0..3 {
                        out.extend(plane.channel(c).iter().map(|&v| processing.input(v, scale)));
                    }
                }
                Ok(out)
            })
            .collect::<Result<Vec<_>, FilterError>>()?;
        let first = window[0].color.expect("a beauty model reads colour");
        Ok(Some(blend.shares(
            &processed,
            first.width(),
            first.height(),
        )))
    }

    /// Frames per window.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// The per-frame U-Net (its configuration, exposure and tiles).
    pub fn unet(&self) -> &UnetFilter {
        &self.filter
    }

    /// Denoises the centre of `window` (one set of images per frame, aligned to the centre,
    /// all of one size) at input scale `scale`, in tiles of at most `budget` pixels: the
    /// network's output as an RGB plane of the frame's size.
    pub fn run(
        &self,
        window: &[UnetImages],
        scale: f32,
        budget: usize,
    ) -> Result<Plane, FilterError> {
        self.run_in_tiles(window, scale, |w, h| self.tiles_within(w, h, budget))
    }

    /// [`TemporalFilter::run`] in the tiles `tiles` gives for the frame's width and height.
    fn run_in_tiles(
        &self,
        window: &[UnetImages],
        scale: f32,
        tiles: impl Fn(usize, usize) -> Vec<Tile>,
    ) -> Result<Plane, FilterError> {
        assert_eq!(
            window.len(),
            self.frames,
            "a window of the network's length"
        );
        let planes = window
            .iter()
            .map(|images| self.filter.planes(images))
            .collect::<Result<Vec<_>, _>>()?;
        let (w, h) = (planes[0][0].0.width(), planes[0][0].0.height());
        if planes
            .iter()
            .any(|p| p[0].0.width() != w || p[0].0.height() != h)
        {
            return Err(FilterError::Shape(
                "the window's frames differ in size".into(),
            ));
        }
        let mut out = Plane::zeros(w, h, 3);
        let mut tiles = tiles(w, h);
        tiles.sort_by_key(|t| std::cmp::Reverse(t.pixels()));
        for tile in tiles {
            let levels: Vec<Vec<Blocked>> = planes
                .iter()
                .map(|p| self.filter.encode(self.filter.tile_input(p, &tile, scale)))
                .collect();
            let result = self.filter.decode(self.blend(levels));
            self.filter.tile_output(&result, &tile, scale, &mut out);
            self.filter.scratch().recycle(result);
        }
        self.filter.scratch().trim();
        Ok(out)
    }

    /// Denoises the centre of `window`, whose frames are as rendered (not aligned), at input
    /// scale `scale`: each frame's encoder levels are warped to the centre by `motion` (the
    /// window's full-resolution motion, padded to the frame's multiple of 16) before the
    /// blocks. The frame runs as one tile.
    pub fn run_warped(
        &self,
        window: &[UnetImages],
        motion: HostMotion,
        scale: f32,
    ) -> Result<Plane, FilterError> {
        assert_eq!(
            window.len(),
            self.frames,
            "a window of the network's length"
        );
        let levels = window
            .iter()
            .map(|images| self.encode_frame(images, scale))
            .collect::<Result<Vec<_>, _>>()?;
        let motion = self.motion_levels(motion);
        self.decode_warped(&levels.iter().collect::<Vec<_>>(), &motion, scale)
    }

    /// One frame's encoder levels over the whole frame (padded to a multiple of 16) at input
    /// scale `scale`: what every window the frame is in reads ([`TemporalFilter::decode_warped`]).
    pub fn encode_frame(
        &self,
        images: &UnetImages,
        scale: f32,
    ) -> Result<FrameLevels, FilterError> {
        let planes = self.filter.planes(images)?;
        let (width, height) = (planes[0].0.width(), planes[0].0.height());
        let tile = Self::whole(width, height);
        Ok(FrameLevels {
            levels: self
                .filter
                .encode(self.filter.tile_input(&planes, &tile, scale)),
            width,
            height,
            scale,
        })
    }

    /// The centre frame's output from the window's encoder levels (`window`, one per frame,
    /// as rendered), each side frame's warped to the centre by `motion` before the blocks, at
    /// the centre's input scale `scale`.
    pub fn decode_warped(
        &self,
        window: &[&FrameLevels],
        motion: &MotionLevels,
        scale: f32,
    ) -> Result<Plane, FilterError> {
        let (w, h) = (window[0].width, window[0].height);
        if window.iter().any(|f| f.width != w || f.height != h) {
            return Err(FilterError::Shape(
                "the window's frames differ in size".into(),
            ));
        }
        let t = self.frames;
        let centre = &window[t / 2].levels;
        let mut levels: Vec<Blocked> = Vec::with_capacity(centre.len());
        let mut blends = self.blends.iter().peekable();
        for (l, own) in centre.iter().enumerate() {
            levels.push(match blends.next_if(|b| b.level == l) {
                Some(b) => {
                    let maps: Vec<&Blocked> = window.iter().map(|f| &f.levels[l]).collect();
                    self.blend_level(b, &maps, motion.at(l))
                }
                None => own.clone(),
            });
        }
        let tile = Self::whole(w, h);
        let result = self.filter.decode(levels);
        let mut out = Plane::zeros(w, h, 3);
        self.filter.tile_output(&result, &tile, scale, &mut out);
        self.filter.scratch().recycle(result);
        self.filter.scratch().trim();
        Ok(out)
    }

    /// A window's full-resolution motion (`motion`, padded to the frame's multiple of 16) at
    /// each level that has a block: pooled once per window, for the beauty and every AOV.
    pub fn motion_levels(&self, motion: HostMotion) -> MotionLevels {
        let deepest = self.blends.iter().map(|b| b.level).max().unwrap_or(0);
        let mut levels: Vec<Option<HostMotion>> = (0..=deepest)
            .map(|l| {
                (l > 0 && self.blends.iter().any(|b| b.level == l)).then(|| motion.at_level(l))
            })
            .collect();
        levels[0] = Some(motion);
        MotionLevels(levels)
    }

    /// The one tile of a whole `w × h` frame.
    fn whole(w: usize, h: usize) -> Tile {
        Tile {
            buffer: [
                0,
                0,
                w.next_multiple_of(ALIGNMENT),
                h.next_multiple_of(ALIGNMENT),
            ],
            core: [0, 0, w, h],
        }
    }

    /// The window's encoder levels (one list per frame, aligned) blended into the centre
    /// frame's.
    fn blend(&self, mut levels: Vec<Vec<Blocked>>) -> Vec<Blocked> {
        let t = self.frames;
        let scratch = self.filter.scratch();
        for b in &self.blends {
            let maps: Vec<&Blocked> = levels.iter().map(|f| &f[b.level]).collect();
            let mixed = self.blend_level(b, &maps, None);
            scratch.recycle(std::mem::replace(&mut levels[t / 2][b.level], mixed));
        }
        let centre = levels.swap_remove(t / 2);
        for frame in levels {
            for m in frame {
                scratch.recycle(m);
            }
        }
        centre
    }

    /// One blended level: the window's maps at that level (`maps`, one per frame; with
    /// `motion`, the window's motion at that level, side frames' are first warped to the
    /// centre), the block's result for the centre let into the centre's map through the gate.
    fn blend_level(
        &self,
        b: &HostBlend,
        maps: &[&Blocked],
        motion: Option<&HostMotion>,
    ) -> Blocked {
        let t = self.frames;
        let (c, hh, ww) = (maps[0].channels(), maps[0].height(), maps[0].width());
        let plane = hh * ww;
        let map = c * plane;
        let t0 = std::time::Instant::now();
        let mut stacked = vec![0.0f32; t * map];
        for (m, dst) in maps.iter().zip(stacked.chunks_mut(map)) {
            m.to_planar_into(dst);
        }
        if let Some(at) = motion {
            let centre = stacked[t / 2 * map..][..map].to_vec();
            for k in (0..t).filter(|&k| k != t / 2) {
                let warped = at.to_centre(k, &stacked[k * map..][..map], &centre);
                stacked[k * map..][..map].copy_from_slice(&warped);
            }
        }
        let t1 = std::time::Instant::now();
        let blended_centre = b.ra.centre_on_host(&stacked, [t, c, hh, ww]);
        let t2 = std::time::Instant::now();
        let centre = &stacked[t / 2 * map..][..map];
        let mut mixed = vec![0.0f32; map];
        for ch in 0..c {
            let g = b.gate[ch];
            let range = ch * plane..(ch + 1) * plane;
            for ((o, &h), &a) in mixed[range.clone()]
                .iter_mut()
                .zip(&centre[range.clone()])
                .zip(&blended_centre[range])
            {
                *o = h + (a - h) * g;
            }
        }
        let out = Blocked::from_planar(&mixed, c, hh, ww);
        tracing::trace!(
            "blend at level {}: {:.1} ms to the block, {:.1} ms in it, {:.1} ms after",
            b.level,
            (t1 - t0).as_secs_f64() * 1e3,
            (t2 - t1).as_secs_f64() * 1e3,
            t2.elapsed().as_secs_f64() * 1e3
        );
        out
    }

    /// The tiles a `w × h` window runs in within `budget` pixels, overlapping by
    /// [`TemporalFilter::reach`] so that tiled output equals whole-frame output.
    pub fn tiles_within(&self, w: usize, h: usize, budget: usize) -> Vec<Tile> {
        let ov = self.reach().next_multiple_of(ALIGNMENT);
        self.filter.tiles_overlapping(w, h, budget, ov)
    }

    /// How many pixels beyond an output pixel the network reads: the U-Net's reach plus the
    /// widest block's (a block at level k reads its own reach at scale 2^k; any path from the
    /// output to the input passes through one block, and the encoder to level k and the
    /// decoder from it are parts of the U-Net's deepest path).
    pub fn reach(&self) -> usize {
        let blocks = self
            .blends
            .iter()
            .map(|b| b.ra.centre_reach() << b.level)
            .max()
            .unwrap_or(0);
        let input = if self.input.is_some() {
            InputBlend::reach()
        } else {
            0
        };
        self.filter.config().layers.reach() + blocks + input
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::oidn_unet::input_blend::HostInputBlend;
    use crate::oidn_unet::temporal::TemporalConfig;
    use crate::oidn_unet::transfer::{AUX_ALBEDO, AUX_NORMAL, HDR_BEAUTY};
    use burn::tensor::{Device, Tensor, TensorData};

    fn plane(w: usize, h: usize, seed: usize, scale: f32) -> Plane {
        Plane::from_fn(w, h, 3, |x, y, c| {
            let i = (x * 7 + y * 13 + c * 5 + seed * 11) % 23;
            scale * (0.1 + i as f32 / 23.0)
        })
    }

    /// OIDN's standard U-Net converted over 3 frames with blocks at `levels` (their weights
    /// from `seed`) and every gate at `gate`.
    fn converted(levels: Vec<usize>, seed: u64, gate: f32) -> TemporalUnet {
        converted_with(levels, seed, gate, false)
    }

    /// [`converted`], with a learned input average where `input_blend`.
    fn converted_with(levels: Vec<usize>, seed: u64, gate: f32, input_blend: bool) -> TemporalUnet {
        let device = Device::flex();
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../models/oidn-rt_hdr_alb_nrm.safetensors");
        let unet = crate::oidn_unet::store::load(&path, &device).unwrap();
        device.seed(seed);
        let config = TemporalConfig {
            frames: 3,
            levels,
            color_confidence: None,
            warp: Default::default(),
            aux: Default::default(),
            input_frames: 1,
            stabilize: None,
            input_blend,
        };
        TemporalUnet::convert(unet, config, &device)
            .unwrap()
            .with_gates(gate)
    }

    /// A 3-frame window of beauty, albedo and normal planes.
    struct Frames {
        colors: Vec<Plane>,
        albedo: Vec<Plane>,
        normal: Vec<Plane>,
    }

    impl Frames {
        fn new(w: usize, h: usize) -> Self {
            Self {
                colors: (0..3).map(|k| plane(w, h, k, 2.0)).collect(),
                albedo: (0..3).map(|k| plane(w, h, k + 5, 0.8)).collect(),
                normal: (0..3).map(|k| plane(w, h, k + 9, 1.0)).collect(),
            }
        }

        fn window(&self) -> Vec<UnetImages<'_>> {
            (0..3)
                .map(|k| UnetImages {
                    color: Some(&self.colors[k]),
                    albedo: Some(&self.albedo[k]),
                    normal: Some(&self.normal[k]),
                })
                .collect()
        }

        /// The processed window as burn's input `[3, 9, ph, pw]`, padded with zeros as the
        /// filter pads.
        fn processed(&self, scale: f32, pw: usize, ph: usize) -> Tensor<4> {
            let (w, h) = (self.colors[0].width(), self.colors[0].height());
            let mut x = vec![0.0f32; 3 * 9 * ph * pw];
            for k in 0..3 {
                let images = [
                    (&self.colors[k], HDR_BEAUTY),
                    (&self.albedo[k], AUX_ALBEDO),
                    (&self.normal[k], AUX_NORMAL),
                ];
                for (j, (p, proc_)) in images.into_iter().enumerate() {
                    for c in 0..3 {
                        for yy in 0..h {
                            for xx in 0..w {
                                x[((k * 9 + j * 3 + c) * ph + yy) * pw + xx] =
                                    proc_.input(p.get(xx, yy, c), scale);
                            }
                        }
                    }
                }
            }
            Tensor::from_data(TensorData::new(x, [3, 9, ph, pw]), &Device::flex())
        }
    }

    /// The largest difference between `out` and burn's output `y` (`[1, 3, ph, pw]`, before
    /// the output processing at `scale`) over `out`'s pixels.
    fn from_burn(out: &Plane, y: Tensor<4>, scale: f32) -> f32 {
        let [_, _, ph, pw] = y.dims();
        let y = y.into_data().try_to_vec::<f32>().unwrap();
        let mut worst = 0.0f32;
        for c in 0..3 {
            for yy in 0..out.height() {
                for xx in 0..out.width() {
                    let want = HDR_BEAUTY.output(y[(c * ph + yy) * pw + xx], scale);
                    worst = worst.max((out.get(xx, yy, c) - want).abs());
                }
            }
        }
        worst
    }

    /// The largest difference between two RGB planes.
    fn largest(a: &Plane, b: &Plane) -> f32 {
        (0..3)
            .flat_map(|c| a.channel(c).iter().zip(b.channel(c)))
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max)
    }

    /// The CPU path equals burn's forward of the same network (gates open, so the blocks'
    /// weights count), whole and in tiles.
    #[test]
    fn the_cpu_path_equals_burns_forward() {
        let net = converted(vec![0, 1, 4], 5, 0.7);
        let frames = Frames::new(40, 36);
        let window = frames.window();
        let filter = TemporalFilter::new(&net);
        let scale = filter.unet().autoexposure(&frames.colors[1]);
        let whole = filter.run(&window, scale, usize::MAX).unwrap();
        let y = net.forward(frames.processed(scale, 48, 48), None);
        let worst = from_burn(&whole, y, scale);
        assert!(worst < 1e-4, "largest difference {worst}");
        // the gates matter: closed, the result is the per-frame U-Net's and differs
        let closed = TemporalFilter::new(&net.clone().with_gates(0.0));
        let per_frame = closed.run(&window, scale, usize::MAX).unwrap();
        let moved = largest(&per_frame, &whole);
        assert!(moved > 1e-3, "the open gates changed nothing ({moved})");
        let single = closed.unet().run(&window[1], Some(scale)).unwrap();
        assert_eq!(per_frame.channel(0), single.channel(0));
    }

    /// With a learned input average, the CPU path (the shares applied to the window's linear
    /// colour, then the network on that centre) equals burn's forward; closed, it keeps the
    /// centre as rendered.
    #[test]
    fn the_cpu_input_average_equals_burns() {
        // frames on the U-Net's 16-pixel grid: burn's blend then sees no padding, which the
        // CPU path (computed on the frame itself) never reads
        let net = converted_with(vec![0, 2], 4, 0.7, true);
        let frames = Frames::new(48, 32);
        let window = frames.window();
        let filter = TemporalFilter::new(&net);
        let scale = filter.unet().autoexposure(&frames.colors[1]);
        let shares = filter.input_shares(&window, scale).unwrap().unwrap();
        for i in [0, 700, 1535] {
            let sum: f32 = shares.iter().map(|s| s[i]).sum();
            assert!((sum - 1.0).abs() < 1e-5, "shares sum to {sum}");
            assert!(shares.iter().all(|s| (0.0..=1.0).contains(&s[i])));
        }
        let colours: Vec<&Plane> = frames.colors.iter().collect();
        let blended = HostInputBlend::apply(&colours, &shares);
        let mut averaged = window.clone();
        averaged[1].color = Some(&blended);
        let host = filter.run(&averaged, scale, usize::MAX).unwrap();
        let y = net.forward(frames.processed(scale, 48, 32), None);
        let worst = from_burn(&host, y, scale);
        assert!(worst < 1e-4, "largest difference {worst}");
        // the blend moved the centre's input
        assert!(largest(&blended, &frames.colors[1]) > 1e-2);
        // a shut gate: every share on the centre, the input as rendered, bit for bit
        let shut = TemporalFilter::new(&net.with_gates(0.0));
        let shares = shut.input_shares(&window, scale).unwrap().unwrap();
        let kept = HostInputBlend::apply(&colours, &shares);
        assert_eq!(kept.data(), frames.colors[1].data());
    }

    /// Tiles overlapping by the blocks' reach as well as the U-Net's give the whole frame's
    /// output; the U-Net's overlap alone does not (the blocks read further).
    #[test]
    fn tiled_output_equals_whole_frame_output() {
        let net = converted(vec![0, 2, 4], 9, 0.8);
        let filter = TemporalFilter::new(&net);
        let (w, h) = (720, 40);
        let frames = Frames::new(w, h);
        let window = frames.window();
        let scale = filter.unet().autoexposure(&frames.colors[1]);
        let whole = filter.run(&window, scale, usize::MAX).unwrap();
        let ov = filter.reach().next_multiple_of(ALIGNMENT);
        assert!(ov > filter.unet().config().layers.overlap());
        let budget = 48 * (2 * ov + 64);
        let tiles = filter.tiles_within(w, h, budget);
        assert!(tiles.len() >= 3, "{} tiles", tiles.len());
        let tiled = filter.run(&window, scale, budget).unwrap();
        assert_eq!(largest(&whole, &tiled), 0.0, "tiled differs from whole");
        // the U-Net's own overlap misses what the blocks read
        let unet_overlap = filter.unet().config().layers.overlap();
        let short = filter
            .run_in_tiles(&window, scale, |w, h| {
                filter.unet().tiles_overlapping(w, h, budget, unet_overlap)
            })
            .unwrap();
        // (the far rows weigh little through these weights: some 4e-6, so only exactness shows it)
        assert!(
            largest(&whole, &short) > 0.0,
            "the blocks' reach made no difference"
        );
    }

    /// With motion, the CPU path warps each frame's levels as burn's forward does.
    #[test]
    fn the_feature_warped_cpu_path_equals_burns_forward_with_motion() {
        use crate::oidn_unet::cpu::feature_warp::HostMotion;
        use crate::oidn_unet::feature_warp::WindowMotion;
        let net = converted(vec![0, 1, 3], 3, 0.6);
        let (w, h) = (48, 32);
        let frames = Frames::new(w, h);
        let flows: Vec<Plane> = (0..3)
            .map(|k| {
                Plane::from_fn(w, h, 2, |x, y, c| {
                    if k == 1 {
                        0.0
                    } else {
                        ((x * 3 + y * 5 + c * 7 + k) % 17) as f32 / 2.0 - 4.0
                    }
                })
            })
            .collect();
        let confs: Vec<Plane> = (0..3)
            .map(|k| {
                Plane::from_fn(w, h, 1, |x, y, _| {
                    if k == 1 {
                        1.0
                    } else {
                        ((x + y) % 4) as f32 / 3.0
                    }
                })
            })
            .collect();
        let window = frames.window();
        let filter = TemporalFilter::new(&net);
        let scale = filter.unet().autoexposure(&frames.colors[1]);
        let motion = HostMotion::padded(
            &flows.iter().collect::<Vec<_>>(),
            &confs.iter().collect::<Vec<_>>(),
            w,
            h,
        );
        let cpu = filter.run_warped(&window, motion, scale).unwrap();
        let stacked = |planes: &[Plane], channels: usize| -> Tensor<4> {
            let data = planes.iter().flat_map(|f| f.data().to_vec()).collect();
            Tensor::from_data(TensorData::new(data, [3, channels, h, w]), &Device::flex())
        };
        let m = WindowMotion {
            offsets: stacked(&flows, 2),
            confidence: stacked(&confs, 1),
        };
        let y = net.forward(frames.processed(scale, w, h), Some(&m));
        let worst = from_burn(&cpu, y, scale);
        assert!(worst < 1e-4, "largest difference {worst}");
        // the motion matters: the same frames without it differ
        let still = filter.run(&window, scale, usize::MAX).unwrap();
        let moved = largest(&still, &cpu);
        assert!(moved > 1e-3, "the motion changed nothing ({moved})");
    }
}
