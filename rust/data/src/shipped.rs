//! The files the repository ships and the commands default to (`models/`, `configs/`,
//! `datasets/recipes/`): their defaults are paths relative to the repository root, so that a
//! command run from another folder finds them there.

use std::path::{Path, PathBuf};

/// The nearest folder for which `wanted` holds, above the running executable (a build under
/// `target/`) or, failing that, above this crate's sources (the build's repository).
pub fn nearest_folder_above(wanted: impl Fn(&Path) -> bool) -> Option<PathBuf> {
    let starts = std::env::current_exe()
        .ok()
        .into_iter()
        .chain(std::iter::once(PathBuf::from(env!("CARGO_MANIFEST_DIR"))));
    for start in starts {
        if let Some(dir) = start.ancestors().find(|dir| wanted(dir)) {
            return Some(dir.to_path_buf());
        }
    }
    None
}

/// The boxpose repository this binary belongs to: the nearest folder above it that holds
/// `configs/search` and `datasets/recipes`.
pub fn repository_root() -> Option<PathBuf> {
    nearest_folder_above(|dir| {
        dir.join("configs").join("search").is_dir() && dir.join("datasets").join("recipes").is_dir()
    })
}

/// `path` as given when it exists or is absolute; otherwise the same relative path under the
/// repository root when that exists (a shipped default met from another working folder); else
/// `path` unchanged, so that the error names what was asked for.
pub fn resolve(path: &Path) -> PathBuf {
    if path.is_absolute() || path.exists() {
        return path.to_path_buf();
    }
    repository_root()
        .map(|root| root.join(path))
        .filter(|p| p.exists())
        .unwrap_or_else(|| path.to_path_buf())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_shipped_path_resolves_under_the_repository_root_and_others_stay() {
        let root = repository_root().expect("the crate lives in the repository");
        assert!(root.join("configs/search/single_box.toml").is_file());
        // relative to the test's working folder (the crate's) the shipped file is not there
        let shipped = Path::new("configs/search/single_box.toml");
        assert!(!shipped.exists());
        assert_eq!(resolve(shipped), root.join(shipped));
        // a path that exists nowhere is left as given, for the error to name
        let missing = Path::new("configs/search/no_such_space.toml");
        assert_eq!(resolve(missing), missing);
        // one that exists here is taken as given
        assert_eq!(resolve(Path::new("Cargo.toml")), Path::new("Cargo.toml"));
    }
}
