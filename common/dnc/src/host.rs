//! The welding workstation's side of the DNC link, sans-I/O: turns the
//! recipe engine's `start rcm N` / stop into telegrams (select, then start),
//! and the RCM's acknowledgements, program ends and alarm messages into
//! engine events and robot status (through the alarm table). It also
//! delivers a robot program's text ([`Host::deliver`]: `D`, the `T` lines,
//! `F`, each acknowledged before the next goes), never the program a job
//! of ours runs.

use crate::alarms::{self, Effect};
use crate::procedure::Timing;
use crate::telegram::{EndResult, Mode, ProgramState, Telegram};
use falc_model::alarm::{AlarmClass, Cause};
use falc_model::ids::RobotProgram;
use falc_model::ids::StationName;
use falc_model::mms::error::ServiceError;
use falc_model::mms::vmd::RobotStatusDetail;
use falc_model::mode::ManualAction;
use falc_recipe::engine::{Event, JobEnd};
use falc_recipe::robot_program::ProgramText;
use std::collections::VecDeque;
use std::time::Duration;

/// How often the RCM's status is asked while a program runs. A dead line
/// is known from silence: the link tells an acknowledgement delay (2 s)
/// that passed without one byte ([`crate::procedure::LinkEvent::Silent`];
/// a live RCM answers even a spoilt byte with NAK), so the alarm comes
/// within a status period and an acknowledgement delay (2.5 s) of the
/// line going dead. A line that hears bytes but gets no answer through
/// (noise on every attempt) is silent once a request has gone unanswered
/// for the link's [`Timing::silent_after`] (6.88 s).
pub const STATUS_PERIOD: Duration = Duration::from_millis(500);

/// What the host wants done.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Out {
    /// Send a telegram to the RCM.
    Telegram(Telegram),
    /// Feed the recipe engine.
    Engine(Event),
    /// The robot's status changed.
    Detail(RobotStatusDetail),
    /// Tell people (information report).
    Info(String),
    /// Tell the commander: something no job owns went wrong (a report of
    /// that class, not a job event).
    Alarm(Cause),
    /// A delivery ([`Host::deliver`]) ended: the RCM stored the program,
    /// or why not.
    Delivered(RobotProgram, Result<(), ServiceError>),
}

/// A program's text on its way to the RCM: one telegram at a time, each
/// acknowledged before the next goes.
#[derive(Debug)]
struct Transfer {
    program: RobotProgram,
    /// The telegram whose acknowledgement is awaited.
    awaiting: Telegram,
    /// When the link delivered it (None: not yet).
    since: Option<Duration>,
    /// The telegrams still to go (the `T` lines, then `F`).
    rest: VecDeque<Telegram>,
}

impl Transfer {
    /// The code letter of the awaited telegram, as its acknowledgement
    /// names it.
    fn code(&self) -> u8 {
        self.awaiting.encode().first().copied().unwrap_or(0)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Pending {
    Select(RobotProgram),
    Start(RobotProgram),
}

impl Pending {
    /// The telegram of this step.
    fn telegram(self) -> Telegram {
        match self {
            Self::Select(p) => Telegram::SelectProgram(p),
            Self::Start(_) => Telegram::StartProgram,
        }
    }
}

/// A job's step on its way to the robot, and how far its acknowledgement
/// is awaited.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Step {
    what: Pending,
    ack: AckWait,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum AckWait {
    /// Not sent: the line is not known to be back (opened, or silent
    /// since); the select goes once the RCM answered, after the program
    /// it may still run with no job of ours is stopped
    /// ([`Host::program_status`]).
    Held,
    /// The link has not delivered the telegram yet.
    Undelivered,
    /// Delivered at this time: the acknowledgement is awaited until
    /// [`Host::ack_limit`] after it.
    Since(Duration),
    /// Not acknowledged in time: the status was asked, and its answer
    /// says whether the step was done ([`Host::step_by_status`]).
    Status,
}

impl Step {
    fn new(what: Pending) -> Option<Self> {
        Some(Self {
            what,
            ack: AckWait::Undelivered,
        })
    }
}

/// The host's state.
#[derive(Debug)]
pub struct Host {
    rcm: StationName,
    /// The serial line, for messages.
    line: String,
    pending: Option<Step>,
    /// The program a job of ours runs on the robot (from the start's
    /// acknowledgement until its end).
    running: Option<RobotProgram>,
    /// When the unanswered status request went out.
    asked: Option<Duration>,
    /// How long it may go unanswered ([`Timing::silent_after`]).
    silent_limit: Duration,
    /// When the RCM was last heard.
    heard: Duration,
    /// The line went silent or was (re)opened: ask until the RCM answers,
    /// then stop a program nobody owns.
    probing: bool,
    /// A status request is still in the link's hands (not yet delivered
    /// or given up): no second one is queued behind it.
    asking: bool,
    /// The serial line is open (nothing is asked while it is closed).
    open: bool,
    /// A status that would make the host act, waiting for a second answer
    /// to confirm it.
    suspect: Option<(Option<RobotProgram>, ProgramState)>,
    mode: Option<Mode>,
    /// The RCM's last alarm message (what a maintainer confirms).
    last_alarm: Option<u16>,
    /// A maintainer started the robot's program by hand: it is theirs,
    /// not an orphan to stop, until it ends, is stopped, or a job starts.
    by_hand: bool,
    /// The job's select was sent again after a refusal noise can cause
    /// ([`crate::telegram::AckError::may_be_noise`]) or a lost
    /// acknowledgement.
    reselected: bool,
    /// A program's text under way to the RCM.
    transfer: Option<Transfer>,
}

/// The warning for program `program` found `state` on the RCM on `line`
/// with no job of this workstation, and stopped.
fn orphan(program: Option<RobotProgram>, state: ProgramState, line: &str) -> Cause {
    let shown = program.map_or("none".to_string(), |q| q.number().to_string());
    Cause::new(
        AlarmClass::Warning,
        format!(
            "robot program {shown} was {} on the RCM on {line} with no job of this workstation (a restart of the workstation, or a lost line): stopped",
            word(state)
        ),
    )
}

fn word(state: ProgramState) -> &'static str {
    match state {
        ProgramState::Idle => "idle, no program selected",
        ProgramState::Selected => "selected, not running",
        ProgramState::Running => "running",
        ProgramState::Paused => "paused",
        ProgramState::Stopped => "stopped before its end",
    }
}

impl Host {
    /// A host on serial line `line` (for messages), whose link runs with
    /// `timing`, with nothing pending.
    pub fn new(line: &str, timing: &Timing) -> Self {
        Self {
            rcm: StationName::new("rcm").unwrap_or_else(|_| unreachable!("`rcm` is a valid name")),
            line: line.to_string(),
            pending: None,
            running: None,
            asked: None,
            silent_limit: timing.silent_after(),
            heard: Duration::ZERO,
            probing: false,
            asking: false,
            open: false,
            suspect: None,
            mode: None,
            last_alarm: None,
            by_hand: false,
            reselected: false,
            transfer: None,
        }
    }

    /// A maintainer's operation of the robot (maintenance mode, no job of
    /// ours runs): the telegram, and what was done in words.
    pub fn manual(&mut self, action: &ManualAction) -> Result<(Telegram, String), String> {
        if !self.open {
            return Err(format!("the DNC line {} is not open", self.line));
        }
        let done = match action {
            ManualAction::SelectProgram(n) => {
                let p = RobotProgram::new(*n)
                    .ok_or_else(|| format!("{n} is not a robot program number (1–999)"))?;
                (
                    Telegram::SelectProgram(p),
                    format!("robot program {p} selected"),
                )
            }
            ManualAction::StartProgram => (Telegram::StartProgram, "robot program started".into()),
            ManualAction::StopProgram => (Telegram::StopProgram, "robot program stopped".into()),
            ManualAction::ConfirmAlarm => {
                let code = self
                    .last_alarm
                    .take()
                    .ok_or("the robot reported no alarm to confirm")?;
                (
                    Telegram::ConfirmAlarm(code),
                    format!("robot alarm {code} confirmed"),
                )
            }
            other => return Err(format!("a welding station cannot {other}")),
        };
        match action {
            ManualAction::StartProgram => self.by_hand = true,
            ManualAction::StopProgram => self.by_hand = false,
            _ => {}
        }
        Ok(done)
    }

    /// Whether the serial line is open (telegrams can go).
    pub fn is_open(&self) -> bool {
        self.open
    }

    /// The serial line, for messages.
    pub fn line(&self) -> &str {
        &self.line
    }

    /// Whether the line is open and the RCM answered since it was
    /// (re)opened or last went silent.
    pub fn answered(&self) -> bool {
        self.open && !self.probing
    }

    /// The robot's mode as its last program status said, if one came.
    pub fn mode(&self) -> Option<Mode> {
        self.mode
    }

    /// Asks the robot's status now (its mode, its program), unless a
    /// request is already in the link's hands.
    pub fn ask_status(&mut self, now: Duration) -> Vec<Out> {
        self.ask(now).into_iter().collect()
    }

    /// The robot program a job of ours runs, if any.
    pub fn running(&self) -> Option<RobotProgram> {
        self.running
    }

    /// Whether a job of ours has a program selected, starting or running
    /// on the robot (what [`Self::stop`] stops).
    pub fn has_job(&self) -> bool {
        self.running.is_some() || self.pending.is_some()
    }

    /// The line was (re)opened (also at start-up): initiate DNC and ask
    /// the robot's status (thesis §5.2, appendix H), so a program that no
    /// job of ours owns is found and stopped.
    pub fn connected(&mut self, now: Duration) -> Vec<Out> {
        self.open = true;
        self.probing = true;
        // A new link: nothing of the old one is in flight.
        self.asking = false;
        let mut out = vec![Out::Telegram(Telegram::InitiateDnc)];
        out.extend(self.ask(now));
        out
    }

    /// The line closed: the job, if any, ends in alarm (else the alarm is
    /// reported as it is); nothing is asked until it is open again.
    pub fn closed(&mut self, why: String) -> Vec<Out> {
        self.open = false;
        self.asked = None;
        self.link_failed(why)
    }

    /// The link delivered `telegram` at `now`.
    pub fn sent(&mut self, now: Duration, telegram: &[u8]) {
        if telegram == Telegram::StatusRequest.encode().as_slice() {
            self.asking = false;
        }
        if let Some(step) = &mut self.pending {
            if step.ack == AckWait::Undelivered && telegram == step.what.telegram().encode() {
                step.ack = AckWait::Since(now);
            }
        }
        if let Some(t) = &mut self.transfer {
            if t.since.is_none() && telegram == t.awaiting.encode() {
                t.since = Some(now);
            }
        }
    }

    /// Delivers `program`'s text to the RCM: `D`, then each line as `T`,
    /// then `F`, each sent once the one before was acknowledged; ends with
    /// [`Out::Delivered`]. Refused while the line is not open, while
    /// another delivery is under way, and for the program a job of ours
    /// runs or is starting (the RCM would refuse it, `04`: it is delivered
    /// after the job).
    pub fn deliver(&mut self, program: &ProgramText) -> Result<Vec<Out>, ServiceError> {
        let p = program.number;
        if !self.open {
            return Err(ServiceError::unreachable(format!(
                "robot program {p} not delivered: the DNC line on {} is not open",
                self.line
            )));
        }
        if let Some(t) = &self.transfer {
            return Err(ServiceError::state_conflict(format!(
                "robot program {p} not delivered: program {} is being delivered",
                t.program
            )));
        }
        let job = self.pending.map(|s| match s.what {
            Pending::Select(q) | Pending::Start(q) => q,
        });
        if self.running == Some(p) || job == Some(p) {
            return Err(ServiceError::state_conflict(format!(
                "robot program {p} runs on the RCM: it is replaced after its job ends"
            )));
        }
        let lines = program.lines();
        let count = u16::try_from(lines.len())
            .ok()
            .filter(|n| *n <= 999)
            .ok_or_else(|| {
                ServiceError::malformed(format!(
                    "robot program {p}: {} lines, a transfer carries at most 999",
                    lines.len()
                ))
            })?;
        let rest = lines
            .iter()
            .zip(1u16..)
            .map(|(text, no)| Telegram::Line {
                no,
                text: (*text).to_string(),
            })
            .chain(std::iter::once(Telegram::TextEnd(p)))
            .collect();
        let first = Telegram::Text {
            program: p,
            lines: count,
            hash: program.hash(),
        };
        self.transfer = Some(Transfer {
            program: p,
            awaiting: first.clone(),
            since: None,
            rest,
        });
        Ok(vec![Out::Telegram(first)])
    }

    /// Whether a delivery is under way.
    pub fn delivering(&self) -> bool {
        self.transfer.is_some()
    }

    /// The RCM acknowledged the awaited telegram of the delivery under way
    /// (`error`: refused): the next telegram, or the delivery's end.
    fn transfer_ack(&mut self, error: Option<crate::telegram::AckError>) -> Vec<Out> {
        let Some(mut t) = self.transfer.take() else {
            return Vec::new();
        };
        if let Some(e) = error {
            let code = char::from(t.code());
            let e = e.to_service_error();
            return vec![Out::Delivered(
                t.program,
                Err(ServiceError {
                    description: format!(
                        "robot program {} not delivered: the RCM refused its `{code}`: {}",
                        t.program, e.description
                    ),
                    ..e
                }),
            )];
        }
        match t.rest.pop_front() {
            Some(next) => {
                t.awaiting = next.clone();
                t.since = None;
                self.transfer = Some(t);
                vec![Out::Telegram(next)]
            }
            None => vec![
                Out::Info(format!("robot program {} delivered to the RCM", t.program)),
                Out::Delivered(t.program, Ok(())),
            ],
        }
    }

    /// The delivery under way fails (`why`).
    fn transfer_failed(&mut self, why: &str) -> Vec<Out> {
        self.transfer
            .take()
            .map(|t| {
                Out::Delivered(
                    t.program,
                    Err(ServiceError::unreachable(format!(
                        "robot program {} not delivered: {why}",
                        t.program
                    ))),
                )
            })
            .into_iter()
            .collect()
    }

    /// How long the acknowledgement of a delivered select or start is
    /// awaited before the status is asked: the RCM's answer may lose two
    /// attempts on the way ([`Timing::silent_after`], 6.88 s). A spoilt
    /// answer can also pass 3964R's XOR check as another telegram (two
    /// flips in one bit column), and is then never seen as the
    /// acknowledgement.
    fn ack_limit(&self) -> Duration {
        self.silent_limit
    }

    /// The link gave `telegram` up (3964R attempts spent): a status
    /// request's silence is the supervision's to report; any other
    /// telegram's loss is a link failure.
    pub fn gave_up(&mut self, telegram: &[u8], why: String) -> Vec<Out> {
        if telegram == Telegram::StatusRequest.encode().as_slice() {
            self.asking = false;
            Vec::new()
        } else {
            self.link_failed(why)
        }
    }

    /// Asks the robot's status at `now`, unless a request is still in the
    /// link's hands (then its answer, or its silence, is awaited).
    fn ask(&mut self, now: Duration) -> Option<Out> {
        self.asked = Some(now);
        if std::mem::replace(&mut self.asking, true) {
            None
        } else {
            Some(Out::Telegram(Telegram::StatusRequest))
        }
    }

    /// The engine wants robot program `program` started. While the line
    /// is not known to be back (the RCM has not answered since it was
    /// opened or went silent), or a program found running with no job is
    /// being confirmed before it is stopped, the select is held: that
    /// program would refuse it (DNC error 04), so the answer is awaited,
    /// and such a program stopped, before it goes.
    pub fn start(&mut self, program: RobotProgram) -> Vec<Out> {
        self.pending = Step::new(Pending::Select(program));
        self.by_hand = false;
        self.reselected = false;
        if self.probing || self.suspect.is_some() {
            if let Some(step) = &mut self.pending {
                step.ack = AckWait::Held;
            }
            return Vec::new();
        }
        vec![Out::Telegram(Telegram::SelectProgram(program))]
    }

    /// The engine (or the commander) wants the robot stopped.
    pub fn stop(&mut self) -> Vec<Out> {
        self.pending = None;
        self.running = None;
        vec![Out::Telegram(Telegram::StopProgram)]
    }

    /// The link could not deliver a telegram: a job cannot go on (it ends
    /// in alarm); with none, the alarm is reported as it is.
    pub fn link_failed(&mut self, why: String) -> Vec<Out> {
        let job = self.pending.take().is_some() | self.running.take().is_some();
        self.probing = true;
        let mut out = self.transfer_failed(&why);
        let cause = Cause::new(AlarmClass::Communication, why);
        out.push(if job {
            Out::Engine(Event::Ended(self.rcm.clone(), JobEnd::Alarm(cause)))
        } else {
            Out::Alarm(cause)
        });
        out
    }

    /// When the host next needs the clock: the next status request, or
    /// the end of the wait for its answer.
    pub fn poll_timeout(&self) -> Option<Duration> {
        [
            self.supervision_timeout(),
            self.ack_timeout(),
            self.transfer_timeout(),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// When the acknowledgement of the delivery's telegram counts as lost.
    fn transfer_timeout(&self) -> Option<Duration> {
        let at = self.transfer.as_ref()?.since?;
        self.open.then(|| at + self.ack_limit())
    }

    /// The next status request, or the end of the wait for its answer,
    /// while a program runs (or the line is probed).
    fn supervision_timeout(&self) -> Option<Duration> {
        // A program a maintainer started is supervised like a job's.
        if !self.open || (self.running.is_none() && !self.probing && !self.by_hand) {
            return None;
        }
        Some(match self.asked {
            Some(at) => at + self.silent_limit,
            None => self.heard + STATUS_PERIOD,
        })
    }

    /// When the delivered select's or start's acknowledgement counts as
    /// lost.
    fn ack_timeout(&self) -> Option<Duration> {
        match self.pending {
            Some(Step {
                ack: AckWait::Since(at),
                ..
            }) if self.open => Some(at + self.ack_limit()),
            _ => None,
        }
    }

    /// The clock reached [`Self::poll_timeout`].
    pub fn handle_timeout(&mut self, now: Duration) -> Vec<Out> {
        if self.transfer_timeout().is_some_and(|t| t <= now) {
            let code = self.transfer.as_ref().map_or('?', |t| char::from(t.code()));
            let limit = self.ack_limit().as_secs_f64();
            return self.transfer_failed(&format!(
                "the RCM did not acknowledge its `{code}` within {limit:.2} s"
            ));
        }
        if self.ack_timeout().is_some_and(|t| t <= now) {
            // The acknowledgement is lost: the status tells whether the
            // step was done ([`Self::step_by_status`]).
            if let Some(step) = &mut self.pending {
                step.ack = AckWait::Status;
            }
            return self.ask(now).into_iter().collect();
        }
        if !self.supervision_timeout().is_some_and(|t| t <= now) {
            return Vec::new();
        }
        match self.asked {
            Some(at) => self.went_silent(
                now,
                &format!(
                    "status request unanswered for {:.1} s",
                    now.saturating_sub(at).as_secs_f64()
                ),
            ),
            None => self.ask(now).into_iter().collect(),
        }
    }

    /// The link waited an acknowledgement delay (`waited`) for the RCM and
    /// heard not one byte: the line or the RCM is dead. A program that
    /// runs is no longer supervised: its job ends in alarm (one started
    /// by hand is reported); the RCM is asked until it answers again.
    pub fn silent(&mut self, now: Duration, waited: Duration) -> Vec<Out> {
        self.went_silent(
            now,
            &format!("nothing heard for {:.1} s", waited.as_secs_f64()),
        )
    }

    /// The line went silent (`what` says how it was known): a running
    /// program's job ends in alarm, one started by hand is reported, and
    /// the RCM is asked until it answers again.
    fn went_silent(&mut self, now: Duration, what: &str) -> Vec<Out> {
        self.asked = None;
        self.heard = now;
        self.probing = true;
        if self.running.is_none() && std::mem::take(&mut self.by_hand) {
            // No job to end: the alarm is reported as it is.
            return vec![Out::Alarm(Cause::new(
                AlarmClass::Communication,
                format!(
                    "no connection with RCM on {}: {what} while a robot program started by hand runs",
                    self.line
                ),
            ))];
        }
        let Some(p) = self.running.take() else {
            return Vec::new();
        };
        self.pending = None;
        let why = format!(
            "no connection with RCM on {}: {what} while robot program {} runs",
            self.line,
            p.number()
        );
        vec![Out::Engine(Event::Ended(
            self.rcm.clone(),
            JobEnd::Alarm(Cause::new(AlarmClass::Communication, why)),
        ))]
    }

    /// The status asked because the pending select's or start's
    /// acknowledgement was lost: the step was done if the RCM shows our
    /// program selected (then it is started) or running (then it runs);
    /// else the job selects once more (once), and after that the recipe's
    /// own limit ends it.
    fn step_by_status(
        &mut self,
        program: Option<RobotProgram>,
        state: ProgramState,
        active: bool,
    ) -> Vec<Out> {
        let Some(step) = self.pending.map(|s| s.what) else {
            return Vec::new();
        };
        let (Pending::Select(p) | Pending::Start(p)) = step;
        let lost = |what: &str| {
            Out::Info(format!(
                "the acknowledgement of the {what} of robot program {} was lost; the RCM reports it {}",
                p.number(),
                word(state)
            ))
        };
        match step {
            Pending::Select(_) if program == Some(p) && state == ProgramState::Selected => {
                self.pending = Step::new(Pending::Start(p));
                vec![lost("selection"), Out::Telegram(Telegram::StartProgram)]
            }
            Pending::Start(_) if program == Some(p) && active => {
                self.pending = None;
                self.running = Some(p);
                self.asked = None;
                vec![
                    lost("start"),
                    Out::Engine(Event::Started(self.rcm.clone())),
                    Out::Info(format!("robot program {} started", p.number())),
                ]
            }
            _ if !std::mem::replace(&mut self.reselected, true) => {
                self.pending = Step::new(Pending::Select(p));
                vec![Out::Telegram(Telegram::SelectProgram(p))]
            }
            // The recipe's own limit ends the job; the step is awaited
            // no further.
            _ => {
                self.pending = Step::new(step);
                Vec::new()
            }
        }
    }

    /// A program status from the RCM (asked for or not).
    fn program_status(
        &mut self,
        now: Duration,
        program: Option<RobotProgram>,
        state: ProgramState,
        mode: Mode,
    ) -> Vec<Out> {
        // An answer: the request went out.
        self.asked = None;
        self.asking = false;
        self.mode = Some(mode);
        self.probing = false;
        let mut out = vec![Out::Detail(alarms::status_detail(state, mode))];
        let active = matches!(state, ProgramState::Running | ProgramState::Paused);
        if let Some(held) = self.pending.filter(|s| s.ack == AckWait::Held) {
            if active {
                // Not ours (our select never went). Acted on when a second
                // answer confirms it, like any status that stops the robot.
                if self.suspect != Some((program, state)) {
                    self.suspect = Some((program, state));
                    out.extend(self.ask(now));
                    return out;
                }
                self.suspect = None;
                out.push(Out::Telegram(Telegram::StopProgram));
                out.push(Out::Alarm(orphan(program, state, &self.line)));
            }
            // The RCM takes telegrams in order: the stop, then the select.
            self.pending = Step::new(held.what);
            out.push(Out::Telegram(held.what.telegram()));
            return out;
        }
        if self.pending.is_some_and(|s| s.ack == AckWait::Status) {
            out.extend(self.step_by_status(program, state, active));
            return out;
        }
        let acts = match self.running {
            Some(p) => self.pending.is_none() && !(program == Some(p) && active),
            // A program a maintainer started runs as theirs.
            None => active && self.pending.is_none() && !self.by_hand,
        };
        if !acts {
            self.suspect = None;
            return out;
        }
        // A status that makes the host act (stop a program, end a job) is
        // acted on only when a second answer confirms it: one stray or
        // stale telegram never stops the robot or ends a job.
        if self.suspect != Some((program, state)) {
            self.suspect = Some((program, state));
            out.extend(self.ask(now));
            return out;
        }
        self.suspect = None;
        let shown = program.map_or("none".to_string(), |q| q.number().to_string());
        match self.running.take() {
            Some(p) => {
                // Its end telegram was lost: the status tells how it ended.
                let end = if program == Some(p) && state == ProgramState::Selected {
                    out.push(Out::Info(format!(
                        "robot program {} ended but its end telegram was lost; the RCM reports it {}: taken as complete",
                        p.number(),
                        word(state)
                    )));
                    JobEnd::Done
                } else {
                    JobEnd::Alarm(Cause::new(AlarmClass::Device, format!(
                        "robot program {} is no longer running on the RCM on {} (status: program {shown} {}), and its end telegram was lost",
                        p.number(),
                        self.line,
                        word(state)
                    )))
                };
                out.push(Out::Engine(Event::Ended(self.rcm.clone(), end)));
            }
            None => {
                out.push(Out::Telegram(Telegram::StopProgram));
                out.push(Out::Alarm(orphan(program, state, &self.line)));
            }
        }
        out
    }

    /// The program a job is selecting or starting, if any.
    /// The program a job's start was sent for and not acknowledged yet:
    /// the robot may run it (the acknowledgement lost), so its end may
    /// come. A program only selected has not started, and cannot end.
    fn starting(&self) -> Option<RobotProgram> {
        self.pending.and_then(|s| match s.what {
            Pending::Start(p) => Some(p),
            Pending::Select(_) => None,
        })
    }

    /// A telegram from the RCM, at `now`.
    pub fn telegram(&mut self, now: Duration, t: Telegram) -> Vec<Out> {
        self.heard = now;
        if let Telegram::Ack { of, error } = &t {
            if self.transfer.as_ref().is_some_and(|tr| tr.code() == *of) {
                return self.transfer_ack(*error);
            }
        }
        let rcm = self.rcm.clone();
        // A held select never went: no acknowledgement is of it.
        let sent = self.pending.filter(|s| s.ack != AckWait::Held);
        match (t, sent.map(|s| s.what)) {
            (
                Telegram::Ack {
                    of: b'S',
                    error: None,
                },
                Some(Pending::Select(p)),
            ) => {
                self.pending = Step::new(Pending::Start(p));
                vec![Out::Telegram(Telegram::StartProgram)]
            }
            (
                Telegram::Ack {
                    of: b'G',
                    error: None,
                },
                Some(Pending::Start(p)),
            ) => {
                self.pending = None;
                self.running = Some(p);
                self.asked = None;
                vec![
                    Out::Engine(Event::Started(rcm)),
                    Out::Info(format!("robot program {} started", p.number())),
                ]
            }
            (Telegram::Ack { of, error: Some(e) }, Some(step))
                if of
                    == match step {
                        Pending::Select(_) => b'S',
                        Pending::Start(_) => b'G',
                    } =>
            {
                if e.may_be_noise() && !std::mem::replace(&mut self.reselected, true) {
                    // Perhaps a spoilt telegram (seen at 2 % flips: "no
                    // such program" for a program the RCM has): the job
                    // selects once more.
                    let (Pending::Select(p) | Pending::Start(p)) = step;
                    self.pending = Step::new(Pending::Select(p));
                    return vec![Out::Telegram(Telegram::SelectProgram(p))];
                }
                self.pending = None;
                vec![Out::Engine(Event::StartFailed(
                    rcm,
                    e.to_service_error().to_string(),
                ))]
            }
            (Telegram::Ack { .. }, _) => Vec::new(),
            (Telegram::ProgramEnd { program, .. }, _)
                if self.running.or(self.starting()) != Some(program) && !self.by_hand =>
            {
                // The end of another program than a job's: one that ended
                // while the line was out, its end telegram sent once the
                // line was back, as the next job starts. Not that job's
                // end, even of the same number while that job only selects.
                let now_running = self
                    .running
                    .map_or("no job's program runs".to_string(), |p| {
                        format!("program {} runs", p.number())
                    });
                vec![Out::Info(format!(
                    "robot program {} ended while {now_running}: not a job's end",
                    program.number()
                ))]
            }
            (Telegram::ProgramEnd { program, result }, _) => {
                let ended = self.running.take();
                let by_hand = std::mem::take(&mut self.by_hand);
                let (end, word) = match result {
                    EndResult::Complete => (JobEnd::Done, "complete"),
                    EndResult::WeldAborted => (JobEnd::BadProduct, "weld aborted"),
                };
                let mut out = Vec::new();
                if let Some(p) = ended {
                    out.push(Out::Info(format!(
                        "robot program {} ended: {word}",
                        p.number()
                    )));
                } else if by_hand {
                    // A maintainer's program is followed to its end too.
                    out.push(Out::Info(format!(
                        "robot program {} ended: {word} (started by hand)",
                        program.number()
                    )));
                }
                if let Some(mode) = self.mode {
                    out.push(Out::Detail(alarms::status_detail(
                        ProgramState::Selected,
                        mode,
                    )));
                }
                out.push(Out::Engine(Event::Ended(rcm, end)));
                out
            }
            (Telegram::Alarm(code), _) => {
                self.last_alarm = Some(code);
                let entry = alarms::lookup(code);
                let mut out: Vec<Out> = entry.detail().map(Out::Detail).into_iter().collect();
                let text = format!("RCM message {code}: {}", entry.meaning);
                let text_of_alarm = text.clone();
                out.push(match entry.effect {
                    Effect::Alarm => Out::Engine(Event::Ended(
                        rcm,
                        JobEnd::Alarm(Cause::new(entry.class(), text)),
                    )),
                    Effect::Confirm => Out::Telegram(Telegram::ConfirmAlarm(code)),
                    Effect::Paused => Out::Engine(Event::Paused(rcm)),
                    Effect::Resumed => Out::Engine(Event::Resumed(rcm)),
                    Effect::FailedDanger => Out::Engine(Event::Ended(rcm, JobEnd::FailedDanger)),
                    Effect::FailedSafe => Out::Engine(Event::Ended(rcm, JobEnd::FailedSafe)),
                    // The program-end telegram that follows carries it.
                    Effect::BadProduct | Effect::Info => Out::Info(text),
                });
                if matches!(
                    entry.effect,
                    Effect::Alarm | Effect::FailedDanger | Effect::FailedSafe
                ) {
                    if self.running.is_none() && self.pending.is_none() {
                        // No job to end: the alarm is reported as it is
                        // (an emergency stop while idle must be seen and
                        // acknowledged too).
                        out.push(Out::Alarm(Cause::new(entry.class(), text_of_alarm)));
                    }
                    // The program stopped with the alarm.
                    self.running = None;
                    self.pending = None;
                    self.by_hand = false;
                }
                out
            }
            (
                Telegram::ProgramStatus {
                    program,
                    state,
                    mode,
                },
                _,
            ) => self.program_status(now, program, state, mode),
            (other, _) => vec![Out::Info(format!(
                "unexpected telegram from the RCM: {other:?}"
            ))],
        }
    }

    /// What the host waited for when a recipe's limit ran out.
    pub fn explain_timeout(&self, now: Duration) -> Option<String> {
        let heard = now.saturating_sub(self.heard).as_secs_f64();
        match (self.pending.map(|s| s.what), self.running) {
            (Some(Pending::Select(p)), _) => Some(format!(
                "no acknowledgement of the selection of robot program {} (RCM last heard {heard:.1} s ago)",
                p.number()
            )),
            (Some(Pending::Start(p)), _) => Some(format!(
                "no acknowledgement of the start of robot program {} (RCM last heard {heard:.1} s ago)",
                p.number()
            )),
            (None, Some(p)) => Some(format!(
                "robot program {} did not end in time (the RCM reported it running {heard:.1} s ago)",
                p.number()
            )),
            (None, None) => None,
        }
    }
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;
    use crate::telegram::AckError;
    use falc_model::mms::vmd::RobotVmdState;

    fn rcm() -> StationName {
        StationName::new("rcm").expect("valid")
    }

    fn s(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn p65() -> RobotProgram {
        RobotProgram::of(65)
    }

    fn ack(of: u8) -> Telegram {
        Telegram::Ack { of, error: None }
    }

    fn status(program: Option<RobotProgram>, state: ProgramState) -> Telegram {
        Telegram::ProgramStatus {
            program,
            state,
            mode: Mode::AutomaticExternal,
        }
    }

    /// A host on an open line whose job runs program 65 since `t` ms.
    fn running(t: u64) -> Host {
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        h.connected(s(t));
        h.telegram(s(t), status(None, ProgramState::Idle));
        h.start(p65());
        h.telegram(s(t), ack(b'S'));
        h.telegram(s(t), ack(b'G'));
        h
    }

    /// Hands the host's telegrams to the twin and the twin's answers back
    /// (each delivered at once) until neither has more; the host's other
    /// outputs.
    fn exchange(h: &mut Host, robot: &mut crate::robot::Robot, first: Vec<Out>) -> Vec<Out> {
        let mut queue: VecDeque<Out> = first.into();
        let mut rest = Vec::new();
        while let Some(o) = queue.pop_front() {
            let Out::Telegram(t) = o else {
                rest.push(o);
                continue;
            };
            h.sent(s(0), &t.encode());
            for answer in robot.handle(s(0), t) {
                queue.extend(h.telegram(s(0), answer));
            }
        }
        rest
    }

    fn program(text: &str) -> ProgramText {
        ProgramText::parse(text, "test.prg").expect("a clean program")
    }

    #[test]
    fn a_program_is_delivered_line_by_line_and_the_one_that_runs_is_not_replaced() {
        let mut robot = crate::robot::Robot::new(Mode::AutomaticExternal, 1.0);
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        let p = program("program 65\n# two steps\nmove approach 1\nweld seam_1 2\n");
        // The line closed: refused at once.
        let e = h.deliver(&p).expect_err("no line");
        assert!(e.description.contains("not open"), "{e}");
        h.connected(s(0));
        h.telegram(s(0), status(None, ProgramState::Idle));
        let first = h.deliver(&p).expect("a delivery");
        assert_eq!(
            first,
            vec![Out::Telegram(Telegram::Text {
                program: p65(),
                lines: 4,
                hash: p.hash()
            })]
        );
        assert!(h.delivering());
        // A second one waits its turn.
        assert!(h.deliver(&p).is_err());
        let out = exchange(&mut h, &mut robot, first);
        assert_eq!(out.last(), Some(&Out::Delivered(p65(), Ok(()))), "{out:?}");
        assert!(!h.delivering());
        assert_eq!(
            robot.delivered().collect::<Vec<_>>(),
            vec![(p65(), 4, p.hash())]
        );
        // While a job of ours runs program 65, it is not delivered.
        let mut h = running(0);
        let e = h.deliver(&p).expect_err("it runs");
        assert!(e.description.contains("replaced after its job ends"), "{e}");
    }

    #[test]
    fn a_delivery_the_rcm_refuses_or_never_acknowledges_fails_naming_why() {
        let p = program("program 65\nmove approach 1\n");
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        h.connected(s(0));
        h.telegram(s(0), status(None, ProgramState::Idle));
        // Refused at `F` (as the twin refuses a wrong hash: 08), after `D` and two lines.
        h.deliver(&p).expect("a delivery");
        for code in [b'D', b'T', b'T'] {
            let out = h.telegram(s(0), ack(code));
            assert!(matches!(out[..], [Out::Telegram(_)]), "{out:?}");
        }
        let out = h.telegram(
            s(0),
            Telegram::Ack {
                of: b'F',
                error: Some(AckError::TextRefused),
            },
        );
        let [Out::Delivered(q, Err(e))] = &out[..] else {
            panic!("{out:?}")
        };
        assert_eq!(*q, p65());
        assert!(
            e.description
                .starts_with("robot program 65 not delivered: the RCM refused its `F`"),
            "{e}"
        );
        // A `D` delivered and never acknowledged: lost after the limit.
        h.deliver(&p).expect("again");
        h.sent(
            s(1_000),
            &Telegram::Text {
                program: p65(),
                lines: 2,
                hash: p.hash(),
            }
            .encode(),
        );
        let at = h.poll_timeout().expect("the acknowledgement's limit");
        assert_eq!(at, s(1_000) + h.ack_limit());
        assert!(h.handle_timeout(at - s(1)).is_empty());
        let out = h.handle_timeout(at);
        let [Out::Delivered(_, Err(e))] = &out[..] else {
            panic!("{out:?}")
        };
        assert!(e.description.contains("did not acknowledge its `D`"), "{e}");
        // The line lost mid-delivery ends it too, beside the alarm.
        h.deliver(&p).expect("again");
        let out = h.closed("the line closed".into());
        assert!(
            matches!(&out[0], Out::Delivered(_, Err(e)) if e.description.contains("the line closed")),
            "{out:?}"
        );
        assert!(!h.delivering());
    }

    #[test]
    fn a_maintainer_operates_the_robot_with_the_telegrams_that_exist() {
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        let e = h.manual(&ManualAction::StartProgram).unwrap_err();
        assert!(e.contains("not open"), "{e}");
        h.connected(s(0));
        let sel = h.manual(&ManualAction::SelectProgram(65)).unwrap();
        assert_eq!(sel.0, Telegram::SelectProgram(p65()));
        assert!(h.manual(&ManualAction::SelectProgram(1000)).is_err());
        assert_eq!(
            h.manual(&ManualAction::StartProgram).unwrap().0,
            Telegram::StartProgram
        );
        assert_eq!(
            h.manual(&ManualAction::StopProgram).unwrap().0,
            Telegram::StopProgram
        );
        let e = h.manual(&ManualAction::ConfirmAlarm).unwrap_err();
        assert!(e.contains("no alarm to confirm"), "{e}");
        h.telegram(s(1), Telegram::Alarm(24));
        let confirm = h.manual(&ManualAction::ConfirmAlarm).unwrap();
        assert_eq!(
            confirm,
            (
                Telegram::ConfirmAlarm(24),
                "robot alarm 24 confirmed".into()
            )
        );
        assert!(h
            .manual(&ManualAction::Press("A".into()))
            .unwrap_err()
            .contains("welding station cannot"));
    }

    fn ended(out: &[Out]) -> Option<&JobEnd> {
        out.iter().find_map(|o| match o {
            Out::Engine(Event::Ended(_, e)) => Some(e),
            _ => None,
        })
    }

    #[test]
    fn a_lost_line_ends_the_job_or_is_reported_and_nothing_is_asked_while_closed() {
        let mut h = running(0);
        let out = h.closed("no connection with RCM on /dev/ttyS0: the line closed".into());
        assert!(
            matches!(ended(&out), Some(JobEnd::Alarm(c)) if c.class == AlarmClass::Communication),
            "{out:?}"
        );
        assert_eq!(h.poll_timeout(), None, "nothing asked on a closed line");
        assert!(!h.answered());
        // Idle: reported as it is.
        let out = h.link_failed("gone".into());
        assert!(
            matches!(&out[..], [Out::Alarm(c)] if c.text == "gone"),
            "{out:?}"
        );
        // Reopened: asked again; a status request given up is the
        // supervision's to report, a start's is the job's alarm.
        h.connected(s(10));
        assert!(h
            .gave_up(&Telegram::StatusRequest.encode(), "x".into())
            .is_empty());
        h.start(p65());
        let out = h.gave_up(&Telegram::SelectProgram(p65()).encode(), "x".into());
        assert!(matches!(ended(&out), Some(JobEnd::Alarm(_))), "{out:?}");
    }

    /// Seen in `falc-sim` (seed 7 of 1,000 orders, with the `memory`
    /// fault in the deck): program 65 ended while the line was unplugged;
    /// its end telegram went once the line was back, just after the next
    /// job had started program 66, and ended that job `done` at once while
    /// 66 ran on (the next order's select then met DNC error 04).
    #[test]
    fn the_late_end_of_another_program_does_not_end_the_job() {
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        let p66 = RobotProgram::new(66).expect("valid");
        let end65 = Telegram::ProgramEnd {
            program: p65(),
            result: EndResult::Complete,
        };
        // Before the job's start (no job's program runs) …
        h.start(p66);
        let out = h.telegram(s(0), end65.clone());
        assert_eq!(
            out,
            vec![Out::Info(
                "robot program 65 ended while no job's program runs: not a job's end".into()
            )]
        );
        h.telegram(s(0), ack(b'S'));
        h.telegram(s(0), ack(b'G'));
        // … or after it.
        let out = h.telegram(
            s(1),
            Telegram::ProgramEnd {
                program: p65(),
                result: EndResult::Complete,
            },
        );
        assert_eq!(ended(&out), None, "{out:?}");
        assert_eq!(
            out,
            vec![Out::Info(
                "robot program 65 ended while program 66 runs: not a job's end".into()
            )]
        );
        assert_eq!(h.running(), Some(p66));
        let out = h.telegram(
            s(2),
            Telegram::ProgramEnd {
                program: p66,
                result: EndResult::Complete,
            },
        );
        assert_eq!(ended(&out), Some(&JobEnd::Done));
    }

    /// Seen in `falc-sim` (a plant, seed 4 of 3,000 orders): program 66
    /// ended while the line was unplugged; its end telegram came once the
    /// line was back, while the next job, for program 66 too, held its
    /// select: the job ended `done` before its program started, and the
    /// program it then started ran with no job (the next order's select
    /// met DNC error 04).
    #[test]
    fn the_late_end_of_the_same_program_before_its_start_does_not_end_the_job() {
        let waited = Timing::default().ack_delay;
        let mut h = running(1000);
        let p66 = RobotProgram::of(66);
        let end66 = Telegram::ProgramEnd {
            program: p66,
            result: EndResult::Complete,
        };
        // The line went silent under a job's program; the next job starts
        // before the line is back: its select is held.
        assert!(ended(&h.silent(s(3500), waited)).is_some());
        assert_eq!(h.start(p66), vec![]);
        let out = h.telegram(s(4000), end66.clone());
        assert_eq!(ended(&out), None, "{out:?}");
        assert_eq!(
            out,
            vec![Out::Info(
                "robot program 66 ended while no job's program runs: not a job's end".into()
            )]
        );
        // Nor while its select is on its way.
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        assert_eq!(
            h.start(p66),
            vec![Out::Telegram(Telegram::SelectProgram(p66))]
        );
        assert_eq!(ended(&h.telegram(s(0), end66.clone())), None);
        // Once the start went, an end of its program is the job's (its
        // acknowledgement may be lost while the program runs).
        assert_eq!(
            h.telegram(s(0), ack(b'S')),
            vec![Out::Telegram(Telegram::StartProgram)]
        );
        assert_eq!(ended(&h.telegram(s(9), end66)), Some(&JobEnd::Done));
    }

    #[test]
    fn select_then_start_then_started() {
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        let p = p65();
        assert_eq!(h.start(p), vec![Out::Telegram(Telegram::SelectProgram(p))]);
        assert_eq!(
            h.telegram(s(0), ack(b'S')),
            vec![Out::Telegram(Telegram::StartProgram)]
        );
        assert_eq!(
            h.telegram(s(0), ack(b'G')),
            vec![
                Out::Engine(Event::Started(rcm())),
                Out::Info("robot program 65 started".into())
            ]
        );
        assert_eq!(h.running(), Some(p));
        let out = h.telegram(
            s(10),
            Telegram::ProgramEnd {
                program: p,
                result: EndResult::Complete,
            },
        );
        assert_eq!(ended(&out), Some(&JobEnd::Done));
        assert!(
            out.contains(&Out::Info("robot program 65 ended: complete".into())),
            "{out:?}"
        );
        assert_eq!(h.running(), None);
        assert_eq!(h.poll_timeout(), None, "nothing to supervise");
    }

    #[test]
    fn refusals_and_alarms_become_engine_events() {
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        h.start(p65());
        match h
            .telegram(
                s(0),
                Telegram::Ack {
                    of: b'S',
                    error: Some(AckError::NotInDncMode),
                },
            )
            .as_slice()
        {
            [Out::Engine(Event::StartFailed(_, why))] => {
                assert!(why.contains("automatic-external"), "{why}")
            }
            other => panic!("{other:?}"),
        }
        // A refusal noise can cause: selected once more, then refused.
        h.start(p65());
        let unknown = Telegram::Ack {
            of: b'S',
            error: Some(AckError::UnknownProgram),
        };
        assert!(matches!(
            h.telegram(s(0), unknown.clone()).as_slice(),
            [Out::Telegram(Telegram::SelectProgram(p))] if *p == p65()
        ));
        assert!(matches!(
            h.telegram(s(0), unknown).as_slice(),
            [Out::Engine(Event::StartFailed(_, _))]
        ));
        let estop = h.telegram(s(0), Telegram::Alarm(24));
        assert!(
            matches!(&estop[0], Out::Detail(d) if d.specific & RobotStatusDetail::SAFETY_INTERLOCKS_VIOLATED != 0)
        );
        assert!(
            matches!(&estop[1], Out::Engine(Event::Ended(_, JobEnd::Alarm(t))) if t.contains("emergency stop") && t.class == AlarmClass::Safety)
        );
        assert!(matches!(
            h.telegram(s(0), Telegram::Alarm(30)).last(),
            Some(Out::Engine(Event::Paused(_)))
        ));
        let limit = h.telegram(s(0), Telegram::Alarm(40));
        assert!(
            limit
                .iter()
                .any(|o| matches!(o, Out::Engine(Event::Ended(_, JobEnd::FailedDanger)))),
            "{limit:?}"
        );
        assert!(
            limit
                .iter()
                .any(|o| matches!(o, Out::Alarm(c) if c.class == AlarmClass::Safety)),
            "no job runs: reported as a safety alarm too: {limit:?}"
        );
        assert_eq!(
            h.telegram(s(0), Telegram::Alarm(3)).last(),
            Some(&Out::Telegram(Telegram::ConfirmAlarm(3)))
        );
    }

    #[test]
    fn an_alarm_while_no_job_runs_is_reported_as_it_is() {
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        let out = h.telegram(s(0), Telegram::Alarm(24));
        assert!(
            out.iter().any(|o| matches!(o, Out::Alarm(c) if c.class == AlarmClass::Safety && c.contains("emergency stop"))),
            "{out:?}"
        );
        // While a job runs, the job's end carries it instead.
        let mut h = running(0);
        let out = h.telegram(s(1), Telegram::Alarm(24));
        assert!(!out.iter().any(|o| matches!(o, Out::Alarm(_))), "{out:?}");
    }

    #[test]
    fn the_status_detail_follows_the_program_status_after_an_alarm() {
        let mut h = running(0);
        let estop = h.telegram(s(5), Telegram::Alarm(24));
        assert!(
            matches!(&estop[0], Out::Detail(d) if d.state == RobotVmdState::ManualInterventionRequired)
        );
        // Cleared, then the next program runs: the robot's own status rules.
        let out = h.telegram(s(9), status(Some(p65()), ProgramState::Stopped));
        assert_eq!(
            out,
            vec![Out::Detail(RobotStatusDetail {
                state: RobotVmdState::Ready,
                specific: RobotStatusDetail::ALL_CALIBRATED,
                mask: alarms::MASK,
            })]
        );
        let out = h.telegram(s(9), status(None, ProgramState::Idle));
        assert!(
            matches!(&out[0], Out::Detail(d) if d.specific & RobotStatusDetail::SAFETY_INTERLOCKS_VIOLATED == 0)
        );
        let manual = alarms::status_detail(ProgramState::Idle, Mode::Manual);
        assert_ne!(manual.specific & RobotStatusDetail::LOCAL_CONTROL, 0);
    }

    #[test]
    fn a_running_program_is_supervised_and_an_unanswered_request_is_an_alarm_within_the_links_budget(
    ) {
        // Bytes heard but no answer through: the limit is the link's, two
        // lost attempts on the way (6.88 s).
        let limit = Timing::default().silent_after();
        assert_eq!(limit, s(6880));
        let period = STATUS_PERIOD;
        assert_eq!(period, s(500));
        let mut h = running(1000);
        // A status request a period after the RCM was last heard.
        let asked = s(1000) + period;
        assert_eq!(h.poll_timeout(), Some(asked));
        assert!(h.handle_timeout(asked - s(1)).is_empty(), "not due yet");
        assert_eq!(
            h.handle_timeout(asked),
            vec![Out::Telegram(Telegram::StatusRequest)]
        );
        // Answered after two attempts were lost (4.88 s): no alarm.
        let answered = asked + s(4880);
        let out = h.telegram(answered, status(Some(p65()), ProgramState::Running));
        assert!(ended(&out).is_none(), "{out:?}");
        assert_eq!(h.poll_timeout(), Some(answered + period));
        h.handle_timeout(answered + period);
        // The request goes unanswered.
        let asked = answered + period;
        assert_eq!(h.poll_timeout(), Some(asked + limit));
        assert!(h.handle_timeout(asked + limit - s(1)).is_empty());
        let out = h.handle_timeout(asked + limit);
        match ended(&out) {
            Some(JobEnd::Alarm(why)) => {
                assert_eq!(why.class, AlarmClass::Communication);
                assert!(why.contains("/dev/ttyS0"), "names the device: {why}");
                assert!(why.contains("status request unanswered for 6.9 s"), "{why}");
                assert!(why.contains("program 65"), "{why}");
            }
            other => panic!("{other:?}"),
        }
        assert!(!h.answered());
        // It keeps asking, and when the line is back stops the program it
        // no longer owns; never a second request behind one the link
        // still tries (3964R: up to 6 × 2 s).
        let t = asked + limit;
        assert!(h.handle_timeout(t + period).is_empty());
        h.sent(t + period, &Telegram::StatusRequest.encode());
        assert_eq!(h.poll_timeout(), Some(t + period + limit));
        h.handle_timeout(t + period + limit);
        h.sent(t + period + limit, &Telegram::StatusRequest.encode());
        let t = t + period + limit + period;
        assert_eq!(
            h.handle_timeout(t),
            vec![Out::Telegram(Telegram::StatusRequest)]
        );
        // Seen once: asked again to be sure; confirmed: stopped.
        let out = h.telegram(t + s(50), status(Some(p65()), ProgramState::Running));
        assert!(
            out.contains(&Out::Telegram(Telegram::StatusRequest)),
            "{out:?}"
        );
        assert!(
            !out.contains(&Out::Telegram(Telegram::StopProgram)),
            "{out:?}"
        );
        let out = h.telegram(t + s(100), status(Some(p65()), ProgramState::Running));
        assert!(
            out.contains(&Out::Telegram(Telegram::StopProgram)),
            "{out:?}"
        );
        assert!(
            out.iter().any(|o| matches!(o, Out::Alarm(t) if t.contains("robot program 65") && t.contains("no job") && t.class == AlarmClass::Warning)),
            "{out:?}"
        );
        assert_eq!(h.poll_timeout(), None);
    }

    #[test]
    fn a_silent_line_is_an_alarm_at_once_for_a_program_that_runs_and_nothing_while_idle() {
        // The link heard nothing for an acknowledgement delay.
        let waited = Timing::default().ack_delay;
        let mut h = running(1000);
        let out = h.silent(s(3500), waited);
        match ended(&out) {
            Some(JobEnd::Alarm(why)) => {
                assert_eq!(why.class, AlarmClass::Communication);
                assert!(why.contains("/dev/ttyS0"), "names the device: {why}");
                assert!(why.contains("nothing heard for 2.0 s"), "{why}");
                assert!(why.contains("program 65"), "{why}");
            }
            other => panic!("{other:?}"),
        }
        assert!(!h.answered(), "the RCM does not answer until it does");
        assert!(!h.has_job());
        // The job is gone: a second silence tells nothing new.
        assert!(h.silent(s(6000), waited).is_empty());
        // The RCM answers again: it is ready once more.
        h.telegram(s(7000), status(None, ProgramState::Idle));
        assert!(h.answered());
        // Idle (no program): a silence is no alarm, but the RCM does not
        // answer until it does.
        assert!(h.silent(s(9000), waited).is_empty());
        assert!(!h.answered());
    }

    /// Found by `falc-sim` (seeds 2 and 6): the line came back under a
    /// program whose job had ended in alarm, and the next order's job
    /// selected before the RCM had answered: refused, "a program is
    /// running on the RCM (DNC error 04)", and the order failed.
    #[test]
    fn a_job_started_before_the_line_is_back_selects_once_the_left_program_is_stopped() {
        let waited = Timing::default().ack_delay;
        let mut h = running(1000);
        assert!(ended(&h.silent(s(3500), waited)).is_some());
        // The way back's start comes before the RCM answered: held.
        assert_eq!(h.start(RobotProgram::of(66)), vec![]);
        assert!(h.has_job());
        // A stray acknowledgement is not of the held select.
        assert_eq!(h.telegram(s(3600), ack(b'S')), vec![]);
        // The RCM answers: 65 still runs. Confirmed by a second answer,
        // it is stopped, and then the select goes.
        let first = h.telegram(s(4000), status(Some(p65()), ProgramState::Running));
        assert!(
            first.contains(&Out::Telegram(Telegram::StatusRequest)),
            "{first:?}"
        );
        assert!(!first
            .iter()
            .any(|o| matches!(o, Out::Telegram(Telegram::SelectProgram(_)))));
        let second = h.telegram(s(4100), status(Some(p65()), ProgramState::Running));
        let telegrams: Vec<&Telegram> = second
            .iter()
            .filter_map(|o| match o {
                Out::Telegram(t) => Some(t),
                _ => None,
            })
            .collect();
        assert_eq!(
            telegrams,
            [
                &Telegram::StopProgram,
                &Telegram::SelectProgram(RobotProgram::of(66))
            ]
        );
        assert!(second.iter().any(|o| matches!(o, Out::Alarm(c)
            if c.class == AlarmClass::Warning && c.contains("robot program 65 was running"))));
        // The job goes on as any: acknowledged, started.
        assert_eq!(
            h.telegram(s(4200), ack(b'S')),
            vec![Out::Telegram(Telegram::StartProgram)]
        );
        assert!(matches!(
            h.telegram(s(4300), ack(b'G')).first(),
            Some(Out::Engine(Event::Started(_)))
        ));
        // Seen once running with no job when the job starts (the line
        // answered again a moment before): held until it is confirmed.
        let mut h = running(1000);
        h.silent(s(3500), Timing::default().ack_delay);
        let seen = h.telegram(s(4000), status(Some(p65()), ProgramState::Running));
        assert!(seen.contains(&Out::Telegram(Telegram::StatusRequest)));
        assert!(h.answered());
        assert_eq!(h.start(RobotProgram::of(66)), vec![]);
        let out = h.telegram(s(4100), status(Some(p65()), ProgramState::Running));
        assert!(
            out.contains(&Out::Telegram(Telegram::StopProgram)),
            "{out:?}"
        );
        assert!(
            out.contains(&Out::Telegram(Telegram::SelectProgram(RobotProgram::of(
                66
            )))),
            "{out:?}"
        );
        // An idle RCM: the held select goes at its first answer.
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        h.connected(s(0));
        assert_eq!(h.start(p65()), vec![]);
        let out = h.telegram(s(10), status(None, ProgramState::Idle));
        assert!(
            out.contains(&Out::Telegram(Telegram::SelectProgram(p65()))),
            "{out:?}"
        );
    }

    #[test]
    fn a_lost_acknowledgement_of_the_select_or_the_start_is_asked_for() {
        let limit = Timing::default().silent_after();
        let selected = |h: &mut Host, at: Duration| {
            h.connected(s(0));
            h.telegram(s(0), status(None, ProgramState::Idle));
            assert_eq!(
                h.start(p65()),
                vec![Out::Telegram(Telegram::SelectProgram(p65()))]
            );
            h.sent(at, &Telegram::SelectProgram(p65()).encode());
        };
        // The select's acknowledgement is lost: after the link's budget for
        // an answer the status is asked; it shows 65 selected: started.
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        selected(&mut h, s(1000));
        assert_eq!(h.poll_timeout(), Some(s(1000) + limit));
        assert!(h.handle_timeout(s(1000) + limit - s(1)).is_empty());
        assert_eq!(
            h.handle_timeout(s(1000) + limit),
            vec![Out::Telegram(Telegram::StatusRequest)]
        );
        let out = h.telegram(s(8000), status(Some(p65()), ProgramState::Selected));
        assert!(
            out.contains(&Out::Telegram(Telegram::StartProgram)),
            "{out:?}"
        );
        assert!(
            out.iter().any(|o| matches!(o, Out::Info(t) if t.contains("acknowledgement of the selection of robot program 65 was lost"))),
            "{out:?}"
        );
        // Then the start's acknowledgement is lost too: the status shows
        // 65 running, so it runs, as ours.
        h.sent(s(8100), &Telegram::StartProgram.encode());
        assert_eq!(
            h.handle_timeout(s(8100) + limit),
            vec![Out::Telegram(Telegram::StatusRequest)]
        );
        let out = h.telegram(s(15_100), status(Some(p65()), ProgramState::Running));
        assert!(
            out.iter()
                .any(|o| matches!(o, Out::Engine(Event::Started(_)))),
            "{out:?}"
        );
        assert_eq!(h.running(), Some(p65()));
        assert!(
            !out.contains(&Out::Telegram(Telegram::StopProgram)),
            "{out:?}"
        );
        // The acknowledgement in time: no status asked for it.
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        selected(&mut h, s(1000));
        h.telegram(s(1100), ack(b'S'));
        h.sent(s(1200), &Telegram::StartProgram.encode());
        h.telegram(s(1300), ack(b'G'));
        assert_eq!(h.running(), Some(p65()));
        assert_eq!(h.poll_timeout(), Some(s(1300) + STATUS_PERIOD));
        // Lost, and the status shows nothing selected (the select never
        // took): the job selects once more, and only once.
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        selected(&mut h, s(1000));
        h.handle_timeout(s(1000) + limit);
        let out = h.telegram(s(8000), status(None, ProgramState::Idle));
        assert!(
            out.contains(&Out::Telegram(Telegram::SelectProgram(p65()))),
            "{out:?}"
        );
        h.sent(s(8100), &Telegram::SelectProgram(p65()).encode());
        h.handle_timeout(s(8100) + limit);
        let out = h.telegram(s(15_100), status(None, ProgramState::Idle));
        assert!(
            !out.iter().any(|o| matches!(o, Out::Telegram(_))),
            "the recipe's own limit ends it: {out:?}"
        );
        // The line lost while the status for a lost acknowledgement is
        // awaited: that wait goes with the job, and on the line's return
        // a program found running is stopped as no job's (two statuses).
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        selected(&mut h, s(1000));
        h.handle_timeout(s(1000) + limit);
        h.closed("unplugged".into());
        h.connected(s(20_000));
        let out = h.telegram(s(20_100), status(Some(p65()), ProgramState::Running));
        assert!(
            !out.contains(&Out::Telegram(Telegram::StopProgram)),
            "{out:?}"
        );
        let out = h.telegram(s(20_200), status(Some(p65()), ProgramState::Running));
        assert!(
            out.contains(&Out::Telegram(Telegram::StopProgram)),
            "{out:?}"
        );
    }

    #[test]
    fn a_lost_program_end_is_recovered_from_the_status() {
        let mut h = running(0);
        h.handle_timeout(s(1000));
        let out = h.telegram(s(1020), status(Some(p65()), ProgramState::Selected));
        assert_eq!(ended(&out), None, "confirmed first: {out:?}");
        assert!(out.contains(&Out::Telegram(Telegram::StatusRequest)));
        let out = h.telegram(s(1040), status(Some(p65()), ProgramState::Selected));
        assert_eq!(ended(&out), Some(&JobEnd::Done), "{out:?}");
        // A stray answer that the next one contradicts changes nothing.
        let mut h = running(0);
        h.handle_timeout(s(1000));
        h.telegram(s(1020), status(None, ProgramState::Idle));
        let out = h.telegram(s(1040), status(Some(p65()), ProgramState::Running));
        assert_eq!(ended(&out), None, "{out:?}");
        assert_eq!(h.running(), Some(p65()));
        // Stopped before its end (an emergency stop whose alarm was lost):
        // an alarm that says so.
        let mut h = running(0);
        h.handle_timeout(s(1000));
        h.telegram(s(1020), status(Some(p65()), ProgramState::Stopped));
        let out = h.telegram(s(1040), status(Some(p65()), ProgramState::Stopped));
        match ended(&out) {
            Some(JobEnd::Alarm(why)) => assert!(why.contains("stopped before its end"), "{why}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn on_connection_a_program_no_job_owns_is_stopped_and_reported() {
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        assert_eq!(
            h.connected(s(0)),
            vec![
                Out::Telegram(Telegram::InitiateDnc),
                Out::Telegram(Telegram::StatusRequest)
            ]
        );
        h.telegram(s(30), status(Some(p65()), ProgramState::Paused));
        let out = h.telegram(s(60), status(Some(p65()), ProgramState::Paused));
        assert!(
            out.contains(&Out::Telegram(Telegram::StopProgram)),
            "{out:?}"
        );
        // An idle robot: nothing to do, nothing more to ask.
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        h.connected(s(0));
        let out = h.telegram(s(30), status(None, ProgramState::Idle));
        assert_eq!(out.len(), 1, "{out:?}");
        assert_eq!(h.poll_timeout(), None);
        // Unanswered at start-up (the line is silent): no alarm; asked
        // again once the link gave the first request up.
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        h.connected(s(0));
        assert!(h.handle_timeout(s(6880)).is_empty());
        h.sent(s(6880), &Telegram::StatusRequest.encode());
        assert_eq!(
            h.handle_timeout(s(7880)),
            vec![Out::Telegram(Telegram::StatusRequest)]
        );
    }

    #[test]
    fn a_program_a_maintainer_started_is_supervised_and_a_silent_line_is_an_alarm() {
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        h.connected(s(0));
        h.telegram(s(1), status(None, ProgramState::Idle));
        assert_eq!(h.poll_timeout(), None, "nothing runs: nothing asked");
        h.manual(&ManualAction::StartProgram).unwrap();
        // Its status is asked while it runs.
        let at = h.poll_timeout().expect("supervised");
        let out = h.handle_timeout(at);
        assert!(
            out.iter()
                .any(|o| matches!(o, Out::Telegram(Telegram::StatusRequest))),
            "{out:?}"
        );
        // Unanswered: an alarm of its own (no job to end).
        let limit = h.poll_timeout().expect("the answer awaited");
        let out = h.handle_timeout(limit);
        assert!(
            matches!(&out[..], [Out::Alarm(c)] if c.text.contains("started by hand")),
            "{out:?}"
        );
    }

    #[test]
    fn a_program_a_maintainer_started_is_theirs_not_an_orphan() {
        let mut h = Host::new("/dev/ttyS0", &Timing::default());
        h.connected(s(0));
        h.telegram(s(10), status(None, ProgramState::Idle));
        h.manual(&ManualAction::SelectProgram(65)).unwrap();
        h.manual(&ManualAction::StartProgram).unwrap();
        for at in [30, 60, 90] {
            let out = h.telegram(s(at), status(Some(p65()), ProgramState::Running));
            assert!(
                !out.contains(&Out::Telegram(Telegram::StopProgram)),
                "a program started by hand is left running: {out:?}"
            );
        }
        // Its end is reported, as a job's is.
        let out = h.telegram(
            s(100),
            Telegram::ProgramEnd {
                program: p65(),
                result: EndResult::Complete,
            },
        );
        assert!(
            out.contains(&Out::Info(
                "robot program 65 ended: complete (started by hand)".into()
            )),
            "{out:?}"
        );
        // Once it ended, a program running with no job is an orphan again.
        h.telegram(s(130), status(Some(p65()), ProgramState::Running));
        let out = h.telegram(s(160), status(Some(p65()), ProgramState::Running));
        assert!(
            out.contains(&Out::Telegram(Telegram::StopProgram)),
            "{out:?}"
        );
    }
}
