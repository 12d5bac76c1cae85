//! ISA-95 job orders (OPC 10031-4 Job Control, as OPC 40001-3 Machinery
//! Job Management uses it) over FALC's orders, sans-I/O: a job order an
//! MES sends checked and turned into FALC's operator calls, each job
//! order's state derived from the orders that carry its JobOrderID, and
//! its job response from their records. `server` decodes and encodes the
//! structures (`structures`) and makes the calls.
//!
//! A job order is FALC orders: its work master is the cell recipe, its
//! parameter `Count` how many orders (1 by default), its priority and
//! end time the orders' priority and due time, its JobOrderID kept in
//! each order's record (`falc order show`). The machine is the cell, so
//! the orders are for that cell.

use falc_model::api::{
    ApiRequest, ListState, Placement, MAX_JOB_ORDER_CHARS, MAX_ORDERS_PER_ADD, MAX_PRIORITY,
};
use falc_model::ids::{printable, CellId};
use falc_model::mode::CellMode;
use falc_model::product::OrderRecord;
use falc_model::records::{Order, OrderState};

/// ReturnStatus bits (OPC 10031-4 Annex B.2): the value a method returns.
pub mod status {
    /// No error.
    pub const NO_ERROR: u64 = 1;
    /// The JobOrderID is not known.
    pub const UNKNOWN_JOB_ORDER: u64 = 1 << 1;
    /// The job order's state does not allow the command.
    pub const INVALID_STATUS: u64 = 1 << 3;
    /// The job order cannot be accepted.
    pub const UNABLE_TO_ACCEPT: u64 = 1 << 4;
    /// The request is invalid for another reason (FALC does not do it).
    pub const INVALID_REQUEST: u64 = 1 << 32;
}

/// A job order's state (ISA95JobOrderStateMachineType): its number and
/// name as the standard's state objects have them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JobState {
    /// Stored, not commanded to start: its orders are queued while the
    /// cell does not work through its list.
    NotAllowedToStart,
    /// Commanded to start: its orders are queued and the cell works
    /// through its list.
    AllowedToStart,
    /// One of its orders runs, or some ran and the rest wait their turn.
    Running,
    /// Held: its order runs in step mode, or the list stopped between its
    /// orders.
    Interrupted,
    /// Every order of it ended done.
    Ended,
    /// Every order of it ended, one or more not done (failed, stopped,
    /// interrupted).
    Aborted,
}

impl JobState {
    /// Its StateNumber.
    pub fn number(self) -> u32 {
        match self {
            Self::NotAllowedToStart => 1,
            Self::AllowedToStart => 2,
            Self::Running => 3,
            Self::Interrupted => 4,
            Self::Ended => 5,
            Self::Aborted => 6,
        }
    }

    /// Its name (the state object's browse name).
    pub fn name(self) -> &'static str {
        match self {
            Self::NotAllowedToStart => "NotAllowedToStart",
            Self::AllowedToStart => "AllowedToStart",
            Self::Running => "Running",
            Self::Interrupted => "Interrupted",
            Self::Ended => "Ended",
            Self::Aborted => "Aborted",
        }
    }

    /// Whether it ended (nothing of it will run).
    pub fn ended(self) -> bool {
        matches!(self, Self::Ended | Self::Aborted)
    }
}

/// The state of a job order carried by `orders` (at least one), in a
/// cell whose list is `list` and mode `mode`.
pub fn state(orders: &[&Order], list: ListState, mode: CellMode) -> JobState {
    let ended = |o: &&&Order| !matches!(o.state, OrderState::Queued | OrderState::Running);
    let working = list == ListState::Running;
    if orders.iter().any(|o| o.state == OrderState::Running) {
        return if mode == CellMode::Auto {
            JobState::Running
        } else {
            JobState::Interrupted
        };
    }
    if orders.iter().all(|o| ended(&o)) {
        return if orders.iter().all(|o| o.state == OrderState::Done) {
            JobState::Ended
        } else {
            JobState::Aborted
        };
    }
    match (orders.iter().any(|o| ended(&o)), working) {
        (true, true) => JobState::Running,
        (true, false) => JobState::Interrupted,
        (false, true) => JobState::AllowedToStart,
        (false, false) => JobState::NotAllowedToStart,
    }
}

/// One job order as the cell's orders show it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Job {
    /// Its JobOrderID.
    pub id: String,
    /// Its work master: the cell recipe.
    pub recipe: String,
    /// Its orders' ids, first first.
    pub orders: Vec<i64>,
    /// Of those, the ones still queued.
    pub queued: Vec<i64>,
    /// Of those, the one that runs.
    pub running: Option<i64>,
    /// Its state.
    pub state: JobState,
    /// When its first order started (ms since the Unix epoch).
    pub started_ms: Option<i64>,
    /// When its last order ended, once every one has.
    pub ended_ms: Option<i64>,
    /// Its priority.
    pub priority: i32,
    /// When it is due.
    pub due_ms: Option<i64>,
    /// How each ended order ended (`order 12: done`).
    pub results: Vec<String>,
}

/// The job orders among `orders` (those carrying a JobOrderID), in the
/// order their first orders were added.
pub fn jobs(orders: &[&Order], list: ListState, mode: CellMode) -> Vec<Job> {
    let mut ids: Vec<&str> = Vec::new();
    for o in orders {
        if let Some(j) = o.job_order.as_deref() {
            if !ids.contains(&j) {
                ids.push(j);
            }
        }
    }
    ids.into_iter()
        .map(|id| {
            let mut mine: Vec<&Order> = orders
                .iter()
                .copied()
                .filter(|o| o.job_order.as_deref() == Some(id))
                .collect();
            mine.sort_by_key(|o| o.id);
            let state = state(&mine, list, mode);
            Job {
                id: id.to_string(),
                recipe: mine[0].recipe.clone(),
                orders: mine.iter().map(|o| o.id).collect(),
                queued: mine
                    .iter()
                    .filter(|o| o.state == OrderState::Queued)
                    .map(|o| o.id)
                    .collect(),
                running: mine
                    .iter()
                    .find(|o| o.state == OrderState::Running)
                    .map(|o| o.id),
                state,
                started_ms: mine.iter().filter_map(|o| o.started_ms).min(),
                ended_ms: if state.ended() {
                    mine.iter().filter_map(|o| o.ended_ms).max()
                } else {
                    None
                },
                priority: mine[0].priority,
                due_ms: mine[0].due_ms,
                results: mine
                    .iter()
                    .filter_map(|o| {
                        o.result
                            .as_ref()
                            .map(|r| format!("order {}: {}", o.id, printable(r)))
                    })
                    .collect(),
            }
        })
        .collect()
}

/// A parameter's value as the MES sent it.
#[derive(Debug, Clone, PartialEq)]
pub enum ParamValue {
    /// A String.
    Text(String),
    /// An integer of any width.
    Int(i64),
    /// Anything else (its type's name).
    Other(String),
}

/// A job order as the MES sent it (ISA95JobOrderDataType, the fields FALC
/// reads).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct JobOrderIn {
    /// JobOrderID.
    pub id: String,
    /// The IDs of its WorkMasterID entries.
    pub work_masters: Vec<String>,
    /// Its JobOrderParameters: ID and value.
    pub parameters: Vec<(String, ParamValue)>,
    /// Priority, if given.
    pub priority: Option<i16>,
    /// EndTime (ms since the Unix epoch), if given.
    pub end_ms: Option<i64>,
}

/// The parameters a job order may have.
pub const PARAMETERS: [&str; 2] = ["Count", "Cell"];

/// A job order FALC can carry out.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct JobOrder {
    /// Its JobOrderID.
    pub id: String,
    /// The cell recipe.
    pub recipe: String,
    /// How many orders.
    pub count: u16,
    /// Priority and due time.
    pub priority: i32,
    /// Due time.
    pub due_ms: Option<i64>,
}

impl JobOrder {
    /// Checks what the MES sent for machine `cell` (None: the one cell):
    /// exactly one work master (the cell recipe), known parameters of the
    /// right types, a priority within FALC's.
    pub fn check(j: &JobOrderIn, cell: Option<&CellId>) -> Result<JobOrder, String> {
        let id = j.id.trim();
        if id.is_empty()
            || id.chars().count() > MAX_JOB_ORDER_CHARS
            || id.chars().any(falc_model::ids::unprintable)
        {
            return Err(format!(
                "JobOrderID \"{}\" is empty, longer than {MAX_JOB_ORDER_CHARS} characters or \
                 holds a control character",
                falc_model::ids::excerpt(&j.id)
            ));
        }
        let recipe = match j.work_masters.as_slice() {
            [one] if !one.trim().is_empty() => one.trim().to_string(),
            [] => {
                return Err(format!(
                    "job order {id}: give its cell recipe as its WorkMasterID"
                ))
            }
            _ => {
                return Err(format!(
                    "job order {id}: give one WorkMasterID (the cell recipe), not {}",
                    j.work_masters.len()
                ))
            }
        };
        let mut count = 1u16;
        for (name, value) in &j.parameters {
            match (name.as_str(), value) {
                ("Count", ParamValue::Int(n)) => {
                    count = u16::try_from(*n)
                        .ok()
                        .filter(|n| (1..=MAX_ORDERS_PER_ADD).contains(n))
                        .ok_or_else(|| {
                            format!(
                                "job order {id}: Count {n} is outside 1 to {MAX_ORDERS_PER_ADD}"
                            )
                        })?;
                }
                ("Cell", ParamValue::Text(c)) => {
                    let mine = cell.map_or("", |c| c.as_str());
                    if c != mine {
                        return Err(format!(
                            "job order {id}: parameter Cell is {}, but this machine is {}",
                            printable(c),
                            if mine.is_empty() {
                                "the one cell"
                            } else {
                                mine
                            }
                        ));
                    }
                }
                ("Count" | "Cell", other) => {
                    return Err(format!(
                        "job order {id}: parameter {name} has the wrong type ({other:?}): Count \
                         is an integer, Cell a String"
                    ))
                }
                _ => {
                    return Err(format!(
                        "job order {id}: unknown parameter {}; FALC reads {}",
                        printable(name),
                        PARAMETERS.join(" and ")
                    ))
                }
            }
        }
        let priority = i32::from(j.priority.unwrap_or(0));
        if !(-MAX_PRIORITY..=MAX_PRIORITY).contains(&priority) {
            return Err(format!(
                "job order {id}: priority {priority} is outside -{MAX_PRIORITY} to {MAX_PRIORITY}"
            ));
        }
        Ok(JobOrder {
            id: id.to_string(),
            recipe,
            count,
            priority,
            due_ms: j.end_ms,
        })
    }

    /// The operator call that stores it in the list of `cell`.
    pub fn add(&self, cell: Option<&CellId>) -> ApiRequest {
        ApiRequest::OrderAdd {
            recipe: self.recipe.clone(),
            placement: Placement {
                cell: cell.cloned(),
                priority: self.priority,
                due_ms: self.due_ms,
                job_order: Some(self.id.clone()),
            },
            count: self.count,
        }
    }
}

/// A method of JobOrderControl.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// Store(JobOrder, Comment).
    Store,
    /// StoreAndStart(JobOrder, Comment).
    StoreAndStart,
    /// Update(JobOrder, Comment).
    Update,
    /// Start(JobOrderID, Comment).
    Start,
    /// Stop(JobOrderID, Comment).
    Stop,
    /// Abort(JobOrderID, Comment).
    Abort,
    /// Cancel(JobOrderID, Comment).
    Cancel,
    /// Clear(JobOrderID, Comment).
    Clear,
    /// RevokeStart(JobOrderID, Comment).
    RevokeStart,
    /// Pause(JobOrderID, Comment).
    Pause,
    /// Resume(JobOrderID, Comment).
    Resume,
}

impl Command {
    /// Every command.
    pub const ALL: [Command; 11] = [
        Self::Store,
        Self::StoreAndStart,
        Self::Update,
        Self::Start,
        Self::Stop,
        Self::Abort,
        Self::Cancel,
        Self::Clear,
        Self::RevokeStart,
        Self::Pause,
        Self::Resume,
    ];

    /// Its browse name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Store => "Store",
            Self::StoreAndStart => "StoreAndStart",
            Self::Update => "Update",
            Self::Start => "Start",
            Self::Stop => "Stop",
            Self::Abort => "Abort",
            Self::Cancel => "Cancel",
            Self::Clear => "Clear",
            Self::RevokeStart => "RevokeStart",
            Self::Pause => "Pause",
            Self::Resume => "Resume",
        }
    }

    /// Whether its first argument is a whole job order (else a
    /// JobOrderID).
    pub fn takes_job_order(self) -> bool {
        matches!(self, Self::Store | Self::StoreAndStart | Self::Update)
    }
}

/// What a command does: the operator calls in turn, or the ReturnStatus
/// and the reason it is refused with.
pub type Plan = Result<Vec<ApiRequest>, (u64, String)>;

/// The operator calls that carry out `command` on machine `cell`, whose
/// job orders are `jobs`, list is `list` and mode `mode`. `order` is the
/// job order sent (Store, StoreAndStart, Update), `id` its JobOrderID or
/// the one named (the others). Clear needs no call: the gateway stops
/// listing the ended job order (FALC keeps its orders' records).
pub fn plan(
    command: Command,
    order: Option<&JobOrder>,
    id: &str,
    cell: Option<&CellId>,
    jobs: &[Job],
    list: ListState,
) -> Plan {
    use status::*;
    let job = jobs.iter().find(|j| j.id == id);
    let start = |calls: &mut Vec<ApiRequest>| {
        if list != ListState::Running {
            calls.push(ApiRequest::Start);
        }
    };
    let remove = |j: &Job| -> Vec<ApiRequest> {
        j.queued
            .iter()
            .map(|&id| ApiRequest::OrderRemove { id })
            .collect()
    };
    let refuse = |bits: u64, why: String| Err((bits, why));
    match (command, job) {
        (Command::Store | Command::StoreAndStart, Some(_)) => refuse(
            UNABLE_TO_ACCEPT,
            format!("job order {id} exists already: Update it, or give a new JobOrderID"),
        ),
        (Command::Store | Command::StoreAndStart, None) => {
            let Some(o) = order else {
                return refuse(INVALID_REQUEST, "no job order given".into());
            };
            let mut calls = vec![o.add(cell)];
            if command == Command::StoreAndStart {
                start(&mut calls);
            }
            Ok(calls)
        }
        (_, None) => refuse(
            UNKNOWN_JOB_ORDER,
            format!("there is no job order {}", printable(id)),
        ),
        (Command::Update, Some(j)) => match (j.state, order) {
            (JobState::NotAllowedToStart | JobState::AllowedToStart, Some(o)) => {
                let mut calls = remove(j);
                calls.push(o.add(cell));
                Ok(calls)
            }
            (_, None) => refuse(INVALID_REQUEST, "no job order given".into()),
            (s, _) => refuse(
                INVALID_STATUS,
                format!(
                    "job order {id} is {}: only one not started may be updated",
                    s.name()
                ),
            ),
        },
        (Command::Start, Some(j)) => match j.state {
            JobState::NotAllowedToStart => {
                let mut calls = Vec::new();
                start(&mut calls);
                Ok(calls)
            }
            JobState::AllowedToStart => Ok(Vec::new()),
            s => refuse(
                INVALID_STATUS,
                format!(
                    "job order {id} is {}: only a stored one may be started",
                    s.name()
                ),
            ),
        },
        (Command::Stop | Command::Abort, Some(j)) => match j.state {
            JobState::Running | JobState::Interrupted => {
                // The running order stops (and with it the list); the
                // rest of the job order's go.
                let mut calls = Vec::new();
                if j.running.is_some() {
                    calls.push(ApiRequest::Stop);
                }
                calls.extend(remove(j));
                Ok(calls)
            }
            JobState::NotAllowedToStart | JobState::AllowedToStart if command == Command::Abort => {
                Ok(remove(j))
            }
            s => refuse(
                INVALID_STATUS,
                format!(
                    "job order {id} is {}: {} one that runs (Cancel one that has not started)",
                    s.name(),
                    if command == Command::Stop {
                        "Stop stops"
                    } else {
                        "Abort aborts"
                    }
                ),
            ),
        },
        (Command::Cancel, Some(j)) => match j.state {
            JobState::NotAllowedToStart | JobState::AllowedToStart => Ok(remove(j)),
            s => refuse(
                INVALID_STATUS,
                format!(
                    "job order {id} is {}: only one not started may be cancelled",
                    s.name()
                ),
            ),
        },
        (Command::Clear, Some(j)) => {
            if j.state.ended() {
                Ok(Vec::new())
            } else {
                refuse(
                    INVALID_STATUS,
                    format!(
                        "job order {id} is {}: only an ended one may be cleared",
                        j.state.name()
                    ),
                )
            }
        }
        (Command::RevokeStart, Some(_)) => refuse(
            INVALID_REQUEST,
            "FALC starts its order list, not one job order: Cancel the job order, or stop the \
             list with the FALC object's Stop"
                .into(),
        ),
        (Command::Pause, Some(j)) => match j.state {
            JobState::Running => Ok(vec![ApiRequest::Mode {
                mode: CellMode::Step,
                stations: Vec::new(),
            }]),
            s => refuse(
                INVALID_STATUS,
                format!(
                    "job order {id} is {}: Pause holds one that runs (the cell goes to step mode)",
                    s.name()
                ),
            ),
        },
        (Command::Resume, Some(j)) => match j.state {
            JobState::Interrupted => Ok(vec![ApiRequest::Mode {
                mode: CellMode::Auto,
                stations: Vec::new(),
            }]),
            s => refuse(
                INVALID_STATUS,
                format!(
                    "job order {id} is {}: Resume goes on with a held one",
                    s.name()
                ),
            ),
        },
    }
}

/// The ReturnStatus of a command whose operator call `call` was refused:
/// an order not added is a job order not accepted; any other call, one
/// whose state did not allow the command.
pub fn refused_status(call: &ApiRequest) -> u64 {
    match call {
        ApiRequest::OrderAdd { .. } => status::UNABLE_TO_ACCEPT,
        _ => status::INVALID_STATUS,
    }
}

/// A parameter of a job response: ID, value, and parameters under it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Param {
    /// Its ID.
    pub id: String,
    /// Its value.
    pub value: String,
    /// Parameters under it.
    pub subs: Vec<Param>,
}

impl Param {
    fn new(id: &str, value: impl Into<String>) -> Param {
        Param {
            id: id.to_string(),
            value: value.into(),
            subs: Vec::new(),
        }
    }
}

/// A job order's ISA-95 job response (ISA95JobResponseDataType, the
/// fields FALC fills).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Response {
    /// JobResponseID.
    pub id: String,
    /// JobOrderID.
    pub job_order: String,
    /// Description.
    pub description: String,
    /// Actual start.
    pub started_ms: Option<i64>,
    /// Actual end.
    pub ended_ms: Option<i64>,
    /// JobState.
    pub state: JobState,
    /// The equipment it ran on (the cell).
    pub equipment: Option<String>,
    /// JobResponseData: `Recipe`, then per order `Order` with its state,
    /// result, `RecipeVersion`s and workstation `Job`s.
    pub data: Vec<Param>,
}

/// The job response of `job` on machine `cell`, from its orders' records
/// (`records`: those the operator gave; an order without one is named
/// with its state only).
pub fn response(job: &Job, cell: Option<&CellId>, records: &[OrderRecord]) -> Response {
    let mut data = vec![Param::new("Recipe", job.recipe.as_str())];
    for &id in &job.orders {
        let mut p = Param::new("Order", id.to_string());
        if let Some(r) = records.iter().find(|r| r.order.id == id) {
            p.subs.push(Param::new("State", r.order.state.as_str()));
            if let Some(result) = &r.order.result {
                p.subs.push(Param::new("Result", printable(result)));
            }
            for run in &r.runs {
                for u in &run.recipes {
                    p.subs.push(Param::new(
                        "RecipeVersion",
                        format!("{} {} v{} {}", u.domain, u.file, u.version, u.hash),
                    ));
                }
            }
            for j in &r.jobs {
                p.subs.push(Param {
                    id: "Job".into(),
                    value: format!("{} {}", j.station, j.program),
                    subs: vec![Param::new("Outcome", printable(&j.outcome))],
                });
            }
        }
        data.push(p);
    }
    let cell_name = cell.map_or_else(
        || {
            records
                .iter()
                .find_map(|r| r.order.cell.clone())
                .unwrap_or_default()
        },
        |c| c.to_string(),
    );
    Response {
        id: job.id.clone(),
        job_order: job.id.clone(),
        description: format!(
            "{} order(s) of {}{}",
            job.orders.len(),
            job.recipe,
            if job.results.is_empty() {
                String::new()
            } else {
                format!(": {}", job.results.join("; "))
            }
        ),
        started_ms: job.started_ms,
        ended_ms: job.ended_ms,
        state: job.state,
        equipment: (!cell_name.is_empty()).then_some(cell_name),
        data,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn order(id: i64, state: OrderState, job: &str) -> Order {
        Order {
            id,
            recipe: "dikdroog".into(),
            state,
            added_by: "opcua".into(),
            started_ms: (state != OrderState::Queued).then_some(1_000 * id),
            ended_ms: matches!(state, OrderState::Done | OrderState::Failed)
                .then_some(1_000 * id + 500),
            result: (state == OrderState::Done).then(|| "done".to_string()),
            cell: None,
            wanted: Some("falc2".into()),
            priority: 0,
            due_ms: None,
            job_order: Some(job.into()),
        }
    }

    fn job_in(parameters: Vec<(&str, ParamValue)>) -> JobOrderIn {
        JobOrderIn {
            id: "MES-1".into(),
            work_masters: vec!["dikdroog".into()],
            parameters: parameters
                .into_iter()
                .map(|(n, v)| (n.to_string(), v))
                .collect(),
            priority: Some(5),
            end_ms: Some(99),
        }
    }

    #[test]
    fn a_job_order_state_follows_its_orders_and_the_list() {
        use JobState as J;
        use OrderState as O;
        let st = |states: &[O], list, mode| {
            let orders: Vec<Order> = states
                .iter()
                .enumerate()
                .map(|(i, s)| order(i as i64 + 1, *s, "j"))
                .collect();
            let refs: Vec<&Order> = orders.iter().collect();
            state(&refs, list, mode)
        };
        let (idle, run, auto) = (ListState::Idle, ListState::Running, CellMode::Auto);
        assert_eq!(st(&[O::Queued], idle, auto), J::NotAllowedToStart);
        assert_eq!(st(&[O::Queued], run, auto), J::AllowedToStart);
        assert_eq!(st(&[O::Running, O::Queued], run, auto), J::Running);
        assert_eq!(st(&[O::Running], run, CellMode::Step), J::Interrupted);
        assert_eq!(st(&[O::Done, O::Queued], run, auto), J::Running);
        assert_eq!(
            st(&[O::Done, O::Queued], ListState::Alarm, auto),
            J::Interrupted
        );
        assert_eq!(st(&[O::Done, O::Done], idle, auto), J::Ended);
        assert_eq!(st(&[O::Done, O::Failed], idle, auto), J::Aborted);
        assert_eq!(st(&[O::Stopped], run, auto), J::Aborted);
        assert_eq!(J::Ended.number(), 5);
    }

    #[test]
    fn orders_of_one_job_order_are_one_job_with_its_times_and_results() {
        let mut orders = vec![
            order(1, OrderState::Done, "A"),
            order(2, OrderState::Done, "A"),
            order(3, OrderState::Queued, "B"),
        ];
        orders.push(Order {
            job_order: None,
            ..order(4, OrderState::Queued, "")
        });
        let refs: Vec<&Order> = orders.iter().collect();
        let jobs = jobs(&refs, ListState::Idle, CellMode::Auto);
        assert_eq!(jobs.len(), 2, "{jobs:?}");
        assert_eq!(jobs[0].id, "A");
        assert_eq!(jobs[0].orders, vec![1, 2]);
        assert_eq!(jobs[0].state, JobState::Ended);
        assert_eq!(jobs[0].started_ms, Some(1_000));
        assert_eq!(jobs[0].ended_ms, Some(2_500));
        assert_eq!(jobs[0].results, vec!["order 1: done", "order 2: done"]);
        assert_eq!(jobs[1].queued, vec![3]);
        assert_eq!(jobs[1].ended_ms, None);
    }

    #[test]
    fn a_job_order_is_checked_before_it_becomes_orders() {
        let cell = CellId::new("falc2").ok();
        let ok = JobOrder::check(
            &job_in(vec![
                ("Count", ParamValue::Int(3)),
                ("Cell", ParamValue::Text("falc2".into())),
            ]),
            cell.as_ref(),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            ok,
            JobOrder {
                id: "MES-1".into(),
                recipe: "dikdroog".into(),
                count: 3,
                priority: 5,
                due_ms: Some(99),
            }
        );
        let ApiRequest::OrderAdd {
            placement, count, ..
        } = ok.add(cell.as_ref())
        else {
            panic!("not an OrderAdd");
        };
        assert_eq!((placement.job_order.as_deref(), count), (Some("MES-1"), 3));
        assert_eq!(placement.cell, cell);

        let refused = |j: JobOrderIn| JobOrder::check(&j, cell.as_ref()).unwrap_err();
        assert!(
            refused(job_in(vec![("Cell", ParamValue::Text("falc1".into()))]))
                .contains("this machine is falc2")
        );
        assert!(refused(job_in(vec![("Colour", ParamValue::Int(1))]))
            .contains("unknown parameter Colour"));
        assert!(refused(job_in(vec![("Count", ParamValue::Int(0))])).contains("outside 1 to"));
        assert!(
            refused(job_in(vec![("Count", ParamValue::Text("3".into()))])).contains("wrong type")
        );
        assert!(refused(JobOrderIn {
            work_masters: vec![],
            ..job_in(vec![])
        })
        .contains("WorkMasterID"));
        assert!(refused(JobOrderIn {
            id: " ".into(),
            ..job_in(vec![])
        })
        .contains("JobOrderID"));
        assert!(refused(JobOrderIn {
            priority: Some(500),
            ..job_in(vec![])
        })
        .contains("priority 500"));
    }

    #[test]
    fn each_command_maps_to_the_operator_calls_or_names_why_not() {
        let cell = CellId::new("falc2").ok();
        let o = JobOrder::check(&job_in(vec![]), cell.as_ref()).unwrap_or_else(|e| panic!("{e}"));
        let stored = jobs(
            &[&order(7, OrderState::Queued, "MES-1")],
            ListState::Idle,
            CellMode::Auto,
        );
        let running = jobs(
            &[
                &order(7, OrderState::Running, "MES-1"),
                &order(8, OrderState::Queued, "MES-1"),
            ],
            ListState::Running,
            CellMode::Auto,
        );
        let plan_ = |c, jobs: &[Job], list| plan(c, Some(&o), "MES-1", cell.as_ref(), jobs, list);
        // StoreAndStart: the orders, then the list started.
        let calls = plan_(Command::StoreAndStart, &[], ListState::Idle).unwrap_or_default();
        assert_eq!(calls.len(), 2);
        assert!(matches!(calls[0], ApiRequest::OrderAdd { .. }));
        assert_eq!(calls[1], ApiRequest::Start);
        // …but no second start of a list that runs.
        assert_eq!(
            plan_(Command::StoreAndStart, &[], ListState::Running).map(|c| c.len()),
            Ok(1)
        );
        assert_eq!(
            plan_(Command::Store, &stored, ListState::Idle)
                .unwrap_err()
                .0,
            status::UNABLE_TO_ACCEPT
        );
        assert_eq!(
            plan_(Command::Start, &stored, ListState::Idle),
            Ok(vec![ApiRequest::Start])
        );
        assert_eq!(
            plan_(Command::Cancel, &stored, ListState::Idle),
            Ok(vec![ApiRequest::OrderRemove { id: 7 }])
        );
        assert_eq!(
            plan_(Command::Abort, &running, ListState::Running),
            Ok(vec![ApiRequest::Stop, ApiRequest::OrderRemove { id: 8 }])
        );
        assert_eq!(
            plan_(Command::Cancel, &running, ListState::Running)
                .unwrap_err()
                .0,
            status::INVALID_STATUS
        );
        assert_eq!(
            plan(
                Command::Start,
                None,
                "nope",
                cell.as_ref(),
                &stored,
                ListState::Idle
            )
            .unwrap_err()
            .0,
            status::UNKNOWN_JOB_ORDER
        );
        assert!(matches!(
            plan_(Command::Pause, &running, ListState::Running).as_deref(),
            Ok([ApiRequest::Mode {
                mode: CellMode::Step,
                ..
            }])
        ));
        assert_eq!(
            plan_(Command::RevokeStart, &stored, ListState::Idle)
                .unwrap_err()
                .0,
            status::INVALID_REQUEST
        );
        // An operator's refusal, by the call refused.
        assert_eq!(
            refused_status(&o.add(cell.as_ref())),
            status::UNABLE_TO_ACCEPT
        );
        assert_eq!(refused_status(&ApiRequest::Start), status::INVALID_STATUS);
        assert_eq!(
            plan_(Command::Clear, &stored, ListState::Idle)
                .unwrap_err()
                .0,
            status::INVALID_STATUS
        );
    }
}
