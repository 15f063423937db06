//! Where a network denoiser's time goes, per stage: each stage's wall time is added to a
//! per-thread tally while it runs ([`timed`]), and [`take`] hands the tally over and clears
//! it, so `radn denoise -v` can print one line per frame (docs/research/benchmarks.md, "Where the time
//! goes"). A frame's stages run on the thread that denoises it (the parallel work happens
//! inside them), so the per-thread tally is that frame's. Timing costs two clock reads per
//! stage call, a few hundred per frame.

use std::cell::RefCell;
use std::fmt;
use std::time::{Duration, Instant};

/// A stage of denoising a window with a network.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Motion composition, warps, confidence and centre mixing of the window.
    Align,
    /// Building the network's per-frame input channels of each tile.
    Inputs,
    /// The per-frame convolutions of the backbone (input layer, residual or UNet blocks).
    Backbone,
    /// The Robust Average blocks.
    RobustAverage,
    /// Kernel heads (every scale), the scale blend heads and the kernel activation η_t.
    Heads,
    /// Applying the kernels to colour, AOVs and alpha (with demodulation and the multi-scale
    /// combination).
    Kernels,
    /// The input blend that follows the frame's noise level.
    InputBlend,
    /// The guide mix of a guided network.
    GuideMix,
}

const STAGES: [Stage; 8] = [
    Stage::Align,
    Stage::Inputs,
    Stage::Backbone,
    Stage::RobustAverage,
    Stage::Heads,
    Stage::Kernels,
    Stage::InputBlend,
    Stage::GuideMix,
];

impl Stage {
    fn index(self) -> usize {
        STAGES
            .iter()
            .position(|&s| s == self)
            .expect("a listed stage")
    }

    fn name(self) -> &'static str {
        match self {
            Stage::Align => "align",
            Stage::Inputs => "inputs",
            Stage::Backbone => "backbone convs",
            Stage::RobustAverage => "RA blocks",
            Stage::Heads => "heads",
            Stage::Kernels => "kernel application",
            Stage::InputBlend => "input blend",
            Stage::GuideMix => "guide mix",
        }
    }
}

/// Time spent per stage.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes([Duration; 8]);

impl StageTimes {
    /// The time of `stage`.
    pub fn get(&self, stage: Stage) -> Duration {
        self.0[stage.index()]
    }

    /// All stages together.
    pub fn total(&self) -> Duration {
        self.0.iter().sum()
    }
}

impl fmt::Display for StageTimes {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let parts: Vec<String> = STAGES
            .iter()
            .filter(|&&s| self.get(s) > Duration::ZERO)
            .map(|&s| format!("{} {:.2} s", s.name(), self.get(s).as_secs_f64()))
            .collect();
        write!(f, "{}", parts.join(", "))
    }
}

thread_local! {
    static TALLY: RefCell<StageTimes> = RefCell::new(StageTimes::default());
}

/// Runs `f`, adding its wall time to `stage` in this thread's tally. A stage timed inside
/// another is subtracted from it, so stages never count twice.
pub fn timed<T>(stage: Stage, f: impl FnOnce() -> T) -> T {
    let before = TALLY.with(|t| *t.borrow());
    let start = Instant::now();
    let out = f();
    let elapsed = start.elapsed();
    TALLY.with(|t| {
        let mut t = t.borrow_mut();
        let inner = t.total().saturating_sub(before.total());
        t.0[stage.index()] += elapsed.saturating_sub(inner);
    });
    out
}

/// This thread's tally since the last call, cleared; each stage is also added to the run's
/// sums ([`radn_core::run::timing`]).
pub fn take() -> StageTimes {
    let times = TALLY.with(|t| std::mem::take(&mut *t.borrow_mut()));
    for s in STAGES {
        if times.get(s) > Duration::ZERO {
            radn_core::run::timing::add(s.name(), times.get(s));
        }
    }
    times
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nested_stages_count_once_and_take_clears_the_tally() {
        take();
        let spin = |ms: u64| {
            let s = Instant::now();
            while s.elapsed() < Duration::from_millis(ms) {}
        };
        timed(Stage::Backbone, || {
            spin(20);
            timed(Stage::RobustAverage, || spin(200));
        });
        let t = take();
        let (b, r) = (t.get(Stage::Backbone), t.get(Stage::RobustAverage));
        assert!(r >= Duration::from_millis(200), "{r:?}");
        assert!(
            b >= Duration::from_millis(20) && b < Duration::from_millis(150),
            "{b:?}"
        );
        assert!(t.to_string().contains("RA blocks"));
        assert_eq!(take(), StageTimes::default());
    }
}
