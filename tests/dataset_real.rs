//! Dataset tests on the staged real data (skipped when it is missing, failing under CI=true).

use cgenreg::dataset::fragment::{build_fragment_with, CropBox, FragmentOptions};
use cgenreg::io::rgbd_sequence::RgbdSequence;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Point3;
use rayon::prelude::*;

/// Fraction of `query` points whose nearest neighbour in `reference` is within `radius`.
fn fraction_within(query: &[Point3<f32>], reference: &[Point3<f32>], radius: f32) -> f64 {
    let pts: Vec<[f32; 3]> = reference.iter().map(|p| [p.x, p.y, p.z]).collect();
    let tree = ImmutableKdTree::new_from_slice(&pts).unwrap();
    let hits = query
        .par_iter()
        .filter(|q| {
            let nn = tree
                .query(&[q.x, q.y, q.z])
                .nearest_one::<SquaredEuclidean<f32>>()
                .execute();
            nn.distance <= radius * radius
        })
        .count();
    hits as f64 / query.len().max(1) as f64
}

#[test]
fn explore_fragment_options() {
    let Some(root) = cgenreg::test_data_root() else { return };
    let seq = RgbdSequence::open(&root.join("7scenes-redkitchen-rgbd")).unwrap();
    let staged = cgenreg::io::cloud::load_cloud(&root.join("3dmatch-redkitchen/teaser-plusplus/cloud_bin_0.ply")).unwrap();
    let crop = CropBox::THREEDMATCH;
    for (voxel, maxd) in [(0.01, 4.0), (0.006, 4.0)] {
        let t = std::time::Instant::now();
        let opts = FragmentOptions { voxel, max_depth: maxd, ..Default::default() };
        let frag = build_fragment_with(&seq, 0, 50, &opts, "0").unwrap();
        let dt = t.elapsed();
        let inside: Vec<_> = frag.cloud.points.iter().copied().filter(|p| crop.contains(p)).collect();
        let a = fraction_within(&staged.points, &frag.cloud.points, 0.02);
        let b = fraction_within(&inside, &staged.points, 0.02);
        let c = fraction_within(&frag.cloud.points, &staged.points, 0.02);
        println!("voxel {voxel} maxd {maxd}: n {} inside {} staged {}; staged->rebuilt {a:.4} rebuilt(in box)->staged {b:.4} rebuilt(all)->staged {c:.4} ({dt:?})", frag.cloud.len(), inside.len(), staged.len());
    }
    let lo = staged.bounds().unwrap();
    println!("staged bounds {lo:?}");
}
