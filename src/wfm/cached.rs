//! The `cached` backend: an existing Cosmos output folder plus the JSONL spec it was made from
//! (the authors' published layout, reference §2.7):
//!
//! ```text
//! <spec>.json                       one JSON line per pair; line i <-> depth video i
//! <output_dir>/video_<i>/output.mp4 the generated video of line i (H.264, 960x704, 30 fps)
//! <output_dir>/video_<i>/prompt.txt the prompt actually used
//! ```
//!
//! Cosmos creates `video_<i>/` before generating, so a pair blocked by its guardrail leaves an
//! empty folder that keeps the later positions aligned. Opening validates the positional
//! mapping (a line whose depth video is named `NNNNNN_...mp4` must have NNNNNN == i); the report
//! lists empty (guardrail) and missing folders; `generate` fails clearly on either.
//!
//! A request is matched to its line by, in order: the file name of `depth_video_path` against
//! the spec's `input_control` names; `pair_id` as a line number; `pair_id` as a video name (with
//! or without `.mp4`, with or without its `NNNNNN_` prefix).

use super::backend::{now_unix, GenerateRequest, Generation, Provenance, WfmBackend};
use super::cosmos::ingest_output;
use super::prompt::{read_reference_jsonl, BatchLine};
use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum EntryStatus {
    /// `video_<i>/output.mp4` exists.
    Present,
    /// `video_<i>/` exists but is empty: blocked by the guardrail.
    EmptyGuardrail,
    /// `video_<i>/` exists, is not empty, but has no `output.mp4`.
    NoOutputMp4,
    /// No `video_<i>/` folder at all.
    Missing,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct CachedEntry {
    pub line: usize,
    pub video_dir: PathBuf,
    pub depth_video_name: String,
    pub status: EntryStatus,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct CachedReport {
    pub entries: Vec<CachedEntry>,
    /// `video_<i>` folders with i beyond the last spec line.
    pub extra_folders: Vec<String>,
}

impl CachedReport {
    pub fn count(&self, s: EntryStatus) -> usize {
        self.entries.iter().filter(|e| e.status == s).count()
    }

    /// One line for users: "1623 lines: 1620 present, 2 empty (guardrail), 1 missing".
    pub fn summary(&self) -> String {
        let mut s = format!(
            "{} lines: {} present, {} empty (guardrail), {} missing",
            self.entries.len(),
            self.count(EntryStatus::Present),
            self.count(EntryStatus::EmptyGuardrail),
            self.count(EntryStatus::Missing)
        );
        let n = self.count(EntryStatus::NoOutputMp4);
        if n > 0 {
            s.push_str(&format!(", {n} without output.mp4"));
        }
        if !self.extra_folders.is_empty() {
            s.push_str(&format!(
                ", {} folders beyond the spec",
                self.extra_folders.len()
            ));
        }
        s
    }
}

pub struct CachedBackend {
    pub output_dir: PathBuf,
    pub spec_path: PathBuf,
    pub lines: Vec<BatchLine>,
}

impl CachedBackend {
    pub fn open(output_dir: &Path, spec_path: &Path) -> Result<Self> {
        if !output_dir.is_dir() {
            return Err(Error::format(
                output_dir,
                "folder",
                "a Cosmos output folder holding video_<i>/ sub-folders",
                "no such folder",
            ));
        }
        let lines = read_reference_jsonl(spec_path)?;
        if lines.is_empty() {
            return Err(Error::format(
                spec_path,
                "lines",
                "at least one JSON line",
                "an empty file",
            ));
        }
        for l in &lines {
            if let Some(k) = l.video_index() {
                if k != l.line {
                    return Err(Error::format(
                        spec_path,
                        format!("line {}: control_overrides.depth.input_control", l.line + 1),
                        format!(
                            "a depth video numbered {:06} (line i <-> depth video i <-> video_<i>)",
                            l.line
                        ),
                        l.video_file_name().to_string(),
                    ));
                }
            }
        }
        Ok(CachedBackend {
            output_dir: output_dir.to_path_buf(),
            spec_path: spec_path.to_path_buf(),
            lines,
        })
    }

    pub fn video_dir(&self, line: usize) -> PathBuf {
        self.output_dir.join(format!("video_{line}"))
    }

    /// The state of every line's output folder.
    pub fn report(&self) -> Result<CachedReport> {
        let entries = self
            .lines
            .iter()
            .map(|l| {
                let dir = self.video_dir(l.line);
                let status = if !dir.is_dir() {
                    EntryStatus::Missing
                } else if dir.join("output.mp4").is_file() {
                    EntryStatus::Present
                } else if std::fs::read_dir(&dir)
                    .map_err(|e| Error::io(&dir, e))?
                    .next()
                    .is_none()
                {
                    EntryStatus::EmptyGuardrail
                } else {
                    EntryStatus::NoOutputMp4
                };
                Ok(CachedEntry {
                    line: l.line,
                    video_dir: dir,
                    depth_video_name: l.video_file_name().to_string(),
                    status,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let mut extra_folders = Vec::new();
        for e in std::fs::read_dir(&self.output_dir).map_err(|e| Error::io(&self.output_dir, e))? {
            let e = e.map_err(|e| Error::io(&self.output_dir, e))?;
            let name = e.file_name().to_string_lossy().into_owned();
            if let Some(i) = name
                .strip_prefix("video_")
                .and_then(|s| s.parse::<usize>().ok())
            {
                if i >= self.lines.len() {
                    extra_folders.push(name);
                }
            }
        }
        extra_folders.sort();
        Ok(CachedReport {
            entries,
            extra_folders,
        })
    }

    /// The spec line a request refers to (see the module docs for the matching rules).
    pub fn line_for(&self, req: &GenerateRequest) -> Result<usize> {
        if let Some(p) = &req.depth_video_path {
            if let Some(name) = p.file_name().and_then(|n| n.to_str()) {
                if let Some(l) = self.lines.iter().find(|l| l.video_file_name() == name) {
                    return Ok(l.line);
                }
            }
        }
        let id = req.pair_id.trim();
        if let Ok(i) = id.parse::<usize>() {
            return if i < self.lines.len() {
                Ok(i)
            } else {
                Err(Error::Missing(format!(
                    "cached backend: pair `{id}` is line {i}, but {} has {} lines",
                    self.spec_path.display(),
                    self.lines.len()
                )))
            };
        }
        let id_stem = id.strip_suffix(".mp4").unwrap_or(id);
        for l in &self.lines {
            let name = l.video_file_name();
            let stem = name.strip_suffix(".mp4").unwrap_or(name);
            let unnumbered = stem.split_once('_').map(|(_, r)| r).unwrap_or(stem);
            if id_stem == stem || id_stem == unnumbered {
                return Ok(l.line);
            }
        }
        Err(Error::Missing(format!(
            "cached backend: pair `{id}` is not in {}: give its line number, its depth video \
             name (e.g. `{}`), or a depth_video_path with that file name",
            self.spec_path.display(),
            self.lines[0].video_file_name()
        )))
    }
}

impl WfmBackend for CachedBackend {
    fn id(&self) -> String {
        format!("cached:{}", self.output_dir.display())
    }

    fn generate(&self, req: &GenerateRequest) -> Result<Generation> {
        let i = self.line_for(req)?;
        let line = &self.lines[i];
        let dir = self.video_dir(i);
        let (frames, used) = ingest_output(&dir).map_err(|e| match e {
            Error::Format {
                path,
                field,
                expected,
                found,
            } => Error::Format {
                path,
                field: format!("{field} (line {} of {})", i + 1, self.spec_path.display()),
                expected,
                found,
            },
            other => other,
        })?;
        let mut warnings = Vec::new();
        let prompt = match used {
            Some(p) => {
                if p.trim() != line.prompt.trim() {
                    warnings.push(format!(
                        "{}/prompt.txt differs from line {} of the spec",
                        dir.display(),
                        i + 1
                    ));
                }
                p
            }
            None => {
                warnings.push(format!(
                    "{} has no prompt.txt; using the spec's prompt",
                    dir.display()
                ));
                line.prompt.clone()
            }
        };
        if prompt.trim() != req.prompt.text().trim() {
            warnings.push(
                "the cached frames were generated with a different prompt than the one requested"
                    .into(),
            );
        }
        if !req.depth_video.is_empty() && frames.len() != req.depth_video.len() {
            warnings.push(format!(
                "cached video has {} frames, the depth video {}",
                frames.len(),
                req.depth_video.len()
            ));
        }
        let provenance = Provenance {
            backend: self.id(),
            model: "Cosmos-Transfer1 output read from a cache folder (generated elsewhere)".into(),
            command: None,
            prompt,
            seed: req.seed,
            params: serde_json::json!({
                "spec": self.spec_path.to_string_lossy(),
                "line": i,
                "video": dir.join("output.mp4").to_string_lossy(),
                "depth_video_name": line.video_file_name(),
                "control_weight": line.control_weight,
                "generator_seed": "unknown (the reference ran Cosmos with its default seed 1)",
            }),
            created_unix: now_unix(),
            frame_count: frames.len(),
            warnings,
        };
        Ok(Generation { frames, provenance })
    }
}

/// Whether `p` is a Cosmos batch spec: a `.jsonl` file, or a `.json` file whose first line is a
/// batch line (an object with `prompt` and `control_overrides`, like the authors'
/// `generation_specs/3dmatch_test.json`) rather than a single JSON document.
pub fn is_batch_spec(p: &Path) -> bool {
    use std::io::BufRead;
    let ext = p
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if !p.is_file() {
        return false;
    }
    match ext.as_str() {
        "jsonl" => true,
        "json" => {
            let Ok(f) = std::fs::File::open(p) else {
                return false;
            };
            let mut line = String::new();
            let mut r = std::io::BufReader::new(f);
            while line.trim().is_empty() {
                line.clear();
                if r.read_line(&mut line).map_or(true, |n| n == 0) {
                    return false;
                }
            }
            serde_json::from_str::<serde_json::Value>(line.trim())
                .is_ok_and(|v| v.get("prompt").is_some() && v.get("control_overrides").is_some())
        }
        _ => false,
    }
}

/// The JSONL batch spec of a Cosmos output folder, searched in the folder, its parent, and the
/// authors' published layout (`generation_specs/` next to `generated_videos/`). Where one place
/// holds several specs, the one named like the folder wins (`3dmatch_rgb_gen_vids` ->
/// `3dmatch_test.json`); none or several left is an error naming the places and files.
pub fn find_cosmos_spec(dir: &Path) -> Result<PathBuf> {
    if !dir.is_dir() {
        return Err(Error::format(
            dir,
            "folder",
            "a Cosmos output folder (video_<i>/output.mp4)",
            "not a folder",
        ));
    }
    let has_videos = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .flatten()
        .any(|e| e.file_name().to_string_lossy().starts_with("video_") && e.path().is_dir());
    if !has_videos {
        return Err(Error::format(
            dir,
            "video_<i>/ folders",
            "a Cosmos output folder (video_<i>/output.mp4)",
            "no video_<i> folder",
        ));
    }
    let specs_in = |d: &Path| -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(d)
            .map(|rd| {
                rd.flatten()
                    .map(|e| e.path())
                    .filter(|p| is_batch_spec(p))
                    .collect()
            })
            .unwrap_or_default();
        v.sort();
        v
    };
    let names = |v: &[PathBuf]| {
        v.iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    // "3dmatch_rgb_gen_vids" -> "3dmatch"
    let word = dir
        .file_name()
        .map(|n| n.to_string_lossy().to_ascii_lowercase())
        .and_then(|n| n.split(['_', '-', '.']).next().map(str::to_owned))
        .unwrap_or_default();
    let mut places = vec![dir.to_path_buf()];
    if let Some(parent) = dir.parent() {
        places.push(parent.to_path_buf());
        places.push(parent.join("generation_specs"));
        if let Some(gp) = parent.parent() {
            places.push(gp.join("generation_specs"));
        }
    }
    places.dedup();
    for d in &places {
        let found = specs_in(d);
        match found.as_slice() {
            [] => continue,
            [one] => return Ok(one.clone()),
            many => {
                let named: Vec<PathBuf> = many
                    .iter()
                    .filter(|p| {
                        !word.is_empty()
                            && p.file_name().is_some_and(|n| {
                                n.to_string_lossy().to_ascii_lowercase().starts_with(&word)
                            })
                    })
                    .cloned()
                    .collect();
                if let [one] = named.as_slice() {
                    return Ok(one.clone());
                }
                return Err(Error::Usage(format!(
                    "{}: several JSONL batch specs ({}), none named like {}; choose one under \
                     Image branch > JSONL spec",
                    d.display(),
                    names(many),
                    dir.display()
                )));
            }
        }
    }
    Err(Error::Missing(format!(
        "no JSONL batch spec (*.jsonl, or a .json of JSON lines) for the Cosmos output folder \
         {}: looked in {}; put the spec there or choose it under Image branch > JSONL spec",
        dir.display(),
        names(&places)
    )))
}
