//! Progress bars for work over frames.

use std::fmt::Write;

use indicatif::{ProgressBar, ProgressState, ProgressStyle};

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
    pb
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
    pb
}
