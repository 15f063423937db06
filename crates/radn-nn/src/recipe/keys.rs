//! `--tune KEY=VALUE`: a recipe's fields by name, to override one without a flag of its own,
//! and the list `radn denoise --tune help` prints with the values the model's recipe holds.

use radn_core::align::warp::Resampling;
use radn_core::setting::{Positive, Setting};

use super::{Recipe, StabilizeSettings};
use crate::infer::guide_mix::{MixGuide, OutlierRamp};
use crate::infer::input_blend::InputBlend;

/// The keys a recipe takes, each with what its value means.
pub const KEYS: &[(&str, &str)] = &[
    (
        "guide.quality",
        "OIDN guide's beauty filter: high|balanced|fast",
    ),
    (
        "guide.prefilter",
        "OIDN guide's albedo/normal prefilters: high|balanced|fast|off",
    ),
    (
        "threshold",
        "kernel threshold t (paper eq. 3), below 1/taps; auto: the model's",
    ),
    (
        "resampling",
        "side frames between pixels: bilinear|catmull-rom|nearest; auto: as trained",
    ),
    ("schedule.min-scale", "noise scale of the cleanest frames"),
    (
        "schedule.level-at-min",
        "noise level up to which the scale is smallest",
    ),
    (
        "schedule.exponent",
        "how steeply the scale grows with the level",
    ),
    (
        "schedule.max-scale",
        "scale above which a frame counts as too noisy",
    ),
    (
        "confidence.guide",
        "guide term's tolerance (guided runs)|off",
    ),
    (
        "confidence.color",
        "colour term's tolerance at the cleanest frames|off",
    ),
    (
        "confidence.loosen",
        "most the albedo/normal/depth terms loosen (>= 1)|off",
    ),
    (
        "input-blend",
        "auto: noise scale per frame from the schedule|off|fixed scale K",
    ),
    ("input-blend.radius", "box radius of the input blend"),
    (
        "input-blend.variance-radius",
        "its box radius where frames carry the renderer's variance|off",
    ),
    (
        "input-blend.variance-scale",
        "factor on the renderer's variance (below 1 for stratified samplers)",
    ),
    (
        "mix.weight",
        "guide's weight in the guide mix, 0 to 1 (guided models)",
    ),
    (
        "mix.from",
        "which guide: auto (by noise level)|centre|window",
    ),
    (
        "mix.range",
        "window guide's range sigma at the cleanest frames|off",
    ),
    (
        "mix.outliers",
        "FROM:TO ramp where the guide alone is taken|off",
    ),
    (
        "stabilize",
        "temporal pass over the results: strength A|off",
    ),
    ("stabilize.floor", "smallest range of the temporal pass"),
    (
        "stabilize.noise-radius",
        "box radius of the temporal pass's noise estimate",
    ),
];

impl Recipe {
    /// Sets `key` to `value` (`auto` where the key has a default beyond the recipe: the
    /// model's threshold and resampling, the per-frame input blend, the level-chosen guide).
    pub fn set(&mut self, key: &str, value: &str) -> Result<(), String> {
        let bad = |what: &str| format!("--tune {key}={value}: {what}");
        let num = |v: &str| v.parse::<Positive>().map(|p| p.0).map_err(|e| bad(&e));
        let off_or = |v: &str| -> Result<Option<f32>, String> {
            match v.parse::<Setting<Positive>>().map_err(|e| bad(&e))? {
                Setting::Auto => Err(bad("'auto' has no meaning here: give off or a number")),
                s => Ok(s.resolve(None).map(|p| p.0)),
            }
        };
        let whole = |v: &str| v.parse::<usize>().map_err(|_| bad("not a whole number"));
        match key {
            "guide.quality" => self.guide.quality = value.parse().map_err(|e: String| bad(&e))?,
            "guide.prefilter" => {
                self.guide.prefilter = value.parse().map_err(|e: String| bad(&e))?
            }
            "threshold" => {
                self.threshold = match value.parse::<Setting<f32>>().map_err(|e| bad(&e))? {
                    Setting::Auto => None,
                    Setting::Off => Some(0.0),
                    Setting::Value(t) if t.is_finite() && t >= 0.0 => Some(t),
                    Setting::Value(_) => return Err(bad("not a threshold >= 0")),
                }
            }
            "resampling" => {
                self.resampling = match value {
                    "auto" => None,
                    "bilinear" => Some(Resampling::Bilinear),
                    "catmull-rom" => Some(Resampling::CatmullRom),
                    "nearest" => Some(Resampling::Nearest),
                    _ => return Err(bad("give auto, bilinear, catmull-rom or nearest")),
                }
            }
            "schedule.min-scale" => self.schedule.min_scale = num(value)?,
            "schedule.level-at-min" => self.schedule.level_at_min = num(value)?,
            "schedule.exponent" => self.schedule.exponent = num(value)?,
            "schedule.max-scale" => self.schedule.max_scale = num(value)?,
            "confidence.guide" => self.confidence.guide = off_or(value)?,
            "confidence.color" => self.confidence.color = off_or(value)?,
            "confidence.loosen" => {
                self.confidence.loosen_sampled = off_or(value)?;
                if self.confidence.loosen_sampled.is_some_and(|k| k < 1.0) {
                    return Err(bad("a loosening is a factor of at least 1"));
                }
            }
            "input-blend" => {
                let radius = self.input_blend.map_or(1, |b| b.radius);
                self.input_blend = match value.parse::<Setting<Positive>>().map_err(|e| bad(&e))? {
                    Setting::Off => None,
                    s => Some(InputBlend {
                        radius,
                        noise_scale: s.resolve(None).map(|p| p.0),
                        variance_radius: self.input_blend.and_then(|b| b.variance_radius),
                        variance_scale: self.input_blend.and_then(|b| b.variance_scale),
                    }),
                }
            }
            "input-blend.variance-radius" => {
                let r = if value == "off" { 0 } else { whole(value)? };
                match self.input_blend.as_mut() {
                    // off stays as stored where it was never set (guided models)
                    Some(b) if r == 0 && b.variance_radius.is_none() => {}
                    Some(b) => b.variance_radius = Some(r),
                    None => return Err(bad("the input blend is off (set input-blend first)")),
                }
            }
            "input-blend.variance-scale" => {
                let s = num(value)?;
                match self.input_blend.as_mut() {
                    Some(b) => b.variance_scale = (s != 1.0).then_some(s),
                    None => return Err(bad("the input blend is off (set input-blend first)")),
                }
            }
            "input-blend.radius" => {
                let r = whole(value)?;
                match self.input_blend.as_mut() {
                    Some(b) => b.radius = r,
                    None => return Err(bad("the input blend is off (set input-blend first)")),
                }
            }
            "mix.weight" => {
                self.guide_mix.weight = match value {
                    "off" => 0.0,
                    v => match v.parse::<f32>() {
                        Ok(w) if (0.0..=1.0).contains(&w) => w,
                        _ => return Err(bad("give off or a weight in [0, 1]")),
                    },
                };
            }
            "mix.from" => {
                self.guide_mix.from = match value {
                    "auto" => MixGuide::FollowLevel,
                    "centre" | "center" => MixGuide::Centre,
                    "window" => MixGuide::Window,
                    _ => return Err(bad("give auto, centre or window")),
                }
            }
            "mix.range" => self.guide_mix.range = off_or(value)?,
            "mix.outliers" => {
                self.guide_mix.outliers = match value {
                    "off" => None,
                    v => {
                        let (from, to) = v
                            .split_once(':')
                            .ok_or_else(|| bad("give off or FROM:TO"))?;
                        let (from, to) = (num(from)?, num(to)?);
                        if to <= from {
                            return Err(bad("TO must be above FROM"));
                        }
                        Some(OutlierRamp { from, to })
                    }
                }
            }
            "stabilize" => {
                let base = self.stabilize.unwrap_or(super::tuned::STABILIZE);
                self.stabilize =
                    off_or(value)?.map(|strength| StabilizeSettings { strength, ..base });
            }
            "stabilize.floor" | "stabilize.noise-radius" => {
                let Some(s) = self.stabilize.as_mut() else {
                    return Err(bad("the temporal pass is off (set stabilize first)"));
                };
                if key == "stabilize.floor" {
                    s.floor = num(value)?;
                } else {
                    s.noise_radius = whole(value)?;
                }
            }
            _ => {
                return Err(format!(
                    "--tune {key}: no such key (radn denoise --tune help lists them)"
                ))
            }
        }
        self.schedule.validate().map_err(|e| bad(&e))
    }

    /// The value of `key` as `--tune` would take it back.
    pub fn get(&self, key: &str) -> Option<String> {
        let opt = |v: Option<f32>| v.map_or("off".to_string(), |v| v.to_string());
        Some(match key {
            "guide.quality" => self.guide.quality.to_string(),
            "guide.prefilter" => self.guide.prefilter.to_string(),
            "threshold" => self.threshold.map_or("auto".to_string(), |t| t.to_string()),
            "resampling" => match self.resampling {
                None => "auto".into(),
                Some(Resampling::Bilinear) => "bilinear".into(),
                Some(r) => r.name().into(),
            },
            "schedule.min-scale" => self.schedule.min_scale.to_string(),
            "schedule.level-at-min" => self.schedule.level_at_min.to_string(),
            "schedule.exponent" => self.schedule.exponent.to_string(),
            "schedule.max-scale" => self.schedule.max_scale.to_string(),
            "confidence.guide" => opt(self.confidence.guide),
            "confidence.color" => opt(self.confidence.color),
            "confidence.loosen" => opt(self.confidence.loosen_sampled),
            "input-blend" => match self.input_blend {
                None => "off".into(),
                Some(b) => b.noise_scale.map_or("auto".into(), |k| k.to_string()),
            },
            "input-blend.radius" => self
                .input_blend
                .map_or("-".into(), |b| b.radius.to_string()),
            "input-blend.variance-radius" => {
                self.input_blend
                    .map_or("-".into(), |b| match b.variance_radius.unwrap_or(0) {
                        0 => "off".into(),
                        r => r.to_string(),
                    })
            }
            "input-blend.variance-scale" => self
                .input_blend
                .map_or("-".into(), |b| b.variance_scale.unwrap_or(1.0).to_string()),
            "mix.weight" => self.guide_mix.weight.to_string(),
            "mix.from" => match self.guide_mix.from {
                MixGuide::FollowLevel => "auto".into(),
                MixGuide::Centre => "centre".into(),
                MixGuide::Window => "window".into(),
            },
            "mix.range" => opt(self.guide_mix.range),
            "mix.outliers" => self
                .guide_mix
                .outliers
                .map_or("off".into(), |r| format!("{}:{}", r.from, r.to)),
            "stabilize" => opt(self.stabilize.map(|s| s.strength)),
            "stabilize.floor" => self.stabilize.map_or("-".into(), |s| s.floor.to_string()),
            "stabilize.noise-radius" => self
                .stabilize
                .map_or("-".into(), |s| s.noise_radius.to_string()),
            _ => return None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::config::NetConfig;

    fn guided() -> Recipe {
        let mut c = NetConfig::preset("small").unwrap();
        c.inputs.guide = true;
        Recipe::tuned_for(&c)
    }

    #[test]
    fn every_key_reads_back_what_it_was_set_to() {
        let mut r = guided();
        for (key, _) in KEYS {
            let v = r.get(key).unwrap_or_else(|| panic!("{key} has no value"));
            // setting a key to its own value changes nothing
            let before = r.clone();
            if v != "-" {
                r.set(key, &v).unwrap_or_else(|e| panic!("{key}={v}: {e}"));
            }
            assert_eq!(r, before, "{key}={v}");
        }
    }

    #[test]
    fn values_are_checked_and_named_in_errors() {
        let mut r = guided();
        r.set("mix.range", "0.04").unwrap();
        assert_eq!(r.guide_mix.range, Some(0.04));
        r.set("mix.range", "off").unwrap();
        assert_eq!(r.guide_mix.range, None);
        r.set("stabilize", "off").unwrap();
        assert!(r.stabilize.is_none());
        assert!(r
            .set("stabilize.floor", "0.001")
            .unwrap_err()
            .contains("off"));
        r.set("input-blend.variance-scale", "0.1").unwrap();
        assert_eq!(r.input_blend.unwrap().variance_scale, Some(0.1));
        assert!(r.set("input-blend.variance-scale", "0").is_err());
        r.set("mix.outliers", "0.05:0.2").unwrap();
        assert_eq!(
            r.guide_mix.outliers,
            Some(OutlierRamp {
                from: 0.05,
                to: 0.2
            })
        );
        for (k, v) in [
            ("mix.weight", "2"),
            ("mix.outliers", "0.2:0.1"),
            ("confidence.loosen", "0.5"),
            ("schedule.max-scale", "1"),
            ("threshold", "-1"),
            ("nonsense", "1"),
        ] {
            let e = r.clone().set(k, v).unwrap_err();
            assert!(e.contains(k), "{k}={v}: {e}");
        }
    }
}
