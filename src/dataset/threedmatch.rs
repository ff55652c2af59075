//! 3DMatch-style fragment folders: `cloud_bin_<k>.{ply,pcd,npy,pth}` and a `gt.log` whose
//! entry `i j` gives p_i = T * p_j (target i, source j). The 3DMatch split comes from
//! `<dir>/gt.log` (or `<dir>/3DMatch/gt.log`); the 3DLoMatch split, when present, from
//! `<dir>/3DLoMatch/gt.log` or, in the Predator layout, `<dir>/../../3DLoMatch/<scene>/gt.log`
//! next to `.../3DMatch/<scene>/gt.log`.

use super::manifest::{Dataset, FragmentSource, FragmentSpec, PairSpec};
use crate::error::{Error, Result};
use crate::io::gtlog::{read_gt_info, read_gt_log};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

const CLOUD_EXTS: [&str; 4] = ["ply", "pcd", "npy", "pth"];

fn first_file(cands: &[PathBuf]) -> Option<PathBuf> {
    cands.iter().find(|p| p.is_file()).cloned()
}

/// Open a 3DMatch-style folder as a dataset named after the folder. Pairs are the gt.log
/// entries whose two fragments are both present, ids `"<folder>/<i>-<j>"`.
pub fn open_folder(dir: &Path) -> Result<Dataset> {
    let rd = std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))?;
    let mut clouds: BTreeMap<usize, PathBuf> = BTreeMap::new();
    for ent in rd {
        let ent = ent.map_err(|e| Error::io(dir, e))?;
        let name = ent.file_name().to_string_lossy().into_owned();
        let Some(rest) = name.strip_prefix("cloud_bin_") else {
            continue;
        };
        let Some((num, ext)) = rest.split_once('.') else {
            continue;
        };
        let (Ok(k), true) = (num.parse::<usize>(), CLOUD_EXTS.contains(&ext)) else {
            continue;
        };
        // Prefer the first extension in CLOUD_EXTS order when several exist.
        let better = match clouds.get(&k) {
            Some(old) => {
                let rank = |p: &Path| {
                    p.extension()
                        .and_then(|e| CLOUD_EXTS.iter().position(|x| e == *x))
                        .unwrap_or(usize::MAX)
                };
                rank(&ent.path()) < rank(old)
            }
            None => true,
        };
        if better {
            clouds.insert(k, ent.path());
        }
    }
    if clouds.is_empty() {
        return Err(Error::format(
            dir,
            "fragments",
            "cloud_bin_<k>.{ply,pcd,npy,pth} files",
            "none",
        ));
    }
    let scene = dir
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "3dmatch".into());
    let lo_cands = {
        let mut v = vec![dir.join("3DLoMatch/gt.log")];
        if let Some(gp) = dir.parent().and_then(|p| p.parent()) {
            v.push(gp.join("3DLoMatch").join(&scene).join("gt.log"));
        }
        v
    };
    let splits = [
        (
            "3DMatch",
            first_file(&[dir.join("gt.log"), dir.join("3DMatch/gt.log")]),
        ),
        ("3DLoMatch", first_file(&lo_cands)),
    ];
    if splits[0].1.is_none() && splits[1].1.is_none() {
        return Err(Error::format(
            dir,
            "gt.log",
            "gt.log (3DMatch pairs) in the folder",
            "none",
        ));
    }
    let mut pairs = Vec::new();
    for (split, log) in &splits {
        let Some(log) = log else { continue };
        // the information matrices beside it, when present (3DMatch's RMSE recall)
        let info = log.with_file_name("gt.info");
        let infos = if info.is_file() {
            read_gt_info(&info)?
        } else {
            Vec::new()
        };
        for e in read_gt_log(log)? {
            if !(clouds.contains_key(&e.target) && clouds.contains_key(&e.source)) {
                continue;
            }
            let id = format!("{scene}/{}-{}", e.target, e.source);
            if pairs.iter().any(|p: &PairSpec| p.id == id) {
                continue;
            }
            pairs.push(PairSpec {
                preset: None,
                id,
                target: e.target.to_string(),
                source: e.source.to_string(),
                split: split.to_string(),
                gt_target_from_source: Some(e.target_from_source),
                gt_origin: Some(format!(
                    "{} entry `{} {}`",
                    log.display(),
                    e.target,
                    e.source
                )),
                scene: Some(scene.clone()),
                gt_info: infos
                    .iter()
                    .find(|i| i.target == e.target && i.source == e.source)
                    .cloned(),
            });
        }
    }
    Ok(Dataset {
        preset: None,
        scene_prompt: None,
        geo_features: None,
        fragment_cache: None,
        name: scene,
        manifest: None,
        root: dir.to_path_buf(),
        fragments: clouds
            .into_iter()
            .map(|(k, path)| FragmentSpec {
                id: k.to_string(),
                source: FragmentSource::Cloud {
                    path,
                    frames: None,
                    kitti_fields: None,
                },
            })
            .collect(),
        pairs,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::gtlog::{write_gt_log, GtEntry};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    fn write_ply(path: &Path, pts: &[[f32; 3]]) {
        let mut b = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
            pts.len()
        )
        .into_bytes();
        for p in pts {
            for v in p {
                b.extend_from_slice(&v.to_le_bytes());
            }
        }
        std::fs::write(path, b).unwrap();
    }

    #[test]
    fn folder_with_two_splits() {
        let d = tempfile::tempdir().unwrap();
        let scene = d.path().join("3DMatch/kitchen");
        std::fs::create_dir_all(&scene).unwrap();
        std::fs::create_dir_all(d.path().join("3DLoMatch/kitchen")).unwrap();
        let pts: Vec<[f32; 3]> = (0..100)
            .map(|i| [i as f32 * 0.01, (i % 7) as f32, 1.0])
            .collect();
        for k in [0, 1, 3] {
            write_ply(&scene.join(format!("cloud_bin_{k}.ply")), &pts);
        }
        let t = Isometry3::from_parts(
            Translation3::new(0.3, 0.0, -0.1),
            UnitQuaternion::from_euler_angles(0.0, 0.3, 0.0),
        );
        let e = |i, j| GtEntry {
            target: i,
            source: j,
            n_fragments: 4,
            target_from_source: t,
        };
        // (0,2) references a fragment that is not in the folder and must be skipped.
        write_gt_log(&scene.join("gt.log"), &[e(0, 1), e(0, 2), e(1, 3)]).unwrap();
        write_gt_log(&d.path().join("3DLoMatch/kitchen/gt.log"), &[e(0, 3)]).unwrap();
        let ds = open_folder(&scene).unwrap();
        let ids: Vec<_> = ds
            .pairs()
            .iter()
            .map(|p| (p.id.as_str(), p.split.as_str()))
            .collect();
        assert_eq!(
            ids,
            [
                ("kitchen/0-1", "3DMatch"),
                ("kitchen/1-3", "3DMatch"),
                ("kitchen/0-3", "3DLoMatch")
            ]
        );
        let pair = ds.load_pair("kitchen/1-3").unwrap();
        assert_eq!(pair.source.cloud.len(), 100);
        let g = pair.gt_target_from_source.unwrap();
        assert!((g.to_homogeneous() - t.to_homogeneous()).amax() < 1e-7);
        assert!(open_folder(d.path())
            .unwrap_err()
            .to_string()
            .contains("cloud_bin_"));
    }
}
