//! The f-theta virtual camera for LiDAR scans (paper appendix B.3: Cosmos-Transfer's AV models
//! use an f-theta camera; depth maps are rendered at 1280x640 with a wide field of view).
//!
//! Model: a ray at angle `theta` from the optical axis (+z, OpenCV axes) lands at distance
//! `r(theta) = k1 theta + k2 theta^2 + ... ` pixels from the principal point (cx, cy), in the
//! direction of the ray's (x, y) component. The pure equidistant case `r = f theta` is the
//! default; the polynomial must be increasing on [0, max_angle]. Unlike a pinhole, this handles
//! fields of view of 180 degrees and more without blowing up at large incidence angles.
//!
//! Depth images store the range along the ray in millimetres (z can be <= 0 beyond 90 degrees).
//! The paper does not publish its virtual camera's parameters; ours: 1280x640, equidistant,
//! 180 degrees horizontally (90 degrees vertically), mounted at the LiDAR origin looking along
//! the LiDAR's +x axis ([`lidar_front_camera_from_scan`]).

use super::render::{
    border_pixels, estimate_point_spacing, splat_zbuffer, to_mm, visible_from_zbuffer,
    zbuffer_to_depth, Frustum, Splat, SplatOptions,
};
use crate::error::{Error, Result};
use crate::io::depth_png::DepthImage;
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FThetaCamera {
    pub width: u32,
    pub height: u32,
    pub cx: f64,
    pub cy: f64,
    /// Coefficients of r(theta) = sum_i poly[i] * theta^(i+1), pixels per radian^(i+1).
    pub poly: Vec<f64>,
    /// Rays beyond this angle from the axis (radians) are not imaged.
    pub max_angle: f64,
}

impl Default for FThetaCamera {
    /// 1280x640, equidistant, 180 degrees horizontal field of view.
    fn default() -> Self {
        FThetaCamera::equidistant(1280, 640, 180.0)
    }
}

impl FThetaCamera {
    /// Equidistant f-theta (`r = f theta`) with the given horizontal field of view, principal
    /// point at the image centre; rays are imaged up to the angle of the image corners.
    pub fn equidistant(width: u32, height: u32, hfov_deg: f64) -> Self {
        let f = (width as f64 / 2.0) / (hfov_deg.to_radians() / 2.0);
        let corner = ((width as f64 / 2.0).powi(2) + (height as f64 / 2.0).powi(2)).sqrt();
        FThetaCamera {
            width,
            height,
            cx: width as f64 / 2.0 - 0.5,
            cy: height as f64 / 2.0 - 0.5,
            poly: vec![f],
            max_angle: (corner / f).min(std::f64::consts::PI - 1e-6),
        }
    }

    /// Check the model: positive size, non-empty polynomial, r increasing on [0, max_angle].
    pub fn validate(&self) -> Result<()> {
        if self.width == 0 || self.height == 0 || self.poly.is_empty() {
            return Err(Error::Param(format!(
                "f-theta camera: size {}x{} and {} polynomial coefficients; need a positive size and at least one coefficient",
                self.width,
                self.height,
                self.poly.len()
            )));
        }
        if !(self.max_angle > 0.0 && self.max_angle < std::f64::consts::PI) {
            return Err(Error::Param(format!(
                "f-theta camera: max_angle {} rad must be in (0, pi)",
                self.max_angle
            )));
        }
        let n = 256;
        for i in 0..=n {
            let t = self.max_angle * i as f64 / n as f64;
            if self.dr_dtheta(t) <= 0.0 {
                return Err(Error::Param(format!(
                    "f-theta camera: r(theta) is not increasing at theta = {:.3} rad",
                    t
                )));
            }
        }
        Ok(())
    }

    /// Distance in pixels from the principal point of a ray at angle `theta`.
    pub fn radius(&self, theta: f64) -> f64 {
        self.poly
            .iter()
            .rev()
            .fold(0.0, |acc, &k| (acc + k) * theta)
    }

    /// dr/dtheta, pixels per radian.
    pub fn dr_dtheta(&self, theta: f64) -> f64 {
        self.poly
            .iter()
            .enumerate()
            .rev()
            .fold(0.0, |acc, (i, &k)| acc * theta + (i + 1) as f64 * k)
    }

    /// The ray angle for a pixel radius (inverse of `radius` on [0, max_angle]); None beyond.
    pub fn theta(&self, r: f64) -> Option<f64> {
        if r < 0.0 || r > self.radius(self.max_angle) * (1.0 + 1e-12) {
            return None;
        }
        // Newton from the linear guess, safeguarded by bisection (r is increasing).
        let (mut lo, mut hi) = (0.0, self.max_angle);
        let mut t = (r / self.poly[0].max(1e-12)).clamp(lo, hi);
        for _ in 0..60 {
            let e = self.radius(t) - r;
            if e.abs() < 1e-12 * r.max(1.0) {
                break;
            }
            if e > 0.0 {
                hi = t;
            } else {
                lo = t;
            }
            let d = self.dr_dtheta(t);
            let nt = t - e / d;
            t = if d > 0.0 && nt > lo && nt < hi {
                nt
            } else {
                0.5 * (lo + hi)
            };
        }
        Some(t)
    }

    /// Pixel of a camera-frame point; None at the camera centre or beyond `max_angle`.
    pub fn project(&self, p: &Point3<f64>) -> Option<(f64, f64)> {
        let rho = (p.x * p.x + p.y * p.y).sqrt();
        if rho == 0.0 && p.z <= 0.0 {
            return None;
        }
        let theta = rho.atan2(p.z);
        if theta > self.max_angle {
            return None;
        }
        if rho == 0.0 {
            return Some((self.cx, self.cy));
        }
        let r = self.radius(theta);
        Some((self.cx + r * p.x / rho, self.cy + r * p.y / rho))
    }

    /// Unit ray (camera frame) through pixel (u, v); None beyond `max_angle`.
    pub fn unproject(&self, u: f64, v: f64) -> Option<Vector3<f64>> {
        let (dx, dy) = (u - self.cx, v - self.cy);
        let r = (dx * dx + dy * dy).sqrt();
        let theta = self.theta(r)?;
        if r == 0.0 {
            return Some(Vector3::z());
        }
        let s = theta.sin() / r;
        Some(Vector3::new(dx * s, dy * s, theta.cos()))
    }

    /// Whether pixel (u, v) (centre convention) is inside the image.
    pub fn in_image(&self, u: f64, v: f64) -> bool {
        let (x, y) = (u.round(), v.round());
        x >= 0.0 && y >= 0.0 && x < self.width as f64 && y < self.height as f64
    }

    fn splats(
        &self,
        points: &[Point3<f32>],
        camera_from_scan: &Isometry3<f64>,
        opts: &SplatOptions,
    ) -> Vec<Option<Splat>> {
        let spacing = opts
            .point_spacing
            .or_else(|| estimate_point_spacing(points))
            .unwrap_or(0.0) as f64;
        points
            .par_iter()
            .map(|p| {
                let q = camera_from_scan * p.cast::<f64>();
                let (u, v) = self.project(&q)?;
                let range = q.coords.norm();
                let mm = to_mm(range)?;
                // Pixels per radian: radial dr/dtheta, tangential r / sin(theta).
                let theta = (q.x * q.x + q.y * q.y).sqrt().atan2(q.z);
                let tangential = if theta > 1e-6 {
                    self.radius(theta) / theta.sin()
                } else {
                    self.dr_dtheta(0.0)
                };
                let ppr = self.dr_dtheta(theta).max(tangential);
                let r = (0.5 * spacing * ppr / range)
                    .ceil()
                    .min(opts.max_radius_px as f64) as i64;
                Some(Splat { u, v, mm, r })
            })
            .collect()
    }

    /// Range image (mm along each ray) of `points` seen with pose `camera_from_scan`.
    pub fn render_depth(
        &self,
        points: &[Point3<f32>],
        camera_from_scan: &Isometry3<f64>,
        opts: &SplatOptions,
    ) -> DepthImage {
        let s = self.splats(points, camera_from_scan, opts);
        zbuffer_to_depth(
            self.width,
            self.height,
            splat_zbuffer(self.width, self.height, &s),
        )
    }

    /// For each point: true if it is imaged and not hidden behind nearer points.
    pub fn visibility(
        &self,
        points: &[Point3<f32>],
        camera_from_scan: &Isometry3<f64>,
        opts: &SplatOptions,
    ) -> Vec<bool> {
        let s = self.splats(points, camera_from_scan, opts);
        let z = splat_zbuffer(self.width, self.height, &s);
        visible_from_zbuffer(self.width, self.height, &z, &s, opts)
    }

    /// The image border pushed out to `range` metres along its rays, in scan coordinates, for
    /// display (`per_side` samples per side; the border of a wide f-theta image is curved).
    /// Border pixels beyond `max_angle` are left out.
    pub fn frustum(
        &self,
        camera_from_scan: &Isometry3<f64>,
        range: f64,
        per_side: usize,
    ) -> Frustum {
        let scan_from_camera = camera_from_scan.inverse();
        let at = |(u, v): (f64, f64)| {
            self.unproject(u, v)
                .map(|d| scan_from_camera * Point3::from(d * range))
        };
        let (w, h) = (self.width as f64, self.height as f64);
        let apex = scan_from_camera * Point3::origin();
        // Corners may lie beyond max_angle (e.g. a circular fisheye): fall back to the apex.
        let corner = |u, v| at((u, v)).unwrap_or(apex);
        Frustum {
            apex,
            corners: [
                corner(-0.5, -0.5),
                corner(w - 0.5, -0.5),
                corner(w - 0.5, h - 0.5),
                corner(-0.5, h - 0.5),
            ],
            border: border_pixels(w, h, per_side)
                .into_iter()
                .filter_map(at)
                .collect(),
        }
    }
}

/// Close the gaps a spinning LiDAR leaves between its rings: in each column, a run of at most
/// `max_gap` empty pixels between two valid ones whose ranges differ by at most `rel_tol`
/// (relative) is filled by linear interpolation. Runs across a depth edge stay empty, so
/// foreground and background are never bridged. A world model conditioned on depth expects a
/// dense map, not a stripe pattern.
pub fn fill_ring_gaps(d: &mut DepthImage, max_gap: u32, rel_tol: f32) {
    let (w, h) = (d.width as usize, d.height as usize);
    for x in 0..w {
        let mut last: Option<(usize, u16)> = None;
        for y in 0..h {
            let v = d.data[y * w + x];
            if v == 0 {
                continue;
            }
            if let Some((ly, lv)) = last {
                let gap = y - ly - 1;
                let (a, b) = (lv as f32, v as f32);
                if gap > 0 && gap <= max_gap as usize && (a - b).abs() <= rel_tol * a.min(b) {
                    for g in 1..=gap {
                        let t = g as f32 / (gap + 1) as f32;
                        d.data[(ly + g) * w + x] = (a + t * (b - a)).round() as u16;
                    }
                }
            }
            last = Some((y, v));
        }
    }
}

/// Free-function form of [`FThetaCamera::render_depth`] with default splat options.
pub fn render_depth_ftheta(
    points: &[Point3<f32>],
    cam: &FThetaCamera,
    camera_from_scan: &Isometry3<f64>,
) -> DepthImage {
    cam.render_depth(points, camera_from_scan, &SplatOptions::default())
}

/// The virtual camera pose for a LiDAR scan (x forward, y left, z up): at the sensor origin,
/// optical axis along the scan's +x turned by `yaw` radians about +z (left positive), image y
/// pointing down (-z). Returns `camera_from_scan`.
pub fn lidar_front_camera_from_scan(yaw: f64) -> Isometry3<f64> {
    let (s, c) = yaw.sin_cos();
    let forward = Vector3::new(c, s, 0.0);
    let right = Vector3::new(s, -c, 0.0);
    let down = Vector3::new(0.0, 0.0, -1.0);
    let m = nalgebra::Matrix3::from_columns(&[right, down, forward]);
    let rot = nalgebra::UnitQuaternion::from_rotation_matrix(
        &nalgebra::Rotation3::from_matrix_unchecked(m),
    );
    Isometry3::from_parts(nalgebra::Translation3::identity(), rot).inverse()
}

/// [`lidar_front_camera_from_scan`] with the camera at `origin` (scan frame) instead of the
/// scan's origin: `scan_from_camera` = translation(origin) * the yawed rotation.
pub fn lidar_camera_from_scan_at(yaw: f64, origin: &Point3<f64>) -> Isometry3<f64> {
    let rotation = lidar_front_camera_from_scan(yaw).rotation.inverse();
    Isometry3::from_parts(nalgebra::Translation3::from(origin.coords), rotation).inverse()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn project_unproject_round_trip() {
        for cam in [
            FThetaCamera::default(),
            FThetaCamera {
                poly: vec![400.0, -20.0, 3.0],
                ..FThetaCamera::equidistant(1280, 640, 200.0)
            },
        ] {
            cam.validate().unwrap();
            // Pixels -> rays -> pixels.
            for v in (0..cam.height).step_by(37) {
                for u in (0..cam.width).step_by(53) {
                    let Some(d) = cam.unproject(u as f64, v as f64) else {
                        continue;
                    };
                    assert!((d.norm() - 1.0).abs() < 1e-12);
                    let (pu, pv) = cam.project(&Point3::from(d * 7.5)).unwrap();
                    assert!((pu - u as f64).abs() < 1e-6 && (pv - v as f64).abs() < 1e-6);
                }
            }
            // Directions -> pixels -> directions, including beyond 90 degrees.
            for i in 0..200 {
                let theta = cam.max_angle * (i as f64 + 0.5) / 200.0;
                let phi = i as f64 * 0.7;
                let d = Vector3::new(
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                );
                let (u, v) = cam.project(&Point3::from(d * 3.0)).unwrap();
                let back = cam.unproject(u, v).unwrap();
                assert!((back - d).norm() < 1e-9, "theta {theta}");
            }
        }
        let cam = FThetaCamera::default();
        assert_eq!(
            cam.project(&Point3::new(0.0, 0.0, 2.0)),
            Some((cam.cx, cam.cy))
        );
        assert_eq!(cam.project(&Point3::new(0.0, 0.0, -2.0)), None);
        // Equidistant 180 degrees: a point 90 degrees to the right is at the right edge.
        let (u, v) = cam.project(&Point3::new(5.0, 0.0, 0.0)).unwrap();
        assert!((u - (cam.cx + 640.0)).abs() < 1e-9 && (v - cam.cy).abs() < 1e-9);
        assert!(FThetaCamera {
            poly: vec![-1.0],
            ..cam.clone()
        }
        .validate()
        .is_err());
    }

    #[test]
    fn rendering_a_plane_gives_its_range() {
        // A wall z = 4 m in front (camera frame), 20 m x 8 m, 2 cm grid.
        let cam = FThetaCamera::default();
        let mut pts = Vec::new();
        for i in 0..=1000 {
            for j in 0..=400 {
                pts.push(Point3::new(
                    -10.0 + 0.02 * i as f32,
                    -4.0 + 0.02 * j as f32,
                    4.0,
                ));
            }
        }
        let d = cam.render_depth(&pts, &Isometry3::identity(), &SplatOptions::default());
        let mut checked = 0;
        for v in (100..540).step_by(40) {
            for u in (300..980).step_by(40) {
                let range_at = |u: f64, v: f64| 4.0 / cam.unproject(u, v).unwrap().z;
                let range = range_at(u as f64, v as f64);
                let got = d.raw(u, v) as f64 / 1000.0;
                // Flat splats (half-width <= 3 px here) draw the nearest point whose square
                // covers the pixel: between the nearest true range within 3 px and the true
                // range plus half the 2 cm grid spacing.
                let mut lo = range;
                for dv in -3..=3 {
                    for du in -3..=3 {
                        lo = lo.min(range_at((u as i32 + du) as f64, (v as i32 + dv) as f64));
                    }
                }
                assert!(
                    got >= lo - 0.002 && got <= range + 0.012,
                    "{u},{v}: {got} vs {range} (lo {lo})"
                );
                checked += 1;
            }
        }
        assert!(checked > 150);
    }

    #[test]
    fn point_behind_a_wall_is_occluded() {
        let cam = FThetaCamera::default();
        let mut pts = Vec::new();
        for i in 0..=300 {
            for j in 0..=300 {
                pts.push(Point3::new(
                    -3.0 + 0.02 * i as f32,
                    -3.0 + 0.02 * j as f32,
                    5.0,
                ));
            }
        }
        let n = pts.len();
        pts.push(Point3::new(0.3, -0.2, 8.0)); // behind the wall
        pts.push(Point3::new(0.3, -0.2, 2.0)); // in front of it
        pts.push(Point3::new(6.0, 0.0, 1.0)); // wide to the right, beside the wall: visible
        pts.push(Point3::new(0.0, 0.0, -3.0)); // straight behind the camera: not imaged
        let vis = cam.visibility(&pts, &Isometry3::identity(), &SplatOptions::default());
        assert!(vis[..n].iter().filter(|&&v| v).count() > n * 99 / 100);
        assert_eq!(&vis[n..], &[false, true, true, false]);
    }

    #[test]
    fn lidar_mount_and_frustum() {
        let t = lidar_front_camera_from_scan(0.0);
        // LiDAR +x (forward) is camera +z; LiDAR +z (up) is camera -y; LiDAR +y (left) is -x.
        assert!((t * Point3::new(1.0, 0.0, 0.0) - Point3::new(0.0, 0.0, 1.0)).norm() < 1e-12);
        assert!((t * Point3::new(0.0, 0.0, 1.0) - Point3::new(0.0, -1.0, 0.0)).norm() < 1e-12);
        assert!((t * Point3::new(0.0, 1.0, 0.0) - Point3::new(-1.0, 0.0, 0.0)).norm() < 1e-12);
        let t90 = lidar_front_camera_from_scan(std::f64::consts::FRAC_PI_2);
        assert!((t90 * Point3::new(0.0, 1.0, 0.0) - Point3::new(0.0, 0.0, 1.0)).norm() < 1e-12);
        let cam = FThetaCamera::default();
        let f = cam.frustum(&t, 10.0, 16);
        assert_eq!(f.border.len(), 64);
        for p in &f.border {
            assert!((p.coords.norm() - 10.0).abs() < 1e-9);
        }
        // The left edge's middle looks 90 degrees to the left (+y in the LiDAR frame).
        let left_mid = f.border[3 * 16 + 8];
        assert!(
            (left_mid - Point3::new(0.0, 10.0, 0.0)).norm() < 0.1,
            "{left_mid}"
        );
    }

    #[test]
    fn ring_gaps_fill_only_within_a_surface() {
        // Column 0: rings at rows 0, 5 (same surface, 4 m) then a far ring at row 9 (12 m).
        let mut d = DepthImage {
            width: 2,
            height: 12,
            data: vec![0; 24],
        };
        d.data[0] = 4000;
        d.data[5 * 2] = 4200;
        d.data[9 * 2] = 12000;
        // Column 1: a gap longer than the limit.
        d.data[1] = 3000;
        d.data[11 * 2 + 1] = 3000;
        fill_ring_gaps(&mut d, 8, 0.1);
        let col0: Vec<u16> = (0..12).map(|y| d.data[y * 2]).collect();
        assert_eq!(&col0[..6], &[4000, 4040, 4080, 4120, 4160, 4200]);
        assert_eq!(&col0[6..9], &[0, 0, 0], "no bridge across the depth edge");
        assert_eq!(col0[9], 12000);
        assert!(
            (1..11).all(|y| d.data[y * 2 + 1] == 0),
            "gap of 10 > 8 stays"
        );
    }
}
