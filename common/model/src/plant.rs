//! The plant topology, `launch/factory.toml`: one factory controller (the
//! operator node) above several cells, each cell with its own router on
//! its own network, the cell routers joined to the factory router.
//!
//! One file says it all, as `launch/cell.toml` does for one cell: the
//! plant's name (the key chunk of the operator API), the factory router,
//! the operator, the console users and every cell with its router and its
//! stations. Each cell's [`Topology`] is derived from it (the operator as
//! its root, then the cell's stations), so everything the cell-level code
//! derives from a topology (keys, the cell router's rules, credentials)
//! follows unchanged; [`Plant::factory`] is the topology of the factory
//! level (the operator and the consoles, under the plant's name).
//!
//! A single `launch/cell.toml` stays what it is: a plant of one, with no
//! factory router.

use crate::ids::{CellId, StationName};
use crate::topology::{
    default_lease_ms, from_toml, read, Console, RawTopology, Station, StationKind, Topology,
    TopologyError,
};
use serde::Deserialize;
use std::collections::BTreeSet;
use std::net::IpAddr;
use std::path::Path;
use std::time::Duration;

/// What a topology file describes: one cell (`launch/cell.toml`) or a
/// plant (`launch/factory.toml`, a file with `plant = …`).
#[derive(Debug, Clone)]
pub enum Layout {
    /// One cell, a plant of one.
    Cell(Topology),
    /// Several cells under one operator.
    Plant(Plant),
}

impl Layout {
    /// Reads a topology file, a cell's or a plant's.
    pub fn load(path: &Path) -> Result<Self, TopologyError> {
        let (text, origin) = read(path)?;
        let is_plant = toml::from_str::<toml::Table>(&text)
            .map(|t| t.contains_key("plant"))
            .unwrap_or(false);
        if is_plant {
            Plant::parse(&text, &origin).map(Layout::Plant)
        } else {
            Topology::parse(&text, &origin).map(Layout::Cell)
        }
    }
}

/// The zenoh user name a cell's router logs in with at the factory router.
pub fn router_user(cell: &CellId) -> String {
    format!("router-{cell}")
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCell {
    cell: CellId,
    router: String,
    /// The factory router's endpoint as this cell's router reaches it.
    #[serde(default)]
    uplink: Option<String>,
    /// The cell router PC's address, for the factory router's firewall.
    #[serde(default)]
    host: Option<IpAddr>,
    #[serde(rename = "station", default)]
    stations: Vec<Station>,
    /// How the cell names itself as a machine (OPC UA Machinery).
    #[serde(default)]
    identification: Option<crate::topology::Identification>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawOperator {
    #[serde(default = "default_operator")]
    name: StationName,
    #[serde(default)]
    host: Option<IpAddr>,
}

fn default_operator() -> StationName {
    StationName::new("operator").unwrap_or_else(|_| unreachable!("a valid name"))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPlant {
    plant: CellId,
    router: String,
    #[serde(default = "default_lease_ms")]
    lease_ms: u64,
    operator: RawOperator,
    #[serde(rename = "console", default)]
    consoles: Vec<Console>,
    #[serde(rename = "cell", default)]
    cells: Vec<RawCell>,
    /// Local time minus UTC for the shifts (`+01:00`; default UTC).
    #[serde(default)]
    utc_offset: Option<String>,
    /// The plant's shift calendar, every cell's (none: always).
    #[serde(rename = "shift", default)]
    shifts: Vec<crate::calendar::RawShift>,
}

/// One cell of the plant.
#[derive(Debug, Clone)]
pub struct PlantCell {
    topology: Topology,
    uplink: Option<String>,
    host: Option<IpAddr>,
    router_user: StationName,
}

impl PlantCell {
    /// The cell's id (second key chunk of its keys).
    pub fn id(&self) -> &CellId {
        self.topology.cell()
    }

    /// The cell's topology: the operator as its root, then its stations;
    /// its router is the cell router.
    pub fn topology(&self) -> &Topology {
        &self.topology
    }

    /// The user its router logs in with at the factory router.
    pub fn router_user(&self) -> &StationName {
        &self.router_user
    }

    /// The factory router's endpoint as this cell's router reaches it
    /// (`uplink` in its `[[cell]]`: another address, a gateway), if the
    /// file names one; else the plant's `router`.
    pub fn uplink(&self) -> Option<&str> {
        self.uplink.as_deref()
    }

    /// The cell router PC's address, if the file names one.
    pub fn host(&self) -> Option<IpAddr> {
        self.host
    }

    /// Replaces the cell router's endpoint (tests pick free ports).
    pub fn set_router(&mut self, endpoint: String) {
        self.topology.set_router(endpoint);
    }
}

/// A validated plant topology.
#[derive(Debug, Clone)]
pub struct Plant {
    factory: Topology,
    operator_host: Option<IpAddr>,
    cells: Vec<PlantCell>,
}

impl Plant {
    /// Reads and validates a plant file.
    pub fn load(path: &Path) -> Result<Self, TopologyError> {
        let (text, origin) = read(path)?;
        Self::parse(&text, &origin)
    }

    /// Parses and validates plant text; `origin` names it in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Self, TopologyError> {
        let raw: RawPlant = from_toml(text, origin)?;
        let fail = |message: String| TopologyError::Hierarchy {
            origin: origin.to_string(),
            message,
        };
        let operator = Station {
            name: raw.operator.name.clone(),
            kind: StationKind::Operator,
            commander: None,
            device: None,
            equipment: None,
            host: raw.operator.host,
        };
        if raw.cells.is_empty() {
            return Err(fail(
                "the plant has no [[cell]]; a plant of one is launch/cell.toml".into(),
            ));
        }
        let factory = Topology::from_raw(
            RawTopology {
                cell: raw.plant.clone(),
                router: raw.router,
                lease_ms: raw.lease_ms,
                stations: vec![operator.clone()],
                consoles: raw.consoles,
                utc_offset: raw.utc_offset.clone(),
                shifts: raw.shifts.clone(),
                identification: None,
            },
            origin,
        )?;
        // Every user of the factory router needs a name of its own.
        let mut factory_users: BTreeSet<String> =
            factory.users().map(|u| u.as_str().to_string()).collect();
        let mut ids = BTreeSet::new();
        let mut cells = Vec::new();
        for c in raw.cells {
            let id = c.cell.clone();
            if id == raw.plant {
                return Err(fail(format!(
                    "cell `{id}` has the plant's name; the operator API's keys are the plant's"
                )));
            }
            if !ids.insert(id.clone()) {
                return Err(fail(format!("cell `{id}` is defined twice")));
            }
            if let Some(op) = c.stations.iter().find(|s| s.kind == StationKind::Operator) {
                return Err(fail(format!(
                    "cell `{id}`: station `{}` is of kind operator; the plant's operator is \
                     [operator], above every cell",
                    op.name
                )));
            }
            for st in &c.stations {
                if st.name == operator.name || factory.console(&st.name).is_some() {
                    return Err(fail(format!(
                        "cell `{id}`: station `{}` has the name of the operator or a console",
                        st.name
                    )));
                }
            }
            let user = router_user(&id);
            let router_user = StationName::new(&user)
                .map_err(|e| fail(format!("cell `{id}`: its router's user name: {e}")))?;
            if !factory_users.insert(user.clone()) {
                return Err(fail(format!(
                    "`{user}` names a console or the operator, but is cell `{id}`'s router's \
                     user at the factory router"
                )));
            }
            let topology = Topology::from_raw(
                RawTopology {
                    cell: id.clone(),
                    router: c.router,
                    lease_ms: raw.lease_ms,
                    stations: std::iter::once(operator.clone())
                        .chain(c.stations)
                        .collect(),
                    // The plant's console users, whose roles each cell's
                    // order list checks again; they log in at the factory
                    // router only.
                    consoles: factory.consoles().to_vec(),
                    utc_offset: raw.utc_offset.clone(),
                    shifts: raw.shifts.clone(),
                    identification: c.identification,
                },
                &format!("{origin}, cell `{id}`"),
            )?;
            if topology.subordinates_of(&operator.name).len() != 1 {
                return Err(fail(format!(
                    "cell `{id}` must have exactly one station commanded by `{}` (its cell \
                     controller)",
                    operator.name
                )));
            }
            cells.push(PlantCell {
                topology,
                uplink: c.uplink,
                host: c.host,
                router_user,
            });
        }
        Ok(Plant {
            factory,
            operator_host: raw.operator.host,
            cells,
        })
    }

    /// The plant's name: the key chunk of the operator API
    /// (`falc/<plant>/operator/api/…`).
    pub fn name(&self) -> &CellId {
        self.factory.cell()
    }

    /// The factory level as a topology: the operator as its only station,
    /// the console users, the factory router, all under the plant's name.
    pub fn factory(&self) -> &Topology {
        &self.factory
    }

    /// The factory router's endpoint.
    pub fn router(&self) -> &str {
        self.factory.router()
    }

    /// Replaces the factory router's endpoint (tests pick free ports).
    pub fn set_router(&mut self, endpoint: String) {
        self.factory.set_router(endpoint);
    }

    /// The zenoh lease of every link of the plant.
    pub fn lease(&self) -> Duration {
        self.factory.lease()
    }

    /// The operator (the factory controller), root of every cell.
    pub fn operator(&self) -> &Station {
        self.factory.root()
    }

    /// The operator PC's address, if the file names one.
    pub fn operator_host(&self) -> Option<IpAddr> {
        self.operator_host
    }

    /// Every cell, in file order.
    pub fn cells(&self) -> &[PlantCell] {
        &self.cells
    }

    /// Every cell, to change (tests pick free ports for the routers).
    pub fn cells_mut(&mut self) -> &mut [PlantCell] {
        &mut self.cells
    }

    /// One cell by id.
    pub fn cell(&self, id: &CellId) -> Option<&PlantCell> {
        self.cells.iter().find(|c| c.id() == id)
    }

    /// The cell whose router logs in as `user` at the factory router.
    pub fn cell_of_router_user(&self, user: &str) -> Option<&PlantCell> {
        self.cells.iter().find(|c| c.router_user.as_str() == user)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) const PLANT: &str = r#"
plant = "plant"
router = "tcp/127.0.0.1:7446"
[operator]
name = "operator"
[[console]]
name = "console"
role = "operator"
[[cell]]
cell = "falc1"
router = "tcp/127.0.0.1:7447"
[[cell.station]]
name = "cell"
kind = "cell"
commander = "operator"
[[cell.station]]
name = "welding"
kind = "welding"
commander = "cell"
[[cell]]
cell = "falc2"
router = "tcp/127.0.0.1:7448"
uplink = "tcp/10.1.0.1:7446"
[[cell.station]]
name = "cell"
kind = "cell"
commander = "operator"
[[cell.station]]
name = "transport"
kind = "transport"
commander = "cell"
"#;

    fn refused(text: &str) -> String {
        match Plant::parse(text, "factory.toml") {
            Ok(_) => panic!("accepted: {text}"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn each_cell_is_a_topology_under_the_operator() {
        let plant = Plant::parse(PLANT, "factory.toml").expect("plant");
        assert_eq!(plant.name().as_str(), "plant");
        assert_eq!(plant.router(), "tcp/127.0.0.1:7446");
        assert_eq!(plant.cells().len(), 2);
        let c2 = plant
            .cell(&CellId::new("falc2").expect("id"))
            .expect("falc2");
        assert_eq!(c2.topology().router(), "tcp/127.0.0.1:7448");
        // Its router reaches the factory router at its own address; cell 1
        // at the plant's.
        assert_eq!(c2.uplink(), Some("tcp/10.1.0.1:7446"));
        assert_eq!(plant.cells()[0].uplink(), None);
        assert_eq!(c2.topology().root().name.as_str(), "operator");
        let names: Vec<&str> = c2
            .topology()
            .stations()
            .iter()
            .map(|s| s.name.as_str())
            .collect();
        assert_eq!(names, ["operator", "cell", "transport"]);
        let consoles: Vec<&str> = c2
            .topology()
            .consoles()
            .iter()
            .map(|c| c.name.as_str())
            .collect();
        assert_eq!(consoles, ["console"], "the plant's, for their roles");
        assert_eq!(c2.router_user().as_str(), "router-falc2");
        assert_eq!(
            plant
                .cell_of_router_user("router-falc1")
                .map(|c| c.id().as_str()),
            Some("falc1")
        );
        let factory: Vec<&str> = plant.factory().users().map(|u| u.as_str()).collect();
        assert_eq!(factory, ["operator", "console"]);
    }

    #[test]
    fn each_cell_names_itself_as_a_machine() {
        let text = PLANT.replace(
            "uplink = \"tcp/10.1.0.1:7446\"\n",
            "uplink = \"tcp/10.1.0.1:7446\"\n[cell.identification]\nserial_number = \"S-2\"\n",
        );
        let plant = Plant::parse(&text, "factory.toml").expect("plant");
        let [one, two] = plant.cells() else {
            panic!("two cells");
        };
        assert_eq!(one.topology().identification().serial_number, None);
        let two = two.topology().identification();
        assert_eq!(two.serial_number.as_deref(), Some("S-2"));
        assert_eq!(two.manufacturer, "FALC");
        let unknown = text.replace("serial_number = \"S-2\"", "serial = \"S-2\"");
        assert!(refused(&unknown).contains("unknown field `serial`"));
    }

    #[test]
    fn a_topology_file_is_read_as_a_cell_or_as_a_plant() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../launch");
        assert!(matches!(
            Layout::load(&root.join("cell.toml")),
            Ok(Layout::Cell(_))
        ));
        assert!(matches!(
            Layout::load(&root.join("factory.toml")),
            Ok(Layout::Plant(_))
        ));
    }

    #[test]
    fn the_shipped_demo_plant_has_three_cells_of_three_stations() {
        let plant = Plant::parse(
            include_str!("../../../launch/factory.toml"),
            "launch/factory.toml",
        )
        .expect("the shipped plant");
        assert_eq!(plant.cells().len(), 3);
        for c in plant.cells() {
            let kinds: Vec<&str> = c
                .topology()
                .stations()
                .iter()
                .map(|s| s.kind.as_str())
                .collect();
            assert_eq!(
                kinds,
                ["operator", "cell", "welding", "transport"],
                "{}",
                c.id()
            );
        }
        let routers: BTreeSet<&str> = std::iter::once(plant.router())
            .chain(plant.cells().iter().map(|c| c.topology().router()))
            .collect();
        assert_eq!(routers.len(), 4, "a router of its own for each cell");
    }

    #[test]
    fn a_plant_with_no_cell_or_a_cell_twice_is_refused() {
        let none = PLANT.split("[[cell]]").next().expect("head");
        assert!(refused(none).contains("no [[cell]]"));
        let twice = PLANT.replace("cell = \"falc2\"", "cell = \"falc1\"");
        assert!(refused(&twice).contains("`falc1` is defined twice"));
        let plant_name = PLANT.replace("cell = \"falc2\"", "cell = \"plant\"");
        assert!(refused(&plant_name).contains("the plant's name"));
    }

    #[test]
    fn a_cell_names_no_operator_of_its_own_and_no_console() {
        let own = PLANT.replace(
            "name = \"transport\"\nkind = \"transport\"\ncommander = \"cell\"",
            "name = \"boss\"\nkind = \"operator\"",
        );
        assert!(refused(&own).contains("kind operator"), "{}", refused(&own));
        let console = PLANT.replace("name = \"transport\"", "name = \"console\"");
        assert!(refused(&console).contains("the name of the operator or a console"));
        let no_commander = PLANT.replace(
            "name = \"transport\"\nkind = \"transport\"\ncommander = \"cell\"",
            "name = \"transport\"\nkind = \"transport\"\ncommander = \"nobody\"",
        );
        let e = refused(&no_commander);
        assert!(e.contains("cell `falc2`") && e.contains("`nobody`"), "{e}");
    }

    #[test]
    fn a_console_cannot_take_a_cell_routers_name() {
        let text = PLANT.replace("name = \"console\"", "name = \"router-falc2\"");
        assert!(refused(&text).contains("`router-falc2` names a console"));
    }

    #[test]
    fn every_cell_has_one_cell_controller_under_the_operator() {
        let two = PLANT.replace(
            "name = \"transport\"\nkind = \"transport\"\ncommander = \"cell\"",
            "name = \"cell2\"\nkind = \"cell\"\ncommander = \"operator\"",
        );
        assert!(refused(&two).contains("exactly one station commanded by `operator`"));
    }
}
