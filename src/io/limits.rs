//! Resource limits on untrusted input, in one place (documented in `docs/reliability.md`).
//!
//! Every reader goes through these checks, so a small or hostile file cannot make cgenreg
//! hang, overflow its stack or allocate without bound:
//!
//! | limit                              | default | override (environment)        |
//! |------------------------------------|---------|-------------------------------|
//! | nesting depth of a pickle          | 1,000   | `CGENREG_MAX_NESTING`         |
//! | nesting depth of JSON (serde_json) | 128     | fixed by serde_json           |
//! | decoded bytes of one buffer (NPZ entry, LZF block, image, mp4) | 512 MiB | `CGENREG_MAX_DECODED_BYTES` |
//! | size of an input file read whole   | 8 GiB   | `CGENREG_MAX_INPUT_BYTES`     |
//! | frames per fragment (`--frames`)   | 1,000   | `CGENREG_MAX_FRAMES`          |
//! | declared element counts            | at most what the file's bytes can hold | none (a lie) |
//! | non-regular input files (FIFO, device, directory) | refused | none |
//! | log bytes read for an error message | last 64 KiB | none |
//!
//! An override is a positive integer; a malformed value is ignored with the default kept
//! (a warning is printed once on stderr). Library callers can also set a limit for one call
//! with [`with_limit`].

use crate::error::{Error, Result};
use std::path::Path;

/// Default maximum nesting depth of a pickle (NumPy pickles nest about 5 levels).
pub const DEFAULT_MAX_NESTING: usize = 1_000;
/// Default maximum decoded size of one buffer: 512 MiB (about 44 million float32 x,y,z points).
pub const DEFAULT_MAX_DECODED_BYTES: u64 = 512 << 20;
/// Default maximum size of a file read into memory whole: 8 GiB.
pub const DEFAULT_MAX_INPUT_BYTES: u64 = 8 << 30;
/// Default maximum frames per fragment of a depth video (the paper's videos have 121 frames).
pub const DEFAULT_MAX_FRAMES: usize = 1_000;
/// Bytes read from the end of a log to show its last lines in an error message.
pub const LOG_TAIL_BYTES: u64 = 64 << 10;

pub const ENV_MAX_NESTING: &str = "CGENREG_MAX_NESTING";
pub const ENV_MAX_DECODED_BYTES: &str = "CGENREG_MAX_DECODED_BYTES";
pub const ENV_MAX_INPUT_BYTES: &str = "CGENREG_MAX_INPUT_BYTES";
pub const ENV_MAX_FRAMES: &str = "CGENREG_MAX_FRAMES";
pub const ENV_MAX_MANIFEST_BYTES: &str = "CGENREG_MAX_MANIFEST_BYTES";
/// Default maximum size of a dataset manifest: 16 MiB (a manifest of 1,600 pairs with their
/// GT matrices is about 0.5 MB). Checked before the TOML is parsed.
pub const DEFAULT_MAX_MANIFEST_BYTES: u64 = 16 << 20;

thread_local! {
    static OVERRIDES: std::cell::RefCell<Vec<(&'static str, u64)>> =
        const { std::cell::RefCell::new(Vec::new()) };
}

/// Run `f` with limit `name` (one of the `ENV_*` names) set to `value` on this thread,
/// whatever the environment says: for callers that know their input (and for tests, which
/// cannot set environment variables without racing each other).
pub fn with_limit<T>(name: &'static str, value: u64, f: impl FnOnce() -> T) -> T {
    struct Reset;
    impl Drop for Reset {
        fn drop(&mut self) {
            OVERRIDES.with(|o| {
                o.borrow_mut().pop();
            });
        }
    }
    OVERRIDES.with(|o| o.borrow_mut().push((name, value)));
    let _reset = Reset;
    f()
}

fn env_or(name: &str, default: u64) -> u64 {
    if let Some(v) = OVERRIDES.with(|o| {
        o.borrow()
            .iter()
            .rev()
            .find(|(n, _)| *n == name)
            .map(|(_, v)| *v)
    }) {
        return v;
    }
    match std::env::var(name) {
        Ok(v) => match v.trim().parse::<u64>() {
            Ok(n) if n > 0 => n,
            _ => {
                static WARNED: std::sync::Once = std::sync::Once::new();
                WARNED.call_once(|| {
                    eprintln!("warning: {name}={v:?} is not a positive integer; using {default}")
                });
                default
            }
        },
        Err(_) => default,
    }
}

/// Maximum nesting depth of a pickle.
pub fn max_nesting() -> usize {
    env_or(ENV_MAX_NESTING, DEFAULT_MAX_NESTING as u64) as usize
}

/// Maximum decoded size of one buffer (NPZ entry, LZF block, image, video frames).
pub fn max_decoded_bytes() -> u64 {
    env_or(ENV_MAX_DECODED_BYTES, DEFAULT_MAX_DECODED_BYTES)
}

/// Maximum size of an input file read whole.
pub fn max_input_bytes() -> u64 {
    env_or(ENV_MAX_INPUT_BYTES, DEFAULT_MAX_INPUT_BYTES)
}

/// Maximum size of a dataset manifest (capped by the input limit).
pub fn max_manifest_bytes() -> u64 {
    env_or(ENV_MAX_MANIFEST_BYTES, DEFAULT_MAX_MANIFEST_BYTES).min(max_input_bytes())
}

/// Maximum frames per fragment.
pub fn max_frames() -> usize {
    env_or(ENV_MAX_FRAMES, DEFAULT_MAX_FRAMES as u64) as usize
}

/// Fail unless `bytes` decoded bytes (of `what` in `path`) fit the decoded-size limit.
pub fn check_decoded(path: &Path, what: &str, bytes: u64) -> Result<()> {
    let max = max_decoded_bytes();
    if bytes > max {
        return Err(Error::format(
            path,
            what,
            format!(
                "at most {max} decoded bytes (raise {ENV_MAX_DECODED_BYTES} if the data is real)"
            ),
            format!("{bytes} bytes"),
        ));
    }
    Ok(())
}

/// Fail unless `count` declared items of at least `min_bytes` each fit in `available` bytes:
/// a header that declares more elements than its file can hold is a lie (or a truncation),
/// and trusting it would hang or allocate without bound.
pub fn check_count(
    path: &Path,
    field: &str,
    count: u64,
    min_bytes: u64,
    available: u64,
) -> Result<()> {
    match count.checked_mul(min_bytes) {
        Some(need) if need <= available => Ok(()),
        _ => Err(Error::format(
            path,
            field,
            format!(
                "a count whose items ({min_bytes} byte(s) each at least) fit in the {available} \
                 bytes of data"
            ),
            format!("{count} (file truncated or header wrong)"),
        )),
    }
}

/// Bytes this process can still allocate, as far as the system says: the address-space limit
/// (`ulimit -v`) less the address space in use, and the machine's available memory plus free
/// swap; None where neither is known.
pub fn memory_headroom() -> Option<u64> {
    let mut bounds: Vec<u64> = Vec::new();
    #[cfg(target_os = "linux")]
    {
        let mut lim = libc::rlimit {
            rlim_cur: 0,
            rlim_max: 0,
        };
        // SAFETY: getrlimit writes the struct it is given.
        if unsafe { libc::getrlimit(libc::RLIMIT_AS, &mut lim) } == 0
            && lim.rlim_cur != libc::RLIM_INFINITY
        {
            // SAFETY: sysconf has no preconditions.
            let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) }.max(4096) as u64;
            let used = std::fs::read_to_string("/proc/self/statm")
                .ok()
                .and_then(|s| s.split_whitespace().next()?.parse::<u64>().ok())
                .map_or(0, |pages| pages * page);
            // rlim_t is u64 here and u32 on 32-bit targets
            #[allow(clippy::unnecessary_cast)]
            let cur = lim.rlim_cur as u64;
            bounds.push(cur.saturating_sub(used));
        }
        if let Ok(info) = std::fs::read_to_string("/proc/meminfo") {
            let kib = |key: &str| {
                info.lines()
                    .find(|l| l.starts_with(key))
                    .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
            };
            if let Some(avail) = kib("MemAvailable:") {
                bounds.push((avail + kib("SwapFree:").unwrap_or(0)) * 1024);
            }
        }
    }
    bounds.into_iter().min()
}

/// Fail with [`Error::OutOfMemory`] when `need` bytes (what `what` will allocate, estimated
/// before it does) exceed [`memory_headroom`]: an allocation that fails aborts the process (a
/// Rust program cannot catch it), which would take a Python interpreter with it.
pub fn check_memory(what: &str, need: u64) -> Result<()> {
    match memory_headroom() {
        Some(available) if need > available => Err(Error::OutOfMemory {
            what: what.to_string(),
            need,
            available,
        }),
        _ => Ok(()),
    }
}

/// Memory a registration may use per input point, at most: its copy of the point (12 bytes),
/// the voxel grid's accumulators, keys and order, and the reader's or caller's own buffers,
/// rounded up. Checked with [`check_memory`] before an array of points enters the library.
pub const BYTES_PER_INPUT_POINT: u64 = 96;

/// A vector of `n` copies of `T` reserved without aborting: [`check_memory`], then a fallible
/// reservation, either failing as [`Error::OutOfMemory`].
pub fn try_vec<T>(what: &str, n: usize) -> Result<Vec<T>> {
    let need = (n as u64).saturating_mul(std::mem::size_of::<T>() as u64);
    check_memory(what, need)?;
    let mut v = Vec::new();
    v.try_reserve_exact(n).map_err(|_| Error::OutOfMemory {
        what: what.to_string(),
        need,
        available: memory_headroom().unwrap_or(0),
    })?;
    Ok(v)
}

/// What kind of non-regular file `m` is, for error messages.
fn kind_name(m: &std::fs::Metadata) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        let t = m.file_type();
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
    if m.is_dir() {
        "a directory"
    } else {
        "not a regular file"
    }
}

/// The one check of what an input is: a regular file no larger than the input limit (`m`,
/// the metadata of `path` or of what was opened from it).
fn check_kind_and_size(path: &Path, m: &std::fs::Metadata) -> Result<()> {
    if !m.is_file() {
        return Err(Error::format(
            path,
            "file type",
            "a regular file",
            kind_name(m),
        ));
    }
    let max = max_input_bytes();
    if m.len() > max {
        return Err(Error::format(
            path,
            "file size",
            format!("at most {max} bytes (raise {ENV_MAX_INPUT_BYTES} if the file is real)"),
            format!("{} bytes", m.len()),
        ));
    }
    Ok(())
}

/// Fail unless `path` is a regular file (after following links) no larger than the input
/// limit. FIFOs would block forever and devices like `/dev/zero` never end.
pub fn check_regular(path: &Path) -> Result<u64> {
    let m = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    check_kind_and_size(path, &m)?;
    Ok(m.len())
}

/// Paths a manifest confined to its root (a file, or a folder whose files are confined too),
/// with the root they must stay in: [`open_input`] checks what it opened against it.
static CONFINED: std::sync::Mutex<
    Option<std::collections::HashMap<std::path::PathBuf, std::path::PathBuf>>,
> = std::sync::Mutex::new(None);

/// Notes that `path` (a file, or a folder and everything under it), as a manifest resolved it,
/// must stay inside `real_root` (resolved) when opened: a file swapped for a link after the
/// manifest's check is then refused by [`open_input`], which checks the file it opened.
pub fn confine(path: &Path, real_root: &Path) {
    if let Ok(mut m) = CONFINED.lock() {
        m.get_or_insert_with(Default::default)
            .insert(path.to_path_buf(), real_root.to_path_buf());
    }
}

/// The root `path` or a folder above it was confined to, if any.
fn confinement(path: &Path) -> Option<std::path::PathBuf> {
    let m = CONFINED.lock().ok()?;
    let m = m.as_ref()?;
    path.ancestors().find_map(|a| m.get(a).cloned())
}

/// Opens an input file once and checks what was opened: a regular file (a FIFO is opened
/// without blocking and refused, a device refused before any read), no larger than the input
/// limit, and, when a manifest confined the path ([`confine`]), a file inside its root (the
/// opened file's real path, so a link swapped in after the manifest's check is refused).
/// Every reader of an input goes through this (or [`read_file`]).
pub fn open_input(path: &Path) -> Result<(std::fs::File, u64)> {
    // a device or FIFO is refused by its metadata before it is opened (opening some devices
    // has effects)
    check_regular(path)?;
    let mut o = std::fs::File::options();
    o.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        // a FIFO swapped in after the check must not block the open
        o.custom_flags(libc::O_NONBLOCK | libc::O_NOCTTY);
    }
    let f = o.open(path).map_err(|e| Error::io(path, e))?;
    let m = f.metadata().map_err(|e| Error::io(path, e))?;
    check_kind_and_size(path, &m)?;
    #[cfg(target_os = "linux")]
    if let Some(root) = confinement(path) {
        use std::os::unix::io::AsRawFd;
        let opened = std::fs::read_link(format!("/proc/self/fd/{}", f.as_raw_fd()))
            .map_err(|e| Error::io(path, e))?;
        if !opened.starts_with(&root) {
            return Err(Error::format(
                path,
                "path",
                format!(
                    "a file inside the manifest's root {} (the file opened is checked, links \
                     resolved)",
                    root.display()
                ),
                format!("{} (outside the root)", opened.display()),
            ));
        }
    }
    Ok((f, m.len()))
}

/// Read a whole regular file (see [`open_input`]); the read stops at the size limit even
/// if the file grows meanwhile.
pub fn read_file(path: &Path) -> Result<Vec<u8>> {
    use std::io::Read;
    let (f, len) = open_input(path)?;
    let max = max_input_bytes();
    let mut buf = Vec::with_capacity(len as usize);
    f.take(max + 1)
        .read_to_end(&mut buf)
        .map_err(|e| Error::io(path, e))?;
    if buf.len() as u64 > max {
        return Err(Error::format(
            path,
            "file size",
            format!("at most {max} bytes"),
            "a file that grew past the limit while read",
        ));
    }
    Ok(buf)
}

/// [`read_file`] as UTF-8 text.
pub fn read_text(path: &Path) -> Result<String> {
    let b = read_file(path)?;
    String::from_utf8(b).map_err(|e| {
        Error::format(
            path,
            "text",
            "UTF-8 text",
            format!("invalid byte at offset {}", e.utf8_error().valid_up_to()),
        )
    })
}

/// The last `n` lines of a log, reading at most its last [`LOG_TAIL_BYTES`] bytes (a
/// generator can write gigabytes of log). Missing or unreadable logs give "".
pub fn tail_lines(path: &Path, n: usize) -> String {
    use std::io::{Read, Seek, SeekFrom};
    let Ok(mut f) = std::fs::File::open(path) else {
        return String::new();
    };
    let len = f.metadata().map(|m| m.len()).unwrap_or(0);
    let start = len.saturating_sub(LOG_TAIL_BYTES);
    if f.seek(SeekFrom::Start(start)).is_err() {
        return String::new();
    }
    let mut buf = Vec::new();
    let _ = f.take(LOG_TAIL_BYTES).read_to_end(&mut buf);
    let text = String::from_utf8_lossy(&buf);
    let mut lines: Vec<&str> = text.lines().collect();
    // A partial first line (the cut) is dropped unless it is all there is.
    if start > 0 && lines.len() > 1 {
        lines.remove(0);
    }
    let tail = lines[lines.len().saturating_sub(n)..].join("\n");
    if start > 0 {
        format!("[... {start} earlier bytes not shown]\n{tail}")
    } else {
        tail
    }
}

/// A fresh, uniquely named folder under the system temp dir, removed (with its content)
/// when dropped. For scratch files of runs that must leave nothing behind (`--no-cache`).
#[derive(Debug)]
pub struct ScratchDir(std::path::PathBuf);

impl ScratchDir {
    pub fn new(prefix: &str) -> Result<ScratchDir> {
        use std::sync::atomic::{AtomicU64, Ordering};
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let base = std::env::temp_dir();
        for _ in 0..100 {
            let nanos = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.subsec_nanos())
                .unwrap_or(0);
            let p = base.join(format!(
                "{prefix}-{}-{}-{nanos:08x}",
                std::process::id(),
                NEXT.fetch_add(1, Ordering::Relaxed)
            ));
            match std::fs::create_dir(&p) {
                Ok(()) => return Ok(ScratchDir(p)),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(e) => return Err(Error::io(&p, e)),
            }
        }
        Err(Error::Invalid(format!(
            "could not create a unique scratch folder under {}",
            base.display()
        )))
    }

    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What was opened is checked, not only what the path named before: a confined path
    /// swapped for a link out of its root after the check is refused, as is a FIFO (without
    /// blocking); a file inside the root, or reached by a link inside it, is read.
    #[cfg(target_os = "linux")]
    #[test]
    fn open_input_checks_what_it_opened() {
        let d = tempfile::tempdir().unwrap();
        let root = d.path().join("root");
        std::fs::create_dir_all(root.join("seq")).unwrap();
        let outside = d.path().join("secret.txt");
        std::fs::write(&outside, "secret").unwrap();
        let frame = root.join("seq/frame.txt");
        std::fs::write(&frame, "frame").unwrap();
        let real_root = root.canonicalize().unwrap();
        confine(&root.join("seq"), &real_root);
        assert_eq!(read_file(&frame).unwrap(), b"frame");
        // swapped for a link out of the root after the manifest's check
        std::fs::remove_file(&frame).unwrap();
        std::os::unix::fs::symlink(&outside, &frame).unwrap();
        let e = read_file(&frame).unwrap_err().to_string();
        assert!(
            e.contains("outside the root") && e.contains("secret.txt"),
            "{e}"
        );
        // a link that stays inside the root is fine
        std::fs::write(root.join("seq/other.txt"), "other").unwrap();
        std::fs::remove_file(&frame).unwrap();
        std::os::unix::fs::symlink(root.join("seq/other.txt"), &frame).unwrap();
        assert_eq!(read_file(&frame).unwrap(), b"other");
        // a FIFO is refused at once
        let fifo = root.join("seq/fifo");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let t = std::time::Instant::now();
        let e = open_input(&fifo).unwrap_err().to_string();
        assert!(e.contains("FIFO"), "{e}");
        assert!(t.elapsed().as_secs() < 2);
        // an unconfined path may be a link anywhere
        let free = d.path().join("free.txt");
        std::os::unix::fs::symlink(&outside, &free).unwrap();
        assert_eq!(read_file(&free).unwrap(), b"secret");
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn memory_checks_refuse_what_cannot_fit() {
        let e = check_memory("a test", u64::MAX).unwrap_err();
        assert!(matches!(e, Error::OutOfMemory { .. }), "{e}");
        assert!(e.to_string().contains("a test"), "{e}");
        check_memory("a test", 1024).unwrap();
        assert!(try_vec::<u64>("huge", usize::MAX / 4).is_err());
        assert_eq!(try_vec::<u8>("small", 16).unwrap().capacity(), 16);
    }

    #[test]
    fn counts_must_fit_the_data() {
        let p = Path::new("f.ply");
        assert!(check_count(p, "element face", 10, 2, 20).is_ok());
        let e = check_count(p, "element face", 11, 2, 20)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("f.ply") && e.contains("element face") && e.contains("11"),
            "{e}"
        );
        // Overflowing products are refused, not wrapped.
        assert!(check_count(p, "x", u64::MAX, 2, u64::MAX).is_err());
        assert!(check_count(p, "x", 1 << 62, 8, u64::MAX).is_err());
    }

    #[test]
    fn decoded_limit_names_the_override() {
        let e = check_decoded(
            Path::new("a.npz"),
            "entry x.npy",
            DEFAULT_MAX_DECODED_BYTES + 1,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("a.npz") && e.contains(ENV_MAX_DECODED_BYTES),
            "{e}"
        );
        assert!(check_decoded(Path::new("a"), "b", 1000).is_ok());
    }

    #[cfg(unix)]
    #[test]
    fn fifos_and_devices_are_refused_without_blocking() {
        let d = tempfile::tempdir().unwrap();
        let fifo = d.path().join("pipe.ply");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let e = read_file(&fifo).unwrap_err().to_string();
        assert!(e.contains("pipe.ply") && e.contains("FIFO"), "{e}");
        let e = read_file(Path::new("/dev/zero")).unwrap_err().to_string();
        assert!(
            e.contains("/dev/zero") && e.contains("character device"),
            "{e}"
        );
        let e = read_file(d.path()).unwrap_err().to_string();
        assert!(e.contains("directory"), "{e}");
        // Through the cloud dispatcher too.
        let e = crate::io::cloud::load_cloud(&fifo).unwrap_err().to_string();
        assert!(e.contains("FIFO"), "{e}");
    }

    #[test]
    fn log_tail_reads_only_the_end() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("err.log");
        let mut text = String::new();
        for i in 0..100_000 {
            text.push_str(&format!("line {i}\n"));
        }
        std::fs::write(&p, &text).unwrap();
        let t = tail_lines(&p, 3);
        assert!(t.ends_with("line 99997\nline 99998\nline 99999"), "{t}");
        assert!(t.starts_with("[... "), "{t}");
        std::fs::write(&p, "a\nb\n").unwrap();
        assert_eq!(tail_lines(&p, 20), "a\nb");
        assert_eq!(tail_lines(&d.path().join("missing"), 20), "");
    }

    #[test]
    fn scratch_dirs_are_unique_and_removed() {
        let a = ScratchDir::new("cgenreg-test").unwrap();
        let b = ScratchDir::new("cgenreg-test").unwrap();
        assert_ne!(a.path(), b.path());
        std::fs::write(a.path().join("x"), b"1").unwrap();
        let pa = a.path().to_path_buf();
        drop(a);
        assert!(!pa.exists());
        assert!(b.path().is_dir());
    }
}
