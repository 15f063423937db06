//! Per-pixel image losses.

use burn::tensor::Tensor;

/// Symmetric mean absolute percentage error (Vogels et al. 2018): `|x − y| / (|x| + |y| + ε)`,
/// averaged; robust to the HDR range of renders.
pub fn smape(x: Tensor<4>, y: Tensor<4>) -> Tensor<1> {
    let num = (x.clone() - y.clone()).abs();
    let den = x.abs() + y.abs() + 1e-2;
    (num / den).mean()
}

/// Mean absolute error.
pub fn l1(x: Tensor<4>, y: Tensor<4>) -> Tensor<1> {
    (x - y).abs().mean()
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Device, TensorData};

    #[test]
    fn smape_and_l1_known_values() {
        let d = Device::flex();
        let x = Tensor::<4>::from_data(TensorData::new(vec![1.0f32, 2.0], [1, 1, 1, 2]), &d);
        let y = Tensor::<4>::from_data(TensorData::new(vec![3.0f32, 2.0], [1, 1, 1, 2]), &d);
        let s = smape(x.clone(), y.clone()).into_scalar::<f32>();
        assert!((s - (2.0 / 4.01) / 2.0).abs() < 1e-6);
        assert!((l1(x, y).into_scalar::<f32>() - 1.0).abs() < 1e-6);
    }
}
