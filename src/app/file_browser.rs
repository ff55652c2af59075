//! The in-app file browser: opens the same kinds as the native dialog (manifest, two clouds
//! with an optional GT, 3DMatch / RGB-D / Cosmos folders) where no native dialog is available
//! (no xdg portal and no zenity: rfd then answers "cancelled" at once). A path field with Tab
//! completion over a directory listing filtered to the kind's files.

use std::path::{Path, PathBuf};

use eframe::egui;

use crate::dataset::open::OpenKind;

/// File extensions a kind opens (lower case); folder kinds list folders only.
pub fn extensions(kind: OpenKind) -> &'static [&'static str] {
    match kind {
        OpenKind::Manifest => &["json", "toml", "txt"],
        OpenKind::TwoClouds => &["ply", "pcd", "xyz", "npy", "bin", "pth", "txt"],
        OpenKind::Comparison => &["json"],
        _ => &[],
    }
}

/// Kinds opened from several picked files (clicking a file picks it instead of opening it).
fn picks_files(kind: OpenKind) -> bool {
    matches!(kind, OpenKind::TwoClouds | OpenKind::Comparison)
}

/// One row of the listing.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Entry {
    pub name: String,
    pub is_dir: bool,
}

/// The folders and the kind's files in `dir`, folders first, each group by name; hidden
/// entries (leading dot) left out.
pub fn list_dir(dir: &Path, kind: OpenKind) -> Result<Vec<Entry>, String> {
    let rd = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let exts = extensions(kind);
    let mut out: Vec<Entry> = rd
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') {
                return None;
            }
            // follows symlinks: a linked data folder is a folder
            let is_dir = e.path().is_dir();
            let ext = Path::new(&name)
                .extension()
                .map(|x| x.to_string_lossy().to_ascii_lowercase())
                .unwrap_or_default();
            (is_dir || exts.contains(&ext.as_str())).then_some(Entry { name, is_dir })
        })
        .collect();
    out.sort_by(|a, b| b.is_dir.cmp(&a.is_dir).then_with(|| a.name.cmp(&b.name)));
    Ok(out)
}

/// Completions of a typed path: the entries of its folder whose names start with its last
/// component (folders end in `/`), and the longest common extension of the typed text.
pub fn complete(text: &str, kind: OpenKind) -> (Vec<String>, String) {
    let (dir, prefix) = match text.rfind('/') {
        Some(i) => (&text[..=i], &text[i + 1..]),
        None => ("", text),
    };
    let list_in = if dir.is_empty() { "." } else { dir };
    let Ok(entries) = list_dir(Path::new(list_in), kind) else {
        return (Vec::new(), text.to_string());
    };
    let cands: Vec<String> = entries
        .into_iter()
        .filter(|e| e.name.starts_with(prefix))
        .map(|e| format!("{dir}{}{}", e.name, if e.is_dir { "/" } else { "" }))
        .collect();
    let common = match cands.first() {
        None => text.to_string(),
        Some(first) => {
            let mut n = first.len();
            for c in &cands[1..] {
                n = n.min(
                    first
                        .char_indices()
                        .zip(c.chars())
                        .take_while(|((_, a), b)| a == b)
                        .last()
                        .map_or(0, |((i, a), _)| i + a.len_utf8()),
                );
            }
            first[..n].to_string()
        }
    };
    let common = if common.len() >= text.len() {
        common
    } else {
        text.to_string()
    };
    (cands, common)
}

/// What opening `paths` as `kind` would need, or why it cannot.
pub fn validate(kind: OpenKind, paths: &[PathBuf]) -> Result<(), String> {
    if paths.is_empty() {
        return Err("nothing chosen yet".into());
    }
    if kind.wants_folder() {
        return match paths {
            [p] if p.is_dir() => Ok(()),
            [p] => Err(format!("{}: not a folder", p.display())),
            _ => Err("choose one folder".into()),
        };
    }
    for p in paths {
        if !p.is_file() {
            return Err(format!("{}: no such file", p.display()));
        }
    }
    match kind {
        OpenKind::TwoClouds => crate::dataset::open::split_two_clouds(paths).map(|_| ()),
        OpenKind::Comparison if paths.len() == 2 => Ok(()),
        OpenKind::Comparison => Err("choose two bench JSONs: run A, then run B".into()),
        _ if paths.len() == 1 => Ok(()),
        _ => Err("choose one file".into()),
    }
}

/// The browser's state; shown as a window until the user opens or cancels.
#[derive(Clone, Debug)]
pub struct FileBrowser {
    pub kind: OpenKind,
    /// The folder listed.
    pub dir: PathBuf,
    /// The path field (a file or a folder; relative paths are against `dir`).
    pub text: String,
    /// Files picked for a two-cloud open (source, target and optionally the GT).
    pub picked: Vec<PathBuf>,
    listing: Option<(PathBuf, Result<Vec<Entry>, String>)>,
    completions: Vec<String>,
    pub message: Option<String>,
}

/// What the user did this frame.
#[derive(Clone, Debug, PartialEq)]
pub enum BrowserOutcome {
    Open(OpenKind, Vec<PathBuf>),
    Cancel,
}

impl FileBrowser {
    pub fn new(kind: OpenKind, start: Option<&Path>) -> Self {
        let dir = start
            .map(|p| {
                if p.is_dir() {
                    p.to_path_buf()
                } else {
                    p.parent().map(Path::to_path_buf).unwrap_or_default()
                }
            })
            .filter(|p| p.is_dir())
            .or_else(|| std::env::current_dir().ok())
            .unwrap_or_else(|| PathBuf::from("/"));
        let mut text = dir.display().to_string();
        if !text.ends_with('/') {
            text.push('/');
        }
        Self {
            kind,
            dir,
            text,
            picked: Vec::new(),
            listing: None,
            completions: Vec::new(),
            message: None,
        }
    }

    fn typed_path(&self) -> PathBuf {
        let p = PathBuf::from(self.text.trim());
        if p.is_absolute() {
            p
        } else {
            self.dir.join(p)
        }
    }

    fn enter(&mut self, dir: PathBuf) {
        self.dir = dir;
        self.text = self.dir.display().to_string();
        if !self.text.ends_with('/') {
            self.text.push('/');
        }
        self.completions.clear();
    }

    /// The paths an "Open" now would send.
    pub fn chosen(&self) -> Vec<PathBuf> {
        if picks_files(self.kind) {
            return self.picked.clone();
        }
        let p = self.typed_path();
        if self.kind.wants_folder() || p.is_file() {
            vec![p]
        } else {
            Vec::new()
        }
    }

    /// Enter in the path field: a folder is listed (or, for a folder kind, opened when it
    /// is already the one listed), a file is picked (two clouds) or opened.
    fn submit(&mut self) -> Option<BrowserOutcome> {
        let p = self.typed_path();
        if p.is_dir() {
            if self.kind.wants_folder() && p == self.dir {
                return self.try_open();
            }
            self.enter(p);
            return None;
        }
        if p.is_file() {
            if picks_files(self.kind) {
                self.pick(p);
                return None;
            }
            return self.try_open();
        }
        self.message = Some(format!("{}: no such file or folder", p.display()));
        None
    }

    fn pick(&mut self, p: PathBuf) {
        if let Some(i) = self.picked.iter().position(|q| *q == p) {
            self.picked.remove(i);
        } else if self.kind == OpenKind::Comparison && self.picked.len() < 2 {
            self.picked.push(p);
        } else if self.kind == OpenKind::Comparison {
            self.message = Some("two runs: A, then B (click a picked file to drop it)".into());
        } else if self.picked.len() < 3 {
            self.picked.push(p);
        } else {
            self.message = Some("at most two clouds and one GT file".into());
        }
    }

    fn try_open(&mut self) -> Option<BrowserOutcome> {
        let paths = self.chosen();
        match validate(self.kind, &paths) {
            Ok(()) => Some(BrowserOutcome::Open(self.kind, paths)),
            Err(e) => {
                self.message = Some(e);
                None
            }
        }
    }

    /// Draws the browser window; returns the user's decision once made.
    pub fn show(&mut self, ctx: &egui::Context) -> Option<BrowserOutcome> {
        let mut outcome = None;
        let title = format!("Open {}", self.kind.label().trim_end_matches('…'));
        egui::Window::new(title)
            .collapsible(false)
            .default_size(egui::vec2(560.0, 420.0))
            .show(ctx, |ui| outcome = self.ui(ui));
        outcome
    }

    fn ui(&mut self, ui: &mut egui::Ui) -> Option<BrowserOutcome> {
        let mut outcome = None;
        ui.weak("No native file dialog here (no xdg portal or zenity): the built-in browser.");
        ui.horizontal(|ui| {
            let label = ui.label("Path");
            let edit = egui::TextEdit::singleline(&mut self.text)
                .desired_width(ui.available_width() - 120.0)
                .lock_focus(true);
            let r = ui.add(edit).labelled_by(label.id);
            if r.has_focus() && ui.input(|i| i.key_pressed(egui::Key::Tab)) {
                let (cands, common) = complete(&self.text, self.kind);
                self.text = common;
                self.completions = cands;
                // the cursor goes to the end of the completed text
                if let Some(mut st) = egui::TextEdit::load_state(ui.ctx(), r.id) {
                    let end = egui::text::CCursor::new(self.text.chars().count());
                    st.cursor
                        .set_char_range(Some(egui::text::CCursorRange::one(end)));
                    st.store(ui.ctx(), r.id);
                }
                r.request_focus();
            } else if r.changed() {
                self.completions.clear();
                self.message = None;
            }
            if r.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter)) {
                outcome = self.submit();
            }
            if ui
                .button("Go")
                .on_hover_text("list or pick the typed path")
                .clicked()
            {
                outcome = self.submit();
            }
            if ui.button("Up").clicked() {
                if let Some(p) = self.dir.parent() {
                    self.enter(p.to_path_buf());
                }
            }
        });
        if !self.completions.is_empty() {
            ui.horizontal_wrapped(|ui| {
                ui.weak("Tab:");
                for c in self.completions.clone().iter().take(12) {
                    let name = c.trim_end_matches('/').rsplit('/').next().unwrap_or(c);
                    if ui.small_button(name).clicked() {
                        self.text = c.clone();
                        self.completions.clear();
                    }
                }
                if self.completions.len() > 12 {
                    ui.weak(format!("… {} more", self.completions.len() - 12));
                }
            });
        }
        ui.label(egui::RichText::new(self.dir.display().to_string()).strong());
        if self.listing.as_ref().is_none_or(|(d, _)| *d != self.dir) {
            self.listing = Some((self.dir.clone(), list_dir(&self.dir, self.kind)));
        }
        let entries = match &self.listing {
            Some((_, Ok(e))) => e.clone(),
            Some((_, Err(e))) => {
                ui.colored_label(egui::Color32::from_rgb(240, 80, 70), e);
                Vec::new()
            }
            None => Vec::new(),
        };
        let list_h = (ui.available_height() - 70.0).max(120.0);
        egui::ScrollArea::vertical()
            .id_salt("file_browser_list")
            .max_height(list_h)
            .auto_shrink([false, true])
            .show(ui, |ui| {
                if entries.is_empty() {
                    ui.weak("(nothing to open here)");
                }
                for e in &entries {
                    let p = self.dir.join(&e.name);
                    let label = if e.is_dir {
                        format!("{}/", e.name)
                    } else {
                        e.name.clone()
                    };
                    let sel = self.picked.contains(&p) || self.typed_path() == p;
                    let r = ui.selectable_label(sel, label);
                    if r.double_clicked() && !e.is_dir && self.kind == OpenKind::Manifest {
                        self.text = p.display().to_string();
                        outcome = self.try_open();
                    } else if r.clicked() {
                        if e.is_dir {
                            self.enter(p);
                        } else if picks_files(self.kind) {
                            self.pick(p);
                        } else {
                            self.text = p.display().to_string();
                        }
                    }
                }
            });
        if picks_files(self.kind) {
            ui.label(format!(
                "picked ({}): {}",
                if self.kind == OpenKind::Comparison {
                    "run A, run B"
                } else {
                    "source, target, optional 4x4 GT"
                },
                if self.picked.is_empty() {
                    "none".to_string()
                } else {
                    self.picked
                        .iter()
                        .map(|p| p.file_name().unwrap_or_default().to_string_lossy())
                        .collect::<Vec<_>>()
                        .join(", ")
                }
            ));
        }
        if let Some(m) = &self.message {
            ui.colored_label(egui::Color32::from_rgb(230, 190, 60), m);
        }
        ui.horizontal(|ui| {
            let open_label = if self.kind.wants_folder() {
                "Open this folder"
            } else {
                "Open"
            };
            if ui.button(open_label).clicked() {
                if self.kind.wants_folder() && !self.typed_path().is_dir() {
                    self.text = self.dir.display().to_string();
                }
                outcome = self.try_open();
            }
            if ui.button("Cancel").clicked() {
                outcome = Some(BrowserOutcome::Cancel);
            }
        });
        outcome
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn listing_filters_by_kind_and_completion_extends_the_common_prefix() {
        let d = tempfile::tempdir().unwrap();
        let root = d.path();
        std::fs::create_dir(root.join("scans")).unwrap();
        std::fs::create_dir(root.join(".hidden")).unwrap();
        for f in ["scan_a.ply", "scan_b.ply", "notes.doc", "gt.txt", "m.toml"] {
            std::fs::write(root.join(f), b"x").unwrap();
        }
        let names = |k| {
            list_dir(root, k)
                .unwrap()
                .into_iter()
                .map(|e| e.name)
                .collect::<Vec<_>>()
        };
        assert_eq!(
            names(OpenKind::TwoClouds),
            ["scans", "gt.txt", "scan_a.ply", "scan_b.ply"]
        );
        assert_eq!(names(OpenKind::Manifest), ["scans", "gt.txt", "m.toml"]);
        assert_eq!(names(OpenKind::RgbdSequence), ["scans"]);
        let base = format!("{}/", root.display());
        let (c, common) = complete(&format!("{base}sc"), OpenKind::TwoClouds);
        assert_eq!(c.len(), 3, "{c:?}");
        assert_eq!(common, format!("{base}scan"));
        let (c, common) = complete(&format!("{base}scan_a"), OpenKind::TwoClouds);
        assert_eq!(c, [format!("{base}scan_a.ply")]);
        assert_eq!(common, format!("{base}scan_a.ply"));
        let (c, common) = complete(&format!("{base}scans"), OpenKind::RgbdSequence);
        assert_eq!(common, format!("{base}scans/"), "{c:?}");
        // nothing matches: the text stays
        let (c, common) = complete(&format!("{base}zz"), OpenKind::TwoClouds);
        assert!(c.is_empty());
        assert_eq!(common, format!("{base}zz"));
    }

    #[test]
    fn validation_names_what_is_wrong() {
        let d = tempfile::tempdir().unwrap();
        let a = d.path().join("a.ply");
        let b = d.path().join("b.ply");
        std::fs::write(&a, b"x").unwrap();
        std::fs::write(&b, b"x").unwrap();
        assert!(validate(OpenKind::TwoClouds, &[a.clone(), b.clone()]).is_ok());
        let e = validate(OpenKind::TwoClouds, std::slice::from_ref(&a)).unwrap_err();
        assert!(e.contains("two point-cloud files"), "{e}");
        let e = validate(OpenKind::RgbdSequence, std::slice::from_ref(&a)).unwrap_err();
        assert!(e.contains("not a folder"), "{e}");
        assert!(validate(OpenKind::RgbdSequence, &[d.path().to_path_buf()]).is_ok());
        let e = validate(OpenKind::Manifest, &[d.path().join("none.toml")]).unwrap_err();
        assert!(e.contains("no such file"), "{e}");
        assert!(validate(OpenKind::Manifest, &[]).is_err());
    }
}
