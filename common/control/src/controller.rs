//! The recipe runtime every control level runs, sans-I/O: a workstation
//! around its device (welding, transport), the cell around its
//! workstations. It owns the VMD served to the commander (domains, program
//! invocations), one running recipe at a time, its job events (done, alarm,
//! bad product, failed …) and reports, and the level's status.
//!
//! Quinn-proto style: the driver hands in what happened with the time it
//! happened ([`Controller::handle_request`], [`Controller::feed`],
//! [`Controller::fault`], [`Controller::handle_timeout`]), calls
//! [`Controller::settle`], then publishes what [`Controller::poll_output`]
//! gives and sleeps until [`Controller::poll_timeout`]. Time is a
//! [`Duration`] since the driver's start, so tests run on a virtual clock.
//! The driver on the bus is `falc_node::controller_node`.
//!
//! Modes (`falc_model::mode`): the commander sets the cell's mode with
//! [`Request::Mode`]; in step mode a level that steps holds each recipe
//! state until [`Request::Step`]; in maintenance mode no program starts
//! but a [`Request::Manual`] is carried out by the device (or runs one of
//! the station's recipes, its `home`), and refused in any other mode. A
//! Stop keeps the run: Resume goes on where it stopped (ISO 9506); a Start
//! whose argument ends in `from N` begins at state N (an order restarted).
//!
//! What differs per level is its [`Device`]: how the engine's device
//! actions (`start rcm`, `activate`, `waitplace`, a cell's `start`) are
//! carried out, why a recipe cannot start now, and what the device adds to
//! the status.

use falc_model::alarm::{AlarmClass, Cause};
use falc_model::ids::{ObjectName, RobotProgram, StationName};
use falc_model::mms::association::Role;
use falc_model::mms::domain::content_hash;
use falc_model::mms::error::{DefinitionError, ErrorClass, ServiceError};
use falc_model::mms::pdu::{JobEvent, Request, Response, Severity, Unconfirmed};
use falc_model::mms::program::{PiCompletion, PiRequest, PiState};
use falc_model::mms::vmd::{Identity, ProgramState, RecipeState, Transition, Vmd, VmdStatus};
use falc_model::mode::{CellMode, HeldStep, ManualAction, ModeSetting};
use falc_recipe::check::{check, Program};
use falc_recipe::commands::RecipeKind;
use falc_recipe::condition::{unmet, Conditions, Fact};
use falc_recipe::engine::{Action, Awaited, Engine, Event, JobEnd, Outcome};
use falc_recipe::problem::Problem;
use falc_recipe::robot_program::ProgramText;
use falc_recipe::syntax::{parse, StateNo};
use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use std::time::Duration;

/// What happens to a level's device: the running recipe's actions, its
/// end, the associations and the mode, and the clock
/// ([`Device::handle`]).
#[derive(Debug, PartialEq)]
pub enum Happening<'a> {
    /// A device action of the running recipe (`Start`, `Stop`,
    /// `Activate`, `Reset`, `Watch`, `Unwatch`, `Output`, `Input`).
    Act(Action),
    /// The commander stopped or killed the recipe: stop the device.
    Halt,
    /// The recipe ended: leave the device safe.
    Finished(&'a Outcome),
    /// An association was lost (the commander, or a subordinate of a cell).
    Lost(&'a StationName),
    /// The commander associated (and with it every subordinate).
    Associated,
    /// The cell's mode changed (the device releases what a maintainer
    /// left pressed when maintenance ends).
    Mode(CellMode),
    /// The clock reached [`Device::poll_timeout`].
    Clock,
}

/// A level's device, as its recipes see it: what happens goes in through
/// [`Device::handle`] with the time, what the device raises comes out
/// through [`Device::poll_report`], and it is asked why it cannot start,
/// whether it settles and what it adds to the status. Commands to the
/// device's own link (a serial telegram, a coil write) leave through the
/// device's own `poll_*`, which its driver calls.
pub trait Device {
    /// Something happened ([`Happening`]); events for the running recipe
    /// that follow at once go into `out`.
    fn handle(&mut self, now: Duration, what: Happening<'_>, out: &mut Vec<Event>);
    /// Why no recipe can start now (no link, emergency stop), if so.
    fn unavailable(&self) -> Option<String>;
    /// Why the station is not ready for its commander's work (published
    /// in its status: the cell refuses a start while a workstation says
    /// so): what [`Self::unavailable`] says, and what only the station's
    /// own recipes may put right (a robot not in automatic-external mode,
    /// which its `home` recipe checks again).
    fn unready(&self) -> Option<String> {
        self.unavailable()
    }
    /// The device's part of the status (physical status, additional detail).
    fn status(&self, status: &mut VmdStatus);
    /// Whether outputs the recipe issued are not carried out yet: a job
    /// that ended well is reported done only once they are (the commander
    /// must not start the next job while, say, a coil write is in flight).
    fn settling(&self) -> bool {
        false
    }
    /// A limit is about to run out: what the device sees, for the alarm
    /// text (e.g. which input was not reached, which line still runs).
    fn explain_timeout(&self, _now: Duration) -> Option<String> {
        None
    }
    /// When the device's own supervision next needs the clock (a status
    /// request due, a silence limit), if ever. The controller sleeps until
    /// the earlier of this and the recipe's limit, then hands the device
    /// [`Happening::Clock`].
    fn poll_timeout(&self) -> Option<Duration> {
        None
    }
    /// What the device tells the operator, reported when the controller
    /// settles, in order: what it does (a robot program started or ended,
    /// the robot's information messages, a conveyor line run, a carrier
    /// arriving), and alarms no recipe step owns (a lost line while idle,
    /// a program found running that nobody started).
    fn poll_report(&mut self) -> Option<(Severity, String)> {
        None
    }
    /// A fault the device's own supervision found on the clock
    /// ([`Happening::Clock`]): the running recipe ends in it, and it goes
    /// up as an alarm (also when no recipe runs).
    fn poll_fault(&mut self) -> Option<Cause> {
        None
    }
    /// What `program` names that this device lacks (a conveyor line its
    /// equipment does not have), as problems at their lines: a start of
    /// it is refused with them. Nothing, for a device that names nothing.
    fn check_program(&self, _program: &Program) -> Vec<Problem> {
        Vec::new()
    }
    /// A manual operation (maintenance mode, no recipe running; the
    /// controller checked both): what was done, or why not.
    fn manual(&mut self, _now: Duration, action: &ManualAction) -> Result<String, String> {
        Err(format!(
            "{action}: this station has no such manual operation"
        ))
    }
    /// A precondition is about to be evaluated at `now`: when the device's
    /// reading may be older than what it observes (a poll period), it
    /// asks for a fresh one and answers true; the controller then holds
    /// the Start until [`Device::has_fresh_reading`]. False: evaluate now.
    fn ask_fresh_reading(&mut self, _now: Duration) -> bool {
        false
    }
    /// Whether the reading [`Device::ask_fresh_reading`] asked for came
    /// (or can no longer come).
    fn has_fresh_reading(&self) -> bool {
        true
    }
    /// What the device observes of `fact` now (a place occupied, a line
    /// running, the robot ready), for a recipe's `#PRE` and `#POST`; None
    /// when it cannot tell (no reading, no such input).
    fn observes(&self, _fact: Fact) -> Option<bool> {
        None
    }
    /// The way to the device's named state `state` from what it shows
    /// now, as a recipe of this level (`#GOTO_<STATE>`) and a line saying
    /// what it does; or why there is none. No named states: none.
    fn way_to(&self, state: &str) -> Result<(String, String), String> {
        Err(format!("this station has no named state `{state}`"))
    }
    /// Delivers a robot program's text (a domain `PROGRAM_065` the
    /// commander downloaded) to the device's robot; how it ended comes
    /// out of [`Device::poll_delivered`]. A device without a robot refuses.
    fn deliver_program(&mut self, program: &ProgramText) -> Result<(), ServiceError> {
        Err(ServiceError::undefined(format!(
            "robot program {} cannot be delivered here: this station has no robot",
            program.number
        )))
    }
    /// A delivery of [`Device::deliver_program`] that ended.
    fn poll_delivered(&mut self) -> Option<(RobotProgram, Result<(), ServiceError>)> {
        None
    }
}

/// What the controller publishes, in order.
#[derive(Debug, Clone, PartialEq)]
pub enum Output {
    /// A report (operator message) from this station.
    Report {
        /// How bad it is (an alarm carries its class).
        severity: Severity,
        /// What happened.
        text: String,
    },
    /// A job event of a program invocation (done, alarm, bad product …).
    Job {
        /// The program invocation.
        program: ObjectName,
        /// What became of it.
        event: JobEvent,
    },
}

impl Output {
    /// The publication it is, as `station` puts it on the bus.
    pub fn publication(self, station: StationName) -> Unconfirmed {
        match self {
            Output::Report { severity, text } => Unconfirmed::Report {
                station,
                severity,
                text,
            },
            Output::Job { program, event } => Unconfirmed::Job {
                station,
                program,
                event,
            },
        }
    }
}

struct Running {
    name: ObjectName,
    engine: Engine,
    /// What the device saw when a limit last ran out.
    timed_out: Option<String>,
    /// A workstation's job reported paused because a step waits (its
    /// commander's limits stand still meanwhile).
    paused_for_step: bool,
}

impl Running {
    /// A run of `engine` as recipe `name`, just started.
    fn new(name: ObjectName, engine: Engine) -> Self {
        Self {
            name,
            engine,
            timed_out: None,
            paused_for_step: false,
        }
    }

    /// State `s`'s command as the recipe gives it (empty for none).
    fn command_of(&self, s: StateNo) -> &str {
        self.engine
            .program()
            .states
            .get(&s)
            .map_or("", |st| st.text.as_str())
    }
}

/// What one reading of a device means ([`Controller::take_reading`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Reading {
    /// For the running recipe.
    pub events: Vec<Event>,
    /// An emergency stop (safety), or the device out of ready.
    pub alarm: Option<Cause>,
    /// The device became usable again: the line to report.
    pub ready: Option<String>,
}

/// The runtime of one control level.
pub struct Controller<D> {
    vmd: Vmd,
    /// This station (whether it steps in step mode).
    me: StationName,
    mode: ModeSetting,
    /// The run a Stop stopped, kept for Resume.
    stopped: Option<Running>,
    /// The device.
    pub device: D,
    kind: RecipeKind,
    confirm_limit: Duration,
    running: Option<Running>,
    /// Whether a running recipe goes on when the commander is lost
    /// ([`Self::runs_on_alone`]).
    runs_on_alone: bool,
    /// An alarm (a device fault, a run that did not end done) since the
    /// last reset: the recipe state is ERROR until a run starts or the
    /// commander resets a program invocation.
    alarmed: bool,
    out: VecDeque<Output>,
    /// Each loaded program invocation's recipe, checked (or why it does
    /// not check), with a hash of the text it was read from: what a Start
    /// runs, and whose `#PRE` the status's [`VmdStatus::unmet`] lists.
    programs: BTreeMap<ObjectName, (u64, Result<Arc<Program>, ServiceError>)>,
    /// A recipe came or went since the programs were read.
    programs_stale: bool,
    /// The status's `unmet`, and what the device observed of every term
    /// when it was made (made again only when that changed).
    unmet: BTreeMap<ObjectName, String>,
    unmet_seen: Option<Vec<Option<bool>>>,
}

impl<D: Device> Controller<D> {
    /// A controller of `kind`; a `start` in its recipes waits
    /// `confirm_limit` for the device's confirm.
    pub fn new(kind: RecipeKind, confirm_limit: Duration, device: D) -> Self {
        Self {
            vmd: Vmd::new(Identity {
                vendor: "FALC".into(),
                model: kind.to_string(),
                revision: env!("CARGO_PKG_VERSION").into(),
            }),
            // cell, welding, transport: valid station names.
            me: StationName::new(&kind.to_string())
                .unwrap_or_else(|e| unreachable!("{kind} as a station name: {e}")),
            mode: ModeSetting::default(),
            stopped: None,
            device,
            kind,
            confirm_limit,
            running: None,
            runs_on_alone: false,
            alarmed: false,
            out: VecDeque::new(),
            programs: BTreeMap::new(),
            programs_stale: false,
            unmet: BTreeMap::new(),
            unmet_seen: None,
        }
    }

    /// A level whose running recipe goes on to its end when the commander
    /// is lost (a cell: `StationKind::runs_on_alone`). The end is kept in
    /// the program invocation ([`Vmd::record_end`]) for the commander to
    /// ask once it is back; a lost subordinate still ends the recipe.
    pub fn runs_on_alone(mut self, yes: bool) -> Self {
        self.runs_on_alone = yes;
        self
    }

    /// Its recipe memory holds at most `bytes` of domains (default
    /// [`falc_model::mms::vmd::RECIPE_MEMORY`]): a delivery past it is
    /// refused, and the delivery taken back.
    pub fn set_recipe_memory(&mut self, bytes: usize) {
        self.vmd.set_memory(bytes);
    }

    /// The station this controller is (default: its kind's name).
    pub fn named(mut self, me: StationName) -> Self {
        self.me = me;
        self
    }

    /// The mode as this level has it.
    pub fn mode(&self) -> &ModeSetting {
        &self.mode
    }

    /// Whether a recipe runs.
    pub fn is_running(&self) -> bool {
        self.running.is_some()
    }

    /// When the clock is next needed: the running recipe's next limit or
    /// the device's supervision, whichever comes first.
    pub fn poll_timeout(&self) -> Option<Duration> {
        let recipe = self.running.as_ref().and_then(|r| r.engine.poll_timeout());
        match (recipe, self.device.poll_timeout()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The clock reached [`Self::poll_timeout`]: the device's supervision
    /// and the recipe's limit, each if due.
    pub fn handle_timeout(&mut self, now: Duration) {
        if self.device.poll_timeout().is_some_and(|d| d <= now) {
            let mut out = Vec::new();
            self.device.handle(now, Happening::Clock, &mut out);
            self.feed(now, out);
            while let Some(cause) = self.device.poll_fault() {
                self.fault(cause);
            }
        }
        let due = self
            .running
            .as_ref()
            .and_then(|r| r.engine.poll_timeout())
            .is_some_and(|d| d <= now);
        if !due {
            return;
        }
        let explained = self.device.explain_timeout(now);
        if let Some(r) = &mut self.running {
            if let Some(e) = &explained {
                tracing::info!(state = %r.engine.state(), "limit ran out: {e}");
            }
            r.timed_out = explained;
            r.engine.handle_timeout(now);
        }
    }

    /// Feeds device events to the running recipe.
    pub fn feed(&mut self, now: Duration, events: Vec<Event>) {
        if let Some(r) = &mut self.running {
            for ev in events {
                r.engine.handle(now, ev);
            }
        }
    }

    /// Takes in what one reading of the device means: its events for the
    /// running recipe, then its alarm, or else the line saying it became
    /// usable again. True when that line was reported.
    pub fn take_reading(&mut self, now: Duration, reading: Reading) -> bool {
        self.feed(now, reading.events);
        match (reading.alarm, reading.ready) {
            (Some(cause), _) => {
                self.fault(cause);
                false
            }
            (None, Some(line)) => {
                self.report(Severity::Info, line);
                true
            }
            (None, None) => false,
        }
    }

    /// The device failed: the running recipe ends in alarm with `cause`,
    /// and the alarm goes up (also when no recipe runs).
    pub fn fault(&mut self, cause: Cause) {
        if let Some(r) = &mut self.running {
            r.engine.abort(cause.clone());
        }
        self.alarmed = true;
        self.report(Severity::Alarm(cause.class), cause.text);
    }

    /// Queues a report (operator message) from this station.
    pub fn report(&mut self, severity: Severity, text: String) {
        self.out.push_back(Output::Report { severity, text });
    }

    /// The next thing to publish, in order.
    pub fn poll_output(&mut self) -> Option<Output> {
        self.out.pop_front()
    }

    /// What it put out since it was last asked, as publications from this
    /// station in order, then its status if it differs from `told` (the
    /// status the driver last published, which it then becomes; none:
    /// publish it whatever it is).
    pub fn publications(&mut self, told: &mut Option<VmdStatus>) -> Vec<Unconfirmed> {
        let reread = self.read_programs();
        let mut out: Vec<Unconfirmed> = std::iter::from_fn(|| self.out.pop_front())
            .map(|o| o.publication(self.me.clone()))
            .collect();
        let mut status = self.status();
        if !reread && told.as_ref() == Some(&status) {
            return out;
        }
        // What the preconditions' terms observe shows in the rest of the
        // status (the inputs, the link, the robot's state): evaluated
        // again only when that changed.
        if self.read_unmet() {
            status.unmet = self.unmet.clone();
        }
        if told.as_ref() != Some(&status) {
            *told = Some(status.clone());
            out.push(Unconfirmed::Status {
                station: self.me.clone(),
                status,
            });
        }
        out
    }

    /// The recipe state this level is in (the local detail of its
    /// status), as the thesis defines them, for its own recipe: while one
    /// runs, WAIT_ACK while a Start it sent waits for its confirm, PENDING
    /// while it waits for a job below to end (`wait`), else EXECUTING;
    /// ERROR after an alarm until a run starts or a program invocation is
    /// reset; READY with a recipe loaded that a Start would run now (the
    /// device available, not in maintenance mode); LOADED with one loaded
    /// that could not start now; else IDLE. An alarm waiting for its
    /// acknowledgement is the alarm list's, not a recipe state.
    pub fn recipe_state(&self) -> RecipeState {
        self.recipe_state_with(|| self.device.unready().is_some())
    }

    /// [`Self::recipe_state`], asking `unready` only when it matters.
    fn recipe_state_with(&self, unready: impl FnOnce() -> bool) -> RecipeState {
        if let Some(r) = &self.running {
            match r.engine.awaiting() {
                Some(Awaited::Confirm) => RecipeState::WaitAck,
                Some(Awaited::End) => RecipeState::Pending,
                None => RecipeState::Executing,
            }
        } else if self.alarmed {
            RecipeState::Error
        } else if self.vmd.programs().next().is_none() {
            RecipeState::Idle
        } else if self.mode.mode != CellMode::Maintenance && !unready() {
            RecipeState::Ready
        } else {
            RecipeState::Loaded
        }
    }

    /// Reads and checks the recipe of every loaded program invocation
    /// whose text is new or changed (and forgets those gone), once a
    /// recipe came or went. Whether they were read again.
    fn read_programs(&mut self) -> bool {
        if !std::mem::take(&mut self.programs_stale) {
            return false;
        }
        let mut now = BTreeMap::new();
        for pi in self.vmd.programs() {
            let name = pi.name().clone();
            // A robot program's invocation runs no recipe here.
            if RobotProgram::of_domain(&name).is_some() {
                continue;
            }
            let Some(text) = pi.domains().first().and_then(|d| self.vmd.domain(d)) else {
                continue;
            };
            let hash = content_hash(text.content());
            let program = match self.programs.remove(&name) {
                Some((known, program)) if known == hash => program,
                _ => self.program_of(&name, &String::from_utf8_lossy(text.content())),
            };
            now.insert(name, (hash, program));
        }
        self.programs = now;
        self.unmet_seen = None;
        true
    }

    /// Makes the status's `unmet` again if what the device observes of
    /// the preconditions' terms changed; whether it did.
    fn read_unmet(&mut self) -> bool {
        // While a recipe runs no Start would be taken anyway: none is
        // listed (its inputs change at every step).
        if self.running.is_some() {
            let had = !self.unmet.is_empty();
            self.unmet.clear();
            self.unmet_seen = None;
            return had;
        }
        // A recipe that does not check has no precondition to show: its
        // Start is refused for what is wrong with it.
        let seen: Vec<Option<bool>> = self
            .programs
            .values()
            .filter_map(|(_, p)| p.as_ref().ok()?.pre.as_ref())
            .flat_map(|c| c.terms.iter().map(|t| self.device.observes(t.fact)))
            .collect();
        if self.unmet_seen.as_ref() == Some(&seen) {
            return false;
        }
        self.unmet = self
            .programs
            .iter()
            .filter_map(|(name, (_, p))| {
                let pre = &p.as_ref().ok()?.pre;
                Some((name.clone(), self.unmet("precondition", name, pre)?))
            })
            .collect();
        self.unmet_seen = Some(seen);
        true
    }

    /// The status as it is now (the driver publishes it when it changed).
    pub fn status(&self) -> VmdStatus {
        // Asked once: a device's reason is a formatted text.
        let unready = self.device.unready();
        let mut status = VmdStatus {
            local_detail: self.recipe_state_with(|| unready.is_some()),
            unready,
            program: self.running.as_ref().map(|r| ProgramState {
                name: r.name.clone(),
                state: r.engine.state().0,
            }),
            mode: self.mode.mode,
            held: self.running.as_ref().and_then(|r| {
                let state = r.engine.held()?;
                Some(HeldStep {
                    state: state.0,
                    command: r.command_of(state).to_string(),
                })
            }),
            unmet: self.unmet.clone(),
            ..VmdStatus::default()
        };
        self.device.status(&mut status);
        status
    }

    /// Runs the engine's actions and finishes the job if it ended: call
    /// after every event.
    pub fn settle(&mut self, now: Duration) {
        while let Some(r) = &mut self.running {
            let Some(action) = r.engine.poll_action() else {
                break;
            };
            match action {
                Action::Alarm(cause) => {
                    let cause = match &r.timed_out {
                        Some(why) => cause.map(|t| format!("{t}: {why}")),
                        None => cause,
                    };
                    self.report(Severity::Alarm(cause.class), cause.text);
                }
                Action::Entered(s) => tracing::debug!(state = %s, "recipe state"),
                Action::Held(s) => {
                    let command = r.command_of(s);
                    let text = format!(
                        "step: {} state {s} waits for `falc step`: {}",
                        r.name,
                        if command.is_empty() {
                            "(no command)"
                        } else {
                            command
                        }
                    );
                    self.report(Severity::Info, text);
                }
                a => {
                    let mut out = Vec::new();
                    self.device.handle(now, Happening::Act(a), &mut out);
                    self.feed(now, out);
                }
            }
        }
        // A workstation whose step waits tells its commander its job is
        // paused, so the limits above stand still too; and resumed.
        if let Some(r) = &mut self.running {
            let held = r.engine.held().is_some();
            if self.kind.is_workstation() && held != r.paused_for_step {
                r.paused_for_step = held;
                let event = if held {
                    JobEvent::Paused
                } else {
                    JobEvent::Resumed
                };
                self.out.push_back(Output::Job {
                    program: r.name.clone(),
                    event,
                });
            }
        }
        // What the device reported comes before the job's end it caused
        // ("robot program 65 ended" before "job DROOG_DIK ended").
        while let Some((severity, text)) = self.device.poll_report() {
            self.report(severity, text);
        }
        let ended = self
            .running
            .as_ref()
            .and_then(|r| r.engine.outcome().cloned())
            .filter(|o| *o != Outcome::Done || !self.device.settling());
        if let Some(outcome) = ended {
            // A job done must leave what its postcondition says.
            let broken = self
                .running
                .as_ref()
                .filter(|_| outcome == Outcome::Done)
                .and_then(|r| self.unmet("postcondition", &r.name, &r.engine.program().post));
            let outcome = match broken {
                Some(why) => {
                    let cause = Cause::process(why);
                    self.report(Severity::Alarm(cause.class), cause.text.clone());
                    Outcome::Alarm(cause)
                }
                None => outcome,
            };
            // Only now, with the outcome known, is the job taken out.
            if let Some(r) = self.running.take() {
                self.device
                    .handle(now, Happening::Finished(&outcome), &mut Vec::new());
                let _ = self.vmd.complete(&r.name, PiCompletion::Finished);
                let event = match outcome {
                    Outcome::Done => JobEvent::Done,
                    Outcome::Alarm(c) => JobEvent::Alarm(match r.timed_out {
                        Some(why) => c.map(|t| format!("{t}: {why}")),
                        None => c,
                    }),
                    Outcome::Failed(JobEnd::BadProduct) => JobEvent::BadProduct,
                    Outcome::Failed(JobEnd::FailedSafe) => JobEvent::FailedSafe,
                    Outcome::Failed(JobEnd::FailedDanger) => JobEvent::FailedDanger,
                    Outcome::Failed(other) => JobEvent::Alarm(Cause::process(format!("{other:?}"))),
                };
                // Kept until the next Start: a commander that was away
                // when it ended asks for it.
                self.vmd.record_end(&r.name, event.clone());
                self.alarmed |= event != JobEvent::Done;
                self.out.push_back(Output::Job {
                    program: r.name,
                    event,
                });
            }
        }
        while let Some((severity, text)) = self.device.poll_report() {
            self.report(severity, text);
        }
    }

    /// The association with `peer` was lost (the commander, or a
    /// subordinate of a cell): a running recipe ends in a communication
    /// alarm naming it; unless `peer` is the commander and this level runs
    /// on alone, when the recipe goes on and its end is kept.
    pub fn handle_abort(&mut self, now: Duration, peer: &StationName, role: Role) {
        self.device
            .handle(now, Happening::Lost(peer), &mut Vec::new());
        if role == Role::Commander && self.runs_on_alone {
            if let Some(r) = &self.running {
                let text = format!(
                    "no connection with the commander {peer}: {} runs on to its end, \
                     which is kept for {peer}",
                    r.name
                );
                self.report(Severity::Warning, text);
            }
            return;
        }
        if self.running.is_some() {
            self.fault(Cause::new(
                AlarmClass::Communication,
                format!("no connection with station {peer}"),
            ));
        }
    }

    /// The commander associated (and with it every subordinate).
    pub fn handle_associated(&mut self, now: Duration) {
        self.device
            .handle(now, Happening::Associated, &mut Vec::new());
    }

    /// Builds the engine for program invocation `name` from its domain's
    /// recipe, checked when it came.
    fn engine_for(&mut self, name: &ObjectName) -> Result<Engine, ServiceError> {
        self.read_programs();
        let program = match self.programs.get(name) {
            Some((_, program)) => program.clone()?,
            None => {
                return Err(ServiceError::undefined(format!(
                    "program invocation {name} has no recipe domain"
                )))
            }
        };
        Ok(Engine::new(program).with_confirm_limit(self.confirm_limit))
    }

    /// An engine for recipe `text` ([`Self::program_of`]).
    fn engine_of(&self, name: &ObjectName, text: &str) -> Result<Engine, ServiceError> {
        let program = self.program_of(name, text)?;
        Ok(Engine::new(program).with_confirm_limit(self.confirm_limit))
    }

    /// Delivers domain `domain`, a robot program's text the commander
    /// downloaded ([`RobotProgram::of_domain`]), to the device: the text
    /// is checked first. Refused (and the domain taken back out) when it
    /// is no program of that number, or the device refuses it; else the
    /// commander's confirm waits for [`Device::poll_delivered`].
    pub fn deliver_program(&mut self, domain: &ObjectName) -> Result<RobotProgram, ServiceError> {
        let delivered = self.check_and_deliver(domain);
        if delivered.is_err() {
            self.discard_domain(domain);
        }
        delivered
    }

    fn check_and_deliver(&mut self, domain: &ObjectName) -> Result<RobotProgram, ServiceError> {
        let Some(number) = RobotProgram::of_domain(domain) else {
            return Err(ServiceError::undefined(format!(
                "{domain} is no robot program's domain (PROGRAM_NNN)"
            )));
        };
        let content = self
            .vmd
            .domain(domain)
            .map(|d| String::from_utf8_lossy(d.content()).into_owned())
            .ok_or_else(|| ServiceError::undefined(format!("no domain {domain}")))?;
        let refuse = |why: String| {
            ServiceError::new(
                ErrorClass::Definition(DefinitionError::ObjectAttributeInconsistent),
                why,
            )
        };
        let program = ProgramText::parse(&content, domain.as_str()).map_err(|problems| {
            refuse(format!("error in robot program: {}", problems.join("; ")))
        })?;
        if program.number != number {
            return Err(refuse(format!(
                "domain {domain} holds robot program {}",
                program.number
            )));
        }
        self.device.deliver_program(&program)?;
        Ok(number)
    }

    /// Recipe `text` checked as the recipes of this level and against the
    /// device (named `name` in problems).
    fn program_of(&self, name: &ObjectName, text: &str) -> Result<Arc<Program>, ServiceError> {
        let recipe = parse(text, name.as_str());
        let refuse = |problems: Vec<Problem>| {
            let lines: Vec<String> = problems.iter().map(|p| p.to_string()).collect();
            ServiceError::new(
                ErrorClass::Definition(DefinitionError::ObjectAttributeInconsistent),
                format!("error in recipe {name}: {}", lines.join("; ")),
            )
        };
        let program = check(&recipe, self.kind).map_err(refuse)?;
        let lacking = self.device.check_program(&program);
        if !lacking.is_empty() {
            return Err(refuse(lacking));
        }
        Ok(Arc::new(program))
    }

    /// The object store (domains, program invocations).
    pub fn vmd(&self) -> &Vmd {
        &self.vmd
    }

    /// Takes a domain back out (a delivery that failed).
    pub fn discard_domain(&mut self, name: &ObjectName) {
        self.programs_stale = true;
        let _ = self.vmd.handle(&Request::DeleteDomain {
            domain: name.clone(),
        });
    }

    /// Answers one indication from the commander (the driver sends the
    /// response), and settles.
    pub fn handle_request(
        &mut self,
        now: Duration,
        req: &Request,
    ) -> Result<Response, ServiceError> {
        // A recipe that came or went: its precondition is read again.
        self.programs_stale |= matches!(
            req,
            Request::TerminateDownloadSequence { .. }
                | Request::DeleteDomain { .. }
                | Request::CreateProgramInvocation { .. }
                | Request::DeleteProgramInvocation { .. }
        );
        match req {
            Request::Mode(setting) => return self.set_mode(now, setting),
            Request::Step { station, to } => {
                if station.as_ref().is_some_and(|s| *s != self.me) {
                    return Err(ServiceError::undefined(format!(
                        "{} has no station {} below it to step",
                        self.me,
                        station.as_ref().map_or("", |s| s.as_str())
                    )));
                }
                return self.step(now, *to);
            }
            Request::Manual { station, .. } if *station != self.me => {
                return Err(ServiceError::undefined(format!(
                    "a manual operation for {station} reached {}",
                    self.me
                )))
            }
            Request::Manual { action, by, .. } => return self.manual(now, action, by),
            // A Start of a program invocation a Stop left stopped begins
            // anew: it is reset first and the kept run dropped (ISO 9506
            // would refuse it; a commander that starts means to start).
            Request::Start { name, .. } if RobotProgram::of_domain(name).is_some() => {
                return Err(ServiceError::state_conflict(format!(
                    "{name} is a robot program delivered to the robot: a welding recipe runs it \
                     (start rcm {})",
                    RobotProgram::of_domain(name).map_or(0, RobotProgram::number)
                )))
            }
            Request::Start { name, .. } => self.reset_stopped(name),
            _ => {}
        }
        let Some((result, transition)) = self.vmd.handle(req) else {
            return Err(ServiceError::malformed(format!(
                "{} is not served by a {} station",
                req.service(),
                self.kind
            )));
        };
        let Some(t) = transition else { return result };
        let done = match t.request {
            PiRequest::Start | PiRequest::Resume => {
                let refused = (self.mode.mode == CellMode::Maintenance).then(|| {
                    ServiceError::state_conflict(format!(
                        "{} is in maintenance mode: no recipe starts (falc mode auto)",
                        self.me
                    ))
                });
                self.start_invocation(now, req, &t, refused)?
            }
            PiRequest::Stop | PiRequest::Kill => {
                // The device stops first: `finished` forgets what runs (a
                // cell forgets which workstations its recipe started).
                let mut out = Vec::new();
                self.device.handle(now, Happening::Halt, &mut out);
                self.stopped = None;
                if let Some(mut r) = self.running.take() {
                    let why = Cause::process(format!("{:?} by the commander", t.request));
                    r.engine.abort(why.clone());
                    let end = Outcome::Alarm(why);
                    self.device.handle(now, Happening::Finished(&end), &mut out);
                    if t.request == PiRequest::Stop {
                        // Kept for Resume (ISO 9506): it goes on there.
                        while r.engine.poll_action().is_some() {}
                        self.stopped = Some(r);
                    }
                }
                if t.request == PiRequest::Kill {
                    return result;
                }
                PiCompletion::Stopped
            }
            PiRequest::Reset => {
                self.stopped = None;
                self.alarmed = false;
                PiCompletion::ResetDone
            }
            PiRequest::Delete => return result,
        };
        let state = self.vmd.complete(&t.name, done).unwrap_or_else(|s| s);
        self.settle(now);
        Ok(Response::ProgramInvocationState(state))
    }

    /// The Start or Resume transition `t` of request `req`: the run
    /// launched (a Start's argument may name the state to begin at), or the
    /// invocation marked failed to start with why.
    fn start_invocation(
        &mut self,
        now: Duration,
        req: &Request,
        t: &Transition,
        refused: Option<ServiceError>,
    ) -> Result<PiCompletion, ServiceError> {
        let from = match req {
            Request::Start { argument, .. } => restart_state(argument),
            _ => Ok(None),
        };
        let launched = from.and_then(|from| self.launch(now, &t.name, t.request, from, refused));
        if let Err(e) = launched {
            let _ = self.vmd.complete(&t.name, PiCompletion::StartFailed);
            return Err(e);
        }
        // A run began: the alarm before it is dealt with.
        self.alarmed = false;
        if t.request == PiRequest::Start && self.kind.is_workstation() {
            self.out.push_back(Output::Job {
                program: t.name.clone(),
                event: JobEvent::Started,
            });
        }
        Ok(if t.request == PiRequest::Start {
            PiCompletion::Started
        } else {
            PiCompletion::Resumed
        })
    }

    /// Starts (or resumes) program invocation `name`: a Resume of the run a
    /// Stop kept goes on where it stopped; else a new run, at state `from`
    /// or the first. `refused` (and a device that is unavailable, or
    /// another run) refuses it.
    fn launch(
        &mut self,
        now: Duration,
        name: &ObjectName,
        request: PiRequest,
        from: Option<StateNo>,
        refused: Option<ServiceError>,
    ) -> Result<(), ServiceError> {
        let refused = refused.or_else(|| {
            if self.running.is_some() {
                Some(ServiceError::state_conflict(format!(
                    "another {} recipe is running",
                    self.kind
                )))
            } else {
                self.device.unavailable().map(ServiceError::state_conflict)
            }
        });
        if let Some(e) = refused {
            return Err(e);
        }
        let steps = self.mode.steps(&self.me);
        let kept = self.stopped.take().filter(|r| r.name == *name);
        if let (PiRequest::Resume, Some(mut r)) = (request, kept) {
            r.engine.set_stepping(now, steps);
            r.timed_out = None;
            r.paused_for_step = false;
            let at = r.engine.resume(now);
            tracing::info!(program = %name, state = ?at, "resumed where it stopped");
            self.running = Some(r);
            return Ok(());
        }
        let mut engine = self.engine_for(name)?;
        // A new run from its first state: its precondition must hold, or
        // the Start is refused before anything is written.
        if from.is_none() {
            if let Some(why) = self.unmet("precondition", name, &engine.program().pre) {
                return Err(ServiceError::state_conflict(why));
            }
        }
        engine.set_stepping(now, steps);
        match from {
            Some(state) => engine
                .start_at(now, state)
                .map_err(|e| ServiceError::undefined(format!("{name}: {e}")))?,
            None => engine.start(now),
        }
        self.running = Some(Running::new(name.clone(), engine));
        Ok(())
    }

    /// Whether Start `req` must wait for a fresh reading of the device
    /// before it is taken: a new run of a recipe with a `#PRE`, which the
    /// device evaluates on readings older than now (the device is asked
    /// for one). The driver holds the Start until
    /// [`Self::has_fresh_reading`], then hands it on; whether it is then
    /// taken at all is [`Self::handle_request`]'s to decide.
    pub fn holds_for_reading(&mut self, now: Duration, req: &Request) -> bool {
        let Request::Start { name, argument } = req else {
            return false;
        };
        if !matches!(restart_state(argument), Ok(None)) {
            return false;
        }
        self.read_programs();
        let has_pre = self
            .programs
            .get(name)
            .is_some_and(|(_, p)| p.as_ref().is_ok_and(|p| p.pre.is_some()));
        has_pre && self.device.ask_fresh_reading(now)
    }

    /// Whether the reading a held Start waits for came.
    pub fn has_fresh_reading(&self) -> bool {
        self.device.has_fresh_reading()
    }

    /// The terms of `condition` (recipe `name`'s `#PRE` or `#POST`, the
    /// `which`) the device does not observe to hold, as the refusal or
    /// alarm names them; None when it holds (or there is none).
    fn unmet(
        &self,
        which: &str,
        name: &ObjectName,
        condition: &Option<Conditions>,
    ) -> Option<String> {
        let terms = unmet(&condition.as_ref()?.terms, |s| self.device.observes(s));
        (!terms.is_empty()).then(|| format!("{which} of {name}: {} is false", terms.join(", ")))
    }

    /// Runs a recipe the device made (a way to a named state), not a
    /// program invocation of the store: it runs, reports and ends like
    /// one, and is gone when it ended.
    fn launch_engine(&mut self, now: Duration, name: ObjectName, mut engine: Engine) {
        engine.set_stepping(now, self.mode.steps(&self.me));
        engine.start(now);
        self.running = Some(Running::new(name.clone(), engine));
        self.alarmed = false;
        self.out.push_back(Output::Job {
            program: name,
            event: JobEvent::Started,
        });
    }

    /// Resets program invocation `name` if a Stop left it stopped (its kept
    /// run is dropped): a Start begins anew.
    fn reset_stopped(&mut self, name: &ObjectName) {
        if self.vmd.program(name).map(|p| p.state()) == Some(PiState::Stopped) {
            let _ = self.vmd.handle(&Request::Reset { name: name.clone() });
            let _ = self.vmd.complete(name, PiCompletion::ResetDone);
            self.stopped = None;
        }
    }

    /// The commander set the mode.
    fn set_mode(&mut self, now: Duration, setting: &ModeSetting) -> Result<Response, ServiceError> {
        if let Some(r) = &self.running {
            if !self.mode.mode.may_change_running(setting.mode) {
                return Err(ServiceError::state_conflict(format!(
                    "the mode cannot change from {} to {} while {} runs (only auto and step \
                     change while an order runs)",
                    self.mode.mode, setting.mode, r.name
                )));
            }
        }
        if self.mode.mode != setting.mode {
            self.device
                .handle(now, Happening::Mode(setting.mode), &mut Vec::new());
        }
        self.mode = setting.clone();
        let steps = self.mode.steps(&self.me);
        if let Some(r) = &mut self.running {
            r.engine.set_stepping(now, steps);
        }
        tracing::info!(mode = %self.mode, steps, "mode set");
        self.settle(now);
        Ok(Response::Done)
    }

    /// Step mode: the waiting step is carried out (and, with `to`, the
    /// steps up to state `to`).
    fn step(&mut self, now: Duration, to: Option<u16>) -> Result<Response, ServiceError> {
        let Some(r) = &mut self.running else {
            return Err(ServiceError::state_conflict(format!(
                "no recipe runs on {}: nothing to step",
                self.me
            )));
        };
        if !self.mode.steps(&self.me) {
            return Err(ServiceError::state_conflict(format!(
                "{} is not in step mode (falc mode step)",
                self.me
            )));
        }
        r.engine
            .step(now, to.map(StateNo))
            .map_err(|e| ServiceError::state_conflict(format!("{}: {e}", r.name)))?;
        self.settle(now);
        Ok(Response::Done)
    }

    /// A manual operation: only in maintenance mode, with no recipe running
    /// (a home recipe it starts runs like any other, and reports its end).
    fn manual(
        &mut self,
        now: Duration,
        action: &ManualAction,
        by: &str,
    ) -> Result<Response, ServiceError> {
        if self.mode.mode != CellMode::Maintenance {
            return Err(ServiceError::state_conflict(format!(
                "{action} refused by {}: the cell is in {} mode; manual operation needs \
                 maintenance mode (falc mode maintenance)",
                self.me, self.mode.mode
            )));
        }
        if let Some(r) = &self.running {
            return Err(ServiceError::state_conflict(format!(
                "{action} refused by {}: recipe {} runs (falc stop first)",
                self.me, r.name
            )));
        }
        let done = match action {
            ManualAction::RunRecipe(recipe) => {
                let name = ObjectName::new(&recipe.to_uppercase())
                    .map_err(|e| ServiceError::malformed(format!("recipe name `{recipe}`: {e}")))?;
                if self.vmd.program(&name).is_none() {
                    let known: Vec<String> = self
                        .vmd
                        .programs()
                        .map(|p| p.name().as_str().to_lowercase())
                        .collect();
                    return Err(ServiceError::undefined(format!(
                        "{} has no recipe {recipe} (it has: {})",
                        self.me,
                        known.join(", ")
                    )));
                }
                self.reset_stopped(&name);
                let start = Request::Start {
                    name: name.clone(),
                    argument: "manual".into(),
                };
                let Some((result, Some(t))) = self.vmd.handle(&start) else {
                    return Err(ServiceError::state_conflict(format!(
                        "{name} cannot start now"
                    )));
                };
                result?;
                // Maintenance allows this one start.
                let done = self.start_invocation(now, &start, &t, None)?;
                let _ = self.vmd.complete(&t.name, done);
                format!("{name} started")
            }
            ManualAction::Goto(state) => {
                let (text, what) = self
                    .device
                    .way_to(state)
                    .map_err(|e| ServiceError::state_conflict(format!("{action}: {e}")))?;
                let name = ObjectName::new(&format!("GOTO_{}", state.trim().to_uppercase()))
                    .map_err(|e| ServiceError::malformed(format!("state `{state}`: {e}")))?;
                let engine = self.engine_of(&name, &text)?;
                self.launch_engine(now, name.clone(), engine);
                tracing::info!(program = %name, "{what}");
                format!("{name} started: the way {what}")
            }
            other => self
                .device
                .manual(now, other)
                .map_err(|e| ServiceError::state_conflict(format!("{other}: {e}")))?,
        };
        self.report(Severity::Info, format!("manual, by {by}: {done}"));
        self.settle(now);
        Ok(Response::Done)
    }
}

/// The state a Start's argument asks to begin at (`order 7 from 12`), if
/// any.
fn restart_state(argument: &str) -> Result<Option<StateNo>, ServiceError> {
    let mut words = argument.split_whitespace();
    while let Some(w) = words.next() {
        if w == "from" {
            let n = words.next().unwrap_or_default();
            return n
                .parse::<u16>()
                .ok()
                .filter(|&n| n > 0)
                .map(|n| Some(StateNo(n)))
                .ok_or_else(|| {
                    ServiceError::malformed(format!(
                        "start argument `{argument}`: `from` needs a state number, not `{n}`"
                    ))
                });
        }
    }
    Ok(None)
}

/// What the unit tests of the controller cores share: loading a recipe as
/// the commander's delivery does, and draining the outputs.
#[cfg(test)]
pub(crate) mod testing {
    use super::*;
    use falc_model::mms::delivery::{Delivery, DeliveryStep};

    /// A cell recipe for tests: an output and a question to the operator,
    /// a transport job started and waited for, an alarm state.
    pub const CELL_RECIPE: &str = "A test cell recipe.\n\
        -1 | output hallo          |       |            | 2\n\
        -2 | input (ja/nee)        |       | answer=ja  | 3\n\
        -2 | input (ja/nee)        |       | answer=*   | 0\n\
        -3 | start transport store |       | gestart    | 4\n\
        -3 | start transport store |       | tijdlimiet | 6\n\
        -4 | wait transport 60     |       | klaar      | 5\n\
        -4 | wait transport 60     |       | tijdlimiet | 6\n\
        -5 | output einde          |       |            | 0\n\
        -6 |                       | alarm |            | 0\n";

    /// A welding recipe for tests: robot program 65 started and waited
    /// for, an alarm state.
    pub const DROOG_DIK: &str = "#DROOG_DIK\n\
        -1 | start rcm 65 |       | gestart    | 2\n\
        -1 | start rcm 65 |       | tijdlimiet | 3\n\
        -2 | wait rcm 170  |       | klaar      | 0\n\
        -2 | wait rcm 170  |       | tijdlimiet | 3\n\
        -3 |              | alarm |            | 0\n";

    /// Delivers `text` as domain and reusable program invocation `name`,
    /// as a commander does ([`Delivery`]).
    pub fn load<D: Device>(c: &mut Controller<D>, name: &str, text: &str) {
        let n = ObjectName::new(name).unwrap();
        let me = StationName::new("test").unwrap();
        let mut d = Delivery::new(me, n, text.as_bytes(), true);
        let mut step = d.start();
        while let DeliveryStep::Send(req) = step {
            step = d.answered(c.handle_request(Duration::ZERO, &req));
        }
        assert_eq!(step, DeliveryStep::Done(Ok(())), "{name} delivered");
    }

    /// Everything put out so far, in order.
    pub fn outputs<D: Device>(c: &mut Controller<D>) -> Vec<Output> {
        std::iter::from_fn(|| c.poll_output()).collect()
    }

    /// The job events among `outs`, in order.
    pub fn job_events(outs: &[Output]) -> Vec<JobEvent> {
        outs.iter()
            .filter_map(|o| match o {
                Output::Job { event, .. } => Some(event.clone()),
                _ => None,
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    //! The runtime on a virtual clock, with a fake device that records what
    //! the recipe made it do: the paths the multi-process tests cover
    //! (done, time limit, lost association, refusal, stop, settling).

    use super::testing::{job_events, load, outputs};
    use super::*;
    use falc_model::ids::RobotProgram;
    use falc_model::mms::program::PiState;
    use falc_recipe::check::{Job, Signal};

    use super::testing::DROOG_DIK;

    #[derive(Default)]
    struct Fake {
        acts: Vec<Action>,
        halted: usize,
        finished: Vec<Outcome>,
        down: Option<String>,
        settling: bool,
        lost: Vec<StationName>,
        /// Its supervision's next deadline, and when it ran.
        supervise_at: Option<Duration>,
        supervised: Vec<Duration>,
        /// Raised by the supervision: a line gone silent.
        alarms: std::collections::VecDeque<Cause>,
        /// The manual operations carried out.
        manual: Vec<ManualAction>,
        /// What `way_to` answers.
        way: Option<Result<(String, String), String>>,
        /// What it observes (`observes`).
        seen: std::collections::BTreeMap<Fact, bool>,
    }

    impl Device for Fake {
        fn handle(&mut self, now: Duration, what: Happening<'_>, _out: &mut Vec<Event>) {
            match what {
                Happening::Act(action) => self.acts.push(action),
                Happening::Halt => self.halted += 1,
                Happening::Finished(outcome) => self.finished.push(outcome.clone()),
                Happening::Lost(station) => self.lost.push(station.clone()),
                Happening::Clock => {
                    self.supervised.push(now);
                    self.supervise_at = None;
                    self.alarms.push_back(Cause::new(
                        AlarmClass::Communication,
                        "status request unanswered".to_string(),
                    ));
                }
                Happening::Associated | Happening::Mode(_) => {}
            }
        }
        fn unavailable(&self) -> Option<String> {
            self.down.clone()
        }
        fn settling(&self) -> bool {
            self.settling
        }
        fn explain_timeout(&self, _now: Duration) -> Option<String> {
            Some("robot program 65 still runs".into())
        }
        fn status(&self, _status: &mut VmdStatus) {}
        fn poll_timeout(&self) -> Option<Duration> {
            self.supervise_at
        }
        fn poll_report(&mut self) -> Option<(Severity, String)> {
            let c = self.alarms.pop_front()?;
            Some((Severity::Alarm(c.class), c.text))
        }
        fn manual(&mut self, _now: Duration, action: &ManualAction) -> Result<String, String> {
            self.manual.push(action.clone());
            Ok(format!("{action} done"))
        }
        fn observes(&self, fact: Fact) -> Option<bool> {
            self.seen.get(&fact).copied()
        }
        fn way_to(&self, state: &str) -> Result<(String, String), String> {
            self.way
                .clone()
                .unwrap_or_else(|| Err(format!("no state {state}")))
        }
    }

    fn name(s: &str) -> ObjectName {
        ObjectName::new(s).unwrap()
    }

    fn rcm() -> StationName {
        StationName::new("rcm").unwrap()
    }

    fn secs(s: u64) -> Duration {
        Duration::from_secs(s)
    }

    /// A welding controller holding `droog_dik` as a program invocation.
    fn loaded() -> Controller<Fake> {
        let mut c = Controller::new(RecipeKind::Welding, secs(30), Fake::default());
        load(&mut c, "droog_dik", DROOG_DIK);
        c
    }

    fn start(c: &mut Controller<Fake>, now: Duration) -> Result<Response, ServiceError> {
        c.handle_request(
            now,
            &Request::Start {
                name: name("droog_dik"),
                argument: String::new(),
            },
        )
    }

    fn mode(mode: CellMode, stepping: &[&str]) -> Request {
        Request::Mode(ModeSetting {
            mode,
            stepping: stepping
                .iter()
                .map(|s| StationName::new(s).unwrap())
                .collect(),
        })
    }

    fn step(c: &mut Controller<Fake>, now: Duration) -> Result<Response, ServiceError> {
        c.handle_request(
            now,
            &Request::Step {
                station: None,
                to: None,
            },
        )
    }

    #[test]
    fn in_step_mode_each_state_waits_and_the_job_above_is_paused_meanwhile() {
        let mut c = loaded();
        assert!(step(&mut c, secs(0))
            .unwrap_err()
            .description
            .contains("no recipe runs"));
        c.handle_request(secs(0), &mode(CellMode::Step, &["welding"]))
            .unwrap();
        start(&mut c, secs(1)).unwrap();
        assert!(c.device.acts.is_empty(), "state 1 waits before it starts");
        let held = c.status().held.expect("a step waits");
        assert_eq!((held.state, held.command.as_str()), (1, "start rcm 65"));
        assert_eq!(c.status().mode, CellMode::Step);
        let outs = outputs(&mut c);
        assert_eq!(job_events(&outs), vec![JobEvent::Started, JobEvent::Paused]);
        assert!(outs.iter().any(|o| matches!(o, Output::Report { text, .. }
            if text == "step: DROOG_DIK state 1 waits for `falc step`: start rcm 65")));
        assert_eq!(c.poll_timeout(), None, "no limit runs while a step waits");
        step(&mut c, secs(100)).unwrap();
        assert_eq!(c.device.acts.len(), 1, "{:?}", c.device.acts);
        assert_eq!(job_events(&outputs(&mut c)), vec![JobEvent::Resumed]);
        c.feed(secs(101), vec![Event::Started(rcm())]);
        c.settle(secs(101));
        assert_eq!(c.status().held.map(|h| h.state), Some(2));
        assert_eq!(job_events(&outputs(&mut c)), vec![JobEvent::Paused]);
        // Back to auto while it runs: the step is carried out at once.
        c.handle_request(secs(110), &mode(CellMode::Auto, &[]))
            .unwrap();
        assert_eq!(c.status().held, None);
        assert_eq!(c.status().program.map(|p| p.state), Some(2));
        assert_eq!(job_events(&outputs(&mut c)), vec![JobEvent::Resumed]);
        assert_eq!(
            c.poll_timeout(),
            Some(secs(280)),
            "170 s from state 2 at 110 s"
        );
    }

    #[test]
    fn a_reading_feeds_the_recipe_then_raises_its_alarm_or_reports_the_device_ready() {
        let mut c = loaded();
        start(&mut c, secs(0)).unwrap();
        c.settle(secs(0));
        outputs(&mut c);
        let ready = Reading {
            events: vec![Event::Started(rcm())],
            alarm: None,
            ready: Some("robot ready".into()),
        };
        assert!(c.take_reading(secs(1), ready));
        c.settle(secs(1));
        assert_eq!(c.status().program.map(|p| p.state), Some(2), "fed");
        assert!(outputs(&mut c).iter().any(|o| matches!(o,
            Output::Report { severity: Severity::Info, text } if text == "robot ready")));
        let alarm = Reading {
            alarm: Some(Cause::new(AlarmClass::Safety, "emergency stop")),
            ready: Some("never said".into()),
            ..Reading::default()
        };
        assert!(!c.take_reading(secs(2), alarm));
        let outs = outputs(&mut c);
        assert!(outs.iter().any(|o| matches!(
            o,
            Output::Report {
                severity: Severity::Alarm(AlarmClass::Safety),
                ..
            }
        )));
        assert!(!outs.iter().any(|o| matches!(o,
            Output::Report { text, .. } if text == "never said")));
    }

    #[test]
    fn another_station_in_step_mode_does_not_make_this_one_step() {
        let mut c = loaded();
        c.handle_request(secs(0), &mode(CellMode::Step, &["cell"]))
            .unwrap();
        start(&mut c, secs(1)).unwrap();
        assert_eq!(c.status().held, None);
        assert_eq!(c.device.acts.len(), 1);
        let e = step(&mut c, secs(2)).unwrap_err();
        assert!(e.description.contains("not in step mode"), "{e}");
    }

    #[test]
    fn maintenance_only_while_idle_and_manual_operations_only_in_maintenance() {
        let mut c = loaded();
        let press = Request::Manual {
            station: StationName::new("welding").unwrap(),
            action: ManualAction::StopProgram,
            by: "maint".into(),
        };
        let e = c.handle_request(secs(0), &press).unwrap_err();
        assert!(
            e.description
                .contains("refused by welding: the cell is in auto mode"),
            "{e}"
        );
        start(&mut c, secs(1)).unwrap();
        let e = c
            .handle_request(secs(2), &mode(CellMode::Maintenance, &[]))
            .unwrap_err();
        assert!(e.description.contains("while DROOG_DIK runs"), "{e}");
        c.handle_request(secs(2), &mode(CellMode::Step, &[]))
            .unwrap();
        c.handle_request(
            secs(3),
            &Request::Stop {
                name: name("droog_dik"),
            },
        )
        .unwrap();
        c.handle_request(secs(4), &mode(CellMode::Maintenance, &[]))
            .unwrap();
        let e = start(&mut c, secs(5)).unwrap_err();
        assert_eq!(
            c.vmd().program(&name("droog_dik")).map(|p| p.state()),
            Some(PiState::Idle)
        );
        assert!(e.description.contains("maintenance mode"), "{e}");
        outputs(&mut c);
        c.handle_request(secs(6), &press).unwrap();
        assert_eq!(c.device.manual, vec![ManualAction::StopProgram]);
        assert!(outputs(&mut c)
            .iter()
            .any(|o| matches!(o, Output::Report { text, .. }
            if text == "manual, by maint: stop the robot program done")));
        // A station's own recipe, by hand.
        let run = |r: &str| Request::Manual {
            station: StationName::new("welding").unwrap(),
            action: ManualAction::RunRecipe(r.into()),
            by: "maint".into(),
        };
        let e = c.handle_request(secs(7), &run("home")).unwrap_err();
        assert!(
            e.description
                .contains("welding has no recipe home (it has: droog_dik)"),
            "{e}"
        );
        c.handle_request(secs(7), &run("droog_dik")).unwrap();
        assert!(c.is_running());
        let e = c.handle_request(secs(8), &press).unwrap_err();
        assert!(e.description.contains("recipe DROOG_DIK runs"), "{e}");
    }

    /// `goto`: the device's way runs as a recipe of the station's own
    /// (`GOTO_HOME`), reported and ended like any job, and is gone after
    /// it; the device's refusal is the operation's, and so is a way that
    /// does not check.
    #[test]
    fn a_way_to_a_named_state_runs_as_a_recipe_of_its_own() {
        let mut c = Controller::new(RecipeKind::Transport, secs(10), Fake::default());
        c.handle_request(secs(0), &mode(CellMode::Maintenance, &[]))
            .unwrap();
        outputs(&mut c);
        let goto = Request::Manual {
            station: StationName::new("transport").unwrap(),
            action: ManualAction::Goto("home".into()),
            by: "maint".into(),
        };
        c.device.way = Some(Err("the carrier at W7 cannot reach state home".into()));
        let e = c.handle_request(secs(1), &goto).unwrap_err();
        assert!(
            e.description
                .contains("go to state home: the carrier at W7 cannot reach state home"),
            "{e}"
        );
        assert!(!c.is_running() && c.device.acts.is_empty());
        c.device.way = Some(Ok((
            "#GOTO_HOME\n-1 | activate i | | | 0\n".into(),
            "x".into(),
        )));
        let e = c.handle_request(secs(1), &goto).unwrap_err();
        assert!(e.description.contains("error in recipe GOTO_HOME"), "{e}");
        c.device.way = Some(Ok((
            "#GOTO_HOME\n-1 | activate a | | | 2\n-2 | reset a | | | 0\n".into(),
            "to home from carriers seen at W6: line A to W2".into(),
        )));
        c.handle_request(secs(2), &goto).unwrap();
        assert_eq!(
            c.device.acts,
            [
                Action::Activate(falc_recipe::check::Button::Line('A')),
                Action::Reset(falc_recipe::check::Button::Line('A'))
            ]
        );
        let outs = outputs(&mut c);
        assert_eq!(job_events(&outs), vec![JobEvent::Started, JobEvent::Done]);
        assert!(outs.iter().any(|o| matches!(o, Output::Report { text, .. }
            if text == "manual, by maint: GOTO_HOME started: the way to home from carriers seen at W6: line A to W2")));
        assert!(!c.is_running());
        assert!(c.vmd().program(&name("goto_home")).is_none());
    }

    /// `#PRE` and `#POST`: a Start whose precondition the device does
    /// not observe is refused naming the terms, before anything is
    /// written; a job done whose postcondition does not hold ends in an
    /// alarm naming them; both holding, it is done. A start `from` a
    /// state (a restart) is not a new run from the first: no PRE.
    #[test]
    fn a_precondition_refuses_the_start_and_a_postcondition_fails_the_job() {
        use falc_model::ids::Place;
        let mut c = Controller::new(RecipeKind::Transport, secs(10), Fake::default());
        load(
            &mut c,
            "park",
            "#PARK\n\
             #PRE place 2 occupied, place 3 empty\n\
             #POST line K stopped\n\
             -1 | activate k | | | 2\n\
             -2 | reset k    | | | 0\n",
        );
        let go = |a: &str| Request::Start {
            name: name("park"),
            argument: a.into(),
        };
        let place = |n| Fact::Signal(Signal::Place(Place::of(n)));
        c.device.seen.insert(place(2), false);
        c.device.seen.insert(place(3), true);
        let e = c.handle_request(secs(0), &go("order 1")).unwrap_err();
        assert_eq!(
            e.description,
            "precondition of PARK: place 2 occupied, place 3 empty is false"
        );
        assert!(c.device.acts.is_empty() && !c.is_running());
        // The status says so beforehand, for a restart to be refused.
        let status_of = |c: &mut Controller<Fake>| {
            let mut told = None;
            c.publications(&mut told);
            told.map(|s| s.unmet).unwrap_or_default()
        };
        assert_eq!(
            status_of(&mut c).get(&name("park")).map(String::as_str),
            Some("precondition of PARK: place 2 occupied, place 3 empty is false")
        );
        // An input the device cannot tell is no term that holds.
        c.device.seen.clear();
        c.device.seen.insert(place(2), true);
        let e = c.handle_request(secs(0), &go("order 1")).unwrap_err();
        assert!(e.description.contains("place 3 empty is false"), "{e}");
        c.device.seen.insert(place(3), false);
        c.device.seen.insert(Fact::Signal(Signal::Line('K')), true);
        assert!(status_of(&mut c).is_empty());
        outputs(&mut c);
        c.handle_request(secs(1), &go("order 1")).unwrap();
        let outs = outputs(&mut c);
        let text = "postcondition of PARK: line K stopped is false";
        assert_eq!(
            job_events(&outs).last(),
            Some(&JobEvent::Alarm(Cause::process(text.to_string())))
        );
        assert!(outs
            .iter()
            .any(|o| matches!(o, Output::Report { text: t, .. } if t == text)));
        c.device.seen.insert(Fact::Signal(Signal::Line('K')), false);
        c.handle_request(secs(2), &go("order 2")).unwrap();
        assert_eq!(job_events(&outputs(&mut c)).last(), Some(&JobEvent::Done));
        // From state 2 (a restart): the precondition is the first state's.
        c.device.seen.insert(place(2), false);
        c.handle_request(secs(3), &go("order 2 from 2")).unwrap();
        assert_eq!(job_events(&outputs(&mut c)).last(), Some(&JobEvent::Done));
    }

    #[test]
    fn a_stop_keeps_the_run_and_resume_goes_on_where_it_stopped() {
        let mut c = Controller::new(RecipeKind::Transport, secs(10), Fake::default());
        load(
            &mut c,
            "park",
            "#PARK\n\
             -1 | activate a       | | | 2\n\
             -2 | waitplace 3 1 30 | | klaar | 0\n\
             -2 | waitplace 3 1 30 | | tijdlimiet | 3\n\
             -3 |                  | alarm | | 0\n",
        );
        let park = name("park");
        let go = Request::Start {
            name: park.clone(),
            argument: "order 1".into(),
        };
        c.handle_request(secs(0), &go).unwrap();
        assert_eq!(c.status().program.map(|p| p.state), Some(2));
        c.handle_request(secs(5), &Request::Stop { name: park.clone() })
            .unwrap();
        assert_eq!(c.device.halted, 1);
        assert!(!c.is_running());
        c.device.acts.clear();
        let r = c
            .handle_request(secs(50), &Request::Resume { name: park.clone() })
            .unwrap();
        assert_eq!(r, Response::ProgramInvocationState(PiState::Running));
        assert_eq!(c.status().program.map(|p| p.state), Some(2));
        assert!(
            matches!(c.device.acts.as_slice(), [Action::Watch { .. }]),
            "state 2 watches again, nothing is pressed again: {:?}",
            c.device.acts
        );
        assert_eq!(c.poll_timeout(), Some(secs(80)), "the wait's limit anew");
        // A Start after a Stop begins anew (at state 1, or `from`).
        c.handle_request(secs(51), &Request::Stop { name: park.clone() })
            .unwrap();
        let from = |a: &str| Request::Start {
            name: park.clone(),
            argument: a.into(),
        };
        let e = c
            .handle_request(secs(53), &from("order 1 from 7"))
            .unwrap_err();
        assert!(e.description.contains("state 7 does not exist"), "{e}");
        let e = c
            .handle_request(secs(53), &from("order 1 from x"))
            .unwrap_err();
        assert!(e.description.contains("needs a state number"), "{e}");
        c.handle_request(secs(54), &from("order 1 from 3")).unwrap();
        assert!(!c.is_running(), "state 3 ends in alarm at once");
        let outs = outputs(&mut c);
        assert!(
            matches!(job_events(&outs).last(), Some(JobEvent::Alarm(_))),
            "{outs:?}"
        );
    }

    #[test]
    fn a_recipe_runs_to_done_and_its_job_event_goes_up() {
        let mut c = loaded();
        let r = start(&mut c, secs(1)).unwrap();
        assert_eq!(r, Response::ProgramInvocationState(PiState::Running));
        assert!(c.is_running());
        assert_eq!(
            c.device.acts,
            vec![Action::Start {
                target: rcm(),
                job: Job::Program(RobotProgram::of(65))
            }]
        );
        assert_eq!(c.status().program.map(|p| p.state), Some(1));
        // The run's start goes up, numbered like its end.
        assert_eq!(job_events(&outputs(&mut c)), vec![JobEvent::Started]);
        c.feed(secs(2), vec![Event::Started(rcm())]);
        c.settle(secs(2));
        assert_eq!(c.status().program.map(|p| p.state), Some(2));
        // The wait's limit: 170 s from entering state 2.
        assert_eq!(c.poll_timeout(), Some(secs(172)));
        // The device reports the robot's end with the event that ends the
        // job: its report comes first (cause, then effect).
        c.device.alarms.push_back(Cause::new(
            AlarmClass::Process,
            "robot program 65 ended: complete",
        ));
        c.feed(secs(60), vec![Event::Ended(rcm(), JobEnd::Done)]);
        c.settle(secs(60));
        assert!(!c.is_running());
        let outs = outputs(&mut c);
        assert_eq!(job_events(&outs), vec![JobEvent::Done]);
        let order: Vec<bool> = outs
            .iter()
            .map(|o| matches!(o, Output::Job { .. }))
            .collect();
        assert_eq!(
            order,
            [false, true],
            "the report, then the job's end: {outs:?}"
        );
        assert_eq!(c.device.finished, vec![Outcome::Done]);
        assert_eq!(c.poll_timeout(), None);
        assert_eq!(c.status().local_detail, RecipeState::Ready);
    }

    #[test]
    fn the_recipe_state_is_loaded_ready_wait_ack_pending_and_error_until_reset() {
        let mut c = Controller::new(RecipeKind::Welding, secs(30), Fake::default());
        assert_eq!(c.status().local_detail, RecipeState::Idle);
        load(&mut c, "droog_dik", DROOG_DIK);
        assert_eq!(c.recipe_state(), RecipeState::Ready);
        // Loaded, but a Start would be refused now.
        c.device.down = Some("no link".into());
        assert_eq!(c.recipe_state(), RecipeState::Loaded);
        c.device.down = None;
        c.handle_request(secs(0), &mode(CellMode::Maintenance, &[]))
            .unwrap();
        assert_eq!(c.recipe_state(), RecipeState::Loaded);
        c.handle_request(secs(0), &mode(CellMode::Auto, &[]))
            .unwrap();
        start(&mut c, secs(1)).unwrap();
        // `start rcm 65` waits for the robot's confirm, `wait rcm` for
        // the program's end.
        assert_eq!(c.status().local_detail, RecipeState::WaitAck);
        c.feed(secs(1), vec![Event::Started(rcm())]);
        c.settle(secs(1));
        assert_eq!(c.status().local_detail, RecipeState::Pending);
        // An alarm ends the run: ERROR until the next run starts.
        c.fault(Cause::new(AlarmClass::Safety, "emergency stop".to_string()));
        c.settle(secs(2));
        assert!(!c.is_running());
        assert_eq!(c.status().local_detail, RecipeState::Error);
        start(&mut c, secs(3)).unwrap();
        assert_eq!(c.recipe_state(), RecipeState::WaitAck);
        c.feed(secs(4), vec![Event::Started(rcm())]);
        c.feed(secs(5), vec![Event::Ended(rcm(), JobEnd::Done)]);
        c.settle(secs(5));
        assert_eq!(c.recipe_state(), RecipeState::Ready);
        // A fault while idle, and a run that fails: each ERROR until a
        // run starts.
        c.fault(Cause::new(AlarmClass::Device, "line open".to_string()));
        assert_eq!(c.recipe_state(), RecipeState::Error);
        start(&mut c, secs(7)).unwrap();
        assert_eq!(c.recipe_state(), RecipeState::WaitAck);
        c.feed(secs(8), vec![Event::Started(rcm())]);
        c.feed(secs(9), vec![Event::Ended(rcm(), JobEnd::BadProduct)]);
        c.settle(secs(9));
        assert_eq!(c.recipe_state(), RecipeState::Error);
    }

    #[test]
    fn a_limit_that_runs_out_is_an_alarm_naming_what_the_device_saw() {
        let mut c = loaded();
        start(&mut c, Duration::ZERO).unwrap();
        c.feed(secs(1), vec![Event::Started(rcm())]);
        c.settle(secs(1));
        let deadline = c.poll_timeout().unwrap();
        // Not yet: an early wake-up changes nothing.
        c.handle_timeout(deadline - secs(1));
        c.settle(deadline - secs(1));
        assert!(c.is_running());
        c.handle_timeout(deadline);
        c.settle(deadline);
        assert!(!c.is_running());
        let outs = outputs(&mut c);
        let alarm = outs.iter().find_map(|o| match o {
            Output::Report {
                severity: Severity::Alarm(class),
                text,
            } => Some((*class, text.clone())),
            _ => None,
        });
        let (class, text) = alarm.unwrap();
        assert_eq!(class, AlarmClass::Process);
        assert!(text.contains("robot program 65 still runs"), "{text}");
        match job_events(&outs).as_slice() {
            [JobEvent::Started, JobEvent::Alarm(cause)] => {
                assert!(
                    cause.text.contains("robot program 65 still runs"),
                    "{cause:?}"
                )
            }
            other => panic!("expected one alarm job event, got {other:?}"),
        }
    }

    #[test]
    fn a_lost_commander_ends_the_running_recipe_in_a_communication_alarm() {
        let mut c = loaded();
        start(&mut c, Duration::ZERO).unwrap();
        let cell = StationName::new("cell").unwrap();
        c.handle_abort(Duration::ZERO, &cell, Role::Commander);
        c.settle(secs(1));
        assert!(!c.is_running());
        assert_eq!(c.device.lost, vec![cell.clone()]);
        let outs = outputs(&mut c);
        let expected = Cause::new(
            AlarmClass::Communication,
            "no connection with station cell".to_string(),
        );
        assert!(outs.contains(&Output::Report {
            severity: Severity::Alarm(AlarmClass::Communication),
            text: expected.text.clone(),
        }));
        // The run's start, numbered like its end (read back after a cut).
        assert_eq!(
            job_events(&outs),
            vec![JobEvent::Started, JobEvent::Alarm(expected)]
        );
        // Lost while idle: the device hears of it, nothing is reported.
        c.handle_abort(Duration::ZERO, &cell, Role::Commander);
        assert_eq!(outputs(&mut c), vec![]);
        assert_eq!(c.device.lost.len(), 2);
    }

    #[test]
    fn a_device_that_cannot_start_refuses_and_a_second_start_is_refused_while_one_runs() {
        let mut c = loaded();
        c.device.down = Some("emergency stop pressed".into());
        let e = start(&mut c, Duration::ZERO).unwrap_err();
        assert!(e.description.contains("emergency stop pressed"), "{e:?}");
        assert!(!c.is_running());
        assert!(c.device.acts.is_empty());
        c.device.down = None;
        start(&mut c, secs(1)).unwrap();
        let e = start(&mut c, secs(2)).unwrap_err();
        assert!(e.description.contains("is running"), "{e:?}");
        assert_eq!(
            c.device.acts.len(),
            1,
            "the running recipe is not started twice"
        );
    }

    #[test]
    fn a_stop_halts_the_device_and_forgets_the_job() {
        let mut c = loaded();
        start(&mut c, Duration::ZERO).unwrap();
        let r = c
            .handle_request(
                secs(3),
                &Request::Stop {
                    name: name("droog_dik"),
                },
            )
            .unwrap();
        assert_eq!(r, Response::ProgramInvocationState(PiState::Stopped));
        assert_eq!(c.device.halted, 1);
        assert!(!c.is_running());
        assert!(matches!(c.device.finished.as_slice(), [Outcome::Alarm(_)]));
        outputs(&mut c);
        // A late end of the robot's program changes nothing.
        c.feed(secs(4), vec![Event::Ended(rcm(), JobEnd::Done)]);
        c.settle(secs(4));
        assert_eq!(job_events(&outputs(&mut c)), vec![]);
    }

    #[test]
    fn done_waits_until_the_device_has_carried_out_its_outputs() {
        let mut c = loaded();
        start(&mut c, Duration::ZERO).unwrap();
        assert_eq!(job_events(&outputs(&mut c)), vec![JobEvent::Started]);
        c.feed(secs(1), vec![Event::Started(rcm())]);
        c.device.settling = true;
        c.feed(secs(5), vec![Event::Ended(rcm(), JobEnd::Done)]);
        c.settle(secs(5));
        assert!(c.is_running(), "done is held back while outputs settle");
        assert_eq!(job_events(&outputs(&mut c)), vec![]);
        c.device.settling = false;
        c.settle(secs(6));
        assert_eq!(job_events(&outputs(&mut c)), vec![JobEvent::Done]);
    }

    #[test]
    fn a_recipe_with_an_error_is_refused_with_its_line_and_the_invocation_stays_usable() {
        let mut c = Controller::new(RecipeKind::Welding, secs(30), Fake::default());
        load(&mut c, "bad", "#BAD\n-1 | frobnicate |  |  | 0\n");
        let n = name("bad");
        let e = c
            .handle_request(
                secs(1),
                &Request::Start {
                    name: n.clone(),
                    argument: String::new(),
                },
            )
            .unwrap_err();
        assert!(e.description.starts_with("error in recipe BAD:"), "{e:?}");
        assert!(e.description.contains("BAD:2: state 1"), "{e:?}");
        assert!(!c.is_running());
        // Refused, not stuck: the next Start meets the same check again.
        let again = c
            .handle_request(
                secs(2),
                &Request::Start {
                    name: n,
                    argument: String::new(),
                },
            )
            .unwrap_err();
        assert_eq!(again.description, e.description);
    }

    #[test]
    fn a_fault_without_a_recipe_is_still_reported() {
        let mut c = loaded();
        c.fault(Cause::new(AlarmClass::Safety, "emergency stop".to_string()));
        assert_eq!(
            outputs(&mut c),
            vec![Output::Report {
                severity: Severity::Alarm(AlarmClass::Safety),
                text: "emergency stop".into()
            }]
        );
    }

    #[test]
    fn the_device_supervision_shares_the_clock_and_its_alarms_are_reported() {
        let mut c = loaded();
        // Idle: only the device wants the clock.
        c.device.supervise_at = Some(secs(1));
        assert_eq!(c.poll_timeout(), Some(secs(1)));
        c.handle_timeout(secs(1));
        c.settle(secs(1));
        assert_eq!(c.device.supervised, vec![secs(1)]);
        assert_eq!(
            outputs(&mut c),
            vec![Output::Report {
                severity: Severity::Alarm(AlarmClass::Communication),
                text: "status request unanswered".into()
            }]
        );
        // Running: the earlier of the recipe's limit and the device's.
        start(&mut c, secs(2)).unwrap();
        c.feed(secs(2), vec![Event::Started(rcm())]);
        c.settle(secs(2));
        assert_eq!(c.poll_timeout(), Some(secs(172)));
        c.device.supervise_at = Some(secs(3));
        assert_eq!(c.poll_timeout(), Some(secs(3)));
        c.handle_timeout(secs(3));
        c.settle(secs(3));
        assert_eq!(c.device.supervised, vec![secs(1), secs(3)]);
        assert!(c.is_running(), "the recipe's own limit is not due yet");
        assert_eq!(c.poll_timeout(), Some(secs(172)));
    }
}
