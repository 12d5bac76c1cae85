//! The recipe text format of the 1992 thesis (appendix E), parsed into rows.
//!
//! - A table line starts with `-` followed by the state number, directly
//!   (`-1`, appendix E) or after blanks (`- 1`, as appendix F prints its
//!   states right-aligned); leading blanks are allowed. A line beginning
//!   with `-` is always a table line: one without a state number is a
//!   problem, never a comment. Every other line is a comment, except a
//!   `#NAME` line (a `#` directly followed by a letter): the program
//!   invocation name of a workstation recipe.
//! - Columns are separated by `|` or `;`:
//!   `state | command args | report | criterion | next`.
//! - Inside a column, words are separated by blanks, tabs and `=`.
//! - Keywords are case-insensitive, Dutch or English: `gestart`/`started`,
//!   `klaar`/`done`, `tijdlimiet`/`timeout`, `answer=<text>`, `answer=*`,
//!   and the criteria added since 1992: `bad_product`, `failed_safe`,
//!   `failed_danger`. The only report is `alarm`.
//!
//! Parsing never stops at a bad line: each becomes a [`Problem`] and the
//! others are still parsed, so one check lists every defect.

use super::problem::{Problem, ProblemKind};
use falc_model::ids::ObjectName;
use std::fmt;

/// A state number; 0 ends the recipe.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct StateNo(pub u16);

impl StateNo {
    /// The end state.
    pub const END: StateNo = StateNo(0);
}

impl fmt::Display for StateNo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// The report column.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Report {
    /// `alarm`: the recipe ends in alarm and the cell stops.
    Alarm,
}

/// The criterion column.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Criterion {
    /// `gestart` / `started`: the start was confirmed.
    Started,
    /// `klaar` / `done`: finished.
    Done,
    /// `tijdlimiet` / `timeout`: not in time.
    Timeout,
    /// `answer=<text>` (lower case).
    Answer(String),
    /// `answer=*`: any other answer.
    AnswerAny,
    /// `bad_product`: finished, but the product is bad (a weld aborted).
    BadProduct,
    /// `failed_safe`: failed without danger outside its own work area.
    FailedSafe,
    /// `failed_danger`: failed with danger (a hardware limit switch).
    FailedDanger,
}

impl fmt::Display for Criterion {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Started => f.write_str("started"),
            Self::Done => f.write_str("done"),
            Self::Timeout => f.write_str("timeout"),
            Self::Answer(a) => write!(f, "answer={a}"),
            Self::AnswerAny => f.write_str("answer=*"),
            Self::BadProduct => f.write_str("bad_product"),
            Self::FailedSafe => f.write_str("failed_safe"),
            Self::FailedDanger => f.write_str("failed_danger"),
        }
    }
}

/// The command column, split: the command word (lower case), its
/// arguments, and the raw text after the command word (for `output` and
/// `input`, whose argument is free text).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CommandText {
    /// The command word, lower case.
    pub name: String,
    /// The arguments, as written.
    pub args: Vec<String>,
    /// Everything after the command word, blanks collapsed.
    pub text: String,
}

impl CommandText {
    /// A normal form for comparing the rows of one state.
    pub fn normal(&self) -> String {
        format!("{} {}", self.name, self.args.join(" ").to_lowercase())
    }
}

impl fmt::Display for CommandText {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.text.is_empty() {
            f.write_str(&self.name)
        } else {
            write!(f, "{} {}", self.name, self.text)
        }
    }
}

/// One table line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Row {
    /// 1-based line number in the file.
    pub line: usize,
    /// The state.
    pub state: StateNo,
    /// The command, if any.
    pub command: Option<CommandText>,
    /// The report, if any.
    pub report: Option<Report>,
    /// The criterion, if any.
    pub criterion: Option<Criterion>,
    /// The next state.
    pub next: StateNo,
}

/// A parsed recipe: its rows, its `#NAME`, and the lines that did not parse.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Recipe {
    /// Where it came from (file path), for messages.
    pub origin: String,
    /// The `#NAME` and its line.
    pub name: Option<(ObjectName, usize)>,
    /// The `#PRE` line's text and line, if any.
    pub pre: Option<(String, usize)>,
    /// The `#POST` line's text and line, if any.
    pub post: Option<(String, usize)>,
    /// The table rows, in file order.
    pub rows: Vec<Row>,
    /// Lines that did not parse.
    pub problems: Vec<Problem>,
}

fn words(column: &str) -> Vec<&str> {
    column
        .split([' ', '\t', '='])
        .filter(|w| !w.is_empty())
        .collect()
}

fn parse_state(text: &str) -> Option<StateNo> {
    if text.is_empty() || !text.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    text.parse().ok().map(StateNo)
}

/// Parses a criterion column; `Err` names what was not understood.
pub fn parse_criterion(column: &str) -> Result<Option<Criterion>, String> {
    let w = words(column);
    let lower: Vec<String> = w.iter().map(|s| s.to_lowercase()).collect();
    let first = match lower.first() {
        None => return Ok(None),
        Some(f) => f.as_str(),
    };
    let c = match (first, lower.len()) {
        ("gestart" | "started", 1) => Criterion::Started,
        ("klaar" | "done", 1) => Criterion::Done,
        ("tijdlimiet" | "timeout", 1) => Criterion::Timeout,
        ("bad_product", 1) => Criterion::BadProduct,
        ("failed_safe", 1) => Criterion::FailedSafe,
        ("failed_danger", 1) => Criterion::FailedDanger,
        ("answer" | "antwoord", 2) if lower[1] == "*" => Criterion::AnswerAny,
        ("answer" | "antwoord", n) if n >= 2 => Criterion::Answer(lower[1..].join(" ")),
        ("answer" | "antwoord", _) => return Err("`answer` needs `=text` or `=*`".into()),
        _ => return Err(format!("unknown criterion `{}`", column.trim())),
    };
    Ok(Some(c))
}

/// Parses recipe text; `origin` names it in problems.
pub fn parse(text: &str, origin: &str) -> Recipe {
    let mut recipe = Recipe {
        origin: origin.to_string(),
        name: None,
        pre: None,
        post: None,
        rows: Vec::new(),
        problems: Vec::new(),
    };
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let trimmed = raw.trim_start();
        let mut problem = |state: Option<StateNo>, kind: ProblemKind, message: String| {
            recipe.problems.push(Problem {
                origin: origin.to_string(),
                line,
                state,
                kind,
                message,
            })
        };
        if let Some(rest) = trimmed.strip_prefix('#') {
            // `#PRE …` / `#POST …`: the recipe's conditions (checked by
            // the checker, `crate::condition`).
            let word = rest.split_whitespace().next().unwrap_or("");
            if word.eq_ignore_ascii_case("pre") || word.eq_ignore_ascii_case("post") {
                let text = rest.get(word.len()..).unwrap_or("").trim().to_string();
                let slot = if word.eq_ignore_ascii_case("pre") {
                    &mut recipe.pre
                } else {
                    &mut recipe.post
                };
                match slot {
                    Some((_, at)) => {
                        let at = *at;
                        problem(
                            None,
                            ProblemKind::MalformedLine,
                            format!(
                                "a second #{} line; the first is on line {at} (list every term \
                                 on one line, separated by commas)",
                                word.to_uppercase()
                            ),
                        )
                    }
                    None => *slot = Some((text, line)),
                }
                continue;
            }
            if rest.starts_with(|c: char| c.is_ascii_alphabetic()) {
                let word = rest.split_whitespace().next().unwrap_or(rest);
                match (ObjectName::new(word), &recipe.name) {
                    (Ok(_), Some((first, at))) => problem(
                        None,
                        ProblemKind::MalformedLine,
                        format!(
                            "a second #NAME line; the recipe is already named {first} on line {at}"
                        ),
                    ),
                    (Ok(name), None) => recipe.name = Some((name, line)),
                    (Err(e), _) => {
                        problem(None, ProblemKind::MalformedLine, format!("bad #NAME: {e}"))
                    }
                }
            }
            continue;
        }
        let Some(after_dash) = trimmed.strip_prefix('-') else {
            continue; // a comment
        };
        let mut cols: Vec<&str> = after_dash.split(['|', ';']).map(str::trim).collect();
        if cols.len() == 6 && cols[5].is_empty() {
            cols.pop(); // a trailing separator
        }
        let Some(state) = parse_state(cols[0]) else {
            problem(
                None,
                ProblemKind::MalformedLine,
                if cols[0].is_empty() {
                    "wrong line structure: a line beginning with `-` is a table line, and no state number follows the `-`".to_string()
                } else {
                    format!(
                        "wrong line structure: a line beginning with `-` is a table line, and `{}` after the `-` is not a state number",
                        cols[0]
                    )
                },
            );
            continue;
        };
        if cols.len() != 5 {
            problem(
                Some(state),
                ProblemKind::MalformedLine,
                format!(
                    "wrong line structure: {} columns, expected 5 (state | command | report | criterion | next)",
                    cols.len()
                ),
            );
            continue;
        }
        let Some(next) = parse_state(cols[4]) else {
            problem(
                Some(state),
                ProblemKind::MalformedLine,
                format!(
                    "wrong line structure: next state `{}` is not a number",
                    cols[4]
                ),
            );
            continue;
        };
        let report = match cols[2].to_lowercase().as_str() {
            "" => None,
            "alarm" => Some(Report::Alarm),
            other => {
                problem(
                    Some(state),
                    ProblemKind::MalformedLine,
                    format!("unknown report `{other}`; the only report is `alarm`"),
                );
                continue;
            }
        };
        let criterion = match parse_criterion(cols[3]) {
            Ok(c) => c,
            Err(e) => {
                problem(Some(state), ProblemKind::WrongCriterion, e);
                continue;
            }
        };
        let command = {
            let col = cols[1];
            let w = words(col);
            w.first().map(|first| {
                let after = col.trim_start()[first.len()..].trim_start_matches([' ', '\t', '=']);
                CommandText {
                    name: first.to_lowercase(),
                    args: w[1..].iter().map(|s| s.to_string()).collect(),
                    text: after.split_whitespace().collect::<Vec<_>>().join(" "),
                }
            })
        };
        recipe.rows.push(Row {
            line,
            state,
            command,
            report,
            criterion,
            next,
        });
    }
    recipe
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_thesis_format() {
        let r = parse(
            "#DROOG_PIJP   (test64.rcp)\nwelding recipe\n-1 | start rcm 64 |       | gestart    | 2\n-1 ; START RCM 64 ;; TijdLimiet ; 3\n  -3 |              | alarm |            | 0\n-6 | input (ja/nee) | | answer=ja | 7\n-6 | input (ja/nee) | | Answer = * | 6\n",
            "t.rcp",
        );
        assert_eq!(r.problems, vec![]);
        assert_eq!(
            r.name.as_ref().map(|(n, l)| (n.as_str(), *l)),
            Some(("DROOG_PIJP", 1))
        );
        assert_eq!(r.rows.len(), 5);
        assert_eq!(r.rows[0].criterion, Some(Criterion::Started));
        assert_eq!(r.rows[1].criterion, Some(Criterion::Timeout));
        assert_eq!(
            r.rows[1].command.as_ref().map(|c| c.normal()),
            Some("start rcm 64".into())
        );
        assert_eq!(r.rows[2].report, Some(Report::Alarm));
        assert_eq!(r.rows[2].command, None);
        assert_eq!(r.rows[3].criterion, Some(Criterion::Answer("ja".into())));
        assert_eq!(r.rows[4].criterion, Some(Criterion::AnswerAny));
        assert_eq!(
            r.rows[3].command.as_ref().map(|c| c.text.as_str()),
            Some("(ja/nee)")
        );
    }

    #[test]
    fn states_printed_right_aligned_are_table_lines() {
        let r = parse(
            "- 1 | output a | | | 2\n -\t2 | output b | | | 10\n-10 | output c | | | 0\n",
            "f.rcp",
        );
        assert!(r.problems.is_empty(), "{:?}", r.problems);
        let states: Vec<u16> = r.rows.iter().map(|row| row.state.0).collect();
        assert_eq!(states, [1, 2, 10]);
        assert_eq!(r.rows[0].line, 1);
    }

    #[test]
    fn a_dash_line_is_never_a_silent_comment() {
        for line in [
            "-",
            "- ",
            "--- section ---",
            "-a | b | | | 0",
            "- 1 2 | a | | | 0",
        ] {
            let r = parse(&format!("comment\n{line}\n"), "f.rcp");
            assert_eq!(r.problems.len(), 1, "{line:?}: {:?}", r.problems);
            assert_eq!(r.problems[0].line, 2, "{line:?}");
            assert_eq!(r.problems[0].kind, ProblemKind::MalformedLine, "{line:?}");
        }
    }

    #[test]
    fn bad_lines_are_problems_with_line_numbers() {
        let r = parse("-1 | output x | | \n-x | a | | | 2\n-2 | a | b | | 2\n-3 | a | | soon | 0\n-4 | a | | | z\n- comment\n", "f.rcp");
        let got: Vec<(usize, ProblemKind)> = r.problems.iter().map(|p| (p.line, p.kind)).collect();
        assert_eq!(
            got,
            vec![
                (1, ProblemKind::MalformedLine),
                (2, ProblemKind::MalformedLine),
                (3, ProblemKind::MalformedLine),
                (4, ProblemKind::WrongCriterion),
                (5, ProblemKind::MalformedLine),
                (6, ProblemKind::MalformedLine),
            ]
        );
        assert!(
            r.problems[5]
                .to_string()
                .contains("a line beginning with `-` is a table line, and `comment` after the `-` is not a state number"),
            "{}",
            r.problems[5]
        );
        assert!(
            r.problems[0]
                .to_string()
                .starts_with("f.rcp:1: state 1: wrong line structure"),
            "{}",
            r.problems[0]
        );
    }
}

#[cfg(test)]
mod prop {
    use super::parse;
    use crate::check::check;
    use crate::commands::RecipeKind;
    use crate::engine::{Engine, Event};
    use proptest::prelude::*;
    use std::sync::Arc;
    use std::time::Duration;

    /// Lines that look like recipe lines, to get past the first checks.
    fn recipe_like() -> impl Strategy<Value = String> {
        let line = prop_oneof![
            "-[0-9]{1,3} *[|;] *(start|wait|output|input|activate|reset|waitline|waitplace|waitstation)? *(rcm|welding|transport|[a-l]|[0-9]{1,3})? *[0-9a-z*]{0,3} *[|;] *(alarm)? *[|;] *(gestart|klaar|tijdlimiet|answer=[a-z*]{0,3}|bad_product)? *[|;] *[0-9]{1,3}",
            "#[A-Za-z_]{0,8}",
            ".{0,40}",
        ];
        proptest::collection::vec(line, 0..20).prop_map(|v| v.join("\n"))
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]
        #[test]
        fn parser_and_checker_never_panic(text in recipe_like()) {
            let r = parse(&text, "p.rcp");
            for kind in RecipeKind::ALL {
                if let Ok(program) = check(&r, kind) {
                    // A clean program also runs without panicking.
                    let mut e = Engine::new(Arc::new(program));
                    e.start(Duration::ZERO);
                    e.handle(Duration::from_secs(1), Event::Answer("ja".into()));
                    e.handle_timeout(Duration::from_secs(100_000));
                    while e.poll_action().is_some() {}
                }
            }
        }

        #[test]
        fn parser_never_panics_on_any_text(text in "(?s).{0,400}") {
            let r = parse(&text, "p.rcp");
            let _ = check(&r, RecipeKind::Cell);
        }
    }
}
