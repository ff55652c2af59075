//! The inspector's module structure (`src/app`), read from the source: no file over 600
//! lines, one module layout (`foo/mod.rs`, never `foo.rs` beside `foo/`), and imports that
//! only go downwards: no cycle between the app's modules, nothing imported through
//! `app/mod.rs`, the model and the channel free of panels, the worker free of the UI.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The most lines an app file may have.
const MAX_LINES: usize = 600;

fn app_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("src")
        .join("app")
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The module path of a file below `src/app` (`tabs/views/mod.rs` -> [tabs, views]).
fn module_path(rel: &Path) -> Vec<String> {
    let mut parts: Vec<String> = rel
        .iter()
        .map(|c| c.to_string_lossy().into_owned())
        .collect();
    let last = parts.pop().unwrap();
    let stem = last.trim_end_matches(".rs");
    if stem != "mod" {
        parts.push(stem.to_string());
    }
    parts
}

/// The source without its unit tests (their `super` is the file itself) and without line
/// comments (doc comments name modules in links and prose).
fn code_of(text: &str) -> String {
    let text = match text.find("#[cfg(test)]\nmod tests") {
        Some(i) => &text[..i],
        None => text,
    };
    text.lines()
        .map(|l| match l.find("//") {
            Some(i) => &l[..i],
            None => l,
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn ident_at(s: &str) -> &str {
    let end = s
        .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
        .unwrap_or(s.len());
    &s[..end]
}

/// The first name of each item of a `{ ... }` group starting at `s` (after the brace).
fn group_heads(s: &str) -> Vec<String> {
    let (mut depth, mut heads, mut at_item) = (0usize, Vec::new(), true);
    let mut i = 0;
    let b = s.as_bytes();
    while i < b.len() {
        let c = b[i] as char;
        match c {
            '{' => depth += 1,
            '}' if depth == 0 => break,
            '}' => depth -= 1,
            ',' if depth == 0 => at_item = true,
            c if at_item && depth == 0 && (c.is_ascii_alphabetic() || c == '_' || c == '*') => {
                heads.push(if c == '*' {
                    "*".to_string()
                } else {
                    ident_at(&s[i..]).to_string()
                });
                at_item = false;
            }
            _ => {}
        }
        i += 1;
    }
    heads
}

/// Every app-level name a file refers to through `crate::app::` or `super::`, resolved from
/// the file's module path: (the first component below `app`, or None for `app` itself, and the
/// text found).
fn references(path: &[String], code: &str) -> Vec<(Vec<String>, String)> {
    let mut out = Vec::new();
    let bytes = code.as_bytes();
    let mut i = 0;
    while i < code.len() {
        let boundary = i == 0 || {
            let p = bytes[i - 1] as char;
            !(p.is_ascii_alphanumeric() || p == '_' || p == ':')
        };
        let rest = &code[i..];
        let (base, after) = if boundary && rest.starts_with("crate::app::") {
            (Some(Vec::new()), &rest["crate::app::".len()..])
        } else if boundary && rest.starts_with("super::") {
            let mut r = rest;
            let mut n = 0;
            while let Some(x) = r.strip_prefix("super::") {
                r = x;
                n += 1;
            }
            (
                (n <= path.len()).then(|| path[..path.len() - n].to_vec()),
                r,
            )
        } else {
            (None, "")
        };
        if let Some(base) = base {
            let names = match after.strip_prefix('{') {
                Some(g) => group_heads(g),
                None if after.starts_with('*') => vec!["*".to_string()],
                None => vec![ident_at(after).to_string()],
            };
            for name in names {
                let mut full = base.clone();
                if name != "self" {
                    full.push(name);
                }
                let shown = rest[..rest.len().min(60)]
                    .lines()
                    .next()
                    .unwrap_or("")
                    .to_string();
                out.push((full, shown));
            }
            i += rest.len() - after.len();
        } else {
            i += rest.chars().next().map_or(1, char::len_utf8);
        }
    }
    out
}

struct AppSource {
    /// The app's top-level modules.
    units: BTreeSet<String>,
    /// unit -> the units it imports.
    deps: BTreeMap<String, BTreeSet<String>>,
    /// Imports of `app/mod.rs` items (re-exports) from inside the app: (file, text).
    through_facade: Vec<(String, String)>,
    /// (file, lines).
    lines: Vec<(String, usize)>,
    files: Vec<PathBuf>,
}

fn read_app() -> AppSource {
    let dir = app_dir();
    let mut files = Vec::new();
    rust_files(&dir, &mut files);
    let units: BTreeSet<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_dir() || p.file_name().is_some_and(|n| n != "mod.rs"))
        .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    let mut src = AppSource {
        units: units.clone(),
        deps: BTreeMap::new(),
        through_facade: Vec::new(),
        lines: Vec::new(),
        files: files.clone(),
    };
    for f in &files {
        let rel = f.strip_prefix(&dir).unwrap();
        let text = std::fs::read_to_string(f).unwrap();
        let name = rel.display().to_string();
        src.lines.push((name.clone(), text.lines().count()));
        let path = module_path(rel);
        let Some(own) = path.first() else {
            continue; // app/mod.rs: the facade declares and re-exports
        };
        for (full, shown) in references(&path, &code_of(&text)) {
            match full.first() {
                Some(u) if u == own => {}
                Some(u) if units.contains(u) => {
                    src.deps.entry(own.clone()).or_default().insert(u.clone());
                }
                _ => src.through_facade.push((name.clone(), shown)),
            }
        }
    }
    src
}

/// A cycle of the unit graph, if there is one.
pub(crate) fn find_cycle(deps: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        u: &str,
        deps: &BTreeMap<String, BTreeSet<String>>,
        state: &mut BTreeMap<String, u8>,
        stack: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(u.to_string(), 1);
        stack.push(u.to_string());
        for v in deps.get(u).into_iter().flatten() {
            match state.get(v.as_str()).copied().unwrap_or(0) {
                1 => {
                    let at = stack.iter().position(|s| s == v).unwrap();
                    let mut c = stack[at..].to_vec();
                    c.push(v.clone());
                    return Some(c);
                }
                0 => {
                    if let Some(c) = visit(v, deps, state, stack) {
                        return Some(c);
                    }
                }
                _ => {}
            }
        }
        stack.pop();
        state.insert(u.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for u in deps.keys() {
        if state.get(u.as_str()).copied().unwrap_or(0) == 0 {
            if let Some(c) = visit(u, deps, &mut state, &mut Vec::new()) {
                return Some(c);
            }
        }
    }
    None
}

#[test]
fn app_files_stay_under_600_lines() {
    let src = read_app();
    assert!(src.files.len() > 30, "read {} app files", src.files.len());
    let long: Vec<_> = src.lines.iter().filter(|(_, n)| *n > MAX_LINES).collect();
    assert!(
        long.is_empty(),
        "src/app files over {MAX_LINES} lines (split them by concern): {long:?}"
    );
}

#[test]
fn app_uses_one_module_layout() {
    let src = read_app();
    let mixed: Vec<String> = src
        .files
        .iter()
        .filter(|f| f.file_name().is_some_and(|n| n != "mod.rs"))
        .filter(|f| f.with_extension("").is_dir())
        .map(|f| f.display().to_string())
        .collect();
    assert!(
        mixed.is_empty(),
        "foo.rs beside foo/ (use foo/mod.rs): {mixed:?}"
    );
}

#[test]
fn app_modules_import_downwards_only() {
    let src = read_app();
    for u in [
        "model", "channel", "state", "tabs", "shell", "worker", "view3d",
    ] {
        assert!(src.units.contains(u), "no app module {u}: {:?}", src.units);
    }
    // the scan sees the imports it must see (a broken scan would pass everything)
    let tabs = &src.deps["tabs"];
    assert!(
        tabs.contains("state") && tabs.contains("model") && tabs.contains("channel"),
        "{tabs:?}"
    );
    assert!(
        src.deps["shell"].contains("tabs"),
        "{:?}",
        src.deps["shell"]
    );
    assert!(
        src.through_facade.is_empty(),
        "import from the module that defines it, not through app/mod.rs: {:?}",
        src.through_facade
    );
    if let Some(c) = find_cycle(&src.deps) {
        panic!("import cycle between app modules: {}", c.join(" -> "));
    }
    let allowed = |unit: &str, ok: &[&str]| {
        let got: Vec<&String> = src
            .deps
            .get(unit)
            .into_iter()
            .flatten()
            .filter(|d| !ok.contains(&d.as_str()))
            .collect();
        assert!(got.is_empty(), "app::{unit} must not import {got:?}");
    };
    // plain data: no panel, widget or channel type inside the model
    allowed("model", &["colormap"]);
    allowed("channel", &["model"]);
    // the pipeline side knows the model and the channel, nothing of the UI
    allowed("worker", &["model", "channel"]);
}

#[test]
fn the_structure_scan_finds_what_it_must() {
    // a cycle and a facade import in a made-up module pair are found
    let code = "use super::{channel::Command, model};\nuse crate::app::Shared;\n";
    let refs = references(&["tabs".into(), "views".into()], code);
    let fulls: Vec<Vec<String>> = refs.iter().map(|r| r.0.clone()).collect();
    assert!(fulls.contains(&vec!["tabs".to_string(), "channel".to_string()]));
    assert!(fulls.contains(&vec!["Shared".to_string()]));
    let refs = references(&["state".into()], "use super::{channel::Command, model};");
    let fulls: Vec<Vec<String>> = refs.iter().map(|r| r.0.clone()).collect();
    assert_eq!(
        fulls,
        vec![vec!["channel".to_string()], vec!["model".to_string()]]
    );
    let mut deps = BTreeMap::new();
    deps.insert("a".to_string(), BTreeSet::from(["b".to_string()]));
    deps.insert("b".to_string(), BTreeSet::from(["a".to_string()]));
    assert!(find_cycle(&deps).is_some());
    deps.remove("b");
    assert!(find_cycle(&deps).is_none());
}
