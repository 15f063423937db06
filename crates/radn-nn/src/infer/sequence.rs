//! The network as a sequence method: whole windows, or bands of rows with their halo.

use std::ops::Range;

use radn_core::align::align_bands;
use radn_core::io::frame::Frame;
use radn_core::post::wiener::LOCAL_VARIANCE_RADIUS;
use radn_core::run::banding::{FrameBand, FrameStats, ALIGNMENT_EDGE_ROWS};
use radn_core::run::denoiser::{BandDenoiser, BandFeatures, Denoised, WindowDenoiser};
use radn_core::Plane;

use crate::infer::input::FeatureScales;
use crate::infer::stems::WindowStems;
use crate::profile::{self, timed, Stage};

use super::NetworkDenoiser;

/// Pixels of output per band when a frame goes band by band: a 512-pixel tile's row on frames
/// up to 2048 pixels wide, about 270 rows at 4K and 135 at 8K, so a band's memory stays about
/// the same whatever the width (`docs/research/guided-speed.md`, "Memory").
const BAND_PIXELS: usize = 1 << 20;

impl NetworkDenoiser {
    /// Whether the network's per-frame layers run once per frame as rendered and their
    /// features are warped into each window ([`crate::model::config::NetConfig::frame_local_stem`]).
    pub fn reuses_frame_layers(&self) -> bool {
        self.denoiser.config.frame_local_stem && self.warp_stem_features
    }

    /// A guided network needs every frame's guide: an error naming the first frame without
    /// one. A network that reads no guide ignores guides.
    fn check_guides<'f>(&self, frames: impl Iterator<Item = &'f Frame>) -> radn_core::Result<()> {
        if !self.denoiser.config.inputs.guide {
            return Ok(());
        }
        match frames.into_iter().find(|f| f.guide.is_none()) {
            Some(f) => Err(radn_core::Error::Guide {
                path: f.path.clone(),
                detail: "the model reads a guide and this frame has none (give one with \
                         --guide oidn, --guide denoised or --guide LAYER)"
                    .into(),
            }),
            None => Ok(()),
        }
    }
}

impl WindowDenoiser for NetworkDenoiser {
    fn radius(&self) -> usize {
        self.denoiser.config.frames / 2
    }

    fn frame_features(&self, frame: &Frame) -> Option<Plane> {
        self.reuses_frame_layers().then(|| self.frame_stem(frame))
    }

    fn has_frame_features(&self) -> bool {
        self.reuses_frame_layers()
    }

    fn denoise(&self, window: &[Option<&Frame>]) -> radn_core::Result<Denoised> {
        self.check_guides(window.iter().flatten().copied())?;
        let (win, scales) = timed(Stage::Align, || self.align_for_centre(window));
        let stems = self
            .reuses_frame_layers()
            .then(|| WindowStems::new(window, &win, self.resampling(), |f| self.frame_stem(f)));
        let h = win.centre().color.height();
        let out = self.denoise_rows(&win, stems.as_ref(), scales, 0..h);
        log_stages(
            window
                .get(window.len() / 2)
                .copied()
                .flatten()
                .map(|f| f.path.as_path()),
        );
        Ok(out)
    }

    fn banded(&self) -> Option<&dyn BandDenoiser> {
        // tiles of a receptive field's halo make bands possible; UNets and `--tile 0` need
        // whole frames (multi-scale kernels are banded on their grid: `band_rows`, `halo`)
        (self.tile > 0 && self.denoiser.receptive_radius().is_some()).then_some(self as _)
    }
}

impl BandDenoiser for NetworkDenoiser {
    fn band_rows(&self, width: usize, limit: usize) -> usize {
        // one row of tiles, on the coarsest kernel scale's grid so every band starts on it;
        // fewer rows on frames so wide that a band's window (five frames of every input and
        // their aligned copies, some 250 bytes a pixel) would outgrow BAND_PIXELS
        let g = self.denoiser.tile_grid();
        let rows = self.tile.min(BAND_PIXELS / width.max(1)).min(limit);
        (rows / g * g).max(g)
    }

    fn halo(&self) -> usize {
        // the network's receptive field (after the stem, where each frame's stem features are
        // computed once and given), and the rows banded alignment gets wrong at a cut; the
        // refine blend reads the result `p.radius` rows further, and the window's noise
        // `LOCAL_VARIANCE_RADIUS` beyond those. With multi-scale kernels the tiles' regions
        // start and end on the coarsest grid (`tiles`), and the halo is a multiple of it, so
        // a band (its first row `band_rows` · i − halo) starts on the frame's grid too.
        let g = self.denoiser.tile_grid();
        let network = if self.reuses_frame_layers() {
            self.denoiser.receptive_radius_after_stem()
        } else {
            self.denoiser.receptive_radius()
        };
        let refine = self.recipe.input_blend.map_or(0, |p| {
            let estimated = p.radius.div_ceil(g) * g + LOCAL_VARIANCE_RADIUS;
            // on frames with the renderer's variance: its box and the brightness box inside it
            let variance = p.variance_radius.map_or(0, |r| r + 1);
            estimated.max(variance)
        });
        (network.unwrap_or(0) + refine + ALIGNMENT_EDGE_ROWS).div_ceil(g) * g
    }

    fn band_features(&self) -> Option<BandFeatures> {
        self.reuses_frame_layers().then(|| BandFeatures {
            channels: self.denoiser.stem_channels(),
            halo: self.denoiser.stem_radius(),
        })
    }

    fn frame_band_features(
        &self,
        band: FrameBand,
        out: Range<usize>,
        stats: &FrameStats,
    ) -> Option<Plane> {
        self.reuses_frame_layers()
            .then(|| self.frame_stem_rows(band.frame, FeatureScales::of_stats(stats), out))
    }

    fn denoise_band(
        &self,
        window: &[Option<FrameBand>],
        out: Range<usize>,
        centre: &FrameStats,
    ) -> radn_core::Result<Denoised> {
        self.check_guides(window.iter().flatten().map(|b| b.frame))?;
        let params = self.align_params_for(centre.noise_level());
        let win = timed(Stage::Align, || align_bands(window, &params));
        let scales = FeatureScales::of_stats(centre);
        if out.start == 0 {
            if let Some(b) = self.recipe.input_blend {
                tracing::debug!(
                    frame = %centre.names.path.display(),
                    noise_level = ?scales.noise_level,
                    noise_scale = ?b
                        .params(scales.noise_level, &self.recipe.schedule)
                        .map(|p| p.noise_scale),
                    "input blend"
                );
            }
        }
        let stems = self
            .reuses_frame_layers()
            .then(|| WindowStems::of_bands(window, &win, self.resampling()));
        let band = out.clone();
        let result = self.denoise_rows(&win, stems.as_ref(), scales, out);
        tracing::debug!(
            frame = %centre.names.path.display(),
            rows = ?band,
            "network stages: {}",
            profile::take()
        );
        Ok(result)
    }
}

/// Logs where the time of the frame just denoised went (`radn denoise -v`), and clears the
/// tally for the next frame.
fn log_stages(frame: Option<&std::path::Path>) {
    let times = profile::take();
    match frame {
        Some(p) => tracing::debug!(frame = %p.display(), "network stages: {times}"),
        None => tracing::debug!("network stages: {times}"),
    }
}
