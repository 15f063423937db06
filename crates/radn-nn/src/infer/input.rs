//! From aligned windows (radn-core) to network tensors: the per-frame input features and the
//! linear values kernels are applied to.

use radn_core::align::AlignedWindow;
use radn_core::frame::{add_geometry_depths, mean_geometry_depth, FAR_DEPTH};

use crate::model::config::INPUT_CHANNELS;

/// Largest magnitude of the log depth ratio fed to the network.
const DEPTH_CLAMP: f32 = 3.0;

/// A pixel rectangle `[x0, x1) × [y0, y1)` of a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Region {
    /// First column.
    pub x0: usize,
    /// First row.
    pub y0: usize,
    /// One past the last column.
    pub x1: usize,
    /// One past the last row.
    pub y1: usize,
}

impl Region {
    /// The whole `w × h` frame.
    pub fn whole(w: usize, h: usize) -> Self {
        Self {
            x0: 0,
            y0: 0,
            x1: w,
            y1: h,
        }
    }

    /// Width and height: regions of one size can share a network call.
    pub fn size(&self) -> (usize, usize) {
        (self.x1 - self.x0, self.y1 - self.y0)
    }

    /// Pixels in the region.
    pub fn pixels(&self) -> usize {
        (self.x1 - self.x0) * (self.y1 - self.y0)
    }

    /// The region's part of every channel of `plane`, channel-major.
    pub fn crop(&self, plane: &radn_core::Plane, out: &mut Vec<f32>) {
        let w = plane.width();
        for c in 0..plane.channels() {
            let ch = plane.channel(c);
            for y in self.y0..self.y1 {
                out.extend_from_slice(&ch[y * w + self.x0..y * w + self.x1]);
            }
        }
    }
}

/// The depth scale of a window: the centre frame's mean finite depth (1 without depth). One
/// number per frame, so that tiles of a frame see the same depth features as the whole frame.
pub fn depth_scale(win: &AlignedWindow) -> f32 {
    win.centre().depth.as_ref().map_or(1.0, |d| {
        mean_geometry_depth(add_geometry_depths(d, (0.0, 0)))
    })
}

/// Per-frame network features of a window, `[T, INPUT_CHANNELS, H, W]` row-major: log colour,
/// albedo, normal, depth relative to the centre frame's mean (log), confidence.
pub fn features(win: &AlignedWindow) -> Vec<f32> {
    let c = win.centre();
    let region = Region::whole(c.color.width(), c.color.height());
    features_in(win, depth_scale(win), region)
}

/// The features of [`features`] for one region of the frame, `[T, INPUT_CHANNELS, h, w]`
/// (tiled inference computes them tile by tile instead of holding the whole frame's).
pub fn features_in(win: &AlignedWindow, depth_ref: f32, region: Region) -> Vec<f32> {
    let n = region.pixels();
    let mut out = Vec::with_capacity(win.frames.len() * INPUT_CHANNELS * n);
    let mut part = Vec::with_capacity(3 * n);
    let mut put = |plane: &radn_core::Plane, map: &dyn Fn(f32) -> f32, out: &mut Vec<f32>| {
        part.clear();
        region.crop(plane, &mut part);
        out.extend(part.iter().map(|&v| map(v)));
    };
    for f in &win.frames {
        put(&f.color, &|v| v.max(0.0).ln_1p(), &mut out);
        match &f.albedo {
            Some(a) => put(a, &|v| v.clamp(0.0, 2.0), &mut out),
            None => out.extend(std::iter::repeat_n(0.0, 3 * n)),
        }
        match &f.normal {
            Some(nm) => put(nm, &|v| v.clamp(-1.0, 1.0), &mut out),
            None => out.extend(std::iter::repeat_n(0.0, 3 * n)),
        }
        match &f.depth {
            Some(d) => put(
                d,
                &|z| {
                    if z >= 0.5 * FAR_DEPTH || !z.is_finite() {
                        DEPTH_CLAMP
                    } else {
                        (z.max(1e-6) / depth_ref)
                            .ln()
                            .clamp(-DEPTH_CLAMP, DEPTH_CLAMP)
                    }
                },
                &mut out,
            ),
            None => out.extend(std::iter::repeat_n(0.0, n)),
        }
        put(&f.confidence, &|v| v, &mut out);
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
