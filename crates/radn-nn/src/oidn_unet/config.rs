//! What an imported OIDN U-Net is without its weights: which OIDN model it came from, its
//! inputs and their transfer function, its layer list (standard or large) and every
//! convolution's channel counts. Written into the model file's header, so the file alone
//! rebuilds the network.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::oidn_unet::tza::TzaTensor;

/// OIDN's layer lists: the standard U-Net (`addUNet`, also its `_small` weights) and the large
/// one (`addUNetLarge`: two convolutions per encoder level, three at the end).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Layers {
    /// One convolution per encoder level (receptive field 174 px).
    Standard,
    /// Paired convolutions per encoder level (receptive field 202 px).
    Large,
}

/// What a model denoises, which decides its inputs and their transfer function.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Input {
    /// A beauty, HDR (OIDN's "PU" transfer) or LDR (sRGB), with optional auxiliaries.
    Beauty {
        /// HDR (`rt_hdr*`) rather than LDR (`rt_ldr*`).
        hdr: bool,
        /// An albedo image follows the colour.
        albedo: bool,
        /// A normal image follows the albedo.
        normal: bool,
        /// The auxiliaries are expected noise-free (`calb`/`cnrm` weights, OIDN's `cleanAux`).
        clean_aux: bool,
    },
    /// An albedo image alone (`rt_alb*`: the albedo prefilter, sRGB transfer).
    Albedo,
    /// A normal image alone (`rt_nrm*`: the normal prefilter, signed, linear).
    Normal,
}

impl Input {
    /// The input channels the network reads (three per image).
    pub fn channels(self) -> usize {
        match self {
            Input::Beauty { albedo, normal, .. } => 3 + 3 * albedo as usize + 3 * normal as usize,
            Input::Albedo | Input::Normal => 3,
        }
    }

    /// What OIDN's model `name` (e.g. `rt_hdr_alb_nrm`, `rt_alb_large`) denoises; `None` for
    /// names that are not one of OIDN's RT filter models.
    pub fn of_weights(name: &str) -> Option<Self> {
        let base = name
            .strip_suffix("_large")
            .or_else(|| name.strip_suffix("_small"))
            .unwrap_or(name);
        Some(match base {
            "rt_alb" => Input::Albedo,
            "rt_nrm" => Input::Normal,
            _ => {
                let rest = base.strip_prefix("rt_")?;
                let (hdr, aux) = match rest.split_once('_') {
                    Some((kind, aux)) => (kind, aux),
                    None => (rest, ""),
                };
                let hdr = match hdr {
                    "hdr" => true,
                    "ldr" => false,
                    _ => return None,
                };
                let (albedo, normal, clean_aux) = match aux {
                    "" => (false, false, false),
                    "alb" => (true, false, false),
                    "alb_nrm" => (true, true, false),
                    "calb_cnrm" => (true, true, true),
                    _ => return None,
                };
                Input::Beauty {
                    hdr,
                    albedo,
                    normal,
                    clean_aux,
                }
            }
        })
    }
}

/// Where a convolution's second input comes from, for the decoder's concatenations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Skip {
    /// The processed network input.
    Input,
    /// The output of the encoder's pooling number `n` (1 = full resolution halved).
    Pool(usize),
}

/// What follows a convolution (after its ReLU).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum After {
    /// Nothing.
    Nothing,
    /// 2×2 max pooling, stride 2; the pooled map is also kept as a skip.
    Pool,
    /// Nearest-neighbour upsampling by 2.
    Upsample,
}

/// One step of the network: a 3×3 convolution with ReLU over the previous step's output
/// (concatenated with `skip` where there is one, the previous output first), then `after`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Step {
    /// The convolution's name in OIDN's weights (`enc_conv0`, `dec_conv1a`, …).
    pub conv: &'static str,
    /// The concatenated second input.
    pub skip: Option<Skip>,
    /// What follows the convolution.
    pub after: After,
}

const fn step(conv: &'static str, skip: Option<Skip>, after: After) -> Step {
    Step { conv, skip, after }
}

use After::{Nothing, Pool, Upsample};

/// OIDN's standard U-Net, as `addUNet` builds it.
const STANDARD: [Step; 16] = [
    step("enc_conv0", None, Nothing),
    step("enc_conv1", None, Pool),
    step("enc_conv2", None, Pool),
    step("enc_conv3", None, Pool),
    step("enc_conv4", None, Pool),
    step("enc_conv5a", None, Nothing),
    step("enc_conv5b", None, Upsample),
    step("dec_conv4a", Some(Skip::Pool(3)), Nothing),
    step("dec_conv4b", None, Upsample),
    step("dec_conv3a", Some(Skip::Pool(2)), Nothing),
    step("dec_conv3b", None, Upsample),
    step("dec_conv2a", Some(Skip::Pool(1)), Nothing),
    step("dec_conv2b", None, Upsample),
    step("dec_conv1a", Some(Skip::Input), Nothing),
    step("dec_conv1b", None, Nothing),
    step("dec_conv0", None, Nothing),
];

/// OIDN's large U-Net, as `addUNetLarge` builds it.
const LARGE: [Step; 19] = [
    step("enc_conv1a", None, Nothing),
    step("enc_conv1b", None, Pool),
    step("enc_conv2a", None, Nothing),
    step("enc_conv2b", None, Pool),
    step("enc_conv3a", None, Nothing),
    step("enc_conv3b", None, Pool),
    step("enc_conv4a", None, Nothing),
    step("enc_conv4b", None, Pool),
    step("enc_conv5a", None, Nothing),
    step("enc_conv5b", None, Upsample),
    step("dec_conv4a", Some(Skip::Pool(3)), Nothing),
    step("dec_conv4b", None, Upsample),
    step("dec_conv3a", Some(Skip::Pool(2)), Nothing),
    step("dec_conv3b", None, Upsample),
    step("dec_conv2a", Some(Skip::Pool(1)), Nothing),
    step("dec_conv2b", None, Upsample),
    step("dec_conv1a", Some(Skip::Input), Nothing),
    step("dec_conv1b", None, Nothing),
    step("dec_conv1c", None, Nothing),
];

/// Levels of pooling in both layer lists: frames are padded to a multiple of 2^4.
pub const POOLINGS: usize = 4;
/// The alignment every tile origin and the padded frame keep, so that pooling grids agree.
pub const ALIGNMENT: usize = 1 << POOLINGS;

impl Layers {
    /// The network's steps, in order.
    pub fn steps(self) -> &'static [Step] {
        match self {
            Layers::Standard => &STANDARD,
            Layers::Large => &LARGE,
        }
    }

    /// Steps of the encoder: up to the first convolution whose output is upsampled (the
    /// bottleneck), which the per-frame half of a converted network runs.
    pub fn encoder_steps(self) -> usize {
        self.steps()
            .iter()
            .position(|s| s.after == After::Upsample)
            .expect("a U-Net upsamples")
            + 1
    }

    /// How far (in pixels) an output pixel can see: the sum over the steps of each 3×3
    /// convolution's reach and each pooling's, at its scale. Tiles overlap by at least this
    /// (rounded up to [`ALIGNMENT`]) so that tiled output equals whole-frame output.
    pub fn reach(self) -> usize {
        let mut scale = 1;
        let mut reach = 0;
        for s in self.steps() {
            reach += scale;
            match s.after {
                After::Pool => {
                    reach += scale;
                    scale *= 2;
                }
                After::Upsample => scale /= 2,
                After::Nothing => {}
            }
        }
        reach
    }

    /// The overlap tiles need: [`Self::reach`] rounded up to [`ALIGNMENT`].
    pub fn overlap(self) -> usize {
        self.reach().next_multiple_of(ALIGNMENT)
    }
}

/// One convolution's channels: input (both parts of a concatenation) and output.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ConvShape {
    /// Its name in OIDN's weights.
    pub name: String,
    /// Input channels (the previous output's, then the skip's).
    pub cin: usize,
    /// Output channels.
    pub cout: usize,
}

/// An imported OIDN U-Net without its weights.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct UnetConfig {
    /// OIDN's name for the weights (`rt_hdr_alb_nrm`, …).
    pub weights: String,
    /// The OIDN version the weights came from ("unknown" where the library did not say).
    pub oidn_version: String,
    /// Standard or large layer list.
    pub layers: Layers,
    /// What the network denoises.
    pub input: Input,
    /// Every convolution's channels, in step order.
    pub convs: Vec<ConvShape>,
}

impl UnetConfig {
    /// The configuration of OIDN's model `weights` from its tensors, checked: every step's
    /// weight and bias present with the shapes the layer list implies.
    pub fn from_tensors(
        weights: &str,
        oidn_version: &str,
        tensors: &BTreeMap<String, TzaTensor>,
    ) -> Result<Self, String> {
        let input = Input::of_weights(weights).ok_or_else(|| {
            format!("'{weights}' is not one of OIDN's RT filter models (rt_hdr*, rt_ldr*, rt_alb*, rt_nrm*)")
        })?;
        let layers = if tensors.contains_key("enc_conv1b.weight") {
            Layers::Large
        } else {
            Layers::Standard
        };
        let mut convs = Vec::new();
        let mut prev = input.channels();
        let mut pools = Vec::new();
        for s in layers.steps() {
            let w = tensors
                .get(&format!("{}.weight", s.conv))
                .ok_or_else(|| format!("the weights lack {}.weight", s.conv))?;
            let b = tensors
                .get(&format!("{}.bias", s.conv))
                .ok_or_else(|| format!("the weights lack {}.bias", s.conv))?;
            let skip = match s.skip {
                None => 0,
                Some(Skip::Input) => input.channels(),
                Some(Skip::Pool(n)) => *pools
                    .get(n - 1)
                    .ok_or_else(|| format!("{} reads a pooling that comes later", s.conv))?,
            };
            let cin = prev + skip;
            let &[cout, wcin, 3, 3] = w.dims.as_slice() else {
                return Err(format!(
                    "{}.weight has shape {:?}, not a 3×3 convolution",
                    s.conv, w.dims
                ));
            };
            if wcin != cin || b.dims != [cout] {
                return Err(format!(
                    "{} has weight {:?} and bias {:?}; the layer list expects {cin} input channels",
                    s.conv, w.dims, b.dims
                ));
            }
            if s.after == After::Pool {
                pools.push(cout);
            }
            convs.push(ConvShape {
                name: s.conv.to_string(),
                cin,
                cout,
            });
            prev = cout;
        }
        if prev != 3 {
            return Err(format!("the last convolution has {prev} outputs, not 3"));
        }
        Ok(Self {
            weights: weights.to_string(),
            oidn_version: oidn_version.to_string(),
            layers,
            input,
            convs,
        })
    }

    /// Each convolution's sources' channels, in step order: the previous output's, then the
    /// skip's where it concatenates one (how its weights split between the two).
    pub fn conv_inputs(&self) -> Vec<Vec<usize>> {
        let mut prev = self.input.channels();
        let mut pools = Vec::new();
        let mut out = Vec::new();
        for (step, shape) in self.layers.steps().iter().zip(&self.convs) {
            out.push(match step.skip {
                None => vec![prev],
                Some(Skip::Input) => vec![prev, self.input.channels()],
                Some(Skip::Pool(n)) => vec![prev, pools[n - 1]],
            });
            if step.after == After::Pool {
                pools.push(shape.cout);
            }
            prev = shape.cout;
        }
        out
    }

    /// The number of weights and biases.
    pub fn parameters(&self) -> usize {
        self.convs.iter().map(|c| c.cout * (c.cin * 9 + 1)).sum()
    }

    /// Multiply-adds per output pixel (each convolution at its level's resolution).
    pub fn macs_per_pixel(&self) -> f64 {
        let mut scale = 1.0;
        let mut macs = 0.0;
        for (s, c) in self.layers.steps().iter().zip(&self.convs) {
            macs += (c.cin * c.cout * 9) as f64 * scale;
            match s.after {
                After::Pool => scale /= 4.0,
                After::Upsample => scale *= 4.0,
                After::Nothing => {}
            }
        }
        macs
    }

    /// The configuration as TOML (the model file's header).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a U-Net configuration serialises")
    }

    /// Reads a configuration written by [`Self::to_toml`].
    pub fn parse(text: &str) -> Result<Self, String> {
        toml::from_str(text).map_err(|e| e.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn oidn_model_names_say_what_they_denoise() {
        assert_eq!(
            Input::of_weights("rt_hdr_alb_nrm"),
            Some(Input::Beauty {
                hdr: true,
                albedo: true,
                normal: true,
                clean_aux: false
            })
        );
        assert_eq!(
            Input::of_weights("rt_hdr_calb_cnrm_large").map(Input::channels),
            Some(9)
        );
        assert_eq!(
            Input::of_weights("rt_ldr_small").map(Input::channels),
            Some(3)
        );
        assert_eq!(Input::of_weights("rt_alb_large"), Some(Input::Albedo));
        assert_eq!(Input::of_weights("rt_nrm"), Some(Input::Normal));
        assert_eq!(Input::of_weights("rtlightmap_hdr"), None);
        assert_eq!(Input::of_weights("rt_hdr_nrm"), None);
    }

    #[test]
    fn the_reach_covers_oidns_receptive_fields_and_the_overlap_is_aligned() {
        // OIDN's receptive fields: 174 px (standard) and 202 px (large), i.e. radii 87 and 101
        assert!(Layers::Standard.reach() >= 87);
        assert!(Layers::Large.reach() >= 101);
        assert_eq!(Layers::Standard.overlap(), 96);
        assert_eq!(Layers::Large.overlap(), 112);
    }
}
