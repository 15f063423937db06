//! Planar f32 images: the unit every buffer of a frame is stored in.

/// A multi-channel f32 image stored channel-major (all of channel 0, then channel 1, ...).
///
/// Channel-major matches the network's NCHW tensors and lets per-channel work run on
/// contiguous slices.
#[derive(Clone, Debug, PartialEq)]
pub struct Plane {
    width: usize,
    height: usize,
    channels: usize,
    data: Vec<f32>,
}

impl Plane {
    /// A plane of the given size filled with `value`.
    pub fn filled(width: usize, height: usize, channels: usize, value: f32) -> Self {
        Self {
            width,
            height,
            channels,
            data: vec![value; width * height * channels],
        }
    }

    /// A plane of zeros.
    pub fn zeros(width: usize, height: usize, channels: usize) -> Self {
        Self::filled(width, height, channels, 0.0)
    }

    /// Wraps channel-major data; panics if the length does not match the size (a programming error).
    pub fn from_vec(width: usize, height: usize, channels: usize, data: Vec<f32>) -> Self {
        assert_eq!(
            data.len(),
            width * height * channels,
            "plane data length does not match its size"
        );
        Self {
            width,
            height,
            channels,
            data,
        }
    }

    /// Builds a plane from single-channel slices of equal length.
    pub fn from_channels(width: usize, height: usize, channels: &[&[f32]]) -> Self {
        let mut data = Vec::with_capacity(width * height * channels.len());
        for c in channels {
            assert_eq!(
                c.len(),
                width * height,
                "channel length does not match the plane size"
            );
            data.extend_from_slice(c);
        }
        Self {
            width,
            height,
            channels: channels.len(),
            data,
        }
    }

    /// A plane whose value at every pixel and channel is `f(x, y, c)`.
    pub fn from_fn(
        width: usize,
        height: usize,
        channels: usize,
        f: impl Fn(usize, usize, usize) -> f32,
    ) -> Self {
        let mut data = Vec::with_capacity(width * height * channels);
        for c in 0..channels {
            for y in 0..height {
                for x in 0..width {
                    data.push(f(x, y, c));
                }
            }
        }
        Self {
            width,
            height,
            channels,
            data,
        }
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Number of channels.
    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Pixels per channel.
    pub fn pixels(&self) -> usize {
        self.width * self.height
    }

    /// All samples, channel-major.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// All samples, channel-major, mutable.
    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }

    /// Consumes the plane and returns its channel-major samples.
    pub fn into_vec(self) -> Vec<f32> {
        self.data
    }

    /// One channel's samples, row-major.
    pub fn channel(&self, c: usize) -> &[f32] {
        let n = self.pixels();
        &self.data[c * n..(c + 1) * n]
    }

    /// One channel's samples, row-major, mutable.
    pub fn channel_mut(&mut self, c: usize) -> &mut [f32] {
        let n = self.pixels();
        &mut self.data[c * n..(c + 1) * n]
    }

    /// The sample at pixel (x, y) of channel c.
    #[inline]
    pub fn get(&self, x: usize, y: usize, c: usize) -> f32 {
        self.data[(c * self.height + y) * self.width + x]
    }

    /// Sets the sample at pixel (x, y) of channel c.
    #[inline]
    pub fn set(&mut self, x: usize, y: usize, c: usize, v: f32) {
        let (w, h) = (self.width, self.height);
        self.data[(c * h + y) * w + x] = v;
    }

    /// True when both planes have the same width and height (channels may differ).
    pub fn same_size(&self, other: &Plane) -> bool {
        self.width == other.width && self.height == other.height
    }

    /// A new plane holding channels `start..start + count` of this one.
    pub fn select_channels(&self, start: usize, count: usize) -> Plane {
        let n = self.pixels();
        Plane::from_vec(
            self.width,
            self.height,
            count,
            self.data[start * n..(start + count) * n].to_vec(),
        )
    }

    /// Stacks planes of equal size along the channel axis.
    pub fn concat(planes: &[&Plane]) -> Plane {
        let (w, h) = (planes[0].width, planes[0].height);
        let mut data = Vec::new();
        let mut channels = 0;
        for p in planes {
            assert!(
                p.width == w && p.height == h,
                "concatenated planes differ in size"
            );
            data.extend_from_slice(&p.data);
            channels += p.channels;
        }
        Plane::from_vec(w, h, channels, data)
    }

    /// Rows `rows` of every channel, as a plane of its own (a horizontal band).
    pub fn rows(&self, rows: std::ops::Range<usize>) -> Plane {
        assert!(rows.end <= self.height, "rows beyond the plane");
        let n = self.pixels();
        let (a, b) = (rows.start * self.width, rows.end * self.width);
        let mut data = Vec::with_capacity((b - a) * self.channels);
        for c in 0..self.channels {
            data.extend_from_slice(&self.data[c * n + a..c * n + b]);
        }
        Plane::from_vec(self.width, rows.len(), self.channels, data)
    }

    /// Copies out the rectangle starting at (x0, y0) of the given size; pixels outside
    /// the plane repeat the nearest edge pixel.
    pub fn crop_clamped(&self, x0: isize, y0: isize, width: usize, height: usize) -> Plane {
        let mut out = Plane::zeros(width, height, self.channels);
        for c in 0..self.channels {
            for y in 0..height {
                let sy = (y0 + y as isize).clamp(0, self.height as isize - 1) as usize;
                for x in 0..width {
                    let sx = (x0 + x as isize).clamp(0, self.width as isize - 1) as usize;
                    out.set(x, y, c, self.get(sx, sy, c));
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indexing_is_channel_major() {
        let p = Plane::from_fn(3, 2, 2, |x, y, c| (c * 100 + y * 10 + x) as f32);
        assert_eq!(p.get(2, 1, 1), 112.0);
        assert_eq!(p.channel(1)[0], 100.0);
        assert_eq!(p.data()[3 * 2 + 4], 111.0);
    }

    #[test]
    fn rows_cut_every_channel_alike() {
        let p = Plane::from_fn(3, 5, 2, |x, y, c| (c * 100 + y * 10 + x) as f32);
        let b = p.rows(1..4);
        assert_eq!((b.width(), b.height(), b.channels()), (3, 3, 2));
        assert_eq!(b.get(2, 0, 1), 112.0);
        assert_eq!(b.get(0, 2, 0), 30.0);
    }

    #[test]
    fn crop_repeats_edges() {
        let p = Plane::from_fn(4, 4, 1, |x, y, _| (y * 4 + x) as f32);
        let c = p.crop_clamped(-1, 2, 3, 3);
        assert_eq!(c.get(0, 0, 0), 8.0);
        assert_eq!(c.get(1, 0, 0), 8.0);
        assert_eq!(c.get(2, 2, 0), 13.0);
    }
}
