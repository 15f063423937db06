//! Whether training moves every layer: per layer, the norm of its weights, of its gradient and
//! of one optimizer step's update relative to the weights, logged to `layers.csv` beside
//! `metrics.csv` (and plotted in `curves.png`). A layer whose update ratio stays orders of
//! magnitude below the others' is a layer the network does not learn with.

use std::io::Write;
use std::path::Path;

use burn::tensor::{Gradients, Tensor};

use radn_nn::error::{NnError, Result};

/// One layer's training signal at one step.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerStat {
    /// Layer name ([`radn_nn::model::Denoiser::layer_weights`]).
    pub layer: String,
    /// ‖w‖ before the step.
    pub weight_norm: f64,
    /// ‖∂loss/∂w‖.
    pub grad_norm: f64,
    /// ‖w_after − w_before‖ / ‖w_before‖: how far the step moved the layer.
    pub update_ratio: f64,
}

/// The Euclidean norm of a tensor's values.
pub fn norm(t: Tensor<4>) -> f64 {
    (t.detach().powf_scalar(2.0).sum().into_scalar::<f32>() as f64).sqrt()
}

/// The gradient norm of each of `weights` (0 where a layer got no gradient).
pub fn gradient_norms(weights: &[(String, Tensor<4>)], grads: &Gradients) -> Vec<f64> {
    weights
        .iter()
        .map(|(_, w)| w.grad(grads).map_or(0.0, norm))
        .collect()
}

/// ‖b − a‖ / ‖a‖ for each pair of same-named weights (two states of one network).
pub fn relative_changes(
    a: &[(String, Tensor<4>)],
    b: &[(String, Tensor<4>)],
) -> Vec<(String, f64)> {
    a.iter()
        .zip(b)
        .map(|((name, wa), (nb, wb))| {
            assert_eq!(name, nb, "the same network's layers");
            let base = norm(wa.clone()).max(f64::MIN_POSITIVE);
            (
                name.clone(),
                norm(wb.clone().detach() - wa.clone().detach()) / base,
            )
        })
        .collect()
}

/// The statistics of one step from the weights before it, their gradient norms and the
/// weights after it.
pub fn step_stats(
    before: &[(String, Tensor<4>)],
    grad_norms: &[f64],
    after: &[(String, Tensor<4>)],
) -> Vec<LayerStat> {
    relative_changes(before, after)
        .into_iter()
        .zip(before.iter().zip(grad_norms))
        .map(|((layer, update_ratio), ((_, w), &grad_norm))| LayerStat {
            layer,
            weight_norm: norm(w.clone()),
            grad_norm,
            update_ratio,
        })
        .collect()
}

/// The header of `layers.csv`.
pub const CSV_HEADER: &str = "step,layer,weight_norm,grad_norm,update_ratio";

/// Appends one step's rows to `path` (the header written once).
pub fn append_csv(path: &Path, step: usize, stats: &[LayerStat]) -> Result<()> {
    let err = |e: std::io::Error| NnError::Save {
        path: path.to_path_buf(),
        detail: e.to_string(),
    };
    let new = !path.exists();
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(err)?;
    let mut text = String::new();
    if new {
        text.push_str(CSV_HEADER);
        text.push('\n');
    }
    for s in stats {
        text.push_str(&format!(
            "{step},{},{:.6e},{:.6e},{:.6e}\n",
            s.layer, s.weight_norm, s.grad_norm, s.update_ratio
        ));
    }
    f.write_all(text.as_bytes()).map_err(err)
}

/// The rows of a `layers.csv`: (step, layer, update ratio), in file order.
pub fn read_update_ratios(path: &Path) -> Vec<(usize, String, f64)> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Vec::new();
    };
    text.lines()
        .skip(1)
        .filter_map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            Some((
                f.first()?.parse().ok()?,
                f.get(1)?.to_string(),
                f.get(4)?.parse().ok()?,
            ))
        })
        .collect()
}

/// The group a layer is plotted in: the backbone's convolutions, its Robust Average blocks, or
/// the kernel head(s).
pub fn layer_group(layer: &str) -> &'static str {
    if layer.contains(".ra") {
        "RA blocks"
    } else if layer.starts_with("backbone.") {
        "backbone convs"
    } else {
        "kernel head"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, TensorData};

    fn t(v: &[f32]) -> Tensor<4> {
        Tensor::from_data(
            TensorData::new(v.to_vec(), [1, 1, 1, v.len()]),
            &Device::flex(),
        )
    }

    #[test]
    fn statistics_measure_how_far_a_step_moved_each_layer() {
        let before = vec![
            ("a".to_string(), t(&[3.0, 4.0])),
            ("b".to_string(), t(&[1.0, 0.0])),
        ];
        let after = vec![
            ("a".to_string(), t(&[3.0, 4.5])),
            ("b".to_string(), t(&[1.0, 0.0])),
        ];
        let s = step_stats(&before, &[2.0, 0.0], &after);
        assert!((s[0].weight_norm - 5.0).abs() < 1e-6);
        assert!((s[0].update_ratio - 0.1).abs() < 1e-6, "{s:?}");
        assert_eq!(s[1].update_ratio, 0.0);
        assert_eq!(s[0].grad_norm, 2.0);
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("layers.csv");
        append_csv(&p, 3, &s).unwrap();
        append_csv(&p, 4, &s).unwrap();
        let rows = read_update_ratios(&p);
        assert_eq!(rows.len(), 4);
        assert_eq!((rows[2].0, rows[2].1.as_str()), (4, "a"));
        assert!((rows[2].2 - 0.1).abs() < 1e-6);
        assert_eq!(
            std::fs::read_to_string(&p).unwrap().lines().next(),
            Some(CSV_HEADER)
        );
    }

    #[test]
    fn layers_are_grouped_for_the_plot() {
        assert_eq!(layer_group("backbone.ra2.weight"), "RA blocks");
        assert_eq!(layer_group("backbone.block3.a"), "backbone convs");
        assert_eq!(layer_group("head"), "kernel head");
        assert_eq!(layer_group("temporal_a"), "kernel head");
    }
}
