//! The shipped recipes (`recipes/`), compiled in, as the order list's
//! recipe store: checked and verified across levels by the same
//! [`checked_set`] the operator node runs on its directory.

use falc_factory::recipe_source::{checked_set, PutError, RecipeSet, RecipeSource};
use falc_model::console::{RecipeFile, RecipeInfo, RecipeText};
use falc_model::ids::StationName;
use falc_model::mms::domain::content_hash;
use falc_model::topology::Topology;
use falc_recipe::files::{entry_in, StationKinds};
use std::path::Path;

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
];

/// The shipped recipes as a recipe store: read-only (a save is refused),
/// so the set is checked and verified once, not at every start.
#[derive(Debug, Clone)]
pub struct Shipped {
    /// The cell's topology.
    topology: Topology,
    /// The cell the set is for.
    cell: StationName,
    checked: std::cell::OnceCell<Result<RecipeSet, Vec<String>>>,
}

impl Shipped {
    /// The shipped recipes for `cell` of `topology`.
    pub fn new(topology: Topology, cell: StationName) -> Self {
        Self {
            topology,
            cell,
            checked: std::cell::OnceCell::new(),
        }
    }

    /// The cell's topology.
    pub fn topology(&self) -> &Topology {
        &self.topology
    }

    fn check(&self) -> Result<RecipeSet, Vec<String>> {
        let kinds = StationKinds::of(&self.topology);
        let mut entries = Vec::new();
        for (file, text) in SHIPPED {
            let path = Path::new("recipes").join(file);
            entries.push(entry_in(&path, None, &kinds, text.to_string()).map_err(|e| vec![e])?);
        }
        checked_set(&entries, &self.topology, &self.cell)
    }
}

impl RecipeSource for Shipped {
    fn load(&self) -> Result<RecipeSet, Vec<String>> {
        self.checked.get_or_init(|| self.check()).clone()
    }

    fn list(&self) -> Result<Vec<RecipeInfo>, String> {
        Ok(Vec::new())
    }

    fn get(&self, file: &RecipeFile) -> Result<RecipeText, String> {
        let name = format!("{}/{}", file.station(), file.file());
        SHIPPED
            .iter()
            .find(|(f, _)| *f == name)
            .map(|(_, text)| RecipeText {
                file: file.clone(),
                text: text.to_string(),
                hash: content_hash(text.as_bytes()),
            })
            .ok_or_else(|| format!("no recipe {name}"))
    }

    fn put(&self, _: &RecipeFile, _: &str, _: Option<u64>) -> Result<(), PutError> {
        Err(PutError::Refused(
            "the simulation's recipes are the shipped ones".into(),
        ))
    }
}
