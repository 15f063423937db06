//! Repair of NaN and infinite samples before anything else sees them.

use crate::image::plane::Plane;

/// What to do with NaN/Inf samples in an input.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum NonFinitePolicy {
    /// Replace each bad sample by the mean of its finite 3×3 neighbours (0 if none) and count it.
    #[default]
    Repair,
    /// Refuse the file with an error naming the channel and the count.
    Error,
}

/// Counts NaN/Inf samples per channel of a plane.
pub fn count_nonfinite(plane: &Plane) -> Vec<usize> {
    (0..plane.channels())
        .map(|c| plane.channel(c).iter().filter(|v| !v.is_finite()).count())
        .collect()
}

/// Replaces every NaN/Inf sample by the mean of the finite samples in its 3×3 neighbourhood of
/// the same channel (0 when there are none). `far` replaces +Inf instead, for buffers such as
/// depth where +Inf means "infinitely far" rather than a broken sample. Returns how many
/// samples were replaced.
pub fn repair_nonfinite(plane: &mut Plane, far: Option<f32>) -> usize {
    let (w, h) = (plane.width(), plane.height());
    let mut repaired = 0;
    for c in 0..plane.channels() {
        let ch = plane.channel(c);
        if ch.iter().all(|v| v.is_finite()) {
            continue;
        }
        let src = ch.to_vec();
        let dst = plane.channel_mut(c);
        for y in 0..h {
            for x in 0..w {
                let v = src[y * w + x];
                if v.is_finite() {
                    continue;
                }
                repaired += 1;
                if let (Some(f), true) = (far, v == f32::INFINITY) {
                    dst[y * w + x] = f;
                    continue;
                }
                let (mut sum, mut n) = (0.0f64, 0usize);
                for ny in y.saturating_sub(1)..(y + 2).min(h) {
                    for nx in x.saturating_sub(1)..(x + 2).min(w) {
                        let s = src[ny * w + nx];
                        if s.is_finite() {
                            sum += s as f64;
                            n += 1;
                        }
                    }
                }
                dst[y * w + x] = if n > 0 { (sum / n as f64) as f32 } else { 0.0 };
            }
        }
    }
    repaired
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nan_becomes_neighbour_mean_and_is_counted() {
        let mut p = Plane::filled(3, 3, 2, 2.0);
        p.set(1, 1, 0, f32::NAN);
        p.set(0, 0, 1, f32::INFINITY);
        p.set(2, 2, 1, f32::NEG_INFINITY);
        assert_eq!(count_nonfinite(&p), vec![1, 2]);
        assert_eq!(repair_nonfinite(&mut p, None), 3);
        assert_eq!(p.get(1, 1, 0), 2.0);
        assert_eq!(p.get(0, 0, 1), 2.0);
        assert!(p.data().iter().all(|v| v.is_finite()));
    }

    #[test]
    fn infinite_depth_becomes_far() {
        let mut p = Plane::filled(2, 2, 1, 5.0);
        p.set(0, 0, 0, f32::INFINITY);
        repair_nonfinite(&mut p, Some(1e10));
        assert_eq!(p.get(0, 0, 0), 1e10);
    }
}
