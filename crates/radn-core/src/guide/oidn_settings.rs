//! How OIDN makes a guide: the beauty filter's quality and how the auxiliaries are cleaned
//! first. A guided model's recipe holds these (its guides at training were made one way);
//! `--tune guide.quality=…` and `--tune guide.prefilter=…` override them.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// OIDN's `quality` filter setting: the size of the network a filter runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OidnQuality {
    /// OIDN's smallest network (interactive previews).
    Fast,
    /// OIDN's middle network (fast math).
    Balanced,
    /// OIDN's final-frame network.
    #[default]
    High,
}

impl OidnQuality {
    /// The value of `OIDN_QUALITY_*` in oidn.h.
    pub(crate) fn code(self) -> i32 {
        match self {
            Self::Fast => 4,
            Self::Balanced => 5,
            Self::High => 6,
        }
    }

    /// The name users write.
    pub fn name(self) -> &'static str {
        match self {
            Self::Fast => "fast",
            Self::Balanced => "balanced",
            Self::High => "high",
        }
    }
}

impl fmt::Display for OidnQuality {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for OidnQuality {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "fast" => Ok(Self::Fast),
            "balanced" => Ok(Self::Balanced),
            "high" => Ok(Self::High),
            _ => Err(format!(
                "'{s}' is not an OIDN quality: high, balanced or fast"
            )),
        }
    }
}

/// How the albedo and normal are cleaned before the beauty filter.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Prefilter {
    /// Not at all: the beauty filter takes them noisy, as rendered (one filter per frame).
    Off,
    /// OIDN's albedo and normal filters at fast quality, then `cleanAux`.
    Fast,
    /// OIDN's albedo and normal filters at balanced quality, then `cleanAux`.
    Balanced,
    /// OIDN's albedo and normal filters at high quality, then `cleanAux`.
    #[default]
    High,
}

impl Prefilter {
    /// The prefilters' quality; `None` where there are none.
    pub fn quality(self) -> Option<OidnQuality> {
        match self {
            Self::Off => None,
            Self::Fast => Some(OidnQuality::Fast),
            Self::Balanced => Some(OidnQuality::Balanced),
            Self::High => Some(OidnQuality::High),
        }
    }
}

impl FromStr for Prefilter {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "off" => Ok(Self::Off),
            _ => match s.parse::<OidnQuality>() {
                Ok(OidnQuality::Fast) => Ok(Self::Fast),
                Ok(OidnQuality::Balanced) => Ok(Self::Balanced),
                Ok(OidnQuality::High) => Ok(Self::High),
                Err(_) => Err(format!(
                    "'{s}' is not a prefilter: high, balanced, fast or off"
                )),
            },
        }
    }
}

impl fmt::Display for Prefilter {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.quality().map_or("off", OidnQuality::name))
    }
}

/// The filters of one guide: the auxiliaries' prefilters, then the beauty.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OidnSettings {
    /// The beauty filter's quality.
    #[serde(default)]
    pub quality: OidnQuality,
    /// How the albedo and normal are cleaned first.
    #[serde(default)]
    pub prefilter: Prefilter,
}

impl Default for OidnSettings {
    /// OIDN's final-frame mode: both auxiliaries prefiltered at high quality, then the beauty
    /// with `cleanAux` at high quality (how `tools/datagen` makes training guides).
    fn default() -> Self {
        Self {
            quality: OidnQuality::High,
            prefilter: Prefilter::High,
        }
    }
}

impl OidnSettings {
    /// Whether these are the defaults (model files leave them out).
    pub fn is_default(&self) -> bool {
        *self == Self::default()
    }
}

impl fmt::Display for OidnSettings {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.prefilter.quality() {
            Some(p) => write!(
                f,
                "beauty at {} quality over auxiliaries prefiltered at {p}",
                self.quality
            ),
            None => write!(
                f,
                "beauty at {} quality over the noisy auxiliaries",
                self.quality
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn qualities_parse_by_name_and_refuse_others() {
        for q in [OidnQuality::Fast, OidnQuality::Balanced, OidnQuality::High] {
            assert_eq!(q.name().parse::<OidnQuality>().unwrap(), q);
        }
        assert!("best".parse::<OidnQuality>().unwrap_err().contains("best"));
        assert_eq!("off".parse::<Prefilter>().unwrap(), Prefilter::Off);
        assert_eq!(
            "balanced".parse::<Prefilter>().unwrap().quality(),
            Some(OidnQuality::Balanced)
        );
        assert!("none".parse::<Prefilter>().is_err());
    }

    #[test]
    fn settings_survive_toml_and_default_when_left_out() {
        #[derive(Serialize, Deserialize)]
        struct Holder {
            #[serde(default)]
            guide: OidnSettings,
        }
        let h: Holder = toml::from_str("").unwrap();
        assert!(h.guide.is_default());
        let s = OidnSettings {
            quality: OidnQuality::Balanced,
            prefilter: Prefilter::Off,
        };
        let text = toml::to_string(&Holder { guide: s }).unwrap();
        assert_eq!(toml::from_str::<Holder>(&text).unwrap().guide, s);
    }
}
