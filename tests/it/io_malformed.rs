//! Every cloud/array reader on malformed files (generated here): each must fail with an
//! error that names the file and the problem, never panic and never return a partial cloud.

use cgenreg::geometry::cloud::PointCloud;
use cgenreg::io::{cloud, kitti, npy, pcd, pickle, ply, xyz};
use nalgebra::{Point3, Vector3};
use std::path::{Path, PathBuf};

fn sample(n: usize) -> PointCloud {
    PointCloud {
        points: (0..n)
            .map(|i| Point3::new(i as f32 * 0.01, (i % 13) as f32 * 0.2, 1.0 + (i % 7) as f32))
            .collect(),
        colors: Some((0..n).map(|i| [(i % 256) as u8, 7, 9]).collect()),
        normals: Some((0..n).map(|_| Vector3::new(0.0, 0.0, 1.0)).collect()),
        intensity: Some((0..n).map(|i| i as f32).collect()),
    }
}

/// Write `bytes` to `dir/name`, run `read`, and check the error mentions the file and every
/// one of `needles`.
fn expect_err<T: std::fmt::Debug>(
    dir: &Path,
    name: &str,
    bytes: &[u8],
    read: impl Fn(&Path) -> cgenreg::Result<T>,
    needles: &[&str],
) -> String {
    let p: PathBuf = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    let e = read(&p).expect_err(name).to_string();
    assert!(
        e.contains(name),
        "{name}: error does not name the file: {e}"
    );
    for n in needles {
        assert!(e.contains(n), "{name}: error lacks {n:?}: {e}");
    }
    e
}

#[test]
fn ply() {
    let d = tempfile::tempdir().unwrap();
    let good = ply::encode_ply(&sample(100));
    // Truncated binary PLY: the last vertex is cut short.
    expect_err(
        d.path(),
        "cut.ply",
        &good[..good.len() - 5],
        ply::read_ply,
        &["vertex data", "truncated"],
    );
    // Header cut before end_header.
    let head_end = good.windows(10).position(|w| w == b"end_header").unwrap();
    expect_err(
        d.path(),
        "nohead.ply",
        &good[..head_end],
        ply::read_ply,
        &["end_header"],
    );
    // Wrong magic.
    let mut bad = good.clone();
    bad[..3].copy_from_slice(b"plx");
    expect_err(d.path(), "magic.ply", &bad, ply::read_ply, &["magic"]);
    // Declared more vertices than present.
    let s = String::from_utf8_lossy(&good[..head_end]).replace("vertex 100", "vertex 101");
    let mut lie = s.into_bytes();
    lie.extend_from_slice(&good[head_end..]);
    expect_err(
        d.path(),
        "count.ply",
        &lie,
        ply::read_ply,
        &["101 vertices"],
    );
    // Empty cloud, NaN coordinates, unknown format, bad ascii token.
    let empty = ply::encode_ply(&PointCloud::default());
    expect_err(d.path(), "empty.ply", &empty, ply::read_ply, &["empty"]);
    let mut c = sample(10);
    c.points[4].x = f32::NAN;
    expect_err(
        d.path(),
        "nan.ply",
        &ply::encode_ply(&c),
        ply::read_ply,
        &["point 4", "finite"],
    );
    let text = b"ply\nformat binary_middle_endian 1.0\nelement vertex 0\nend_header\n";
    expect_err(d.path(), "fmt.ply", text, ply::read_ply, &["format"]);
    let text = b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
                 property float z\nend_header\n1 2 3\n4 five 6\n";
    expect_err(
        d.path(),
        "tok.ply",
        text,
        ply::read_ply,
        // the field and the token's size, never the file's content
        &["instance 1", "property y", "content is not shown"],
    );
    let text = b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
                 property float z\nend_header\n1 2 3\n4 5\n";
    expect_err(d.path(), "short.ply", text, ply::read_ply, &["truncated"]);
}

#[test]
fn huge_declared_counts_fail_without_allocating() {
    let d = tempfile::tempdir().unwrap();
    let text = b"ply\nformat ascii 1.0\nelement vertex 1000000000000000\nproperty float x\n\
                 property float y\nproperty float z\nend_header\n1 2 3\n";
    expect_err(d.path(), "huge.ply", text, ply::read_ply, &["truncated"]);
    let text = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000000\n\
                 property float x\nproperty float y\nproperty float z\nend_header\n";
    expect_err(
        d.path(),
        "huge_bin.ply",
        text,
        ply::read_ply,
        &["vertex data"],
    );
    for data in ["ascii", "binary", "binary_compressed"] {
        let text = format!(
            "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1000000000000\n\
             HEIGHT 1\nPOINTS 1000000000000\nDATA {data}\n0 0 0 0 0 0 0 0 0 0 0 0\n"
        );
        let name = format!("huge_{data}.pcd");
        expect_err(d.path(), &name, text.as_bytes(), pcd::read_pcd, &["POINTS"]);
    }
}

#[test]
fn pcd() {
    let d = tempfile::tempdir().unwrap();
    let c = sample(50);
    for data in ["ascii", "binary", "binary_compressed"] {
        // A header that lies about the point count (POINTS and WIDTH both say 60).
        let good = pcd::encode_pcd(&c, data);
        let s = String::from_utf8_lossy(&good).into_owned();
        let cut = s.find("DATA").unwrap();
        let mut lie = s[..cut]
            .replace("POINTS 50", "POINTS 60")
            .replace("WIDTH 50", "WIDTH 60")
            .into_bytes();
        lie.extend_from_slice(&good[cut..]);
        let name = format!("lie_{data}.pcd");
        expect_err(
            d.path(),
            &name,
            &lie,
            pcd::read_pcd,
            &["POINTS", "60 points"],
        );
        // POINTS disagreeing with WIDTH x HEIGHT.
        let mut lie = s[..cut].replace("POINTS 50", "POINTS 49").into_bytes();
        lie.extend_from_slice(&good[cut..]);
        let name = format!("wh_{data}.pcd");
        expect_err(
            d.path(),
            &name,
            &lie,
            pcd::read_pcd,
            &["POINTS", "WIDTH x HEIGHT = 50"],
        );
    }
    let good = pcd::encode_pcd(&c, "binary");
    expect_err(
        d.path(),
        "cut.pcd",
        &good[..good.len() - 1],
        pcd::read_pcd,
        &["POINTS", "truncated"],
    );
    // Corrupt LZF stream: a back-reference before the start of the output.
    let good = pcd::encode_pcd(&c, "binary_compressed");
    let s = String::from_utf8_lossy(&good).into_owned();
    let body = s.find("DATA binary_compressed\n").unwrap() + "DATA binary_compressed\n".len();
    let mut bad = good.clone();
    bad[body + 8] = 0xE0; // first control byte: long back-reference with nothing decoded yet
    expect_err(d.path(), "lzf.pcd", &bad, pcd::read_pcd, &["LZF"]);
    expect_err(
        d.path(),
        "sizes.pcd",
        &good[..body + 4],
        pcd::read_pcd,
        &["sizes"],
    );
    let text = b"VERSION 0.7\nFIELDS x y\nSIZE 4 4\nTYPE F F\nCOUNT 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2\n";
    expect_err(d.path(), "noz.pcd", text, pcd::read_pcd, &["x, y and z"]);
    let text = b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4\nTYPE F F F\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2 3\n";
    expect_err(
        d.path(),
        "sizes2.pcd",
        text,
        pcd::read_pcd,
        &["FIELDS/SIZE/TYPE/COUNT"],
    );
    let text = b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 inf 3\n";
    expect_err(
        d.path(),
        "inf.pcd",
        text,
        pcd::read_pcd,
        // rows with a non-finite coordinate are dropped (organised clouds); none left is an error
        &["at least one point", "finite"],
    );
    expect_err(
        d.path(),
        "nodata.pcd",
        b"VERSION 0.7\nFIELDS x y z\n",
        pcd::read_pcd,
        &["DATA"],
    );
}

/// Replace the first `from` in `b` by `to` (same length), byte-wise.
fn replace(b: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
    let at = b.windows(from.len()).position(|w| w == from).unwrap();
    let mut out = b.to_vec();
    out[at..at + to.len()].copy_from_slice(to);
    out
}

#[test]
fn npy_and_npz() {
    let d = tempfile::tempdir().unwrap();
    let good = npy::encode_npy_f32(&[10, 3], &[0.5; 30]);
    expect_err(
        d.path(),
        "cut.npy",
        &good[..good.len() - 4],
        npy::read_npy,
        &["truncated"],
    );
    expect_err(
        d.path(),
        "magic.npy",
        b"NUMPY\x01\x00",
        npy::read_npy,
        &["magic"],
    );
    let mut bad = good.clone();
    bad[6] = 9;
    expect_err(d.path(), "ver.npy", &bad, npy::read_npy, &["version"]);
    let s = replace(&good, b"'<f4'", b"'<i4'");
    expect_err(
        d.path(),
        "int.npy",
        &s,
        npy::read_npy,
        &["dtype", "float32 or float64"],
    );
    let s = replace(&good, b"'shape'", b"'shope'");
    expect_err(d.path(), "dict.npy", &s, npy::read_npy, &["header"]);
    let four = npy::encode_npy_f32(&[10, 4], &[0.5; 40]);
    expect_err(
        d.path(),
        "shape.npy",
        &four,
        npy::read_npy_points,
        &["(N, 3)", "(10, 4)"],
    );
    expect_err(d.path(), "m.npy", &good, npy::read_npy_matrix4, &["(4, 4)"]);
    let mut m = vec![0f32; 16];
    m[0] = 2.0; // scale, not a rotation
    m[5] = 1.0;
    m[10] = 1.0;
    m[15] = 1.0;
    expect_err(
        d.path(),
        "scale.npy",
        &npy::encode_npy_f32(&[4, 4], &m),
        npy::read_npy_matrix4,
        &["rigid"],
    );
    let empty = npy::encode_npy_f32(&[0, 3], &[]);
    expect_err(
        d.path(),
        "empty.npy",
        &empty,
        npy::read_npy_points,
        &["empty"],
    );
    expect_err(
        d.path(),
        "zip.npz",
        b"PK\x03\x04 not a zip",
        npy::read_npz,
        &["zip"],
    );
}

#[test]
fn pickle_and_pth() {
    let d = tempfile::tempdir().unwrap();
    // A global outside the NumPy whitelist is refused, never executed.
    let evil = b"\x80\x02cbuiltins\neval\nq\x00X\x04\x00\x00\x001+1q\x01\x85q\x02Rq\x03.";
    expect_err(
        d.path(),
        "evil.pkl",
        evil,
        pickle::read_pickle_arrays,
        &["builtins.eval"],
    );
    expect_err(
        d.path(),
        "evil.pth",
        evil,
        pickle::read_pth_array,
        &["builtins.eval"],
    );
    expect_err(
        d.path(),
        "cut.pkl",
        b"\x80\x02}q\x00(X\x05\x00",
        pickle::read_pickle_arrays,
        &["truncated"],
    );
    expect_err(
        d.path(),
        "list.pkl",
        b"\x80\x02]q\x00.",
        pickle::read_pickle_arrays,
        &["dict"],
    );
    expect_err(
        d.path(),
        "op.pkl",
        b"\x80\x02\xff.",
        pickle::read_pickle_arrays,
        &["opcode 0xff"],
    );
    expect_err(
        d.path(),
        "tensor.pth",
        b"\x80\x02X\x01\x00\x00\x00aQ.",
        pickle::read_pth_array,
        &["torch tensor"],
    );
    expect_err(
        d.path(),
        "proto.pkl",
        b"\x80\x09}.",
        pickle::read_pickle_arrays,
        &["protocol"],
    );
    expect_err(
        d.path(),
        "zip.pth",
        b"PK\x03\x04....",
        pickle::read_pth_array,
        &["zip"],
    );

    // Staged .pth files cut anywhere must fail cleanly.
    if let Some(root) = cgenreg::testing::test_data_root() {
        let real = std::fs::read(root.join("3dmatch-redkitchen/regtr/cloud_bin_0.pth")).unwrap();
        for cut in [10, 200, 400, real.len() / 2, real.len() - 3] {
            let name = format!("cut{cut}.pth");
            expect_err(
                d.path(),
                &name,
                &real[..cut],
                pickle::read_pth_array,
                &["pickle"],
            );
        }
    }
}

#[test]
fn kitti_xyz_and_dispatch() {
    let d = tempfile::tempdir().unwrap();
    expect_err(
        d.path(),
        "odd.bin",
        &[0u8; 33],
        kitti::read_kitti_bin,
        &["multiple of 16"],
    );
    expect_err(
        d.path(),
        "empty.bin",
        &[],
        kitti::read_kitti_bin,
        &["empty"],
    );
    let mut nan = vec![0u8; 32];
    nan[20..24].copy_from_slice(&f32::NAN.to_le_bytes());
    expect_err(
        d.path(),
        "nan.bin",
        &nan,
        kitti::read_kitti_bin,
        &["point 1"],
    );
    expect_err(
        d.path(),
        "cols.xyz",
        b"1 2 3\n4 5\n",
        xyz::read_xyz,
        &["line 2", "3 columns"],
    );
    expect_err(d.path(), "word.txt", b"x y z\n", xyz::read_xyz, &["line 1"]);
    expect_err(
        d.path(),
        "blank.pts",
        b"# only a comment\n",
        xyz::read_xyz,
        &["empty"],
    );
    expect_err(
        d.path(),
        "cloud.obj",
        b"v 1 2 3\n",
        cloud::load_cloud,
        &["extension", ".ply"],
    );
    // Dispatch reaches the right reader: a PLY named .pcd fails as a PCD.
    let ply_bytes = ply::encode_ply(&sample(3));
    expect_err(
        d.path(),
        "wrong.pcd",
        &ply_bytes,
        cloud::load_cloud,
        &["header line 1"],
    );
    let e = cloud::save_cloud(&d.path().join("out.e57"), &sample(3))
        .unwrap_err()
        .to_string();
    assert!(e.contains("out.e57") && e.contains("extension"), "{e}");
}

#[test]
fn learned_features() {
    use cgenreg::features::learned::load_learned_features;
    let d = tempfile::tempdir().unwrap();
    expect_err(
        d.path(),
        "f.npy",
        &npy::encode_npy_f32(&[1, 3], &[0.0; 3]),
        load_learned_features,
        &["extension"],
    );
    expect_err(
        d.path(),
        "f.npz",
        b"not a zip",
        load_learned_features,
        &["zip"],
    );
    expect_err(
        d.path(),
        "f.pkl",
        b"\x80\x02}q\x00.",
        load_learned_features,
        &["no float arrays"],
    );
}
