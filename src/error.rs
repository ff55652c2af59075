//! One error type for the library. Every variant that concerns a file names the file, and
//! parse errors also name the field and what was expected, so a user can fix the input.

use std::path::PathBuf;

pub type Result<T> = std::result::Result<T, Error>;

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A file whose content does not match its format.
    #[error("{path}: {field}: expected {expected}, found {found}")]
    Format {
        path: PathBuf,
        field: String,
        expected: String,
        found: String,
    },
    /// Input that is well formed but cannot be used (an empty cloud, a scan that is not what a
    /// step needs, ...) where none of the narrower kinds below says it better.
    #[error("invalid input: {0}")]
    Invalid(String),
    /// Inputs whose sizes do not agree with each other or with what a step needs (features
    /// and points, the two branches' matrices, weights and correspondences, an index out of
    /// range): a caller's mistake or a damaged cache entry, never a matter of settings.
    #[error("shape mismatch: {0}")]
    Shape(String),
    /// A parameter outside its range (a temperature, a prior, K, L, a camera's size, a flag's
    /// value): the message names the parameter as the user sets it and what it accepts.
    #[error("invalid parameter: {0}")]
    Param(String),
    /// Something a step needs that is not there: a pair id the manifest does not list, a
    /// branch's posterior a fusion mode needs, a scan's frames, inputs a run did not keep.
    #[error("missing input: {0}")]
    Missing(String),
    /// A command line or a choice of settings that cannot run as given (a flag that needs
    /// another one, two that exclude each other): the message says what to add or drop.
    #[error("{0}")]
    Usage(String),
    /// A value that could not be written in its file format (JSON, PNG, an archive).
    #[error("encoding: {0}")]
    Encode(String),
    /// A computation that cannot produce a meaningful result for this input
    /// (fewer than 3 correspondences, collinear points, ...).
    #[error("degenerate input: {0}")]
    Degenerate(String),
    /// Code that panicked where a run goes on without it (one pair of a run, one command of the
    /// inspector's worker): the panic's message. A bug to report, never an answer to input.
    #[error("panicked: {0}")]
    Panicked(String),
    /// An external program or model that failed.
    #[error("{what}: {message}")]
    External { what: String, message: String },
    #[error("cache: {0}")]
    Cache(String),
    /// A model that tract, the pure-Rust fallback, cannot load or run: it needs the native ONNX
    /// Runtime.
    #[error(
        "{model}: tract, the pure-Rust ONNX fallback, cannot run this model ({reason}); it needs \
         the native ONNX Runtime: `pip install onnxruntime` (found automatically) or set \
         ORT_DYLIB_PATH"
    )]
    NeedsNativeRuntime { model: PathBuf, reason: String },
    /// The image branch was asked not to generate, and the generation for this depth video,
    /// prompt and seed is not in the cache (the GUI then offers to run the generator; a study
    /// skips the setting).
    #[error("generation not cached: {backend}, prompt {prompt}, seed {seed}")]
    GenerationNotCached {
        backend: String,
        prompt: String,
        seed: u64,
    },
    /// The run was interrupted (Ctrl-C in the Python package, see [`crate::cancel`]): it stopped
    /// between two steps and wrote nothing more.
    #[error("interrupted")]
    Cancelled,
    /// A step whose memory, estimated before it allocates, exceeds what the process may still
    /// allocate (its address-space limit, or the machine's available memory): an error instead
    /// of an abort of the process (and of a Python interpreter around it).
    #[error(
        "out of memory: {what} needs about {} MiB, only about {} MiB can still be allocated",
        need / (1 << 20),
        available / (1 << 20)
    )]
    OutOfMemory {
        what: String,
        need: u64,
        available: u64,
    },
    /// A cache command that deletes was pointed at a directory without the marker file a
    /// cgenreg cache holds (`cgenreg cache init` marks an existing cache).
    #[error(
        "{}: not a cgenreg cache (no {marker}); nothing was removed. If this is a cache made \
         before the marker existed, run `cgenreg cache --dir {} init` first",
        dir.display(),
        dir.display()
    )]
    NotACache { dir: PathBuf, marker: String },
}

impl Error {
    /// The command line's exit status for this error: 2 when what the user typed cannot run
    /// (a flag that needs another one, a value out of range), as for a command line the parser
    /// refuses; 1 for every other failure. A script or a job array can tell "called wrongly"
    /// from "failed".
    pub fn exit_status(&self) -> i32 {
        match self {
            Error::Usage(_) | Error::Param(_) => 2,
            // as a shell reports a command ended by SIGINT
            Error::Cancelled => 130,
            _ => 1,
        }
    }

    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }

    pub fn format(
        path: impl Into<PathBuf>,
        field: impl Into<String>,
        expected: impl Into<String>,
        found: impl Into<String>,
    ) -> Self {
        Error::Format {
            path: path.into(),
            field: field.into(),
            expected: expected.into(),
            found: found.into(),
        }
    }
}

/// A panic's message (`panic!` with a literal or a formatted string; "(no message)" otherwise).
pub fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(no message)".into())
}

/// Runs `f`, a panic inside it becoming [`Error::Panicked`]: the one last-resort guard around
/// a pair of a run (`bench`, studies, the inspector's Run all: the pair is recorded as failed
/// and the run goes on) and around a command of the inspector's worker.
pub fn catch_panic<T>(f: impl FnOnce() -> Result<T>) -> Result<T> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(f))
        .unwrap_or_else(|payload| Err(Error::Panicked(panic_message(payload.as_ref()))))
}
