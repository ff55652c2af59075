//! The GT overlap of every pair of a manifest (the rule that picks development pairs, see
//! docs/ablation.md): `cargo run --example pair_overlap -- MANIFEST [CACHE_DIR]`.
//! Prints one line per pair: id, split, source %, target %, max %, and the split the max falls
//! in (> 30 %: 3DMatch-like, 10-30 %: 3DLoMatch-like, < 10 %: too low).

// Benchmarks, examples and tests: a failed step is reported by the panic that ends them.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use cgenreg::dataset::Dataset;
use cgenreg::metrics::overlap::{pair_overlap, OVERLAP_RADIUS_M, OVERLAP_VOXEL_M};

fn main() -> cgenreg::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(manifest) = args.first() else {
        return Err(cgenreg::Error::Invalid(
            "usage: pair_overlap MANIFEST [CACHE_DIR]".into(),
        ));
    };
    let cache = args.get(1).map(cgenreg::cache::Cache::open).transpose()?;
    let ds = Dataset::load(std::path::Path::new(manifest))?.with_fragment_cache(cache);
    println!(
        "# overlap at voxel {OVERLAP_VOXEL_M} m, radius {OVERLAP_RADIUS_M} m (GT target_from_source)"
    );
    println!("# pair\tsplit\tsource%\ttarget%\tmax%\tclass");
    for p in ds.pairs() {
        let Some(gt) = p.gt_target_from_source else {
            println!("{}\t{}\tno GT", p.id, p.split);
            continue;
        };
        let pair = ds.load_pair(&p.id)?;
        let o = pair_overlap(&pair.source.cloud, &pair.target.cloud, &gt);
        let class = match o.max() {
            m if m > 0.3 => "3DMatch-like",
            m if m >= 0.1 => "3DLoMatch-like",
            _ => "low",
        };
        println!(
            "{}\t{}\t{:.1}\t{:.1}\t{:.1}\t{class}",
            p.id,
            p.split,
            100.0 * o.source,
            100.0 * o.target,
            100.0 * o.max()
        );
    }
    Ok(())
}
