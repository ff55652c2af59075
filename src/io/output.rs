//! Output files and run files, in one place: where cgenreg may write, and how it reads its own
//! JSON back.
//!
//! **Writing** ([`prepare`], [`write`]). An output goes only to a new path or to an existing
//! regular file. A symbolic link is refused (writing through it would change another file; a
//! rename over it would silently replace the link), and so are directories, FIFOs, devices
//! and sockets (an atomic rename would turn `/dev/null` into a regular file). An existing
//! regular file is replaced only when cgenreg wrote it, as this kind of output: judged by
//! cgenreg's own marker in it (a `Software: cgenreg` text chunk in a PNG, the archive comment
//! `cgenreg` of an `.npz`, a run file's or a result's own header, a PLY's `comment cgenreg`),
//! never by the container format alone (any PNG, any ZIP); other files only with `--force`.
//! Formats with no room for a marker (`.npy`, `.xyz`) never replace a file without `--force`.
//! The folder must exist: a typo in a path is an error, not a new folder tree. Every write
//! goes to a temporary file in the same folder, is checked again right before the rename
//! (a link or FIFO planted meanwhile is refused, never followed) and renamed over the path:
//! a kill mid-write leaves the previous file whole, never a truncated one.
//!
//! **Run files held by a running process** ([`lock`]). A run file that a command rewrites as
//! it goes (`--json` of bench, study, generate) is locked for the command's lifetime; a
//! second process given the same path is refused, naming the conflict.
//!
//! **Reading** ([`read_json`]). Run files (shard, bench, study, generate, merge outputs) and
//! the other JSON cgenreg reads back are read by one bounded reader: regular files only, at
//! most [`max_run_file_bytes`] (see [`crate::io::limits`]), nesting bounded by serde_json.

use crate::error::{Error, Result};
use serde::de::DeserializeOwned;
use std::io::Write as _;
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

/// The kinds of output cgenreg writes, recognised by cgenreg's own marker in them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutputKind {
    /// A PNG image cgenreg rendered (`screenshot --out`): a `tEXt` chunk `Software` =
    /// `cgenreg` ([`png_with_marker`]).
    Png,
    /// A NumPy `.npz` archive cgenreg wrote (`register --export-corr`): the archive comment
    /// [`NPZ_MARKER`].
    Npz,
    /// A cgenreg run file: a JSON object whose `run` header has cgenreg's `identity`, `shard`
    /// and `host` (`bench`/`study`/`generate` `--json`, `merge --json`).
    RunJson,
    /// A registration result as `register --json` prints it (`screenshot --result-json`): a
    /// JSON object with `pair_id`, `target_from_source`, `timings` and `total_ms`.
    ResultJson,
    /// A point cloud (the Python package's `write_cloud`): a PLY with cgenreg's
    /// `comment cgenreg` header line; `.npy` and text clouds carry no marker, so an existing
    /// one is never replaced without `force`.
    Cloud,
}

/// The archive comment of the `.npz` files cgenreg writes.
pub const NPZ_MARKER: &str = "cgenreg";
/// The `tEXt` keyword and value of the PNGs cgenreg renders.
pub const PNG_MARKER: (&str, &str) = ("Software", "cgenreg");

impl OutputKind {
    fn describe(self) -> &'static str {
        match self {
            OutputKind::Png => "a PNG image cgenreg rendered",
            OutputKind::Npz => "an .npz archive cgenreg exported",
            OutputKind::RunJson => "a cgenreg run file (JSON with cgenreg's \"run\" header)",
            OutputKind::ResultJson => "a registration result cgenreg wrote (JSON)",
            OutputKind::Cloud => "a PLY cloud cgenreg wrote",
        }
    }

    /// Whether an existing file carries cgenreg's marker for this kind of output.
    fn matches(self, path: &Path) -> bool {
        let json_object = |keys: &[&str], inner: Option<(&str, &[&str])>| {
            let Ok(serde_json::Value::Object(m)) = read_json::<serde_json::Value>(path, "output")
            else {
                return false;
            };
            keys.iter().all(|k| m.contains_key(*k))
                && inner.is_none_or(|(field, sub)| {
                    m.get(field)
                        .and_then(|v| v.as_object())
                        .is_some_and(|o| sub.iter().all(|k| o.contains_key(*k)))
                })
        };
        match self {
            OutputKind::Png => head(path, 1 << 16).is_some_and(|b| png_has_marker(&b)),
            OutputKind::Npz => npz_has_marker(path),
            OutputKind::RunJson => {
                json_object(&["run"], Some(("run", &["identity", "shard", "host"])))
            }
            OutputKind::ResultJson => json_object(
                &["pair_id", "target_from_source", "timings", "total_ms"],
                None,
            ),
            OutputKind::Cloud => {
                path.extension()
                    .is_some_and(|e| e.eq_ignore_ascii_case("ply"))
                    && head(path, 4096).is_some_and(|b| ply_has_marker(&b))
            }
        }
    }
}

/// The first `n` bytes of `path` (fewer for a shorter file).
fn head(path: &Path, n: u64) -> Option<Vec<u8>> {
    use std::io::Read;
    let f = std::fs::File::open(path).ok()?;
    let mut buf = Vec::new();
    f.take(n).read_to_end(&mut buf).ok()?;
    Some(buf)
}

/// Whether a PNG's chunks before its image data hold cgenreg's `tEXt` marker.
fn png_has_marker(b: &[u8]) -> bool {
    const SIG: &[u8] = b"\x89PNG\r\n\x1a\n";
    if !b.starts_with(SIG) {
        return false;
    }
    let want = [PNG_MARKER.0.as_bytes(), b"\0", PNG_MARKER.1.as_bytes()].concat();
    let mut at = SIG.len();
    while at + 8 <= b.len() {
        let len = u32::from_be_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]) as usize;
        let kind = &b[at + 4..at + 8];
        let Some(data) = b.get(at + 8..at + 8 + len) else {
            return false;
        };
        if kind == b"tEXt" && data == want.as_slice() {
            return true;
        }
        if kind == b"IDAT" || kind == b"IEND" {
            return false;
        }
        at += 12 + len;
    }
    false
}

/// Whether a zip archive's end record carries cgenreg's comment.
fn npz_has_marker(path: &Path) -> bool {
    use std::io::{Read, Seek, SeekFrom};
    let Ok(mut f) = std::fs::File::open(path) else {
        return false;
    };
    let want = NPZ_MARKER.as_bytes();
    // the end record (22 bytes) followed by the comment ends the file
    let tail = 22 + want.len() as u64;
    let mut buf = Vec::new();
    if f.seek(SeekFrom::End(-(tail as i64))).is_err()
        || f.take(tail).read_to_end(&mut buf).is_err()
        || buf.len() as u64 != tail
    {
        return false;
    }
    buf.starts_with(b"PK\x05\x06")
        && u16::from_le_bytes([buf[20], buf[21]]) as usize == want.len()
        && &buf[22..] == want
}

/// Whether a PLY header (before `end_header`) has cgenreg's `comment cgenreg` line.
fn ply_has_marker(b: &[u8]) -> bool {
    let text = String::from_utf8_lossy(b);
    for line in text.lines() {
        let line = line.trim_end_matches('\r');
        if line == "comment cgenreg" {
            return true;
        }
        if line == "end_header" {
            return false;
        }
    }
    false
}

/// `png` (a PNG stream) with cgenreg's `tEXt` marker chunk inserted after its header chunk,
/// so that a later run may replace it without `--force`.
pub fn png_with_marker(png: &[u8]) -> Result<Vec<u8>> {
    // signature (8) + IHDR chunk (4 length + 4 type + 13 data + 4 CRC)
    const AFTER_IHDR: usize = 8 + 25;
    if png.len() < AFTER_IHDR || &png[12..16] != b"IHDR" {
        return Err(Error::Encode("a PNG without its header chunk".into()));
    }
    let data = [PNG_MARKER.0.as_bytes(), b"\0", PNG_MARKER.1.as_bytes()].concat();
    let mut chunk = Vec::with_capacity(12 + data.len());
    chunk.extend_from_slice(&(data.len() as u32).to_be_bytes());
    chunk.extend_from_slice(b"tEXt");
    chunk.extend_from_slice(&data);
    chunk.extend_from_slice(&crc32(&chunk[4..]).to_be_bytes());
    Ok([&png[..AFTER_IHDR], &chunk, &png[AFTER_IHDR..]].concat())
}

/// CRC-32 (ISO-HDLC, as PNG chunks use).
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 {
                (c >> 1) ^ 0xEDB8_8320
            } else {
                c >> 1
            };
        }
    }
    !c
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
/// replacing an existing regular file cgenreg did not write. Call it before the work that
/// produces the output, so a bad path fails at once; [`write`] checks again.
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
            "an existing file cgenreg did not write (no cgenreg marker in it)",
        ));
    }
    Ok(())
}

/// [`prepare`], then an atomic write of `bytes`: a temporary file in the same folder, the
/// checks again right before the rename (what was planted at `path` meanwhile is refused, and
/// the temporary file removed), then the rename. A kill during the write leaves the previous
/// file whole.
pub fn write(path: &Path, kind: OutputKind, force: bool, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    prepare(path, kind, force)?;
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.{}.tmp", unique_suffix()));
    let written = (|| -> Result<()> {
        let mut f = std::fs::File::options()
            .write(true)
            .create_new(true)
            .open(&tmp)
            .map_err(|e| Error::io(&tmp, e))?;
        f.write_all(bytes)
            .and_then(|()| f.sync_all())
            .map_err(|e| Error::io(path, e))?;
        // the path may have changed while the output was computed and written
        prepare(path, kind, force)?;
        std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

/// A lock on an output a command rewrites as it runs (a run file): held until dropped, it
/// keeps a second process from writing the same file (two shards given the same `--json`).
/// The lock is `flock` on a hidden `.<name>.lock` beside the output, removed when released.
#[derive(Debug)]
pub struct OutputLock {
    file: std::fs::File,
    path: std::path::PathBuf,
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // removed while still held: a process waiting to lock it finds it gone and retries
        let _ = std::fs::remove_file(&self.path);
        let _ = &self.file;
    }
}

/// Locks `output` for this process (see [`OutputLock`]); a lock another running process
/// holds is an error naming it.
pub fn lock(output: &Path) -> Result<OutputLock> {
    let dir = output
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = output
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let path = dir.join(format!(".{name}.lock"));
    for _ in 0..8 {
        let file = std::fs::File::options()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|e| Error::io(&path, e))?;
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            use std::os::unix::io::AsRawFd;
            // SAFETY: flock on a descriptor this function owns.
            if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
                let holder = std::fs::read_to_string(&path).unwrap_or_default();
                let holder = holder.trim();
                return Err(Error::Usage(format!(
                    "{}: another running cgenreg process ({}) is writing this file: give each \
                     run its own output",
                    output.display(),
                    if holder.is_empty() { "unknown" } else { holder }
                )));
            }
            // the holder before us may have removed the file between our open and our lock
            let same = std::fs::metadata(&path)
                .ok()
                .zip(file.metadata().ok())
                .is_some_and(|(a, b)| a.ino() == b.ino() && a.dev() == b.dev());
            if !same {
                continue;
            }
        }
        let _ = file.set_len(0);
        let _ = (&file).write_all(format!("process {}", std::process::id()).as_bytes());
        return Ok(OutputLock { file, path });
    }
    Err(Error::Usage(format!(
        "{}: could not lock this output (its lock file keeps changing)",
        output.display()
    )))
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

/// Write `bytes` to `path` atomically: a temporary file in the same directory, then rename.
/// A reader never sees a half-written file, and a crash leaves the old content in place.
pub fn write_atomic(path: &std::path::Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.{}.tmp", unique_suffix()));
    {
        // create_new: a name another writer happens to use is an error, never shared.
        let mut f = std::fs::File::options()
            .write(true)
            .create_new(true)
            .open(&tmp)
            .map_err(|e| Error::io(&tmp, e))?;
        // A full disk fails here: the partial temporary file must not stay behind.
        if let Err(e) = f.write_all(bytes).and_then(|()| f.sync_all()) {
            drop(f);
            let _ = std::fs::remove_file(&tmp);
            return Err(Error::io(path, e));
        }
    }
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        Error::io(path, e)
    })?;
    Ok(())
}

/// A name part no other writer uses at the same time, on this host or another one sharing
/// the file system: host name, process id, a per-process counter and the clock's nanoseconds
/// (process ids repeat across hosts and containers).
pub fn unique_suffix() -> String {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    static HOST: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    let host = HOST.get_or_init(|| {
        let h = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
        let h: String = h
            .trim()
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || *c == '-')
            .take(32)
            .collect();
        if h.is_empty() {
            "host".into()
        } else {
            h
        }
    });
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    format!(
        "{host}-{}-{}-{nanos:09}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
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
        assert!(e.contains("--force") && e.contains("did not write"), "{e}");
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
        // Any PNG is not enough: only one carrying cgenreg's marker is replaced without --force.
        let mut plain = std::io::Cursor::new(Vec::new());
        image::RgbImage::new(2, 2)
            .write_to(&mut plain, image::ImageFormat::Png)
            .unwrap();
        let plain = plain.into_inner();
        write(&victim, OutputKind::Png, true, &plain).unwrap();
        assert!(write(&victim, OutputKind::Png, false, &plain).is_err());
        let marked = png_with_marker(&plain).unwrap();
        assert!(
            image::load_from_memory(&marked).is_ok(),
            "still a valid PNG"
        );
        write(&victim, OutputKind::Png, true, &marked).unwrap();
        write(&victim, OutputKind::Png, false, &marked).unwrap();
        // the same for archives: the archive comment, not the ZIP signature
        let npz = d.path().join("c.npz");
        let ours = crate::io::npy::encode_npz(&[("a.npy".into(), vec![1, 2, 3])]).unwrap();
        write(&npz, OutputKind::Npz, false, &ours).unwrap();
        write(&npz, OutputKind::Npz, false, &ours).unwrap();
        let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
        zip.start_file(
            "word/document.xml",
            zip::write::SimpleFileOptions::default(),
        )
        .unwrap();
        let docx = zip.finish().unwrap().into_inner();
        write(&npz, OutputKind::Npz, true, &docx).unwrap();
        assert!(write(&npz, OutputKind::Npz, false, &ours).is_err());
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
        std::fs::write(
            &run,
            br#"{"run": {"identity": {}, "shard": "0/1", "host": "h"}, "records": []}"#,
        )
        .unwrap();
        prepare(&run, OutputKind::RunJson, false).unwrap();
        // a JSON object with a "run" key of its own is not a cgenreg run file
        std::fs::write(&run, br#"{"run": {"x": 1}, "records": []}"#).unwrap();
        assert!(prepare(&run, OutputKind::RunJson, false).is_err());
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
