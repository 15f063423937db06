//! Reading windows of a sequence: the 2r+1 frames around each centre frame, every frame
//! decoded once while the windows in flight need it and checked against the sequence's size,
//! ready to be aligned onto the centre ([`crate::align`]).

use std::collections::BTreeMap;
use std::path::PathBuf;

use crate::align::estimate::MotionSignal;
use crate::align::{align_window, window_indices, AlignParams, AlignedWindow};
use crate::error::Result;
use crate::guide::JobGuides;
use crate::io::exr_file::ExrFile;
use crate::io::frame::{Frame, FrameReader};
use crate::run::motion::{MotionSource, SequenceMotion, Vectors};

/// A file's name for the log.
fn file_name(path: &std::path::Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// Decoded frames of a sequence, read window by window in increasing order of the centre:
/// a frame is decoded the first time a window reaches it and forgotten once no later window
/// can, so memory holds one window's frames (and the reach beyond it that a caller asks for).
pub struct WindowReader<'a> {
    reader: &'a FrameReader,
    files: &'a [PathBuf],
    radius: usize,
    keep_files: bool,
    guides: JobGuides,
    rendered: Option<&'a [PathBuf]>,
    frames: BTreeMap<usize, (Frame, Option<ExrFile>)>,
    size: Option<(usize, usize)>,
    repaired: usize,
    motion: Option<SequenceMotion>,
    transform: Option<&'a FrameTransform<'a>>,
}

/// A change made to every frame as it is decoded, before its guide and motion (e.g. its
/// auxiliaries replaced by cleaned ones); its error names the frame.
pub type FrameTransform<'a> = dyn Fn(&mut Frame) -> Result<()> + Sync + 'a;

impl<'a> WindowReader<'a> {
    /// Windows of `radius` frames on each side over the sequence `files`, read by `reader`.
    pub fn new(reader: &'a FrameReader, files: &'a [PathBuf], radius: usize) -> Self {
        Self {
            reader,
            files,
            radius,
            keep_files: false,
            guides: JobGuides::FromReader,
            rendered: None,
            frames: BTreeMap::new(),
            size: None,
            repaired: 0,
            motion: None,
            transform: None,
        }
    }

    /// Runs `transform` on each frame as it is decoded, before its guide is computed and its
    /// motion estimated.
    pub fn with_transform(mut self, transform: &'a FrameTransform<'a>) -> Self {
        self.transform = Some(transform);
        self
    }

    /// Aligns with `motion`'s source: the renderer's vectors, or motion estimated from the
    /// frames as they are decoded (then windows also end at the cuts it finds).
    pub fn with_motion(mut self, motion: SequenceMotion) -> Self {
        self.motion = Some(motion);
        self
    }

    /// The sequence's motion, where it is chosen ([`WindowReader::with_motion`]).
    pub fn motion(&self) -> Option<&SequenceMotion> {
        self.motion.as_ref()
    }

    /// Also keeps each frame's decoded file (every part and layer), so a result can be
    /// written into a copy of it ([`WindowReader::take_file`]).
    pub fn keeping_files(mut self) -> Self {
        self.keep_files = true;
        self
    }

    /// Attaches each frame's guide as it is decoded, where `guides` computes them (the
    /// reader's own guide layer is read with the frame in any case).
    pub fn with_guides(mut self, guides: JobGuides) -> Self {
        self.guides = guides;
        self
    }

    /// Attaches each frame's beauty as rendered ([`Frame::rendered`]) as it is decoded, from
    /// `originals` (one per file, in order): the file itself where it is its own original,
    /// else the original decoded once more.
    pub fn with_rendered(mut self, originals: &'a [PathBuf]) -> Self {
        self.rendered = Some(originals);
        self
    }

    /// Frames in the sequence.
    pub fn len(&self) -> usize {
        self.files.len()
    }

    /// Whether the sequence has no frames.
    pub fn is_empty(&self) -> bool {
        self.files.is_empty()
    }

    /// NaN/Inf samples repaired in the frames decoded so far.
    pub fn repaired(&self) -> usize {
        self.repaired
    }

    /// Decodes every frame within `reach` positions of `pos` that is not decoded yet, after
    /// forgetting those further before `pos` (centres must come in increasing order). Every
    /// frame must have the size of the first one decoded.
    pub fn load(&mut self, pos: usize, reach: usize) -> Result<()> {
        self.frames.retain(|&k, _| k + reach >= pos);
        if let Some(m) = &mut self.motion {
            m.forget_before(pos.saturating_sub(reach));
        }
        for k in pos.saturating_sub(reach)..(pos + reach + 1).min(self.files.len()) {
            if let std::collections::btree_map::Entry::Vacant(e) = self.frames.entry(k) {
                let (mut frame, file) =
                    super::timing::timed("decoding", || self.reader.read(&self.files[k]))?;
                let (w, h) = *self.size.get_or_insert((frame.width(), frame.height()));
                frame.ensure_size(w, h)?;
                if let Some(t) = self.transform {
                    t(&mut frame)?;
                }
                if let JobGuides::Oidn { guides, originals } = &self.guides {
                    let original = &originals[k];
                    frame.guide = Some(if *original == self.files[k] {
                        guides.of_frame(&frame, original)?
                    } else {
                        guides.of_file(self.reader, original)?
                    });
                }
                if let Some(originals) = self.rendered {
                    let original = &originals[k];
                    frame.rendered = Some(if *original == self.files[k] {
                        frame.color.clone()
                    } else {
                        let (rendered, _) = self.reader.read(original)?;
                        rendered.ensure_size(w, h)?;
                        rendered.color
                    });
                }
                self.repaired += frame.repaired;
                let mut estimated = false;
                if let Some(m) = &mut self.motion {
                    let vectors = Vectors::of(&frame);
                    if m.decide(vectors, &self.files[k])? != MotionSource::Renderer {
                        frame.motion_prev = None;
                        frame.motion_next = None;
                        let signal = super::timing::timed("motion estimation", || {
                            MotionSignal::of_frame(&frame, m.params())
                        });
                        let files = self.files;
                        m.add_signal(k, signal, |i| file_name(&files[i]));
                        estimated = true;
                    } else if m.lacks_vectors(vectors) {
                        return Err(self.reader.missing_motion(&self.files[k]));
                    }
                }
                e.insert((frame, self.keep_files.then_some(file)));
                if estimated {
                    self.attach_motion(k);
                    if k > 0 && self.frames.contains_key(&(k - 1)) {
                        self.attach_motion(k - 1);
                    }
                }
            }
        }
        Ok(())
    }

    /// Sets the estimated motion of loaded frame `k` (towards the neighbours estimated so far).
    fn attach_motion(&mut self, k: usize) {
        let (Some(m), Some((frame, _))) = (&self.motion, self.frames.get_mut(&k)) else {
            return;
        };
        let h = frame.height();
        m.attach(k, frame, 0..h);
    }

    /// The decoded frame at `pos`, if it is loaded.
    pub fn get(&self, pos: usize) -> Option<&Frame> {
        self.frames.get(&pos).map(|(f, _)| f)
    }

    /// The decoded frame at `pos`, which must be loaded.
    pub fn frame(&self, pos: usize) -> &Frame {
        self.get(pos)
            .unwrap_or_else(|| panic!("frame {pos} is read before it is used"))
    }

    /// The decoded frame at `pos`, which must be loaded, to attach what a method computes from
    /// it once ([`crate::run::denoiser::WindowDenoiser::frame_features`]).
    pub fn frame_mut(&mut self, pos: usize) -> &mut Frame {
        self.frames
            .get_mut(&pos)
            .map(|(f, _)| f)
            .unwrap_or_else(|| panic!("frame {pos} is read before it is used"))
    }

    /// Hands over the decoded file of the frame at `pos` (once; with
    /// [`WindowReader::keeping_files`]).
    pub fn take_file(&mut self, pos: usize) -> Option<ExrFile> {
        self.frames.get_mut(&pos).and_then(|(_, file)| file.take())
    }

    /// The sequence positions of the window around `pos` (`None` beyond either end).
    pub fn indices(&self, pos: usize) -> Vec<Option<usize>> {
        let mut idx = window_indices(pos, self.files.len(), self.radius);
        if let Some(m) = &self.motion {
            m.cut_window(&mut idx);
        }
        idx
    }

    /// The loaded frames of the window around `pos` (`None` beyond the sequence ends).
    pub fn window(&self, pos: usize) -> Vec<Option<&Frame>> {
        self.indices(pos)
            .iter()
            .map(|i| i.map(|i| self.frame(i)))
            .collect()
    }

    /// Reads the window around `pos` and returns its frames.
    pub fn read(&mut self, pos: usize) -> Result<Vec<Option<&Frame>>> {
        self.load(pos, self.radius)?;
        Ok(self.window(pos))
    }

    /// Reads the window around `pos` and aligns it onto its centre.
    pub fn aligned(&mut self, pos: usize, params: &AlignParams) -> Result<AlignedWindow> {
        Ok(align_window(&self.read(pos)?, params))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::plane::Plane;
    use crate::io::frame::Requirements;
    use crate::io::mapping::ChannelMapping;

    fn sequence(dir: &std::path::Path, sizes: &[(usize, usize)]) -> Vec<PathBuf> {
        sizes
            .iter()
            .enumerate()
            .map(|(i, &(w, h))| {
                let p = dir.join(format!("f{i}.exr"));
                let v = |c: usize| Plane::from_fn(w, h, 1, |x, y, _| (i * 100 + x + y + c) as f32);
                let channels = ["R", "G", "B"]
                    .iter()
                    .enumerate()
                    .map(|(c, n)| (n.to_string(), v(c).channel(0).to_vec()))
                    .collect();
                ExrFile::from_channels(&p, w, h, channels, crate::io::exr_file::SampleKind::F32)
                    .write_atomic(&p)
                    .unwrap();
                p
            })
            .collect()
    }

    #[test]
    fn windows_hold_their_frames_in_order_and_forget_what_no_later_window_needs() {
        let d = tempfile::tempdir().unwrap();
        let files = sequence(d.path(), &[(6, 4); 5]);
        let reader = FrameReader::new(
            ChannelMapping::builtin("generic").unwrap(),
            Requirements::COLOR_ONLY,
        );
        let mut wr = WindowReader::new(&reader, &files, 1);
        let first = wr.read(0).unwrap();
        assert!(first[0].is_none());
        assert_eq!(first[1].unwrap().color.get(0, 0, 0), 0.0);
        assert_eq!(first[2].unwrap().color.get(0, 0, 0), 100.0);
        let w3: Vec<f32> = wr
            .read(3)
            .unwrap()
            .iter()
            .map(|f| f.unwrap().color.get(0, 0, 0))
            .collect();
        assert_eq!(w3, vec![200.0, 300.0, 400.0]);
        assert!(wr.get(0).is_none() && wr.get(1).is_none() && wr.get(2).is_some());
        assert!(
            wr.take_file(3).is_none(),
            "files are kept only when asked for"
        );
        let last = wr.read(4).unwrap();
        assert!(last[2].is_none() && last[1].unwrap().color.get(0, 0, 0) == 400.0);
    }

    #[test]
    fn a_frame_of_another_size_is_an_error_naming_it() {
        let d = tempfile::tempdir().unwrap();
        let files = sequence(d.path(), &[(6, 4), (6, 4), (5, 4)]);
        let reader = FrameReader::new(
            ChannelMapping::builtin("generic").unwrap(),
            Requirements::COLOR_ONLY,
        );
        let mut wr = WindowReader::new(&reader, &files, 1).keeping_files();
        wr.load(0, 1).unwrap();
        assert!(wr.take_file(0).is_some() && wr.take_file(0).is_none());
        let e = wr.read(1).map(|_| ()).unwrap_err().to_string();
        assert!(e.contains("f2.exr"), "{e}");
    }
}
