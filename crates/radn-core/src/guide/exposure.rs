//! The exposure OIDN gives an HDR beauty (its `inputScale` when left automatic), gathered band
//! by band: a frame whose guide is filtered in bands must be filtered at the whole frame's
//! exposure, or each band would be scaled by its own and the guide would step at band seams.
//!
//! OIDN's autoexposure splits the image into bins of at most 16 × 16 pixels (bin `i` of `n`
//! spans rows `i·H/n .. (i+1)·H/n`, columns likewise), takes each bin's mean luminance
//! (Rec. 709 weights, NaN as 0, negative as 0), and returns 0.18 / 2^(mean log2 of the bins
//! brighter than 1e-8). The sums here are in f64, so the result can differ from OIDN's own in
//! its last bits.

use crate::image::plane::Plane;

/// OIDN's largest autoexposure bin side.
const MAX_BIN: usize = 16;
/// The mid-grey OIDN maps the frame's log-average luminance to.
const KEY: f64 = 0.18;
/// Bins darker than this are left out.
const EPS: f64 = 1e-8;

/// Luminance sums per autoexposure bin of one frame, filled by rows in any band order.
#[derive(Clone, Debug)]
pub struct ExposureBins {
    width: usize,
    height: usize,
    bins_w: usize,
    bins_h: usize,
    sums: Vec<f64>,
}

impl ExposureBins {
    /// Empty bins for a `width × height` frame.
    pub fn new(width: usize, height: usize) -> Self {
        let bins_w = width.div_ceil(MAX_BIN).max(1);
        let bins_h = height.div_ceil(MAX_BIN).max(1);
        Self {
            width,
            height,
            bins_w,
            bins_h,
            sums: vec![0.0; bins_w * bins_h],
        }
    }

    /// The bin of row or column `v` of `size`, split into `bins`.
    fn bin_of(v: usize, size: usize, bins: usize) -> usize {
        // the largest i with i·size/bins <= v
        let mut i = (v * bins) / size;
        while i + 1 < bins && (i + 1) * size / bins <= v {
            i += 1;
        }
        while i > 0 && i * size / bins > v {
            i -= 1;
        }
        i
    }

    /// Adds the rows of `band`, whose first row is frame row `y0`: an RGB image, or any other
    /// as the grey of its channels' mean (how a one-channel AOV is given to an RGB network).
    pub fn add_rows(&mut self, y0: usize, band: &Plane) {
        assert_eq!(band.width(), self.width, "a band is as wide as its frame");
        let channels = band.channels();
        assert!(channels >= 1, "an image has channels");
        let col_bin: Vec<usize> = (0..self.width)
            .map(|x| Self::bin_of(x, self.width, self.bins_w))
            .collect();
        let c = |v: f32| {
            if v.is_nan() {
                0.0
            } else {
                v.clamp(0.0, f32::MAX) as f64
            }
        };
        let luminance =
            |r: f32, g: f32, b: f32| 0.212671 * c(r) + 0.715160 * c(g) + 0.072169 * c(b);
        for y in 0..band.height() {
            let row_bin = Self::bin_of(y0 + y, self.height, self.bins_h);
            let sums = &mut self.sums[row_bin * self.bins_w..(row_bin + 1) * self.bins_w];
            let base = y * self.width;
            if channels == 3 {
                let (r, g, b) = (band.channel(0), band.channel(1), band.channel(2));
                for x in 0..self.width {
                    let i = base + x;
                    sums[col_bin[x]] += luminance(r[i], g[i], b[i]);
                }
            } else {
                for x in 0..self.width {
                    let i = base + x;
                    let grey =
                        (0..channels).map(|k| band.channel(k)[i]).sum::<f32>() / channels as f32;
                    sums[col_bin[x]] += luminance(grey, grey, grey);
                }
            }
        }
    }

    /// OIDN's exposure for the frame whose rows were all added.
    pub fn exposure(&self) -> f32 {
        let (mut sum, mut count) = (0.0f64, 0usize);
        for i in 0..self.bins_h {
            let rows = (i + 1) * self.height / self.bins_h - i * self.height / self.bins_h;
            for j in 0..self.bins_w {
                let cols = (j + 1) * self.width / self.bins_w - j * self.width / self.bins_w;
                let mean = self.sums[i * self.bins_w + j] / (rows * cols).max(1) as f64;
                if mean > EPS {
                    sum += mean.log2();
                    count += 1;
                }
            }
        }
        if count == 0 {
            1.0
        } else {
            (KEY / (sum / count as f64).exp2()) as f32
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_cover_every_row_once_in_order() {
        for (size, bins) in [(100, 7), (1080, 68), (16, 1), (17, 2), (5, 1)] {
            let of: Vec<usize> = (0..size)
                .map(|v| ExposureBins::bin_of(v, size, bins))
                .collect();
            for (v, &i) in of.iter().enumerate() {
                assert!(
                    i * size / bins <= v && v < (i + 1) * size / bins,
                    "{size} {bins} {v}"
                );
            }
        }
    }

    #[test]
    fn bands_in_any_order_give_the_whole_frames_exposure() {
        let p = Plane::from_fn(70, 45, 3, |x, y, c| {
            ((x * 7 + y * 13 + c * 5) % 17) as f32 * 0.1 + if x > 50 { 4.0 } else { 0.0 }
        });
        let mut whole = ExposureBins::new(70, 45);
        whole.add_rows(0, &p);
        let mut banded = ExposureBins::new(70, 45);
        for (a, b) in [(30, 45), (0, 11), (11, 30)] {
            banded.add_rows(a, &p.rows(a..b));
        }
        assert_eq!(whole.exposure(), banded.exposure());
        // a uniform frame of luminance L gets 0.18 / L
        let grey = Plane::from_fn(40, 20, 3, |_, _, _| 0.5);
        let mut e = ExposureBins::new(40, 20);
        e.add_rows(0, &grey);
        assert!((e.exposure() - 0.36).abs() < 1e-5, "{}", e.exposure());
        // black frames keep their scale
        let mut dark = ExposureBins::new(8, 8);
        dark.add_rows(0, &Plane::from_fn(8, 8, 3, |_, _, _| 0.0));
        assert_eq!(dark.exposure(), 1.0);
    }
}
