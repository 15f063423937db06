//! Gradients reach every RA block, and the `small` network can overfit one real window.

use std::path::PathBuf;

use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::{Device, Tensor, TensorData};
use radn_core::align::{align_window, AlignParams};
use radn_core::io::frame::{Frame, FrameReader, Requirements};
use radn_core::io::mapping::ChannelMapping;
use radn_nn::infer::input::{color_values, features};
use radn_nn::model::config::INPUT_CHANNELS;
use radn_nn::{Denoiser, NetConfig};
use radn_train::loss::smape;

fn sample(level: &str, f: i64) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!(
        "../../samples/cycles-sample/{level}/frame_{f:04}.exr"
    ))
}

/// A 32×32 crop of the sample's aligned window around frame 5 (4 spp) and the 1024-spp
/// reference of frame 5: (features, values, target).
fn crop_window(device: &Device) -> (Tensor<5>, Tensor<5>, Tensor<4>) {
    let r = FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::DENOISE,
    );
    let frames: Vec<Frame> = (3..=7)
        .map(|f| r.read(&sample("low", f)).unwrap().0)
        .collect();
    let win = align_window(
        &frames.iter().map(Some).collect::<Vec<_>>(),
        &AlignParams::default(),
    );
    let reference = FrameReader::new(
        ChannelMapping::builtin("cycles").unwrap(),
        Requirements::COLOR_ONLY,
    )
    .read(&sample("ref", 5))
    .unwrap()
    .0;
    let (w, h) = (win.centre().color.width(), win.centre().color.height());
    let (x0, y0, s) = (60usize, 30usize, 32usize);
    let crop = |data: Vec<f32>, planes: usize| -> Vec<f32> {
        let mut out = Vec::with_capacity(planes * s * s);
        for p in 0..planes {
            for y in y0..y0 + s {
                out.extend_from_slice(&data[p * w * h + y * w + x0..p * w * h + y * w + x0 + s]);
            }
        }
        out
    };
    let feats = crop(features(&win), 5 * INPUT_CHANNELS);
    let vals = crop(color_values(&win), 5 * 3);
    let target = crop(reference.color.data().to_vec(), 3);
    (
        Tensor::from_data(TensorData::new(feats, [1, 5, INPUT_CHANNELS, s, s]), device),
        Tensor::from_data(TensorData::new(vals, [1, 5, 3, s, s]), device),
        Tensor::from_data(TensorData::new(target, [1, 3, s, s]), device),
    )
}

#[test]
fn gradients_reach_every_ra_block() {
    let device = Device::flex().autodiff();
    let d = Denoiser::new(NetConfig::preset("small").unwrap(), &device);
    let (x, v, y) = crop_window(&device);
    let out = d.predict(x, d.config.default_threshold()).apply(v);
    let grads = smape(out, y).backward();
    let blocks = d.ra_blocks();
    assert_eq!(blocks.len(), 3);
    for (i, b) in blocks.iter().enumerate() {
        for w in b.conv_weights() {
            let g = w.grad(&grads).expect("a gradient for every RA weight");
            let norm = g.powf_scalar(2.0).sum().into_scalar::<f32>().sqrt();
            assert!(
                norm > 0.0 && norm.is_finite(),
                "RA block {}: gradient norm {norm}",
                i + 1
            );
        }
    }
}

#[test]
fn small_network_overfits_one_window() {
    let device = Device::flex().autodiff();
    let mut d = Denoiser::new(NetConfig::preset("small").unwrap(), &device);
    let (x, v, y) = crop_window(&device);
    let t = d.config.default_threshold();
    let mut optim = AdamConfig::new().init();
    let mut first = None;
    let mut last = 0.0;
    for _ in 0..40 {
        let loss = smape(d.predict(x.clone(), t).apply(v.clone()), y.clone());
        last = loss.clone().into_scalar::<f32>();
        first.get_or_insert(last);
        let grads = GradientsParams::from_grads(loss.backward(), &d.net);
        d.net = optim.step(2e-3, d.net, grads);
    }
    let first = first.unwrap();
    eprintln!("SMAPE {first:.4} -> {last:.4}");
    assert!(
        last < 0.5 * first,
        "loss {first} -> {last}: less than a 50% drop"
    );
}
