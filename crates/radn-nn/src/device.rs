//! Where the network runs: `--device cpu|cuda[:N]`.
//!
//! `cpu` is burn's `flex` backend with radn's own CPU fast paths (the default, and the only
//! device of a build without the `cuda` feature). `cuda[:N]` is burn's CUDA backend (cubecl,
//! LLVM → PTX), available in a build with the `cuda` feature (`scripts/build-cuda`). Model files
//! are the same on both: weights are loaded onto whichever device is opened.
//!
//! Opening a CUDA device first asks the driver itself (`libcuda.so.1`, loaded at run time) how
//! many GPUs there are, so a machine without a driver or without that GPU gets one clear error
//! instead of a panic deep inside the backend.

use std::fmt;
use std::str::FromStr;

use burn::tensor::Device;

use crate::error::{NnError, Result};

/// A device the network can run on, as the user names it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ComputeDevice {
    /// The CPU (burn's `flex` backend and radn's CPU fast paths).
    #[default]
    Cpu,
    /// The CUDA GPU with this index (as `nvidia-smi` numbers them).
    Cuda(usize),
}

impl FromStr for ComputeDevice {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        let s = s.trim().to_ascii_lowercase();
        match s.as_str() {
            "cpu" => Ok(Self::Cpu),
            "cuda" | "gpu" => Ok(Self::Cuda(0)),
            _ => match s.strip_prefix("cuda:") {
                Some(n) => n.parse().map(Self::Cuda).map_err(|_| {
                    format!("'{s}': the GPU index after 'cuda:' must be a number, e.g. cuda:0")
                }),
                None => Err(format!("unknown device '{s}'; known: cpu, cuda, cuda:N")),
            },
        }
    }
}

/// OIDN on the same device as the network: its CUDA device for a GPU run.
impl From<ComputeDevice> for radn_core::guide::OidnDevice {
    fn from(d: ComputeDevice) -> Self {
        match d {
            ComputeDevice::Cpu => Self::Cpu,
            ComputeDevice::Cuda(n) => Self::Cuda(n),
        }
    }
}

impl fmt::Display for ComputeDevice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Cpu => write!(f, "cpu"),
            Self::Cuda(n) => write!(f, "cuda:{n}"),
        }
    }
}

impl ComputeDevice {
    /// Whether this build can open CUDA devices at all (it was built with the `cuda` feature).
    pub const CUDA_BUILT: bool = cfg!(feature = "cuda");

    /// The burn device for inference, after checking that it exists.
    pub fn open(self) -> Result<Device> {
        match self {
            Self::Cpu => Ok(Device::flex()),
            Self::Cuda(index) => open_cuda(index),
        }
    }

    /// The burn device for training (the same device with automatic differentiation; needs
    /// the `autodiff` feature, which `radn-train` turns on).
    #[cfg(feature = "autodiff")]
    pub fn open_for_training(self) -> Result<Device> {
        Ok(self.open()?.autodiff())
    }

    /// Whether this is a GPU.
    pub fn is_gpu(self) -> bool {
        matches!(self, Self::Cuda(_))
    }
}

#[cfg(not(feature = "cuda"))]
fn open_cuda(index: usize) -> Result<Device> {
    Err(NnError::Device {
        device: ComputeDevice::Cuda(index).to_string(),
        detail: "this radn was built without CUDA; build it with scripts/build-cuda \
                 (cargo build --release -p radn --features cuda)"
            .into(),
    })
}

#[cfg(feature = "cuda")]
fn open_cuda(index: usize) -> Result<Device> {
    let count = cuda_driver::device_count().map_err(|detail| NnError::Device {
        device: ComputeDevice::Cuda(index).to_string(),
        detail,
    })?;
    if index >= count {
        return Err(NnError::Device {
            device: ComputeDevice::Cuda(index).to_string(),
            detail: format!(
                "the CUDA driver reports {count} GPU{}",
                if count == 1 { "" } else { "s" }
            ),
        });
    }
    Ok(Device::cuda(index))
}

/// The few driver calls needed to count GPUs before burn's backend touches them.
#[cfg(feature = "cuda")]
mod cuda_driver {
    use std::os::raw::c_int;

    type CuInit = unsafe extern "C" fn(flags: u32) -> c_int;
    type CuDeviceGetCount = unsafe extern "C" fn(count: *mut c_int) -> c_int;

    /// How many CUDA devices the driver sees, or why it cannot say.
    pub fn device_count() -> Result<usize, String> {
        // SAFETY: libcuda.so.1 is NVIDIA's driver library; loading it runs no code of ours, and
        // the two symbols have the C signatures of the CUDA driver API (cuda.h) declared above.
        unsafe {
            let lib = libloading::Library::new("libcuda.so.1")
                .map_err(|e| format!("no NVIDIA driver: libcuda.so.1 cannot be loaded ({e})"))?;
            let init: libloading::Symbol<CuInit> = lib
                .get(b"cuInit\0")
                .map_err(|e| format!("libcuda.so.1 has no cuInit ({e})"))?;
            let get_count: libloading::Symbol<CuDeviceGetCount> = lib
                .get(b"cuDeviceGetCount\0")
                .map_err(|e| format!("libcuda.so.1 has no cuDeviceGetCount ({e})"))?;
            let status = init(0);
            if status != 0 {
                return Err(format!(
                    "the CUDA driver failed to start (cuInit returned {status}; \
                     100 means no GPU is visible)"
                ));
            }
            let mut count: c_int = 0;
            let status = get_count(&mut count);
            if status != 0 {
                return Err(format!("cuDeviceGetCount returned {status}"));
            }
            // The library stays loaded for the process: burn's backend opens it again.
            std::mem::forget(lib);
            Ok(count.max(0) as usize)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn device_names_parse_and_print_back() {
        for (text, device) in [
            ("cpu", ComputeDevice::Cpu),
            ("CPU", ComputeDevice::Cpu),
            ("cuda", ComputeDevice::Cuda(0)),
            ("gpu", ComputeDevice::Cuda(0)),
            ("cuda:3", ComputeDevice::Cuda(3)),
        ] {
            assert_eq!(text.parse::<ComputeDevice>().unwrap(), device, "{text}");
        }
        assert_eq!(ComputeDevice::Cuda(2).to_string(), "cuda:2");
        assert_eq!(
            "cuda:2".parse::<ComputeDevice>().unwrap().to_string(),
            "cuda:2"
        );
        let e = "cuda:x".parse::<ComputeDevice>().unwrap_err();
        assert!(e.contains("must be a number"), "{e}");
        let e = "tpu".parse::<ComputeDevice>().unwrap_err();
        assert!(e.contains("cpu, cuda, cuda:N"), "{e}");
    }

    #[test]
    fn the_cpu_is_the_default_and_opens_the_flex_backend() {
        assert_eq!(ComputeDevice::default(), ComputeDevice::Cpu);
        let device = ComputeDevice::Cpu.open().unwrap();
        assert!(device == Device::flex());
        #[cfg(feature = "autodiff")]
        assert!(ComputeDevice::Cpu
            .open_for_training()
            .unwrap()
            .is_autodiff());
    }

    #[cfg(not(feature = "cuda"))]
    #[test]
    fn a_cpu_build_refuses_cuda_with_how_to_build_it() {
        let e = ComputeDevice::Cuda(0).open().unwrap_err().to_string();
        assert!(
            e.contains("cuda:0") && e.contains("scripts/build-cuda"),
            "{e}"
        );
    }

    #[cfg(feature = "cuda")]
    #[test]
    fn a_cuda_build_opens_a_gpu_or_says_why_not() {
        match ComputeDevice::Cuda(0).open() {
            Ok(_) => {}
            Err(e) => {
                let e = e.to_string();
                assert!(e.contains("cuda:0"), "{e}");
                eprintln!("no GPU here, the error is: {e}");
            }
        }
        let e = ComputeDevice::Cuda(999).open().unwrap_err().to_string();
        assert!(e.contains("cuda:999"), "{e}");
    }
}
