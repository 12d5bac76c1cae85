//! Reading recipes from disk: a file, a station directory
//! (`recipes/welding/`) or a recipe tree (`recipes/` holding `cell/`,
//! `welding/`, `transport/`). The directory a file sits in names its
//! station and, unless given, its kind.

use super::check::Entry;
use super::commands::RecipeKind;
use super::syntax::parse;
use falc_model::ids::StationName;
use std::path::{Path, PathBuf};

fn read_entry(path: &Path, kind: Option<RecipeKind>) -> Result<Entry, String> {
    let text = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let text = String::from_utf8(text).map_err(|e| {
        format!(
            "{}: not UTF-8 text (byte {} is invalid)",
            path.display(),
            e.utf8_error().valid_up_to()
        )
    })?;
    entry(path, kind, text)
}

/// The entry of `text` as if read from `path` (a recipe about to be saved
/// there): the directory names its station and, unless given, its kind.
pub fn entry(path: &Path, kind: Option<RecipeKind>, text: String) -> Result<Entry, String> {
    let dir = path
        .parent()
        .and_then(|p| p.file_name())
        .and_then(|n| n.to_str())
        .unwrap_or("");
    let kind = match kind {
        Some(k) => k,
        None => dir.parse().map_err(|_| {
            format!(
                "{}: cannot tell the recipe kind: put it under cell/, welding/ or transport/, or pass --kind",
                path.display()
            )
        })?,
    };
    let station = StationName::new(dir)
        .or_else(|_| StationName::new(&kind.to_string()))
        .map_err(|e| e.to_string())?;
    Ok(Entry {
        station,
        kind,
        recipe: parse(&text, &path.display().to_string()),
        text,
    })
}

fn rcp_files(dir: &Path) -> Result<Vec<PathBuf>, String> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("rcp")))
        .collect();
    v.sort();
    Ok(v)
}

/// Loads every recipe under `paths` (files, station directories or recipe
/// trees). `kind` overrides the kind the directory names.
pub fn load(paths: &[PathBuf], kind: Option<RecipeKind>) -> Result<Vec<Entry>, Vec<String>> {
    let mut entries = Vec::new();
    let mut errors = Vec::new();
    let mut files = Vec::new();
    for p in paths {
        if p.is_dir() {
            let subdirs: Vec<PathBuf> = RecipeKind::ALL
                .iter()
                .map(|k| p.join(k.to_string()))
                .filter(|d| d.is_dir())
                .collect();
            let dirs = if subdirs.is_empty() {
                vec![p.clone()]
            } else {
                subdirs
            };
            for d in dirs {
                match rcp_files(&d) {
                    Ok(mut f) => files.append(&mut f),
                    Err(e) => errors.push(e),
                }
            }
        } else {
            files.push(p.clone());
        }
    }
    for f in files {
        match read_entry(&f, kind) {
            Ok(e) => entries.push(e),
            Err(e) => errors.push(e),
        }
    }
    if errors.is_empty() {
        Ok(entries)
    } else {
        Err(errors)
    }
}
