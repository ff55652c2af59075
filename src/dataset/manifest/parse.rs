//! Reading a manifest: the TOML as written (`Raw*`), `$VAR` expansion, the fragment options,
//! the paths resolved under the root, and each fragment's and pair's spec with its ground truth.

use super::*;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawManifest {
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
pub(super) struct RawOptions {
    voxel: Option<f64>,
    max_depth: Option<f64>,
    min_depth: Option<f64>,
    crop: Option<String>,
    color: Option<bool>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawFragment {
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
pub(super) struct RawPair {
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
pub(super) fn preset_field(path: &Path, field: &str, s: Option<&str>) -> Result<Option<Preset>> {
    match s {
        None => Ok(None),
        Some(s) => Preset::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .map(Some)
            .ok_or_else(|| bad(path, field, "\"indoor\" or \"outdoor\"", format!("{s:?}"))),
    }
}

/// Expand `$VAR` and `${VAR}`. `CGENREG_DATA` falls back to [`crate::data_root`] when unset.
pub(super) fn expand_env(manifest: &Path, s: &str) -> Result<String> {
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

pub(super) fn parse_crop(manifest: &Path, field: &str, s: &str) -> Result<Option<CropBox>> {
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

pub(super) fn apply_options(
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

/// Paths of a manifest, resolved against its root: they must exist with the kind asked for and,
/// unless the manifest allows otherwise, lie inside the root once symlinks are resolved.
pub(super) struct Resolver<'a> {
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
pub(super) fn fragment_source(
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
                None => crate::dataset::fragment::FRAGMENT_LEN,
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
pub(super) fn pair_info(
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
            Some(crate::dataset::read_gt_matrix(&fp)?),
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
}
