//! Model files of converted U-Nets ([`TemporalUnet`]): burn's SafeTensors store of every
//! weight (the U-Net's and the temporal blends'), with the U-Net's configuration and the
//! window's ([`TemporalConfig`]) as metadata, so that the file alone rebuilds the network.

use std::io::Read;
use std::path::Path;

use burn::store::{ModuleSnapshot, SafetensorsStore};
use burn::tensor::Device;

use crate::error::{NnError, Result};
use crate::oidn_unet::config::UnetConfig;
use crate::oidn_unet::temporal::{TemporalConfig, TemporalUnet};
use crate::oidn_unet::OidnUnet;

/// The `radn.format` value of a converted U-Net's file.
pub const FORMAT: &str = "oidn-temporal-1";
const FORMAT_KEY: &str = "radn.format";
const UNET_KEY: &str = "radn.unet";
const TEMPORAL_KEY: &str = "radn.temporal";

/// Saves `net` to `path` (through a temporary file renamed into place).
pub fn save(net: &TemporalUnet, path: &Path) -> Result<()> {
    let err = |detail: String| NnError::Save {
        path: path.to_path_buf(),
        detail,
    };
    let temporal = net.config().to_toml();
    radn_core::io::output::write_atomically_with(path, |_, tmp| {
        let mut store = SafetensorsStore::from_file(tmp)
            .metadata(FORMAT_KEY, FORMAT)
            .metadata(UNET_KEY, net.unet.config().to_toml())
            .metadata(TEMPORAL_KEY, temporal.clone())
            .overwrite(true);
        net.save_into(&mut store).map_err(|e| err(format!("{e:?}")))
    })
}

/// The SafeTensors metadata of the file at `path` (only its header is read); `None` when it
/// is not a SafeTensors file.
fn metadata(path: &Path) -> Option<serde_json::Value> {
    let mut f = std::fs::File::open(path).ok()?;
    let mut len = [0u8; 8];
    f.read_exact(&mut len).ok()?;
    let n = u64::from_le_bytes(len);
    if n > 100 << 20 {
        return None;
    }
    let mut header = vec![0u8; n as usize];
    f.read_exact(&mut header).ok()?;
    let json: serde_json::Value = serde_json::from_slice(&header).ok()?;
    Some(json["__metadata__"].clone())
}

/// Whether the file at `path` is a converted U-Net's model file (only its header is read).
pub fn is_temporal_file(path: &Path) -> bool {
    metadata(path).is_some_and(|m| m[FORMAT_KEY].as_str() == Some(FORMAT))
}

/// Loads a converted U-Net's model file onto `device`.
pub fn load(path: &Path, device: &Device) -> Result<TemporalUnet> {
    let err = |detail: String| NnError::Load {
        path: path.to_path_buf(),
        detail,
    };
    if !path.is_file() {
        return Err(err("no such file".into()));
    }
    let meta = metadata(path).ok_or_else(|| err("not a model file".into()))?;
    if meta[FORMAT_KEY].as_str() != Some(FORMAT) {
        return Err(err(
            "not a converted OIDN U-Net (radn train writes them with network = \"oidn-temporal\")"
                .into(),
        ));
    }
    let text = |key: &str| {
        meta[key]
            .as_str()
            .map(str::to_string)
            .ok_or_else(|| err(format!("the file has no {key} metadata")))
    };
    let unet = UnetConfig::parse(&text(UNET_KEY)?)
        .map_err(|e| err(format!("its U-Net configuration: {e}")))?;
    let temporal: TemporalConfig = toml::from_str(&text(TEMPORAL_KEY)?)
        .map_err(|e| err(format!("its window configuration: {e}")))?;
    let mut net = TemporalUnet::convert(OidnUnet::new(unet, device), temporal, device)
        .map_err(|e| err(e.to_string()))?;
    let mut store = SafetensorsStore::from_file(path);
    let result = net
        .load_from(&mut store)
        .map_err(|e| err(format!("{e:?}")))?;
    if !result.missing.is_empty() || !result.errors.is_empty() {
        return Err(err(format!(
            "weights do not match the configuration (missing {:?}, errors {:?})",
            result.missing, result.errors
        )));
    }
    Ok(net)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Tensor, TensorData};

    #[test]
    fn a_saved_network_loads_with_the_same_output() {
        let device = Device::flex();
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../models/oidn-rt_hdr_alb_nrm.safetensors");
        let unet = crate::oidn_unet::store::load(&path, &device).unwrap();
        device.seed(3);
        let config = TemporalConfig {
            frames: 3,
            levels: vec![0, 2],
            color_confidence: Some(0.6),
            warp: Default::default(),
            aux: Default::default(),
            input_frames: 3,
            stabilize: Some(radn_core::post::stabilize::StabilizeSettings {
                strength: 0.6,
                floor: 0.0005,
                noise_radius: 2,
            }),
            input_blend: false,
        };
        let net = TemporalUnet::convert(unet, config.clone(), &device).unwrap();
        // open the gates so the blocks' weights matter
        let net = net.with_gates(0.5);
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("t.safetensors");
        save(&net, &file).unwrap();
        assert!(is_temporal_file(&file));
        assert!(!is_temporal_file(&path));
        let back = load(&file, &device).unwrap();
        assert_eq!(back.config(), &config);
        let n = 3 * 9 * 16 * 32;
        let x: Tensor<4> = Tensor::from_data(
            TensorData::new(
                (0..n).map(|i| ((i * 31) % 97) as f32 / 97.0).collect(),
                [3, 9, 16, 32],
            ),
            &device,
        );
        let a = net.forward(x.clone(), None).into_data();
        let b = back.forward(x.clone(), None).into_data();
        assert_eq!(a.as_slice::<f32>().unwrap(), b.as_slice::<f32>().unwrap());
        // a learned input average is kept with its gate
        let blended = TemporalConfig {
            input_frames: 1,
            input_blend: true,
            ..config
        };
        let net = TemporalUnet::convert(back.unet.clone(), blended.clone(), &device)
            .unwrap()
            .with_gates(0.5);
        let file = dir.path().join("blend.safetensors");
        save(&net, &file).unwrap();
        let back = load(&file, &device).unwrap();
        assert_eq!(back.config(), &blended);
        assert_eq!(back.temporal.input_openness(), Some(0.5));
        let a = net.forward(x.clone(), None).into_data();
        let b = back.forward(x, None).into_data();
        assert_eq!(a.as_slice::<f32>().unwrap(), b.as_slice::<f32>().unwrap());
        // a plain U-Net's file is refused with a message
        let e = load(&path, &device).unwrap_err().to_string();
        assert!(e.contains("not a converted OIDN U-Net"), "{e}");
    }
}
