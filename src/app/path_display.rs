//! How a path setting reads in a text field: relative to the repository (where `models/`
//! lives) or the working directory when under one of them, the full path otherwise. The field
//! keeps the setting's full path (its tooltip shows it); only what the user types changes it.

use std::path::{Path, PathBuf};

/// The repository the binary was built from: `models/` and `assets/` are under it.
fn repo_dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// `path` as the field shows it: relative to `repo` or `cwd` when under one of them.
pub fn shown_in(path: &Path, repo: &Path, cwd: Option<&Path>) -> String {
    let bases = std::iter::once(repo).chain(cwd);
    for base in bases {
        if let Ok(rel) = path.strip_prefix(base) {
            if !rel.as_os_str().is_empty() {
                return rel.display().to_string();
            }
        }
    }
    path.display().to_string()
}

/// The path a typed text means: a relative path names a file under the working directory when
/// one is there, else under the repository when one is there, else it is kept as typed.
pub fn typed_in(text: &str, repo: &Path, cwd: Option<&Path>) -> PathBuf {
    let p = PathBuf::from(text.trim());
    if p.is_absolute() || p.as_os_str().is_empty() {
        return p;
    }
    if cwd.is_some_and(|c| c.join(&p).exists()) {
        return p;
    }
    let in_repo = repo.join(&p);
    if in_repo.exists() {
        in_repo
    } else {
        p
    }
}

/// [`shown_in`] with this binary's repository and the working directory.
pub fn shown(path: &Path) -> String {
    shown_in(path, repo_dir(), std::env::current_dir().ok().as_deref())
}

/// [`typed_in`] with this binary's repository and the working directory.
pub fn typed(text: &str) -> PathBuf {
    typed_in(text, repo_dir(), std::env::current_dir().ok().as_deref())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_path_reads_relative_and_round_trips() {
        let repo = repo_dir();
        let model = repo.join("models").join("xfeat.onnx");
        // under the repository: shown relative, never the checkout's absolute path
        let text = shown_in(&model, repo, Some(Path::new("/elsewhere")));
        assert_eq!(
            text,
            Path::new("models").join("xfeat.onnx").display().to_string()
        );
        assert!(!text.starts_with('/'));
        // elsewhere: the full path
        let other = Path::new("/opt/weights/disk.onnx");
        assert_eq!(shown_in(other, repo, None), "/opt/weights/disk.onnx");
        // under the working directory
        assert_eq!(
            shown_in(other, repo, Some(Path::new("/opt"))),
            Path::new("weights").join("disk.onnx").display().to_string()
        );
        // a relative text of a repository file means the repository's file
        let cargo = typed_in("Cargo.toml", repo, Some(Path::new("/nonexistent-cwd")));
        assert_eq!(cargo, repo.join("Cargo.toml"));
        // a file that exists nowhere is kept as typed; absolute stays absolute
        assert_eq!(
            typed_in(" nope/x.onnx ", repo, None),
            PathBuf::from("nope/x.onnx")
        );
        assert_eq!(
            typed_in("/a/b.onnx", repo, None),
            PathBuf::from("/a/b.onnx")
        );
    }
}
