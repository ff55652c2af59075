//! A virtual pinhole camera path for inputs that are only point clouds: the depth video the
//! WFM needs is rendered along it (see [`super::render`]).
//!
//! The path is an arc around the cloud's centre: the camera stays `distance` from the centre
//! (chosen so the cloud's 90th-percentile radius fills the narrower half field of view), looks
//! at the centre, is raised by `elevation_deg` towards `up`, and sweeps `sweep_deg` about the
//! `up` axis, centred on the direction `forward` (the camera looks along `forward` at the
//! middle frame). Defaults follow the RGB-D convention of 3DMatch-style fragments, whose
//! coordinates are those of the first camera: looking along +z with -y up. Poses are returned
//! as `scan_from_camera` (p_scan = T * p_camera), the convention of `RgbdFrame`; render with
//! its inverse.

use super::render::look_at;
use super::Intrinsics;
use crate::error::{Error, Result};
use crate::geometry::PointCloud;
use nalgebra::{Isometry3, Point3, Rotation3, Unit, Vector3};

#[derive(Clone, Debug, PartialEq)]
pub struct TrajectoryOptions {
    /// The virtual camera (its field of view sets the distance).
    pub intrinsics: Intrinsics,
    /// Up direction in scan coordinates.
    pub up: Vector3<f64>,
    /// Viewing direction at the middle of the path.
    pub forward: Vector3<f64>,
    /// Total sweep about `up`, degrees.
    pub sweep_deg: f64,
    /// Elevation of the camera above the centre's horizontal plane, degrees.
    pub elevation_deg: f64,
    /// Multiplies the automatic distance (1.0: the cloud just fills the view).
    pub distance_scale: f64,
}

impl Default for TrajectoryOptions {
    fn default() -> Self {
        TrajectoryOptions {
            intrinsics: Intrinsics {
                fx: 585.0,
                fy: 585.0,
                cx: 319.5,
                cy: 239.5,
                width: 640,
                height: 480,
            },
            up: Vector3::new(0.0, -1.0, 0.0),
            forward: Vector3::new(0.0, 0.0, 1.0),
            sweep_deg: 30.0,
            elevation_deg: 15.0,
            distance_scale: 1.0,
        }
    }
}

/// Robust centre (per-axis median) and radius (90th percentile of distances to it).
fn centre_and_radius(points: &[Point3<f32>]) -> Option<(Point3<f64>, f64)> {
    let pts: Vec<Point3<f64>> = points
        .iter()
        .filter(|p| p.coords.iter().all(|c| c.is_finite()))
        .map(|p| p.cast())
        .collect();
    if pts.is_empty() {
        return None;
    }
    let median = |k: usize| {
        let mut v: Vec<f64> = pts.iter().map(|p| p[k]).collect();
        let m = v.len() / 2;
        v.select_nth_unstable_by(m, |a, b| a.total_cmp(b));
        v[m]
    };
    let c = Point3::new(median(0), median(1), median(2));
    let mut d: Vec<f64> = pts.iter().map(|p| (p - c).norm()).collect();
    let i = (d.len() * 9 / 10).min(d.len() - 1);
    d.select_nth_unstable_by(i, |a, b| a.total_cmp(b));
    Some((c, d[i]))
}

/// `n_frames` camera poses (`scan_from_camera`) along a smooth arc looking at the cloud.
pub fn virtual_trajectory(
    cloud: &PointCloud,
    n_frames: usize,
    opts: &TrajectoryOptions,
) -> Result<Vec<Isometry3<f64>>> {
    if n_frames == 0 {
        return Err(Error::Param(
            "virtual trajectory: n_frames must be at least 1".into(),
        ));
    }
    let (c, radius) = centre_and_radius(&cloud.points).ok_or_else(|| {
        Error::Invalid("virtual trajectory: the cloud has no finite points".into())
    })?;
    let up = Unit::try_new(opts.up, 1e-12)
        .ok_or_else(|| Error::Param("virtual trajectory: `up` is the zero vector".into()))?;
    let f0 = opts.forward - up.into_inner() * opts.forward.dot(&up);
    let f0 = f0.try_normalize(1e-9).ok_or_else(|| {
        Error::Param("virtual trajectory: `forward` must not be parallel to `up`".into())
    })?;
    let k = &opts.intrinsics;
    if !(k.fx > 0.0 && k.fy > 0.0 && k.width > 0 && k.height > 0) {
        return Err(Error::Param(format!(
            "virtual trajectory: invalid intrinsics {k:?}"
        )));
    }
    let half_fov = (k.width as f64 / 2.0 / k.fx)
        .atan()
        .min((k.height as f64 / 2.0 / k.fy).atan());
    // Distance so that a sphere of the robust radius fits the narrower half field of view.
    let distance = (radius.max(1e-3) / half_fov.sin()) * opts.distance_scale.max(1e-3);
    let elevation = opts.elevation_deg.to_radians();
    let sweep = opts.sweep_deg.to_radians();
    (0..n_frames)
        .map(|i| {
            let t = if n_frames == 1 {
                0.0
            } else {
                i as f64 / (n_frames - 1) as f64 - 0.5
            };
            let yaw = Rotation3::from_axis_angle(&up, sweep * t);
            let horizontal = yaw * f0;
            // Raised camera looks down: the view direction gets a component against `up`.
            let dir = horizontal * elevation.cos() - up.into_inner() * elevation.sin();
            let eye = c - dir * distance;
            look_at(&eye, &c, &up).ok_or_else(|| {
                Error::Degenerate("virtual trajectory: view direction parallel to up".into())
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::render::render_depth;

    /// A box-shaped room corner: floor and two walls, 2 cm grid, centred near z = 3.
    fn corner_cloud() -> PointCloud {
        let mut pts = Vec::new();
        for i in 0..100 {
            for j in 0..100 {
                let (a, b) = (i as f32 * 0.02, j as f32 * 0.02);
                pts.push(Point3::new(-1.0 + a, 1.0, 2.0 + b)); // floor (y = 1, y down)
                pts.push(Point3::new(-1.0 + a, -1.0 + b, 4.0)); // back wall
                pts.push(Point3::new(-1.0, -1.0 + a, 2.0 + b)); // left wall
            }
        }
        PointCloud::from_points(pts)
    }

    #[test]
    fn arc_looks_at_the_cloud_and_sees_it() {
        let cloud = corner_cloud();
        let opts = TrajectoryOptions::default();
        let poses = virtual_trajectory(&cloud, 9, &opts).unwrap();
        assert_eq!(poses.len(), 9);
        let (c, _) = centre_and_radius(&cloud.points).unwrap();
        let k = &opts.intrinsics;
        let dists: Vec<f64> = poses
            .iter()
            .map(|p| (p.translation.vector - c.coords).norm())
            .collect();
        for (i, p) in poses.iter().enumerate() {
            // The centre projects to the principal point.
            let q = p.inverse() * c;
            let (u, v) = k.project(&q).unwrap();
            assert!(
                (u - k.cx).abs() < 1e-6 && (v - k.cy).abs() < 1e-6,
                "frame {i}"
            );
            // Same distance on the whole arc.
            assert!((dists[i] - dists[0]).abs() < 1e-9);
            // Camera y axis points against `up` (no roll).
            let y = p.rotation * Vector3::y();
            assert!(y.dot(&opts.up) < 0.0);
            // The rendered depth sees a good part of the cloud.
            let d = render_depth(&cloud.points, k, &p.inverse());
            assert!(
                d.valid_count() > 640 * 480 / 5,
                "frame {i}: {}",
                d.valid_count()
            );
        }
        // Smooth: equal steps between consecutive poses, and the middle frame looks along
        // `forward` tilted down by the elevation.
        let steps: Vec<f64> = poses
            .windows(2)
            .map(|w| (w[1].translation.vector - w[0].translation.vector).norm())
            .collect();
        assert!(steps
            .iter()
            .all(|s| (s - steps[0]).abs() < 1e-9 && *s > 0.0));
        let z_mid = poses[4].rotation * Vector3::z();
        let e = 15f64.to_radians();
        assert!(
            (z_mid - Vector3::new(0.0, e.sin(), e.cos())).norm() < 1e-9,
            "{z_mid}"
        );
        // The sweep is 30 degrees end to end.
        let (za, zb) = (
            poses[0].rotation * Vector3::z(),
            poses[8].rotation * Vector3::z(),
        );
        let ha = Vector3::new(za.x, 0.0, za.z).normalize();
        let hb = Vector3::new(zb.x, 0.0, zb.z).normalize();
        assert!((ha.dot(&hb).acos().to_degrees() - 30.0).abs() < 1e-6);
    }

    #[test]
    fn bad_inputs() {
        let opts = TrajectoryOptions::default();
        assert!(virtual_trajectory(&PointCloud::default(), 5, &opts).is_err());
        assert!(virtual_trajectory(&corner_cloud(), 0, &opts).is_err());
        let bad = TrajectoryOptions {
            forward: Vector3::new(0.0, 1.0, 0.0),
            ..opts.clone()
        };
        assert!(virtual_trajectory(&corner_cloud(), 5, &bad).is_err());
        assert_eq!(
            virtual_trajectory(&corner_cloud(), 1, &opts).unwrap().len(),
            1
        );
    }
}
