//! One whole-frame denoising pass swept over a sequence, a centre at a time in increasing
//! order: each frame decoded once while the windows in flight need it, given its per-frame
//! features and prepared where the method asks for that, then the window denoised. Both the
//! sequence job ([`crate::run::job`]) and the fused temporal pass ([`crate::run::fused`]) drive
//! it; what happens to each result is theirs.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use crate::align::estimate::EstimateParams;
use crate::error::Result;
use crate::guide::JobGuides;
use crate::io::exr_file::ExrFile;
use crate::io::frame::{Frame, FrameReader};
use crate::post::variance_check::{apply_scale, frame_scale};
use crate::run::denoiser::{Denoised, WindowDenoiser};
use crate::run::motion::{MotionChoice, SequenceMotion};
use crate::run::window::WindowReader;

/// A method's pass over a sequence's frames, whole frame by whole frame.
pub struct WindowSweep<'a> {
    method: &'a dyn WindowDenoiser,
    windows: WindowReader<'a>,
    prepared: BTreeMap<usize, Frame>,
}

/// Where one window's time went.
#[derive(Clone, Copy, Debug, Default)]
pub struct SweepTimes {
    /// Decoding the frames new to the window (with their guides).
    pub decoding: Duration,
    /// Their per-frame features and preparation.
    pub preparing: Duration,
    /// The method on the window.
    pub denoising: Duration,
}

impl<'a> WindowSweep<'a> {
    /// A sweep of `method` over `files`, read by `reader`, each frame's decoded file kept for
    /// writing into, with `guides` attached and, where given, each frame as rendered from
    /// `rendered`; windows aligned with the motion `motion` chooses.
    pub fn new(
        method: &'a dyn WindowDenoiser,
        reader: &'a FrameReader,
        files: &'a [PathBuf],
        guides: JobGuides,
        rendered: Option<&'a [PathBuf]>,
        motion: MotionChoice,
    ) -> Self {
        let mut windows = WindowReader::new(reader, files, method.radius())
            .keeping_files()
            .with_guides(guides);
        if method.radius() > 0 {
            windows = windows.with_motion(SequenceMotion::new(motion, EstimateParams::default()));
        }
        if method.needs_rendered() {
            windows = windows.with_rendered(rendered.unwrap_or(files));
        }
        Self {
            method,
            windows,
            prepared: BTreeMap::new(),
        }
    }

    /// Denoises the window around `pos` (centres in increasing order).
    pub fn denoise(&mut self, pos: usize) -> Result<(Denoised, SweepTimes)> {
        let method = self.method;
        let n = self.windows.len();
        let r = method.radius();
        let reach = if method.prepare_needs_neighbours() {
            r + 1
        } else {
            r
        };
        let mut times = SweepTimes::default();
        // decode what this window needs, once
        let started = Instant::now();
        self.windows.load(pos, reach)?;
        times.decoding = started.elapsed();
        let preparing = Instant::now();
        if method.has_frame_features() {
            for k in pos.saturating_sub(r)..(pos + r + 1).min(n) {
                if self.windows.frame(k).features.is_none() {
                    let features = method.frame_features(self.windows.frame(k));
                    self.windows.frame_mut(k).features = features;
                }
            }
        }
        let prepares = method.prepares_frames();
        if prepares {
            self.prepared.retain(|&k, _| k + r >= pos);
            for k in pos.saturating_sub(r)..(pos + r + 1).min(n) {
                if let std::collections::btree_map::Entry::Vacant(e) = self.prepared.entry(k) {
                    let mut f = self.windows.frame(k).clone();
                    let prev = k.checked_sub(1).and_then(|j| self.windows.get(j));
                    let next = self.windows.get(k + 1);
                    method.prepare(&mut f, prev, next);
                    e.insert(f);
                }
            }
        }
        // the centre's variance channels, checked against its neighbours (a window reads only
        // its centre's), scaled for this window alone: the next centre is checked against this
        // frame as it was decoded
        let centre = self.windows.frame(pos);
        let prev = pos.checked_sub(1).and_then(|j| self.windows.get(j));
        let scale = centre
            .variance
            .as_ref()
            .and_then(|_| frame_scale(centre, prev, self.windows.get(pos + 1)));
        let decoded_variance = scale.and_then(|s| {
            tracing::debug!("frame {pos}: variance channels scaled by {s:.4} (checked)");
            if let Some(f) = self.prepared.get_mut(&pos) {
                apply_scale(f, s);
            }
            let f = self.windows.frame_mut(pos);
            let decoded = f.variance.clone();
            apply_scale(f, s);
            decoded
        });
        times.preparing = preparing.elapsed();
        let denoising = Instant::now();
        let out = if prepares {
            let window: Vec<Option<&Frame>> = self
                .windows
                .indices(pos)
                .iter()
                .map(|i| i.map(|i| &self.prepared[&i]))
                .collect();
            method.denoise(&window)?
        } else {
            method.denoise(&self.windows.window(pos))?
        };
        times.denoising = denoising.elapsed();
        if let Some(v) = decoded_variance {
            self.windows.frame_mut(pos).variance = Some(v);
        }
        Ok((out, times))
    }

    /// The decoded frame at `pos` (loaded by the last [`WindowSweep::denoise`] around it).
    pub fn frame(&self, pos: usize) -> &Frame {
        self.windows.frame(pos)
    }

    /// Hands over the decoded file of the frame at `pos` (once).
    pub fn take_file(&mut self, pos: usize) -> Option<ExrFile> {
        self.windows.take_file(pos)
    }

    /// NaN/Inf samples repaired in the frames decoded so far.
    pub fn repaired(&self) -> usize {
        self.windows.repaired()
    }

    /// The cuts found so far (positions of the frames before them).
    pub fn cuts(&self) -> impl Iterator<Item = usize> + '_ {
        self.windows.motion().into_iter().flat_map(|m| m.cuts())
    }
}
