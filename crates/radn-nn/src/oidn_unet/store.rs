//! Model files of imported U-Nets: SafeTensors with each convolution's weight and bias under
//! OIDN's names, its configuration (layer list, inputs, channels, OIDN model and version) as
//! TOML metadata. Weights that are exact in half precision (OIDN's are) are stored as f16, so a
//! file is as large as OIDN's own blob; others (after fine-tuning) as f32.

use std::collections::HashMap;
use std::path::Path;

use burn::tensor::Device;
use safetensors::{Dtype, SafeTensors};

use crate::error::{NnError, Result};
use crate::oidn_unet::config::UnetConfig;
use crate::oidn_unet::OidnUnet;

/// The metadata key whose value marks an imported U-Net's file.
pub const FORMAT_KEY: &str = "radn.format";
/// That value.
pub const FORMAT: &str = "oidn-unet-1";
/// The metadata key of the configuration.
const CONFIG_KEY: &str = "radn.unet";

/// The bytes of `net`'s model file.
pub fn to_bytes(net: &OidnUnet) -> Vec<u8> {
    let mut tensors: Vec<(String, Dtype, Vec<usize>, Vec<u8>)> = Vec::new();
    for (shape, (w, b)) in net.config().convs.iter().zip(net.host_weights()) {
        for (suffix, values, dims) in [
            ("weight", w, vec![shape.cout, shape.cin, 3, 3]),
            ("bias", b, vec![shape.cout]),
        ] {
            let exact = values
                .iter()
                .all(|&v| half::f16::from_f32(v).to_f32().to_bits() == v.to_bits());
            let (dtype, bytes) = if exact {
                (
                    Dtype::F16,
                    values
                        .iter()
                        .flat_map(|&v| half::f16::from_f32(v).to_le_bytes())
                        .collect(),
                )
            } else {
                (
                    Dtype::F32,
                    values.iter().flat_map(|v| v.to_le_bytes()).collect(),
                )
            };
            tensors.push((format!("{}.{suffix}", shape.name), dtype, dims, bytes));
        }
    }
    let views: Vec<(String, safetensors::tensor::TensorView)> = tensors
        .iter()
        .map(|(n, d, s, b)| {
            (
                n.clone(),
                safetensors::tensor::TensorView::new(*d, s.clone(), b).expect("consistent sizes"),
            )
        })
        .collect();
    let meta = HashMap::from([
        (FORMAT_KEY.to_string(), FORMAT.to_string()),
        (CONFIG_KEY.to_string(), net.config().to_toml()),
    ]);
    safetensors::serialize(views, Some(meta)).expect("a U-Net serialises")
}

/// Saves `net` to `path` (through a temporary file renamed into place).
pub fn save(net: &OidnUnet, path: &Path) -> Result<()> {
    let bytes = to_bytes(net);
    radn_core::io::output::write_atomically_with(path, |_, tmp| {
        std::fs::write(tmp, &bytes).map_err(|e| NnError::Save {
            path: path.to_path_buf(),
            detail: e.to_string(),
        })
    })
}

/// Whether `bytes` start a U-Net model file: the SafeTensors JSON header (after its 8-byte
/// length) names the format; nothing else is read.
pub fn is_unet(bytes: &[u8]) -> bool {
    let Some(len) = bytes
        .get(..8)
        .map(|b| u64::from_le_bytes(b.try_into().unwrap()))
    else {
        return false;
    };
    let Some(header) = usize::try_from(len)
        .ok()
        .and_then(|n| bytes.get(8..8usize.checked_add(n)?))
    else {
        return false;
    };
    serde_json::from_slice::<serde_json::Value>(header)
        .is_ok_and(|j| j["__metadata__"][FORMAT_KEY].as_str() == Some(FORMAT))
}

/// Whether the file at `path` is a U-Net model file (only its header is read).
pub fn is_unet_file(path: &Path) -> bool {
    use std::io::Read;
    let Ok(mut f) = std::fs::File::open(path) else {
        return false;
    };
    let mut len = [0u8; 8];
    if f.read_exact(&mut len).is_err() {
        return false;
    }
    let n = u64::from_le_bytes(len);
    if n > 100 << 20 {
        return false;
    }
    let mut head = vec![0u8; 8 + n as usize];
    head[..8].copy_from_slice(&len);
    f.read_exact(&mut head[8..]).is_ok() && is_unet(&head)
}

/// Loads a U-Net model file.
pub fn load(path: &Path, device: &Device) -> Result<OidnUnet> {
    let bytes = std::fs::read(path).map_err(|e| NnError::Load {
        path: path.to_path_buf(),
        detail: e.to_string(),
    })?;
    load_bytes(&bytes, path, device)
}

/// Loads a U-Net held in memory (e.g. compiled into the binary); `name` labels errors.
pub fn load_bytes(bytes: &[u8], name: &Path, device: &Device) -> Result<OidnUnet> {
    let err = |detail: String| NnError::Load {
        path: name.to_path_buf(),
        detail,
    };
    let file =
        SafeTensors::deserialize(bytes).map_err(|e| err(format!("not a model file ({e})")))?;
    let (_, meta) = SafeTensors::read_metadata(bytes).map_err(|e| err(e.to_string()))?;
    let meta = meta.metadata().clone().unwrap_or_default();
    if meta.get(FORMAT_KEY).map(String::as_str) != Some(FORMAT) {
        return Err(err(
            "not an imported OIDN U-Net (radn model import-oidn writes them)".into(),
        ));
    }
    let config = UnetConfig::parse(
        meta.get(CONFIG_KEY)
            .ok_or_else(|| err("the file has no U-Net configuration".into()))?,
    )
    .map_err(|e| err(format!("its configuration: {e}")))?;
    let mut weights = Vec::new();
    for c in &config.convs {
        let read = |suffix: &str, dims: &[usize]| -> Result<Vec<f32>> {
            let name = format!("{}.{suffix}", c.name);
            let t = file
                .tensor(&name)
                .map_err(|_| err(format!("it lacks {name}")))?;
            if t.shape() != dims {
                return Err(err(format!(
                    "{name} has shape {:?}, the configuration says {dims:?}",
                    t.shape()
                )));
            }
            Ok(match t.dtype() {
                Dtype::F16 => t
                    .data()
                    .chunks_exact(2)
                    .map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32())
                    .collect(),
                Dtype::F32 => t
                    .data()
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
                    .collect(),
                d => return Err(err(format!("{name} has element type {d:?}"))),
            })
        };
        weights.push((
            read("weight", &[c.cout, c.cin, 3, 3])?,
            read("bias", &[c.cout])?,
        ));
    }
    Ok(OidnUnet::from_weights(config, &weights, device))
}
