//! Denoising with a network: windows aligned by radn-core, kernels predicted tile by tile with a
//! halo of the network's receptive field (so the result does not depend on the tile size and
//! the network's memory does not grow with the frame), applied to colour, AOVs and alpha.
//! The network's inputs are built in [`input`]; temporal utilisation (paper Table 1) is
//! measured in [`utilization`].

mod frame_stem;
pub mod guide_mix;
pub mod input;
pub mod input_blend;
pub mod post;
pub mod schedule;
mod sequence;
pub mod signals;
pub mod stems;
mod tiles;
pub mod utilization;

use burn::tensor::Device;

use radn_core::align::warp::Resampling;
use radn_core::align::{align_window, AlignParams, AlignedWindow};
use radn_core::io::frame::Frame;
use radn_core::run::denoiser::Denoised;

use crate::infer::input::FeatureScales;
use crate::infer::schedule::NoiseSchedule;
use crate::infer::stems::WindowStems;
use crate::model::Denoiser;
use crate::recipe::Recipe;

/// A trained network as a sequence method: the network, its [`Recipe`] (every tuned setting of
/// alignment and of the stages after the kernels), and how the work is cut up.
pub struct NetworkDenoiser {
    /// The network.
    pub denoiser: Denoiser,
    /// The tuned inference settings (the model file's, or those its kind was tuned with).
    pub recipe: Recipe,
    /// Output tile side in pixels (0: the whole frame at once).
    pub tile: usize,
    /// Tiles of equal size per network call (1: one at a time, the fastest on a CPU; larger
    /// batches can pay where a call has fixed overhead, e.g. on a GPU).
    pub batch: usize,
    /// Where the network runs.
    pub device: Device,
    /// For a network with a frame-local stem: run the stem once per frame as rendered and warp
    /// its features into each window (true, the default), or run it in every window on the
    /// aligned frames as training does (false: five times the stem's work, for measuring what
    /// warping features instead of inputs changes). Ignored by other networks.
    pub warp_stem_features: bool,
}

/// How many times the confidence terms that compare sampled buffers
/// ([`radn_core::align::confidence::ConfidenceParams::loosened`]) loosen for a centre frame of noise
/// level `level`: the schedule's loosening (1 at the cleanest frames), at most `most`, and
/// `most` for frames too noisy for the schedule or without a level.
pub fn sampled_terms_loosening(level: Option<f32>, most: f32, schedule: &NoiseSchedule) -> f32 {
    schedule
        .loosening(level)
        .unwrap_or(most)
        .clamp(1.0, most.max(1.0))
}

/// `base` with the confidence terms that compare sampled buffers loosened for a centre frame of
/// noise level `level` by [`sampled_terms_loosening`] up to `most` (`None`: `base` as it is).
/// One rule for inference ([`NetworkDenoiser::align_params_for`]) and for the tiles a network
/// trains on (`radn_train::dataset::PrepareOptions::loosen_sampled_terms`), so a network
/// sees its training's windows at inference.
pub fn align_params_loosened(
    base: AlignParams,
    most: Option<f32>,
    level: Option<f32>,
    schedule: &NoiseSchedule,
) -> AlignParams {
    let mut p = base;
    if let Some(most) = most {
        p.confidence = p
            .confidence
            .loosened(sampled_terms_loosening(level, most, schedule));
    }
    p
}

/// Smallest tile [`auto_tile`] picks (the tile every model ran with before it existed).
const MIN_AUTO_TILE: usize = 256;
/// Largest tile [`auto_tile`] picks.
const MAX_AUTO_TILE: usize = 1024;
/// Bytes the widest per-tile map (features of every frame, or the kernel weights) may take
/// for [`auto_tile`] to double the tile: a few such maps are alive at once.
const AUTO_TILE_MAP_BYTES: usize = 128 << 20;

/// The output tile for `denoiser` when the user does not choose one: the largest of 256, 512
/// and 1024 pixels whose widest map (all frames' head features, or the kernel weights, over the
/// tile and its halo) stays within 128 MiB, and 256 at least. A tile computes its halo again,
/// so larger tiles do less work (`docs/research/benchmarks.md`); a wide model's maps would
/// take several hundred MB at 512.
pub fn auto_tile(denoiser: &Denoiser) -> usize {
    let Some(halo) = denoiser.receptive_radius() else {
        return MIN_AUTO_TILE; // a UNet runs whole frames whatever the tile
    };
    let per_pixel = (denoiser.config.frames * denoiser.feature_channels())
        .max(denoiser.config.kernel_taps())
        * std::mem::size_of::<f32>();
    let mut tile = MIN_AUTO_TILE;
    while tile * 2 <= MAX_AUTO_TILE {
        let side = tile * 2 + 2 * halo;
        if side * side * per_pixel > AUTO_TILE_MAP_BYTES {
            break;
        }
        tile *= 2;
    }
    tile
}

impl NetworkDenoiser {
    /// A denoiser running the model's recipe, with its [`auto_tile`].
    pub fn new(denoiser: Denoiser, device: Device) -> Self {
        let tile = auto_tile(&denoiser);
        let recipe = denoiser.recipe.clone();
        Self {
            denoiser,
            recipe,
            tile,
            batch: 1,
            device,
            warp_stem_features: true,
        }
    }

    /// Kernel threshold t (paper eq. 3): the recipe's, else the configuration's default.
    pub fn threshold(&self) -> f32 {
        self.recipe
            .threshold
            .unwrap_or_else(|| self.denoiser.config.default_threshold())
    }

    /// How side frames are sampled between pixels: the recipe's, else as the model was trained.
    pub fn resampling(&self) -> Resampling {
        self.recipe
            .resampling
            .unwrap_or(self.denoiser.config.resampling)
    }

    /// Alignment's options before the noise level loosens them: the model's resampling and the
    /// recipe's guide term.
    pub fn align_base(&self) -> AlignParams {
        let mut p = AlignParams {
            resampling: self.resampling(),
            ..AlignParams::default()
        };
        p.confidence.guide = self.recipe.confidence.guide;
        p
    }

    /// The alignment options for a window whose centre frame has noise level `level`: with the
    /// recipe's colour term, its tolerance is that base times the schedule's loosening (1 at
    /// the cleanest frames), and off for frames too noisy for the schedule, whose colour is too
    /// noisy to compare; the terms that compare sampled buffers loosen by
    /// [`sampled_terms_loosening`] up to the recipe's most.
    pub fn align_params_for(&self, level: Option<f32>) -> AlignParams {
        let schedule = &self.recipe.schedule;
        let mut p = align_params_loosened(
            self.align_base(),
            self.recipe.confidence.loosen_sampled,
            level,
            schedule,
        );
        if let Some(base) = self.recipe.confidence.color {
            p.confidence.color = schedule.loosening(level).map(|k| base * k);
        }
        p
    }

    /// Whether the guide mix of a frame of noise level `level` uses the window's guide, and if
    /// so with which range term ([`guide_mix::window_guide`]): `None` for the centre's guide,
    /// `Some(None)` for the window's by confidence alone, `Some(Some(σ))` with the range term.
    /// Like the colour confidence, the recipe's range σ holds for the cleanest frames and
    /// loosens with the schedule; frames too noisy for it get the window's guide without it.
    /// With a range, [`guide_mix::MixGuide::FollowLevel`] takes the window's guide at every
    /// level: the range keeps the centre's detail that made clean frames use the centre's
    /// guide before.
    pub fn guide_mix_range_for(&self, level: Option<f32>) -> Option<Option<f32>> {
        let mix = &self.recipe.guide_mix;
        let schedule = &self.recipe.schedule;
        let loosening = schedule.loosening(level);
        let range = mix.range.and_then(|sigma| loosening.map(|k| sigma * k));
        let window = mix.from.uses_window(level, schedule)
            || (mix.range.is_some() && mix.from == guide_mix::MixGuide::FollowLevel);
        window.then_some(range)
    }

    /// The window of frames `window` aligned for its centre frame's scales, and those scales
    /// (computed once, before aligning, from the frame as rendered).
    pub(super) fn align_for_centre(
        &self,
        window: &[Option<&Frame>],
    ) -> (AlignedWindow, FeatureScales) {
        let c = window[window.len() / 2].expect("the centre frame of a window must exist");
        let scales = FeatureScales::of_centre(&c.color, c.albedo.as_ref(), c.depth.as_ref());
        let params = self.align_params_for(scales.noise_level);
        (align_window(window, &params), scales)
    }

    /// Denoises an aligned window: colour, then every AOV and alpha with the same kernels. A
    /// network with a frame-local stem runs it here on the aligned frames, as in training;
    /// [`radn_core::run::denoiser::WindowDenoiser::denoise`] runs it on the frames as rendered and warps its features.
    pub fn denoise_aligned(&self, win: &AlignedWindow) -> Denoised {
        self.denoise_aligned_with(win, None)
    }

    /// [`NetworkDenoiser::denoise_aligned`] with every window frame's stem features warped onto
    /// the centre frame (`stems`) for a network with a frame-local stem.
    pub fn denoise_aligned_with(
        &self,
        win: &AlignedWindow,
        stems: Option<&WindowStems>,
    ) -> Denoised {
        let h = win.centre().color.height();
        self.denoise_rows(win, stems, FeatureScales::of(win), 0..h)
    }
}

#[cfg(test)]
mod tests;
