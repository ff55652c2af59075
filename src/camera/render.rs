//! Depth rendering of point clouds by z-buffered point splatting, for inputs that are only
//! point clouds (virtual pinhole trajectory) and for LiDAR (the f-theta camera).
//!
//! Each point is drawn as a square of `(2r+1)^2` pixels at its own depth, nearest wins. The
//! half-width `r` is chosen so that neighbouring points' squares touch, which closes sampled
//! surfaces: `r = ceil(0.5 * spacing * pixels_per_radian / range)`, capped at `max_radius_px`,
//! where `spacing` is the cloud's point spacing (given, or the median nearest-neighbour
//! distance of up to 2,000 sampled points). Squares are flat, so a slanted surface is drawn a
//! few millimetres nearer than it is near its points' neighbours; that error is at most about
//! half the point spacing times the slope.
//!
//! Pixel convention: integer (u, v) are pixel centres (OpenCV), so a point lands in pixel
//! `(round(u), round(v))`, the inverse of `Intrinsics::backproject(u, v, z)`.
//!
//! Output: `DepthImage` in millimetres (16 bit, 0 = nothing drawn). Pinhole images store z along
//! the optical axis (like the sensor); f-theta images store the range along the ray (a
//! wide-angle ray can have z <= 0). Depths outside [1, 65534] mm are not drawn.

use crate::camera::Intrinsics;
use crate::io::depth_png::DepthImage;
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SplatOptions {
    /// Point spacing in metres; None estimates it from the cloud.
    pub point_spacing: Option<f32>,
    /// Largest splat half-width in pixels (keeps a stray near point from blotting the image).
    pub max_radius_px: u32,
    /// A point counts as visible when its depth is within this many metres (or 1 % of its
    /// depth, whichever is larger) of the z-buffer.
    pub visibility_tolerance: f32,
}

impl Default for SplatOptions {
    fn default() -> Self {
        SplatOptions {
            point_spacing: None,
            max_radius_px: 8,
            visibility_tolerance: 0.05,
        }
    }
}

/// Median distance from a point to its nearest neighbour, over up to 2,000 evenly strided
/// sample points. None for fewer than two distinct points.
pub fn estimate_point_spacing(points: &[Point3<f32>]) -> Option<f32> {
    use kiddo::{ImmutableKdTree, SquaredEuclidean};
    use std::num::NonZero;
    let pts: Vec<[f32; 3]> = points
        .iter()
        .filter(|p| p.coords.iter().all(|c| c.is_finite()))
        .map(|p| [p.x, p.y, p.z])
        .collect();
    if pts.len() < 2 {
        return None;
    }
    let tree = ImmutableKdTree::<f32, 3>::new_from_slice(&pts).ok()?;
    let stride = (pts.len() / 2000).max(1);
    let n = NonZero::new(2usize)?;
    let mut d: Vec<f32> = pts
        .iter()
        .step_by(stride)
        .filter_map(|q| {
            let r = tree
                .query(q)
                .nearest_n::<SquaredEuclidean<f32>>(n)
                .execute();
            // Skip the query point itself (and exact duplicates).
            r.iter()
                .map(|x| x.distance)
                .find(|&x| x > 0.0)
                .map(f32::sqrt)
        })
        .collect();
    if d.is_empty() {
        return None;
    }
    let mid = d.len() / 2;
    d.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    Some(d[mid])
}

/// A point ready for splatting: pixel position, depth (mm) and half-width.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Splat {
    pub u: f64,
    pub v: f64,
    pub mm: u32,
    pub r: i64,
}

pub(crate) fn to_mm(d: f64) -> Option<u32> {
    let mm = (d * 1000.0).round();
    (1.0..=65534.0).contains(&mm).then_some(mm as u32)
}

/// Z-buffer of the splats, row-major, u32::MAX where nothing was drawn.
pub(crate) fn splat_zbuffer(width: u32, height: u32, splats: &[Option<Splat>]) -> Vec<u32> {
    let (w, h) = (width as i64, height as i64);
    let mut zbuf = vec![u32::MAX; (w * h) as usize];
    if w == 0 || h == 0 {
        return zbuf;
    }
    // Bands of rows in parallel, each drawing the squares that reach it (binned once, in one
    // pass) with a plain minimum: a pixel's value is the least depth drawn on it whatever the
    // order, so the image is the one per-pixel atomic minima gave, without their contention.
    let bands = (rayon::current_num_threads() * 4).clamp(1, h as usize) as i64;
    let rows = (h + bands - 1) / bands;
    let mut bins: Vec<Vec<(i64, i64, i64, u32)>> = vec![Vec::new(); bands as usize];
    for s in splats.iter().flatten() {
        // OpenCV convention: integer coordinates are pixel centres.
        let (pu, pv) = (s.u.round() as i64, s.v.round() as i64);
        if s.r < 0 || pu + s.r < 0 || pv + s.r < 0 || pu - s.r >= w || pv - s.r >= h {
            continue;
        }
        let (first, last) = ((pv - s.r).max(0) / rows, (pv + s.r).min(h - 1) / rows);
        for b in &mut bins[first as usize..=last as usize] {
            b.push((pu, pv, s.r, s.mm));
        }
    }
    zbuf.par_chunks_mut((rows * w) as usize)
        .zip(bins.par_iter())
        .enumerate()
        .for_each(|(t, (band, squares))| {
            let y0 = t as i64 * rows;
            let y1 = (y0 + rows).min(h) - 1;
            for &(pu, pv, r, mm) in squares {
                let (ya, yb) = ((pv - r).max(y0), (pv + r).min(y1));
                let (xa, xb) = ((pu - r).max(0) as usize, (pu + r).min(w - 1) as usize);
                for y in ya..=yb {
                    let row = ((y - y0) * w) as usize;
                    for z in &mut band[row + xa..=row + xb] {
                        *z = (*z).min(mm);
                    }
                }
            }
        });
    zbuf
}

pub(crate) fn zbuffer_to_depth(width: u32, height: u32, z: Vec<u32>) -> DepthImage {
    DepthImage {
        width,
        height,
        data: z
            .into_iter()
            .map(|v| if v == u32::MAX { 0 } else { v as u16 })
            .collect(),
    }
}

/// Visible = projects into the image, and its depth is within tolerance of the z-buffer.
pub(crate) fn visible_from_zbuffer(
    width: u32,
    height: u32,
    zbuf: &[u32],
    splats: &[Option<Splat>],
    opts: &SplatOptions,
) -> Vec<bool> {
    splats
        .par_iter()
        .map(|s| {
            let Some(s) = s else { return false };
            let (x, y) = (s.u.round(), s.v.round());
            if x < 0.0 || y < 0.0 || x >= width as f64 || y >= height as f64 {
                return false;
            }
            let z = zbuf[(y as usize) * width as usize + x as usize];
            let tol = (opts.visibility_tolerance * 1000.0).max(0.01 * s.mm as f32);
            (s.mm as f32) <= z as f32 + tol
        })
        .collect()
}

fn pinhole_splats(
    points: &[Point3<f32>],
    intr: &Intrinsics,
    camera_from_scan: &Isometry3<f64>,
    opts: &SplatOptions,
) -> Vec<Option<Splat>> {
    let spacing = opts
        .point_spacing
        .or_else(|| estimate_point_spacing(points))
        .unwrap_or(0.0) as f64;
    let f = intr.fx.max(intr.fy);
    points
        .par_iter()
        .map(|p| {
            let q = camera_from_scan * p.cast::<f64>();
            let (u, v) = intr.project(&q)?;
            if !(u.is_finite() && v.is_finite()) {
                return None;
            }
            let mm = to_mm(q.z)?;
            let r = (0.5 * spacing * f / q.z)
                .ceil()
                .min(opts.max_radius_px as f64) as i64;
            Some(Splat { u, v, mm, r })
        })
        .collect()
}

/// Render a depth image (z in mm) of `points` (scan coordinates) seen by a pinhole camera
/// with pose `camera_from_scan`, splat size from the estimated point spacing.
pub fn render_depth(
    points: &[Point3<f32>],
    intr: &Intrinsics,
    camera_from_scan: &Isometry3<f64>,
) -> DepthImage {
    render_depth_with(points, intr, camera_from_scan, &SplatOptions::default())
}

pub fn render_depth_with(
    points: &[Point3<f32>],
    intr: &Intrinsics,
    camera_from_scan: &Isometry3<f64>,
    opts: &SplatOptions,
) -> DepthImage {
    let splats = pinhole_splats(points, intr, camera_from_scan, opts);
    let z = splat_zbuffer(intr.width, intr.height, &splats);
    zbuffer_to_depth(intr.width, intr.height, z)
}

/// Which points a pinhole camera sees (inside the image and not hidden behind nearer points).
pub fn visibility_pinhole(
    points: &[Point3<f32>],
    intr: &Intrinsics,
    camera_from_scan: &Isometry3<f64>,
    opts: &SplatOptions,
) -> Vec<bool> {
    let splats = pinhole_splats(points, intr, camera_from_scan, opts);
    let z = splat_zbuffer(intr.width, intr.height, &splats);
    visible_from_zbuffer(intr.width, intr.height, &z, &splats, opts)
}

/// A camera frustum for display, in scan coordinates: the camera centre and the image border
/// pushed out to `depth` (corners first: top-left, top-right, bottom-right, bottom-left, then
/// the whole border as a closed polyline).
#[derive(Clone, Debug, PartialEq)]
pub struct Frustum {
    pub apex: Point3<f64>,
    pub corners: [Point3<f64>; 4],
    pub border: Vec<Point3<f64>>,
}

/// The outer edge of an image of size w x h (pixel centres at integers, so the edge runs from
/// -0.5 to w - 0.5), `per_side` samples per side, clockwise from the top-left corner.
pub(crate) fn border_pixels(w: f64, h: f64, per_side: usize) -> Vec<(f64, f64)> {
    let n = per_side.max(1);
    let mut out = Vec::with_capacity(4 * n);
    let t = |i: usize| i as f64 / n as f64;
    for i in 0..n {
        out.push((-0.5 + w * t(i), -0.5));
    }
    for i in 0..n {
        out.push((w - 0.5, -0.5 + h * t(i)));
    }
    for i in 0..n {
        out.push((w - 0.5 - w * t(i), h - 0.5));
    }
    for i in 0..n {
        out.push((-0.5, h - 0.5 - h * t(i)));
    }
    out
}

/// Pinhole frustum at `depth` metres (z along the axis).
pub fn pinhole_frustum(
    intr: &Intrinsics,
    camera_from_scan: &Isometry3<f64>,
    depth: f64,
) -> Frustum {
    let scan_from_camera = camera_from_scan.inverse();
    let at = |u: f64, v: f64| scan_from_camera * intr.backproject(u, v, depth);
    let (w, h) = (intr.width as f64, intr.height as f64);
    Frustum {
        apex: scan_from_camera * Point3::origin(),
        corners: [
            at(-0.5, -0.5),
            at(w - 0.5, -0.5),
            at(w - 0.5, h - 0.5),
            at(-0.5, h - 0.5),
        ],
        border: border_pixels(w, h, 1)
            .into_iter()
            .map(|(u, v)| at(u, v))
            .collect(),
    }
}

/// A camera pose looking from `eye` at `target`: returns `scan_from_camera` with OpenCV axes
/// (x right, y down, z forward); `up` is the scan's up direction. None when the view direction
/// is parallel to `up` or the points coincide.
pub fn look_at(
    eye: &Point3<f64>,
    target: &Point3<f64>,
    up: &Vector3<f64>,
) -> Option<Isometry3<f64>> {
    let z = (target - eye).try_normalize(1e-12)?;
    let x = (-up).cross(&z).try_normalize(1e-9)?;
    let y = z.cross(&x);
    let m = nalgebra::Matrix3::from_columns(&[x, y, z]);
    let rot = nalgebra::UnitQuaternion::from_rotation_matrix(
        &nalgebra::Rotation3::from_matrix_unchecked(m),
    );
    Some(Isometry3::from_parts(eye.coords.into(), rot))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kinect() -> Intrinsics {
        Intrinsics {
            fx: 585.0,
            fy: 585.0,
            cx: 320.0,
            cy: 240.0,
            width: 640,
            height: 480,
        }
    }

    /// A grid of points on z = z0 (camera frame) with spacing s.
    fn plane(z0: f32, half_w: f32, half_h: f32, s: f32) -> Vec<Point3<f32>> {
        let (nx, ny) = ((2.0 * half_w / s) as i32, (2.0 * half_h / s) as i32);
        (0..=nx)
            .flat_map(|i| {
                (0..=ny)
                    .map(move |j| Point3::new(-half_w + i as f32 * s, -half_h + j as f32 * s, z0))
            })
            .collect()
    }

    /// The banded z-buffer against per-splat minima drawn one by one: squares inside, across
    /// and outside the borders, several depths per pixel, heights that the bands do not divide.
    #[test]
    fn the_zbuffer_is_the_least_depth_drawn_on_each_pixel() {
        let mut rng = crate::testing::Lcg(5);
        for (w, h) in [(37u32, 23u32), (64, 48), (5, 1), (1, 7)] {
            let splats: Vec<Option<Splat>> = (0..600)
                .map(|k| {
                    let f = |rng: &mut crate::testing::Lcg, lo: f32, hi: f32| {
                        (lo + (hi - lo) * rng.unit_f32()) as f64
                    };
                    (k % 9 != 0).then(|| Splat {
                        u: f(&mut rng, -12.0, w as f32 + 12.0),
                        v: f(&mut rng, -12.0, h as f32 + 12.0),
                        mm: 1 + (rng.unit_f32() * 5000.0) as u32,
                        r: (rng.unit_f32() * 9.0) as i64,
                    })
                })
                .collect();
            let (wi, hi) = (w as i64, h as i64);
            let mut want = vec![u32::MAX; (w * h) as usize];
            for s in splats.iter().flatten() {
                let (pu, pv) = (s.u.round() as i64, s.v.round() as i64);
                for y in (pv - s.r).max(0)..=(pv + s.r).min(hi - 1) {
                    for x in (pu - s.r).max(0)..=(pu + s.r).min(wi - 1) {
                        let z = &mut want[(y * wi + x) as usize];
                        *z = (*z).min(s.mm);
                    }
                }
            }
            let got = splat_zbuffer(w, h, &splats);
            assert_eq!(got, want, "{w} x {h}");
            assert!(got.iter().any(|&z| z != u32::MAX));
        }
        assert!(splat_zbuffer(0, 4, &[]).is_empty());
    }

    #[test]
    fn spacing_of_a_grid() {
        let s = estimate_point_spacing(&plane(2.0, 1.0, 1.0, 0.02)).unwrap();
        assert!((s - 0.02).abs() < 1e-4, "{s}");
        assert_eq!(estimate_point_spacing(&[Point3::origin()]), None);
    }

    #[test]
    fn fronto_parallel_plane_is_closed_and_exact() {
        // 3 m x 2 m at 2 m fills more than the 640x480 view (which spans 2.19 x 1.64 m).
        let pts = plane(2.0, 1.5, 1.0, 0.015);
        let d = render_depth(&pts, &kinect(), &Isometry3::identity());
        assert_eq!(d.valid_count(), 640 * 480, "holes in a closed surface");
        assert!(d.data.iter().all(|&v| v == 2000));
    }

    #[test]
    fn slanted_plane_depth_matches_the_analytic_surface() {
        // z = 2 + 0.5 x (camera frame), sampled on a 1 cm grid in x/y.
        let pts: Vec<Point3<f32>> = plane(0.0, 1.5, 1.0, 0.01)
            .into_iter()
            .map(|p| Point3::new(p.x, p.y, 2.0 + 0.5 * p.x))
            .collect();
        let k = kinect();
        let d = render_depth(&pts, &k, &Isometry3::identity());
        let mut checked = 0;
        for v in (20..460).step_by(37) {
            for u in (20..620).step_by(41) {
                let z = d.raw(u, v) as f64 / 1000.0;
                assert!(z > 0.0, "hole at {u},{v}");
                // Ray through the pixel centre meets z = 2 + 0.5 x where x = (u - cx) z / fx.
                let a = (u as f64 - k.cx) / k.fx;
                let z_true = 2.0 / (1.0 - 0.5 * a);
                assert!((z - z_true).abs() < 0.012, "{u},{v}: {z} vs {z_true}");
                checked += 1;
            }
        }
        assert!(checked > 100);
    }

    #[test]
    fn zbuffer_equals_brute_force() {
        // Random points; every pixel's depth = min over the points whose square covers it.
        let mut s = crate::testing::Lcg(12345);
        let mut rnd = || s.unit31_f32();
        let pts: Vec<Point3<f32>> = (0..300)
            .map(|_| Point3::new(rnd() * 2.0 - 1.0, rnd() * 1.5 - 0.75, 1.0 + 3.0 * rnd()))
            .collect();
        let k = Intrinsics {
            fx: 60.0,
            fy: 60.0,
            cx: 40.0,
            cy: 30.0,
            width: 80,
            height: 60,
        };
        let opts = SplatOptions {
            point_spacing: Some(0.05),
            ..Default::default()
        };
        let d = render_depth_with(&pts, &k, &Isometry3::identity(), &opts);
        for y in 0..60i64 {
            for x in 0..80i64 {
                let mut best = 0u16;
                for p in &pts {
                    let q = p.cast::<f64>();
                    let (u, v) = k.project(&q).unwrap();
                    let r = (0.5 * 0.05 * 60.0 / q.z).ceil().min(8.0) as i64;
                    let (pu, pv) = (u.round() as i64, v.round() as i64);
                    if (x - pu).abs() <= r && (y - pv).abs() <= r {
                        let mm = (q.z * 1000.0).round() as u16;
                        if best == 0 || mm < best {
                            best = mm;
                        }
                    }
                }
                assert_eq!(d.raw(x as u32, y as u32), best, "pixel {x},{y}");
            }
        }
    }

    #[test]
    fn pinhole_visibility_behind_a_wall() {
        let mut pts = plane(2.0, 0.9, 0.7, 0.01);
        let n = pts.len();
        pts.push(Point3::new(0.1, 0.1, 3.0)); // behind the wall
        pts.push(Point3::new(0.1, 0.1, 1.0)); // in front of it
        pts.push(Point3::new(0.0, 0.0, -1.0)); // behind the camera
        pts.push(Point3::new(5.0, 0.0, 1.0)); // outside the image
        let vis = visibility_pinhole(
            &pts,
            &kinect(),
            &Isometry3::identity(),
            &SplatOptions::default(),
        );
        assert!(vis[..n].iter().filter(|&&v| v).count() > n * 99 / 100);
        assert_eq!(&vis[n..], &[false, true, false, false]);
    }

    #[test]
    fn look_at_and_frustum() {
        let eye = Point3::new(0.0, 0.0, -3.0);
        let t = look_at(&eye, &Point3::origin(), &Vector3::new(0.0, -1.0, 0.0)).unwrap();
        // Looking along +z with y down: the identity rotation.
        assert!((t.rotation.angle()).abs() < 1e-12);
        assert!(look_at(&eye, &Point3::origin(), &Vector3::new(0.0, 0.0, 1.0)).is_none());
        let f = pinhole_frustum(&kinect(), &t.inverse(), 1.0);
        assert!((f.apex - eye).norm() < 1e-12);
        // Top-left corner: x = -cx/fx, y = -cy/fy at depth 1, shifted by the eye.
        let c = f.corners[0];
        assert!((c.x + 320.5 / 585.0).abs() < 1e-9 && (c.y + 240.5 / 585.0).abs() < 1e-9);
        assert!((c.z + 2.0).abs() < 1e-9);
    }
}
