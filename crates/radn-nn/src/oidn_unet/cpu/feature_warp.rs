//! Pre-warping a window's encoder features to its centre frame on the CPU: the twin of
//! [`crate::oidn_unet::feature_warp`] (burn) for planar `f32` maps, with the same motion per
//! level (offsets averaged over each 2^k block and divided by 2^k, confidence averaged), the
//! same bilinear lookup (pixel centres, coordinates clamped to the map) and the same mix with
//! the centre's features where the confidence is below one.

use rayon::prelude::*;

use radn_core::image::plane::Plane;

/// How each frame of a window maps onto its centre, at one scale of a padded frame.
#[derive(Clone, Debug)]
pub struct HostMotion {
    width: usize,
    height: usize,
    /// Per frame: `[2, height, width]`, where each centre pixel lies in that frame, as (dx, dy)
    /// pixels from the same pixel.
    offsets: Vec<Vec<f32>>,
    /// Per frame: `[height, width]`, how far to trust the warped pixel, in [0, 1].
    confidence: Vec<Vec<f32>>,
}

impl HostMotion {
    /// The motion of a window at full resolution, padded to `width × height` (the network's
    /// padded frame) by repeating the frame's last column and row. `flows[k]` (two channels:
    /// dx, dy) and `confidences[k]` (one channel) are frame k's, of the frame's size.
    pub fn padded(flows: &[&Plane], confidences: &[&Plane], width: usize, height: usize) -> Self {
        assert_eq!(flows.len(), confidences.len(), "one confidence per flow");
        let pad = |p: &Plane, c: usize| -> Vec<f32> {
            let (w, h) = (p.width(), p.height());
            let src = p.channel(c);
            let mut out = vec![0.0f32; width * height];
            out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
                let sy = y.min(h - 1);
                for (x, v) in row.iter_mut().enumerate() {
                    *v = src[sy * w + x.min(w - 1)];
                }
            });
            out
        };
        Self {
            width,
            height,
            offsets: flows
                .iter()
                .map(|f| [pad(f, 0), pad(f, 1)].concat())
                .collect(),
            confidence: confidences.iter().map(|c| pad(c, 0)).collect(),
        }
    }

    /// The motion at pyramid level `level` (scale 1/2^level).
    pub fn at_level(&self, level: usize) -> HostMotion {
        let k = 1usize << level;
        assert!(
            self.width.is_multiple_of(k) && self.height.is_multiple_of(k),
            "a padded frame divides into 2^level blocks"
        );
        let (w, h) = (self.width / k, self.height / k);
        let pool = |src: &[f32], divide: f32| -> Vec<f32> {
            let mut out = vec![0.0f32; w * h];
            let area = (k * k) as f32;
            out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
                for (x, v) in row.iter_mut().enumerate() {
                    let mut sum = 0.0f32;
                    for yy in y * k..(y + 1) * k {
                        for xx in x * k..(x + 1) * k {
                            sum += src[yy * self.width + xx];
                        }
                    }
                    *v = sum / area / divide;
                }
            });
            out
        };
        let plane = self.width * self.height;
        HostMotion {
            width: w,
            height: h,
            offsets: self
                .offsets
                .iter()
                .map(|o| [pool(&o[..plane], k as f32), pool(&o[plane..], k as f32)].concat())
                .collect(),
            confidence: self.confidence.iter().map(|c| pool(c, 1.0)).collect(),
        }
    }

    /// Frame `frame`'s planar features (`[c, height, width]`) warped to the centre and mixed
    /// with the centre's features `centre` (same shape) by the confidence.
    pub fn to_centre(&self, frame: usize, features: &[f32], centre: &[f32]) -> Vec<f32> {
        let (w, h) = (self.width, self.height);
        let plane = w * h;
        assert_eq!(features.len() % plane, 0, "features at this level's scale");
        assert_eq!(features.len(), centre.len(), "the centre's features alike");
        let (ox, oy) = self.offsets[frame].split_at(plane);
        let conf = &self.confidence[frame];
        // each pixel's taps, found once for every channel: the top-left source pixel and the
        // offsets to its right and lower neighbours (0 at the map's edge), and the weights
        let taps: Vec<Tap> = (0..plane)
            .into_par_iter()
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let sx = (x as f32 + ox[i]).clamp(0.0, (w - 1) as f32);
                let sy = (y as f32 + oy[i]).clamp(0.0, (h - 1) as f32);
                let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
                Tap {
                    at: (y0 * w + x0) as u32,
                    right: u32::from(x0 + 1 < w),
                    down: if y0 + 1 < h { w as u32 } else { 0 },
                    fx: sx - x0 as f32,
                    fy: sy - y0 as f32,
                }
            })
            .collect();
        let mut out = vec![0.0f32; features.len()];
        out.par_chunks_mut(w).enumerate().for_each(|(row, dst)| {
            let (c, y) = (row / h, row % h);
            let src = &features[c * plane..][..plane];
            let mid = &centre[c * plane + y * w..][..w];
            let taps = &taps[y * w..][..w];
            let conf = &conf[y * w..][..w];
            for x in 0..w {
                let t = taps[x];
                let i = t.at as usize;
                let (r, d) = (t.right as usize, t.down as usize);
                let top = src[i] * (1.0 - t.fx) + src[i + r] * t.fx;
                let bottom = src[i + d] * (1.0 - t.fx) + src[i + d + r] * t.fx;
                let warped = top * (1.0 - t.fy) + bottom * t.fy;
                dst[x] = warped * conf[x] + mid[x] * (1.0 - conf[x]);
            }
        });
        out
    }
}

/// One pixel's bilinear lookup: the top-left source index, the steps to the right and lower
/// neighbours, and the fractions towards them.
#[derive(Clone, Copy)]
struct Tap {
    at: u32,
    right: u32,
    down: u32,
    fx: f32,
    fy: f32,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::oidn_unet::feature_warp::{to_centre, WindowMotion};
    use burn::tensor::{Device, Tensor, TensorData};

    /// The CPU warp equals burn's on the same features and motion, at a level above 0.
    #[test]
    fn equals_burns_warp_and_mix() {
        let (t, c, h, w) = (3usize, 2usize, 16usize, 16usize);
        let device = Device::flex();
        let flow = |k: usize| {
            Plane::from_fn(w, h, 2, |x, y, ch| {
                ((x * 3 + y * 5 + ch * 7 + k * 11) % 13) as f32 / 2.5 - 2.0
            })
        };
        let conf = |k: usize| Plane::from_fn(w, h, 1, |x, y, _| ((x + 2 * y + k) % 5) as f32 / 4.0);
        let flows: Vec<Plane> = (0..t).map(flow).collect();
        let confs: Vec<Plane> = (0..t).map(conf).collect();
        let host = HostMotion::padded(
            &flows.iter().collect::<Vec<_>>(),
            &confs.iter().collect::<Vec<_>>(),
            w,
            h,
        )
        .at_level(1);
        let (lw, lh) = (w / 2, h / 2);
        let features: Vec<f32> = (0..t * c * lh * lw)
            .map(|i| ((i * 7919) % 101) as f32 / 10.0)
            .collect();
        let to_tensor = |v: Vec<f32>, shape: [usize; 4]| -> Tensor<4> {
            Tensor::from_data(TensorData::new(v, shape), &device)
        };
        let motion = WindowMotion {
            offsets: to_tensor(
                flows.iter().flat_map(|f| f.data().to_vec()).collect(),
                [t, 2, h, w],
            ),
            confidence: to_tensor(
                confs.iter().flat_map(|f| f.data().to_vec()).collect(),
                [t, 1, h, w],
            ),
        }
        .at_level(1);
        let burn = to_centre(to_tensor(features.clone(), [t, c, lh, lw]), t, &motion)
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        let map = c * lh * lw;
        let centre = &features[map..2 * map];
        for k in 0..t {
            let cpu = host.to_centre(k, &features[k * map..][..map], centre);
            for (i, (a, b)) in cpu.iter().zip(&burn[k * map..][..map]).enumerate() {
                assert!((a - b).abs() < 1e-4, "frame {k} element {i}: {a} vs {b}");
            }
        }
    }
}
