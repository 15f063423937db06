//! Progress for work over frames: bars for a terminal, or JSON lines for a host application
//! (the Python package, the Blender extension, a farm's wrapper) that shows progress itself.

use std::fmt::Write;
use std::sync::OnceLock;

use indicatif::{ProgressBar, ProgressState, ProgressStyle};

/// How progress is shown (`--progress`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Style {
    // bars on stderr when it is a terminal (the variants' help stays out of `--help`, which the
    // option's own line explains)
    #[default]
    Bar,
    // one JSON object per line on stderr (`{"event":"progress",…}`), for programs
    Json,
    // nothing
    Off,
}

static STYLE: OnceLock<Style> = OnceLock::new();

/// Sets the process's progress style, once, before any work.
pub fn set_style(style: Style) {
    let _ = STYLE.set(style);
}

/// The process's progress style.
pub fn style() -> Style {
    STYLE.get().copied().unwrap_or_default()
}

/// Writes one event as a JSON line on stderr when the style is [`Style::Json`].
pub fn event(value: serde_json::Value) {
    if style() == Style::Json {
        eprintln!("{value}");
    }
}

/// A bar that draws only in the [`Style::Bar`] style.
fn visible(pb: ProgressBar) -> ProgressBar {
    if style() != Style::Bar {
        pb.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    pb
}

/// A frame-counting progress bar with rate and ETA (hidden when stderr is not a terminal).
pub fn frames(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template(
            "{msg:>10} [{bar:32}] {pos}/{len} frames  {per_sec}  ETA {eta}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    visible(pb)
}

/// Steps a [`fine_frames`] bar counts per frame.
pub const PARTS_PER_FRAME: u64 = 1000;

/// A frame-counting progress bar that also moves within a frame (a large frame denoised band
/// by band takes minutes): set its position with `frames done × PARTS_PER_FRAME`.
pub fn fine_frames(len: u64, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(len * PARTS_PER_FRAME);
    let per = PARTS_PER_FRAME as f64;
    pb.set_style(
        ProgressStyle::with_template("{msg:>10} [{bar:32}] {frames} frames  {fps}  ETA {eta}")
            .expect("valid template")
            .with_key("frames", move |s: &ProgressState, w: &mut dyn Write| {
                let _ = write!(
                    w,
                    "{:.1}/{}",
                    s.pos() as f64 / per,
                    s.len().unwrap_or(0) as f64 / per
                );
            })
            .with_key("fps", move |s: &ProgressState, w: &mut dyn Write| {
                let fps = s.per_sec() / per;
                let _ = if fps >= 0.1 {
                    write!(w, "{fps:.2} frames/s")
                } else {
                    write!(w, "{:.0} s/frame", 1.0 / fps.max(1e-9))
                };
            })
            .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    visible(pb)
}
