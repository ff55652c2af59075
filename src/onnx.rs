//! ONNX Runtime backend selection and session loading: the one ONNX module, shared by the
//! geometric branch (SpinNet) and the image branch (the VFMs).
//!
//! One `ort` build (2.0.0-rc.14, `alternative-backend`) serves up to two backends, chosen once
//! per process on first use:
//! 1. native ONNX Runtime (>= 1.24, C API 24), from `ORT_DYLIB_PATH`, else the shared library of
//!    a pip-installed `onnxruntime` wheel (`onnxruntime/capi/libonnxruntime.so.*`), found in the
//!    build folder's private venv (`target/ortvenv`, made by scripts/setup.sh), through the
//!    `python3` on `PATH` (isolated, run from `/`, asked where the package is without importing
//!    it: see [`python_onnxruntime_dir`]) and by globbing the usual site-packages folders;
//! 2. tract (pure Rust), when no native library loads, in a build with the opt-in `tract`
//!    feature; without it a missing native library is an error that says how to get one.
//!
//! `CGENREG_ORT_BACKEND=tract` forces tract (a `tract` build) and `=native` makes a missing
//! native library an error (used by the benchmark). Loading is checked step by step (file, symbol, API version), so a
//! missing or broken library never panics; the reason is kept in [`backend_info`].
//!
//! Native sessions run on the CPU, or on an NVIDIA GPU through ONNX Runtime's CUDA execution
//! provider when the loaded library has it (the `onnxruntime-gpu` wheel): `CGENREG_ORT_PROVIDER`
//! = `auto` (the default: CUDA when available), `cpu`, or `cuda` (an error without it). The
//! provider is chosen once per process and named in [`BackendInfo::describe`], so every result
//! says where its descriptors were computed.

use crate::error::{Error, Result};
use ort::session::Session;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

/// The backend chosen for this process.
#[derive(Clone, Debug)]
pub struct BackendInfo {
    /// "onnxruntime" or "tract".
    pub kind: &'static str,
    /// Native library version, when native.
    pub version: Option<String>,
    pub library: Option<PathBuf>,
    /// Why the native library was not used (when tract was chosen), or None.
    pub note: Option<String>,
    /// Where native sessions run (always the CPU under tract).
    pub provider: Provider,
}

/// Where native ONNX Runtime sessions run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Provider {
    Cpu,
    /// ONNX Runtime's CUDA execution provider (an NVIDIA GPU).
    Cuda,
}

/// The provider for a `CGENREG_ORT_PROVIDER` value (`auto` or empty, `cpu`, `cuda`), given
/// whether the loaded ONNX Runtime has the CUDA provider.
pub fn choose_provider(
    request: &str,
    cuda_available: bool,
) -> std::result::Result<Provider, String> {
    match request.trim() {
        "" | "auto" if cuda_available => Ok(Provider::Cuda),
        "" | "auto" | "cpu" => Ok(Provider::Cpu),
        "cuda" if cuda_available => Ok(Provider::Cuda),
        "cuda" => Err(
            "CGENREG_ORT_PROVIDER=cuda but the loaded ONNX Runtime has no CUDA provider (it needs \
             the onnxruntime-gpu build and the CUDA libraries: see docs/install.md)"
                .to_string(),
        ),
        other => Err(format!(
            "CGENREG_ORT_PROVIDER: expected auto, cpu or cuda, got {other:?}"
        )),
    }
}

impl BackendInfo {
    pub fn describe(&self) -> String {
        match (self.kind, &self.version, &self.library) {
            // The file name only: this string lands in results, tables and plot titles, where a
            // machine's folders do not belong (`library` keeps the full path).
            ("onnxruntime", Some(v), Some(p)) => format!(
                "onnxruntime {v} ({}{})",
                p.file_name()
                    .map(|n| n.to_string_lossy())
                    .unwrap_or_default(),
                match self.provider {
                    Provider::Cpu => "",
                    Provider::Cuda => ", CUDA",
                }
            ),
            _ => match &self.note {
                Some(n) => format!("tract (pure Rust; {n})"),
                None => "tract (pure Rust)".to_string(),
            },
        }
    }
}

struct Runtime {
    info: BackendInfo,
    env: ort::environment::Environment,
}

static RUNTIME: OnceLock<std::result::Result<Runtime, String>> = OnceLock::new();

fn runtime() -> Result<&'static Runtime> {
    RUNTIME
        .get_or_init(init)
        .as_ref()
        .map_err(|e| Error::External {
            what: "ONNX runtime".into(),
            message: e.clone(),
        })
}

/// The backend in use (initialising it on first call).
pub fn backend_info() -> Result<BackendInfo> {
    runtime().map(|r| r.info.clone())
}

/// One-line description of the backend in use, or why none could be set up.
pub fn backend_name() -> String {
    match runtime() {
        Ok(r) => r.info.describe(),
        Err(e) => format!("none ({e})"),
    }
}

/// No native ONNX Runtime: tract, the pure-Rust fallback, in a build with the `tract` feature.
#[cfg(feature = "tract")]
fn fallback(forced: &str, why: String) -> std::result::Result<BackendInfo, String> {
    if forced == "native" {
        return Err(format!(
            "CGENREG_ORT_BACKEND=native but no native ONNX Runtime: {why}"
        ));
    }
    ort::set_api(ort_tract::api());
    Ok(BackendInfo {
        kind: "tract",
        version: None,
        library: None,
        note: Some(why),
        provider: Provider::Cpu,
    })
}

/// No native ONNX Runtime, and a build without the `tract` fallback: what to do about it.
#[cfg(not(feature = "tract"))]
fn fallback(_forced: &str, why: String) -> std::result::Result<BackendInfo, String> {
    Err(format!(
        "no native ONNX Runtime could be loaded ({why}); run scripts/setup.sh (it unpacks one \
         under target/), or set ORT_DYLIB_PATH to a libonnxruntime.so (docs/install.md); a \
         build with `--features tract` falls back to the pure-Rust tract instead"
    ))
}

fn init() -> std::result::Result<Runtime, String> {
    let forced = std::env::var("CGENREG_ORT_BACKEND").unwrap_or_default();
    let native = if forced == "tract" {
        Err("forced by CGENREG_ORT_BACKEND=tract".to_string())
    } else {
        load_native()
    };
    let info = match native {
        Ok((api, version, library)) => {
            ort::set_api(api);
            BackendInfo {
                kind: "onnxruntime",
                version: Some(version),
                library: Some(library),
                note: None,
                provider: Provider::Cpu,
            }
        }
        Err(why) => fallback(&forced, why)?,
    };
    let env = ort::init()
        .with_name("cgenreg")
        .build()
        .map_err(|e| format!("creating the {} environment: {e}", info.kind))?;
    let mut info = info;
    if info.kind == "onnxruntime" {
        let request = std::env::var("CGENREG_ORT_PROVIDER").unwrap_or_default();
        let (usable, why) = cuda_usable(&env, info.library.as_deref());
        info.provider = choose_provider(&request, usable).map_err(|e| match &why {
            Some(w) => format!("{e}; {w}"),
            None => e,
        })?;
        if info.provider == Provider::Cpu && request.trim() != "cpu" {
            info.note = why;
        }
    }
    Ok(Runtime { info, env })
}

/// Whether a session can take ONNX Runtime's CUDA provider here: the loaded library lists it
/// (the onnxruntime-gpu build) and registering it works (its CUDA and cuDNN libraries load).
/// Otherwise why not, when the library has the provider but cannot use it.
fn cuda_usable(
    env: &ort::environment::Environment,
    library: Option<&Path>,
) -> (bool, Option<String>) {
    use ort::ep::ExecutionProvider;
    if !ort::ep::CUDA::is_available().unwrap_or(false) {
        return (false, None);
    }
    if let Some(lib) = library {
        preload_cuda_wheels(lib);
    }
    let probe = Session::builder(env).and_then(|b| {
        b.with_execution_providers([ort::ep::CUDA::default().build().error_on_failure()])
            .map_err(ort::Error::from)
    });
    match probe {
        Ok(_) => (true, None),
        Err(e) => (
            false,
            Some(format!(
                "the CUDA provider is present but does not load: {e}"
            )),
        ),
    }
}

/// The CUDA and cuDNN libraries of the `nvidia-*` wheels that `onnxruntime-gpu[cuda,cudnn]`
/// installs beside it (`site-packages/nvidia/*/lib`), loaded globally before the CUDA provider
/// is registered, as ONNX Runtime's own Python package does: the provider finds them by name
/// then, without `LD_LIBRARY_PATH`. Libraries that do not load are left to the system's search
/// path (a CUDA toolkit installed system-wide); the probe that follows says whether it worked.
#[cfg(unix)]
fn preload_cuda_wheels(ort_library: &Path) {
    // <site-packages>/onnxruntime/capi/libonnxruntime.so.*
    let Some(site) = ort_library.ancestors().nth(3) else {
        return;
    };
    let Ok(groups) = std::fs::read_dir(site.join("nvidia")) else {
        return;
    };
    let mut left: Vec<PathBuf> = groups
        .flatten()
        .filter_map(|g| std::fs::read_dir(g.path().join("lib")).ok())
        .flat_map(|d| d.flatten().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("lib") && n.contains(".so"))
        })
        .collect();
    left.sort();
    // a library whose dependencies are not loaded yet fails; retry until no progress
    loop {
        let before = left.len();
        left.retain(|p| {
            use libloading::os::unix::{Library, RTLD_GLOBAL, RTLD_NOW};
            // SAFETY: loading the CUDA runtime's libraries runs their initialisers, as ONNX
            // Runtime's own loading of them would; they stay loaded for the process.
            match unsafe { Library::open(Some(p), RTLD_NOW | RTLD_GLOBAL) } {
                Ok(l) => {
                    std::mem::forget(l);
                    false
                }
                Err(_) => true,
            }
        });
        if left.is_empty() || left.len() == before {
            break;
        }
    }
}

#[cfg(not(unix))]
fn preload_cuda_wheels(_ort_library: &Path) {}

/// Candidate native libraries, best first.
pub fn native_library_candidates() -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Ok(p) = std::env::var("ORT_DYLIB_PATH") {
        if !p.is_empty() {
            out.push(PathBuf::from(p));
            // An explicit path is the user's choice: do not silently try others.
            return out;
        }
    }
    let mut dirs: Vec<PathBuf> = Vec::new();
    let mut roots: Vec<PathBuf> = Vec::new();
    // scripts/setup.sh installs the wheel into a private venv in the build folder
    // (`target/ortvenv`), never into the system Python: look beside the running binary first
    // (target/release/cgenreg, target/debug/deps/<test>).
    // The Python extension is a shared object in the source tree (python/cgenreg/), its
    // process the interpreter: look beside the object holding this code too.
    let here = [std::env::current_exe().ok(), this_object()];
    for exe in here.iter().flatten() {
        let found = exe.ancestors().skip(1).take(4).find_map(|a| {
            [a.join("ortvenv/lib"), a.join("target/ortvenv/lib")]
                .into_iter()
                .find(|lib| lib.is_dir())
        });
        if let Some(lib) = found {
            dirs.extend(site_packages(&lib));
            break;
        }
    }
    if let Some(d) = python_onnxruntime_dir() {
        dirs.push(d);
    }
    if let Ok(v) = std::env::var("VIRTUAL_ENV") {
        roots.push(PathBuf::from(v).join("lib"));
    }
    if let Ok(h) = std::env::var("HOME") {
        roots.push(PathBuf::from(h).join(".local/lib"));
    }
    roots.extend(["/usr/local/lib", "/usr/lib"].map(PathBuf::from));
    for root in roots {
        dirs.extend(site_packages(&root));
    }
    for d in dirs {
        let capi = d.join("capi");
        let Ok(rd) = std::fs::read_dir(&capi) else {
            continue;
        };
        let mut libs: Vec<PathBuf> = rd
            .flatten()
            .map(|e| e.path())
            .filter(|p| {
                p.file_name()
                    .map(|n| n.to_string_lossy().starts_with("libonnxruntime.so"))
                    .unwrap_or(false)
            })
            .collect();
        libs.sort();
        for l in libs.into_iter().rev() {
            if !out.contains(&l) {
                out.push(l);
            }
        }
    }
    out
}

/// Where the `python3` on `PATH` has its `onnxruntime` package, without running any code from
/// the working directory or a data folder: the interpreter is looked up in absolute `PATH`
/// entries only (a `.` or empty entry would run a `python3` lying in the working directory),
/// and it runs isolated (`-I`: no working directory or script folder on `sys.path`, no
/// `PYTHON*` variables, no user site) from `/`, and only asks the import system where the
/// package is (`find_spec` of a top-level package reads no module of it). Before, `python3 -c
/// 'import onnxruntime'` ran in the working directory, so an `onnxruntime.py` lying there ran.
pub fn python_onnxruntime_dir() -> Option<PathBuf> {
    const ASK: &str = "import importlib.util as u\n\
                       s = u.find_spec('onnxruntime')\n\
                       print((list(s.submodule_search_locations or []) or [''])[0] if s else '')";
    let python = absolute_path_program("python3")?;
    let o = std::process::Command::new(python)
        .args(["-I", "-c", ASK])
        .current_dir("/")
        .stdin(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .output()
        .ok()?;
    let s = String::from_utf8_lossy(&o.stdout).trim().to_string();
    let dir = PathBuf::from(s);
    (o.status.success() && dir.is_absolute()).then_some(dir)
}

/// The file of the executable or shared object this code was loaded from (the Python
/// extension's `.so` inside an interpreter).
#[cfg(unix)]
fn this_object() -> Option<PathBuf> {
    let mut info: libc::Dl_info = unsafe { std::mem::zeroed() };
    let addr = this_object as *const () as *const libc::c_void;
    // SAFETY: dladdr reads the address and fills `info` with pointers into the loader's data.
    if unsafe { libc::dladdr(addr, &mut info) } == 0 || info.dli_fname.is_null() {
        return None;
    }
    // SAFETY: a NUL-terminated path owned by the loader.
    let name = unsafe { std::ffi::CStr::from_ptr(info.dli_fname) };
    use std::os::unix::ffi::OsStrExt;
    let p = PathBuf::from(std::ffi::OsStr::from_bytes(name.to_bytes()));
    p.canonicalize().ok()
}

#[cfg(not(unix))]
fn this_object() -> Option<PathBuf> {
    None
}

/// `name` in the absolute folders of `PATH` (relative entries, `.` and empty ones included, are
/// skipped: they name the working directory).
fn absolute_path_program(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .filter(|d| d.is_absolute())
        .map(|d| d.join(name))
        .find(|p| {
            #[cfg(unix)]
            {
                use std::os::unix::fs::PermissionsExt;
                std::fs::metadata(p)
                    .map(|m| m.is_file() && m.permissions().mode() & 0o111 != 0)
                    .unwrap_or(false)
            }
            #[cfg(not(unix))]
            {
                p.is_file()
            }
        })
}

/// `<lib>/python3*/{site,dist}-packages/onnxruntime` folders under a Python `lib` folder.
fn site_packages(lib: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let Ok(rd) = std::fs::read_dir(lib) else {
        return out;
    };
    for e in rd.flatten() {
        if e.file_name().to_string_lossy().starts_with("python3") {
            for sp in ["site-packages", "dist-packages"] {
                out.push(e.path().join(sp).join("onnxruntime"));
            }
        }
    }
    out
}

/// dlopen a native ONNX Runtime and fetch its C API at the version this build uses.
fn load_native() -> std::result::Result<(ort::sys::OrtApi, String, PathBuf), String> {
    let cands = native_library_candidates();
    if cands.is_empty() {
        return Err(
            "no native ONNX Runtime found (run scripts/setup.sh, or set ORT_DYLIB_PATH)".into(),
        );
    }
    let mut errors = Vec::new();
    for path in cands {
        match load_one(&path) {
            Ok((api, v)) => return Ok((api, v, path)),
            Err(e) => errors.push(format!("{}: {e}", path.display())),
        }
    }
    Err(errors.join("; "))
}

fn load_one(path: &Path) -> std::result::Result<(ort::sys::OrtApi, String), String> {
    if !path.is_file() {
        return Err("no such file".into());
    }
    // SAFETY: loading a shared library runs its initialisers; ONNX Runtime's are benign. The
    // library is leaked below so the API pointers stay valid for the process lifetime.
    let lib = unsafe { libloading::Library::new(path) }.map_err(|e| e.to_string())?;
    let get_base: libloading::Symbol<unsafe extern "C" fn() -> *const ort::sys::OrtApiBase> =
        unsafe { lib.get(b"OrtGetApiBase") }
            .map_err(|e| format!("not an ONNX Runtime library ({e})"))?;
    let base = unsafe { get_base() };
    if base.is_null() {
        return Err("OrtGetApiBase returned null".into());
    }
    let version = unsafe {
        let s = ((*base).GetVersionString)();
        if s.is_null() {
            String::from("?")
        } else {
            std::ffi::CStr::from_ptr(s).to_string_lossy().into_owned()
        }
    };
    let api = unsafe { ((*base).GetApi)(ort::sys::ORT_API_VERSION) };
    if api.is_null() {
        return Err(format!(
            "version {version} does not provide C API {} (need ONNX Runtime >= 1.{})",
            ort::sys::ORT_API_VERSION,
            ort::sys::ORT_API_VERSION
        ));
    }
    let api = unsafe { std::ptr::read(api) };
    std::mem::forget(lib);
    Ok((api, version))
}

/// A loaded model: a session behind a mutex (`ort` runs take `&mut`), with its I/O names.
pub struct OnnxModel {
    pub path: PathBuf,
    pub inputs: Vec<String>,
    pub outputs: Vec<String>,
    session: Mutex<Session>,
}

impl std::fmt::Debug for OnnxModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxModel")
            .field("path", &self.path)
            .field("inputs", &self.inputs)
            .field("outputs", &self.outputs)
            .finish()
    }
}

/// Intra-op threads: `CGENREG_ORT_THREADS`, else all cores.
fn threads() -> usize {
    std::env::var("CGENREG_ORT_THREADS")
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|&n| n > 0)
        .unwrap_or_else(|| {
            std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1)
        })
}

impl OnnxModel {
    /// Load `path`, checking that it exists, parses as ONNX, and has the named inputs and
    /// outputs (`expected` describes the model for error messages).
    pub fn load(
        path: &Path,
        want_inputs: &[&str],
        want_outputs: &[&str],
        expected: &str,
    ) -> Result<OnnxModel> {
        let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
        if meta.len() < 16 {
            return Err(Error::format(
                path,
                "model",
                expected,
                format!("a {}-byte file", meta.len()),
            ));
        }
        let rt = runtime()?;
        let mut builder = Session::builder(&rt.env).map_err(|e| Error::External {
            what: rt.info.describe(),
            message: e.to_string(),
        })?;
        if rt.info.kind == "onnxruntime" {
            // No spin-waiting between a run's parallel sections: the pipeline runs sessions beside
            // its own rayon work (and several sessions at once), where ONNX Runtime's spinning
            // threads only take cores from the work (a `pause` loop was 2-3 % of the test suite's
            // CPU time). How a run is split over threads, and so its results, do not change.
            let external = |e: ort::Error| Error::External {
                what: rt.info.describe(),
                message: e.to_string(),
            };
            builder = builder
                .with_intra_threads(threads())
                .map_err(|e| external(e.into()))?
                .with_intra_op_spinning(false)
                .map_err(|e| external(e.into()))?;
            if rt.info.provider == Provider::Cuda {
                // an error, not a silent CPU run, when the GPU cannot take the session: the
                // results say CUDA
                builder = builder
                    .with_execution_providers([ort::ep::CUDA::default().build().error_on_failure()])
                    .map_err(|e| Error::External {
                        what: rt.info.describe(),
                        message: format!("registering the CUDA execution provider: {e}"),
                    })?;
            }
        }
        let session = builder.commit_from_file(path).map_err(|e| {
            Error::format(
                path,
                "model",
                format!("{expected} loadable by {}", rt.info.describe()),
                e.to_string(),
            )
        })?;
        let inputs: Vec<String> = session
            .inputs()
            .iter()
            .map(|o| o.name().to_string())
            .collect();
        let outputs: Vec<String> = session
            .outputs()
            .iter()
            .map(|o| o.name().to_string())
            .collect();
        for (kind, want, have) in [
            ("inputs", want_inputs, &inputs),
            ("outputs", want_outputs, &outputs),
        ] {
            for w in want {
                if !have.iter().any(|h| h == w) {
                    return Err(Error::format(
                        path,
                        kind,
                        format!("{expected} with {kind} named {want:?}"),
                        format!("{have:?}"),
                    ));
                }
            }
        }
        Ok(OnnxModel {
            path: path.to_path_buf(),
            inputs,
            outputs,
            session: Mutex::new(session),
        })
    }

    /// Run on f32 inputs and hand one named f32 output, as (shape, data) borrowed from the
    /// runtime, to `f`: no copy of the output is made, and it is freed when `f` returns (the
    /// dense models read a few pixels of a full-resolution map this way).
    pub fn run_with<R>(
        &self,
        inputs: Vec<(&str, Vec<i64>, Vec<f32>)>,
        output: &str,
        f: impl FnOnce(&[i64], &[f32]) -> Result<R>,
    ) -> Result<R> {
        // One output asked, so `f` runs once.
        let mut f = Some(f);
        self.run_each(inputs, &[output], |shape, data| match f.take() {
            Some(f) => f(shape, data),
            None => Err(Error::Invalid(format!("output {output} seen twice"))),
        })?
        .pop()
        .ok_or_else(|| Error::Missing(format!("no result for output {output}")))
    }

    /// Run on f32 inputs given as (name, shape, data); returns the named f32 outputs as
    /// (shape, data) in the order of `outputs`.
    pub fn run(
        &self,
        inputs: Vec<(&str, Vec<i64>, Vec<f32>)>,
        outputs: &[&str],
    ) -> Result<Vec<(Vec<i64>, Vec<f32>)>> {
        self.run_each(inputs, outputs, |shape, data| {
            Ok((shape.to_vec(), data.to_vec()))
        })
    }

    /// Run on f32 inputs and hand each named f32 output, in the order of `outputs`, to `f` as
    /// (shape, data) while it is still the runtime's buffer.
    fn run_each<R>(
        &self,
        inputs: Vec<(&str, Vec<i64>, Vec<f32>)>,
        outputs: &[&str],
        mut f: impl FnMut(&[i64], &[f32]) -> Result<R>,
    ) -> Result<Vec<R>> {
        let err = |e: ort::Error| Error::External {
            what: format!("{} ({})", self.path.display(), backend_name()),
            message: e.to_string(),
        };
        let mut values: Vec<(
            std::borrow::Cow<'_, str>,
            ort::session::SessionInputValue<'_>,
        )> = Vec::new();
        for (name, shape, data) in inputs {
            let t = ort::value::Tensor::from_array((shape, data)).map_err(err)?;
            values.push((name.to_string().into(), t.into()));
        }
        let mut session = self
            .session
            .lock()
            .map_err(|_| Error::Invalid("ONNX session poisoned by an earlier panic".into()))?;
        let out = session.run(values).map_err(err)?;
        let mut res = Vec::with_capacity(outputs.len());
        for name in outputs {
            let v = out.get(*name).ok_or_else(|| Error::External {
                what: self.path.display().to_string(),
                message: format!("no output named {name}"),
            })?;
            let (shape, data) = v.try_extract_tensor::<f32>().map_err(err)?;
            let shape: Vec<i64> = shape.iter().copied().collect();
            res.push(f(&shape, data)?);
        }
        Ok(res)
    }
}

/// Short content id of a model (blake3, first 16 hex digits), for cache keys: the `.onnx` file
/// and, in order, every external-data file it names (`mast3r_512.onnx.data` for an export made
/// by models/export_mast3r.py, where all the weights live). A model without external data keeps
/// the id of its bytes alone.
pub fn file_id(path: &Path) -> Result<String> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let locations = external_data_locations(&bytes);
    if locations.is_empty() {
        return Ok(blake3::hash(&bytes).to_hex()[..16].to_string());
    }
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut h = blake3::Hasher::new();
    h.update(&bytes);
    for loc in locations {
        let rel = Path::new(&loc);
        if rel.is_absolute()
            || rel
                .components()
                .any(|c| c == std::path::Component::ParentDir)
        {
            return Err(Error::format(
                path,
                "external_data location",
                "a file name beside the model",
                loc,
            ));
        }
        let p = dir.join(rel);
        let f = std::fs::File::open(&p).map_err(|e| {
            Error::format(
                path,
                "external_data location",
                format!("{} (the model's weights) beside the model", p.display()),
                format!("no readable file: {e}"),
            )
        })?;
        h.update(loc.as_bytes());
        h.update_reader(f).map_err(|e| Error::io(&p, e))?;
    }
    Ok(h.finalize().to_hex()[..16].to_string())
}

/// The distinct external-data file names an ONNX model refers to, in order of first use. Each
/// one is a `StringStringEntryProto { key: "location", value }` of a tensor's `external_data`:
/// the bytes `0a 08 "location" 12 <varint length> <value>`.
pub fn external_data_locations(onnx: &[u8]) -> Vec<String> {
    const KEY: &[u8] = b"\x0a\x08location\x12";
    let mut out: Vec<String> = Vec::new();
    let mut i = 0;
    while let Some(at) = onnx[i..].windows(KEY.len()).position(|w| w == KEY) {
        let mut j = i + at + KEY.len();
        i = j;
        let (mut len, mut shift) = (0usize, 0u32);
        while let Some(&b) = onnx.get(j) {
            j += 1;
            len |= ((b & 0x7f) as usize) << shift;
            shift += 7;
            if b & 0x80 == 0 || shift > 28 {
                break;
            }
        }
        let Some(name) = onnx.get(j..j.saturating_add(len)) else {
            continue;
        };
        if let Ok(name) = std::str::from_utf8(name) {
            if !name.is_empty() && !out.iter().any(|n| n == name) {
                out.push(name.to_string());
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An ONNX-like byte string with two tensors stored in `w.data` and one in `v.data`.
    fn with_locations() -> Vec<u8> {
        let entry = |name: &str| {
            let mut e = b"\x0a\x08location\x12".to_vec();
            e.push(name.len() as u8);
            e.extend_from_slice(name.as_bytes());
            e.extend_from_slice(b"\x0a\x06offset\x12\x010");
            e
        };
        let mut b = b"\x08\x08\x12\x0bpytorch".to_vec();
        for n in ["w.data", "w.data", "v.data"] {
            b.extend(entry(n));
        }
        b
    }

    #[test]
    fn the_provider_is_cuda_only_where_the_library_has_it() {
        assert_eq!(choose_provider("", true), Ok(Provider::Cuda));
        assert_eq!(choose_provider("auto", false), Ok(Provider::Cpu));
        assert_eq!(choose_provider("cpu", true), Ok(Provider::Cpu));
        assert_eq!(choose_provider(" cuda ", true), Ok(Provider::Cuda));
        let e = choose_provider("cuda", false).unwrap_err();
        assert!(
            e.contains("no CUDA provider") && e.contains("onnxruntime-gpu"),
            "{e}"
        );
        let e = choose_provider("gpu", true).unwrap_err();
        assert!(
            e.contains("expected auto, cpu or cuda") && e.contains("\"gpu\""),
            "{e}"
        );
        let mut info = BackendInfo {
            kind: "onnxruntime",
            version: Some("1.24.1".into()),
            library: Some(PathBuf::from("/x/libonnxruntime.so.1.24.1")),
            note: None,
            provider: Provider::Cpu,
        };
        assert_eq!(
            info.describe(),
            "onnxruntime 1.24.1 (libonnxruntime.so.1.24.1)"
        );
        info.provider = Provider::Cuda;
        assert_eq!(
            info.describe(),
            "onnxruntime 1.24.1 (libonnxruntime.so.1.24.1, CUDA)"
        );
    }

    #[test]
    fn external_data_locations_are_found_once_each() {
        assert_eq!(
            external_data_locations(&with_locations()),
            vec!["w.data".to_string(), "v.data".to_string()]
        );
        assert!(external_data_locations(b"\x08\x08 no external data").is_empty());
        // A truncated entry at the end is ignored, not a panic.
        let mut cut = with_locations();
        cut.extend_from_slice(b"\x0a\x08location\x12\x7f");
        assert_eq!(external_data_locations(&cut).len(), 2);
    }

    #[test]
    fn file_id_covers_the_external_data_and_names_a_missing_file() {
        let dir = tempfile::tempdir().unwrap();
        let model = dir.path().join("m.onnx");
        std::fs::write(&model, with_locations()).unwrap();
        let e = file_id(&model).unwrap_err().to_string();
        assert!(e.contains("m.onnx") && e.contains("w.data"), "{e}");
        std::fs::write(dir.path().join("w.data"), [1u8; 64]).unwrap();
        std::fs::write(dir.path().join("v.data"), [2u8; 64]).unwrap();
        let a = file_id(&model).unwrap();
        std::fs::write(dir.path().join("v.data"), [3u8; 64]).unwrap();
        let b = file_id(&model).unwrap();
        assert_ne!(a, b, "changed weights must change the model id");
        // Without external data the id is that of the bytes alone (existing cache keys hold).
        let plain = dir.path().join("p.onnx");
        std::fs::write(&plain, b"plain model bytes").unwrap();
        assert_eq!(
            file_id(&plain).unwrap(),
            blake3::hash(b"plain model bytes").to_hex()[..16].to_string()
        );
        let mut bad = b"\x0a\x08location\x12\x09../x.data".to_vec();
        bad.insert(0, 8);
        std::fs::write(&model, bad).unwrap();
        assert!(file_id(&model).is_err());
    }
}
