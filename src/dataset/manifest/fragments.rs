//! Data sets without a manifest (two cloud files, a raw RGB-D sequence) and loading a data
//! set's fragments and pairs (built from raw frames through the fragment cache, or read).

use super::*;

impl Dataset {
    /// A one-pair dataset `"files"` from two point-cloud files: `source` is registered onto
    /// `target`, with optional ground truth `target_from_source` (p_target = T * p_source) from
    /// a 4x4 text or .npy file ([`crate::dataset::read_gt_matrix`], read here). The pair id is
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
        let gt_t = gt.map(crate::dataset::read_gt_matrix).transpose()?;
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

    pub(super) fn origin(&self) -> String {
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
