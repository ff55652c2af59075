//! Dataset manifests: a small TOML file naming fragments and scan pairs with ground truth.
//!
//! ```toml
//! name = "redkitchen"            # dataset name, the prefix of pair ids
//! preset = "indoor"              # optional: the protocol its pairs are run and judged by,
//!                                # "indoor" (3DMatch, the default) or "outdoor" (KITTI); a
//!                                # pair may name its own. `--preset` overrides both.
//! scene_prompt = "a kitchen ..." # optional: the scene-specific prompt's description of this
//!                                # data set's scene (the WFM prompt's scene part; see wfm::prompt)
//! geo_features = "fpfh"          # optional: the geometric descriptor its pairs are run with,
//!                                # "fpfh" (the default), "spinnet-3dmatch" or "spinnet-kitti";
//!                                # `--geo-features` (or learned feature files) override it
//! root = "$CGENREG_DATA"         # paths below are relative to this; "." (the default) is the
//!                                # manifest's folder; $VAR / ${VAR} are expanded
//! # allow_outside_root = true    # paths must stay inside root (symlinks resolved) unless
//!                                # this is set: a shared manifest cannot read other files
//!
//! [fragment_options]             # optional defaults for fragments built from RGB-D frames
//! voxel = 0.01                   # merge voxel (m)
//! max_depth = 4.0                # drop depths beyond this (m)
//! crop = "3dmatch"               # or "none": 3DMatch's box x,y in [-1.5,1.5], z in [0.5,3.5]
//! color = false                  # sample colours (only when colour and depth are registered)
//!
//! [[fragments]]                  # a point-cloud file (.ply .pcd .npy .pth .bin .xyz) ...
//! id = "0"
//! cloud = "3dmatch-redkitchen/teaser-plusplus/cloud_bin_0.ply"
//! sequence = "7scenes-redkitchen-rgbd"   # optional: the frames it was made from
//! first = 0
//! count = 50
//! # kitti_fields = 3             # .bin only: 3 for x,y,z files, 4 for KITTI x,y,z,intensity
//!                                # (default: CGENREG_KITTI_FIELDS, else the file size)
//!
//! [[fragments]]                  # ... or a fragment built from raw RGB-D frames
//! id = "3"                       # (per-fragment voxel/max_depth/crop/color override)
//! sequence = "7scenes-redkitchen-rgbd"
//! first = 150
//! count = 50
//!
//! [[pairs]]
//! target = "0"                   # gt.log `i j`: i is the target, j the source
//! source = "3"
//! split = "3DMatch"              # free text; "3DMatch" / "3DLoMatch" for the benchmark
//! gt_log = "3dmatch-redkitchen/benchmark/3DMatch/gt.log"
//! gt_entry = [0, 3]              # optional; default: the numeric target and source ids
//! gt_info = "3dmatch-redkitchen/benchmark/3DMatch/gt.info"   # optional, with gt_log: the
//!                                # entry's 6x6 information matrix (3DMatch's RMSE recall)
//! scene = "7-scenes-redkitchen"  # optional: the scene, for per-scene tables
//! # or: gt_matrix = [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]   (p_target = T p_source)
//! # or: gt_file = "pair/gt.txt"  (4x4 text, target_from_source)
//! # or: gt_poses = true          (both fragments made from frames of one RGB-D sequence:
//! #                                T = inv(P_target_first) * P_source_first, poses
//! #                                camera-to-world, each fragment in its first frame's camera)
//! # or no gt at all
//! # preset = "outdoor"           # optional: this pair's protocol (default: the data set's)
//! ```
//!
//! Pair ids are `"<name>/<target>-<source>"`. Ground truth is always `target_from_source`
//! (p_target = T * p_source), as in gt.log. Every error names the manifest file and the field.

mod fragments;
mod parse;

use super::fragment::{build_fragment_with, fragment_frames, CropBox, FragmentOptions};
use super::fragment_cache::{build_fragment_cached, FragmentCacheStatus};
use super::{Scan, ScanPair};
use crate::dataset::preset::Preset;
use crate::dataset::rgbd_sequence::RgbdSequence;
use crate::error::{Error, Result};
use crate::geometry::transform::isometry_from_matrix;
use crate::io::gtlog::{read_gt_info, read_gt_log, GtEntry, GtInfo};
use crate::io::kitti::KittiFields;
use nalgebra::{Isometry3, Matrix4};
use serde::Deserialize;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The frames a fragment comes from: frames `first .. first+count` of a raw RGB-D sequence.
#[derive(Clone, Debug, PartialEq)]
pub struct SequenceRange {
    pub dir: PathBuf,
    pub first: usize,
    pub count: usize,
}

#[derive(Clone, Debug, PartialEq)]
pub enum FragmentSource {
    /// A point-cloud file, optionally with the frames it was made from.
    Cloud {
        path: PathBuf,
        frames: Option<SequenceRange>,
        /// Fields per point of a `.bin` file, when the manifest says (`kitti_fields`).
        kitti_fields: Option<KittiFields>,
    },
    /// Built from raw RGB-D frames (see [`super::fragment`]).
    Rgbd {
        range: SequenceRange,
        options: FragmentOptions,
    },
}

#[derive(Clone, Debug, PartialEq)]
pub struct FragmentSpec {
    pub id: String,
    pub source: FragmentSource,
}

#[derive(Clone, Debug, PartialEq)]
pub struct PairSpec {
    /// `"<dataset>/<target>-<source>"`.
    pub id: String,
    pub target: String,
    pub source: String,
    /// "3DMatch", "3DLoMatch", or whatever the manifest says; empty when not given.
    pub split: String,
    /// p_target = T * p_source.
    pub gt_target_from_source: Option<Isometry3<f64>>,
    /// Where the ground truth came from, e.g. "gt.log entry `0 5`".
    pub gt_origin: Option<String>,
    /// The protocol this pair names (None: the data set's).
    pub preset: Option<Preset>,
    /// The scene it belongs to (`scene` in the manifest), for per-scene tables.
    pub scene: Option<String>,
    /// The gt.info entry of its gt.log entry (`gt_info`): 3DMatch's RMSE recall.
    pub gt_info: Option<GtInfo>,
}

#[derive(Clone, Debug)]
pub struct Dataset {
    pub name: String,
    /// The manifest file (None for datasets built in code, e.g. from a 3DMatch folder).
    pub manifest: Option<PathBuf>,
    /// The folder relative paths were resolved against.
    pub root: PathBuf,
    /// The protocol its pairs are run and judged by (`preset` in the manifest; None: indoor,
    /// unless a pair or the command line names one).
    pub preset: Option<Preset>,
    /// The scene-specific prompt's description of its scene (`scene_prompt` in the manifest;
    /// None: the pipeline's own text, written for the redkitchen data).
    pub scene_prompt: Option<String>,
    /// The geometric descriptor its pairs are run with (`geo_features` in the manifest; None:
    /// FPFH, unless the command line names one).
    pub geo_features: Option<crate::features::DescriptorName>,
    pub(crate) fragments: Vec<FragmentSpec>,
    pub(crate) pairs: Vec<PairSpec>,
    /// The stage cache that keeps fragments built from raw RGB-D frames (stage `fragments`;
    /// None: rebuilt every time).
    pub fragment_cache: Option<crate::cache::Cache>,
}

fn bad(
    path: &Path,
    field: impl Into<String>,
    expected: impl Into<String>,
    found: impl Into<String>,
) -> Error {
    Error::format(path, field, expected, found)
}

/// `t` as a manifest's inline `gt_matrix` value (`[[r0], [r1], [r2], [r3]]`, row-major, every
/// number written so it reads back to the same `f64`): for code that writes manifests.
pub fn gt_matrix_toml(t: &Isometry3<f64>) -> String {
    let m = t.to_homogeneous();
    let rows: Vec<String> = (0..4)
        .map(|r| {
            let v: Vec<String> = (0..4).map(|c| format!("{:?}", m[(r, c)])).collect();
            format!("[{}]", v.join(", "))
        })
        .collect();
    format!("[{}]", rows.join(", "))
}

fn matrix_field(manifest: &Path, field: &str, rows: &[Vec<f64>]) -> Result<Isometry3<f64>> {
    let flat: Vec<f64> = rows.iter().flatten().copied().collect();
    if rows.len() != 4 || rows.iter().any(|r| r.len() != 4) {
        return Err(bad(
            manifest,
            field,
            "4 rows of 4 numbers",
            format!("{} rows, {} numbers", rows.len(), flat.len()),
        ));
    }
    isometry_from_matrix(&Matrix4::from_row_slice(&flat)).ok_or_else(|| {
        bad(
            manifest,
            field,
            "a finite rigid 4x4 transform (last row 0 0 0 1)",
            crate::geometry::transform::rigidity_problem(&Matrix4::from_row_slice(&flat)),
        )
    })
}

/// The frames a fragment was made from, if the manifest says.
fn frame_range(f: &FragmentSpec) -> Option<&SequenceRange> {
    match &f.source {
        FragmentSource::Rgbd { range, .. } => Some(range),
        FragmentSource::Cloud { frames, .. } => frames.as_ref(),
    }
}

/// `gt_poses = true`: `target_from_source = inv(P_t) * P_s` with P the camera-to-world poses
/// of the two fragments' first frames (each fragment is in its first frame's camera, see
/// [`super::fragment`]). Both fragments must come from frames of the same sequence folder.
fn gt_from_poses(
    manifest: &Path,
    field: &str,
    fragments: &[FragmentSpec],
    target: &str,
    source: &str,
    seqs: &mut HashMap<PathBuf, RgbdSequence>,
) -> Result<(Isometry3<f64>, String)> {
    let range = |id: &str, which: &str| {
        fragments
            .iter()
            .find(|f| f.id == id)
            .and_then(frame_range)
            .ok_or_else(|| {
                bad(
                    manifest,
                    format!("{field}.gt_poses"),
                    format!("a {which} fragment made from RGB-D frames (`sequence` + `first`)"),
                    format!("fragment {id:?} without frames"),
                )
            })
    };
    let (rt, rs) = (range(target, "target")?, range(source, "source")?);
    if rt.dir != rs.dir {
        return Err(bad(
            manifest,
            format!("{field}.gt_poses"),
            "target and source frames from the same sequence (poses share one world frame)",
            format!("{} and {}", rt.dir.display(), rs.dir.display()),
        ));
    }
    if !seqs.contains_key(&rt.dir) {
        let seq = RgbdSequence::open(&rt.dir)?;
        seqs.insert(rt.dir.clone(), seq);
    }
    let seq = &seqs[&rt.dir];
    let t = seq.world_from_camera(rt.first)?.inverse() * seq.world_from_camera(rs.first)?;
    Ok((
        t,
        format!(
            "poses: inv(P of frame-{:06}) * P of frame-{:06} in {}",
            rt.first,
            rs.first,
            rt.dir.display()
        ),
    ))
}

/// The longest fragment id a manifest may give (ids become file and pair names).
const MAX_ID_BYTES: usize = 255;

/// Whether `s` holds a character that would act on a terminal or hide what is printed: a
/// control character (C0, DEL, C1: ESC, NUL, line breaks) or a direction or invisible
/// formatting mark (U+200B-U+200F, U+202A-U+202E, U+2060-U+2069, U+FEFF).
pub fn has_hidden_characters(s: &str) -> bool {
    s.chars().any(|c| {
        c.is_control()
            || matches!(c, '\u{200B}'..='\u{200F}' | '\u{202A}'..='\u{202E}'
                | '\u{2060}'..='\u{2069}' | '\u{FEFF}')
    })
}

impl Dataset {
    /// The protocol of pair `id`: its own `preset`, else the data set's (None: neither names one).
    pub fn preset_of(&self, id: &str) -> Option<Preset> {
        self.pair(id).and_then(|p| p.preset).or(self.preset)
    }

    pub fn pairs(&self) -> &[PairSpec] {
        &self.pairs
    }

    /// The pairs of `split` (any case; all when None), the first `limit` of them.
    pub fn select_pairs(&self, split: Option<&str>, limit: Option<usize>) -> Vec<&PairSpec> {
        self.pairs
            .iter()
            .filter(|p| split.is_none_or(|s| p.split.eq_ignore_ascii_case(s)))
            .take(limit.unwrap_or(usize::MAX))
            .collect()
    }

    pub fn fragments(&self) -> &[FragmentSpec] {
        &self.fragments
    }

    pub fn pair(&self, id: &str) -> Option<&PairSpec> {
        self.pairs.iter().find(|p| p.id == id)
    }

    pub fn fragment(&self, id: &str) -> Option<&FragmentSpec> {
        self.fragments.iter().find(|f| f.id == id)
    }

    /// Pairs whose split equals `split` (case-insensitive).
    pub fn pairs_in_split<'a>(&'a self, split: &'a str) -> impl Iterator<Item = &'a PairSpec> + 'a {
        self.pairs
            .iter()
            .filter(move |p| p.split.eq_ignore_ascii_case(split))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    /// What `gt_matrix_toml` writes reads back as the same numbers, to the bit (the reader then
    /// makes the rotation exactly orthonormal, a change at the 1e-12 level).
    #[test]
    fn gt_matrix_toml_reads_back_exactly() {
        let t = Isometry3::new(
            nalgebra::Vector3::new(0.1, -2.0 / 3.0, 1e-9),
            nalgebra::Vector3::new(0.3, -1.1, 0.7),
        );
        #[derive(Deserialize)]
        struct Row {
            gt_matrix: Vec<Vec<f64>>,
        }
        let text = format!("gt_matrix = {}", gt_matrix_toml(&t));
        let row: Row = toml::from_str(&text).unwrap();
        let h = t.to_homogeneous();
        for (r, v) in row.gt_matrix.iter().enumerate() {
            assert_eq!(
                v.as_slice(),
                h.row(r).iter().copied().collect::<Vec<_>>(),
                "{text}"
            );
        }
        let back = matrix_field(Path::new("m.toml"), "gt_matrix", &row.gt_matrix).unwrap();
        assert!((back.to_homogeneous() - h).amax() < 1e-12, "{text}");
    }

    const GTLOG: &str = "0 1 3\n1 0 0 0.5\n0 1 0 0\n0 0 1 0\n0 0 0 1\n";

    fn setup() -> tempfile::TempDir {
        let d = tempfile::tempdir().unwrap();
        write(d.path(), "a.ply", "x");
        write(d.path(), "b.ply", "x");
        write(d.path(), "gt.log", GTLOG);
        d
    }

    #[test]
    fn parses_fragments_pairs_and_gt() {
        let d = setup();
        let m = write(
            d.path(),
            "m.toml",
            r#"
name = "t"
[[fragments]]
id = "0"
cloud = "a.ply"
[[fragments]]
id = "1"
cloud = "b.ply"
[[pairs]]
target = "0"
source = "1"
split = "3DMatch"
gt_log = "gt.log"
[[pairs]]
target = "1"
source = "0"
gt_matrix = [[1,0,0,0],[0,1,0,2],[0,0,1,0],[0,0,0,1]]
"#,
        );
        let ds = Dataset::load(&m).unwrap();
        assert_eq!(ds.pairs().len(), 2);
        assert_eq!(ds.pairs()[0].id, "t/0-1");
        assert_eq!(ds.pairs()[0].split, "3DMatch");
        let t = ds.pairs()[0].gt_target_from_source.unwrap();
        assert!((t.translation.vector.x - 0.5).abs() < 1e-12);
        let t = ds.pairs()[1].gt_target_from_source.unwrap();
        assert!((t.translation.vector.y - 2.0).abs() < 1e-12);
        assert_eq!(ds.pairs_in_split("3dmatch").count(), 1);
        assert_eq!(ds.root, d.path());
    }

    fn err_of(d: &Path, body: &str) -> String {
        let m = write(d, "bad.toml", body);
        Dataset::load(&m).unwrap_err().to_string()
    }

    #[test]
    fn clear_errors() {
        let d = setup();
        let frag = "name = \"t\"\n[[fragments]]\nid = \"0\"\ncloud = \"a.ply\"\n[[fragments]]\nid = \"1\"\ncloud = \"b.ply\"\n";
        // Missing cloud file.
        let e = err_of(
            d.path(),
            "name = \"t\"\n[[fragments]]\nid = \"0\"\ncloud = \"nope.ply\"\n",
        );
        assert!(
            e.contains("bad.toml")
                && e.contains("fragments[0]")
                && e.contains("cloud")
                && e.contains("nope.ply"),
            "{e}"
        );
        // Unknown fragment id in a pair.
        let e = err_of(
            d.path(),
            &format!("{frag}[[pairs]]\ntarget = \"0\"\nsource = \"7\"\n"),
        );
        assert!(
            e.contains("bad.toml") && e.contains("source") && e.contains("\"7\""),
            "{e}"
        );
        // gt.log entry that does not exist.
        let e = err_of(
            d.path(),
            &format!("{frag}[[pairs]]\ntarget = \"1\"\nsource = \"0\"\ngt_log = \"gt.log\"\n"),
        );
        assert!(
            e.contains("bad.toml") && e.contains("gt_log") && e.contains("`1 0`"),
            "{e}"
        );
        // Non-rigid inline matrix.
        let e = err_of(d.path(), &format!("{frag}[[pairs]]\ntarget = \"1\"\nsource = \"0\"\ngt_matrix = [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]\n"));
        assert!(e.contains("gt_matrix") && e.contains("rigid"), "{e}");
        // Wrong shape.
        let e = err_of(
            d.path(),
            &format!(
                "{frag}[[pairs]]\ntarget = \"1\"\nsource = \"0\"\ngt_matrix = [[1,0,0],[0,1,0]]\n"
            ),
        );
        assert!(e.contains("4 rows"), "{e}");
        // Unknown field (typo).
        let e = err_of(
            d.path(),
            &format!("{frag}[[pairs]]\ntarget = \"1\"\nsource = \"0\"\ngt_lg = \"gt.log\"\n"),
        );
        assert!(e.contains("bad.toml") && e.contains("gt_lg"), "{e}");
        // Duplicate fragment id.
        let e = err_of(d.path(), "name = \"t\"\n[[fragments]]\nid = \"0\"\ncloud = \"a.ply\"\n[[fragments]]\nid = \"0\"\ncloud = \"b.ply\"\n");
        assert!(e.contains("duplicate"), "{e}");
        // Unset variable in root.
        let e = err_of(
            d.path(),
            "name = \"t\"\nroot = \"$CGENREG_SURELY_UNSET_VAR_42\"\n",
        );
        assert!(
            e.contains("root") && e.contains("CGENREG_SURELY_UNSET_VAR_42"),
            "{e}"
        );
        // A fragment with neither cloud nor sequence.
        let e = err_of(d.path(), "name = \"t\"\n[[fragments]]\nid = \"0\"\n");
        assert!(e.contains("fragments[0]") && e.contains("sequence"), "{e}");
        // Unknown pair id at load time.
        let m = write(d.path(), "ok.toml", frag);
        let ds = Dataset::load(&m).unwrap();
        let e = ds.load_pair("t/0-9").unwrap_err().to_string();
        assert!(e.contains("ok.toml") && e.contains("t/0-9"), "{e}");
    }

    /// `kitti_fields = 3` reads an x,y,z `.bin` whose size also fits 16-byte points (48 bytes
    /// per 4 or 3 points), which the size rule alone refuses; misuse is a clear error.
    #[test]
    fn kitti_fields_in_a_manifest() {
        let d = tempfile::tempdir().unwrap();
        let xyz: Vec<u8> = (0..36)
            .flat_map(|i| ((i as f32 - 20.0) * 0.25).to_le_bytes())
            .collect();
        std::fs::write(d.path().join("s.bin"), &xyz).unwrap();
        let frag = |extra: &str| {
            format!("name = \"t\"\n[[fragments]]\nid = \"0\"\ncloud = \"s.bin\"\n{extra}")
        };
        let ds = Dataset::load(&write(d.path(), "m3.toml", &frag("kitti_fields = 3\n"))).unwrap();
        let s = ds.load_fragment("0").unwrap();
        assert_eq!(s.cloud.len(), 12);
        assert!(s.cloud.intensity.is_none());
        let ds = Dataset::load(&write(d.path(), "m.toml", &frag(""))).unwrap();
        let e = ds.load_fragment("0").unwrap_err().to_string();
        assert!(e.contains("s.bin") && e.contains("kitti_fields"), "{e}");
        let e = err_of(d.path(), &frag("kitti_fields = 5\n"));
        assert!(
            e.contains("fragments[0]") && e.contains(".kitti_fields") && e.contains("3 (x, y, z)"),
            "{e}"
        );
        std::fs::write(d.path().join("a.ply"), b"").unwrap();
        let e = err_of(
            d.path(),
            "name = \"t\"\n[[fragments]]\nid = \"0\"\ncloud = \"a.ply\"\nkitti_fields = 3\n",
        );
        assert!(e.contains("kitti_fields only with"), "{e}");
    }

    /// `gt_poses = true` gives `target_from_source = inv(P_target_first) * P_source_first`:
    /// a source point in its first camera lands on the same world point as its image in the
    /// target's first camera. Misuse is a clear error.
    #[test]
    fn gt_from_frame_poses() {
        use nalgebra::{Point3, Translation3, UnitQuaternion};
        let d = tempfile::tempdir().unwrap();
        let seq = d.path().join("seq");
        std::fs::create_dir_all(&seq).unwrap();
        write(
            &seq,
            "camera-intrinsics.txt",
            "585 0 320\n0 585 240\n0 0 1\n",
        );
        let pose = |i: usize| {
            Isometry3::from_parts(
                Translation3::new(0.1 * i as f64, -0.05 * i as f64, 0.02 * i as f64),
                UnitQuaternion::from_euler_angles(
                    0.01 * i as f64,
                    0.02 * i as f64,
                    0.03 * i as f64,
                ),
            )
        };
        for i in 0..6 {
            write(&seq, &format!("frame-{i:06}.depth.png"), "x");
            crate::camera::camera_txt::write_pose(
                &seq.join(format!("frame-{i:06}.pose.txt")),
                &pose(i),
            )
            .unwrap();
        }
        write(d.path(), "a.ply", "x");
        let frags =
            "name = \"t\"\n[[fragments]]\nid = \"a\"\nsequence = \"seq\"\nfirst = 1\ncount = 2\n\
                     [[fragments]]\nid = \"b\"\nsequence = \"seq\"\nfirst = 4\ncount = 2\n\
                     [[fragments]]\nid = \"c\"\ncloud = \"a.ply\"\n";
        let m = write(
            d.path(),
            "m.toml",
            &format!("{frags}[[pairs]]\ntarget = \"a\"\nsource = \"b\"\ngt_poses = true\n"),
        );
        let ds = Dataset::load(&m).unwrap();
        let p = &ds.pairs()[0];
        let t = p.gt_target_from_source.unwrap();
        let q = Point3::new(0.3, -0.2, 1.5); // a point in frame 4's camera
        let world = pose(4) * q;
        let in_target = t * q;
        assert!((pose(1) * in_target - world).norm() < 1e-6);
        assert!(
            (t.to_homogeneous() - (pose(1).inverse() * pose(4)).to_homogeneous()).amax() < 1e-6
        );
        assert!(
            p.gt_origin.as_deref().unwrap().contains("frame-000001")
                && p.gt_origin.as_deref().unwrap().contains("frame-000004")
        );
        // A fragment without frames, and two GT sources at once.
        let e = err_of(
            d.path(),
            &format!("{frags}[[pairs]]\ntarget = \"a\"\nsource = \"c\"\ngt_poses = true\n"),
        );
        assert!(e.contains("gt_poses") && e.contains("\"c\""), "{e}");
        let e = err_of(
            d.path(),
            &format!("{frags}[[pairs]]\ntarget = \"a\"\nsource = \"b\"\ngt_poses = true\ngt_matrix = [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]\n"),
        );
        assert!(e.contains("at most one"), "{e}");
    }

    #[test]
    fn root_override_and_env_expansion() {
        let d = setup();
        let sub = d.path().join("manifests");
        std::fs::create_dir_all(&sub).unwrap();
        let body = "name = \"t\"\nroot = \"..\"\n[[fragments]]\nid = \"0\"\ncloud = \"a.ply\"\n";
        let m = write(&sub, "m.toml", body);
        let ds = Dataset::load(&m).unwrap();
        assert!(
            matches!(&ds.fragments()[0].source, FragmentSource::Cloud { path, .. } if path.is_file())
        );
        // Override: same manifest, root given explicitly.
        let ds = Dataset::load_with_root(&m, Some(d.path())).unwrap();
        assert_eq!(ds.root, d.path());
        // ${VAR} expansion with a variable set by the test process itself.
        let var = "CGENREG_TEST_MANIFEST_ROOT_X";
        std::env::set_var(var, d.path());
        let m2 = write(&sub, "m2.toml", &format!("name = \"t\"\nroot = \"${{{var}}}\"\n[[fragments]]\nid = \"0\"\ncloud = \"a.ply\"\n"));
        let ds = Dataset::load(&m2).unwrap();
        assert_eq!(ds.root, d.path());
    }
}
