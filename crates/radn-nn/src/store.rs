//! Model files: burn's SafeTensors store with the network configuration embedded as metadata,
//! so a model file alone is enough to rebuild and run the network.

use std::io::Read;
use std::path::Path;

use burn::store::{ModuleSnapshot, SafetensorsStore};
use burn::tensor::Device;

use crate::config::NetConfig;
use crate::error::{NnError, Result};
use crate::model::Denoiser;

const CONFIG_KEY: &str = "radn.config";
const FORMAT_KEY: &str = "radn.format";
const FORMAT: &str = "1";

/// Saves the weights and configuration to `path` (through a temporary file renamed into place).
pub fn save(denoiser: &Denoiser, path: &Path) -> Result<()> {
    let err = |detail: String| NnError::Save {
        path: path.to_path_buf(),
        detail,
    };
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| err(e.to_string()))?;
    let tmp = tempfile::Builder::new()
        .prefix(".radn-model-")
        .suffix(".safetensors")
        .tempfile_in(dir)
        .map_err(|e| err(e.to_string()))?;
    let mut store = SafetensorsStore::from_file(tmp.path())
        .metadata(CONFIG_KEY, denoiser.config.to_toml())
        .metadata(FORMAT_KEY, FORMAT)
        .overwrite(true);
    denoiser
        .net
        .save_into(&mut store)
        .map_err(|e| err(format!("{e:?}")))?;
    tmp.persist(path).map_err(|e| err(e.error.to_string()))?;
    Ok(())
}

/// The configuration stored in a model file.
pub fn read_config(path: &Path) -> Result<NetConfig> {
    let err = |detail: String| NnError::Load {
        path: path.to_path_buf(),
        detail,
    };
    let mut f = std::fs::File::open(path).map_err(|e| err(e.to_string()))?;
    let mut len = [0u8; 8];
    f.read_exact(&mut len)
        .map_err(|_| err("not a model file (too short)".into()))?;
    let len = u64::from_le_bytes(len);
    if len > 100 << 20 {
        return Err(err("not a model file (bad SafeTensors header)".into()));
    }
    let mut header = vec![0u8; len as usize];
    f.read_exact(&mut header)
        .map_err(|_| err("the file is truncated".into()))?;
    let json: serde_json::Value = serde_json::from_slice(&header)
        .map_err(|_| err("not a model file (bad SafeTensors header)".into()))?;
    let meta = &json["__metadata__"];
    if meta[FORMAT_KEY].as_str() != Some(FORMAT) {
        return Err(err("not a radn model (no radn.format metadata)".into()));
    }
    let text = meta[CONFIG_KEY]
        .as_str()
        .ok_or_else(|| err("the model has no embedded configuration".into()))?;
    NetConfig::parse(text).map_err(|e| err(e.to_string()))
}

/// Loads a model file onto `device`.
pub fn load(path: &Path, device: &Device) -> Result<Denoiser> {
    let config = read_config(path)?;
    let mut d = Denoiser::new(config, device);
    let mut store = SafetensorsStore::from_file(path);
    let result = d.net.load_from(&mut store).map_err(|e| NnError::Load {
        path: path.to_path_buf(),
        detail: format!("{e:?}"),
    })?;
    if !result.missing.is_empty() || !result.errors.is_empty() {
        return Err(NnError::Load {
            path: path.to_path_buf(),
            detail: format!(
                "weights do not match the configuration (missing {:?}, errors {:?})",
                result.missing, result.errors
            ),
        });
    }
    Ok(d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::{Tensor, TensorData};

    #[test]
    fn a_saved_model_reloads_from_its_file_alone_and_predicts_the_same() {
        let device = Device::flex();
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.safetensors");
        let cfg = NetConfig::preset("small").unwrap();
        let d = Denoiser::new(cfg.clone(), &device);
        save(&d, &p).unwrap();
        let e = load(&p, &device).unwrap();
        assert_eq!(e.config, cfg);
        let n = 5 * crate::config::INPUT_CHANNELS * 6 * 6;
        let x = Tensor::<5>::from_data(
            TensorData::new(
                (0..n).map(|i| (i % 17) as f32 / 17.0).collect::<Vec<f32>>(),
                [1, 5, crate::config::INPUT_CHANNELS, 6, 6],
            ),
            &device,
        );
        let a = d
            .predict(x.clone(), 0.004)
            .frame_mass(5)
            .to_data()
            .try_to_vec::<f32>()
            .unwrap();
        let b = e
            .predict(x, 0.004)
            .frame_mass(5)
            .to_data()
            .try_to_vec::<f32>()
            .unwrap();
        assert_eq!(a, b);
        // not a model
        std::fs::write(dir.path().join("x"), b"hello").unwrap();
        assert!(load(&dir.path().join("x"), &device).is_err());
    }
}
