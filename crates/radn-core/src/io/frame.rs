//! Frames: the named buffers of one rendered image, read from an EXR through a channel mapping.

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::image::plane::Plane;
use crate::io::exr_file::ExrFile;
use crate::io::hygiene::{count_nonfinite, repair_nonfinite, NonFinitePolicy};
use crate::io::mapping::{resolve, ChannelMapping, MotionSpec, MotionUnits, PlaneSpec};

use crate::image::stats::FAR_DEPTH;

/// An extra buffer (AOV) carried through denoising with the beauty's kernels.
#[derive(Clone, Debug)]
pub struct Aov {
    /// The name the user gave (`diffuse`, `DiffCol`, ...).
    pub name: String,
    /// The full EXR channel names, one per plane channel.
    pub channels: Vec<String>,
    /// The samples.
    pub plane: Plane,
}

/// One rendered frame in linear f32, in radn's conventions (motion in pixels, +Y down).
#[derive(Clone, Debug)]
pub struct Frame {
    /// The file it was read from.
    pub path: PathBuf,
    /// Beauty RGB.
    pub color: Plane,
    /// Beauty alpha.
    pub alpha: Option<Plane>,
    /// Albedo RGB.
    pub albedo: Option<Plane>,
    /// Normal XYZ.
    pub normal: Option<Plane>,
    /// Depth (distance or Z; only compared with itself).
    pub depth: Option<Plane>,
    /// Displacement in pixels from each pixel to where its surface point was one frame earlier.
    pub motion_prev: Option<Plane>,
    /// Displacement in pixels from each pixel to where its surface point will be one frame later.
    pub motion_next: Option<Plane>,
    /// The variance of each pixel's mean beauty (RGB), where the file has the renderer's.
    pub variance: Option<Plane>,
    /// Extra buffers requested by the caller.
    pub aovs: Vec<Aov>,
    /// A per-frame spatial estimate of the beauty (RGB) that steers a guided network: the
    /// renderer's denoised layer or Intel Open Image Denoise's result ([`crate::guide`]).
    /// Read by [`FrameReader`] from a layer of the file ([`FrameReader::guide`]), or attached
    /// by a sequence job (Intel Open Image Denoise).
    pub guide: Option<Plane>,
    /// Per-frame features a denoising method computed once for this frame in
    /// [`crate::run::denoiser::WindowDenoiser::frame_features`] (a network's per-frame layers), so that the
    /// windows the frame belongs to reuse them instead of computing them again. Never read from
    /// files.
    pub features: Option<Plane>,
    /// The beauty as rendered, where `color` holds an earlier pass's result and the method
    /// asks for it ([`crate::run::denoiser::WindowDenoiser::needs_rendered`]): attached by the
    /// sequence job from the original input file. Never read from this file's own layers.
    pub rendered: Option<Plane>,
    /// The full channel names the beauty was read from (R, G, B), for writing results back.
    pub color_channels: Vec<String>,
    /// The full channel names of the renderer's own denoised beauty, where the file holds one
    /// beside the noisy beauty that was read ([`ChannelMapping::denoised`]): results are
    /// written into these as well, so that every reader of the output sees radn's result.
    pub denoised_channels: Option<Vec<String>>,
    /// The full channel name of alpha, if read.
    pub alpha_channel: Option<String>,
    /// How many NaN/Inf samples were repaired.
    pub repaired: usize,
}

impl Frame {
    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.color.width()
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.color.height()
    }

    /// Errors unless this frame is `width`×`height` (frames of one sequence must match).
    pub fn ensure_size(&self, width: usize, height: usize) -> Result<()> {
        if self.width() != width || self.height() != height {
            return Err(Error::SizeMismatch {
                path: self.path.clone(),
                expected_w: width,
                expected_h: height,
                found_w: self.width(),
                found_h: self.height(),
            });
        }
        Ok(())
    }

    /// Rows `rows` of every plane: the band of this frame banded alignment reads.
    pub fn rows(&self, rows: std::ops::Range<usize>) -> Frame {
        let cut = |p: &Option<Plane>| p.as_ref().map(|p| p.rows(rows.clone()));
        Frame {
            path: self.path.clone(),
            color: self.color.rows(rows.clone()),
            alpha: cut(&self.alpha),
            albedo: cut(&self.albedo),
            normal: cut(&self.normal),
            depth: cut(&self.depth),
            motion_prev: cut(&self.motion_prev),
            motion_next: cut(&self.motion_next),
            variance: cut(&self.variance),
            aovs: self
                .aovs
                .iter()
                .map(|a| Aov {
                    name: a.name.clone(),
                    channels: a.channels.clone(),
                    plane: a.plane.rows(rows.clone()),
                })
                .collect(),
            guide: cut(&self.guide),
            features: cut(&self.features),
            rendered: cut(&self.rendered),
            color_channels: self.color_channels.clone(),
            denoised_channels: self.denoised_channels.clone(),
            alpha_channel: self.alpha_channel.clone(),
            repaired: self.repaired,
        }
    }

    /// A frame holding only the given planes, for tests and synthetic data.
    pub fn synthetic(color: Plane) -> Self {
        Self {
            path: PathBuf::from("<synthetic>"),
            color,
            alpha: None,
            albedo: None,
            normal: None,
            depth: None,
            motion_prev: None,
            motion_next: None,
            variance: None,
            aovs: Vec::new(),
            guide: None,
            features: None,
            rendered: None,
            color_channels: vec!["R".into(), "G".into(), "B".into()],
            denoised_channels: None,
            alpha_channel: None,
            repaired: 0,
        }
    }
}

/// Which buffers a caller cannot work without.
#[derive(Clone, Copy, Debug)]
pub struct Requirements {
    /// Albedo must be present.
    pub albedo: bool,
    /// Normal must be present.
    pub normal: bool,
    /// Depth must be present.
    pub depth: bool,
    /// Motion towards the previous or the next frame must be present.
    pub motion: bool,
}

impl Requirements {
    /// Only the beauty.
    pub const COLOR_ONLY: Requirements = Requirements {
        albedo: false,
        normal: false,
        depth: false,
        motion: false,
    };
    /// What a per-frame network needs: albedo and normal (no motion).
    pub const AUXILIARIES: Requirements = Requirements {
        albedo: true,
        normal: true,
        depth: false,
        motion: false,
    };
    /// What warping and the denoisers need: albedo, normal and motion (depth used when present).
    pub const DENOISE: Requirements = Requirements {
        albedo: true,
        normal: true,
        depth: false,
        motion: true,
    };
}

/// Reads frames from EXR files through a channel mapping, checking and repairing as it goes.
#[derive(Clone, Debug)]
pub struct FrameReader {
    /// The channel mapping (preset or user file).
    pub mapping: ChannelMapping,
    /// The view layer to use when a file holds several.
    pub layer: Option<String>,
    /// Buffers that must be present.
    pub require: Requirements,
    /// What to do with NaN/Inf samples.
    pub nonfinite: NonFinitePolicy,
    /// Extra buffers to read: layer names (with the view-layer prefix implied) or full channel names.
    pub aovs: Vec<String>,
    /// The guide layer to read into [`Frame::guide`], if any.
    pub guide: GuideLayer,
}

/// Which layer of a file [`FrameReader`] reads as the frame's guide.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum GuideLayer {
    /// None.
    #[default]
    None,
    /// The renderer's denoised beauty ([`ChannelMapping::denoised`]), which must be a layer
    /// other than the noisy beauty read.
    Denoised,
    /// A layer by name (view-layer prefix implied) or three full channel names' layer.
    Layer(String),
}

impl FrameReader {
    /// A reader with the given mapping and requirements, repairing NaN/Inf and reading no AOVs.
    pub fn new(mapping: ChannelMapping, require: Requirements) -> Self {
        Self {
            mapping,
            layer: None,
            require,
            nonfinite: NonFinitePolicy::Repair,
            aovs: Vec::new(),
            guide: GuideLayer::None,
        }
    }

    /// The error for a file without the mapping's motion channels (`names`: its channels).
    fn no_motion(&self, path: PathBuf, names: &[String]) -> Error {
        let looked_for = [&self.mapping.motion_prev, &self.mapping.motion_next]
            .iter()
            .filter_map(|m| m.as_ref())
            .map(|m| describe(&m.layer, &m.channels))
            .collect::<Vec<_>>()
            .join(" or ");
        Error::MissingChannel {
            path,
            what: "motion vector".into(),
            preset: self.mapping.name.clone(),
            looked_for: if looked_for.is_empty() {
                "(the mapping defines none)".into()
            } else {
                looked_for
            },
            present: names.join(", "),
        }
    }

    /// The error for a frame of `path` read without motion channels in a sequence aligned by the
    /// renderer's vectors (the other frames have them).
    pub fn missing_motion(&self, path: &Path) -> Error {
        let names = ExrFile::read_channel_names(path).unwrap_or_default();
        self.no_motion(path.to_path_buf(), &names)
    }

    /// The reader for a method that denoises each frame alone: it needs `require` and reads
    /// no motion, depth or variance (a frame's band then holds only what the method uses).
    pub fn per_frame(mut self, require: Requirements) -> Self {
        self.require = require;
        self.mapping.motion_prev = None;
        self.mapping.motion_next = None;
        self.mapping.depth = None;
        self.mapping.variance = None;
        self
    }

    /// Reads one file into a frame, and hands back the decoded file for writing results into.
    pub fn read(&self, path: &Path) -> Result<(Frame, ExrFile)> {
        let file = ExrFile::read(path)?;
        let frame = self.frame_from(&file)?;
        Ok((frame, file))
    }

    /// Reads rows `rows` of one file into a frame `rows.len()` rows tall, decoding only the
    /// blocks that hold them (banded denoising).
    pub fn read_rows(&self, path: &Path, rows: std::ops::Range<usize>) -> Result<Frame> {
        self.frame_from(&ExrFile::read_rows(path, rows)?)
    }

    /// Extracts a frame from an already decoded file.
    pub fn frame_from(&self, file: &ExrFile) -> Result<Frame> {
        let names = file.channel_names();
        let path = file.path().to_path_buf();
        let mut repaired = 0usize;

        let (color, color_channels, prefix) = {
            let r = self
                .find(
                    file,
                    &names,
                    "color",
                    &self.mapping.color.layer,
                    &self.mapping.color.channels,
                )?
                .ok_or_else(|| self.missing(file, &names, "color (beauty)", &self.mapping.color))?;
            (
                self.load(file, &r.channels, &mut repaired, None)?,
                r.channels,
                r.prefix,
            )
        };
        let layer_choice = self.layer.clone().or(Some(prefix.clone()));
        let optional = |spec: &Option<PlaneSpec>,
                        what: &str,
                        needed: bool,
                        far: Option<f32>,
                        rep: &mut usize|
         -> Result<Option<(Plane, Vec<String>)>> {
            let Some(spec) = spec else {
                if needed {
                    return Err(Error::MissingChannel {
                        path: path.clone(),
                        what: what.into(),
                        preset: self.mapping.name.clone(),
                        looked_for: "(the mapping defines none)".into(),
                        present: names.join(", "),
                    });
                }
                return Ok(None);
            };
            let r = self.find_with(
                file,
                &names,
                what,
                &spec.layer,
                &spec.channels,
                layer_choice.as_deref(),
            )?;
            match r {
                Some(r) => Ok(Some((self.load(file, &r.channels, rep, far)?, r.channels))),
                None if needed => Err(self.missing(file, &names, what, spec)),
                None => Ok(None),
            }
        };
        let alpha = optional(&self.mapping.alpha, "alpha", false, None, &mut repaired)?;
        let albedo = optional(
            &self.mapping.albedo,
            "albedo",
            self.require.albedo,
            None,
            &mut repaired,
        )?
        .map(|p| p.0);
        let normal = optional(
            &self.mapping.normal,
            "normal",
            self.require.normal,
            None,
            &mut repaired,
        )?
        .map(|p| p.0);
        let depth = optional(
            &self.mapping.depth,
            "depth",
            self.require.depth,
            Some(FAR_DEPTH),
            &mut repaired,
        )?
        .map(|p| p.0);
        let variance = optional(
            &self.mapping.variance,
            "variance",
            false,
            None,
            &mut repaired,
        )?
        .map(|p| p.0);
        let motion_prev = self.motion(
            file,
            &names,
            &self.mapping.motion_prev,
            layer_choice.as_deref(),
            &mut repaired,
        )?;
        let motion_next = self.motion(
            file,
            &names,
            &self.mapping.motion_next,
            layer_choice.as_deref(),
            &mut repaired,
        )?;
        if self.require.motion && motion_prev.is_none() && motion_next.is_none() {
            return Err(self.no_motion(path, &names));
        }
        let mut aovs = Vec::new();
        for name in &self.aovs {
            let channels = aov_channels(&names, name, &prefix);
            if channels.is_empty() {
                return Err(Error::MissingChannel {
                    path,
                    what: format!("AOV '{name}'"),
                    preset: self.mapping.name.clone(),
                    looked_for: format!("a layer '{name}' or a channel named '{name}'"),
                    present: names.join(", "),
                });
            }
            let plane = self.load(file, &channels, &mut repaired, None)?;
            aovs.push(Aov {
                name: name.clone(),
                channels,
                plane,
            });
        }
        let denoised_channels = self.denoised_channels(file, &names, &color_channels, &prefix)?;
        let guide = self.guide_plane(
            file,
            &names,
            &color_channels,
            denoised_channels.as_ref(),
            &prefix,
            &mut repaired,
        )?;
        let (alpha, alpha_channel) = match alpha {
            Some((p, c)) => (Some(p), Some(c[0].clone())),
            None => (None, None),
        };
        Ok(Frame {
            path,
            color,
            alpha,
            albedo,
            normal,
            depth,
            motion_prev,
            motion_next,
            variance,
            aovs,
            guide,
            features: None,
            rendered: None,
            denoised_channels,
            color_channels,
            alpha_channel,
            repaired,
        })
    }

    /// The channels of the renderer's denoised beauty in `file`, if the mapping names one and
    /// it is not the layer the (noisy) beauty `color` was read from.
    fn denoised_channels(
        &self,
        file: &ExrFile,
        names: &[String],
        color: &[String],
        prefix: &str,
    ) -> Result<Option<Vec<String>>> {
        let Some(spec) = &self.mapping.denoised else {
            return Ok(None);
        };
        let choice = self.layer.clone().or(Some(prefix.to_string()));
        let r = self.find_with(
            file,
            names,
            "denoised beauty",
            &spec.layer,
            &spec.channels,
            choice.as_deref(),
        )?;
        Ok(r.map(|r| r.channels).filter(|c| c.as_slice() != color))
    }

    /// The guide plane `self.guide` asks for, from a decoded file whose (noisy) beauty is
    /// `color` and whose renderer-denoised beauty is `denoised`.
    fn guide_plane(
        &self,
        file: &ExrFile,
        names: &[String],
        color: &[String],
        denoised: Option<&Vec<String>>,
        prefix: &str,
        repaired: &mut usize,
    ) -> Result<Option<Plane>> {
        let channels = match &self.guide {
            GuideLayer::None => return Ok(None),
            GuideLayer::Denoised => match denoised {
                Some(c) => c.clone(),
                None => {
                    return Err(Error::MissingChannel {
                        path: file.path().to_path_buf(),
                        what: "denoised beauty (a guide layer beside the noisy beauty)".into(),
                        preset: self.mapping.name.clone(),
                        looked_for: self.mapping.denoised.as_ref().map_or_else(
                            || "(the mapping defines none)".into(),
                            |s| {
                                format!(
                                    "{} other than the beauty's {}",
                                    describe(&s.layer, &s.channels),
                                    color.join(",")
                                )
                            },
                        ),
                        present: names.join(", "),
                    })
                }
            },
            GuideLayer::Layer(layer) => {
                let mut c = aov_channels(names, layer, prefix);
                c.retain(|c| {
                    let last = c.rsplit('.').next().unwrap_or(c).to_ascii_uppercase();
                    ["R", "G", "B", "X", "Y", "Z"].contains(&last.as_str())
                });
                if c.len() != 3 {
                    return Err(Error::MissingChannel {
                        path: file.path().to_path_buf(),
                        what: format!("guide layer '{layer}'"),
                        preset: self.mapping.name.clone(),
                        looked_for: format!("a layer '{layer}' with R, G, B channels"),
                        present: names.join(", "),
                    });
                }
                if c.as_slice() == color {
                    return Err(Error::Unsupported {
                        path: file.path().to_path_buf(),
                        detail: format!(
                            "the guide layer '{layer}' is the beauty being denoised; a guide \
                             must be another estimate of it (the renderer's denoised layer)"
                        ),
                    });
                }
                c
            }
        };
        Ok(Some(self.load(file, &channels, repaired, None)?))
    }

    fn find(
        &self,
        file: &ExrFile,
        names: &[String],
        what: &str,
        layers: &[String],
        comps: &[String],
    ) -> Result<Option<crate::io::mapping::Resolved>> {
        self.find_with(file, names, what, layers, comps, self.layer.as_deref())
    }

    fn find_with(
        &self,
        file: &ExrFile,
        names: &[String],
        what: &str,
        layers: &[String],
        comps: &[String],
        choice: Option<&str>,
    ) -> Result<Option<crate::io::mapping::Resolved>> {
        match resolve(layers, comps, names, choice) {
            Ok(r) => Ok(r),
            Err(prefixes) => Err(Error::AmbiguousLayer {
                path: file.path().to_path_buf(),
                what: what.into(),
                layers: prefixes.join(", "),
            }),
        }
    }

    fn missing(&self, file: &ExrFile, names: &[String], what: &str, spec: &PlaneSpec) -> Error {
        Error::MissingChannel {
            path: file.path().to_path_buf(),
            what: what.into(),
            preset: self.mapping.name.clone(),
            looked_for: describe(&spec.layer, &spec.channels),
            present: names.join(", "),
        }
    }

    fn load(
        &self,
        file: &ExrFile,
        channels: &[String],
        repaired: &mut usize,
        far: Option<f32>,
    ) -> Result<Plane> {
        let (w, h) = (file.width(), file.height());
        let data: Vec<Vec<f32>> = channels
            .iter()
            .map(|c| file.channel_f32(c).expect("resolved channels exist"))
            .collect();
        let refs: Vec<&[f32]> = data.iter().map(|v| v.as_slice()).collect();
        let mut plane = Plane::from_channels(w, h, &refs);
        if let Some(far) = far {
            // +Inf depth is how half-float files store the background: not a defect
            plane
                .data_mut()
                .iter_mut()
                .filter(|v| **v == f32::INFINITY)
                .for_each(|v| *v = far);
        }
        let counts = count_nonfinite(&plane);
        if counts.iter().any(|&n| n > 0) {
            if self.nonfinite == NonFinitePolicy::Error {
                let (i, n) = counts
                    .iter()
                    .enumerate()
                    .find(|(_, n)| **n > 0)
                    .expect("some count is non-zero");
                return Err(Error::NonFinite {
                    path: file.path().to_path_buf(),
                    channel: channels[i].clone(),
                    count: *n,
                });
            }
            let n = repair_nonfinite(&mut plane, far);
            for (i, c) in counts.iter().enumerate().filter(|(_, c)| **c > 0) {
                tracing::warn!(file = %file.path().display(), channel = %channels[i], count = c, "repaired NaN/Inf samples");
            }
            *repaired += n;
        }
        Ok(plane)
    }

    fn motion(
        &self,
        file: &ExrFile,
        names: &[String],
        spec: &Option<MotionSpec>,
        choice: Option<&str>,
        repaired: &mut usize,
    ) -> Result<Option<Plane>> {
        let Some(spec) = spec else { return Ok(None) };
        let Some(r) = self.find_with(
            file,
            names,
            "motion vector",
            &spec.layer,
            &spec.channels,
            choice,
        )?
        else {
            return Ok(None);
        };
        let mut plane = self.load(file, &r.channels, repaired, None)?;
        let (w, h) = (plane.width() as f32, plane.height() as f32);
        let unit = match spec.units {
            MotionUnits::Pixels => [1.0, 1.0],
            MotionUnits::Uv => [w, h],
        };
        for (c, (scale, unit)) in spec.scale.iter().zip(unit).enumerate() {
            let k = scale * unit;
            plane.channel_mut(c).iter_mut().for_each(|v| *v *= k);
        }
        Ok(Some(plane))
    }
}

fn describe(layers: &[String], comps: &[String]) -> String {
    layers
        .iter()
        .map(|l| {
            let c = comps.join(",");
            if l.is_empty() {
                format!("'{c}'")
            } else {
                format!("'{l}.{{{c}}}'")
            }
        })
        .collect::<Vec<_>>()
        .join(" or ")
}

/// The channels of an AOV named `name`: every channel of layer `name` (under the view-layer
/// prefix if there is one), or the single channel of that full name.
fn aov_channels(names: &[String], name: &str, prefix: &str) -> Vec<String> {
    if names.iter().any(|n| n == name) {
        return vec![name.to_string()];
    }
    let mut layers = vec![format!("{name}.")];
    if !prefix.is_empty() {
        layers.insert(0, format!("{prefix}.{name}."));
    }
    for l in layers {
        let mut found: Vec<String> = names
            .iter()
            .filter(|n| n.starts_with(&l) && !n[l.len()..].contains('.'))
            .cloned()
            .collect();
        if !found.is_empty() {
            sort_components(&mut found);
            return found;
        }
    }
    Vec::new()
}

/// Orders channel names R, G, B, A / X, Y, Z, W first, the rest alphabetically.
fn sort_components(v: &mut [String]) {
    let rank = |n: &str| {
        let c = n.rsplit('.').next().unwrap_or(n).to_ascii_uppercase();
        ["R", "G", "B", "A", "X", "Y", "Z", "W"]
            .iter()
            .position(|x| *x == c)
            .unwrap_or(99)
    };
    v.sort_by(|a, b| rank(a).cmp(&rank(b)).then(a.cmp(b)));
}

#[cfg(test)]
mod tests;
