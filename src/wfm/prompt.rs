//! Text prompts for the WFM, and the reference's batch JSONL format (reference §2.4).
//!
//! The paper's prompts are a shared prefix (read the concatenated input as two correlated
//! sequences; photorealism; multi-view consistency) followed by a short scene description. Its
//! prompt study varies only the scene description over four categories, which are the
//! [`PromptPreset`]s here. The prefix and the default descriptions are our own wording; the
//! reference's per-pair prompts (no shared prefix) can be read from its JSONL spec files with
//! [`read_reference_jsonl`].
//!
//! JSONL format, one object per line (line i <-> pair i <-> Cosmos output `video_<i>/`):
//! `{"prompt": str, "control_overrides": {"depth": {"input_control": "<path>.mp4",
//! "control_weight": 1.0}}, "video_save_name": "<i>_gen_vid"}`. `video_save_name` is optional
//! (Cosmos ignores it). We write it as Python's `json.dumps(ensure_ascii=True)` does: non-ASCII
//! characters as `\uXXXX` escapes.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Cosmos-Transfer1's default negative prompt (used by the reference; verbatim).
pub const COSMOS_DEFAULT_NEGATIVE_PROMPT: &str = "The video captures a game playing, with bad crappy graphics and cartoonish frames. It represents a recording of old outdated games. The lighting looks very fake. The textures are very raw and basic. The geometries are very primitive. The images are very pixelated and of poor CG quality. There are many subtitles in the footage. Overall, the video is unrealistic at all.";

/// Our shared prefix (paper §3: instruct the model to treat the input as two correlated
/// sequences, photorealistic and multi-view consistent).
pub const DEFAULT_PREFIX: &str = "The input depth video holds two correlated sequences of the same static scene, recorded one after the other from nearby viewpoints. Render both as one photorealistic video with real materials and natural lighting, keeping every surface's appearance identical wherever it is seen again, and follow the depth exactly. Scene:";

/// A prompt: shared prefix plus scene description.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Prompt {
    pub prefix: String,
    pub scene: String,
}

impl Prompt {
    pub fn new(prefix: impl Into<String>, scene: impl Into<String>) -> Self {
        Prompt {
            prefix: prefix.into(),
            scene: scene.into(),
        }
    }

    /// A prompt used verbatim (e.g. a line of the reference JSONL): no prefix.
    pub fn verbatim(text: impl Into<String>) -> Self {
        Prompt::new("", text)
    }

    /// Our prefix with a preset's default scene description.
    pub fn from_preset(preset: PromptPreset) -> Self {
        Prompt::new(DEFAULT_PREFIX, preset.default_scene())
    }

    /// The full text sent to the model: prefix, one space, scene (either may be empty).
    pub fn text(&self) -> String {
        let p = self.prefix.trim_end();
        let s = self.scene.trim_start();
        match (p.is_empty(), s.is_empty()) {
            (true, _) => s.to_string(),
            (_, true) => p.to_string(),
            _ => format!("{p} {s}"),
        }
    }
}

/// The four prompt categories of the paper's prompt study.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum PromptPreset {
    /// A detailed description of the actual scene (objects, materials, colours).
    #[value(name = "scene")]
    SceneSpecific,
    /// The scene's category only ("a kitchen").
    General,
    /// Almost nothing ("indoor scene").
    Minimal,
    /// A description of a different kind of place ("snowy forest"); degrades registration.
    #[value(name = "wrong")]
    SemanticallyWrong,
}

impl PromptPreset {
    pub const ALL: [PromptPreset; 4] = [
        PromptPreset::SceneSpecific,
        PromptPreset::General,
        PromptPreset::Minimal,
        PromptPreset::SemanticallyWrong,
    ];

    /// Our default scene description for this category. Scene-specific and general are
    /// written for the staged 7-Scenes redkitchen data; replace them for other scenes.
    pub fn default_scene(self) -> &'static str {
        match self {
            PromptPreset::SceneSpecific => "a lived-in home kitchen with glossy red cabinet doors, a dark speckled stone worktop, a pale wooden dining table with two wooden chairs, a few mugs and papers on the table, and a grey striped floor, lit by soft daylight from a window",
            PromptPreset::General => "a kitchen",
            PromptPreset::Minimal => "an indoor scene",
            PromptPreset::SemanticallyWrong => "a snowy pine forest under an overcast winter sky",
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            PromptPreset::SceneSpecific => "scene-specific",
            PromptPreset::General => "general",
            PromptPreset::Minimal => "minimal",
            PromptPreset::SemanticallyWrong => "semantically-wrong",
        }
    }

    /// The inspector's button text.
    pub fn label(self) -> &'static str {
        match self {
            PromptPreset::SceneSpecific => "Scene-specific",
            PromptPreset::General => "General",
            PromptPreset::Minimal => "Minimal",
            PromptPreset::SemanticallyWrong => "Wrong",
        }
    }

    /// The preset whose default scene is `scene`, if any.
    pub fn of_scene(scene: &str) -> Option<PromptPreset> {
        PromptPreset::ALL
            .into_iter()
            .find(|p| p.default_scene() == scene.trim())
    }

    /// The scene text the preset puts in the editor: its default scene; for scene-specific,
    /// `scene_specific` (the pair's own description) when one is known.
    pub fn scene_text(self, scene_specific: &str) -> String {
        match self {
            PromptPreset::SceneSpecific if !scene_specific.trim().is_empty() => {
                scene_specific.to_owned()
            }
            p => p.default_scene().to_owned(),
        }
    }

    pub fn parse(s: &str) -> Option<PromptPreset> {
        let k = s.trim().to_ascii_lowercase().replace(['_', ' '], "-");
        PromptPreset::ALL
            .into_iter()
            .find(|p| p.name() == k || (k == "wrong" && *p == PromptPreset::SemanticallyWrong))
    }
}

/// One line of a reference batch JSONL file.
#[derive(Clone, Debug, PartialEq)]
pub struct BatchLine {
    /// 0-based line number = Cosmos output folder `video_<line>`.
    pub line: usize,
    pub prompt: String,
    /// `control_overrides.depth.input_control`: the depth video path as written.
    pub input_control: String,
    pub control_weight: Option<f64>,
    pub video_save_name: Option<String>,
}

impl BatchLine {
    /// The file name of `input_control` (directories in the authors' specs are theirs).
    pub fn video_file_name(&self) -> &str {
        self.input_control
            .rsplit(['/', '\\'])
            .next()
            .unwrap_or(&self.input_control)
    }

    /// The metadata index the video name starts with (`000123_...mp4` -> 123), if any.
    pub fn video_index(&self) -> Option<usize> {
        super::depth_video::reference_video_index(self.video_file_name())
    }

    /// This line as the reference writes it (ASCII-only JSON, no trailing newline).
    pub fn to_json_line(&self) -> String {
        // Built by hand so the key order is the reference's, not alphabetical.
        let mut out = String::from("{\"prompt\": ");
        write_py_string(&self.prompt, &mut out);
        out.push_str(", \"control_overrides\": {\"depth\": {\"input_control\": ");
        write_py_string(&self.input_control, &mut out);
        if let Some(w) = self.control_weight {
            out.push_str(", \"control_weight\": ");
            out.push_str(&serde_json::Value::from(w).to_string());
        }
        out.push_str("}}");
        if let Some(n) = &self.video_save_name {
            out.push_str(", \"video_save_name\": ");
            write_py_string(n, &mut out);
        }
        out.push('}');
        out
    }
}

/// JSON with every non-ASCII character escaped as `\uXXXX` (UTF-16), like Python's
/// `json.dumps(..., ensure_ascii=True)`; separators `", "` and `": "` as Python's defaults.
pub fn to_ascii_json(v: &serde_json::Value) -> String {
    let mut out = String::new();
    write_py_json(v, &mut out);
    out
}

fn write_py_json(v: &serde_json::Value, out: &mut String) {
    use serde_json::Value;
    match v {
        Value::Object(m) => {
            out.push('{');
            for (i, (k, val)) in m.iter().enumerate() {
                if i > 0 {
                    out.push_str(", ");
                }
                write_py_string(k, out);
                out.push_str(": ");
                write_py_json(val, out);
            }
            out.push('}');
        }
        Value::Array(a) => {
            out.push('[');
            for (i, val) in a.iter().enumerate() {
                if i > 0 {
                    out.push_str(", ");
                }
                write_py_json(val, out);
            }
            out.push(']');
        }
        Value::String(s) => write_py_string(s, out),
        other => out.push_str(&other.to_string()),
    }
}

fn write_py_string(s: &str, out: &mut String) {
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            '\u{8}' => out.push_str("\\b"),
            '\u{c}' => out.push_str("\\f"),
            c if (c as u32) < 0x20 || (c as u32) > 0x7e => {
                let mut buf = [0u16; 2];
                for u in c.encode_utf16(&mut buf) {
                    out.push_str(&format!("\\u{:04x}", u));
                }
            }
            c => out.push(c),
        }
    }
    out.push('"');
}

/// Read a reference batch JSONL spec. Every non-empty line must be an object with a string
/// `prompt` and a string `control_overrides.depth.input_control`; blank lines are allowed
/// only at the end (a blank line in the middle would shift the line <-> video mapping).
pub fn read_reference_jsonl(path: &Path) -> Result<Vec<BatchLine>> {
    let text = crate::io::limits::read_text(path)?;
    parse_reference_jsonl(path, &text)
}

/// [`read_reference_jsonl`] on the file's text; `path` is used only in error messages.
pub fn parse_reference_jsonl(path: &Path, text: &str) -> Result<Vec<BatchLine>> {
    let raw: Vec<&str> = text.lines().collect();
    let last = raw
        .iter()
        .rposition(|l| !l.trim().is_empty())
        .map(|i| i + 1)
        .unwrap_or(0);
    let mut out = Vec::with_capacity(last);
    for (i, l) in raw[..last].iter().enumerate() {
        let field = |f: &str| format!("line {}: {f}", i + 1);
        if l.trim().is_empty() {
            return Err(Error::format(
                path,
                field("(whole line)"),
                "a JSON object (blank lines would shift the line <-> video_<i> mapping)",
                "a blank line",
            ));
        }
        let v: serde_json::Value = serde_json::from_str(l).map_err(|e| {
            Error::format(path, field("(whole line)"), "a JSON object", e.to_string())
        })?;
        let prompt = v.get("prompt").and_then(|p| p.as_str()).ok_or_else(|| {
            Error::format(
                path,
                field("prompt"),
                "a string",
                json_kind(v.get("prompt")),
            )
        })?;
        let depth = v
            .get("control_overrides")
            .and_then(|c| c.get("depth"))
            .ok_or_else(|| {
                Error::format(
                    path,
                    field("control_overrides.depth"),
                    "an object",
                    "missing",
                )
            })?;
        let input_control = depth
            .get("input_control")
            .and_then(|p| p.as_str())
            .ok_or_else(|| {
                Error::format(
                    path,
                    field("control_overrides.depth.input_control"),
                    "a string (path of the depth mp4)",
                    json_kind(depth.get("input_control")),
                )
            })?;
        let control_weight = match depth.get("control_weight") {
            None => None,
            Some(w) => Some(w.as_f64().ok_or_else(|| {
                Error::format(
                    path,
                    field("control_overrides.depth.control_weight"),
                    "a number",
                    json_kind(Some(w)),
                )
            })?),
        };
        out.push(BatchLine {
            line: i,
            prompt: prompt.to_string(),
            input_control: input_control.to_string(),
            control_weight,
            video_save_name: v
                .get("video_save_name")
                .and_then(|n| n.as_str())
                .map(str::to_string),
        });
    }
    Ok(out)
}

fn json_kind(v: Option<&serde_json::Value>) -> String {
    match v {
        None => "missing".into(),
        Some(serde_json::Value::Null) => "null".into(),
        Some(serde_json::Value::Bool(_)) => "a boolean".into(),
        Some(serde_json::Value::Number(n)) => format!("the number {n}"),
        Some(serde_json::Value::String(_)) => "a string".into(),
        Some(serde_json::Value::Array(_)) => "an array".into(),
        Some(serde_json::Value::Object(_)) => "an object".into(),
    }
}

/// Write a batch JSONL spec (one line per pair, `video_save_name` = "<i>_gen_vid") atomically.
pub fn write_batch_jsonl(
    path: &Path,
    items: &[(String, PathBuf)],
    control_weight: f64,
) -> Result<()> {
    let mut text = String::new();
    for (i, (prompt, video)) in items.iter().enumerate() {
        let line = BatchLine {
            line: i,
            prompt: prompt.clone(),
            input_control: video.to_string_lossy().into_owned(),
            control_weight: Some(control_weight),
            video_save_name: Some(format!("{i}_gen_vid")),
        };
        text.push_str(&line.to_json_line());
        text.push('\n');
    }
    crate::io::output::write_atomic(path, text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_joins_prefix_and_scene() {
        assert_eq!(Prompt::new("A.", "b").text(), "A. b");
        assert_eq!(Prompt::new("A. ", " b").text(), "A. b");
        assert_eq!(Prompt::verbatim("only").text(), "only");
        let p = Prompt::from_preset(PromptPreset::Minimal);
        assert!(p.text().starts_with(DEFAULT_PREFIX));
        assert!(p.text().ends_with("an indoor scene"));
        for preset in PromptPreset::ALL {
            assert_eq!(PromptPreset::parse(preset.name()), Some(preset));
        }
        assert_eq!(
            PromptPreset::parse("wrong"),
            Some(PromptPreset::SemanticallyWrong)
        );
        assert_eq!(PromptPreset::parse("nope"), None);
    }

    #[test]
    fn ascii_json_like_python() {
        let l = BatchLine {
            line: 0,
            prompt: "room\u{2019}s \u{2013} caf\u{e9} \"q\" \u{1F600}".into(),
            input_control: "/d/000000_x.mp4".into(),
            control_weight: Some(1.0),
            video_save_name: Some("0_gen_vid".into()),
        };
        let s = l.to_json_line();
        assert!(s.is_ascii());
        assert_eq!(
            s,
            r#"{"prompt": "room\u2019s \u2013 caf\u00e9 \"q\" \ud83d\ude00", "control_overrides": {"depth": {"input_control": "/d/000000_x.mp4", "control_weight": 1.0}}, "video_save_name": "0_gen_vid"}"#
        );
        // And it parses back to the same line.
        let back = parse_reference_jsonl(Path::new("t.jsonl"), &s).unwrap();
        assert_eq!(back, vec![l]);
    }

    #[test]
    fn reads_reference_lines_and_reports_bad_fields() {
        let p = Path::new("spec.json");
        let text = concat!(
            r#"{"prompt": "A photorealistic kitchen", "control_overrides": {"depth": {"input_control": "/my_data_path/3DMatch/test_videos_inv_da/000000_7-scenes-redkitchen-seq-01_frame-000000@seq-01_frame-000050.mp4", "control_weight": 1.0}}, "video_save_name": "0_gen_vid"}"#,
            "\n",
            r#"{"prompt": "B", "control_overrides": {"depth": {"input_control": "000001_b.mp4"}}}"#,
            "\n\n"
        );
        let lines = parse_reference_jsonl(p, text).unwrap();
        assert_eq!(lines.len(), 2);
        assert_eq!(lines[0].video_index(), Some(0));
        assert_eq!(
            lines[0].video_file_name(),
            "000000_7-scenes-redkitchen-seq-01_frame-000000@seq-01_frame-000050.mp4"
        );
        assert_eq!(lines[0].control_weight, Some(1.0));
        assert_eq!(lines[1].line, 1);
        assert_eq!(lines[1].control_weight, None);

        let e = parse_reference_jsonl(p, r#"{"control_overrides": {}}"#)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("spec.json") && e.contains("line 1: prompt"),
            "{e}"
        );
        let e = parse_reference_jsonl(
            p,
            "{\"prompt\": \"a\", \"control_overrides\": {\"depth\": {\"input_control\": 3}}}",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("input_control") && e.contains("number 3"), "{e}");
        let ok = r#"{"prompt": "a", "control_overrides": {"depth": {"input_control": "v.mp4"}}}"#;
        let e = parse_reference_jsonl(p, &format!("{ok}\n\n{ok}"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") && e.contains("blank"), "{e}");
    }

    #[test]
    fn batch_file_roundtrip() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("batch.jsonl");
        write_batch_jsonl(
            &p,
            &[
                ("x".into(), PathBuf::from("/v/a.mp4")),
                ("y\u{e9}".into(), PathBuf::from("/v/b.mp4")),
            ],
            1.0,
        )
        .unwrap();
        let lines = read_reference_jsonl(&p).unwrap();
        assert_eq!(lines.len(), 2);
        assert_eq!(lines[1].prompt, "y\u{e9}");
        assert_eq!(lines[1].video_save_name.as_deref(), Some("1_gen_vid"));
        assert!(std::fs::read_to_string(&p).unwrap().is_ascii());
    }
}
