//! The recipe store (the 1992 PPS): reads and checks every recipe under the
//! recipe directory as one set (the recipe checker of `falc recipe check`),
//! and turns a clean set into what is delivered to the cell: each cell
//! recipe as domain `NAME` (its file name), each workstation recipe as
//! `STATION$NAME` (its `#NAME`), which the cell passes on. A set with any
//! problem is refused whole, with every problem as `file:line: reason`;
//! so is a set the verifier finds a defect in across levels
//! ([`falc_recipe::verify`]: a wait that can only fail, a job cut short by
//! the cell's limit, a recipe that never ends).
//!
//! It also lists, shows and saves single recipe files for the consoles
//! (`falc store`, the TUI's recipe editor): a file is saved only if the
//! whole set checks clean with it, and only if nobody changed it since the
//! editor fetched it; the cell gets it at the next start.
//!
//! The files are read again at every start (the store may have changed);
//! checking and verifying them again is skipped while what was read is
//! what was last checked clean (the result is a function of the texts,
//! the transport stations' equipment files, the topology and the cell
//! alone). A transport recipe may name only the lines, places and stations
//! of its station's equipment file. Verifying took about 5 ms (debug
//! build) at every start of every cell, on the operator's one loop.

use falc_equipment::Equipment;
use falc_factory::recipe_source::{checked_set, PutError, RecipeSet, RecipeSource};
use falc_model::ids::StationName;
use falc_model::mms::domain::content_hash;
use falc_model::recipe_file::{RecipeFile, RecipeInfo, RecipeText, ROBOT_DIR};
use falc_model::topology::Topology;
use falc_recipe::check::Entry;
use falc_recipe::files::{self, StationKinds};
use falc_recipe::robot_program::RobotFile;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};

/// The recipe directory of one cell, as the order list reads it.
#[derive(Debug, Clone)]
pub struct RecipeDir {
    /// The recipe tree (`cell/`, `welding/`, `transport/`).
    pub dir: PathBuf,
    /// The cell's topology.
    pub topology: Topology,
    /// The cell the set is for.
    pub cell: StationName,
    /// The last set checked clean, with what it was checked from.
    checked: Arc<Mutex<Option<Checked>>>,
}

impl RecipeDir {
    /// Cell `cell`'s recipes under `dir`, checked against `topology`.
    pub fn new(dir: PathBuf, topology: Topology, cell: StationName) -> Self {
        Self {
            dir,
            topology,
            cell,
            checked: Arc::default(),
        }
    }
}

/// One file as read: its station, origin and text.
type Read = (StationName, String, String);

/// A set checked clean, with the files (recipes, robot programs) and
/// equipment it was checked against.
type Checked = (
    Vec<Read>,
    Option<Vec<RobotFile>>,
    BTreeMap<StationName, Arc<Equipment>>,
    RecipeSet,
);

impl RecipeSource for RecipeDir {
    /// Reads and checks the recipe tree against the topology: the cell
    /// recipes go to the cell, workstation recipes must belong to one of
    /// its workstations. Returns the set, or every problem
    /// (`file:line: reason`); the texts checked clean last time are not
    /// checked again.
    fn load(&self) -> Result<RecipeSet, Vec<String>> {
        let entries = read(&self.dir, &self.topology)?;
        let read: Vec<Read> = entries
            .iter()
            .map(|e| (e.station.clone(), e.recipe.origin.clone(), e.text.clone()))
            .collect();
        let robot = files::load_robot(&self.dir)?;
        let equipment = equipment(&self.topology)?;
        let mut checked = self.checked.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some((texts, programs, with, set)) = checked.as_ref() {
            if *texts == read && *programs == robot && *with == equipment {
                return Ok(set.clone());
            }
        }
        let set = checked_set(
            &entries,
            robot.as_deref(),
            &self.topology,
            &self.cell,
            &equipment,
        )?;
        *checked = Some((read, robot, equipment, set.clone()));
        Ok(set)
    }
    fn list(&self) -> Result<Vec<RecipeInfo>, String> {
        list(&self.dir, &self.topology, &self.cell)
    }
    fn get(&self, file: &RecipeFile) -> Result<RecipeText, String> {
        get(&self.dir, file)
    }
    fn put(&self, file: &RecipeFile, text: &str, base: Option<u64>) -> Result<(), PutError> {
        put(&self.dir, &self.topology, &self.cell, file, text, base)
    }
}

/// The equipment of the topology's transport stations, read at every
/// check like the recipes (a transport recipe may name only what its
/// station's conveyor has).
fn equipment(topology: &Topology) -> Result<BTreeMap<StationName, Arc<Equipment>>, Vec<String>> {
    Equipment::of_topology(topology).map_err(|e| vec![e])
}

/// Reads and parses every recipe file under `dir`.
fn read(dir: &Path, topology: &Topology) -> Result<Vec<Entry>, Vec<String>> {
    files::load_in(&[PathBuf::from(dir)], None, &StationKinds::of(topology))
}

/// The stations whose directory may hold recipes: the cell and its
/// workstations.
fn stations(topology: &Topology, cell: &StationName) -> Vec<StationName> {
    let mut v = vec![cell.clone()];
    v.extend(topology.subordinates_of(cell).into_iter().cloned());
    v
}

fn path_of(dir: &Path, file: &RecipeFile) -> PathBuf {
    dir.join(file.station().as_str()).join(file.file())
}

/// Every recipe file under `dir`, with its name where the text gives one;
/// the robot programs (named `program N`) first.
fn list(dir: &Path, topology: &Topology, cell: &StationName) -> Result<Vec<RecipeInfo>, String> {
    let mut out = Vec::new();
    let kinds = StationKinds::of(topology);
    let robot = StationName::new(ROBOT_DIR).map_err(|e| e.to_string())?;
    if let Ok(paths) = files::files_ending(&dir.join(ROBOT_DIR), "prg") {
        let mut files: Vec<RecipeFile> = paths
            .iter()
            .filter_map(|p| p.file_name()?.to_str())
            .filter_map(|n| RecipeFile::new(robot.clone(), n).ok())
            .collect();
        files.sort();
        out.extend(files.into_iter().map(|file| RecipeInfo {
            name: file.robot_program().map(|p| format!("program {p}")),
            file,
        }));
    }
    for station in stations(topology, cell) {
        let sub = dir.join(station.as_str());
        let Ok(read) = std::fs::read_dir(&sub) else {
            continue;
        };
        let mut names: Vec<String> = read
            .filter_map(Result::ok)
            .filter_map(|e| e.file_name().into_string().ok())
            .filter(|n| n.ends_with(".rcp"))
            .collect();
        names.sort();
        for n in names {
            let Ok(file) = RecipeFile::new(station.clone(), &n) else {
                continue;
            };
            let name = std::fs::read_to_string(path_of(dir, &file))
                .ok()
                .and_then(|text| files::entry_in(&path_of(dir, &file), None, &kinds, text).ok())
                .and_then(|e| e.name().ok())
                .map(|n| n.to_string());
            out.push(RecipeInfo { file, name });
        }
    }
    Ok(out)
}

/// One recipe file's text and content hash.
fn get(dir: &Path, file: &RecipeFile) -> Result<RecipeText, String> {
    let path = path_of(dir, file);
    match std::fs::read_to_string(&path) {
        Ok(text) => Ok(RecipeText {
            file: file.clone(),
            hash: content_hash(text.as_bytes()),
            text,
        }),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            Err(format!("there is no recipe {file} in the recipe store"))
        }
        Err(e) => Err(format!("cannot read recipe {file}: {e}")),
    }
}

/// Saves `text` as `file` if the whole set under `dir` checks clean with
/// it and the file is still what the editor started from (`base`: its
/// content hash; None for a new file). Written to a temporary file, synced
/// and renamed: the store never holds half a recipe.
fn put(
    dir: &Path,
    topology: &Topology,
    cell: &StationName,
    file: &RecipeFile,
    text: &str,
    base: Option<u64>,
) -> Result<(), PutError> {
    let is_program = file.robot_program().is_some();
    if !is_program && !stations(topology, cell).contains(file.station()) {
        return Err(PutError::Refused(format!(
            "{} is neither the cell nor one of its workstations in the topology",
            file.station()
        )));
    }
    let path = path_of(dir, file);
    let now = match std::fs::read(&path) {
        Ok(b) => Some(content_hash(&b)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => return Err(PutError::Refused(format!("cannot read recipe {file}: {e}"))),
    };
    if now != base {
        return Err(PutError::Refused(match (base, now) {
            (None, Some(_)) => format!("recipe {file} exists already: edit it instead"),
            (Some(_), None) => format!("recipe {file} was removed meanwhile"),
            _ => format!(
                "recipe {file} was changed by someone else since you opened it: open it again"
            ),
        }));
    }
    let kinds = StationKinds::of(topology);
    let mut entries =
        files::load_in(&[PathBuf::from(dir)], None, &kinds).map_err(PutError::Findings)?;
    let mut robot = files::load_robot(dir).map_err(PutError::Findings)?;
    let origin = path.display().to_string();
    if is_program {
        let saved = RobotFile::read(&origin, file.file(), text).map_err(PutError::Findings)?;
        let robot = robot.get_or_insert_with(Vec::new);
        robot.retain(|r| r.file != *file);
        robot.push(saved);
    } else {
        entries.retain(|e| e.recipe.origin != origin);
        entries.push(
            files::entry_in(&path, None, &kinds, text.to_string()).map_err(PutError::Refused)?,
        );
    }
    let equipment = equipment(topology).map_err(PutError::Findings)?;
    checked_set(&entries, robot.as_deref(), topology, cell, &equipment)
        .map_err(PutError::Findings)?;
    write_atomically(&path, text.as_bytes())
        .map_err(|e| PutError::Refused(format!("cannot save recipe {file}: {e}")))
}

fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    let tmp = path.with_extension(format!("{ext}.saving"));
    let mut f = std::fs::File::create(&tmp)?;
    f.write_all(bytes)?;
    f.sync_all()?;
    std::fs::rename(&tmp, path)?;
    std::fs::File::open(dir)?.sync_all()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn topology() -> Topology {
        Topology::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("launch/cell.toml"))
            .expect("shipped topology")
    }

    #[test]
    fn the_shipped_recipes_make_one_set_workstations_first() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("recipes");
        let cell = StationName::new("cell").expect("valid");
        let set = RecipeDir::new(dir, topology(), cell).load().expect("clean");
        // 13 recipes and 4 robot programs for the one welding station.
        assert_eq!(set.deliveries.len(), 13 + 4);
        assert_eq!(set.deliveries[0].domain.as_str(), "WELDING$PROGRAM_010");
        let names: Vec<&str> = set.cell_recipes().iter().map(|n| n.as_str()).collect();
        assert_eq!(names.len(), 3, "{names:?}");
        assert!(set
            .deliveries
            .iter()
            .any(|d| d.domain.as_str() == "WELDING$DROOG_DIK"));
        let first_cell = set.deliveries.iter().position(|d| d.is_cell);
        assert_eq!(first_cell, Some(14));
        let dik = set.get("WELDING$DROOG_DIK").expect("DROOG_DIK");
        assert_eq!(dik.starts, ["WELDING$PROGRAM_065"]);
        let programs: Vec<String> = set.programs.iter().map(|r| r.file.to_string()).collect();
        assert_eq!(
            programs,
            [
                "robot/010.prg",
                "robot/064.prg",
                "robot/065.prg",
                "robot/066.prg"
            ]
        );
    }

    /// Robot programs are listed, fetched and saved like recipes: a save
    /// is checked as a program and with the whole set; a recipe may start
    /// only a program the store holds.
    #[test]
    fn robot_programs_are_kept_like_recipes_and_recipes_start_only_those_held() {
        let tmp = shipped_copy();
        let (t, cell) = (topology(), StationName::new("cell").expect("valid"));
        let robot = StationName::new(ROBOT_DIR).expect("valid");
        let p65 = RecipeFile::new(robot.clone(), "65").expect("valid");
        let listed = list(tmp.path(), &t, &cell).expect("list");
        assert!(listed
            .iter()
            .any(|r| r.file == p65 && r.name.as_deref() == Some("program 65")));
        let got = get(tmp.path(), &p65).expect("get");
        // A step the DNC line cannot carry, and another program's number:
        // refused with file and line, the file unchanged.
        let bad = got.text.replace("weld seam_1 45", "weld seam_1 forty");
        match put(tmp.path(), &t, &cell, &p65, &bad, Some(got.hash)) {
            Err(PutError::Findings(f)) => assert!(
                f.iter()
                    .any(|l| l.contains("065.prg:4:") && l.contains("`forty` is not a time")),
                "{f:?}"
            ),
            other => panic!("{other:?}"),
        }
        let other = got.text.replace("program 65", "program 66");
        match put(tmp.path(), &t, &cell, &p65, &other, Some(got.hash)) {
            Err(PutError::Findings(f)) => {
                assert!(f[0].contains("065.prg:1: the text is program 66"), "{f:?}")
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(get(tmp.path(), &p65).expect("get").text, got.text);
        let edited = got.text.replace("weld seam_1 45", "weld seam_1 50");
        put(tmp.path(), &t, &cell, &p65, &edited, Some(got.hash)).expect("saved");
        assert_eq!(get(tmp.path(), &p65).expect("get").text, edited);
        // A welding recipe that starts a program the store lacks is
        // refused; once the program is saved, it is taken.
        let ws =
            RecipeFile::new(StationName::new("welding").expect("v"), "droog_dik.rcp").expect("v");
        let recipe = get(tmp.path(), &ws).expect("get");
        let rcm67 = recipe.text.replace("start rcm 65", "start rcm 67");
        match put(tmp.path(), &t, &cell, &ws, &rcm67, Some(recipe.hash)) {
            Err(PutError::Findings(f)) => assert!(
                f.iter().any(|l| l.contains(
                    "droog_dik.rcp:8: state 1: the recipe store has no \
                                 robot program 67 (robot/067.prg)"
                )),
                "{f:?}"
            ),
            other => panic!("{other:?}"),
        }
        let p67 = RecipeFile::new(robot, "067.prg").expect("valid");
        put(
            tmp.path(),
            &t,
            &cell,
            &p67,
            &edited.replace("program 65", "program 67"),
            None,
        )
        .expect("a new program");
        put(tmp.path(), &t, &cell, &ws, &rcm67, Some(recipe.hash)).expect("now it is held");
        // A recipe may not take a robot program's domain name.
        let new = RecipeFile::new(StationName::new("welding").expect("v"), "p65").expect("v");
        let named = rcm67.replacen("#DROOG_DIK", "#PROGRAM_065", 1);
        match put(tmp.path(), &t, &cell, &new, &named, None) {
            Err(PutError::Findings(f)) => assert!(
                f.iter()
                    .any(|l| l.contains("p65.rcp:1: the name PROGRAM_065 is kept for a robot")),
                "{f:?}"
            ),
            other => panic!("{other:?}"),
        }
        let set = RecipeDir::new(tmp.path().to_path_buf(), t.clone(), cell.clone())
            .load()
            .expect("clean");
        assert_eq!(set.programs.len(), 5);
        // A store without a robot directory runs the robot's own programs.
        std::fs::remove_dir_all(tmp.path().join(ROBOT_DIR)).expect("rm");
        let set = RecipeDir::new(tmp.path().to_path_buf(), t, cell)
            .load()
            .expect("clean");
        assert!(set.programs.is_empty());
    }

    /// A copy of the shipped recipe tree.
    fn shipped_copy() -> tempfile::TempDir {
        let tmp = tempfile::tempdir().expect("tempdir");
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("recipes");
        for sub in ["cell", "welding", "transport", "robot"] {
            std::fs::create_dir_all(tmp.path().join(sub)).expect("mkdir");
            for f in std::fs::read_dir(src.join(sub)).expect("dir") {
                let f = f.expect("entry").path();
                std::fs::copy(&f, tmp.path().join(sub).join(f.file_name().expect("name")))
                    .expect("copy");
            }
        }
        tmp
    }

    #[test]
    fn put_saves_only_a_clean_set_and_only_over_what_was_fetched() {
        let tmp = shipped_copy();
        let (t, cell) = (topology(), StationName::new("cell").expect("valid"));
        let ws = |f: &str| RecipeFile::new(StationName::new("transport").expect("v"), f);
        let store = ws("store.rcp").expect("valid");
        let listed = list(tmp.path(), &t, &cell).expect("list");
        assert_eq!(listed.len(), 13 + 4, "13 recipes and 4 robot programs");
        assert!(listed
            .iter()
            .any(|r| r.file == store && r.name.as_deref() == Some("STORE")));
        let got = get(tmp.path(), &store).expect("get");
        // A defect: refused with the finding, the file unchanged.
        let bad = got.text.replace("waitplace", "waitplase");
        match put(tmp.path(), &t, &cell, &store, &bad, Some(got.hash)) {
            Err(PutError::Findings(f)) => {
                assert!(
                    f.iter()
                        .any(|l| l.contains("store.rcp:") && l.contains("waitplase")),
                    "{f:?}"
                )
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(get(tmp.path(), &store).expect("get").text, got.text);
        // A clean edit is saved.
        let edited = format!("{}\nA comment line added.\n", got.text.trim_end());
        put(tmp.path(), &t, &cell, &store, &edited, Some(got.hash)).expect("saved");
        assert_eq!(get(tmp.path(), &store).expect("get").text, edited);
        // A second editor that started from the old text is refused.
        match put(tmp.path(), &t, &cell, &store, &got.text, Some(got.hash)) {
            Err(PutError::Refused(why)) => {
                assert!(why.contains("changed by someone else"), "{why}")
            }
            other => panic!("{other:?}"),
        }
        // A new file must not exist yet; a station outside the cell is refused.
        assert!(matches!(
            put(tmp.path(), &t, &cell, &store, &edited, None),
            Err(PutError::Refused(_))
        ));
        let elsewhere = RecipeFile::new(StationName::new("operator").expect("v"), "x").expect("v");
        assert!(matches!(
            put(tmp.path(), &t, &cell, &elsewhere, &edited, None),
            Err(PutError::Refused(_))
        ));
        assert!(get(tmp.path(), &ws("nothing").expect("v")).is_err());
    }

    #[test]
    fn a_save_with_a_defect_across_levels_is_refused() {
        // Each recipe checks clean alone; together the cell gives up on
        // MOVE_TO_MAN before its own limits can end it.
        let tmp = shipped_copy();
        let (t, cell) = (topology(), StationName::new("cell").expect("valid"));
        let file = RecipeFile::new(cell.clone(), "dikdroog.rcp").expect("valid");
        let got = get(tmp.path(), &file).expect("get");
        let bad = got
            .text
            .replace("-12 | wait transport 90 ", "-12 | wait transport 45 ");
        assert_ne!(bad, got.text);
        match put(tmp.path(), &t, &cell, &file, &bad, Some(got.hash)) {
            Err(PutError::Findings(f)) => assert!(
                f.iter().any(|l| l.contains("dikdroog.rcp:")
                    && l.contains("state 12: time limits disagree")
                    && l.contains("falc recipe verify")),
                "{f:?}"
            ),
            other => panic!("{other:?}"),
        }
        assert_eq!(get(tmp.path(), &file).expect("get").text, got.text);
    }

    #[test]
    fn a_defect_refuses_the_whole_set_with_file_and_line() {
        let tmp = shipped_copy();
        let bad = tmp.path().join("transport/store.rcp");
        let text = std::fs::read_to_string(&bad).expect("read");
        std::fs::write(&bad, text.replace("waitplace", "waitplase")).expect("write");
        let cell = StationName::new("cell").expect("valid");
        let source = RecipeDir::new(tmp.path().to_path_buf(), topology(), cell);
        let errors = source.load().expect_err("refused");
        assert!(
            errors
                .iter()
                .any(|e| e.contains("store.rcp:") && e.contains("waitplase")),
            "{errors:?}"
        );
    }

    /// A set checked clean is not checked again while the store holds the
    /// same texts, but a file changed since is: a defect it brings is
    /// refused at the next load, and the set is clean again once mended.
    #[test]
    fn a_changed_store_is_checked_again() {
        let tmp = shipped_copy();
        let cell = StationName::new("cell").expect("valid");
        let source = RecipeDir::new(tmp.path().to_path_buf(), topology(), cell);
        let first = source.load().expect("clean");
        let again = source.load().expect("still clean");
        assert_eq!(first.deliveries.len(), again.deliveries.len());
        let file = tmp.path().join("transport/store.rcp");
        let text = std::fs::read_to_string(&file).expect("read");
        std::fs::write(&file, text.replace("waitplace", "waitplase")).expect("write");
        let errors = source.load().expect_err("the changed file is checked");
        assert!(errors.iter().any(|e| e.contains("waitplase")), "{errors:?}");
        std::fs::write(&file, &text).expect("write");
        let mended = source.load().expect("clean again");
        let contents = |s: &RecipeSet| -> Vec<Vec<u8>> {
            s.deliveries.iter().map(|d| d.content.clone()).collect()
        };
        assert_eq!(contents(&mended), contents(&first));
    }
}
