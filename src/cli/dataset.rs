//! `cgenreg dataset 3dmatch|kitti ROOT --out FILE.toml`: a manifest of a standard benchmark as
//! downloaded (see `dataset::official`), checked by loading it back.

use crate::dataset::official::{
    kitti_manifest, threedmatch_manifest, KittiOptions, KittiRule, Written,
};
use crate::dataset::Dataset;
use crate::error::{Error, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct DatasetArgs {
    #[command(subcommand)]
    pub kind: DatasetKind,
}

#[derive(Subcommand, Debug)]
pub enum DatasetKind {
    /// 3DMatch / 3DLoMatch: the 3DMatch toolbox's layout (<scene>/cloud_bin_<k>.ply,
    /// <scene>-evaluation/{gt.log,gt.info}) or Predator's / GeoTransformer's
    /// (<scene>/cloud_bin_<k>.pth, benchmarks/{3DMatch,3DLoMatch}/<scene>/{gt.log,gt.info}).
    #[command(name = "3dmatch")]
    ThreeDMatch(ThreeDMatchArgs),
    /// KITTI odometry (sequences/NN/velodyne/*.bin, sequences/NN/calib.txt, poses/NN.txt), with
    /// the pair rule of the published KITTI registration tables.
    Kitti(KittiArgs),
}

#[derive(Args, Debug)]
pub struct OutArgs {
    /// The manifest to write (TOML).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace an existing file.
    #[arg(long)]
    pub force: bool,
}

#[derive(Args, Debug)]
pub struct ThreeDMatchArgs {
    /// The download's folder (the scenes' folders in it).
    pub root: PathBuf,
    /// The folder holding 3DMatch/<scene>/ and 3DLoMatch/<scene>/ with gt.log and gt.info
    /// (default: ROOT/benchmarks when present, else the toolbox layout).
    #[arg(long)]
    pub benchmarks: Option<PathBuf>,
    /// Only these scenes (comma-separated folder names).
    #[arg(long, value_delimiter = ',')]
    pub scenes: Option<Vec<String>>,
    #[command(flatten)]
    pub out: OutArgs,
}

#[derive(Args, Debug)]
pub struct KittiArgs {
    /// The download's folder (holding sequences/ and poses/, or dataset/ with them).
    pub root: PathBuf,
    /// Sequences (comma-separated numbers).
    #[arg(long, value_delimiter = ',', default_value = "8,9,10")]
    pub sequences: Vec<u32>,
    /// Pairs at least this far apart (m, between the poses' camera positions).
    #[arg(long, default_value_t = 10.0)]
    pub min_distance: f64,
    /// published: the rule of the KITTI tables (consecutive scans needed); all: every two
    /// scans present at least --min-distance apart.
    #[arg(long, value_enum, default_value_t = KittiRule::Published)]
    pub rule: KittiRule,
    /// Fields per point of the .bin files: 4 (KITTI's x, y, z, intensity) or 3 (x, y, z);
    /// default: from the file size.
    #[arg(long)]
    pub fields: Option<u64>,
    #[command(flatten)]
    pub out: OutArgs,
}

fn write(w: &Written, out: &OutArgs) -> Result<()> {
    if out.out.exists() && !out.force {
        return Err(Error::format(
            &out.out,
            "--out",
            "a new file (--force replaces an existing one)",
            "an existing file",
        ));
    }
    crate::io::output::write_atomic(&out.out, w.text.as_bytes())?;
    // the manifest as `bench` will read it: every path and entry resolved once
    let ds = Dataset::load(&out.out)?;
    outln!(
        "wrote {}: {} ({} fragments, {} scene(s); {} pairs loaded back)",
        out.out.display(),
        w.pairs
            .iter()
            .map(|(b, n)| format!("{b} {n} pairs"))
            .collect::<Vec<_>>()
            .join(", "),
        w.fragments,
        w.scenes.len(),
        ds.pairs().len()
    );
    Ok(())
}

pub fn run(a: DatasetArgs) -> Result<()> {
    match a.kind {
        DatasetKind::ThreeDMatch(t) => {
            let w = threedmatch_manifest(&t.root, t.benchmarks.as_deref(), t.scenes.as_deref())?;
            write(&w, &t.out)
        }
        DatasetKind::Kitti(k) => {
            let o = KittiOptions {
                sequences: k.sequences,
                min_distance_m: k.min_distance,
                rule: k.rule,
                fields: k.fields,
            };
            let w = kitti_manifest(&k.root, &o)?;
            write(&w, &k.out)
        }
    }
}
