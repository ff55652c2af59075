//! Tests of `cache` (kept apart so the module stays readable).

use super::*;
use serde_json::json;

fn key(stage: &str, p: i64) -> CacheKey {
    CacheKey::new(
        stage,
        1,
        &["abc", "def"],
        &json!({"k": p, "t": 0.1, "mode": "noisy_and"}),
    )
    .unwrap()
}

/// Writers' private folders and trash left in a stage folder.
fn dot_entries(stage_dir: &Path) -> usize {
    std::fs::read_dir(stage_dir)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with('.'))
        .count()
}

fn put_sample(c: &Cache, k: &CacheKey) -> Entry {
    let mut e = c.put(k, json!({"backend": "test", "seed": 1})).unwrap();
    e.add_f32_matrix("m.npy", 2, 3, &[1.0, 2.0, 3.0, 4.0, 5.0, 6.5])
        .unwrap();
    e.add_json("info.json", &json!({"n": 2})).unwrap();
    let img = image::RgbImage::from_fn(5, 4, |x, y| image::Rgb([x as u8 * 40, y as u8 * 50, 7]));
    e.add_png("frames/000.png", &img).unwrap();
    e.commit().unwrap()
}

#[test]
fn key_is_canonical_and_sensitive() {
    let a = CacheKey::new("s", 1, &["x"], &json!({"a": 1, "b": [1, 2]})).unwrap();
    let b = CacheKey::new("s", 1, &["x"], &json!({"b": [1, 2], "a": 1})).unwrap();
    assert_eq!(a.hash, b.hash);
    assert_eq!(a.hash.len(), 64);
    for other in [
        CacheKey::new("s", 2, &["x"], &json!({"a": 1, "b": [1, 2]})).unwrap(),
        CacheKey::new("t", 1, &["x"], &json!({"a": 1, "b": [1, 2]})).unwrap(),
        CacheKey::new("s", 1, &["y"], &json!({"a": 1, "b": [1, 2]})).unwrap(),
        CacheKey::new("s", 1, &["x"], &json!({"a": 1, "b": [2, 1]})).unwrap(),
        CacheKey::new("s", 1, &["x"], &json!({"a": 1.0, "b": [1, 2]})).unwrap(),
    ] {
        assert_ne!(a.hash, other.hash);
    }
    assert!(CacheKey::new("../x", 1, &[], &json!({})).is_err());
}

#[test]
fn roundtrip_and_listing() {
    let dir = tempfile::tempdir().unwrap();
    let c = Cache::open(dir.path()).unwrap();
    let k = key("vfm", 4);
    assert!(c.get(&k).unwrap().is_none());
    put_sample(&c, &k);
    let e = c.get(&k).unwrap().unwrap();
    assert_eq!(
        e.read_f32_matrix("m.npy").unwrap(),
        (2, 3, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.5])
    );
    assert_eq!(e.read_json::<Value>("info.json").unwrap(), json!({"n": 2}));
    let img = e.read_png("frames/000.png").unwrap();
    assert_eq!(img.get_pixel(3, 2).0, [120, 100, 7]);
    assert_eq!(e.provenance()["backend"], "test");
    assert_eq!(e.manifest.params["k"], 4);
    assert!(e.read_bytes("nope").is_err());
    let f = e.read_features("m.npy").unwrap();
    assert_eq!((f.len(), f.dim), (2, 3));

    put_sample(&c, &key("vfm", 5));
    put_sample(&c, &key("lift", 1));
    let l = c.list().unwrap();
    assert_eq!(l.len(), 3);
    assert!(l.iter().all(|s| s.problem.is_none() && s.total_bytes > 0));
    assert!(c.verify_all().unwrap().iter().all(|r| r.result.is_ok()));
    assert!(c.remove(&k).unwrap());
    assert!(!c.remove(&k).unwrap());
    assert!(c.get(&k).unwrap().is_none());
    assert_eq!(c.remove_stage("vfm").unwrap(), 1);
    let l = c.list().unwrap();
    assert_eq!(l.len(), 1);
    assert!(c.remove_entry("lift", &l[0].hash[..10]).unwrap());
    assert!(c.list().unwrap().is_empty());
}

#[test]
fn corrupted_payload_is_detected() {
    let dir = tempfile::tempdir().unwrap();
    let c = Cache::open(dir.path()).unwrap();
    let k = key("vfm", 4);
    let e = put_sample(&c, &k);
    let p = e.path("m.npy");
    let mut b = std::fs::read(&p).unwrap();
    let last = b.len() - 1;
    b[last] ^= 0x01;
    std::fs::write(&p, &b).unwrap();
    let err = c.get(&k).unwrap_err().to_string();
    assert!(err.contains("corrupt") && err.contains("m.npy"), "{err}");
    let bad: Vec<_> = c
        .verify_all()
        .unwrap()
        .into_iter()
        .filter(|r| r.result.is_err())
        .collect();
    assert_eq!(bad.len(), 1);
    // truncated file: size mismatch
    std::fs::write(&p, &b[..10]).unwrap();
    assert!(c.get(&k).unwrap_err().to_string().contains("bytes"));
    // a fresh put replaces the corrupt entry
    put_sample(&c, &k);
    assert!(c.get(&k).unwrap().is_some());
}

#[test]
fn partial_entries_are_detected() {
    let dir = tempfile::tempdir().unwrap();
    let c = Cache::open(dir.path()).unwrap();
    let k = key("wfm", 1);
    let e = put_sample(&c, &k);
    std::fs::remove_file(e.path("frames/000.png")).unwrap();
    let err = c.get(&k).unwrap_err().to_string();
    assert!(
        err.contains("partial") && err.contains("frames/000.png"),
        "{err}"
    );

    let k2 = key("wfm", 2);
    let e2 = put_sample(&c, &k2);
    std::fs::remove_file(e2.path(MANIFEST)).unwrap();
    assert!(c.get(&k2).unwrap_err().to_string().contains("partial"));
    let l = c.list().unwrap();
    assert_eq!(l.iter().filter(|s| s.problem.is_some()).count(), 1);

    let k3 = key("wfm", 3);
    let e3 = put_sample(&c, &k3);
    std::fs::write(e3.path(MANIFEST), b"{\"format\": 1, \"stage\"").unwrap();
    assert!(c.get(&k3).unwrap_err().to_string().contains("corrupt"));

    // an uncommitted writer leaves nothing visible
    let k4 = key("wfm", 4);
    {
        let mut w = c.put(&k4, json!({})).unwrap();
        w.add_bytes("a.bin", b"abc").unwrap();
    }
    assert!(c.get(&k4).unwrap().is_none());
    assert_eq!(dot_entries(&dir.path().join("wfm")), 0);
}

#[test]
fn concurrent_put_of_the_same_key_is_safe() {
    let dir = tempfile::tempdir().unwrap();
    let c = Cache::open(dir.path()).unwrap();
    let k = key("vfm", 9);
    std::thread::scope(|s| {
        for _ in 0..8 {
            s.spawn(|| {
                for _ in 0..5 {
                    let e = put_sample(&c, &k);
                    assert_eq!(e.manifest.key, k.hash);
                    assert!(c.get(&k).unwrap().is_some());
                }
            });
        }
    });
    assert_eq!(c.list().unwrap().len(), 1);
    assert!(c.verify_all().unwrap().iter().all(|r| r.result.is_ok()));
    assert_eq!(dot_entries(&dir.path().join("vfm")), 0);
}

#[test]
fn npy_is_numpy_compatible_header() {
    let dir = tempfile::tempdir().unwrap();
    let c = Cache::open(dir.path()).unwrap();
    let e = put_sample(&c, &key("vfm", 9));
    let b = std::fs::read(e.path("m.npy")).unwrap();
    let hlen = u16::from_le_bytes([b[8], b[9]]) as usize;
    assert_eq!((10 + hlen) % 64, 0);
    assert_eq!(b[10 + hlen - 1], b'\n');
    assert_eq!(
        b,
        crate::io::npy::encode_npy_f32(&[2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.5])
    );
    let mut w = c.put(&key("vfm", 10), json!({})).unwrap();
    assert!(w.add_f32_matrix("m.npy", 3, 2, &[0.0; 5]).is_err());
}

/// The `.npy` payload of an entry as the cache's own encoder wrote it before the cache used
/// `io::npy` (NPY v1, `<f4`, C order, header padded with spaces to 64 bytes), spelled out
/// byte by byte: shape (2, 3), values 1, -2.5, 0, 3.25, 0.5, -0.125.
fn old_npy_2x3() -> Vec<u8> {
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend_from_slice(&[0x76, 0x00]); // header length 118: data starts at byte 128
    b.extend_from_slice(b"{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }");
    b.extend_from_slice(&[b' '; 58]);
    b.push(b'\n');
    b.extend_from_slice(&[
        0x00, 0x00, 0x80, 0x3f, 0x00, 0x00, 0x20, 0xc0, 0x00, 0x00, 0x00, 0x00, //
        0x00, 0x00, 0x50, 0x40, 0x00, 0x00, 0x00, 0x3f, 0x00, 0x00, 0x00, 0xbe,
    ]);
    assert_eq!(b.len(), 128 + 24);
    b
}

#[test]
fn an_entry_written_before_the_shared_codec_still_loads() {
    let dir = tempfile::tempdir().unwrap();
    let c = Cache::open(dir.path()).unwrap();
    let k = CacheKey::new(
        "geo-fpfh",
        1,
        &["cloud"],
        &json!({"voxel": 0.05, "points": 2}),
    )
    .unwrap();
    let npy = old_npy_2x3();
    // The entry folder and manifest exactly as an earlier build laid them out.
    let d = dir.path().join("geo-fpfh").join(&k.hash);
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(d.join("keypoints.npy"), &npy).unwrap();
    let manifest = format!(
        r#"{{
  "format": 1,
  "stage": "geo-fpfh",
  "version": 1,
  "key": "{hash}",
  "inputs": [
    "cloud"
  ],
  "params": {{
    "points": 2,
    "voxel": 0.05
  }},
  "provenance": {{
    "backend": "test"
  }},
  "created_unix": 1764000000,
  "files": [
    {{
      "name": "keypoints.npy",
      "size": {size},
      "blake3": "{b3}"
    }}
  ]
}}"#,
        hash = k.hash,
        size = npy.len(),
        b3 = hash_bytes(&npy)
    );
    std::fs::write(d.join(MANIFEST), manifest).unwrap();
    let e = c.get(&k).unwrap().expect("the old entry is found");
    let want = vec![1.0, -2.5, 0.0, 3.25, 0.5, -0.125];
    assert_eq!(
        e.read_f32_matrix("keypoints.npy").unwrap(),
        (2, 3, want.clone())
    );
    let f = e.read_features("keypoints.npy").unwrap();
    assert_eq!((f.len(), f.dim, f.data), (2, 3, want.clone()));
    assert!(c.verify_all().unwrap().iter().all(|r| r.result.is_ok()));
    // The shared encoder writes these very bytes, so new entries match old ones.
    assert_eq!(crate::io::npy::encode_npy_f32(&[2, 3], &want), npy);
}
