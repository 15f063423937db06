//! Where a sequence's motion comes from: the renderer's vectors, or motion estimated from the
//! frames ([`crate::align::estimate`]) when the files have none or the user asks for it; and
//! the cuts found between neighbouring frames, which no window reaches across.

use std::collections::{BTreeMap, BTreeSet};
use std::ops::Range;
use std::path::Path;

use crate::align::estimate::{EstimateParams, MotionSignal, PairMotion};
use crate::error::{Error, Result};
use crate::io::frame::Frame;
use crate::run::banding::MotionReach;

/// Which motion a sequence is aligned with.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MotionChoice {
    /// The renderer's vectors where the files have them, else estimated.
    #[default]
    Auto,
    /// The renderer's vectors only (a file without them is an error).
    Renderer,
    /// Estimated from the frames, whatever the files hold.
    Estimate,
}

impl std::str::FromStr for MotionChoice {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "auto" => Ok(Self::Auto),
            "renderer" => Ok(Self::Renderer),
            "estimate" => Ok(Self::Estimate),
            _ => Err(format!("'{s}': use auto, renderer or estimate")),
        }
    }
}

/// What a frame's file holds of the renderer's motion.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Vectors {
    /// No motion channels.
    Missing,
    /// Motion channels holding only zeros: what Cycles writes with motion blur on.
    Zero,
    /// Motion.
    Present,
}

impl Vectors {
    /// What `frame` (a whole frame) holds.
    pub fn of(frame: &Frame) -> Self {
        Self::Missing.and(frame)
    }

    /// This, with the rows of `band` of the same frame seen too.
    pub fn and(self, band: &Frame) -> Self {
        let planes = [&band.motion_prev, &band.motion_next];
        if self == Self::Present
            || planes
                .iter()
                .flat_map(|p| p.iter())
                .any(|p| p.data().iter().any(|v| *v != 0.0))
        {
            Self::Present
        } else if self == Self::Zero || planes.iter().any(|p| p.is_some()) {
            Self::Zero
        } else {
            Self::Missing
        }
    }
}

/// The motion source a sequence ended up with (said once per run).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MotionSource {
    /// The renderer's vectors.
    Renderer,
    /// Estimated, as asked for.
    Estimated,
    /// Estimated because the files have no motion vectors.
    EstimatedWithoutVectors,
    /// Estimated because the files' vectors are all zero (Cycles with motion blur on).
    EstimatedOverZeroVectors,
}

impl MotionSource {
    /// The one-line message naming the source.
    pub fn message(self) -> &'static str {
        match self {
            Self::Renderer => "motion: the renderer's vectors",
            Self::Estimated => "motion: estimated from the frames (--motion estimate)",
            Self::EstimatedWithoutVectors => {
                "motion: estimated from the frames (the files have no motion vectors)"
            }
            Self::EstimatedOverZeroVectors => {
                "motion: estimated from the frames (the files' motion vectors are all zero, as \
                 Cycles writes them with motion blur on)"
            }
        }
    }
}

/// A sequence's motion while it is swept in increasing order: the source, and, when motion is
/// estimated, each decoded frame's signal and the motion of each neighbouring pair, kept while
/// the windows in flight need them.
#[derive(Debug)]
pub struct SequenceMotion {
    choice: MotionChoice,
    params: EstimateParams,
    source: Option<MotionSource>,
    signals: BTreeMap<usize, MotionSignal>,
    /// Keyed by the pair's earlier frame.
    pairs: BTreeMap<usize, PairMotion>,
    /// Earlier frames of the pairs found to be two shots, over the whole run.
    cuts: BTreeSet<usize>,
}

impl SequenceMotion {
    /// Motion as `choice` says, estimated with `params` where it is.
    pub fn new(choice: MotionChoice, params: EstimateParams) -> Self {
        Self {
            choice,
            params,
            source: None,
            signals: BTreeMap::new(),
            pairs: BTreeMap::new(),
            cuts: BTreeSet::new(),
        }
    }

    /// The source once decided.
    pub fn source(&self) -> Option<MotionSource> {
        self.source
    }

    /// The source, decided on the first frame decoded (holding `vectors`, read from `path`)
    /// and said once in the log.
    pub fn decide(&mut self, vectors: Vectors, path: &Path) -> Result<MotionSource> {
        if let Some(s) = self.source {
            return Ok(s);
        }
        let source = match (self.choice, vectors) {
            (MotionChoice::Estimate, _) => MotionSource::Estimated,
            (MotionChoice::Renderer, Vectors::Present | Vectors::Zero)
            | (MotionChoice::Auto, Vectors::Present) => MotionSource::Renderer,
            (MotionChoice::Auto, Vectors::Zero) => MotionSource::EstimatedOverZeroVectors,
            (MotionChoice::Auto, Vectors::Missing) => MotionSource::EstimatedWithoutVectors,
            (MotionChoice::Renderer, Vectors::Missing) => {
                return Err(Error::Unsupported {
                    path: path.to_path_buf(),
                    detail: "it has no motion vectors, and --motion renderer uses only the \
                             renderer's (use --motion auto to estimate motion from the frames)"
                        .into(),
                })
            }
        };
        tracing::info!("{}", source.message());
        self.source = Some(source);
        Ok(source)
    }

    /// Whether a frame holding `vectors` lacks what the sequence is aligned with: its first
    /// frame had the renderer's vectors, this one has no motion channels.
    pub fn lacks_vectors(&self, vectors: Vectors) -> bool {
        self.source == Some(MotionSource::Renderer) && vectors == Vectors::Missing
    }

    /// Whether motion is estimated (once decided).
    pub fn estimating(&self) -> bool {
        self.source.is_some_and(|s| s != MotionSource::Renderer)
    }

    /// The settings of estimation.
    pub fn params(&self) -> &EstimateParams {
        &self.params
    }

    /// Takes frame `k`'s signal and estimates its motion with the neighbours whose signals are
    /// here; a pair that is two shots gets no motion and is a cut from then on. `name` names
    /// a frame in the log.
    pub fn add_signal(&mut self, k: usize, signal: MotionSignal, name: impl Fn(usize) -> String) {
        self.signals.insert(k, signal);
        for a in [k.checked_sub(1), Some(k)].into_iter().flatten() {
            if self.pairs.contains_key(&a) || self.cuts.contains(&a) {
                continue;
            }
            let (Some(sa), Some(sb)) = (self.signals.get(&a), self.signals.get(&(a + 1))) else {
                continue;
            };
            let pair = crate::run::timing::timed("motion estimation", || {
                PairMotion::estimate(sa, sb, &self.params)
            });
            if pair.same_shot(&self.params) {
                tracing::debug!(
                    "{} → {}: {:.0}% of pixels matched",
                    name(a),
                    name(a + 1),
                    100.0 * pair.matched
                );
                self.pairs.insert(a, pair);
            } else {
                tracing::info!(
                    "cut between {} and {} ({:.0}% of pixels matched): no window reaches across it",
                    name(a),
                    name(a + 1),
                    100.0 * pair.matched
                );
                self.cuts.insert(a);
            }
        }
    }

    /// Sets frame `k`'s estimated motion for its rows `rows` (`frame` holds those rows):
    /// towards each neighbour it was estimated with, none across a cut or where the neighbour
    /// is not decoded yet.
    pub fn attach(&self, k: usize, frame: &mut Frame, rows: Range<usize>) {
        frame.motion_prev = k
            .checked_sub(1)
            .and_then(|j| self.pairs.get(&j))
            .map(|p| p.rows(false, rows.clone()));
        frame.motion_next = self.pairs.get(&k).map(|p| p.rows(true, rows));
    }

    /// How far frame `k`'s estimated motion reaches, in rows.
    pub fn reach(&self, k: usize) -> MotionReach {
        let r = |p: Option<&PairMotion>, forward: bool| {
            p.map_or(0, |p| {
                let flow = if forward { &p.forward } else { &p.backward };
                let most = flow.channel(1).iter().fold(0f32, |m, v| m.max(v.abs()));
                (most * p.factor as f32).ceil() as usize + p.factor
            })
        };
        MotionReach {
            prev: r(k.checked_sub(1).and_then(|j| self.pairs.get(&j)), false),
            next: r(self.pairs.get(&k), true),
        }
    }

    /// Whether a cut lies between frames `k` and `k + 1`.
    pub fn cut_after(&self, k: usize) -> bool {
        self.cuts.contains(&k)
    }

    /// Every cut found so far, by the pair's earlier frame.
    pub fn cuts(&self) -> impl Iterator<Item = usize> + '_ {
        self.cuts.iter().copied()
    }

    /// A window's sequence positions (`None` beyond the sequence) with every position beyond
    /// a cut, seen from the centre, made `None` too: to the window, a cut is an end of the
    /// sequence.
    pub fn cut_window(&self, indices: &mut [Option<usize>]) {
        let r = indices.len() / 2;
        for dir in [-1isize, 1] {
            let mut cut = false;
            for step in 1..=r {
                let i = (r as isize + dir * step as isize) as usize;
                let nearer = (r as isize + dir * (step as isize - 1)) as usize;
                if let (Some(a), Some(b)) = (indices[nearer], indices[i]) {
                    cut |= self.cut_after(a.min(b));
                }
                if cut {
                    indices[i] = None;
                }
            }
        }
    }

    /// Forgets the signals and pairs of frames before `k` (cuts are kept).
    pub fn forget_before(&mut self, k: usize) {
        self.signals.retain(|&j, _| j >= k);
        self.pairs.retain(|&j, _| j >= k);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::plane::Plane;

    #[test]
    fn a_cut_ends_the_window_on_its_side() {
        let mut m = SequenceMotion::new(MotionChoice::Estimate, EstimateParams::default());
        m.cuts.insert(4);
        let mut w = vec![Some(5), Some(6), Some(7), Some(8), Some(9)];
        m.cut_window(&mut w);
        assert_eq!(w, vec![Some(5), Some(6), Some(7), Some(8), Some(9)]);
        let mut w = vec![Some(3), Some(4), Some(5), Some(6), Some(7)];
        m.cut_window(&mut w);
        assert_eq!(w, vec![None, None, Some(5), Some(6), Some(7)]);
        let mut w = vec![Some(2), Some(3), Some(4), Some(5), Some(6)];
        m.cut_window(&mut w);
        assert_eq!(w, vec![Some(2), Some(3), Some(4), None, None]);
        let mut w = vec![Some(4), Some(5), Some(6), Some(7), None];
        m.cut_window(&mut w);
        assert_eq!(w, vec![None, Some(5), Some(6), Some(7), None]);
    }

    #[test]
    fn the_source_is_decided_once_from_the_first_frame() {
        let plain = Frame::synthetic(Plane::zeros(4, 4, 3));
        let mut zero = plain.clone();
        zero.motion_prev = Some(Plane::zeros(4, 4, 2));
        let mut with = zero.clone();
        with.motion_next = Some(Plane::filled(4, 4, 2, 0.5));
        let p = Path::new("f1.exr");
        let source = |choice, f: &Frame| {
            SequenceMotion::new(choice, EstimateParams::default()).decide(Vectors::of(f), p)
        };
        assert_eq!(
            source(MotionChoice::Auto, &with).unwrap(),
            MotionSource::Renderer
        );
        assert_eq!(
            source(MotionChoice::Auto, &plain).unwrap(),
            MotionSource::EstimatedWithoutVectors
        );
        assert_eq!(
            source(MotionChoice::Auto, &zero).unwrap(),
            MotionSource::EstimatedOverZeroVectors
        );
        assert_eq!(
            source(MotionChoice::Renderer, &zero).unwrap(),
            MotionSource::Renderer
        );
        assert_eq!(
            source(MotionChoice::Estimate, &with).unwrap(),
            MotionSource::Estimated
        );
        // a frame's bands seen one after the other: one moving row is motion
        let (top, bottom) = (zero.rows(0..2), with.rows(2..4));
        assert_eq!(Vectors::of(&top), Vectors::Zero);
        assert_eq!(Vectors::of(&top).and(&bottom), Vectors::Present);
        let e = source(MotionChoice::Renderer, &plain)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("f1.exr") && e.contains("no motion vectors"),
            "{e}"
        );
    }
}
