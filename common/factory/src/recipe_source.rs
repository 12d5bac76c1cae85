//! The recipe store as the [`order_list`](crate::order_list) core sees it: a
//! checked recipe set to deliver to the cell, and single recipe files for
//! the consoles. The operator node's recipe directory implements
//! [`RecipeSource`] (`nodes/operator/recipe_store.rs`).

use falc_equipment::vocabulary::lacking_in;
use falc_equipment::Equipment;
use falc_model::ids::{ObjectName, RobotProgram, StationName};
use falc_model::recipe_file::{RecipeFile, RecipeInfo, RecipeText};
use falc_model::topology::{StationKind, Topology};
use falc_recipe::check::{check_set, Command, Entry, Job, Program};
use falc_recipe::commands::RecipeKind;
use falc_recipe::robot_program::{self, RobotFile};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::sync::Arc;

/// One recipe as delivered to the cell.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Delivery {
    /// The domain name at the cell (`DIKDROOG`, `WELDING$DROOG_DIK`).
    pub domain: ObjectName,
    /// Whether it is a cell recipe (startable as an order).
    pub is_cell: bool,
    /// The recipe text.
    pub content: Vec<u8>,
    /// The file it was read from (its versions are kept by file).
    pub file: RecipeFile,
    /// What it starts one level down: the domains of the workstation
    /// recipes a cell recipe starts (`WELDING$DROOG_DIK`), the robot
    /// programs of a welding recipe (`program 12`).
    pub starts: Vec<String>,
}

/// A checked recipe set, workstation recipes first (the cell needs them
/// before a cell recipe that starts them).
#[derive(Debug, Clone, Default)]
pub struct RecipeSet {
    /// Every recipe, in delivery order.
    pub deliveries: Vec<Delivery>,
    /// The store's robot programs (none when it keeps none: the robot
    /// controller's own programs run).
    pub programs: Vec<RobotFile>,
}

impl RecipeSet {
    /// The delivery named `domain`.
    pub fn get(&self, domain: &str) -> Option<&Delivery> {
        self.deliveries.iter().find(|d| d.domain.as_str() == domain)
    }

    /// The cell recipes' names (what an order may name).
    pub fn cell_recipes(&self) -> Vec<&ObjectName> {
        self.deliveries
            .iter()
            .filter(|d| d.is_cell)
            .map(|d| &d.domain)
            .collect()
    }
}

/// Why a recipe was not saved.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PutError {
    /// The set does not check clean with it: every finding.
    Findings(Vec<String>),
    /// Anything else (a changed file, an unknown station, the disk).
    Refused(String),
}

/// Where recipes come from.
pub trait RecipeSource {
    /// Reads and checks the whole set; every problem (`file:line: reason`)
    /// if it is not clean.
    fn load(&self) -> Result<RecipeSet, Vec<String>>;
    /// Every recipe file, with its name where the text gives one.
    fn list(&self) -> Result<Vec<RecipeInfo>, String>;
    /// One recipe file's text and content hash.
    fn get(&self, file: &RecipeFile) -> Result<RecipeText, String>;
    /// Saves `text` as `file` if the set checks clean with it and the file
    /// is still what the editor started from (`base`, its content hash).
    fn put(&self, file: &RecipeFile, text: &str, base: Option<u64>) -> Result<(), PutError>;
}

/// Checks a whole set of read recipes against `topology`: the cell
/// recipes go to `cell`, workstation recipes must belong to one of its
/// workstations, a transport recipe may name only what its station's
/// equipment has (`equipment`, by station: [`Equipment::of_topology`]),
/// and the set must verify across levels. Where the store keeps robot
/// programs (`robot`: its `robot/` directory, read), every `start rcm N`
/// must name one of them. Returns the set (workstation recipes first), or
/// every problem (`file:line: reason`).
pub fn checked_set(
    entries: &[Entry],
    robot: Option<&[RobotFile]>,
    topology: &Topology,
    cell: &StationName,
    equipment: &BTreeMap<StationName, Arc<Equipment>>,
) -> Result<RecipeSet, Vec<String>> {
    let (programs, problems) = check_set(entries);
    let mut errors: Vec<String> = problems.iter().map(ToString::to_string).collect();
    errors.extend(
        lacking_in(equipment, &programs)
            .iter()
            .map(ToString::to_string),
    );
    if let Some(robot) = robot {
        let held: BTreeSet<RobotProgram> = robot.iter().map(|r| r.program.number).collect();
        errors.extend(
            robot_program::lacking(&programs, &held)
                .iter()
                .map(ToString::to_string),
        );
    }
    let workstations = topology.subordinates_of(cell);
    let mut cells = Vec::new();
    let mut stations = Vec::new();
    for (station, program) in &programs {
        // The text that was checked, not the file read again.
        let Some(entry) = entries.iter().find(|e| e.recipe.origin == program.origin) else {
            continue;
        };
        let origin = &program.origin;
        let name = match entry.name() {
            Ok(n) => n,
            Err(e) => {
                errors.push(e);
                continue;
            }
        };
        let content = entry.text.clone().into_bytes();
        let file = match file_of(origin) {
            Ok(f) => f,
            Err(e) => {
                errors.push(format!("{origin}:1: {e}"));
                continue;
            }
        };
        let starts = starts_of(station, program, robot.is_some());
        if program.kind == RecipeKind::Cell {
            cells.push(Delivery {
                domain: name,
                is_cell: true,
                content,
                file,
                starts,
            });
        } else if !workstations.contains(&station) {
            errors.push(format!(
                "{origin}:1: station {station} is not a workstation of {cell} in the topology"
            ));
        } else if RobotProgram::of_domain(&name).is_some() {
            errors.push(format!(
                "{origin}:1: the name {name} is kept for a robot program's domain: name the \
                 recipe otherwise"
            ));
        } else {
            match ObjectName::new(&at_cell(station, name.as_str())) {
                Ok(domain) => stations.push(Delivery {
                    domain,
                    is_cell: false,
                    content,
                    file,
                    starts,
                }),
                Err(e) => errors.push(format!("{origin}:1: {e}")),
            }
        }
    }
    if !errors.is_empty() {
        return Err(errors);
    }
    // Across levels: a defect refuses the set like a checker problem;
    // notes are allowed (`falc recipe verify` prints them with traces).
    let report = falc_recipe::verify::verify(&programs);
    let defects: Vec<String> = report
        .defects()
        .map(|f| format!("{f} (`falc recipe verify` shows the trace)"))
        .collect();
    tracing::info!(
        states = report.states,
        defects = defects.len(),
        notes = report.findings.len() - defects.len(),
        "recipes verified across levels"
    );
    for b in &report.bounded {
        tracing::warn!("{b}");
    }
    if !defects.is_empty() {
        return Err(defects);
    }
    // Each welding workstation gets every robot program, before the
    // recipes that start them.
    let mut deliveries = Vec::new();
    for w in &workstations {
        if topology.station(w).map(|s| s.kind) != Some(StationKind::Welding) {
            continue;
        }
        for r in robot.unwrap_or_default() {
            match ObjectName::new(&at_cell(w, r.program.number.domain().as_str())) {
                Ok(domain) => deliveries.push(Delivery {
                    domain,
                    is_cell: false,
                    content: r.program.text.clone().into_bytes(),
                    file: r.file.clone(),
                    starts: Vec::new(),
                }),
                Err(e) => return Err(vec![format!("{}:1: {e}", r.origin)]),
            }
        }
    }
    deliveries.extend(stations);
    deliveries.extend(cells);
    Ok(RecipeSet {
        deliveries,
        programs: robot.map(<[RobotFile]>::to_vec).unwrap_or_default(),
    })
}

/// The store's name of the recipe file at `origin` (`…/welding/droog_dik.rcp`
/// is `welding/droog_dik.rcp`).
fn file_of(origin: &str) -> Result<RecipeFile, String> {
    let path = Path::new(origin);
    let part = |p: Option<&std::ffi::OsStr>| p.and_then(|s| s.to_str()).map(str::to_string);
    let station = part(path.parent().and_then(Path::file_name));
    let name = part(path.file_name());
    let (Some(station), Some(name)) = (station, name) else {
        return Err("a recipe file must lie in its station's directory".into());
    };
    RecipeFile::new(
        StationName::new(&station).map_err(|e| e.to_string())?,
        &name,
    )
}

/// The cell's domain name of workstation `station`'s domain `name`
/// (`WELDING$DROOG_DIK`), which the cell passes on to it.
fn at_cell(station: &StationName, name: &str) -> String {
    format!("{}${name}", station.as_str().to_uppercase())
}

/// What `program` (of `station`) starts one level down: each workstation
/// recipe's domain (`WELDING$DROOG_DIK`), each robot program, once, in the
/// order of its states: its domain as the cell holds it
/// (`WELDING$PROGRAM_012`) when the store delivers the programs
/// (`delivered`), else `program 12` (the robot's own).
fn starts_of(station: &StationName, program: &Program, delivered: bool) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for state in program.states.values() {
        let Command::Start { target, job, .. } = &state.command else {
            continue;
        };
        let s = match job {
            Job::Recipe(name) => at_cell(target, name.as_str()),
            Job::Program(p) if delivered => at_cell(station, p.domain().as_str()),
            Job::Program(p) => format!("program {}", p.number()),
        };
        if !out.contains(&s) {
            out.push(s);
        }
    }
    out
}

/// A recipe store in memory, for unit tests of the cores: the cell recipe
/// DIKDROOG with its welding recipe; `broken` makes the set fail its check.
#[cfg(test)]
pub(crate) mod fake {
    use super::*;

    /// `broken` makes the set fail its check; a text put replaces the
    /// content of the delivery of its file (a text saying `defect` has a
    /// finding).
    #[derive(Default)]
    pub(crate) struct Source {
        pub(crate) broken: bool,
        pub(crate) saved: std::cell::RefCell<Vec<(RecipeFile, String)>>,
    }

    /// The set the fake delivers.
    pub(crate) fn set() -> RecipeSet {
        let d = |domain: &str, is_cell| Delivery {
            domain: ObjectName::new(domain).unwrap_or_else(|e| panic!("{e}")),
            is_cell,
            content: domain.as_bytes().to_vec(),
            file: RecipeFile::new(
                falc_model::ids::StationName::new(if is_cell { "cell" } else { "welding" })
                    .unwrap_or_else(|e| panic!("{e}")),
                &domain.to_lowercase().replace("welding$", ""),
            )
            .unwrap_or_else(|e| panic!("{e}")),
            starts: if is_cell {
                vec!["WELDING$DROOG_DIK".into()]
            } else {
                vec!["program 1".into()]
            },
        };
        RecipeSet {
            deliveries: vec![d("WELDING$DROOG_DIK", false), d("DIKDROOG", true)],
            programs: Vec::new(),
        }
    }

    impl RecipeSource for Source {
        fn load(&self) -> Result<RecipeSet, Vec<String>> {
            if self.broken {
                return Err(vec!["cell/dikdroog.rcp:3: unknown state 9".into()]);
            }
            let mut set = set();
            for d in &mut set.deliveries {
                if let Some((_, text)) =
                    self.saved.borrow().iter().rev().find(|(f, _)| *f == d.file)
                {
                    d.content = text.clone().into_bytes();
                }
            }
            Ok(set)
        }
        fn list(&self) -> Result<Vec<RecipeInfo>, String> {
            Ok(Vec::new())
        }
        fn get(&self, file: &RecipeFile) -> Result<RecipeText, String> {
            let set = self.load().map_err(|e| e.join("\n"))?;
            let d = set
                .deliveries
                .iter()
                .find(|d| &d.file == file)
                .ok_or_else(|| format!("no {file}"))?;
            let text = String::from_utf8_lossy(&d.content).into_owned();
            Ok(RecipeText {
                file: file.clone(),
                hash: falc_model::mms::domain::content_hash(text.as_bytes()),
                text,
            })
        }
        fn put(&self, file: &RecipeFile, text: &str, base: Option<u64>) -> Result<(), PutError> {
            let now = self.get(file).ok().map(|t| t.hash);
            if now != base {
                return Err(PutError::Refused(format!("{file} changed meanwhile")));
            }
            if text.contains("defect") {
                return Err(PutError::Findings(vec![format!("{file}:1: defect")]));
            }
            self.saved
                .borrow_mut()
                .push((file.clone(), text.to_string()));
            Ok(())
        }
    }
}
