//! Opening scans from what a user names: a dataset manifest, a 3DMatch-style folder, an RGB-D
//! sequence folder or two cloud files (+ a ground-truth file); the kind is given or guessed
//! from the names ([`classify_drop`]). The inspector's Open menu, drag and drop and file
//! browser all come here.

use super::manifest::Dataset;
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// What a dropped or chosen path is meant to be.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum OpenKind {
    /// Decide from the file names (drag and drop).
    Auto,
    Manifest,
    ThreeDMatchFolder,
    RgbdSequence,
    /// Exactly two cloud files: source then target.
    TwoClouds,
    CosmosOutput,
    /// Two `cgenreg bench --json` outputs compared pair by pair (the inspector's Compare
    /// tab); not a dataset.
    Comparison,
}

impl OpenKind {
    pub fn label(self) -> &'static str {
        match self {
            Self::Auto => "Auto",
            Self::Manifest => "Dataset manifest…",
            Self::ThreeDMatchFolder => "3DMatch folder…",
            Self::RgbdSequence => "RGB-D sequence…",
            Self::TwoClouds => "Two cloud files…",
            Self::CosmosOutput => "Cosmos output folder…",
            Self::Comparison => "Compare runs (two bench JSONs)…",
        }
    }
    pub fn wants_folder(self) -> bool {
        matches!(
            self,
            Self::ThreeDMatchFolder | Self::RgbdSequence | Self::CosmosOutput
        )
    }
}

fn ext_lower(p: &Path) -> String {
    p.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

fn is_cloud_file(p: &Path) -> bool {
    matches!(
        ext_lower(p).as_str(),
        "ply" | "pcd" | "xyz" | "npy" | "bin" | "pth"
    )
}

/// A ground-truth file next to two clouds: any `.txt`, or a `.npy` named like a transform.
fn is_gt_file(p: &Path) -> bool {
    let stem = p
        .file_stem()
        .map(|s| s.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext_lower(p).as_str() {
        "txt" => true,
        "npy" => ["gt", "pose", "transform"]
            .iter()
            .any(|w| stem.starts_with(w) || stem.ends_with(w)),
        _ => false,
    }
}

/// Splits the paths of a two-cloud open into (source, target, ground truth): two cloud files
/// and at most one GT file ([`crate::dataset::read_gt_matrix`]). The order given is source
/// then target, unless the names say otherwise (src/source vs tgt/target/ref).
pub fn split_two_clouds(
    paths: &[PathBuf],
) -> std::result::Result<(PathBuf, PathBuf, Option<PathBuf>), String> {
    let (gt, clouds): (Vec<&PathBuf>, Vec<&PathBuf>) = if paths.len() == 3 {
        paths.iter().partition(|p| is_gt_file(p))
    } else {
        (Vec::new(), paths.iter().collect())
    };
    let names = || {
        paths
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    if clouds.len() != 2 || gt.len() > 1 {
        return Err(format!(
            "{}: expected two point-cloud files (source, target) and optionally one 4x4 \
             ground-truth file (.txt or gt.npy)",
            names()
        ));
    }
    if let Some(bad) = clouds.iter().find(|p| !is_cloud_file(p)) {
        return Err(format!(
            "{}: expected a point-cloud file (.ply .pcd .xyz .npy .bin .pth)",
            bad.display()
        ));
    }
    // 0: named as a source, 1: no hint, 2: named as a target
    let rank = |p: &Path| {
        let s = p
            .file_stem()
            .map(|s| s.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        if s.contains("src") || s.contains("source") {
            0
        } else if s.contains("tgt") || s.contains("target") || s.contains("ref") {
            2
        } else {
            1
        }
    };
    let (mut s, mut t) = (clouds[0].clone(), clouds[1].clone());
    if rank(&s) > rank(&t) {
        std::mem::swap(&mut s, &mut t);
    }
    Ok((s, t, gt.first().map(|p| (*p).clone())))
}

/// Guesses what dropped files are, from their names: a manifest, two clouds (+ a GT file), or
/// a folder (RGB-D sequence, Cosmos output or 3DMatch fragments).
pub fn classify_drop(paths: &[PathBuf]) -> OpenKind {
    if (paths.len() == 2 || paths.len() == 3) && split_two_clouds(paths).is_ok() {
        return OpenKind::TwoClouds;
    }
    if paths.len() == 1 {
        let p = &paths[0];
        if p.is_dir() {
            if p.join("seq-01").is_dir() || p.join("camera-intrinsics.txt").is_file() {
                return OpenKind::RgbdSequence;
            }
            if std::fs::read_dir(p)
                .map(|d| {
                    d.flatten()
                        .any(|e| e.file_name().to_string_lossy().starts_with("video_"))
                })
                .unwrap_or(false)
            {
                return OpenKind::CosmosOutput;
            }
            return OpenKind::ThreeDMatchFolder;
        }
        if matches!(ext_lower(p).as_str(), "json" | "toml" | "txt") {
            return OpenKind::Manifest;
        }
    }
    OpenKind::Auto
}

/// Frames per fragment when an RGB-D sequence is opened (3DMatch's fragment length).
pub const SEQUENCE_FRAGMENT_LEN: usize = crate::dataset::fragment::FRAGMENT_LEN;

/// The dataset behind an open request (`Auto` is decided by [`classify_drop`]). Errors
/// name the path and what was expected there.
pub fn open_dataset(kind: OpenKind, paths: &[PathBuf]) -> Result<Dataset> {
    let kind = match kind {
        OpenKind::Auto => classify_drop(paths),
        k => k,
    };
    let one = |expected: &str| -> Result<&PathBuf> {
        match paths {
            [p] => Ok(p),
            _ => Err(Error::Usage(format!(
                "{}: expected {expected}, got {} paths",
                paths
                    .iter()
                    .map(|p| p.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", "),
                paths.len()
            ))),
        }
    };
    let folder = |expected: &str| -> Result<&PathBuf> {
        let p = one(expected)?;
        if !p.is_dir() {
            return Err(Error::format(p, "folder", expected, "not a folder"));
        }
        Ok(p)
    };
    match kind {
        OpenKind::Manifest => Dataset::load(one("one dataset manifest (.toml)")?),
        OpenKind::ThreeDMatchFolder => super::threedmatch::open_folder(folder(
            "a 3DMatch-style folder (cloud_bin_<k>.ply + gt.log)",
        )?),
        OpenKind::RgbdSequence => {
            let mut dir = folder(
                "an RGB-D sequence folder (camera-intrinsics.txt + frame-XXXXXX.depth.png)",
            )?
            .clone();
            // 3DMatch's raw layout keeps the frames in seq-01/
            if !dir.join("camera-intrinsics.txt").is_file()
                && dir.join("seq-01/camera-intrinsics.txt").is_file()
            {
                dir = dir.join("seq-01");
            }
            Dataset::from_rgbd_sequence(&dir, SEQUENCE_FRAGMENT_LEN)
        }
        OpenKind::TwoClouds => {
            let (s, t, gt) = split_two_clouds(paths).map_err(Error::Invalid)?;
            Dataset::from_two_files(&s, &t, gt.as_deref())
        }
        OpenKind::CosmosOutput => Err(Error::Usage(format!(
            "{}: a Cosmos output folder holds generated frames, not scans: it is opened as the \
             image branch's cached Cosmos backend for the open dataset",
            one("one folder")?.display()
        ))),
        OpenKind::Comparison => Err(Error::Usage(format!(
            "{}: two bench runs are compared in the Compare tab, not opened as a dataset",
            paths
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ))),
        OpenKind::Auto => Err(Error::Invalid(format!(
            "cannot tell what {} is: expected a dataset manifest (.toml), a 3DMatch folder, an \
             RGB-D sequence folder, or two cloud files (+ an optional 4x4 GT .txt/.npy)",
            paths
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drops_are_classified() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(
            classify_drop(&["a.ply".into(), "b.PLY".into()]),
            OpenKind::TwoClouds
        );
        assert_eq!(classify_drop(&["m.json".into()]), OpenKind::Manifest);
        std::fs::create_dir(dir.path().join("video_0")).unwrap();
        assert_eq!(
            classify_drop(&[dir.path().to_path_buf()]),
            OpenKind::CosmosOutput
        );
        let seq = tempfile::tempdir().unwrap();
        std::fs::create_dir(seq.path().join("seq-01")).unwrap();
        assert_eq!(
            classify_drop(&[seq.path().to_path_buf()]),
            OpenKind::RgbdSequence
        );
        let frags = tempfile::tempdir().unwrap();
        assert_eq!(
            classify_drop(&[frags.path().to_path_buf()]),
            OpenKind::ThreeDMatchFolder
        );
        // two clouds plus a GT file, in any order
        assert_eq!(
            classify_drop(&["gt.txt".into(), "a.ply".into(), "b.pcd".into()]),
            OpenKind::TwoClouds
        );
        assert_eq!(
            classify_drop(&["src.npy".into(), "ref.npy".into(), "gt.npy".into()]),
            OpenKind::TwoClouds
        );
        assert_eq!(
            classify_drop(&["a.ply".into(), "b.jpg".into()]),
            OpenKind::Auto
        );
        assert_eq!(classify_drop(&["a.ply".into()]), OpenKind::Auto);
    }

    #[test]
    fn two_clouds_split_into_source_target_gt() {
        let p = |v: &[&str]| v.iter().map(PathBuf::from).collect::<Vec<_>>();
        let (s, t, g) = split_two_clouds(&p(&["a.ply", "b.ply"])).unwrap();
        assert_eq!((s, t, g), ("a.ply".into(), "b.ply".into(), None));
        // names win over the order
        let (s, t, g) = split_two_clouds(&p(&["tgt.ply", "gt.txt", "src.ply"])).unwrap();
        assert_eq!(
            (s, t, g),
            ("src.ply".into(), "tgt.ply".into(), Some("gt.txt".into()))
        );
        let (s, t, g) = split_two_clouds(&p(&["ref.npy", "src.npy", "gt.npy"])).unwrap();
        assert_eq!(
            (s, t, g),
            ("src.npy".into(), "ref.npy".into(), Some("gt.npy".into()))
        );
        let e = split_two_clouds(&p(&["a.ply", "b.ply", "c.ply"])).unwrap_err();
        assert!(
            e.contains("c.ply") && e.contains("two point-cloud files"),
            "{e}"
        );
        let e = split_two_clouds(&p(&["a.ply", "notes.doc"])).unwrap_err();
        assert!(
            e.contains("notes.doc") && e.contains("point-cloud file"),
            "{e}"
        );
    }
}
