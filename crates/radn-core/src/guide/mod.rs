//! Guides: a per-frame spatial estimate of the beauty that a guided network reads beside the
//! noisy window (DESIGN.md §5). Kernels are still applied to the noisy frames, so AOVs, alpha
//! and thresholds keep working; the guide only steers the weights.
//!
//! A guide is either a layer the renderer wrote ([`crate::io::frame::GuideLayer`], read with the
//! frame) or Intel Open Image Denoise run on each frame ([`OidnGuides`], computed once per
//! frame from the sequence's original input files, whatever pass is running).

pub mod oidn;

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use crate::error::{Error, Result};
use crate::image::plane::Plane;
use crate::io::frame::{Frame, FrameReader};

pub use oidn::{OidnDenoiser, OidnError};

/// Where each frame's guide comes from, as a user names it (`--guide oidn|denoised|LAYER|none`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum GuideChoice {
    /// No guide.
    #[default]
    None,
    /// Intel Open Image Denoise on each frame (prefiltered albedo and normal).
    Oidn,
    /// The renderer's denoised beauty, beside the noisy one in the same file.
    Denoised,
    /// A named layer of each file.
    Layer(String),
}

impl GuideChoice {
    /// Parses `oidn`, `denoised`, `none` or a layer name.
    pub fn parse(text: &str) -> Self {
        match text {
            "" | "none" => Self::None,
            "oidn" => Self::Oidn,
            "denoised" => Self::Denoised,
            layer => Self::Layer(layer.to_string()),
        }
    }

    /// Whether frames get a guide at all.
    pub fn is_some(&self) -> bool {
        *self != Self::None
    }

    /// The layer [`FrameReader`] reads as the guide (none for OIDN, which computes it).
    pub fn layer(&self) -> crate::io::frame::GuideLayer {
        use crate::io::frame::GuideLayer;
        match self {
            Self::Denoised => GuideLayer::Denoised,
            Self::Layer(l) => GuideLayer::Layer(l.clone()),
            Self::None | Self::Oidn => GuideLayer::None,
        }
    }
}

/// OIDN guides of a sequence: one device shared by every frame (one frame at a time; OIDN
/// uses every thread it was given), computed from the original input files.
pub struct OidnGuides {
    denoiser: Mutex<OidnDenoiser>,
}

impl OidnGuides {
    /// Opens OIDN with `threads` threads (0: every core); fails with a message saying what
    /// to install where the library is missing.
    pub fn new(threads: usize) -> Result<Self> {
        let d = OidnDenoiser::new(threads).map_err(|e| Error::Guide {
            path: PathBuf::new(),
            detail: e.to_string(),
        })?;
        Ok(Self {
            denoiser: Mutex::new(d),
        })
    }

    /// The library in use, for messages: "Intel Open Image Denoise 2.5.1 (PATH)".
    pub fn describe(&self) -> String {
        let d = self
            .denoiser
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        format!(
            "Intel Open Image Denoise {} ({})",
            d.version(),
            d.library().display()
        )
    }

    /// The guide of `frame` (its beauty, albedo and normal as read from `path`).
    pub fn of_frame(&self, frame: &Frame, path: &Path) -> Result<Plane> {
        let mut d = self
            .denoiser
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        d.denoise(&frame.color, frame.albedo.as_ref(), frame.normal.as_ref())
            .map_err(|e| Error::Guide {
                path: path.to_path_buf(),
                detail: e.to_string(),
            })
    }

    /// The guide of the frame in the file at `path`, read whole by `reader`.
    pub fn of_file(&self, reader: &FrameReader, path: &Path) -> Result<Plane> {
        let (frame, _) = reader.read(path)?;
        self.of_frame(&frame, path)
    }
}

/// How a sequence job gets its frames' guides beyond what its reader reads.
#[derive(Clone, Default)]
pub enum JobGuides {
    /// The reader's guide layer, if any, is all.
    #[default]
    FromReader,
    /// OIDN on the original input files `originals` (one per input of the job, in order).
    Oidn {
        /// The shared device.
        guides: std::sync::Arc<OidnGuides>,
        /// The original input file of each of the job's inputs.
        originals: Vec<PathBuf>,
    },
}
