//! What the inspector keeps between runs: the settings file (JSON in the user config dir),
//! read leniently (old forms load with defaults and say so) and written atomically.

use super::*;

/// What persists between runs (JSON in the user config dir).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Persisted {
    /// The pipeline's own parameters (files of the old `settings` form load with defaults).
    pub params: RegisterParams,
    /// The image branch's parameters while it is off (restored when a WFM is chosen).
    pub image_off: ImageBranchParams,
    pub view3d: View3dPrefs,
    pub match_mode: MatchColorMode,
    pub match_count: usize,
    pub line_style: LineStyle,
    pub tab: Panel,
    pub pair_sort: PairSort,
    pub last_opened: Option<(OpenKind, Vec<PathBuf>)>,
}

impl Default for Persisted {
    fn default() -> Self {
        let ui = UiState::default();
        Self {
            params: RegisterParams::default(),
            image_off: ImageBranchParams::default(),
            view3d: View3dPrefs::default(),
            match_mode: ui.match_mode,
            match_count: ui.match_count,
            line_style: ui.line_style,
            tab: ui.tab,
            pair_sort: ui.pair_sort,
            last_opened: None,
        }
    }
}

/// `$XDG_CONFIG_HOME/cgenreg/inspector.json`, else `~/.config/cgenreg/inspector.json`.
pub fn default_settings_path() -> Option<PathBuf> {
    let base = std::env::var_os("XDG_CONFIG_HOME")
        .map(PathBuf::from)
        .filter(|p| p.is_absolute())
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".config")))?;
    Some(base.join("cgenreg").join("inspector.json"))
}

/// The first commands of an inspector started without an explicit dataset: reopen the data
/// persisted as last opened in `settings_path` (falling back to `fallback_pair` of the
/// dataset already loaded when that fails), else register `fallback_pair`.
pub fn startup_commands(settings_path: Option<&Path>, fallback_pair: &str) -> Vec<Command> {
    let last = settings_path.and_then(|p| load_persisted(p).0.last_opened);
    match last {
        Some((kind, paths)) if !paths.is_empty() && kind != OpenKind::CosmosOutput => {
            vec![Command::OpenOrFallback {
                kind,
                paths,
                fallback_pair: fallback_pair.to_string(),
            }]
        }
        _ => vec![Command::SelectPair(fallback_pair.to_string())],
    }
}

/// Reads persisted settings; a missing or unreadable file gives defaults and a message.
pub fn load_persisted(path: &Path) -> (Persisted, Option<String>) {
    match std::fs::read(path) {
        Ok(b) => match serde_json::from_slice::<Persisted>(&b) {
            // before the controls edited the pipeline's own parameters, they were stored
            // under "settings" in a form of their own; the rest of the file still applies
            Ok(p) if is_old_settings_file(&b) => (
                p,
                Some(format!(
                    "{}: pipeline settings from an older cgenreg were reset to defaults \
                     (view, colours and last opened data kept)",
                    path.display()
                )),
            ),
            Ok(p) => (p, None),
            Err(e) => (
                Persisted::default(),
                Some(format!(
                    "{}: ignored unreadable settings ({e})",
                    path.display()
                )),
            ),
        },
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => (Persisted::default(), None),
        Err(e) => (
            Persisted::default(),
            Some(format!("{}: {e}", path.display())),
        ),
    }
}

fn is_old_settings_file(bytes: &[u8]) -> bool {
    serde_json::from_slice::<serde_json::Value>(bytes)
        .is_ok_and(|v| v.get("settings").is_some() && v.get("params").is_none())
}

pub fn save_persisted(path: &Path, p: &Persisted) -> Result<(), String> {
    let bytes = serde_json::to_vec_pretty(p).map_err(|e| e.to_string())?;
    crate::io::output::write_atomic(path, &bytes).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::app::App;

    #[test]
    fn settings_persist_round_trip_and_bad_file_gives_defaults() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cfg").join("inspector.json");
        let mut p = Persisted::default();
        p.image_off.k = 5;
        p.match_mode = MatchColorMode::Confidence;
        p.last_opened = Some((OpenKind::TwoClouds, vec!["a.ply".into(), "b.ply".into()]));
        save_persisted(&path, &p).unwrap();
        let (q, err) = load_persisted(&path);
        assert!(err.is_none());
        assert_eq!(p, q);
        // a file of the old form: the pipeline settings reset, the rest kept, said so
        std::fs::write(
            &path,
            br#"{"settings": {"k": 5, "wfm": "Oracle"}, "match_count": 7}"#,
        )
        .unwrap();
        let (q, err) = load_persisted(&path);
        assert_eq!(q.params, RegisterParams::default());
        assert_eq!(q.match_count, 7);
        assert!(err.unwrap().contains("older cgenreg"));
        std::fs::write(&path, b"{not json").unwrap();
        let (q, err) = load_persisted(&path);
        assert_eq!(q, Persisted::default());
        assert!(err.unwrap().contains("inspector.json"));
        // the app reads the file at start
        save_persisted(&path, &p).unwrap();
        let app = App::new(InspectorModel::demo(), None, Some(path));
        assert_eq!(app.image_off.k, 5);
        assert_eq!(app.ui_state.match_mode, MatchColorMode::Confidence);
    }
}
