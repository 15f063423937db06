//! A model's recipe: every tuned inference setting in one place, saved in the model file beside
//! its configuration. `radn denoise`, `radn prepare` and library callers
//! ([`crate::infer::NetworkDenoiser::new`]) all read it; command-line flags and
//! `--tune KEY=VALUE` only override its fields.
//!
//! A model file without a recipe gets the one its kind was tuned with ([`Recipe::tuned_for`]).
//! Why each value is what it is, and what else was measured, is in `docs/research/`.

pub mod keys;

use serde::{Deserialize, Serialize};

use radn_core::align::warp::Resampling;
use radn_core::guide::OidnSettings;

use crate::infer::guide_mix::{MixGuide, OutlierRamp};
use crate::infer::input_blend::InputBlend;
use crate::infer::schedule::NoiseSchedule;
use crate::model::config::NetConfig;

/// The tuned inference settings of one model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Recipe {
    /// How OIDN makes the guide of a guided model's `--guide oidn` runs.
    #[serde(default, skip_serializing_if = "OidnSettings::is_default")]
    pub guide: OidnSettings,
    /// Kernel threshold t (paper eq. 3); `None`: the configuration's default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub threshold: Option<f32>,
    /// How side frames are sampled between pixels; `None`: as the model was trained.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resampling: Option<Resampling>,
    /// The noise-level schedule the level-following stages share.
    pub schedule: NoiseSchedule,
    /// Alignment's confidence terms.
    pub confidence: ConfidenceRecipe,
    /// The input blend after the kernels; `None`: the kernels' result as it is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub input_blend: Option<InputBlend>,
    /// The guide mix after the input blend (guided models).
    pub guide_mix: GuideMixRecipe,
    /// The temporal pass over the results; `None`: no pass.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stabilize: Option<StabilizeSettings>,
}

/// Alignment's appearance and sampled-buffer confidence terms.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConfidenceRecipe {
    /// The guide term's tolerance (runs with a guide); `None`: off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub guide: Option<f32>,
    /// The colour term's tolerance at the cleanest frames, loosened by the schedule; `None`: off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color: Option<f32>,
    /// The most the sampled buffers' terms (albedo, normal, depth) loosen with the noise level;
    /// `None`: strict at every level.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loosen_sampled: Option<f32>,
}

/// The guide mix of a guided model.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GuideMixRecipe {
    /// The guide's weight in [0, 1] (0: the network's result alone).
    pub weight: f32,
    /// Which guide: the centre frame's, the window's, or by the noise level.
    pub from: MixGuide,
    /// The window guide's range σ at the cleanest frames; `None`: confidence alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub range: Option<f32>,
    /// Where the result and the guide disagree by far more than detail does, the guide alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub outliers: Option<OutlierRamp>,
}

/// The temporal pass over the results ([`radn_core::post::stabilize::TemporalStabilizer`]).
pub use radn_core::post::stabilize::StabilizeSettings;

/// The tuned values: the one place they live. Chosen on validation sets
/// (`docs/research/guided.md`, `docs/research/detail.md`).
mod tuned {
    use super::*;

    pub const SCHEDULE: NoiseSchedule = NoiseSchedule {
        min_scale: 2.0,
        level_at_min: 0.25,
        exponent: 1.0,
        max_scale: 8.0,
    };
    pub const INPUT_BLEND_RADIUS: usize = 1;
    /// The input blend's box radius on frames that carry the renderer's variance.
    pub const INPUT_BLEND_VARIANCE_RADIUS: usize = 2;
    pub const GUIDE_CONFIDENCE: f32 = 0.6;
    pub const COLOR_CONFIDENCE: f32 = 0.5;
    pub const LOOSEN_SAMPLED: f32 = 4.0;
    pub const GUIDE_MIX: f32 = 0.7;
    pub const GUIDE_MIX_RANGE: f32 = 0.02;
    pub const OUTLIERS: OutlierRamp = OutlierRamp {
        from: 0.03,
        to: 0.1,
    };
    pub const STABILIZE: StabilizeSettings = StabilizeSettings {
        strength: 0.3,
        floor: 0.0005,
        noise_radius: 2,
    };
}

impl Recipe {
    /// The recipe a model of configuration `config` was tuned with: for a guided model the
    /// guided path (guide confidence, loosened sampled terms, the ranged window-guide mix with
    /// outliers, the temporal pass); for others the colour confidence and the input blend.
    pub fn tuned_for(config: &NetConfig) -> Self {
        Self::for_kind(config.inputs.guide)
    }

    /// The recipe of the shipped models of a kind: guided (`guided`) or unguided.
    pub fn for_kind(guided: bool) -> Self {
        Self {
            guide: OidnSettings::default(),
            threshold: None,
            resampling: None,
            schedule: tuned::SCHEDULE,
            confidence: ConfidenceRecipe {
                guide: guided.then_some(tuned::GUIDE_CONFIDENCE),
                color: (!guided).then_some(tuned::COLOR_CONFIDENCE),
                loosen_sampled: guided.then_some(tuned::LOOSEN_SAMPLED),
            },
            input_blend: Some(InputBlend {
                radius: tuned::INPUT_BLEND_RADIUS,
                noise_scale: None,
                variance_radius: (!guided).then_some(tuned::INPUT_BLEND_VARIANCE_RADIUS),
                variance_scale: None,
            }),
            guide_mix: GuideMixRecipe {
                weight: if guided { tuned::GUIDE_MIX } else { 0.0 },
                from: MixGuide::FollowLevel,
                range: guided.then_some(tuned::GUIDE_MIX_RANGE),
                outliers: guided.then_some(tuned::OUTLIERS),
            },
            stabilize: guided.then_some(tuned::STABILIZE),
        }
    }

    /// This recipe with every stage around the kernels off (appearance and loosened confidence
    /// terms, input blend, guide mix, temporal pass): the kernels' result alone, for measuring
    /// what the stages add. Threshold, resampling and schedule are kept.
    pub fn without_stages(mut self) -> Self {
        self.confidence = ConfidenceRecipe {
            guide: None,
            color: None,
            loosen_sampled: None,
        };
        self.input_blend = None;
        self.guide_mix = GuideMixRecipe {
            weight: 0.0,
            from: self.guide_mix.from,
            range: None,
            outliers: None,
        };
        self.stabilize = None;
        self
    }

    /// The recipe as TOML (what a model file stores).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a recipe serialises")
    }

    /// A recipe from TOML, as a model of configuration `config` stored it: an unguided model's
    /// input blend stored before it had a renderer-variance radius gets the tuned one (the
    /// variance blend was chosen for unguided models only; guided ones keep theirs off).
    pub fn from_toml(text: &str, config: &NetConfig) -> Result<Self, String> {
        let mut recipe: Self = toml::from_str(text).map_err(|e| e.to_string())?;
        if let (Some(b), false) = (recipe.input_blend.as_mut(), config.inputs.guide) {
            b.variance_radius
                .get_or_insert(tuned::INPUT_BLEND_VARIANCE_RADIUS);
        }
        Ok(recipe)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_recipe_survives_its_toml() {
        for guided in [false, true] {
            let mut c = NetConfig::preset("small").unwrap();
            c.inputs.guide = guided;
            let r = Recipe::tuned_for(&c);
            assert_eq!(Recipe::from_toml(&r.to_toml(), &c).unwrap(), r);
        }
    }

    #[test]
    fn unknown_fields_are_refused() {
        let c = NetConfig::preset("small").unwrap();
        let mut text = Recipe::tuned_for(&c).to_toml();
        text.insert_str(0, "mystery = 1\n");
        assert!(Recipe::from_toml(&text, &c)
            .unwrap_err()
            .contains("mystery"));
    }

    #[test]
    fn an_input_blend_stored_without_a_variance_radius_gets_one_only_in_unguided_models() {
        // as model files written before the variance blend store it
        let mut c = NetConfig::preset("small").unwrap();
        let mut r = Recipe::tuned_for(&c);
        r.input_blend.as_mut().unwrap().variance_radius = None;
        let text = r.to_toml();
        assert!(!text.contains("variance_radius"), "{text}");
        let unguided = Recipe::from_toml(&text, &c).unwrap();
        assert_eq!(
            unguided.input_blend.unwrap().variance_radius,
            Some(tuned::INPUT_BLEND_VARIANCE_RADIUS)
        );
        c.inputs.guide = true;
        let guided = Recipe::from_toml(&text, &c).unwrap();
        assert_eq!(guided.input_blend.unwrap().variance_radius, None);
        // an explicit choice is kept either way
        r.input_blend.as_mut().unwrap().variance_radius = Some(0);
        let off = Recipe::from_toml(&r.to_toml(), &NetConfig::preset("small").unwrap()).unwrap();
        assert_eq!(off.input_blend.unwrap().variance_radius, Some(0));
    }
}
