//! `auto|off|VALUE`: the one parser for every setting that can follow a default, be switched
//! off, or take a value (command-line options and `--tune` keys alike).

use std::fmt;
use std::str::FromStr;

/// A setting's value as the user gave it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Setting<T> {
    /// The default (the model's recipe, or the command's own).
    Auto,
    /// Switched off.
    Off,
    /// This value.
    Value(T),
}

impl<T> Setting<T> {
    /// The value to use: `auto` gives `default`, `off` gives `None`.
    pub fn resolve(self, default: Option<T>) -> Option<T> {
        match self {
            Setting::Auto => default,
            Setting::Off => None,
            Setting::Value(v) => Some(v),
        }
    }
}

impl<T: FromStr> FromStr for Setting<T> {
    type Err = String;

    /// `auto`, `off` (also `none`) or a value of `T`.
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim() {
            "auto" => Ok(Setting::Auto),
            "off" | "none" => Ok(Setting::Off),
            v => v
                .parse::<T>()
                .map(Setting::Value)
                .map_err(|_| format!("'{v}' is not auto, off or a {}", short_type::<T>())),
        }
    }
}

impl<T: fmt::Display> fmt::Display for Setting<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Setting::Auto => f.write_str("auto"),
            Setting::Off => f.write_str("off"),
            Setting::Value(v) => v.fmt(f),
        }
    }
}

/// A number that must be positive and finite (a tolerance, a range, a strength).
#[derive(Clone, Copy, Debug, PartialEq, PartialOrd)]
pub struct Positive(pub f32);

impl FromStr for Positive {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().parse::<f32>() {
            Ok(v) if v.is_finite() && v > 0.0 => Ok(Positive(v)),
            _ => Err(format!("'{s}' is not a positive number")),
        }
    }
}

impl fmt::Display for Positive {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
}

/// A short name of `T` for messages ("number", "whole number", …).
fn short_type<T>() -> &'static str {
    let name = std::any::type_name::<T>();
    if name.ends_with("Positive") {
        "positive number"
    } else if name == "f32" || name == "f64" {
        "number"
    } else if name.starts_with('u') || name.starts_with('i') {
        "whole number"
    } else {
        "value"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_off_and_values_parse() {
        assert_eq!("auto".parse::<Setting<f32>>(), Ok(Setting::Auto));
        assert_eq!("off".parse::<Setting<f32>>(), Ok(Setting::Off));
        assert_eq!("0.5".parse::<Setting<f32>>(), Ok(Setting::Value(0.5)));
        assert_eq!("512".parse::<Setting<usize>>(), Ok(Setting::Value(512)));
        let e = "x".parse::<Setting<Positive>>().unwrap_err();
        assert!(e.contains("'x'") && e.contains("positive number"), "{e}");
        assert!("-1".parse::<Setting<Positive>>().is_err());
        assert!("nan".parse::<Setting<Positive>>().is_err());
    }

    #[test]
    fn resolve_applies_the_default() {
        assert_eq!(Setting::<u8>::Auto.resolve(Some(3)), Some(3));
        assert_eq!(Setting::<u8>::Off.resolve(Some(3)), None);
        assert_eq!(Setting::Value(4u8).resolve(Some(3)), Some(4));
        assert_eq!(Setting::Value(4u8).to_string(), "4");
    }
}
