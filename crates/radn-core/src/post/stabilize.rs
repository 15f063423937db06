//! A temporal pass over a denoiser's results (a model recipe's `stabilize`): each frame's result
//! averaged with its neighbours' results aligned onto it, where they agree with it within the
//! error its own render noise leaves.
//!
//! A spatial denoiser's result differs from frame to frame by more than the scene does: it
//! reconstructs each frame's noise its own way, and that difference is the flicker. A guided
//! network averages what its window's motion vectors follow; where they fail (fur, grass, the
//! image through glass) its result, and the guide mixed into it, keep each frame's own error.
//! The aligned neighbours' results show the same surface with independent errors there, so
//! averaging them removes part of that error — but only where what differs is error, not
//! content: a detail a warp softened, a reflection that slid, a disocclusion.
//!
//! The test is a temporal bilateral filter whose range follows the noise. Side frame i of
//! the window gets, per pixel, the weight `exp(−(d/σ)²)`, where `d` is the Euclidean distance
//! between its aligned result and the centre's result in display space (each channel mapped
//! by [`tonemap`], as PSNR is measured), and `σ` is `strength` times the local RMS of the
//! centre's render noise — the difference between the centre frame as rendered and its result,
//! in mapped luminance, over a (2r+1)² box — never less than `floor`. Where a frame was noisy,
//! its result's error is large and neighbours that differ by as much are averaged; on clean
//! frames and flat, well-sampled regions σ shrinks and the result is kept. The colour distance
//! (not only luminance) keeps chroma that a luminance test would let through. Side frames that
//! cannot be aligned at all (beyond the sequence's ends, off screen, facing away: zero
//! confidence) are left out; otherwise the alignment's confidence is not used, since the range
//! term is the stricter test and confidence rejects exactly the fur whose flicker this removes.
//!
//! The same weights apply to alpha and every AOV, so AOVs that summed to the beauty still do.
//! Its settings are tuned per model (`radn_nn::recipe`).

use rayon::prelude::*;

use crate::align::warp::Resampling;
use std::ops::Range;

use crate::align::{align_bands, align_window, AlignParams, AlignedFrame, AlignedWindow};
use crate::error::{Error, Result};
use crate::eval::metrics::{tonemap, tonemap_plane};
use crate::image::ops::{box_mean, luminance};
use crate::image::plane::Plane;
use crate::io::frame::Frame;
use crate::run::banding::{FrameBand, FrameStats};
use crate::run::denoiser::{BandDenoiser, Denoised, WindowDenoiser};

/// The temporal pass's settings as model files keep them ([`TemporalStabilizer::new`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StabilizeSettings {
    /// σ in local RMS of the frame's render noise.
    pub strength: f32,
    /// The smallest σ.
    pub floor: f32,
    /// The noise box's radius.
    pub noise_radius: usize,
}

impl StabilizeSettings {
    /// The pass these settings describe.
    pub fn stabilizer(&self) -> TemporalStabilizer {
        TemporalStabilizer::new(self.strength, self.floor, self.noise_radius)
    }
}

/// The temporal pass over results ([module docs](self)).
#[derive(Clone, Debug)]
pub struct TemporalStabilizer {
    /// The range term's scale: σ is this many local RMS of the centre's render noise (in
    /// mapped luminance).
    pub strength: f32,
    /// The smallest σ, in mapped display values: a result whose input had no noise at all
    /// keeps neighbours only where they match it to this.
    pub floor: f32,
    /// Radius of the box over which the centre's render noise is measured.
    pub noise_radius: usize,
    /// Frames on each side of the centre.
    pub radius: usize,
    /// Output rows per band when the pass runs band by band.
    pub band_rows: usize,
    /// How the neighbours' results are aligned: the renderer's motion, Catmull-Rom resampling
    /// (a result is sharp, and bilinear sampling would soften what it averages in), side frames
    /// not mixed towards the centre (the range term decides).
    pub align: AlignParams,
}

impl TemporalStabilizer {
    /// The pass with range scale `strength`, smallest σ `floor` and noise box radius
    /// `noise_radius`, over two frames on each side like the network's window.
    pub fn new(strength: f32, floor: f32, noise_radius: usize) -> Self {
        Self {
            strength,
            floor,
            noise_radius,
            radius: 2,
            band_rows: 128,
            align: AlignParams {
                mix_centre: false,
                resampling: Resampling::CatmullRom,
                ..AlignParams::default()
            },
        }
    }

    /// σ per pixel: `strength` × the local RMS of (rendered − result) in mapped luminance, at
    /// least `floor`; `result_mapped` is the result already mapped by [`tonemap`].
    fn sigma(&self, rendered: &Plane, result_mapped: &Plane) -> Plane {
        let (w, h) = (result_mapped.width(), result_mapped.height());
        let lr = luminance(&tonemap_plane(rendered));
        let lc = luminance(result_mapped);
        let sq: Vec<f32> = lr
            .data()
            .par_iter()
            .zip(lc.data().par_iter())
            .map(|(a, b)| (a - b) * (a - b))
            .collect();
        let rms = box_mean(&Plane::from_vec(w, h, 1, sq), self.noise_radius);
        let s: Vec<f32> = rms
            .data()
            .par_iter()
            .map(|m| (self.strength * m.max(0.0).sqrt()).max(self.floor))
            .collect();
        Plane::from_vec(w, h, 1, s)
    }

    /// The weight of an aligned side frame per pixel against the centre's mapped result.
    fn weights(side: &AlignedFrame, centre_mapped: &Plane, sigma: &Plane) -> Vec<f32> {
        let n = centre_mapped.pixels();
        let (c, x) = (centre_mapped.data(), side.color.data());
        let (conf, s) = (side.confidence.data(), sigma.data());
        (0..n)
            .into_par_iter()
            .map(|i| {
                if conf[i] <= 0.0 {
                    return 0.0;
                }
                let d2: f32 = (0..3)
                    .map(|ch| {
                        let d = tonemap(x[ch * n + i]) - c[ch * n + i];
                        d * d
                    })
                    .sum();
                (-d2 / (s[i] * s[i])).exp()
            })
            .collect()
    }

    /// Stabilizes the result `window[radius]` (every frame of the window a result, with its
    /// motion and buffers as rendered) against its neighbours. The centre frame must carry its
    /// beauty as rendered ([`Frame::rendered`]), which sets the range.
    pub fn stabilize(&self, window: &[Option<&Frame>]) -> Result<Denoised> {
        let centre = window[window.len() / 2].expect("the centre frame of a window must exist");
        let rendered = rendered_of(centre)?;
        Ok(self.combine(&align_window(window, &self.align), rendered))
    }

    /// The weighted average of the aligned window `win` whose centre was rendered as
    /// `rendered` (its rows).
    fn combine(&self, win: &AlignedWindow, rendered: &Plane) -> Denoised {
        let c = win.centre();
        let centre_mapped = tonemap_plane(&c.color);
        let sigma = self.sigma(rendered, &centre_mapped);
        let sides: Vec<(&AlignedFrame, Vec<f32>)> = win
            .frames
            .iter()
            .filter(|f| f.offset != 0)
            .map(|f| (f, Self::weights(f, &centre_mapped, &sigma)))
            .collect();
        let n = c.color.pixels();
        let norm: Vec<f32> = (0..n)
            .into_par_iter()
            .map(|i| 1.0 / (1.0 + sides.iter().map(|(_, w)| w[i]).sum::<f32>()))
            .collect();
        let average = |pick: &(dyn Fn(&AlignedFrame) -> &Plane + Sync)| -> Plane {
            let mut out = pick(c).clone();
            let channels = out.channels();
            for ch in 0..channels {
                let dst = out.channel_mut(ch);
                dst.par_iter_mut().enumerate().for_each(|(i, v)| {
                    let sum: f32 = sides
                        .iter()
                        .map(|(f, w)| w[i] * pick(f).channel(ch)[i])
                        .sum();
                    *v = (*v + sum) * norm[i];
                });
            }
            out
        };
        Denoised {
            color: average(&|f| &f.color),
            alpha: c
                .alpha
                .as_ref()
                .map(|_| average(&|f| f.alpha.as_ref().expect("every frame has alpha"))),
            aovs: (0..c.aovs.len())
                .map(|k| average(&|f| &f.aovs[k]))
                .collect(),
        }
    }
}

/// The centre frame's beauty as rendered, which the pass needs beside its result.
fn rendered_of(centre: &Frame) -> Result<&Plane> {
    centre.rendered.as_ref().ok_or_else(|| Error::Unsupported {
        path: centre.path.clone(),
        detail: "the temporal pass over results needs the frame as rendered beside its result \
                 (it runs after a denoising pass)"
            .into(),
    })
}

impl BandDenoiser for TemporalStabilizer {
    fn band_rows(&self, _width: usize, limit: usize) -> usize {
        self.band_rows.min(limit).max(1)
    }

    fn halo(&self) -> usize {
        // the noise box, and the two rows at a cut that banded alignment gets wrong
        self.noise_radius + 2
    }

    fn denoise_band(
        &self,
        window: &[Option<FrameBand>],
        out: Range<usize>,
        _centre: &FrameStats,
    ) -> Result<Denoised> {
        let centre = window[window.len() / 2].expect("the centre band of a window must exist");
        let rendered = rendered_of(centre.frame)?;
        let d = crate::run::timing::timed("temporal pass", || {
            self.combine(&align_bands(window, &self.align), rendered)
        });
        Ok(Denoised {
            color: d.color.rows(out.clone()),
            alpha: d.alpha.map(|a| a.rows(out.clone())),
            aovs: d.aovs.into_iter().map(|a| a.rows(out.clone())).collect(),
        })
    }
}

impl WindowDenoiser for TemporalStabilizer {
    fn radius(&self) -> usize {
        self.radius
    }

    fn needs_rendered(&self) -> bool {
        true
    }

    fn denoise(&self, window: &[Option<&Frame>]) -> Result<Denoised> {
        crate::run::timing::timed("temporal pass", || self.stabilize(window))
    }

    fn banded(&self) -> Option<&dyn BandDenoiser> {
        Some(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::frame::Aov;

    const W: usize = 48;
    const H: usize = 32;

    /// A value in [−1, 1] that changes with every argument (independent per frame and pixel).
    fn hash(t: usize, x: usize, y: usize, salt: u32) -> f32 {
        let mut v = (t as u32).wrapping_mul(0x9E37_79B9)
            ^ (x as u32).wrapping_mul(0x85EB_CA6B)
            ^ (y as u32).wrapping_mul(0xC2B2_AE35)
            ^ salt.wrapping_mul(0x27D4_EB2F);
        v ^= v >> 15;
        v = v.wrapping_mul(0x2C1B_3C6D);
        v ^= v >> 12;
        v = v.wrapping_mul(0x297A_2D39);
        v ^= v >> 15;
        (v as f32 / u32::MAX as f32) * 2.0 - 1.0
    }

    /// The noise-free image of frame `t`: a texture moving one pixel to the right per frame.
    fn truth(t: usize) -> Plane {
        Plane::from_fn(W, H, 3, |x, y, c| {
            let u = x as f32 - t as f32;
            0.4 + 0.2 * (0.3 * u + c as f32).sin() * (0.2 * y as f32).cos()
        })
    }

    /// Frame `t` of a result sequence over [`truth`]: the result is the truth plus a
    /// per-frame error of `error` (independent from frame to frame, as a spatial denoiser's
    /// is), the render behind it the truth plus noise of `noise`; the motion vectors are
    /// exact.
    fn result_frame(t: usize, error: f32, noise: f32) -> Frame {
        let truth = truth(t);
        let result = Plane::from_fn(W, H, 3, |x, y, c| {
            truth.get(x, y, c) + error * hash(t, x, y, 1)
        });
        let rendered = Plane::from_fn(W, H, 3, |x, y, c| {
            (truth.get(x, y, c) + noise * hash(t, x, y, 2 + c as u32)).max(0.0)
        });
        let mut f = Frame::synthetic(result);
        f.motion_prev = Some(Plane::from_fn(W, H, 2, |_, _, c| [-1.0, 0.0][c]));
        f.motion_next = Some(Plane::from_fn(W, H, 2, |_, _, c| [1.0, 0.0][c]));
        f.rendered = Some(rendered);
        f
    }

    /// RMS of `a − b` over the pixels every side frame reaches (four columns in from each side).
    fn rms_inside(a: &Plane, b: &Plane) -> f32 {
        let mut sum = 0.0;
        let mut n = 0;
        for c in 0..3 {
            for y in 0..H {
                for x in 4..W - 4 {
                    sum += (a.get(x, y, c) - b.get(x, y, c)).powi(2);
                    n += 1;
                }
            }
        }
        (sum / n as f32).sqrt()
    }

    fn window(frames: &[Frame]) -> Vec<Option<&Frame>> {
        frames.iter().map(Some).collect()
    }

    #[test]
    fn a_results_frame_to_frame_error_is_averaged_away_where_its_render_was_noisy() {
        let frames: Vec<Frame> = (0..5).map(|t| result_frame(t, 0.01, 0.3)).collect();
        let out = TemporalStabilizer::new(0.3, 0.0005, 2)
            .stabilize(&window(&frames))
            .unwrap();
        let before = rms_inside(&frames[2].color, &truth(2));
        let after = rms_inside(&out.color, &truth(2));
        // five frames with independent errors: ideally 1/√5 ≈ 0.45 of the error
        assert!(after < 0.6 * before, "RMS error {before:.5} -> {after:.5}");
    }

    #[test]
    fn where_the_render_was_clean_or_the_image_really_changed_the_centres_result_is_kept() {
        // clean renders the denoiser kept as they were: the range is at its floor, far below
        // the frames' differences
        let mut frames: Vec<Frame> = (0..5)
            .map(|t| {
                let mut f = result_frame(t, 0.01, 0.0);
                f.rendered = Some(f.color.clone());
                f
            })
            .collect();
        let st = TemporalStabilizer::new(0.3, 0.0005, 2);
        let out = st.stabilize(&window(&frames)).unwrap();
        // only neighbours within the floor of the centre are averaged in: no pixel moves by
        // more than a tenth of the frames' error
        let kept = out
            .color
            .data()
            .iter()
            .zip(frames[2].color.data())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(kept < 1e-3, "clean frames changed by up to {kept}");
        // noisy renders, but a light brightens the side frames' right half: there the
        // centre's result is kept, while the left half is still averaged
        frames = (0..5).map(|t| result_frame(t, 0.01, 0.3)).collect();
        for (t, f) in frames.iter_mut().enumerate() {
            if t != 2 {
                for c in 0..3 {
                    for y in 0..H {
                        for x in W / 2..W {
                            let v = f.color.get(x, y, c);
                            f.color.set(x, y, c, v + 0.5);
                        }
                    }
                }
            }
        }
        let out = st.stabilize(&window(&frames)).unwrap();
        let centre = &frames[2].color;
        let (mut lit, mut unlit) = (0.0f32, 0.0f32);
        for c in 0..3 {
            for y in 0..H {
                for x in 4..W - 4 {
                    let d = (out.color.get(x, y, c) - centre.get(x, y, c)).abs();
                    if x >= W / 2 + 2 {
                        lit = lit.max(d);
                    } else if x < W / 2 - 2 {
                        unlit = unlit.max(d);
                    }
                }
            }
        }
        assert!(lit < 1e-3, "the brightened half moved by {lit}");
        assert!(
            unlit > 5e-3,
            "the unchanged half was not averaged ({unlit})"
        );
    }

    #[test]
    fn alpha_and_aovs_take_the_beauty_weights_so_they_still_sum_to_it() {
        let frames: Vec<Frame> = (0..5)
            .map(|t| {
                let mut f = result_frame(t, 0.01, 0.3);
                let share = |k: f32| Plane::from_fn(W, H, 3, |x, y, c| k * f.color.get(x, y, c));
                f.aovs = vec![
                    Aov {
                        name: "diffuse".into(),
                        channels: vec!["d.R".into(), "d.G".into(), "d.B".into()],
                        plane: share(0.3),
                    },
                    Aov {
                        name: "specular".into(),
                        channels: vec!["s.R".into(), "s.G".into(), "s.B".into()],
                        plane: share(0.7),
                    },
                ];
                f.alpha = Some(Plane::filled(W, H, 1, 1.0));
                f
            })
            .collect();
        let out = TemporalStabilizer::new(0.3, 0.0005, 2)
            .stabilize(&window(&frames))
            .unwrap();
        assert!(
            rms_inside(&out.color, &frames[2].color) > 1e-3,
            "nothing averaged"
        );
        let worst = (0..out.color.data().len())
            .map(|i| (out.aovs[0].data()[i] + out.aovs[1].data()[i] - out.color.data()[i]).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "AOVs differ from the beauty by {worst}");
        let alpha = out.alpha.unwrap();
        assert!(alpha.data().iter().all(|a| (a - 1.0).abs() < 1e-6));
    }

    #[test]
    fn sequence_ends_are_left_out_and_a_frame_without_its_render_is_named() {
        let frames: Vec<Frame> = (0..3).map(|t| result_frame(t + 2, 0.01, 0.3)).collect();
        // the first frame of a sequence: only the two later frames can be averaged in
        let first = [
            None,
            None,
            Some(&frames[0]),
            Some(&frames[1]),
            Some(&frames[2]),
        ];
        let out = TemporalStabilizer::new(0.3, 0.0005, 2)
            .stabilize(&first)
            .unwrap();
        let before = rms_inside(&frames[0].color, &truth(2));
        let after = rms_inside(&out.color, &truth(2));
        assert!(after < 0.75 * before, "RMS error {before:.5} -> {after:.5}");
        let mut bare = frames[0].clone();
        bare.rendered = None;
        bare.path = "shot/frame_0003.exr".into();
        let e = TemporalStabilizer::new(0.3, 0.0005, 2)
            .stabilize(&[None, None, Some(&bare), Some(&frames[1]), Some(&frames[2])])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("frame_0003.exr") && e.contains("as rendered"),
            "{e}"
        );
    }
}
