//! Output files and run files, in one place: where cgenreg may write, and how it reads its own
//! JSON back.
//!
//! **Writing** ([`prepare`], [`write`]). An output goes only to a new path or to an existing
//! regular file. A symbolic link is refused (writing through it would change another file; a
//! rename over it would silently replace the link), and so are directories, FIFOs, devices
//! and sockets (an atomic rename would turn `/dev/null` into a regular file). An existing
//! regular file is replaced only when it already is this kind of output (a PNG for a
//! screenshot, an NPZ for exported correspondences, a cgenreg run file for `--json`), or when
//! the user passes `--force`. The folder must exist: a typo in a path is an error, not a new
//! folder tree.
//!
//! **Reading** ([`read_json`]). Run files (shard, bench, study, generate, merge outputs) and
//! the other JSON cgenreg reads back are read by one bounded reader: regular files only, at
//! most [`max_run_file_bytes`] (see [`crate::io::limits`]), nesting bounded by serde_json.

use crate::error::{Error, Result};
use serde::de::DeserializeOwned;
use std::path::Path;

/// How an error describes a piece of an input file without quoting it: a path in a manifest
/// may point at any file (`/etc/passwd`), and an error message must not leak its content.
pub fn unquoted(s: &str) -> String {
    let n = s.len();
    let kind = if s.trim().is_empty() {
        "blank text"
    } else if s.contains(char::is_whitespace) {
        "text"
    } else {
        "a word"
    };
    format!("{kind} of {n} byte(s) (file content is not shown)")
}

/// The kinds of output cgenreg writes, recognised by their content.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputKind {
    /// A PNG image (`screenshot --out`).
    Png,
    /// A NumPy `.npz` archive (`register --export-corr`).
    Npz,
    /// A cgenreg run file: a JSON object with a `run` header (`bench`/`study`/`generate`
    /// `--json`, `merge --json`).
    RunJson,
}

impl OutputKind {
    fn describe(self) -> &'static str {
        match self {
            OutputKind::Png => "a PNG image",
            OutputKind::Npz => "a NumPy .npz archive",
            OutputKind::RunJson => "a cgenreg run file (JSON with a \"run\" header)",
        }
    }

    /// Whether the first bytes of an existing file show it is this kind of output.
    fn matches(self, path: &Path) -> bool {
        match self {
            OutputKind::Png => starts_with(path, b"\x89PNG\r\n\x1a\n"),
            // An npz is a zip archive (local file header, or an empty archive's end record).
            OutputKind::Npz => starts_with(path, b"PK\x03\x04") || starts_with(path, b"PK\x05\x06"),
            OutputKind::RunJson => matches!(
                read_json::<serde_json::Value>(path, "run file"),
                Ok(serde_json::Value::Object(m)) if m.get("run").is_some_and(|r| r.is_object())
            ),
        }
    }
}

fn starts_with(path: &Path, magic: &[u8]) -> bool {
    use std::io::Read;
    let Ok(f) = std::fs::File::open(path) else {
        return false;
    };
    let mut buf = Vec::with_capacity(magic.len());
    f.take(magic.len() as u64).read_to_end(&mut buf).is_ok() && buf == magic
}

/// What kind of non-regular file `t` is, for error messages.
fn kind_name(t: &std::fs::FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO (named pipe)";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
        if t.is_socket() {
            return "a socket";
        }
    }
    if t.is_dir() {
        "a directory"
    } else if t.is_symlink() {
        "a symbolic link"
    } else {
        "not a regular file"
    }
}

/// Checks that `path` may receive an output of `kind` (see the module docs); `force` allows
/// replacing an existing regular file of another kind. Call it before the work that produces
/// the output, so a bad path fails at once.
pub fn prepare(path: &Path, kind: OutputKind, force: bool) -> Result<()> {
    if path.as_os_str().is_empty() {
        return Err(Error::Param("an empty output path".into()));
    }
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    match std::fs::metadata(dir) {
        Ok(m) if m.is_dir() => {}
        Ok(_) => {
            return Err(Error::format(
                path,
                "output folder",
                "an existing folder",
                format!("{} is not a folder", dir.display()),
            ))
        }
        Err(_) => {
            return Err(Error::format(
                path,
                "output folder",
                "an existing folder (create it first)",
                format!("{} does not exist", dir.display()),
            ))
        }
    }
    let m = match std::fs::symlink_metadata(path) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(Error::io(path, e)),
    };
    let t = m.file_type();
    if !t.is_file() {
        return Err(Error::format(
            path,
            "output",
            "a new path or a regular file (cgenreg never writes through a link or over a \
             device, FIFO or folder)",
            kind_name(&t),
        ));
    }
    if !force && !kind.matches(path) {
        return Err(Error::format(
            path,
            "output",
            format!(
                "{} to replace, or a new path (pass --force to replace this file)",
                kind.describe()
            ),
            "an existing file of another kind",
        ));
    }
    Ok(())
}

/// [`prepare`], then an atomic write of `bytes`.
pub fn write(path: &Path, kind: OutputKind, force: bool, bytes: &[u8]) -> Result<()> {
    prepare(path, kind, force)?;
    crate::error::write_atomic(path, bytes)
}

/// Default maximum size of a run file or other JSON cgenreg reads back: 1 GiB (a 1,623-pair
/// bench run is a few MiB).
pub const DEFAULT_MAX_RUN_FILE_BYTES: u64 = 1 << 30;
pub const ENV_MAX_RUN_FILE_BYTES: &str = "CGENREG_MAX_RUN_FILE_BYTES";

/// Maximum size of a run file (`CGENREG_MAX_RUN_FILE_BYTES`, capped by the input limit).
pub fn max_run_file_bytes() -> u64 {
    let v = std::env::var(ENV_MAX_RUN_FILE_BYTES)
        .ok()
        .and_then(|s| s.trim().parse::<u64>().ok())
        .filter(|&n| n > 0)
        .unwrap_or(DEFAULT_MAX_RUN_FILE_BYTES);
    v.min(crate::io::limits::max_input_bytes())
}

/// Reads a JSON file cgenreg wrote (run files, plans, comparisons): a regular file only
/// (a FIFO or `/dev/zero` is refused before any read), at most [`max_run_file_bytes`], UTF-8
/// with or without a byte-order mark refused with a clear message. `what` names the file's
/// role in errors ("run file", "plan").
pub fn read_json<T: DeserializeOwned>(path: &Path, what: &str) -> Result<T> {
    use std::io::Read;
    let len = crate::io::limits::check_regular(path)?;
    let max = max_run_file_bytes();
    if len > max {
        return Err(Error::format(
            path,
            "file size",
            format!(
                "a {what} of at most {max} bytes (raise {ENV_MAX_RUN_FILE_BYTES} if it is real)"
            ),
            format!("{len} bytes"),
        ));
    }
    let f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut buf = Vec::with_capacity(len as usize);
    f.take(max + 1)
        .read_to_end(&mut buf)
        .map_err(|e| Error::io(path, e))?;
    if buf.len() as u64 > max {
        return Err(Error::format(
            path,
            "file size",
            format!("a {what} of at most {max} bytes"),
            "a file that grew past the limit while read",
        ));
    }
    if buf.is_empty() {
        return Err(Error::format(path, what, "JSON", "an empty file"));
    }
    if buf.starts_with(b"\xEF\xBB\xBF") {
        return Err(Error::format(
            path,
            what,
            "JSON without a byte-order mark",
            "a UTF-8 byte-order mark (the file was edited by another tool)",
        ));
    }
    serde_json::from_slice(&buf).map_err(|e| {
        let why = match e.classify() {
            serde_json::error::Category::Eof => format!("a truncated file ({e})"),
            _ => e.to_string(),
        };
        Error::format(path, what, "JSON written by cgenreg", why)
    })
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    fn mkfifo(p: &Path) {
        let c = std::ffi::CString::new(p.to_str().unwrap()).unwrap();
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    }

    #[test]
    fn outputs_refuse_links_fifos_folders_and_foreign_files() {
        let d = tempfile::tempdir().unwrap();
        let fifo = d.path().join("null");
        mkfifo(&fifo);
        let e = write(&fifo, OutputKind::RunJson, true, b"{}")
            .unwrap_err()
            .to_string();
        assert!(e.contains("FIFO") && e.contains("null"), "{e}");
        let victim = d.path().join("victim.txt");
        std::fs::write(&victim, "keep me").unwrap();
        let link = d.path().join("out.png");
        std::os::unix::fs::symlink(&victim, &link).unwrap();
        let e = write(&link, OutputKind::Png, true, b"x")
            .unwrap_err()
            .to_string();
        assert!(e.contains("symbolic link"), "{e}");
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        // A foreign regular file: refused without --force, replaced with it.
        let e = write(&victim, OutputKind::Png, false, b"png")
            .unwrap_err()
            .to_string();
        assert!(e.contains("--force") && e.contains("another kind"), "{e}");
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
        write(&victim, OutputKind::Png, true, b"\x89PNG\r\n\x1a\nrest").unwrap();
        // Now it is a PNG: replaced without --force.
        write(&victim, OutputKind::Png, false, b"\x89PNG\r\n\x1a\nnew").unwrap();
        let e = write(d.path(), OutputKind::Npz, true, b"")
            .unwrap_err()
            .to_string();
        assert!(e.contains("directory"), "{e}");
        let e = prepare(&d.path().join("no/such/x.png"), OutputKind::Png, false)
            .unwrap_err()
            .to_string();
        assert!(e.contains("does not exist"), "{e}");
        // A run file is recognised by its header.
        let run = d.path().join("run.json");
        std::fs::write(&run, br#"{"run": {"x": 1}, "records": []}"#).unwrap();
        prepare(&run, OutputKind::RunJson, false).unwrap();
        std::fs::write(&run, br#"{"other": 1}"#).unwrap();
        assert!(prepare(&run, OutputKind::RunJson, false).is_err());
    }

    #[test]
    fn json_reader_is_bounded_and_regular_only() {
        let d = tempfile::tempdir().unwrap();
        let z = d.path().join("zero.json");
        std::os::unix::fs::symlink("/dev/zero", &z).unwrap();
        let t = std::time::Instant::now();
        let e = read_json::<serde_json::Value>(&z, "run file")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("character device") && e.contains("zero.json"),
            "{e}"
        );
        assert!(t.elapsed().as_secs() < 2);
        let big = d.path().join("big.json");
        std::fs::write(&big, vec![b' '; 4096]).unwrap();
        let e = crate::io::limits::with_limit(crate::io::limits::ENV_MAX_INPUT_BYTES, 1000, || {
            read_json::<serde_json::Value>(&big, "run file")
                .unwrap_err()
                .to_string()
        });
        assert!(e.contains("4096 bytes"), "{e}");
        let bom = d.path().join("bom.json");
        std::fs::write(&bom, b"\xEF\xBB\xBF{}").unwrap();
        let e = read_json::<serde_json::Value>(&bom, "run file")
            .unwrap_err()
            .to_string();
        assert!(e.contains("byte-order mark"), "{e}");
        let trunc = d.path().join("t.json");
        std::fs::write(&trunc, b"{\"run\": {").unwrap();
        let e = read_json::<serde_json::Value>(&trunc, "run file")
            .unwrap_err()
            .to_string();
        assert!(e.contains("truncated"), "{e}");
        let deep = d.path().join("deep.json");
        std::fs::write(&deep, "[".repeat(100_000)).unwrap();
        let e = read_json::<serde_json::Value>(&deep, "run file")
            .unwrap_err()
            .to_string();
        assert!(e.contains("deep.json") && e.contains("recursion"), "{e}");
    }
}
