//! Model files: burn's SafeTensors store with the network configuration and its recipe
//! embedded as metadata, so a model file alone is enough to rebuild and run the network as
//! tuned. A file saved before recipes existed gets the one its kind was tuned with.

use std::io::Read;
use std::path::Path;

use burn::store::{ModuleSnapshot, SafetensorsStore};
use burn::tensor::Device;

use crate::error::{NnError, Result};
use crate::model::config::NetConfig;
use crate::model::Denoiser;
use crate::recipe::Recipe;

const CONFIG_KEY: &str = "radn.config";
const RECIPE_KEY: &str = "radn.recipe";
const FORMAT_KEY: &str = "radn.format";
const FORMAT: &str = "1";

/// Saves the weights and configuration to `path` (through a temporary file renamed into place).
pub fn save(denoiser: &Denoiser, path: &Path) -> Result<()> {
    let err = |detail: String| NnError::Save {
        path: path.to_path_buf(),
        detail,
    };
    radn_core::io::output::write_atomically_with(path, |_, tmp| {
        let mut store = SafetensorsStore::from_file(tmp)
            .metadata(CONFIG_KEY, denoiser.config.to_toml())
            .metadata(RECIPE_KEY, denoiser.recipe.to_toml())
            .metadata(FORMAT_KEY, FORMAT)
            .overwrite(true);
        denoiser
            .net
            .save_into(&mut store)
            .map_err(|e| err(format!("{e:?}")))
    })
}

/// The configuration stored in a model file.
pub fn read_config(path: &Path) -> Result<NetConfig> {
    read_header(path).map(|(config, _)| config)
}

/// The configuration and the recipe stored in a model file (the recipe its kind was tuned
/// with where the file has none).
pub fn read_header(path: &Path) -> Result<(NetConfig, Recipe)> {
    let err = |detail: String| NnError::Load {
        path: path.to_path_buf(),
        detail,
    };
    let mut f = std::fs::File::open(path).map_err(|e| err(e.to_string()))?;
    let mut len = [0u8; 8];
    f.read_exact(&mut len)
        .map_err(|_| err("not a model file (too short)".into()))?;
    let n = header_len(&len).map_err(err)?;
    let mut header = vec![0u8; n];
    f.read_exact(&mut header)
        .map_err(|_| err("the file is truncated".into()))?;
    model_header(&header).map_err(err)
}

/// The SafeTensors header length from the file's first 8 bytes, refused when implausible.
fn header_len(first: &[u8]) -> std::result::Result<usize, String> {
    let len = u64::from_le_bytes(
        first
            .get(..8)
            .and_then(|b| b.try_into().ok())
            .ok_or("not a model file (too short)")?,
    );
    if len > 100 << 20 {
        return Err("not a model file (bad SafeTensors header)".into());
    }
    Ok(len as usize)
}

/// The radn configuration and recipe in a SafeTensors JSON header.
fn model_header(header: &[u8]) -> std::result::Result<(NetConfig, Recipe), String> {
    let json: serde_json::Value = serde_json::from_slice(header)
        .map_err(|_| "not a model file (bad SafeTensors header)".to_string())?;
    let meta = &json["__metadata__"];
    if meta[FORMAT_KEY].as_str() == Some(crate::oidn_unet::store::FORMAT) {
        return Err(
            "an imported OIDN U-Net, not a Robust Average network (run it with --method spatial)"
                .into(),
        );
    }
    if meta[FORMAT_KEY].as_str() != Some(FORMAT) {
        return Err("not a radn model (no radn.format metadata)".into());
    }
    let text = meta[CONFIG_KEY]
        .as_str()
        .ok_or("the model has no embedded configuration")?;
    let config = NetConfig::parse(text).map_err(|e| e.to_string())?;
    let recipe = match meta[RECIPE_KEY].as_str() {
        Some(text) => Recipe::from_toml(text, &config).map_err(|e| format!("its recipe: {e}"))?,
        None => Recipe::tuned_for(&config),
    };
    Ok((config, recipe))
}

/// Loads a model file onto `device`.
pub fn load(path: &Path, device: &Device) -> Result<Denoiser> {
    let (config, recipe) = read_header(path)?;
    load_into(
        config,
        recipe,
        SafetensorsStore::from_file(path),
        path,
        device,
    )
}

/// Loads a model held in memory (e.g. one compiled into the binary); `name` labels errors.
pub fn load_bytes(bytes: &[u8], name: &Path, device: &Device) -> Result<Denoiser> {
    let err = |detail: String| NnError::Load {
        path: name.to_path_buf(),
        detail,
    };
    let n = header_len(bytes).map_err(err)?;
    let header = bytes
        .get(8..8 + n)
        .ok_or_else(|| err("the model is truncated".into()))?;
    let (config, recipe) = model_header(header).map_err(err)?;
    load_into(
        config,
        recipe,
        SafetensorsStore::from_bytes(Some(bytes.to_vec())),
        name,
        device,
    )
}

fn load_into(
    config: NetConfig,
    recipe: Recipe,
    mut store: SafetensorsStore,
    path: &Path,
    device: &Device,
) -> Result<Denoiser> {
    let mut d = Denoiser::new(config, device);
    d.recipe = recipe;
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
        let n = 5 * crate::model::config::INPUT_CHANNELS * 6 * 6;
        let x = Tensor::<5>::from_data(
            TensorData::new(
                (0..n).map(|i| (i % 17) as f32 / 17.0).collect::<Vec<f32>>(),
                [1, 5, crate::model::config::INPUT_CHANNELS, 6, 6],
            ),
            &device,
        );
        let mass = |m: &Denoiser| {
            m.predict(x.clone(), 0.004)
                .frame_mass(5)
                .to_data()
                .try_to_vec::<f32>()
                .unwrap()
        };
        assert_eq!(mass(&d), mass(&e));
        // the same bytes loaded from memory give the same network
        let bytes = std::fs::read(&p).unwrap();
        let m = load_bytes(&bytes, Path::new("mem"), &device).unwrap();
        assert_eq!(mass(&e), mass(&m));
        assert!(load_bytes(&bytes[..bytes.len() / 2], Path::new("mem"), &device).is_err());
        // not a model
        std::fs::write(dir.path().join("x"), b"hello").unwrap();
        assert!(load(&dir.path().join("x"), &device).is_err());
    }

    #[test]
    fn a_recipe_is_saved_and_a_file_without_one_gets_its_kinds() {
        let device = Device::flex();
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.safetensors");
        let mut d = Denoiser::new(NetConfig::preset("small").unwrap(), &device);
        let tuned = d.recipe.clone();
        d.recipe.set("mix.range", "0.05").unwrap();
        d.recipe.set("stabilize", "0.4").unwrap();
        save(&d, &p).unwrap();
        let (_, recipe) = read_header(&p).unwrap();
        assert_eq!(recipe, d.recipe);
        assert_eq!(load(&p, &device).unwrap().recipe, d.recipe);
        // files saved before recipes existed carry none: each gets the recipe of its kind
        let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models");
        let (config, recipe) = read_header(&shipped.join("guided-lean.safetensors")).unwrap();
        assert!(config.inputs.guide);
        assert_eq!(recipe, Recipe::tuned_for(&config));
        assert!(recipe.stabilize.is_some() && recipe.confidence.guide.is_some());
        // the compiled-in guided model carries the recipe chosen for it on validation data
        let (config, recipe) = read_header(&shipped.join("guided-mix.safetensors")).unwrap();
        assert!(config.inputs.guide && recipe != Recipe::tuned_for(&config));
        assert!(recipe.stabilize.is_none() && recipe.input_blend.is_none());
        assert_eq!(recipe.guide_mix, Recipe::tuned_for(&config).guide_mix);
        let (_, recipe) = read_header(&shipped.join("default.safetensors")).unwrap();
        assert_eq!(recipe, tuned);
        assert!(recipe.stabilize.is_none() && recipe.confidence.color.is_some());
    }
}
