//! Where SpinNet is evaluated: a seeded random subset of the voxel-downsampled cloud (the
//! authors evaluate at 5,000 random points; at 3-4 GFLOP each that is minutes per fragment on
//! two cores, so the count is a parameter, chosen on development pairs).

use crate::estimate::rng::Pcg32;
use crate::geometry::voxel::voxel_downsample;
use crate::geometry::PointCloud;

/// Up to `n` keypoints of `cloud` at keypoint voxel `voxel`, in the downsampled cloud's order
/// (all of them when it has `n` or fewer).
pub fn select(cloud: &PointCloud, voxel: f64, n: usize, seed: u64) -> PointCloud {
    let down = voxel_downsample(cloud, voxel);
    if down.len() <= n {
        return PointCloud::from_points(down.points);
    }
    let mut idx: Vec<usize> = (0..down.len()).collect();
    let mut rng = Pcg32::new(seed, 0x5eed);
    for i in 0..n {
        let j = i + rng.below((idx.len() - i) as u32) as usize;
        idx.swap(i, j);
    }
    idx.truncate(n);
    idx.sort_unstable();
    PointCloud::from_points(idx.into_iter().map(|i| down.points[i]).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn a_reproducible_subset_of_the_downsampled_cloud() {
        let pts: Vec<Point3<f32>> = (0..40)
            .flat_map(|i| (0..40).map(move |j| Point3::new(i as f32 * 0.1, j as f32 * 0.1, 0.0)))
            .collect();
        let c = PointCloud::from_points(pts);
        let down = voxel_downsample(&c, 0.1);
        let a = select(&c, 0.1, 100, 0);
        assert_eq!(a.len(), 100);
        assert_eq!(a.points, select(&c, 0.1, 100, 0).points);
        assert_ne!(a.points, select(&c, 0.1, 100, 1).points);
        assert!(a.points.iter().all(|p| down.points.contains(p)));
        assert_eq!(select(&c, 0.1, 1_000_000, 0).len(), down.len());
    }
}
