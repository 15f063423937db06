//! `radn denoise --method temporal`: OIDN's U-Net converted into the paper's spatio-temporal
//! network ([`TemporalUnet`](crate::oidn_unet::temporal::TemporalUnet), fine-tuned by
//! `radn train`) over each frame's window, moved onto its centre frame by the renderer's motion
//! with radn's confidence. With `warp = "features"` (the model's) each frame goes through the
//! encoder once and its levels are warped to the centre; with `"images"` the window is aligned
//! as images (with centre mixing, as the training tiles were) and every aligned frame goes
//! through the encoder; frames that run band by band warp images. Each AOV goes through the
//! same network with the same auxiliaries (one-channel AOVs as grey); alpha is kept as
//! rendered.

use std::borrow::Cow;
use std::ops::Range;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use radn_core::align::warp::Resampling;
use radn_core::align::{align_bands, align_window, AlignParams, AlignedWindow};
use radn_core::error::{Error, Result};
use radn_core::io::frame::Frame;
use radn_core::post::stabilize::{StabilizeSettings, TemporalStabilizer};
use radn_core::run::banding::{FrameBand, FrameStats, ALIGNMENT_EDGE_ROWS};
use radn_core::run::denoiser::{BandDenoiser, BandFeatures, Denoised, WindowDenoiser};
use radn_core::Plane;

use crate::oidn_unet::config::ALIGNMENT;
use crate::oidn_unet::cpu::feature_warp::HostMotion;
use crate::oidn_unet::denoiser::{as_rgb, to_channels};
use crate::oidn_unet::filter::{UnetImages, DEFAULT_MAX_TILE_PIXELS};
use crate::oidn_unet::input_blend::HostInputBlend;
use crate::oidn_unet::input_mean::window_mean;
use crate::oidn_unet::prefilter::{cleaned_of, AuxPrefilter, CLEAN_AUX_CHANNELS};
use crate::oidn_unet::temporal::{AuxSource, TemporalConfig, WarpSpace};
use crate::oidn_unet::temporal_filter::{FrameLevels, TemporalFilter};

/// The network's tiles hold at most this many pixels (overlap included) unless set: a 1080p
/// frame runs as one tile. Each pixel of a tile holds every window frame's encoder levels, the
/// blocks' working maps and the decoder's, so `--tile` trades memory for time.
pub const DEFAULT_TILE_PIXELS: usize = DEFAULT_MAX_TILE_PIXELS;

/// How far (in stops) a side frame's exposure may be from the centre's for the levels made at
/// its own exposure to serve the centre's window: further, it goes through the encoder again
/// at the centre's, since the blocks were trained on windows at one exposure. Small enough that
/// reuse changes nothing measurable, large enough that slowly brightening shots reuse every
/// frame's levels (docs/research/oidn-temporal.md).
pub const EXPOSURE_REUSE_STOPS: f32 = 1.0 / 16.0;

/// The temporal method: a converted U-Net and how its windows are aligned.
pub struct TemporalDenoiser {
    filter: TemporalFilter,
    align: AlignParams,
    name: String,
    tile_pixels: usize,
    warp: WarpSpace,
    prefilter: Option<AuxPrefilter>,
    input_frames: usize,
    input_blend: bool,
    stabilize: Option<StabilizeSettings>,
    cache: Mutex<LevelCache>,
}

impl TemporalDenoiser {
    /// Runs `filter` on windows aligned with radn's default alignment (the training tiles')
    /// and the model's colour term, moved onto the centre as the model's `config` says; with
    /// `prefilter` (required by, and only by, models whose auxiliaries are prefiltered) every
    /// frame's albedo and normal are cleaned first. `name` labels the model in the summary.
    pub fn new(
        filter: TemporalFilter,
        config: &TemporalConfig,
        name: String,
        prefilter: Option<AuxPrefilter>,
    ) -> Self {
        assert_eq!(
            config.aux == AuxSource::Prefiltered,
            prefilter.is_some(),
            "a prefiltered model needs its prefilters, and only it"
        );
        let mut align = AlignParams::default();
        align.confidence.color = config.color_confidence;
        if config.input_frames > 1 || config.input_blend {
            // the mean's noise stays per pixel (white, as the U-Net was trained on) with
            // nearest-pixel samples; blended samples leave it correlated, which the U-Net
            // keeps as blotches on dark, noisy frames (docs/research/oidn-temporal.md)
            align.resampling = Resampling::Nearest;
        }
        Self {
            filter,
            align,
            name,
            tile_pixels: DEFAULT_TILE_PIXELS,
            warp: config.warp,
            prefilter,
            input_frames: config.input_frames,
            input_blend: config.input_blend,
            stabilize: config.stabilize,
            cache: Mutex::default(),
        }
    }

    /// Caps the network's tiles at `pixels` (overlap included): less memory, more time
    /// (tiles overlap by the network's reach). The output does not depend on it.
    pub fn with_tile_pixels(mut self, pixels: usize) -> Self {
        self.tile_pixels = pixels.max(ALIGNMENT * ALIGNMENT);
        self
    }

    /// The temporal pass over the results the model asks for, if any.
    pub fn stabilizer(&self) -> Option<TemporalStabilizer> {
        self.stabilize.map(|s| s.stabilizer())
    }

    /// Which model runs, for the run's summary line.
    pub fn summary(&self) -> String {
        let c = self.filter.unet().config();
        format!(
            "{} ({}{} over {} frames{}, OIDN {}, {} warped)",
            self.name,
            c.weights,
            self.prefilter.as_ref().map_or(String::new(), |p| {
                let (a, n) = p.names();
                format!(" on {a} and {n}")
            }),
            self.filter.frames(),
            match (self.input_frames, self.input_blend) {
                (_, true) => ", input averaged as learned".to_string(),
                (1, false) => String::new(),
                (n, false) => format!(", input averaged over {n}"),
            } + &self.stabilize.map_or(String::new(), |s| {
                format!(", results stabilized at {}", s.strength)
            }),
            c.oidn_version,
            match self.warp {
                WarpSpace::Images => "images",
                WarpSpace::Features => "features",
            }
        )
    }

    /// Rows `out` of the centre of the aligned window `win` (the rows of `centre`, a frame or
    /// a band of one), the beauty and each AOV at its exposure in `scales` (the beauty's, then
    /// each AOV's in the reader's order).
    fn denoise_aligned(
        &self,
        win: &AlignedWindow,
        centre: &Frame,
        scales: &[f32],
        out: Range<usize>,
    ) -> Result<Denoised> {
        let fail = |e: crate::oidn_unet::filter::FilterError| Error::Unsupported {
            path: centre.path.clone(),
            detail: e.to_string(),
        };
        let whole = out == (0..centre.height());
        // one plane per frame of the window through the network, with every frame's aligned
        // auxiliaries
        let run = |planes: &[Cow<Plane>], scale: f32| -> Result<Plane> {
            let images: Vec<UnetImages> = win
                .frames
                .iter()
                .zip(planes)
                .map(|(f, p)| UnetImages {
                    color: Some(p),
                    albedo: f.albedo.as_ref(),
                    normal: f.normal.as_ref(),
                })
                .collect();
            let d = self
                .filter
                .run(&images, scale, self.tile_pixels)
                .map_err(fail)?;
            Ok(if whole { d } else { d.rows(out.clone()) })
        };
        let colors: Vec<Cow<Plane>> = win.frames.iter().map(|f| Cow::Borrowed(&f.color)).collect();
        let color = run(&colors, scales[0])?;
        let mut aovs = Vec::with_capacity(centre.aovs.len());
        for (k, (a, &scale)) in centre.aovs.iter().zip(&scales[1..]).enumerate() {
            let planes: Vec<Cow<Plane>> = win.frames.iter().map(|f| as_rgb(&f.aovs[k])).collect();
            aovs.push(to_channels(run(&planes, scale)?, a.plane.channels()));
        }
        Ok(Denoised {
            color,
            alpha: centre.alpha.as_ref().map(|a| {
                if whole {
                    a.clone()
                } else {
                    a.rows(out.clone())
                }
            }),
            aovs,
        })
    }
}

impl TemporalDenoiser {
    /// The centre of `window` with each frame's encoder levels (made once per frame, at the
    /// frame's own exposure, and kept while windows still read them) warped to the centre by
    /// the motion and confidence alignment found (`win`); frames beyond the sequence ends are
    /// the centre's, at zero confidence.
    fn denoise_warped(
        &self,
        window: &[Option<&Frame>],
        win: &AlignedWindow,
        mean: Option<&Frame>,
        scales: &[f32],
    ) -> Result<Denoised> {
        let centre = window[self.radius()].expect("the centre frame is present");
        let frames: Vec<&Frame> = window.iter().map(|f| f.unwrap_or(centre)).collect();
        let (w, h) = (centre.width(), centre.height());
        let motion = self.filter.motion_levels(HostMotion::padded(
            &win.frames.iter().map(|f| &f.flow).collect::<Vec<_>>(),
            &win.frames.iter().map(|f| &f.confidence).collect::<Vec<_>>(),
            w.next_multiple_of(ALIGNMENT),
            h.next_multiple_of(ALIGNMENT),
        ));
        let run = |image: usize| -> Result<Plane> {
            // the blocks mix the window's levels, so they must share the centre's exposure: a
            // side frame's own levels serve where its exposure is within
            // EXPOSURE_REUSE_STOPS of the centre's, else it goes through the encoder again
            let levels = frames
                .iter()
                .enumerate()
                .map(|(k, f)| {
                    // the centre's input averaged over its window is encoded for this window
                    // alone; the frame as rendered serves its neighbours' windows
                    if let Some(m) = mean.filter(|_| k == self.radius()) {
                        return self
                            .encode(m, image, scales[image], "from its window's mean")
                            .map(Arc::new);
                    }
                    let own = self.levels_of(f, image)?;
                    let stops = (own.scale() / scales[image]).log2().abs();
                    if stops <= EXPOSURE_REUSE_STOPS {
                        Ok(own)
                    } else {
                        self.encode(f, image, scales[image], "again at the centre's exposure")
                            .map(Arc::new)
                    }
                })
                .collect::<Result<Vec<_>>>()?;
            let refs: Vec<&FrameLevels> = levels.iter().map(|l| l.as_ref()).collect();
            self.filter
                .decode_warped(&refs, &motion, scales[image])
                .map_err(|e| Error::Unsupported {
                    path: centre.path.clone(),
                    detail: e.to_string(),
                })
        };
        let color = run(0)?;
        let mut aovs = Vec::with_capacity(centre.aovs.len());
        for (k, a) in centre.aovs.iter().enumerate() {
            aovs.push(to_channels(run(k + 1)?, a.plane.channels()));
        }
        Ok(Denoised {
            color,
            alpha: centre.alpha.clone(),
            aovs,
        })
    }

    /// Frame `f`'s encoder levels of its beauty (`image` 0) or of AOV `image` − 1 at the
    /// plane's own exposure, from the cache or made now and kept.
    fn levels_of(&self, f: &Frame, image: usize) -> Result<Arc<FrameLevels>> {
        let key = (f.path.clone(), image);
        if let Some(hit) = self.cache.lock().expect("no panic while held").get(&key) {
            return Ok(hit);
        }
        let scale = self.filter.unet().autoexposure(Self::rendered(f, image));
        let levels = Arc::new(self.encode(f, image, scale, "at its own exposure")?);
        self.cache.lock().expect("no panic while held").insert(
            key,
            levels.clone(),
            self.filter.frames() * (1 + f.aovs.len()),
        );
        Ok(levels)
    }

    /// The plane `image` of frame `f` as rendered: the beauty (0) or AOV `image` − 1.
    fn rendered(f: &Frame, image: usize) -> &Plane {
        match image {
            0 => &f.color,
            k => &f.aovs[k - 1].plane,
        }
    }

    /// Frame `f`'s encoder levels of plane `image` at input scale `scale` (`why`: for the log).
    fn encode(&self, f: &Frame, image: usize, scale: f32, why: &str) -> Result<FrameLevels> {
        let plane = as_rgb(Self::rendered(f, image));
        let images = UnetImages {
            color: Some(&plane),
            albedo: f.albedo.as_ref(),
            normal: f.normal.as_ref(),
        };
        let started = std::time::Instant::now();
        let levels = self
            .filter
            .encode_frame(&images, scale)
            .map_err(|e| Error::Unsupported {
                path: f.path.clone(),
                detail: e.to_string(),
            })?;
        tracing::debug!(
            frame = %f.path.display(),
            image,
            scale,
            "encoder levels made {why} in {:.2} s ({} MB)",
            started.elapsed().as_secs_f64(),
            levels.bytes() >> 20
        );
        Ok(levels)
    }
}

impl TemporalDenoiser {
    /// The beauty and AOVs of the centre averaged over its aligned window `win`: over the
    /// middle `input_frames` frames, or with the shares the model's learned input average
    /// gives each frame (read from the window at the beauty's input scale `scale`); `None`
    /// when the model reads the centre (`centre`, named in errors) as rendered.
    fn input_mean(
        &self,
        win: &AlignedWindow,
        scale: f32,
        centre: &Frame,
    ) -> Result<Option<(Plane, Vec<Plane>)>> {
        if self.input_frames > 1 {
            return Ok(Some(window_mean(win, self.input_frames)));
        }
        if !self.input_blend {
            return Ok(None);
        }
        let images: Vec<UnetImages> = win
            .frames
            .iter()
            .map(|f| UnetImages {
                color: Some(&f.color),
                albedo: f.albedo.as_ref(),
                normal: f.normal.as_ref(),
            })
            .collect();
        let shares = self
            .filter
            .input_shares(&images, scale)
            .map_err(|e| Error::Unsupported {
                path: centre.path.clone(),
                detail: e.to_string(),
            })?;
        Ok(shares.map(|shares| {
            let blend = |planes: Vec<&Plane>| HostInputBlend::apply(&planes, &shares);
            let color = blend(win.frames.iter().map(|f| &f.color).collect());
            let aovs = (0..win.centre().aovs.len())
                .map(|a| blend(win.frames.iter().map(|f| &f.aovs[a]).collect()))
                .collect();
            (color, aovs)
        }))
    }
}

/// `win` with its centre's beauty and AOVs replaced by `mean`, where given.
fn with_centre(mut win: AlignedWindow, mean: Option<(Plane, Vec<Plane>)>) -> AlignedWindow {
    if let Some((color, aovs)) = mean {
        let r = win.radius();
        win.frames[r].color = color;
        win.frames[r].aovs = aovs;
    }
    win
}

/// `centre` (a frame) with its beauty and AOVs replaced by `mean`: what its encoder reads.
fn centre_with((color, aovs): (Plane, Vec<Plane>), centre: &Frame) -> Frame {
    let mut f = centre.clone();
    f.color = color;
    for (a, p) in f.aovs.iter_mut().zip(aovs) {
        a.plane = p;
    }
    f
}

/// Frame (or band) `f` with the albedo and normal its features hold cleaned
/// ([`AuxPrefilter::features`], made once per frame by the sequence job), or cleaned now where
/// it has no features (a window given frames directly).
fn with_clean_aux(f: &Frame, prefilter: &AuxPrefilter) -> Result<Frame> {
    let (albedo, normal) = match cleaned_of(f) {
        (Some(a), Some(n)) => (Some(a), Some(n)),
        _ => prefilter.clean(f, None)?,
    };
    Ok(Frame {
        albedo,
        normal,
        ..f.clone()
    })
}

/// The encoder levels of the frames the latest windows read, the least recently used first.
#[derive(Default)]
struct LevelCache {
    entries: Vec<((PathBuf, usize), Arc<FrameLevels>)>,
}

impl LevelCache {
    /// The levels kept for `key`, now the most recently used.
    fn get(&mut self, key: &(PathBuf, usize)) -> Option<Arc<FrameLevels>> {
        let i = self.entries.iter().position(|(k, _)| k == key)?;
        let entry = self.entries.remove(i);
        let levels = entry.1.clone();
        self.entries.push(entry);
        Some(levels)
    }

    /// Keeps `levels` for `key`, dropping the least recently used beyond `capacity`.
    fn insert(&mut self, key: (PathBuf, usize), levels: Arc<FrameLevels>, capacity: usize) {
        self.entries.retain(|(k, _)| *k != key);
        self.entries.push((key, levels));
        let excess = self.entries.len().saturating_sub(capacity.max(1));
        self.entries.drain(..excess);
    }
}

impl WindowDenoiser for TemporalDenoiser {
    fn radius(&self) -> usize {
        self.filter.frames() / 2
    }

    fn frame_features(&self, frame: &Frame) -> Option<Plane> {
        let p = self.prefilter.as_ref()?;
        Some(p.features(frame, 0..frame.height(), None))
    }

    fn has_frame_features(&self) -> bool {
        self.prefilter.is_some()
    }

    fn denoise(&self, window: &[Option<&Frame>]) -> Result<Denoised> {
        // with prefiltered auxiliaries the window is made of copies that hold them
        let cleaned: Vec<Option<Frame>> = match &self.prefilter {
            Some(p) => window
                .iter()
                .map(|f| f.map(|f| with_clean_aux(f, p)).transpose())
                .collect::<Result<_>>()?,
            None => Vec::new(),
        };
        let window: Vec<Option<&Frame>> = if self.prefilter.is_some() {
            cleaned.iter().map(Option::as_ref).collect()
        } else {
            window.to_vec()
        };
        let window = window.as_slice();
        let r = self.radius();
        let centre = window[r].expect("the centre frame is present");
        let win = align_window(window, &self.align);
        // every plane at OIDN's exposure of the centre's plane as rendered
        let scales: Vec<f32> = std::iter::once(&centre.color)
            .chain(centre.aovs.iter().map(|a| &a.plane))
            .map(|p| self.filter.unet().autoexposure(p))
            .collect();
        let mean = self.input_mean(&win, scales[0], centre)?;
        match self.warp {
            WarpSpace::Images => {
                let win = with_centre(win, mean);
                self.denoise_aligned(&win, centre, &scales, 0..centre.height())
            }
            WarpSpace::Features => {
                let mean = mean.map(|m| centre_with(m, centre));
                self.denoise_warped(window, &win, mean.as_ref(), &scales)
            }
        }
    }

    fn banded(&self) -> Option<&dyn BandDenoiser> {
        // feature warping keeps whole frames' levels; frames large enough to run band by band
        // (above the job's band size) warp images instead, which measured the same quality
        Some(self)
    }
}

impl BandDenoiser for TemporalDenoiser {
    fn band_rows(&self, width: usize, limit: usize) -> usize {
        // bands whose rows and halo fill about one tile, but at least twice the halo (which
        // each band computes again), on the network's 16-row grid so that every band starts
        // on the whole frame's
        let halo = self.halo();
        let rows = (self.tile_pixels / width.max(1))
            .saturating_sub(2 * halo)
            .max(2 * halo)
            .min(limit);
        (rows / ALIGNMENT * ALIGNMENT).max(ALIGNMENT)
    }

    fn halo(&self) -> usize {
        // the network's reach, and the rows banded alignment gets wrong next to a band's cut
        (self.filter.reach() + ALIGNMENT_EDGE_ROWS).next_multiple_of(ALIGNMENT)
    }

    fn band_features(&self) -> Option<BandFeatures> {
        // prefiltered auxiliaries are cleaned band by band first, with the prefilters' halo
        self.prefilter.as_ref().map(|p| BandFeatures {
            channels: CLEAN_AUX_CHANNELS,
            halo: p.reach().next_multiple_of(ALIGNMENT),
        })
    }

    fn frame_band_features(
        &self,
        band: FrameBand,
        out: Range<usize>,
        _stats: &FrameStats,
    ) -> Option<Plane> {
        let p = self.prefilter.as_ref()?;
        Some(p.features(band.frame, out, Some(self.tile_pixels)))
    }

    fn denoise_band(
        &self,
        window: &[Option<FrameBand>],
        out: Range<usize>,
        centre: &FrameStats,
    ) -> Result<Denoised> {
        // bands warp images in either warp space (see `banded`); with prefiltered auxiliaries
        // each band is a copy holding them
        let cleaned: Vec<Option<Frame>> = match &self.prefilter {
            Some(p) => window
                .iter()
                .map(|b| b.map(|b| with_clean_aux(b.frame, p)).transpose())
                .collect::<Result<_>>()?,
            None => Vec::new(),
        };
        let window: Vec<Option<FrameBand>> = if self.prefilter.is_some() {
            window
                .iter()
                .zip(&cleaned)
                .map(|(b, c)| {
                    b.zip(c.as_ref()).map(|(b, c)| FrameBand {
                        frame: c,
                        y0: b.y0,
                        full_height: b.full_height,
                    })
                })
                .collect()
        } else {
            window.to_vec()
        };
        let band = window[self.radius()].expect("the centre band is present");
        let win = align_bands(&window, &self.align);
        // every band at the exposure of the whole centre frame's planes
        let scales: Vec<f32> = centre
            .autoexposure
            .iter()
            .map(|bins| self.filter.unet().exposure_of(bins))
            .collect();
        let mean = self.input_mean(&win, scales[0], band.frame)?;
        let win = with_centre(win, mean);
        self.denoise_aligned(&win, band.frame, &scales, out)
    }
}
