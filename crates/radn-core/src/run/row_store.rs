//! Rows of a frame kept on disk while the windows of band-by-band denoising need them.
//!
//! Band by band, each output frame reads, of each of its five window frames, only the rows its
//! bands reach; each frame belongs to five windows, so its rows are read some ten times over.
//! Decoding them from the EXR file each time (decompressing its blocks) would cost several
//! times the decoding of a whole frame. So each frame is decoded once, band by band, when it
//! first enters a window ([`FrameStore`]); its Intel Open Image Denoise guide, where the job
//! computes one, and the method's per-frame features, where it has them
//! ([`crate::run::denoiser::BandDenoiser::band_features`]), are computed once likewise and kept in
//! a [`RowStore`] each. Every band then reads back only the rows it reaches, as stored.
//! Memory follows the band, not the frame.
//!
//! A store is an anonymous temporary file (in `TMPDIR`, or the system's temporary folder):
//! the operating system removes it when the store is dropped or the process ends, killed or
//! not. Rows are stored whole and in order (every channel of every plane of row 0, then of row
//! 1, …) as f32 in the machine's byte order, so a band of rows is one contiguous read and
//! reads back bit for bit what was written.

use std::fs::File;
use std::io::{Read, Seek, SeekFrom, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::image::plane::Plane;
use crate::io::frame::{Aov, Frame};

/// Rows of planes of one size (each with its own channel count) in a temporary file (see the
/// module's documentation).
pub struct RowStore {
    file: File,
    /// The frame the rows are of, for error messages.
    frame: PathBuf,
    width: usize,
    height: usize,
    /// Channels of each plane.
    channels: Vec<usize>,
}

impl RowStore {
    /// An empty store for planes of `channels` channels each, `width` × `height`, of the
    /// frame read from `frame`.
    pub fn new(frame: &Path, width: usize, height: usize, channels: Vec<usize>) -> Result<Self> {
        let file = tempfile::tempfile().map_err(|e| scratch_error(frame, "create", e))?;
        Ok(Self {
            file,
            frame: frame.to_path_buf(),
            width,
            height,
            channels,
        })
    }

    /// Values in one row of every channel of every plane.
    fn row_len(&self) -> usize {
        self.width * self.channels.iter().sum::<usize>()
    }

    /// Stores `planes` (one per plane of the store, all of one height) as the frame's rows
    /// `y0..y0 + height`.
    ///
    /// # Panics
    /// When the planes differ from the store's in number, width or channels, or reach past
    /// the frame.
    pub fn write_rows(&self, y0: usize, planes: &[&Plane]) -> Result<()> {
        assert_eq!(
            planes.len(),
            self.channels.len(),
            "row store: one plane each"
        );
        let h = planes.first().map_or(0, |p| p.height());
        for (p, &c) in planes.iter().zip(&self.channels) {
            assert!(
                p.width() == self.width && p.channels() == c && p.height() == h,
                "row store: a {}×{} plane of {} channels written to planes of {}×{h} with {c}",
                p.width(),
                p.height(),
                p.channels(),
                self.width
            );
        }
        assert!(y0 + h <= self.height, "row store: rows past the frame");
        let w = self.width;
        let mut values = Vec::with_capacity(h * self.row_len());
        for y in 0..h {
            for p in planes {
                for c in 0..p.channels() {
                    values.extend_from_slice(&p.channel(c)[y * w..(y + 1) * w]);
                }
            }
        }
        let mut file = &self.file;
        file.seek(SeekFrom::Start((y0 * self.row_len() * 4) as u64))
            .and_then(|_| file.write_all(bytemuck::cast_slice(&values)))
            .map_err(|e| scratch_error(&self.frame, "write", e))
    }

    /// The frame's rows `rows` of every plane, as they were written.
    ///
    /// # Panics
    /// When `rows` reaches past the frame.
    pub fn read_rows(&self, rows: Range<usize>) -> Result<Vec<Plane>> {
        assert!(rows.end <= self.height, "row store: rows past the frame");
        let (w, h) = (self.width, rows.len());
        let mut values = vec![0f32; h * self.row_len()];
        let mut file = &self.file;
        file.seek(SeekFrom::Start((rows.start * self.row_len() * 4) as u64))
            .and_then(|_| file.read_exact(bytemuck::cast_slice_mut(&mut values)))
            .map_err(|e| scratch_error(&self.frame, "read", e))?;
        let mut planes: Vec<Plane> = self
            .channels
            .iter()
            .map(|&c| Plane::zeros(w, h, c))
            .collect();
        let mut rows_in = values.chunks_exact(w);
        for y in 0..h {
            for p in planes.iter_mut() {
                for c in 0..p.channels() {
                    let src = rows_in
                        .next()
                        .expect("one chunk per row, plane and channel");
                    p.channel_mut(c)[y * w..(y + 1) * w].copy_from_slice(src);
                }
            }
        }
        Ok(planes)
    }
}

/// The error of a failed `what` (create, write, read) on a scratch file of `frame`'s rows.
fn scratch_error(frame: &Path, what: &str, source: std::io::Error) -> Error {
    Error::Scratch {
        path: frame.to_path_buf(),
        detail: format!(
            "cannot {what} the temporary file that keeps its decoded rows between windows in \
             '{}' (TMPDIR sets the folder; it needs room for six decoded frames)",
            std::env::temp_dir().display()
        ),
        source,
    }
}

/// A frame's decoded planes (beauty, alpha, albedo, normal, depth, motion, a guide layer and
/// AOVs, as the reader gave them, repaired samples included) kept on disk band by band: see
/// the module's documentation. Features are not kept here, nor guides the job computes: the
/// job attaches them.
pub struct FrameStore {
    rows: RowStore,
    /// The frame with no rows: which planes it has, their names and channels.
    template: Frame,
}

impl FrameStore {
    /// An empty store for a frame `height` rows tall whose planes are those of `band`, a band
    /// of it.
    pub fn new(band: &Frame, height: usize) -> Result<Self> {
        let channels = planes(band).iter().map(|p| p.channels()).collect();
        let mut template = band.rows(0..0);
        template.features = None;
        template.repaired = 0;
        Ok(Self {
            rows: RowStore::new(&band.path, band.width(), height, channels)?,
            template,
        })
    }

    /// Stores `band` as the frame's rows `y0..y0 + band.height()`.
    pub fn write(&self, y0: usize, band: &Frame) -> Result<()> {
        self.rows.write_rows(y0, &planes(band))
    }

    /// The frame's rows `rows`, as [`crate::io::frame::FrameReader::read_rows`] read them (its
    /// count of repaired samples is the statistics pass's, not repeated here: 0).
    pub fn read(&self, rows: Range<usize>) -> Result<Frame> {
        let mut stored = self.rows.read_rows(rows)?.into_iter();
        let mut next = || stored.next().expect("one plane per plane of the frame");
        let t = &self.template;
        let mut take = |p: &Option<Plane>| p.as_ref().map(|_| next());
        let (alpha, albedo, normal, depth, motion_prev, motion_next, guide, variance) = (
            take(&t.alpha),
            take(&t.albedo),
            take(&t.normal),
            take(&t.depth),
            take(&t.motion_prev),
            take(&t.motion_next),
            take(&t.guide),
            take(&t.variance),
        );
        let mut frame = t.clone();
        frame.alpha = alpha;
        frame.albedo = albedo;
        frame.normal = normal;
        frame.depth = depth;
        frame.motion_prev = motion_prev;
        frame.motion_next = motion_next;
        frame.guide = guide;
        frame.variance = variance;
        frame.color = next();
        frame.aovs = t
            .aovs
            .iter()
            .map(|a| Aov {
                name: a.name.clone(),
                channels: a.channels.clone(),
                plane: next(),
            })
            .collect();
        Ok(frame)
    }
}

/// The planes of `frame` a [`FrameStore`] keeps, in its order: alpha, albedo, normal, depth,
/// the motion fields, the guide and the variance (those it has), the beauty, then the AOVs.
fn planes(frame: &Frame) -> Vec<&Plane> {
    let optional = [
        &frame.alpha,
        &frame.albedo,
        &frame.normal,
        &frame.depth,
        &frame.motion_prev,
        &frame.motion_next,
        &frame.guide,
        &frame.variance,
    ];
    let mut out: Vec<&Plane> = optional.iter().filter_map(|p| p.as_ref()).collect();
    out.push(&frame.color);
    out.extend(frame.aovs.iter().map(|a| &a.plane));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pattern(w: usize, h: usize, c: usize, seed: f32) -> Plane {
        Plane::from_fn(w, h, c, |x, y, ch| {
            (x as f32 * 0.37 - y as f32 * 1.9 + ch as f32 * 11.0 + seed).sin() * 1e3
        })
    }

    #[test]
    fn rows_read_back_exactly_as_written_in_any_order_of_bands() {
        let (w, h) = (7, 23);
        let (a, b) = (pattern(w, h, 3, 0.0), pattern(w, h, 1, 5.0));
        let store = RowStore::new(Path::new("frame_0001.exr"), w, h, vec![3, 1]).unwrap();
        // bands written out of order, the last one short
        for y0 in [10, 0, 20, 5, 15] {
            let rows = y0..(y0 + 5).min(h);
            store
                .write_rows(y0, &[&a.rows(rows.clone()), &b.rows(rows)])
                .unwrap();
        }
        for rows in [0..h, 3..9, 0..1, 22..23, 4..21] {
            let got = store.read_rows(rows.clone()).unwrap();
            assert_eq!(got[0].data(), a.rows(rows.clone()).data());
            assert_eq!(got[1].data(), b.rows(rows).data());
        }
    }

    #[test]
    fn reading_rows_never_written_names_the_frame() {
        let store = RowStore::new(Path::new("shot/frame_0042.exr"), 4, 10, vec![2]).unwrap();
        store.write_rows(0, &[&Plane::zeros(4, 3, 2)]).unwrap();
        let err = store.read_rows(2..8).unwrap_err().to_string();
        assert!(
            err.contains("shot/frame_0042.exr") && err.contains("cannot read"),
            "{err}"
        );
    }

    #[test]
    fn a_frame_stored_band_by_band_reads_back_as_its_rows() {
        let (w, h) = (9, 17);
        let mut frame = Frame::synthetic(pattern(w, h, 3, 1.0));
        frame.path = "shot/frame_0007.exr".into();
        frame.albedo = Some(pattern(w, h, 3, 2.0));
        frame.depth = Some(pattern(w, h, 1, 3.0));
        frame.motion_next = Some(pattern(w, h, 2, 4.0));
        frame.guide = Some(pattern(w, h, 3, 6.0));
        frame.aovs = vec![Aov {
            name: "diffuse".into(),
            channels: vec!["d.R".into(), "d.G".into(), "d.B".into()],
            plane: pattern(w, h, 3, 5.0),
        }];
        frame.color_channels = vec!["c.R".into(), "c.G".into(), "c.B".into()];
        let store = FrameStore::new(&frame.rows(0..4), h).unwrap();
        for y0 in (0..h).step_by(4) {
            store.write(y0, &frame.rows(y0..(y0 + 4).min(h))).unwrap();
        }
        let want = frame.rows(5..16);
        let got = store.read(5..16).unwrap();
        assert_eq!(got.path, want.path);
        assert_eq!(got.color_channels, want.color_channels);
        assert_eq!(got.color.data(), want.color.data());
        let data = |p: &Option<Plane>| p.as_ref().map(|p| p.data().to_vec());
        assert_eq!(data(&got.albedo), data(&want.albedo));
        assert_eq!(data(&got.depth), data(&want.depth));
        assert_eq!(data(&got.motion_next), data(&want.motion_next));
        assert_eq!(data(&got.guide), data(&want.guide));
        assert!(got.normal.is_none() && got.motion_prev.is_none() && got.alpha.is_none());
        assert_eq!(got.aovs.len(), 1);
        assert_eq!(got.aovs[0].name, "diffuse");
        assert_eq!(got.aovs[0].channels, want.aovs[0].channels);
        assert_eq!(got.aovs[0].plane.data(), want.aovs[0].plane.data());
    }
}
