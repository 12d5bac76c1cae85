//! The cell's coordination of its stations, sans-I/O: the cell
//! controller's [`Device`]. A cell recipe's `start` / `stop` become Start /
//! Stop (then Reset) requests to a workstation's program invocation,
//! `output` / `input` become operator-communication requests to the
//! commander. They leave as [`Command`]s ([`Stations::poll_command`]); the
//! driver sends each on its station's lane (one request at a time per
//! station, in order: outputs reach the operator in the recipe's order, a
//! Stop never overtakes its Start) and hands the confirm back with
//! [`handle_reply`]. Job events the workstations publish come in through
//! [`Stations::unconfirmed`]; only the job this recipe started counts.
//! [`route`] says where a commander's request is answered: a mode here and
//! then on every workstation, a step or manual operation on the one named.

use crate::controller::{Controller, Device, Happening};
use falc_model::alarm::{AlarmClass, Cause};
use falc_model::api::MAX_OUTPUT_LINES;
use falc_model::ids::{ObjectName, StationName};
use falc_model::mms::error::{DefinitionError, ErrorClass, ServiceError};
use falc_model::mms::pdu::{JobEvent, Request, Response, Severity, Unconfirmed};
use falc_model::mms::vmd::{PhysicalStatus, VmdStatus};
use falc_recipe::check::Job;
use falc_recipe::engine::{Action, Event, JobEnd};
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::Duration;

/// How long the operator may take to answer an `input`.
pub const ANSWER_LIMIT: Duration = Duration::from_secs(24 * 3600);
/// How long a workstation may take to confirm a request.
pub const CONFIRM_LIMIT: Duration = Duration::from_secs(10);
/// At most this many output lines the operator could not be shown (the
/// connection lost) are kept, to show once it is back; more are counted.
pub const MAX_UNSHOWN: usize = 1000;

/// `STATION$NAME` → the workstation and the recipe's name there: a domain
/// the operator downloads to the cell under that name is the workstation's
/// recipe, which the cell passes on.
pub fn workstation_domain(domain: &ObjectName) -> Option<(StationName, ObjectName)> {
    let (st, name) = domain.as_str().split_once('$')?;
    Some((StationName::new(st).ok()?, ObjectName::new(name).ok()?))
}

/// What a confirm means to the cell: which request it answers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Awaiting {
    /// The Start of the recipe's job on this station, by the recipe run
    /// numbered so (`Stations::run`): the confirm of an earlier run's
    /// Start (it timed out after a cut, say) is not this run's.
    Started(StationName, u64),
    /// The operator's answer to an `input`.
    Answer,
    /// The operator showing an `output`: its lines, kept if no answer
    /// came; `late` when they are lines it could not be shown before
    /// (no recipe's end waits for those).
    Shown {
        /// The lines.
        lines: Vec<String>,
        /// Shown once the operator was back.
        late: bool,
    },
    /// Anything else (Stop, Reset): only a refusal matters; what it was.
    Other(String),
}

/// A request the cell makes of a station below or of its operator.
#[derive(Debug, Clone, PartialEq)]
pub struct Command {
    /// The station (or the operator).
    pub to: StationName,
    /// The request.
    pub request: Request,
    /// How long its confirm may take.
    pub limit: Duration,
    /// What its confirm means.
    pub awaiting: Awaiting,
}

/// The confirm of a [`Command`]: the response, or why there is none.
#[derive(Debug, Clone, PartialEq)]
pub struct Reply {
    /// What it answers.
    pub awaiting: Awaiting,
    /// The response, or why there is none (refused, or no answer came:
    /// [`ServiceError::unanswered`]).
    pub result: Result<Response, ServiceError>,
}

/// The workstations below and the operator above.
#[derive(Debug, Default)]
pub struct Stations {
    operator: Option<StationName>,
    /// The program invocation the running recipe started on each station.
    started: BTreeMap<StationName, ObjectName>,
    /// Stations whose association was lost since the commander associated.
    lost: BTreeSet<StationName>,
    /// What each workstation's status last said keeps it from being
    /// ready (the start-up check: a start is refused naming it).
    unready: BTreeMap<StationName, String>,
    /// Outputs the operator has not confirmed yet: the recipe's end waits
    /// for them, so its last line is journalled under its own order.
    showing: usize,
    /// Output lines the operator could not be shown (the connection was
    /// lost), shown once the commander associates again.
    unshown: VecDeque<String>,
    /// How many more were not kept ([`MAX_UNSHOWN`]).
    unshown_dropped: usize,
    commands: VecDeque<Command>,
    /// Confirms known without asking anybody (no operator to ask).
    local: VecDeque<Reply>,
    /// The recipe run, counted up at each end: what a Start's confirm
    /// belongs to.
    run: u64,
}

impl Stations {
    /// A cell's stations, answering to `operator`.
    pub fn new(operator: Option<StationName>) -> Self {
        Self {
            operator,
            ..Self::default()
        }
    }

    /// Keeps output lines the operator could not be shown.
    fn keep_unshown(&mut self, lines: Vec<String>) {
        for line in lines {
            if self.unshown.len() < MAX_UNSHOWN {
                self.unshown.push_back(line);
            } else {
                self.unshown_dropped += 1;
            }
        }
    }

    /// Shows the operator, back, what it could not be shown: the lines as
    /// they came, under a first line that says so, in outputs of at most
    /// [`MAX_OUTPUT_LINES`] lines.
    fn show_unshown(&mut self) {
        let Some(op) = self.operator.clone() else {
            return;
        };
        if self.unshown.is_empty() && self.unshown_dropped == 0 {
            return;
        }
        let mut lines: Vec<String> = std::mem::take(&mut self.unshown).into();
        let dropped = std::mem::take(&mut self.unshown_dropped);
        if dropped > 0 {
            lines.push(format!("({dropped} more lines were not kept)"));
        }
        let header = "(shown late: the connection with the operator was lost)".to_string();
        for chunk in lines.chunks(MAX_OUTPUT_LINES - 1) {
            let lines = std::iter::once(header.clone())
                .chain(chunk.iter().cloned())
                .collect();
            // Not counted in `showing`: no recipe's end waits for these.
            let kept = Awaiting::Shown {
                lines: chunk.to_vec(),
                late: true,
            };
            self.request(op.clone(), Request::Output { lines }, CONFIRM_LIMIT, kept);
        }
    }

    /// The next request to send, in order.
    pub fn poll_command(&mut self) -> Option<Command> {
        self.commands.pop_front()
    }

    /// A confirm that needs no request (the driver hands it to
    /// [`handle_reply`] like any other).
    pub fn poll_local_reply(&mut self) -> Option<Reply> {
        self.local.pop_front()
    }

    fn request(&mut self, to: StationName, request: Request, limit: Duration, awaiting: Awaiting) {
        self.commands.push_back(Command {
            to,
            request,
            limit,
            awaiting,
        });
    }

    /// A publication of a workstation: the engine events it means for the
    /// running recipe (only the job this recipe started there counts).
    pub fn unconfirmed(&mut self, u: &Unconfirmed) -> Vec<Event> {
        if let Unconfirmed::Status { station, status } = u {
            match &status.unready {
                Some(why) => self.unready.insert(station.clone(), why.clone()),
                None => self.unready.remove(station),
            };
            return Vec::new();
        }
        let Unconfirmed::Job {
            station,
            program,
            event,
        } = u
        else {
            return Vec::new();
        };
        if self.started.get(station) != Some(program) {
            return Vec::new();
        }
        let st = station.clone();
        if *event == JobEvent::Started {
            // Its Start's confirm says so already.
            return Vec::new();
        }
        vec![match event {
            JobEvent::Done => Event::Ended(st, JobEnd::Done),
            JobEvent::BadProduct => Event::Ended(st, JobEnd::BadProduct),
            JobEvent::FailedSafe => Event::Ended(st, JobEnd::FailedSafe),
            JobEvent::FailedDanger => Event::Ended(st, JobEnd::FailedDanger),
            JobEvent::Alarm(text) => Event::Ended(st, JobEnd::Alarm(text.clone())),
            JobEvent::Paused => Event::Paused(st),
            JobEvent::Resumed => Event::Resumed(st),
            JobEvent::Started => return Vec::new(),
        }]
    }
}

/// Where a commander's request to the cell is answered ([`route`]).
#[derive(Debug, Clone, PartialEq)]
pub enum Route {
    /// By the cell's own controller.
    Here,
    /// By the cell's controller first (a mode); once it accepted, passed
    /// on to every workstation, whose first refusal is the answer.
    HereThenAll,
    /// By the workstation named (a step on it, a manual operation).
    To(StationName),
    /// Refused at once.
    Refused(ServiceError),
}

/// Where the commander's `request` is answered, for a cell over
/// `workstations`. A manual operation is never the cell's own: it goes to
/// the workstation it names, or is refused.
pub fn route(request: &Request, workstations: &[StationName]) -> Route {
    match request {
        Request::Mode(_) => Route::HereThenAll,
        Request::Step {
            station: Some(st), ..
        }
        | Request::Manual { station: st, .. }
            if workstations.contains(st) =>
        {
            Route::To(st.clone())
        }
        Request::Manual { station, .. } => Route::Refused(ServiceError::undefined(format!(
            "{station} is not a workstation of this cell: manual operations are on the \
             workstations ({})",
            workstations
                .iter()
                .map(StationName::as_str)
                .collect::<Vec<_>>()
                .join(", ")
        ))),
        _ => Route::Here,
    }
}

/// A confirm came back: what it means for the running cell recipe. A
/// refused Start takes the recipe's failure path (reported as a warning);
/// no answer from the operator is a communication alarm.
pub fn handle_reply(cell: &mut Controller<Stations>, now: Duration, reply: Reply) {
    match (reply.awaiting, reply.result) {
        (Awaiting::Started(st, run), r) if run != cell.device.run => {
            // Found by falc-sim: a Start lost in a cut timed out during the
            // next order's run and failed it.
            tracing::info!("the confirm of an earlier run's start on {st} came late: {r:?}");
        }
        (Awaiting::Started(st, _), Ok(_)) => cell.feed(now, vec![Event::Started(st)]),
        (Awaiting::Started(st, _), Err(e)) => {
            // The recipe takes its failure path; an alarm state there names this.
            cell.report(Severity::Warning, format!("start on {st} refused: {e}"));
            cell.feed(now, vec![Event::StartFailed(st, e.to_string())]);
        }
        (Awaiting::Answer, Ok(Response::Answer(a))) => cell.feed(now, vec![Event::Answer(a)]),
        (Awaiting::Answer, Ok(other)) => cell.fault(Cause::new(
            AlarmClass::Communication,
            format!("no answer from the operator: the operator answered {other:?}"),
        )),
        // The recipe that asked was stopped meanwhile (the operator then
        // refuses the question it waited on): nothing failed.
        (Awaiting::Answer, Err(e)) if !cell.is_running() => {
            tracing::info!("the question of a stopped recipe was withdrawn: {e}");
        }
        (Awaiting::Answer, Err(e)) => cell.fault(Cause::new(
            AlarmClass::Communication,
            format!("no answer from the operator: {e}"),
        )),
        (Awaiting::Shown { lines, late }, r) => {
            if !late {
                cell.device.showing = cell.device.showing.saturating_sub(1);
            }
            match r {
                // Kept to show once the operator is back.
                Err(e) if e.unanswered() => {
                    tracing::warn!("output not shown: {e}; kept to show once the operator is back");
                    cell.device.keep_unshown(lines);
                }
                Err(e) => tracing::warn!("output to the operator refused: {e}"),
                Ok(_) => {}
            }
        }
        (Awaiting::Other(what), Err(e)) => tracing::warn!("{what} refused: {e}"),
        (Awaiting::Other(_), Ok(_)) => {}
    }
}

/// What the device does when something happens ([`Device::handle`]).
impl Stations {
    fn act(&mut self, action: Action) {
        match action {
            Action::Start {
                target,
                job: Job::Recipe(name),
            } => {
                self.started.insert(target.clone(), name.clone());
                let req = Request::Start {
                    name,
                    argument: String::new(),
                };
                let awaiting = Awaiting::Started(target.clone(), self.run);
                self.request(target, req, CONFIRM_LIMIT, awaiting);
            }
            Action::Stop(target) => {
                // Stop, then Reset on the same lane: the program invocation
                // is idle again for the next order (a stopped one refuses
                // Start). A Reset refused because the job had already ended
                // is harmless.
                if let Some(name) = self.started.get(&target).cloned() {
                    let what = Awaiting::Other(format!("Stop of {name} on {target}"));
                    let stop = Request::Stop { name: name.clone() };
                    self.request(target.clone(), stop, CONFIRM_LIMIT, what);
                    let what = Awaiting::Other(format!("Reset of {name} on {target}"));
                    self.request(target, Request::Reset { name }, CONFIRM_LIMIT, what);
                }
            }
            Action::Output(text) => {
                if let Some(op) = self.operator.clone() {
                    let lines = vec![text];
                    let req = Request::Output {
                        lines: lines.clone(),
                    };
                    self.showing += 1;
                    let kept = Awaiting::Shown { lines, late: false };
                    self.request(op, req, CONFIRM_LIMIT, kept);
                }
            }
            Action::Input(prompt) => match self.operator.clone() {
                Some(op) => {
                    let req = Request::Input {
                        prompt,
                        timeout_s: None,
                    };
                    self.request(op, req, ANSWER_LIMIT, Awaiting::Answer);
                }
                None => self.local.push_back(Reply {
                    awaiting: Awaiting::Answer,
                    result: Err(ServiceError::new(
                        ErrorClass::Definition(DefinitionError::ObjectUndefined),
                        "this cell has no operator",
                    )),
                }),
            },
            other => tracing::warn!("a cell recipe cannot {other:?}"),
        }
    }

    fn halt(&mut self) {
        let running: Vec<StationName> = self.started.keys().cloned().collect();
        for st in running {
            self.act(Action::Stop(st));
        }
    }

    fn finished(&mut self) {
        self.started.clear();
        self.run += 1;
    }

    fn lost(&mut self, station: &StationName) {
        if Some(station) != self.operator.as_ref() {
            self.lost.insert(station.clone());
        }
    }

    fn associated(&mut self) {
        self.lost.clear();
        self.show_unshown();
    }
}

impl Device for Stations {
    fn handle(&mut self, _now: Duration, what: Happening<'_>, _out: &mut Vec<Event>) {
        match what {
            Happening::Act(action) => self.act(action),
            Happening::Halt => self.halt(),
            Happening::Finished(_) => self.finished(),
            Happening::Lost(station) => self.lost(station),
            Happening::Associated => self.associated(),
            Happening::Mode(_) | Happening::Clock => {}
        }
    }

    fn unavailable(&self) -> Option<String> {
        let lost = self
            .lost
            .iter()
            .next()
            .map(|s| format!("no connection with station {}", s.as_str().to_uppercase()));
        lost.or_else(|| {
            self.unready
                .iter()
                .next()
                .map(|(s, why)| format!("station {s} is not ready: {why}"))
        })
    }

    fn settling(&self) -> bool {
        self.showing > 0
    }

    fn status(&self, status: &mut VmdStatus) {
        if !self.lost.is_empty() {
            status.physical = PhysicalStatus::PartiallyOperational;
        }
    }
}

#[cfg(test)]
mod tests {
    //! The cell on a virtual clock: the controller with [`Stations`], the
    //! test playing the operator and the workstations by answering the
    //! commands it sends.

    use super::*;
    use crate::controller::testing::{job_events, load, outputs};
    use crate::controller::Output;
    use falc_model::mms::association::Role;
    use falc_model::mms::error::{ServiceErrorCode, VmdStateError};
    use falc_model::mms::program::PiState;
    use falc_recipe::commands::RecipeKind;

    const CELL: &str = crate::controller::testing::CELL_RECIPE;

    fn st(s: &str) -> StationName {
        StationName::new(s).unwrap()
    }

    fn name(s: &str) -> ObjectName {
        ObjectName::new(s).unwrap()
    }

    fn secs(s: u64) -> Duration {
        Duration::from_secs(s)
    }

    fn cell_with(operator: Option<StationName>) -> Controller<Stations> {
        let mut c = Controller::new(RecipeKind::Cell, CONFIRM_LIMIT, Stations::new(operator));
        load(&mut c, "test", CELL);
        c
    }

    fn cell() -> Controller<Stations> {
        cell_with(Some(st("operator")))
    }

    fn start(
        c: &mut Controller<Stations>,
    ) -> Result<Response, falc_model::mms::error::ServiceError> {
        c.handle_request(
            Duration::ZERO,
            &Request::Start {
                name: name("test"),
                argument: String::new(),
            },
        )
    }

    /// Settles as the driver does (local confirms included) and returns
    /// the commands to send.
    fn settle(c: &mut Controller<Stations>, now: Duration) -> Vec<Command> {
        loop {
            c.settle(now);
            match c.device.poll_local_reply() {
                Some(r) => handle_reply(c, now, r),
                None => break,
            }
        }
        std::iter::from_fn(|| c.device.poll_command()).collect()
    }

    /// The station (or operator) `cmd` went to confirms it with `r`.
    fn reply(c: &mut Controller<Stations>, now: Duration, cmd: &Command, r: Response) {
        answer(c, now, cmd, Ok(r));
    }

    /// … or the confirm does not come: refused with `error`, or no
    /// answer ([`ServiceError::unanswered`]).
    fn refused(c: &mut Controller<Stations>, now: Duration, cmd: &Command, error: ServiceError) {
        answer(c, now, cmd, Err(error));
    }

    fn answer(
        c: &mut Controller<Stations>,
        now: Duration,
        cmd: &Command,
        result: Result<Response, ServiceError>,
    ) {
        let awaiting = cmd.awaiting.clone();
        handle_reply(c, now, Reply { awaiting, result });
    }

    /// … or no answer comes at all: the peer is not reachable.
    fn no_reply(c: &mut Controller<Stations>, now: Duration, cmd: &Command) {
        let error = ServiceError::unreachable(format!("no reply from {}", cmd.to));
        refused(c, now, cmd, error);
    }

    fn job_done(station: &str, program: &str) -> Unconfirmed {
        Unconfirmed::Job {
            station: st(station),
            program: name(program),
            event: JobEvent::Done,
        }
    }

    /// [`up_to_the_transport_job`], its start confirmed: the commands that
    /// follow (none while the job runs).
    fn transport_job_running(c: &mut Controller<Stations>) -> Vec<Command> {
        let store = up_to_the_transport_job(c);
        reply(
            c,
            secs(6),
            &store,
            Response::ProgramInvocationState(PiState::Running),
        );
        settle(c, secs(6))
    }

    /// Runs the recipe to its `start transport store`, returning that
    /// command.
    fn up_to_the_transport_job(c: &mut Controller<Stations>) -> Command {
        start(c).unwrap();
        // An output does not wait for its confirm: the question follows
        // on the same lane.
        let cmds = settle(c, Duration::ZERO);
        assert_eq!(cmds.len(), 2);
        assert!(cmds.iter().all(|c| c.to == st("operator")));
        assert_eq!(
            cmds[0].request,
            Request::Output {
                lines: vec!["hallo".into()]
            }
        );
        assert_eq!(cmds[1].awaiting, Awaiting::Answer);
        assert_eq!(cmds[1].limit, ANSWER_LIMIT);
        reply(c, secs(1), &cmds[0], Response::Done);
        assert!(settle(c, secs(1)).is_empty());
        reply(c, secs(5), &cmds[1], Response::Answer("ja".into()));
        let cmds = settle(c, secs(5));
        assert_eq!(cmds.len(), 1);
        assert_eq!(cmds[0].to, st("transport"));
        assert_eq!(
            cmds[0].request,
            Request::Start {
                name: name("STORE"),
                argument: String::new()
            }
        );
        cmds[0].clone()
    }

    #[test]
    fn a_cell_recipe_runs_through_operator_and_workstation_to_done() {
        let mut c = cell();
        assert!(transport_job_running(&mut c).is_empty());
        assert_eq!(c.status().program.map(|p| p.state), Some(4));
        // Another program's end on the same station is not this job's.
        let other = c.device.unconfirmed(&job_done("transport", "MOVE_TO_MAN"));
        assert!(other.is_empty());
        let events = c.device.unconfirmed(&job_done("transport", "STORE"));
        c.feed(secs(30), events);
        let cmds = settle(&mut c, secs(30));
        assert_eq!(
            cmds[0].request,
            Request::Output {
                lines: vec!["einde".into()]
            }
        );
        // The end waits until the operator has shown the last output.
        assert!(c.is_running());
        assert!(!outputs(&mut c)
            .iter()
            .any(|o| matches!(o, Output::Job { .. })));
        reply(&mut c, secs(31), &cmds[0], Response::Done);
        settle(&mut c, secs(31));
        assert!(!c.is_running());
        assert_eq!(
            outputs(&mut c),
            vec![Output::Job {
                program: name("test"),
                event: JobEvent::Done
            }]
        );
    }

    #[test]
    fn a_refused_start_below_is_a_warning_and_takes_the_failure_path() {
        let mut c = cell();
        let store = up_to_the_transport_job(&mut c);
        refused(
            &mut c,
            secs(6),
            &store,
            ServiceError::new(
                ErrorClass::VmdState(VmdStateError::VmdStateConflict),
                "emergency stop",
            ),
        );
        settle(&mut c, secs(6));
        assert!(!c.is_running());
        let outs = outputs(&mut c);
        assert!(
            outs.iter().any(|o| matches!(o,
            Output::Report { severity: Severity::Warning, text }
                if text.contains("start on transport refused") && text.contains("emergency stop")))
        );
        assert!(outs.iter().any(|o| matches!(
            o,
            Output::Job {
                event: JobEvent::Alarm(_),
                ..
            }
        )));
    }

    #[test]
    fn a_late_confirm_of_an_earlier_runs_start_is_not_this_runs() {
        // Found by falc-sim: a Start lost in a cut timed out during the
        // next order's run and failed it.
        let mut c = cell();
        let first = up_to_the_transport_job(&mut c);
        c.handle_abort(Duration::ZERO, &st("transport"), Role::Subordinate);
        settle(&mut c, secs(6));
        assert!(!c.is_running());
        outputs(&mut c);
        c.handle_associated(Duration::ZERO);
        let second = up_to_the_transport_job(&mut c);
        no_reply(&mut c, secs(16), &first);
        settle(&mut c, secs(16));
        assert!(c.is_running(), "the earlier run's confirm ends nothing");
        assert!(
            !outputs(&mut c)
                .iter()
                .any(|o| matches!(o, Output::Report { text, .. } if text.contains("refused"))),
            "and is not reported as this run's"
        );
        // This run's own refusal still takes the failure path.
        no_reply(&mut c, secs(17), &second);
        settle(&mut c, secs(17));
        assert!(!c.is_running());
    }

    #[test]
    fn a_lost_workstation_ends_the_recipe_and_refuses_starts_until_the_commander_associates() {
        let mut c = cell();
        transport_job_running(&mut c);
        c.handle_abort(Duration::ZERO, &st("transport"), Role::Subordinate);
        settle(&mut c, secs(7));
        assert!(!c.is_running());
        let outs = outputs(&mut c);
        assert!(outs.contains(&Output::Report {
            severity: Severity::Alarm(AlarmClass::Communication),
            text: "no connection with station transport".into()
        }));
        assert_eq!(c.status().physical, PhysicalStatus::PartiallyOperational);
        // A late end of the lost station's job changes nothing.
        assert!(c
            .device
            .unconfirmed(&job_done("transport", "STORE"))
            .is_empty());
        let refused = start(&mut c).unwrap_err();
        assert!(
            refused
                .description
                .contains("no connection with station TRANSPORT"),
            "{refused:?}"
        );
        c.handle_associated(Duration::ZERO);
        start(&mut c).unwrap();
        assert_eq!(
            settle(&mut c, secs(8)).len(),
            2,
            "output and question again"
        );
    }

    #[test]
    fn a_cell_cut_off_from_its_commander_runs_its_order_to_the_end_and_keeps_it() {
        let mut c = cell().runs_on_alone(true);
        transport_job_running(&mut c);
        c.handle_abort(Duration::ZERO, &st("operator"), Role::Commander);
        assert!(settle(&mut c, secs(7)).is_empty(), "nothing is stopped");
        assert!(c.is_running());
        let outs = outputs(&mut c);
        assert!(
            matches!(outs.as_slice(), [Output::Report { severity: Severity::Warning, text }]
                if text.contains("runs on to its end")),
            "{outs:?}"
        );
        // The workstation's job ends; the last output cannot reach the
        // operator (refused at once): the recipe ends all the same.
        let events = c.device.unconfirmed(&job_done("transport", "STORE"));
        c.feed(secs(30), events);
        let cmds = settle(&mut c, secs(30));
        no_reply(&mut c, secs(30), &cmds[0]);
        settle(&mut c, secs(30));
        assert!(!c.is_running());
        assert_eq!(job_events(&outputs(&mut c)), vec![JobEvent::Done]);
        // The end is kept for the commander, until the next Start.
        let attributes = |c: &mut Controller<Stations>| match c.handle_request(
            secs(31),
            &Request::GetProgramInvocationAttributes { name: name("test") },
        ) {
            Ok(Response::PiAttributes(a)) => a,
            other => panic!("{other:?}"),
        };
        let a = attributes(&mut c);
        assert_eq!((a.state, a.last_end), (PiState::Idle, Some(JobEvent::Done)));
        // Back: what it could not be shown is shown now, said late.
        c.handle_associated(Duration::ZERO);
        let cmds = settle(&mut c, secs(32));
        assert_eq!(
            cmds.iter().map(|c| &c.request).collect::<Vec<_>>(),
            vec![&Request::Output {
                lines: vec![
                    "(shown late: the connection with the operator was lost)".into(),
                    "einde".into()
                ]
            }]
        );
        reply(&mut c, secs(32), &cmds[0], Response::Done);
        c.handle_associated(Duration::ZERO);
        assert!(settle(&mut c, secs(33)).is_empty(), "shown once");
        start(&mut c).unwrap();
        assert_eq!(attributes(&mut c).last_end, None);
    }

    #[test]
    fn a_cell_that_does_not_run_on_alone_ends_its_order_when_the_commander_is_lost() {
        let mut c = cell();
        transport_job_running(&mut c);
        c.handle_abort(Duration::ZERO, &st("operator"), Role::Commander);
        let cmds = settle(&mut c, secs(7));
        assert!(!c.is_running());
        assert!(cmds.iter().any(|c| c.request
            == Request::Stop {
                name: name("STORE")
            }));
        assert!(matches!(
            job_events(&outputs(&mut c)).as_slice(),
            [JobEvent::Alarm(cause)] if cause.text == "no connection with station operator"
        ));
    }

    #[test]
    fn a_stop_from_the_commander_stops_then_resets_the_job_below_in_that_order() {
        let mut c = cell();
        transport_job_running(&mut c);
        c.handle_request(secs(7), &Request::Stop { name: name("test") })
            .unwrap();
        let cmds = settle(&mut c, secs(7));
        let sent: Vec<(StationName, Request)> =
            cmds.into_iter().map(|c| (c.to, c.request)).collect();
        assert_eq!(
            sent,
            vec![
                (
                    st("transport"),
                    Request::Stop {
                        name: name("STORE")
                    }
                ),
                (
                    st("transport"),
                    Request::Reset {
                        name: name("STORE")
                    }
                ),
            ]
        );
        assert!(!c.is_running());
    }

    #[test]
    fn no_answer_from_the_operator_is_a_communication_alarm() {
        let mut c = cell();
        start(&mut c).unwrap();
        let cmds = settle(&mut c, Duration::ZERO);
        reply(&mut c, secs(1), &cmds[0], Response::Done);
        refused(
            &mut c,
            secs(2),
            &cmds[1],
            ServiceError::unreachable("the operator is not reachable"),
        );
        settle(&mut c, secs(2));
        assert!(!c.is_running());
        assert!(outputs(&mut c).iter().any(|o| matches!(o,
            Output::Report { severity: Severity::Alarm(AlarmClass::Communication), text }
                if text.starts_with("no answer from the operator"))));
    }

    #[test]
    fn a_mode_goes_everywhere_a_step_or_manual_operation_to_its_workstation() {
        use falc_model::mode::{ManualAction, ModeSetting};
        let below = [st("welding"), st("transport")];
        assert_eq!(
            route(&Request::Mode(ModeSetting::default()), &below),
            Route::HereThenAll
        );
        let step = |station: Option<&str>| Request::Step {
            station: station.map(st),
            to: None,
        };
        assert_eq!(route(&step(None), &below), Route::Here);
        assert_eq!(route(&step(Some("cell")), &below), Route::Here);
        assert_eq!(
            route(&step(Some("transport")), &below),
            Route::To(st("transport"))
        );
        let manual = |station: &str| Request::Manual {
            station: st(station),
            action: ManualAction::StopProgram,
            by: "maint".into(),
        };
        assert_eq!(route(&manual("welding"), &below), Route::To(st("welding")));
        let Route::Refused(e) = route(&manual("cell"), &below) else {
            panic!("the cell has no manual operations")
        };
        assert!(e.description.contains("(welding, transport)"), "{e}");
        assert_eq!(route(&Request::Status, &below), Route::Here);
    }

    #[test]
    fn the_question_of_a_stopped_recipe_refused_is_no_alarm() {
        let mut c = cell();
        start(&mut c).unwrap();
        let cmds = settle(&mut c, Duration::ZERO);
        reply(&mut c, secs(1), &cmds[0], Response::Done);
        c.handle_request(secs(2), &Request::Stop { name: name("test") })
            .unwrap();
        outputs(&mut c);
        let stopped = ServiceError::new(
            ErrorClass::Service(ServiceErrorCode::ObjectStateConflict),
            "the order was stopped",
        );
        refused(&mut c, secs(2), &cmds[1], stopped);
        settle(&mut c, secs(2));
        assert_eq!(outputs(&mut c), vec![], "no alarm: nothing failed");
    }

    #[test]
    fn a_cell_without_an_operator_cannot_ask_and_says_so() {
        let mut c = cell_with(None);
        start(&mut c).unwrap();
        // No operator: the output goes nowhere, the input fails at once.
        let cmds = settle(&mut c, Duration::ZERO);
        assert!(cmds.is_empty());
        assert!(!c.is_running());
        assert!(outputs(&mut c).iter().any(|o| matches!(o,
            Output::Report { text, .. } if text.contains("this cell has no operator"))));
    }

    #[test]
    fn a_start_is_refused_while_a_workstation_says_it_is_not_ready_naming_why() {
        use falc_model::mms::vmd::{RecipeState, VmdStatus};
        let mut c = cell();
        assert_eq!(c.recipe_state(), RecipeState::Ready);
        let status = |unready: Option<&str>| Unconfirmed::Status {
            station: st("welding"),
            status: VmdStatus {
                unready: unready.map(str::to_string),
                ..VmdStatus::default()
            },
        };
        let why = "the robot on /dev/ttyS0 is in manual mode, not automatic-external (AUE)";
        assert!(c.device.unconfirmed(&status(Some(why))).is_empty());
        assert_eq!(c.recipe_state(), RecipeState::Loaded);
        assert_eq!(
            c.status().unready.as_deref(),
            Some(format!("station welding is not ready: {why}").as_str())
        );
        let e = start(&mut c).expect_err("refused");
        assert!(
            e.description.contains("station welding is not ready")
                && e.description.contains("manual mode"),
            "{e:?}"
        );
        assert!(!c.is_running());
        // Ready again: the start goes.
        c.device.unconfirmed(&status(None));
        assert_eq!(c.recipe_state(), RecipeState::Ready);
        assert!(start(&mut c).is_ok());
    }
}
