//! Every fragment of a manifest written as a plain PLY cloud, with a clouds-only manifest of the same
//! pairs and GT (the revisit set's clouds-only rows and Open3D's input, docs/ablation.md "Revisits"):
//! `cargo run --example export_fragments -- MANIFEST OUT_DIR [CACHE_DIR]`.
//! Writes OUT_DIR/<fragment id>.ply (points, and colours or normals where the fragment has them) and
//! OUT_DIR/clouds.toml (root "." = OUT_DIR, inline `gt_matrix` = target_from_source).

// Benchmarks, examples and tests: a failed step is reported by the panic that ends them.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use std::fmt::Write as _;
use std::path::Path;

use cgenreg::dataset::manifest::gt_matrix_toml;
use cgenreg::dataset::Dataset;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(manifest), Some(out)) = (args.first(), args.get(1)) else {
        return Err("usage: export_fragments MANIFEST OUT_DIR [CACHE_DIR]".into());
    };
    let cache = args.get(2).map(cgenreg::cache::Cache::open).transpose()?;
    let ds = Dataset::load(Path::new(manifest))?.with_fragment_cache(cache);
    let out = Path::new(out);
    std::fs::create_dir_all(out)?;
    let mut m = format!(
        "# {} as plain clouds (written by examples/export_fragments.rs from {manifest}).\n\
         # GT: gt_matrix = target_from_source (p_target = T p_source).\nname = \"{}-clouds\"\nroot = \".\"\n",
        ds.name, ds.name
    );
    for f in ds.fragments() {
        let scan = ds.load_fragment(&f.id)?;
        let file = format!("{}.ply", f.id);
        cgenreg::io::ply::write_ply(&out.join(&file), &scan.cloud)?;
        let _ = write!(
            m,
            "\n[[fragments]]\nid = \"{}\"\ncloud = \"{file}\"\n",
            f.id
        );
        eprintln!("{}: {} points", f.id, scan.cloud.len());
    }
    for p in ds.pairs() {
        let Some(gt) = p.gt_target_from_source else {
            continue;
        };
        let _ = write!(
            m,
            "\n[[pairs]]\ntarget = \"{}\"\nsource = \"{}\"\nsplit = \"{}\"\ngt_matrix = {}\n",
            p.target,
            p.source,
            p.split,
            gt_matrix_toml(&gt)
        );
    }
    std::fs::write(out.join("clouds.toml"), m)?;
    eprintln!("wrote {}", out.join("clouds.toml").display());
    Ok(())
}
