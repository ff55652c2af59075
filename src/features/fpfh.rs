//! Fast Point Feature Histograms (Rusu et al. 2009), 33-D, computed exactly as Open3D's
//! `compute_fpfh_feature` (pipelines/registration/Feature.cpp):
//!
//! - **Neighbourhood** of p: Open3D's hybrid search (the `feature_max_nn` nearest points
//!   within `feature_radius`, p included), p itself then dropped.
//! - **Pair feature** of (p1, n1) -> (p2, n2), d = p2 - p1: the source of the Darboux frame
//!   is the point whose normal makes the smaller angle with the line (Open3D's test
//!   `acos|n1.d̂| > acos|n2.d̂|` swaps the roles and negates d). With u = n1, v = (d x u)/|d x u|,
//!   w = u x v: `f0 = atan2(w.n2, u.n2)` in [-pi, pi], `f1 = v.n2`, `f2 = u.d̂` (negated after a
//!   swap), both in [-1, 1]. Coincident points or d parallel to u give f = 0.
//! - **SPFH** of p: 11 bins each for f0, f1, f2 (bin = floor(11 (f0 + pi) / 2pi), floor(11 (f + 1) / 2),
//!   clamped), each neighbour adding 100 / k, so each sub-histogram sums to 100 (k >= 1).
//! - **FPFH** of p: `sum_k SPFH(p_k) / |p - p_k|^2` over its neighbours (Open3D weights by the
//!   inverse *squared* distance, skipping coincident neighbours), each 11-bin sub-histogram
//!   rescaled to sum 100, plus SPFH(p). Each non-isolated point's sub-histograms therefore sum
//!   to 200; a point with no neighbour gets an all-zero feature.
//!
//! The neighbourhoods are searched once and shared by the SPFH and FPFH passes (Open3D
//! searches twice). Everything runs in parallel with rayon.

use super::Features;
use crate::geometry::knn::KdIndex;
use crate::geometry::normals::{estimate_normals, orient_towards_viewpoint};
use crate::geometry::voxel::voxel_downsample;
use crate::geometry::PointCloud;
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use std::f64::consts::PI;

/// Feature dimension: three 11-bin histograms.
pub const FPFH_DIM: usize = 33;
const BINS: usize = 11;

/// Search parameters for normals and features (radii in metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FpfhParams {
    pub normal_radius: f64,
    pub normal_max_nn: usize,
    pub feature_radius: f64,
    pub feature_max_nn: usize,
}

impl FpfhParams {
    /// The settings of Open3D's registration examples for voxel size `v`: normals with
    /// radius 2v and at most 30 neighbours, features with radius 5v and at most 100.
    pub fn for_voxel(v: f64) -> Self {
        FpfhParams {
            normal_radius: 2.0 * v,
            normal_max_nn: 30,
            feature_radius: 5.0 * v,
            feature_max_nn: 100,
        }
    }
}

impl Default for FpfhParams {
    /// [`FpfhParams::for_voxel`] at the 3DMatch voxel size, 2.5 cm.
    fn default() -> Self {
        FpfhParams::for_voxel(0.025)
    }
}

/// The four pair values (f0, f1, f2, distance) of Open3D's `ComputePairFeatures`.
pub fn pair_features(
    p1: &Point3<f32>,
    n1: &Vector3<f32>,
    p2: &Point3<f32>,
    n2: &Vector3<f32>,
) -> [f64; 4] {
    let mut d = (p2 - p1).cast::<f64>();
    let dist = d.norm();
    if dist == 0.0 {
        return [0.0; 4];
    }
    let (mut u, mut m) = (n1.cast::<f64>(), n2.cast::<f64>());
    let a1 = u.dot(&d) / dist;
    let a2 = m.dot(&d) / dist;
    // Open3D: swap if acos|a1| > acos|a2|. acos is decreasing and NaN (|a| > 1 from
    // rounding) compares false, hence the range checks.
    let (c1, c2) = (a1.abs(), a2.abs());
    let f2 = if c1 <= 1.0 && c2 <= 1.0 && c1 < c2 {
        std::mem::swap(&mut u, &mut m);
        d = -d;
        -a2
    } else {
        a1
    };
    let v = d.cross(&u);
    let vn = v.norm();
    if vn == 0.0 {
        return [0.0; 4];
    }
    let v = v / vn;
    let w = u.cross(&v);
    [w.dot(&m).atan2(u.dot(&m)), v.dot(&m), f2, dist]
}

#[inline]
fn bin(x: f64) -> usize {
    // `as` saturates (NaN -> 0), matching Open3D's clamp to [0, 10].
    ((x.floor()) as i64).clamp(0, BINS as i64 - 1) as usize
}

/// Bin indices (0..33) of a pair feature in the SPFH layout.
#[inline]
pub fn pair_bins(f: &[f64; 4]) -> [usize; 3] {
    [
        bin(BINS as f64 * (f[0] + PI) / (2.0 * PI)),
        BINS + bin(BINS as f64 * (f[1] + 1.0) * 0.5),
        2 * BINS + bin(BINS as f64 * (f[2] + 1.0) * 0.5),
    ]
}

/// atan on [0, 1], Abramowitz & Stegun 4.4.49 (|error| <= 2e-8).
#[inline]
fn atan_unit(z: f64) -> f64 {
    let z2 = z * z;
    z * (0.9999993329
        + z2 * (-0.3332985605
            + z2 * (0.1994653599
                + z2 * (-0.1390853351
                    + z2 * (0.0964200441
                        + z2 * (-0.0559098861 + z2 * (0.0218612288 - z2 * 0.0040540580)))))))
}

/// The f0 bin position 11 (atan2(y, x) + pi) / 2pi. A polynomial atan2 is used unless
/// the result lies within 1e-6 of a bin edge (or is not finite), where libm's atan2
/// decides: the bin is then exactly the one `atan2` gives.
#[inline]
fn f0_position(y: f64, x: f64) -> f64 {
    const K: f64 = BINS as f64 / (2.0 * PI);
    let (ax, ay) = (x.abs(), y.abs());
    let (lo, hi) = if ay > ax { (ax, ay) } else { (ay, ax) };
    let mut a = atan_unit(lo / hi);
    if ay > ax {
        a = std::f64::consts::FRAC_PI_2 - a;
    }
    if x < 0.0 {
        a = PI - a;
    }
    if y < 0.0 {
        a = -a;
    }
    let t = K * (a + PI);
    let frac = t - t.floor();
    if t.is_finite() && frac > 1e-6 && frac < 1.0 - 1e-6 {
        t
    } else {
        K * (y.atan2(x) + PI)
    }
}

/// [`pair_bins`] of [`pair_features`], computed without normalising the frame vectors
/// and with the fast atan2 above; same bins (the tests check it against the plain path).
#[inline]
fn pair_bins_fast(
    p1: &Point3<f32>,
    n1: &Vector3<f32>,
    p2: &Point3<f32>,
    n2: &Vector3<f32>,
) -> [usize; 3] {
    const DEGENERATE: [usize; 3] = [5, BINS + 5, 2 * BINS + 5];
    let mut d = (p2 - p1).cast::<f64>();
    let dist = d.norm();
    if dist == 0.0 {
        return DEGENERATE;
    }
    let (mut u, mut m) = (n1.cast::<f64>(), n2.cast::<f64>());
    let a1 = u.dot(&d) / dist;
    let a2 = m.dot(&d) / dist;
    let (c1, c2) = (a1.abs(), a2.abs());
    let f2 = if c1 <= 1.0 && c2 <= 1.0 && c1 < c2 {
        std::mem::swap(&mut u, &mut m);
        d = -d;
        -a2
    } else {
        a1
    };
    let v = d.cross(&u);
    let vn = v.norm();
    if vn == 0.0 {
        return DEGENERATE;
    }
    // v and w = u x v are used unnormalised: divide the dot products instead.
    let w = u.cross(&v);
    let f1 = v.dot(&m) / vn;
    [
        bin(f0_position(w.dot(&m) / vn, u.dot(&m))),
        BINS + bin(BINS as f64 * (f1 + 1.0) * 0.5),
        2 * BINS + bin(BINS as f64 * (f2 + 1.0) * 0.5),
    ]
}

/// Per-point neighbour lists (self excluded) in compressed rows, with squared distances.
struct Neighbourhoods {
    start: Vec<usize>,
    idx: Vec<u32>,
    d2: Vec<f32>,
}

impl Neighbourhoods {
    fn search(points: &[Point3<f32>], index: &KdIndex, radius: f64, max_nn: usize) -> Self {
        // Chunks keep one growing buffer per task instead of one Vec per point.
        const CHUNK: usize = 512;
        let parts: Vec<(Vec<u32>, Vec<u32>, Vec<f32>)> = points
            .par_chunks(CHUNK)
            .enumerate()
            .map(|(c, chunk)| {
                let mut counts = Vec::with_capacity(chunk.len());
                let mut idx = Vec::with_capacity(chunk.len() * max_nn.min(64));
                let mut d2 = Vec::with_capacity(idx.capacity());
                let mut nb = Vec::new();
                for (o, p) in chunk.iter().enumerate() {
                    // a cancelled run searches no more (an empty neighbourhood per point);
                    // the stage discards what was computed
                    if crate::cancel::requested() {
                        counts.push(0);
                        continue;
                    }
                    let i = c * CHUNK + o;
                    index.hybrid_sq_unsorted_into(p, radius, max_nn, &mut nb);
                    let before = idx.len();
                    for &(j, d) in &nb {
                        if j != i {
                            idx.push(j as u32);
                            d2.push(d);
                        }
                    }
                    counts.push((idx.len() - before) as u32);
                }
                (counts, idx, d2)
            })
            .collect();
        let total: usize = parts.iter().map(|p| p.1.len()).sum();
        let mut start = Vec::with_capacity(points.len() + 1);
        let mut idx = Vec::with_capacity(total);
        let mut d2 = Vec::with_capacity(total);
        start.push(0);
        for (counts, i, d) in parts {
            for c in counts {
                let last = *start.last().unwrap_or(&0);
                start.push(last + c as usize);
            }
            idx.extend_from_slice(&i);
            d2.extend_from_slice(&d);
        }
        Neighbourhoods { start, idx, d2 }
    }

    #[inline]
    fn of(&self, i: usize) -> (&[u32], &[f32]) {
        let r = self.start[i]..self.start[i + 1];
        (&self.idx[r.clone()], &self.d2[r])
    }
}

fn spfh_from(points: &[Point3<f32>], normals: &[Vector3<f32>], nbh: &Neighbourhoods) -> Vec<f32> {
    let mut out = vec![0.0f32; points.len() * FPFH_DIM];
    out.par_chunks_mut(FPFH_DIM).enumerate().for_each(|(i, h)| {
        let (nb, _) = nbh.of(i);
        if nb.is_empty() || crate::cancel::requested() {
            return;
        }
        let incr = 100.0 / nb.len() as f64;
        let mut acc = [0.0f64; FPFH_DIM];
        for &j in nb {
            let j = j as usize;
            for b in pair_bins_fast(&points[i], &normals[i], &points[j], &normals[j]) {
                acc[b] += incr;
            }
        }
        for (o, a) in h.iter_mut().zip(acc) {
            *o = a as f32;
        }
    });
    out
}

fn check_inputs(points: &[Point3<f32>], normals: &[Vector3<f32>], index: &KdIndex) {
    assert_eq!(
        points.len(),
        normals.len(),
        "FPFH: one normal per point required"
    );
    assert_eq!(
        points.len(),
        index.len(),
        "FPFH: the index must be built over `points`"
    );
}

/// Simplified point feature histograms (the SPFH stage alone), N x 33.
///
/// # Panics
/// When `normals` or `index` do not have one entry per point (a caller bug, not bad data).
pub fn compute_spfh(
    points: &[Point3<f32>],
    normals: &[Vector3<f32>],
    index: &KdIndex,
    params: &FpfhParams,
) -> Features {
    check_inputs(points, normals, index);
    let nbh = Neighbourhoods::search(points, index, params.feature_radius, params.feature_max_nn);
    Features::new(FPFH_DIM, spfh_from(points, normals, &nbh))
}

/// FPFH features (N x 33, see the module docs) of `points` with their `normals`, using
/// `params.feature_radius` / `feature_max_nn` (the normal parameters are not used here).
///
/// # Panics
/// When `normals` or `index` do not have one entry per point (a caller bug, not bad data).
pub fn compute_fpfh(
    points: &[Point3<f32>],
    normals: &[Vector3<f32>],
    index: &KdIndex,
    params: &FpfhParams,
) -> Features {
    check_inputs(points, normals, index);
    let nbh = Neighbourhoods::search(points, index, params.feature_radius, params.feature_max_nn);
    let spfh = spfh_from(points, normals, &nbh);
    let mut out = vec![0.0f32; points.len() * FPFH_DIM];
    out.par_chunks_mut(FPFH_DIM).enumerate().for_each(|(i, h)| {
        let (nb, d2) = nbh.of(i);
        if nb.is_empty() || crate::cancel::requested() {
            return;
        }
        let mut acc = [0.0f32; FPFH_DIM];
        for (&j, &d) in nb.iter().zip(d2) {
            if d == 0.0 {
                continue;
            }
            let w = 1.0 / d;
            let s = &spfh[j as usize * FPFH_DIM..(j as usize + 1) * FPFH_DIM];
            for (a, v) in acc.iter_mut().zip(s) {
                *a += v * w;
            }
        }
        let own = &spfh[i * FPFH_DIM..(i + 1) * FPFH_DIM];
        for k in 0..3 {
            let r = k * BINS..(k + 1) * BINS;
            let sum: f32 = acc[r.clone()].iter().sum();
            let scale = if sum != 0.0 { 100.0 / sum } else { 0.0 };
            for b in r {
                h[b] = acc[b] * scale + own[b];
            }
        }
    });
    Features::new(FPFH_DIM, out)
}

/// The usual geometric-branch pipeline for one fragment: voxel downsampling at `voxel`
/// metres, normals (radius 2 voxel, 30 neighbours) oriented towards the origin (the
/// fragment's camera), then FPFH with [`FpfhParams::for_voxel`]. Returns the downsampled
/// cloud, with its normals set, and one feature row per downsampled point. A non-positive
/// voxel keeps every point but then gives zero-radius searches (all-zero features).
pub fn fpfh_for_cloud(cloud: &PointCloud, voxel: f64) -> (PointCloud, Features) {
    let mut down = voxel_downsample(cloud, voxel);
    let params = FpfhParams::for_voxel(voxel.max(0.0));
    let index = KdIndex::new(&down.points);
    let mut normals = estimate_normals(
        &down.points,
        &index,
        params.normal_radius,
        params.normal_max_nn,
    );
    orient_towards_viewpoint(&down.points, &mut normals, Point3::origin());
    let feats = compute_fpfh(&down.points, &normals, &index, &params);
    down.normals = Some(normals);
    (down, feats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::knn::tests::fragment;
    use crate::testing::Lcg;
    use nalgebra::{Isometry3, Vector3};

    const S: f64 = std::f64::consts::FRAC_1_SQRT_2;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-6
    }

    #[test]
    fn hand_checked_pair_features() {
        let o = Point3::origin();
        let z = Vector3::z();
        // n2 makes the smaller angle with the line, so the frame starts at p2:
        // u = n2, d = (-1, 0, 0), v = (0, 1, 0), w = (-s, 0, s):
        // f0 = atan2(w.n1, u.n1) = atan2(s, s) = pi/4, f1 = v.n1 = 0, f2 = -n2.d̂ = -s.
        let n2 = Vector3::new(1.0f32, 0.0, 1.0).normalize();
        let f = pair_features(&o, &z, &Point3::new(1.0, 0.0, 0.0), &n2);
        assert!(close(f[0], PI / 4.0) && close(f[1], 0.0) && close(f[2], -S) && close(f[3], 1.0));
        // floor(11 * 0.625) = 6; floor(5.5) = 5; floor(11 * (1 - s) / 2) = 1.
        assert_eq!(pair_bins(&f), [6, 11 + 5, 22 + 1]);
        // No swap: p1's normal is more aligned with d = (0, 2, 0).
        // u = (0, s, s), v = d x u / |..| = (1, 0, 0), w = u x v = (0, s, -s);
        // n2 = x: f0 = atan2(0, 0) = 0, f1 = 1, f2 = s.
        let n1 = Vector3::new(0.0f32, 1.0, 1.0).normalize();
        let f = pair_features(&o, &n1, &Point3::new(0.0, 2.0, 0.0), &Vector3::x());
        assert!(close(f[0], 0.0) && close(f[1], 1.0) && close(f[2], S) && close(f[3], 2.0));
        assert_eq!(pair_bins(&f), [5, 11 + 10, 22 + 9]);
        // Degenerate pairs: coincident points; line along the normal.
        assert_eq!(pair_features(&o, &z, &o, &z), [0.0; 4]);
        assert_eq!(
            pair_features(&o, &z, &Point3::new(0.0, 0.0, 1.0), &z),
            [0.0; 4]
        );
        assert_eq!(pair_bins(&[0.0; 4]), [5, 16, 27]);
    }

    #[test]
    fn fast_pair_bins_equal_plain_ones() {
        // Polynomial atan against libm on a dense sweep of angles.
        let mut max_err = 0.0f64;
        for k in 0..200_001 {
            let th = -PI + 2.0 * PI * k as f64 / 200_000.0;
            let (y, x) = (th.sin() * 3.0, th.cos() * 3.0);
            let t = f0_position(y, x);
            let want = BINS as f64 * (y.atan2(x) + PI) / (2.0 * PI);
            max_err = max_err.max((t - want).abs());
            assert_eq!(bin(t), bin(want), "theta {th}");
        }
        assert!(max_err < 1e-7, "{max_err}");
        // Exact edges (signed zeros included) go through libm.
        for (y, x) in [
            (0.0, -1.0),
            (-0.0, -1.0),
            (0.0, 0.0),
            (-0.0, -0.0),
            (0.0, 1.0),
        ] {
            assert_eq!(
                bin(f0_position(y, x)),
                bin(BINS as f64 * (f64::atan2(y, x) + PI) / (2.0 * PI))
            );
        }
        // Full pair features on random oriented pairs, including near-degenerate ones.
        let mut rng = Lcg(9);
        let mut unit = || {
            let v = Vector3::new(
                rng.unit_f32() - 0.5,
                rng.unit_f32() - 0.5,
                rng.unit_f32() - 0.5,
            );
            v.normalize()
        };
        for t in 0..200_000 {
            let (n1, n2) = (unit(), unit());
            let p1 = Point3::new(0.1f32, -0.2, 0.3);
            let p2 = match t % 4 {
                0 => p1 + n1 * 0.05, // line along n1
                1 => p1,
                _ => p1 + unit() * 0.07,
            };
            let plain = pair_bins(&pair_features(&p1, &n1, &p2, &n2));
            assert_eq!(pair_bins_fast(&p1, &n1, &p2, &n2), plain, "pair {t}");
        }
    }

    /// A wavy height field with PCA normals oriented upwards.
    fn wavy(n: usize, seed: u64) -> (Vec<Point3<f32>>, Vec<Vector3<f32>>) {
        let mut rng = Lcg(seed);
        let pts: Vec<Point3<f32>> = (0..n)
            .map(|_| {
                let (x, y) = (2.0 * rng.unit_f32(), 2.0 * rng.unit_f32());
                let z = 0.15 * (3.0 * x).sin() * (2.0 * y).cos() + 0.05 * (7.0 * y).sin();
                Point3::new(x, y, z)
            })
            .collect();
        let index = KdIndex::new(&pts);
        let mut ns = estimate_normals(&pts, &index, 0.05, 30);
        orient_towards_viewpoint(&pts, &mut ns, Point3::new(1.0, 1.0, 10.0));
        (pts, ns)
    }

    /// Open3D's algorithm written plainly over brute-force neighbourhoods.
    fn brute_fpfh(pts: &[Point3<f32>], ns: &[Vector3<f32>], r: f32, max_nn: usize) -> Vec<f64> {
        let nbrs: Vec<Vec<(usize, f32)>> = (0..pts.len())
            .map(|i| {
                let mut v: Vec<(usize, f32)> = (0..pts.len())
                    .map(|j| (j, (pts[j] - pts[i]).norm()))
                    .filter(|e| e.1 <= r)
                    .collect();
                v.sort_by(|a, b| a.1.total_cmp(&b.1));
                v.truncate(max_nn);
                v.retain(|e| e.0 != i);
                v
            })
            .collect();
        let mut spfh = vec![0.0f64; pts.len() * 33];
        for i in 0..pts.len() {
            for &(j, _) in &nbrs[i] {
                for b in pair_bins(&pair_features(&pts[i], &ns[i], &pts[j], &ns[j])) {
                    spfh[i * 33 + b] += 100.0 / nbrs[i].len() as f64;
                }
            }
        }
        let mut out = vec![0.0f64; pts.len() * 33];
        for i in 0..pts.len() {
            if nbrs[i].is_empty() {
                continue;
            }
            let mut acc = [0.0f64; 33];
            for &(j, d) in &nbrs[i] {
                for b in 0..33 {
                    acc[b] += spfh[j * 33 + b] / (d as f64 * d as f64);
                }
            }
            for b in 0..33 {
                let sum: f64 = acc[b / 11 * 11..b / 11 * 11 + 11].iter().sum();
                out[i * 33 + b] = acc[b] * 100.0 / sum + spfh[i * 33 + b];
            }
        }
        out
    }

    #[test]
    fn matches_plain_implementation_and_histograms_sum() {
        let (pts, ns) = wavy(3000, 1);
        let index = KdIndex::new(&pts);
        let params = FpfhParams::default();
        let f = compute_fpfh(&pts, &ns, &index, &params);
        let want = brute_fpfh(&pts, &ns, params.feature_radius as f32, 100);
        assert_eq!(f.len(), pts.len());
        assert_eq!(f.dim, 33);
        let max_diff = f
            .data
            .iter()
            .zip(&want)
            .map(|(a, b)| (*a as f64 - b).abs())
            .fold(0.0, f64::max);
        assert!(max_diff < 1e-3, "max diff {max_diff}");
        let spfh = compute_spfh(&pts, &ns, &index, &params);
        for i in 0..pts.len() {
            for k in 0..3 {
                let s: f32 = spfh.row(i)[k * 11..k * 11 + 11].iter().sum();
                assert!((s - 100.0).abs() < 1e-3, "spfh sum {s}");
                let s: f32 = f.row(i)[k * 11..k * 11 + 11].iter().sum();
                assert!((s - 200.0).abs() < 1e-3, "fpfh sum {s}");
            }
        }
        // An isolated point has an all-zero feature.
        let mut pts2 = pts.clone();
        pts2.push(Point3::new(50.0, 50.0, 50.0));
        let mut ns2 = ns.clone();
        ns2.push(Vector3::z());
        let f2 = compute_fpfh(&pts2, &ns2, &KdIndex::new(&pts2), &params);
        assert!(f2.row(pts.len()).iter().all(|&v| v == 0.0));
        // The other points are unaffected (up to summation order).
        let d = f
            .data
            .iter()
            .zip(&f2.data)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(d < 1e-3, "{d}");
    }

    fn max_abs_diff(a: &Features, b: &Features) -> f32 {
        a.data
            .iter()
            .zip(&b.data)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max)
    }

    fn spfh_and_fpfh(pts: &[Point3<f32>], ns: &[Vector3<f32>]) -> (Features, Features) {
        let idx = KdIndex::new(pts);
        let params = FpfhParams::default();
        (
            compute_spfh(pts, ns, &idx, &params),
            compute_fpfh(pts, ns, &idx, &params),
        )
    }

    #[test]
    fn invariant_under_exact_rigid_motion() {
        // Points on a 2^-12 m grid moved by a signed axis permutation (a proper rotation)
        // and a dyadic translation: the motion is exact in f32, so SPFH and FPFH must agree.
        let q = 4096.0f32;
        let (pts, ns) = wavy(4000, 2);
        let pts: Vec<Point3<f32>> = pts.iter().map(|p| (p * q).map(f32::round) / q).collect();
        let mv = |v: &Vector3<f32>| Vector3::new(-v.z, -v.x, v.y);
        let pts_t: Vec<Point3<f32>> = pts
            .iter()
            .map(|p| Point3::from(mv(&p.coords) + Vector3::new(1.5, -2.25, 3.0)))
            .collect();
        let ns_t: Vec<Vector3<f32>> = ns.iter().map(mv).collect();
        let (s0, f0) = spfh_and_fpfh(&pts, &ns);
        let (s1, f1) = spfh_and_fpfh(&pts_t, &ns_t);
        assert!(max_abs_diff(&s0, &s1) < 1e-3);
        assert!(max_abs_diff(&f0, &f1) < 1e-3);
    }

    #[test]
    fn nearly_invariant_under_general_rigid_motion() {
        // A general rotation rounds every coordinate in f32; a pair value within ~1e-5 of a
        // bin edge can then change bin (as in Open3D), so most, not all, rows are equal.
        let (pts, ns) = wavy(4000, 3);
        let t = Isometry3::new(
            Vector3::new(3.0f32, -1.5, 7.0),
            Vector3::new(0.4, -1.1, 2.3),
        );
        let pts_t: Vec<Point3<f32>> = pts.iter().map(|p| t * p).collect();
        let ns_t: Vec<Vector3<f32>> = ns.iter().map(|n| t.rotation * n).collect();
        let (s0, f0) = spfh_and_fpfh(&pts, &ns);
        let (s1, f1) = spfh_and_fpfh(&pts_t, &ns_t);
        for (a, b) in [(s0, s1), (f0, f1)] {
            let rows_equal = (0..a.len())
                .filter(|&i| {
                    a.row(i)
                        .iter()
                        .zip(b.row(i))
                        .all(|(x, y)| (x - y).abs() < 1e-3)
                })
                .count();
            let mean = a
                .data
                .iter()
                .zip(&b.data)
                .map(|(x, y)| (x - y).abs())
                .sum::<f32>()
                / a.data.len() as f32;
            assert!(
                rows_equal as f64 > 0.97 * a.len() as f64,
                "{rows_equal} rows equal"
            );
            assert!(mean < 1e-2, "mean difference {mean}");
            // One flipped pair moves 100/k between neighbouring bins: bounded.
            assert!(max_abs_diff(&a, &b) < 10.0);
        }
    }

    fn feature_nn(f: &Features, q: &[f32]) -> usize {
        (0..f.len())
            .map(|j| {
                let d: f32 = f.row(j).iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum();
                (j, d)
            })
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|e| e.0)
            .unwrap()
    }

    /// Over sampled overlapping source points: the fraction whose feature nearest neighbour
    /// in the target lies within 10 cm of the ground-truth position, and the same fraction
    /// among the mutual nearest neighbours (with their count).
    fn match_ratio(
        src: &(PointCloud, Features),
        tgt: &(PointCloud, Features),
        target_from_source: &Isometry3<f32>,
        keep: impl Fn(&Point3<f32>) -> bool,
    ) -> (f64, f64, usize) {
        let tidx = KdIndex::new(&tgt.0.points);
        let overlap: Vec<usize> = (0..src.0.len())
            .filter(|&i| keep(&src.0.points[i]))
            .filter(|&i| {
                let p = target_from_source * src.0.points[i];
                tidx.nearest(&p).is_some_and(|(_, d)| d < 0.025)
            })
            .collect();
        let sample: Vec<usize> = overlap
            .iter()
            .step_by((overlap.len() / 600).max(1))
            .copied()
            .collect();
        let res: Vec<(bool, bool)> = sample
            .par_iter()
            .map(|&i| {
                let j = feature_nn(&tgt.1, src.1.row(i));
                let ok = (tgt.0.points[j] - target_from_source * src.0.points[i]).norm() < 0.1;
                (ok, feature_nn(&src.1, tgt.1.row(j)) == i)
            })
            .collect();
        let good = res.iter().filter(|r| r.0).count();
        let mutual = res.iter().filter(|r| r.1).count();
        let mutual_good = res.iter().filter(|r| r.0 && r.1).count();
        (
            good as f64 / res.len() as f64,
            mutual_good as f64 / mutual.max(1) as f64,
            mutual,
        )
    }

    #[test]
    fn matching_two_views_of_a_real_scene() {
        let (Some(p0), Some(p4)) = (fragment("cloud_bin_0.ply"), fragment("cloud_bin_4.ply"))
        else {
            return;
        };
        // (a) Two views of the same scene: disjoint halves of fragment 0's points, cropped to
        // overlapping slabs, one moved rigidly. Different samples give different voxel
        // centroids, so only the local geometry is shared.
        let xs: Vec<f32> = p0.iter().map(|p| p.x).collect();
        let mid = xs.iter().sum::<f32>() / xs.len() as f32;
        let a = PointCloud::from_points(
            p0.iter()
                .step_by(2)
                .filter(|p| p.x < mid + 0.4)
                .copied()
                .collect(),
        );
        let b_local: Vec<Point3<f32>> = p0
            .iter()
            .skip(1)
            .step_by(2)
            .filter(|p| p.x > mid - 0.4)
            .copied()
            .collect();
        let moved = Isometry3::new(
            Vector3::new(0.2f32, -0.1, 0.3),
            Vector3::new(0.1, 0.3, -0.2),
        );
        let b = PointCloud::from_points(b_local.iter().map(|p| moved * p).collect());
        let fa = fpfh_for_cloud(&a, 0.025);
        let fb = fpfh_for_cloud(&b, 0.025);
        // Score points at least a feature radius inside both crops, where the two views
        // see the same neighbourhoods.
        let back = moved.inverse();
        let inside = |p: &Point3<f32>| ((back * p).x - mid).abs() < 0.25;
        let (r, rm, m) = match_ratio(&fb, &fa, &back, inside);
        eprintln!(
            "two halves: {:.1} % of NN, {:.1} % of {m} mutual NN within 10 cm",
            100.0 * r,
            100.0 * rm
        );
        assert!(r > 0.4 && rm > 0.5 && m > 100, "{r} {rm} {m}");

        // (b) The real 3DMatch pair (0, 4): gt.log "0 4" gives p_0 = T p_4.
        #[rustfmt::skip]
        let t = nalgebra::Matrix4::new(
            9.79957209e-01, -8.09359517e-02, 1.81876614e-01, -8.65004597e-02,
            9.80194727e-02, 9.91351448e-01, -8.69879436e-02, -4.58251665e-01,
            -1.73272374e-01, 1.03077496e-01, 9.79441054e-01, 5.07580899e-01,
            0.0, 0.0, 0.0, 1.0,
        );
        let t = crate::geometry::transform::isometry_from_matrix(&t)
            .unwrap()
            .cast::<f32>();
        let f0 = fpfh_for_cloud(&PointCloud::from_points(p0), 0.025);
        let f4 = fpfh_for_cloud(&PointCloud::from_points(p4), 0.025);
        let (r, rm, m) = match_ratio(&f4, &f0, &t, |_| true);
        eprintln!(
            "3DMatch 0-4: {:.1} % of NN, {:.1} % of {m} mutual NN within 10 cm",
            100.0 * r,
            100.0 * rm
        );
        // FPFH's inlier ratio on 3DMatch is low (a few to ~15 %); chance is < 1 %.
        assert!(r > 0.08 && rm > 0.08, "{r} {rm}");
    }
}
