//! The centre frame's input averaged over its aligned window before the U-Net's encoder
//! ([`TemporalConfig::input_frames`](crate::oidn_unet::temporal::TemporalConfig)): the window
//! holds several frames' samples, and the mean of the aligned frames carries them into the
//! U-Net in linear colour, where averaging Monte Carlo noise is unbiased. The windows are
//! aligned with centre mixing, so where alignment is unsure a side frame is already the centre
//! frame and the mean falls back to it.

use radn_core::align::AlignedWindow;
use radn_core::Plane;

/// The mean of the beauty and of each AOV over the `frames` aligned frames at the middle of
/// `win` (odd, at most the window's length): the planes the centre frame's encoder reads.
pub fn window_mean(win: &AlignedWindow, frames: usize) -> (Plane, Vec<Plane>) {
    assert!(
        frames % 2 == 1 && frames <= win.frames.len(),
        "an odd number of frames within the window"
    );
    let r = win.radius();
    let used = &win.frames[r - frames / 2..=r + frames / 2];
    let color = mean(used.iter().map(|f| &f.color));
    let aovs = (0..win.centre().aovs.len())
        .map(|a| mean(used.iter().map(|f| &f.aovs[a])))
        .collect();
    (color, aovs)
}

/// The pixelwise mean of `planes` (at least one, all of one size).
fn mean<'a>(mut planes: impl ExactSizeIterator<Item = &'a Plane>) -> Plane {
    let n = planes.len() as f32;
    let mut sum = planes.next().expect("at least one plane").clone();
    for p in planes {
        for (s, v) in sum.data_mut().iter_mut().zip(p.data()) {
            *s += v;
        }
    }
    sum.data_mut().iter_mut().for_each(|s| *s /= n);
    sum
}

#[cfg(test)]
mod tests {
    use super::*;
    use radn_core::align::AlignedFrame;

    fn frame(offset: i32, value: f32) -> AlignedFrame {
        let p = |c: usize, v: f32| Plane::filled(4, 3, c, v);
        AlignedFrame {
            offset,
            color: p(3, value),
            alpha: None,
            albedo: None,
            normal: None,
            depth: None,
            aovs: vec![p(1, 2.0 * value)],
            guide: None,
            variance: None,
            confidence: p(1, 1.0),
            flow: p(2, 0.0),
        }
    }

    #[test]
    fn the_mean_reads_only_the_middle_frames() {
        let win = AlignedWindow {
            frames: [100.0, 1.0, 2.0, 6.0, -50.0]
                .iter()
                .enumerate()
                .map(|(i, &v)| frame(i as i32 - 2, v))
                .collect(),
        };
        let (color, aovs) = window_mean(&win, 3);
        assert!(color.data().iter().all(|&v| v == 3.0));
        assert!(aovs[0].data().iter().all(|&v| v == 6.0));
        let (color, _) = window_mean(&win, 1);
        assert!(color.data().iter().all(|&v| v == 2.0));
        let (color, _) = window_mean(&win, 5);
        assert!(color.data().iter().all(|&v| (v - 59.0 / 5.0).abs() < 1e-5));
    }
}
