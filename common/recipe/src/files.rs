//! Reading recipes from disk: a file, a station directory
//! (`recipes/welding/`) or a recipe tree (`recipes/` holding a directory
//! per station: `cell/`, `welding/`, `transport/`, `welding2/` …). The
//! directory a file sits in names its station; the station's kind comes
//! from the topology ([`StationKinds`]), else from the directory's name.
//! A tree's `robot/` directory holds its robot programs ([`load_robot`]).

use super::check::Entry;
use super::commands::RecipeKind;
use super::robot_program::RobotFile;
use super::syntax::parse;
use falc_model::ids::StationName;
use falc_model::recipe_file::ROBOT_DIR;
use falc_model::topology::{StationKind, Topology};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The recipe kind of each station, from the topology's stanzas: a second
/// welding station `welding2` reads `recipes/welding2/` as welding
/// recipes. A directory no stanza names is read by its own name (`cell`,
/// `welding`, `transport`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct StationKinds(BTreeMap<StationName, RecipeKind>);

impl StationKinds {
    /// The kinds of `topology`'s stations (the operator has no recipes).
    pub fn of(topology: &Topology) -> Self {
        Self(
            topology
                .stations()
                .iter()
                .filter_map(|s| {
                    let kind = match s.kind {
                        StationKind::Operator => return None,
                        StationKind::Cell => RecipeKind::Cell,
                        StationKind::Welding => RecipeKind::Welding,
                        StationKind::Transport => RecipeKind::Transport,
                    };
                    Some((s.name.clone(), kind))
                })
                .collect(),
        )
    }

    /// The kind of the recipes in directory `dir`.
    fn kind_of(&self, dir: &str) -> Option<RecipeKind> {
        StationName::new(dir)
            .ok()
            .and_then(|s| self.0.get(&s).copied())
            .or_else(|| dir.parse().ok())
    }

    /// The station directories a recipe tree may hold.
    fn dirs(&self) -> Vec<String> {
        let mut v: Vec<String> = RecipeKind::ALL.iter().map(ToString::to_string).collect();
        for s in self.0.keys() {
            if !v.iter().any(|d| d == s.as_str()) {
                v.push(s.as_str().to_string());
            }
        }
        v
    }
}

fn read_entry(
    path: &Path,
    kind: Option<RecipeKind>,
    kinds: &StationKinds,
) -> Result<Entry, String> {
    let text = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let text = String::from_utf8(text).map_err(|e| {
        format!(
            "{}: not UTF-8 text (byte {} is invalid)",
            path.display(),
            e.utf8_error().valid_up_to()
        )
    })?;
    entry_in(path, kind, kinds, text)
}

/// The entry of `text` as if read from `path` (a recipe about to be saved
/// there): the directory names its station and, unless given, its kind.
pub fn entry(path: &Path, kind: Option<RecipeKind>, text: String) -> Result<Entry, String> {
    entry_in(path, kind, &StationKinds::default(), text)
}

/// [`entry`], the station's kind from `kinds`.
pub fn entry_in(
    path: &Path,
    kind: Option<RecipeKind>,
    kinds: &StationKinds,
    text: String,
) -> Result<Entry, String> {
    let dir = path
        .parent()
        .and_then(|p| p.file_name())
        .and_then(|n| n.to_str())
        .unwrap_or("");
    let kind = match kind {
        Some(k) => k,
        None => kinds.kind_of(dir).ok_or_else(|| {
            format!(
                "{}: cannot tell the recipe kind: put it under the directory of a station of the topology (cell/, welding/, transport/ …), or pass --kind",
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
    files_ending(dir, "rcp")
}

/// The files of `dir` whose extension is `ext` (any case), sorted; the
/// directory that cannot be read named in the error.
pub fn files_ending(dir: &Path, ext: &str) -> Result<Vec<PathBuf>, String> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case(ext)))
        .collect();
    v.sort();
    Ok(v)
}

/// The robot programs of recipe tree `tree` (every `robot/*.prg`), each
/// checked; None when the tree has no `robot/` directory (the robot
/// controller's own programs are run, as in 1992). Every problem as
/// `file:line: reason`.
pub fn load_robot(tree: &Path) -> Result<Option<Vec<RobotFile>>, Vec<String>> {
    let dir = tree.join(ROBOT_DIR);
    if !dir.is_dir() {
        return Ok(None);
    }
    let mut out = Vec::new();
    let mut errors = Vec::new();
    for path in files_ending(&dir, "prg").map_err(|e| vec![e])? {
        let origin = path.display().to_string();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
        let read = std::fs::read(&path)
            .map_err(|e| vec![format!("{origin}: {e}")])
            .and_then(|b| {
                String::from_utf8(b).map_err(|e| {
                    vec![format!(
                        "{origin}: not UTF-8 text (byte {} is invalid)",
                        e.utf8_error().valid_up_to()
                    )]
                })
            })
            .and_then(|text| RobotFile::read(&origin, name, &text));
        match read {
            Ok(r) => out.push(r),
            Err(mut e) => errors.append(&mut e),
        }
    }
    if errors.is_empty() {
        Ok(Some(out))
    } else {
        Err(errors)
    }
}

/// Loads every recipe under `paths` (files, station directories or recipe
/// trees). `kind` overrides the kind the directory names.
pub fn load(paths: &[PathBuf], kind: Option<RecipeKind>) -> Result<Vec<Entry>, Vec<String>> {
    load_in(paths, kind, &StationKinds::default())
}

/// [`load`], each station's kind (and the station directories of a tree)
/// from `kinds`.
pub fn load_in(
    paths: &[PathBuf],
    kind: Option<RecipeKind>,
    kinds: &StationKinds,
) -> Result<Vec<Entry>, Vec<String>> {
    let mut entries = Vec::new();
    let mut errors = Vec::new();
    let mut files = Vec::new();
    for p in paths {
        if p.is_dir() {
            let subdirs: Vec<PathBuf> = kinds
                .dirs()
                .iter()
                .map(|d| p.join(d))
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
        match read_entry(&f, kind, kinds) {
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

#[cfg(test)]
mod tests {
    use super::*;

    const TOPOLOGY: &str = r#"
cell = "falc1"
router = "tcp/127.0.0.1:7447"
[[station]]
name = "operator"
kind = "operator"
[[station]]
name = "cell"
kind = "cell"
commander = "operator"
[[station]]
name = "welding2"
kind = "welding"
commander = "cell"
"#;

    #[test]
    fn a_tree_s_robot_programs_are_read_and_checked_with_file_and_line() {
        let tmp = tempfile::tempdir().expect("tempdir");
        assert_eq!(load_robot(tmp.path()), Ok(None), "no robot directory");
        let dir = tmp.path().join("robot");
        std::fs::create_dir_all(&dir).expect("mkdir");
        assert_eq!(load_robot(tmp.path()), Ok(Some(Vec::new())));
        std::fs::write(dir.join("065.prg"), "program 65\nmove home 2\n").expect("write");
        std::fs::write(dir.join("notes.txt"), "not a program").expect("write");
        let read = load_robot(tmp.path()).expect("clean").expect("a directory");
        assert_eq!(read.len(), 1);
        assert_eq!(read[0].file.to_string(), "robot/065.prg");
        assert_eq!(read[0].program.steps.len(), 1);
        std::fs::write(dir.join("home.prg"), "program 1\nmove home 2\n").expect("write");
        std::fs::write(dir.join("002.prg"), "program 2\nmove home\n").expect("write");
        std::fs::write(dir.join("003.prg"), [b'p', 0xff]).expect("write");
        let errors = load_robot(tmp.path()).expect_err("three bad files");
        assert_eq!(errors.len(), 3, "{errors:?}");
        assert!(errors[0].ends_with("002.prg:2: `move home` is not a step: write `move NAME SECONDS` or `weld NAME SECONDS`"), "{errors:?}");
        assert!(
            errors[1].contains("003.prg: not UTF-8 text (byte 1"),
            "{errors:?}"
        );
        assert!(
            errors[2].contains("home.prg:1: robot program file name \"home.prg\""),
            "{errors:?}"
        );
    }

    #[test]
    fn a_station_directory_s_kind_comes_from_the_topology() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let dir = tmp.path().join("welding2");
        std::fs::create_dir_all(&dir).expect("mkdir");
        std::fs::write(
            dir.join("w.rcp"),
            "#W\n-1 | start rcm 65 | | gestart | 2\n-1 | start rcm 65 | | tijdlimiet | 0\n-2 | wait rcm 10 | | klaar | 0\n-2 | wait rcm 10 | | tijdlimiet | 0\n",
        )
        .expect("write");
        let topology = Topology::parse(TOPOLOGY, "t.toml").expect("valid");
        let kinds = StationKinds::of(&topology);
        let entries = load_in(&[tmp.path().to_path_buf()], None, &kinds).expect("loaded");
        assert_eq!(entries.len(), 1);
        assert_eq!(entries[0].kind, RecipeKind::Welding);
        assert_eq!(entries[0].station.as_str(), "welding2");
        // Without the topology the tree has no such directory, and a file
        // in it names no kind.
        assert!(load(&[tmp.path().to_path_buf()], None)
            .expect("loaded")
            .is_empty());
        let errors = load(&[dir.join("w.rcp")], None).expect_err("no kind");
        assert!(
            errors[0].contains("cannot tell the recipe kind"),
            "{errors:?}"
        );
    }
}
