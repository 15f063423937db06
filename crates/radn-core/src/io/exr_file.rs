//! Whole EXR files kept in memory, so that writing back preserves every layer, channel and
//! attribute radn did not change.

use std::collections::HashMap;
use std::io::Read;
use std::ops::Range;
use std::path::{Path, PathBuf};

use exr::block::reader::ChunksReader;
use exr::prelude::*;
use half::f16;

use crate::error::{Error, Result};

/// The storage type of one EXR channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleKind {
    /// 16-bit float.
    F16,
    /// 32-bit float.
    F32,
    /// 32-bit unsigned integer (object ids and the like).
    U32,
}

impl std::fmt::Display for SampleKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SampleKind::F16 => "half",
            SampleKind::F32 => "float",
            SampleKind::U32 => "uint",
        })
    }
}

/// Where one channel lives inside the decoded image.
#[derive(Clone, Copy, Debug)]
struct ChannelRef {
    layer: usize,
    index: usize,
}

/// A decoded EXR file: all layers (parts), channels and header attributes.
///
/// Channels are addressed by their *full name*: `part.channel` for named parts of a
/// multi-part file, the plain channel name otherwise (single-part multilayer files such as
/// Cycles' already carry dotted names like `ViewLayer.Combined.R`).
#[derive(Clone, Debug)]
pub struct ExrFile {
    path: PathBuf,
    image: FlatImage,
    index: HashMap<String, ChannelRef>,
}

/// The first four bytes of every OpenEXR file.
const EXR_MAGIC: [u8; 4] = [0x76, 0x2f, 0x31, 0x01];

/// Opens a file for decoding, refusing one that cannot be opened or does not start with the
/// OpenEXR magic number (so a JPEG or an empty file is reported as "not an EXR" rather than as
/// a decoder error), or whose headers claim more pixels than it can hold
/// ([`check_plausible_size`]); the file is handed back rewound, so each read opens it once.
pub(crate) fn open_exr(path: &Path) -> Result<std::fs::File> {
    use std::io::Seek;
    let mut f = open_exr_unchecked(path)?;
    let meta = headers_of(path, &mut f)?;
    check_plausible_size(path, &meta, &f)?;
    f.rewind().map_err(|source| Error::Open {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(f)
}

/// Opens an EXR file after checking its magic number, at its start.
fn open_exr_unchecked(path: &Path) -> Result<std::fs::File> {
    use std::io::Seek;
    let mut magic = [0u8; 4];
    let mut f = std::fs::File::open(path).map_err(|source| Error::Open {
        path: path.to_path_buf(),
        source,
    })?;
    if f.read_exact(&mut magic).is_err() || magic != EXR_MAGIC {
        return Err(Error::NotExr {
            path: path.to_path_buf(),
        });
    }
    f.rewind().map_err(|source| Error::Open {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(f)
}

/// A file's headers alone (no pixel data decoded), one opening of the file.
pub(crate) fn read_headers(path: &Path) -> Result<exr::meta::MetaData> {
    let mut f = open_exr_unchecked(path)?;
    let meta = headers_of(path, &mut f)?;
    check_plausible_size(path, &meta, &f)?;
    Ok(meta)
}

fn headers_of(path: &Path, f: &mut std::fs::File) -> Result<exr::meta::MetaData> {
    exr::meta::MetaData::read_from_unbuffered(&mut *f, false).map_err(|e| Error::Decode {
        path: path.to_path_buf(),
        detail: describe_exr_error(e),
    })
}

/// How many bytes of pixels one byte of a part compressed this way can decode to, at most
/// (with room to spare): deflate (ZIP, PXR24) cannot exceed 1032:1, PIZ's Huffman runs about
/// 450:1, RLE 64:1, B44 about 11:1; the DCT and wavelet codecs (DWA, HTJ2K) are given far more.
fn max_expansion(c: exr::compression::Compression) -> u128 {
    use exr::compression::Compression as C;
    match c {
        C::Uncompressed => 1,
        C::RLE => 128,
        C::B44 | C::B44A => 32,
        C::ZIP1 | C::ZIP16 | C::PXR24 | C::PIZ => 2048,
        _ => 1 << 17,
    }
}

/// Refuses a file whose headers claim more pixels than its bytes could hold under its
/// compression, before anything that big is allocated: a damaged size in a header (a data
/// window of 100 000 × 100 000 in a 250 kB file) would otherwise ask for gigabytes.
fn check_plausible_size(
    path: &Path,
    meta: &exr::meta::MetaData,
    file: &std::fs::File,
) -> Result<()> {
    let len = file.metadata().map(|m| m.len()).unwrap_or(u64::MAX) as u128;
    let (mut decoded, mut room) = (0u128, 0u128);
    for h in meta.headers.iter() {
        let (w, ht) = (h.layer_size.width() as u128, h.layer_size.height() as u128);
        let per_pixel: u128 = h
            .channels
            .list
            .iter()
            .map(|c| c.sample_type.bytes_per_sample() as u128)
            .sum();
        decoded += w * ht * per_pixel;
        room = room.max(max_expansion(h.compression));
    }
    // small files get headroom: headers, tables and codec set-up dominate them
    let limit = (len + (1 << 16)) * room;
    if decoded > limit {
        let first = &meta.headers[0];
        return Err(Error::Decode {
            path: path.to_path_buf(),
            detail: format!(
                "its header claims {}x{} pixels ({:.1} GB decoded) in a {:.1} kB file, more \
                 than {} can hold: the header is damaged",
                first.layer_size.width(),
                first.layer_size.height(),
                decoded as f64 / 1e9,
                len as f64 / 1e3,
                first.compression,
            ),
        });
    }
    Ok(())
}

impl ExrFile {
    /// Reads and decodes a whole file; every failure names the file.
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let file = open_exr(&path)?;
        let image = read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .all_layers()
            .all_attributes()
            .from_unbuffered(file)
            .map_err(|e| Error::Decode {
                path: path.clone(),
                detail: describe_exr_error(e),
            })?;
        let file = Self::from_image(path, image);
        file.check_layers()?;
        Ok(file)
    }

    /// Reads rows `rows` of every part and channel, decoding only the blocks that hold them:
    /// what banded denoising reads, so memory follows the band rather than the frame. The
    /// result is for reading channels from (its parts are `rows.len()` rows tall), not for
    /// writing back.
    pub fn read_rows(path: impl AsRef<Path>, rows: Range<usize>) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let file = open_exr(&path)?;
        let decode = |e: exr::error::Error| Error::Decode {
            path: path.clone(),
            detail: describe_exr_error(e),
        };
        let reader = exr::block::read(std::io::BufReader::new(file), false).map_err(decode)?;
        let headers = reader.headers().to_vec();
        let first = headers.first().ok_or_else(|| Error::Decode {
            path: path.clone(),
            detail: "the file has no parts".into(),
        })?;
        let (w, h) = (first.layer_size.width(), first.layer_size.height());
        if rows.start >= rows.end || rows.end > h {
            return Err(Error::Unsupported {
                path: path.clone(),
                detail: format!("rows {}..{} asked of a {h}-row image", rows.start, rows.end),
            });
        }
        if headers.iter().any(|hd| hd.deep) {
            return Err(Error::Unsupported {
                path: path.clone(),
                detail: "it holds deep data, which radn does not denoise".into(),
            });
        }
        let n = w * rows.len();
        let mut samples: Vec<Vec<FlatSamples>> = headers
            .iter()
            .map(|hd| {
                hd.channels
                    .list
                    .iter()
                    .map(|c| match c.sample_type {
                        SampleType::F16 => FlatSamples::F16(vec![f16::ZERO; n]),
                        SampleType::F32 => FlatSamples::F32(vec![0.0; n]),
                        SampleType::U32 => FlatSamples::U32(vec![0; n]),
                    })
                    .collect()
            })
            .collect();
        let wanted = rows.clone();
        let chunks = reader
            .filter_chunks(false, move |_, _, b| {
                b.level == Vec2(0, 0)
                    && b.pixel_position.y() < wanted.end
                    && b.pixel_position.y() + b.pixel_size.height() > wanted.start
            })
            .map_err(decode)?;
        let same_size = headers.iter().all(|hd| hd.layer_size == first.layer_size);
        chunks
            .decompress_sequential(false, |meta, block| {
                let header = &meta.headers[block.index.layer];
                if !same_size {
                    return Ok(()); // refused below with the sizes named
                }
                for line in block.lines(&header.channels) {
                    let y = line.location.position.y();
                    if !rows.contains(&y) {
                        continue;
                    }
                    let at = (y - rows.start) * w + line.location.position.x();
                    let count = line.location.sample_count;
                    match &mut samples[block.index.layer][line.location.channel] {
                        FlatSamples::F16(v) => {
                            line.read_samples_into_slice(&mut v[at..at + count])?
                        }
                        FlatSamples::F32(v) => {
                            line.read_samples_into_slice(&mut v[at..at + count])?
                        }
                        FlatSamples::U32(v) => {
                            line.read_samples_into_slice(&mut v[at..at + count])?
                        }
                    }
                }
                Ok(())
            })
            .map_err(decode)?;
        let layer_data = headers
            .iter()
            .zip(samples)
            .map(|(hd, data)| {
                let list = hd
                    .channels
                    .list
                    .iter()
                    .zip(data)
                    .map(|(c, sample_data)| AnyChannel {
                        name: c.name.clone(),
                        sample_data,
                        quantize_linearly: c.quantize_linearly,
                        sampling: c.sampling,
                    })
                    .collect();
                Layer {
                    channel_data: AnyChannels { list },
                    attributes: hd.own_attributes.clone(),
                    size: if same_size {
                        Vec2(w, rows.len())
                    } else {
                        hd.layer_size
                    },
                    encoding: Encoding {
                        compression: hd.compression,
                        blocks: Blocks::ScanLines,
                        line_order: hd.line_order,
                    },
                }
            })
            .collect();
        let image: FlatImage = Image {
            attributes: first.shared_attributes.clone(),
            layer_data,
        };
        let file = Self::from_image(path, image);
        file.check_layers()?;
        Ok(file)
    }

    /// The pixel size of a file's first part from its header alone (no pixel data decoded), so a
    /// whole sequence can be checked before hours of work start; failures name the file.
    pub fn read_size(path: impl AsRef<Path>) -> Result<(usize, usize)> {
        let path = path.as_ref().to_path_buf();
        let meta = read_headers(&path)?;
        let h = meta.headers.first().ok_or_else(|| Error::Decode {
            path: path.clone(),
            detail: "the file has no parts".into(),
        })?;
        Ok((h.layer_size.width(), h.layer_size.height()))
    }

    /// The full channel names of a file (`layer.channel` for named parts), sorted, from its
    /// headers alone: what choosing a channel preset needs, without decoding any pixel.
    pub fn read_channel_names(path: impl AsRef<Path>) -> Result<Vec<String>> {
        let path = path.as_ref().to_path_buf();
        let meta = read_headers(&path)?;
        let mut names: Vec<String> = meta
            .headers
            .iter()
            .flat_map(|h| {
                let prefix = h.own_attributes.layer_name.as_ref().map(|t| t.to_string());
                h.channels.list.iter().map(move |c| match &prefix {
                    Some(p) => format!("{p}.{}", c.name),
                    None => c.name.to_string(),
                })
            })
            .collect();
        names.sort();
        names.dedup();
        Ok(names)
    }

    /// Builds a new single-part file from named planes of one size.
    pub fn from_channels(
        path: impl AsRef<Path>,
        width: usize,
        height: usize,
        channels: Vec<(String, Vec<f32>)>,
        kind: SampleKind,
    ) -> Self {
        let list = channels
            .into_iter()
            .map(|(name, data)| {
                assert_eq!(
                    data.len(),
                    width * height,
                    "channel '{name}' has the wrong length"
                );
                AnyChannel::new(Text::from(name.as_str()), samples_of_kind(&data, kind))
            })
            .collect();
        let layer = Layer::new(
            Vec2(width, height),
            LayerAttributes::default(),
            Encoding::SMALL_LOSSLESS,
            AnyChannels::sort(list),
        );
        let single = Image::from_layer(layer);
        let image: FlatImage = Image {
            attributes: single.attributes,
            layer_data: std::iter::once(single.layer_data).collect(),
        };
        Self::from_image(path.as_ref().to_path_buf(), image)
    }

    fn from_image(path: PathBuf, image: FlatImage) -> Self {
        let mut file = Self {
            path,
            image,
            index: HashMap::new(),
        };
        file.reindex();
        file
    }

    fn reindex(&mut self) {
        self.index.clear();
        for (li, layer) in self.image.layer_data.iter().enumerate() {
            let prefix = layer.attributes.layer_name.as_ref().map(|t| t.to_string());
            for (ci, ch) in layer.channel_data.list.iter().enumerate() {
                let name = match &prefix {
                    Some(p) => format!("{p}.{}", ch.name),
                    None => ch.name.to_string(),
                };
                self.index.insert(
                    name,
                    ChannelRef {
                        layer: li,
                        index: ci,
                    },
                );
            }
        }
    }

    fn check_layers(&self) -> Result<()> {
        let first = self
            .image
            .layer_data
            .first()
            .ok_or_else(|| Error::Unsupported {
                path: self.path.clone(),
                detail: "the file has no image layers".into(),
            })?;
        for layer in &self.image.layer_data {
            if layer.size != first.size {
                return Err(Error::Unsupported {
                    path: self.path.clone(),
                    detail: format!(
                        "its parts differ in size ({}x{} vs {}x{}); radn needs one data window",
                        layer.size.0, layer.size.1, first.size.0, first.size.1
                    ),
                });
            }
            for ch in &layer.channel_data.list {
                if ch.sampling != Vec2(1, 1) {
                    return Err(Error::Unsupported {
                        path: self.path.clone(),
                        detail: format!(
                            "channel '{}' is subsampled, which radn does not support",
                            ch.name
                        ),
                    });
                }
            }
        }
        Ok(())
    }

    /// The file this was read from (or will be written to).
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Width of the data window in pixels.
    pub fn width(&self) -> usize {
        self.image.layer_data[0].size.0
    }

    /// Height of the data window in pixels.
    pub fn height(&self) -> usize {
        self.image.layer_data[0].size.1
    }

    /// Full names of all channels, sorted.
    pub fn channel_names(&self) -> Vec<String> {
        let mut names: Vec<String> = self.index.keys().cloned().collect();
        names.sort();
        names
    }

    /// Value statistics of every channel (sorted by name), as `radn inspect` shows them.
    pub fn channel_stats(&self) -> Vec<ChannelStats> {
        self.channel_names()
            .iter()
            .map(|n| {
                let v = self.channel_f32(n).expect("listed channel exists");
                let (mut min, mut max, mut sum, mut nan, mut inf, mut finite) =
                    (f32::INFINITY, f32::NEG_INFINITY, 0f64, 0, 0, 0usize);
                for &x in &v {
                    if x.is_nan() {
                        nan += 1;
                    } else if x.is_infinite() {
                        inf += 1;
                    } else {
                        min = min.min(x);
                        max = max.max(x);
                        sum += x as f64;
                        finite += 1;
                    }
                }
                ChannelStats {
                    name: n.clone(),
                    kind: self
                        .channel_kind(n)
                        .expect("listed channel exists")
                        .to_string(),
                    min,
                    max,
                    mean: if finite > 0 {
                        sum / finite as f64
                    } else {
                        f64::NAN
                    },
                    nan,
                    inf,
                }
            })
            .collect()
    }

    /// True when the file has a channel of this full name.
    pub fn has_channel(&self, name: &str) -> bool {
        self.index.contains_key(name)
    }

    /// The storage type of a channel.
    pub fn channel_kind(&self, name: &str) -> Option<SampleKind> {
        self.samples(name).map(|s| match s {
            FlatSamples::F16(_) => SampleKind::F16,
            FlatSamples::F32(_) => SampleKind::F32,
            FlatSamples::U32(_) => SampleKind::U32,
        })
    }

    fn samples(&self, name: &str) -> Option<&FlatSamples> {
        let r = self.index.get(name)?;
        Some(&self.image.layer_data[r.layer].channel_data.list[r.index].sample_data)
    }

    /// A channel's samples converted to f32, row-major.
    pub fn channel_f32(&self, name: &str) -> Option<Vec<f32>> {
        self.samples(name).map(|s| match s {
            FlatSamples::F16(v) => v.iter().map(|x| x.to_f32()).collect(),
            FlatSamples::F32(v) => v.clone(),
            FlatSamples::U32(v) => v.iter().map(|&x| x as f32).collect(),
        })
    }

    /// Replaces a channel's samples, keeping its storage type; adds the channel (as f32
    /// unless `kind` says otherwise) when it does not exist yet.
    ///
    /// A new channel goes into the part whose name prefixes it, or else the first part.
    pub fn set_channel(&mut self, name: &str, data: &[f32], kind_if_new: SampleKind) {
        assert_eq!(
            data.len(),
            self.width() * self.height(),
            "channel '{name}' has the wrong length"
        );
        if let Some(r) = self.index.get(name).copied() {
            let ch = &mut self.image.layer_data[r.layer].channel_data.list[r.index];
            let kind = match ch.sample_data {
                FlatSamples::F16(_) => SampleKind::F16,
                FlatSamples::F32(_) => SampleKind::F32,
                FlatSamples::U32(_) => SampleKind::U32,
            };
            ch.sample_data = samples_of_kind(data, kind);
            return;
        }
        let (layer_index, local_name) = self
            .image
            .layer_data
            .iter()
            .enumerate()
            .find_map(|(i, l)| {
                let p = l.attributes.layer_name.as_ref()?.to_string();
                name.strip_prefix(&format!("{p}."))
                    .map(|rest| (i, rest.to_string()))
            })
            .unwrap_or((0, name.to_string()));
        let layer = &mut self.image.layer_data[layer_index];
        let mut list = std::mem::take(&mut layer.channel_data.list);
        list.push(AnyChannel::new(
            Text::from(local_name.as_str()),
            samples_of_kind(data, kind_if_new),
        ));
        layer.channel_data = AnyChannels::sort(list);
        self.reindex();
    }

    /// Changes the storage type of an existing channel (values converted); false if absent.
    pub fn convert_channel(&mut self, name: &str, kind: SampleKind) -> bool {
        let Some(r) = self.index.get(name).copied() else {
            return false;
        };
        let data = self.channel_f32(name).expect("indexed channel exists");
        self.image.layer_data[r.layer].channel_data.list[r.index].sample_data =
            samples_of_kind(&data, kind);
        true
    }

    /// A short description of each part for `radn inspect`: name, compression, block layout.
    pub fn parts(&self) -> Vec<PartInfo> {
        self.image
            .layer_data
            .iter()
            .map(|l| PartInfo {
                name: l.attributes.layer_name.as_ref().map(|t| t.to_string()),
                width: l.size.0,
                height: l.size.1,
                compression: format!("{:?}", l.encoding.compression),
                tiles: match l.encoding.blocks {
                    Blocks::ScanLines => None,
                    Blocks::Tiles(t) => Some((t.0, t.1)),
                },
                channels: l.channel_data.list.len(),
            })
            .collect()
    }

    /// Names of the image-level header attributes other than the standard ones.
    pub fn custom_attribute_names(&self) -> Vec<String> {
        let mut v: Vec<String> = self
            .image
            .attributes
            .other
            .keys()
            .map(|k| k.to_string())
            .collect();
        for l in &self.image.layer_data {
            v.extend(l.attributes.other.keys().map(|k| k.to_string()));
        }
        v.sort();
        v.dedup();
        v
    }

    /// Writes the file to `path` through a temporary file in the same folder renamed into
    /// place, so a failed or interrupted write never leaves a partial file at `path`.
    pub fn write_atomic(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        crate::io::output::write_atomically(path, |w| {
            self.image
                .write()
                .to_buffered(w)
                .map_err(|e| Error::Encode {
                    path: path.to_path_buf(),
                    detail: describe_exr_error(e),
                })
        })
    }
}

/// Value statistics of one channel: range and mean of its finite samples, and how many are
/// NaN or infinite.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ChannelStats {
    /// Full channel name.
    pub name: String,
    /// Storage type (`half`, `float`, `uint`).
    pub kind: String,
    /// Smallest finite sample (+inf when none is finite).
    pub min: f32,
    /// Largest finite sample (−inf when none is finite).
    pub max: f32,
    /// Mean of the finite samples (NaN when none is finite).
    pub mean: f64,
    /// NaN samples.
    pub nan: usize,
    /// Infinite samples.
    pub inf: usize,
}

/// One part (layer) of an EXR file, as shown by `radn inspect`.
#[derive(Clone, Debug)]
pub struct PartInfo {
    /// The part's name, if it has one.
    pub name: Option<String>,
    /// Data window width.
    pub width: usize,
    /// Data window height.
    pub height: usize,
    /// Compression method.
    pub compression: String,
    /// Tile size, or `None` for scanline storage.
    pub tiles: Option<(usize, usize)>,
    /// Number of channels in the part.
    pub channels: usize,
}

fn samples_of_kind(data: &[f32], kind: SampleKind) -> FlatSamples {
    match kind {
        SampleKind::F16 => FlatSamples::F16(data.iter().map(|&x| f16::from_f32(x)).collect()),
        SampleKind::F32 => FlatSamples::F32(data.to_vec()),
        SampleKind::U32 => {
            FlatSamples::U32(data.iter().map(|&x| x.max(0.0).round() as u32).collect())
        }
    }
}

pub(crate) fn describe_exr_error(e: exr::error::Error) -> String {
    match e {
        exr::error::Error::Invalid(msg) => format!("the file is corrupt or truncated ({msg})"),
        exr::error::Error::NotSupported(msg) => format!("unsupported EXR feature ({msg})"),
        exr::error::Error::Io(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            "the file is truncated (unexpected end of file)".to_string()
        }
        exr::error::Error::Io(io) => format!("i/o error ({io})"),
        exr::error::Error::Aborted => "aborted".to_string(),
    }
}

#[cfg(test)]
mod tests;

#[cfg(test)]
pub(crate) mod format_tests;
