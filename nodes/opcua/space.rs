//! The gateway's address space, and what fills it, without I/O: the node
//! of every value and method ([`Scope`], [`Method`], [`layout()`]), the
//! values of one look at a cell or the plant ([`values`]: status, order
//! list, journal), and the [`Mirror`] that turns successive looks into the
//! changes to publish and the alarm events to raise. The server side
//! (`server.rs`) only writes what this module computes.
//!
//! One cell (a plant of one):
//!
//! ```text
//! Objects/FALC                      the cell (PackML state, mode, order …)
//! Objects/FALC/<methods>            AddOrder, RemoveOrder, Start, Stop, Acknowledge, Answer
//! Objects/FALC/Orders               Ids, Recipes, States, Results
//! Objects/FALC/Journal              Ids, Times, Kinds, Who, Texts (the last entries)
//! Objects/FALC/Alarms               Ids, Texts (every listed alarm)
//! Objects/FALC/Admin                PackML Admin: ProdProcessedCount, ProdDefectiveCount,
//!                                   StopReason, StateCumulativeTime (ms) with StateNames
//! Objects/FALC/Stations/<station>   Connected, Kind, Program, RecipeState, … per kind
//! ```
//!
//! A plant of several cells: the plant object, and under it one object
//! per cell laid out as the one cell above, each with its own PackML
//! state, methods and alarm events:
//!
//! ```text
//! Objects/FALC                      the plant (OperatorReachable, Cells, Queued, LastRefusal)
//! Objects/FALC/<methods>            the same six, as `falc` without --cell does them
//! Objects/FALC/Orders               Ids, Recipes, States, Results, Cells (every order)
//! Objects/FALC/<cell>               cell <cell>, as Objects/FALC of one cell
//! ```

use crate::machinery::Machine;
use crate::packml;
use falc_equipment::Equipment;
use falc_model::alarm::{Alarm, AlarmClass};
use falc_model::api::{ApiReply, ApiRequest, Call, CellStatus};
use falc_model::figures::CellFigures;
use falc_model::ids::{CellId, StationName};
use falc_model::mms::vmd::VmdStatus;
use falc_model::records::{Entry, Order, OrderState};
use falc_model::topology::StationKind;
use falc_plc::map::Inputs;
use std::collections::{BTreeMap, BTreeSet, HashMap, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The prefix of every node id of the gateway's namespace.
pub const ROOT: &str = "FALC";

/// One object of the address space with the methods on it: a cell (the
/// one cell, or one of a plant's), or the plant above several cells.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Scope {
    /// Its node id, the prefix of every node under it (`FALC`,
    /// `FALC.falc2`).
    pub root: String,
    /// What it is.
    pub part: Part,
    /// A cell as a machine of OPC UA Machinery (the plant's scope has
    /// none).
    pub machine: Option<Machine>,
}

/// What a [`Scope`] is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Part {
    /// A cell and its stations; `id` names it in a plant of several (None:
    /// the one cell, whose calls name no cell).
    Cell {
        /// The cell of a plant.
        id: Option<CellId>,
        /// Its stations.
        stations: Vec<(StationName, StationKind)>,
        /// Its transport stations' equipment (absent: the 1992 conveyor).
        equipment: BTreeMap<StationName, Arc<Equipment>>,
    },
    /// The plant above these cells.
    Plant {
        /// Its cells, in the plant file's order.
        cells: Vec<CellId>,
    },
}

impl Scope {
    /// The one cell of a single-cell topology: everything under `FALC`.
    pub fn one_cell(stations: Vec<(StationName, StationKind)>) -> Vec<Scope> {
        vec![Scope {
            root: ROOT.into(),
            part: Part::Cell {
                id: None,
                stations,
                equipment: BTreeMap::new(),
            },
            machine: None,
        }]
    }

    /// A plant of several cells: the plant (`FALC`) first, then each cell
    /// under it (`FALC.<cell>`). A cell id is lower case and every name of
    /// the plant object's own nodes is capitalised, so no cell's object is
    /// one of them.
    pub fn plant(cells: Vec<(CellId, Vec<(StationName, StationKind)>)>) -> Vec<Scope> {
        let mut out = vec![Scope {
            root: ROOT.into(),
            part: Part::Plant {
                cells: cells.iter().map(|(c, _)| c.clone()).collect(),
            },
            machine: None,
        }];
        for (id, stations) in cells {
            out.push(Scope {
                root: format!("{ROOT}.{id}"),
                part: Part::Cell {
                    id: Some(id),
                    stations,
                    equipment: BTreeMap::new(),
                },
                machine: None,
            });
        }
        out
    }

    /// The same with `equipment` as its transport stations' (a cell; a
    /// plant has none of its own).
    pub fn with_equipment(mut self, equipment: BTreeMap<StationName, Arc<Equipment>>) -> Self {
        if let Part::Cell { equipment: e, .. } = &mut self.part {
            *e = equipment;
        }
        self
    }

    /// The same as machine `m` (a cell's scope).
    pub fn with_machine(mut self, m: Machine) -> Self {
        if matches!(self.part, Part::Cell { .. }) {
            self.machine = Some(m);
        }
        self
    }

    /// The cell its operator API calls are for (None: the plant, or the
    /// one cell).
    pub fn cell(&self) -> Option<&CellId> {
        match &self.part {
            Part::Cell { id, .. } => id.as_ref(),
            Part::Plant { .. } => None,
        }
    }

    /// The node id of `name` under it.
    pub fn id(&self, name: &str) -> String {
        format!("{}.{name}", self.root)
    }

    /// Its browse name (`FALC`, `falc2`).
    pub fn name(&self) -> &str {
        self.root.rsplit('.').next().unwrap_or(&self.root)
    }

    /// The object it belongs to (None: the Objects folder).
    fn parent(&self) -> Option<&str> {
        self.root.rsplit_once('.').map(|(p, _)| p)
    }

    /// Its method whose node id is `id` (in any namespace: the ids are
    /// the gateway's own).
    pub fn method(&self, id: &opcua::types::NodeId) -> Option<Method> {
        match &id.identifier {
            opcua::types::Identifier::String(s) => Method::ALL
                .into_iter()
                .find(|m| s.as_ref() == self.method_id(*m)),
            _ => None,
        }
    }

    /// The request its method `m` makes for these arguments, or what is
    /// wrong with them: a cell's `AddOrder` adds an order for that cell
    /// only (`falc order add --cell`).
    pub fn request(&self, m: Method, args: &[Arg]) -> Result<ApiRequest, String> {
        let mut request = m.request(args)?;
        if let (ApiRequest::OrderAdd { placement, .. }, Some(cell)) = (&mut request, self.cell()) {
            placement.cell = Some(cell.clone());
        }
        Ok(request)
    }

    /// The node id of its method `m`.
    pub fn method_id(&self, m: Method) -> String {
        self.id(m.name())
    }
}

/// A value of the address space, with its OPC UA type.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// Boolean.
    Bool(bool),
    /// Byte.
    Byte(u8),
    /// Int32.
    Int32(i32),
    /// Int64.
    Int64(i64),
    /// String.
    Text(String),
    /// Boolean[].
    Bools(Vec<bool>),
    /// Int64[].
    Int64s(Vec<i64>),
    /// String[].
    Texts(Vec<String>),
    /// DateTime[], as ms since the Unix epoch.
    Times(Vec<i64>),
    /// LocalizedText (a state machine's CurrentState).
    Localized(String),
    /// NodeId of a state object of OPC UA Machinery's namespace (a
    /// CurrentState's Id).
    StateId(u32),
    /// ISA95JobOrderAndStateDataType[]: a machine's job orders.
    JobOrders(Vec<crate::jobs::Job>),
    /// ISA95JobResponseDataType[]: the responses of these job orders.
    JobResponses(Vec<crate::jobs::Job>),
}

/// A folder or object of the layout, and the object it belongs to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Object {
    /// Its node id (`FALC.Stations.welding`).
    pub id: String,
    /// Its browse name (`welding`).
    pub name: String,
    /// The object it belongs to (None: the Objects folder).
    pub parent: Option<String>,
    /// Whether it is a plain folder.
    pub folder: bool,
}

/// The objects of the address space for these scopes, parents first.
pub fn layout(scopes: &[Scope]) -> Vec<Object> {
    let object = |id: String, name: &str, parent: Option<&str>, folder: bool| Object {
        id,
        name: name.to_string(),
        parent: parent.map(str::to_string),
        folder,
    };
    let mut out = Vec::new();
    for scope in scopes {
        let root = scope.root.as_str();
        out.push(object(root.into(), scope.name(), scope.parent(), false));
        out.push(object(scope.id("Orders"), "Orders", Some(root), true));
        let Part::Cell { stations, .. } = &scope.part else {
            continue;
        };
        for folder in ["Journal", "Alarms", "Stations", "Admin"] {
            out.push(object(scope.id(folder), folder, Some(root), true));
        }
        let stations_id = scope.id("Stations");
        for (name, _) in stations {
            out.push(object(
                station_id(scope, name),
                name.as_str(),
                Some(&stations_id),
                false,
            ));
        }
    }
    out
}

/// The node id of station `name`'s object under `scope`.
pub fn station_id(scope: &Scope, name: &StationName) -> String {
    scope.id(&format!("Stations.{name}"))
}

/// A method of a cell or plant object: the operator API call it makes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// `AddOrder(Recipe: String) → OrderId: Int64`.
    AddOrder,
    /// `RemoveOrder(OrderId: Int64)`.
    RemoveOrder,
    /// `Start()`: works through the order list.
    Start,
    /// `Stop()`: stops the running order and the list.
    Stop,
    /// `Acknowledge(AlarmId: Int64)`: one alarm, or 0 for every one.
    Acknowledge,
    /// `Answer(Text: String)`: answers the waiting question.
    Answer,
}

/// An argument's OPC UA type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArgType {
    /// String.
    Text,
    /// Int64.
    Int64,
}

/// A method's argument as the client passed it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Arg {
    /// A String.
    Text(String),
    /// An Int64 (or a smaller integer).
    Int64(i64),
    /// Anything else (its OPC UA type's name): never a valid argument.
    Other(String),
}

impl Method {
    /// Every method.
    pub const ALL: [Method; 6] = [
        Self::AddOrder,
        Self::RemoveOrder,
        Self::Start,
        Self::Stop,
        Self::Acknowledge,
        Self::Answer,
    ];

    /// Its browse name.
    pub fn name(self) -> &'static str {
        match self {
            Self::AddOrder => "AddOrder",
            Self::RemoveOrder => "RemoveOrder",
            Self::Start => "Start",
            Self::Stop => "Stop",
            Self::Acknowledge => "Acknowledge",
            Self::Answer => "Answer",
        }
    }

    /// The method whose node id is `id` under any object (in any
    /// namespace: the ids are the gateway's own): what its name says.
    pub fn of(id: &opcua::types::NodeId) -> Option<Self> {
        match &id.identifier {
            opcua::types::Identifier::String(s) => {
                let (root, name) = s.as_ref().rsplit_once('.')?;
                (root == ROOT || root.starts_with(&format!("{ROOT}.")))
                    .then(|| Self::ALL.into_iter().find(|m| m.name() == name))
                    .flatten()
            }
            _ => None,
        }
    }

    /// The operator API call it makes (whose role it needs).
    pub fn call(self) -> Call {
        match self {
            Self::AddOrder => Call::OrderAdd,
            Self::RemoveOrder => Call::OrderRemove,
            Self::Start => Call::Start,
            Self::Stop => Call::Stop,
            Self::Acknowledge => Call::Ack,
            Self::Answer => Call::Answer,
        }
    }

    /// Its input arguments: name and type.
    pub fn inputs(self) -> &'static [(&'static str, ArgType)] {
        match self {
            Self::AddOrder => &[("Recipe", ArgType::Text)],
            Self::RemoveOrder => &[("OrderId", ArgType::Int64)],
            Self::Acknowledge => &[("AlarmId", ArgType::Int64)],
            Self::Answer => &[("Text", ArgType::Text)],
            Self::Start | Self::Stop => &[],
        }
    }

    /// The request for these arguments, or what is wrong with them.
    pub fn request(self, args: &[Arg]) -> Result<ApiRequest, String> {
        let text = |i: usize| match args.get(i) {
            Some(Arg::Text(t)) => Ok(t.clone()),
            _ => Err(format!(
                "{}: argument {} must be a String",
                self.name(),
                self.inputs()[i].0
            )),
        };
        let number = |i: usize| match args.get(i) {
            Some(Arg::Int64(n)) => Ok(*n),
            _ => Err(format!(
                "{}: argument {} must be an integer",
                self.name(),
                self.inputs()[i].0
            )),
        };
        if args.len() != self.inputs().len() {
            return Err(format!(
                "{} takes {} argument(s), not {}",
                self.name(),
                self.inputs().len(),
                args.len()
            ));
        }
        let request = match self {
            Self::AddOrder => ApiRequest::order_add(&text(0)?),
            Self::RemoveOrder => ApiRequest::OrderRemove { id: number(0)? },
            Self::Start => ApiRequest::Start,
            Self::Stop => ApiRequest::Stop,
            Self::Acknowledge => ApiRequest::Ack {
                id: Some(number(0)?).filter(|&n| n != 0),
            },
            Self::Answer => ApiRequest::Answer { text: text(0)? },
        };
        request.check_limits()?;
        Ok(request)
    }
}

/// One look at a cell or the plant: what the operator answered.
#[derive(Debug, Clone, Default)]
pub struct Look {
    /// Whether the operator answered.
    pub reachable: bool,
    /// `status` of this cell (None: the plant's object, or not reached).
    pub status: Option<CellStatus>,
    /// `order-list`: every order of the plant (a cell of a plant of
    /// several serves those it runs or ran, or that were added for it).
    pub orders: Vec<Order>,
    /// The newest journal entries (of this cell), oldest first.
    pub journal: Vec<Entry>,
    /// Why the operator refused the last method call on this object.
    pub last_refusal: String,
    /// This cell's figures of the last day (None: not known yet).
    pub figures: Option<CellFigures>,
    /// The JobOrderIDs of job orders cleared (no longer listed).
    pub cleared_jobs: Vec<String>,
}

/// Every value of `scope`'s part of the address space for this look: node
/// id and value. The set of ids depends only on the scope, never on the
/// look.
pub fn values(scope: &Scope, look: &Look) -> Vec<(String, Value)> {
    match &scope.part {
        Part::Cell {
            id,
            stations,
            equipment,
        } => cell_values(scope, id.as_ref(), stations, equipment, look),
        Part::Plant { cells } => plant_values(scope, cells, look),
    }
}

/// The plant object's values: reachable, its cells, the queued orders and
/// every order.
fn plant_values(scope: &Scope, cells: &[CellId], look: &Look) -> Vec<(String, Value)> {
    let r = |n: &str| scope.id(n);
    let queued = look
        .orders
        .iter()
        .filter(|o| o.state == OrderState::Queued)
        .count();
    let mut out = vec![
        (r("OperatorReachable"), Value::Bool(look.reachable)),
        (
            r("Cells"),
            Value::Texts(cells.iter().map(ToString::to_string).collect()),
        ),
        (
            r("Queued"),
            Value::Int32(i32::try_from(queued).unwrap_or(i32::MAX)),
        ),
        (r("LastRefusal"), Value::Text(look.last_refusal.clone())),
    ];
    let orders: Vec<&Order> = look.orders.iter().collect();
    order_values(scope, &orders, &mut |id, v| out.push((id, v)));
    out.push((
        r("Orders.Cells"),
        Value::Texts(
            orders
                .iter()
                .map(|o| o.cell.clone().or(o.wanted.clone()).unwrap_or_default())
                .collect(),
        ),
    ));
    out
}

/// The `Orders` folder's values of these orders.
fn order_values(scope: &Scope, o: &[&Order], put: &mut dyn FnMut(String, Value)) {
    let r = |n: &str| scope.id(n);
    put(
        r("Orders.Ids"),
        Value::Int64s(o.iter().map(|o| o.id).collect()),
    );
    put(
        r("Orders.Recipes"),
        Value::Texts(o.iter().map(|o| o.recipe.clone()).collect()),
    );
    put(
        r("Orders.States"),
        Value::Texts(o.iter().map(|o| o.state.to_string()).collect()),
    );
    put(
        r("Orders.Results"),
        Value::Texts(
            o.iter()
                .map(|o| o.result.clone().unwrap_or_default())
                .collect(),
        ),
    );
}

/// The states of `Admin.StateCumulativeTime`, in its order.
pub const ADMIN_STATES: [&str; 5] = ["Execute", "Aborted", "Idle", "Maintenance", "Step"];

/// A cell's PackML Admin values: parts made and defective (orders ended
/// done or failed, and failed), why it stopped last (the alarm holding
/// it, else the end of the last order that did not end done), and the
/// planned busy time spent in each state over the last day
/// ([`ADMIN_STATES`], ms; from the figures: Execute an order runs, Aborted an alarm holds the cell, Idle
/// the rest, and the time in maintenance and step mode).
fn admin_values(
    scope: &Scope,
    orders: &[&Order],
    status: Option<&CellStatus>,
    figures: Option<&CellFigures>,
    put: &mut dyn FnMut(String, Value),
) {
    let r = |n: &str| scope.id(n);
    let count = |f: &dyn Fn(OrderState) -> bool| {
        let n = orders.iter().filter(|o| f(o.state)).count();
        Value::Int32(i32::try_from(n).unwrap_or(i32::MAX))
    };
    put(
        r("Admin.ProdProcessedCount"),
        count(&|s| matches!(s, OrderState::Done | OrderState::Failed)),
    );
    put(
        r("Admin.ProdDefectiveCount"),
        count(&|s| s == OrderState::Failed),
    );
    let last_stop = orders
        .iter()
        .filter(|o| o.ended_ms.is_some() && o.state != OrderState::Done)
        .max_by_key(|o| (o.ended_ms, o.id))
        .and_then(|o| o.result.clone());
    let reason = status
        .and_then(|s| s.alarm.clone())
        .or(last_stop)
        .unwrap_or_default();
    put(r("Admin.StopReason"), Value::Text(reason));
    let times = figures.map_or_else(
        || vec![0; ADMIN_STATES.len()],
        |f| {
            let t = &f.total.time;
            vec![
                t.production_ms,
                t.down_total_ms(),
                t.idle_ms,
                t.maintenance_ms,
                t.setup_ms,
            ]
        },
    );
    put(r("Admin.StateCumulativeTime"), Value::Int64s(times));
    put(
        r("Admin.StateNames"),
        Value::Texts(ADMIN_STATES.iter().map(|s| s.to_string()).collect()),
    );
}

/// The orders of `cell` (a cell of a plant of several, None: the one
/// cell) among `orders`: a cell of a plant serves the orders it runs or
/// ran, or that wait for it.
pub fn cell_orders<'a>(cell: Option<&CellId>, orders: &'a [Order]) -> Vec<&'a Order> {
    orders
        .iter()
        .filter(|o| {
            cell.map_or(true, |c| {
                o.cell.as_deref().or(o.wanted.as_deref()) == Some(c.as_str())
            })
        })
        .collect()
}

/// Scope `scope`'s status in the operator's answer to `status`: one
/// cell's status answers for the one cell (or a plant's one cell); a
/// plant's holds each cell's; the plant's object has none.
pub fn status_of(scope: &Scope, reply: Option<&ApiReply>) -> Option<CellStatus> {
    match (&scope.part, reply) {
        (Part::Plant { .. }, _) => None,
        (Part::Cell { .. }, Some(ApiReply::Status(s))) => Some(s.clone()),
        (Part::Cell { id: Some(id), .. }, Some(ApiReply::Plant(p))) => p
            .cells
            .iter()
            .find(|(c, _)| c == id)
            .map(|(_, s)| s.clone()),
        _ => None,
    }
}

/// A cell object's values (`cell`: which cell of a plant of several).
fn cell_values(
    scope: &Scope,
    cell: Option<&CellId>,
    stations: &[(StationName, StationKind)],
    equipment: &BTreeMap<StationName, Arc<Equipment>>,
    look: &Look,
) -> Vec<(String, Value)> {
    let mut out: Vec<(String, Value)> = Vec::new();
    let mut put = |id: String, v: Value| out.push((id, v));
    let s = look.status.as_ref();
    let last_ended = look
        .orders
        .iter()
        .filter(|o| o.ended_ms.is_some())
        .max_by_key(|o| (o.ended_ms, o.id))
        .map(|o| o.state);
    let (state, mode) = match s {
        Some(s) => (packml::state(s, last_ended), s.mode),
        None => (packml::State::Stopped, Default::default()),
    };
    let (unit_mode, unit_mode_name) = packml::unit_mode(mode);
    let cell_station = stations
        .iter()
        .find(|(_, k)| *k == StationKind::Cell)
        .and_then(|(n, _)| s?.stations.iter().find(|v| &v.name == n))
        .and_then(|v| v.status.as_ref()?.program.clone());
    let text = |t: Option<&String>| text_of(t, String::clone);
    let r = |n: &str| scope.id(n);
    put(r("OperatorReachable"), Value::Bool(look.reachable));
    put(r("PackMLState"), Value::Text(state.name().into()));
    put(r("PackMLStateCode"), Value::Int32(state.code()));
    put(r("Mode"), Value::Text(mode.to_string()));
    put(r("PackMLUnitMode"), Value::Int32(unit_mode));
    put(r("PackMLUnitModeName"), Value::Text(unit_mode_name.into()));
    put(r("List"), text_of(s, |s| s.list.as_str().to_string()));
    put(
        r("CellAssociated"),
        Value::Bool(s.is_some_and(|s| s.cell_associated)),
    );
    put(r("Problem"), text(s.and_then(|s| s.problem.as_ref())));
    let running = s.and_then(|s| s.running.as_ref());
    put(r("RunningOrder"), Value::Int64(running.map_or(0, |o| o.id)));
    put(r("RunningRecipe"), text(running.map(|o| &o.recipe)));
    put(
        r("CellProgram"),
        text_of(cell_station.as_ref(), |p| p.name.to_string()),
    );
    put(
        r("CellRecipeState"),
        Value::Int32(cell_station.as_ref().map_or(0, |p| i32::from(p.state))),
    );
    put(r("Question"), text(s.and_then(|s| s.question.as_ref())));
    put(r("Alarm"), text(s.and_then(|s| s.alarm.as_ref())));
    put(
        r("Queued"),
        Value::Int32(s.map_or(0, |s| i32::try_from(s.queued).unwrap_or(i32::MAX))),
    );
    put(r("LastRefusal"), Value::Text(look.last_refusal.clone()));

    let orders = cell_orders(cell, &look.orders);
    if let Some(m) = &scope.machine {
        crate::machinery::values(m, look, state, &mut put);
        crate::job_management::values(m, look, &orders, &mut put);
    }
    order_values(scope, &orders, &mut put);
    admin_values(scope, &orders, s, look.figures.as_ref(), &mut put);

    let j = &look.journal;
    put(
        r("Journal.Ids"),
        Value::Int64s(j.iter().map(|e| e.id).collect()),
    );
    put(
        r("Journal.Times"),
        Value::Times(j.iter().map(|e| e.at_ms).collect()),
    );
    put(
        r("Journal.Kinds"),
        Value::Texts(j.iter().map(|e| e.kind.as_str().to_string()).collect()),
    );
    put(
        r("Journal.Who"),
        Value::Texts(j.iter().map(|e| e.who.clone()).collect()),
    );
    put(
        r("Journal.Texts"),
        Value::Texts(j.iter().map(|e| e.text.clone()).collect()),
    );

    let alarms = s.map_or(&[][..], |s| &s.alarms[..]);
    put(
        r("Alarms.Ids"),
        Value::Int64s(alarms.iter().map(|a| a.id).collect()),
    );
    put(
        r("Alarms.Texts"),
        Value::Texts(alarms.iter().map(alarm_text).collect()),
    );

    for (name, kind) in stations {
        let view = s.and_then(|s| s.stations.iter().find(|v| &v.name == name));
        let vmd = view.and_then(|v| v.status.as_ref());
        let id = |n: &str| format!("{}.{n}", station_id(scope, name));
        put(
            id("Connected"),
            Value::Bool(view.is_some_and(|v| v.connected)),
        );
        put(id("Kind"), Value::Text(kind.as_str().into()));
        put(id("Logical"), text_of(vmd, |v| format!("{:?}", v.logical)));
        put(
            id("Physical"),
            text_of(vmd, |v| format!("{:?}", v.physical)),
        );
        put(
            id("RecipeStatus"),
            text_of(vmd, |v| v.local_detail.to_string()),
        );
        let program = vmd.and_then(|v| v.program.as_ref());
        put(id("Program"), text_of(program, |p| p.name.to_string()));
        put(
            id("RecipeState"),
            Value::Int32(program.map_or(0, |p| i32::from(p.state))),
        );
        put(id("Mode"), text_of(vmd, |v| v.mode.to_string()));
        put(
            id("HeldStep"),
            text_of(vmd.and_then(|v| v.held.as_ref()), |h| {
                format!("state {}: {}", h.state, h.command)
            }),
        );
        match kind {
            StationKind::Transport => {
                let e = equipment
                    .get(name)
                    .cloned()
                    .unwrap_or_else(Equipment::conveyor_1992);
                station_inputs(vmd, &e, &id, &mut put)
            }
            StationKind::Welding => {
                let robot = vmd.and_then(|v| v.additional);
                put(
                    id("RobotState"),
                    text_of(robot, |r| format!("{:?}", r.state)),
                );
                put(
                    id("RobotStatusBits"),
                    Value::Byte(robot.map_or(0, |r| r.specific & r.mask)),
                );
            }
            StationKind::Operator | StationKind::Cell => {}
        }
    }
    out
}

/// A text value: what `f` says of `v`, or "" when there is none.
fn text_of<T>(v: Option<T>, f: impl FnOnce(T) -> String) -> Value {
    Value::Text(v.map_or_else(String::new, f))
}

/// A transport station's conveyor inputs: every bit, and the lit ones by
/// name.
fn station_inputs(
    vmd: Option<&VmdStatus>,
    equipment: &Arc<Equipment>,
    id: &dyn Fn(&str) -> String,
    put: &mut dyn FnMut(String, Value),
) {
    let bits = vmd.map_or(Vec::new(), |v| v.inputs.clone());
    let lit = Inputs::from_bits(equipment, &bits)
        .map(|i| i.lit().map(|input| input.to_string()).collect())
        .unwrap_or_default();
    put(id("Inputs"), Value::Bools(bits));
    put(id("LitInputs"), Value::Texts(lit));
}

/// One alarm in a line: `#3 welding communication: …`.
pub fn alarm_text(a: &Alarm) -> String {
    format!("#{} {} {}: {}", a.id, a.station, a.class, a.text)
}

/// The OPC UA severity (1–1000) of an alarm class.
pub fn severity(class: AlarmClass) -> u16 {
    match class {
        AlarmClass::Safety => 1000,
        AlarmClass::Communication => 800,
        AlarmClass::Device => 700,
        AlarmClass::Process => 500,
        AlarmClass::Warning => 300,
    }
}

/// An alarm event to raise on the cell object.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AlarmEvent {
    /// The alarm's number.
    pub id: i64,
    /// The station that raised it.
    pub station: String,
    /// Severity 1–1000.
    pub severity: u16,
    /// The message: what happened to it.
    pub message: String,
}

fn acked_by(a: &Alarm) -> String {
    format!(
        "acknowledged by {}",
        a.acked.as_ref().map_or("?", |(w, _)| w.as_str())
    )
}

fn event(a: &Alarm, what: &str) -> AlarmEvent {
    AlarmEvent {
        id: a.id,
        station: a.station.to_string(),
        severity: severity(a.class),
        message: format!("alarm {what}: {}", alarm_text(a)),
    }
}

/// When, after the last write, the values written are written again,
/// unchanged: covers sampling intervals up to 50 ms (asyncua's default)
/// at once, up to 5 s eventually. async-opcua 0.19 holds back a change
/// that comes within a monitored item's sampling interval of the previous
/// one and, when its subscription ticks before the held value is due,
/// forgets to tick it again (`Subscription::tick` drains
/// `notified_monitored_items`): the change would reach the client only
/// with the next one. Writing the same values again once the held one is
/// due lets it out (an unchanged value is no notification of its own).
/// Seen in benches/opcua.rs: 1 in ~70 changes lost without it.
pub const REFRESH: [Duration; 3] = [
    Duration::from_millis(60),
    Duration::from_secs(1),
    Duration::from_secs(5),
];

/// Successive looks, as changes: each value only when it changed, an
/// event when an alarm appears, is acknowledged or clears; and when to
/// write the values written again ([`REFRESH`]).
#[derive(Debug, Default)]
pub struct Mirror {
    values: HashMap<String, Value>,
    alarms: BTreeMap<i64, Alarm>,
    seen: bool,
    /// The values written since the refreshes began, and when each
    /// refresh is due (earliest first).
    refresh: BTreeSet<String>,
    refresh_due: VecDeque<Instant>,
}

/// What one look changed.
#[derive(Debug, Default, PartialEq)]
pub struct Changes {
    /// The values that changed (all of them on the first look).
    pub values: Vec<(String, Value)>,
    /// Alarm events to raise.
    pub events: Vec<AlarmEvent>,
}

impl Mirror {
    /// Forgets the values passed on (they could not be written), so the
    /// next look passes on every one; the alarms stay known.
    pub fn forget_values(&mut self) {
        self.values.clear();
    }

    /// `values` were written at `now`: the refreshes begin again.
    pub fn written(&mut self, now: Instant, values: &[(String, Value)]) {
        if values.is_empty() {
            return;
        }
        self.refresh.extend(values.iter().map(|(id, _)| id.clone()));
        self.refresh_due = REFRESH.iter().map(|d| now + *d).collect();
    }

    /// When the next refresh is due.
    pub fn next_refresh(&self) -> Option<Instant> {
        self.refresh_due.front().copied()
    }

    /// At `now`: the values to write again, as mirrored now (none when
    /// no refresh is due).
    pub fn refresh(&mut self, now: Instant) -> Vec<(String, Value)> {
        if !matches!(self.next_refresh(), Some(due) if due <= now) {
            return Vec::new();
        }
        while self.next_refresh().is_some_and(|due| due <= now) {
            self.refresh_due.pop_front();
        }
        let values = self
            .refresh
            .iter()
            .filter_map(|id| Some((id.clone(), self.values.get(id)?.clone())))
            .collect();
        if self.refresh_due.is_empty() {
            self.refresh.clear();
        }
        values
    }

    /// Takes in a look's values and alarms.
    pub fn update(&mut self, values: Vec<(String, Value)>, alarms: &[Alarm]) -> Changes {
        let mut out = Changes::default();
        for (id, v) in values {
            if self.values.get(&id) != Some(&v) {
                self.values.insert(id.clone(), v.clone());
                out.values.push((id, v));
            }
        }
        let mut now = BTreeMap::new();
        for a in alarms {
            let before = self.alarms.get(&a.id);
            let what = match before {
                None if !self.seen => None,
                None if a.acked.is_none() => Some("raised".to_string()),
                None => Some(acked_by(a)),
                Some(b) if b.acked.is_none() && a.acked.is_some() => Some(acked_by(a)),
                Some(b) if b.cleared_ms.is_none() && a.cleared_ms.is_some() => {
                    Some("cleared".to_string())
                }
                Some(_) => None,
            };
            if let Some(what) = what {
                out.events.push(event(a, &what));
            }
            now.insert(a.id, a.clone());
        }
        // An alarm leaves the list once both acknowledged and cleared.
        for (id, b) in &self.alarms {
            if !now.contains_key(id) {
                let what = match (b.acked.is_none(), b.cleared_ms.is_none()) {
                    (true, true) => "acknowledged and cleared",
                    (true, false) => "acknowledged",
                    (false, _) => "cleared",
                };
                out.events.push(event(b, what));
            }
        }
        self.alarms = now;
        self.seen = true;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_model::api::{ListState, StationView};
    use falc_model::mms::vmd::{ProgramState, RobotStatusDetail, RobotVmdState};

    #[test]
    fn written_values_are_written_again_when_each_refresh_is_due() {
        let mut m = Mirror::default();
        let t0 = Instant::now();
        let v = |s: &str| Value::Text(s.into());
        let changes = m.update(vec![("a".into(), v("1")), ("b".into(), v("2"))], &[]);
        m.written(t0, &changes.values);
        assert_eq!(m.next_refresh(), Some(t0 + REFRESH[0]));
        assert!(m.refresh(t0).is_empty(), "not due yet");
        // A later write of `a` starts the refreshes again, with its value
        // as mirrored then.
        let later = m.update(vec![("a".into(), v("3")), ("b".into(), v("2"))], &[]);
        let t1 = t0 + Duration::from_millis(30);
        m.written(t1, &later.values);
        assert!(m.refresh(t0 + REFRESH[0]).is_empty());
        let due = m.refresh(t1 + REFRESH[0]);
        assert_eq!(due, vec![("a".into(), v("3")), ("b".into(), v("2"))]);
        assert_eq!(m.next_refresh(), Some(t1 + REFRESH[1]));
        // Late: every refresh that passed is one write, then none is left.
        assert_eq!(m.refresh(t1 + REFRESH[2]).len(), 2);
        assert_eq!(m.next_refresh(), None);
        assert!(m.refresh(t1 + REFRESH[2] * 2).is_empty());
    }

    fn st(s: &str) -> StationName {
        StationName::new(s).expect("valid")
    }

    fn stations() -> Vec<(StationName, StationKind)> {
        vec![
            (st("operator"), StationKind::Operator),
            (st("cell"), StationKind::Cell),
            (st("welding"), StationKind::Welding),
            (st("transport"), StationKind::Transport),
        ]
    }

    /// The one cell's scope.
    fn one() -> Scope {
        Scope::one_cell(stations()).remove(0)
    }

    fn alarm(id: i64) -> Alarm {
        Alarm {
            id,
            station: StationName::new("welding").expect("name"),
            class: AlarmClass::Communication,
            text: "gone".into(),
            order: None,
            raised_ms: 0,
            acked: None,
            cleared_ms: None,
        }
    }

    fn status() -> CellStatus {
        CellStatus {
            list: ListState::Running,
            cell_associated: true,
            running: Some(Order {
                id: 7,
                recipe: "dikdroog".into(),
                state: OrderState::Running,
                added_by: "opcua".into(),
                started_ms: Some(1),
                ended_ms: None,
                result: None,
                cell: Some("falc1".into()),
                wanted: None,
                priority: 0,
                due_ms: None,
                job_order: None,
            }),
            queued: 2,
            question: Some("Gereed?".into()),
            stations: vec![
                StationView {
                    name: st("cell"),
                    status: Some(VmdStatus {
                        program: Some(ProgramState {
                            name: "DIKDROOG".parse().expect("valid"),
                            state: 6,
                        }),
                        ..VmdStatus::default()
                    }),
                    connected: true,
                },
                StationView {
                    name: st("welding"),
                    status: Some(VmdStatus {
                        additional: Some(RobotStatusDetail {
                            state: RobotVmdState::Executing,
                            specific: 0b10110,
                            mask: 0b11111,
                        }),
                        ..VmdStatus::default()
                    }),
                    connected: true,
                },
                StationView {
                    name: st("transport"),
                    status: Some(VmdStatus {
                        // The 1992 conveyor's 21 inputs: line A running,
                        // place 2 occupied.
                        inputs: (0..21).map(|i| i == 0 || i == 11).collect(),
                        ..VmdStatus::default()
                    }),
                    connected: false,
                },
            ],
            ..CellStatus::default()
        }
    }

    fn get<'a>(v: &'a [(String, Value)], id: &str) -> &'a Value {
        &v.iter()
            .find(|(i, _)| i == id)
            .unwrap_or_else(|| panic!("{id}"))
            .1
    }

    #[test]
    fn the_values_say_what_the_status_says() {
        let look = Look {
            status: Some(status()),
            ..Look::default()
        };
        let v = values(&one(), &look);
        assert_eq!(get(&v, "FALC.PackMLState"), &Value::Text("Held".into()));
        assert_eq!(get(&v, "FALC.PackMLStateCode"), &Value::Int32(11));
        assert_eq!(get(&v, "FALC.RunningOrder"), &Value::Int64(7));
        assert_eq!(get(&v, "FALC.CellProgram"), &Value::Text("DIKDROOG".into()));
        assert_eq!(get(&v, "FALC.CellRecipeState"), &Value::Int32(6));
        assert_eq!(get(&v, "FALC.Question"), &Value::Text("Gereed?".into()));
        assert_eq!(get(&v, "FALC.Queued"), &Value::Int32(2));
        assert_eq!(
            get(&v, "FALC.Stations.welding.RobotState"),
            &Value::Text("Executing".into())
        );
        assert_eq!(
            get(&v, "FALC.Stations.welding.RobotStatusBits"),
            &Value::Byte(0b10110)
        );
        assert_eq!(
            get(&v, "FALC.Stations.transport.Connected"),
            &Value::Bool(false)
        );
        let Value::Texts(lit) = get(&v, "FALC.Stations.transport.LitInputs") else {
            panic!("texts")
        };
        assert_eq!(lit.len(), 2, "{lit:?}");
        // The same ids whether or not the operator answered.
        let empty = values(&one(), &Look::default());
        let ids = |v: &[(String, Value)]| v.iter().map(|(i, _)| i.clone()).collect::<Vec<_>>();
        assert_eq!(ids(&v), ids(&empty));
        assert_eq!(get(&empty, "FALC.OperatorReachable"), &Value::Bool(false));
        assert_eq!(
            get(&empty, "FALC.PackMLState"),
            &Value::Text("Stopped".into())
        );
        // Every id under an object of the layout.
        let objects: Vec<String> = layout(&Scope::one_cell(stations()))
            .into_iter()
            .map(|o| o.id)
            .collect();
        for id in ids(&v) {
            let parent = id.rsplit_once('.').map(|(p, _)| p).unwrap_or_default();
            assert!(objects.iter().any(|o| o == parent), "{id}");
        }
    }

    #[test]
    fn the_mirror_passes_on_changes_and_alarm_events() {
        let mut m = Mirror::default();
        let look = Look {
            status: Some(status()),
            ..Look::default()
        };
        let first = m.update(values(&one(), &look), &[alarm(1)]);
        assert!(first.values.len() > 30);
        assert!(first.events.is_empty(), "alarms listed before are no news");
        let again = m.update(values(&one(), &look), &[alarm(1)]);
        assert_eq!(again, Changes::default());
        // Values that could not be written are all passed on again, and
        // no alarm is news for it.
        m.forget_values();
        let again = m.update(values(&one(), &look), &[alarm(1)]);
        assert_eq!(again.values.len(), first.values.len());
        assert!(again.events.is_empty());
        let mut s = status();
        s.question = None;
        let look = Look {
            status: Some(s),
            ..Look::default()
        };
        let mut acked = alarm(1);
        acked.acked = Some(("console".into(), 5));
        let c = m.update(values(&one(), &look), &[acked, alarm(2)]);
        let ids: Vec<&str> = c.values.iter().map(|(i, _)| i.as_str()).collect();
        assert!(
            ids.contains(&"FALC.Question") && ids.contains(&"FALC.PackMLState"),
            "{ids:?}"
        );
        assert_eq!(c.events.len(), 2, "{:?}", c.events);
        assert!(c.events[0]
            .message
            .starts_with("alarm acknowledged by console"));
        assert!(c.events[1].message.starts_with("alarm raised: #2 welding"));
        assert_eq!(c.events[1].severity, 800);
        // Both leave the list: #1 (acknowledged) by clearing, #2 at once.
        let c = m.update(values(&one(), &look), &[]);
        let texts: Vec<&str> = c.events.iter().map(|e| e.message.as_str()).collect();
        assert_eq!(texts.len(), 2, "{texts:?}");
        assert!(texts[0].starts_with("alarm cleared: #1"), "{texts:?}");
        assert!(
            texts[1].starts_with("alarm acknowledged and cleared: #2"),
            "{texts:?}"
        );
    }

    #[test]
    fn methods_make_their_requests_and_refuse_bad_arguments() {
        use Arg::*;
        assert_eq!(
            Method::AddOrder.request(&[Text("dikdroog".into())]),
            Ok(ApiRequest::order_add("dikdroog"))
        );
        assert_eq!(
            Method::Acknowledge.request(&[Int64(0)]),
            Ok(ApiRequest::Ack { id: None })
        );
        assert_eq!(
            Method::Acknowledge.request(&[Int64(3)]),
            Ok(ApiRequest::Ack { id: Some(3) })
        );
        assert_eq!(Method::Start.request(&[]), Ok(ApiRequest::Start));
        let e = Method::AddOrder.request(&[Int64(1)]).expect_err("type");
        assert!(e.contains("Recipe must be a String"), "{e}");
        let e = Method::Answer
            .request(&[Other("Double".into())])
            .expect_err("type");
        assert!(e.contains("Text must be a String"), "{e}");
        let e = Method::Start.request(&[Int64(1)]).expect_err("count");
        assert!(e.contains("takes 0"), "{e}");
        let e = Method::Answer
            .request(&[Text("ja\nnee".into())])
            .expect_err("limits");
        assert!(e.contains("control character"), "{e}");
        let one = one();
        for m in Method::ALL {
            let id = opcua::types::NodeId::new(2, one.method_id(m));
            assert_eq!((one.method(&id), Method::of(&id)), (Some(m), Some(m)));
        }
        assert_eq!(Method::of(&opcua::types::NodeId::new(0, 2253u32)), None);
        assert_eq!(
            Method::Start.call().role(),
            falc_model::topology::Role::Operator
        );
    }

    fn order(id: i64, cell: Option<&str>, wanted: Option<&str>, state: OrderState) -> Order {
        Order {
            id,
            cell: cell.map(str::to_string),
            wanted: wanted.map(str::to_string),
            state,
            ..status().running.expect("an order")
        }
    }

    #[test]
    fn the_packml_admin_values_count_the_cells_parts_and_say_why_it_stopped() {
        let ended = |id, state, result: &str| Order {
            ended_ms: Some(id),
            result: Some(result.into()),
            ..order(id, Some("falc1"), None, state)
        };
        let mut look = Look {
            reachable: true,
            status: Some(CellStatus {
                alarm: None,
                ..status()
            }),
            orders: vec![
                ended(1, OrderState::Done, "done"),
                ended(2, OrderState::Failed, "alarm: emergency stop"),
                ended(3, OrderState::Done, "done"),
                ended(4, OrderState::Stopped, "stopped by console"),
                ended(5, OrderState::Done, "done"),
            ],
            ..Look::default()
        };
        let v = values(&one(), &look);
        assert_eq!(get(&v, "FALC.Admin.ProdProcessedCount"), &Value::Int32(4));
        assert_eq!(get(&v, "FALC.Admin.ProdDefectiveCount"), &Value::Int32(1));
        assert_eq!(
            get(&v, "FALC.Admin.StopReason"),
            &Value::Text("stopped by console".into())
        );
        assert_eq!(
            get(&v, "FALC.Admin.StateCumulativeTime"),
            &Value::Int64s(vec![0; 5]),
            "no figures yet"
        );
        // The figures' time elements, in the order of the names.
        let query = falc_model::figures::FigureQuery {
            since_ms: 0,
            until_ms: Some(10_000),
            planned: Vec::new(),
        };
        let inputs = falc_factory::figures::FigureInputs {
            runs: vec![falc_factory::figures::RunSpan {
                order: 1,
                recipe: "dikdroog".into(),
                cell: "falc1".into(),
                start_ms: 1000,
                end_ms: Some(4000),
                state: OrderState::Done,
            }],
            // The list worked all along (no shift calendar: planned).
            lists: vec![falc_factory::figures::ListChange {
                cell: "falc1".into(),
                at_ms: 0,
                working: true,
            }],
            ..Default::default()
        };
        let f = falc_factory::figures::compute(
            &inputs,
            &falc_model::calendar::Calendar::default(),
            &["falc1"],
            &query,
            10_000,
        );
        look.figures = f.cells.into_iter().next();
        let holding = "#3 safety welding: RCM message 24: emergency stop";
        look.status = Some(CellStatus {
            alarm: Some(holding.into()),
            ..status()
        });
        let v = values(&one(), &look);
        assert_eq!(
            get(&v, "FALC.Admin.StateCumulativeTime"),
            &Value::Int64s(vec![3000, 0, 7000, 0, 0])
        );
        assert_eq!(
            get(&v, "FALC.Admin.StateNames"),
            &Value::Texts(ADMIN_STATES.iter().map(|s| s.to_string()).collect())
        );
        // An alarm holding the cell is the reason now.
        assert_eq!(
            get(&v, "FALC.Admin.StopReason"),
            &Value::Text(holding.into())
        );
    }

    #[test]
    fn a_plant_has_its_object_and_one_object_per_cell_with_its_own_methods() {
        let cell = |c: &str| CellId::new(c).expect("valid");
        let scopes = Scope::plant(vec![
            (cell("falc1"), stations()),
            (cell("falc2"), stations()),
        ]);
        let roots: Vec<&str> = scopes.iter().map(|s| s.root.as_str()).collect();
        assert_eq!(roots, ["FALC", "FALC.falc1", "FALC.falc2"]);
        let objects = layout(&scopes);
        let parent = |id: &str| {
            objects
                .iter()
                .find(|o| o.id == id)
                .unwrap_or_else(|| panic!("{id}"))
                .parent
                .clone()
        };
        assert_eq!(parent("FALC"), None);
        assert_eq!(parent("FALC.falc2"), Some("FALC".into()));
        assert_eq!(
            parent("FALC.falc2.Stations.welding"),
            Some("FALC.falc2.Stations".into())
        );
        // Each cell's methods are its own: one cell's id is no other's.
        let start2 = opcua::types::NodeId::new(2, scopes[2].method_id(Method::Start));
        assert_eq!(scopes[2].method(&start2), Some(Method::Start));
        assert_eq!(scopes[1].method(&start2), None);
        assert_eq!(scopes[0].method(&start2), None);
        assert_eq!(scopes[2].cell().map(CellId::as_str), Some("falc2"));
        // A cell's AddOrder is for that cell; the plant's for any.
        let add = [Arg::Text("dikdroog".into())];
        let placed = |r: Result<ApiRequest, String>| match r {
            Ok(ApiRequest::OrderAdd { placement, .. }) => placement.cell,
            other => panic!("{other:?}"),
        };
        assert_eq!(
            placed(scopes[2].request(Method::AddOrder, &add)),
            Some(cell("falc2"))
        );
        assert_eq!(placed(scopes[0].request(Method::AddOrder, &add)), None);
        assert_eq!(scopes[0].cell(), None);
        // A cell serves the orders it runs or ran, or that wait for it;
        // the plant every order, with its cell.
        let look = Look {
            reachable: true,
            status: Some(status()),
            orders: vec![
                order(1, Some("falc1"), None, OrderState::Done),
                order(2, Some("falc2"), None, OrderState::Running),
                order(3, None, Some("falc2"), OrderState::Queued),
                order(4, None, None, OrderState::Queued),
            ],
            ..Look::default()
        };
        let two = values(&scopes[2], &look);
        assert_eq!(
            get(&two, "FALC.falc2.Orders.Ids"),
            &Value::Int64s(vec![2, 3])
        );
        assert_eq!(
            get(&two, "FALC.falc2.PackMLState"),
            &Value::Text("Held".into())
        );
        let plant = values(&scopes[0], &look);
        assert_eq!(
            get(&plant, "FALC.Orders.Ids"),
            &Value::Int64s(vec![1, 2, 3, 4])
        );
        assert_eq!(
            get(&plant, "FALC.Orders.Cells"),
            &Value::Texts(vec![
                "falc1".into(),
                "falc2".into(),
                "falc2".into(),
                String::new()
            ])
        );
        assert_eq!(get(&plant, "FALC.Queued"), &Value::Int32(2));
        assert_eq!(
            get(&plant, "FALC.Cells"),
            &Value::Texts(vec!["falc1".into(), "falc2".into()])
        );
        assert_eq!(get(&plant, "FALC.OperatorReachable"), &Value::Bool(true));
        // Every value under an object of the layout, and no id twice.
        let mut all: Vec<String> = Vec::new();
        for scope in &scopes {
            all.extend(values(scope, &look).into_iter().map(|(id, _)| id));
        }
        for id in &all {
            let parent = id.rsplit_once('.').map(|(p, _)| p).unwrap_or_default();
            assert!(objects.iter().any(|o| o.id == parent), "{id}");
        }
        let unique: BTreeSet<&String> = all.iter().collect();
        assert_eq!(unique.len(), all.len());
    }
}
