//! The recipes a simulated operator runs, as the order list's recipe
//! store: the shipped ones (`recipes/`, compiled in), or a recipe tree
//! read once at the start (`falc-sim --recipes DIR`, for a topology of
//! other stations); checked and verified across levels by the same
//! [`checked_set`] the operator node runs on its directory.

use falc_equipment::Equipment;
use falc_factory::recipe_source::{checked_set, PutError, RecipeSet, RecipeSource};
use falc_model::ids::StationName;
use falc_model::mms::domain::content_hash;
use falc_model::recipe_file::{RecipeFile, RecipeInfo, RecipeText, ROBOT_DIR};
use falc_model::topology::Topology;
use falc_recipe::files::{entry_in, files_ending, StationKinds};
use falc_recipe::robot_program::RobotFile;
use std::path::{Path, PathBuf};
use std::rc::Rc;

/// Every shipped recipe: (file under `recipes/`, text).
pub const SHIPPED: &[(&str, &str)] = &[
    (
        "welding/droog_dik.rcp",
        include_str!("../../../recipes/welding/droog_dik.rcp"),
    ),
    (
        "welding/droog_dun.rcp",
        include_str!("../../../recipes/welding/droog_dun.rcp"),
    ),
    (
        "welding/droog_pijp.rcp",
        include_str!("../../../recipes/welding/droog_pijp.rcp"),
    ),
    (
        "transport/home.rcp",
        include_str!("../../../recipes/transport/home.rcp"),
    ),
    (
        "transport/move_to_man.rcp",
        include_str!("../../../recipes/transport/move_to_man.rcp"),
    ),
    (
        "transport/store.rcp",
        include_str!("../../../recipes/transport/store.rcp"),
    ),
    (
        "transport/unload.rcp",
        include_str!("../../../recipes/transport/unload.rcp"),
    ),
    (
        "transport/unload_and_load.rcp",
        include_str!("../../../recipes/transport/unload_and_load.rcp"),
    ),
    (
        "transport/unstore.rcp",
        include_str!("../../../recipes/transport/unstore.rcp"),
    ),
    (
        "cell/dikdroog.rcp",
        include_str!("../../../recipes/cell/dikdroog.rcp"),
    ),
    (
        "cell/dundroog.rcp",
        include_str!("../../../recipes/cell/dundroog.rcp"),
    ),
    (
        "cell/pipdroog.rcp",
        include_str!("../../../recipes/cell/pipdroog.rcp"),
    ),
    (
        "robot/010.prg",
        include_str!("../../../recipes/robot/010.prg"),
    ),
    (
        "robot/064.prg",
        include_str!("../../../recipes/robot/064.prg"),
    ),
    (
        "robot/065.prg",
        include_str!("../../../recipes/robot/065.prg"),
    ),
    (
        "robot/066.prg",
        include_str!("../../../recipes/robot/066.prg"),
    ),
];

/// The recipes as a recipe store: read-only (a save is refused), so the
/// set is checked and verified once, not at every start.
#[derive(Debug, Clone)]
pub struct Recipes {
    /// The cell's topology.
    topology: Topology,
    /// The cell the set is for.
    cell: StationName,
    /// Where the files are (`recipes` for the shipped ones), named in
    /// every problem found.
    root: PathBuf,
    /// Each file under the root (`welding/droog_dik.rcp`, `robot/065.prg`)
    /// and its text.
    texts: Rc<Vec<(String, String)>>,
    /// Whether the tree has a robot directory (its programs are the
    /// only ones recipes may start).
    robot_dir: bool,
    checked: std::cell::OnceCell<Result<RecipeSet, Vec<String>>>,
}

impl Recipes {
    /// The shipped recipes for `cell` of `topology`.
    pub fn new(topology: Topology, cell: StationName) -> Self {
        let texts = SHIPPED
            .iter()
            .map(|(f, t)| (f.to_string(), t.to_string()))
            .collect();
        Self {
            topology,
            cell,
            root: PathBuf::from("recipes"),
            texts: Rc::new(texts),
            robot_dir: true,
            checked: std::cell::OnceCell::new(),
        }
    }

    /// The recipe tree `dir` for `cell` of `topology`: the `.rcp` files in
    /// the directory of the cell and of each of its workstations, and the
    /// `.prg` files of its `robot/` directory, read now (checked when
    /// loaded). A directory that cannot be read is refused, naming it; a
    /// station without one has no recipes.
    pub fn read(dir: &Path, topology: Topology, cell: StationName) -> Result<Self, String> {
        let mut dirs: Vec<(String, &str)> = vec![(cell.to_string(), "rcp")];
        dirs.extend(
            topology
                .subordinates_of(&cell)
                .into_iter()
                .map(|s| (s.to_string(), "rcp")),
        );
        dirs.push((ROBOT_DIR.to_string(), "prg"));
        let mut texts = Vec::new();
        for (station, ext) in dirs {
            let sub = dir.join(&station);
            if !sub.is_dir() {
                continue;
            }
            for path in files_ending(&sub, ext)? {
                let text = std::fs::read_to_string(&path)
                    .map_err(|e| format!("{}: {e}", path.display()))?;
                let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
                    return Err(format!("{}: not a UTF-8 file name", path.display()));
                };
                texts.push((format!("{station}/{name}"), text));
            }
        }
        Ok(Self {
            topology,
            cell,
            root: dir.to_path_buf(),
            texts: Rc::new(texts),
            robot_dir: dir.join(ROBOT_DIR).is_dir(),
            checked: std::cell::OnceCell::new(),
        })
    }

    /// The cell's topology.
    pub fn topology(&self) -> &Topology {
        &self.topology
    }

    fn check(&self) -> Result<RecipeSet, Vec<String>> {
        let kinds = StationKinds::of(&self.topology);
        let mut entries = Vec::new();
        let mut robot = Vec::new();
        for (file, text) in self.texts.iter() {
            let path = self.root.join(file);
            match file
                .strip_prefix(ROBOT_DIR)
                .and_then(|f| f.strip_prefix('/'))
            {
                Some(name) => robot.push(RobotFile::read(&path.display().to_string(), name, text)?),
                None => {
                    entries.push(entry_in(&path, None, &kinds, text.clone()).map_err(|e| vec![e])?)
                }
            }
        }
        let equipment = Equipment::of_topology(&self.topology).map_err(|e| vec![e])?;
        let robot = self.robot_dir.then_some(robot.as_slice());
        checked_set(&entries, robot, &self.topology, &self.cell, &equipment)
    }
}

impl RecipeSource for Recipes {
    fn load(&self) -> Result<RecipeSet, Vec<String>> {
        self.checked.get_or_init(|| self.check()).clone()
    }

    fn list(&self) -> Result<Vec<RecipeInfo>, String> {
        Ok(Vec::new())
    }

    fn get(&self, file: &RecipeFile) -> Result<RecipeText, String> {
        let name = format!("{}/{}", file.station(), file.file());
        self.texts
            .iter()
            .find(|(f, _)| *f == name)
            .map(|(_, text)| RecipeText {
                file: file.clone(),
                text: text.clone(),
                hash: content_hash(text.as_bytes()),
            })
            .ok_or_else(|| format!("no recipe {name}"))
    }

    fn put(&self, _: &RecipeFile, _: &str, _: Option<u64>) -> Result<(), PutError> {
        Err(PutError::Refused(
            "the simulation's recipes are read once, at its start".into(),
        ))
    }
}
