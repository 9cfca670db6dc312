//! The one check every writing command makes of its output folder before it writes: a folder
//! holding another dataset or another command's run is refused, so that no command replaces or
//! mixes into what it did not write . Each command names the markers it writes
//! itself, which it may find and rewrite or resume (eval rewriting its own earlier output).

use std::path::Path;

use crate::error::{DataError, Result};
use crate::schema;

/// What the search variants command writes beside its tables: which run and draw they hold, so a
/// resume can tell its own shards from another dataset's.
pub const VARIANTS_FILE: &str = "variants.json";

/// What `boxpose improve` records its settings in; a resumed run must have the same.
pub const IMPROVE_SETTINGS_FILE: &str = "improve.json";

/// The files and folders that mark a folder as some command's output, and what that output is.
const MARKERS: [(&str, &str); 14] = [
    (schema::SCENES.name, "a dataset"),
    (schema::OBJECTS.name, "a dataset"),
    (schema::FRAMES.name, "a dataset"),
    (schema::INSTANCES.name, "a dataset"),
    ("manifest.json", "a dataset"),
    (VARIANTS_FILE, "search variants' dataset"),
    ("run.json", "a search run"),
    ("config.toml", "a training run"),
    ("checkpoint", "a training run"),
    ("eval.parquet", "eval's output"),
    ("eval_results.parquet", "eval-results' output"),
    ("predictions.parquet", "predict's output"),
    ("camera.json", "a BOP export"),
    (IMPROVE_SETTINGS_FILE, "an improve run"),
];

/// Refuses `folder` (the value of `flag`) when it holds a marker of another dataset or run, any
/// marker but the command's `own`. Checked before anything is created, so a refused command
/// leaves the folder as it found it.
pub fn refuse_foreign(folder: &Path, flag: &str, command: &str, own: &[&str]) -> Result<()> {
    let held: Vec<(&str, &str)> = MARKERS
        .into_iter()
        .filter(|(name, _)| !own.contains(name) && folder.join(name).exists())
        .collect();
    let Some((_, what)) = held.first() else {
        return Ok(());
    };
    let names: Vec<&str> = held.iter().map(|(name, _)| *name).collect();
    Err(DataError::OutputFolder(format!(
        "{flag} {} already holds {what} ({}): {command} would replace or mix into output it did \
         not write; choose a new or empty folder for {flag}",
        folder.display(),
        names.join(", ")
    )))
}

/// A writing command's hold on its output folder: [`claim`] checked that it holds no other
/// output and locked the folder itself (flock on the directory, so the folder gains no lock
/// file). The kernel releases the lock when the process ends, however it ends. Dropped, it
/// removes the folder again when [`claim`] created it and nothing was written into it, so a
/// command that fails on its input leaves nothing behind.
pub struct Claim {
    _locked: std::fs::File,
    created: Option<std::path::PathBuf>,
}

impl Drop for Claim {
    fn drop(&mut self) {
        if let Some(folder) = &self.created {
            let _ = std::fs::remove_dir(folder); // only succeeds while the folder is empty
        }
    }
}

/// [`refuse_foreign`], then the folder (created if missing) locked for this process: a second
/// `boxpose` writing into it at the same time is refused, naming the folder.
pub fn claim(folder: &Path, flag: &str, command: &str, own: &[&str]) -> Result<Claim> {
    refuse_foreign(folder, flag, command, own)?;
    let created = if folder.exists() {
        None
    } else {
        std::fs::create_dir_all(folder).map_err(|e| {
            refused(format!(
                "{flag} {}: cannot create it: {e}",
                folder.display()
            ))
        })?;
        Some(folder.to_path_buf())
    };
    let claim = Claim {
        _locked: std::fs::File::open(folder)
            .map_err(|e| refused(format!("{flag} {}: cannot open it: {e}", folder.display())))?,
        created,
    };
    match claim._locked.try_lock() {
        Ok(()) => Ok(claim),
        Err(std::fs::TryLockError::WouldBlock) => Err(refused(format!(
            "{flag} {}: another boxpose command is writing into it now; wait for it to end, or \
             choose another folder for {flag}",
            folder.display()
        ))),
        Err(std::fs::TryLockError::Error(e)) => Err(refused(format!(
            "{flag} {}: cannot lock it: {e}",
            folder.display()
        ))),
    }
}

/// Removes an output an earlier run into the same folder wrote and this one does not, so that
/// the folder never mixes two runs' results.
pub fn remove_stale(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Err(source) if source.kind() != std::io::ErrorKind::NotFound => Err(DataError::Io {
            path: path.to_path_buf(),
            source,
        }),
        _ => Ok(()),
    }
}

fn refused(message: String) -> DataError {
    DataError::OutputFolder(message)
}
