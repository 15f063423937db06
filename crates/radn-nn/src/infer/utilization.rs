//! Temporal utilisation (paper Table 1 and Fig. 6): how much of each window frame a network's
//! kernels use, per pixel ([`super::NetworkDenoiser::utilization`]) and summed up over the
//! frames of a sequence ([`Utilization`]).

use radn_core::io::output::{write_png, PngColor};
use radn_core::Plane;

/// Kernel-weight statistics of each window frame over the frames of a sequence: the mean and
/// the largest weight over all pixels, and each frame's own means.
#[derive(Clone, Debug)]
pub struct Utilization {
    sum: Vec<f64>,
    max: Vec<f32>,
    pixels: usize,
    /// Per frame evaluated, in order: its number and the mean weight of each window frame.
    pub frames: Vec<(i64, Vec<f64>)>,
}

impl Utilization {
    /// Empty statistics for windows of `frames` frames.
    pub fn new(frames: usize) -> Self {
        Self {
            sum: vec![0.0; frames],
            max: vec![0.0; frames],
            pixels: 0,
            frames: Vec::new(),
        }
    }

    /// Adds frame `number`'s per-pixel weights of each window frame (`mass`, in window order,
    /// as [`super::NetworkDenoiser::utilization`] gives them).
    pub fn add(&mut self, number: i64, mass: &[Plane]) {
        assert_eq!(mass.len(), self.sum.len(), "one plane per window frame");
        let mut means = Vec::with_capacity(mass.len());
        for (k, m) in mass.iter().enumerate() {
            let s = m.data().iter().map(|&v| v as f64).sum::<f64>();
            self.sum[k] += s;
            self.max[k] = self.max[k].max(m.data().iter().copied().fold(0.0, f32::max));
            means.push(s / m.pixels() as f64);
        }
        self.pixels += mass[0].pixels();
        self.frames.push((number, means));
    }

    /// Window offsets from the centre (−2..=2 for five frames).
    pub fn offsets(&self) -> Vec<i64> {
        let t = self.sum.len() as i64;
        (0..t).map(|k| k - t / 2).collect()
    }

    /// Mean weight of each window frame over every pixel of every frame added.
    pub fn mean(&self) -> Vec<f64> {
        self.sum.iter().map(|s| s / self.pixels as f64).collect()
    }

    /// Largest weight of each window frame at any pixel.
    pub fn max(&self) -> &[f32] {
        &self.max
    }

    /// The table `radn eval --utilization` prints: offsets, then the mean and max rows.
    pub fn table(&self) -> String {
        let row = |label: &str, cells: String| format!("{label:>6} {cells}\n");
        row(
            "frame",
            self.offsets().iter().map(|o| format!("{o:>8}")).collect(),
        ) + &row(
            "avg",
            self.mean().iter().map(|m| format!("{m:>8.4}")).collect(),
        ) + &row(
            "max",
            self.max.iter().map(|m| format!("{m:>8.4}")).collect(),
        )
    }

    /// The statistics as JSON, with the model and input they were measured on.
    pub fn to_json(&self, model: &str, input: &str) -> String {
        let frames: Vec<serde_json::Value> = self
            .frames
            .iter()
            .map(|(f, m)| serde_json::json!({"frame": f, "mean": m}))
            .collect();
        let v = serde_json::json!({
            "model": model, "input": input, "offsets": self.offsets(),
            "avg": self.mean(), "max": self.max, "frames": frames,
        });
        serde_json::to_string_pretty(&v).expect("statistics serialise")
    }
}

/// Writes a weight map in [0, 1] as an 8-bit grey PNG (white = all weight on that frame).
pub fn write_heatmap(plane: &Plane, path: &std::path::Path) -> radn_core::Result<()> {
    let bytes: Vec<u8> = plane
        .data()
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    write_png(path, &bytes, plane.width(), plane.height(), PngColor::Grey)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn statistics_average_over_pixels_and_frames() {
        let mut u = Utilization::new(3);
        let p = |v: f32| Plane::filled(2, 2, 1, v);
        u.add(7, &[p(0.2), p(0.5), p(0.3)]);
        let mut skewed = p(0.1);
        skewed.set(0, 0, 0, 0.7);
        u.add(8, &[p(0.0), skewed, p(0.9)]);
        let m = u.mean();
        assert!(
            (m[0] - 0.1).abs() < 1e-6 && (m[1] - 0.375).abs() < 1e-6 && (m[2] - 0.6).abs() < 1e-6,
            "{m:?}"
        );
        assert_eq!(u.max(), &[0.2, 0.7, 0.9]);
        assert_eq!(u.offsets(), vec![-1, 0, 1]);
        assert_eq!(u.frames[1].0, 8);
        assert!(u.table().lines().count() == 3 && u.table().contains("0.3750"));
    }
}
