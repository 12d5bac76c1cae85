//! The recipe store (the 1992 PPS): reads and checks every recipe under the
//! recipe directory as one set (the recipe checker of `falc recipe check`),
//! and turns a clean set into what is delivered to the cell: each cell
//! recipe as domain `NAME` (its file name), each workstation recipe as
//! `STATION$NAME` (its `#NAME`), which the cell passes on. A set with any
//! problem is refused whole, with every problem as `file:line: reason`.

use falc_common::ids::{ObjectName, StationName};
use falc_common::recipe::check::check_set;
use falc_common::recipe::commands::RecipeKind;
use falc_common::recipe::files;
use falc_common::topology::Topology;
use std::path::{Path, PathBuf};

/// One recipe as delivered to the cell.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Delivery {
    /// The domain name at the cell (`DIKDROOG`, `WELDING$DROOG_DIK`).
    pub domain: ObjectName,
    /// Whether it is a cell recipe (startable as an order).
    pub is_cell: bool,
    /// The recipe text.
    pub content: Vec<u8>,
}

/// A checked recipe set, workstation recipes first (the cell needs them
/// before a cell recipe that starts them).
#[derive(Debug, Clone, Default)]
pub struct RecipeSet {
    /// Every recipe, in delivery order.
    pub deliveries: Vec<Delivery>,
}

impl RecipeSet {
    /// The cell recipes' names (what an order may name).
    pub fn cell_recipes(&self) -> Vec<&ObjectName> {
        self.deliveries
            .iter()
            .filter(|d| d.is_cell)
            .map(|d| &d.domain)
            .collect()
    }
}

/// Reads and checks the recipe tree `dir` against `topology`: the cell
/// recipes go to `cell`, workstation recipes must belong to one of its
/// workstations. Returns the set, or every problem (`file:line: reason`).
pub fn load(dir: &Path, topology: &Topology, cell: &StationName) -> Result<RecipeSet, Vec<String>> {
    let entries = files::load(&[PathBuf::from(dir)], None)?;
    let (programs, problems) = check_set(&entries);
    let mut errors: Vec<String> = problems.iter().map(ToString::to_string).collect();
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
        if program.kind == RecipeKind::Cell {
            cells.push(Delivery {
                domain: name,
                is_cell: true,
                content,
            });
        } else if !workstations.contains(&station) {
            errors.push(format!(
                "{origin}:1: station {station} is not a workstation of {cell} in the topology"
            ));
        } else {
            let domain = format!("{}${name}", station.as_str().to_uppercase());
            match ObjectName::new(&domain) {
                Ok(domain) => stations.push(Delivery {
                    domain,
                    is_cell: false,
                    content,
                }),
                Err(e) => errors.push(format!("{origin}:1: {e}")),
            }
        }
    }
    if !errors.is_empty() {
        return Err(errors);
    }
    stations.extend(cells);
    Ok(RecipeSet {
        deliveries: stations,
    })
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
        let set = load(&dir, &topology(), &cell).expect("clean");
        assert_eq!(set.deliveries.len(), 11);
        let names: Vec<&str> = set.cell_recipes().iter().map(|n| n.as_str()).collect();
        assert_eq!(names.len(), 3, "{names:?}");
        assert!(set
            .deliveries
            .iter()
            .any(|d| d.domain.as_str() == "WELDING$DROOG_DIK"));
        let first_cell = set.deliveries.iter().position(|d| d.is_cell);
        assert_eq!(first_cell, Some(8));
    }

    #[test]
    fn a_defect_refuses_the_whole_set_with_file_and_line() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("recipes");
        for sub in ["cell", "welding", "transport"] {
            std::fs::create_dir_all(tmp.path().join(sub)).expect("mkdir");
            for f in std::fs::read_dir(src.join(sub)).expect("dir") {
                let f = f.expect("entry").path();
                std::fs::copy(&f, tmp.path().join(sub).join(f.file_name().expect("name")))
                    .expect("copy");
            }
        }
        let bad = tmp.path().join("transport/store.rcp");
        let text = std::fs::read_to_string(&bad).expect("read");
        std::fs::write(&bad, text.replace("waitplace", "waitplase")).expect("write");
        let cell = StationName::new("cell").expect("valid");
        let errors = load(tmp.path(), &topology(), &cell).expect_err("refused");
        assert!(
            errors
                .iter()
                .any(|e| e.contains("store.rcp:") && e.contains("waitplase")),
            "{errors:?}"
        );
    }
}
