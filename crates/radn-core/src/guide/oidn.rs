//! Intel Open Image Denoise 2.x, loaded at run time: the per-frame spatial estimate a guided
//! network reads (`radn denoise --guide oidn`).
//!
//! The library is opened when a guide is first asked for, not linked: radn builds and runs
//! without OIDN, and only `--guide oidn` needs it. Where it is looked for, in order:
//! `$RADN_OIDN_LIBRARY` (the library file, or the folder holding it; when set, nothing else is
//! tried), `$OIDN_DIR/lib`, the system's loader path (`libOpenImageDenoise.so.2`), the `pyoidn`
//! wheel of the `python3` on `PATH` (which `scripts/setup` installs: `pyoidn==2.5.1.0` ships
//! OIDN 2.5.1 with its CPU device and TBB), Blender's own copy in the `bpy` wheel of that
//! `python3` (`bpy/lib/`), and the one beside a `blender` on `PATH` (Blender 4.x bundles
//! OIDN 2.x). Each library finds its core and device modules in its own folder.
//!
//! By default each frame is filtered as OIDN recommends for final frames: the albedo and the
//! normal are denoised first, each by its own `RT` filter, and the beauty filter (HDR) then runs
//! with `cleanAux` on. This is the "prefiltered" mode of `tools/datagen` (`radn_datagen oidn`),
//! so the guides radn computes equal those of the training data. [`OidnSettings`](super::OidnSettings) choose other
//! qualities, or the noisy auxiliaries without prefilters.

use std::ffi::{c_char, c_int, c_void, CStr, CString};
use std::path::{Path, PathBuf};
use std::time::Duration;

use super::oidn_library::{
    candidates, version_text, Api, DEVICE_TYPE_CPU, DEVICE_TYPE_CUDA, FORMAT_FLOAT3, OLDEST_VERSION,
};
use super::oidn_settings::OidnQuality;
use crate::image::plane::Plane;

/// The device OIDN filters on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum OidnDevice {
    /// The CPU (OIDN's CPU device module, with TBB's threads).
    #[default]
    Cpu,
    /// NVIDIA GPU `N` through CUDA (OIDN's CUDA device module and the NVIDIA driver).
    Cuda(usize),
}

impl std::fmt::Display for OidnDevice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Cpu => write!(f, "CPU"),
            Self::Cuda(n) => write!(f, "CUDA GPU {n}"),
        }
    }
}

/// Where one guide's time went.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GuideTimes {
    /// The albedo and normal prefilters.
    pub prefilters: Duration,
    /// The beauty filter.
    pub beauty: Duration,
}

impl GuideTimes {
    /// The sum of `self` and `other`.
    pub fn plus(self, other: Self) -> Self {
        Self {
            prefilters: self.prefilters + other.prefilters,
            beauty: self.beauty + other.beauty,
        }
    }
}

/// Why OIDN could not be used: the message says what to install or what failed.
#[derive(Debug, thiserror::Error)]
pub enum OidnError {
    /// The library was not found, or not a usable OIDN 2.x.
    #[error(
        "Intel Open Image Denoise 2.x is not available: {detail}. Install it with \
         `scripts/setup` (pip package pyoidn==2.5.1.0) or a system OIDN 2.x, or point \
         RADN_OIDN_LIBRARY at libOpenImageDenoise.so.2"
    )]
    Unavailable {
        /// What was tried and what failed.
        detail: String,
    },
    /// The library opened but cannot make the device asked for.
    #[error(
        "Intel Open Image Denoise cannot use the {device}: {detail}. A GPU needs NVIDIA's \
         driver and OIDN's CUDA device module (libOpenImageDenoise_device_cuda) beside the \
         library; the pyoidn wheel ships it"
    )]
    NoDevice {
        /// The device asked for.
        device: String,
        /// The library and OIDN's message.
        detail: String,
    },
    /// OIDN reported an error.
    #[error("Intel Open Image Denoise failed in {stage}: {message}")]
    Failed {
        /// What it was doing.
        stage: String,
        /// OIDN's own message.
        message: String,
    },
    /// The images cannot be filtered together.
    #[error("Intel Open Image Denoise: {0}")]
    Input(String),
}

/// One OIDN CPU device and the three `RT` filters of prefiltered denoising (albedo, normal,
/// beauty), kept across frames: creating and first committing a filter costs far more than
/// filtering once more with new images.
pub struct OidnDenoiser {
    api: Api,
    device: *mut c_void,
    /// Which device it is.
    kind: OidnDevice,
    /// Whether images go through OIDN buffers (copied to and from the device) rather than
    /// being shared with it: for a device that cannot read the process's memory.
    copy_images: bool,
    /// Albedo, normal and beauty filters, created when first used.
    filters: [*mut c_void; 3],
    /// The beauty's exposure; `None`: OIDN's autoexposure.
    input_scale: Option<f32>,
    /// OIDN's scratch memory bound per filter.
    max_memory_mb: Option<usize>,
    version: c_int,
    /// The library file that was opened.
    path: PathBuf,
    // last: the functions above point into it
    _lib: libloading::Library,
}

// SAFETY: OIDN devices and filters may be used from any thread, one call at a time; radn
// holds an `OidnDenoiser` behind `&mut` (or a mutex) for every call.
unsafe impl Send for OidnDenoiser {}

impl OidnDenoiser {
    /// Opens the library (see the module documentation for where it is looked for) and makes
    /// a CPU device using `threads` threads (0: OIDN's choice, every core).
    pub fn new(threads: usize) -> Result<Self, OidnError> {
        Self::on(OidnDevice::Cpu, threads)
    }

    /// Opens the library and makes a device of kind `device` (`threads`: the CPU device's
    /// threads, 0 for every core; unused on a GPU). A GPU that OIDN cannot use (no driver, no
    /// CUDA device module beside the library, no such GPU) is [`OidnError::NoDevice`].
    pub fn on(device: OidnDevice, threads: usize) -> Result<Self, OidnError> {
        let mut tried = Vec::new();
        for (path, what) in candidates() {
            // SAFETY: loading OIDN runs only its (and TBB's) library initialisers.
            match unsafe { libloading::Library::new(&path) } {
                Ok(lib) => return Self::with_library(lib, path, device, threads),
                Err(e) => tried.push(format!("{} ({what}): {e}", path.display())),
            }
        }
        Err(OidnError::Unavailable {
            detail: format!("tried {}", tried.join("; ")),
        })
    }

    fn with_library(
        lib: libloading::Library,
        path: PathBuf,
        kind: OidnDevice,
        threads: usize,
    ) -> Result<Self, OidnError> {
        let api = Api::load(&lib).map_err(|detail| OidnError::Unavailable {
            detail: format!("{}: {detail}", path.display()),
        })?;
        // a library found by its bare name is named by the file the loader read
        let path = if path.is_absolute() {
            path
        } else {
            super::oidn_library::loaded_file(api.new_device as *const c_void).unwrap_or(path)
        };
        // SAFETY: OIDN's C API, called as oidn.h documents; the CUDA device is given one
        // device ID and the default stream (null).
        let device = unsafe {
            match kind {
                OidnDevice::Cpu => (api.new_device)(DEVICE_TYPE_CPU),
                OidnDevice::Cuda(0) => (api.new_device)(DEVICE_TYPE_CUDA),
                OidnDevice::Cuda(n) => {
                    let id = n.min(c_int::MAX as usize) as c_int;
                    let stream: *mut c_void = std::ptr::null_mut();
                    (api.new_cuda_device)(&id, &stream, 1)
                }
            }
        };
        let mut me = Self {
            api,
            device,
            kind,
            copy_images: false,
            filters: [std::ptr::null_mut(); 3],
            input_scale: None,
            max_memory_mb: None,
            version: 0,
            path,
            _lib: lib,
        };
        let stage = format!("creating the {kind} device");
        let no_device = |me: &Self, e: OidnError| match e {
            OidnError::Failed { message, .. } => OidnError::NoDevice {
                device: kind.to_string(),
                detail: format!("{} ({message})", me.path.display()),
            },
            e => e,
        };
        if me.device.is_null() {
            // a device that could not be made leaves its error with the thread (oidn.h)
            let e = me.check(&stage).err().unwrap_or(OidnError::Failed {
                stage: stage.clone(),
                message: "no device was made".into(),
            });
            return Err(no_device(&me, e));
        }
        let c = |s: &str| CString::new(s).expect("no NUL in a parameter name");
        // SAFETY: a live device; parameter names are NUL-terminated.
        unsafe {
            if threads > 0 && kind == OidnDevice::Cpu {
                (me.api.set_device_int)(
                    device,
                    c("numThreads").as_ptr(),
                    threads.min(c_int::MAX as usize) as c_int,
                );
            }
            (me.api.commit_device)(device);
        }
        me.check(&stage).map_err(|e| no_device(&me, e))?;
        // SAFETY: a committed device.
        me.version = unsafe { (me.api.get_device_int)(device, c("version").as_ptr()) };
        if me.version < OLDEST_VERSION {
            return Err(OidnError::Unavailable {
                detail: format!(
                    "{} is OIDN {}, older than 2.0",
                    me.path.display(),
                    version_text(me.version)
                ),
            });
        }
        // a GPU that cannot read the process's memory gets its images through buffers
        me.copy_images = !me.shares_memory();
        tracing::debug!(
            "Intel Open Image Denoise {} from {} on the {kind}{}",
            version_text(me.version),
            me.path.display(),
            if me.copy_images {
                " (images copied to and from it)"
            } else {
                ""
            }
        );
        Ok(me)
    }

    /// The device it filters on.
    pub fn device(&self) -> OidnDevice {
        self.kind
    }

    /// Hands images to OIDN through its buffers (copied in, the output copied back) instead
    /// of sharing the caller's memory with the device. A GPU that cannot read the process's
    /// memory always takes this way; on the CPU it gives the same result as sharing, which is
    /// how the copying is checked without a GPU.
    pub fn copy_images(&mut self, copy: bool) {
        self.copy_images = copy || !self.shares_memory();
    }

    /// Whether the device reads the process's memory (the CPU's does).
    fn shares_memory(&self) -> bool {
        let c = CString::new("systemMemorySupported").expect("no NUL");
        self.kind == OidnDevice::Cpu
            // SAFETY: a committed device; the parameter name is NUL-terminated.
            || unsafe { (self.api.get_device_bool)(self.device, c.as_ptr()) }
    }

    /// The library's version, e.g. "2.5.1".
    pub fn version(&self) -> String {
        version_text(self.version)
    }

    /// The library file that was opened.
    pub fn library(&self) -> &Path {
        &self.path
    }

    /// The device's pending error, if any.
    fn check(&self, stage: &str) -> Result<(), OidnError> {
        let mut msg: *const c_char = std::ptr::null();
        // SAFETY: a live device; OIDN owns the message until the next call.
        let code = unsafe { (self.api.get_device_error)(self.device, &mut msg) };
        if code == 0 {
            return Ok(());
        }
        let message = if msg.is_null() {
            format!("error code {code}")
        } else {
            // SAFETY: a NUL-terminated string from OIDN.
            unsafe { CStr::from_ptr(msg) }
                .to_string_lossy()
                .into_owned()
        };
        Err(OidnError::Failed {
            stage: stage.into(),
            message,
        })
    }

    /// Runs filter `role` (0 albedo, 1 normal, 2 beauty) on interleaved RGB images `images`
    /// (name, data), all `w × h`, with boolean parameters `flags`, at `quality`.
    fn run(
        &mut self,
        role: usize,
        (w, h): (usize, usize),
        images: &mut [(&str, &mut [f32])],
        flags: &[(&str, bool)],
        quality: OidnQuality,
    ) -> Result<(), OidnError> {
        let stage = [
            "the albedo filter",
            "the normal filter",
            "the beauty filter",
        ][role];
        let c = |s: &str| CString::new(s).expect("no NUL in a parameter name");
        // with bounded memory one filter serves every role, so only one holds scratch memory
        // (OIDN frees a filter's scratch when a commit rebuilds it for other images)
        let slot = if self.max_memory_mb.is_some() {
            0
        } else {
            role
        };
        if self.filters[slot].is_null() {
            // SAFETY: a live device.
            self.filters[slot] = unsafe { (self.api.new_filter)(self.device, c("RT").as_ptr()) };
            self.check(stage)?;
            if self.filters[slot].is_null() {
                return Err(OidnError::Failed {
                    stage: stage.into(),
                    message: "no RT filter could be made".into(),
                });
            }
        }
        let f = self.filters[slot];
        // where the device cannot read this memory, each image gets a buffer of its own
        let mut buffers = Buffers {
            release: self.api.release_buffer,
            made: Vec::new(),
        };
        for (name, data) in images.iter_mut() {
            assert_eq!(data.len(), 3 * w * h, "an RGB image of the frame's size");
            if !self.copy_images {
                // SAFETY: `data` outlives the execution below and holds w*h float3 pixels.
                unsafe {
                    (self.api.set_shared_filter_image)(
                        f,
                        c(name).as_ptr(),
                        data.as_mut_ptr().cast(),
                        FORMAT_FLOAT3,
                        w,
                        h,
                        0,
                        0,
                        0,
                    )
                };
                continue;
            }
            let bytes = std::mem::size_of_val(&**data);
            // SAFETY: a live device; a new buffer of `bytes` bytes.
            let b = unsafe { (self.api.new_buffer)(self.device, bytes) };
            self.check(stage)?;
            if b.is_null() {
                return Err(OidnError::Failed {
                    stage: stage.into(),
                    message: format!("no buffer of {bytes} bytes could be made"),
                });
            }
            buffers.made.push((name.to_string(), b));
            // SAFETY: `b` holds `bytes` bytes, as does `data`; the buffer outlives the filter's
            // use of it (the images are unset before `buffers` releases it).
            unsafe {
                if *name != "output" {
                    (self.api.write_buffer)(b, 0, bytes, data.as_ptr().cast());
                }
                (self.api.set_filter_image)(f, c(name).as_ptr(), b, FORMAT_FLOAT3, w, h, 0, 0, 0);
            }
        }
        // SAFETY: a live filter whose images are set.
        unsafe {
            // every flag is set each time: a shared filter keeps what an earlier role set
            for name in ["hdr", "cleanAux"] {
                let value = flags.iter().any(|(n, v)| *n == name && *v);
                (self.api.set_filter_bool)(f, c(name).as_ptr(), value);
            }
            (self.api.set_filter_int)(f, c("quality").as_ptr(), quality.code());
            // the HDR beauty's exposure: the frame's where a band is filtered, else OIDN's own
            // (the prefilters' always OIDN's own: a shared filter keeps what was set)
            let scale = match role {
                2 => self.input_scale.unwrap_or(f32::NAN),
                _ => f32::NAN,
            };
            (self.api.set_filter_float)(f, c("inputScale").as_ptr(), scale);
            (self.api.set_filter_int)(
                f,
                c("maxMemoryMB").as_ptr(),
                self.max_memory_mb
                    .map_or(-1, |m| m.min(c_int::MAX as usize) as c_int),
            );
            (self.api.commit_filter)(f);
        }
        self.check(stage)?;
        // SAFETY: a committed filter.
        unsafe { (self.api.execute_filter)(f) };
        let mut result = self.check(stage);
        if result.is_ok() {
            // the output back from its buffer (the only image OIDN writes)
            for (name, data) in images.iter_mut().filter(|(n, _)| *n == "output") {
                if let Some((_, b)) = buffers.made.iter().find(|(n, _)| n == name) {
                    // SAFETY: the output buffer holds as many bytes as `data`; reading waits
                    // for the filter to finish.
                    unsafe {
                        (self.api.read_buffer)(
                            *b,
                            0,
                            std::mem::size_of_val(&**data),
                            data.as_mut_ptr().cast(),
                        )
                    };
                    result = self.check(stage);
                }
            }
        }
        // the images are the caller's: forget them before they go
        for (name, _) in images.iter() {
            // SAFETY: a live filter.
            unsafe { (self.api.unset_filter_image)(f, c(name).as_ptr()) };
        }
        result
    }

    /// Sets the HDR beauty's exposure (OIDN's `inputScale`) for the filterings that follow;
    /// `None`: OIDN's own autoexposure of each image it is given. A frame filtered band by
    /// band needs the whole frame's ([`super::exposure::ExposureBins`]).
    pub fn set_input_scale(&mut self, scale: Option<f32>) {
        self.input_scale = scale;
    }

    /// Bounds OIDN's scratch memory per filter (`maxMemoryMB`; it then filters in overlapping
    /// tiles of its own); `None`: OIDN's default.
    /// While bounded, one filter serves the prefilters and the beauty in turn, so that OIDN
    /// holds one filter's scratch memory, not three.
    pub fn set_max_memory_mb(&mut self, mb: Option<usize>) {
        if mb.is_some() != self.max_memory_mb.is_some() {
            self.release_filters();
        }
        self.max_memory_mb = mb;
    }

    /// Releases every filter and the memory it holds (they are made again when next used).
    fn release_filters(&mut self) {
        for f in self.filters.iter_mut() {
            if !f.is_null() {
                // SAFETY: a filter made by this library, released once.
                unsafe { (self.api.release_filter)(*f) };
                *f = std::ptr::null_mut();
            }
        }
    }

    /// How many rows of context OIDN itself keeps around a tile (`tileOverlap` of its beauty
    /// filter at `quality`): the halo a band needs to be filtered as within the whole frame.
    pub fn tile_overlap(&mut self, quality: OidnQuality) -> Result<usize, OidnError> {
        let mut px = vec![0.0f32; 3 * 16 * 16];
        let mut out = vec![0.0f32; 3 * 16 * 16];
        // a filter is only sized once committed with images
        self.run(
            2,
            (16, 16),
            &mut [("color", &mut px), ("output", &mut out)],
            &[("hdr", true)],
            quality,
        )?;
        let c = CString::new("tileOverlap").expect("no NUL");
        // SAFETY: a live, committed filter.
        let slot = if self.max_memory_mb.is_some() { 0 } else { 2 };
        let v = unsafe { (self.api.get_filter_int)(self.filters[slot], c.as_ptr()) };
        self.check("reading the beauty filter's tile overlap")?;
        Ok(v.max(0) as usize)
    }

    /// OIDN's albedo or normal filter on `aux` (RGB) at `quality`.
    pub fn prefilter(
        &mut self,
        aux: &Plane,
        which: Aux,
        quality: OidnQuality,
    ) -> Result<Plane, OidnError> {
        let (w, h) = (aux.width(), aux.height());
        let (role, name, mut data) = match which {
            Aux::Albedo => (0, "albedo", interleave(aux, |v| v.clamp(0.0, 1.0))),
            Aux::Normal => (1, "normal", interleave(aux, |v| v.clamp(-1.0, 1.0))),
        };
        let mut out = vec![0.0f32; data.len()];
        self.run(
            role,
            (w, h),
            &mut [(name, &mut data), ("output", &mut out)],
            &[],
            quality,
        )?;
        Ok(deinterleave(w, h, &out))
    }

    /// OIDN's HDR beauty filter on `color` with its auxiliaries at `quality`, told they are
    /// clean (prefiltered) where `clean`.
    pub fn beauty(
        &mut self,
        color: &Plane,
        albedo: Option<&Plane>,
        normal: Option<&Plane>,
        quality: OidnQuality,
        clean: bool,
    ) -> Result<Plane, OidnError> {
        check_images(color, albedo, normal)?;
        let (w, h) = (color.width(), color.height());
        let mut col = interleave(color, |v| v.max(0.0));
        let mut out = vec![0.0f32; col.len()];
        let mut alb = albedo.map(|p| interleave(p, |v| v.clamp(0.0, 1.0)));
        let mut nrm = normal.map(|p| interleave(p, |v| v.clamp(-1.0, 1.0)));
        let clean = clean && (alb.is_some() || nrm.is_some());
        let mut images: Vec<(&str, &mut [f32])> = vec![("color", &mut col)];
        if let Some(a) = alb.as_mut() {
            images.push(("albedo", a));
        }
        if let Some(n) = nrm.as_mut() {
            images.push(("normal", n));
        }
        images.push(("output", &mut out));
        self.run(
            2,
            (w, h),
            &mut images,
            &[("hdr", true), ("cleanAux", clean)],
            quality,
        )?;
        Ok(deinterleave(w, h, &out))
    }
}

/// OIDN buffers made for one filtering, released when it is done.
struct Buffers {
    release: unsafe extern "C" fn(*mut c_void),
    /// Each image's name and buffer.
    made: Vec<(String, *mut c_void)>,
}

impl Drop for Buffers {
    fn drop(&mut self) {
        for (_, b) in self.made.drain(..) {
            // SAFETY: a buffer made by this library, released once (a filter that still uses
            // it keeps its own reference).
            unsafe { (self.release)(b) };
        }
    }
}

/// An auxiliary buffer OIDN prefilters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Aux {
    /// The albedo.
    Albedo,
    /// The shading normal.
    Normal,
}

/// Checks that a beauty and its auxiliaries can be filtered together.
fn check_images(
    color: &Plane,
    albedo: Option<&Plane>,
    normal: Option<&Plane>,
) -> Result<(), OidnError> {
    let (w, h) = (color.width(), color.height());
    for (p, what) in [(albedo, "albedo"), (normal, "normal")] {
        if let Some(p) = p {
            if !p.same_size(color) || p.channels() != 3 {
                return Err(OidnError::Input(format!(
                    "the {what} is {}x{}x{}, the beauty {w}x{h}x3",
                    p.width(),
                    p.height(),
                    p.channels()
                )));
            }
        }
    }
    if color.channels() != 3 {
        return Err(OidnError::Input("the beauty must be RGB".into()));
    }
    if normal.is_some() && albedo.is_none() {
        return Err(OidnError::Input("a normal needs an albedo".into()));
    }
    Ok(())
}

impl Drop for OidnDenoiser {
    fn drop(&mut self) {
        // SAFETY: the filters and the device were made by this library and are released once.
        self.release_filters();
        unsafe {
            if !self.device.is_null() {
                (self.api.release_device)(self.device);
            }
        }
    }
}

/// Channel-major RGB to interleaved, through `map`.
fn interleave(p: &Plane, map: impl Fn(f32) -> f32) -> Vec<f32> {
    let n = p.pixels();
    let (r, g, b) = (p.channel(0), p.channel(1), p.channel(2));
    let mut out = Vec::with_capacity(3 * n);
    for i in 0..n {
        out.extend_from_slice(&[map(r[i]), map(g[i]), map(b[i])]);
    }
    out
}

/// Interleaved RGB to a channel-major plane.
fn deinterleave(w: usize, h: usize, v: &[f32]) -> Plane {
    let n = w * h;
    let mut data = vec![0.0f32; 3 * n];
    for i in 0..n {
        for c in 0..3 {
            data[c * n + i] = v[3 * i + c];
        }
    }
    Plane::from_vec(w, h, 3, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interleaving_round_trips() {
        let p = Plane::from_fn(3, 2, 3, |x, y, c| (x + 10 * y + 100 * c) as f32);
        let back = deinterleave(3, 2, &interleave(&p, |v| v));
        assert_eq!(back.data(), p.data());
    }
}
