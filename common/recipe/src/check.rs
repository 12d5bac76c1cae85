//! The checker: a parsed [`Recipe`] of a given [`RecipeKind`] becomes a
//! [`Program`] the engine can run, or the list of every defect found.
//!
//! Per recipe: malformed lines, unknown commands, bad arguments, missing or
//! wrong criteria, inconsistent states (different commands or reports in one
//! state), duplicate criteria, missing branches (`start` without `started`
//! and `timeout`, `wait` without `done` and `timeout`, `input` without
//! `answer=*`), a `wait` with no time limit anywhere, unknown next states,
//! unreachable states, states with no path to 0, loops that never wait, a
//! workstation recipe without `#NAME`. Across a set of recipes
//! ([`check_set`]): a cell recipe starting a workstation recipe that no
//! workstation defines, and two workstation recipes with one name.

use super::commands::{lookup, Arg, CommandSpec, Criteria, Handler, RecipeKind};
use super::condition::{parse_terms, Condition, Conditions, Fact};
use super::problem::{Problem, ProblemKind};
use super::syntax::{CommandText, Criterion, Recipe, Report, Row, StateNo};
use falc_model::ids::{excerpt, IoName, ObjectName, Place, PlcStation, RobotProgram, StationName};
use falc_model::mode::ManualAction;
use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;

/// A PLC output a recipe writes: a conveyor line's or a station's
/// button, or a plain output of the equipment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Button {
    /// Line A–Z but I and O (upper case).
    Line(char),
    /// Station 1–99.
    Station(PlcStation),
    /// A plain output (`set beacon 1`).
    Output(IoName),
}

/// A PLC input to wait for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Signal {
    /// Line A–Z (but I and O) running.
    Line(char),
    /// Place 1–99 occupied.
    Place(Place),
    /// Station 1–99 busy.
    Station(PlcStation),
    /// A plain input on (`waitinput door_closed 1 30`).
    Input(IoName),
}

/// What a `start` starts.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Job {
    /// A workstation recipe by name (cell).
    Recipe(ObjectName),
    /// A robot program number (welding).
    Program(RobotProgram),
}

/// A checked command.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    /// No command (a state with only a report).
    Nothing,
    /// Start a job one level down.
    Start {
        /// The station (cell) or `rcm` (welding).
        target: StationName,
        /// What to start.
        job: Job,
        /// The whole job's time limit, if given on `start`.
        limit: Option<Duration>,
    },
    /// Wait for a job one level down.
    Wait {
        /// The station or `rcm`.
        target: StationName,
        /// The limit; None uses what is left of the `start` limit.
        limit: Option<Duration>,
    },
    /// Show text.
    Output(String),
    /// Ask the operator.
    Input(String),
    /// Press a button.
    Activate(Button),
    /// Release a button.
    Reset(Button),
    /// Wait for an input level.
    WaitInput {
        /// The input.
        signal: Signal,
        /// The level waited for.
        level: bool,
        /// The limit.
        limit: Duration,
    },
    /// Wait until the robot takes DNC commands: automatic-external mode,
    /// the DNC link answering (the thesis' start-up check).
    WaitReady {
        /// The limit.
        limit: Duration,
    },
}

impl Command {
    /// Whether the state waits (else it moves on at once).
    pub fn waits(&self) -> bool {
        matches!(
            self,
            Self::Start { .. }
                | Self::Wait { .. }
                | Self::Input(_)
                | Self::WaitInput { .. }
                | Self::WaitReady { .. }
        )
    }
}

/// One checked state.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct State {
    /// Its number.
    pub no: StateNo,
    /// Its first line.
    pub line: usize,
    /// Its command.
    pub command: Command,
    /// The command as written (for diagrams and logs).
    pub text: String,
    /// Its report.
    pub report: Option<Report>,
    /// Its branches: criterion (None = unconditional) → next state.
    pub branches: Vec<(Option<Criterion>, StateNo)>,
}

/// A recipe that passed the checker.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Program {
    /// Its controller kind.
    pub kind: RecipeKind,
    /// Its `#NAME` (workstation recipes).
    pub name: Option<ObjectName>,
    /// Where it came from.
    pub origin: String,
    /// The first state (of the first table line).
    pub first: StateNo,
    /// Every state.
    pub states: BTreeMap<StateNo, State>,
    /// What its station must observe for a Start to be taken (`#PRE`).
    pub pre: Option<Conditions>,
    /// What its station must observe when the job ended, for it to be
    /// done (`#POST`).
    pub post: Option<Conditions>,
}

impl Program {
    /// The workstation recipe a run from `state` starts first, when it
    /// gets there without waiting (through states that only show text or
    /// press buttons): the station and the recipe. None when it waits,
    /// asks or ends first.
    pub fn job_started_from(&self, state: StateNo) -> Option<(&StationName, &ObjectName)> {
        let mut at = state;
        for _ in 0..=self.states.len() {
            let st = self.states.get(&at)?;
            match &st.command {
                Command::Start {
                    target,
                    job: Job::Recipe(name),
                    ..
                } => return Some((target, name)),
                Command::Nothing
                | Command::Output(_)
                | Command::Activate(_)
                | Command::Reset(_) => {
                    at = st.branches.first()?.1;
                }
                _ => return None,
            }
        }
        None
    }
}

struct Ctx<'a> {
    origin: &'a str,
    problems: Vec<Problem>,
}

impl Ctx<'_> {
    fn add(&mut self, line: usize, state: Option<StateNo>, kind: ProblemKind, message: String) {
        self.problems.push(Problem {
            origin: self.origin.to_string(),
            line,
            state,
            kind,
            message,
        });
    }
}

fn seconds(s: &str) -> Result<Duration, String> {
    match s.parse::<u32>() {
        Ok(n) if (1..=86_400).contains(&n) => Ok(Duration::from_secs(n.into())),
        _ => Err(format!(
            "`{}` is not a time limit in seconds (1–86400)",
            excerpt(s)
        )),
    }
}

/// A conveyor line's name as recipes write it: one letter A–Z (any case;
/// I and O are left out, they read like 1 and 0). Which lines a conveyor
/// has is its equipment file's (the 1992 one's: A–H, J–L).
pub fn line_letter(s: &str) -> Result<char, String> {
    let mut it = s.chars();
    match (it.next().map(|c| c.to_ascii_uppercase()), it.next()) {
        (Some(c @ 'A'..='Z'), None) if c != 'I' && c != 'O' => Ok(c),
        _ => Err(format!(
            "`{}` is not a conveyor line (a letter A–Z but I and O)",
            excerpt(s)
        )),
    }
}

/// Checks the texts of a manual operation as a recipe's arguments are
/// checked: a button is a line (a letter) or a station (a number), a line a line,
/// a recipe a valid name, a state a word. The refusal quotes an excerpt, never the whole
/// text, so a maintainer's typo (or a 60 KB argument) is refused in a line.
pub fn check_manual(action: &ManualAction) -> Result<(), String> {
    match action {
        ManualAction::Press(b) | ManualAction::Release(b) => b.parse::<Button>().map(|_| ()),
        ManualAction::RunLine { line, .. } => line_letter(line).map(|_| ()),
        ManualAction::RunRecipe(name) => {
            ObjectName::new(name).map(|_| ()).map_err(|e| e.to_string())
        }
        ManualAction::Goto(state) => {
            let word = !state.is_empty()
                && state.len() <= 32
                && state.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
            if word {
                Ok(())
            } else {
                Err(format!(
                    "`{}` is not a state name (a word like `home`)",
                    excerpt(state)
                ))
            }
        }
        ManualAction::SelectProgram(_)
        | ManualAction::StartProgram
        | ManualAction::StopProgram
        | ManualAction::ConfirmAlarm => Ok(()),
    }
}

impl std::str::FromStr for Button {
    type Err = String;
    /// A line (a letter), a station (a number) or a plain output (a
    /// longer word), as a recipe (or a maintainer) writes it.
    fn from_str(s: &str) -> Result<Self, String> {
        if s.parse::<u8>().is_ok() {
            return Ok(Button::Station(PlcStation::parse(s)?));
        }
        if s.chars().count() > 1 {
            if let Ok(n) = IoName::parse(s) {
                return Ok(Button::Output(n));
            }
        }
        Ok(Button::Line(line_letter(s)?))
    }
}

impl std::fmt::Display for Button {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Line(l) => write!(f, "line button {l}"),
            Self::Station(s) => write!(f, "station button {s}"),
            Self::Output(n) => write!(f, "output {n}"),
        }
    }
}

/// A level as a recipe (or a twin's control) writes it: 1 or 0.
pub fn level(s: &str) -> Result<bool, String> {
    match s {
        "1" => Ok(true),
        "0" => Ok(false),
        other => Err(format!("`{}` is not a level (1 or 0)", excerpt(other))),
    }
}

/// Validates the arguments of a command against its spec.
fn build_command(spec: &CommandSpec, c: &CommandText) -> Result<Command, String> {
    let fixed = spec
        .args
        .iter()
        .filter(|a| !matches!(a, Arg::OptSeconds | Arg::Text))
        .count();
    let optional = spec.args.iter().any(|a| matches!(a, Arg::OptSeconds));
    let text_arg = spec.args.contains(&Arg::Text);
    if !text_arg && (c.args.len() < fixed || c.args.len() > fixed + usize::from(optional)) {
        return Err(format!(
            "`{}` takes {} argument(s): {}",
            spec.name, fixed, spec.usage
        ));
    }
    let a = |i: usize| c.args.get(i).map(String::as_str).unwrap_or("");
    let opt = |i: usize| c.args.get(i).map(|s| seconds(s)).transpose();
    let target = |s: &str| StationName::new(s).map_err(|e| e.to_string());
    Ok(match spec.handler {
        Handler::Output => Command::Output(c.text.clone()),
        Handler::Input => Command::Input(c.text.clone()),
        Handler::Start => match spec.args[0] {
            Arg::Rcm => {
                if !a(0).eq_ignore_ascii_case("rcm") {
                    return Err(format!(
                        "`start` on a welding station starts `rcm`, not `{}`",
                        a(0)
                    ));
                }
                let program = RobotProgram::parse(a(1))?;
                Command::Start {
                    target: target("rcm")?,
                    job: Job::Program(program),
                    limit: opt(2)?,
                }
            }
            _ => Command::Start {
                target: target(a(0))?,
                job: Job::Recipe(ObjectName::new(a(1)).map_err(|e| e.to_string())?),
                limit: opt(2)?,
            },
        },
        Handler::Wait => {
            if spec.args[0] == Arg::Rcm && !a(0).eq_ignore_ascii_case("rcm") {
                return Err(format!(
                    "`wait` on a welding station waits for `rcm`, not `{}`",
                    a(0)
                ));
            }
            Command::Wait {
                target: target(a(0))?,
                limit: opt(1)?,
            }
        }
        Handler::Activate | Handler::Reset => {
            let b: Button = a(0).parse()?;
            if spec.handler == Handler::Activate {
                Command::Activate(b)
            } else {
                Command::Reset(b)
            }
        }
        Handler::Set => {
            let b = Button::Output(IoName::parse(a(0))?);
            if level(a(1))? {
                Command::Activate(b)
            } else {
                Command::Reset(b)
            }
        }
        Handler::WaitInput => {
            let signal = match spec.args[0] {
                Arg::Line => Signal::Line(line_letter(a(0))?),
                Arg::Place => Signal::Place(Place::parse(a(0))?),
                Arg::InputName => Signal::Input(IoName::parse(a(0))?),
                _ => Signal::Station(PlcStation::parse(a(0))?),
            };
            let level = level(a(1))?;
            Command::WaitInput {
                signal,
                level,
                limit: seconds(a(2))?,
            }
        }
        Handler::WaitReady => {
            if !a(0).eq_ignore_ascii_case("rcm") {
                return Err(format!("`waitready` waits for `rcm`, not `{}`", a(0)));
            }
            Command::WaitReady {
                limit: seconds(a(1))?,
            }
        }
    })
}

/// Checks one recipe of `kind`.
pub fn check(recipe: &Recipe, kind: RecipeKind) -> Result<Program, Vec<Problem>> {
    let mut cx = Ctx {
        origin: &recipe.origin,
        problems: recipe.problems.clone(),
    };
    if kind.is_workstation() && recipe.name.is_none() {
        cx.add(
            1,
            None,
            ProblemKind::MissingName,
            format!("a {kind} recipe needs a #NAME line: the name the cell starts it by"),
        );
    }
    if recipe.rows.is_empty() {
        if cx.problems.is_empty() {
            cx.add(
                1,
                None,
                ProblemKind::MissingName,
                "the recipe has no table lines (`-<state> | …`)".into(),
            );
        }
        cx.problems.sort_by_key(|p| (p.line, p.kind));
        return Err(cx.problems);
    }
    let mut by_state: BTreeMap<StateNo, Vec<&Row>> = BTreeMap::new();
    for r in &recipe.rows {
        by_state.entry(r.state).or_default().push(r);
    }
    let mut states = BTreeMap::new();
    for (&no, rows) in &by_state {
        let first = rows[0];
        let s = Some(no);
        if no == StateNo::END {
            cx.add(
                first.line,
                s,
                ProblemKind::UnknownState,
                "state 0 ends the recipe and cannot have lines".into(),
            );
            continue;
        }
        // One command and one report per state.
        let norm = |r: &Row| r.command.as_ref().map(|c| c.normal());
        if let Some(other) = rows
            .iter()
            .find(|r| norm(r) != norm(first) || r.report != first.report)
        {
            cx.add(
                other.line,
                s,
                ProblemKind::Inconsistent,
                format!(
                    "inconsistent: line {} has `{}`{}, line {} has `{}`{}",
                    first.line,
                    first
                        .command
                        .as_ref()
                        .map_or(String::new(), |c| c.to_string()),
                    if first.report.is_some() {
                        " | alarm"
                    } else {
                        ""
                    },
                    other.line,
                    other
                        .command
                        .as_ref()
                        .map_or(String::new(), |c| c.to_string()),
                    if other.report.is_some() {
                        " | alarm"
                    } else {
                        ""
                    },
                ),
            );
            continue;
        }
        let (spec, command) = match &first.command {
            None => (None, Command::Nothing),
            Some(c) => match lookup(kind, &c.name) {
                None => {
                    cx.add(
                        first.line,
                        s,
                        ProblemKind::UnknownCommand,
                        format!("wrong command `{}` for a {kind} recipe", c.name),
                    );
                    continue;
                }
                Some(spec) => match build_command(spec, c) {
                    Ok(cmd) => (Some(spec), cmd),
                    Err(e) => {
                        cx.add(first.line, s, ProblemKind::BadArgument, e);
                        continue;
                    }
                },
            },
        };
        let criteria = spec.map_or(Criteria::None, |sp| sp.criteria);
        let mut ok = true;
        let mut seen = BTreeSet::new();
        for r in rows {
            match (&r.criterion, criteria) {
                (None, Criteria::None) => {}
                (Some(c), Criteria::None) => {
                    cx.add(
                        r.line,
                        s,
                        ProblemKind::WrongCriterion,
                        format!(
                            "wrong criterion `{c}`: `{}` takes no criterion",
                            first
                                .command
                                .as_ref()
                                .map_or("(no command)".into(), |c| c.name.clone())
                        ),
                    );
                    ok = false;
                }
                (None, _) => {
                    cx.add(
                        r.line,
                        s,
                        ProblemKind::NoCriterion,
                        format!(
                            "no criterion; `{}` needs {}",
                            first
                                .command
                                .as_ref()
                                .map_or(String::new(), |c| c.name.clone()),
                            criteria.describe()
                        ),
                    );
                    ok = false;
                }
                (Some(c), _) if !criteria.allows(c) => {
                    cx.add(
                        r.line,
                        s,
                        ProblemKind::WrongCriterion,
                        format!(
                            "wrong criterion `{c}`; `{}` allows {}",
                            first
                                .command
                                .as_ref()
                                .map_or(String::new(), |c| c.name.clone()),
                            criteria.describe()
                        ),
                    );
                    ok = false;
                }
                (Some(_), _) => {}
            }
            if let Some(c) = &r.criterion {
                if !seen.insert(c.clone()) {
                    cx.add(
                        r.line,
                        s,
                        ProblemKind::DuplicateCriterion,
                        format!("criterion `{c}` appears twice"),
                    );
                    ok = false;
                }
            }
        }
        if criteria == Criteria::None && rows.len() > 1 && ok {
            cx.add(rows[1].line, s, ProblemKind::Inconsistent, format!("inconsistent: {} lines, but its command takes no criterion, so only one can apply", rows.len()));
            ok = false;
        }
        if ok {
            for req in criteria.required() {
                if !seen.contains(req) {
                    cx.add(
                        first.line,
                        s,
                        ProblemKind::MissingBranch,
                        format!("no `{req}` branch: what happens then is not written down"),
                    );
                    ok = false;
                }
            }
        }
        if !ok {
            continue;
        }
        states.insert(
            no,
            State {
                no,
                line: first.line,
                command,
                text: first
                    .command
                    .as_ref()
                    .map_or(String::new(), |c| c.to_string()),
                report: first.report,
                branches: rows.iter().map(|r| (r.criterion.clone(), r.next)).collect(),
            },
        );
    }
    // Next states exist.
    for r in &recipe.rows {
        if r.next != StateNo::END && !by_state.contains_key(&r.next) {
            cx.add(
                r.line,
                Some(r.state),
                ProblemKind::UnknownState,
                format!("state {} does not exist", r.next),
            );
        }
    }
    let first = recipe.rows[0].state;
    let edges = |s: StateNo| -> Vec<StateNo> {
        by_state
            .get(&s)
            .map_or(Vec::new(), |rows| rows.iter().map(|r| r.next).collect())
    };
    // Reachable from the first state.
    let mut reach = BTreeSet::from([first]);
    let mut stack = vec![first];
    while let Some(s) = stack.pop() {
        for n in edges(s) {
            if reach.insert(n) {
                stack.push(n);
            }
        }
    }
    for (&no, rows) in &by_state {
        if !reach.contains(&no) {
            cx.add(
                rows[0].line,
                Some(no),
                ProblemKind::Unreachable,
                format!("unreachable: no path from the first state {first} leads here"),
            );
        }
    }
    // A path to 0.
    let mut ends = BTreeSet::from([StateNo::END]);
    loop {
        let before = ends.len();
        for (&no, rows) in &by_state {
            if rows.iter().any(|r| ends.contains(&r.next)) {
                ends.insert(no);
            }
        }
        if ends.len() == before {
            break;
        }
    }
    for (&no, rows) in &by_state {
        if reach.contains(&no) && !ends.contains(&no) {
            cx.add(
                rows[0].line,
                Some(no),
                ProblemKind::NoPathToEnd,
                "no path from here leads to state 0: the recipe could never end".into(),
            );
        }
    }
    // Loops through states that never wait would spin.
    let passes = |s: StateNo| states.get(&s).is_some_and(|st: &State| !st.command.waits());
    let mut reported = BTreeSet::new();
    for &start in states.keys() {
        if !passes(start) || reported.contains(&start) {
            continue;
        }
        let mut seen = BTreeSet::from([start]);
        let mut stack = vec![start];
        while let Some(s) = stack.pop() {
            for n in edges(s) {
                if n == start {
                    reported.extend(seen.iter().copied());
                    cx.add(states[&start].line, Some(start), ProblemKind::LoopWithoutWait, "a loop of states none of which waits: it would run forever without the cell doing anything".into());
                    stack.clear();
                    break;
                }
                if passes(n) && seen.insert(n) {
                    stack.push(n);
                }
            }
        }
    }
    // A wait without a limit needs a start of its target with one.
    for st in states.values() {
        if let Command::Wait {
            target,
            limit: None,
        } = &st.command
        {
            let given = states.values().any(|o| matches!(&o.command, Command::Start { target: t, limit: Some(_), .. } if t == target));
            if !given {
                cx.add(st.line, Some(st.no), ProblemKind::MissingTimeLimit, format!("`wait {target}` has no time limit, and no `start {target} … <max_s>` gives one"));
            }
        }
    }
    let mut condition = |which: &str, raw: &Option<(String, usize)>| {
        let (text, line) = raw.as_ref()?;
        let mut bad = |message: String| cx.add(*line, None, ProblemKind::BadArgument, message);
        // A station's terms are over what it observes: the conveyor's
        // inputs for transport, the robot's facts for welding.
        let fits = |c: &Condition| {
            matches!(
                (kind, c.fact),
                (RecipeKind::Transport, Fact::Signal(_)) | (RecipeKind::Welding, Fact::Robot(_))
            )
        };
        match parse_terms(text) {
            Ok(_) if kind == RecipeKind::Cell => {
                bad(format!(
                    "#{which}: a cell recipe has no conditions (its workstation recipes state \
                     theirs)"
                ));
                None
            }
            Ok(terms) => match terms.iter().find(|c| !fits(c)) {
                Some(c) => {
                    let what = match kind {
                        RecipeKind::Welding => "the robot's facts (`robot ready`, `robot idle`)",
                        _ => "the conveyor's inputs (`place 2 occupied`, `line K stopped`)",
                    };
                    bad(format!(
                        "#{which}: `{c}` is not something a {kind} station observes: its \
                         terms name {what}"
                    ));
                    None
                }
                None => Some(Conditions { terms, line: *line }),
            },
            Err(e) => {
                bad(format!("#{which}: {e}"));
                None
            }
        }
    };
    let pre = condition("PRE", &recipe.pre);
    let post = condition("POST", &recipe.post);
    if cx.problems.is_empty() {
        Ok(Program {
            kind,
            name: recipe.name.as_ref().map(|(n, _)| n.clone()),
            origin: recipe.origin.clone(),
            first,
            states,
            pre,
            post,
        })
    } else {
        cx.problems.sort_by_key(|p| (p.line, p.kind));
        Err(cx.problems)
    }
}

/// A recipe of a set, with its station (the directory it came from).
#[derive(Debug, Clone)]
pub struct Entry {
    /// The station whose recipe it is (`cell`, `welding`, …).
    pub station: StationName,
    /// Its kind.
    pub kind: RecipeKind,
    /// The parsed text.
    pub recipe: Recipe,
    /// The text as read: what is checked is what is delivered.
    pub text: String,
}

impl Entry {
    /// The recipe's name: its `#NAME`, else (a cell recipe) its file name
    /// without extension; an error says why neither is a valid name.
    pub fn name(&self) -> Result<ObjectName, String> {
        if let Some((n, _)) = &self.recipe.name {
            return Ok(n.clone());
        }
        let origin = &self.recipe.origin;
        let stem = std::path::Path::new(origin)
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or_default();
        ObjectName::new(stem)
            .map_err(|e| format!("{origin}:1: the file name is the recipe's name: {e}"))
    }
}

/// Checks a set of recipes: each one, then across them. Returns the
/// programs of the clean ones and every problem.
pub fn check_set(entries: &[Entry]) -> (Vec<(StationName, Program)>, Vec<Problem>) {
    let mut programs = Vec::new();
    let mut problems = Vec::new();
    for e in entries {
        match check(&e.recipe, e.kind) {
            Ok(p) => programs.push((e.station.clone(), p)),
            Err(mut v) => problems.append(&mut v),
        }
    }
    // Workstation recipe names per station, from every parsed #NAME.
    let mut names: BTreeMap<(StationName, ObjectName), (String, usize)> = BTreeMap::new();
    for e in entries.iter().filter(|e| e.kind.is_workstation()) {
        if let Some((n, line)) = &e.recipe.name {
            if let Some((other, other_line)) = names.insert(
                (e.station.clone(), n.clone()),
                (e.recipe.origin.clone(), *line),
            ) {
                problems.push(Problem {
                    origin: e.recipe.origin.clone(),
                    line: *line,
                    state: None,
                    kind: ProblemKind::MalformedLine,
                    message: format!(
                        "recipe {n} is defined twice on WS {}: also {other}:{other_line}",
                        e.station
                    ),
                });
            }
        }
    }
    for (_, p) in programs.iter().filter(|(_, p)| p.kind == RecipeKind::Cell) {
        for st in p.states.values() {
            if let Command::Start {
                target,
                job: Job::Recipe(r),
                ..
            } = &st.command
            {
                if !names.contains_key(&(target.clone(), r.clone())) {
                    let what = if names.keys().any(|(s, _)| s == target) {
                        format!("recipe {r} does not exist on WS {target}")
                    } else {
                        format!(
                            "no connection with station {target}: no recipes for it in this set"
                        )
                    };
                    problems.push(Problem {
                        origin: p.origin.clone(),
                        line: st.line,
                        state: Some(st.no),
                        kind: ProblemKind::UnknownRecipe,
                        message: what,
                    });
                }
            }
        }
    }
    (programs, problems)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::syntax::parse;

    /// The (state, kind) of every problem of `text` checked as `kind`.
    fn problems(kind: RecipeKind, text: &str) -> Vec<(Option<u16>, ProblemKind)> {
        match check(&parse(text, "t.rcp"), kind) {
            Ok(_) => vec![],
            Err(v) => v
                .into_iter()
                .map(|p| (p.state.map(|s| s.0), p.kind))
                .collect(),
        }
    }

    fn only(kind: RecipeKind, text: &str, state: Option<u16>, want: ProblemKind) {
        assert_eq!(problems(kind, text), vec![(state, want)], "{text}");
    }

    const OK_WELDING: &str = "#W\n-1 | start rcm 64 | | gestart | 2\n-1 | start rcm 64 | | tijdlimiet | 3\n-2 | wait rcm 80 | | klaar | 0\n-2 | wait rcm 80 | | tijdlimiet | 3\n-3 | | alarm | | 0\n";

    #[test]
    fn a_clean_recipe_checks_clean() {
        assert_eq!(problems(RecipeKind::Welding, OK_WELDING), vec![]);
        let p = check(&parse(OK_WELDING, "t"), RecipeKind::Welding).expect("clean");
        assert_eq!(p.first, StateNo(1));
        assert_eq!(p.states.len(), 3);
    }

    /// `#PRE` and `#POST` lines: read into the program of a transport
    /// recipe (conveyor terms) and of a welding recipe (robot terms);
    /// refused, at their line, for a cell recipe, with a term its station
    /// does not observe, with a term that is none, or given twice.
    #[test]
    fn conditions_are_a_workstation_recipes_and_name_their_line() {
        let text = "#PARK\n#PRE place 2 occupied, line K stopped\n#POST place 3 occupied\n\
                    -1 | activate k | | | 0\n";
        let p = check(&parse(text, "park.rcp"), RecipeKind::Transport).expect("clean");
        let pre = p.pre.expect("a precondition");
        assert_eq!(
            (pre.line, pre.to_string().as_str()),
            (2, "place 2 occupied, line K stopped")
        );
        assert_eq!(p.post.map(|c| c.line), Some(3));
        let problems_of = |kind, text: &str| -> Vec<String> {
            check(&parse(text, "r.rcp"), kind)
                .err()
                .unwrap_or_default()
                .iter()
                .map(Problem::to_string)
                .collect()
        };
        let on_welding = OK_WELDING.replace("#W\n", "#W\n#PRE place 2 occupied\n");
        assert_eq!(
            problems_of(RecipeKind::Welding, &on_welding),
            [
                "r.rcp:2: #PRE: `place 2 occupied` is not something a welding station observes: \
              its terms name the robot's facts (`robot ready`, `robot idle`)"
            ]
        );
        let robot = OK_WELDING.replace(
            "#W\n",
            "#W\n#PRE robot ready, robot idle\n#POST robot idle\n",
        );
        let p = check(&parse(&robot, "w.rcp"), RecipeKind::Welding).expect("robot terms");
        assert_eq!(
            p.pre.map(|c| c.to_string()).as_deref(),
            Some("robot ready, robot idle")
        );
        let on_transport = text.replace("line K stopped", "robot idle");
        assert!(problems_of(RecipeKind::Transport, &on_transport)[0]
            .contains("`robot idle` is not something a transport station observes"));
        let on_cell = "#PRE robot idle\n-1 | output hi | | | 0\n";
        assert_eq!(
            problems_of(RecipeKind::Cell, on_cell),
            ["r.rcp:1: #PRE: a cell recipe has no conditions (its workstation recipes state theirs)"]
        );
        let bad = text.replace("line K stopped", "line K halted");
        let found = problems_of(RecipeKind::Transport, &bad);
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(
            found[0].starts_with("r.rcp:2: #PRE: `line K halted` is not a condition"),
            "{found:?}"
        );
        let twice = text.replace("#POST", "#PRE");
        let found = problems_of(RecipeKind::Transport, &twice);
        assert!(
            found[0].starts_with("r.rcp:3: a second #PRE line; the first is on line 2"),
            "{found:?}"
        );
    }

    #[test]
    fn malformed_line() {
        only(
            RecipeKind::Welding,
            &format!("{OK_WELDING}-3 | | alarm | 0\n"),
            Some(3),
            ProblemKind::MalformedLine,
        );
    }

    #[test]
    fn unknown_state() {
        let t = OK_WELDING.replace("| klaar | 0", "| klaar | 9");
        assert_eq!(
            problems(RecipeKind::Welding, &t),
            vec![(Some(2), ProblemKind::UnknownState)]
        );
    }

    #[test]
    fn state_without_criterion() {
        let t = OK_WELDING.replace("| klaar | 0", "| | 0");
        only(RecipeKind::Welding, &t, Some(2), ProblemKind::NoCriterion);
    }

    #[test]
    fn inconsistent_state() {
        let t = OK_WELDING.replace(
            "-2 | wait rcm 80 | | tijdlimiet",
            "-2 | wait rcm 90 | | tijdlimiet",
        );
        only(RecipeKind::Welding, &t, Some(2), ProblemKind::Inconsistent);
        let t = "-1 | output a | | | 2\n-1 | output a | | | 0\n-2 | output b | | | 0\n";
        only(RecipeKind::Cell, t, Some(1), ProblemKind::Inconsistent);
    }

    #[test]
    fn unknown_command() {
        only(
            RecipeKind::Welding,
            &OK_WELDING.replace("start rcm", "begin rcm"),
            Some(1),
            ProblemKind::UnknownCommand,
        );
        // A cell command in a transport recipe.
        only(
            RecipeKind::Transport,
            "#T\n-1 | output x | | | 0\n",
            Some(1),
            ProblemKind::UnknownCommand,
        );
    }

    #[test]
    fn bad_argument() {
        only(
            RecipeKind::Welding,
            &OK_WELDING.replace("start rcm 64", "start rcm x64"),
            Some(1),
            ProblemKind::BadArgument,
        );
        only(
            RecipeKind::Transport,
            "#T\n-1 | activate i | | | 0\n",
            Some(1),
            ProblemKind::BadArgument,
        );
        only(
            RecipeKind::Transport,
            "#T\n-1 | waitplace 100 1 10 | | klaar | 0\n-1 | waitplace 100 1 10 | | tijdlimiet | 0\n",
            Some(1),
            ProblemKind::BadArgument,
        );
        // A place the language allows but a conveyor may lack is its
        // equipment file's to refuse (`falc_equipment::vocabulary`).
        assert!(problems(
            RecipeKind::Transport,
            "#T\n-1 | waitplace 7 1 10 | | klaar | 0\n-1 | waitplace 7 1 10 | | tijdlimiet | 0\n",
        )
        .is_empty());
    }

    #[test]
    fn wrong_criterion() {
        only(
            RecipeKind::Welding,
            &OK_WELDING.replace("| gestart |", "| klaar |"),
            Some(1),
            ProblemKind::WrongCriterion,
        );
        only(
            RecipeKind::Transport,
            "#T\n-1 | activate e | | klaar | 0\n",
            Some(1),
            ProblemKind::WrongCriterion,
        );
    }

    #[test]
    fn duplicate_criterion() {
        let t = OK_WELDING.replace(
            "-2 | wait rcm 80 | | tijdlimiet | 3",
            "-2 | wait rcm 80 | | tijdlimiet | 3\n-2 | wait rcm 80 | | timeout | 0",
        );
        only(
            RecipeKind::Welding,
            &t,
            Some(2),
            ProblemKind::DuplicateCriterion,
        );
    }

    #[test]
    fn missing_time_limit_branch() {
        let t = OK_WELDING.replace("-1 | start rcm 64 | | tijdlimiet | 3\n", "");
        only(RecipeKind::Welding, &t, Some(1), ProblemKind::MissingBranch);
        let t = "-1 | input ok? | | answer=ja | 0\n";
        only(RecipeKind::Cell, t, Some(1), ProblemKind::MissingBranch);
    }

    #[test]
    fn missing_time_limit() {
        let t = OK_WELDING.replace("wait rcm 80", "wait rcm");
        only(
            RecipeKind::Welding,
            &t,
            Some(2),
            ProblemKind::MissingTimeLimit,
        );
        // A limit on start is enough.
        let t = t.replace("start rcm 64", "start rcm 64 100");
        assert_eq!(problems(RecipeKind::Welding, &t), vec![]);
    }

    #[test]
    fn unreachable_state() {
        let t = format!("{OK_WELDING}-4 | | alarm | | 0\n");
        only(RecipeKind::Welding, &t, Some(4), ProblemKind::Unreachable);
    }

    #[test]
    fn no_path_to_end() {
        let t = OK_WELDING.replace(
            "-3 | | alarm | | 0",
            "-3 | wait rcm 5 | alarm | klaar | 3\n-3 | wait rcm 5 | alarm | tijdlimiet | 3",
        );
        only(RecipeKind::Welding, &t, Some(3), ProblemKind::NoPathToEnd);
    }

    #[test]
    fn loop_without_wait() {
        let t = "-1 | output a | | | 2\n-2 | output b | | | 1\n-3 | output c | | | 0\n";
        let got = problems(RecipeKind::Cell, t);
        assert!(
            got.contains(&(Some(1), ProblemKind::LoopWithoutWait)),
            "{got:?}"
        );
    }

    #[test]
    fn missing_name() {
        only(
            RecipeKind::Welding,
            &OK_WELDING.replace("#W\n", ""),
            None,
            ProblemKind::MissingName,
        );
        assert_eq!(
            problems(RecipeKind::Cell, "no table at all\n"),
            vec![(None, ProblemKind::MissingName)]
        );
    }

    #[test]
    fn unknown_workstation_recipe_across_a_set() {
        let entry = |station: &str, kind, text: &str| Entry {
            station: StationName::new(station).expect("valid"),
            kind,
            recipe: parse(text, &format!("{station}.rcp")),
            text: text.to_string(),
        };
        let cell = "-1 | start welding droog_dik | | gestart | 2\n-1 | start welding droog_dik | | tijdlimiet | 3\n-2 | wait welding 10 | | klaar | 0\n-2 | wait welding 10 | | tijdlimiet | 3\n-3 | | alarm | | 0\n";
        let set = [
            entry("cell", RecipeKind::Cell, cell),
            entry("welding", RecipeKind::Welding, OK_WELDING),
        ];
        let (programs, problems) = check_set(&set);
        assert_eq!(programs.len(), 2);
        assert_eq!(problems.len(), 1);
        assert_eq!(problems[0].kind, ProblemKind::UnknownRecipe);
        assert!(
            problems[0]
                .message
                .contains("recipe DROOG_DIK does not exist on WS welding"),
            "{}",
            problems[0]
        );
        let named = [
            entry("cell", RecipeKind::Cell, cell),
            entry(
                "welding",
                RecipeKind::Welding,
                &OK_WELDING.replace("#W", "#DROOG_DIK"),
            ),
        ];
        assert!(check_set(&named).1.is_empty());
    }
}
