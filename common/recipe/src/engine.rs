//! The recipe interpreter, sans-I/O: a checked [`Program`] is run by feeding
//! [`Event`]s in (`handle`), the clock in (`handle_timeout`), and taking
//! [`Action`]s out (`poll_action`); `poll_timeout` says when the clock
//! matters next. Time is a `Duration` since any origin the driver picks.
//!
//! Beyond the 1992 interpreter:
//! - a time limit on `start` covers the whole job; a `wait` without its own
//!   limit uses what is left of it;
//! - an `alarm` status from below ends the recipe in alarm at once, whatever
//!   the recipe is doing, and stops the other jobs below;
//! - `bad_product`, `failed_safe`, `failed_danger` are criteria of `wait`
//!   (unhandled, they end the recipe with the same failure, passed up);
//! - while a job below reports paused, its time limits are frozen;
//! - the alarm report stops every job still running below;
//! - step mode ([`Engine::set_stepping`]): each state waits before it is
//!   carried out until [`Engine::step`] (or runs on to a chosen state);
//!   time limits do not run while a step waits;
//! - an aborted run resumes ([`Engine::resume`], ISO 9506 Stop → Resume) at
//!   the state it stopped in, or, where a job below was stopped with it,
//!   at the state that started that job. Nothing is pressed again: a
//!   conveyor line runs on to its end once pressed, and a second press
//!   would send the next carrier along it.

use super::check::{Button, Command, Job, Program, Signal};
use super::syntax::{Criterion, Report, StateNo};
use falc_model::alarm::Cause;
use falc_model::ids::StationName;
use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use std::time::Duration;

/// How long a `start` may wait for its confirm when it gives no shorter limit.
pub const START_CONFIRM_LIMIT: Duration = Duration::from_secs(10);
/// More immediate transitions than this in one step is a runaway recipe.
const MAX_IMMEDIATE_STEPS: usize = 10_000;

/// How a job below ended (its unsolicited status).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum JobEnd {
    /// Finished normally.
    Done,
    /// Finished, product bad (weld aborted).
    BadProduct,
    /// Failed without danger.
    FailedSafe,
    /// Failed with danger (limit switch).
    FailedDanger,
    /// Alarm: the recipe ends in alarm at once.
    Alarm(Cause),
}

/// What happens, fed to the engine.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// The start of a job on `target` was confirmed.
    Started(StationName),
    /// The start was refused or failed.
    StartFailed(StationName, String),
    /// The job on `target` ended.
    Ended(StationName, JobEnd),
    /// The job on `target` is paused (a person in the work area).
    Paused(StationName),
    /// … and goes on.
    Resumed(StationName),
    /// The operator answered.
    Answer(String),
    /// What a state watches holds: the PLC input reached its level, or
    /// the robot is ready (`waitready`).
    InputReached,
}

/// What the engine wants done.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Action {
    /// The recipe entered a state (for the status line and the journal).
    Entered(StateNo),
    /// Start a job below.
    Start {
        /// The station or `rcm`.
        target: StationName,
        /// What.
        job: Job,
    },
    /// Stop a job below.
    Stop(StationName),
    /// Show text to the operator.
    Output(String),
    /// Ask the operator.
    Input(String),
    /// Press a PLC button.
    Activate(Button),
    /// Release a PLC button.
    Reset(Button),
    /// Watch a PLC input until it reaches `level`.
    Watch {
        /// The input.
        signal: Signal,
        /// The level.
        level: bool,
    },
    /// Watch the robot until it takes DNC commands (`waitready`): the
    /// device says [`Event::InputReached`] once it does.
    WatchReady,
    /// Stop watching.
    Unwatch,
    /// Report an alarm upward.
    Alarm(Cause),
    /// Step mode: the state waits before it is carried out.
    Held(StateNo),
}

/// How a run ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Outcome {
    /// State 0 reached without alarm.
    Done,
    /// Ended in alarm, with the cause.
    Alarm(Cause),
    /// A job below failed in a way no state handled (`bad_product`,
    /// `failed_safe`, `failed_danger`): passed up as the same failure, so
    /// the level above can handle it.
    Failed(JobEnd),
}

/// What a run waits for from the level below ([`Engine::awaiting`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Awaited {
    /// The confirm of a Start it sent (`start`).
    Confirm,
    /// The end of a job it started (`wait`).
    End,
}

#[derive(Debug, Clone, PartialEq, Eq)]
enum JobState {
    Starting,
    Running,
    Ended(JobEnd),
}

#[derive(Debug, Clone)]
struct JobInfo {
    state: JobState,
    deadline: Option<Duration>,
    paused_since: Option<Duration>,
    /// The state that started it, and the step count then (a resume goes
    /// back to the earliest start of a job stopped with the run).
    started_in: Option<(u64, StateNo)>,
}

#[derive(Debug, Clone, PartialEq, Eq)]
enum Phase {
    NotStarted,
    AwaitStart {
        target: StationName,
        deadline: Duration,
    },
    AwaitJob {
        target: StationName,
        deadline: Option<Duration>,
    },
    AwaitAnswer,
    AwaitInput {
        deadline: Duration,
    },
    /// Step mode: the state waits for [`Engine::step`] since then.
    AwaitStep {
        since: Duration,
    },
    Ended(Outcome),
}

/// One run of a program.
#[derive(Debug, Clone)]
pub struct Engine {
    program: Arc<Program>,
    state: StateNo,
    phase: Phase,
    jobs: BTreeMap<StationName, JobInfo>,
    actions: VecDeque<Action>,
    alarm: Option<Cause>,
    /// Why the last `timeout` branch was taken (what was waited for, or
    /// the refusal with its ISO 9506 class and code): an alarm state the
    /// branch leads to names it.
    failure: Option<String>,
    steps: u64,
    confirm_limit: Duration,
    /// Step mode: every state waits before it is carried out.
    stepping: bool,
    /// Step mode: run on until this state, then wait.
    step_to: Option<StateNo>,
    /// The next state entered is carried out without waiting (confirmed).
    released: bool,
    /// Where [`Engine::resume`] goes on, once aborted.
    resume_at: Option<StateNo>,
}

impl Engine {
    /// A run of `program`, not started yet.
    pub fn new(program: Arc<Program>) -> Self {
        Self {
            state: program.first,
            program,
            phase: Phase::NotStarted,
            jobs: BTreeMap::new(),
            actions: VecDeque::new(),
            alarm: None,
            failure: None,
            steps: 0,
            confirm_limit: START_CONFIRM_LIMIT,
            stepping: false,
            step_to: None,
            released: false,
            resume_at: None,
        }
    }

    /// Step mode on or off. Off while a step waits: it is carried out now.
    pub fn set_stepping(&mut self, now: Duration, on: bool) {
        self.stepping = on;
        if !on {
            self.step_to = None;
            if self.held().is_some() {
                let _ = self.step(now, None);
            }
        }
    }

    /// The state waiting for confirmation (step mode), if one does.
    pub fn held(&self) -> Option<StateNo> {
        matches!(self.phase, Phase::AwaitStep { .. }).then_some(self.state)
    }

    /// Carries out the waiting step; with `to`, goes on without waiting
    /// until state `to` is next (it then waits). The time limits of the
    /// jobs below are moved on by the time the step waited.
    pub fn step(&mut self, now: Duration, to: Option<StateNo>) -> Result<(), String> {
        let Phase::AwaitStep { since } = self.phase else {
            return Err(match &self.phase {
                Phase::Ended(_) | Phase::NotStarted => "no recipe runs".to_string(),
                _ => format!(
                    "state {} is being carried out; the next step waits when it is reached",
                    self.state
                ),
            });
        };
        if let Some(t) = to {
            if !self.program.states.contains_key(&t) {
                return Err(format!("state {t} does not exist in this recipe"));
            }
        }
        let waited = now.saturating_sub(since);
        for j in self.jobs.values_mut() {
            j.deadline = j.deadline.map(|d| d + waited);
        }
        self.step_to = to;
        self.released = true;
        self.enter(now, self.state);
        Ok(())
    }

    /// Starts the run at `state` instead of the first (a restart of an
    /// order from a state the operator chose).
    pub fn start_at(&mut self, now: Duration, state: StateNo) -> Result<(), String> {
        if !self.program.states.contains_key(&state) {
            return Err(format!("state {state} does not exist in this recipe"));
        }
        if self.phase == Phase::NotStarted {
            self.enter(now, state);
        }
        Ok(())
    }

    /// After [`Engine::abort`]: where [`Engine::resume`] would go on.
    pub fn resume_point(&self) -> Option<StateNo> {
        self.resume_at
    }

    /// Goes on after an abort (ISO 9506 Resume after Stop): at the state it
    /// stopped in, or at the earliest `start` of a job below that was
    /// stopped with it. The state to go on at, or None if the run was not
    /// aborted.
    pub fn resume(&mut self, now: Duration) -> Option<StateNo> {
        let at = self.resume_at.take()?;
        self.jobs.clear();
        self.alarm = None;
        self.failure = None;
        self.phase = Phase::NotStarted;
        self.enter(now, at);
        Some(at)
    }

    /// How long a `start` waits for its confirm (default
    /// [`START_CONFIRM_LIMIT`]); a node whose device link retries longer
    /// (DNC: 6 × 2 s per telegram) sets more, so the link's own, clearer
    /// failure arrives first.
    pub fn with_confirm_limit(mut self, limit: Duration) -> Self {
        self.confirm_limit = limit;
        self
    }

    /// The program.
    pub fn program(&self) -> &Program {
        &self.program
    }

    /// The current state.
    pub fn state(&self) -> StateNo {
        self.state
    }

    /// States entered so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// What the run waits for from the level below, if it waits for it:
    /// the confirm of a Start it sent, or the end of a job it started.
    pub fn awaiting(&self) -> Option<Awaited> {
        match self.phase {
            Phase::AwaitStart { .. } => Some(Awaited::Confirm),
            Phase::AwaitJob { .. } => Some(Awaited::End),
            _ => None,
        }
    }

    /// The outcome, once ended.
    pub fn outcome(&self) -> Option<&Outcome> {
        match &self.phase {
            Phase::Ended(o) => Some(o),
            _ => None,
        }
    }

    /// Starts the run at the first state.
    pub fn start(&mut self, now: Duration) {
        if self.phase == Phase::NotStarted {
            self.enter(now, self.program.first);
        }
    }

    /// The next action, if any.
    pub fn poll_action(&mut self) -> Option<Action> {
        self.actions.pop_front()
    }

    /// When `handle_timeout` must be called next (None: no deadline runs;
    /// a paused job's deadline does not run).
    pub fn poll_timeout(&self) -> Option<Duration> {
        match &self.phase {
            Phase::AwaitStart { deadline, .. } | Phase::AwaitInput { deadline } => Some(*deadline),
            // Time limits do not run while a step waits.
            Phase::AwaitStep { .. } => None,
            Phase::AwaitJob { target, deadline } => {
                let paused = self
                    .jobs
                    .get(target)
                    .is_some_and(|j| j.paused_since.is_some());
                if paused {
                    None
                } else {
                    *deadline
                }
            }
            _ => None,
        }
    }

    /// The clock reached `now`: a passed deadline takes the `timeout` branch.
    pub fn handle_timeout(&mut self, now: Duration) {
        if self.poll_timeout().is_some_and(|d| d <= now) {
            if matches!(self.phase, Phase::AwaitInput { .. }) {
                self.actions.push_back(Action::Unwatch);
            }
            self.failure = match &self.phase {
                Phase::AwaitStart { target, .. } => {
                    Some(format!("the start of {target} was not confirmed in time"))
                }
                Phase::AwaitJob { target, .. } => {
                    Some(format!("{target} did not finish within its time limit"))
                }
                Phase::AwaitInput { .. } => {
                    Some("what the state waited for did not come within its time limit".into())
                }
                _ => None,
            };
            self.branch(now, &Criterion::Timeout);
        }
    }

    /// Ends the run in alarm from outside (the commander stopped it, the
    /// link to a device was lost): stops the jobs below.
    pub fn abort(&mut self, cause: Cause) {
        if !matches!(self.phase, Phase::Ended(_)) {
            let stopped_job = self
                .jobs
                .values()
                .filter(|j| matches!(j.state, JobState::Starting | JobState::Running))
                .filter_map(|j| j.started_in)
                .min();
            self.resume_at = Some(stopped_job.map_or(self.state, |(_, s)| s));
            self.stop_jobs(None);
            self.end(Outcome::Alarm(cause));
        }
    }

    /// Feeds an event.
    pub fn handle(&mut self, now: Duration, event: Event) {
        if matches!(self.phase, Phase::Ended(_) | Phase::NotStarted) {
            return;
        }
        match event {
            Event::Started(t) => {
                if let Some(j) = self.jobs.get_mut(&t) {
                    if j.state == JobState::Starting {
                        j.state = JobState::Running;
                    }
                }
                if matches!(&self.phase, Phase::AwaitStart { target, .. } if *target == t) {
                    self.branch(now, &Criterion::Started);
                }
            }
            Event::StartFailed(t, why) => {
                if let Some(j) = self.jobs.get_mut(&t) {
                    j.state = JobState::Ended(JobEnd::FailedSafe);
                }
                if matches!(&self.phase, Phase::AwaitStart { target, .. } if *target == t) {
                    tracing::info!(station = %t, "start failed: {why}");
                    self.failure = Some(format!("the start of {t} was refused: {why}"));
                    self.branch(now, &Criterion::Timeout);
                }
            }
            Event::Ended(t, JobEnd::Alarm(text)) => {
                if let Some(j) = self.jobs.get_mut(&t) {
                    j.state = JobState::Ended(JobEnd::Alarm(text.clone()));
                }
                let cause = text.passed_on(t.as_str());
                self.stop_jobs(Some(&t));
                self.actions.push_back(Action::Alarm(cause.clone()));
                self.end(Outcome::Alarm(cause));
            }
            Event::Ended(t, end) => {
                let j = self.jobs.entry(t.clone()).or_insert(JobInfo {
                    state: JobState::Running,
                    deadline: None,
                    paused_since: None,
                    started_in: None,
                });
                j.state = JobState::Ended(end.clone());
                j.paused_since = None;
                if matches!(&self.phase, Phase::AwaitJob { target, .. } if *target == t) {
                    self.job_ended(now, &t, &end);
                }
            }
            Event::Paused(t) => {
                if let Some(j) = self.jobs.get_mut(&t) {
                    if j.paused_since.is_none() {
                        j.paused_since = Some(now);
                    }
                }
            }
            Event::Resumed(t) => {
                let Some(j) = self.jobs.get_mut(&t) else {
                    return;
                };
                let Some(since) = j.paused_since.take() else {
                    return;
                };
                let frozen = now.saturating_sub(since);
                j.deadline = j.deadline.map(|d| d + frozen);
                if let Phase::AwaitJob {
                    target,
                    deadline: Some(d),
                } = &mut self.phase
                {
                    if *target == t {
                        *d += frozen;
                    }
                }
            }
            Event::Answer(text) => {
                if self.phase == Phase::AwaitAnswer {
                    let a = text.trim().to_lowercase();
                    let exact = self
                        .current_branches()
                        .iter()
                        .any(|(c, _)| *c == Some(Criterion::Answer(a.clone())));
                    let c = if exact {
                        Criterion::Answer(a)
                    } else {
                        Criterion::AnswerAny
                    };
                    self.branch(now, &c);
                }
            }
            Event::InputReached => {
                if matches!(self.phase, Phase::AwaitInput { .. }) {
                    self.actions.push_back(Action::Unwatch);
                    self.branch(now, &Criterion::Done);
                }
            }
        }
    }

    fn current_branches(&self) -> &[(Option<Criterion>, StateNo)] {
        self.program
            .states
            .get(&self.state)
            .map_or(&[], |s| s.branches.as_slice())
    }

    fn job_ended(&mut self, now: Duration, target: &StationName, end: &JobEnd) {
        let Some(c) = criterion_of(end) else {
            return;
        };
        if self
            .current_branches()
            .iter()
            .any(|(b, _)| b.as_ref() == Some(&c))
        {
            self.branch(now, &c);
        } else {
            tracing::info!(
                "{target} ended with {c}, which state {} does not handle: passed up",
                self.state
            );
            self.stop_jobs(None);
            self.end(Outcome::Failed(end.clone()));
        }
    }

    /// ` (why the last timeout branch was taken)`, once, for the alarm it
    /// leads to; empty if none was.
    fn why_here(&mut self) -> String {
        self.failure
            .take()
            .map(|w| format!(" ({w})"))
            .unwrap_or_default()
    }

    fn branch(&mut self, now: Duration, c: &Criterion) {
        if *c != Criterion::Timeout {
            self.failure = None;
        }
        let next = self
            .current_branches()
            .iter()
            .find(|(b, _)| b.as_ref() == Some(c))
            .map(|(_, n)| *n);
        match next {
            Some(n) => self.enter(now, n),
            None => {
                let why = self.why_here();
                let cause =
                    Cause::process(format!("state {} has no `{c}` branch{why}", self.state));
                self.stop_jobs(None);
                self.actions.push_back(Action::Alarm(cause.clone()));
                self.end(Outcome::Alarm(cause));
            }
        }
    }

    fn stop_jobs(&mut self, except: Option<&StationName>) {
        for (t, j) in &mut self.jobs {
            if Some(t) != except && matches!(j.state, JobState::Starting | JobState::Running) {
                j.state = JobState::Ended(JobEnd::FailedSafe);
                self.actions.push_back(Action::Stop(t.clone()));
            }
        }
    }

    fn end(&mut self, outcome: Outcome) {
        self.phase = Phase::Ended(outcome);
    }

    /// Enters `next` and runs every state that does not wait.
    fn enter(&mut self, now: Duration, mut next: StateNo) {
        for _ in 0..MAX_IMMEDIATE_STEPS {
            let released = std::mem::take(&mut self.released);
            if next == StateNo::END {
                let outcome = self.alarm.take().map_or(Outcome::Done, Outcome::Alarm);
                self.end(outcome);
                return;
            }
            let Some(st) = self.program.states.get(&next).cloned() else {
                let cause = Cause::process(format!("state {next} does not exist"));
                self.actions.push_back(Action::Alarm(cause.clone()));
                self.end(Outcome::Alarm(cause));
                return;
            };
            self.state = next;
            let wait_here = self.step_to.map_or(true, |t| t == next);
            if self.stepping && !released && wait_here {
                self.step_to = None;
                self.phase = Phase::AwaitStep { since: now };
                self.actions.push_back(Action::Held(next));
                return;
            }
            self.steps += 1;
            self.actions.push_back(Action::Entered(next));
            if st.report == Some(Report::Alarm) {
                let cause = Cause::process(format!(
                    "alarm in state {next}{}{}",
                    if st.text.is_empty() {
                        String::new()
                    } else {
                        format!(": {}", st.text)
                    },
                    self.why_here()
                ));
                self.stop_jobs(None);
                self.actions.push_back(Action::Alarm(cause.clone()));
                self.alarm = Some(cause);
            }
            let unconditional = st.branches.first().map(|(_, n)| *n).unwrap_or(StateNo::END);
            match st.command {
                Command::Nothing => {}
                Command::Output(text) => self.actions.push_back(Action::Output(text)),
                Command::Activate(b) => self.actions.push_back(Action::Activate(b)),
                Command::Reset(b) => self.actions.push_back(Action::Reset(b)),
                Command::Input(prompt) => {
                    self.actions.push_back(Action::Input(prompt));
                    self.phase = Phase::AwaitAnswer;
                    return;
                }
                Command::WaitInput {
                    signal,
                    level,
                    limit,
                } => {
                    self.actions.push_back(Action::Watch { signal, level });
                    self.phase = Phase::AwaitInput {
                        deadline: now + limit,
                    };
                    return;
                }
                Command::WaitReady { limit } => {
                    self.actions.push_back(Action::WatchReady);
                    self.phase = Phase::AwaitInput {
                        deadline: now + limit,
                    };
                    return;
                }
                Command::Start { target, job, limit } => {
                    self.jobs.insert(
                        target.clone(),
                        JobInfo {
                            state: JobState::Starting,
                            deadline: limit.map(|l| now + l),
                            paused_since: None,
                            started_in: Some((self.steps, next)),
                        },
                    );
                    self.actions.push_back(Action::Start {
                        target: target.clone(),
                        job,
                    });
                    let confirm = limit.map_or(self.confirm_limit, |l| l.min(self.confirm_limit));
                    self.phase = Phase::AwaitStart {
                        target,
                        deadline: now + confirm,
                    };
                    return;
                }
                Command::Wait { target, limit } => {
                    let Some(job) = self.jobs.get(&target).cloned() else {
                        let cause = Cause::process(format!(
                            "state {next} waits for {target}, which this recipe has not started"
                        ));
                        self.stop_jobs(None);
                        self.actions.push_back(Action::Alarm(cause.clone()));
                        self.end(Outcome::Alarm(cause));
                        return;
                    };
                    let deadline = limit.map(|l| now + l).or(job.deadline);
                    self.phase = Phase::AwaitJob {
                        target: target.clone(),
                        deadline,
                    };
                    if let JobState::Ended(end) = job.state {
                        // The job ended before this wait: its branch is
                        // taken at once, in this loop (a cycle of such
                        // waits is a runaway, not a stack overflow).
                        let branch = criterion_of(&end).and_then(|c| {
                            st.branches
                                .iter()
                                .find(|(b, _)| b.as_ref() == Some(&c))
                                .map(|(_, n)| *n)
                        });
                        if let Some(n) = branch {
                            self.failure = None;
                            next = n;
                            continue;
                        }
                        self.job_ended(now, &target, &end);
                    }
                    return;
                }
            }
            next = unconditional;
        }
        let cause = Cause::process(format!(
            "more than {MAX_IMMEDIATE_STEPS} states without waiting near state {next}"
        ));
        self.actions.push_back(Action::Alarm(cause.clone()));
        self.end(Outcome::Alarm(cause));
    }
}

/// The criterion a job's end takes (none for an alarm: it ends the recipe).
fn criterion_of(end: &JobEnd) -> Option<Criterion> {
    match end {
        JobEnd::Done => Some(Criterion::Done),
        JobEnd::BadProduct => Some(Criterion::BadProduct),
        JobEnd::FailedSafe => Some(Criterion::FailedSafe),
        JobEnd::FailedDanger => Some(Criterion::FailedDanger),
        JobEnd::Alarm(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::check;
    use crate::commands::RecipeKind;
    use crate::syntax::parse;
    use falc_model::alarm::AlarmClass;
    use falc_model::ids::Place;

    fn st(s: &str) -> StationName {
        StationName::new(s).expect("valid")
    }

    fn secs(n: u64) -> Duration {
        Duration::from_secs(n)
    }

    const CELL: &str = "\
-1 | start welding w 100 | | gestart | 2
-1 | start welding w 100 | | tijdlimiet | 9
-2 | start transport t | | gestart | 3
-2 | start transport t | | tijdlimiet | 9
-3 | wait transport 20 | | klaar | 4
-3 | wait transport 20 | | tijdlimiet | 9
-4 | wait welding | | klaar | 0
-4 | wait welding | | tijdlimiet | 9
-4 | wait welding | | bad_product | 8
-8 | output slechte las | | | 0
-9 | output er is wat mis | alarm | | 0
";

    fn engine(text: &str, kind: RecipeKind) -> Engine {
        let program = check(&parse(text, "t.rcp"), kind).expect("clean recipe");
        Engine::new(Arc::new(program))
    }

    fn drain(e: &mut Engine) -> Vec<Action> {
        std::iter::from_fn(|| e.poll_action()).collect()
    }

    fn entered(actions: &[Action]) -> Vec<u16> {
        actions
            .iter()
            .filter_map(|a| match a {
                Action::Entered(s) => Some(s.0),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn step_mode_waits_before_each_state_and_its_time_stands_still() {
        let mut e = engine(CELL, RecipeKind::Cell);
        e.set_stepping(secs(0), true);
        e.start(secs(0));
        assert_eq!(drain(&mut e), vec![Action::Held(StateNo(1))]);
        assert_eq!(e.held(), Some(StateNo(1)));
        assert_eq!(e.poll_timeout(), None, "no limit runs while a step waits");
        e.step(secs(5), None).expect("held");
        let a = drain(&mut e);
        assert_eq!(entered(&a), vec![1]);
        assert!(matches!(a[1], Action::Start { .. }), "{a:?}");
        e.handle(secs(6), Event::Started(st("welding")));
        assert_eq!(drain(&mut e), vec![Action::Held(StateNo(2))]);
        // Waiting 100 s before state 2 moves welding's limit (100 s from
        // t=5) on by those 100 s.
        e.step(secs(106), None).expect("held");
        drain(&mut e);
        e.handle(secs(106), Event::Started(st("transport")));
        e.step(secs(106), None).expect("held at 3");
        drain(&mut e);
        e.handle(secs(107), Event::Ended(st("transport"), JobEnd::Done));
        assert_eq!(drain(&mut e), vec![Action::Held(StateNo(4))]);
        e.step(secs(108), None).expect("held at 4");
        assert_eq!(
            e.poll_timeout(),
            Some(secs(206)),
            "5 + 100, moved on by the waits before 2 (100 s) and 4 (1 s)"
        );
        assert!(e
            .step(secs(108), None)
            .unwrap_err()
            .contains("being carried out"));
    }

    #[test]
    fn step_to_runs_on_until_the_chosen_state_and_off_releases_the_wait() {
        let mut e = engine(CELL, RecipeKind::Cell);
        e.set_stepping(secs(0), true);
        e.start(secs(0));
        assert!(e
            .step(secs(0), Some(StateNo(7)))
            .unwrap_err()
            .contains("state 7"));
        e.step(secs(0), Some(StateNo(3))).expect("held");
        e.handle(secs(1), Event::Started(st("welding")));
        e.handle(secs(2), Event::Started(st("transport")));
        let a = drain(&mut e);
        assert_eq!(entered(&a), vec![1, 2]);
        assert_eq!(a.last(), Some(&Action::Held(StateNo(3))));
        e.set_stepping(secs(3), false);
        assert_eq!(entered(&drain(&mut e)), vec![3]);
        e.handle(secs(4), Event::Ended(st("transport"), JobEnd::Done));
        assert_eq!(entered(&drain(&mut e)), vec![4], "no more waits");
    }

    #[test]
    fn a_resume_goes_on_at_the_stopped_state_and_presses_nothing_again() {
        let text = "#T\n\
-1 | activate A |  |  | 2\n\
-2 | waitplace 3 1 30 |  | klaar | 3\n\
-2 | waitplace 3 1 30 |  | tijdlimiet | 0\n\
-3 | reset A |  |  | 0\n";
        let mut e = engine(text, RecipeKind::Transport);
        e.start(secs(0));
        drain(&mut e);
        assert_eq!(e.state(), StateNo(2));
        e.abort(Cause::process("Stop by the commander"));
        assert_eq!(e.resume_point(), Some(StateNo(2)));
        assert_eq!(e.resume(secs(50)), Some(StateNo(2)));
        let a = drain(&mut e);
        assert!(
            !a.iter().any(|x| matches!(x, Action::Activate(_))),
            "line A runs on by itself; a second press would send another carrier: {a:?}"
        );
        assert_eq!(entered(&a), vec![2], "not state 1 again");
        assert_eq!(e.poll_timeout(), Some(secs(80)), "its limit anew");
        e.handle(secs(51), Event::InputReached);
        assert_eq!(e.outcome(), Some(&Outcome::Done));
        assert_eq!(e.resume(secs(52)), None, "only after an abort");
    }

    #[test]
    fn a_resume_goes_back_to_the_start_of_a_job_stopped_with_the_run() {
        let mut e = at_wait_welding();
        e.abort(Cause::process("Stop by the commander"));
        assert_eq!(drain(&mut e), vec![Action::Stop(st("welding"))]);
        assert_eq!(
            e.resume_point(),
            Some(StateNo(1)),
            "welding was started in state 1 and stopped with the run"
        );
        e.resume(secs(40));
        let a = drain(&mut e);
        assert_eq!(entered(&a), vec![1]);
        assert!(matches!(&a[1], Action::Start { target, .. } if *target == st("welding")));
    }

    #[test]
    fn a_run_starts_at_a_chosen_state_that_exists() {
        let mut e = engine(CELL, RecipeKind::Cell);
        assert!(e
            .start_at(secs(0), StateNo(5))
            .unwrap_err()
            .contains("state 5"));
        e.start_at(secs(0), StateNo(8)).expect("state 8 exists");
        assert_eq!(entered(&drain(&mut e)), vec![8]);
        assert_eq!(e.outcome(), Some(&Outcome::Done));
    }

    /// Runs the cell recipe to state 4 (waiting for welding) at t = 30 s.
    fn at_wait_welding() -> Engine {
        let mut e = engine(CELL, RecipeKind::Cell);
        e.start(secs(0));
        assert!(drain(&mut e).contains(&Action::Start {
            target: st("welding"),
            job: Job::Recipe(falc_model::ids::ObjectName::new("w").expect("valid"))
        }));
        e.handle(secs(1), Event::Started(st("welding")));
        e.handle(secs(2), Event::Started(st("transport")));
        assert_eq!(
            e.poll_timeout(),
            Some(secs(22)),
            "wait transport 20 from t=2"
        );
        e.handle(secs(30), Event::Ended(st("transport"), JobEnd::Done));
        assert_eq!(e.state(), StateNo(4));
        drain(&mut e);
        e
    }

    #[test]
    fn a_loop_of_waits_for_an_ended_job_is_a_runaway_not_a_stack_overflow() {
        // State 3 waits again for the job state 2 already waited for: its
        // old end takes `klaar` back to 3 at once, for ever. This used to
        // recurse until the stack overflowed (found by the verifier's
        // property test).
        let mut e = engine(
            "\
-1 | start transport t | | gestart | 2
-1 | start transport t | | tijdlimiet | 0
-2 | wait transport 10 | | klaar | 3
-2 | wait transport 10 | | tijdlimiet | 0
-3 | wait transport 10 | | klaar | 3
-3 | wait transport 10 | | tijdlimiet | 0
",
            RecipeKind::Cell,
        );
        e.start(secs(0));
        e.handle(secs(1), Event::Started(st("transport")));
        e.handle(secs(2), Event::Ended(st("transport"), JobEnd::Done));
        match e.outcome() {
            Some(Outcome::Alarm(c)) => assert!(
                c.text.contains("states without waiting near state 3"),
                "{c:?}"
            ),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn wait_uses_what_is_left_of_the_start_limit() {
        let mut e = at_wait_welding();
        assert_eq!(e.poll_timeout(), Some(secs(100)), "start at t=0 with 100 s");
        e.handle_timeout(secs(99));
        assert_eq!(e.state(), StateNo(4), "not yet");
        e.handle_timeout(secs(100));
        assert_eq!(
            e.outcome(),
            Some(&Outcome::Alarm(Cause::process(
                "alarm in state 9: output er is wat mis (welding did not finish within its time limit)"
            )))
        );
        assert!(
            drain(&mut e).contains(&Action::Stop(st("welding"))),
            "the alarm stops the timed-out weld"
        );
    }

    #[test]
    fn paused_freezes_the_time_limit() {
        let mut e = at_wait_welding();
        e.handle(secs(50), Event::Paused(st("welding")));
        assert_eq!(e.poll_timeout(), None, "no deadline runs while paused");
        e.handle_timeout(secs(120));
        assert_eq!(e.state(), StateNo(4));
        e.handle(secs(80), Event::Resumed(st("welding")));
        assert_eq!(e.poll_timeout(), Some(secs(130)), "30 s paused are added");
        e.handle(secs(125), Event::Ended(st("welding"), JobEnd::Done));
        assert_eq!(e.outcome(), Some(&Outcome::Done));
    }

    #[test]
    fn alarm_from_below_ends_at_once_and_stops_the_rest() {
        let mut e = engine(CELL, RecipeKind::Cell);
        e.start(secs(0));
        e.handle(secs(1), Event::Started(st("welding")));
        e.handle(secs(2), Event::Started(st("transport")));
        drain(&mut e);
        // While the recipe waits for transport, welding reports an alarm.
        e.handle(
            secs(5),
            Event::Ended(
                st("welding"),
                JobEnd::Alarm(Cause::new(AlarmClass::Safety, "emergency stop")),
            ),
        );
        let actions = drain(&mut e);
        assert_eq!(
            actions,
            vec![
                Action::Stop(st("transport")),
                Action::Alarm(Cause::new(
                    AlarmClass::Safety,
                    "alarm from welding: emergency stop"
                ))
            ]
        );
        assert_eq!(
            e.outcome(),
            Some(&Outcome::Alarm(Cause::new(
                AlarmClass::Safety,
                "alarm from welding: emergency stop"
            ))),
            "the class set where it was raised travels up"
        );
    }

    #[test]
    fn failure_criteria_and_unhandled_failures() {
        let mut e = at_wait_welding();
        e.handle(secs(40), Event::Ended(st("welding"), JobEnd::BadProduct));
        assert!(drain(&mut e).contains(&Action::Output("slechte las".into())));
        assert_eq!(e.outcome(), Some(&Outcome::Done));
        let mut e = at_wait_welding();
        e.handle(secs(40), Event::Ended(st("welding"), JobEnd::FailedDanger));
        assert_eq!(
            e.outcome(),
            Some(&Outcome::Failed(JobEnd::FailedDanger)),
            "passed up"
        );
    }

    #[test]
    fn a_job_that_ended_before_its_wait_is_done_at_once() {
        let mut e = engine(CELL, RecipeKind::Cell);
        e.start(secs(0));
        e.handle(secs(1), Event::Started(st("welding")));
        e.handle(secs(2), Event::Started(st("transport")));
        e.handle(secs(3), Event::Ended(st("welding"), JobEnd::Done));
        e.handle(secs(4), Event::Ended(st("transport"), JobEnd::Done));
        assert_eq!(e.outcome(), Some(&Outcome::Done));
    }

    #[test]
    fn refused_start_takes_the_failure_path_and_answers_match_case_insensitively() {
        let mut e = engine(CELL, RecipeKind::Cell);
        e.start(secs(0));
        e.handle(
            secs(0),
            Event::StartFailed(st("welding"), "no connection".into()),
        );
        assert!(matches!(e.outcome(), Some(Outcome::Alarm(_))));

        let mut e = engine("-1 | input go? | | answer=ja | 2\n-1 | input go? | | answer=* | 1\n-2 | output ok | | | 0\n", RecipeKind::Cell);
        e.start(secs(0));
        e.handle(secs(1), Event::Answer("misschien".into()));
        assert_eq!(e.state(), StateNo(1));
        e.handle(secs(2), Event::Answer("  JA ".into()));
        assert_eq!(e.outcome(), Some(&Outcome::Done));
    }

    #[test]
    fn transport_waits_watch_and_unwatch() {
        let mut e = engine("#T\n-1 | activate k | | | 2\n-2 | waitplace 3 1 40 | | klaar | 3\n-2 | waitplace 3 1 40 | | tijdlimiet | 4\n-3 | reset k | | | 0\n-4 | reset k | alarm | | 0\n", RecipeKind::Transport);
        e.start(secs(0));
        assert_eq!(
            drain(&mut e),
            vec![
                Action::Entered(StateNo(1)),
                Action::Activate(Button::Line('K')),
                Action::Entered(StateNo(2)),
                Action::Watch {
                    signal: Signal::Place(Place::of(3)),
                    level: true
                },
            ]
        );
        assert_eq!(e.poll_timeout(), Some(secs(40)));
        e.handle(secs(12), Event::InputReached);
        assert_eq!(
            drain(&mut e),
            vec![
                Action::Unwatch,
                Action::Entered(StateNo(3)),
                Action::Reset(Button::Line('K'))
            ]
        );
        assert_eq!(e.outcome(), Some(&Outcome::Done));
    }
}
