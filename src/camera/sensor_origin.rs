//! Where a spinning LiDAR stood when it took a scan, estimated from the scan alone (no pose,
//! no ground truth): the virtual f-theta camera rig is placed there
//! ([`crate::pipeline::params::LidarOrigin::Estimated`]).
//!
//! A roof-mounted spinning LiDAR's beams meet flat ground in concentric rings centred under
//! the sensor. Two steps, both in the horizontal (x, y) plane; the scan's z axis is taken to be
//! vertical:
//! 1. coarse: ground-like points (within [`GROUND_BAND`] of the lowest point of their 1 m
//!    column) are binned into 0.3 m cells; a cell whose points lie along a line (a piece of a
//!    ring) votes along the line's normal, which passes through the rings' centre. The normals
//!    of ring pieces meet at the sensor; those of walls, kerbs and road markings are parallel
//!    and do not pile up. The best-voted 0.5 m cell is the coarse centre.
//! 2. fine: the centre (within 1.5 m of the coarse one, on a 0.1 m then a 0.02 m grid) at which
//!    the distances of the ground points in the innermost rings ([`RING_BAND`]) are most sharply
//!    concentrated (the sum of the squared counts of a 5 cm histogram, per point).
//!
//! The height is not estimated: the origin's z is the scan frame's z = 0 (for a scan in its
//! sensor frame that is the sensor; for PandaSet's world frame it is the frame-0 sensor's
//! height, right for a car on a level road). The yaw is not estimated either: the rig keeps
//! the scan frame's axes.

use crate::error::{Error, Result};
use nalgebra::Point3;
use std::collections::HashMap;

/// A ground-like point is at most this far (m) above the lowest point of its 1 m column.
pub const GROUND_BAND: f64 = 0.15;
/// Radial band (m) of the innermost ground rings used by the fine step. The lowest beams of
/// roof-mounted spinning LiDARs (about -25° from about 1.8 m: Pandar64, HDL-64, OS1-64) meet the
/// ground about 4 m out; rings farther out are shifted by the road's slope and the car's pitch.
/// 8 m rather than 10 m was chosen by checking the estimate on the one frame whose sensor
/// position is known (`ego_000000` of the PandaSet data, and the same scan as `world_000000`;
/// with 10 m its estimate is 0.6 m off): no registration was run to choose it.
pub const RING_BAND: (f64, f64) = (3.0, 8.0);
/// Cells (0.3 m) with at least this many ground points and a line-like spread vote.
const MIN_CELL_POINTS: usize = 5;
/// A cell is line-like when its smaller spread is below this fraction of the larger.
const LINE_RATIO: f64 = 0.02;
/// Fewest line-like cells for an estimate.
const MIN_LINE_CELLS: usize = 50;
/// Normals vote up to this distance (m) from their cell.
const VOTE_REACH: f64 = 40.0;
/// Cell size (m) of the vote accumulator.
const VOTE_CELL: f64 = 0.5;
/// Largest accumulator side, in cells (bounds its memory; a larger cloud uses larger cells).
const MAX_VOTE_SIDE: f64 = 2000.0;

/// What [`estimate_sensor_origin`] found.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorOrigin {
    /// x, y estimated; z = 0 (the scan frame's height).
    pub origin: Point3<f64>,
    /// The coarse centre (m) before the fine step.
    pub coarse: [f64; 2],
    /// Line-like ground cells that voted.
    pub line_cells: usize,
    /// Ground points in the fine step's ring band around `origin`.
    pub ring_points: usize,
}

/// The sensor position of a spinning-LiDAR scan (module doc). An error when the scan shows no
/// ground rings (too few points or line-like ground cells, or no ground points in the ring
/// band): it is then not a spinning-LiDAR scan, or one of a kind this does not handle.
pub fn estimate_sensor_origin(points: &[Point3<f32>]) -> Result<SensorOrigin> {
    let pts: Vec<[f64; 3]> = points
        .iter()
        .filter(|p| p.x.is_finite() && p.y.is_finite() && p.z.is_finite())
        .map(|p| [p.x as f64, p.y as f64, p.z as f64])
        .collect();
    if pts.len() < 1000 {
        return Err(Error::Invalid(format!(
            "sensor origin: {} finite points; a spinning-LiDAR scan has tens of thousands",
            pts.len()
        )));
    }
    let ground = ground_points(&pts);
    let (coarse, line_cells) = coarse_centre(&ground)?;
    let mut c = coarse;
    for (step, span) in [(0.1, 1.5), (0.02, 0.1)] {
        c = refine(&ground, c, step, span);
    }
    let ring_points = ring_distances(&ground, c).len();
    if ring_points == 0 {
        return Err(Error::Invalid(format!(
            "sensor origin: no ground point {}-{} m from the centre found at ({:.2}, {:.2}); \
             not a spinning-LiDAR scan?",
            RING_BAND.0, RING_BAND.1, c[0], c[1]
        )));
    }
    Ok(SensorOrigin {
        origin: Point3::new(c[0], c[1], 0.0),
        coarse,
        line_cells,
        ring_points,
    })
}

fn cell_of(x: f64, y: f64, size: f64) -> (i64, i64) {
    ((x / size).floor() as i64, (y / size).floor() as i64)
}

/// x, y of the points within [`GROUND_BAND`] of the lowest point of their 1 m column.
fn ground_points(pts: &[[f64; 3]]) -> Vec<[f64; 2]> {
    let mut lowest: HashMap<(i64, i64), f64> = HashMap::new();
    for p in pts {
        let z = lowest.entry(cell_of(p[0], p[1], 1.0)).or_insert(p[2]);
        *z = z.min(p[2]);
    }
    pts.iter()
        .filter(|p| p[2] <= lowest[&cell_of(p[0], p[1], 1.0)] + GROUND_BAND)
        .map(|p| [p[0], p[1]])
        .collect()
}

/// The best-voted 0.5 m cell's centre and the number of line-like cells that voted.
fn coarse_centre(ground: &[[f64; 2]]) -> Result<([f64; 2], usize)> {
    // Sums per 0.3 m cell, relative to the cell's corner (keeps the squares small).
    #[derive(Default)]
    struct Sums {
        n: usize,
        x: f64,
        y: f64,
        xx: f64,
        xy: f64,
        yy: f64,
    }
    const CELL: f64 = 0.3;
    let mut cells: HashMap<(i64, i64), Sums> = HashMap::new();
    for p in ground {
        let k = cell_of(p[0], p[1], CELL);
        let (x, y) = (p[0] - k.0 as f64 * CELL, p[1] - k.1 as f64 * CELL);
        let s = cells.entry(k).or_default();
        s.n += 1;
        s.x += x;
        s.y += y;
        s.xx += x * x;
        s.xy += x * y;
        s.yy += y * y;
    }
    // (centroid, unit normal, weight) of each line-like cell
    let mut lines: Vec<([f64; 2], [f64; 2], f64)> = Vec::new();
    for (k, s) in &cells {
        if s.n < MIN_CELL_POINTS {
            continue;
        }
        let n = s.n as f64;
        let (mx, my) = (s.x / n, s.y / n);
        let (cxx, cxy, cyy) = (s.xx / n - mx * mx, s.xy / n - mx * my, s.yy / n - my * my);
        let half_tr = 0.5 * (cxx + cyy);
        let disc = (half_tr * half_tr - (cxx * cyy - cxy * cxy))
            .max(0.0)
            .sqrt();
        let (l1, l2) = (half_tr + disc, half_tr - disc);
        if l1 <= 0.0 || l2 > LINE_RATIO * l1 {
            continue;
        }
        // eigenvector of l1: the line's direction
        let (tx, ty) = if cxy.abs() > 1e-15 {
            (cxy, l1 - cxx)
        } else if cxx >= cyy {
            (1.0, 0.0)
        } else {
            (0.0, 1.0)
        };
        let norm = (tx * tx + ty * ty).sqrt();
        let centroid = [mx + k.0 as f64 * CELL, my + k.1 as f64 * CELL];
        lines.push((centroid, [-ty / norm, tx / norm], n));
    }
    if lines.len() < MIN_LINE_CELLS {
        return Err(Error::Invalid(format!(
            "sensor origin: {} line-like ground cells (pieces of LiDAR rings), at least \
             {MIN_LINE_CELLS} needed; not a spinning-LiDAR scan?",
            lines.len()
        )));
    }
    // Accumulator over the lines' reach.
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for (c, _, _) in &lines {
        for a in 0..2 {
            lo[a] = lo[a].min(c[a] - VOTE_REACH);
            hi[a] = hi[a].max(c[a] + VOTE_REACH);
        }
    }
    let side = (hi[0] - lo[0]).max(hi[1] - lo[1]);
    let cell = VOTE_CELL.max(side / MAX_VOTE_SIDE);
    let w = ((hi[0] - lo[0]) / cell).ceil() as usize + 1;
    let h = ((hi[1] - lo[1]) / cell).ceil() as usize + 1;
    let mut acc = vec![0.0f64; w * h];
    let steps = (2.0 * VOTE_REACH / (0.5 * cell)).ceil() as usize;
    for (c, nrm, weight) in &lines {
        let mut last = usize::MAX;
        for s in 0..=steps {
            let t = -VOTE_REACH + s as f64 * 0.5 * cell;
            let (x, y) = (c[0] + t * nrm[0], c[1] + t * nrm[1]);
            let (i, j) = (((x - lo[0]) / cell) as usize, ((y - lo[1]) / cell) as usize);
            if i >= w || j >= h {
                continue;
            }
            let idx = j * w + i;
            if idx != last {
                acc[idx] += weight;
                last = idx;
            }
        }
    }
    let (best, _) =
        acc.iter().enumerate().fold(
            (0, f64::NEG_INFINITY),
            |b, (i, &v)| if v > b.1 { (i, v) } else { b },
        );
    let (i, j) = (best % w, best / w);
    Ok((
        [
            lo[0] + (i as f64 + 0.5) * cell,
            lo[1] + (j as f64 + 0.5) * cell,
        ],
        lines.len(),
    ))
}

/// Horizontal distances from `c` of the ground points in [`RING_BAND`].
fn ring_distances(ground: &[[f64; 2]], c: [f64; 2]) -> Vec<f64> {
    ground
        .iter()
        .map(|p| ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2)).sqrt())
        .filter(|d| (RING_BAND.0..RING_BAND.1).contains(d))
        .collect()
}

/// How sharply the ring band's distances from `c` concentrate: the sum of the squared counts
/// of a 5 cm histogram, divided by the number of points (0 with none).
fn sharpness(ground: &[[f64; 2]], c: [f64; 2]) -> f64 {
    const BIN: f64 = 0.05;
    let d = ring_distances(ground, c);
    if d.is_empty() {
        return 0.0;
    }
    let bins = ((RING_BAND.1 - RING_BAND.0) / BIN).ceil() as usize;
    let mut hist = vec![0u32; bins];
    for x in &d {
        let b = (((x - RING_BAND.0) / BIN) as usize).min(bins - 1);
        hist[b] += 1;
    }
    hist.iter().map(|&k| (k as f64).powi(2)).sum::<f64>() / d.len() as f64
}

/// The sharpest centre on a grid of `step` within `span` of `c` (first best in grid order).
fn refine(ground: &[[f64; 2]], c: [f64; 2], step: f64, span: f64) -> [f64; 2] {
    // only the points that can fall in the band from any candidate
    let reach = RING_BAND.1 + span * std::f64::consts::SQRT_2;
    let near: Vec<[f64; 2]> = ground
        .iter()
        .filter(|p| (p[0] - c[0]).abs() <= reach && (p[1] - c[1]).abs() <= reach)
        .copied()
        .collect();
    let n = (span / step).round() as i64;
    let mut best = (f64::NEG_INFINITY, c);
    for a in -n..=n {
        for b in -n..=n {
            let cand = [c[0] + a as f64 * step, c[1] + b as f64 * step];
            let s = sharpness(&near, cand);
            if s > best.0 {
                best = (s, cand);
            }
        }
    }
    best.1
}

/// A synthetic spinning-LiDAR scan taken at `sensor` (its height is `sensor.z` above the ground
/// plane z = `ground_z`): `beams` beams from -25° to +10°, `azimuths` firings per turn; a ray
/// returns its first hit on the ground or on the walls x = `wall_x` and y = `wall_y` (when
/// given), or nothing within 120 m. For tests.
pub fn synthetic_ring_scan(
    sensor: Point3<f64>,
    ground_z: f64,
    beams: usize,
    azimuths: usize,
    walls: (Option<f64>, Option<f64>),
) -> Vec<Point3<f32>> {
    let mut out = Vec::new();
    for b in 0..beams {
        let el = (-25.0 + 35.0 * b as f64 / (beams.max(2) - 1) as f64).to_radians();
        for a in 0..azimuths {
            let az = std::f64::consts::TAU * a as f64 / azimuths as f64;
            let dir = [el.cos() * az.cos(), el.cos() * az.sin(), el.sin()];
            let mut t = f64::INFINITY;
            if dir[2] < 0.0 {
                t = t.min((ground_z - sensor.z) / dir[2]);
            }
            if let Some(wx) = walls.0 {
                let s = (wx - sensor.x) / dir[0];
                if s > 0.0 {
                    t = t.min(s);
                }
            }
            if let Some(wy) = walls.1 {
                let s = (wy - sensor.y) / dir[1];
                if s > 0.0 {
                    t = t.min(s);
                }
            }
            if t.is_finite() && t < 120.0 {
                out.push(Point3::new(
                    (sensor.x + t * dir[0]) as f32,
                    (sensor.y + t * dir[1]) as f32,
                    (sensor.z + t * dir[2]) as f32,
                ));
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_the_sensor_of_a_synthetic_ring_scan_away_from_the_origin() {
        let sensor = Point3::new(23.7, -41.3, 0.0);
        let pts = synthetic_ring_scan(sensor, -1.8, 32, 1800, (Some(38.0), Some(-30.0)));
        let est = estimate_sensor_origin(&pts).unwrap();
        let err = ((est.origin.x - sensor.x).powi(2) + (est.origin.y - sensor.y).powi(2)).sqrt();
        assert!(err < 0.05, "{est:?}");
        assert_eq!(est.origin.z, 0.0);
        // the same scan at the origin
        let pts0 = synthetic_ring_scan(Point3::origin(), -1.8, 32, 1800, (Some(14.0), None));
        let est0 = estimate_sensor_origin(&pts0).unwrap();
        assert!(est0.origin.coords.norm() < 0.05, "{est0:?}");
    }

    #[test]
    fn clouds_without_ground_rings_are_an_error() {
        assert!(estimate_sensor_origin(&[Point3::origin(); 10]).is_err());
        // a solid block of points: no line-like ground cells
        let mut block = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                for k in 0..3 {
                    block.push(Point3::new(
                        i as f32 * 0.37,
                        j as f32 * 0.41,
                        k as f32 * 0.5,
                    ));
                }
            }
        }
        let e = estimate_sensor_origin(&block).unwrap_err().to_string();
        assert!(e.contains("line-like"), "{e}");
    }
}
