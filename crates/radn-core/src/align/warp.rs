//! Backward warping of planes along a displacement field: bilinear, or clamped Catmull-Rom
//! where one-pixel detail must survive subpixel shifts.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::image::plane::Plane;
use crate::run::banding::Band;

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

/// How a warp samples a plane between its pixels.
///
/// Bilinear interpolation at a half-pixel shift averages two pixels: a line one pixel wide
/// loses half its contrast in every warped side frame, and a static wire under a panning
/// camera is shifted by a fraction of a pixel in every frame of the window. Catmull-Rom keeps
/// it; its result is clamped to the range of the four nearest pixels, so it neither rings
/// around edges nor goes negative on HDR values, and whole-pixel shifts copy pixels exactly
/// with either.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Resampling {
    /// The four nearest pixels, weighted by distance.
    #[default]
    Bilinear,
    /// The sixteen nearest pixels with Catmull-Rom weights (a cubic through the middle two
    /// pixels of each row and column, with slopes from their neighbours), clamped to the four
    /// nearest pixels' range.
    CatmullRom,
    /// The nearest pixel: no blend between pixels, so Monte Carlo noise stays per pixel
    /// (white) in a mean of warped frames, at up to half a pixel's misplacement.
    Nearest,
}

impl Resampling {
    /// True for the default ([`Resampling::Bilinear`]), which model files leave out.
    pub fn is_bilinear(&self) -> bool {
        *self == Resampling::Bilinear
    }

    /// The name the command line and model descriptions use.
    pub fn name(&self) -> &'static str {
        match self {
            Resampling::Bilinear => "bilinear",
            Resampling::CatmullRom => "catmull-rom",
            Resampling::Nearest => "nearest",
        }
    }
}

/// [`warp_band`] of several planes of one frame band along one flow, sampled with
/// `resampling`: each pixel's taps and weights are computed once for every channel of every
/// plane (bilinear values equal warping each plane alone with [`warp_band`], bit for bit). A
/// side frame's alignment warps some twenty channels (colour, albedo, normal, their prefiltered
/// guides, alpha, AOVs, the guide) along one flow. The sources must hold the rows the flow
/// reaches, rounded out to whole rows, and one more on each side: a lookup reads with a
/// non-zero weight no farther (Catmull-Rom's second row below a position lies beyond the
/// rounded reach only where the position is a whole row short of it).
///
/// # Panics
/// When the planes are not bands of one size and position in one frame, or differ from the
/// flow in width.
pub fn warp_bands(srcs: &[Band], flow: Band, resampling: Resampling) -> Vec<Plane> {
    warp_bands_linked(srcs, flow, resampling, None)
}

/// Sources of [`warp_bands_linked`] that must keep summing to another after the warp: the
/// beauty (`lead`) and its AOVs (`parts`), indices into the sources.
#[derive(Clone, Debug)]
pub struct SummingPlanes {
    /// The plane the others sum to (three channels: the beauty).
    pub lead: usize,
    /// The planes that sum to it (those with three channels share its clamp; others are
    /// clamped on their own).
    pub parts: Vec<usize>,
}

/// [`warp_bands`], keeping `summing` planes summing to their lead under Catmull-Rom
/// resampling. The clamp to the four nearest pixels' range is not linear: clamping the beauty
/// and each AOV on its own would break their sum wherever one of them overshoots. Each channel
/// of the lead is clamped as before (exactly), and that clamp written as a blend from the
/// bilinear value towards the cubic one, `b + λ·(c − b)`, where `λ` ∈ [0, 1] is what keeps the
/// lead's channel in range; each part's same channel takes the same blend with the same `λ`.
/// The blend is linear in the plane, so parts that summed to the lead still do. Bilinear
/// resampling is linear already and ignores `summing`.
pub fn warp_bands_linked(
    srcs: &[Band],
    flow: Band,
    resampling: Resampling,
    summing: Option<&SummingPlanes>,
) -> Vec<Plane> {
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
    // the band row holding frame row `fr` (clamped to the frame first)
    let band_row = |fr: i64| -> usize {
        let fr = fr.clamp(0, full_h as i64 - 1) as usize;
        fr.saturating_sub(band_y0).min(last)
    };
    let col = |c: i64| -> usize { c.clamp(0, w as i64 - 1) as usize };
    // the lead's blend per channel, and whether each source is one of its three-channel parts
    let summing = summing
        .filter(|_| resampling == Resampling::CatmullRom)
        .filter(|l| srcs[l.lead].plane.channels() == 3);
    let part_of_lead: Vec<bool> = (0..srcs.len())
        .map(|k| summing.is_some_and(|l| l.parts.contains(&k) && srcs[k].plane.channels() == 3))
        .collect();
    let mut order: Vec<usize> = (0..srcs.len()).collect();
    if let Some(l) = summing {
        // the lead first, so its blends exist when its parts are warped
        order.retain(|&k| k != l.lead);
        order.insert(0, l.lead);
    }
    (0..h).into_par_iter().for_each_init(
        || (Vec::new(), Vec::new(), Vec::new()),
        |(taps, cubic, blend): &mut (Vec<Tap>, Vec<CubicTap>, Vec<f32>), y| {
            taps.clear();
            cubic.clear();
            for x in 0..w {
                let i = y * w + x;
                // exactly the arithmetic of `Band::bilinear`
                let xf = (x as f32 + fx[i]).clamp(0.0, (w - 1) as f32);
                let yf = ((y + flow.y0) as f32 + fy[i]).clamp(0.0, (full_h - 1) as f32);
                let x0 = xf.floor() as usize;
                let y0 = yf.floor() as usize;
                let (tx, ty) = (xf - x0 as f32, yf - y0 as f32);
                debug_assert!(
                    y0 >= band_y0 && y0 - band_y0 <= last,
                    "band rows do not hold row {y0}"
                );
                match resampling {
                    Resampling::Bilinear | Resampling::Nearest => {
                        // the nearest pixel is the bilinear blend with weights rounded to 0 or 1
                        let (tx, ty) = match resampling {
                            Resampling::Nearest => (tx.round(), ty.round()),
                            _ => (tx, ty),
                        };
                        let x1 = (x0 + 1).min(w - 1);
                        let y1 = (y0 + 1).min(full_h - 1);
                        let r0 = y0.saturating_sub(band_y0).min(last);
                        let r1 = y1.saturating_sub(band_y0).min(last);
                        debug_assert!(
                            ty == 0.0 || y1 - band_y0 <= last,
                            "band rows do not hold row {y1}"
                        );
                        taps.push(Tap {
                            top: [r0 * w + x0, r0 * w + x1],
                            bottom: [r1 * w + x0, r1 * w + x1],
                            fx: tx,
                            fy: ty,
                        });
                    }
                    Resampling::CatmullRom => {
                        let (x0, y0) = (x0 as i64, y0 as i64);
                        cubic.push(CubicTap {
                            rows: [-1, 0, 1, 2].map(|d| band_row(y0 + d) * w),
                            cols: [-1, 0, 1, 2].map(|d| col(x0 + d)),
                            wx: catmull_rom_weights(tx),
                            wy: catmull_rom_weights(ty),
                            tx,
                            ty,
                        });
                    }
                }
            }
            for &k in &order {
                let (src, dst) = (&srcs[k], &dsts[k]);
                let lead = summing.is_some_and(|l| l.lead == k);
                if lead {
                    blend.clear();
                    blend.resize(3 * w, 1.0);
                }
                for c in 0..src.plane.channels() {
                    let ch = src.plane.channel(c);
                    // SAFETY: row `y` of channel `c` of this output: `c * n + y * w .. + w`
                    // lies within the `channels · n` floats reserved, and only this job
                    // writes it.
                    let row = unsafe { dst.row(c * n + y * w, w) };
                    match resampling {
                        Resampling::Bilinear | Resampling::Nearest => {
                            for (d, t) in row.iter_mut().zip(taps.iter()) {
                                let a = ch[t.top[0]] * (1.0 - t.fx) + ch[t.top[1]] * t.fx;
                                let b = ch[t.bottom[0]] * (1.0 - t.fx) + ch[t.bottom[1]] * t.fx;
                                d.write(a * (1.0 - t.fy) + b * t.fy);
                            }
                        }
                        Resampling::CatmullRom if lead => {
                            let lambdas = &mut blend[c * w..(c + 1) * w];
                            for ((d, t), l) in row.iter_mut().zip(cubic.iter()).zip(lambdas) {
                                let (v, lambda) = t.sample_with_blend(ch);
                                *l = lambda;
                                d.write(v);
                            }
                        }
                        Resampling::CatmullRom if part_of_lead[k] => {
                            let lambdas = &blend[c * w..(c + 1) * w];
                            for ((d, t), l) in row.iter_mut().zip(cubic.iter()).zip(lambdas) {
                                d.write(t.blended(ch, *l));
                            }
                        }
                        Resampling::CatmullRom => {
                            for (d, t) in row.iter_mut().zip(cubic.iter()) {
                                d.write(t.sample(ch));
                            }
                        }
                    }
                }
            }
        },
    );
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

/// The Catmull-Rom weights of the pixels at −1, 0, 1 and 2 for a position `t` ∈ [0, 1) past
/// pixel 0: they sum to 1, reproduce linear ramps, and are (0, 1, 0, 0) at `t = 0`.
fn catmull_rom_weights(t: f32) -> [f32; 4] {
    let t2 = t * t;
    let t3 = t2 * t;
    [
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    ]
}

/// One pixel's bilinear lookup: the indices of its four neighbours in a band's channel and the
/// weights of the right and lower ones.
struct Tap {
    top: [usize; 2],
    bottom: [usize; 2],
    fx: f32,
    fy: f32,
}

/// One pixel's Catmull-Rom lookup: the offsets of its four rows in a band's channel, its four
/// columns, and their weights.
struct CubicTap {
    rows: [usize; 4],
    cols: [usize; 4],
    wx: [f32; 4],
    wy: [f32; 4],
    /// The position past the second column and row (the bilinear weights).
    tx: f32,
    ty: f32,
}

impl CubicTap {
    /// The unclamped Catmull-Rom value of one channel.
    #[inline]
    fn cubic(&self, ch: &[f32]) -> f32 {
        let mut acc = 0.0;
        for (r, wy) in self.rows.iter().zip(self.wy) {
            let row = &ch[*r..];
            let v = row[self.cols[0]] * self.wx[0]
                + row[self.cols[1]] * self.wx[1]
                + row[self.cols[2]] * self.wx[2]
                + row[self.cols[3]] * self.wx[3];
            acc += v * wy;
        }
        acc
    }

    /// The bilinear value of one channel from the four nearest pixels.
    #[inline]
    fn bilinear(&self, ch: &[f32]) -> f32 {
        let (top, bottom) = (&ch[self.rows[1]..], &ch[self.rows[2]..]);
        let (c0, c1) = (self.cols[1], self.cols[2]);
        let a = top[c0] * (1.0 - self.tx) + top[c1] * self.tx;
        let b = bottom[c0] * (1.0 - self.tx) + bottom[c1] * self.tx;
        a * (1.0 - self.ty) + b * self.ty
    }

    /// [`CubicTap::sample`], and the blend `λ` that gives it from the bilinear value `b` and
    /// the cubic one `c` as `b + λ·(c − b)` (1 where the clamp did nothing).
    #[inline]
    fn sample_with_blend(&self, ch: &[f32]) -> (f32, f32) {
        let v = self.sample(ch);
        let c = self.cubic(ch);
        if v == c {
            return (v, 1.0);
        }
        let b = self.bilinear(ch);
        // b lies in the four pixels' range and c outside it, so c ≠ b and λ ∈ [0, 1)
        let lambda = ((v - b) / (c - b)).clamp(0.0, 1.0);
        (v, if lambda.is_finite() { lambda } else { 0.0 })
    }

    /// The value `b + λ·(c − b)` of one channel: linear in the channel, for planes that must
    /// keep summing to the plane `λ` came from.
    #[inline]
    fn blended(&self, ch: &[f32], lambda: f32) -> f32 {
        if lambda == 1.0 {
            return self.cubic(ch);
        }
        let b = self.bilinear(ch);
        b + lambda * (self.cubic(ch) - b)
    }

    /// The clamped Catmull-Rom value of one channel.
    #[inline]
    fn sample(&self, ch: &[f32]) -> f32 {
        let acc = self.cubic(ch);
        let near = [
            ch[self.rows[1] + self.cols[1]],
            ch[self.rows[1] + self.cols[2]],
            ch[self.rows[2] + self.cols[1]],
            ch[self.rows[2] + self.cols[2]],
        ];
        let lo = near.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = near.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        // (max then min: never panics, and a NaN neighbour cannot reach here, frames are
        // repaired when read)
        acc.max(lo).min(hi)
    }
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

    /// Warps `src` along a constant flow with the given resampling.
    fn shifted(src: &Plane, dx: f32, dy: f32, resampling: Resampling) -> Plane {
        let flow = Plane::from_fn(
            src.width(),
            src.height(),
            2,
            |_, _, c| {
                if c == 0 {
                    dx
                } else {
                    dy
                }
            },
        );
        warp_bands(&[Band::whole(src)], Band::whole(&flow), resampling).remove(0)
    }

    /// `out` is `src` moved `dx` pixels left and `dy` down, exactly, wherever both hold it.
    fn assert_copied(out: &Plane, src: &Plane, dx: usize, dy: usize) {
        for y in dy..src.height() {
            for x in 0..src.width() - dx {
                for c in 0..src.channels() {
                    assert_eq!(out.get(x, y, c), src.get(x + dx, y - dy, c), "{x},{y}");
                }
            }
        }
    }

    #[test]
    fn nearest_takes_the_closest_pixel_unblended() {
        let src = Plane::from_fn(16, 12, 2, |x, y, c| (x * 7 + y * 13 + c * 101) as f32);
        // 2.4 rounds to 2, -1.6 to -2: every value is a source pixel's, exactly
        assert_copied(&shifted(&src, 2.4, -1.6, Resampling::Nearest), &src, 2, 2);
        let out = shifted(&src, 0.6, 0.5, Resampling::Nearest);
        assert_eq!(out.get(4, 4, 1), src.get(5, 5, 1));
    }

    #[test]
    fn catmull_rom_copies_whole_pixel_shifts_and_reproduces_ramps() {
        let src = Plane::from_fn(16, 12, 2, |x, y, c| (x * 7 + y * 13 + c * 101) as f32);
        assert_copied(
            &shifted(&src, 3.0, -2.0, Resampling::CatmullRom),
            &src,
            3,
            2,
        );
        // a linear ramp at a subpixel shift, away from the clamped edges: exactly the ramp
        let ramp = Plane::from_fn(16, 12, 1, |x, y, _| 0.5 * x as f32 - 0.25 * y as f32);
        let out = shifted(&ramp, 0.3, 0.7, Resampling::CatmullRom);
        for y in 1..9 {
            for x in 1..13 {
                let want = 0.5 * (x as f32 + 0.3) - 0.25 * (y as f32 + 0.7);
                assert!((out.get(x, y, 0) - want).abs() < 1e-5, "{x},{y}");
            }
        }
    }

    #[test]
    fn catmull_rom_keeps_a_one_pixel_line_sharper_than_bilinear_without_overshoot() {
        // a vertical line one pixel wide on a dark ground, shifted a quarter pixel sideways
        let line = Plane::from_fn(16, 8, 1, |x, _, _| if x == 8 { 1.0 } else { 0.0 });
        let bilinear = shifted(&line, 0.25, 0.0, Resampling::Bilinear);
        let cubic = shifted(&line, 0.25, 0.0, Resampling::CatmullRom);
        // the line lands at x = 7.75: pixel 8 reads 0.75 bilinear, 0.867 Catmull-Rom
        assert!((bilinear.get(8, 4, 0) - 0.75).abs() < 1e-6);
        assert!((cubic.get(8, 4, 0) - 0.8671875).abs() < 1e-6);
        // the unclamped weights are negative two pixels out: clamping keeps them at 0
        assert!(cubic.data().iter().all(|&v| (0.0..=1.0).contains(&v)));
        // a step edge does not ring past either side
        let step = Plane::from_fn(16, 8, 1, |x, _, _| if x < 8 { 0.1 } else { 4.0 });
        let cubic = shifted(&step, 0.4, 0.3, Resampling::CatmullRom);
        assert!(cubic.data().iter().all(|&v| (0.1..=4.0).contains(&v)));
        assert!(cubic.get(3, 4, 0) == 0.1 && cubic.get(12, 4, 0) == 4.0);
    }

    #[test]
    fn catmull_rom_keeps_aovs_summing_to_the_beauty_where_the_clamp_acts() {
        // two AOVs with step edges at different places, the beauty their sum, warped by a
        // subpixel flow that varies per pixel: the clamp acts on each plane somewhere
        let (w, h) = (24, 16);
        let diffuse = Plane::from_fn(w, h, 3, |x, y, c| {
            if (x + y / 3) % 7 < 3 {
                0.05 + 0.1 * c as f32
            } else {
                2.0 + c as f32
            }
        });
        let specular = Plane::from_fn(w, h, 3, |x, y, c| {
            if (x * 2 + y) % 9 < 2 {
                8.0 - c as f32
            } else {
                0.02
            }
        });
        let beauty = Plane::from_fn(w, h, 3, |x, y, c| {
            diffuse.get(x, y, c) + specular.get(x, y, c)
        });
        let flow = Plane::from_fn(w, h, 2, |x, y, c| {
            [0.37 + 0.05 * (y % 5) as f32, -0.61 + 0.03 * (x % 4) as f32][c]
        });
        let bands = [
            Band::whole(&diffuse),
            Band::whole(&beauty),
            Band::whole(&specular),
        ];
        let summing = SummingPlanes {
            lead: 1,
            parts: vec![0, 2],
        };
        let flow_band = Band::whole(&flow);
        let linked = warp_bands_linked(&bands, flow_band, Resampling::CatmullRom, Some(&summing));
        let alone = warp_bands(&bands, flow_band, Resampling::CatmullRom);
        // the beauty is exactly what it was
        assert_eq!(linked[1].data(), alone[1].data());
        // clamped alone, the AOVs no longer sum to it; linked, they do
        let off = |d: &Plane, s: &Plane| {
            (0..beauty.data().len())
                .map(|i| (d.data()[i] + s.data()[i] - linked[1].data()[i]).abs())
                .fold(0.0f32, f32::max)
        };
        assert!(off(&alone[0], &alone[2]) > 0.1, "the clamp never acted");
        assert!(off(&linked[0], &linked[2]) < 1e-5);
        // bilinear is linear anyway and ignores the link
        let bl = warp_bands_linked(&bands, flow_band, Resampling::Bilinear, Some(&summing));
        assert_eq!(
            bl[0].data(),
            warp_bands(&bands, flow_band, Resampling::Bilinear)[0].data()
        );
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
        let together = warp_bands(&[band(&a), band(&b)], flow_band, Resampling::Bilinear);
        assert_eq!(together.len(), 2);
        for (got, src) in together.iter().zip([&a, &b]) {
            let alone = warp_band(band(src), flow_band);
            assert_eq!(got.channels(), src.channels());
            assert_eq!(got.data(), alone.data());
        }
        assert!(warp_bands(&[], flow_band, Resampling::CatmullRom).is_empty());
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
