//! Regression tests for the reader crashes, hangs, wrong successes and unbounded memory a
//! hostile probe found (issue 12), each on its reproducing input (made here), and for the
//! limits of `cgenreg::io::limits`.

use cgenreg::io::limits::{self, with_limit, ENV_MAX_DECODED_BYTES};
use cgenreg::io::{cloud, npy, pcd, ply};
use cgenreg::wfm::video;
use std::path::Path;
use std::time::{Duration, Instant};

/// Run `f` on another thread and fail if it takes longer than `secs` (a hang regression
/// must fail, not block the test run).
fn within<T: Send + 'static>(secs: u64, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(Duration::from_secs(secs))
        .unwrap_or_else(|_| panic!("did not finish within {secs} s"))
}

const HUGE_COUNT_HEADER: &str = "VERSION .7\nFIELDS x y z _\nSIZE 4 4 4 8\nTYPE F F F F\n\
                                 COUNT 1 1 1 2305843009213693952\nWIDTH 1\nHEIGHT 1\nPOINTS 1\n";

#[test]
fn pcd_huge_count_is_an_error_in_every_encoding() {
    // ascii panicked with "capacity overflow".
    let ascii = format!("{HUGE_COUNT_HEADER}DATA ascii\n1 2 3 4\n");
    let e = pcd::parse_pcd(Path::new("count.pcd"), ascii.as_bytes())
        .unwrap_err()
        .to_string();
    assert!(e.contains("count.pcd") && e.contains("COUNT"), "{e}");
    // binary: 8 x 2^61 wrapped to 0 bytes of padding and the file loaded.
    let mut bin = format!("{HUGE_COUNT_HEADER}DATA binary\n").into_bytes();
    for v in [1f32, 2.0, 3.0] {
        bin.extend_from_slice(&v.to_le_bytes());
    }
    let e = pcd::parse_pcd(Path::new("count.pcd"), &bin)
        .unwrap_err()
        .to_string();
    assert!(e.contains("overflow"), "{e}");
    // binary_compressed: the same.
    let mut comp = format!("{HUGE_COUNT_HEADER}DATA binary_compressed\n").into_bytes();
    let raw: Vec<u8> = [1f32, 2.0, 3.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let c = pcd::lzf_compress(&raw);
    comp.extend_from_slice(&(c.len() as u32).to_le_bytes());
    comp.extend_from_slice(&(raw.len() as u32).to_le_bytes());
    comp.extend_from_slice(&c);
    let e = pcd::parse_pcd(Path::new("count.pcd"), &comp)
        .unwrap_err()
        .to_string();
    assert!(e.contains("overflow"), "{e}");
    // A COUNT that does not overflow but that the data cannot hold is refused too.
    let ascii = "VERSION .7\nFIELDS x y z h\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1000000000\n\
                 WIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3 4\n";
    let e = pcd::parse_pcd(Path::new("c2.pcd"), ascii.as_bytes())
        .unwrap_err()
        .to_string();
    assert!(e.contains("c2.pcd") && e.contains("values"), "{e}");
}

#[test]
fn pcd_lzf_decoded_size_is_capped() {
    // Valid LZF runs expand ~88x: a 13.6 MB file reached 2.3 GB. Here with a 1 MB limit and
    // a 2.4 MB decoded block from a ~30 KB file.
    let n = 200_000usize;
    let cloud =
        cgenreg::geometry::cloud::PointCloud::from_points(vec![
            nalgebra::Point3::new(1.0, 2.0, 3.0);
            n
        ]);
    let bytes = pcd::encode_pcd(&cloud, "binary_compressed");
    assert!(bytes.len() < 100_000, "{} bytes", bytes.len());
    let e = with_limit(ENV_MAX_DECODED_BYTES, 1 << 20, || {
        pcd::parse_pcd(Path::new("runs.pcd"), &bytes)
    })
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("runs.pcd") && e.contains(ENV_MAX_DECODED_BYTES),
        "{e}"
    );
    // Under the default limit it is a fine cloud.
    assert_eq!(
        pcd::parse_pcd(Path::new("runs.pcd"), &bytes).unwrap().len(),
        n
    );
}

#[test]
fn ply_element_without_properties_and_a_huge_count_does_not_hang() {
    let text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
                property float z\nelement face 1000000000000000000\nend_header\n0 0 0\n1 1 1\n";
    let t = Instant::now();
    let c = within(10, move || {
        ply::parse_ply(Path::new("f.ply"), text.as_bytes())
    })
    .unwrap();
    assert_eq!(c.len(), 2);
    assert!(t.elapsed() < Duration::from_secs(2));
    // With a property, each instance needs data: the count is checked against the file.
    let text = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
                property float z\nelement face 1000000000000000000\nproperty int k\nend_header\n\
                0 0 0\n1\n";
    let e = within(10, move || {
        ply::parse_ply(Path::new("g.ply"), text.as_bytes())
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("g.ply") && e.contains("element face"), "{e}");
    // Binary list lengths that overflow are errors, not wraps.
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n\
                  property float y\nproperty float z\nelement face 1\n\
                  property list uint int vertex_indices\nend_header\n"
        .to_vec();
    b.extend_from_slice(&[0u8; 12]);
    b.extend_from_slice(&u32::MAX.to_le_bytes());
    let e = ply::parse_ply(Path::new("l.ply"), &b)
        .unwrap_err()
        .to_string();
    assert!(e.contains("l.ply"), "{e}");
}

fn npz_with(name: &str, npy_bytes: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let mut w = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated);
    w.start_file(name, opts).unwrap();
    w.write_all(npy_bytes).unwrap();
    w.finish().unwrap().into_inner()
}

#[test]
fn npz_entry_decoded_size_is_capped() {
    // A 3.1 MB NPZ reached 6.1 GB. Here: a 4 MB entry of zeros (a few KB compressed)
    // under a 1 MB limit.
    let n = 1 << 20;
    let npy_bytes = npy::encode_npy_f32(&[n / 3, 3], &vec![0.0; n / 3 * 3]);
    let z = npz_with("feats.npy", &npy_bytes);
    assert!(z.len() < 100_000);
    let e = with_limit(ENV_MAX_DECODED_BYTES, 1 << 20, || {
        npy::parse_npz(Path::new("bomb.npz"), &z)
    })
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("bomb.npz") && e.contains("feats.npy") && e.contains(ENV_MAX_DECODED_BYTES),
        "{e}"
    );
    assert_eq!(
        npy::parse_npz(Path::new("ok.npz"), &z).unwrap()["feats"].shape,
        vec![n / 3, 3]
    );
}

#[test]
fn npy_header_nesting_is_refused() {
    let mut h = String::from("{'descr': '<f4', 'fortran_order': False, 'shape': ");
    h += &"(".repeat(100_000);
    let mut b = b"\x93NUMPY\x02\x00".to_vec();
    b.extend_from_slice(&(h.len() as u32).to_le_bytes());
    b.extend_from_slice(h.as_bytes());
    let e = npy::parse_npy(Path::new("deep.npy"), &b)
        .unwrap_err()
        .to_string();
    assert!(e.contains("deep.npy") && e.contains("header"), "{e}");
}

#[cfg(unix)]
#[test]
fn fifos_and_devices_are_refused_as_source_and_manifest() {
    let d = tempfile::tempdir().unwrap();
    let fifo = d.path().join("in.ply");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let f2 = fifo.clone();
    let e = within(10, move || cloud::load_cloud(&f2))
        .unwrap_err()
        .to_string();
    assert!(e.contains("in.ply") && e.contains("FIFO"), "{e}");
    let toml = d.path().join("m.toml");
    let c = std::ffi::CString::new(toml.to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let e = within(10, move || cgenreg::dataset::Dataset::load(&toml))
        .unwrap_err()
        .to_string();
    assert!(e.contains("m.toml") && e.contains("FIFO"), "{e}");
    // A link to /dev/zero under a cloud's name: the target's type counts, not the link's.
    let zero = d.path().join("zero.ply");
    std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
    let e = within(10, move || cloud::load_cloud(&zero))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("zero.ply") && e.contains("character device"),
        "{e}"
    );
    // Through the CLI, as the probe ran it.
    let bin = env!("CARGO_BIN_EXE_cgenreg");
    let out = within(60, move || {
        std::process::Command::new(bin)
            .args(["register", "--source"])
            .arg(&fifo)
            .arg("--target")
            .arg(&fifo)
            .output()
            .unwrap()
    });
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("FIFO"), "{err}");
    let out = within(60, move || {
        std::process::Command::new(bin)
            .args(["register", "--source", "/dev/zero", "--target", "/dev/zero"])
            .output()
            .unwrap()
    });
    assert!(!out.status.success());
}

#[test]
fn bad_numeric_options_are_rejected_by_name() {
    let bin = env!("CARGO_BIN_EXE_cgenreg");
    for (args, needle) in [
        (vec!["--lift-radius", "-1"], "--lift-radius"),
        (vec!["--voxel=-0.05"], "--voxel"),
        (vec!["--voxel", "0"], "--voxel"),
        (vec!["--voxel", "nan"], "--voxel"),
        (vec!["--frames", "100000"], "CGENREG_MAX_FRAMES"),
        (vec!["--frames", "0"], "--frames"),
        (vec!["--frames", "-3"], "--frames"),
    ] {
        let out = std::process::Command::new(bin)
            .args(["register", "--source", "a.ply", "--target", "b.ply"])
            .args(&args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} accepted");
        assert!(err.contains(needle), "{args:?}: {err}");
    }
    // The limit is an overridable policy, checked before any work (a.ply does not exist:
    // the error is about the file, so --frames 2000 passed validation).
    let out = std::process::Command::new(bin)
        .args([
            "register", "--source", "a.ply", "--target", "b.ply", "--frames", "2000",
        ])
        .env(limits::ENV_MAX_FRAMES, "5000")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(!err.contains("CGENREG_MAX_FRAMES"), "{err}");
}

// ---------------------------------------------------------------------------------------
// mp4
// ---------------------------------------------------------------------------------------

fn test_mp4(n: usize) -> (Vec<image::RgbImage>, Vec<u8>) {
    let frames: Vec<image::RgbImage> = (0..n)
        .map(|t| {
            image::RgbImage::from_fn(64, 48, |x, y| {
                image::Rgb([(x * 3 + t as u32 * 9) as u8, (y * 5) as u8, 100])
            })
        })
        .collect();
    let b = video::encode_mp4_h264(&frames, 30).unwrap();
    (frames, b)
}

/// Offset of the first box of type `kind` (its size field).
fn find_box(b: &[u8], kind: &[u8; 4]) -> usize {
    b.windows(4).position(|w| w == kind).expect("box present") - 4
}

fn decode(b: Vec<u8>) -> cgenreg::Result<Vec<image::RgbImage>> {
    within(20, move || video::decode_mp4_frames(Path::new("v.mp4"), b))
}

#[test]
fn mp4_box_of_size_zero_is_an_error_not_a_loop() {
    let (_, good) = test_mp4(3);
    for kind in [b"mvhd", b"vmhd", b"tkhd", b"stsd"] {
        let mut b = good.clone();
        let at = find_box(&b, kind);
        b[at..at + 4].copy_from_slice(&0u32.to_be_bytes());
        let e = decode(b).unwrap_err().to_string();
        assert!(e.contains("v.mp4") && e.contains("size 0"), "{kind:?}: {e}");
    }
    // A nested size smaller than a header (the demuxer would seek backwards).
    let mut b = good.clone();
    let at = find_box(&b, b"mvhd");
    b[at..at + 4].copy_from_slice(&4u32.to_be_bytes());
    assert!(decode(b).is_err());
}

#[test]
fn mp4_stsz_with_4_billion_samples_is_an_error_not_an_abort() {
    let (_, good) = test_mp4(3);
    let at = find_box(&good, b"stsz") + 8;
    // stsz: version/flags (4), sample_size (4), sample_count (4).
    for sample_size in [0u32, 1000] {
        let mut b = good.clone();
        b[at + 4..at + 8].copy_from_slice(&sample_size.to_be_bytes());
        b[at + 8..at + 12].copy_from_slice(&4_000_000_000u32.to_be_bytes());
        let e = decode(b).unwrap_err().to_string();
        assert!(e.contains("v.mp4") && e.contains("mp4 boxes"), "{e}");
    }
}

#[test]
fn avc3_mp4s_are_read_like_avc1() {
    let (frames, good) = test_mp4(4);
    let want = decode(good.clone()).unwrap();
    assert_eq!(want.len(), frames.len());
    let mut b = good.clone();
    // The sample entry inside stsd (ftyp also lists an "avc1" brand).
    let stsd = find_box(&b, b"stsd");
    let at = stsd + find_box(&b[stsd..], b"avc1");
    b[at + 4..at + 8].copy_from_slice(b"avc3");
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("avc3.mp4");
    std::fs::write(&p, &b).unwrap();
    assert_eq!(video::probe_mp4(&p).unwrap().codec, "avc3");
    assert_eq!(video::read_mp4_frames(&p).unwrap(), want);
}

/// The decoder cannot tell damaged slice data from real data: neither ISO-BMFF nor H.264
/// carries a checksum. Mutations of the media data either fail to decode or decode to other
/// frames; they never panic. (The cache's own content hashes catch damage to stored data.)
#[test]
fn mp4_media_mutations_decode_or_fail_but_never_panic() {
    let (_, good) = test_mp4(6);
    let want = decode(good.clone()).unwrap();
    let mdat = find_box(&good, b"mdat") + 8;
    let (mut errors, mut different, mut same) = (0, 0, 0);
    let mut x = 0x1234_5678u64;
    for _ in 0..30 {
        let mut b = good.clone();
        for _ in 0..3 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let i = mdat + (x as usize % (b.len() - mdat));
            b[i] ^= 1 << (x >> 40 & 7);
        }
        match decode(b) {
            Err(_) => errors += 1,
            Ok(f) if f != want => different += 1,
            Ok(_) => same += 1,
        }
    }
    println!("30 mutants: {errors} errors, {different} decoded differently, {same} identical");
    assert_eq!(errors + different + same, 30);
}

#[test]
fn decoded_frames_are_capped_before_decoding() {
    let (_, good) = test_mp4(3);
    let e = with_limit(ENV_MAX_DECODED_BYTES, 10_000, || {
        video::decode_mp4_frames(Path::new("big.mp4"), good.clone())
    })
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("big.mp4") && e.contains(ENV_MAX_DECODED_BYTES),
        "{e}"
    );
}

#[test]
fn deeply_nested_toml_and_json_are_errors_not_stack_overflows() {
    let d = tempfile::tempdir().unwrap();
    let m = d.path().join("deep.toml");
    std::fs::write(&m, format!("name = {}", "[".repeat(100_000))).unwrap();
    let e = within(20, move || cgenreg::dataset::Dataset::load(&m))
        .unwrap_err()
        .to_string();
    assert!(e.contains("deep.toml"), "{e}");
    let line = format!("{}\n", "[".repeat(100_000));
    let e = within(20, move || {
        cgenreg::wfm::prompt::parse_reference_jsonl(Path::new("deep.jsonl"), &line)
    })
    .unwrap_err()
    .to_string();
    assert!(e.contains("deep.jsonl") && e.contains("recursion"), "{e}");
}

// ---------------------------------------------------------------------------------------
// Inputs found by libFuzzer (scripts/fuzz.sh, docs/reliability.md section 3)
// ---------------------------------------------------------------------------------------

thread_local! {
    static PANICS: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// Run `f` and fail if it panicked anywhere on this thread, even if the panic was caught
/// inside (the readers wrap third-party demuxers in `catch_unwind`; libFuzzer aborts on any
/// panic, caught or not, and so does this check).
fn without_panics<T>(f: impl FnOnce() -> T) -> T {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let prev = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            PANICS.with(|p| p.set(p.get() + 1));
            prev(info);
        }));
    });
    let before = PANICS.with(|p| p.get());
    let out = f();
    let after = PANICS.with(|p| p.get());
    assert_eq!(
        after, before,
        "the reader panicked (caught inside) on this input"
    );
    out
}

fn decode_no_panic(b: Vec<u8>) -> cgenreg::Result<Vec<image::RgbImage>> {
    within(20, move || {
        without_panics(|| video::decode_mp4_frames(Path::new("v.mp4"), b))
    })
}

/// libFuzzer's first mp4 crash (`crash-fa67e642...`, 939 bytes, found in 10 s): an `stsc`
/// entry with 0 samples per chunk made the `mp4` crate divide by zero in `sample_offset`
/// (caught by the reader's `catch_unwind`, but a panic all the same).
#[test]
fn mp4_fuzz_crash_stsc_zero_samples_per_chunk() {
    let b = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/fuzz/mp4-stsc-crash-fa67e642.mp4"),
    )
    .unwrap();
    assert_eq!(b.len(), 939);
    let e = decode_no_panic(b).unwrap_err().to_string();
    assert!(
        e.contains("v.mp4") && e.contains("mp4 sample table") && e.contains("samples per chunk"),
        "{e}"
    );
}

/// Every sample-table field the `mp4` crate uses unchecked, damaged one at a time in a
/// valid file: each is an error naming the table, with no panic inside the demuxer.
#[test]
fn mp4_damaged_sample_tables_are_errors_without_panics() {
    let (_, good) = test_mp4(3);
    let be = |v: u32| v.to_be_bytes();
    // stsc: size, type, version/flags, entry count, then (first_chunk, per_chunk, desc).
    let stsc = find_box(&good, b"stsc") + 16;
    // stts: size, type, version/flags, entry count, then (count, delta).
    let stts = find_box(&good, b"stts") + 16;
    // stsz: size, type, version/flags, sample_size, sample_count, then per-sample sizes.
    let stsz = find_box(&good, b"stsz") + 8;
    let cases: Vec<(&str, usize, [u8; 4], &str)> = vec![
        (
            "stsc samples per chunk 0",
            stsc + 4,
            be(0),
            "samples per chunk",
        ),
        ("stsc first chunk 0", stsc, be(0), "first chunk"),
        ("stts covers no sample", stts, be(0), "stts gives times"),
    ];
    for (what, at, bytes, needle) in cases {
        let mut b = good.clone();
        b[at..at + 4].copy_from_slice(&bytes);
        let e = decode_no_panic(b).unwrap_err().to_string();
        assert!(
            e.contains("v.mp4") && e.contains("mp4 sample table") && e.contains(needle),
            "{what}: {e}"
        );
    }
    // A per-sample size of 4 GB (the crate allocates it before reading).
    let size = u32::from_be_bytes(good[stsz + 4..stsz + 8].try_into().unwrap());
    if size == 0 {
        let mut b = good.clone();
        b[stsz + 12..stsz + 16].copy_from_slice(&be(0xFFFF_FFF0));
        let e = decode_no_panic(b).unwrap_err().to_string();
        assert!(e.contains("stsz sample size"), "{e}");
    }
}

/// `probe_mp4` with a zero mdhd timescale: the crate's `frame_rate` divides by it.
#[test]
fn mp4_probe_with_zero_timescale_reports_no_rate_without_panics() {
    let (frames, good) = test_mp4(3);
    let mut b = good.clone();
    // mdhd version 0: size, type, version/flags, creation, modification, timescale.
    let at = find_box(&b, b"mdhd") + 20;
    b[at..at + 4].copy_from_slice(&0u32.to_be_bytes());
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("ts0.mp4");
    std::fs::write(&p, &b).unwrap();
    let info = without_panics(|| video::probe_mp4(&p)).unwrap();
    assert_eq!(info.frame_count as usize, frames.len());
    assert_eq!(info.fps, 0.0);
    // The good file's rate is unchanged by the checked computation.
    let q = d.path().join("good.mp4");
    std::fs::write(&q, &good).unwrap();
    assert_eq!(video::probe_mp4(&q).unwrap().fps, 30.0);
}

/// libFuzzer's mp4 timeout (`timeout-c6a8c152...`, 939 bytes, after 294,660 executions of the
/// long run): a `dref` with entry count 0xff000008 whose first entry box has size 0; the
/// `mp4` crate re-read that box once per declared entry (4 billion times). The box check now
/// walks `dref` entries like every other child box.
#[test]
fn mp4_fuzz_timeout_dref_entry_of_size_zero() {
    let b = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/fuzz/mp4-dref-timeout-c6a8c152.mp4"),
    )
    .unwrap();
    assert_eq!(b.len(), 939);
    let e = decode_no_panic(b).unwrap_err().to_string();
    assert!(e.contains("v.mp4") && e.contains("size 0"), "{e}");
    // The same damage in a valid file: a huge entry count and an entry of size 0.
    let (_, good) = test_mp4(3);
    let mut b = good.clone();
    // dref: size, type, version/flags, entry count, then the entry boxes.
    let at = find_box(&b, b"dref");
    b[at + 12..at + 16].copy_from_slice(&0xff00_0008u32.to_be_bytes());
    b[at + 16..at + 20].copy_from_slice(&0u32.to_be_bytes());
    let e = decode_no_panic(b).unwrap_err().to_string();
    assert!(e.contains("v.mp4") && e.contains("size 0"), "{e}");
    // The valid file still decodes (its dref entries pass the walk).
    assert_eq!(decode_no_panic(good).unwrap().len(), 3);
}

/// libFuzzer's third mp4 input (`crash-8d7a54c5...`, re-run after the dref fix): `stts`
/// entries whose sample counts sum past 32 bits; the `mp4` crate unwrapped the overflow
/// error in `read_sample` (a panic, caught by the reader).
#[test]
fn mp4_fuzz_crash_stts_sample_count_overflow() {
    let b = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/fuzz/mp4-stts-overflow-crash-8d7a54c5.mp4"),
    )
    .unwrap();
    assert_eq!(b.len(), 939);
    let e = decode_no_panic(b).unwrap_err().to_string();
    assert!(e.contains("v.mp4"), "{e}");
}

/// libFuzzer's mp4 crash of session 12 (`crash-8453caff...`, 38 bytes, after 575 k
/// executions from the x264 seeds): a top-level `emsg` box (version 0) of 32 bytes whose
/// strings and fields need 34; the `mp4` crate subtracted the fields' size from the box size
/// with overflow in `EmsgBox::read_box` (a panic, caught by the reader).
#[test]
fn mp4_fuzz_crash_emsg_fields_past_box_end() {
    let b = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures/fuzz/mp4-emsg-crash-8453caff.mp4"),
    )
    .unwrap();
    assert_eq!(b.len(), 38);
    let e = decode_no_panic(b).unwrap_err().to_string();
    assert!(e.contains("v.mp4") && e.contains("emsg"), "{e}");
    // emsg boxes after a valid file: version 0 and 1 that fit still decode; cut short (into
    // their fields or strings) they are errors, not panics.
    let (_, good) = test_mp4(3);
    let emsg = |version: u8, cut: usize| {
        let mut body = vec![version, 0, 0, 0];
        let strings = b"urn:x\0v\0";
        if version == 0 {
            body.extend_from_slice(strings);
            body.extend_from_slice(&[0; 16]);
        } else {
            body.extend_from_slice(&[0; 20]);
            body.extend_from_slice(strings);
        }
        body.extend_from_slice(b"msg");
        let keep = body.len() - cut;
        let mut b = good.clone();
        b.extend_from_slice(&((keep + 8) as u32).to_be_bytes());
        b.extend_from_slice(b"emsg");
        b.extend_from_slice(&body[..keep]);
        b
    };
    for version in [0, 1] {
        assert_eq!(decode_no_panic(emsg(version, 0)).unwrap().len(), 3);
        // Without the message (3 bytes) the fields still fit; one byte less, they do not.
        assert_eq!(decode_no_panic(emsg(version, 3)).unwrap().len(), 3);
        for cut in [4, 6, 12] {
            let e = decode_no_panic(emsg(version, cut)).unwrap_err().to_string();
            assert!(e.contains("emsg"), "version {version}, cut {cut}: {e}");
        }
    }
}
