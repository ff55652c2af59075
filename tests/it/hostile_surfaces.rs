//! The surfaces a later hostile probe went after, through the real binary: no code from the
//! working directory runs, the default fusion survives a candidate without correspondences,
//! every output is guarded and atomic, and inputs are bounded. Everything here runs on
//! temporary files and the bundled demo.

use crate::common;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_cgenreg"));
    c.env_remove("CGENREG_CACHE")
        .env_remove("ORT_DYLIB_PATH")
        .env_remove("CGENREG_MAX_RUN_FILE_BYTES");
    c
}

fn text(o: &Output) -> String {
    format!(
        "status {:?}\nstdout:\n{}\nstderr:\n{}",
        o.status.code(),
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

/// A working directory holding what would run if cgenreg ran a Python import or a `python3`
/// there: an `onnxruntime.py`, an `onnxruntime/` package and an executable `python3`, each
/// creating its own marker file when run.
pub fn planted_folder(dir: &Path) -> Vec<PathBuf> {
    let marks: Vec<PathBuf> = ["MARK-module", "MARK-package", "MARK-python3"]
        .iter()
        .map(|m| dir.join(m))
        .collect();
    let py = |m: &Path| format!("open({:?}, 'w').write('ran')\n", m.to_str().unwrap());
    std::fs::write(dir.join("onnxruntime.py"), py(&marks[0])).unwrap();
    std::fs::create_dir_all(dir.join("onnxruntime")).unwrap();
    std::fs::write(dir.join("onnxruntime/__init__.py"), py(&marks[1])).unwrap();
    let sh = dir.join("python3");
    std::fs::write(
        &sh,
        format!("#!/bin/sh\ntouch '{}'\nexit 1\n", marks[2].display()),
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&sh, std::fs::Permissions::from_mode(0o755)).unwrap();
    marks
}

/// A `PATH` that names the working directory first (`.` and an empty entry), as a careless
/// shell profile does.
pub fn path_with_cwd() -> String {
    format!(".::{}", std::env::var("PATH").unwrap_or_default())
}

/// The image branch (which loads ONNX Runtime) run from a folder holding a planted
/// `onnxruntime.py`, `onnxruntime/` and `python3`, with `.` on `PATH`: none of them runs, and
/// the run still finds the runtime.
#[test]
fn a_planted_onnxruntime_or_python3_in_the_working_directory_never_runs() {
    let tmp = tempfile::tempdir().unwrap();
    let cwd = tmp.path().join("work");
    std::fs::create_dir_all(&cwd).unwrap();
    let marks = planted_folder(&cwd);
    let o = bin()
        .current_dir(&cwd)
        .env("PATH", path_with_cwd())
        .args(["register", "--manifest"])
        .arg(common::demo_manifest())
        .args([
            "--pair",
            "synth-room/0-1",
            "--wfm",
            "builtin",
            "--frames",
            "8",
            "--margin",
            "1",
            "--k",
            "2",
            "--voxel",
            "0.3",
            "--no-cache",
        ])
        .output()
        .unwrap();
    for m in &marks {
        assert!(!m.exists(), "{} ran: {}", m.display(), text(&o));
    }
    assert!(o.status.success(), "{}", text(&o));
    // the descriptors came from ONNX Runtime ("VFM xfeat@... (onnxruntime 1.x ...)"): the
    // lookup did run, and found the runtime
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("(onnxruntime "), "{}", text(&o));
}

// ---------------------------------------------------------------- the default fusion

/// A room's walls and a pillar (`n` wall points), shifted by `dx` metres along x.
fn room(n: usize, dx: f32, seed: &mut u64) -> Vec<nalgebra::Point3<f32>> {
    let mut u = || {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*seed >> 40) as f32 / (1u64 << 24) as f32
    };
    let mut pts = Vec::new();
    for _ in 0..n {
        let (a, b, f) = (u() * 4.0, u() * 3.0, (u() * 6.0) as u32);
        let [x, y, z] = match f {
            0 => [a, b, 0.0],
            1 => [a, b, 3.0],
            2 => [a, 0.0, b],
            3 => [a, 4.0, b],
            4 => [0.0, a * 0.75, b],
            _ => [4.0, a * 0.75, b],
        };
        pts.push(nalgebra::Point3::new(x + dx, y, z));
    }
    for _ in 0..n / 4 {
        let (t, h) = (u() * std::f32::consts::TAU, u());
        pts.push(nalgebra::Point3::new(
            2.0 + 0.4 * t.cos() + dx,
            2.0 + 0.4 * t.sin(),
            h,
        ));
    }
    pts
}

/// Two copies of a room 100 km apart, and the same turned by 0.3 rad: the virtual camera that
/// sees a whole cloud 1e5 m wide links no keypoint to a pixel, so the Noisy-AND and image
/// candidates of the default (visibility) fusion have no correspondences while the geometric
/// branch registers. Before, the run failed ("kabsch: need at least 3 correspondences");
/// now those candidates are skipped and named, and the pose is the geometric branch's.
#[test]
fn the_default_fusion_returns_a_pose_when_a_candidate_has_no_correspondences() {
    use cgenreg::geometry::PointCloud;
    let tmp = tempfile::tempdir().unwrap();
    let mut seed = 7;
    let mut src = room(3000, 0.0, &mut seed);
    src.extend(room(3000, 1e5, &mut seed));
    let (c, s) = (0.3f32.cos(), 0.3f32.sin());
    let tgt: Vec<_> = src
        .iter()
        .map(|p| nalgebra::Point3::new(c * p.x - s * p.y + 0.5, s * p.x + c * p.y - 0.2, p.z + 0.1))
        .collect();
    let (sp, tp) = (tmp.path().join("s.ply"), tmp.path().join("t.ply"));
    cgenreg::io::cloud::save_cloud(&sp, &PointCloud::from_points(src)).unwrap();
    cgenreg::io::cloud::save_cloud(&tp, &PointCloud::from_points(tgt)).unwrap();
    let o = bin()
        .args(["register", "--source"])
        .arg(&sp)
        .arg("--target")
        .arg(&tp)
        .args([
            "--wfm",
            "builtin",
            "--frames",
            "8",
            "--margin",
            "1",
            "--k",
            "2",
            "--voxel",
            "0.2",
            "--no-cache",
            "--json",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let vis = &r["visibility"];
    let skipped: Vec<&str> = vis["skipped"]
        .as_array()
        .unwrap_or_else(|| panic!("no skipped candidates: {vis}"))
        .iter()
        .map(|c| c["pose"].as_str().unwrap())
        .collect();
    assert!(
        skipped.contains(&"noisy-and") && skipped.contains(&"image"),
        "{vis}"
    );
    assert!(
        vis["skipped"][0]["reason"]
            .as_str()
            .unwrap()
            .contains("correspondences"),
        "{vis}"
    );
    assert!(
        matches!(vis["chosen"].as_str(), Some("union" | "geometry")),
        "{vis}"
    );
    // the kept pose is the geometric branch's: within 2 degrees of the true turn
    let t = &r["target_from_source"];
    let (r00, r10) = (t[0][0].as_f64().unwrap(), t[1][0].as_f64().unwrap());
    let yaw = r10.atan2(r00);
    assert!((yaw - 0.3).abs() < 0.035, "yaw {yaw}: {t}");
    assert!(
        r["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .any(|w| w.as_str().unwrap().contains("could not be estimated")),
        "{}",
        r["warnings"]
    );
}

// ---------------------------------------------------------------- outputs

fn mkfifo(p: &Path) {
    let c = std::ffi::CString::new(p.to_str().unwrap()).unwrap();
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

fn is_link(p: &Path) -> bool {
    std::fs::symlink_metadata(p)
        .map(|m| m.file_type().is_symlink())
        .unwrap_or(false)
}

/// A valid PNG and a valid ZIP that cgenreg did not write (a figure, a .docx or data .npz).
fn foreign_png_and_zip(dir: &Path) -> (PathBuf, PathBuf) {
    let png = dir.join("figure.png");
    image::RgbImage::new(4, 3).save(&png).unwrap();
    let zip = dir.join("report.npz");
    let mut w = zip::ZipWriter::new(std::fs::File::create(&zip).unwrap());
    w.start_file(
        "word/document.xml",
        zip::write::SimpleFileOptions::default(),
    )
    .unwrap();
    std::io::Write::write_all(&mut w, b"<w:document/>").unwrap();
    w.finish().unwrap();
    (png, zip)
}

/// `screenshot --result-json` goes through the output guard (it replaced a text file, the
/// source cloud, a FIFO and a device node); `screenshot --out` and `--export-corr` judge an
/// existing file by cgenreg's own marker, not by the container format (any PNG, any ZIP was
/// replaced). All refused before any work, the files unchanged.
#[test]
fn outputs_never_replace_a_file_cgenreg_did_not_write() {
    let d = tempfile::tempdir().unwrap();
    let (png, zip) = foreign_png_and_zip(d.path());
    let (png_bytes, zip_bytes) = (std::fs::read(&png).unwrap(), std::fs::read(&zip).unwrap());
    let txt = d.path().join("notes.txt");
    std::fs::write(&txt, "keep me").unwrap();
    let cloud = d.path().join("cloud.ply");
    std::fs::write(&cloud, "ply\nformat ascii 1.0\nend_header\n").unwrap();
    let fifo = d.path().join("fifo.json");
    mkfifo(&fifo);
    let null = d.path().join("null.json");
    std::os::unix::fs::symlink("/dev/null", &null).unwrap();
    let fresh = d.path().join("fresh.png");
    for (target, why) in [
        (&txt, "--force"),
        (&cloud, "--force"),
        (&fifo, "FIFO"),
        (&null, "symbolic link"),
    ] {
        let o = bin()
            .args(["screenshot", "--panel", "pairs", "--out"])
            .arg(&fresh)
            .arg("--result-json")
            .arg(target)
            .output()
            .unwrap();
        assert!(!o.status.success(), "{}", text(&o));
        assert!(
            String::from_utf8_lossy(&o.stderr).contains(why),
            "{}",
            text(&o)
        );
    }
    assert_eq!(std::fs::read_to_string(&txt).unwrap(), "keep me");
    assert!(is_link(&null) && !fresh.exists());
    let o = bin()
        .args(["screenshot", "--panel", "pairs", "--out"])
        .arg(&png)
        .output()
        .unwrap();
    assert!(!o.status.success(), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("did not write"),
        "{}",
        text(&o)
    );
    let o = bin()
        .args(["register", "--manifest"])
        .arg(common::demo_manifest())
        .args(["--pair", "synth-room/0-1", "--export-corr"])
        .arg(&zip)
        .output()
        .unwrap();
    assert!(!o.status.success(), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("did not write"),
        "{}",
        text(&o)
    );
    assert_eq!(std::fs::read(&png).unwrap(), png_bytes);
    assert_eq!(std::fs::read(&zip).unwrap(), zip_bytes);
}

/// Runs `cmd` with its file-size limit at `bytes`: a write past it kills the process with
/// SIGXFSZ in the middle of writing, as a SIGTERM during the write would.
fn with_file_size_limit(cmd: &mut Command, bytes: u64) -> &mut Command {
    use std::os::unix::process::CommandExt;
    unsafe {
        cmd.pre_exec(move || {
            let l = libc::rlimit {
                rlim_cur: bytes,
                rlim_max: bytes,
            };
            if libc::setrlimit(libc::RLIMIT_FSIZE, &l) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        })
    }
}

/// `screenshot --out` killed in the middle of writing its PNG (file-size limit below the
/// picture's size) leaves the previous picture whole: the PNG goes to a temporary file that is
/// renamed when complete. Before, it was written in place: a truncated picture. Then a
/// screenshot over a PNG cgenreg rendered needs no --force, and a link planted in its place
/// while the pair registers is refused, never followed.
#[test]
fn a_screenshot_killed_mid_write_or_given_a_link_mid_run_changes_nothing() {
    let d = tempfile::tempdir().unwrap();
    let shot = |out: &Path, force: bool| {
        let mut c = bin();
        c.args([
            "screenshot",
            "--panel",
            "3d",
            "--voxel",
            "0.1",
            "--width",
            "320",
        ])
        .args(["--height", "200", "--no-cache", "--manifest"])
        .env("MESA_SHADER_CACHE_DISABLE", "true")
        .arg(common::demo_manifest())
        .arg("--out")
        .arg(out)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped());
        if force {
            c.arg("--force");
        }
        c
    };
    let killed = d.path().join("killed");
    std::fs::create_dir(&killed).unwrap();
    let previous = killed.join("shot.png");
    std::fs::write(&previous, b"the previous picture").unwrap();
    let o = with_file_size_limit(&mut shot(&previous, true), 4096)
        .output()
        .unwrap();
    assert!(!o.status.success(), "{}", text(&o));
    // killed while writing the picture, not before
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("registered synth-room"),
        "{}",
        text(&o)
    );
    assert_eq!(std::fs::read(&previous).unwrap(), b"the previous picture");
    // a picture cgenreg rendered is replaced without --force ...
    let out = d.path().join("shot.png");
    let o = shot(&out, false).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert!(std::fs::read(&out).unwrap().starts_with(b"\x89PNG"));
    // ... but not through a link planted once the run has started (its first check passed)
    let victim = d.path().join("victim.txt");
    std::fs::write(&victim, "keep me").unwrap();
    let child = shot(&out, false).spawn().unwrap();
    std::thread::sleep(std::time::Duration::from_millis(300));
    std::fs::remove_file(&out).unwrap();
    std::os::unix::fs::symlink(&victim, &out).unwrap();
    let o = child.wait_with_output().unwrap();
    assert!(!o.status.success(), "{}", text(&o));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("symbolic link"),
        "{}",
        text(&o)
    );
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
    assert!(is_link(&out));
    // a refused write leaves no temporary file
    let left: Vec<String> = std::fs::read_dir(d.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
}

/// Two runs given the same `--json` both said "wrote" and the file held one run's records: a
/// run file is locked while its run lasts, and the second process is refused, naming the
/// conflict; once the holder is gone the same command completes.
#[test]
fn two_processes_never_write_the_same_run_file() {
    use std::os::unix::io::AsRawFd;
    let d = tempfile::tempdir().unwrap();
    let json = d.path().join("run.json");
    let run = || {
        let mut c = bin();
        c.args(["bench"])
            .arg(common::demo_manifest())
            .args(["--voxel", "0.1", "--json"])
            .arg(&json);
        c.output().unwrap()
    };
    // This test process holds the run file's lock as a running bench does (flock on the hidden
    // lock file beside it), for as long as the second run takes: no timing to win or lose.
    let lock_path = d.path().join(".run.json.lock");
    let held = std::fs::File::create(&lock_path).unwrap();
    // SAFETY: flock on a descriptor this test owns.
    let r = unsafe { libc::flock(held.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    assert_eq!(r, 0);
    let refused = run();
    assert!(
        !refused.status.success(),
        "wrote past the lock: {}",
        text(&refused)
    );
    let e = String::from_utf8_lossy(&refused.stderr);
    assert!(
        e.contains("another running cgenreg process") && e.contains("run.json"),
        "{}",
        text(&refused)
    );
    assert!(!json.exists(), "the refused run wrote its file");
    // released, the same command writes (the lock file left behind is taken over, as after a
    // holder that died)
    drop(held);
    let ok = run();
    assert!(ok.status.success(), "{}", text(&ok));
    // the lock does not outlive the run, and the file is the finished run's
    assert!(!lock_path.exists());
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(v["run"]["complete"], true, "{v}");
}

// ---------------------------------------------------------------- false alarms, vague errors

/// redkitchen-rgbd 0-7 with oracle RGB and the authors' order (`--reference`) registers at
/// 1.1 deg / 14 cm, yet was told "no rigid transform explains the correspondences": an affine
/// map squeezing one axis (singular value 1.087, det 0.505) fitted the pair's near-planar
/// consensus. The warning now fires only for a similarity (a mirror, a change of units).
#[test]
fn the_no_rigid_transform_warning_stays_silent_on_a_pair_that_registers() {
    let Some(root) = cgenreg::testing::test_data_root() else {
        return;
    };
    let manifest =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/manifests/redkitchen-rgbd.toml");
    let o = bin()
        .env("CGENREG_DATA", &root)
        .args(["register", "--manifest"])
        .arg(&manifest)
        .args([
            "--pair",
            "redkitchen-rgbd/0-7",
            "--wfm",
            "oracle",
            "--reference",
            "--no-cache",
            "--json",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(r["metrics"]["success"], true, "{}", r["metrics"]);
    let warnings = r["warnings"].to_string();
    assert!(!warnings.contains("no rigid transform"), "{warnings}");
    assert!(!warnings.contains("too few to trust"), "{warnings}");
}

/// Every value of a numeric option that is not accepted gets the same kind of message, naming
/// the option, what it accepts and the value given: `--frames -1` said "invalid digit found in
/// string" where `--frames 0` said "must be at least 1", `--k -1` "unexpected argument '-1'",
/// and `--tau-img nan` passed the parser and failed later with "the plan was made for other
/// parameters than the registration's".
#[test]
fn neighbouring_values_of_an_option_give_equally_clear_errors() {
    let cases: &[(&str, &[&str], &str)] = &[
        (
            "--frames",
            &["-1", "0", "1.5", "x"],
            "whole number of at least 1",
        ),
        (
            "--k",
            &["-1", "0", "2.5", "x"],
            "whole number of at least 1",
        ),
        (
            "--topk",
            &["-1", "0", "99999999999999999999999"],
            "whole number of at least 1",
        ),
        (
            "--margin",
            &["-1", "1.5", "x"],
            "whole number of at least 0",
        ),
        (
            "--tau-img",
            &["-1", "0", "nan", "inf", "x"],
            "positive number",
        ),
        ("--tau-geo", &["-0.1", "0", "nan"], "positive number"),
        (
            "--prior",
            &["-1", "0", "1", "nan", "x"],
            "probability between 0 and 1",
        ),
        ("--voxel", &["-1", "0", "nan", "inf"], "positive length"),
    ];
    for (opt, values, want) in cases {
        for v in *values {
            let o = bin()
                .args(["register", "--source", "a.ply", "--target", "b.ply", opt, v])
                .output()
                .unwrap();
            let e = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{opt} {v}: {}", text(&o));
            assert!(
                e.contains(opt) && e.contains(want) && e.contains(v.trim_start_matches('-')),
                "{opt} {v}: {e}"
            );
        }
    }
}

// ---------------------------------------------------------------- inputs and manifests

/// `cmd`'s output, or a failure when it runs past `secs` (it is killed).
fn output_within(cmd: &mut Command, secs: u64) -> Output {
    let mut child = cmd
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let t = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t.elapsed().as_secs() >= secs {
            child.kill().unwrap();
            panic!(
                "still running after {secs} s: {:?}",
                cmd.get_args().collect::<Vec<_>>()
            );
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    child.wait_with_output().unwrap()
}

/// A copy of the bundled demo in `dir` (its manifest and both sequence folders).
fn demo_copy(dir: &Path) -> PathBuf {
    let src = common::demo_manifest();
    let from = src.parent().unwrap();
    for sub in ["source", "target"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
        for e in std::fs::read_dir(from.join(sub)).unwrap() {
            let e = e.unwrap();
            std::fs::copy(e.path(), dir.join(sub).join(e.file_name())).unwrap();
        }
    }
    std::fs::copy(&src, dir.join("demo.toml")).unwrap();
    dir.join("demo.toml")
}

/// Inputs read outside the readers' checks: an ONNX model that is a FIFO blocked the run
/// (the runtime and the model's hash read it directly), one that is a link to `/dev/zero` grew
/// memory. Both are refused at once, named by their kind.
#[test]
fn inputs_that_are_fifos_or_devices_are_refused_at_once() {
    let d = tempfile::tempdir().unwrap();
    let fifo = d.path().join("model.onnx");
    mkfifo(&fifo);
    let zero = d.path().join("zero.onnx");
    std::os::unix::fs::symlink("/dev/zero", &zero).unwrap();
    for (model, kind) in [(&fifo, "FIFO"), (&zero, "character device")] {
        let o = output_within(
            bin()
                .args(["register", "--manifest"])
                .arg(common::demo_manifest())
                .args(["--pair", "synth-room/0-1", "--no-cache", "--voxel", "0.3"])
                .args([
                    "--wfm", "builtin", "--frames", "8", "--margin", "1", "--k", "2",
                ])
                .arg("--vfm-model")
                .arg(model),
            30,
        );
        assert!(!o.status.success(), "{}", text(&o));
        let e = String::from_utf8_lossy(&o.stderr);
        let name = model.file_name().unwrap().to_str().unwrap();
        assert!(e.contains(kind) && e.contains(name), "{e}");
    }
}

/// Manifests: a 20 MB one (a `gt_matrix` of a million rows) is refused before it is parsed;
/// `root = "/"` (which confines nothing) is refused; ids and splits with ESC, NUL, a line
/// break, a right-to-left override or a zero-width space are refused, the error escaping
/// them; a depth frame of a `sequence` folder linked out of the root is refused when read.
#[test]
fn manifests_are_bounded_confined_and_ids_plain() {
    use cgenreg::dataset::Dataset;
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("a.xyz"), "0 0 0\n1 0 0\n0 1 0\n0 0 1\n").unwrap();
    let head = "name = \"m\"\n[[fragments]]\nid = \"a\"\ncloud = \"a.xyz\"\n\
                [[fragments]]\nid = \"b\"\ncloud = \"a.xyz\"\n";
    // 1. size, checked before the parse
    let big = d.path().join("big.toml");
    let row = "[1.0, 0.0, 0.0, 0.0], ";
    let mut text = format!("{head}[[pairs]]\ntarget = \"a\"\nsource = \"b\"\ngt_matrix = [");
    text.push_str(&row.repeat(1_000_000));
    text.push_str("]\n");
    std::fs::write(&big, &text).unwrap();
    let t = std::time::Instant::now();
    let e = Dataset::load(&big).unwrap_err().to_string();
    assert!(
        e.contains("file size") && e.contains("CGENREG_MAX_MANIFEST_BYTES"),
        "{e}"
    );
    assert!(t.elapsed().as_secs() < 2, "{:?}", t.elapsed());
    // 2. root = "/"
    let rooted = d.path().join("rooted.toml");
    std::fs::write(&rooted, format!("root = \"/\"\n{head}")).unwrap();
    let e = Dataset::load(&rooted).unwrap_err().to_string();
    assert!(e.contains("root") && e.contains("confines nothing"), "{e}");
    std::fs::write(
        &rooted,
        "root = \"/\"\nallow_outside_root = true\nname = \"m\"\n",
    )
    .unwrap();
    Dataset::load(&rooted).unwrap();
    // 3. hidden characters in ids and splits
    for bad in [
        "\\u001b[31mred",
        "a\\u0000b",
        "a\\nb",
        "a\\u202eb",
        "a\\u200bb",
    ] {
        let m = d.path().join("ids.toml");
        std::fs::write(
            &m,
            format!("name = \"m\"\n[[fragments]]\nid = \"{bad}\"\ncloud = \"a.xyz\"\n"),
        )
        .unwrap();
        let e = Dataset::load(&m).unwrap_err().to_string();
        assert!(
            e.contains(".id") && e.contains("control characters"),
            "{bad}: {e}"
        );
        assert!(
            !e.chars()
                .any(|c| c.is_control() || c == '\u{202e}' || c == '\u{200b}'),
            "{e:?}"
        );
        std::fs::write(
            &m,
            format!("{head}[[pairs]]\ntarget = \"a\"\nsource = \"b\"\nsplit = \"{bad}\"\n"),
        )
        .unwrap();
        let e = Dataset::load(&m).unwrap_err().to_string();
        assert!(e.contains(".split"), "{bad}: {e}");
    }
    // 4. a frame of a sequence folder linked out of the root after the manifest's check
    let demo = demo_copy(&d.path().join("demo"));
    let ds = Dataset::load(&demo).unwrap();
    let frame = d.path().join("demo/target/frame-000001.depth.png");
    let outside = d.path().join("outside.png");
    std::fs::rename(&frame, &outside).unwrap();
    std::os::unix::fs::symlink(&outside, &frame).unwrap();
    let e = ds.load_pair("synth-room/0-1").unwrap_err().to_string();
    assert!(
        e.contains("outside the root") && e.contains("outside.png"),
        "{e}"
    );
}
