//! What users read speaks about the project, not about how it was developed: README.md,
//! BENCHMARKS.md, everything under docs/ and studies/ (Markdown, text, JSON, CSV, TOML) and
//! the `--help` text of every subcommand carry no numbered development sessions, rounds or issue
//! numbers, no worktree names, no "the lead", and no absolute paths of development machines
//! (their home, work and temporary folders). History belongs in CHANGELOG.md (and the records
//! beside it in changelog/), which is not checked.

use std::path::{Path, PathBuf};

/// Why `line` (any case) breaks the rule, or None. Hand-written rather than a regex crate so
/// the test adds no dependency.
fn violation(line: &str) -> Option<String> {
    let l = line.to_lowercase();
    for path in ["/work/", "/tmp/", "/home/", "/root/", "/users/"] {
        if l.contains(path) {
            return Some(format!("a development machine's path ({path})"));
        }
    }
    for phrase in [
        "the lead",
        "worktree",
        "helper session",
        "development round",
        "session's",
        "sessions'",
    ] {
        if contains_word(&l, phrase) {
            return Some(format!("development-process words ({phrase:?})"));
        }
    }
    for w in [
        "this", "that", "last", "earlier", "previous", "later", "next", "same", "each", "every",
        "the",
    ] {
        for what in ["session", "round"] {
            let phrase = format!("{w} {what}");
            if contains_word(&l, &phrase) {
                return Some(format!("development-process words ({phrase:?})"));
            }
        }
    }
    // "session 12", "session-11", "round 3", "issue 30", "issues 3 and 10", "issue #3"
    for word in ["session", "sessions", "round", "rounds", "issue", "issues"] {
        for (i, _) in l.match_indices(word) {
            if !word_start(&l, i) {
                continue;
            }
            let rest = &l[i + word.len()..];
            let rest = rest
                .strip_prefix(' ')
                .or_else(|| rest.strip_prefix('-'))
                .unwrap_or(rest);
            let rest = rest.strip_prefix('#').unwrap_or(rest);
            if rest.starts_with(|c: char| c.is_ascii_digit()) {
                return Some(format!("a numbered development step ({word} N)"));
            }
        }
    }
    let b = l.as_bytes();
    for (i, &c) in b.iter().enumerate() {
        // "#12" (an issue reference; not "&#12;" nor a colour "#1f77b4")
        if c == b'#'
            && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'&'))
            && b.get(i + 1).is_some_and(|c| c.is_ascii_digit())
        {
            let end = b[i + 1..]
                .iter()
                .position(|c| !c.is_ascii_alphanumeric())
                .map_or(b.len(), |p| i + 1 + p);
            if b[i + 1..end].iter().all(|c| c.is_ascii_digit()) {
                return Some("an issue reference (#N)".into());
            }
        }
        // "vfm-s11": a session number in a folder or file name
        if i > 0
            && c == b'-'
            && b[i - 1].is_ascii_alphanumeric()
            && b.get(i + 1) == Some(&b's')
            && b.get(i + 2).is_some_and(|c| c.is_ascii_digit())
        {
            let digits = b[i + 2..].iter().take_while(|c| c.is_ascii_digit()).count();
            let after = b.get(i + 2 + digits);
            if digits <= 2 && !after.is_some_and(|c| c.is_ascii_alphanumeric()) {
                return Some("a session number in a name (-sN)".into());
            }
        }
    }
    None
}

fn word_start(l: &str, i: usize) -> bool {
    i == 0 || !l.as_bytes()[i - 1].is_ascii_alphanumeric()
}

fn contains_word(l: &str, phrase: &str) -> bool {
    l.match_indices(phrase).any(|(i, _)| {
        let end = i + phrase.len();
        word_start(l, i)
            && !l
                .as_bytes()
                .get(end)
                .is_some_and(|c| c.is_ascii_alphanumeric())
    })
}

/// Every violation in `text`, as "where:line: why: the line".
fn scan(where_: &str, text: &str) -> Vec<String> {
    text.lines()
        .enumerate()
        .filter_map(|(i, line)| {
            violation(line).map(|why| format!("{where_}:{}: {why}: {}", i + 1, line.trim()))
        })
        .collect()
}

fn files_under(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("reading {}: {e}", dir.display()))
        .flatten()
        .map(|e| e.path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            files_under(&p, out);
        } else {
            out.push(p);
        }
    }
}

#[test]
fn the_checker_flags_process_words_and_machine_paths() {
    for bad in [
        "measured in session 12 on a quiet machine",
        "the session-11 section",
        "Session 10: every row again",
        "see issue 30, item 2",
        "(issues 3 and 10)",
        "fixed in #42",
        "as the lead asked",
        "a helper session ran it",
        "run from the worktree",
        "this session's release build",
        "in the same session",
        "CGENREG_DATA=/work/shared/data",
        "/tmp/lidar-cache",
        "/home/alice/data",
        "/root/.cache/cgenreg",
        "docs/ablation/vfm-s11/fpfh-nn.json",
        "the last development round",
    ] {
        assert!(violation(bad).is_some(), "not flagged: {bad:?}");
    }
    for good in [
        "loading the ONNX session takes 0.7 s",
        "app/worker/session.rs",
        "round-off differs in the last bit",
        "3DMatch (27 pairs), 3DLoMatch (10 pairs)",
        "colour #1f77b4 and &#38;",
        "`--shard I/N` with --k 4 -s 2",
        "CGENREG_DATA=$CGENREG_DATA, ~/.cache/cgenreg",
        "docs/ablation/vfm-per-pixel/fpfh-nn.json",
        "## 3. Fuzzing",
    ] {
        assert_eq!(violation(good), None, "flagged: {good:?}");
    }
}

#[test]
fn user_documents_carry_no_process_words_or_machine_paths() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = vec![root.join("README.md"), root.join("BENCHMARKS.md")];
    files_under(&root.join("docs"), &mut files);
    // the studies' READMEs and results, which the result pages link to
    files_under(&root.join("studies"), &mut files);
    let mut found = Vec::new();
    let mut read = 0;
    for f in &files {
        let ext = f.extension().and_then(|e| e.to_str()).unwrap_or("");
        if !matches!(
            ext,
            "md" | "txt" | "json" | "csv" | "toml" | "jsonl" | "log"
        ) {
            continue;
        }
        let text =
            std::fs::read_to_string(f).unwrap_or_else(|e| panic!("reading {}: {e}", f.display()));
        read += 1;
        let rel = f.strip_prefix(root).unwrap_or(f).display().to_string();
        found.extend(scan(&rel, &text));
    }
    assert!(
        read > 50,
        "only {read} documents found under {}",
        root.display()
    );
    assert!(
        found.is_empty(),
        "{} lines in user documents mention the development process or a machine's path \
         (history goes to CHANGELOG.md; paths as repo-relative or $CGENREG_DATA/...):\n{}",
        found.len(),
        found.join("\n")
    );
}

#[test]
fn help_texts_carry_no_process_words_or_machine_paths() {
    use clap::CommandFactory;
    fn walk(cmd: &mut clap::Command, name: String, out: &mut Vec<(String, String)>) {
        out.push((name.clone(), cmd.render_long_help().to_string()));
        for sub in cmd.get_subcommands_mut() {
            let n = format!("{name} {}", sub.get_name());
            walk(sub, n, out);
        }
    }
    let mut cmd = cgenreg::cli::Cli::command();
    cmd.build();
    let mut helps = Vec::new();
    walk(&mut cmd, "cgenreg".into(), &mut helps);
    assert!(helps.len() >= 12, "only {} commands found", helps.len());
    let mut found: Vec<String> = helps
        .iter()
        .flat_map(|(name, text)| scan(&format!("`{name} --help`"), text))
        .collect();
    // doc comments double as help: rustdoc's link syntax means nothing to a user
    for (name, text) in &helps {
        for line in text.lines().filter(|l| l.contains("[`")) {
            found.push(format!("`{name} --help`: rustdoc link: {}", line.trim()));
        }
    }
    assert!(found.is_empty(), "help texts:\n{}", found.join("\n"));
}
