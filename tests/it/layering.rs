//! The library's floors, read from the source: the computing floors below the pipeline
//! import neither the pipeline nor anything above it, and the floors below the data sets and
//! the generators import neither (docs/architecture.md). A doc comment may name an upper
//! floor; code may not.

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
                "simd", "vfm", "wfm", "synth", "dataset",
            ],
            &UPPER,
        ),
        (
            &[
                "io", "geometry", "camera", "cache", "features", "fusion", "estimate", "metrics",
                "simd", "vfm", "wfm",
            ],
            &["dataset", "synth"],
        ),
        (
            &[
                "io", "geometry", "camera", "cache", "features", "fusion", "estimate", "metrics",
                "simd", "vfm",
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
