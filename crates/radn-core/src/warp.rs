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
