//! From aligned windows (radn-core) to network tensors: the per-frame input features and the
//! linear values kernels are applied to.

use radn_core::align::AlignedWindow;
use radn_core::frame::FAR_DEPTH;

use crate::config::INPUT_CHANNELS;

/// Largest magnitude of the log depth ratio fed to the network.
const DEPTH_CLAMP: f32 = 3.0;

/// Per-frame network features of a window, `[T, INPUT_CHANNELS, H, W]` row-major: log colour,
/// albedo, normal, depth relative to the centre frame's mean (log), confidence.
pub fn features(win: &AlignedWindow) -> Vec<f32> {
    let c = win.centre();
    let (w, h) = (c.color.width(), c.color.height());
    let n = w * h;
    // the centre frame's mean finite depth sets the depth scale
    let depth_ref = c
        .depth
        .as_ref()
        .map(|d| {
            let v: Vec<f32> = d
                .data()
                .iter()
                .copied()
                .filter(|&z| z > 0.0 && z < 0.5 * FAR_DEPTH)
                .collect();
            if v.is_empty() {
                1.0
            } else {
                v.iter().sum::<f32>() / v.len() as f32
            }
        })
        .unwrap_or(1.0);
    let mut out = Vec::with_capacity(win.frames.len() * INPUT_CHANNELS * n);
    for f in &win.frames {
        out.extend(f.color.data().iter().map(|v| v.max(0.0).ln_1p()));
        match &f.albedo {
            Some(a) => out.extend(a.data().iter().map(|v| v.clamp(0.0, 2.0))),
            None => out.extend(std::iter::repeat_n(0.0, 3 * n)),
        }
        match &f.normal {
            Some(nm) => out.extend(nm.data().iter().map(|v| v.clamp(-1.0, 1.0))),
            None => out.extend(std::iter::repeat_n(0.0, 3 * n)),
        }
        match &f.depth {
            Some(d) => out.extend(d.data().iter().map(|&z| {
                if z >= 0.5 * FAR_DEPTH || !z.is_finite() {
                    DEPTH_CLAMP
                } else {
                    (z.max(1e-6) / depth_ref)
                        .ln()
                        .clamp(-DEPTH_CLAMP, DEPTH_CLAMP)
                }
            })),
            None => out.extend(std::iter::repeat_n(0.0, n)),
        }
        out.extend_from_slice(f.confidence.data());
    }
    out
}

/// The linear beauty of every frame, `[T, 3, H, W]`.
pub fn color_values(win: &AlignedWindow) -> Vec<f32> {
    win.frames
        .iter()
        .flat_map(|f| f.color.data().iter().copied())
        .collect()
}

/// Any per-frame plane of the window (an AOV by index, or alpha), `[T, C, H, W]`.
pub fn plane_values(
    win: &AlignedWindow,
    pick: impl Fn(&radn_core::align::AlignedFrame) -> &radn_core::Plane,
) -> Vec<f32> {
    win.frames
        .iter()
        .flat_map(|f| pick(f).data().iter().copied())
        .collect()
}
