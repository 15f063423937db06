//! The perceptual loss of paper eq. 6: `(VGG19₅₄ + VGG19₃₄) · SMAPE`, with VGG19 ImageNet
//! weights the user supplies as SafeTensors in torchvision's layout (`features.{0,2,5,…}.weight`
//! and `.bias`). Nothing is downloaded; the network is frozen (it only shapes gradients).

use std::path::Path;

use burn::module::Module;
use burn::nn::conv::Conv2d;
use burn::store::{ModuleSnapshot, SafetensorsStore};
use burn::tensor::activation::relu;
use burn::tensor::module::max_pool2d;
use burn::tensor::ops::MaxPoolOptions;
use burn::tensor::{Device, Tensor};

use crate::loss::smape;
use radn_nn::error::{NnError, Result};
use radn_nn::model::layers::conv3;

/// Input and output channels of VGG19's sixteen 3×3 convolutions, in order.
const LAYERS: [(usize, usize); 16] = [
    (3, 64),
    (64, 64),
    (64, 128),
    (128, 128),
    (128, 256),
    (256, 256),
    (256, 256),
    (256, 256),
    (256, 512),
    (512, 512),
    (512, 512),
    (512, 512),
    (512, 512),
    (512, 512),
    (512, 512),
    (512, 512),
];
/// Their indices in torchvision's `vgg19().features`.
const TORCHVISION_INDEX: [usize; 16] = [0, 2, 5, 7, 10, 12, 14, 16, 19, 21, 23, 25, 28, 30, 32, 34];
/// Convolutions per block (a max-pool follows each block).
const BLOCKS: [usize; 5] = [2, 2, 4, 4, 4];

/// VGG19's convolutional part up to relu5_4.
#[derive(Module, Debug)]
pub struct Vgg19 {
    convs: Vec<Conv2d>,
}

impl Vgg19 {
    /// A randomly initialised network (weights are then loaded or, in tests, saved).
    pub fn new(device: &Device) -> Self {
        Self {
            convs: LAYERS.iter().map(|&(i, o)| conv3(i, o, device)).collect(),
        }
    }

    /// Loads torchvision-layout weights; every one of the 32 tensors must be present.
    pub fn load(path: &Path, device: &Device) -> Result<Self> {
        let mut net = Self::new(device);
        let mut store = SafetensorsStore::from_file(path).allow_partial(true);
        for (k, idx) in TORCHVISION_INDEX.iter().enumerate() {
            store = store.with_key_remapping(format!(r"^features\.{idx}\."), format!("convs.{k}."));
        }
        let r = net.load_from(&mut store).map_err(|e| NnError::Load {
            path: path.to_path_buf(),
            detail: format!("{e:?}"),
        })?;
        if !r.missing.is_empty() || !r.errors.is_empty() {
            return Err(NnError::Load {
                path: path.to_path_buf(),
                detail: format!(
                    "not VGG19 weights in torchvision's layout (features.N.weight/bias): {} of 32 tensors missing, {} mismatched",
                    r.missing.len(),
                    r.errors.len()
                ),
            });
        }
        Ok(net)
    }

    /// Saves in torchvision's layout (used by tests to make weight files).
    pub fn save_torchvision(&self, path: &Path) -> Result<()> {
        let mut store = SafetensorsStore::from_file(path).overwrite(true);
        for (k, idx) in TORCHVISION_INDEX.iter().enumerate() {
            store = store.with_key_remapping(format!(r"^convs\.{k}\."), format!("features.{idx}."));
        }
        self.save_into(&mut store).map_err(|e| NnError::Save {
            path: path.to_path_buf(),
            detail: format!("{e:?}"),
        })
    }

    /// Features after relu3_4 and relu5_4 of linear HDR images `[B, 3, H, W]` (tonemapped, then
    /// ImageNet-normalised).
    pub fn features(&self, x: Tensor<4>) -> (Tensor<4>, Tensor<4>) {
        let device = x.device();
        let x = x.clamp_min(0.0);
        let x = (x.clone() / (x + 1.0)).powf_scalar(1.0 / 2.2);
        let mean = Tensor::<1>::from_floats([0.485f32, 0.456, 0.406].as_slice(), &device)
            .reshape([1, 3, 1, 1]);
        let std = Tensor::<1>::from_floats([0.229f32, 0.224, 0.225].as_slice(), &device)
            .reshape([1, 3, 1, 1]);
        let mut h = (x - mean) / std;
        let mut k = 0;
        let mut relu34 = None;
        for (b, &n) in BLOCKS.iter().enumerate() {
            for _ in 0..n {
                h = relu(self.convs[k].forward(h));
                k += 1;
            }
            if b == 2 {
                relu34 = Some(h.clone());
            }
            if b < 4 {
                h = max_pool2d(h, MaxPoolOptions::new([2, 2]));
            }
        }
        (relu34.expect("block 3 ran"), h)
    }

    /// Paper eq. 6: `(L1(VGG₅₄) + L1(VGG₃₄)) · SMAPE`.
    pub fn loss(&self, x: Tensor<4>, y: Tensor<4>) -> Tensor<1> {
        let (x34, x54) = self.features(x.clone());
        let (y34, y54) = self.features(y.clone().detach());
        let perceptual = (x54 - y54).abs().mean() + (x34 - y34).abs().mean();
        perceptual * smape(x, y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    #[test]
    fn torchvision_layout_round_trips_and_the_loss_behaves() {
        let device = Device::flex();
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("vgg19.safetensors");
        let a = Vgg19::new(&device);
        a.save_torchvision(&p).unwrap();
        let b = Vgg19::load(&p, &device).unwrap();
        let x = Tensor::<4>::random([1, 3, 32, 32], Distribution::Uniform(0.0, 2.0), &device);
        let y = Tensor::<4>::random([1, 3, 32, 32], Distribution::Uniform(0.0, 2.0), &device);
        let (fa, fb) = (a.features(x.clone()).1, b.features(x.clone()).1);
        assert_eq!(
            fa.to_data().try_to_vec::<f32>().unwrap(),
            fb.to_data().try_to_vec::<f32>().unwrap()
        );
        assert_eq!(b.loss(x.clone(), x.clone()).into_scalar::<f32>(), 0.0);
        assert!(b.loss(x, y).into_scalar::<f32>() > 0.0);
        // a file without VGG's tensors is refused with a clear message
        let other = dir.path().join("other.safetensors");
        radn_nn::model::store::save(
            &radn_nn::Denoiser::new(radn_nn::NetConfig::preset("spatial").unwrap(), &device),
            &other,
        )
        .unwrap();
        let e = Vgg19::load(&other, &device).unwrap_err().to_string();
        assert!(
            e.contains("other.safetensors") && e.contains("torchvision"),
            "{e}"
        );
    }
}
