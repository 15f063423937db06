//! Network configuration: plain TOML, the same format for built-in presets and user files,
//! stored inside every model file so that the file alone is enough to run it.

use radn_core::align::warp::Resampling;
use serde::{Deserialize, Serialize};

use crate::error::{NnError, Result};

/// Which network family.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Arch {
    /// The paper's network: a per-frame backbone with Robust Average blocks, 5×5×T kernels.
    Ra,
    /// Baseline of Vogels et al. 2018: spatial kernels per frame, then a temporal combination.
    Tkpcn,
    /// Baseline: 5×5 kernels on the centre frame only.
    Spatial,
}

/// The kernel activation (paper section 4).
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum Activation {
    /// η_t (paper eq. 3) on the raw outputs: `max(0, w − t) / Σ max(0, w − t)`.
    Eta,
    /// Softmax, then η_t on the normalised weights.
    SoftmaxEta,
    /// The raw outputs' positive part normalised to sum 1, then η_t (the paper's "additional
    /// normalization", section 4). Unlike [`Activation::Eta`] the threshold then acts on
    /// weights whose scale is fixed (a uniform kernel is 1/K everywhere), so every `t` in
    /// [0, 1/K) is a meaningful strength control: raising it drops the taps weaker than `t`
    /// and moves the output toward the taps the network trusts most, without changing flat
    /// regions whose kernels are uniform. With `Eta` the raw weights settle near 2/K in
    /// training, above every allowed `t`, and the threshold barely acts.
    NormEta,
}

/// The per-frame backbone.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum Backbone {
    /// A ResNet without down- or upsampling (paper Fig. 1).
    Resnet {
        /// Residual blocks (two 3×3 convolutions each).
        blocks: usize,
        /// Channels of every convolution.
        width: usize,
        /// Insert an RA block after these residual blocks (1-based).
        ra_after: Vec<usize>,
        /// Feed the outputs of these RA blocks (1-based among the RA blocks) to the head.
        skips_from: Vec<usize>,
    },
    /// A UNet; an RA block follows the encoder block of every scale in `ra_scales`.
    Unet {
        /// Channels per scale, finest first.
        widths: Vec<usize>,
        /// The scales (0 = full resolution) whose encoder block an RA block follows, in
        /// increasing order. `None`: every scale. At a coarse scale an RA block costs 1/4^s of
        /// a full-resolution one and compares frames over a wider context.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        ra_scales: Option<Vec<usize>>,
    },
}

/// A whole network description.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NetConfig {
    /// Name shown in logs and model cards.
    pub name: String,
    /// Network family.
    pub arch: Arch,
    /// Frames in the window (odd).
    pub frames: usize,
    /// Spatial kernel size (odd).
    pub kernel_size: usize,
    /// Kernel activation.
    pub activation: Activation,
    /// Default threshold t; `None` means the paper's default 1/(2K).
    #[serde(default)]
    pub threshold: Option<f32>,
    /// Albedo demodulation ε: when set, kernels filter colour (and 3-channel AOVs) divided by
    /// `albedo + ε` and the result is multiplied by the centre frame's `albedo + ε`. Texture
    /// then survives however wide the kernel averages, so the network only has to find pixels
    /// with the same lighting, not the same lighting *and* texture. ε bounds the gain where
    /// albedo is near zero (emitters, background). `None`: kernels filter colour as rendered.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub demodulate: Option<f32>,
    /// Initial scale of the kernel head's weights: they are drawn with standard deviation
    /// `head_init / √(9·c_in)`, so the raw kernel weights first vary by about this much around
    /// the box filter the biases set. `None`: 1e-3. The head's weights scale every gradient
    /// that reaches the backbone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub head_init: Option<f32>,
    /// Kernel scales (Vogels et al. 2018): `n` predicts 5×5×T kernels also at 1/2, …,
    /// 1/2^(n−1) resolution, applies them to the correspondingly downsampled window and
    /// combines the results coarse to fine with per-pixel predicted blend weights
    /// ([`crate::model::multiscale`]). `None` or 1: one full-resolution kernel per pixel.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kernel_scales: Option<usize>,
    /// Guide blend (needs `inputs.guide`): a per-frame head predicts `β ∈ (0, 1)` at
    /// every pixel of every window frame, and the kernels filter `(1 − β)·x + β·g` — the noisy
    /// frame `x` moved toward its guide `g` — instead of `x` alone, so the kernels average the
    /// guides of the aligned frames where the network trusts them (a learned temporal filter
    /// over OIDN's frames) and the noisy frames elsewhere. Applied as a per-pixel gain
    /// `1 − β + β·g / max(x, ε)` on every RGB group, it keeps AOVs summing to the beauty
    /// ([`crate::model::guide_blend`]); alpha is not blended. Off: the guide is an input only.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub guide_blend: bool,
    /// Frame-local stem: the layers before the first RA block read only what a
    /// frame holds itself (colour, albedo, normal, depth, guide, each frame normalised by its
    /// own exposure and depth at inference), and the window's own inputs (alignment confidence,
    /// the noise estimate) join after them through a 1×1 convolution. Inference then computes
    /// those layers once per frame, on the frame as rendered, and warps their features with the
    /// window (centre mixing included) instead of warping the inputs, so the five windows a frame
    /// belongs to share one computation. Training runs them on the aligned window, which equals
    /// warping the features where motion is a whole-pixel shift and approximates it elsewhere.
    /// ResNet backbones with RA blocks only.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub frame_local_stem: bool,
    /// How alignment samples the side frames between pixels
    /// ([`radn_core::align::warp::Resampling`]): the network learns from windows aligned this way
    /// (`radn prepare --resampling`), and inference aligns the same way unless told otherwise.
    /// Absent: bilinear, as every model before it.
    #[serde(default, skip_serializing_if = "Resampling::is_bilinear")]
    pub resampling: Resampling,
    /// Optional input features beyond the base ones ([`INPUT_CHANNELS`]): exposure
    /// normalisation and a per-pixel noise estimate. Absent in models from before them.
    #[serde(default, skip_serializing_if = "InputConfig::is_base")]
    pub inputs: InputConfig,
    /// The backbone.
    pub backbone: Backbone,
}

const PRESETS: &[(&str, &str)] = &[
    ("paper", include_str!("../../presets/paper.toml")),
    ("small", include_str!("../../presets/small.toml")),
    ("unet", include_str!("../../presets/unet.toml")),
    ("unet-ms", include_str!("../../presets/unet-ms.toml")),
    ("tkpcn", include_str!("../../presets/tkpcn.toml")),
    ("spatial", include_str!("../../presets/spatial.toml")),
    ("lean-k5", include_str!("../../presets/lean-k5.toml")),
    (
        "guided-lean",
        include_str!("../../presets/guided-lean.toml"),
    ),
    (
        "guided-blend",
        include_str!("../../presets/guided-blend.toml"),
    ),
];

/// Number of base input channels per frame: log colour (3), albedo (3), normal (3), depth (1),
/// confidence (1). Tiles store these; [`InputConfig`] derives the network's own from them.
pub const INPUT_CHANNELS: usize = 11;

/// Input features a network may ask for beyond the base ones (and the guide). They are computed from the window (and its guides) alone, the same way at
/// training and at inference
/// ([`crate::infer::input::network_features`]).
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(deny_unknown_fields)]
pub struct InputConfig {
    /// Divide colour by the centre frame's log-average luminance (its exposure) before the
    /// log transform, so that the kernels do not depend on the HDR scale of the shot: the same
    /// frames rendered twice as bright get exactly the same kernels.
    #[serde(default)]
    pub exposure: bool,
    /// Append a per-pixel noise estimate: the spread of the (exposure-normalised) log
    /// luminance across the window's frames, each weighted by its alignment confidence. It
    /// tells the network how much of what it sees is noise, at every input level.
    #[serde(default)]
    pub noise: bool,
    /// Append a guide: each frame's spatial estimate of the beauty (the
    /// renderer's denoised layer or Intel Open Image Denoise's result, `radn denoise
    /// --guide`), warped with the window and transformed as the colour (three channels after
    /// the others). Kernels are still applied to the noisy frames: the guide steers the
    /// weights only.
    #[serde(default)]
    pub guide: bool,
}

impl InputConfig {
    /// True for the base features only (models from before these options).
    pub fn is_base(&self) -> bool {
        !self.exposure && !self.noise && !self.guide
    }

    /// Where a frame's guide starts among its channels (with `guide`).
    pub fn guide_offset(&self) -> usize {
        INPUT_CHANNELS + usize::from(self.noise)
    }

    /// Channels per frame the network reads.
    pub fn channels(&self) -> usize {
        INPUT_CHANNELS + usize::from(self.noise) + 3 * usize::from(self.guide)
    }

    /// The channels that depend on the window rather than on the frame alone, as `(first,
    /// count)`: the alignment confidence and, where read, the noise estimate right after it.
    pub fn window_channels(&self) -> (usize, usize) {
        (INPUT_CHANNELS - 1, 1 + usize::from(self.noise))
    }

    /// The channels a frame determines by itself, as ranges in order: everything but
    /// [`InputConfig::window_channels`].
    pub fn frame_channels(&self) -> Vec<std::ops::Range<usize>> {
        let (first, count) = self.window_channels();
        let mut v = Vec::with_capacity(2);
        v.push(0..first);
        if first + count < self.channels() {
            v.push(first + count..self.channels());
        }
        v
    }
}

impl NetConfig {
    /// Names of the built-in presets.
    pub fn preset_names() -> Vec<&'static str> {
        PRESETS.iter().map(|(n, _)| *n).collect()
    }

    /// A built-in preset.
    pub fn preset(name: &str) -> Result<NetConfig> {
        let text = PRESETS
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, t)| *t)
            .ok_or_else(|| {
                NnError::Config(format!(
                    "unknown preset '{name}'; known: {}",
                    Self::preset_names().join(", ")
                ))
            })?;
        Self::parse(text)
    }

    /// Parses and checks a TOML description.
    pub fn parse(text: &str) -> Result<NetConfig> {
        let c: NetConfig = toml::from_str(text).map_err(|e| NnError::Config(e.to_string()))?;
        c.validate()?;
        Ok(c)
    }

    /// The TOML form (embedded in model files).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("configs serialise")
    }

    /// Checks the numbers fit together.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(NnError::Config(m));
        if self.frames.is_multiple_of(2) {
            return bad(format!("frames must be odd, got {}", self.frames));
        }
        if self.kernel_size.is_multiple_of(2) {
            return bad(format!("kernel_size must be odd, got {}", self.kernel_size));
        }
        match &self.backbone {
            Backbone::Resnet {
                blocks,
                width,
                ra_after,
                skips_from,
            } => {
                if *width == 0 || *blocks == 0 {
                    return bad("resnet needs blocks > 0 and width > 0".into());
                }
                if let Some(b) = ra_after.iter().find(|&&b| b == 0 || b > *blocks) {
                    return bad(format!("ra_after names block {b}, but there are {blocks}"));
                }
                if let Some(s) = skips_from.iter().find(|&&s| s == 0 || s > ra_after.len()) {
                    return bad(format!(
                        "skips_from names RA block {s}, but there are {}",
                        ra_after.len()
                    ));
                }
                if self.arch != Arch::Ra && !ra_after.is_empty() {
                    return bad("only arch = \"ra\" has RA blocks".into());
                }
            }
            Backbone::Unet { widths, ra_scales } => {
                if widths.is_empty() || widths.contains(&0) {
                    return bad("unet needs at least one non-zero width".into());
                }
                if let Some(r) = ra_scales {
                    if r.windows(2).any(|p| p[0] >= p[1]) || r.iter().any(|&s| s >= widths.len()) {
                        return bad(format!(
                            "ra_scales {r:?} must be increasing scales below {}",
                            widths.len()
                        ));
                    }
                    if self.arch != Arch::Ra && !r.is_empty() {
                        return bad("only arch = \"ra\" has RA blocks".into());
                    }
                }
            }
        }
        if let Some(n) = self.kernel_scales {
            if !(1..=4).contains(&n) {
                return bad(format!("kernel_scales = {n} must be 1 to 4"));
            }
            if n > 1 && self.arch != Arch::Ra {
                return bad("only arch = \"ra\" has multi-scale kernels".into());
            }
        }
        if self.frame_local_stem {
            let has_ra =
                matches!(&self.backbone, Backbone::Resnet { ra_after, .. } if !ra_after.is_empty());
            if self.arch != Arch::Ra || !has_ra {
                return bad(
                    "frame_local_stem needs arch = \"ra\" and a resnet backbone with RA blocks"
                        .into(),
                );
            }
        }
        if self.guide_blend && !(self.inputs.guide && self.arch == Arch::Ra) {
            return bad("guide_blend needs arch = \"ra\" and [inputs] guide = true".into());
        }
        if let Some(eps) = self.demodulate {
            if !(eps.is_finite() && eps > 0.0) {
                return bad(format!("demodulate = {eps} must be a positive number"));
            }
        }
        if let Some(t) = self.threshold {
            if !(0.0..1.0 / self.kernel_taps() as f32).contains(&t) {
                return bad(format!(
                    "threshold {t} must be in [0, 1/K) with K = {}",
                    self.kernel_taps()
                ));
            }
        }
        Ok(())
    }

    /// Channels per frame the network reads.
    pub fn input_channels(&self) -> usize {
        self.inputs.channels()
    }

    /// K: weights per output pixel (kernel taps over all frames the kernel covers).
    pub fn kernel_taps(&self) -> usize {
        let frames = if self.arch == Arch::Spatial {
            1
        } else {
            self.frames
        };
        frames * self.kernel_size * self.kernel_size
    }

    /// Kernel scales (1: full resolution only).
    pub fn scales(&self) -> usize {
        self.kernel_scales.unwrap_or(1)
    }

    /// The threshold used when the caller gives none: the config's, else 1/(2K).
    pub fn default_threshold(&self) -> f32 {
        self.threshold
            .unwrap_or(1.0 / (2.0 * self.kernel_taps() as f32))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_preset_parses_and_round_trips() {
        for n in NetConfig::preset_names() {
            let c = NetConfig::preset(n).unwrap();
            assert_eq!(NetConfig::parse(&c.to_toml()).unwrap(), c, "{n}");
        }
        assert_eq!(
            NetConfig::preset("paper").unwrap().default_threshold(),
            1.0 / 250.0
        );
    }

    #[test]
    fn inconsistent_configs_are_refused() {
        let mut c = NetConfig::preset("small").unwrap();
        c.frames = 4;
        assert!(c.validate().is_err());
        let t = NetConfig::preset("small")
            .unwrap()
            .to_toml()
            .replace("skips_from = [1, 2]", "skips_from = [9]");
        assert!(NetConfig::parse(&t)
            .unwrap_err()
            .to_string()
            .contains("skips_from"));
    }

    #[test]
    fn a_frame_local_stem_needs_a_resnet_with_ra_blocks_and_names_the_window_channels() {
        let mut c = NetConfig::preset("small").unwrap();
        c.frame_local_stem = true;
        assert!(c.validate().is_ok());
        // the split's channels: confidence and the noise estimate, then the guide again
        c.inputs = InputConfig {
            exposure: true,
            noise: true,
            guide: true,
        };
        assert_eq!(c.inputs.window_channels(), (INPUT_CHANNELS - 1, 2));
        assert_eq!(
            c.inputs.frame_channels(),
            vec![
                0..INPUT_CHANNELS - 1,
                INPUT_CHANNELS + 1..INPUT_CHANNELS + 4
            ]
        );
        for other in ["unet", "tkpcn", "spatial"] {
            let mut c = NetConfig::preset(other).unwrap();
            c.frame_local_stem = true;
            assert!(
                c.validate()
                    .unwrap_err()
                    .to_string()
                    .contains("frame_local_stem"),
                "{other}"
            );
        }
    }
}
