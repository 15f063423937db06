//! Progress bars for work over frames.

use indicatif::{ProgressBar, ProgressStyle};

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
