//! How a window's signals travel through the kernels and every stage after them: stacked along
//! channels as the beauty (3 channels), each AOV (its own count), then alpha (1). One
//! description, so the kernels, the input blend and the guide mix agree on which channels are
//! which, and AOVs keep summing to the beauty.

use std::ops::Range;

use radn_core::align::AlignedWindow;
use radn_core::run::denoiser::Denoised;
use radn_core::Plane;

/// The channel layout of a window's signals.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Signals {
    /// Channels of each AOV, in the frames' order.
    pub aovs: Vec<usize>,
    /// Whether alpha follows them.
    pub alpha: bool,
}

impl Signals {
    /// The layout of `win`'s centre frame (every frame of a window has the same).
    pub fn of(win: &AlignedWindow) -> Self {
        let c = win.centre();
        Self {
            aovs: c.aovs.iter().map(|a| a.channels()).collect(),
            alpha: c.alpha.is_some(),
        }
    }

    /// Channels in all.
    pub fn channels(&self) -> usize {
        3 + self.aovs.iter().sum::<usize>() + usize::from(self.alpha)
    }

    /// The first channel of each three-channel AOV (colour AOVs, which take the beauty's gains).
    pub fn rgb_aovs(&self) -> Vec<usize> {
        let mut at = 3;
        let mut out = Vec::new();
        for &n in &self.aovs {
            if n == 3 {
                out.push(at);
            }
            at += n;
        }
        out
    }

    /// The first channel of the beauty and of each three-channel AOV (what albedo
    /// demodulation divides).
    pub fn rgb_groups(&self) -> Vec<usize> {
        std::iter::once(0).chain(self.rgb_aovs()).collect()
    }

    /// The centre frame's signals at rows `rows`, stacked in this layout.
    pub fn centre_values(win: &AlignedWindow, rows: Range<usize>) -> Plane {
        let c = win.centre();
        let mut planes = vec![c.color.rows(rows.clone())];
        planes.extend(c.aovs.iter().map(|a| a.rows(rows.clone())));
        planes.extend(c.alpha.iter().map(|a| a.rows(rows.clone())));
        Plane::concat(&planes.iter().collect::<Vec<_>>())
    }

    /// The result `out`, stacked in this layout, as a frame's beauty, AOVs and alpha.
    pub fn split(&self, out: &Plane) -> Denoised {
        let color = out.select_channels(0, 3);
        let mut at = 3;
        let aovs = self
            .aovs
            .iter()
            .map(|&n| {
                let p = out.select_channels(at, n);
                at += n;
                p
            })
            .collect();
        let alpha = self.alpha.then(|| out.select_channels(at, 1));
        Denoised { color, alpha, aovs }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn channels_and_groups_follow_the_stacking() {
        let s = Signals {
            aovs: vec![3, 1, 3],
            alpha: true,
        };
        assert_eq!(s.channels(), 3 + 7 + 1);
        assert_eq!(s.rgb_aovs(), vec![3, 7]);
        assert_eq!(s.rgb_groups(), vec![0, 3, 7]);
        let p = Plane::from_fn(2, 1, s.channels(), |_, _, c| c as f32);
        let d = s.split(&p);
        assert_eq!(d.aovs.len(), 3);
        assert_eq!(d.aovs[1].channel(0)[0], 6.0);
        assert_eq!(d.alpha.unwrap().channel(0)[0], 10.0);
    }
}
