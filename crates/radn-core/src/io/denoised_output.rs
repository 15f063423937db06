//! Writing denoised frames: a copy of the input file in which the denoised channels carry new
//! values and every other part, channel and attribute is kept, through a temporary file renamed
//! into place — whole ([`write_result`]), or block by block as bands of denoised rows arrive
//! ([`write_banded`]), so neither the file nor the denoised frame is ever held whole.

use std::ops::Range;
use std::path::Path;

use exr::block::reader::ChunksReader;
use exr::block::writer::ChunksWriter;
use exr::block::{BlockIndex, UncompressedBlock};
use exr::math::Vec2;
use exr::meta::attribute::{LevelMode, LineOrder, SampleType, TileDescription};
use exr::meta::header::Header;
use exr::meta::{BlockDescription, MetaData};
use half::f16;
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::image::plane::Plane;
use crate::io::exr_file::{describe_exr_error, read_headers, ExrFile, SampleKind};
use crate::io::frame::Frame;
use crate::run::denoiser::Denoised;

/// Where a denoised channel's values come from: plane (0 colour, 1 alpha, 2 + i AOV i) and
/// channel within it.
type Source = (usize, usize);

/// Writes `output` (through a temporary file renamed into place) as a copy of `input` whose
/// channels named in `names` (its beauty, alpha and AOV channel names) hold the denoised values
/// `band(rows)` returns for consecutive bands of `band_rows` rows; `kind` overrides their
/// storage type. Every other part, channel and attribute of `input` is kept; tiled parts are
/// written without their lower-resolution levels, as [`crate::io::exr_file::ExrFile`] does.
pub fn write_banded(
    input: &Path,
    output: &Path,
    names: &Frame,
    kind: Option<SampleKind>,
    band_rows: usize,
    mut band: impl FnMut(Range<usize>) -> Result<Denoised>,
) -> Result<()> {
    let meta = read_headers(input)?;
    let first = meta.headers.first().ok_or_else(|| Error::Decode {
        path: input.to_path_buf(),
        detail: "the file has no parts".into(),
    })?;
    let size = first.layer_size;
    if meta.headers.iter().any(|h| h.deep || h.layer_size != size) {
        return Err(Error::Unsupported {
            path: input.to_path_buf(),
            detail: "its parts differ in size or hold deep data".into(),
        });
    }
    let height = size.height();
    let sources = sources(&meta.headers, names, input)?;
    let headers: Vec<Header> = meta
        .headers
        .iter()
        .zip(&sources)
        .map(|(h, src)| output_header(h, src, kind))
        .collect();
    // every block of every part in increasing y, with its index in its part's offset table
    let blocks: Vec<Vec<(usize, BlockIndex)>> = headers
        .iter()
        .enumerate()
        .map(|(layer, h)| {
            h.blocks_increasing_y_order()
                .enumerate()
                .map(|(i, tile)| {
                    let b = h
                        .get_absolute_block_pixel_coordinates(tile.location)
                        .expect("block of a validated header");
                    (
                        i,
                        BlockIndex {
                            layer,
                            pixel_position: Vec2(b.position.x() as usize, b.position.y() as usize),
                            pixel_size: b.size,
                            level: Vec2(0, 0),
                        },
                    )
                })
                .collect()
        })
        .collect();

    crate::io::output::write_atomically(output, |writer| {
        let mut failure: Option<Error> = None;
        let written = exr::block::write(writer, headers.into(), true, |meta, chunks| {
            let mut run = || -> Result<()> {
                // denoised rows not yet written, from row `buf_y0`
                let mut buf: Option<Denoised> = None;
                let mut buf_y0 = 0;
                let mut next = vec![0usize; blocks.len()]; // per part: first block not written
                for y0 in (0..height).step_by(band_rows.max(1)) {
                    let y1 = (y0 + band_rows.max(1)).min(height);
                    let part = band(y0..y1)?;
                    buf = Some(match buf.take() {
                        None => part,
                        Some(b) => append_rows(b, &part),
                    });
                    let b = buf.as_ref().expect("just set");
                    // the blocks whose rows are all denoised now
                    let mut ready: Vec<(usize, usize)> = Vec::new(); // (part, position in blocks)
                    for (p, list) in blocks.iter().enumerate() {
                        while next[p] < list.len() {
                            let bi = list[next[p]].1;
                            if bi.pixel_position.y() + bi.pixel_size.height() > y1 {
                                break;
                            }
                            ready.push((p, next[p]));
                            next[p] += 1;
                        }
                    }
                    write_blocks(input, &meta, chunks, &blocks, &ready, &sources, b, buf_y0)?;
                    // drop rows every part has written
                    let keep_from = blocks
                        .iter()
                        .zip(&next)
                        .map(|(list, &n)| list.get(n).map_or(y1, |(_, bi)| bi.pixel_position.y()))
                        .min()
                        .unwrap_or(y1);
                    if keep_from > buf_y0 {
                        buf = buf.map(|b| drop_rows(b, keep_from - buf_y0));
                        buf_y0 = keep_from;
                    }
                }
                Ok(())
            };
            run().map_err(|e| {
                failure = Some(e);
                exr::error::Error::Aborted
            })
        });
        if let Some(e) = failure {
            return Err(e);
        }
        written.map_err(|e| Error::Encode {
            path: output.to_path_buf(),
            detail: describe_exr_error(e),
        })
    })
}

/// For every part and channel, where its denoised values come from (None: copied as is). A
/// channel named in `names` that the file does not have is an error naming it.
fn sources(headers: &[Header], names: &Frame, path: &Path) -> Result<Vec<Vec<Option<Source>>>> {
    let mut wanted: Vec<(String, Source)> = Vec::new();
    for (c, n) in names.color_channels.iter().enumerate() {
        wanted.push((n.clone(), (0, c)));
    }
    for (c, n) in names.denoised_channels.iter().flatten().enumerate() {
        wanted.push((n.clone(), (0, c)));
    }
    if let Some(a) = &names.alpha_channel {
        wanted.push((a.clone(), (1, 0)));
    }
    for (i, aov) in names.aovs.iter().enumerate() {
        for (c, n) in aov.channels.iter().enumerate() {
            wanted.push((n.clone(), (2 + i, c)));
        }
    }
    let mut found = vec![false; wanted.len()];
    let out = headers
        .iter()
        .map(|h| {
            let prefix = h.own_attributes.layer_name.as_ref().map(|t| t.to_string());
            h.channels
                .list
                .iter()
                .map(|ch| {
                    let full = match &prefix {
                        Some(p) => format!("{p}.{}", ch.name),
                        None => ch.name.to_string(),
                    };
                    let k = wanted.iter().position(|(n, _)| *n == full)?;
                    found[k] = true;
                    Some(wanted[k].1)
                })
                .collect()
        })
        .collect();
    if let Some(k) = found.iter().position(|f| !f) {
        return Err(Error::Decode {
            path: path.to_path_buf(),
            detail: format!(
                "it has no channel '{}' to write the result into",
                wanted[k].0
            ),
        });
    }
    Ok(out)
}

/// The input part's header for the output: denoised channels in `kind`, one resolution level,
/// blocks in increasing y (the order they are written in).
fn output_header(h: &Header, sources: &[Option<Source>], kind: Option<SampleKind>) -> Header {
    let mut list = h.channels.list.clone();
    if let Some(k) = kind {
        for (ch, src) in list.iter_mut().zip(sources) {
            if src.is_some() {
                ch.sample_type = match k {
                    SampleKind::F16 => SampleType::F16,
                    SampleKind::F32 => SampleType::F32,
                    SampleKind::U32 => SampleType::U32,
                };
            }
        }
    }
    let blocks = match h.blocks {
        BlockDescription::Tiles(t) => BlockDescription::Tiles(TileDescription {
            level_mode: LevelMode::Singular,
            ..t
        }),
        b => b,
    };
    Header {
        channels: exr::meta::attribute::ChannelList::new(list),
        ..h.clone()
    }
    .with_encoding(h.compression, blocks, LineOrder::Increasing)
}

/// Decodes the input's `ready` blocks, replaces their denoised channels with `buf`'s rows
/// (`buf` starts at frame row `buf_y0`) and writes them.
#[allow(clippy::too_many_arguments)]
fn write_blocks<W: ChunksWriter>(
    input: &Path,
    out_meta: &MetaData,
    chunks: &mut W,
    blocks: &[Vec<(usize, BlockIndex)>],
    ready: &[(usize, usize)],
    sources: &[Vec<Option<Source>>],
    buf: &Denoised,
    buf_y0: usize,
) -> Result<()> {
    if ready.is_empty() {
        return Ok(());
    }
    let decode = |e: exr::error::Error| Error::Decode {
        path: input.to_path_buf(),
        detail: describe_exr_error(e),
    };
    let wanted: std::collections::HashMap<BlockIndex, usize> = ready
        .iter()
        .map(|&(p, k)| (blocks[p][k].1, blocks[p][k].0))
        .collect();
    let file = std::fs::File::open(input).map_err(|source| Error::Open {
        path: input.to_path_buf(),
        source,
    })?;
    let reader = exr::block::read(std::io::BufReader::new(file), false).map_err(decode)?;
    let in_headers = reader.headers().to_vec();
    let filtered = reader
        .filter_chunks(false, |_, _, b| wanted.contains_key(&b))
        .map_err(decode)?;
    let planes: Vec<&Plane> = std::iter::once(&buf.color)
        .chain(buf.alpha.iter())
        .chain(buf.aovs.iter())
        .collect();
    let plane_of = |src: Source| {
        // alpha is plane 1 only when present; AOVs follow
        let (p, c) = src;
        let idx = match (p, buf.alpha.is_some()) {
            (0, _) => 0,
            (1, _) => 1,
            (q, true) => q,
            (q, false) => q - 1,
        };
        (planes[idx], c)
    };
    let mut pending: Vec<(usize, UncompressedBlock)> = Vec::new();
    filtered
        .decompress_parallel(false, |_, block| {
            let index = block.index;
            let in_h = &in_headers[index.layer];
            let out_h = &out_meta.headers[index.layer];
            let mut data =
                Vec::with_capacity(out_h.channels.bytes_per_pixel * index.pixel_size.area());
            for line in block.lines(&in_h.channels) {
                let loc = line.location;
                match sources[index.layer][loc.channel] {
                    None => data.extend_from_slice(line.value),
                    Some(src) => {
                        let (plane, c) = plane_of(src);
                        let w = plane.width();
                        let row = loc.position.y() - buf_y0;
                        let vals = &plane.channel(c)[row * w + loc.position.x()
                            ..row * w + loc.position.x() + loc.sample_count];
                        match out_h.channels.list[loc.channel].sample_type {
                            SampleType::F16 => {
                                for v in vals {
                                    data.extend_from_slice(&f16::from_f32(*v).to_ne_bytes());
                                }
                            }
                            SampleType::F32 => {
                                for v in vals {
                                    data.extend_from_slice(&v.to_ne_bytes());
                                }
                            }
                            SampleType::U32 => {
                                for v in vals {
                                    data.extend_from_slice(
                                        &(v.max(0.0).round() as u32).to_ne_bytes(),
                                    );
                                }
                            }
                        }
                    }
                }
            }
            pending.push((wanted[&index], UncompressedBlock { index, data }));
            Ok(())
        })
        .map_err(decode)?;
    if pending.len() != ready.len() {
        return Err(Error::Decode {
            path: input.to_path_buf(),
            detail: format!("{} of its blocks are missing", ready.len() - pending.len()),
        });
    }
    // each part's blocks in increasing y, as the headers promise; compressed in parallel
    pending.sort_by_key(|(i, b)| (b.index.layer, *i));
    let compressed: Vec<(usize, exr::error::Result<exr::block::chunk::Chunk>)> = pending
        .into_par_iter()
        .map(|(i, block)| (i, block.compress_to_chunk(&out_meta.headers)))
        .collect();
    for (i, chunk) in compressed {
        let chunk = chunk.map_err(|e| Error::Encode {
            path: input.to_path_buf(),
            detail: describe_exr_error(e),
        })?;
        chunks.write_chunk(i, chunk).map_err(|e| Error::Encode {
            path: input.to_path_buf(),
            detail: describe_exr_error(e),
        })?;
    }
    Ok(())
}

/// `a` with `b`'s rows appended below.
fn append_rows(a: Denoised, b: &Denoised) -> Denoised {
    let cat = |a: Plane, b: &Plane| {
        let (w, ch) = (a.width(), a.channels());
        let h = a.height() + b.height();
        let mut data = Vec::with_capacity(w * h * ch);
        for c in 0..ch {
            data.extend_from_slice(a.channel(c));
            data.extend_from_slice(b.channel(c));
        }
        Plane::from_vec(w, h, ch, data)
    };
    Denoised {
        color: cat(a.color, &b.color),
        alpha: a.alpha.zip(b.alpha.as_ref()).map(|(x, y)| cat(x, y)),
        aovs: a
            .aovs
            .into_iter()
            .zip(&b.aovs)
            .map(|(x, y)| cat(x, y))
            .collect(),
    }
}

/// `d` without its first `n` rows.
fn drop_rows(d: Denoised, n: usize) -> Denoised {
    let cut = |p: Plane| p.rows(n..p.height());
    Denoised {
        color: cut(d.color),
        alpha: d.alpha.map(cut),
        aovs: d.aovs.into_iter().map(cut).collect(),
    }
}

/// Writes denoised buffers over the input's own channels (named by `frame`, which may be any
/// band of it), keeping everything else; `kind` overrides the storage type of the denoised
/// channels.
pub fn write_result(
    mut file: ExrFile,
    frame: &Frame,
    out: &Denoised,
    path: &Path,
    kind: Option<SampleKind>,
) -> Result<()> {
    if out.color.width() != file.width() || out.color.height() != file.height() {
        return Err(Error::Incompatible {
            what: "denoised result".into(),
            a_w: out.color.width(),
            a_h: out.color.height(),
            b_w: file.width(),
            b_h: file.height(),
        });
    }
    let mut put = |name: &str, data: &[f32]| {
        if let Some(k) = kind {
            file.convert_channel(name, k);
        }
        file.set_channel(name, data, kind.unwrap_or(SampleKind::F32));
    };
    for (c, name) in frame.color_channels.iter().enumerate() {
        put(name, out.color.channel(c));
    }
    for (c, name) in frame.denoised_channels.iter().flatten().enumerate() {
        put(name, out.color.channel(c));
    }
    if let (Some(a), Some(name)) = (&out.alpha, &frame.alpha_channel) {
        put(name, a.channel(0));
    }
    for (aov, plane) in frame.aovs.iter().zip(&out.aovs) {
        for (c, name) in aov.channels.iter().enumerate() {
            put(name, plane.channel(c));
        }
    }
    file.write_atomic(path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::frame::Aov;

    #[test]
    fn band_by_band_writing_equals_writing_the_whole_frame() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in.exr");
        // a tiled half part (16×16 PIZ tiles) and a scanline float part (16-line ZIP blocks)
        crate::io::exr_file::format_tests::multipart(&input);
        let (w, h) = (40, 24);
        let mut names = Frame::synthetic(Plane::zeros(w, h, 3));
        names.color_channels = ["R", "G", "B"].map(|c| format!("beauty.{c}")).to_vec();
        names.aovs = vec![Aov {
            name: "depth".into(),
            channels: vec!["aux.Z".into()],
            plane: Plane::zeros(w, h, 1),
        }];
        let denoised = Denoised {
            color: Plane::from_fn(w, h, 3, |x, y, c| 0.01 * (x * 3 + y * 7 + c) as f32 + 0.3),
            alpha: None,
            aovs: vec![Plane::from_fn(w, h, 1, |x, y, _| {
                100.0 + (x + 40 * y) as f32 * 0.5
            })],
        };
        for kind in [None, Some(SampleKind::F32), Some(SampleKind::F16)] {
            let whole = dir.path().join("whole.exr");
            write_result(
                ExrFile::read(&input).unwrap(),
                &names,
                &denoised,
                &whole,
                kind,
            )
            .unwrap();
            // bands that cut tiles and scanline blocks in the middle
            for rows in [5usize, 16, 24] {
                let banded = dir.path().join(format!("banded{rows}.exr"));
                let mut asked = Vec::new();
                write_banded(&input, &banded, &names, kind, rows, |r| {
                    asked.push(r.clone());
                    Ok(Denoised {
                        color: denoised.color.rows(r.clone()),
                        alpha: None,
                        aovs: vec![denoised.aovs[0].rows(r)],
                    })
                })
                .unwrap();
                assert_eq!(asked.len(), h.div_ceil(rows));
                let (a, b) = (
                    ExrFile::read(&whole).unwrap(),
                    ExrFile::read(&banded).unwrap(),
                );
                assert_eq!(a.channel_names(), b.channel_names());
                for n in a.channel_names() {
                    assert_eq!(a.channel_kind(&n), b.channel_kind(&n), "{n} {kind:?}");
                    assert_eq!(a.channel_f32(&n), b.channel_f32(&n), "{n} {kind:?} {rows}");
                }
                let parts = |f: &ExrFile| format!("{:?}", f.parts());
                assert_eq!(parts(&a), parts(&b));
                assert_eq!(a.custom_attribute_names(), b.custom_attribute_names());
            }
        }
        // the denoised values really are in the file
        let b = ExrFile::read(dir.path().join("banded5.exr")).unwrap();
        assert!((b.channel_f32("aux.Z").unwrap()[41] - 120.5).abs() < 1e-3);
        // a failing band leaves no output and no temporary file behind
        let out = dir.path().join("failed.exr");
        let err = write_banded(&input, &out, &names, None, 8, |r| {
            if r.start >= 8 {
                Err(Error::Unsupported {
                    path: input.clone(),
                    detail: "band failed".into(),
                })
            } else {
                Ok(Denoised {
                    color: denoised.color.rows(r.clone()),
                    alpha: None,
                    aovs: vec![denoised.aovs[0].rows(r)],
                })
            }
        })
        .unwrap_err();
        assert!(err.to_string().contains("band failed"), "{err}");
        assert!(!out.exists());
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
            .collect();
        assert!(left.is_empty(), "{left:?}");
    }
}
