//! The cell topology, `launch/cell.toml`: which stations exist, what kind each
//! is, who commands whom, where each node's device is, and how nodes reach the
//! router.
//!
//! Everything that depends on the hierarchy (keys a node serves, ACL rules,
//! credentials, console panes) is derived from this one file. Validation is
//! complete at load time: a topology that loads is a tree with exactly one
//! root, unique names and known commanders.

use crate::calendar::{Calendar, RawShift};
use crate::ids::{CellId, StationName};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::net::IpAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The kind of controller a station runs; decides its command set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum StationKind {
    /// The factory controller: order list, recipe store, journal. The root.
    Operator,
    /// The cell controller.
    Cell,
    /// A welding workstation bridging to a robot controller.
    Welding,
    /// A transport workstation driving a conveyor PLC.
    Transport,
}

impl StationKind {
    /// Its word in the topology file (`welding`).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Operator => "operator",
            Self::Cell => "cell",
            Self::Welding => "welding",
            Self::Transport => "transport",
        }
    }

    /// Whether a station of this kind runs its order on to its end when
    /// its commander is lost (a cell: its recipe coordinates its
    /// workstations by itself, and its commander asks how the order ended
    /// once it is back). A workstation stops: without its cell nothing
    /// coordinates it with the other workstations.
    pub fn runs_on_alone(self) -> bool {
        self == Self::Cell
    }
}

/// One station stanza.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Station {
    /// Its name: key chunk, zenoh user name, console pane title.
    pub name: StationName,
    /// Its controller kind.
    pub kind: StationKind,
    /// Its one commander; absent only for the root (the operator).
    #[serde(default)]
    pub commander: Option<StationName>,
    /// Its device address (serial port, Modbus endpoint), if it has one.
    #[serde(default)]
    pub device: Option<String>,
    /// A transport station's equipment file (its conveyor: layout,
    /// signals, feedback, twin timings), relative to the working directory
    /// like the recipe directory; absent: the 1992 conveyor,
    /// `equipment/conveyor-1992.toml`, built into every node.
    #[serde(default)]
    pub equipment: Option<PathBuf>,
    /// The IP address of the PC it runs on, for the router's firewall
    /// (`falc-router firewall`); absent in an all-in-one cell.
    #[serde(default)]
    pub host: Option<IpAddr>,
}

/// What a console user may do through the operator API (docs/architecture.md, "Access control").
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Reads everything: status, order list, messages, journal.
    Observer,
    /// Also orders, start/stop, answers, acknowledgements, shut down.
    Operator,
    /// Also recipes.
    Engineer,
    /// Also manual operations on the workstations (maintenance mode):
    /// buttons, lines, the robot, a station's home recipe.
    Maintainer,
}

/// One console user stanza: a person (or script) using `falc`.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Console {
    /// The zenoh user name; named in every journal entry it causes.
    pub name: StationName,
    /// What it may do.
    pub role: Role,
    /// The IP address of the PC it is used from, for the router's firewall
    /// (`falc-router firewall`); absent in an all-in-one cell.
    #[serde(default)]
    pub host: Option<IpAddr>,
}

/// A topology as read, before validation.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawTopology {
    pub(crate) cell: CellId,
    pub(crate) router: String,
    #[serde(default = "default_lease_ms")]
    pub(crate) lease_ms: u64,
    #[serde(rename = "station", default)]
    pub(crate) stations: Vec<Station>,
    #[serde(rename = "console", default)]
    pub(crate) consoles: Vec<Console>,
    /// Local time minus UTC for the shifts (`+01:00`; default UTC).
    #[serde(default)]
    pub(crate) utc_offset: Option<String>,
    /// The shift calendar (none: planned busy always).
    #[serde(rename = "shift", default)]
    pub(crate) shifts: Vec<RawShift>,
    /// How the cell names itself as a machine (OPC UA Machinery).
    #[serde(default)]
    pub(crate) identification: Option<Identification>,
}

/// How a cell names itself as a machine to a plant's MES (OPC 40001-1
/// Machinery's Identification; FALC's version is its software revision):
/// `[identification]` in the topology, every field optional.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Identification {
    /// Who built the cell (default "FALC").
    #[serde(default = "default_manufacturer")]
    pub manufacturer: String,
    /// What kind of cell it is (default "FALC flexible assembly cell").
    #[serde(default = "default_model")]
    pub model: String,
    /// Its serial number (default: the cell id).
    #[serde(default)]
    pub serial_number: Option<String>,
}

fn default_manufacturer() -> String {
    "FALC".into()
}

fn default_model() -> String {
    "FALC flexible assembly cell".into()
}

impl Identification {
    /// The defaults, for a topology without `[identification]`.
    pub fn default_for() -> Self {
        Self {
            manufacturer: default_manufacturer(),
            model: default_model(),
            serial_number: None,
        }
    }
}

pub(crate) fn default_lease_ms() -> u64 {
    1000
}

/// A validated cell topology.
#[derive(Debug, Clone)]
pub struct Topology {
    cell: CellId,
    router: String,
    lease: Duration,
    stations: Vec<Station>,
    consoles: Vec<Console>,
    index: BTreeMap<StationName, usize>,
    calendar: Calendar,
    identification: Identification,
}

/// The link protocols a router endpoint may use: `tcp` on one machine or a
/// trusted segment, `quic` (mutual TLS 1.3) between PCs.
pub const ROUTER_PROTOCOLS: [&str; 2] = ["tcp", "quic"];

/// Checks the router endpoint's protocol. zenoh's `tls/` link is refused:
/// it shares one TLS stream between its reading and writing tasks, which
/// rustls does not allow (zenoh issue #2557), and links dropped under load.
fn check_router(router: &str) -> Result<(), String> {
    let protocol = router.split_once('/').map(|(p, _)| p).unwrap_or("");
    if ROUTER_PROTOCOLS.contains(&protocol) {
        return Ok(());
    }
    if protocol == "tls" {
        return Err(format!(
            "router = \"{router}\": zenoh's tls/ link drops links under load (zenoh \
             issue #2557); use quic/ for mutual TLS between PCs"
        ));
    }
    Err(format!(
        "router = \"{router}\": the endpoint must begin with {}",
        ROUTER_PROTOCOLS.map(|p| format!("{p}/")).join(" or ")
    ))
}

/// Names no station or console may have: their files in the credentials
/// directory are the cell CA's (`ca.crt`, `ca.key`) and the router's.
pub const RESERVED_NAMES: [&str; 2] = ["ca", "router"];

/// Why a topology was refused.
#[derive(Debug, thiserror::Error)]
pub enum TopologyError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The TOML is malformed or has unknown or missing fields.
    #[error("{origin}: {message}")]
    Syntax {
        /// The file or source name.
        origin: String,
        /// The parser's message, with line and column.
        message: String,
    },
    /// A rule of the hierarchy is broken.
    #[error("{origin}: {message}")]
    Hierarchy {
        /// The file or source name.
        origin: String,
        /// What is wrong, naming the station.
        message: String,
    },
}

/// A topology file's text and the name it goes by in errors (its path).
pub(crate) fn read(path: &Path) -> Result<(String, String), TopologyError> {
    let origin = path.display().to_string();
    match std::fs::read_to_string(path) {
        Ok(text) => Ok((text, origin)),
        Err(source) => Err(TopologyError::Read {
            path: origin,
            source,
        }),
    }
}

/// TOML text as `T`, or the parser's message with line and column.
pub(crate) fn from_toml<T: serde::de::DeserializeOwned>(
    text: &str,
    origin: &str,
) -> Result<T, TopologyError> {
    toml::from_str(text).map_err(|e| TopologyError::Syntax {
        origin: origin.to_string(),
        message: e.to_string().trim_end().to_string(),
    })
}

impl Topology {
    /// Reads and validates a topology file.
    pub fn load(path: &Path) -> Result<Self, TopologyError> {
        let (text, origin) = read(path)?;
        Self::parse(&text, &origin)
    }

    /// Parses and validates topology text; `origin` names it in errors.
    pub fn parse(text: &str, origin: &str) -> Result<Self, TopologyError> {
        Self::from_raw(from_toml(text, origin)?, origin)
    }

    /// Validates a topology given in parts (a plant's cells are built
    /// this way, [`crate::plant`]); `origin` names it in errors.
    pub(crate) fn from_raw(raw: RawTopology, origin: &str) -> Result<Self, TopologyError> {
        let fail = |message: String| TopologyError::Hierarchy {
            origin: origin.to_string(),
            message,
        };
        check_router(&raw.router).map_err(fail)?;
        let calendar = Calendar::new(raw.utc_offset.as_deref(), &raw.shifts).map_err(fail)?;
        if raw.lease_ms < 100 {
            return Err(fail(format!(
                "lease_ms = {} is too short; use at least 100",
                raw.lease_ms
            )));
        }
        let mut index = BTreeMap::new();
        for (i, st) in raw.stations.iter().enumerate() {
            if index.insert(st.name.clone(), i).is_some() {
                return Err(fail(format!("station `{}` is defined twice", st.name)));
            }
            if st.name.as_str() == crate::recipe_file::ROBOT_DIR {
                return Err(fail(format!(
                    "a station may not be named `{}`: the recipe store keeps the robot programs \
                     in that directory",
                    st.name
                )));
            }
        }
        let names = raw
            .stations
            .iter()
            .map(|s| &s.name)
            .chain(raw.consoles.iter().map(|c| &c.name));
        for name in names {
            if RESERVED_NAMES.contains(&name.as_str()) {
                return Err(fail(format!(
                    "`{name}` cannot name a station or console: the credentials directory keeps \
                     the cell CA and the router's certificate under the names {}",
                    RESERVED_NAMES.join(" and ")
                )));
            }
        }
        for c in &raw.consoles {
            if index.contains_key(&c.name) {
                return Err(fail(format!(
                    "console `{}` has the name of a station; each zenoh user needs its own name",
                    c.name
                )));
            }
            if raw.consoles.iter().filter(|o| o.name == c.name).count() > 1 {
                return Err(fail(format!("console `{}` is defined twice", c.name)));
            }
        }
        let roots: Vec<_> = raw
            .stations
            .iter()
            .filter(|s| s.commander.is_none())
            .collect();
        match roots.as_slice() {
            [root] if root.kind == StationKind::Operator => {}
            [root] => {
                return Err(fail(format!(
                    "station `{}` has no commander but is not of kind operator",
                    root.name
                )))
            }
            [] => {
                return Err(fail(
                    "no station without commander: the operator is missing".into(),
                ))
            }
            many => {
                let names: Vec<_> = many.iter().map(|s| s.name.as_str()).collect();
                return Err(fail(format!(
                    "only the operator may lack a commander, but {} do",
                    names.join(", ")
                )));
            }
        }
        for st in &raw.stations {
            if st.equipment.is_some() && st.kind != StationKind::Transport {
                return Err(fail(format!(
                    "station `{}` names an equipment file, but only a transport station \
                     drives equipment of its own",
                    st.name
                )));
            }
            if let Some(cmd) = &st.commander {
                if !index.contains_key(cmd) {
                    return Err(fail(format!(
                        "station `{}` names commander `{cmd}`, which is not defined",
                        st.name
                    )));
                }
                if cmd == &st.name {
                    return Err(fail(format!("station `{}` commands itself", st.name)));
                }
            }
            // Walk up: a tree reaches the root in fewer steps than stations.
            let mut cur = st;
            for _ in 0..=raw.stations.len() {
                match &cur.commander {
                    None => break,
                    Some(c) => cur = &raw.stations[index[c]],
                }
            }
            if cur.commander.is_some() {
                return Err(fail(format!("station `{}` is in a command cycle", st.name)));
            }
        }
        Ok(Self {
            cell: raw.cell,
            router: raw.router,
            lease: Duration::from_millis(raw.lease_ms),
            stations: raw.stations,
            consoles: raw.consoles,
            index,
            calendar,
            identification: raw
                .identification
                .unwrap_or_else(Identification::default_for),
        })
    }

    /// How the cell names itself as a machine.
    pub fn identification(&self) -> &Identification {
        &self.identification
    }

    /// The shift calendar the figures are planned against.
    pub fn calendar(&self) -> &Calendar {
        &self.calendar
    }

    /// The cell id (second key chunk).
    pub fn cell(&self) -> &CellId {
        &self.cell
    }

    /// The router endpoint nodes connect to (`tcp/127.0.0.1:7447`).
    pub fn router(&self) -> &str {
        &self.router
    }

    /// Replaces the router endpoint (tests and the launcher pick free ports).
    pub fn set_router(&mut self, endpoint: String) {
        self.router = endpoint;
    }

    /// The zenoh lease: how soon a frozen node or a cut cable is noticed.
    pub fn lease(&self) -> Duration {
        self.lease
    }

    /// Every station, in file order.
    pub fn stations(&self) -> &[Station] {
        &self.stations
    }

    /// One station by name.
    pub fn station(&self, name: &StationName) -> Option<&Station> {
        self.index.get(name).map(|&i| &self.stations[i])
    }

    /// Every console user, in file order.
    pub fn consoles(&self) -> &[Console] {
        &self.consoles
    }

    /// Every station and console user with the IP address of its PC, if
    /// the topology names one (`host = "…"`).
    pub fn user_hosts(&self) -> impl Iterator<Item = (&StationName, Option<IpAddr>)> {
        self.stations
            .iter()
            .map(|s| (&s.name, s.host))
            .chain(self.consoles.iter().map(|c| (&c.name, c.host)))
    }

    /// One console user by name.
    pub fn console(&self, name: &StationName) -> Option<&Console> {
        self.consoles.iter().find(|c| &c.name == name)
    }

    /// Every zenoh user of the cell: stations, then consoles.
    pub fn users(&self) -> impl Iterator<Item = &StationName> {
        self.stations
            .iter()
            .map(|s| &s.name)
            .chain(self.consoles.iter().map(|c| &c.name))
    }

    /// The root station (the operator).
    pub fn root(&self) -> &Station {
        // Validated in `parse`: exactly one station has no commander.
        self.stations
            .iter()
            .find(|s| s.commander.is_none())
            .unwrap_or(&self.stations[0])
    }

    /// The commander of a station (None for the root or an unknown name).
    pub fn commander_of(&self, name: &StationName) -> Option<&StationName> {
        self.station(name).and_then(|s| s.commander.as_ref())
    }

    /// How many levels of subordinates a station has below it (0 for a
    /// workstation, 1 for a cell of workstations).
    pub fn height(&self, name: &StationName) -> u32 {
        self.subordinates_of(name)
            .into_iter()
            .map(|s| 1 + self.height(s))
            .max()
            .unwrap_or(0)
    }

    /// The direct subordinates of a station, in file order.
    pub fn subordinates_of(&self, name: &StationName) -> Vec<&StationName> {
        self.stations
            .iter()
            .filter(|s| s.commander.as_ref() == Some(name))
            .map(|s| &s.name)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CELL: &str = r#"
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
name = "welding"
kind = "welding"
commander = "cell"
device = "/dev/ttyS0"
"#;

    #[test]
    fn a_kinds_word_is_the_one_the_file_uses() {
        for k in [
            StationKind::Operator,
            StationKind::Cell,
            StationKind::Welding,
            StationKind::Transport,
        ] {
            let wire = serde_json::to_string(&k).expect("serializes");
            assert_eq!(wire, format!("\"{}\"", k.as_str()));
        }
    }

    #[test]
    fn a_shift_calendar_is_read_and_a_bad_shift_refused_with_its_name() {
        assert!(Topology::parse(CELL, "cell.toml")
            .expect("valid")
            .calendar()
            .always());
        // The keys before the first table.
        let with = |stanza: &str| format!("utc_offset = \"+01:00\"\n{CELL}{stanza}");
        let t = Topology::parse(
            &with("[[shift]]\nname = \"early\"\nstart = \"06:00\"\nend = \"14:00\"\n"),
            "cell.toml",
        )
        .expect("valid");
        let c = t.calendar();
        assert_eq!((c.utc_offset_min, c.shifts.len()), (60, 1));
        assert_eq!((c.shifts[0].start_min, c.shifts[0].length_min), (360, 480));
        let e = Topology::parse(
            &with("[[shift]]\nname = \"late\"\nstart = \"14:00\"\nend = \"26:00\"\n"),
            "cell.toml",
        )
        .expect_err("refused");
        assert!(e.to_string().contains("shift `late` end"), "{e}");
    }

    #[test]
    fn a_cell_names_itself_as_a_machine_with_defaults_for_what_it_leaves_out() {
        let t = Topology::parse(CELL, "cell.toml").expect("valid");
        assert_eq!(t.identification(), &Identification::default_for());
        // A table between the top-level keys and the stations.
        let with = |stanza: &str| CELL.replacen("[[station]]", &format!("{stanza}[[station]]"), 1);
        let t = Topology::parse(
            &with("[identification]\nserial_number = \"S-1\"\n"),
            "cell.toml",
        )
        .expect("valid");
        assert_eq!(t.identification().manufacturer, "FALC");
        assert_eq!(t.identification().serial_number.as_deref(), Some("S-1"));
        let e = Topology::parse(&with("[identification]\nvendor = \"x\"\n"), "cell.toml")
            .expect_err("refused");
        assert!(e.to_string().contains("unknown field `vendor`"), "{e}");
    }

    #[test]
    fn parses_the_tree() {
        let t = Topology::parse(CELL, "cell.toml").expect("valid");
        let cell = StationName::new("cell").expect("valid");
        assert_eq!(t.root().name.as_str(), "operator");
        assert_eq!(t.subordinates_of(&cell).len(), 1);
        assert_eq!(t.commander_of(&cell).map(|s| s.as_str()), Some("operator"));
        assert_eq!(t.lease(), Duration::from_secs(1));
        assert_eq!(t.height(&t.root().name), 2);
        assert_eq!(t.height(&cell), 1);
    }

    fn refusal(text: &str) -> String {
        match Topology::parse(text, "t.toml") {
            Ok(_) => panic!("accepted: {text}"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn refuses_broken_hierarchies() {
        assert!(refusal(&format!(
            "{CELL}[[station]]\nname=\"welding\"\nkind=\"welding\"\ncommander=\"cell\"\n"
        ))
        .contains("defined twice"));
        assert!(
            refusal(&CELL.replace("name = \"welding\"", "name = \"robot\""))
                .contains("may not be named `robot`")
        );
        assert!(
            refusal(&CELL.replace("commander = \"cell\"", "commander = \"nobody\""))
                .contains("`nobody`, which is not defined")
        );
        assert!(refusal(&CELL.replace("commander = \"operator\"", "")).contains("lack a commander"));
        assert!(
            refusal(&CELL.replace("commander = \"operator\"", "commander = \"welding\""))
                .contains("cycle")
        );
        assert!(
            refusal(&CELL.replace("kind = \"welding\"", "kind = \"painting\""))
                .contains("painting")
        );
        assert!(refusal(&CELL.replace("name = \"cell\"", "name = \"c ell\"")).contains("c ell"));
    }

    #[test]
    fn only_a_transport_station_names_an_equipment_file() {
        let transport = "[[station]]\nname = \"transport\"\nkind = \"transport\"\n\
                         commander = \"cell\"\nequipment = \"equipment/small.toml\"\n";
        let t = Topology::parse(&format!("{CELL}{transport}"), "t.toml").expect("valid");
        let stanza = t
            .station(&StationName::new("transport").expect("valid"))
            .expect("there");
        assert_eq!(
            stanza.equipment.as_deref(),
            Some(Path::new("equipment/small.toml"))
        );
        let welding = CELL.replace(
            "device = \"/dev/ttyS0\"",
            "device = \"/dev/ttyS0\"\nequipment = \"equipment/small.toml\"",
        );
        assert!(
            refusal(&welding).contains(
                "station `welding` names an equipment file, but only a transport station"
            ),
            "{}",
            refusal(&welding)
        );
    }

    #[test]
    fn the_router_is_tcp_or_quic_and_tls_is_refused_with_its_reason() {
        for ok in ["tcp/", "quic/"] {
            let t = Topology::parse(&CELL.replace("tcp/", ok), "t").expect("valid");
            assert!(t.router().starts_with(ok));
        }
        let tls = refusal(&CELL.replace("tcp/", "tls/"));
        assert!(tls.contains("#2557") && tls.contains("quic/"), "{tls}");
        assert!(refusal(&CELL.replace("tcp/", "udp/")).contains("tcp/ or quic/"));
    }

    #[test]
    fn stations_and_consoles_may_name_their_host() {
        let t = Topology::parse(
            &format!(
                "{}[[console]]\nname=\"ann\"\nrole=\"operator\"\nhost=\"10.0.0.9\"\n",
                CELL.replace("kind = \"cell\"", "kind = \"cell\"\nhost = \"10.0.0.2\"")
            ),
            "t",
        )
        .expect("valid");
        let cell = StationName::new("cell").expect("valid");
        let ann = StationName::new("ann").expect("valid");
        assert_eq!(
            t.station(&cell).and_then(|s| s.host),
            Some("10.0.0.2".parse().expect("ip"))
        );
        assert_eq!(
            t.console(&ann).and_then(|c| c.host),
            Some("10.0.0.9".parse().expect("ip"))
        );
        assert!(
            refusal(&CELL.replace("kind = \"cell\"", "kind = \"cell\"\nhost = \"pc7\""))
                .contains("host")
        );
    }

    #[test]
    fn consoles_have_roles_and_their_own_names() {
        let t = Topology::parse(
            &format!("{CELL}[[console]]\nname=\"ann\"\nrole=\"operator\"\n"),
            "t",
        )
        .expect("valid");
        let ann = StationName::new("ann").expect("valid");
        assert_eq!(t.console(&ann).map(|c| c.role), Some(Role::Operator));
        assert_eq!(t.users().count(), 4);
        assert!(refusal(&format!(
            "{CELL}[[console]]\nname=\"cell\"\nrole=\"observer\"\n"
        ))
        .contains("has the name of a station"));
        assert!(
            refusal(&format!("{CELL}[[console]]\nname=\"ann\"\nrole=\"boss\"\n")).contains("boss")
        );
    }

    #[test]
    fn reserved_names_are_refused() {
        let refusal = |text: &str| match Topology::parse(text, "t") {
            Err(e) => e.to_string(),
            Ok(_) => panic!("accepted: {text}"),
        };
        let text = refusal(&format!(
            "{CELL}[[console]]\nname=\"ca\"\nrole=\"observer\"\n"
        ));
        assert!(text.contains("`ca` cannot name"), "{text}");
        let text = refusal(&CELL.replace("name = \"welding\"", "name = \"router\""));
        assert!(text.contains("`router` cannot name"), "{text}");
    }
}
