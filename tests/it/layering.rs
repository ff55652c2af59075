//! The library's floors, read from the source: the computing floors below the pipeline
//! import neither the pipeline nor anything above it, and the floors below the data sets and
//! the generators import neither (docs/architecture.md); no import cycle between the crate's
//! modules nor between the pipeline's files; the shared kernels (ONNX, the matrix, the cloud
//! validator, the camera-file reader) below their users. A doc comment may name an upper
//! floor; code may not.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// Every `crate::<module>` a floor's code (not its comments) names, with where.
fn imports(floor: &str) -> Vec<(String, String)> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    let dir = src.join(floor);
    if dir.is_dir() {
        rust_files(&dir, &mut files);
    }
    let single = src.join(format!("{floor}.rs"));
    if single.is_file() {
        files.push(single);
    }
    assert!(!files.is_empty(), "no module {floor}");
    let mut out = Vec::new();
    for f in files {
        let text = std::fs::read_to_string(&f).unwrap();
        for (n, line) in text.lines().enumerate() {
            let code = line.split("//").next().unwrap_or("");
            let mut rest = code;
            while let Some(i) = rest.find("crate::") {
                rest = &rest[i + "crate::".len()..];
                let m: String = rest
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                    .collect();
                let at = format!("{}:{}", f.strip_prefix(&src).unwrap().display(), n + 1);
                out.push((m, at));
            }
        }
    }
    out
}

#[test]
fn lower_floors_import_no_upper_floor() {
    const UPPER: [&str; 4] = ["pipeline", "report", "cli", "app"];
    let rules: [(&[&str], &[&str]); 3] = [
        (
            &[
                "io", "geometry", "camera", "cache", "features", "fusion", "estimate", "metrics",
                "simd", "onnx", "matrix", "vfm", "wfm", "synth", "dataset",
            ],
            &UPPER,
        ),
        (
            &[
                "io", "geometry", "camera", "cache", "features", "fusion", "estimate", "metrics",
                "simd", "onnx", "matrix", "vfm", "wfm",
            ],
            &["dataset", "synth"],
        ),
        (
            &[
                "io", "geometry", "camera", "cache", "features", "fusion", "estimate", "metrics",
                "simd", "onnx", "matrix", "vfm",
            ],
            &["wfm"],
        ),
    ];
    let mut bad = Vec::new();
    for (floors, forbidden) in rules {
        for floor in floors {
            for (m, at) in imports(floor) {
                if forbidden.contains(&m.as_str()) {
                    bad.push(format!("{at}: {floor} imports crate::{m}"));
                }
            }
        }
    }
    bad.sort();
    bad.dedup();
    assert!(bad.is_empty(), "imports up the floors:\n{}", bad.join("\n"));
    // the test sees imports at all (a floor that does import a lower one)
    assert!(imports("pipeline").iter().any(|(m, _)| m == "dataset"));
}

/// A module of the crate: its path below `src` (`pipeline/tail/mod.rs` -> "pipeline::tail").
type Module = String;

/// The module of a file below `src` (None: the binary's `main.rs`).
fn module_of(rel: &Path) -> Option<Vec<String>> {
    let mut parts: Vec<String> = rel
        .iter()
        .map(|c| c.to_string_lossy().into_owned())
        .collect();
    let last = parts.pop()?;
    match last.trim_end_matches(".rs") {
        "main" if parts.is_empty() => None,
        "lib" if parts.is_empty() => Some(parts),
        "mod" => Some(parts),
        stem => {
            parts.push(stem.to_string());
            Some(parts)
        }
    }
}

/// The code of a file without its unit tests and its line comments.
fn code_of(text: &str) -> String {
    let text = match text.find("#[cfg(test)]\nmod tests") {
        Some(i) => &text[..i],
        None => text,
    };
    text.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .collect::<Vec<_>>()
        .join("\n")
}

fn is_ident(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// `a::b::c` at the start of `s` (the segments, and the rest after them; a trailing `::{`
/// stays in the rest).
fn path_at(s: &str) -> (Vec<String>, &str) {
    let mut segs = Vec::new();
    let mut rest = s;
    loop {
        let end = rest.find(|c: char| !is_ident(c)).unwrap_or(rest.len());
        if end == 0 {
            break;
        }
        segs.push(rest[..end].to_string());
        rest = &rest[end..];
        match rest.strip_prefix("::") {
            Some(r) if r.starts_with(|c: char| is_ident(c)) => rest = r,
            _ => break,
        }
    }
    (segs, rest)
}

/// The paths of the items of a `{ ... }` group starting after its brace (nested groups give
/// their prefix).
fn group_items(s: &str) -> Vec<Vec<String>> {
    let (mut depth, mut out, mut at_item) = (0usize, Vec::new(), true);
    let mut i = 0;
    while i < s.len() {
        let c = s[i..].chars().next().unwrap_or(' ');
        match c {
            '{' => depth += 1,
            '}' if depth == 0 => break,
            '}' => depth -= 1,
            ',' if depth == 0 => at_item = true,
            c if at_item && depth == 0 && is_ident(c) => {
                let (segs, rest) = path_at(&s[i..]);
                i = s.len() - rest.len();
                out.push(segs);
                at_item = false;
                continue;
            }
            _ => {}
        }
        i += c.len_utf8();
    }
    out
}

/// Every module a file's code names through `crate::`, `super::` or `self::`, resolved to the
/// longest module path the crate has. A folder's `mod.rs` naming its own children by their bare
/// names (`mod union;` ... `union::register`) is the folder handing its parts on, not an import.
fn named_modules(own: &[String], code: &str, modules: &BTreeSet<Vec<String>>) -> BTreeSet<Module> {
    let mut out = BTreeSet::new();
    let mut i = 0;
    while i < code.len() {
        let boundary = i == 0
            || code[..i]
                .chars()
                .next_back()
                .is_none_or(|p| !(is_ident(p) || p == ':'));
        let rest = &code[i..];
        let base = if !boundary {
            None
        } else if let Some(r) = rest.strip_prefix("crate::") {
            Some((Vec::new(), r))
        } else if rest.starts_with("super::") || rest.starts_with("self::") {
            let mut r = rest;
            let mut n = 0;
            while let Some(x) = r.strip_prefix("super::") {
                r = x;
                n += 1;
            }
            let r = r.strip_prefix("self::").unwrap_or(r);
            (n <= own.len()).then(|| (own[..own.len() - n].to_vec(), r))
        } else {
            None
        };
        let Some((base, after)) = base else {
            i += rest.chars().next().map_or(1, char::len_utf8);
            continue;
        };
        let (prefix, tail) = path_at(after);
        let items = match tail.strip_prefix("::{").or(tail.strip_prefix('{')) {
            Some(g) => group_items(g),
            None => vec![Vec::new()],
        };
        for item in items {
            let full: Vec<String> = base
                .iter()
                .chain(&prefix)
                .chain(&item)
                .filter(|s| *s != "self")
                .cloned()
                .collect();
            let found = (1..=full.len())
                .rev()
                .map(|k| &full[..k])
                .find(|m| modules.contains(*m));
            if let Some(m) = found.filter(|m| *m != own) {
                out.insert(m.join("::"));
            }
        }
        i = code.len() - after.len();
    }
    out
}

/// The crate's import graph, file by file: module -> the modules its code names.
fn file_graph() -> BTreeMap<Module, BTreeSet<Module>> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mods: Vec<(Vec<String>, PathBuf)> = files
        .into_iter()
        .filter_map(|f| Some((module_of(f.strip_prefix(&src).ok()?)?, f)))
        .collect();
    let modules: BTreeSet<Vec<String>> = mods.iter().map(|(m, _)| m.clone()).collect();
    mods.iter()
        .map(|(m, f)| {
            let text = std::fs::read_to_string(f).unwrap();
            (m.join("::"), named_modules(m, &code_of(&text), &modules))
        })
        .collect()
}

/// The graph between the modules under `under` (a module path; "" for the crate), each module
/// taken as its first `depth` components below `under` (1: its children as wholes).
fn graph_under(
    files: &BTreeMap<Module, BTreeSet<Module>>,
    under: &str,
    depth: Option<usize>,
) -> BTreeMap<Module, BTreeSet<Module>> {
    let unit = |m: &str| -> Option<String> {
        let rest = if under.is_empty() {
            m
        } else {
            m.strip_prefix(under)?.strip_prefix("::")?
        };
        let parts: Vec<&str> = rest.split("::").filter(|s| !s.is_empty()).collect();
        if parts.is_empty() {
            return None;
        }
        let n = depth.map_or(parts.len(), |d| d.min(parts.len()));
        Some(parts[..n].join("::"))
    };
    let mut g: BTreeMap<Module, BTreeSet<Module>> = BTreeMap::new();
    for (m, deps) in files {
        let Some(a) = unit(m) else { continue };
        for d in deps {
            if let Some(b) = unit(d).filter(|b| *b != a) {
                g.entry(a.clone()).or_default().insert(b);
            }
        }
    }
    g
}

#[test]
fn the_pipeline_files_import_without_a_cycle() {
    let files = file_graph();
    let g = graph_under(&files, "pipeline", None);
    // the scan sees the imports it must see
    assert!(g["register"].contains("scales"), "{:?}", g["register"]);
    assert!(
        g["tail::visibility"].contains("tail::union"),
        "{:?}",
        g["tail::visibility"]
    );
    assert!(
        g["stages::lift"].contains("graph"),
        "{:?}",
        g["stages::lift"]
    );
    if let Some(c) = crate::gui_structure::find_cycle(&g) {
        panic!("import cycle between pipeline files: {}", c.join(" -> "));
    }
    // data at the bottom: the stage names, the plan's steps, the tail's inputs, the reports
    // and the result import no other pipeline file but these
    for (leaf, may) in [
        ("graph", &["params"][..]),
        ("inputs", &[][..]),
        ("arbitration", &[][..]),
        ("result", &["graph", "inputs", "arbitration"][..]),
    ] {
        let bad: Vec<&String> = g
            .get(leaf)
            .into_iter()
            .flatten()
            .filter(|d| !may.contains(&d.as_str()))
            .collect();
        assert!(bad.is_empty(), "pipeline::{leaf} must not import {bad:?}");
    }
}

#[test]
fn the_crate_modules_import_without_a_cycle() {
    let files = file_graph();
    let g = graph_under(&files, "", Some(1));
    assert!(g["pipeline"].contains("dataset"), "{:?}", g["pipeline"]);
    if let Some(c) = crate::gui_structure::find_cycle(&g) {
        panic!(
            "import cycle between the crate's modules: {}",
            c.join(" -> ")
        );
    }
}

#[test]
fn the_import_scan_resolves_paths() {
    let modules: BTreeSet<Vec<String>> = [
        vec!["pipeline".to_string()],
        vec!["pipeline".into(), "graph".into()],
        vec!["pipeline".into(), "tail".into()],
        vec!["pipeline".into(), "tail".into(), "union".into()],
        vec!["fusion".into()],
    ]
    .into_iter()
    .collect();
    let own = [
        "pipeline".to_string(),
        "tail".to_string(),
        "visibility".to_string(),
    ];
    let code = "use super::union::{a, b};\nuse crate::pipeline::{graph::StageName, x};\n\
                let y = crate::fusion::f(); let z = notcrate::fusion::g();";
    let got = named_modules(&own, code, &modules);
    let want: BTreeSet<String> = [
        "pipeline::tail::union",
        "pipeline::graph",
        "pipeline",
        "fusion",
    ]
    .into_iter()
    .map(String::from)
    .collect();
    assert_eq!(got, want);
}

#[test]
fn shared_kernels_stay_on_the_ground_floor() {
    let files = file_graph();
    let g = graph_under(&files, "", Some(1));
    let only = |m: &str, may: &[&str]| {
        let bad: Vec<&String> = g
            .get(m)
            .into_iter()
            .flatten()
            .filter(|d| !may.contains(&d.as_str()))
            .collect();
        assert!(bad.is_empty(), "{m} must not import {bad:?}");
    };
    // one ONNX module and one matrix type, which both branches use
    only("onnx", &["error"]);
    only("matrix", &["error", "io"]);
    assert!(g["vfm"].contains("onnx") && g["features"].contains("onnx"));
    assert!(g["vfm"].contains("matrix") && g["fusion"].contains("matrix"));
    // neither branch files a shared kernel with the other: no features -> vfm -> fusion loop
    for (m, not) in [
        ("features", "vfm"),
        ("vfm", "fusion"),
        ("vfm", "features"),
        ("io", "camera"),
    ] {
        assert!(!g[m].contains(not), "{m} imports {not}: {:?}", g[m]);
    }
    // the cloud readers' one validator stands below them (cloud.rs dispatches to the readers)
    let v = &files["io::validate"];
    assert!(
        v.iter().all(|d| d == "error" || d.starts_with("geometry")),
        "{v:?}"
    );
    for reader in ["io::ply", "io::pcd", "io::xyz", "io::kitti", "io::npy"] {
        assert!(files[reader].contains("io::validate"), "{reader}");
        assert!(
            !files[reader].contains("io::cloud"),
            "{reader} imports io::cloud"
        );
    }
    // the camera-file reader is the camera's, the posed depth view one type
    assert!(files.contains_key("camera::camera_txt"));
    assert!(
        files["vfm::lift"].contains("camera"),
        "{:?}",
        files["vfm::lift"]
    );
}
