//! Linking geometric-branch points to image pixels (reference §4 and §7).
//!
//! Each selected view's sensor depth is back-projected with its intrinsics and moved into the
//! fragment's coordinates (`scan_from_camera`, i.e. `inv(first_pose) · pose`). As the reference:
//! - depth = raw / 1000, valid = raw > 0, then clipped to `max_depth` (5 m). 65535 is *not*
//!   treated as invalid here (the reference keeps it, so it becomes a point at `max_depth`);
//! - the 3-D point map is resized to the generated image size (e.g. 960×704) with OpenCV
//!   nearest-neighbour (`src = floor(dst · src_size / dst_size)`), so every pixel link is in
//!   generated-image coordinates;
//! - every geometric point takes the nearest valid pixel over all views if it lies within
//!   `radius` (inclusive), otherwise None (the reference's (−1, −1, −1)).
//!
//! Nearest resizing repeats each depth pixel over ~1.5×1.5 image pixels. The tree holds each
//! distinct depth pixel once, linked to the first (smallest row, then column) image pixel that
//! copies it; the reference leaves that tie to cKDTree's internals.

use crate::camera::DepthView;
use crate::error::{Error, Result};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Point3;
use rayon::prelude::*;

/// A pixel of the generated image of view `view` (column u, row v).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PixelLink {
    pub view: u16,
    pub u: u32,
    pub v: u32,
}

/// Pairs (dst, src) of the first destination index for each source index that OpenCV's
/// INTER_NEAREST resize from `src` to `dst` samples.
fn nearest_first(src: u32, dst: u32) -> Vec<(u32, u32)> {
    let mut out = Vec::new();
    let mut last = u32::MAX;
    for d in 0..dst {
        let s = ((d as u64 * src as u64) / dst as u64).min(src as u64 - 1) as u32;
        if s != last {
            out.push((d, s));
            last = s;
        }
    }
    out
}

/// Back-projected, nearest-resized valid pixels of all views: (point, link).
pub fn lifted_pixels(
    views: &[DepthView],
    image_size: (u32, u32),
    max_depth: f32,
) -> Result<Vec<([f32; 3], PixelLink)>> {
    if views.len() > u16::MAX as usize {
        return Err(Error::Invalid(format!(
            "{} views, at most 65535",
            views.len()
        )));
    }
    if image_size.0 == 0 || image_size.1 == 0 {
        return Err(Error::Param(format!("image size {image_size:?}")));
    }
    let per_view: Vec<Vec<([f32; 3], PixelLink)>> = views
        .par_iter()
        .enumerate()
        .map(|(vi, view)| {
            let d = view.depth;
            if d.width == 0 || d.height == 0 || d.data.len() != (d.width * d.height) as usize {
                return Err(Error::Shape(format!(
                    "view {vi}: depth image {}x{} with {} values",
                    d.width,
                    d.height,
                    d.data.len()
                )));
            }
            let cols = nearest_first(d.width, image_size.0);
            let rows = nearest_first(d.height, image_size.1);
            let cam = view.camera;
            let t = view.scan_from_camera;
            let mut out = Vec::with_capacity(cols.len() * rows.len());
            for &(dv, sv) in &rows {
                for &(du, su) in &cols {
                    let raw = d.data[(sv * d.width + su) as usize];
                    if raw == 0 {
                        continue;
                    }
                    let z = (raw as f32 / 1000.0).min(max_depth) as f64;
                    let Some(pc) = cam.backproject(su as f64, sv as f64, z) else {
                        continue;
                    };
                    let p = t * pc;
                    let p = [p.x as f32, p.y as f32, p.z as f32];
                    // The reference marks invalid pixels by p == 0 after the transform.
                    if p[0] * p[0] + p[1] * p[1] + p[2] * p[2] <= 1e-12 {
                        continue;
                    }
                    out.push((
                        p,
                        PixelLink {
                            view: vi as u16,
                            u: du,
                            v: dv,
                        },
                    ));
                }
            }
            Ok(out)
        })
        .collect::<Result<_>>()?;
    Ok(per_view.into_iter().flatten().collect())
}

/// For every geometric point, the nearest lifted pixel over all views within `radius` (m).
pub fn lift_views(
    views: &[DepthView],
    geo_points: &[Point3<f32>],
    radius: f32,
    image_size: (u32, u32),
    max_depth: f32,
) -> Result<Vec<Option<PixelLink>>> {
    let pixels = lifted_pixels(views, image_size, max_depth)?;
    if pixels.is_empty() || geo_points.is_empty() {
        return Ok(vec![None; geo_points.len()]);
    }
    if pixels.len() > u32::MAX as usize {
        return Err(Error::Invalid(format!("{} lifted pixels", pixels.len())));
    }
    let pts: Vec<[f32; 3]> = pixels.iter().map(|p| p.0).collect();
    let tree: ImmutableKdTree<f32, 3> = ImmutableKdTree::new_from_slice_parallel(&pts)
        .map_err(|e| Error::Invalid(format!("building the pixel k-d tree: {e:?}")))?;
    let r2 = radius * radius;
    Ok(geo_points
        .par_iter()
        .map(|q| {
            let n = tree
                .query(&[q.x, q.y, q.z])
                .nearest_one::<SquaredEuclidean<f32>>()
                .execute();
            (n.distance <= r2).then(|| pixels[n.item as usize].1)
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{CameraModel, Intrinsics};
    use crate::io::depth_png::DepthImage;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

    fn intr() -> Intrinsics {
        Intrinsics {
            fx: 585.0,
            fy: 585.0,
            cx: 320.0,
            cy: 240.0,
            width: 640,
            height: 480,
        }
    }

    /// A tilted plane with a bump, some holes and some 65535 pixels.
    fn depth(seed: u32) -> DepthImage {
        let (w, h) = (640u32, 480u32);
        let mut data = vec![0u16; (w * h) as usize];
        for v in 0..h {
            for u in 0..w {
                let i = (v * w + u) as usize;
                let hash = (u.wrapping_mul(73856093) ^ v.wrapping_mul(19349663) ^ seed) % 97;
                data[i] = if hash == 0 {
                    0
                } else if hash == 1 {
                    u16::MAX
                } else {
                    let bump = if (u as i32 - 300).pow(2) + (v as i32 - 200).pow(2) < 60 * 60 {
                        300
                    } else {
                        0
                    };
                    (1500 + u + v / 2 + seed * 10 - bump) as u16
                };
            }
        }
        DepthImage {
            width: w,
            height: h,
            data,
        }
    }

    fn pose(i: usize) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.1 * i as f64, -0.05 * i as f64, 0.02 * i as f64),
            UnitQuaternion::from_euler_angles(0.05 * i as f64, -0.1 * i as f64, 0.03),
        )
    }

    #[test]
    fn nearest_first_matches_cv2_rule() {
        // 640 -> 960: dst 0,1 -> src 0; dst 2 -> src 1; first dst for src s is ceil(s*1.5)
        let m = nearest_first(640, 960);
        assert_eq!(m.len(), 640);
        for &(d, s) in &m {
            assert_eq!(s, d * 640 / 960);
            assert_eq!(d, (s * 960).div_ceil(640));
        }
        // downsampling skips source pixels
        let m = nearest_first(10, 4);
        assert_eq!(m, vec![(0, 0), (1, 2), (2, 5), (3, 7)]);
    }

    #[test]
    fn lift_matches_brute_force() {
        let depths: Vec<DepthImage> = (0..4).map(depth).collect();
        let cam = CameraModel::Pinhole(intr());
        let views: Vec<DepthView> = depths
            .iter()
            .enumerate()
            .map(|(i, d)| DepthView {
                depth: d,
                scan_from_camera: pose(i),
                camera: &cam,
            })
            .collect();
        let pixels = lifted_pixels(&views, (960, 704), 5.0).unwrap();
        // query points: near lifted pixels (jittered), plus far ones
        let mut geo = Vec::new();
        for (i, (p, _)) in pixels.iter().enumerate().step_by(4999) {
            let j = (i % 13) as f32 * 0.006 - 0.036;
            geo.push(Point3::new(p[0] + j, p[1] - 0.5 * j, p[2] + 0.3 * j));
        }
        geo.push(Point3::new(100.0, 0.0, 0.0));
        geo.push(Point3::new(0.0, 0.0, -3.0));
        let got = lift_views(&views, &geo, 0.05, (960, 704), 5.0).unwrap();
        let mut mapped = 0;
        for (q, g) in geo.iter().zip(&got) {
            let (best, bd) = pixels
                .iter()
                .map(|(p, l)| {
                    let d = (p[0] - q.x).powi(2) + (p[1] - q.y).powi(2) + (p[2] - q.z).powi(2);
                    (l, d)
                })
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            match g {
                None => assert!(bd > 0.05 * 0.05, "missed a pixel at {}", bd.sqrt()),
                Some(l) => {
                    mapped += 1;
                    let p = pixels.iter().find(|(_, ll)| ll == l).unwrap().0;
                    let d = (p[0] - q.x).powi(2) + (p[1] - q.y).powi(2) + (p[2] - q.z).powi(2);
                    assert!((d - bd).abs() < 1e-6, "not nearest: {d} vs {bd} ({best:?})");
                    assert!(d <= 0.05 * 0.05);
                }
            }
        }
        assert!(mapped > geo.len() / 2, "{mapped} of {}", geo.len());
        assert!(got[got.len() - 1].is_none() && got[got.len() - 2].is_none());
    }

    #[test]
    fn synthetic_scene_links_points_to_their_pixels() {
        // Camera at the origin of the fragment, looking at a fronto-parallel wall at 2 m.
        let k = CameraModel::Pinhole(intr());
        let d = DepthImage {
            width: 640,
            height: 480,
            data: vec![2000; 640 * 480],
        };
        let second = Isometry3::from_parts(
            Translation3::new(0.0, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI),
        );
        let views = [
            DepthView {
                depth: &d,
                scan_from_camera: Isometry3::identity(),
                camera: &k,
            },
            // looks the other way: its wall is at z = -2 in the fragment
            DepthView {
                depth: &d,
                scan_from_camera: second,
                camera: &k,
            },
        ];
        // exact back-projection of depth pixel (su, sv) of view 0
        let on_pixel = |su: f64, sv: f64| {
            Point3::new(
                ((su - 320.0) * 2.0 / 585.0) as f32,
                ((sv - 240.0) * 2.0 / 585.0) as f32,
                2.0,
            )
        };
        let geo = vec![
            on_pixel(100.0, 50.0),
            on_pixel(401.0, 333.0) + Vector3::new(0.0, 0.0, 0.03),
            Point3::new(0.0, 0.0, -2.0), // the second view's wall, centre pixel
            Point3::new(0.0, 0.0, 2.2),  // 20 cm in front of the wall: unmapped
            Point3::new(0.0, 0.0, 0.0),
        ];
        let got = lift_views(&views, &geo, 0.05, (960, 704), 5.0).unwrap();
        // depth (100, 50) -> first image pixel with floor(u*640/960) = 100: u = 150; rows 480->704
        assert_eq!(
            got[0],
            Some(PixelLink {
                view: 0,
                u: 150,
                v: (50u32 * 704).div_ceil(480)
            })
        );
        assert_eq!(
            got[1],
            Some(PixelLink {
                view: 0,
                u: (401u32 * 960).div_ceil(640),
                v: (333u32 * 704).div_ceil(480)
            })
        );
        let l = got[2].unwrap();
        assert_eq!(l.view, 1);
        // pixel (320, 240) of view 1 maps to x=0: nearest-resize first copies are u=480, v=352
        assert_eq!((l.u, l.v), (480, 352));
        assert_eq!(got[3], None);
        assert_eq!(got[4], None);
    }

    #[test]
    fn depth_is_clipped_and_zero_is_invalid() {
        let k = CameraModel::Pinhole(intr());
        let mut data = vec![0u16; 640 * 480];
        data[240 * 640 + 320] = 9000; // 9 m -> clipped to 5 m
        data[240 * 640 + 321] = u16::MAX; // kept, clipped to 5 m (reference behaviour)
        let d = DepthImage {
            width: 640,
            height: 480,
            data,
        };
        let v = [DepthView {
            depth: &d,
            scan_from_camera: Isometry3::identity(),
            camera: &k,
        }];
        let px = lifted_pixels(&v, (640, 480), 5.0).unwrap();
        assert_eq!(px.len(), 2);
        assert!(px.iter().all(|(p, _)| (p[2] - 5.0).abs() < 1e-6));
        assert_eq!(lift_views(&v, &[], 0.05, (640, 480), 5.0).unwrap(), vec![]);
        let empty = DepthImage {
            width: 640,
            height: 480,
            data: vec![0; 640 * 480],
        };
        let v = [DepthView {
            depth: &empty,
            scan_from_camera: Isometry3::identity(),
            camera: &k,
        }];
        assert_eq!(
            lift_views(&v, &[Point3::origin()], 0.05, (960, 704), 5.0).unwrap(),
            vec![None]
        );
    }

    #[test]
    fn ftheta_range_lifts_along_the_ray() {
        use crate::camera::ftheta::{lidar_front_camera_from_scan, FThetaCamera};
        // A LiDAR-like scan: points on a cylinder of radius 6 m around the sensor (x forward,
        // z up), rendered into the f-theta camera and lifted back.
        let mut pts = Vec::new();
        for a in 0..720 {
            let yaw = (a as f64 / 720.0 - 0.5) * std::f64::consts::PI * 1.6;
            for h in 0..60 {
                let z = -1.5 + 3.0 * h as f64 / 60.0;
                pts.push(Point3::new(
                    (6.0 * yaw.cos()) as f32,
                    (6.0 * yaw.sin()) as f32,
                    z as f32,
                ));
            }
        }
        let cam = CameraModel::FTheta(FThetaCamera::equidistant(320, 160, 180.0));
        let camera_from_scan = lidar_front_camera_from_scan(0.0);
        let d = cam.render_depth(&pts, &camera_from_scan);
        let views = [DepthView {
            depth: &d,
            scan_from_camera: camera_from_scan.inverse(),
            camera: &cam,
        }];
        let px = lifted_pixels(&views, (320, 160), 65.0).unwrap();
        assert!(px.len() > 3000, "{} pixels", px.len());
        // Every lifted pixel lies on the cylinder (range stored along the ray, not z).
        for (p, _) in &px {
            let r = (p[0] * p[0] + p[1] * p[1]).sqrt();
            assert!((r - 6.0).abs() < 0.08, "radius {r} at {p:?}");
            assert!(p[2].abs() < 1.6, "height {}", p[2]);
        }
        // Points beside the sensor (90 degrees off the axis) are lifted too: wide field of view.
        assert!(px.iter().any(|(p, _)| p[0].abs() < 1.0 && p[1] > 5.0));
        let got = lift_views(&views, &pts, 0.05, (320, 160), 65.0).unwrap();
        // In front (within 80 degrees of the axis) nearly all points get a pixel; behind, none.
        let front: Vec<bool> = pts
            .iter()
            .map(|p| p.y.atan2(p.x).abs() < 80f32.to_radians())
            .collect();
        let linked = |f: bool| {
            got.iter()
                .zip(&front)
                .filter(|(l, &ff)| ff == f && l.is_some())
                .count()
        };
        let n_front = front.iter().filter(|&&f| f).count();
        assert!(
            linked(true) * 10 > n_front * 9,
            "{} of {n_front}",
            linked(true)
        );
        let behind: Vec<bool> = pts.iter().map(|p| p.x < -0.5).collect();
        assert!(got.iter().zip(&behind).all(|(l, &b)| !b || l.is_none()));
    }
}
