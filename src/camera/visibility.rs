//! Free-space (visibility) consistency of a pose with depth views, a verification signal that
//! needs no descriptor and no branch's scores.
//!
//! Under a correct `target_from_source`, a source point seen by a target depth view lies on the
//! observed surface (consistent) or behind it (occluded: no information); it never lies in the
//! space the view saw through (a conflict). A wrong pose that aligns one consistent cluster of
//! structure puts the rest of the source cloud into the target's observed free space. This is
//! the visibility test used to verify pairwise matches in multi-view range-scan registration
//! (e.g. Huber and Hebert, 2003). The only distance is `theta`, the pipeline's inlier threshold.

use crate::camera::CameraModel;
use crate::io::depth_png::DepthImage;
use nalgebra::{Isometry3, Point3};

/// One depth view of a scan: its camera, where it is, and what it measured.
#[derive(Clone, Copy, Debug)]
pub struct DepthView<'a> {
    pub camera: &'a CameraModel,
    /// p_scan = scan_from_camera * p_camera.
    pub scan_from_camera: Isometry3<f64>,
    /// Depth in the camera model's convention (z for pinhole, range for f-theta).
    pub depth: &'a DepthImage,
}

/// How the points of one scan, moved into another scan's frame, agree with that scan's views.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Visibility {
    /// Points on an observed surface (within `theta`) in at least as many views as they conflict.
    pub consistent: usize,
    /// Points in observed free space (in front of the surface by more than `theta`) in more
    /// views than they lie on a surface.
    pub conflict: usize,
    /// Points outside every view, on invalid pixels, or only behind observed surfaces.
    pub unseen: usize,
}

impl Visibility {
    /// Support minus conflict (V): a count, which grows with the overlap a pose creates as well
    /// as with its consistency.
    pub fn score(&self) -> i64 {
        self.consistent as i64 - self.conflict as i64
    }

    /// F: the Wilson lower bound, at the 95 % level (z = 1.96), of the share of seen points that
    /// are consistent, consistent / (consistent + conflict); 0 when no point was seen. The share
    /// measures consistency whatever the overlap; the bound keeps a pose that shows only a few
    /// points from winning on a small sample.
    pub fn share_lower_bound(&self) -> f64 {
        const Z: f64 = 1.96;
        let n = (self.consistent + self.conflict) as f64;
        if n == 0.0 {
            return 0.0;
        }
        let p = self.consistent as f64 / n;
        let z2 = Z * Z;
        (p + z2 / (2.0 * n) - Z * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt()) / (1.0 + z2 / n)
    }
}

impl std::ops::Add for Visibility {
    type Output = Visibility;
    fn add(self, o: Visibility) -> Visibility {
        Visibility {
            consistent: self.consistent + o.consistent,
            conflict: self.conflict + o.conflict,
            unseen: self.unseen + o.unseen,
        }
    }
}

/// Classify each of `points` (source frame) moved by `target_from_source` against the target's
/// `views`. A view whose image size differs from its camera's is skipped (it cannot be indexed).
pub fn visibility(
    points: &[Point3<f32>],
    target_from_source: &Isometry3<f64>,
    views: &[DepthView<'_>],
    theta: f64,
) -> Visibility {
    let usable: Vec<(Isometry3<f64>, &DepthView)> = views
        .iter()
        .filter(|v| v.camera.size() == (v.depth.width, v.depth.height))
        .map(|v| (v.scan_from_camera.inverse(), v))
        .collect();
    // Chunks of points in parallel: counts, so the sum is the same whatever the split.
    use rayon::prelude::*;
    points
        .par_chunks(512)
        .map(|chunk| classify(chunk, target_from_source, &usable, theta))
        .reduce(Visibility::default, |a, b| a + b)
}

/// [`visibility`] of `points` against the usable views (`camera_from_scan` with each view).
fn classify(
    points: &[Point3<f32>],
    target_from_source: &Isometry3<f64>,
    usable: &[(Isometry3<f64>, &DepthView<'_>)],
    theta: f64,
) -> Visibility {
    let mut out = Visibility::default();
    for p in points {
        let q = target_from_source * p.cast::<f64>();
        let (mut on, mut free) = (0usize, 0usize);
        for (camera_from_scan, v) in usable {
            let c = camera_from_scan * q;
            let Some((u, w)) = v.camera.project(&c) else {
                continue;
            };
            let (u, w) = (u.round(), w.round());
            if u < 0.0 || w < 0.0 || u >= v.depth.width as f64 || w >= v.depth.height as f64 {
                continue;
            }
            let Some(observed) = v.depth.meters(u as u32, w as u32) else {
                continue;
            };
            let d = v.camera.depth_of(&c);
            let observed = observed as f64;
            if (d - observed).abs() <= theta {
                on += 1;
            } else if d < observed - theta {
                free += 1;
            }
        }
        if on == 0 && free == 0 {
            out.unseen += 1;
        } else if free > on {
            out.conflict += 1;
        } else {
            out.consistent += 1;
        }
    }
    out
}

/// Both directions of a pose's visibility: `source` keypoints moved by `target_from_source`
/// against the target's views, plus `target` keypoints moved back against the source's (the
/// score the `visibility` fusion and the scale search compare poses by).
pub fn both_ways(
    (source, target): (&[Point3<f32>], &[Point3<f32>]),
    target_from_source: &Isometry3<f64>,
    (source_views, target_views): (&[DepthView<'_>], &[DepthView<'_>]),
    theta: f64,
) -> Visibility {
    visibility(source, target_from_source, target_views, theta)
        + visibility(target, &target_from_source.inverse(), source_views, theta)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;

    /// A wall at z = 2 m seen by a camera at the origin looking down +z.
    fn wall() -> (CameraModel, DepthImage) {
        let k = Intrinsics {
            fx: 50.0,
            fy: 50.0,
            cx: 32.0,
            cy: 24.0,
            width: 64,
            height: 48,
        };
        let depth = DepthImage {
            width: 64,
            height: 48,
            data: vec![2000; 64 * 48],
        };
        (k.into(), depth)
    }

    #[test]
    fn the_share_bound_matches_the_study_and_grows_with_the_sample() {
        let v = |consistent, conflict| Visibility {
            consistent,
            conflict,
            unseen: 7,
        };
        // the study's F (`r6_share` in studies/fusion/rounds.py) of two poses of one development pair
        assert!((v(2245, 461).share_lower_bound() - 0.8150076541061555).abs() < 1e-12);
        assert!((v(1876, 2563).share_lower_bound() - 0.4081589581605628).abs() < 1e-12);
        // nothing seen: no evidence; all consistent: below 1, and rising with the sample
        assert_eq!(v(0, 0).share_lower_bound(), 0.0);
        let (few, many) = (v(3, 0).share_lower_bound(), v(300, 0).share_lower_bound());
        assert!((few - 0.4384939195509822).abs() < 1e-12, "{few}");
        assert!(few < many && many < 1.0, "{few} {many}");
        assert!(v(0, 9).share_lower_bound().abs() < 1e-12);
        // a bound below the observed share
        assert!(v(80, 20).share_lower_bound() < 0.8);
    }

    #[test]
    fn on_the_surface_in_front_of_it_behind_it_and_outside() {
        let (cam, depth) = wall();
        let views = [DepthView {
            camera: &cam,
            scan_from_camera: Isometry3::identity(),
            depth: &depth,
        }];
        let pts = [
            Point3::new(0.0, 0.0, 2.05), // on the wall (within 0.1 m)
            Point3::new(0.1, 0.0, 1.0),  // in the free space the camera saw through
            Point3::new(0.0, 0.1, 3.0),  // behind the wall: occluded
            Point3::new(50.0, 0.0, 2.0), // outside the image
            Point3::new(0.0, 0.0, -1.0), // behind the camera
        ];
        let v = visibility(&pts, &Isometry3::identity(), &views, 0.1);
        assert_eq!(
            v,
            Visibility {
                consistent: 1,
                conflict: 1,
                unseen: 3
            }
        );
        assert_eq!(v.score(), 0);
        // Moving every point 0.5 m towards the camera puts the wall point in free space too
        // (and the occluded one still behind the wall).
        let t = Isometry3::translation(0.0, 0.0, -0.5);
        let moved = visibility(&pts, &t, &views, 0.1);
        assert_eq!(moved.conflict, 2);
        assert_eq!(moved.consistent, 0);
    }

    #[test]
    fn a_view_of_the_wrong_size_is_skipped() {
        let (cam, mut depth) = wall();
        depth.width = 32;
        depth.data.truncate(32 * 48);
        let views = [DepthView {
            camera: &cam,
            scan_from_camera: Isometry3::identity(),
            depth: &depth,
        }];
        let v = visibility(
            &[Point3::new(0.0, 0.0, 2.0)],
            &Isometry3::identity(),
            &views,
            0.1,
        );
        assert_eq!(v.unseen, 1);
    }
}
