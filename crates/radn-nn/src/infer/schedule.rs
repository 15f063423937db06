//! The noise-level schedule: how settings tuned for the cleanest frames follow a frame's noise
//! level ([`radn_core::image::noise_level`]). One object, given to every stage that follows the level
//! (the input blend, alignment's colour and sampled-buffer terms, the guide mix's range and its
//! choice of guide), so that retuning it retunes them together and on purpose.
//!
//! The level is gathered over the whole frame, so bands and tiles of a frame get the same
//! values.

use serde::{Deserialize, Serialize};

/// A noise scale that grows with the frame's noise level, and the level above which a frame is
/// too noisy for level-following settings at all.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoiseSchedule {
    /// The smallest noise scale (that of the cleanest frames).
    pub min_scale: f32,
    /// The noise level at and below which the scale is `min_scale`.
    pub level_at_min: f32,
    /// How steeply the scale grows with the level above `level_at_min` (a power).
    pub exponent: f32,
    /// Above this scale a frame counts as too noisy: the level-following settings leave it.
    pub max_scale: f32,
}

impl NoiseSchedule {
    /// A schedule for tests and examples: the values the shipped recipes hold.
    #[cfg(test)]
    pub(crate) fn example() -> Self {
        Self {
            min_scale: 2.0,
            level_at_min: 0.25,
            exponent: 1.0,
            max_scale: 8.0,
        }
    }

    /// The noise scale of a frame of noise level `level`:
    /// `min_scale · max(1, level / level_at_min)^exponent`; `None` above `max_scale` or for a
    /// frame without a level (black).
    pub fn noise_scale(&self, level: Option<f32>) -> Option<f32> {
        let level = level.filter(|l| l.is_finite())?;
        let k = self.min_scale * (level / self.level_at_min).max(1.0).powf(self.exponent);
        (k <= self.max_scale).then_some(k)
    }

    /// How many times a tolerance set for the cleanest frames loosens for a frame of noise
    /// level `level`: the noise scale over its smallest (1 at the cleanest frames, up to
    /// `max_scale / min_scale`); `None` for frames too noisy for the schedule.
    pub fn loosening(&self, level: Option<f32>) -> Option<f32> {
        self.noise_scale(level).map(|k| k / self.min_scale)
    }

    /// The noise level at which the schedule reaches `max_scale`: frames above it are too noisy.
    pub fn noisiest_level(&self) -> f32 {
        self.level_at_min * (self.max_scale / self.min_scale).powf(1.0 / self.exponent)
    }

    /// Checks that the schedule is usable: positive, finite, growing.
    pub fn validate(&self) -> Result<(), String> {
        let v = [
            self.min_scale,
            self.level_at_min,
            self.exponent,
            self.max_scale,
        ];
        if v.iter().any(|x| !x.is_finite() || *x <= 0.0) || self.max_scale < self.min_scale {
            return Err(format!(
                "the noise schedule needs positive values and max-scale >= min-scale: {self:?}"
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scale_grows_with_the_level_and_a_noisy_frame_gets_none() {
        let s = NoiseSchedule::example();
        assert_eq!(s.noise_scale(Some(1e-4)), Some(s.min_scale));
        let middle = s.noise_scale(Some(s.level_at_min * 2.0)).unwrap();
        assert!(middle > s.min_scale && middle <= s.max_scale);
        let edge = s.noisiest_level();
        assert_eq!(s.noise_scale(Some(edge)), Some(s.max_scale));
        assert_eq!(s.noise_scale(Some(1.01 * edge)), None);
        assert_eq!(s.noise_scale(None), None);
        assert_eq!(s.noise_scale(Some(f32::NAN)), None);
        assert_eq!(s.loosening(Some(1e-4)), Some(1.0));
        assert_eq!(s.loosening(Some(edge)), Some(s.max_scale / s.min_scale));
    }

    #[test]
    fn a_bad_schedule_is_refused() {
        let mut s = NoiseSchedule::example();
        assert!(s.validate().is_ok());
        s.max_scale = 1.0;
        assert!(s.validate().is_err());
    }
}
