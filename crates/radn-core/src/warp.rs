//! Backward bilinear warping of whole planes along a displacement field.

use rayon::prelude::*;

use crate::banding::Band;
use crate::plane::Plane;

/// Warps `src` onto the frame `flow` is defined on: `out(x) = src(x + flow(x))`, bilinear,
/// repeating edge pixels for lookups that fall off the image (their confidence is 0 anyway).
pub fn warp_plane(src: &Plane, flow: &Plane) -> Plane {
    assert!(
        src.width() == flow.width() && src.height() == flow.height(),
        "warp: source and flow differ in size"
    );
    warp_band(Band::whole(src), Band::whole(flow))
}

/// [`warp_plane`] on bands of one frame size: the result covers `flow`'s rows; `src` must hold
/// every row the flow reaches.
pub fn warp_band(src: Band, flow: Band) -> Plane {
    let (w, h) = (flow.plane.width(), flow.plane.height());
    assert_eq!(
        src.plane.width(),
        w,
        "warp: source and flow differ in width"
    );
    let channels = src.plane.channels();
    let mut out = Plane::zeros(w, h, channels);
    let (fx, fy) = (flow.plane.channel(0), flow.plane.channel(1));
    out.data_mut()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(row, dst)| {
            let c = row / h;
            let y = row % h;
            for (x, d) in dst.iter_mut().enumerate() {
                let i = y * w + x;
                *d = src.bilinear(c, x as f32 + fx[i], (y + flow.y0) as f32 + fy[i]);
            }
        });
    out
}

/// [`warp_band`] of several planes of one frame band along one flow: each pixel's bilinear
/// taps and weights are computed once for every channel of every plane (the values equal
/// warping each plane alone, bit for bit). A side frame's alignment warps some twenty channels
/// (colour, albedo, normal, their prefiltered guides, alpha, AOVs, the guide) along one flow.
///
/// # Panics
/// When the planes are not bands of one size and position in one frame, or differ from the
/// flow in width.
pub fn warp_bands(srcs: &[Band], flow: Band) -> Vec<Plane> {
    let (w, h) = (flow.plane.width(), flow.plane.height());
    let Some(first) = srcs.first() else {
        return Vec::new();
    };
    for s in srcs {
        assert_eq!(s.plane.width(), w, "warp: source and flow differ in width");
        assert!(
            s.plane.height() == first.plane.height()
                && s.y0 == first.y0
                && s.full_height == first.full_height,
            "warp: the planes must be the same band of one frame"
        );
    }
    let (band_y0, full_h) = (first.y0, first.full_height);
    let last = first.plane.height() - 1;
    let n = w * h;
    let mut outs: Vec<Vec<f32>> = srcs
        .iter()
        .map(|s| Vec::with_capacity(s.plane.channels() * n))
        .collect();
    let dsts: Vec<RowWriter> = outs.iter_mut().map(|v| RowWriter(v.as_mut_ptr())).collect();
    let (fx, fy) = (flow.plane.channel(0), flow.plane.channel(1));
    (0..h)
        .into_par_iter()
        .for_each_init(Vec::new, |taps: &mut Vec<Tap>, y| {
            taps.clear();
            for x in 0..w {
                let i = y * w + x;
                // exactly the arithmetic of `Band::bilinear`
                let xf = (x as f32 + fx[i]).clamp(0.0, (w - 1) as f32);
                let yf = ((y + flow.y0) as f32 + fy[i]).clamp(0.0, (full_h - 1) as f32);
                let x0 = xf.floor() as usize;
                let y0 = yf.floor() as usize;
                let x1 = (x0 + 1).min(w - 1);
                let y1 = (y0 + 1).min(full_h - 1);
                let r0 = y0.saturating_sub(band_y0).min(last);
                let r1 = y1.saturating_sub(band_y0).min(last);
                debug_assert!(
                    y0 >= band_y0
                        && y0 - band_y0 <= last
                        && (yf == y0 as f32 || y1 - band_y0 <= last),
                    "band rows do not hold row {y0}"
                );
                taps.push(Tap {
                    top: [r0 * w + x0, r0 * w + x1],
                    bottom: [r1 * w + x0, r1 * w + x1],
                    fx: xf - x0 as f32,
                    fy: yf - y0 as f32,
                });
            }
            for (src, dst) in srcs.iter().zip(&dsts) {
                for c in 0..src.plane.channels() {
                    let ch = src.plane.channel(c);
                    // SAFETY: row `y` of channel `c` of this output: `c * n + y * w .. + w` lies
                    // within the `channels · n` floats reserved, and only this job writes it.
                    let row = unsafe { dst.row(c * n + y * w, w) };
                    for (d, t) in row.iter_mut().zip(taps.iter()) {
                        let a = ch[t.top[0]] * (1.0 - t.fx) + ch[t.top[1]] * t.fx;
                        let b = ch[t.bottom[0]] * (1.0 - t.fx) + ch[t.bottom[1]] * t.fx;
                        d.write(a * (1.0 - t.fy) + b * t.fy);
                    }
                }
            }
        });
    srcs.iter()
        .zip(outs)
        .map(|(s, mut v)| {
            let len = s.plane.channels() * n;
            // SAFETY: every row of every channel was written above.
            unsafe { v.set_len(len) };
            Plane::from_vec(w, h, s.plane.channels(), v)
        })
        .collect()
}

/// One pixel's bilinear lookup: the indices of its four neighbours in a band's channel and the
/// weights of the right and lower ones.
struct Tap {
    top: [usize; 2],
    bottom: [usize; 2],
    fx: f32,
    fy: f32,
}

/// The start of an output buffer whose rows the parallel jobs of [`warp_bands`] write, each
/// job its own rows.
struct RowWriter(*mut f32);

impl RowWriter {
    /// `len` floats from `at`, as uninitialised values to write.
    ///
    /// # Safety
    /// The range must lie within the buffer's capacity, and no other job may access it.
    #[allow(clippy::mut_from_ref)]
    unsafe fn row(&self, at: usize, len: usize) -> &mut [std::mem::MaybeUninit<f32>] {
        // SAFETY: the caller's promise.
        unsafe { std::slice::from_raw_parts_mut(self.0.add(at).cast(), len) }
    }
}

// SAFETY: the jobs write disjoint rows through the pointer.
unsafe impl Send for RowWriter {}
unsafe impl Sync for RowWriter {}

/// Blends a warped side-frame plane towards the centre frame's by confidence:
/// `c · warped + (1 − c) · centre` (paper section 3, "centre mixing").
pub fn mix_with_centre(warped: &mut Plane, centre: &Plane, confidence: &Plane) {
    let n = warped.pixels();
    let conf = confidence.channel(0);
    warped
        .data_mut()
        .par_chunks_mut(n)
        .enumerate()
        .for_each(|(c, ch)| {
            let centre = centre.channel(c);
            for i in 0..n {
                ch[i] = conf[i] * ch[i] + (1.0 - conf[i]) * centre[i];
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integer_translation_moves_pixels_exactly() {
        let src = Plane::from_fn(16, 12, 2, |x, y, c| (x * 7 + y * 13 + c * 101) as f32);
        let flow = Plane::from_fn(16, 12, 2, |_, _, c| if c == 0 { 3.0 } else { -2.0 });
        let out = warp_plane(&src, &flow);
        for y in 2..12 {
            for x in 0..13 {
                for c in 0..2 {
                    assert_eq!(out.get(x, y, c), src.get(x + 3, y - 2, c));
                }
            }
        }
    }

    #[test]
    fn warping_planes_together_equals_warping_each_alone_bit_for_bit() {
        // a band of rows 3..15 of a 20-row frame, flows that reach the band's edges, subpixel
        // positions and lookups off the frame (clamped)
        let (w, full_h) = (23, 20);
        let a = Plane::from_fn(w, 12, 3, |x, y, c| {
            ((x * 31 + y * 17 + c * 7) % 29) as f32 * 0.37
        });
        let b = Plane::from_fn(w, 12, 1, |x, y, _| (x as f32 - 0.3 * y as f32).sin());
        let flow = Plane::from_fn(w, 6, 2, |x, y, c| {
            if c == 0 {
                (x as f32 * 0.731).sin() * 4.3 - 1.2
            } else {
                (y as f32 * 1.37 + x as f32 * 0.11).cos() * 1.9 + 0.25
            }
        });
        let band = |p| Band {
            plane: p,
            y0: 3,
            full_height: full_h,
        };
        let flow_band = Band {
            plane: &flow,
            y0: 6,
            full_height: full_h,
        };
        let together = warp_bands(&[band(&a), band(&b)], flow_band);
        assert_eq!(together.len(), 2);
        for (got, src) in together.iter().zip([&a, &b]) {
            let alone = warp_band(band(src), flow_band);
            assert_eq!(got.channels(), src.channels());
            assert_eq!(got.data(), alone.data());
        }
        assert!(warp_bands(&[], flow_band).is_empty());
    }

    #[test]
    fn centre_mixing_follows_confidence() {
        let mut w = Plane::filled(2, 1, 1, 10.0);
        let centre = Plane::filled(2, 1, 1, 2.0);
        let conf = Plane::from_vec(2, 1, 1, vec![1.0, 0.25]);
        mix_with_centre(&mut w, &centre, &conf);
        assert_eq!(w.data(), &[10.0, 4.0]);
    }
}
