//! Channel mappings: which EXR channels hold colour, albedo, normal, depth and motion for a
//! renderer. Built-in presets are TOML files of the same format a user can write.

use std::collections::BTreeMap;
use std::path::Path;

use serde::Deserialize;

use crate::error::{Error, Result};

/// Where one buffer lives: candidate layer names (tried in order) and its component channels.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneSpec {
    /// Candidate layer (pass) names, tried in order; `""` means channels without a layer.
    /// A layer matches with any view-layer prefix (`ViewLayer.Combined` matches `Combined`).
    pub layer: Vec<String>,
    /// Component channel names, case-insensitive; `"R|X"` accepts either name.
    pub channels: Vec<String>,
}

/// Units a renderer stores motion vectors in.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq)]
#[serde(rename_all = "lowercase")]
pub enum MotionUnits {
    /// Pixels of the data window.
    #[default]
    Pixels,
    /// Fractions of the image width and height.
    Uv,
}

/// A motion-vector buffer and its conversion into radn's convention.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionSpec {
    /// Candidate layer names.
    pub layer: Vec<String>,
    /// The two component channels.
    pub channels: Vec<String>,
    /// Per-component factors (after unit conversion) giving radn's convention: pixels,
    /// +Y down, displacement from this frame towards the other frame.
    #[serde(default = "unit_scale")]
    pub scale: [f32; 2],
    /// Units the file stores.
    #[serde(default)]
    pub units: MotionUnits,
}

fn unit_scale() -> [f32; 2] {
    [1.0, 1.0]
}

/// A full channel mapping: a built-in preset or a user's TOML file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelMapping {
    /// Name shown in messages.
    pub name: String,
    /// One line saying what the mapping is for.
    #[serde(default)]
    pub description: String,
    /// The beauty (RGB).
    pub color: PlaneSpec,
    /// Beauty alpha, if the renderer writes it.
    pub alpha: Option<PlaneSpec>,
    /// Albedo (RGB).
    pub albedo: Option<PlaneSpec>,
    /// Shading normal (XYZ).
    pub normal: Option<PlaneSpec>,
    /// Depth (one channel).
    pub depth: Option<PlaneSpec>,
    /// Motion towards the previous frame.
    pub motion_prev: Option<MotionSpec>,
    /// Motion towards the next frame.
    pub motion_next: Option<MotionSpec>,
    /// The variance of each pixel's mean beauty (RGB), where the renderer writes one: the noise
    /// the input blend and the classic denoiser's last blend compare their changes with.
    #[serde(default)]
    pub variance: Option<PlaneSpec>,
    /// The renderer's own denoised beauty (RGB), where a file holds it beside the noisy one
    /// (Cycles with denoising data stored: `Combined` is denoised, `Noisy Image` noisy). Only
    /// a layer other than the one [`ChannelMapping::color`] resolved to counts: the noisy
    /// beauty is always what radn denoises, the denoised one at most its guide.
    pub denoised: Option<PlaneSpec>,
}

const BUILTIN: &[(&str, &str)] = &[
    ("cycles", include_str!("../../presets/cycles.toml")),
    ("arnold", include_str!("../../presets/arnold.toml")),
    ("renderman", include_str!("../../presets/renderman.toml")),
    ("karma", include_str!("../../presets/karma.toml")),
    ("generic", include_str!("../../presets/generic.toml")),
];

/// The channels a spec resolved to in one file, and the view-layer prefix they carry.
#[derive(Clone, Debug, PartialEq)]
pub struct Resolved {
    /// Full channel names, one per component.
    pub channels: Vec<String>,
    /// The view-layer prefix (`"ViewLayer"` for Cycles' default), empty if none.
    pub prefix: String,
}

impl ChannelMapping {
    /// Names of the built-in presets.
    pub fn builtin_names() -> Vec<&'static str> {
        BUILTIN.iter().map(|(n, _)| *n).collect()
    }

    /// A built-in preset by name.
    pub fn builtin(name: &str) -> Option<ChannelMapping> {
        BUILTIN
            .iter()
            .find(|(n, _)| n.eq_ignore_ascii_case(name))
            .map(|(_, text)| toml::from_str(text).expect("built-in presets are valid TOML"))
    }

    /// Reads a user mapping file.
    pub fn from_file(path: &Path) -> Result<ChannelMapping> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::Mapping {
            path: path.to_path_buf(),
            detail: e.to_string(),
        })?;
        let m: ChannelMapping = toml::from_str(&text).map_err(|e| Error::Mapping {
            path: path.to_path_buf(),
            detail: e.to_string(),
        })?;
        m.validate().map_err(|detail| Error::Mapping {
            path: path.to_path_buf(),
            detail,
        })?;
        Ok(m)
    }

    fn validate(&self) -> std::result::Result<(), String> {
        let n = |s: &PlaneSpec, k: usize, what: &str| {
            if s.channels.len() != k {
                Err(format!(
                    "{what} needs {k} channels, got {}",
                    s.channels.len()
                ))
            } else {
                Ok(())
            }
        };
        n(&self.color, 3, "color")?;
        if let Some(s) = &self.alpha {
            n(s, 1, "alpha")?;
        }
        if let Some(s) = &self.albedo {
            n(s, 3, "albedo")?;
        }
        if let Some(s) = &self.normal {
            n(s, 3, "normal")?;
        }
        if let Some(s) = &self.depth {
            n(s, 1, "depth")?;
        }
        if let Some(s) = &self.denoised {
            n(s, 3, "denoised")?;
        }
        if let Some(s) = &self.variance {
            n(s, 3, "variance")?;
        }
        for (m, what) in [
            (&self.motion_prev, "motion_prev"),
            (&self.motion_next, "motion_next"),
        ] {
            if let Some(m) = m {
                if m.channels.len() != 2 {
                    return Err(format!("{what} needs 2 channels, got {}", m.channels.len()));
                }
            }
        }
        Ok(())
    }

    /// Picks the built-in preset that fits a file's channels best: among the presets whose
    /// colour resolves, the one whose motion vectors resolve (without them a window cannot be
    /// aligned), then the one that resolves most of albedo, normal, depth and alpha; the first
    /// built-in wins a tie. Several presets share a bare `R,G,B,A` beauty, and only their motion
    /// and auxiliary layers tell them apart.
    pub fn detect(channel_names: &[String]) -> Option<ChannelMapping> {
        let found = |layers: &[String], channels: &[String]| {
            // several view layers holding it is a fit too: `--layer` chooses among them
            matches!(
                resolve(layers, channels, channel_names, None),
                Ok(Some(_)) | Err(_)
            )
        };
        let plane =
            |s: &Option<PlaneSpec>| s.as_ref().is_some_and(|s| found(&s.layer, &s.channels));
        let motion =
            |s: &Option<MotionSpec>| s.as_ref().is_some_and(|s| found(&s.layer, &s.channels));
        let mut best: Option<((bool, usize), ChannelMapping)> = None;
        for m in Self::builtin_names().into_iter().filter_map(Self::builtin) {
            if !found(&m.color.layer, &m.color.channels) {
                continue;
            }
            let aux = [&m.albedo, &m.normal, &m.depth, &m.alpha]
                .into_iter()
                .filter(|s| plane(s))
                .count();
            let score = (motion(&m.motion_prev) || motion(&m.motion_next), aux);
            if best.as_ref().is_none_or(|(b, _)| score > *b) {
                best = Some((score, m));
            }
        }
        best.map(|(_, m)| m)
    }
}

/// Resolves candidate layers and components against a file's channel names.
///
/// Returns `Ok(None)` when no candidate layer has every component, and `Err(prefixes)` when
/// several view layers have them and `layer_choice` does not pick one.
pub fn resolve(
    layers: &[String],
    components: &[String],
    names: &[String],
    layer_choice: Option<&str>,
) -> std::result::Result<Option<Resolved>, Vec<String>> {
    for layer in layers {
        // view-layer prefix -> channel found for each component
        let mut groups: BTreeMap<String, Vec<Option<String>>> = BTreeMap::new();
        for (k, comp) in components.iter().enumerate() {
            for alt in comp.split('|') {
                for name in names {
                    if let Some(prefix) = match_channel(name, layer, alt, components.len() == 1) {
                        let slot = groups
                            .entry(prefix)
                            .or_insert_with(|| vec![None; components.len()]);
                        if slot[k].is_none() {
                            slot[k] = Some(name.clone());
                        }
                    }
                }
            }
        }
        let complete: Vec<(String, Vec<String>)> = groups
            .into_iter()
            .filter(|(p, _)| {
                layer_choice.is_none_or(|c| p == c || (p.is_empty() && layer.is_empty()))
            })
            .filter_map(|(p, v)| v.into_iter().collect::<Option<Vec<_>>>().map(|v| (p, v)))
            .collect();
        match complete.len() {
            0 => continue,
            1 => {
                let (prefix, channels) = complete.into_iter().next().expect("one element");
                return Ok(Some(Resolved { channels, prefix }));
            }
            _ => return Err(complete.into_iter().map(|(p, _)| p).collect()),
        }
    }
    Ok(None)
}

/// If `name` is channel `component` of `layer`, returns the view-layer prefix before the layer.
fn match_channel(name: &str, layer: &str, component: &str, single: bool) -> Option<String> {
    let (pre, ch) = match name.rfind('.') {
        Some(i) => (&name[..i], &name[i + 1..]),
        None => ("", name),
    };
    if ch.eq_ignore_ascii_case(component) {
        if layer.is_empty() {
            if pre.is_empty() {
                return Some(String::new());
            }
        } else if pre.eq_ignore_ascii_case(layer) {
            return Some(String::new());
        } else if let Some(p) = strip_suffix_ci(pre, layer) {
            if let Some(p) = p.strip_suffix('.') {
                return Some(p.to_string());
            }
        }
    }
    // a one-channel buffer stored as a bare channel named like the layer (e.g. "Pz")
    if single && !layer.is_empty() {
        if name.eq_ignore_ascii_case(layer) {
            return Some(String::new());
        }
        if let Some(p) = strip_suffix_ci(name, layer).and_then(|p| p.strip_suffix('.')) {
            return Some(p.to_string());
        }
    }
    None
}

fn strip_suffix_ci<'a>(s: &'a str, suffix: &str) -> Option<&'a str> {
    if s.len() >= suffix.len()
        && s.is_char_boundary(s.len() - suffix.len())
        && s[s.len() - suffix.len()..].eq_ignore_ascii_case(suffix)
    {
        Some(&s[..s.len() - suffix.len()])
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn every_builtin_parses_and_validates() {
        for n in ChannelMapping::builtin_names() {
            let m = ChannelMapping::builtin(n).unwrap();
            m.validate().unwrap();
            assert_eq!(m.name, n);
        }
    }

    #[test]
    fn cycles_view_layer_prefix_is_found() {
        let f = names(&[
            "ViewLayer.Combined.R",
            "ViewLayer.Combined.G",
            "ViewLayer.Combined.B",
            "ViewLayer.Vector.X",
        ]);
        let m = ChannelMapping::builtin("cycles").unwrap();
        let r = resolve(&m.color.layer, &m.color.channels, &f, None)
            .unwrap()
            .unwrap();
        assert_eq!(r.prefix, "ViewLayer");
        assert_eq!(
            r.channels,
            names(&[
                "ViewLayer.Combined.R",
                "ViewLayer.Combined.G",
                "ViewLayer.Combined.B"
            ])
        );
    }

    #[test]
    fn two_view_layers_are_ambiguous_unless_chosen() {
        let f = names(&[
            "A.Combined.R",
            "A.Combined.G",
            "A.Combined.B",
            "B.Combined.R",
            "B.Combined.G",
            "B.Combined.B",
        ]);
        let m = ChannelMapping::builtin("cycles").unwrap();
        let e = resolve(&m.color.layer, &m.color.channels, &f, None).unwrap_err();
        assert_eq!(e, names(&["A", "B"]));
        let r = resolve(&m.color.layer, &m.color.channels, &f, Some("B"))
            .unwrap()
            .unwrap();
        assert_eq!(r.channels[0], "B.Combined.R");
    }

    #[test]
    fn plain_layer_does_not_match_prefixed_channels_and_case_is_ignored() {
        let f = names(&["r", "g", "b", "albedo.R", "albedo.G", "albedo.B", "z"]);
        let m = ChannelMapping::builtin("generic").unwrap();
        let r = resolve(&m.color.layer, &m.color.channels, &f, None)
            .unwrap()
            .unwrap();
        assert_eq!(r.channels, names(&["r", "g", "b"]));
        let d = m.depth.unwrap();
        assert_eq!(
            resolve(&d.layer, &d.channels, &f, None)
                .unwrap()
                .unwrap()
                .channels,
            names(&["z"])
        );
    }

    #[test]
    fn detection_prefers_presets_whose_albedo_fits() {
        let f = names(&[
            "ViewLayer.Combined.R",
            "ViewLayer.Combined.G",
            "ViewLayer.Combined.B",
            "ViewLayer.Denoising Albedo.R",
            "ViewLayer.Denoising Albedo.G",
            "ViewLayer.Denoising Albedo.B",
        ]);
        assert_eq!(ChannelMapping::detect(&f).unwrap().name, "cycles");
        let g = names(&["R", "G", "B", "A"]);
        let d = ChannelMapping::detect(&g).unwrap().name;
        assert!(d == "arnold" || d == "generic" || d == "renderman", "{d}");
    }

    /// Each built-in preset's own layout, as its renderer writes it.
    fn layout_of(preset: &str) -> Vec<String> {
        let rgb = |l: &str, c: [&str; 3]| c.map(|c| format!("{l}.{c}")).to_vec();
        let mut v: Vec<String> = match preset {
            "cycles" => {
                let l = |x: &str| format!("ViewLayer.{x}");
                let mut v = rgb(&l("Combined"), ["R", "G", "B"]);
                v.push(l("Combined.A"));
                v.extend(rgb(&l("Noisy Image"), ["R", "G", "B"]));
                v.extend(rgb(&l("Denoising Albedo"), ["R", "G", "B"]));
                v.extend(rgb(&l("Denoising Normal"), ["X", "Y", "Z"]));
                v.push(l("Denoising Depth.Z"));
                v.extend(["X", "Y", "Z", "W"].map(|c| l(&format!("Vector.{c}"))));
                v
            }
            "arnold" => {
                let mut v = names(&["R", "G", "B", "A", "Z"]);
                v.extend(rgb("albedo", ["R", "G", "B"]));
                v.extend(rgb("N", ["X", "Y", "Z"]));
                v.extend(names(&["motionvector.R", "motionvector.G"]));
                v
            }
            "renderman" => {
                let mut v = names(&["R", "G", "B", "A", "Z"]);
                v.extend(rgb("albedo", ["R", "G", "B"]));
                v.extend(rgb("normal", ["R", "G", "B"]));
                v.extend(names(&[
                    "forward.R",
                    "forward.G",
                    "backward.R",
                    "backward.G",
                ]));
                v
            }
            "karma" => {
                let mut v = rgb("C", ["R", "G", "B"]);
                v.push("C.A".into());
                v.extend(rgb("albedo", ["R", "G", "B"]));
                v.extend(rgb("N", ["R", "G", "B"]));
                v.extend(names(&["Pz", "motionvector.R", "motionvector.G"]));
                v
            }
            "generic" => {
                let mut v = names(&["R", "G", "B", "A", "Z"]);
                v.extend(rgb("albedo", ["R", "G", "B"]));
                v.extend(rgb("N", ["X", "Y", "Z"]));
                v.extend(names(&["motion.X", "motion.Y"]));
                v
            }
            p => panic!("no layout for preset {p}"),
        };
        v.sort();
        v
    }

    #[test]
    fn every_builtin_preset_is_detected_on_its_own_layout() {
        for preset in ChannelMapping::builtin_names() {
            let layout = layout_of(preset);
            let m = ChannelMapping::detect(&layout).unwrap();
            assert_eq!(m.name, preset, "layout {layout:?}");
            // and the layout really holds the preset's motion vectors
            let spec = m.motion_prev.as_ref().or(m.motion_next.as_ref()).unwrap();
            assert!(
                matches!(
                    resolve(&spec.layer, &spec.channels, &layout, None),
                    Ok(Some(_))
                ),
                "{preset}: motion not found"
            );
        }
    }

    #[test]
    fn a_generic_file_without_motion_still_resolves_to_a_preset() {
        // no preset's motion fits: the one that resolves most auxiliary buffers is chosen
        let mut v = names(&["R", "G", "B", "A", "Z"]);
        v.extend(names(&[
            "albedo.R", "albedo.G", "albedo.B", "N.X", "N.Y", "N.Z",
        ]));
        assert!(ChannelMapping::detect(&v).is_some());
    }

    #[test]
    fn user_mapping_errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.toml");
        std::fs::write(
            &p,
            "name = \"x\"\n[color]\nlayer=[\"\"]\nchannels=[\"R\",\"G\"]\n",
        )
        .unwrap();
        let e = ChannelMapping::from_file(&p).unwrap_err().to_string();
        assert!(e.contains("m.toml") && e.contains("color needs 3"), "{e}");
        // a variance is one per colour channel
        std::fs::write(
            &p,
            "name = \"x\"\n[color]\nlayer=[\"\"]\nchannels=[\"R\",\"G\",\"B\"]\n\
             [variance]\nlayer=[\"variance\"]\nchannels=[\"Y\"]\n",
        )
        .unwrap();
        let e = ChannelMapping::from_file(&p).unwrap_err().to_string();
        assert!(
            e.contains("m.toml") && e.contains("variance needs 3"),
            "{e}"
        );
    }
}
