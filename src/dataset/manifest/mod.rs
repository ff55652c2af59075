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

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawManifest {
    name: String,
    root: Option<String>,
    /// Paths may lead outside `root` (`..`, absolute paths, symlinks).
    allow_outside_root: Option<bool>,
    preset: Option<String>,
    scene_prompt: Option<String>,
    geo_features: Option<String>,
    fragment_options: Option<RawOptions>,
    #[serde(default)]
    fragments: Vec<RawFragment>,
    #[serde(default)]
    pairs: Vec<RawPair>,
}

#[derive(Deserialize, Default, Clone)]
#[serde(deny_unknown_fields)]
struct RawOptions {
    voxel: Option<f64>,
    max_depth: Option<f64>,
    min_depth: Option<f64>,
    crop: Option<String>,
    color: Option<bool>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFragment {
    id: String,
    cloud: Option<String>,
    kitti_fields: Option<u64>,
    sequence: Option<String>,
    first: Option<usize>,
    count: Option<usize>,
    voxel: Option<f64>,
    max_depth: Option<f64>,
    min_depth: Option<f64>,
    crop: Option<String>,
    color: Option<bool>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPair {
    target: String,
    source: String,
    split: Option<String>,
    gt_log: Option<String>,
    gt_entry: Option<[usize; 2]>,
    gt_info: Option<String>,
    scene: Option<String>,
    gt_matrix: Option<Vec<Vec<f64>>>,
    gt_file: Option<String>,
    gt_poses: Option<bool>,
    preset: Option<String>,
}

/// A `preset` field: "indoor" or "outdoor".
fn preset_field(path: &Path, field: &str, s: Option<&str>) -> Result<Option<Preset>> {
    match s {
        None => Ok(None),
        Some(s) => Preset::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .map(Some)
            .ok_or_else(|| bad(path, field, "\"indoor\" or \"outdoor\"", format!("{s:?}"))),
    }
}

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

/// Expand `$VAR` and `${VAR}`. `CGENREG_DATA` falls back to [`crate::data_root`] when unset.
fn expand_env(manifest: &Path, s: &str) -> Result<String> {
    let mut out = String::new();
    let mut rest = s;
    while let Some(pos) = rest.find('$') {
        out.push_str(&rest[..pos]);
        let after = &rest[pos + 1..];
        let (var, tail) = if let Some(b) = after.strip_prefix('{') {
            let end = b
                .find('}')
                .ok_or_else(|| bad(manifest, "root", "`${VAR}` with a closing brace", s))?;
            (&b[..end], &b[end + 1..])
        } else {
            let end = after
                .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
                .unwrap_or(after.len());
            (&after[..end], &after[end..])
        };
        if var.is_empty() {
            return Err(bad(manifest, "root", "a variable name after `$`", s));
        }
        let val = match std::env::var(var) {
            Ok(v) => v,
            Err(_) if var == "CGENREG_DATA" => crate::data_root()
                .map(|p| p.to_string_lossy().into_owned())
                .ok_or_else(|| {
                    bad(
                        manifest,
                        "root",
                        "$CGENREG_DATA set to the data folder (or ../shared/data next to the crate)",
                        "neither exists",
                    )
                })?,
            Err(_) => {
                return Err(bad(
                    manifest,
                    "root",
                    format!("environment variable {var} to be set"),
                    "unset",
                ))
            }
        };
        out.push_str(&val);
        rest = tail;
    }
    out.push_str(rest);
    Ok(out)
}

fn parse_crop(manifest: &Path, field: &str, s: &str) -> Result<Option<CropBox>> {
    match s.to_ascii_lowercase().as_str() {
        "3dmatch" => Ok(Some(CropBox::THREEDMATCH)),
        "none" | "" => Ok(None),
        _ => Err(bad(
            manifest,
            field,
            "\"3dmatch\" or \"none\"",
            format!("{s:?}"),
        )),
    }
}

fn apply_options(
    manifest: &Path,
    field: &str,
    base: &FragmentOptions,
    o: &RawOptions,
) -> Result<FragmentOptions> {
    let mut r = base.clone();
    if let Some(v) = o.voxel {
        if !(v.is_finite() && v >= 0.0) {
            return Err(bad(
                manifest,
                format!("{field}.voxel"),
                "a voxel size >= 0 (m)",
                v.to_string(),
            ));
        }
        r.voxel = v;
    }
    if let Some(v) = o.max_depth {
        r.max_depth = v;
    }
    if let Some(v) = o.min_depth {
        r.min_depth = v;
    }
    if !(r.max_depth.is_finite() && r.min_depth.is_finite() && r.max_depth > r.min_depth) {
        return Err(bad(
            manifest,
            format!("{field}.max_depth"),
            "finite depths with min_depth < max_depth",
            format!("[{}, {}]", r.min_depth, r.max_depth),
        ));
    }
    if let Some(c) = &o.crop {
        r.crop = parse_crop(manifest, &format!("{field}.crop"), c)?;
    }
    if let Some(c) = o.color {
        r.with_color = c;
    }
    Ok(r)
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

/// Paths of a manifest, resolved against its root: they must exist with the kind asked for and,
/// unless the manifest allows otherwise, lie inside the root once symlinks are resolved.
struct Resolver<'a> {
    manifest: &'a Path,
    root: &'a Path,
    real_root: PathBuf,
    allow_outside: bool,
}

impl Resolver<'_> {
    fn resolve(&self, field: &str, rel: &str, dir: bool) -> Result<PathBuf> {
        let (path, root) = (self.manifest, self.root);
        let p = root.join(expand_env(path, rel)?);
        let want = if dir { "folder" } else { "file" };
        let expected = || format!("an existing {want} (relative to root {})", root.display());
        let found = match std::fs::metadata(&p) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Some("not found"),
            Err(_) => Some("not readable"),
            Ok(m) if dir && !m.is_dir() => Some("not a folder"),
            Ok(m) if !dir && m.is_dir() => Some("a folder"),
            Ok(m) if !dir && !m.is_file() => Some("not a regular file (a FIFO, device or socket)"),
            Ok(_) => None,
        };
        if let Some(why) = found {
            return Err(bad(
                path,
                field,
                expected(),
                format!("{} ({why})", p.display()),
            ));
        }
        if !self.allow_outside {
            // the readers check the file they open against the root again (a file swapped
            // for a link after this check, a frame inside a sequence folder)
            crate::io::limits::confine(&p, &self.real_root);
            let real = p.canonicalize().map_err(|e| Error::io(&p, e))?;
            if !real.starts_with(&self.real_root) {
                return Err(bad(
                    path,
                    field,
                    format!(
                        "a path inside root {} (symlinks resolved; put \
                         `allow_outside_root = true` in the manifest to allow others)",
                        root.display()
                    ),
                    format!("{} (outside the root)", p.display()),
                ));
            }
        }
        Ok(p)
    }
}

/// Where a fragment's points come from: a cloud file (with the frames of a sequence when it
/// names one), or the RGB-D frames of a sequence fused with the fragment options.
fn fragment_source(
    path: &Path,
    field: &str,
    f: &RawFragment,
    resolve: &dyn Fn(&str, &str, bool) -> Result<PathBuf>,
    default_opts: &FragmentOptions,
) -> Result<FragmentSource> {
    let range = match &f.sequence {
        Some(s) => Some(SequenceRange {
            dir: resolve(&format!("{field}.sequence"), s, true)?,
            first: f.first.ok_or_else(|| {
                bad(
                    path,
                    format!("{field}.first"),
                    "the first frame index of the fragment",
                    "missing",
                )
            })?,
            count: match f.count {
                Some(0) => {
                    return Err(bad(path, format!("{field}.count"), "at least 1 frame", "0"))
                }
                Some(c) => c,
                None => super::fragment::FRAGMENT_LEN,
            },
        }),
        None => None,
    };
    let kitti_fields = match f.kitti_fields {
        None => None,
        Some(n) => {
            let is_bin = f.cloud.as_deref().is_some_and(|c| {
                Path::new(c)
                    .extension()
                    .is_some_and(|e| e.eq_ignore_ascii_case("bin"))
            });
            if !is_bin {
                return Err(bad(
                    path,
                    format!("{field}.kitti_fields"),
                    "kitti_fields only with a `cloud = \"....bin\"` file",
                    format!("{:?}", f.cloud.as_deref().unwrap_or("no cloud")),
                ));
            }
            Some(KittiFields::from_count(n).ok_or_else(|| {
                bad(
                    path,
                    format!("{field}.kitti_fields"),
                    "3 (x, y, z) or 4 (x, y, z, intensity)",
                    n.to_string(),
                )
            })?)
        }
    };
    Ok(match (&f.cloud, range) {
        (Some(c), frames) => FragmentSource::Cloud {
            path: resolve(&format!("{field}.cloud"), c, false)?,
            frames,
            kitti_fields,
        },
        (None, Some(range)) => {
            let o = RawOptions {
                voxel: f.voxel,
                max_depth: f.max_depth,
                min_depth: f.min_depth,
                crop: f.crop.clone(),
                color: f.color,
            };
            FragmentSource::Rgbd {
                range,
                options: apply_options(path, field, default_opts, &o)?,
            }
        }
        (None, None) => {
            return Err(bad(
                path,
                field,
                "`cloud = \"file\"` or `sequence = \"dir\"` + `first`",
                "neither",
            ))
        }
    })
}

/// The gt.info entry of a pair's gt.log entry (each file read once).
fn pair_info(
    path: &Path,
    field: &str,
    p: &RawPair,
    info: &str,
    resolve: &dyn Fn(&str, &str, bool) -> Result<PathBuf>,
    infos: &mut HashMap<PathBuf, Vec<GtInfo>>,
) -> Result<GtInfo> {
    let ip = resolve(&format!("{field}.gt_info"), info, false)?;
    let [ei, ej] = gt_entry_indices(path, field, p)?;
    if !infos.contains_key(&ip) {
        let entries = read_gt_info(&ip)?;
        infos.insert(ip.clone(), entries);
    }
    infos[&ip]
        .iter()
        .find(|e| e.target == ei && e.source == ej)
        .cloned()
        .ok_or_else(|| {
            bad(
                path,
                format!("{field}.gt_info"),
                format!("an entry `{ei} {ej}` in {}", ip.display()),
                "no such entry",
            )
        })
}

/// The `i j` of a pair's gt.log / gt.info entry: `gt_entry`, else the fragment ids when both
/// are numbers (target i, source j).
fn gt_entry_indices(path: &Path, field: &str, p: &RawPair) -> Result<[usize; 2]> {
    match (p.gt_entry, p.target.parse(), p.source.parse()) {
        (Some(e), _, _) => Ok(e),
        (None, Ok(a), Ok(b)) => Ok([a, b]),
        _ => Err(bad(
            path,
            format!("{field}.gt_entry"),
            "gt_entry = [i, j] (the ids are not numbers)",
            "missing",
        )),
    }
}

/// A pair's ground truth `target_from_source` and where it came from: a `gt.log` entry (read
/// once per file), an inline matrix, the fragments' frame poses, or a matrix file; none.
#[allow(clippy::too_many_arguments)]
fn pair_gt(
    path: &Path,
    field: &str,
    p: &RawPair,
    resolve: &dyn Fn(&str, &str, bool) -> Result<PathBuf>,
    fragments: &[FragmentSpec],
    logs: &mut HashMap<PathBuf, Vec<GtEntry>>,
    seqs: &mut HashMap<PathBuf, RgbdSequence>,
) -> Result<(Option<Isometry3<f64>>, Option<String>)> {
    let gt_poses = p.gt_poses.unwrap_or(false);
    Ok(if let Some(log) = &p.gt_log {
        let lp = resolve(&format!("{field}.gt_log"), log, false)?;
        let [ei, ej] = gt_entry_indices(path, field, p)?;
        if !logs.contains_key(&lp) {
            let entries = read_gt_log(&lp)?;
            logs.insert(lp.clone(), entries);
        }
        let e = logs[&lp]
            .iter()
            .find(|e| e.target == ei && e.source == ej)
            .ok_or_else(|| {
                bad(
                    path,
                    format!("{field}.gt_log"),
                    format!("an entry `{ei} {ej}` in {}", lp.display()),
                    "no such entry",
                )
            })?;
        (
            Some(e.target_from_source),
            Some(format!("{} entry `{ei} {ej}`", lp.display())),
        )
    } else if let Some(m) = &p.gt_matrix {
        (
            Some(matrix_field(path, &format!("{field}.gt_matrix"), m)?),
            Some("inline gt_matrix".to_string()),
        )
    } else if gt_poses {
        let (t, o) = gt_from_poses(path, field, fragments, &p.target, &p.source, seqs)?;
        (Some(t), Some(o))
    } else if let Some(f) = &p.gt_file {
        let fp = resolve(&format!("{field}.gt_file"), f, false)?;
        (
            Some(super::read_gt_matrix(&fp)?),
            Some(fp.display().to_string()),
        )
    } else {
        (None, None)
    })
}

impl Dataset {
    /// Load a manifest; relative paths resolve against its `root` field.
    pub fn load(path: &Path) -> Result<Dataset> {
        Self::load_with_root(path, None)
    }

    /// Load a manifest, with `root` (when given) replacing the manifest's `root` field.
    pub fn load_with_root(path: &Path, root: Option<&Path>) -> Result<Dataset> {
        // before the parse: the TOML document takes about 60 times its bytes in memory
        let len = crate::io::limits::check_regular(path)?;
        let max = crate::io::limits::max_manifest_bytes();
        if len > max {
            return Err(bad(
                path,
                "file size",
                format!(
                    "a manifest of at most {max} bytes (raise {} if it is real)",
                    crate::io::limits::ENV_MAX_MANIFEST_BYTES
                ),
                format!("{len} bytes"),
            ));
        }
        let text = crate::io::limits::read_text(path)?;
        Self::parse_with_root(path, &text, root)
    }

    /// Parse manifest `text` as if read from `path` (errors name it; relative paths resolve
    /// against its folder or `root`). [`Dataset::load_with_root`] without the file read; the
    /// fuzz target calls it on bytes in memory.
    pub fn parse_with_root(path: &Path, text: &str, root: Option<&Path>) -> Result<Dataset> {
        let raw: RawManifest = toml::from_str(text).map_err(|e| {
            bad(
                path,
                "toml",
                "a dataset manifest (see dataset::manifest docs)",
                e.to_string(),
            )
        })?;
        let base = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."))
            .to_path_buf();
        let root = match root {
            Some(r) => r.to_path_buf(),
            None => {
                let r = expand_env(path, raw.root.as_deref().unwrap_or("."))?;
                base.join(r)
            }
        };
        if !root.is_dir() {
            return Err(bad(
                path,
                "root",
                "an existing folder",
                root.display().to_string(),
            ));
        }
        let allow_outside = raw.allow_outside_root.unwrap_or(false);
        let real_root = root.canonicalize().map_err(|e| Error::io(&root, e))?;
        if !allow_outside && real_root.parent().is_none() {
            // every file is inside "/": the confinement would confine nothing
            return Err(bad(
                path,
                "root",
                "the data's folder (the file system's root confines nothing; put \
                 `allow_outside_root = true` in the manifest to read any file)",
                root.display().to_string(),
            ));
        }
        if raw.name.is_empty() || raw.name.contains('/') || has_hidden_characters(&raw.name) {
            return Err(bad(
                path,
                "name",
                "a non-empty dataset name without '/'",
                format!("{:?}", raw.name),
            ));
        }
        let default_opts = apply_options(
            path,
            "fragment_options",
            &FragmentOptions::default(),
            &raw.fragment_options.clone().unwrap_or_default(),
        )?;

        let resolver = Resolver {
            manifest: path,
            allow_outside,
            // resolved once: every path is checked against the real root (symlinks resolved)
            real_root,
            root: &root,
        };
        let resolve = |field: &str, rel: &str, dir: bool| resolver.resolve(field, rel, dir);

        let mut fragments = Vec::with_capacity(raw.fragments.len());
        let mut seen = HashMap::new();
        for (i, f) in raw.fragments.iter().enumerate() {
            let field = format!("fragments[{i}] (id {:?})", f.id);
            if f.id.is_empty()
                || f.id.contains('/')
                || f.id.contains('-')
                || f.id.len() > MAX_ID_BYTES
                || has_hidden_characters(&f.id)
            {
                return Err(bad(
                    path,
                    format!("{field}.id"),
                    format!(
                        "a non-empty id of at most {MAX_ID_BYTES} bytes without '/', '-' or \
                         control characters (ESC, NUL, line breaks, direction marks)"
                    ),
                    // escaped: the id may hold terminal escapes
                    format!("{:?}", f.id.escape_default().to_string()),
                ));
            }
            if seen.insert(f.id.clone(), i).is_some() {
                return Err(bad(
                    path,
                    format!("{field}.id"),
                    "a unique fragment id",
                    "a duplicate",
                ));
            }
            let source = fragment_source(path, &field, f, &resolve, &default_opts)?;
            fragments.push(FragmentSpec {
                id: f.id.clone(),
                source,
            });
        }

        let mut logs: HashMap<PathBuf, Vec<GtEntry>> = HashMap::new();
        let mut infos: HashMap<PathBuf, Vec<GtInfo>> = HashMap::new();
        let mut seqs: HashMap<PathBuf, RgbdSequence> = HashMap::new();
        let mut pairs = Vec::with_capacity(raw.pairs.len());
        let mut pair_ids = HashMap::new();
        for (i, p) in raw.pairs.iter().enumerate() {
            let field = format!(
                "pairs[{i}] ({} <- {})",
                p.target.escape_debug(),
                p.source.escape_debug()
            );
            for (which, id) in [("target", &p.target), ("source", &p.source)] {
                if !seen.contains_key(id) {
                    return Err(bad(
                        path,
                        format!("{field}.{which}"),
                        "the id of a fragment listed under [[fragments]]",
                        format!("{id:?} (unknown)"),
                    ));
                }
            }
            if let Some(split) = p.split.as_deref().filter(|s| has_hidden_characters(s)) {
                return Err(bad(
                    path,
                    format!("{field}.split"),
                    "a split name without control characters or direction marks",
                    format!("{:?}", split.escape_default().to_string()),
                ));
            }
            let gt_poses = p.gt_poses.unwrap_or(false);
            let n_gt = [
                p.gt_log.is_some(),
                p.gt_matrix.is_some(),
                p.gt_file.is_some(),
                gt_poses,
            ]
            .iter()
            .filter(|&&b| b)
            .count();
            if n_gt > 1 {
                return Err(bad(
                    path,
                    &field,
                    "at most one of gt_log, gt_matrix, gt_file, gt_poses",
                    "several",
                ));
            }
            for (name, given) in [
                ("gt_entry", p.gt_entry.is_some()),
                ("gt_info", p.gt_info.is_some()),
            ] {
                if given && p.gt_log.is_none() {
                    return Err(bad(
                        path,
                        format!("{field}.{name}"),
                        format!("{name} only together with gt_log"),
                        format!("{name} alone"),
                    ));
                }
            }
            let (gt, origin) =
                pair_gt(path, &field, p, &resolve, &fragments, &mut logs, &mut seqs)?;
            let pair_preset = preset_field(path, &format!("{field}.preset"), p.preset.as_deref())?;
            let gt_info = match &p.gt_info {
                Some(info) => Some(pair_info(path, &field, p, info, &resolve, &mut infos)?),
                None => None,
            };
            let id = format!("{}/{}-{}", raw.name, p.target, p.source);
            if pair_ids.insert(id.clone(), i).is_some() {
                return Err(bad(
                    path,
                    field,
                    "each pair listed once",
                    format!("{id} twice"),
                ));
            }
            pairs.push(PairSpec {
                id,
                target: p.target.clone(),
                source: p.source.clone(),
                split: p.split.clone().unwrap_or_default(),
                gt_target_from_source: gt,
                gt_origin: origin,
                preset: pair_preset,
                scene: p.scene.clone(),
                gt_info,
            });
        }
        let scene_prompt = match raw.scene_prompt {
            Some(t) if t.trim().is_empty() => {
                return Err(bad(
                    path,
                    "scene_prompt",
                    "a description of the scene (or no scene_prompt field)",
                    "an empty text",
                ))
            }
            t => t.map(|t| t.trim().to_owned()),
        };
        let geo_features = match raw.geo_features.as_deref() {
            None => None,
            Some(s) => Some(crate::features::DescriptorName::parse(s).ok_or_else(|| {
                let names: Vec<String> = crate::features::DescriptorName::ALL
                    .iter()
                    .map(|d| format!("{:?}", d.name()))
                    .collect();
                bad(path, "geo_features", names.join(", "), format!("{s:?}"))
            })?),
        };
        Ok(Dataset {
            preset: preset_field(path, "preset", raw.preset.as_deref())?,
            scene_prompt,
            geo_features,
            name: raw.name,
            manifest: Some(path.to_path_buf()),
            root,
            fragments,
            pairs,
            fragment_cache: None,
        })
    }

    /// A one-pair dataset `"files"` from two point-cloud files: `source` is registered onto
    /// `target`, with optional ground truth `target_from_source` (p_target = T * p_source) from
    /// a 4x4 text or .npy file ([`super::read_gt_matrix`], read here). The pair id is
    /// `"files/<target stem>-<source stem>"` ('-' and '/' in stems become '_'). The clouds are
    /// read when the pair is loaded; here they only have to exist.
    pub fn from_two_files(source: &Path, target: &Path, gt: Option<&Path>) -> Result<Dataset> {
        for p in [source, target] {
            if !p.is_file() {
                return Err(bad(
                    p,
                    "file",
                    "an existing point-cloud file (.ply .pcd .npy .pth .bin .xyz)",
                    "not found",
                ));
            }
        }
        let gt_t = gt.map(super::read_gt_matrix).transpose()?;
        let stem = |p: &Path, dflt: &str| {
            let s: String = p
                .file_stem()
                .map(|s| s.to_string_lossy().replace(['-', '/'], "_"))
                .unwrap_or_default();
            if s.is_empty() {
                dflt.to_string()
            } else {
                s
            }
        };
        let tid = stem(target, "target");
        let mut sid = stem(source, "source");
        if sid == tid {
            sid.push_str("_source");
        }
        let frag = |id: &str, p: &Path| FragmentSpec {
            id: id.to_string(),
            source: FragmentSource::Cloud {
                path: p.to_path_buf(),
                frames: None,
                kitti_fields: None,
            },
        };
        Ok(Dataset {
            preset: None,
            scene_prompt: None,
            geo_features: None,
            name: "files".into(),
            manifest: None,
            root: target
                .parent()
                .filter(|p| !p.as_os_str().is_empty())
                .unwrap_or(Path::new("."))
                .to_path_buf(),
            fragments: vec![frag(&tid, target), frag(&sid, source)],
            pairs: vec![PairSpec {
                preset: None,
                id: format!("files/{tid}-{sid}"),
                target: tid,
                source: sid,
                split: String::new(),
                gt_target_from_source: gt_t,
                gt_origin: gt.map(|p| p.display().to_string()),
                scene: None,
                gt_info: None,
            }],
            fragment_cache: None,
        })
    }

    /// A dataset from a raw RGB-D sequence folder ([`RgbdSequence`] layout): consecutive
    /// fragments of `fragment_len` frames built as 3DMatch did
    /// ([`FragmentOptions::threedmatch`], 1 cm voxel), and the pairs of neighbouring fragments
    /// (target k, source k+1) with ground truth from the poses,
    /// `target_from_source = inv(P_target_first) * P_source_first` (poses camera-to-world).
    /// Fragment ids are `first_frame / fragment_len` when the first frame index is a multiple
    /// of it (so 7-Scenes fragment k is 3DMatch's cloud_bin_k), else 0, 1, ...
    pub fn from_rgbd_sequence(dir: &Path, fragment_len: usize) -> Result<Dataset> {
        let seq = RgbdSequence::open(dir)?;
        let l = fragment_len.max(1);
        let first = seq.frames[0].index;
        let complete = |s: usize| (s..s + l).all(|i| seq.frame(i).is_some());
        let starts: Vec<usize> = (0..)
            .map(|k| first + k * l)
            .take_while(|&s| complete(s))
            .collect();
        if starts.len() < 2 {
            return Err(bad(
                dir,
                "frames",
                format!(
                    "at least {} consecutive frames from frame {first} (two fragments of {l})",
                    2 * l
                ),
                format!("{} frames", seq.frames.len()),
            ));
        }
        let id = |s: usize| {
            if first % l == 0 {
                (s / l).to_string()
            } else {
                ((s - first) / l).to_string()
            }
        };
        let name = dir
            .file_name()
            .map(|n| n.to_string_lossy().replace('/', "_"))
            .filter(|n| !n.is_empty())
            .unwrap_or_else(|| "rgbd".into());
        let fragments = starts
            .iter()
            .map(|&s| FragmentSpec {
                id: id(s),
                source: FragmentSource::Rgbd {
                    range: SequenceRange {
                        dir: dir.to_path_buf(),
                        first: s,
                        count: l,
                    },
                    options: FragmentOptions::threedmatch(0.01),
                },
            })
            .collect();
        let mut pairs = Vec::with_capacity(starts.len() - 1);
        for w in starts.windows(2) {
            let (t, s) = (w[0], w[1]);
            let gt = seq.world_from_camera(t)?.inverse() * seq.world_from_camera(s)?;
            pairs.push(PairSpec {
                preset: None,
                id: format!("{name}/{}-{}", id(t), id(s)),
                target: id(t),
                source: id(s),
                split: "sequence".into(),
                gt_target_from_source: Some(gt),
                gt_origin: Some(format!("poses: inv(P of frame-{t:06}) * P of frame-{s:06}")),
                scene: None,
                gt_info: None,
            });
        }
        Ok(Dataset {
            preset: None,
            scene_prompt: None,
            geo_features: None,
            name,
            manifest: None,
            root: dir.to_path_buf(),
            fragments,
            pairs,
            fragment_cache: None,
        })
    }

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

    fn origin(&self) -> String {
        self.manifest
            .as_ref()
            .map(|p| p.display().to_string())
            .unwrap_or_else(|| self.root.display().to_string())
    }

    /// Cache fragments built from raw frames in `cache` (see [`super::fragment_cache`]).
    pub fn with_fragment_cache(mut self, cache: Option<crate::cache::Cache>) -> Self {
        self.fragment_cache = cache;
        self
    }

    /// Load (or build) one fragment.
    pub fn load_fragment(&self, id: &str) -> Result<Scan> {
        self.load_fragment_status(id).map(|(s, _)| s)
    }

    /// [`Self::load_fragment`], with how the fragment cache was used (None: no cache involved).
    pub fn load_fragment_status(&self, id: &str) -> Result<(Scan, Option<FragmentCacheStatus>)> {
        let spec = self.fragment(id).ok_or_else(|| {
            Error::Missing(format!("{}: no fragment with id {id:?}", self.origin()))
        })?;
        let name = format!("{}/{}", self.name, spec.id);
        match &spec.source {
            FragmentSource::Cloud {
                path,
                frames,
                kitti_fields,
            } => {
                let (cloud, notes) = match kitti_fields {
                    Some(k) => {
                        let c = crate::io::kitti::read_kitti_bin_fields(path, Some(*k))?;
                        let n = crate::io::cloud::cloud_notes(path, &c, 0);
                        (c, n)
                    }
                    None => crate::io::cloud::load_cloud_noted(path)?,
                };
                if cloud.is_empty() {
                    return Err(Error::Invalid(format!(
                        "{}: empty point cloud",
                        path.display()
                    )));
                }
                let frames = match frames {
                    Some(r) => Some(fragment_frames(
                        &RgbdSequence::open(&r.dir)?,
                        r.first,
                        r.count,
                    )?),
                    None => None,
                };
                Ok((
                    Scan {
                        name,
                        cloud,
                        frames,
                        notes,
                    },
                    None,
                ))
            }
            FragmentSource::Rgbd { range, options } => {
                let seq = RgbdSequence::open(&range.dir)?;
                match &self.fragment_cache {
                    Some(dir) => {
                        build_fragment_cached(&seq, range.first, range.count, options, name, dir)
                            .map(|(s, st)| (s, Some(st)))
                    }
                    None => build_fragment_with(&seq, range.first, range.count, options, name)
                        .map(|s| (s, None)),
                }
            }
        }
    }

    /// Load a pair by id (`"<dataset>/<target>-<source>"`); both fragments load in parallel.
    pub fn load_pair(&self, id: &str) -> Result<ScanPair> {
        self.load_pair_status(id).map(|(p, _)| p)
    }

    /// [`Self::load_pair`], with the fragment cache status of (target, source).
    pub fn load_pair_status(
        &self,
        id: &str,
    ) -> Result<(ScanPair, [Option<FragmentCacheStatus>; 2])> {
        let spec = self.pair(id).ok_or_else(|| {
            Error::Missing(format!(
                "{}: no pair with id {id:?} (ids look like \"{}/<target>-<source>\")",
                self.origin(),
                self.name
            ))
        })?;
        let (target, source) = rayon::join(
            || self.load_fragment_status(&spec.target),
            || self.load_fragment_status(&spec.source),
        );
        let ((target, st), (source, ss)) = (target?, source?);
        Ok((
            ScanPair {
                id: spec.id.clone(),
                source,
                target,
                gt_target_from_source: spec.gt_target_from_source,
            },
            [st, ss],
        ))
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
