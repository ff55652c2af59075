//! A deterministic synthetic indoor demo the project makes itself (no third-party data).
//!
//! A room with furniture-like boxes, cylinders and a sphere, each with its own procedural
//! texture ([`scene`]), is ray-cast with exact pinhole intrinsics along a smooth camera path
//! into two overlapping RGB-D sequences, `target/` and `source/`, in the 7-Scenes raw layout
//! (`camera-intrinsics.txt`, `frame-XXXXXX.{color.png,depth.png,pose.txt}`; depth 16-bit mm
//! along z, 0 = invalid; pose camera-to-world, p_world = P * p_camera; OpenCV camera axes).
//! Both sequences share one world frame. A manifest `demo.toml` names fragment "0" (all
//! target frames) and "1" (all source frames) and the pair `synth-room/0-1` whose exact GT is
//! `target_from_source = inv(P_target[0]) * P_source[0]`.
//!
//! Everything is a pure function of [`DemoParams`]: the same parameters give the same bytes.
//! Optional sensor-like realism: depth noise growing with z^2, a few dropped pixels, and
//! dropouts at grazing angles, all from a hash of (seed, sequence, frame, pixel).

pub mod scene;

use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use crate::io::depth_png::{write_depth_png, DepthImage};
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rayon::prelude::*;
use scene::{hash64, unit, Scene};
use std::path::{Path, PathBuf};

#[derive(Clone, Debug, PartialEq)]
pub struct DemoParams {
    /// Image size; intrinsics are the 7-Scenes ones (640x480, fx = fy = 585, cx = 320,
    /// cy = 240) scaled by width / 640.
    pub width: u32,
    pub height: u32,
    /// Frames in each of the two sequences.
    pub frames: usize,
    /// Depth noise, dropped pixels and grazing-angle dropouts.
    pub sensor_noise: bool,
    pub seed: u64,
}

impl Default for DemoParams {
    fn default() -> Self {
        DemoParams {
            width: 640,
            height: 480,
            frames: 8,
            sensor_noise: true,
            seed: 1,
        }
    }
}

impl DemoParams {
    pub fn intrinsics(&self) -> Intrinsics {
        let s = self.width as f64 / 640.0;
        Intrinsics {
            fx: 585.0 * s,
            fy: 585.0 * s,
            cx: 320.0 * s,
            cy: 240.0 * s,
            width: self.width,
            height: self.height,
        }
    }
}

/// Camera-to-world pose along the demo path at parameter `t` in [0, 1]: the camera moves on
/// an ellipse around the room centre at about 1.5 m height (from the west side to the south
/// side as t goes 0 -> 1), looking across the room and slightly down, like a hand-held scan.
/// The target sequence covers t in [0, 0.45], the source t in [0.3, 0.75].
pub fn camera_path(t: f64) -> Isometry3<f64> {
    let phi = (200.0 + 120.0 * t).to_radians();
    let (c, s) = (phi.cos(), phi.sin());
    let centre = Vector3::new(2.5, 2.0, 0.0);
    let eye = centre
        + Vector3::new(
            1.8 * c,
            1.3 * s,
            1.5 + 0.1 * (std::f64::consts::PI * 2.0 * t).sin(),
        );
    let look = centre + Vector3::new(-0.7 * c + 0.3 * (5.0 * t).sin(), -0.7 * s, 0.7);
    let fwd = (look - eye).normalize();
    let right = fwd.cross(&Vector3::z()).normalize();
    let down = fwd.cross(&right);
    // Columns: camera x (right), y (down), z (forward) in world coordinates.
    let r = Matrix3::from_columns(&[right, down, fwd]);
    Isometry3::from_parts(
        Translation3::from(eye),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
    )
}

/// Path parameter of frame `i` of sequence `seq` (0 = target, 1 = source).
pub fn frame_param(seq: usize, i: usize, frames: usize) -> f64 {
    let start = if seq == 0 { 0.0 } else { 0.3 };
    start + 0.45 * i as f64 / (frames.max(2) - 1) as f64
}

/// Render one RGB-D frame: z-depth in millimetres (0 = invalid) and 8-bit RGB.
pub fn render_frame(
    scene: &Scene,
    k: &Intrinsics,
    world_from_camera: &Isometry3<f64>,
    noise: Option<u64>,
) -> (DepthImage, Vec<u8>) {
    let (w, h) = (k.width as usize, k.height as usize);
    let o = Point3::from(world_from_camera.translation.vector);
    let rot = world_from_camera.rotation;
    let rows: Vec<(Vec<u16>, Vec<u8>)> = (0..h)
        .into_par_iter()
        .map(|v| {
            let mut depth = vec![0u16; w];
            let mut rgb = vec![0u8; 3 * w];
            for u in 0..w {
                // Camera ray with z = 1, so the hit parameter is the z-depth itself.
                let dc = Vector3::new((u as f64 - k.cx) / k.fx, (v as f64 - k.cy) / k.fy, 1.0);
                let d = rot * dc;
                let Some(hit) = scene.cast(&o, &d) else {
                    continue;
                };
                let p = o + d * hit.t;
                let c = scene.shade(&p, &hit);
                for ch in 0..3 {
                    rgb[3 * u + ch] = (c[ch] * 255.0).round() as u8;
                }
                let mut z = hit.t;
                if let Some(seed) = noise {
                    let pix = hash64(seed ^ ((v * w + u) as u64).wrapping_mul(0x2545F4914F6CDD1D));
                    let cos = (hit.normal.dot(&d) / d.norm()).abs();
                    if unit(pix) < 0.003 || cos < 0.12 {
                        continue;
                    }
                    // Approximately Gaussian (sum of 4 uniforms), sigma = 0.5 mm * z^2.
                    let g: f64 =
                        (1..=4).map(|s| unit(hash64(pix ^ s)) - 0.5).sum::<f64>() * 3f64.sqrt();
                    z += g * 0.0005 * z * z;
                }
                let mm = (z * 1000.0).round();
                if (1.0..65535.0).contains(&mm) {
                    depth[u] = mm as u16;
                }
            }
            (depth, rgb)
        })
        .collect();
    let mut data = Vec::with_capacity(w * h);
    let mut rgb = Vec::with_capacity(3 * w * h);
    for (d, c) in rows {
        data.extend_from_slice(&d);
        rgb.extend_from_slice(&c);
    }
    (
        DepthImage {
            width: k.width,
            height: k.height,
            data,
        },
        rgb,
    )
}

fn write_color_png(path: &Path, w: u32, h: u32, rgb: Vec<u8>) -> Result<()> {
    let img = image::RgbImage::from_raw(w, h, rgb).ok_or_else(|| {
        Error::Shape(format!("colour image size mismatch for {}", path.display()))
    })?;
    let mut out = Vec::new();
    image::DynamicImage::ImageRgb8(img)
        .write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
        .map_err(|e| Error::External {
            what: format!("png encoder for {}", path.display()),
            message: e.to_string(),
        })?;
    crate::io::output::write_atomic(path, &out)
}

/// Render the demo into `dir` (`target/`, `source/`, `demo.toml`) and return the manifest path.
pub fn write_demo(dir: &Path, params: &DemoParams) -> Result<PathBuf> {
    if params.width < 16 || params.height < 16 || params.width > 4096 || params.height > 4096 {
        return Err(Error::Param(format!(
            "demo image size {}x{}: expected 16..4096 pixels per side",
            params.width, params.height
        )));
    }
    if params.frames < 2 {
        return Err(Error::Param(format!(
            "demo needs at least 2 frames per sequence, got {}",
            params.frames
        )));
    }
    let scene = Scene::demo_room();
    let k = params.intrinsics();
    let kfile = format!("{:?} 0 {:?}\n0 {:?} {:?}\n0 0 1\n", k.fx, k.cx, k.fy, k.cy);
    let names = ["target", "source"];
    for (s, name) in names.iter().enumerate() {
        let sd = dir.join(name);
        std::fs::create_dir_all(&sd).map_err(|e| Error::io(&sd, e))?;
        crate::io::output::write_atomic(&sd.join("camera-intrinsics.txt"), kfile.as_bytes())?;
        // Frames in sequence; each render is parallel over rows.
        for i in 0..params.frames {
            let pose = camera_path(frame_param(s, i, params.frames));
            let noise = params
                .sensor_noise
                .then(|| hash64(params.seed ^ hash64((s as u64) << 32 | i as u64)));
            let (depth, rgb) = render_frame(&scene, &k, &pose, noise);
            let stem = sd.join(format!("frame-{i:06}"));
            write_depth_png(&stem.with_extension("depth.png"), &depth)?;
            write_color_png(&stem.with_extension("color.png"), k.width, k.height, rgb)?;
            crate::camera::camera_txt::write_pose(&stem.with_extension("pose.txt"), &pose)?;
        }
    }
    let gt = camera_path(frame_param(0, 0, params.frames)).inverse()
        * camera_path(frame_param(1, 0, params.frames));
    let manifest = format!(
        r#"# Synthetic demo room rendered by cgenreg::synth::write_demo ({w}x{h}, {n} frames per sequence,
# sensor noise: {noise}). Fragment 0 = all target frames, fragment 1 = all source frames, each in
# the camera frame of its first frame. GT is exact: target_from_source = inv(P_target0) P_source0.
name = "synth-room"
root = "."

[fragment_options]
voxel = 0.01
max_depth = 10.0
crop = "none"
color = true

[[fragments]]
id = "0"
sequence = "target"
first = 0
count = {n}

[[fragments]]
id = "1"
sequence = "source"
first = 0
count = {n}

[[pairs]]
target = "0"
source = "1"
split = "synthetic"
gt_matrix = {gt}
"#,
        w = params.width,
        h = params.height,
        n = params.frames,
        noise = params.sensor_noise,
        gt = crate::dataset::manifest::gt_matrix_toml(&gt),
    );
    let path = dir.join("demo.toml");
    crate::io::output::write_atomic(&path, manifest.as_bytes())?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::Dataset;

    fn small() -> DemoParams {
        DemoParams {
            width: 160,
            height: 120,
            frames: 4,
            ..Default::default()
        }
    }

    fn files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
        let mut out = Vec::new();
        for sub in ["", "target", "source"] {
            let d = dir.join(sub);
            let mut names: Vec<_> = std::fs::read_dir(&d)
                .unwrap()
                .map(|e| e.unwrap().path())
                .filter(|p| p.is_file())
                .collect();
            names.sort();
            for p in names {
                let rel = p.strip_prefix(dir).unwrap().to_path_buf();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
        out
    }

    #[test]
    fn rendering_is_deterministic() {
        let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
        write_demo(a.path(), &small()).unwrap();
        write_demo(b.path(), &small()).unwrap();
        let (fa, fb) = (files(a.path()), files(b.path()));
        assert_eq!(fa.len(), 1 + 2 * (1 + 3 * 4));
        assert!(fa == fb, "two renders differ");
        // A different seed changes the noisy depth but not the colours.
        let c = tempfile::tempdir().unwrap();
        write_demo(c.path(), &DemoParams { seed: 2, ..small() }).unwrap();
        let fc = files(c.path());
        let differs = |ext: &str| {
            fa.iter()
                .zip(&fc)
                .any(|((p, x), (_, y))| p.to_string_lossy().ends_with(ext) && x != y)
        };
        assert!(differs("depth.png") && !differs("color.png"));
    }

    #[test]
    fn bundled_demo_is_current() {
        let bundled = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/demo");
        let fresh = tempfile::tempdir().unwrap();
        write_demo(fresh.path(), &DemoParams::default()).unwrap();
        for (rel, bytes) in files(fresh.path()) {
            let b = std::fs::read(bundled.join(&rel)).unwrap();
            assert!(
                b == bytes,
                "assets/demo/{} differs from a fresh render",
                rel.display()
            );
        }
    }

    #[test]
    fn depth_and_pose_conventions_are_exact() {
        // Without noise, every floor-tile pixel back-projects onto the plane z = 0.01 (world).
        let p = DemoParams {
            sensor_noise: false,
            ..small()
        };
        let k = p.intrinsics();
        let scene = Scene::demo_room();
        let pose = camera_path(0.1);
        let (depth, _) = render_frame(&scene, &k, &pose, None);
        let mut on_floor = 0;
        for v in 0..k.height {
            for u in 0..k.width {
                let z = depth.meters(u, v).unwrap() as f64;
                let pw = pose * k.backproject(u as f64, v as f64, z);
                // Which object does the exact ray hit?
                let d = pose.rotation
                    * Vector3::new((u as f64 - k.cx) / k.fx, (v as f64 - k.cy) / k.fy, 1.0);
                let hit = scene
                    .cast(&Point3::from(pose.translation.vector), &d)
                    .unwrap();
                if hit.object == 1 && hit.normal.z > 0.5 {
                    // Depth is rounded to 1 mm along z: at most ~0.5 mm * |dz/dz| off the plane.
                    assert!((pw.z - 0.01).abs() < 2e-3, "({u},{v}) z_world {}", pw.z);
                    on_floor += 1;
                }
            }
        }
        assert!(on_floor > 1000, "{on_floor}");
    }

    #[test]
    fn fragments_align_under_exact_gt() {
        // The bundled demo (equal to a fresh render, see bundled_demo_is_current).
        let m = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/demo/demo.toml");
        let ds = Dataset::load(&m).unwrap();
        let pair = ds.load_pair("synth-room/0-1").unwrap();
        assert!(pair.source.cloud.colors.is_some());
        assert_eq!(pair.source.frames.as_ref().unwrap().frames.len(), 8);
        let gt = pair.gt_target_from_source.unwrap();
        let tgt: Vec<[f32; 3]> = pair
            .target
            .cloud
            .points
            .iter()
            .map(|p| [p.x, p.y, p.z])
            .collect();
        let tree = kiddo::ImmutableKdTree::new_from_slice(&tgt).unwrap();
        let frac = |t: &Isometry3<f64>, r: f32| {
            let tf: Isometry3<f32> = t.cast();
            let hits = pair
                .source
                .cloud
                .points
                .par_iter()
                .filter(|p| {
                    let q = tf * *p;
                    tree.query(&[q.x, q.y, q.z])
                        .nearest_one::<kiddo::SquaredEuclidean<f32>>()
                        .execute()
                        .distance
                        <= r * r
                })
                .count();
            hits as f64 / pair.source.cloud.len() as f64
        };
        let (near, overlap) = (frac(&gt, 0.01), frac(&gt, 0.05));
        let off = Isometry3::from_parts(
            Translation3::new(0.015, 0.015, 0.015),
            UnitQuaternion::identity(),
        ) * gt;
        let near_off = frac(&off, 0.01);
        eprintln!(
            "demo pair: within 1 cm {near:.3}, within 5 cm {overlap:.3}, 2.6 cm off {near_off:.3}"
        );
        // The overlapping part aligns to 1 cm, and a 2.6 cm error is clearly visible.
        assert!(overlap > 0.4 && near / overlap > 0.9, "{near} / {overlap}");
        assert!(near_off < 0.5 * near, "{near_off} vs {near}");
    }
}
