//! The equipment file: a conveyor described in data (`equipment/*.toml`),
//! checked when it is read. It holds what differs between cells, so that a
//! cell of another layout needs a file, not Rust:
//!
//! - the **layout**: places (with capacity and what a fault of their
//!   presence sensor is), lines (from where to where), stations (the place
//!   each takes its carrier from);
//! - the **signals**: every coil and discrete input with its Modbus address
//!   and what it is, and each coil's safe state per occasion;
//! - the **feedback** each actuator must show (which input follows which
//!   output, within what time, and what a mismatch is);
//! - the **twin's** timings: each line's travel time, each station's cycle
//!   time, where the carriers start.
//!
//! Every problem is reported with the file and line it is on, and a
//! reference to something that does not exist names what does. The file
//! format is explained for PLC programmers in docs/plc.md, with
//! `equipment/conveyor-1992.toml` (the default, [`Equipment::conveyor_1992`])
//! as the example.

use crate::signal::{Coil, Input, SafeState, Spot};
use crate::states::NamedState;
use falc_model::alarm::AlarmClass;
use falc_model::ids::{IoName, Place, PlcStation, StationName};
use falc_model::topology::{StationKind, Topology};
use falc_recipe::check::{Button, Signal};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;
use std::sync::{Arc, OnceLock};
use std::time::Duration;
use toml::Spanned;

/// The text of the 1992 conveyor's file, built in: the default when a
/// transport stanza names no `equipment`.
const CONVEYOR_1992: &str = include_str!("../../../equipment/conveyor-1992.toml");

/// Where the default file lives in the repository (for messages).
pub const CONVEYOR_1992_PATH: &str = "equipment/conveyor-1992.toml";

/// One problem of an equipment file: where, and what.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    /// The file (as named to the reader).
    pub origin: String,
    /// Its 1-based line.
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}: {}", self.origin, self.line, self.message)
    }
}

/// Every problem of a file that did not load.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub struct Problems(pub Vec<Problem>);

impl fmt::Display for Problems {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let lines: Vec<String> = self.0.iter().map(Problem::to_string).collect();
        f.write_str(&lines.join("\n"))
    }
}

/// What a fault of a signal is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FaultClass {
    /// A device alarm: it holds the next start until acknowledged.
    #[default]
    Alarm,
    /// A warning: listed until acknowledged, holds nothing.
    Warning,
}

impl FaultClass {
    /// The alarm class a fault of this class is.
    pub fn alarm_class(self) -> AlarmClass {
        match self {
            FaultClass::Alarm => AlarmClass::Device,
            FaultClass::Warning => AlarmClass::Warning,
        }
    }
}

/// When a coil goes to its safe state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Occasion {
    /// An alarm, a failed or halted job, the end of maintenance.
    Error,
    /// The commander lost (its association aborted).
    Loss,
    /// The node stopping (SIGTERM, `falc shutdown`).
    Stop,
    /// The node's first connection after a restart (a crash, perhaps
    /// mid-job): what the PLC holds is adopted or released by this.
    Crash,
}

/// A coil's safe state on each [`Occasion`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SafeStates {
    /// On an error.
    pub error: SafeState,
    /// On the commander's loss.
    pub loss: SafeState,
    /// On a stop.
    pub stop: SafeState,
    /// After a crash.
    pub crash: SafeState,
}

impl SafeStates {
    /// The same state on every occasion.
    pub const fn all(s: SafeState) -> Self {
        Self {
            error: s,
            loss: s,
            stop: s,
            crash: s,
        }
    }

    /// The state on `occasion`.
    pub fn on(&self, occasion: Occasion) -> SafeState {
        match occasion {
            Occasion::Error => self.error,
            Occasion::Loss => self.loss,
            Occasion::Stop => self.stop,
            Occasion::Crash => self.crash,
        }
    }
}

impl fmt::Display for SafeStates {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let word = |s: SafeState| match s {
            SafeState::Off => "drop",
            SafeState::Hold => "hold",
        };
        if *self == Self::all(self.error) {
            f.write_str(word(self.error))
        } else {
            write!(
                f,
                "error {}, loss {}, stop {}, crash {}",
                word(self.error),
                word(self.loss),
                word(self.stop),
                word(self.crash)
            )
        }
    }
}

/// A place of the layout.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlaceSpec {
    /// Its name.
    pub place: Place,
    /// How many carriers it holds.
    pub capacity: usize,
    /// What a fault of its presence sensor is.
    pub sensor_fault: FaultClass,
}

/// A line of the layout.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LineSpec {
    /// Its name.
    pub line: char,
    /// Where it takes a carrier from.
    pub from: Spot,
    /// Where it brings it.
    pub to: Spot,
    /// How long the twin takes for it, at time scale 1.
    pub travel: Duration,
}

/// A station of the layout.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StationSpec {
    /// Its name.
    pub station: PlcStation,
    /// The place it takes its carrier from.
    pub takes_from: Place,
    /// How long the twin takes to take a carrier on, at time scale 1.
    pub cycle: Duration,
}

/// A coil and where it is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CoilSpec {
    /// Its Modbus address.
    pub address: u16,
    /// What it is.
    pub coil: Coil,
    /// Its safe states.
    pub safe: SafeStates,
}

/// A discrete input and where it is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InputSpec {
    /// Its Modbus address.
    pub address: u16,
    /// What it is.
    pub input: Input,
}

/// An actuator's feedback: `input` must follow `output`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FeedbackSpec {
    /// The actuator.
    pub output: Coil,
    /// The input that shows it acting.
    pub input: Input,
    /// How long they may disagree.
    pub within: Duration,
    /// What a longer disagreement is.
    pub fault: FaultClass,
}

/// A conveyor, as its equipment file describes it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Equipment {
    name: String,
    title: String,
    origin: String,
    places: Vec<PlaceSpec>,
    lines: Vec<LineSpec>,
    stations: Vec<StationSpec>,
    /// By address.
    coils: Vec<CoilSpec>,
    /// By address.
    inputs: Vec<InputSpec>,
    feedback: Vec<FeedbackSpec>,
    states: Vec<NamedState>,
    carriers: Vec<Spot>,
    run_empty: Duration,
    inputs_on: Vec<IoName>,
    /// Index into `inputs` by [`input_key`] (`NONE`: not in the file): a
    /// reading is looked up at every poll and every twin step.
    input_keys: Vec<u16>,
    /// The same into `coils` by [`coil_key`].
    coil_keys: Vec<u16>,
}

const NONE: u16 = u16::MAX;
const KEYS: usize = 26 + 256 + 256 + 2;

/// A dense number for every input there can be but a plain one (`None`:
/// looked up by name).
fn input_key(i: Input) -> Option<usize> {
    Some(match i {
        Input::Signal(Signal::Line(c)) => {
            usize::from(c as u8).saturating_sub(usize::from(b'A')) % 26
        }
        Input::Signal(Signal::Place(p)) => 26 + usize::from(p.number()),
        Input::Signal(Signal::Station(s)) => 26 + 256 + usize::from(s.number()),
        Input::Ready => 26 + 512,
        Input::EStop => 26 + 513,
        Input::Signal(Signal::Input(_)) => return None,
    })
}

/// The same for every coil.
fn coil_key(c: Coil) -> Option<usize> {
    match c {
        Coil::Button(Button::Line(l)) => input_key(Input::Signal(Signal::Line(l))),
        Coil::Button(Button::Station(s)) => input_key(Input::Signal(Signal::Station(s))),
        Coil::ExternalControl => Some(26 + 512),
        Coil::Button(Button::Output(_)) => None,
    }
}

fn keys<T>(items: &[T], key: impl Fn(&T) -> Option<usize>) -> Vec<u16> {
    let mut out = vec![NONE; KEYS];
    for (i, x) in items.iter().enumerate() {
        if let (Some(slot), Ok(i)) = (key(x).and_then(|k| out.get_mut(k)), u16::try_from(i)) {
            *slot = i;
        }
    }
    out
}

// ---------------------------------------------------------------------------
// The file as read.

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    name: Spanned<String>,
    #[serde(default)]
    title: String,
    #[serde(rename = "place", default)]
    places: Vec<RawPlace>,
    #[serde(rename = "line", default)]
    lines: Vec<RawLine>,
    #[serde(rename = "station", default)]
    stations: Vec<RawStation>,
    #[serde(rename = "coil", default)]
    coils: Vec<RawCoil>,
    #[serde(rename = "input", default)]
    inputs: Vec<RawInput>,
    #[serde(rename = "feedback", default)]
    feedback: Vec<RawFeedback>,
    #[serde(rename = "state", default)]
    states: Vec<RawNamedState>,
    #[serde(default)]
    twin: Option<RawTwin>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawNamedState {
    name: Spanned<String>,
    #[serde(default)]
    title: String,
    #[serde(default)]
    on: Vec<Spanned<String>>,
    #[serde(default)]
    off: Vec<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPlace {
    name: Spanned<String>,
    #[serde(default)]
    capacity: Option<Spanned<u8>>,
    #[serde(default)]
    sensor_fault: FaultClass,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLine {
    name: Spanned<String>,
    from: Spanned<String>,
    to: Spanned<String>,
    travel_s: Spanned<f64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStation {
    name: Spanned<String>,
    takes_from: Spanned<String>,
    cycle_s: Spanned<f64>,
}

#[derive(Deserialize, Clone, Copy)]
#[serde(rename_all = "lowercase")]
enum RawState {
    Drop,
    Hold,
}

impl From<RawState> for SafeState {
    fn from(s: RawState) -> Self {
        match s {
            RawState::Drop => SafeState::Off,
            RawState::Hold => SafeState::Hold,
        }
    }
}

#[derive(Deserialize)]
#[serde(untagged)]
enum RawSafe {
    All(RawState),
    Each {
        error: RawState,
        loss: RawState,
        stop: RawState,
        crash: RawState,
    },
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCoil {
    address: Spanned<u16>,
    signal: Spanned<String>,
    #[serde(default)]
    safe: Option<RawSafe>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawInput {
    address: Spanned<u16>,
    signal: Spanned<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFeedback {
    output: Spanned<String>,
    input: Spanned<String>,
    within_ms: Spanned<u64>,
    #[serde(default)]
    fault: FaultClass,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTwin {
    #[serde(default)]
    carriers: Option<Spanned<Vec<String>>>,
    #[serde(default)]
    run_empty_s: Option<Spanned<f64>>,
    #[serde(default)]
    inputs_on: Vec<Spanned<String>>,
}

/// Gathers problems with their lines.
struct Reader<'a> {
    text: &'a str,
    origin: &'a str,
    problems: Vec<Problem>,
}

impl Reader<'_> {
    fn line(&self, offset: usize) -> usize {
        self.text
            .get(..offset)
            .map_or(1, |t| t.matches('\n').count() + 1)
    }

    fn add<T>(&mut self, at: &Spanned<T>, message: String) {
        let line = self.line(at.span().start);
        self.problems.push(Problem {
            origin: self.origin.to_string(),
            line,
            message,
        });
    }

    fn seconds(&mut self, v: &Spanned<f64>, what: &str) -> Duration {
        let s = *v.get_ref();
        if !(s > 0.0 && s <= 3600.0) {
            self.add(v, format!("{what} must be between 0 and 3600 s, not {s}"));
            return Duration::from_secs(1);
        }
        Duration::from_secs_f64(s)
    }
}

/// A line name as the recipe language has it (`A`–`H`, `J`–`L`).
fn line_name(s: &str) -> Option<char> {
    falc_recipe::check::line_letter(s).ok()
}

/// `items` for a message: comma-separated, or `none`.
pub(crate) fn names<T: fmt::Display>(items: impl Iterator<Item = T>) -> String {
    let v: Vec<String> = items.map(|x| x.to_string()).collect();
    if v.is_empty() {
        "none".into()
    } else {
        v.join(", ")
    }
}

impl Spot {
    /// Parses `W2`, `place 2`, `S1`, `station 1` (any case).
    pub fn parse(s: &str) -> Option<Spot> {
        let s = s.trim().to_ascii_lowercase();
        let (kind, n) = if let Some(n) = s.strip_prefix("place ") {
            ('w', n.trim())
        } else if let Some(n) = s.strip_prefix("station ") {
            ('s', n.trim())
        } else {
            let mut c = s.chars();
            (c.next()?, c.as_str())
        };
        let n: u8 = n.parse().ok()?;
        match kind {
            'w' => Place::new(n).map(Spot::Place),
            's' => PlcStation::new(n).map(Spot::Station),
            _ => None,
        }
    }
}

impl Coil {
    /// Parses a coil's signal as the equipment file and the table name it
    /// (`button line A`, `button station 1`, `external control`).
    pub fn parse(s: &str) -> Option<Coil> {
        let lower = s.trim().to_ascii_lowercase();
        let words: Vec<&str> = lower.split_whitespace().collect();
        match words.as_slice() {
            ["button", "line", l] => line_name(l).map(|c| Coil::Button(Button::Line(c))),
            ["button", "station", n] => PlcStation::parse(n)
                .ok()
                .map(|n| Coil::Button(Button::Station(n))),
            ["external", "control"] => Some(Coil::ExternalControl),
            ["output", n] => IoName::parse(n)
                .ok()
                .map(|n| Coil::Button(Button::Output(n))),
            _ => None,
        }
    }
}

impl Input {
    /// Parses an input's signal as the equipment file and the table name
    /// it (`line A running`, `place 2 occupied`, `station 1 busy`, `PLC
    /// ready`, `emergency stop`).
    pub fn parse(s: &str) -> Option<Input> {
        let lower = s.trim().to_ascii_lowercase();
        let words: Vec<&str> = lower.split_whitespace().collect();
        match words.as_slice() {
            ["line", l, "running"] => line_name(l).map(|c| Input::Signal(Signal::Line(c))),
            ["place", n, "occupied"] => Place::parse(n)
                .ok()
                .map(|n| Input::Signal(Signal::Place(n))),
            ["station", n, "busy"] => PlcStation::parse(n)
                .ok()
                .map(|n| Input::Signal(Signal::Station(n))),
            ["plc", "ready"] => Some(Input::Ready),
            ["emergency", "stop"] => Some(Input::EStop),
            ["input", n] => IoName::parse(n)
                .ok()
                .map(|n| Input::Signal(Signal::Input(n))),
            _ => None,
        }
    }
}

const COIL_FORMS: &str = "`button line <line>`, `button station <station>`, \
     `external control` or `output <name>`";
const INPUT_FORMS: &str = "`line <line> running`, `place <place> occupied`, \
     `station <station> busy`, `PLC ready`, `emergency stop` or `input <name>`";

impl Equipment {
    /// The 1992 cell's conveyor (`equipment/conveyor-1992.toml`, built in).
    pub fn conveyor_1992() -> Arc<Equipment> {
        static ONE: OnceLock<Arc<Equipment>> = OnceLock::new();
        ONE.get_or_init(
            || match Equipment::parse(CONVEYOR_1992, CONVEYOR_1992_PATH) {
                Ok(e) => Arc::new(e),
                // The built-in file is checked by a unit test; a broken one
                // cannot be shipped.
                Err(p) => unreachable!("the built-in equipment file does not load: {p}"),
            },
        )
        .clone()
    }

    /// Reads and checks the file at `path`.
    pub fn load(path: &Path) -> Result<Equipment, Problems> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| {
            Problems(vec![Problem {
                origin: origin.clone(),
                line: 1,
                message: format!("cannot read the equipment file: {e}"),
            }])
        })?;
        Self::parse(&text, &origin)
    }

    /// The equipment of a transport stanza: the file it names, or the
    /// 1992 conveyor.
    pub fn of_stanza(path: Option<&Path>) -> Result<Arc<Equipment>, Problems> {
        match path {
            Some(p) => Self::load(p).map(Arc::new),
            None => Ok(Self::conveyor_1992()),
        }
    }

    /// The equipment of every transport station of `topology`, by name
    /// (the file its stanza names, else the 1992 conveyor); the first file
    /// that does not load is the error, naming the station.
    pub fn of_topology(
        topology: &Topology,
    ) -> Result<BTreeMap<StationName, Arc<Equipment>>, String> {
        let mut out = BTreeMap::new();
        for s in topology.stations() {
            if s.kind == StationKind::Transport {
                let e = Self::of_stanza(s.equipment.as_deref())
                    .map_err(|p| format!("the equipment of station {}:\n{p}", s.name))?;
                out.insert(s.name.clone(), e);
            }
        }
        Ok(out)
    }

    /// Checks `text` (named `origin` in problems).
    pub fn parse(text: &str, origin: &str) -> Result<Equipment, Problems> {
        let raw: RawFile = toml::from_str(text).map_err(|e| {
            let line = e.span().map_or(1, |s| {
                text.get(..s.start)
                    .map_or(1, |t| t.matches('\n').count() + 1)
            });
            Problems(vec![Problem {
                origin: origin.to_string(),
                line,
                message: e.message().trim().to_string(),
            }])
        })?;
        let mut r = Reader {
            text,
            origin,
            problems: Vec::new(),
        };
        let e = Self::build(&mut r, raw);
        if r.problems.is_empty() {
            Ok(e)
        } else {
            r.problems.sort_by_key(|p| p.line);
            Err(Problems(r.problems))
        }
    }

    fn build(r: &mut Reader<'_>, raw: RawFile) -> Equipment {
        let name = raw.name.get_ref().trim().to_string();
        if name.is_empty() {
            r.add(&raw.name, "the equipment needs a `name`".into());
        }
        // Places.
        let mut places: Vec<PlaceSpec> = Vec::new();
        for p in &raw.places {
            let Ok(place) = Place::parse(p.name.get_ref()) else {
                r.add(
                    &p.name,
                    format!(
                        "`{}` is not a place name: places are numbered {}–{}",
                        p.name.get_ref(),
                        Place::MIN,
                        Place::MAX
                    ),
                );
                continue;
            };
            if places.iter().any(|x| x.place == place) {
                r.add(&p.name, format!("place {place} is defined twice"));
                continue;
            }
            let capacity = match &p.capacity {
                Some(c) if *c.get_ref() == 0 => {
                    r.add(c, format!("place {place} must hold at least one carrier"));
                    1
                }
                Some(c) => usize::from(*c.get_ref()),
                None => 1,
            };
            places.push(PlaceSpec {
                place,
                capacity,
                sensor_fault: p.sensor_fault,
            });
        }
        let place_names = |places: &[PlaceSpec]| names(places.iter().map(|p| p.place));
        // Stations (before lines: a line may start at one).
        let mut stations: Vec<StationSpec> = Vec::new();
        // Every name defined, also of a part refused for another reason
        // (so that its signals are not refused as well).
        let mut declared: Vec<Thing> = places.iter().map(|p| Thing::Place(p.place)).collect();
        for s in &raw.stations {
            let Ok(station) = PlcStation::parse(s.name.get_ref()) else {
                r.add(
                    &s.name,
                    format!(
                        "`{}` is not a station name: stations are numbered {}–{}",
                        s.name.get_ref(),
                        PlcStation::MIN,
                        PlcStation::MAX
                    ),
                );
                continue;
            };
            if stations.iter().any(|x| x.station == station) {
                r.add(&s.name, format!("station {station} is defined twice"));
                continue;
            }
            declared.push(Thing::Station(station));
            let takes_from = match Spot::parse(s.takes_from.get_ref()) {
                Some(Spot::Place(p)) if places.iter().any(|x| x.place == p) => p,
                _ => {
                    r.add(
                        &s.takes_from,
                        format!(
                            "station {station} takes its carrier from `{}`, which is no place \
                             of this equipment (places: {})",
                            s.takes_from.get_ref(),
                            place_names(&places)
                        ),
                    );
                    continue;
                }
            };
            let cycle = r.seconds(&s.cycle_s, "cycle_s");
            stations.push(StationSpec {
                station,
                takes_from,
                cycle,
            });
        }
        let spot_names = |places: &[PlaceSpec], stations: &[StationSpec]| {
            names(
                places
                    .iter()
                    .map(|p| Spot::Place(p.place))
                    .chain(stations.iter().map(|s| Spot::Station(s.station))),
            )
        };
        let known = |spot: Spot, places: &[PlaceSpec], stations: &[StationSpec]| match spot {
            Spot::Place(p) => places.iter().any(|x| x.place == p),
            Spot::Station(s) => stations.iter().any(|x| x.station == s),
        };
        // Lines.
        let mut lines: Vec<LineSpec> = Vec::new();
        for l in &raw.lines {
            let Some(line) = line_name(l.name.get_ref()) else {
                r.add(
                    &l.name,
                    format!(
                        "`{}` is not a line name: a line is a letter A–Z but I and O",
                        l.name.get_ref()
                    ),
                );
                continue;
            };
            if lines.iter().any(|x| x.line == line) {
                r.add(&l.name, format!("line {line} is defined twice"));
                continue;
            }
            declared.push(Thing::Line(line));
            let mut end = |at: &Spanned<String>, what: &str| -> Option<Spot> {
                match Spot::parse(at.get_ref()) {
                    Some(s) if known(s, &places, &stations) => Some(s),
                    _ => {
                        r.add(
                            at,
                            format!(
                                "line {line} runs {what} `{}`, which is no place or station of \
                                 this equipment (there are: {})",
                                at.get_ref(),
                                spot_names(&places, &stations)
                            ),
                        );
                        None
                    }
                }
            };
            let from = end(&l.from, "from");
            let to = end(&l.to, "to");
            let (Some(from), Some(to)) = (from, to) else {
                continue;
            };
            if let Spot::Station(_) = to {
                r.add(
                    &l.to,
                    format!(
                        "line {line} runs to station `{}`: a station takes its carrier from \
                         its place (`takes_from`), a line runs to a place",
                        l.to.get_ref()
                    ),
                );
                continue;
            }
            if from == to {
                r.add(&l.to, format!("line {line} runs from {from} to itself"));
                continue;
            }
            let travel = r.seconds(&l.travel_s, "travel_s");
            lines.push(LineSpec {
                line,
                from,
                to,
                travel,
            });
        }
        // Signals.
        let mut coils: Vec<CoilSpec> = Vec::new();
        let mut coil_lines: Vec<usize> = Vec::new();
        for c in &raw.coils {
            let Some(coil) = Coil::parse(c.signal.get_ref()) else {
                r.add(
                    &c.signal,
                    format!(
                        "`{}` is not a coil signal: write {COIL_FORMS}",
                        c.signal.get_ref()
                    ),
                );
                continue;
            };
            if let Some(thing) = coil_thing(coil).filter(|t| !declared.contains(t)) {
                r.add(&c.signal, Self::no_such(thing, &lines, &places, &stations));
                continue;
            }
            let address = *c.address.get_ref();
            if let Some(i) = coils.iter().position(|x| x.address == address) {
                let at = coil_lines[i];
                r.add(
                    &c.address,
                    format!(
                        "coil {address} is used twice: by `{coil}` and, on line {at}, by `{}`",
                        coils[i].coil
                    ),
                );
                continue;
            }
            if let Some(i) = coils.iter().position(|x| x.coil == coil) {
                r.add(
                    &c.signal,
                    format!("`{coil}` has two coils: {} and {address}", coils[i].address),
                );
                continue;
            }
            // A line stops and a plain output goes off; a clamp and
            // external control stay.
            let default = match coil {
                Coil::Button(Button::Line(_) | Button::Output(_)) => SafeState::Off,
                _ => SafeState::Hold,
            };
            let safe = match c.safe {
                None => SafeStates::all(default),
                Some(RawSafe::All(s)) => SafeStates::all(s.into()),
                Some(RawSafe::Each {
                    error,
                    loss,
                    stop,
                    crash,
                }) => SafeStates {
                    error: error.into(),
                    loss: loss.into(),
                    stop: stop.into(),
                    crash: crash.into(),
                },
            };
            coil_lines.push(r.line(c.address.span().start));
            coils.push(CoilSpec {
                address,
                coil,
                safe,
            });
        }
        let mut inputs: Vec<InputSpec> = Vec::new();
        let mut input_lines: Vec<usize> = Vec::new();
        for i in &raw.inputs {
            let Some(input) = Input::parse(i.signal.get_ref()) else {
                r.add(
                    &i.signal,
                    format!(
                        "`{}` is not an input signal: write {INPUT_FORMS}",
                        i.signal.get_ref()
                    ),
                );
                continue;
            };
            if let Some(thing) = input_thing(input).filter(|t| !declared.contains(t)) {
                r.add(&i.signal, Self::no_such(thing, &lines, &places, &stations));
                continue;
            }
            let address = *i.address.get_ref();
            if let Some(k) = inputs.iter().position(|x| x.address == address) {
                let at = input_lines[k];
                r.add(
                    &i.address,
                    format!(
                        "discrete input {address} is used twice: by `{input}` and, on line {at}, by `{}`",
                        inputs[k].input
                    ),
                );
                continue;
            }
            if let Some(k) = inputs.iter().position(|x| x.input == input) {
                r.add(
                    &i.signal,
                    format!(
                        "`{input}` has two inputs: {} and {address}",
                        inputs[k].address
                    ),
                );
                continue;
            }
            input_lines.push(r.line(i.address.span().start));
            inputs.push(InputSpec { address, input });
        }
        // Every part of the layout needs its signals.
        let name_span = &raw.name;
        let need = |r: &mut Reader<'_>, ok: bool, what: String| {
            if !ok {
                r.add(name_span, what);
            }
        };
        for l in &lines {
            let b = Coil::Button(Button::Line(l.line));
            let s = Input::Signal(Signal::Line(l.line));
            need(
                r,
                coils.iter().any(|c| c.coil == b),
                format!("line {} has no coil `{b}`", l.line),
            );
            need(
                r,
                inputs.iter().any(|i| i.input == s),
                format!("line {} has no input `{s}`", l.line),
            );
        }
        for p in &places {
            let s = Input::Signal(Signal::Place(p.place));
            need(
                r,
                inputs.iter().any(|i| i.input == s),
                format!("place {} has no input `{s}`", p.place),
            );
        }
        for st in &stations {
            let b = Coil::Button(Button::Station(st.station));
            let s = Input::Signal(Signal::Station(st.station));
            need(
                r,
                coils.iter().any(|c| c.coil == b),
                format!("station {} has no coil `{b}`", st.station),
            );
            need(
                r,
                inputs.iter().any(|i| i.input == s),
                format!("station {} has no input `{s}`", st.station),
            );
        }
        for (ok, what) in [
            (
                coils.iter().any(|c| c.coil == Coil::ExternalControl),
                "a coil `external control`",
            ),
            (
                inputs.iter().any(|i| i.input == Input::Ready),
                "an input `PLC ready`",
            ),
            (
                inputs.iter().any(|i| i.input == Input::EStop),
                "an input `emergency stop`",
            ),
        ] {
            need(r, ok, format!("the equipment needs {what}"));
        }
        // Feedback.
        let mut feedback = Vec::new();
        for f in &raw.feedback {
            let output =
                Coil::parse(f.output.get_ref()).filter(|c| coils.iter().any(|x| x.coil == *c));
            let input =
                Input::parse(f.input.get_ref()).filter(|i| inputs.iter().any(|x| x.input == *i));
            if output.is_none() {
                r.add(
                    &f.output,
                    format!(
                        "feedback of `{}`: no coil of this equipment is that (coils: {})",
                        f.output.get_ref(),
                        names(coils.iter().map(|c| c.coil))
                    ),
                );
            }
            if input.is_none() {
                r.add(
                    &f.input,
                    format!(
                        "feedback `{}`: no input of this equipment is that (inputs: {})",
                        f.input.get_ref(),
                        names(inputs.iter().map(|i| i.input))
                    ),
                );
            }
            let within = *f.within_ms.get_ref();
            if !(1..=600_000).contains(&within) {
                r.add(
                    &f.within_ms,
                    format!("within_ms must be 1–600000, not {within}"),
                );
            }
            if let (Some(output), Some(input)) = (output, input) {
                feedback.push(FeedbackSpec {
                    output,
                    input,
                    within: Duration::from_millis(within),
                    fault: f.fault,
                });
            }
        }
        let states = Self::named_states(r, &raw.states, &inputs);
        // The twin.
        let mut carriers = Vec::new();
        let mut run_empty = Duration::from_secs(20);
        let mut inputs_on = Vec::new();
        if let Some(t) = &raw.twin {
            if let Some(c) = &t.carriers {
                for w in c.get_ref() {
                    match Spot::parse(w) {
                        Some(s) if known(s, &places, &stations) => carriers.push(s),
                        _ => r.add(
                            c,
                            format!(
                                "a carrier of the twin starts at `{w}`, which is no place or \
                                 station of this equipment (there are: {})",
                                spot_names(&places, &stations)
                            ),
                        ),
                    }
                }
            }
            if let Some(s) = &t.run_empty_s {
                run_empty = r.seconds(s, "run_empty_s");
            }
            for n in &t.inputs_on {
                match Input::parse(&format!("input {}", n.get_ref())) {
                    Some(Input::Signal(Signal::Input(name)))
                        if inputs
                            .iter()
                            .any(|i| i.input == Input::Signal(Signal::Input(name))) =>
                    {
                        inputs_on.push(name)
                    }
                    _ => r.add(
                        n,
                        format!(
                            "the twin's `inputs_on` names `{}`, which is no plain input of this \
                             equipment (plain inputs: {})",
                            n.get_ref(),
                            names(inputs.iter().filter_map(|i| plain_input(i.input)))
                        ),
                    ),
                }
            }
        }
        coils.sort_by_key(|c| c.address);
        inputs.sort_by_key(|i| i.address);
        Equipment {
            input_keys: keys(&inputs, |i| input_key(i.input)),
            coil_keys: keys(&coils, |c| coil_key(c.coil)),
            name,
            title: raw.title,
            origin: r.origin.to_string(),
            places,
            lines,
            stations,
            coils,
            inputs,
            feedback,
            states,
            carriers,
            run_empty,
            inputs_on,
        }
    }

    /// The `[[state]]` tables: a name each (a lower-case word, once), and
    /// inputs of this equipment, each on or off, none both.
    fn named_states(
        r: &mut Reader<'_>,
        raw: &[RawNamedState],
        inputs: &[InputSpec],
    ) -> Vec<NamedState> {
        let mut out: Vec<NamedState> = Vec::new();
        for s in raw {
            let name = s.name.get_ref().trim().to_string();
            let word = !name.is_empty()
                && name.len() <= 32
                && name.starts_with(|c: char| c.is_ascii_lowercase())
                && name
                    .chars()
                    .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
            if !word {
                r.add(
                    &s.name,
                    format!(
                        "`{name}` is not a state name: a lower-case word (a-z, 0-9, _; at \
                         most 32), like `home`"
                    ),
                );
                continue;
            }
            if out.iter().any(|x| x.name == name) {
                r.add(&s.name, format!("state {name} is defined twice"));
                continue;
            }
            let read = |list: &[Spanned<String>], r: &mut Reader<'_>| -> Vec<Input> {
                let mut got = Vec::new();
                for i in list {
                    match Input::parse(i.get_ref()).filter(|x| inputs.iter().any(|y| y.input == *x))
                    {
                        Some(x) => got.push(x),
                        None => r.add(
                            i,
                            format!(
                                "state {name}: `{}` is no input of this equipment (inputs: {})",
                                i.get_ref(),
                                names(inputs.iter().map(|x| x.input))
                            ),
                        ),
                    }
                }
                got
            };
            let on = read(&s.on, r);
            let off = read(&s.off, r);
            if let Some(both) = on.iter().find(|i| off.contains(i)) {
                r.add(
                    &s.name,
                    format!("state {name} lists `{both}` both on and off"),
                );
                continue;
            }
            if s.on.is_empty() && s.off.is_empty() {
                r.add(
                    &s.name,
                    format!("state {name} lists no input: give `on` and `off`"),
                );
                continue;
            }
            out.push(NamedState {
                name,
                title: s.title.clone(),
                on,
                off,
            });
        }
        out
    }

    fn no_such(
        thing: Thing,
        lines: &[LineSpec],
        places: &[PlaceSpec],
        stations: &[StationSpec],
    ) -> String {
        match thing {
            Thing::Line(l) => format!(
                "line {l} is not in the layout (lines: {})",
                names(lines.iter().map(|x| x.line))
            ),
            Thing::Place(p) => format!(
                "place {p} is not in the layout (places: {})",
                names(places.iter().map(|x| x.place))
            ),
            Thing::Station(s) => format!(
                "station {s} is not in the layout (stations: {})",
                names(stations.iter().map(|x| x.station))
            ),
        }
    }

    /// Its `name`.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Its plain inputs (`input NAME`), by address.
    pub fn plain_inputs(&self) -> impl Iterator<Item = IoName> + '_ {
        self.inputs.iter().filter_map(|i| plain_input(i.input))
    }

    /// Its plain outputs (`output NAME`), by address.
    pub fn plain_outputs(&self) -> impl Iterator<Item = IoName> + '_ {
        self.coils.iter().filter_map(|c| match c.coil {
            Coil::Button(Button::Output(n)) => Some(n),
            _ => None,
        })
    }

    /// The plain inputs the twin starts with on (`[twin] inputs_on`).
    pub fn inputs_on(&self) -> &[IoName] {
        &self.inputs_on
    }

    /// Its named states (`[[state]]`), in file order.
    pub fn states(&self) -> &[NamedState] {
        &self.states
    }

    /// Its `title`.
    pub fn title(&self) -> &str {
        &self.title
    }

    /// The file it was read from.
    pub fn origin(&self) -> &str {
        &self.origin
    }

    /// The places, in file order.
    pub fn places(&self) -> &[PlaceSpec] {
        &self.places
    }

    /// The lines, in file order.
    pub fn lines(&self) -> &[LineSpec] {
        &self.lines
    }

    /// The stations, in file order.
    pub fn stations(&self) -> &[StationSpec] {
        &self.stations
    }

    /// The coils, by address.
    pub fn coils(&self) -> &[CoilSpec] {
        &self.coils
    }

    /// The discrete inputs, by address.
    pub fn inputs(&self) -> &[InputSpec] {
        &self.inputs
    }

    /// The actuators' feedback.
    pub fn feedback(&self) -> &[FeedbackSpec] {
        &self.feedback
    }

    /// Where the twin's carriers start, carrier 1 first.
    pub fn carriers(&self) -> &[Spot] {
        &self.carriers
    }

    /// How long the twin runs a line pressed with no carrier.
    pub fn run_empty(&self) -> Duration {
        self.run_empty
    }

    /// The line named `l`.
    pub fn line(&self, l: char) -> Option<&LineSpec> {
        self.lines.iter().find(|x| x.line == l)
    }

    /// The station named `s`.
    pub fn station(&self, s: PlcStation) -> Option<&StationSpec> {
        self.stations.iter().find(|x| x.station == s)
    }

    /// The place named `p`.
    pub fn place(&self, p: Place) -> Option<&PlaceSpec> {
        self.places.iter().find(|x| x.place == p)
    }

    /// The place station `s` takes its carrier from.
    pub fn feed(&self, s: PlcStation) -> Option<Spot> {
        self.station(s).map(|x| Spot::Place(x.takes_from))
    }

    /// How many carriers `spot` holds (a station: one).
    pub fn capacity(&self, spot: Spot) -> usize {
        match spot {
            Spot::Place(p) => self.place(p).map_or(1, |x| x.capacity),
            Spot::Station(_) => 1,
        }
    }

    /// The lines that bring a carrier to `place`.
    pub fn moves_towards(&self, place: Place) -> impl Iterator<Item = char> + '_ {
        self.lines
            .iter()
            .filter(move |l| l.to == Spot::Place(place))
            .map(|l| l.line)
    }

    /// The lines that take a carrier away from `place`.
    pub fn moves_away(&self, place: Place) -> impl Iterator<Item = char> + '_ {
        self.lines
            .iter()
            .filter(move |l| l.from == Spot::Place(place))
            .map(|l| l.line)
    }

    /// The coil of `coil`, if the equipment has it.
    pub fn coil(&self, coil: Coil) -> Option<&CoilSpec> {
        self.coil_index(coil).map(|i| &self.coils[i])
    }

    /// The index of `coil` among [`Equipment::coils`].
    pub fn coil_index(&self, coil: Coil) -> Option<usize> {
        let Some(key) = coil_key(coil) else {
            return self.coils.iter().position(|c| c.coil == coil);
        };
        match self.coil_keys.get(key) {
            Some(&i) if i != NONE => Some(usize::from(i)),
            _ => None,
        }
    }

    /// The coil at `address`.
    pub fn coil_at(&self, address: u16) -> Option<Coil> {
        self.coils
            .binary_search_by_key(&address, |c| c.address)
            .ok()
            .map(|i| self.coils[i].coil)
    }

    /// The index of `input` among [`Equipment::inputs`].
    pub fn input_index(&self, input: Input) -> Option<usize> {
        let Some(key) = input_key(input) else {
            return self.inputs.iter().position(|i| i.input == input);
        };
        match self.input_keys.get(key) {
            Some(&i) if i != NONE => Some(usize::from(i)),
            _ => None,
        }
    }

    /// `coil`'s safe state on `occasion` (drop for a coil it lacks).
    pub fn safe(&self, coil: Coil, occasion: Occasion) -> SafeState {
        self.coil(coil)
            .map_or(SafeState::Off, |c| c.safe.on(occasion))
    }

    /// The lowest coil address and the number of addresses up to the
    /// highest (one Modbus read covers them all).
    pub fn coil_span(&self) -> (u16, u16) {
        span(self.coils.iter().map(|c| c.address))
    }

    /// The same for the discrete inputs.
    pub fn input_span(&self) -> (u16, u16) {
        span(self.inputs.iter().map(|i| i.address))
    }

    /// Whether the recipe signal `s` is one of this equipment's.
    pub fn has_signal(&self, s: Signal) -> bool {
        self.input_index(Input::Signal(s)).is_some()
    }

    /// Whether the recipe button `b` is one of this equipment's.
    pub fn has_button(&self, b: Button) -> bool {
        self.coil(Coil::Button(b)).is_some()
    }

    /// The I/O table for a PLC programmer, as Markdown, with every address
    /// moved by `coil_shift` / `input_shift` (0: as in the file).
    pub fn table(&self, coil_shift: u16, input_shift: u16) -> String {
        let mut out = String::from("| kind | address | signal | safe state |\n|---|---|---|---|\n");
        for c in &self.coils {
            out += &format!(
                "| coil | {} | {} | {} |\n",
                u32::from(c.address) + u32::from(coil_shift),
                c.coil,
                c.safe
            );
        }
        for i in &self.inputs {
            out += &format!(
                "| discrete input | {} | {} | |\n",
                u32::from(i.address) + u32::from(input_shift),
                i.input
            );
        }
        out
    }

    /// The layout as Markdown: each line's route and twin travel time,
    /// each station's place and cycle time, each place's capacity and
    /// sensor fault, each named state's inputs.
    pub fn layout_table(&self) -> String {
        let mut out = String::from("| line | from | to | travel |\n|---|---|---|---|\n");
        for l in &self.lines {
            out += &format!(
                "| {} | {} | {} | {} s |\n",
                l.line,
                l.from,
                l.to,
                l.travel.as_secs_f64()
            );
        }
        out += "\n| station | takes from | cycle |\n|---|---|---|\n";
        for s in &self.stations {
            out += &format!(
                "| {} | W{} | {} s |\n",
                s.station,
                s.takes_from,
                s.cycle.as_secs_f64()
            );
        }
        out += "\n| place | holds | sensor fault |\n|---|---|---|\n";
        for p in &self.places {
            out += &format!(
                "| W{} | {} | {} |\n",
                p.place,
                p.capacity,
                match p.sensor_fault {
                    FaultClass::Alarm => "alarm",
                    FaultClass::Warning => "warning",
                }
            );
        }
        if !self.states.is_empty() {
            out += "\n| state | on | off |\n|---|---|---|\n";
            for s in &self.states {
                let list = |v: &[Input]| names(v.iter());
                out += &format!("| {} | {} | {} |\n", s.name, list(&s.on), list(&s.off));
            }
        }
        out
    }
}

fn span(addresses: impl Iterator<Item = u16>) -> (u16, u16) {
    let (mut lo, mut hi) = (u16::MAX, 0u16);
    let mut any = false;
    for a in addresses {
        any = true;
        lo = lo.min(a);
        hi = hi.max(a);
    }
    if any {
        (lo, hi - lo + 1)
    } else {
        (0, 0)
    }
}

/// The name of `i` if it is a plain input.
fn plain_input(i: Input) -> Option<IoName> {
    match i {
        Input::Signal(Signal::Input(n)) => Some(n),
        _ => None,
    }
}

/// A part of the layout a signal belongs to.
#[derive(PartialEq)]
enum Thing {
    Line(char),
    Place(Place),
    Station(PlcStation),
}

/// The part of the layout coil `c` belongs to (none: the PLC's own).
fn coil_thing(c: Coil) -> Option<Thing> {
    match c {
        Coil::Button(Button::Line(l)) => Some(Thing::Line(l)),
        Coil::Button(Button::Station(s)) => Some(Thing::Station(s)),
        Coil::Button(Button::Output(_)) | Coil::ExternalControl => None,
    }
}

/// The part of the layout input `i` belongs to (none: the PLC's own).
fn input_thing(i: Input) -> Option<Thing> {
    match i {
        Input::Signal(Signal::Line(l)) => Some(Thing::Line(l)),
        Input::Signal(Signal::Place(p)) => Some(Thing::Place(p)),
        Input::Signal(Signal::Station(s)) => Some(Thing::Station(s)),
        Input::Signal(Signal::Input(_)) | Input::Ready | Input::EStop => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::signal::{S, W};

    fn problems(text: &str) -> Vec<String> {
        match Equipment::parse(text, "eq.toml") {
            Ok(_) => Vec::new(),
            Err(p) => p.0.iter().map(Problem::to_string).collect(),
        }
    }

    /// A small conveyor: two places, one line each way, one station.
    const SMALL: &str = include_str!("../tests/fixtures/small.toml");

    #[test]
    fn the_1992_conveyor_is_the_built_in_file() {
        let e = Equipment::conveyor_1992();
        assert_eq!(e.name(), "conveyor-1992");
        let routes: Vec<(char, Spot, Spot)> =
            e.lines().iter().map(|l| (l.line, l.from, l.to)).collect();
        assert_eq!(
            routes,
            [
                ('A', W(6), W(2)),
                ('B', W(2), W(6)),
                ('C', S(1), W(6)),
                ('D', W(4), W(2)),
                ('E', W(2), W(5)),
                ('F', S(3), W(4)),
                ('G', W(5), W(4)),
                ('H', W(3), W(5)),
                ('J', S(2), W(3)),
                ('K', W(2), W(3)),
                ('L', W(3), W(4)),
            ]
        );
        let feeds: Vec<Option<Spot>> = (1..=4).map(|s| e.feed(PlcStation::of(s))).collect();
        assert_eq!(feeds, [Some(W(6)), Some(W(3)), Some(W(5)), None]);
        assert_eq!(e.capacity(W(2)), 2);
        assert_eq!(e.capacity(W(3)), 1);
        assert_eq!(e.coil_span(), (0, 15));
        assert_eq!(e.input_span(), (0, 21));
        assert_eq!(e.carriers(), [W(2), W(2)]);
        assert!(e
            .places()
            .iter()
            .all(|p| p.sensor_fault == FaultClass::Alarm));
        let line_a = Coil::Button(Button::Line('A'));
        let clamp = Coil::Button(Button::Station(PlcStation::of(3)));
        for o in [
            Occasion::Error,
            Occasion::Loss,
            Occasion::Stop,
            Occasion::Crash,
        ] {
            assert_eq!(e.safe(line_a, o), SafeState::Off);
            assert_eq!(e.safe(clamp, o), SafeState::Hold);
            assert_eq!(e.safe(Coil::ExternalControl, o), SafeState::Hold);
        }
        // The file's own path, for the docs and the messages.
        assert_eq!(e.origin(), CONVEYOR_1992_PATH);
    }

    #[test]
    fn a_small_conveyor_loads_with_its_gaps() {
        let e = Equipment::parse(SMALL, "eq.toml").expect("loads");
        assert_eq!(e.coil_span(), (0, 9));
        assert_eq!(e.coil_at(8), Some(Coil::ExternalControl));
        assert_eq!(e.coil_at(5), None);
        assert_eq!(e.moves_towards(Place::of(3)).collect::<Vec<_>>(), ['A']);
        assert_eq!(e.moves_away(Place::of(3)).collect::<Vec<_>>(), ['B']);
        assert!(e.carriers().is_empty());
        assert!(!e.has_button(Button::Line('C')));
        assert!(e.has_signal(Signal::Station(PlcStation::of(1))));
    }

    #[test]
    fn an_address_used_twice_names_both_signals_and_lines() {
        let text = SMALL.replace(
            "address = 1\nsignal = \"button line B\"",
            "address = 0\nsignal = \"button line B\"",
        );
        assert_eq!(
            problems(&text),
            ["eq.toml:32: coil 0 is used twice: by `button line B` and, on line 28, by `button line A`",
             "eq.toml:1: line B has no coil `button line B`"]
                .map(String::from)
                .to_vec()
                .into_iter()
                .rev()
                .collect::<Vec<_>>()
        );
        let text = SMALL.replace(
            "address = 6\nsignal = \"emergency stop\"",
            "address = 5\nsignal = \"emergency stop\"",
        );
        let p = problems(&text);
        assert!(
            p.iter().any(|p| p.starts_with("eq.toml:68: discrete input 5 is used twice: by `emergency stop` and, on line 64, by `PLC ready`")),
            "{p:?}"
        );
    }

    #[test]
    fn a_route_to_an_unknown_place_names_the_places_there_are() {
        let text = SMALL.replace("to = \"W3\"", "to = \"W7\"");
        let p = problems(&text);
        assert!(
            p.contains(&"eq.toml:13: line A runs to `W7`, which is no place or station of this equipment (there are: W2, W3, S1)".to_string()),
            "{p:?}"
        );
        let text = SMALL.replace("takes_from = \"W3\"", "takes_from = \"W4\"");
        let p = problems(&text);
        assert!(
            p.contains(&"eq.toml:24: station 1 takes its carrier from `W4`, which is no place of this equipment (places: 2, 3)".to_string()),
            "{p:?}"
        );
    }

    #[test]
    fn a_feedback_naming_no_signal_names_the_signals_there_are() {
        let text = format!(
            "{SMALL}\n[[feedback]]\noutput = \"button line A\"\ninput = \"line C running\"\nwithin_ms = 500\n"
        );
        let p = problems(&text);
        assert_eq!(p.len(), 1, "{p:?}");
        assert!(
            p[0].starts_with("eq.toml:73: feedback `line C running`: no input of this equipment is that (inputs: line A running, line B running, place 2 occupied"),
            "{p:?}"
        );
        let text = format!(
            "{SMALL}\n[[feedback]]\noutput = \"the horn\"\ninput = \"line A running\"\nwithin_ms = 500\nfault = \"warning\"\n"
        );
        let p = problems(&text);
        assert!(
            p[0].starts_with("eq.toml:72: feedback of `the horn`: no coil of this equipment is that (coils: button line A, button line B, button station 1, external control)"),
            "{p:?}"
        );
        let good = format!(
            "{SMALL}\n[[feedback]]\noutput = \"button line A\"\ninput = \"line A running\"\nwithin_ms = 500\nfault = \"warning\"\n"
        );
        let e = Equipment::parse(&good, "eq.toml").expect("loads");
        assert_eq!(
            e.feedback(),
            [FeedbackSpec {
                output: Coil::Button(Button::Line('A')),
                input: Input::Signal(Signal::Line('A')),
                within: Duration::from_millis(500),
                fault: FaultClass::Warning,
            }]
        );
    }

    #[test]
    fn a_signal_of_no_part_of_the_layout_and_a_missing_signal_are_refused() {
        let text = SMALL.replace("signal = \"station 1 busy\"", "signal = \"station 2 busy\"");
        let p = problems(&text);
        assert!(
            p.contains(&"eq.toml:61: station 2 is not in the layout (stations: 1)".to_string()),
            "{p:?}"
        );
        assert!(
            p.contains(&"eq.toml:1: station 1 has no input `station 1 busy`".to_string()),
            "{p:?}"
        );
        let text = SMALL.replace("signal = \"PLC ready\"", "signal = \"ready lamp\"");
        let p = problems(&text);
        assert!(
            p.iter()
                .any(|p| p.starts_with("eq.toml:65: `ready lamp` is not an input signal: write")),
            "{p:?}"
        );
    }

    #[test]
    fn named_states_name_inputs_of_the_file_each_on_or_off() {
        let base = SMALL.lines().count();
        let text = format!(
            "{SMALL}\n[[state]]\nname = \"home\"\non = [\"place 2 occupied\"]\n\
             off = [\"place 3 occupied\", \"line C running\"]\n\
             \n[[state]]\nname = \"Home Base\"\non = [\"place 2 occupied\"]\n\
             \n[[state]]\nname = \"both\"\non = [\"place 2 occupied\"]\noff = [\"place 2 occupied\"]\n\
             \n[[state]]\nname = \"home\"\non = [\"place 3 occupied\"]\n\
             \n[[state]]\nname = \"blank\"\n"
        );
        let p = problems(&text);
        let at = |n: usize| format!("eq.toml:{}: ", base + n);
        assert_eq!(
            p,
            [
                format!(
                    "{}state home: `line C running` is no input of this equipment (inputs: \
                     line A running, line B running, place 2 occupied, place 3 occupied, \
                     station 1 busy, PLC ready, emergency stop)",
                    at(5)
                ),
                format!(
                    "{}`Home Base` is not a state name: a lower-case word (a-z, 0-9, _; at \
                     most 32), like `home`",
                    at(8)
                ),
                format!(
                    "{}state both lists `place 2 occupied` both on and off",
                    at(12)
                ),
                format!("{}state home is defined twice", at(17)),
                format!("{}state blank lists no input: give `on` and `off`", at(21)),
            ]
        );
        let good = format!(
            "{SMALL}\n[[state]]\nname = \"home\"\ntitle = \"at W2\"\non = [\"place 2 occupied\"]\n\
             off = [\"place 3 occupied\", \"line A running\"]\n"
        );
        let e = Equipment::parse(&good, "eq.toml").expect("loads");
        assert_eq!(
            e.states(),
            [NamedState {
                name: "home".into(),
                title: "at W2".into(),
                on: vec![Input::Signal(Signal::Place(Place::of(2)))],
                off: vec![
                    Input::Signal(Signal::Place(Place::of(3))),
                    Input::Signal(Signal::Line('A'))
                ],
            }]
        );
    }

    #[test]
    fn syntax_and_unknown_keys_name_their_line() {
        let p = problems("name = \"x\"\n\n[[line]]\nname = \"A\"\nfrom = \"W2\"\nspeed = 3\n");
        assert_eq!(p.len(), 1, "{p:?}");
        assert!(
            p[0].starts_with("eq.toml:6: unknown field `speed`"),
            "{p:?}"
        );
        let p = problems("name = \"x\"\n[[place]\n");
        assert!(p[0].starts_with("eq.toml:2: "), "{p:?}");
    }

    #[test]
    fn the_tables_in_docs_plc_md_are_the_shipped_files() {
        let doc = include_str!("../../../docs/plc.md");
        let table = Equipment::conveyor_1992().table(0, 0);
        assert!(
            doc.contains(&table),
            "docs/plc.md must carry the table `falc-transport io --map` prints:\n{table}"
        );
        let layout = Equipment::conveyor_1992().layout_table();
        assert!(
            doc.contains(&layout),
            "docs/plc.md must carry the layout table of the 1992 conveyor:\n{layout}"
        );
        // The second shipped layout, the in/out cell's.
        let inout = Equipment::parse(
            include_str!("../../../equipment/conveyor-inout.toml"),
            "equipment/conveyor-inout.toml",
        )
        .unwrap_or_else(|p| panic!("{p}"));
        for table in [inout.table(0, 0), inout.layout_table()] {
            assert!(
                doc.contains(&table),
                "docs/plc.md must carry the in/out conveyor's table:\n{table}"
            );
        }
    }
}
