//! Neighbour search in 3-D over a kiddo k-d tree.
//!
//! Every query returns `(index, distance)` pairs where `index` is the position of the point
//! in the slice given to [`KdIndex::new`] and `distance` is the **Euclidean distance in
//! metres (not squared)**. kiddo works on squared distances internally; radii are squared
//! on the way in and distances square-rooted on the way out. Radius bounds are inclusive
//! (`d <= radius`), as in Open3D. Results are sorted by ascending distance; the order of
//! equidistant points is unspecified.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Point3;
use rayon::prelude::*;
use std::num::NonZeroUsize;

type Tree = ImmutableKdTree<f32, 3>;

/// A static 3-D k-d tree over a set of points. An empty index answers every query with
/// nothing (None / empty).
pub struct KdIndex {
    tree: Option<Tree>,
    len: usize,
}

impl std::fmt::Debug for KdIndex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KdIndex").field("len", &self.len).finish()
    }
}

#[inline]
fn arr(p: &Point3<f32>) -> [f32; 3] {
    [p.x, p.y, p.z]
}

impl KdIndex {
    /// Build the tree. Indices are `u32` inside kiddo, so clouds are limited to 2^32 points.
    pub fn new(points: &[Point3<f32>]) -> KdIndex {
        let pts: Vec<[f32; 3]> = points.iter().map(arr).collect();
        let tree = if pts.is_empty() {
            None
        } else {
            Tree::new_from_slice_parallel(&pts).ok()
        };
        KdIndex {
            tree,
            len: points.len(),
        }
    }

    /// Number of indexed points.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The closest point and its distance (m).
    pub fn nearest(&self, q: &Point3<f32>) -> Option<(usize, f32)> {
        let tree = self.tree.as_ref()?;
        let r = tree
            .query(&arr(q))
            .nearest_one::<SquaredEuclidean<f32>>()
            .execute();
        Some((r.item as usize, r.distance.sqrt()))
    }

    /// The `k` closest points (fewer when the index is smaller), sorted by distance (m).
    pub fn knn(&self, q: &Point3<f32>, k: usize) -> Vec<(usize, f32)> {
        let (Some(tree), Some(k)) = (self.tree.as_ref(), NonZeroUsize::new(k)) else {
            return Vec::new();
        };
        tree.query(&arr(q))
            .nearest_n::<SquaredEuclidean<f32>>(k)
            .execute()
            .into_iter()
            .map(|r| (r.item as usize, r.distance.sqrt()))
            .collect()
    }

    /// Every point with distance <= `radius` (m), sorted by distance.
    pub fn within(&self, q: &Point3<f32>, radius: f64) -> Vec<(usize, f32)> {
        let mut out = Vec::new();
        self.within_into(q, radius, &mut out);
        out.sort_unstable_by(|a, b| a.1.total_cmp(&b.1));
        out
    }

    /// Open3D's `KDTreeSearchParamHybrid`: the `max_nn` nearest points among those with
    /// distance <= `radius`, sorted by distance. The query point itself is included when
    /// it is in the index.
    pub fn hybrid(&self, q: &Point3<f32>, radius: f64, max_nn: usize) -> Vec<(usize, f32)> {
        let mut out = Vec::new();
        self.hybrid_into(q, radius, max_nn, &mut out);
        out
    }

    /// [`hybrid`](Self::hybrid) into a caller-owned buffer (cleared first), so hot loops can
    /// reuse one allocation.
    pub fn hybrid_into(
        &self,
        q: &Point3<f32>,
        radius: f64,
        max_nn: usize,
        out: &mut Vec<(usize, f32)>,
    ) {
        self.hybrid_sq_unsorted_into(q, radius, max_nn, out);
        out.sort_unstable_by(|a, b| a.1.total_cmp(&b.1));
        out.iter_mut().for_each(|e| e.1 = e.1.sqrt());
    }

    /// [`hybrid_into`](Self::hybrid_into) without the final sort and with **squared**
    /// distances: the same set of points, for callers that need neither order nor metres.
    pub fn hybrid_sq_unsorted_into(
        &self,
        q: &Point3<f32>,
        radius: f64,
        max_nn: usize,
        out: &mut Vec<(usize, f32)>,
    ) {
        out.clear();
        if max_nn == 0 {
            return;
        }
        self.within_sq_into(q, radius, out);
        if out.len() > max_nn {
            out.select_nth_unstable_by(max_nn - 1, |a, b| a.1.total_cmp(&b.1));
            out.truncate(max_nn);
        }
    }

    /// Unsorted radius search into `out` (cleared first), distances in metres.
    fn within_into(&self, q: &Point3<f32>, radius: f64, out: &mut Vec<(usize, f32)>) {
        out.clear();
        self.within_sq_into(q, radius, out);
        out.iter_mut().for_each(|e| e.1 = e.1.sqrt());
    }

    /// Appends (index, squared distance) for every point within `radius`, unsorted.
    fn within_sq_into(&self, q: &Point3<f32>, radius: f64, out: &mut Vec<(usize, f32)>) {
        let Some(tree) = self.tree.as_ref() else {
            return;
        };
        // Also rejects NaN.
        if radius.is_nan() || radius < 0.0 {
            return;
        }
        let r2 = (radius * radius) as f32;
        tree.query(&arr(q))
            .within::<SquaredEuclidean<f32>>(r2)
            .unsorted()
            .visit(|r| out.push((r.item as usize, r.distance)));
    }

    /// Nearest neighbour of every query point, in parallel.
    pub fn nearest_batch(&self, qs: &[Point3<f32>]) -> Vec<Option<(usize, f32)>> {
        qs.par_iter().map(|q| self.nearest(q)).collect()
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    use crate::testing::Lcg;

    /// Minimal reader for binary little-endian PLY files whose vertices are exactly
    /// `float x, y, z` (the staged TEASER++ fragments). The real reader lives in `io::ply`.
    pub(crate) fn read_xyz_ply(path: &std::path::Path) -> Vec<Point3<f32>> {
        let bytes = std::fs::read(path).unwrap();
        let end = b"end_header\n";
        let pos = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
        let header = std::str::from_utf8(&bytes[..pos]).unwrap();
        assert!(header.contains("binary_little_endian"));
        let n: usize = header
            .lines()
            .find_map(|l| l.strip_prefix("element vertex "))
            .unwrap()
            .trim()
            .parse()
            .unwrap();
        let props: Vec<&str> = header
            .lines()
            .filter(|l| l.starts_with("property"))
            .collect();
        assert_eq!(
            props,
            ["property float x", "property float y", "property float z"]
        );
        let body = &bytes[pos..pos + n * 12];
        body.chunks_exact(12)
            .map(|c| {
                let f = |i: usize| f32::from_le_bytes(c[i..i + 4].try_into().unwrap());
                Point3::new(f(0), f(4), f(8))
            })
            .collect()
    }

    pub(crate) fn fragment(name: &str) -> Option<Vec<Point3<f32>>> {
        let root = crate::testing::test_data_root()?;
        let p = crate::testing::require_file(
            &root,
            &format!("3dmatch-redkitchen/teaser-plusplus/{name}"),
        )?;
        Some(read_xyz_ply(&p))
    }

    fn brute(points: &[Point3<f32>], q: &Point3<f32>) -> Vec<(usize, f32)> {
        let mut v: Vec<(usize, f32)> = points
            .iter()
            .enumerate()
            .map(|(i, p)| (i, (p - q).norm()))
            .collect();
        v.sort_by(|a, b| a.1.total_cmp(&b.1));
        v
    }

    /// Same distances in the same order, and every returned index really lies at the
    /// reported distance (ties may pick different indices).
    fn check_same(points: &[Point3<f32>], q: &Point3<f32>, got: &[(usize, f32)], want: &[f32]) {
        assert_eq!(got.len(), want.len(), "result count");
        for (k, (&(i, d), &w)) in got.iter().zip(want).enumerate() {
            assert!((d - w).abs() <= 1e-5 * (1.0 + w), "rank {k}: {d} vs {w}");
            assert!(((points[i] - q).norm() - d).abs() <= 1e-5 * (1.0 + d));
        }
        let mut idx: Vec<usize> = got.iter().map(|e| e.0).collect();
        idx.sort_unstable();
        idx.dedup();
        assert_eq!(idx.len(), got.len(), "duplicate indices");
    }

    /// Radius-bounded results: compare away from the boundary where f32 rounding decides.
    fn check_radius(
        points: &[Point3<f32>],
        q: &Point3<f32>,
        got: &[(usize, f32)],
        all: &[(usize, f32)],
        radius: f32,
        max_nn: usize,
    ) {
        let eps = 1e-5;
        let sure = all
            .iter()
            .filter(|e| e.1 < radius - eps)
            .count()
            .min(max_nn);
        let maybe = all
            .iter()
            .filter(|e| e.1 <= radius + eps)
            .count()
            .min(max_nn);
        assert!(
            got.len() >= sure && got.len() <= maybe,
            "{} not in [{sure}, {maybe}]",
            got.len()
        );
        let want: Vec<f32> = all[..got.len()].iter().map(|e| e.1).collect();
        check_same(points, q, got, &want);
        assert!(got.windows(2).all(|w| w[0].1 <= w[1].1), "sorted");
    }

    fn exercise(points: &[Point3<f32>], queries: &[Point3<f32>], radius: f32) {
        let index = KdIndex::new(points);
        assert_eq!(index.len(), points.len());
        let batch = index.nearest_batch(queries);
        for (qi, q) in queries.iter().enumerate() {
            let all = brute(points, q);
            let (i, d) = index.nearest(q).unwrap();
            check_same(points, q, &[(i, d)], &[all[0].1]);
            assert_eq!(batch[qi].unwrap().1, d);
            for k in [1, 7, 30] {
                let got = index.knn(q, k);
                let want: Vec<f32> = all.iter().take(k).map(|e| e.1).collect();
                check_same(points, q, &got, &want);
            }
            let got = index.within(q, radius as f64);
            check_radius(points, q, &got, &all, radius, usize::MAX);
            let mut buf = Vec::new();
            for max_nn in [1, 5, 30, 100] {
                let got = index.hybrid(q, radius as f64, max_nn);
                check_radius(points, q, &got, &all, radius, max_nn);
                index.hybrid_sq_unsorted_into(q, radius as f64, max_nn, &mut buf);
                let mut got2: Vec<(usize, f32)> = buf.iter().map(|e| (e.0, e.1.sqrt())).collect();
                got2.sort_by(|a, b| a.1.total_cmp(&b.1));
                check_radius(points, q, &got2, &all, radius, max_nn);
            }
        }
    }

    #[test]
    fn queries_match_brute_force_on_random_points() {
        let mut rng = Lcg(7);
        let points: Vec<Point3<f32>> = (0..4000).map(|_| rng.point(2.0)).collect();
        // Queries both on indexed points (self at distance 0) and off them.
        let mut queries: Vec<Point3<f32>> = (0..150).map(|_| rng.point(2.2)).collect();
        queries.extend(points.iter().step_by(97).copied());
        exercise(&points, &queries, 0.2);
    }

    #[test]
    fn duplicates_and_tiny_sets() {
        let p = Point3::new(1.0f32, 2.0, 3.0);
        let points = vec![p, p, p, Point3::new(1.0, 2.0, 3.5)];
        let index = KdIndex::new(&points);
        let got = index.knn(&p, 10);
        assert_eq!(got.len(), 4);
        assert_eq!(got[..3].iter().map(|e| e.1).collect::<Vec<_>>(), [0.0; 3]);
        assert!((got[3].1 - 0.5).abs() < 1e-6 && got[3].0 == 3);
        assert_eq!(index.hybrid(&p, 0.1, 2).len(), 2);
        assert_eq!(index.within(&p, 0.5).len(), 4);
        assert_eq!(index.hybrid(&p, 1.0, 0).len(), 0);
        assert!(index.within(&p, -1.0).is_empty());
    }

    #[test]
    fn empty_index_answers_nothing() {
        let index = KdIndex::new(&[]);
        let q = Point3::new(0.0f32, 0.0, 0.0);
        assert!(index.is_empty());
        assert_eq!(index.nearest(&q), None);
        assert!(index.knn(&q, 3).is_empty());
        assert!(index.within(&q, 1.0).is_empty());
        assert!(index.hybrid(&q, 1.0, 10).is_empty());
        assert_eq!(index.nearest_batch(&[q, q]), vec![None, None]);
    }

    #[test]
    fn queries_match_brute_force_on_real_fragment() {
        let Some(pts) = fragment("cloud_bin_0.ply") else {
            return;
        };
        assert!(pts.len() > 200_000);
        // A 40k subset keeps the brute force cheap while keeping real local density.
        let points: Vec<Point3<f32>> = pts.iter().step_by(6).copied().collect();
        let mut queries: Vec<Point3<f32>> = points.iter().step_by(509).copied().collect();
        // Off-cloud queries: real points nudged by a few centimetres.
        let mut rng = Lcg(3);
        queries.extend(
            pts.iter()
                .step_by(4001)
                .map(|p| p + (rng.point(0.06).coords.add_scalar(-0.03))),
        );
        exercise(&points, &queries, 0.05);
    }
}
