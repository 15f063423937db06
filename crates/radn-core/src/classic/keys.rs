//! `--tune classic.KEY=VALUE`: the classic denoiser's settings by name, so that the command line
//! needs no flag per setting (`radn denoise --tune help` lists them with their defaults).

use super::pipeline::ClassicDenoiser;
use crate::post::wiener::VarianceBlend;
use crate::setting::Positive;

/// The keys the classic denoiser takes, each with what its value means.
pub const KEYS: &[(&str, &str)] = &[
    (
        "classic.radius",
        "frames on each side of the centre (2: a 5-frame window)",
    ),
    ("classic.search-radius", "NLM search radius in pixels"),
    ("classic.patch-radius", "NLM patch radius in pixels"),
    (
        "classic.nlm-strength",
        "NLM strength (larger removes more noise and detail)",
    ),
    (
        "classic.flow-refine",
        "refine the renderer's motion with optical flow: on|off",
    ),
    (
        "classic.guided-filter",
        "the guided filter after NLM: on|off",
    ),
    (
        "classic.guided-blend",
        "guided filter only where the noise explains it: on|off",
    ),
    (
        "classic.guided-noise-scale",
        "noise variances of change the guided filter may make",
    ),
    (
        "classic.guided-blend-radius",
        "box radius of that comparison",
    ),
    ("classic.demodulate", "filter beauty / albedo: on|off"),
    (
        "classic.variance-blend",
        "box radius of the last blend where frames carry the renderer's variance|off",
    ),
    (
        "classic.variance-scale",
        "factor on the renderer's variance (below 1 for stratified samplers)",
    ),
];

impl ClassicDenoiser {
    /// Sets `key` (one of [`KEYS`]) to `value`.
    pub fn set(&mut self, key: &str, value: &str) -> Result<(), String> {
        let bad = |what: &str| format!("--tune {key}={value}: {what}");
        let whole = |v: &str| v.parse::<usize>().map_err(|_| bad("not a whole number"));
        let num = |v: &str| v.parse::<Positive>().map(|p| p.0).map_err(|e| bad(&e));
        let on_off = |v: &str| match v {
            "on" | "true" => Ok(true),
            "off" | "false" => Ok(false),
            _ => Err(bad("give on or off")),
        };
        let p = &mut self.params;
        match key {
            "classic.radius" => self.radius = whole(value)?,
            "classic.search-radius" => p.nlm.search_radius = whole(value)?,
            "classic.patch-radius" => p.nlm.patch_radius = whole(value)?,
            "classic.nlm-strength" => p.nlm.strength = num(value)?,
            "classic.flow-refine" => {
                p.flow_refine = on_off(value)?.then(|| p.flow_refine.unwrap_or_default());
            }
            "classic.guided-filter" => {
                p.guided = on_off(value)?.then(|| p.guided.unwrap_or_default());
            }
            "classic.guided-blend" => {
                p.guided_blend = on_off(value)?.then(|| p.guided_blend.unwrap_or_default());
            }
            "classic.guided-noise-scale" | "classic.guided-blend-radius" => {
                let Some(b) = p.guided_blend.as_mut() else {
                    return Err(bad(
                        "the guided blend is off (classic.guided-blend=on first)",
                    ));
                };
                if key == "classic.guided-noise-scale" {
                    b.noise_scale = num(value)?;
                } else {
                    b.radius = whole(value)?;
                }
            }
            "classic.demodulate" => p.demodulate = on_off(value)?,
            "classic.variance-blend" => {
                p.variance_blend = match value {
                    "off" => None,
                    v => Some(VarianceBlend {
                        radius: whole(v)?,
                        scale: p.variance_blend.map_or(1.0, |b| b.scale),
                    }),
                }
            }
            "classic.variance-scale" => {
                let s = num(value)?;
                match p.variance_blend.as_mut() {
                    Some(b) => b.scale = s,
                    None => {
                        return Err(bad(
                            "the variance blend is off (classic.variance-blend=R first)",
                        ))
                    }
                }
            }
            _ => {
                return Err(format!(
                    "--tune {key}: no such key (radn denoise --tune help lists them)"
                ))
            }
        }
        Ok(())
    }

    /// The value of `key` as `--tune` would take it back.
    pub fn get(&self, key: &str) -> Option<String> {
        let p = &self.params;
        let on = |b: bool| if b { "on" } else { "off" }.to_string();
        let blend = p.guided_blend.unwrap_or_default();
        Some(match key {
            "classic.radius" => self.radius.to_string(),
            "classic.search-radius" => p.nlm.search_radius.to_string(),
            "classic.patch-radius" => p.nlm.patch_radius.to_string(),
            "classic.nlm-strength" => p.nlm.strength.to_string(),
            "classic.flow-refine" => on(p.flow_refine.is_some()),
            "classic.guided-filter" => on(p.guided.is_some()),
            "classic.guided-blend" => on(p.guided_blend.is_some()),
            "classic.guided-noise-scale" => blend.noise_scale.to_string(),
            "classic.guided-blend-radius" => blend.radius.to_string(),
            "classic.demodulate" => on(p.demodulate),
            "classic.variance-blend" => p
                .variance_blend
                .map_or("off".into(), |v| v.radius.to_string()),
            "classic.variance-scale" => {
                p.variance_blend.map_or("-".into(), |v| v.scale.to_string())
            }
            _ => return None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_key_reads_back_and_changes_what_it_names() {
        let mut d = ClassicDenoiser::default();
        for (key, _) in KEYS {
            let v = d.get(key).unwrap();
            let before = format!("{:?}", d.params);
            d.set(key, &v).unwrap();
            assert_eq!(format!("{:?}", d.params), before, "{key}={v}");
        }
        d.set("classic.nlm-strength", "0.9").unwrap();
        assert_eq!(d.params.nlm.strength, 0.9);
        d.set("classic.flow-refine", "off").unwrap();
        assert!(d.params.flow_refine.is_none());
        d.set("classic.variance-scale", "0.1").unwrap();
        assert_eq!(d.params.variance_blend.unwrap().scale, 0.1);
        d.set("classic.variance-blend", "2").unwrap();
        assert_eq!(
            d.params.variance_blend.unwrap().scale,
            0.1,
            "a radius keeps the scale"
        );
        assert!(d.set("classic.variance-scale", "0").is_err());
        d.set("classic.variance-blend", "off").unwrap();
        assert!(d.set("classic.variance-scale", "0.5").is_err());
        d.set("classic.guided-blend", "off").unwrap();
        assert!(d.set("classic.guided-noise-scale", "3").is_err());
        assert!(d
            .set("classic.mystery", "1")
            .unwrap_err()
            .contains("mystery"));
        assert!(d
            .set("classic.radius", "x")
            .unwrap_err()
            .contains("classic.radius"));
    }
}
