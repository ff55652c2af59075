//! A pair with its source turned by a known rotation about its origin: the same registration
//! problem in another coordinate frame. A global method should not care, but voxel grids,
//! keypoint sampling and tie-breaks do, so re-posing the source under several seeds shows how
//! much of a one-pair difference between two rows is the frame the data happened to come in
//! (`cgenreg bench --repose-seed N`).
//!
//! Only rotations about the origin: the origin of a scan's frame is its viewpoint (a 3DMatch
//! fragment is in its first camera's frame, a LiDAR scan in its sensor's), and the geometric
//! branch orients normals towards it, so a translation would change the problem (normals
//! flipped away from the real viewpoint), not just its frame. Tried first with translations of
//! up to 2 m: FPFH-NN fell from 8/10 to 3/10 on the 3DLoMatch pairs.

use super::ScanPair;
use crate::error::{Error, Result};
use crate::estimate::rng::Pcg32;
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

/// The seeded motion for one pair: a rotation uniform on SO(3) (Shoemake's method) about the
/// origin. The pair id picks the PCG stream, so every pair of a run gets its own motion and a
/// pair's motion does not depend on which other pairs run.
pub fn repose_motion(seed: u64, pair_id: &str) -> Isometry3<f64> {
    let h = blake3::hash(pair_id.as_bytes());
    let b = h.as_bytes();
    let stream = u64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]);
    let mut rng = Pcg32::new(seed, stream);
    let (u1, u2, u3) = (rng.unit_f64(), rng.unit_f64(), rng.unit_f64());
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    let (t2, t3) = (std::f64::consts::TAU * u2, std::f64::consts::TAU * u3);
    let q = Quaternion::new(b * t3.cos(), a * t2.sin(), a * t2.cos(), b * t3.sin());
    Isometry3::from_parts(Translation3::identity(), UnitQuaternion::from_quaternion(q))
}

impl ScanPair {
    /// The same problem with the source moved by `motion` (p' = motion * p; [`repose_motion`]
    /// gives rotations about the origin, which keep the viewpoint): its points and
    /// normals, and the pose of every frame it was fused from (`scan_from_camera' = motion *
    /// scan_from_camera`, so the images still see the same points). The ground truth becomes
    /// `gt * motion⁻¹`, which maps the moved source onto the target as `gt` mapped the original.
    ///
    /// A source with no frames gets its image branch's virtual cameras at the origin of its
    /// coordinates (the LiDAR sensor for a scan in its own frame); moving it would move them
    /// away from the sensor, so that is refused when `image_branch` is set.
    pub fn with_source_moved(
        mut self,
        motion: &Isometry3<f64>,
        image_branch: bool,
    ) -> Result<ScanPair> {
        if image_branch && self.source.frames.is_none() {
            return Err(Error::Invalid(format!(
                "{}: re-posing a source without frames ({}) would move the image branch's virtual \
                 camera away from its sensor; re-pose RGB-D pairs, or run geometry only",
                self.id, self.source.name
            )));
        }
        self.source.cloud = self.source.cloud.transformed(motion);
        if let Some(fs) = self.source.frames.as_mut() {
            for f in &mut fs.frames {
                f.scan_from_camera = motion * f.scan_from_camera;
            }
        }
        self.gt_target_from_source = self.gt_target_from_source.map(|gt| gt * motion.inverse());
        Ok(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::{FrameSet, RgbdFrame, Scan};
    use crate::geometry::PointCloud;
    use nalgebra::{Point3, Vector3};
    use proptest::prelude::*;

    fn pair(gt: Isometry3<f64>, frames: bool) -> ScanPair {
        let pts: Vec<Point3<f32>> = (0..50)
            .map(|i| Point3::new(i as f32 * 0.1, (i % 7) as f32 * 0.2, (i % 3) as f32 * 0.3))
            .collect();
        let frame_set = frames.then(|| FrameSet {
            camera: crate::camera::CameraModel::Pinhole(
                crate::camera::trajectory::TrajectoryOptions::default().intrinsics,
            ),
            frames: vec![RgbdFrame {
                index: 0,
                depth_path: "d.png".into(),
                color_path: None,
                scan_from_camera: Isometry3::translation(0.5, 0.0, 0.0),
            }],
            origin: crate::dataset::ViewOrigin::Sensor,
        });
        ScanPair {
            id: "t/0-1".into(),
            source: Scan {
                name: "s".into(),
                cloud: PointCloud::from_points(pts.clone()),
                frames: frame_set,
                notes: Vec::new(),
            },
            target: Scan {
                name: "t".into(),
                cloud: PointCloud::from_points(pts.iter().map(|p| gt.cast() * p).collect()),
                frames: None,
                notes: Vec::new(),
            },
            gt_target_from_source: Some(gt),
        }
    }

    proptest! {
        /// The moved GT maps every moved source point where the old GT mapped it, and the
        /// frames keep seeing the same points (camera coordinates unchanged).
        #[test]
        fn the_moved_problem_has_the_same_answer(seed in any::<u64>(), yaw in -3.0f64..3.0) {
            let gt = Isometry3::new(Vector3::new(0.3, -1.0, 0.2), Vector3::new(0.1, 0.2, yaw));
            let before = pair(gt, true);
            let m = repose_motion(seed, &before.id);
            let after = before.clone().with_source_moved(&m, true).unwrap();
            let gt2 = after.gt_target_from_source.unwrap();
            for (p, q) in before.source.cloud.points.iter().zip(&after.source.cloud.points) {
                let want = gt * p.cast::<f64>();
                let got = gt2 * q.cast::<f64>();
                prop_assert!((want - got).norm() < 1e-5, "seed {seed}: {want} vs {got}");
            }
            let (c0, c1) = (
                &before.source.frames.as_ref().unwrap().frames[0],
                &after.source.frames.as_ref().unwrap().frames[0],
            );
            let p = before.source.cloud.points[7].cast::<f64>();
            let in_cam0 = c0.scan_from_camera.inverse() * p;
            let in_cam1 = c1.scan_from_camera.inverse() * after.source.cloud.points[7].cast::<f64>();
            prop_assert!((in_cam0 - in_cam1).norm() < 1e-5);
            prop_assert_eq!(&after.target.cloud.points, &before.target.cloud.points);
        }
    }

    #[test]
    fn motions_are_seeded_per_pair_and_rotations_cover_so3() {
        assert_eq!(repose_motion(3, "a/0-1"), repose_motion(3, "a/0-1"));
        assert_ne!(repose_motion(3, "a/0-1"), repose_motion(4, "a/0-1"));
        assert_ne!(repose_motion(3, "a/0-1"), repose_motion(3, "a/0-2"));
        // Uniform on SO(3): the rotation angle has density (1 - cos θ)/π, mean π/2 + 2/π ≈ 2.2 rad.
        let n = 4000;
        let mean = (0..n)
            .map(|s| repose_motion(s, "x").rotation.angle())
            .sum::<f64>()
            / n as f64;
        let want = std::f64::consts::FRAC_PI_2 + 2.0 / std::f64::consts::PI;
        assert!((mean - want).abs() < 0.03, "mean angle {mean}, want {want}");
        // About the origin: the viewpoint normals are oriented towards stays where it was.
        assert_eq!(repose_motion(9, "x").translation.vector.norm(), 0.0);
    }

    #[test]
    fn a_source_without_frames_is_refused_with_the_image_branch_only() {
        let m = repose_motion(1, "t/0-1");
        let e = pair(Isometry3::identity(), false)
            .with_source_moved(&m, true)
            .unwrap_err()
            .to_string();
        assert!(e.contains("t/0-1") && e.contains("without frames"), "{e}");
        assert!(pair(Isometry3::identity(), false)
            .with_source_moved(&m, false)
            .is_ok());
    }
}
