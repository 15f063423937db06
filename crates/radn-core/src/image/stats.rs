//! A frame's whole-frame statistics, gathered as running sums so that a frame read band by band
//! adds up to exactly its whole-frame values: the mean geometry depth and the log-average
//! luminance (the exposure) that normalise the network's features.

use crate::image::plane::Plane;

/// Depth given to background pixels whose depth is +Inf.
pub const FAR_DEPTH: f32 = 1.0e10;

/// Adds a depth plane's geometry depths (finite, positive, not background) to a running
/// (sum, count): the centre frame's mean depth normalises the network's depth feature. A
/// running sum, so that a frame read band by band adds up to exactly its whole-frame value.
pub fn add_geometry_depths(depth: &Plane, acc: (f64, usize)) -> (f64, usize) {
    depth
        .data()
        .iter()
        .filter(|&&z| z > 0.0 && z < 0.5 * FAR_DEPTH)
        .fold(acc, |(s, n), &z| (s + z as f64, n + 1))
}

/// The mean of a (sum, count) from [`add_geometry_depths`]; 1 without geometry.
pub fn mean_geometry_depth((sum, n): (f64, usize)) -> f32 {
    if n == 0 {
        1.0
    } else {
        (sum / n as f64) as f32
    }
}

/// Adds a colour plane's log luminances (`ln` of the mean of R, G, B, over pixels where it is
/// finite and positive) to a running (sum, count). Its average is the frame's exposure (the
/// log-average "key" of Reinhard et al. 2002): fireflies hardly move it, and scaling the
/// frame by `k` scales it by exactly `k`. A running sum, so that a frame read band by band
/// adds up to its whole-frame value.
pub fn add_log_luminance(color: &Plane, acc: (f64, usize)) -> (f64, usize) {
    let n = color.width() * color.height();
    let (r, g, b) = (color.channel(0), color.channel(1), color.channel(2));
    (0..n)
        .map(|i| (r[i] + g[i] + b[i]) / 3.0)
        .filter(|y| y.is_finite() && *y > 0.0)
        .fold(acc, |(s, n), y| (s + (y as f64).ln(), n + 1))
}

/// The exposure of a (sum, count) from [`add_log_luminance`]: the log-average luminance; 1
/// for a black frame.
pub fn log_average_luminance((sum, n): (f64, usize)) -> f32 {
    if n == 0 {
        1.0
    } else {
        ((sum / n as f64).exp() as f32).max(f32::MIN_POSITIVE)
    }
}
