//! A robot program's text, as it is stored with the recipes and delivered
//! over DNC to the robot controller: its number, then its steps, each a
//! motion or a weld with how long it takes at time scale 1. What the
//! twin runs; what is checked when read, with errors naming the file and
//! the line.
//!
//! ```text
//! program 65
//! # thick plate, dry run
//! move approach 4
//! weld seam_1 100
//! move home 16
//! ```
//!
//! The first line that is not blank or a comment (`#`) is `program N`
//! (1–999); then one step per line: `move NAME SECONDS` or `weld NAME
//! SECONDS` (a name of at most 16 lower-case letters, digits and `_`;
//! seconds above 0 and at most 3600, up to three decimals). At least one
//! step, at most [`MAX_STEPS`]; every line at most [`MAX_LINE`] bytes of
//! printable ASCII, so that each goes over the line in one telegram.

use crate::check::{Command, Job, Program};
use crate::problem::{Problem, ProblemKind};
use falc_model::ids::{RobotProgram, StationName};
use falc_model::mms::domain::content_hash;
use falc_model::recipe_file::RecipeFile;
use std::collections::BTreeSet;
use std::fmt;
use std::time::Duration;

/// The most steps a program has.
pub const MAX_STEPS: usize = 99;
/// The longest line of a program text, in bytes.
pub const MAX_LINE: usize = 60;
/// The longest step, in seconds.
const MAX_STEP_S: f64 = 3600.0;

/// What a step does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StepKind {
    /// A motion.
    Move,
    /// A weld (an aborted weld spoils the product).
    Weld,
}

/// One step of a program.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Step {
    /// Motion or weld.
    pub kind: StepKind,
    /// Its name (`approach`, `seam_1`).
    pub name: String,
    /// How long it takes at time scale 1.
    pub time: Duration,
}

impl fmt::Display for Step {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let kind = match self.kind {
            StepKind::Move => "move",
            StepKind::Weld => "weld",
        };
        write!(f, "{kind} {} {} s", self.name, self.time.as_secs_f64())
    }
}

/// A robot program read from its text.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProgramText {
    /// Its number.
    pub number: RobotProgram,
    /// Its steps, in order.
    pub steps: Vec<Step>,
    /// The text it was read from (what is delivered and kept).
    pub text: String,
}

impl ProgramText {
    /// Reads `text` (from `origin`, for errors): every problem as
    /// `origin:line: reason`.
    pub fn parse(text: &str, origin: &str) -> Result<Self, Vec<String>> {
        let mut problems = Vec::new();
        let mut number = None;
        // Whether the first line that says anything was read (as the
        // `program N` line it must be, or as an error saying so).
        let mut headed = false;
        let mut steps = Vec::new();
        for (i, raw) in text.lines().enumerate() {
            let at = i + 1;
            let mut bad = |why: String| problems.push(format!("{origin}:{at}: {why}"));
            if raw.len() > MAX_LINE {
                bad(format!(
                    "the line has {} bytes, at most {MAX_LINE} go over DNC",
                    raw.len()
                ));
                continue;
            }
            if let Some(c) = raw.chars().find(|c| !(c.is_ascii_graphic() || *c == ' ')) {
                bad(format!("{c:?} is not printable ASCII"));
                continue;
            }
            let line = raw.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let words: Vec<&str> = line.split_whitespace().collect();
            let first = !std::mem::replace(&mut headed, true);
            match (first, words.as_slice()) {
                (true, ["program", n]) => match n.parse::<u16>().ok().and_then(RobotProgram::new) {
                    Some(p) => number = Some(p),
                    None => bad(format!("`{n}` is not a robot program number (1-999)")),
                },
                (true, _) => bad("a robot program begins with `program N` (1-999)".into()),
                (false, ["program", ..]) => bad("a second `program` line".into()),
                (false, [kind @ ("move" | "weld"), name, secs]) => {
                    let kind = if *kind == "move" {
                        StepKind::Move
                    } else {
                        StepKind::Weld
                    };
                    match (step_name(name), seconds(secs)) {
                        (Ok(name), Ok(time)) => steps.push(Step { kind, name, time }),
                        (Err(e), _) | (_, Err(e)) => bad(e),
                    }
                }
                (false, _) => bad(format!(
                    "`{line}` is not a step: write `move NAME SECONDS` or `weld NAME SECONDS`"
                )),
            }
        }
        if steps.len() > MAX_STEPS {
            problems.push(format!(
                "{origin}:1: {} steps, a program has at most {MAX_STEPS}",
                steps.len()
            ));
        }
        if !headed {
            problems.push(format!("{origin}:1: no `program N` line"));
        } else if steps.is_empty() && problems.is_empty() {
            problems.push(format!("{origin}:1: the program has no step"));
        }
        match number {
            Some(number) if problems.is_empty() => Ok(Self {
                number,
                steps,
                text: text.to_string(),
            }),
            _ => Err(problems),
        }
    }

    /// How long it runs at time scale 1.
    pub fn duration(&self) -> Duration {
        self.steps.iter().map(|s| s.time).sum()
    }

    /// The text's lines as they go over DNC, one telegram each.
    pub fn lines(&self) -> Vec<&str> {
        self.text.lines().collect()
    }

    /// The text's hash as DNC names it ([`text_hash`]): what a download
    /// carries and a listing shows.
    pub fn hash(&self) -> u32 {
        text_hash(&self.text)
    }
}

/// A robot program of the recipe store (`robot/065.prg`), read and checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RobotFile {
    /// Its file in the store.
    pub file: RecipeFile,
    /// Where it was read from (for errors).
    pub origin: String,
    /// The program.
    pub program: ProgramText,
}

impl RobotFile {
    /// Reads `text` as the program of the file at `origin`, whose name
    /// (`065.prg`) is `file_name`: the text must check clean and be the
    /// program its file is named for.
    pub fn read(origin: &str, file_name: &str, text: &str) -> Result<Self, Vec<String>> {
        let robot = StationName::new(falc_model::recipe_file::ROBOT_DIR)
            .map_err(|e| vec![format!("{origin}:1: {e}")])?;
        let file =
            RecipeFile::new(robot, file_name).map_err(|e| vec![format!("{origin}:1: {e}")])?;
        let program = ProgramText::parse(text, origin)?;
        if file.robot_program() != Some(program.number) {
            let at = text
                .lines()
                .position(|l| l.trim_start().starts_with("program"))
                .map_or(1, |i| i + 1);
            return Err(vec![format!(
                "{origin}:{at}: the text is program {}, its file {}: a program's file is named \
                 by its number ({:03}.prg)",
                program.number,
                file.file(),
                program.number.number()
            )]);
        }
        Ok(Self {
            file,
            origin: origin.to_string(),
            program,
        })
    }
}

/// Every `start rcm N` of `programs` whose program N the store does not
/// hold (`held`: the numbers of its robot directory), as a problem at its
/// state's line.
pub fn lacking(programs: &[(StationName, Program)], held: &BTreeSet<RobotProgram>) -> Vec<Problem> {
    let mut out = Vec::new();
    for (_, program) in programs {
        for state in program.states.values() {
            let Command::Start {
                job: Job::Program(p),
                ..
            } = &state.command
            else {
                continue;
            };
            if !held.contains(p) {
                out.push(Problem {
                    origin: program.origin.clone(),
                    line: state.line,
                    state: Some(state.no),
                    kind: ProblemKind::BadArgument,
                    message: format!(
                        "the recipe store has no robot program {p} (robot/{:03}.prg)",
                        p.number()
                    ),
                });
            }
        }
    }
    out
}

/// The text's hash as a program transfer carries it: the low 32 bits of
/// its content hash as a domain ([`content_hash`], FNV-1a 64) over its
/// lines joined by `\n` (line ends as the line carries them: none after
/// the last).
pub fn text_hash(text: &str) -> u32 {
    let joined = text.lines().collect::<Vec<_>>().join("\n");
    (content_hash(joined.as_bytes()) & u64::from(u32::MAX)) as u32
}

fn step_name(s: &str) -> Result<String, String> {
    let ok = !s.is_empty()
        && s.len() <= 16
        && s.bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_');
    if ok {
        Ok(s.to_string())
    } else {
        Err(format!(
            "`{s}` is not a step name: at most 16 lower-case letters, digits and `_`"
        ))
    }
}

fn seconds(s: &str) -> Result<Duration, String> {
    let bad = || {
        format!("`{s}` is not a time: seconds above 0, at most {MAX_STEP_S}, up to three decimals")
    };
    let decimals = s.split_once('.').map_or(0, |(_, d)| d.len());
    if decimals > 3 || !s.bytes().all(|b| b.is_ascii_digit() || b == b'.') {
        return Err(bad());
    }
    let v: f64 = s.parse().map_err(|_| bad())?;
    if v <= 0.0 || v > MAX_STEP_S {
        return Err(bad());
    }
    Ok(Duration::from_millis((v * 1000.0).round() as u64))
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;

    /// docs/dnc.md's example program reads clean, and the hash its twin
    /// log line shows is the text's.
    #[test]
    fn the_example_in_docs_dnc_md_reads_and_its_hash_is_the_one_shown() {
        let doc = include_str!("../../../docs/dnc.md");
        let start = doc.find("```\nprogram 65\n").expect("the example") + 4;
        let end = start + doc[start..].find("```").expect("its end");
        let p = ProgramText::parse(&doc[start..end], "docs/dnc.md").expect("clean");
        assert_eq!(p.duration(), Duration::from_secs(120));
        assert!(
            doc.contains(&format!(
                "program 65 stored: 3 steps, 120.0 s, hash {:08X}`",
                p.hash()
            )),
            "docs/dnc.md shows another hash than {:08X}",
            p.hash()
        );
    }

    const P65: &str =
        "program 65\n# thick plate, dry run\nmove approach 4\nweld seam_1 100\nmove home 16\n";

    #[test]
    fn a_program_reads_its_steps_and_their_time() {
        let p = ProgramText::parse(P65, "065.prg").expect("clean");
        assert_eq!(p.number, RobotProgram::of(65));
        assert_eq!(p.steps.len(), 3);
        assert_eq!(p.steps[1].to_string(), "weld seam_1 100 s");
        assert_eq!(p.duration(), Duration::from_secs(120));
        assert_eq!(p.lines().len(), 5);
        assert_eq!(p.hash(), text_hash(P65.trim_end()));
        assert_ne!(p.hash(), text_hash(&P65.replace("100", "101")));
    }

    #[test]
    fn every_problem_names_its_file_and_line() {
        let bad = "# no number first\nmove a 1\nprogram 1000\n";
        let e = ProgramText::parse(bad, "x.prg").unwrap_err();
        assert_eq!(
            e,
            [
                "x.prg:2: a robot program begins with `program N` (1-999)",
                "x.prg:3: a second `program` line"
            ]
        );
        let bad =
            "program 65\nmove Approach 4\nweld seam 0\njump home 3\nmove home 1.2345\nprogram 66\n";
        let e = ProgramText::parse(bad, "065.prg").unwrap_err();
        assert_eq!(
            e,
            [
                "065.prg:2: `Approach` is not a step name: at most 16 lower-case letters, digits and `_`",
                "065.prg:3: `0` is not a time: seconds above 0, at most 3600, up to three decimals",
                "065.prg:4: `jump home 3` is not a step: write `move NAME SECONDS` or `weld NAME SECONDS`",
                "065.prg:5: `1.2345` is not a time: seconds above 0, at most 3600, up to three decimals",
                "065.prg:6: a second `program` line",
            ]
        );
        let long = format!("program 65\nmove {} 1\n", "a".repeat(70));
        assert!(
            ProgramText::parse(&long, "l.prg").unwrap_err()[0].contains("at most 60 go over DNC")
        );
        assert_eq!(
            ProgramText::parse("program 65\n", "e.prg").unwrap_err(),
            ["e.prg:1: the program has no step"]
        );
        assert_eq!(
            ProgramText::parse("program 0\nmove a 1\n", "z.prg").unwrap_err(),
            ["z.prg:1: `0` is not a robot program number (1-999)"]
        );
        assert!(ProgramText::parse("program 65\nmove a\u{7} 1\n", "c.prg").is_err());
    }
}
