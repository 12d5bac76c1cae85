//! Verification across levels: a cell recipe explored together with the
//! workstation recipes it starts, every combination of what can happen
//! (each workstation recipe's outcomes as its own state table allows them,
//! every answer the operator can give, every time-out and refusal), in the
//! engine's own semantics ([`crate::engine`]). Sans-I/O: programs in, a
//! [`Report`] out.
//!
//! Each workstation recipe is explored first, with its device below (the
//! robot may end a program done, with a bad product, failed safe, failed
//! with danger or in alarm), giving the outcomes it can reach, each with a
//! witness trace. Then each cell recipe is explored with those outcomes as
//! the ends of its jobs. The explored state is the waiting state, what each
//! station's job is doing (running what, or over how), and whether an alarm
//! was given. It reports ([`FindingKind`]):
//!
//! - a `wait` for a station whose job is not running (never started, its
//!   start refused, already waited for, stopped by an alarm), and a `start`
//!   of a station whose job may still be running;
//! - an outcome a workstation recipe can reach that the cell recipe does
//!   not handle (passed up as a failure instead of taking a branch);
//! - time limits that disagree across levels: the cell giving up on a job
//!   before the job's own limits can end it, or waiting longer than they
//!   allow (its own limit then never fires first);
//! - no progress: states from which no combination reaches the end, and
//!   loops made of time-outs alone (nothing but the clock moves);
//! - states that no combination reaches;
//! - a workstation recipe's `#PRE` that cannot hold where the cell starts
//!   it: a term the `#POST` of a job done before on the same station
//!   contradicts (a station's facts are what its last job done left;
//!   anything else a job ends with, or a job stopped, leaves them
//!   unknown, and unknown is never a finding);
//! - as notes, jobs the cell runs one after the other on two stations
//!   whose conditions do not order them (both state `#PRE`/`#POST`, over
//!   different stations' facts): they could run in parallel, as far as
//!   their conditions say.
//!
//! Every finding carries a [`Trace`] the engine can follow ([`replay`]):
//! the cell's states, the events between them and, for a job's end, the
//! workstation's own trace to that end. Exploration stops at a state limit
//! with a clear message ([`Report::bounded`]).

use crate::check::{Command, Job, Program};
use crate::condition::Fact;
use crate::engine::{Action, Engine, Event as EngineEvent, JobEnd, Outcome, START_CONFIRM_LIMIT};
use crate::syntax::{Criterion, Report as RowReport, StateNo};
use falc_model::alarm::Cause;
use falc_model::ids::{ObjectName, RobotProgram, StationName};
use std::collections::{BTreeMap, BTreeSet, HashMap, VecDeque};
use std::fmt;
use std::sync::Arc;
use std::time::Duration;

/// The default limit of explored states per recipe.
pub const STATE_LIMIT: usize = 200_000;
/// More immediate transitions than this is a runaway (as in the engine).
const MAX_IMMEDIATE: usize = 10_000;
/// The answer that stands for "any other answer" in traces.
pub const OTHER_ANSWER: &str = "(any other answer)";

/// How a job below can end.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum End {
    /// Done.
    Done,
    /// Done, the product bad.
    BadProduct,
    /// Failed without danger.
    FailedSafe,
    /// Failed with danger.
    FailedDanger,
    /// In alarm.
    Alarm,
}

impl End {
    /// What a device (the robot controller) can end a program with.
    pub const DEVICE: [End; 5] = [
        End::Done,
        End::BadProduct,
        End::FailedSafe,
        End::FailedDanger,
        End::Alarm,
    ];

    /// The criterion this end takes (none for an alarm: it ends the recipe).
    pub fn criterion(self) -> Option<Criterion> {
        match self {
            End::Done => Some(Criterion::Done),
            End::BadProduct => Some(Criterion::BadProduct),
            End::FailedSafe => Some(Criterion::FailedSafe),
            End::FailedDanger => Some(Criterion::FailedDanger),
            End::Alarm => None,
        }
    }

    /// The engine's job end.
    pub fn job_end(self) -> JobEnd {
        match self {
            End::Done => JobEnd::Done,
            End::BadProduct => JobEnd::BadProduct,
            End::FailedSafe => JobEnd::FailedSafe,
            End::FailedDanger => JobEnd::FailedDanger,
            End::Alarm => JobEnd::Alarm(Cause::process("an alarm (verify)")),
        }
    }
}

impl fmt::Display for End {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            End::Done => "done",
            End::BadProduct => "bad_product",
            End::FailedSafe => "failed_safe",
            End::FailedDanger => "failed_danger",
            End::Alarm => "alarm",
        })
    }
}

/// How a recipe run ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Ending {
    /// State 0 without alarm.
    Done,
    /// In alarm.
    Alarm,
    /// A job's failure no state handled, passed up.
    Failed(End),
}

impl Ending {
    /// The end a level above sees.
    pub fn as_end(self) -> End {
        match self {
            Ending::Done => End::Done,
            Ending::Alarm => End::Alarm,
            Ending::Failed(e) => e,
        }
    }
}

impl fmt::Display for Ending {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Ending::Done => f.write_str("done"),
            Ending::Alarm => f.write_str("alarm"),
            Ending::Failed(e) => write!(f, "{e} (passed up)"),
        }
    }
}

/// What happens at a waiting state: one event of a trace.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Event {
    /// The start on the station was confirmed.
    Started(StationName),
    /// The start was refused.
    Refused(StationName),
    /// The station's job ended.
    Ended(StationName, End),
    /// The state's time limit passed.
    TimedOut,
    /// The operator answered.
    Answer(String),
    /// The watched input reached its level.
    InputReached,
}

impl fmt::Display for Event {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Event::Started(s) => write!(f, "{s} started"),
            Event::Refused(s) => write!(f, "{s} refused the start"),
            Event::Ended(s, e) => write!(f, "{s} ended {e}"),
            Event::TimedOut => f.write_str("time-out"),
            Event::Answer(a) => write!(f, "answer {a}"),
            Event::InputReached => f.write_str("input reached"),
        }
    }
}

/// One step of a trace: at waiting state `at`, `event` happened, and the
/// recipe entered the states `entered` (the last one waits, or the recipe
/// ended).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Step {
    /// The waiting state.
    pub at: StateNo,
    /// What happened.
    pub event: Event,
    /// The states entered after it.
    pub entered: Vec<StateNo>,
    /// For a job's end: the job's own trace to that end.
    pub below: Option<Box<Trace>>,
}

/// A run of one recipe: the states entered at its start, then each step.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Trace {
    /// The recipe's file.
    pub origin: String,
    /// The station whose recipe it is (`cell`, or the workstation).
    pub level: String,
    /// The states entered at the start.
    pub start: Vec<StateNo>,
    /// The steps.
    pub steps: Vec<Step>,
    /// How the run ended, if it did.
    pub ending: Option<Ending>,
}

impl Trace {
    /// The trace as lines, the levels below indented.
    pub fn lines(&self) -> Vec<String> {
        let mut out = Vec::new();
        self.write_lines("", &mut out);
        out
    }

    fn write_lines(&self, indent: &str, out: &mut Vec<String>) {
        out.push(format!(
            "{indent}{} {}: start → {}",
            self.level,
            self.origin,
            path_text(&self.start)
        ));
        for s in &self.steps {
            out.push(format!(
                "{indent}{} state {}: {} → {}",
                self.level,
                s.at,
                s.event,
                path_text(&s.entered)
            ));
            if let Some(b) = &s.below {
                b.write_lines(&format!("{indent}    "), out);
            }
        }
        if let Some(e) = self.ending {
            out.push(format!("{indent}{} ends {e}", self.level));
        }
    }
}

/// States entered one after the other, `9 → 10 → 11`; `0` for none (the
/// recipe ended).
pub fn path_text(v: &[StateNo]) -> String {
    if v.is_empty() {
        "0".into()
    } else {
        v.iter()
            .map(ToString::to_string)
            .collect::<Vec<_>>()
            .join(" → ")
    }
}

/// What kind of finding.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum FindingKind {
    /// A `wait` for a station whose job is not running.
    WaitNotRunning,
    /// A `start` of a station whose job may still be running.
    StartWhileRunning,
    /// A job's outcome the recipe does not handle.
    Unhandled,
    /// Time limits that disagree across levels.
    TimeLimit,
    /// No way to the end, or a loop of time-outs alone.
    NoProgress,
    /// A state no combination reaches.
    Unreached,
    /// The recipe ends while a job it started may still run.
    LeftRunning,
    /// A job's `#PRE` that what ran before on its station contradicts.
    Precondition,
    /// Two jobs run one after the other that their conditions do not
    /// order (a note).
    Parallel,
}

impl fmt::Display for FindingKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FindingKind::WaitNotRunning => "wait without a running job",
            FindingKind::StartWhileRunning => "start while running",
            FindingKind::Unhandled => "unhandled outcome",
            FindingKind::TimeLimit => "time limits disagree",
            FindingKind::NoProgress => "no progress",
            FindingKind::Unreached => "unreached",
            FindingKind::LeftRunning => "job left running",
            FindingKind::Precondition => "precondition cannot hold",
            FindingKind::Parallel => "could run in parallel",
        })
    }
}

/// How much a finding matters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Severity {
    /// The recipes can do something their writer cannot have meant: a
    /// wait that can only fail, a job cut short, a recipe that never ends.
    Defect,
    /// Worth knowing, and allowed: a status passed up as recipes/README.md
    /// documents, a limit that never fires first, a branch nothing takes.
    Note,
}

/// One finding, with a trace that leads to it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Finding {
    /// What kind.
    pub kind: FindingKind,
    /// How much it matters.
    pub severity: Severity,
    /// The recipe's file.
    pub origin: String,
    /// Its line.
    pub line: usize,
    /// The state.
    pub state: StateNo,
    /// What is wrong.
    pub message: String,
    /// How it is reached (empty steps for an unreached state).
    pub trace: Trace,
}

impl fmt::Display for Finding {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let note = match self.severity {
            Severity::Defect => "",
            Severity::Note => "note: ",
        };
        write!(
            f,
            "{}:{}: state {}: {note}{}: {}",
            self.origin, self.line, self.state, self.kind, self.message
        )
    }
}

/// The result of [`verify`].
#[derive(Debug, Clone, Default)]
pub struct Report {
    /// Every finding, cell recipes first.
    pub findings: Vec<Finding>,
    /// Explored states, all recipes together.
    pub states: usize,
    /// The outcomes each workstation recipe can reach: (station, name).
    pub outcomes: BTreeMap<(StationName, ObjectName), BTreeSet<Ending>>,
    /// Set when a recipe had more states than the limit: what was cut short.
    pub bounded: Vec<String>,
}

impl Report {
    /// The findings that are defects.
    pub fn defects(&self) -> impl Iterator<Item = &Finding> {
        self.findings
            .iter()
            .filter(|f| f.severity == Severity::Defect)
    }
}

/// Verifies a checked recipe set ([`crate::check::check_set`]'s programs)
/// with at most [`STATE_LIMIT`] explored states per recipe.
pub fn verify(programs: &[(StationName, Program)]) -> Report {
    verify_with_limit(programs, STATE_LIMIT)
}

/// [`verify`] with another state limit.
pub fn verify_with_limit(programs: &[(StationName, Program)], limit: usize) -> Report {
    let mut report = Report::default();
    // The workstation recipes first: their outcomes, with witnesses.
    let mut below: HashMap<(StationName, ObjectName), Vec<(End, Trace)>> = HashMap::new();
    let mut ws_findings = Vec::new();
    for (station, p) in programs.iter().filter(|(_, p)| p.kind.is_workstation()) {
        let Some(name) = p.name.clone() else { continue };
        let device = |_: &StationName, _: &Job| -> Vec<(End, Option<Trace>)> {
            End::DEVICE.iter().map(|e| (*e, None)).collect()
        };
        let run = explore(station, p, &device, &HashMap::new(), limit);
        let mut ends = Vec::new();
        for (ending, trace) in &run.endings {
            ends.push((ending.as_end(), trace.clone()));
        }
        report.outcomes.insert(
            (station.clone(), name.clone()),
            run.endings.keys().copied().collect(),
        );
        below.insert((station.clone(), name), ends);
        record(&mut report, run, &mut ws_findings);
    }
    let durations: HashMap<(StationName, ObjectName), Option<Duration>> = programs
        .iter()
        .filter_map(|(s, p)| Some(((s.clone(), p.name.clone()?), longest(p))))
        .collect();
    let workstation: HashMap<(StationName, ObjectName), &Program> = programs
        .iter()
        .filter(|(_, p)| p.kind.is_workstation())
        .filter_map(|(s, p)| Some(((s.clone(), p.name.clone()?), p)))
        .collect();
    let mut cell_findings = Vec::new();
    for (station, p) in programs.iter().filter(|(_, p)| !p.kind.is_workstation()) {
        let jobs = |target: &StationName, job: &Job| -> Vec<(End, Option<Trace>)> {
            match job {
                Job::Recipe(r) => below
                    .get(&(target.clone(), r.clone()))
                    .map(|v| v.iter().map(|(e, t)| (*e, Some(t.clone()))).collect())
                    .unwrap_or_default(),
                Job::Program(_) => End::DEVICE.iter().map(|e| (*e, None)).collect(),
            }
        };
        let mut run = explore(station, p, &jobs, &workstation, limit);
        run.findings.extend(time_limits(p, &run, &durations));
        record(&mut report, run, &mut cell_findings);
    }
    report.findings = cell_findings;
    report.findings.append(&mut ws_findings);
    report
}

fn record(report: &mut Report, run: Run, findings: &mut Vec<Finding>) {
    report.states += run.nodes;
    if let Some(b) = run.bounded {
        report.bounded.push(b);
    }
    findings.extend(run.findings);
}

/// What a station's job is doing.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
enum JobStatus {
    /// Started and confirmed, not waited for yet.
    Running {
        job: JobKey,
        limit: Option<Duration>,
    },
    /// Over: which job, how it ended, and why it is over.
    Over { job: JobKey, end: End, why: Over },
}

#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
enum JobKey {
    Recipe(ObjectName),
    Program(RobotProgram),
}

impl JobKey {
    fn of(job: &Job) -> Self {
        match job {
            Job::Recipe(r) => JobKey::Recipe(r.clone()),
            Job::Program(p) => JobKey::Program(*p),
        }
    }

    fn job(&self) -> Job {
        match self {
            JobKey::Recipe(r) => Job::Recipe(r.clone()),
            JobKey::Program(p) => Job::Program(*p),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
enum Over {
    Waited,
    Refused,
    Stopped,
}

impl fmt::Display for Over {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Over::Waited => "already waited for",
            Over::Refused => "its start was refused",
            Over::Stopped => "stopped by the alarm",
        })
    }
}

/// One explored state.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
enum Node {
    Waiting {
        at: StateNo,
        jobs: BTreeMap<StationName, JobStatus>,
        alarm: bool,
        facts: Facts,
    },
    Ended(Ending),
}

/// What is known of each station's facts: the level, and the job done
/// whose `#POST` says so with the cell state that waited for it.
type Facts = BTreeMap<(StationName, Fact), (bool, ObjectName, StateNo)>;

/// One recipe explored.
struct Run {
    nodes: usize,
    endings: BTreeMap<Ending, Trace>,
    findings: Vec<Finding>,
    bounded: Option<String>,
    /// (state waited in, job, how long the state allows) at each `wait`
    /// on a running recipe job, with the trace to it.
    waits: Vec<(StateNo, StationName, ObjectName, Duration, Trace)>,
}

type Below<'a> = dyn Fn(&StationName, &Job) -> Vec<(End, Option<Trace>)> + 'a;

struct Explorer<'a> {
    level: &'a StationName,
    program: &'a Program,
    below: &'a Below<'a>,
    /// The workstation recipes the cell starts, for their conditions.
    recipes: &'a HashMap<(StationName, ObjectName), &'a Program>,
    nodes: Vec<Node>,
    index: HashMap<Node, usize>,
    /// How each node was first reached: (parent, step), None for the start.
    parent: Vec<Option<(usize, Step)>>,
    start: Vec<StateNo>,
    edges: Vec<Vec<(usize, bool)>>,
    entered: BTreeSet<StateNo>,
    findings: Vec<Finding>,
    seen: BTreeSet<(FindingKind, StateNo, String)>,
}

/// A finding noticed while entering states: kind, state, message.
type Noticed = (FindingKind, StateNo, String);

fn explore(
    level: &StationName,
    program: &Program,
    below: &Below<'_>,
    recipes: &HashMap<(StationName, ObjectName), &Program>,
    limit: usize,
) -> Run {
    let mut x = Explorer {
        level,
        program,
        below,
        recipes,
        nodes: Vec::new(),
        index: HashMap::new(),
        parent: Vec::new(),
        start: Vec::new(),
        edges: Vec::new(),
        entered: BTreeSet::new(),
        findings: Vec::new(),
        seen: BTreeSet::new(),
    };
    let mut start = Vec::new();
    let mut noticed = Vec::new();
    let first = x.enter(
        BTreeMap::new(),
        false,
        Facts::new(),
        program.first,
        &mut start,
        &mut noticed,
    );
    x.start = start;
    let root = x.add(first, None);
    for (kind, state, message) in noticed {
        let trace = x.trace(root);
        x.find(kind, state, message, trace);
    }
    let mut queue = VecDeque::from([root]);
    let mut waits = Vec::new();
    let mut bounded = None;
    let mut unhandled: BTreeMap<StateNo, (String, Vec<End>, Trace)> = BTreeMap::new();
    // Jobs on two stations one after the other (the earlier done and
    // waited for when the later starts), with the first start seen, and
    // those seen running side by side.
    let mut one_after: BTreeMap<(JobOn, JobOn), (StateNo, usize)> = BTreeMap::new();
    let mut side_by_side: BTreeSet<(JobOn, JobOn)> = BTreeSet::new();
    while let Some(n) = queue.pop_front() {
        if x.nodes.len() > limit {
            bounded = Some(format!(
                "{}: exploration stopped at {limit} states; the findings cover only what was explored (raise the limit, or split the recipe)",
                program.origin
            ));
            break;
        }
        let Node::Waiting {
            at,
            jobs,
            alarm,
            facts,
        } = x.nodes[n].clone()
        else {
            continue;
        };
        if let Some(later) = x.started_at(at) {
            for (station, j) in &jobs {
                match j {
                    JobStatus::Running { job, .. } if *station != later.0 => {
                        side_by_side.insert(((station.clone(), job.clone()), later.clone()));
                    }
                    JobStatus::Over {
                        job,
                        end: End::Done,
                        why: Over::Waited,
                    } if *station != later.0 => {
                        one_after
                            .entry(((station.clone(), job.clone()), later.clone()))
                            .or_insert((at, n));
                    }
                    _ => {}
                }
            }
        }
        for (event, below_trace, next_jobs, criterion, noticed, wait) in
            x.successors(at, &jobs, &facts)
        {
            let mut entered = Vec::new();
            let mut more = noticed;
            let next_facts = x.facts_after(at, &event, &jobs, &next_jobs, &facts);
            let node = match criterion {
                Next::Criterion(c) => x.take(
                    at,
                    &c,
                    (next_jobs, next_facts),
                    alarm,
                    &mut entered,
                    &mut more,
                ),
                Next::Ended(ending) => Node::Ended(ending),
            };
            let timeout = event == Event::TimedOut;
            let step = Step {
                at,
                event,
                entered,
                below: below_trace.map(Box::new),
            };
            let known = x.index.get(&node).copied();
            let m = match known {
                Some(m) => m,
                None => {
                    let m = x.add(node, Some((n, step.clone())));
                    queue.push_back(m);
                    m
                }
            };
            x.edges[n].push((m, timeout));
            if !more.is_empty() || wait.is_some() {
                let mut trace = x.trace(n);
                trace.steps.push(step);
                if let Node::Ended(e) = x.nodes[m] {
                    trace.ending = Some(e);
                }
                for (kind, state, message) in more {
                    match (&kind, &trace.steps.last().map(|s| &s.event)) {
                        (FindingKind::Unhandled, Some(Event::Ended(_, end))) => {
                            let entry = unhandled
                                .entry(state)
                                .or_insert_with(|| (message, Vec::new(), trace.clone()));
                            if !entry.1.contains(end) {
                                entry.1.push(*end);
                            }
                        }
                        _ => x.find(kind, state, message, trace.clone()),
                    }
                }
                if let Some((target, recipe, allowed)) = wait {
                    let mut upto = x.trace(n);
                    upto.ending = None;
                    waits.push((at, target, recipe, allowed, upto));
                }
            }
        }
    }
    for (state, (who, ends, trace)) in unhandled {
        let ends: Vec<String> = ends.iter().map(ToString::to_string).collect();
        let ends = match ends.split_last() {
            Some((last, [])) => last.clone(),
            Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
            None => continue,
        };
        x.findings.push(Finding {
            kind: FindingKind::Unhandled,
            severity: Severity::Note,
            origin: program.origin.clone(),
            line: x.line_of(state),
            state,
            message: format!(
                "{who} can end {ends}, which this state does not handle: passed up, so the recipe (and the order) ends failed with it (recipes/README.md: handle it where you can do better)"
            ),
            trace,
        });
    }
    for ((earlier, later), (state, n)) in one_after {
        if side_by_side.contains(&(earlier.clone(), later.clone())) {
            continue;
        }
        if !(x.states_conditions(&earlier) && x.states_conditions(&later)) {
            continue;
        }
        let trace = x.trace(n);
        x.findings.push(Finding {
            kind: FindingKind::Parallel,
            severity: Severity::Note,
            origin: program.origin.clone(),
            line: x.line_of(state),
            state,
            message: format!(
                "{} could start before {} ends: their #PRE and #POST are over different \
                 stations' facts, so they do not order them (a need neither states, such as a \
                 part on the table, still may)",
                job_on(&later),
                job_on(&earlier)
            ),
            trace,
        });
    }
    if bounded.is_none() {
        x.no_progress();
        x.unreached();
    }
    let mut endings = BTreeMap::new();
    for i in 0..x.nodes.len() {
        if let Node::Ended(e) = x.nodes[i] {
            endings.entry(e).or_insert_with(|| x.trace(i));
        }
    }
    Run {
        nodes: x.nodes.len(),
        endings,
        findings: x.findings,
        bounded,
        waits: dedup_waits(waits),
    }
}

fn dedup_waits(
    waits: Vec<(StateNo, StationName, ObjectName, Duration, Trace)>,
) -> Vec<(StateNo, StationName, ObjectName, Duration, Trace)> {
    let mut seen = BTreeSet::new();
    waits
        .into_iter()
        .filter(|(s, t, r, d, _)| seen.insert((*s, t.clone(), r.clone(), *d)))
        .collect()
}

/// Where an event leads: a criterion to branch on, or straight to an end.
enum Next {
    Criterion(Criterion),
    Ended(Ending),
}

/// One successor: the event, the job's trace below (for an end), the jobs
/// after it, where it leads, what was noticed, and for a wait on a recipe
/// job (station, recipe, the time the state allows it).
type Successor = (
    Event,
    Option<Trace>,
    BTreeMap<StationName, JobStatus>,
    Next,
    Vec<Noticed>,
    Option<(StationName, ObjectName, Duration)>,
);

/// A workstation recipe on its station, as the cell starts it.
type JobOn = (StationName, JobKey);

fn job_on((station, job): &JobOn) -> String {
    format!("{station}'s {}", key_name(job))
}

impl Explorer<'_> {
    /// The job the state `at` starts, if it starts one.
    fn started_at(&self, at: StateNo) -> Option<JobOn> {
        match &self.program.states.get(&at)?.command {
            Command::Start { target, job, .. } => Some((target.clone(), JobKey::of(job))),
            _ => None,
        }
    }

    /// Whether a workstation recipe the cell starts states a `#PRE` or a
    /// `#POST`.
    fn states_conditions(&self, (station, job): &JobOn) -> bool {
        let JobKey::Recipe(name) = job else {
            return false;
        };
        self.recipes
            .get(&(station.clone(), name.clone()))
            .is_some_and(|p| p.pre.is_some() || p.post.is_some())
    }

    /// The terms of the `#PRE` of `job` on `target` that the facts known
    /// at its start contradict, as a finding.
    fn contradicted(
        &self,
        at: StateNo,
        target: &StationName,
        job: &Job,
        facts: &Facts,
    ) -> Option<Noticed> {
        let Job::Recipe(name) = job else {
            return None;
        };
        let p = self.recipes.get(&(target.clone(), name.clone()))?;
        let pre = p.pre.as_ref()?;
        let why: Vec<String> = pre
            .terms
            .iter()
            .filter_map(|t| {
                let (level, by, when) = facts.get(&(target.clone(), t.fact))?;
                (*level != t.level).then(|| {
                    let left = crate::condition::Condition {
                        fact: t.fact,
                        level: *level,
                    };
                    format!("`{t}`, but {by}, done in state {when}, leaves {left}")
                })
            })
            .collect();
        (!why.is_empty()).then(|| {
            (
                FindingKind::Precondition,
                at,
                format!(
                    "the precondition of {target}'s {name} ({}:{}) cannot hold: {}",
                    p.origin,
                    pre.line,
                    why.join("; ")
                ),
            )
        })
    }

    /// The facts after `event` at waiting state `at`: a station whose job
    /// ended (or was stopped) has what its `#POST` says if it ended done,
    /// else nothing known.
    fn facts_after(
        &self,
        at: StateNo,
        event: &Event,
        before: &BTreeMap<StationName, JobStatus>,
        after: &BTreeMap<StationName, JobStatus>,
        facts: &Facts,
    ) -> Facts {
        let mut out = facts.clone();
        for (station, was) in before {
            let JobStatus::Running { job, .. } = was else {
                continue;
            };
            if after.get(station) == Some(was) {
                continue;
            }
            out.retain(|(s, _), _| s != station);
            let (Event::Ended(s, End::Done), JobKey::Recipe(name)) = (event, job) else {
                continue;
            };
            if s != station {
                continue;
            }
            let post = self
                .recipes
                .get(&(station.clone(), name.clone()))
                .and_then(|p| p.post.as_ref());
            for t in post.iter().flat_map(|c| &c.terms) {
                out.insert((station.clone(), t.fact), (t.level, name.clone(), at));
            }
        }
        out
    }

    fn add(&mut self, node: Node, parent: Option<(usize, Step)>) -> usize {
        let i = self.nodes.len();
        self.index.insert(node.clone(), i);
        self.nodes.push(node);
        self.parent.push(parent);
        self.edges.push(Vec::new());
        i
    }

    fn line_of(&self, state: StateNo) -> usize {
        self.program.states.get(&state).map_or(1, |s| s.line)
    }

    fn find(&mut self, kind: FindingKind, state: StateNo, message: String, trace: Trace) {
        let severity = match kind {
            FindingKind::Unreached => Severity::Note,
            _ => Severity::Defect,
        };
        if self.seen.insert((kind, state, message.clone())) {
            self.findings.push(Finding {
                kind,
                severity,
                origin: self.program.origin.clone(),
                line: self.line_of(state),
                state,
                message,
                trace,
            });
        }
    }

    /// The trace to node `n` (the shortest: nodes are found breadth first).
    fn trace(&self, n: usize) -> Trace {
        let mut steps = Vec::new();
        let mut i = n;
        while let Some((p, step)) = &self.parent[i] {
            steps.push(step.clone());
            i = *p;
        }
        steps.reverse();
        Trace {
            origin: self.program.origin.clone(),
            level: self.level.to_string(),
            start: self.start.clone(),
            steps,
            ending: match self.nodes[n] {
                Node::Ended(e) => Some(e),
                Node::Waiting { .. } => None,
            },
        }
    }

    /// What can happen in waiting state `at`.
    fn successors(
        &self,
        at: StateNo,
        jobs: &BTreeMap<StationName, JobStatus>,
        facts: &Facts,
    ) -> Vec<Successor> {
        let Some(st) = self.program.states.get(&at) else {
            return Vec::new();
        };
        let mut out: Vec<Successor> = Vec::new();
        match &st.command {
            Command::Input(_) => {
                for (c, _) in &st.branches {
                    let answer = match c {
                        Some(Criterion::Answer(a)) => a.clone(),
                        Some(Criterion::AnswerAny) => OTHER_ANSWER.to_string(),
                        _ => continue,
                    };
                    let c = c.clone().unwrap_or(Criterion::AnswerAny);
                    out.push((
                        Event::Answer(answer),
                        None,
                        jobs.clone(),
                        Next::Criterion(c),
                        Vec::new(),
                        None,
                    ));
                }
            }
            Command::WaitInput { .. } | Command::WaitReady { .. } => {
                out.push((
                    Event::InputReached,
                    None,
                    jobs.clone(),
                    Next::Criterion(Criterion::Done),
                    Vec::new(),
                    None,
                ));
                out.push((
                    Event::TimedOut,
                    None,
                    jobs.clone(),
                    Next::Criterion(Criterion::Timeout),
                    Vec::new(),
                    None,
                ));
            }
            Command::Start { target, job, limit } => {
                let mut noticed = Vec::new();
                if let Some(JobStatus::Running { job: running, .. }) = jobs.get(target) {
                    noticed.push((
                        FindingKind::StartWhileRunning,
                        at,
                        format!(
                            "starts {target} while its job {} may still be running (started, not waited for)",
                            key_name(running)
                        ),
                    ));
                }
                let contradicted = self.contradicted(at, target, job, facts);
                let mut started = jobs.clone();
                started.insert(
                    target.clone(),
                    JobStatus::Running {
                        job: JobKey::of(job),
                        limit: *limit,
                    },
                );
                out.push((
                    Event::Started(target.clone()),
                    None,
                    started,
                    Next::Criterion(Criterion::Started),
                    noticed.iter().cloned().chain(contradicted).collect(),
                    None,
                ));
                let mut refused = jobs.clone();
                refused.insert(
                    target.clone(),
                    JobStatus::Over {
                        job: JobKey::of(job),
                        end: End::FailedSafe,
                        why: Over::Refused,
                    },
                );
                out.push((
                    Event::Refused(target.clone()),
                    None,
                    refused,
                    Next::Criterion(Criterion::Timeout),
                    noticed,
                    None,
                ));
            }
            Command::Wait { target, limit } => {
                let Some(JobStatus::Running { job, limit: start }) = jobs.get(target) else {
                    return out; // resolved on entering (see `enter`)
                };
                let wait = match (job, limit.or(*start)) {
                    (JobKey::Recipe(r), Some(allowed)) => {
                        Some((target.clone(), r.clone(), allowed))
                    }
                    _ => None,
                };
                for (end, trace) in (self.below)(target, &job.job()) {
                    let mut after = jobs.clone();
                    let mut noticed = Vec::new();
                    let next = match end.criterion() {
                        None => {
                            // An alarm below ends the recipe; the engine
                            // stops every other job.
                            Next::Ended(Ending::Alarm)
                        }
                        Some(c) => {
                            after.insert(
                                target.clone(),
                                JobStatus::Over {
                                    job: job.clone(),
                                    end,
                                    why: Over::Waited,
                                },
                            );
                            if st.branches.iter().any(|(b, _)| b.as_ref() == Some(&c)) {
                                Next::Criterion(c)
                            } else {
                                if matches!(job, JobKey::Recipe(_)) {
                                    // Joined per state in `explore`.
                                    noticed.push((
                                        FindingKind::Unhandled,
                                        at,
                                        format!("{target}'s {}", key_name(job)),
                                    ));
                                }
                                Next::Ended(Ending::Failed(end))
                            }
                        }
                    };
                    out.push((
                        Event::Ended(target.clone(), end),
                        trace,
                        after,
                        next,
                        noticed,
                        wait.clone(),
                    ));
                }
                if limit.or(*start).is_some() {
                    out.push((
                        Event::TimedOut,
                        None,
                        jobs.clone(),
                        Next::Criterion(Criterion::Timeout),
                        Vec::new(),
                        wait,
                    ));
                }
            }
            Command::Nothing | Command::Output(_) | Command::Activate(_) | Command::Reset(_) => {}
        }
        out
    }

    /// Takes the branch `c` of waiting state `at` (a missing one is the
    /// engine's alarm).
    fn take(
        &mut self,
        at: StateNo,
        c: &Criterion,
        (jobs, facts): (BTreeMap<StationName, JobStatus>, Facts),
        alarm: bool,
        entered: &mut Vec<StateNo>,
        noticed: &mut Vec<Noticed>,
    ) -> Node {
        let next = self
            .program
            .states
            .get(&at)
            .and_then(|s| s.branches.iter().find(|(b, _)| b.as_ref() == Some(c)))
            .map(|(_, n)| *n);
        match next {
            Some(n) => self.enter(jobs, alarm, facts, n, entered, noticed),
            None => Node::Ended(Ending::Alarm),
        }
    }

    /// Enters `next` and every state that does not wait, as the engine
    /// does; resolves a `wait` whose job is not running at once.
    fn enter(
        &mut self,
        mut jobs: BTreeMap<StationName, JobStatus>,
        mut alarm: bool,
        mut facts: Facts,
        mut next: StateNo,
        entered: &mut Vec<StateNo>,
        noticed: &mut Vec<Noticed>,
    ) -> Node {
        for _ in 0..MAX_IMMEDIATE {
            if next == StateNo::END {
                if let Some((station, job)) = jobs.iter().find_map(|(s, j)| match j {
                    JobStatus::Running { job, .. } => Some((s, job)),
                    JobStatus::Over { .. } => None,
                }) {
                    let last = entered.last().copied().unwrap_or(self.program.first);
                    noticed.push((
                        FindingKind::LeftRunning,
                        last,
                        format!(
                            "the recipe ends while {station}'s job {} may still be running (started, never waited for)",
                            key_name(job)
                        ),
                    ));
                }
                return Node::Ended(if alarm { Ending::Alarm } else { Ending::Done });
            }
            let Some(st) = self.program.states.get(&next) else {
                return Node::Ended(Ending::Alarm);
            };
            self.entered.insert(next);
            entered.push(next);
            if st.report == Some(RowReport::Alarm) {
                alarm = true;
                for (station, j) in jobs.iter_mut() {
                    if let JobStatus::Running { job, .. } = j {
                        // Stopped part way: what it leaves is unknown.
                        facts.retain(|(s, _), _| s != station);
                        *j = JobStatus::Over {
                            job: job.clone(),
                            end: End::FailedSafe,
                            why: Over::Stopped,
                        };
                    }
                }
            }
            let unconditional = st.branches.first().map_or(StateNo::END, |(_, n)| *n);
            match &st.command {
                Command::Nothing
                | Command::Output(_)
                | Command::Activate(_)
                | Command::Reset(_) => next = unconditional,
                Command::Input(_)
                | Command::WaitInput { .. }
                | Command::WaitReady { .. }
                | Command::Start { .. } => {
                    return Node::Waiting {
                        at: next,
                        jobs,
                        alarm,
                        facts,
                    }
                }
                Command::Wait { target, .. } => match jobs.get(target).cloned() {
                    None => {
                        noticed.push((
                            FindingKind::WaitNotRunning,
                            next,
                            format!("waits for {target}, whose job was never started here"),
                        ));
                        return Node::Ended(Ending::Alarm);
                    }
                    Some(JobStatus::Over { end, why, .. }) => {
                        noticed.push((
                            FindingKind::WaitNotRunning,
                            next,
                            format!(
                                "waits for {target}, whose job is not running ({why}): the wait gets its old end, {end}, at once"
                            ),
                        ));
                        let Some(c) = end.criterion() else {
                            return Node::Ended(Ending::Alarm);
                        };
                        match st.branches.iter().find(|(b, _)| b.as_ref() == Some(&c)) {
                            Some((_, n)) => next = *n,
                            None => return Node::Ended(Ending::Failed(end)),
                        }
                    }
                    Some(JobStatus::Running { .. }) => {
                        return Node::Waiting {
                            at: next,
                            jobs,
                            alarm,
                            facts,
                        }
                    }
                },
            }
        }
        Node::Ended(Ending::Alarm)
    }

    /// Waiting states from which no combination reaches an end, and loops
    /// of time-outs alone.
    fn no_progress(&mut self) {
        let n = self.nodes.len();
        let mut reverse: Vec<Vec<usize>> = vec![Vec::new(); n];
        for (from, edges) in self.edges.iter().enumerate() {
            for (to, _) in edges {
                reverse[*to].push(from);
            }
        }
        let mut ends: Vec<bool> = self
            .nodes
            .iter()
            .map(|node| matches!(node, Node::Ended(_)))
            .collect();
        let mut queue: VecDeque<usize> = (0..n).filter(|i| ends[*i]).collect();
        while let Some(i) = queue.pop_front() {
            for p in &reverse[i] {
                if !ends[*p] {
                    ends[*p] = true;
                    queue.push_back(*p);
                }
            }
        }
        let stuck: Vec<(usize, StateNo)> = ends
            .iter()
            .enumerate()
            .filter(|(_, reaches)| !**reaches)
            .filter_map(|(i, _)| match self.nodes[i] {
                Node::Waiting { at, .. } => Some((i, at)),
                Node::Ended(_) => None,
            })
            .collect();
        for (i, at) in stuck {
            let trace = self.trace(i);
            self.find(
                FindingKind::NoProgress,
                at,
                "no combination of outcomes, answers and time-outs leads from here to the end"
                    .into(),
                trace,
            );
        }
        // Loops of time-outs alone: peel nodes without an incoming or an
        // outgoing time-out edge (within what is left) until none; what
        // remains lies on such a loop.
        let mut alive = vec![true; n];
        loop {
            let mut incoming = vec![0usize; n];
            let mut outgoing = vec![0usize; n];
            for (from, edges) in self.edges.iter().enumerate() {
                if !alive[from] {
                    continue;
                }
                for (to, timeout) in edges {
                    if *timeout && alive[*to] {
                        outgoing[from] += 1;
                        incoming[*to] += 1;
                    }
                }
            }
            let mut changed = false;
            for i in 0..n {
                if alive[i] && (incoming[i] == 0 || outgoing[i] == 0) {
                    alive[i] = false;
                    changed = true;
                }
            }
            if !changed {
                break;
            }
        }
        let looping: BTreeSet<StateNo> = (0..n)
            .filter(|i| alive[*i])
            .filter_map(|i| match self.nodes[i] {
                Node::Waiting { at, .. } => Some(at),
                Node::Ended(_) => None,
            })
            .collect();
        if let Some(first) = (0..n).find(|i| alive[*i]) {
            if let Node::Waiting { at, .. } = self.nodes[first] {
                let names: Vec<String> = looping.iter().map(ToString::to_string).collect();
                let trace = self.trace(first);
                self.find(
                    FindingKind::NoProgress,
                    at,
                    format!(
                        "states {} loop on time-outs alone: if nothing below ever answers, the recipe never ends and never alarms",
                        names.join(", ")
                    ),
                    trace,
                );
            }
        }
    }

    /// States no combination enters.
    fn unreached(&mut self) {
        let missing: Vec<StateNo> = self
            .program
            .states
            .keys()
            .filter(|s| !self.entered.contains(s))
            .copied()
            .collect();
        for s in missing {
            let trace = Trace {
                origin: self.program.origin.clone(),
                level: self.level.to_string(),
                start: self.start.clone(),
                steps: Vec::new(),
                ending: None,
            };
            self.find(
                FindingKind::Unreached,
                s,
                "no combination of outcomes, answers and time-outs reaches this state (its branch waits for what the level below never gives)".into(),
                trace,
            );
        }
    }
}

fn key_name(job: &JobKey) -> String {
    match job {
        JobKey::Recipe(r) => r.to_string(),
        JobKey::Program(n) => format!("program {n}"),
    }
}

/// The longest a recipe can run by its own limits, each `start` counted
/// with its limit (or the start confirm limit), each `wait` and `waitline`
/// with its own; None when a loop makes it unbounded.
pub fn longest(p: &Program) -> Option<Duration> {
    fn weight(c: &Command) -> Duration {
        match c {
            Command::Start { limit, .. } => limit.unwrap_or(START_CONFIRM_LIMIT),
            Command::Wait { limit, .. } => limit.unwrap_or(Duration::ZERO),
            Command::WaitInput { limit, .. } | Command::WaitReady { limit } => *limit,
            _ => Duration::ZERO,
        }
    }
    fn go(
        p: &Program,
        s: StateNo,
        memo: &mut HashMap<StateNo, Option<Duration>>,
        stack: &mut BTreeSet<StateNo>,
    ) -> Option<Duration> {
        if s == StateNo::END {
            return Some(Duration::ZERO);
        }
        if let Some(d) = memo.get(&s) {
            return *d;
        }
        let st = p.states.get(&s)?;
        if !stack.insert(s) {
            return None;
        }
        let mut best = Some(Duration::ZERO);
        let targets: BTreeSet<StateNo> = st.branches.iter().map(|(_, n)| *n).collect();
        for n in targets {
            best = match (best, go(p, n, memo, stack)) {
                (Some(a), Some(b)) => Some(a.max(b)),
                _ => None,
            };
        }
        stack.remove(&s);
        // A start whose job the same state's time-out abandons is covered
        // by the start's own limit; a wait without a limit by the start's.
        let d = best.map(|b| b + weight(&st.command));
        memo.insert(s, d);
        d
    }
    go(p, p.first, &mut HashMap::new(), &mut BTreeSet::new())
}

/// Each `wait` on a recipe job against that recipe's own limits.
fn time_limits(
    p: &Program,
    run: &Run,
    durations: &HashMap<(StationName, ObjectName), Option<Duration>>,
) -> Vec<Finding> {
    let mut out = Vec::new();
    for (state, target, recipe, allowed, trace) in &run.waits {
        let Some(Some(own)) = durations.get(&(target.clone(), recipe.clone())) else {
            continue;
        };
        let line = p.states.get(state).map_or(1, |s| s.line);
        let (severity, message) = if allowed < own {
            (Severity::Defect, format!(
                "allows {target}'s {recipe} {} s, but its own limits allow it {} s: the cell may give up on a job that is still within its limits",
                allowed.as_secs(),
                own.as_secs()
            ))
        } else if allowed > own {
            (Severity::Note, format!(
                "allows {target}'s {recipe} {} s, but its own limits end it within {} s: this limit never fires first",
                allowed.as_secs(),
                own.as_secs()
            ))
        } else {
            continue;
        };
        out.push(Finding {
            kind: FindingKind::TimeLimit,
            severity,
            origin: p.origin.clone(),
            line,
            state: *state,
            message,
            trace: trace.clone(),
        });
    }
    out
}

/// Follows `trace` with the real engine on a fake clock: the states it
/// enters, step by step, and its ending must be the trace's; each job's
/// trace below is followed with that recipe's program (`program_of`).
/// `Err` says where the engine went elsewhere.
pub fn replay(
    program: Arc<Program>,
    trace: &Trace,
    program_of: &dyn Fn(&StationName, &ObjectName) -> Option<Arc<Program>>,
) -> Result<(), String> {
    let mut e = Engine::new(program.clone());
    let mut now = Duration::ZERO;
    // The job each station runs, from the `start` states the trace passed.
    let mut started: HashMap<StationName, Job> = HashMap::new();
    e.start(now);
    let entered = drain(&mut e);
    if entered != trace.start {
        return Err(format!(
            "{}: the start entered {entered:?}, the trace {:?}",
            trace.origin, trace.start
        ));
    }
    for (i, step) in trace.steps.iter().enumerate() {
        if e.state() != step.at || e.outcome().is_some() {
            return Err(format!(
                "{}: step {i}: the engine is in state {} ({:?}), the trace at {}",
                trace.origin,
                e.state(),
                e.outcome(),
                step.at
            ));
        }
        match &step.event {
            Event::Started(t) => {
                if let Some(Command::Start { job, .. }) =
                    program.states.get(&step.at).map(|s| &s.command)
                {
                    started.insert(t.clone(), job.clone());
                }
                e.handle(now, EngineEvent::Started(t.clone()));
            }
            Event::Refused(t) => e.handle(
                now,
                EngineEvent::StartFailed(t.clone(), "refused (verify)".into()),
            ),
            Event::Ended(t, end) => {
                if let Some(below) = &step.below {
                    let Some(Job::Recipe(r)) = started.get(t).cloned() else {
                        return Err(format!("{}: step {i}: no recipe job on {t}", trace.origin));
                    };
                    let Some(p) = program_of(t, &r) else {
                        return Err(format!("{}: step {i}: no program {r} on {t}", trace.origin));
                    };
                    replay(p, below, program_of)?;
                    if below.ending.map(Ending::as_end) != Some(*end) {
                        return Err(format!(
                            "{}: step {i}: the trace below ends {:?}, the step says {end}",
                            trace.origin, below.ending
                        ));
                    }
                }
                e.handle(now, EngineEvent::Ended(t.clone(), end.job_end()));
            }
            Event::TimedOut => {
                let Some(d) = e.poll_timeout() else {
                    return Err(format!(
                        "{}: step {i}: a time-out in state {} where no deadline runs",
                        trace.origin, step.at
                    ));
                };
                now = now.max(d);
                e.handle_timeout(now);
            }
            Event::Answer(a) => e.handle(now, EngineEvent::Answer(a.clone())),
            Event::InputReached => e.handle(now, EngineEvent::InputReached),
        }
        let entered = drain(&mut e);
        if entered != step.entered {
            return Err(format!(
                "{}: step {i} ({}): the engine entered {entered:?}, the trace {:?}",
                trace.origin, step.event, step.entered
            ));
        }
    }
    if let Some(want) = trace.ending {
        let got = match e.outcome() {
            Some(Outcome::Done) => Some(Ending::Done),
            Some(Outcome::Alarm(_)) => Some(Ending::Alarm),
            Some(Outcome::Failed(end)) => Some(Ending::Failed(match end {
                JobEnd::Done => End::Done,
                JobEnd::BadProduct => End::BadProduct,
                JobEnd::FailedSafe => End::FailedSafe,
                JobEnd::FailedDanger => End::FailedDanger,
                JobEnd::Alarm(_) => End::Alarm,
            })),
            None => None,
        };
        if got != Some(want) {
            return Err(format!(
                "{}: the engine ended {got:?}, the trace {want}",
                trace.origin
            ));
        }
    }
    Ok(())
}

fn drain(e: &mut Engine) -> Vec<StateNo> {
    let mut v = Vec::new();
    while let Some(a) = e.poll_action() {
        if let Action::Entered(s) = a {
            v.push(s);
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::check;
    use crate::commands::RecipeKind;
    use crate::syntax::parse;

    const DROOG_DIK: &str = include_str!("../../../recipes/welding/droog_dik.rcp");
    const STORE: &str = include_str!("../../../recipes/transport/store.rcp");
    const UNLOAD: &str = include_str!("../../../recipes/transport/unload.rcp");

    fn st(s: &str) -> StationName {
        StationName::new(s).expect("station")
    }

    /// The shipped DROOG_DIK, STORE and UNLOAD, and `cell` as the cell
    /// recipe.
    fn set(cell: &str) -> Vec<(StationName, Program)> {
        let mut v = Vec::new();
        for (station, kind, origin, text) in [
            ("welding", RecipeKind::Welding, "droog_dik.rcp", DROOG_DIK),
            ("transport", RecipeKind::Transport, "store.rcp", STORE),
            ("transport", RecipeKind::Transport, "unload.rcp", UNLOAD),
            ("cell", RecipeKind::Cell, "cell.rcp", cell),
        ] {
            let p = check(&parse(text, origin), kind).unwrap_or_else(|e| panic!("{origin}: {e:?}"));
            v.push((st(station), p));
        }
        v
    }

    fn program_of(
        programs: &[(StationName, Program)],
    ) -> impl Fn(&StationName, &ObjectName) -> Option<Arc<Program>> + '_ {
        move |s, n| {
            programs
                .iter()
                .find(|(ps, p)| ps == s && p.name.as_ref() == Some(n))
                .map(|(_, p)| Arc::new(p.clone()))
        }
    }

    /// Verifies, checks every trace replays in the engine, returns the
    /// findings of the cell recipe.
    fn findings(cell: &str) -> Vec<Finding> {
        let programs = set(cell);
        let report = verify(&programs);
        let cell_program = Arc::new(programs[3].1.clone());
        for f in &report.findings {
            let p = if f.origin == "cell.rcp" {
                cell_program.clone()
            } else {
                let Some((_, p)) = programs.iter().find(|(_, p)| p.origin == f.origin) else {
                    panic!("no program {}", f.origin)
                };
                Arc::new(p.clone())
            };
            if let Err(e) = replay(p, &f.trace, &program_of(&programs)) {
                panic!(
                    "{f}: the engine cannot follow its trace: {e}\n{:#?}",
                    f.trace
                );
            }
        }
        report
            .findings
            .into_iter()
            .filter(|f| f.origin == "cell.rcp")
            .collect()
    }

    /// The findings' kinds, states and severities, but for the notes of
    /// jobs that could run in parallel (STORE and DROOG_DIK, one after
    /// the other in most of these recipes: the tests below check those).
    fn kinds(f: &[Finding]) -> Vec<(FindingKind, u16, Severity)> {
        f.iter()
            .filter(|f| f.kind != FindingKind::Parallel)
            .map(|f| (f.kind, f.state.0, f.severity))
            .collect()
    }

    /// A start whose `#PRE` the `#POST` of the job done before on the
    /// same station contradicts: STORE twice (its POST leaves place 3
    /// occupied, its PRE needs it empty) is a defect, with the trace to
    /// the second start; a first STORE that did not end done leaves the
    /// place unknown, which is no finding.
    #[test]
    fn a_precondition_an_earlier_postcondition_contradicts_is_a_defect() {
        let twice = "\
-1 | start transport store | | gestart    | 2
-1 | start transport store | | tijdlimiet | 9
-2 | wait transport 40     | | klaar      | 3
-2 | wait transport 40     | | tijdlimiet | 9
-3 | start transport store | | gestart    | 4
-3 | start transport store | | tijdlimiet | 9
-4 | wait transport 40     | | klaar      | 0
-4 | wait transport 40     | | tijdlimiet | 9
-9 | output er is wat mis  | alarm |      | 0
";
        let f = findings(twice);
        let pre: Vec<&Finding> = f
            .iter()
            .filter(|f| f.kind == FindingKind::Precondition)
            .collect();
        assert_eq!(pre.len(), 1, "{f:#?}");
        assert_eq!(
            (pre[0].state, pre[0].severity),
            (StateNo(3), Severity::Defect)
        );
        assert_eq!(
            pre[0].message,
            "the precondition of transport's STORE (store.rcp:2) cannot hold: `place 3 empty`, \
             but STORE, done in state 2, leaves place 3 occupied"
        );
        let lines = pre[0].trace.lines();
        assert_eq!(
            lines.last().map(String::as_str),
            Some("cell state 3: transport started → 4"),
            "{lines:#?}"
        );
        assert!(lines
            .iter()
            .any(|l| l == "cell state 2: transport ended done → 3"));
        // A first STORE that timed out (not done) leaves place 3 unknown:
        // only the path where it ended done is a finding.
        let after_a_failure = twice.replace(
            "-2 | wait transport 40     | | tijdlimiet | 9",
            "-2 | wait transport 40     | | tijdlimiet | 3",
        );
        let pre_after: Vec<_> = findings(&after_a_failure)
            .into_iter()
            .filter(|f| f.kind == FindingKind::Precondition)
            .collect();
        assert_eq!(pre_after.len(), 1, "{pre_after:#?}");
        assert!(pre_after[0]
            .trace
            .lines()
            .iter()
            .any(|l| l.contains("ended done → 3")));
    }

    /// Jobs the cell runs one after the other on two stations, both with
    /// conditions over their own station's facts, are notes (could run in
    /// parallel); the same jobs run side by side are not.
    #[test]
    fn jobs_one_after_the_other_no_condition_orders_are_notes() {
        let f = findings(GOOD);
        let parallel: Vec<String> = f
            .iter()
            .filter(|f| f.kind == FindingKind::Parallel)
            .map(|f| format!("{} {:?}: {}", f.state, f.severity, f.message))
            .collect();
        assert_eq!(
            parallel,
            [
                "3 Note: welding's DROOG_DIK could start before transport's STORE ends: their \
              #PRE and #POST are over different stations' facts, so they do not order them (a \
              need neither states, such as a part on the table, still may)"
            ]
        );
        // Started side by side (the weld first, then STORE): no note.
        let side_by_side = "\
-1 | start welding droog_dik 180 | | gestart    | 2
-1 | start welding droog_dik 180 | | tijdlimiet | 9
-2 | start transport store       | | gestart    | 3
-2 | start transport store       | | tijdlimiet | 9
-3 | wait transport 40           | | klaar      | 4
-3 | wait transport 40           | | tijdlimiet | 9
-4 | wait welding                | | klaar      | 0
-4 | wait welding                | | bad_product | 9
-4 | wait welding                | | failed_safe | 9
-4 | wait welding                | | failed_danger | 9
-4 | wait welding                | | tijdlimiet | 9
-9 | output er is wat mis        | alarm |      | 0
";
        let f = findings(side_by_side);
        assert!(!f.iter().any(|f| f.kind == FindingKind::Parallel), "{f:#?}");
    }

    const GOOD: &str = "\
-1 | start transport store       | | gestart    | 2
-1 | start transport store       | | tijdlimiet | 9
-2 | wait transport 40           | | klaar      | 3
-2 | wait transport 40           | | tijdlimiet | 9
-3 | start welding droog_dik 180 | | gestart    | 4
-3 | start welding droog_dik 180 | | tijdlimiet | 9
-4 | wait welding                | | klaar      | 5
-4 | wait welding                | | bad_product | 9
-4 | wait welding                | | failed_safe | 9
-4 | wait welding                | | failed_danger | 9
-4 | wait welding                | | tijdlimiet | 9
-5 | output klaar                | |            | 0
-9 | output er is wat mis        | alarm |      | 0
";

    #[test]
    fn a_sound_set_has_no_findings() {
        assert_eq!(kinds(&findings(GOOD)), []);
        let report = verify(&set(GOOD));
        let outcomes =
            &report.outcomes[&(st("welding"), ObjectName::new("DROOG_DIK").expect("name"))];
        assert_eq!(
            outcomes.iter().copied().collect::<Vec<_>>(),
            [
                Ending::Done,
                Ending::Alarm,
                Ending::Failed(End::BadProduct),
                Ending::Failed(End::FailedSafe),
                Ending::Failed(End::FailedDanger)
            ]
        );
        assert!(report.states > 10, "{}", report.states);
    }

    #[test]
    fn a_wait_before_its_start() {
        // Done with the transport, the cell goes to the weld's wait and
        // skips its start (reached only when the transport times out).
        let cell = GOOD
            .replace(
                "-2 | wait transport 40           | | klaar      | 3",
                "-2 | wait transport 40           | | klaar      | 4",
            )
            .replace(
                "-2 | wait transport 40           | | tijdlimiet | 9",
                "-2 | wait transport 40           | | tijdlimiet | 3",
            );
        let f = findings(&cell);
        // And after the transport's time-out its job is never waited for.
        assert_eq!(
            kinds(&f),
            [
                (FindingKind::WaitNotRunning, 4, Severity::Defect),
                (FindingKind::LeftRunning, 5, Severity::Defect)
            ],
            "{f:#?}"
        );
        assert!(f[0].message.contains("never started"), "{}", f[0]);
        assert_eq!(f[0].trace.ending, Some(Ending::Alarm));
        assert_eq!(
            f[0].trace.steps.last().map(|s| &s.event),
            Some(&Event::Ended(st("transport"), End::Done))
        );
    }

    #[test]
    fn a_wait_for_a_job_already_waited_for() {
        let cell = GOOD.replace(
            "-5 | output klaar                | |            | 0",
            "-5 | wait transport 40           | | klaar      | 0\n-5 | wait transport 40 | | tijdlimiet | 9",
        );
        let f = findings(&cell);
        assert_eq!(
            kinds(&f),
            [(FindingKind::WaitNotRunning, 5, Severity::Defect)],
            "{f:#?}"
        );
        assert!(f[0].message.contains("already waited for"), "{}", f[0]);
    }

    #[test]
    fn an_unhandled_bad_product_is_reported_with_its_trace_below() {
        let cell = GOOD.replace("-4 | wait welding                | | bad_product | 9\n", "");
        let f = findings(&cell);
        assert_eq!(
            kinds(&f),
            [(FindingKind::Unhandled, 4, Severity::Note)],
            "{f:#?}"
        );
        assert!(
            f[0].message.contains("DROOG_DIK can end bad_product"),
            "{}",
            f[0]
        );
        let last = f[0].trace.steps.last().expect("a step");
        assert_eq!(last.event, Event::Ended(st("welding"), End::BadProduct));
        let below = last.below.as_ref().expect("the welding recipe's trace");
        assert_eq!(below.ending, Some(Ending::Failed(End::BadProduct)));
        assert_eq!(f[0].trace.ending, Some(Ending::Failed(End::BadProduct)));
        // Drawn: the welding recipe's box, its start node joined to the
        // cell's step it explains.
        let dot = crate::dot::trace_to_dot(&f[0].trace, &f[0].to_string());
        let start_below = dot
            .lines()
            .skip_while(|l| !l.contains("subgraph cluster_1"))
            .find(|l| l.contains("[label=\"start → 1\"]"))
            .and_then(|l| l.trim().split(' ').next())
            .expect("the welding recipe's start node");
        assert!(
            dot.lines()
                .any(|l| l.trim().starts_with(&format!("{start_below} -> "))
                    && l.contains("explains")),
            "{dot}"
        );
    }

    #[test]
    fn a_cell_limit_shorter_than_the_job_s_own() {
        let cell = GOOD
            .replace("start welding droog_dik 180", "start welding droog_dik    ")
            .replace(
                "-4 | wait welding                |",
                "-4 | wait welding 100            |",
            );
        let mut f = findings(&cell);
        f.retain(|f| f.kind != FindingKind::Parallel);
        assert_eq!(
            kinds(&f),
            [(FindingKind::TimeLimit, 4, Severity::Defect)],
            "{f:#?}"
        );
        assert!(
            f[0].message
                .contains("allows welding's DROOG_DIK 100 s, but its own limits allow it 180 s"),
            "{}",
            f[0]
        );
        // Longer is a note.
        let cell = GOOD.replace("-2 | wait transport 40 ", "-2 | wait transport 60 ");
        assert_eq!(
            kinds(&findings(&cell)),
            [(FindingKind::TimeLimit, 2, Severity::Note)]
        );
    }

    #[test]
    fn a_mutual_wait_on_time_outs_is_no_progress() {
        // Each wait times out into the other: if neither job ends, nothing
        // ever does.
        let cell = GOOD
            .replace(
                "-2 | wait transport 40           | | tijdlimiet | 9",
                "-2 | wait transport 40           | | tijdlimiet | 4",
            )
            .replace(
                "-1 | start transport store       | | gestart    | 2",
                "-1 | start transport store       | | gestart    | 3",
            )
            .replace(
                "-3 | start welding droog_dik 180 | | gestart    | 4",
                "-3 | start welding droog_dik 180 | | gestart    | 2",
            )
            .replace(
                "-4 | wait welding                | | tijdlimiet | 9",
                "-4 | wait welding                | | tijdlimiet | 2",
            );
        let f = findings(&cell);
        let no_progress: Vec<&Finding> = f
            .iter()
            .filter(|f| f.kind == FindingKind::NoProgress)
            .collect();
        assert_eq!(no_progress.len(), 1, "{f:#?}");
        assert!(
            no_progress[0]
                .message
                .contains("states 2, 4 loop on time-outs alone"),
            "{}",
            no_progress[0]
        );
        assert_eq!(no_progress[0].severity, Severity::Defect);
    }

    #[test]
    fn a_start_while_the_job_runs_and_a_job_left_running() {
        let cell = GOOD.replace(
            "-2 | wait transport 40           | | klaar      | 3",
            "-2 | start transport unload      | | gestart    | 3\n-2 | start transport unload | | tijdlimiet | 9",
        )
        .replace("-2 | wait transport 40           | | tijdlimiet | 9\n", "");
        let f = findings(&cell);
        assert!(
            kinds(&f).contains(&(FindingKind::StartWhileRunning, 2, Severity::Defect)),
            "{f:#?}"
        );
        assert!(
            kinds(&f).contains(&(FindingKind::LeftRunning, 5, Severity::Defect)),
            "{f:#?}"
        );
    }

    #[test]
    fn a_branch_no_job_takes_leaves_its_state_unreached() {
        // STORE never ends with bad_product.
        let cell = GOOD.replace(
            "-2 | wait transport 40           | | tijdlimiet | 9",
            "-2 | wait transport 40           | | tijdlimiet | 9\n-2 | wait transport 40 | | bad_product | 8\n-8 | output nooit | | | 0",
        );
        assert_eq!(
            kinds(&findings(&cell)),
            [(FindingKind::Unreached, 8, Severity::Note)]
        );
    }

    #[test]
    fn exploration_stops_at_the_limit_and_says_so() {
        let report = verify_with_limit(&set(GOOD), 3);
        assert!(!report.bounded.is_empty());
        assert!(
            report.bounded[0].contains("exploration stopped at 3 states"),
            "{:?}",
            report.bounded
        );
    }

    #[test]
    fn the_longest_run_by_a_recipe_s_own_limits() {
        let dik = check(&parse(DROOG_DIK, "d"), RecipeKind::Welding).expect("clean");
        assert_eq!(longest(&dik), Some(Duration::from_secs(180)));
        let looping = check(
            &parse("#LOOP\n-1 | waitline a 1 10 | | klaar | 0\n-1 | waitline a 1 10 | | tijdlimiet | 1\n", "l"),
            RecipeKind::Transport,
        )
        .expect("clean");
        assert_eq!(longest(&looping), None);
    }
}

#[cfg(test)]
mod prop {
    //! The verifier never reports a trace the engine cannot follow: random
    //! cell recipes against the shipped workstation recipes, every finding's
    //! trace replayed through the real engine on a fake clock.
    use super::*;
    use crate::check::check;
    use crate::commands::RecipeKind;
    use crate::syntax::parse;
    use proptest::prelude::*;

    const BELOW: [(&str, RecipeKind, &str, &str); 8] = [
        (
            "welding",
            RecipeKind::Welding,
            "droog_dik.rcp",
            include_str!("../../../recipes/welding/droog_dik.rcp"),
        ),
        (
            "welding",
            RecipeKind::Welding,
            "droog_dun.rcp",
            include_str!("../../../recipes/welding/droog_dun.rcp"),
        ),
        (
            "welding",
            RecipeKind::Welding,
            "droog_pijp.rcp",
            include_str!("../../../recipes/welding/droog_pijp.rcp"),
        ),
        (
            "transport",
            RecipeKind::Transport,
            "store.rcp",
            include_str!("../../../recipes/transport/store.rcp"),
        ),
        (
            "transport",
            RecipeKind::Transport,
            "unstore.rcp",
            include_str!("../../../recipes/transport/unstore.rcp"),
        ),
        (
            "transport",
            RecipeKind::Transport,
            "unload.rcp",
            include_str!("../../../recipes/transport/unload.rcp"),
        ),
        (
            "transport",
            RecipeKind::Transport,
            "move_to_man.rcp",
            include_str!("../../../recipes/transport/move_to_man.rcp"),
        ),
        (
            "transport",
            RecipeKind::Transport,
            "unload_and_load.rcp",
            include_str!("../../../recipes/transport/unload_and_load.rcp"),
        ),
    ];
    const WELDS: [&str; 3] = ["droog_dik", "droog_dun", "droog_pijp"];
    const MOVES: [&str; 5] = [
        "store",
        "unstore",
        "unload",
        "move_to_man",
        "unload_and_load",
    ];

    /// One state: its kind and the choices its lines need.
    fn state() -> impl Strategy<Value = (u8, usize, [usize; 3], u64, bool)> {
        (
            0u8..6,
            0usize..5,
            [0usize..16, 0usize..16, 0usize..16],
            0u64..4,
            any::<bool>(),
        )
    }

    /// A cell recipe of `states`: state i's main line goes on to i+1 (the
    /// last to 0), so every state is reachable; its other lines go
    /// anywhere.
    fn cell_text(states: &[(u8, usize, [usize; 3], u64, bool)]) -> String {
        let n = states.len();
        let to = |k: usize| if k > n { 0 } else { k };
        let mut out = String::new();
        for (i, (kind, pick, other, limit, extra)) in states.iter().enumerate() {
            let s = i + 1;
            let main = if s == n { 0 } else { s + 1 };
            let [a, b, c] = other.map(to);
            let secs = [30, 60, 100, 200][*limit as usize];
            let lines: Vec<String> = match kind {
                0 => vec![format!(
                    "-{s} | output stap {s} | {} | | {main}",
                    if *extra { "alarm" } else { "" }
                )],
                1 => vec![
                    format!("-{s} | input (ja/nee) | | answer=ja | {main}"),
                    format!("-{s} | input (ja/nee) | | answer=nee | {a}"),
                    format!("-{s} | input (ja/nee) | | answer=* | {b}"),
                ],
                2 => {
                    let w = WELDS[pick % 3];
                    vec![
                        format!("-{s} | start welding {w} {secs} | | gestart | {main}"),
                        format!("-{s} | start welding {w} {secs} | | tijdlimiet | {a}"),
                    ]
                }
                3 => {
                    let m = MOVES[*pick];
                    vec![
                        format!("-{s} | start transport {m} | | gestart | {main}"),
                        format!("-{s} | start transport {m} | | tijdlimiet | {a}"),
                    ]
                }
                4 => {
                    let mut v = vec![
                        format!("-{s} | wait transport {secs} | | klaar | {main}"),
                        format!("-{s} | wait transport {secs} | | tijdlimiet | {a}"),
                    ];
                    if *extra {
                        v.push(format!(
                            "-{s} | wait transport {secs} | | bad_product | {b}"
                        ));
                    }
                    v
                }
                _ => {
                    let limit = if *extra {
                        format!(" {secs}")
                    } else {
                        String::new()
                    };
                    vec![
                        format!("-{s} | wait welding{limit} | | klaar | {main}"),
                        format!("-{s} | wait welding{limit} | | tijdlimiet | {a}"),
                        format!("-{s} | wait welding{limit} | | bad_product | {b}"),
                        format!("-{s} | wait welding{limit} | | failed_safe | {c}"),
                    ]
                }
            };
            for l in lines {
                out.push_str(&l);
                out.push('\n');
            }
        }
        out
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]
        #[test]
        fn every_reported_trace_replays_in_the_engine(
            states in proptest::collection::vec(state(), 2..14)
        ) {
            let text = cell_text(&states);
            let cell = check(&parse(&text, "cell.rcp"), RecipeKind::Cell);
            // Only recipes the checker passes are verified.
            prop_assume!(cell.is_ok());
            let Ok(cell) = cell else { return Ok(()) };
            let mut programs: Vec<(StationName, Program)> = BELOW
                .iter()
                .map(|(s, kind, origin, text)| {
                    let p = check(&parse(text, origin), *kind).map_err(|e| format!("{e:?}"));
                    (StationName::new(s).map_err(|e| e.to_string()), p)
                })
                .filter_map(|(s, p)| Some((s.ok()?, p.ok()?)))
                .collect();
            prop_assert_eq!(programs.len(), BELOW.len());
            programs.push((StationName::new("cell").map_err(|e| TestCaseError::fail(e.to_string()))?, cell));
            let report = verify(&programs);
            let program_of = |s: &StationName, n: &ObjectName| {
                programs
                    .iter()
                    .find(|(ps, p)| ps == s && p.name.as_ref() == Some(n))
                    .map(|(_, p)| Arc::new(p.clone()))
            };
            for f in &report.findings {
                let Some((_, p)) = programs.iter().find(|(_, p)| p.origin == f.origin) else {
                    return Err(TestCaseError::fail(format!("no program {}", f.origin)));
                };
                if let Err(e) = replay(Arc::new(p.clone()), &f.trace, &program_of) {
                    return Err(TestCaseError::fail(format!("{f}\n{e}\n{text}")));
                }
            }
        }
    }
}
