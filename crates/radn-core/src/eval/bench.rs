//! Throughput of the data path without a network on this machine (`radn bench -i`): decoding a
//! window's frames, aligning it, and the classic denoiser's motion refinement and window
//! filter, each timed alone.

use std::path::PathBuf;
use std::time::Instant;

use crate::align::AlignParams;
use crate::classic::pipeline::{denoise_window, ClassicParams};
use crate::classic::refine::{refine_motion, RefineParams};
use crate::error::Result;
use crate::io::frame::FrameReader;
use crate::run::window::WindowReader;

/// Median seconds of each stage on one 5-frame window.
#[derive(Clone, Copy, Debug)]
pub struct WindowTimings {
    /// The frames' size.
    pub size: (usize, usize),
    /// Decoding the five frames.
    pub read: f64,
    /// Aligning the window onto its centre.
    pub align: f64,
    /// With the classic denoiser: refining the centre frame's motion towards both neighbours,
    /// and denoising the window (without refinement).
    pub classic: Option<(f64, f64)>,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Times the window of the five frames `files` (its centre the third) `repeat` times.
pub fn time_windows(
    reader: &FrameReader,
    files: &[PathBuf],
    repeat: usize,
    classic: bool,
) -> Result<WindowTimings> {
    let mut read_times = Vec::new();
    let mut align_times = Vec::new();
    let mut refine_times = Vec::new();
    let mut classic_times = Vec::new();
    let mut size = (0, 0);
    for _ in 0..repeat.max(1) {
        // a new reader each time, so every repetition decodes the five frames
        let mut windows = WindowReader::new(reader, files, 2);
        let t = Instant::now();
        windows.load(2, 2)?;
        read_times.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let w = windows.aligned(2, &AlignParams::default())?;
        align_times.push(t.elapsed().as_secs_f64());
        size = (w.centre().color.width(), w.centre().color.height());
        std::hint::black_box(w);
        if classic {
            // one frame's refinement: its motion towards both neighbours
            let c = windows.frame(2);
            let t = Instant::now();
            for (other, m) in [
                (windows.frame(1), &c.motion_prev),
                (windows.frame(3), &c.motion_next),
            ] {
                if let Some(m) = m {
                    std::hint::black_box(refine_motion(
                        &c.color,
                        &other.color,
                        m,
                        &RefineParams::default(),
                    ));
                }
            }
            refine_times.push(t.elapsed().as_secs_f64());
            let p = ClassicParams {
                flow_refine: None,
                ..ClassicParams::default()
            };
            let t = Instant::now();
            std::hint::black_box(denoise_window(&windows.window(2), &p));
            classic_times.push(t.elapsed().as_secs_f64());
        }
    }
    Ok(WindowTimings {
        size,
        read: median(read_times),
        align: median(align_times),
        classic: classic.then(|| (median(refine_times), median(classic_times))),
    })
}
