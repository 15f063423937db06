//! The training objective: Noise2Noise pairs of noise levels (paper section 6) and the
//! spatial-to-temporal loss conversion (paper section 5).

use burn::tensor::Tensor;
use serde::{Deserialize, Serialize};

use crate::dataset::{SplitMix, INPUT_LEVELS, TARGET_LEVELS};
use crate::loss::{l1, smape};
use radn_nn::model::demod::Demodulation;
use radn_nn::model::Prediction;

/// Which per-pixel loss.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum PixelLoss {
    /// Symmetric mean absolute percentage error.
    Smape,
    /// Mean absolute error.
    L1,
    /// Paper eq. 6: `(VGG19₅₄ + VGG19₃₄) · SMAPE` (needs VGG19 weights).
    Vgg,
}

/// A ready-to-use loss: a pixel loss, or the perceptual loss with its frozen VGG19.
pub enum LossFn {
    /// SMAPE or L1.
    Pixel(PixelLoss),
    /// The perceptual loss.
    Perceptual(Box<crate::vgg::Vgg19>),
}

impl LossFn {
    /// The loss of `x` against `y`.
    pub fn eval(&self, x: Tensor<4>, y: Tensor<4>) -> Tensor<1> {
        match self {
            LossFn::Pixel(PixelLoss::L1) => l1(x, y),
            LossFn::Pixel(_) => smape(x, y),
            LossFn::Perceptual(vgg) => vgg.loss(x, y),
        }
    }
}

/// How the window's kernels are turned into loss terms.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum LossMode {
    /// The paper's conversion: the centre frame alone, and pairs of one earlier and one later
    /// frame ({1,4} and {2,5} in a 5-frame window), each against the centre target.
    Temporal,
    /// The plain loss on the full window's output (the ablation's baseline).
    Spatial,
}

/// A Noise2Noise pair: input level index (into `INPUT_LEVELS`) and target level index (into
/// `TARGET_LEVELS`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Pair {
    /// Input level.
    pub input: usize,
    /// Target level.
    pub target: usize,
}

/// Noise rank of a level: higher is noisier (low 4 spp > half > high > pseudo-reference).
fn noise_rank(level: &str) -> u8 {
    match level {
        "low" => 3,
        "half" => 2,
        "high" => 1,
        _ => 0, // pseudo
    }
}

/// Which (input, target) pairs training draws from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PairRule {
    /// For which inputs (indexed like [`INPUT_LEVELS`]) the pseudo-reference may be the
    /// target. A teacher's output is the cleanest target but carries its blur: it helps most
    /// where the input is noisiest, so a rule may allow it for the `low` input alone.
    pub pseudo_for: [bool; INPUT_LEVELS.len()],
    /// An independent render noisier than the input may be a target too (`high → half`,
    /// `high → low`, `half → low`): Noise2Noise needs only independent, zero-mean noise in
    /// the target, not less of it, and these pairs are the only ones that show the network
    /// the least noisy input level.
    pub noisier_targets: bool,
    /// The pseudo-reference was made from the `high` render (the classic denoiser's, `radn
    /// pseudoref`), so `high → pseudo` would pair a render with itself. `false` for the OIDN
    /// teacher, an independent render.
    pub pseudo_from_high: bool,
}

/// Every valid pair under `rule`: never the same render, never `high → pseudo` when the
/// pseudo-reference is made from the `high` render, and the target less noisy than the input
/// unless `rule.noisier_targets` allows an independent noisier render.
pub fn valid_pairs(rule: PairRule) -> Vec<Pair> {
    let mut v = Vec::new();
    for (i, inp) in INPUT_LEVELS.iter().enumerate() {
        for (t, tgt) in TARGET_LEVELS.iter().enumerate() {
            let pseudo = *tgt == "pseudo";
            let independent = !(*inp == "high" && pseudo && rule.pseudo_from_high) && inp != tgt;
            let available = !pseudo || rule.pseudo_for[i];
            let direction = noise_rank(tgt) < noise_rank(inp) || (rule.noisier_targets && !pseudo);
            if direction && independent && available {
                v.push(Pair {
                    input: i,
                    target: t,
                });
            }
        }
    }
    v
}

/// Draws one pair uniformly among the valid ones.
pub fn sample_pair(rng: &mut SplitMix, rule: PairRule) -> Pair {
    let pairs = valid_pairs(rule);
    pairs[rng.below(pairs.len())]
}

/// The frame subsets of the temporal loss for a window of `frames`: the centre alone, then
/// pairs (i, i + centre + 1) of one earlier and one later frame.
pub fn loss_subsets(frames: usize) -> Vec<Vec<bool>> {
    let c = frames / 2;
    let mut subsets = vec![(0..frames).map(|i| i == c).collect::<Vec<bool>>()];
    for i in 0..c {
        subsets.push((0..frames).map(|j| j == i || j == i + c + 1).collect());
    }
    subsets
}

/// The loss of a prediction on the window's values against the centre target. With a
/// `demod`ulation the kernels filter the demodulated values and every estimate is remodulated
/// before it meets the target.
#[allow(clippy::too_many_arguments)]
pub fn objective(
    pred: &Prediction,
    values: Tensor<5>,
    target: Tensor<4>,
    demod: Option<&Demodulation>,
    mode: LossMode,
    loss: &LossFn,
    full_weight: f32,
    frames: usize,
) -> Tensor<1> {
    let values = match demod {
        Some(d) => d.demodulate(values),
        None => values,
    };
    let l = |x: Tensor<4>| {
        let x = match demod {
            Some(d) => d.remodulate(x),
            None => x,
        };
        loss.eval(x, target.clone())
    };
    match mode {
        LossMode::Spatial => l(pred.apply(values)),
        LossMode::Temporal => {
            let mut total: Option<Tensor<1>> = None;
            for mask in loss_subsets(frames) {
                if let Some(sub) = pred.subset(&mask) {
                    let term = l(sub.apply(values.clone()));
                    total = Some(match total {
                        Some(t) => t + term,
                        None => term,
                    });
                }
            }
            let total = total.expect("the centre-frame term always exists");
            if full_weight > 0.0 {
                total + l(pred.apply(values)) * full_weight
            } else {
                total
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, TensorData};
    use radn_nn::model::kernel::Kernels;

    #[test]
    fn pairs_never_target_a_noisier_or_the_same_render() {
        for pseudo in [false, true] {
            let rule = PairRule {
                pseudo_for: [pseudo; INPUT_LEVELS.len()],
                noisier_targets: false,
                pseudo_from_high: true,
            };
            let pairs = valid_pairs(rule);
            assert_eq!(pairs.len(), if pseudo { 5 } else { 3 });
            for p in &pairs {
                let (i, t) = (INPUT_LEVELS[p.input], TARGET_LEVELS[p.target]);
                assert!(noise_rank(t) < noise_rank(i), "{i} -> {t}");
                assert_ne!(i, t);
                assert!(!(i == "high" && t == "pseudo"), "pseudo is made from high");
            }
            let mut rng = SplitMix(7);
            for _ in 0..1000 {
                assert!(pairs.contains(&sample_pair(&mut rng, rule)));
            }
        }
    }

    #[test]
    fn an_independent_teacher_is_a_target_for_the_least_noisy_input_too() {
        let name = |p: &Pair| (INPUT_LEVELS[p.input], TARGET_LEVELS[p.target]);
        let rule = |from_high| PairRule {
            pseudo_for: [true; INPUT_LEVELS.len()],
            noisier_targets: false,
            pseudo_from_high: from_high,
        };
        let classic: Vec<_> = valid_pairs(rule(true)).iter().map(name).collect();
        let teacher: Vec<_> = valid_pairs(rule(false)).iter().map(name).collect();
        assert!(!classic.contains(&("high", "pseudo")));
        assert!(teacher.contains(&("high", "pseudo")));
        assert_eq!(teacher.len(), classic.len() + 1);
    }

    #[test]
    fn noisier_targets_add_every_other_independent_render() {
        let name = |p: &Pair| (INPUT_LEVELS[p.input], TARGET_LEVELS[p.target]);
        for pseudo in [false, true] {
            let pairs: Vec<_> = valid_pairs(PairRule {
                pseudo_for: [pseudo; INPUT_LEVELS.len()],
                noisier_targets: true,
                pseudo_from_high: true,
            })
            .iter()
            .map(name)
            .collect();
            // all 3 × 2 ordered pairs of distinct renders, plus low/half → pseudo
            assert_eq!(pairs.len(), if pseudo { 8 } else { 6 }, "{pairs:?}");
            for p in [("high", "half"), ("high", "low"), ("half", "low")] {
                assert!(pairs.contains(&p), "{p:?} missing");
            }
            assert!(!pairs.contains(&("high", "pseudo")));
            assert!(pairs.iter().all(|(i, t)| i != t));
        }
    }

    #[test]
    fn a_teacher_for_the_noisiest_input_only_is_no_target_for_the_others() {
        let name = |p: &Pair| (INPUT_LEVELS[p.input], TARGET_LEVELS[p.target]);
        let low = INPUT_LEVELS.iter().position(|&l| l == "low").unwrap();
        let mut pseudo_for = [false; INPUT_LEVELS.len()];
        pseudo_for[low] = true;
        let pairs: Vec<_> = valid_pairs(PairRule {
            pseudo_for,
            noisier_targets: true,
            pseudo_from_high: false,
        })
        .iter()
        .map(name)
        .collect();
        let to_pseudo: Vec<_> = pairs.iter().filter(|(_, t)| *t == "pseudo").collect();
        assert_eq!(to_pseudo, vec![&("low", "pseudo")]);
        // the six independent pairs stay
        assert_eq!(pairs.len(), 7, "{pairs:?}");
    }

    #[test]
    fn subsets_are_the_papers() {
        let s = loss_subsets(5);
        assert_eq!(s[0], vec![false, false, true, false, false]);
        assert_eq!(s[1], vec![true, false, false, true, false]); // frames {1, 4}, 1-based
        assert_eq!(s[2], vec![false, true, false, false, true]); // frames {2, 5}
        assert_eq!(s.len(), 3);
        assert_eq!(
            loss_subsets(3),
            vec![vec![false, true, false], vec![true, false, true]]
        );
    }

    #[test]
    fn temporal_loss_uses_exactly_those_subsets() {
        // 1×1 kernels, 5 frames, one pixel; frame j holds the value j; the kernel weights
        // (0.1, 0.2, 0.4, 0.2, 0.1); the target is 0
        let d = Device::flex();
        let k = Kernels {
            weights: Tensor::from_data(
                TensorData::new(vec![0.1f32, 0.2, 0.4, 0.2, 0.1], [1, 5, 1, 1]),
                &d,
            ),
            frames: 5,
            size: 1,
        };
        let pred = Prediction::Single(k);
        let values = Tensor::<5>::from_data(
            TensorData::new(vec![0.0f32, 1.0, 2.0, 3.0, 4.0], [1, 5, 1, 1, 1]),
            &d,
        );
        let target = Tensor::<4>::zeros([1, 1, 1, 1], &d);
        let got = objective(
            &pred,
            values.clone(),
            target.clone(),
            None,
            LossMode::Temporal,
            &LossFn::Pixel(PixelLoss::L1),
            0.0,
            5,
        )
        .into_scalar::<f32>();
        // centre alone: 2; {1,4}: (0.1·0 + 0.2·3)/0.3 = 2; {2,5}: (0.2·1 + 0.1·4)/0.3 = 2
        assert!((got - 6.0).abs() < 1e-5, "{got}");
        let spatial = objective(
            &pred,
            values.clone(),
            target.clone(),
            None,
            LossMode::Spatial,
            &LossFn::Pixel(PixelLoss::L1),
            0.0,
            5,
        )
        .into_scalar::<f32>();
        assert!((spatial - 2.0).abs() < 1e-5); // 0.2 + 0.8 + 0.6 + 0.4 = 2
        let with_full = objective(
            &pred,
            values.clone(),
            target.clone(),
            None,
            LossMode::Temporal,
            &LossFn::Pixel(PixelLoss::L1),
            0.5,
            5,
        )
        .into_scalar::<f32>();
        assert!((with_full - 7.0).abs() < 1e-5);
    }
}
