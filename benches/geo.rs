//! Geometry benchmark: voxel downsampling, k-d tree build, normals and FPFH on a real
//! 3DMatch fragment (cloud_bin_0, ~258k points) at voxel 2.5 cm. Plain `Instant` timing,
//! median of 5 runs. Run: `cargo bench --no-default-features --bench geo`.

// Benchmarks, examples and tests: a failed step is reported by the panic that ends them.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use cgenreg::features::fpfh::{compute_fpfh, FpfhParams};
use cgenreg::geometry::knn::KdIndex;
use cgenreg::geometry::normals::{estimate_normals, orient_towards_viewpoint};
use cgenreg::geometry::voxel::voxel_downsample;
use cgenreg::geometry::PointCloud;
use nalgebra::Point3;
use std::hint::black_box;
use std::time::Instant;

/// Binary little-endian PLY with exactly `float x, y, z` vertices (the staged fragment).
fn read_xyz_ply(path: &std::path::Path) -> Option<Vec<Point3<f32>>> {
    let bytes = std::fs::read(path).ok()?;
    let end = b"end_header\n";
    let pos = bytes.windows(end.len()).position(|w| w == end)? + end.len();
    let header = std::str::from_utf8(&bytes[..pos]).ok()?;
    let n: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))?
        .trim()
        .parse()
        .ok()?;
    let body = bytes.get(pos..pos + n * 12)?;
    Some(
        body.chunks_exact(12)
            .map(|c| {
                let f = |i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
                Point3::new(f(0), f(4), f(8))
            })
            .collect(),
    )
}

/// CPU time of this process (all threads), in ms, from /proc (10 ms ticks); None elsewhere.
fn cpu_ms() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = s.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks * 10.0)
}

/// Median wall time (ms) over `runs`, and the mean CPU time per run (ms): on a shared,
/// loaded machine the CPU time shows the work done when wall time is inflated by waiting.
fn median_ms<T>(runs: usize, mut f: impl FnMut() -> T) -> (f64, f64) {
    let c0 = cpu_ms();
    let mut t: Vec<f64> = (0..runs)
        .map(|_| {
            let s = Instant::now();
            black_box(f());
            s.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    let cpu = match (c0, cpu_ms()) {
        (Some(a), Some(b)) => (b - a) / runs as f64,
        _ => f64::NAN,
    };
    t.sort_by(|a, b| a.total_cmp(b));
    (t[runs / 2], cpu)
}

fn main() {
    let Some(root) = cgenreg::data_root() else {
        println!("skipping geo bench: data root not found (set CGENREG_DATA)");
        return;
    };
    let path = root.join("3dmatch-redkitchen/teaser-plusplus/cloud_bin_0.ply");
    let Some(points) = read_xyz_ply(&path) else {
        println!("skipping geo bench: cannot read {}", path.display());
        return;
    };
    let voxel = 0.025;
    let params = FpfhParams::for_voxel(voxel);
    let cloud = PointCloud::from_points(points);
    let runs = 5;

    let t_voxel = median_ms(runs, || voxel_downsample(&cloud, voxel));
    let down = voxel_downsample(&cloud, voxel);
    let pts = &down.points;
    let t_tree = median_ms(runs, || KdIndex::new(pts));
    let index = KdIndex::new(pts);
    let t_normals = median_ms(runs, || {
        let mut n = estimate_normals(pts, &index, params.normal_radius, params.normal_max_nn);
        orient_towards_viewpoint(pts, &mut n, Point3::origin());
        n
    });
    let mut normals = estimate_normals(pts, &index, params.normal_radius, params.normal_max_nn);
    orient_towards_viewpoint(pts, &mut normals, Point3::origin());
    let t_fpfh = median_ms(runs, || compute_fpfh(pts, &normals, &index, &params));
    if std::env::var("GEO_BREAKDOWN").is_ok() {
        use rayon::prelude::*;
        let t_search = median_ms(runs, || {
            pts.par_iter()
                .map_init(Vec::new, |nb, p| {
                    index.hybrid_into(p, params.feature_radius, params.feature_max_nn, nb);
                    nb.len()
                })
                .sum::<usize>()
        });
        let t_within = median_ms(runs, || {
            pts.par_iter()
                .map(|p| index.within(p, params.feature_radius).len())
                .sum::<usize>()
        });
        let n: usize = pts
            .iter()
            .map(|p| index.hybrid(p, params.feature_radius, 100).len())
            .sum();
        let t_spfh = median_ms(runs, || {
            cgenreg::features::fpfh::compute_spfh(pts, &normals, &index, &params)
        });
        println!(
            "breakdown (wall, cpu ms): hybrid search {t_search:.1?}, sorted radius search {t_within:.1?}, \
             search + SPFH {t_spfh:.1?}; mean neighbours {:.1}",
            n as f64 / pts.len() as f64
        );
    }
    let t_all = median_ms(runs, || {
        cgenreg::features::fpfh::fpfh_for_cloud(&cloud, voxel)
    });

    println!(
        "\nFPFH on {} ({} points -> {} at voxel {} m), {} threads, median of {runs} runs\n",
        path.file_name().and_then(|s| s.to_str()).unwrap_or("?"),
        cloud.len(),
        pts.len(),
        voxel,
        rayon::current_num_threads()
    );
    println!("| stage | wall ms (median) | CPU ms (mean) |");
    println!("|---|---:|---:|");
    let row = |name: &str, t: (f64, f64)| println!("| {name} | {:.1} | {:.1} |", t.0, t.1);
    row("voxel downsample", t_voxel);
    row("k-d tree build", t_tree);
    row("normals (r 5 cm, 30 nn) + orientation", t_normals);
    row("FPFH (r 12.5 cm, 100 nn)", t_fpfh);
    row(
        "**normals + FPFH**",
        (t_normals.0 + t_fpfh.0, t_normals.1 + t_fpfh.1),
    );
    row("fpfh_for_cloud (all of the above)", t_all);
    if let Ok(l) = std::fs::read_to_string("/proc/loadavg") {
        println!("\nload average during the run: {}", l.trim());
    }
}
