//! Backward bilinear warping of whole planes along a displacement field.

use rayon::prelude::*;

use crate::motion::bilinear;
use crate::plane::Plane;

/// Warps `src` onto the frame `flow` is defined on: `out(x) = src(x + flow(x))`, bilinear,
/// repeating edge pixels for lookups that fall off the image (their confidence is 0 anyway).
pub fn warp_plane(src: &Plane, flow: &Plane) -> Plane {
    let (w, h) = (flow.width(), flow.height());
    assert!(
        src.width() == w && src.height() == h,
        "warp: source and flow differ in size"
    );
    let mut out = Plane::zeros(w, h, src.channels());
    let n = w * h;
    let (fx, fy) = (flow.channel(0), flow.channel(1));
    out.data_mut()
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(row, dst)| {
            let c = row / h;
            let y = row % h;
            for (x, d) in dst.iter_mut().enumerate() {
                let i = y * w + x;
                *d = bilinear(src, c, x as f32 + fx[i], y as f32 + fy[i]);
            }
        });
    debug_assert_eq!(out.data().len(), n * src.channels());
    out
}

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
    fn centre_mixing_follows_confidence() {
        let mut w = Plane::filled(2, 1, 1, 10.0);
        let centre = Plane::filled(2, 1, 1, 2.0);
        let conf = Plane::from_vec(2, 1, 1, vec![1.0, 0.25]);
        mix_with_centre(&mut w, &centre, &conf);
        assert_eq!(w.data(), &[10.0, 4.0]);
    }
}
