//! Finding Intel Open Image Denoise's library and the C functions of its 2.x API that radn
//! calls (`oidn.h`), resolved once when the library is opened. Where the library is looked for
//! is described in [`super::oidn`].

use std::ffi::{c_char, c_int, c_void};
use std::path::{Path, PathBuf};

/// An OIDN device type: the CPU.
pub(super) const DEVICE_TYPE_CPU: c_int = 1;
/// An OIDN device type: an NVIDIA GPU through CUDA.
pub(super) const DEVICE_TYPE_CUDA: c_int = 3;
/// OIDN's `OIDN_FORMAT_FLOAT3`.
pub(super) const FORMAT_FLOAT3: c_int = 3;
/// The oldest OIDN whose C API this module speaks (2.0.0, as `major*10000 + minor*100 + patch`).
pub(super) const OLDEST_VERSION: c_int = 20000;

type NewDevice = unsafe extern "C" fn(c_int) -> *mut c_void;
type DeviceFn = unsafe extern "C" fn(*mut c_void);
type SetDeviceInt = unsafe extern "C" fn(*mut c_void, *const c_char, c_int);
type GetDeviceInt = unsafe extern "C" fn(*mut c_void, *const c_char) -> c_int;
type GetDeviceError = unsafe extern "C" fn(*mut c_void, *mut *const c_char) -> c_int;
type NewFilter = unsafe extern "C" fn(*mut c_void, *const c_char) -> *mut c_void;
type FilterFn = unsafe extern "C" fn(*mut c_void);
/// `oidnSetSharedFilterImage` and `oidnSetFilterImage`: filter, image name, the host pointer or
/// OIDN buffer, format, width, height, byte offset, pixel and row strides (0: packed).
type SetImage = unsafe extern "C" fn(
    *mut c_void,
    *const c_char,
    *mut c_void,
    c_int,
    usize,
    usize,
    usize,
    usize,
    usize,
);
type NewCudaDevice = unsafe extern "C" fn(*const c_int, *const *mut c_void, c_int) -> *mut c_void;
type GetDeviceBool = unsafe extern "C" fn(*mut c_void, *const c_char) -> bool;
type NewBuffer = unsafe extern "C" fn(*mut c_void, usize) -> *mut c_void;
type CopyToBuffer = unsafe extern "C" fn(*mut c_void, usize, usize, *const c_void);
type CopyFromBuffer = unsafe extern "C" fn(*mut c_void, usize, usize, *mut c_void);
type BufferFn = unsafe extern "C" fn(*mut c_void);
type UnsetFilterImage = unsafe extern "C" fn(*mut c_void, *const c_char);
type SetFilterBool = unsafe extern "C" fn(*mut c_void, *const c_char, bool);
type SetFilterInt = unsafe extern "C" fn(*mut c_void, *const c_char, c_int);
type GetFilterInt = unsafe extern "C" fn(*mut c_void, *const c_char) -> c_int;
type SetFilterFloat = unsafe extern "C" fn(*mut c_void, *const c_char, f32);

/// The C functions radn calls, resolved once from the library.
pub(super) struct Api {
    pub(super) new_device: NewDevice,
    pub(super) new_cuda_device: NewCudaDevice,
    pub(super) get_device_bool: GetDeviceBool,
    pub(super) new_buffer: NewBuffer,
    pub(super) write_buffer: CopyToBuffer,
    pub(super) read_buffer: CopyFromBuffer,
    pub(super) release_buffer: BufferFn,
    pub(super) set_filter_image: SetImage,
    pub(super) commit_device: DeviceFn,
    pub(super) release_device: DeviceFn,
    pub(super) set_device_int: SetDeviceInt,
    pub(super) get_device_int: GetDeviceInt,
    pub(super) get_device_error: GetDeviceError,
    pub(super) new_filter: NewFilter,
    pub(super) commit_filter: FilterFn,
    pub(super) execute_filter: FilterFn,
    pub(super) release_filter: FilterFn,
    pub(super) set_shared_filter_image: SetImage,
    pub(super) unset_filter_image: UnsetFilterImage,
    pub(super) set_filter_bool: SetFilterBool,
    pub(super) set_filter_int: SetFilterInt,
    pub(super) get_filter_int: GetFilterInt,
    pub(super) set_filter_float: SetFilterFloat,
}

impl Api {
    pub(super) fn load(lib: &libloading::Library) -> Result<Self, String> {
        fn get<T: Copy>(lib: &libloading::Library, name: &str) -> Result<T, String> {
            // SAFETY: every caller below names an OIDN 2.x function with its signature of
            // type T (oidn.h); the library outlives the pointers (`OidnDenoiser` drops it last).
            unsafe { lib.get::<T>(name.as_bytes()) }
                .map(|s| *s)
                .map_err(|e| format!("the library lacks {name}: {e}"))
        }
        Ok(Self {
            new_device: get(lib, "oidnNewDevice")?,
            new_cuda_device: get(lib, "oidnNewCUDADevice")?,
            get_device_bool: get(lib, "oidnGetDeviceBool")?,
            new_buffer: get(lib, "oidnNewBuffer")?,
            write_buffer: get(lib, "oidnWriteBuffer")?,
            read_buffer: get(lib, "oidnReadBuffer")?,
            release_buffer: get(lib, "oidnReleaseBuffer")?,
            set_filter_image: get(lib, "oidnSetFilterImage")?,
            commit_device: get(lib, "oidnCommitDevice")?,
            release_device: get(lib, "oidnReleaseDevice")?,
            set_device_int: get(lib, "oidnSetDeviceInt")?,
            get_device_int: get(lib, "oidnGetDeviceInt")?,
            get_device_error: get(lib, "oidnGetDeviceError")?,
            new_filter: get(lib, "oidnNewFilter")?,
            commit_filter: get(lib, "oidnCommitFilter")?,
            execute_filter: get(lib, "oidnExecuteFilter")?,
            release_filter: get(lib, "oidnReleaseFilter")?,
            set_shared_filter_image: get(lib, "oidnSetSharedFilterImage")?,
            unset_filter_image: get(lib, "oidnUnsetFilterImage")?,
            set_filter_bool: get(lib, "oidnSetFilterBool")?,
            set_filter_int: get(lib, "oidnSetFilterInt")?,
            get_filter_int: get(lib, "oidnGetFilterInt")?,
            set_filter_float: get(lib, "oidnSetFilterFloat")?,
        })
    }
}

/// The file name the OIDN 2.x library has on this platform.
fn library_name() -> &'static str {
    if cfg!(target_os = "macos") {
        "libOpenImageDenoise.2.dylib"
    } else if cfg!(windows) {
        "OpenImageDenoise.dll"
    } else {
        "libOpenImageDenoise.so.2"
    }
}

/// Where to look for the library, in order (see the module documentation), with what each
/// candidate is, for messages.
pub(super) fn candidates() -> Vec<(PathBuf, String)> {
    let name = library_name();
    let mut out = Vec::new();
    let in_dir = |d: &Path| {
        if d.is_dir() {
            d.join(name)
        } else {
            d.to_path_buf()
        }
    };
    if let Some(p) = std::env::var_os("RADN_OIDN_LIBRARY") {
        // an explicit choice: nothing else is tried
        out.push((in_dir(Path::new(&p)), "RADN_OIDN_LIBRARY".into()));
        return out;
    }
    if let Some(d) = std::env::var_os("OIDN_DIR") {
        out.push((Path::new(&d).join("lib").join(name), "OIDN_DIR".into()));
    }
    out.push((PathBuf::from(name), "the system loader path".into()));
    let (pyoidn, bpy) = python_lib_dirs();
    if let Some(d) = pyoidn {
        out.push((d.join(name), "the pyoidn wheel".into()));
    }
    if let Some(d) = bpy {
        out.push((d.join(name), "Blender's bpy wheel".into()));
    }
    if let Some(path) = std::env::var_os("PATH") {
        for d in blender_lib_dirs(&path) {
            out.push((d.join(name), "the Blender on PATH".into()));
        }
    }
    out
}

/// The `lib/` folders of the `pyoidn` and `bpy` wheels installed for `python3`, where present
/// (one interpreter start for both; nothing is imported).
fn python_lib_dirs() -> (Option<PathBuf>, Option<PathBuf>) {
    let Ok(out) = std::process::Command::new("python3")
        .args([
            "-c",
            "import importlib.util as u, os\n\
             for m, sub in (('pyoidn', ('oidn', 'lib')), ('bpy', ('lib',))):\n\
             \x20   s = u.find_spec(m)\n\
             \x20   print(os.path.join(os.path.dirname(s.origin), *sub) if s and s.origin else '')",
        ])
        .stderr(std::process::Stdio::null())
        .output()
    else {
        return (None, None);
    };
    let text = String::from_utf8_lossy(&out.stdout);
    let mut lines = text.lines().map(|l| {
        let l = l.trim();
        (!l.is_empty()).then(|| PathBuf::from(l))
    });
    (lines.next().flatten(), lines.next().flatten())
}

/// Where a Blender install on the search path `path` (as `PATH` holds it) keeps its bundled
/// libraries: `lib/` beside the executable (Linux), `../Resources/lib` (macOS),
/// `blender.shared/` (Windows). A `blender` that is a link (e.g. in `/usr/local/bin`) is
/// followed to the install.
fn blender_lib_dirs(path: &std::ffi::OsStr) -> Vec<PathBuf> {
    let exe = if cfg!(windows) {
        "blender.exe"
    } else {
        "blender"
    };
    std::env::split_paths(path)
        .map(|d| d.join(exe))
        .filter(|p| p.is_file())
        .filter_map(|p| std::fs::canonicalize(p).ok())
        .filter_map(|p| p.parent().map(Path::to_path_buf))
        .flat_map(|d| {
            [
                d.join("lib"),
                d.join("../Resources/lib"),
                d.join("blender.shared"),
            ]
        })
        .filter(|d| d.is_dir())
        .collect()
}

/// The file a loaded library was read from, where the system can say (a library opened by its
/// bare name through the loader's search path): the object that holds `symbol`'s address.
pub(super) fn loaded_file(symbol: *const c_void) -> Option<PathBuf> {
    #[cfg(unix)]
    {
        let mut info: libc::Dl_info = unsafe { std::mem::zeroed() };
        // SAFETY: dladdr only reads the loader's tables; `info` is a valid out-parameter.
        if unsafe { libc::dladdr(symbol, &mut info) } == 0 || info.dli_fname.is_null() {
            return None;
        }
        // SAFETY: the loader's NUL-terminated file name, valid while the library is loaded.
        let name = unsafe { std::ffi::CStr::from_ptr(info.dli_fname) };
        let path = PathBuf::from(name.to_string_lossy().into_owned());
        std::fs::canonicalize(&path).ok().or(Some(path))
    }
    #[cfg(not(unix))]
    {
        let _ = symbol;
        None
    }
}

pub(super) fn version_text(v: c_int) -> String {
    format!("{}.{}.{}", v / 10000, v / 100 % 100, v % 100)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_blender_on_the_search_path_gives_its_bundled_library_folder() {
        let d = tempfile::tempdir().unwrap();
        let install = d.path().join("blender-4.5-linux-x64");
        std::fs::create_dir_all(install.join("lib")).unwrap();
        std::fs::write(install.join("blender"), b"#!/bin/sh\n").unwrap();
        // on the search path through a link, as a system install puts it
        let bin = d.path().join("bin");
        std::fs::create_dir_all(&bin).unwrap();
        #[cfg(unix)]
        std::os::unix::fs::symlink(install.join("blender"), bin.join("blender")).unwrap();
        let empty = d.path().join("empty");
        std::fs::create_dir_all(&empty).unwrap();
        let path = std::env::join_paths([&empty, &bin]).unwrap();
        let found = blender_lib_dirs(&path);
        let want = std::fs::canonicalize(install.join("lib")).unwrap();
        assert!(
            found
                .iter()
                .any(|f| std::fs::canonicalize(f).unwrap() == want),
            "{found:?}"
        );
        assert!(blender_lib_dirs(&std::env::join_paths([&empty]).unwrap()).is_empty());
    }
}
