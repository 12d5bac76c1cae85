//! The shipped recipes and the thesis' recipes as printed: checking, every
//! criterion path of every shipped recipe on a fake clock, and the `falc
//! recipe` commands.

use falc_model::ids::StationName;
use falc_recipe::check::{check_set, Command, Program};
use falc_recipe::engine::{Action, Engine, Event, JobEnd, Outcome};
use falc_recipe::files;
use falc_recipe::problem::ProblemKind;
use falc_recipe::syntax::{Criterion, StateNo};
use std::collections::BTreeSet;
use std::path::PathBuf;
use std::process::Command as Process;
use std::sync::Arc;
use std::time::Duration;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn shipped() -> Vec<(StationName, Program)> {
    let entries = files::load(&[root().join("recipes")], None).expect("recipes load");
    let (programs, problems) = check_set(&entries);
    assert!(
        problems.is_empty(),
        "shipped recipes have problems: {problems:#?}"
    );
    programs
}

#[test]
fn every_shipped_recipe_checks_clean() {
    let programs = shipped();
    let count = |s: &str| programs.iter().filter(|(st, _)| st.as_str() == s).count();
    assert_eq!(
        (count("cell"), count("welding"), count("transport")),
        (3, 4, 6)
    );
}

/// The thesis' recipes as printed are rejected with exactly these defects.
#[test]
fn the_printed_recipes_are_rejected_with_their_defects() {
    let entries = files::load(&[root().join("tests/fixtures/thesis_printed")], None).expect("load");
    let (_, problems) = check_set(&entries);
    let of = |file: &str| -> BTreeSet<(Option<u16>, ProblemKind)> {
        problems
            .iter()
            .filter(|p| p.origin.ends_with(file))
            .map(|p| (p.state.map(|s| s.0), p.kind))
            .collect()
    };
    use ProblemKind::*;
    assert_eq!(
        of("testrcp3.rcp"),
        BTreeSet::from([
            (Some(7), Inconsistent),
            (Some(16), MissingBranch),
            (Some(17), MissingBranch),
            (Some(17), Unreachable)
        ])
    );
    assert_eq!(
        of("testrcp1.rcp"),
        BTreeSet::from([
            (Some(1), WrongCriterion),
            (Some(2), NoCriterion),
            (Some(4), WrongCriterion),
            (Some(5), NoCriterion)
        ])
    );
    assert_eq!(
        of("testrcp2.rcp"),
        BTreeSet::from([(Some(1), WrongCriterion), (Some(2), NoCriterion)])
    );
    let pip = of("pipdroog.rcp");
    assert!(
        pip.iter().all(|(_, k)| *k == MalformedLine) && pip.len() == 17,
        "{pip:?}"
    );
    for clean in [
        "dikdroog.rcp",
        "dundroog.rcp",
        "testrcp4.rcp",
        "testrcp5.rcp",
        "droog_dik.rcp",
        "droog_dun.rcp",
        "droog_pijp.rcp",
    ] {
        assert_eq!(of(clean), BTreeSet::new(), "{clean}");
    }
    let line = problems
        .iter()
        .find(|p| p.origin.ends_with("testrcp3.rcp") && p.kind == Inconsistent)
        .expect("found");
    assert!(line.to_string().ends_with("testrcp3.rcp:14: state 7: inconsistent: line 13 has `waitline D 1 30`, line 14 has `waitline d 1 90`"), "{line}");
}

/// The printed recipes keep appendix F's right-aligned states (`- 1` …
/// `-10`), and every line beginning with `-` is a table line or a problem:
/// none is lost as a comment.
#[test]
fn the_printed_right_aligned_states_are_read() {
    let dir = root().join("tests/fixtures/thesis_printed");
    let mut right_aligned = 0;
    for kind in ["cell", "welding", "transport"] {
        for entry in std::fs::read_dir(dir.join(kind)).expect("fixtures") {
            let path = entry.expect("entry").path();
            let text = std::fs::read_to_string(&path).expect("fixture");
            if text.lines().any(|l| l.starts_with("- 1 ")) {
                right_aligned += 1;
            }
            let r = falc_recipe::syntax::parse(&text, &path.display().to_string());
            let read: BTreeSet<usize> = r
                .rows
                .iter()
                .map(|row| row.line)
                .chain(r.problems.iter().map(|p| p.line))
                .collect();
            for (i, line) in text.lines().enumerate() {
                if line.trim_start().starts_with('-') {
                    assert!(
                        read.contains(&(i + 1)),
                        "{}:{}: `{line}` was taken as a comment",
                        path.display(),
                        i + 1
                    );
                }
            }
        }
    }
    assert_eq!(
        right_aligned, 6,
        "the printed recipes with ten states or more"
    );
    let text = std::fs::read_to_string(dir.join("cell/dikdroog.rcp")).expect("dikdroog");
    let r = falc_recipe::syntax::parse(&text, "dikdroog.rcp");
    let states: BTreeSet<u16> = r.rows.iter().map(|row| row.state.0).collect();
    assert_eq!(states, (1..=20).collect::<BTreeSet<u16>>());
}

/// What makes a criterion of the current state true, as the world would.
fn trigger(e: &mut Engine, now: &mut Duration, c: &Option<Criterion>) {
    let st = e.program().states[&e.state()].clone();
    let target = match &st.command {
        Command::Start { target, .. } | Command::Wait { target, .. } => Some(target.clone()),
        _ => None,
    };
    let ended = |end| Event::Ended(target.clone().expect("a job command"), end);
    match c {
        None => unreachable!("waiting states have criteria"),
        Some(Criterion::Timeout) => {
            *now = e
                .poll_timeout()
                .expect("a timeout branch needs a running deadline");
            e.handle_timeout(*now);
        }
        Some(Criterion::Started) => e.handle(*now, Event::Started(target.expect("start"))),
        Some(Criterion::Done)
            if matches!(
                st.command,
                Command::WaitInput { .. } | Command::WaitReady { .. }
            ) =>
        {
            e.handle(*now, Event::InputReached)
        }
        Some(Criterion::Done) => e.handle(*now, ended(JobEnd::Done)),
        Some(Criterion::BadProduct) => e.handle(*now, ended(JobEnd::BadProduct)),
        Some(Criterion::FailedSafe) => e.handle(*now, ended(JobEnd::FailedSafe)),
        Some(Criterion::FailedDanger) => e.handle(*now, ended(JobEnd::FailedDanger)),
        Some(Criterion::Answer(a)) => e.handle(*now, Event::Answer(a.to_uppercase())),
        Some(Criterion::AnswerAny) => e.handle(*now, Event::Answer("iets anders".into())),
    }
}

/// Explores every branch of a program from its first state: each
/// (state, criterion) is taken once; returns the rows covered and the
/// outcomes reached.
fn explore(program: &Arc<Program>) -> (BTreeSet<(StateNo, Option<Criterion>)>, BTreeSet<String>) {
    let mut covered = BTreeSet::new();
    let mut outcomes = BTreeSet::new();
    let mut e = Engine::new(program.clone());
    e.start(Duration::ZERO);
    let first: Vec<Action> = std::iter::from_fn(|| e.poll_action()).collect();
    let mut stack = vec![(e, Duration::ZERO, first)];
    while let Some((e, now, actions)) = stack.pop() {
        // Unconditional rows passed on the way.
        for a in &actions {
            if let Action::Entered(s) = a {
                if !program.states[s].command.waits() {
                    covered.insert((*s, None));
                }
            }
        }
        if let Some(o) = e.outcome() {
            outcomes.insert(match o {
                Outcome::Done => "done".to_string(),
                Outcome::Alarm(_) => "alarm".to_string(),
                Outcome::Failed(_) => "failed".to_string(),
            });
            continue;
        }
        let st = program.states[&e.state()].clone();
        assert!(
            st.command.waits(),
            "stuck in state {} of {}",
            st.no,
            program.origin
        );
        for (c, next) in &st.branches {
            if !covered.insert((st.no, c.clone())) {
                continue;
            }
            let mut branch = e.clone();
            let mut t = now;
            trigger(&mut branch, &mut t, c);
            let actions: Vec<Action> = std::iter::from_fn(|| branch.poll_action()).collect();
            let took = if *next == StateNo::END {
                branch.outcome().is_some()
            } else {
                actions.contains(&Action::Entered(*next))
            };
            assert!(
                took,
                "{}: state {} {:?} should lead to {next}; actions {actions:?}",
                program.origin, st.no, c
            );
            stack.push((branch, t, actions));
        }
    }
    (covered, outcomes)
}

#[test]
fn every_criterion_path_of_every_shipped_recipe_runs() {
    for (_, program) in shipped() {
        let program = Arc::new(program);
        let (covered, outcomes) = explore(&program);
        for st in program.states.values() {
            for (c, _) in &st.branches {
                assert!(
                    covered.contains(&(st.no, c.clone())),
                    "{}: state {} {:?} never taken",
                    program.origin,
                    st.no,
                    c
                );
            }
        }
        assert!(
            outcomes.contains("done"),
            "{}: no path ends done",
            program.origin
        );
        assert!(
            outcomes.contains("alarm"),
            "{}: no path ends in alarm",
            program.origin
        );
    }
}

fn falc(args: &[&str]) -> (i32, String) {
    let out = Process::new(env!("CARGO_BIN_EXE_falc"))
        .args(args)
        .current_dir(root())
        .output()
        .expect("falc runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    )
}

#[test]
fn falc_recipe_check_and_dot() {
    let (code, out) = falc(&["recipe", "check", "recipes"]);
    assert_eq!((code, out.as_str()), (0, ""));
    let (code, out) = falc(&["recipe", "list"]);
    assert_eq!(code, 0, "{out}");
    assert_eq!(out.lines().count(), 13, "{out}");
    assert!(
        out.lines()
            .any(|l| l.starts_with("welding") && l.contains("DROOG_DIK") && l.contains("ok")),
        "{out}"
    );
    let (code, out) = falc(&["recipe", "list", "tests/fixtures/thesis_printed/transport"]);
    assert_eq!(code, 1);
    assert!(out.contains("problem(s)"), "{out}");
    let (code, out) = falc(&[
        "recipe",
        "check",
        "tests/fixtures/thesis_printed/transport/testrcp3.rcp",
    ]);
    assert_eq!(code, 1);
    assert_eq!(out.lines().count(), 4, "{out}");
    assert!(
        out.lines()
            .all(|l| l.starts_with("tests/fixtures/thesis_printed/transport/testrcp3.rcp:")),
        "{out}"
    );
    // The cell recipes alone cannot be cross-checked: their workstations are missing.
    let (code, out) = falc(&["recipe", "check", "recipes/cell"]);
    assert_eq!(code, 1);
    assert!(
        out.contains("state 9: no connection with station transport"),
        "{out}"
    );
    // --kind overrides the directory.
    let (code, _) = falc(&[
        "recipe",
        "check",
        "--kind",
        "cell",
        "recipes/welding/droog_dik.rcp",
    ]);
    assert_eq!(code, 1, "a welding recipe is not a cell recipe");
    let (code, dot) = falc(&[
        "recipe",
        "dot",
        "--current",
        "2",
        "recipes/welding/droog_dik.rcp",
    ]);
    assert_eq!(code, 0);
    assert!(dot.starts_with("digraph \"DROOG_DIK\" {"), "{dot}");
    assert!(dot.contains("s1 -> s2 [label=\"started\"];"), "{dot}");
    assert!(
        dot.contains("s2 [label=\"2\\nwait rcm 170\", style=\"rounded,filled\""),
        "{dot}"
    );
    assert!(
        dot.contains("s3 [label=\"3\\n| alarm\", color=red"),
        "{dot}"
    );
}

/// `falc recipe view` draws SVG in-process: on a machine without Graphviz
/// (no `dot` on the PATH) every shipped recipe is drawn, each of its states
/// in the picture with its command; PNG still needs Graphviz and says how
/// to get it.
#[test]
fn falc_recipe_view_draws_svg_without_graphviz_with_every_state() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let no_graphviz = tmp.path().join("bin");
    std::fs::create_dir(&no_graphviz).expect("an empty PATH");
    let view = |args: &[&str], file: &std::path::Path| {
        Process::new(env!("CARGO_BIN_EXE_falc"))
            .env("PATH", &no_graphviz)
            .args(["recipe", "view"])
            .args(args)
            .arg(file)
            .current_dir(root())
            .output()
            .expect("falc runs")
    };
    let entries = files::load(&[root().join("recipes")], None).expect("recipes load");
    assert_eq!(entries.len(), 13);
    for (i, entry) in entries.iter().enumerate() {
        let file = std::path::Path::new(&entry.recipe.origin);
        let out = tmp.path().join(format!("{i}.svg"));
        let run = view(&["--out", &out.display().to_string()], file);
        assert!(run.status.success(), "{}: {run:?}", file.display());
        let svg = std::fs::read_to_string(&out).expect("svg written");
        assert!(svg.contains("<svg"), "{svg}");
        let program = falc_recipe::check::check(&entry.recipe, entry.kind).expect("checks");
        let states: Vec<(u16, String)> = program
            .states
            .values()
            .map(|st| (st.no.0, st.text.clone()))
            .collect();
        assert!(!states.is_empty());
        for (no, text) in states {
            assert!(
                svg.contains(&format!(">{no}</tspan>")),
                "{}: state {no} not drawn",
                file.display()
            );
            let plain = !text.contains(['<', '>', '&', '\'', '"']);
            if plain && !text.is_empty() {
                assert!(
                    svg.contains(&format!(">{text}</tspan>")),
                    "{}: state {no}'s {text:?} not drawn",
                    file.display()
                );
            }
        }
    }
    // PNG is Graphviz's: without it, how to get it.
    let out = tmp.path().join("droog_dik.png");
    let run = view(
        &["--format", "png", "--out", &out.display().to_string()],
        std::path::Path::new("recipes/welding/droog_dik.rcp"),
    );
    assert_eq!(run.status.code(), Some(1));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("install graphviz"), "{err}");
    assert!(!out.exists());
}

/// The trace `falc recipe verify` prints under finding `line` of `out`.
fn trace_under<'a>(out: &'a str, line: &str) -> Vec<&'a str> {
    let at = out.find(line).expect("the finding");
    out[at..]
        .lines()
        .skip(1)
        .take_while(|l| l.starts_with("    "))
        .collect()
}

/// `falc recipe verify`: the shipped set has no defect across levels (its
/// notes are the statuses passed up on purpose and limits with room to
/// spare); with the thesis' printed dikdroog and dundroog in it, the weld's
/// limits disagree both ways, each with a trace, and `--dot` draws one.
#[test]
fn falc_recipe_verify_finds_the_printed_time_limits() {
    let (code, out) = falc(&["recipe", "verify"]);
    assert_eq!(code, 0, "{out}");
    assert!(
        !out.lines()
            .any(|l| l.starts_with("recipes/") && !l.contains(": note: ")),
        "{out}"
    );

    let tmp = tempfile::tempdir().expect("tempdir");
    let tree = crate::support::copy_recipes(tmp.path());
    for printed in ["dikdroog.rcp", "dundroog.rcp"] {
        std::fs::copy(
            root()
                .join("tests/fixtures/thesis_printed/cell")
                .join(printed),
            tree.join("cell").join(printed),
        )
        .expect("copy");
    }
    let dir = tree.display().to_string();
    let (code, out) = falc(&["recipe", "verify", &dir]);
    assert_eq!(code, 1, "{out}");
    let dik = out
        .lines()
        .find(|l| l.contains("dikdroog.rcp:") && l.contains("state 16: time limits disagree"))
        .unwrap_or_else(|| panic!("{out}"));
    assert!(
        dik.contains("allows welding's DROOG_DIK 100 s, but its own limits allow it 180 s"),
        "{dik}"
    );
    let dun = out
        .lines()
        .find(|l| l.contains("dundroog.rcp:") && l.contains("state 16: note: time limits disagree"))
        .unwrap_or_else(|| panic!("{out}"));
    assert!(
        dun.contains("allows welding's DROOG_DUN 200 s, but its own limits end it within 180 s"),
        "{dun}"
    );
    // The trace under the finding goes from the start to the wait.
    let trace = trace_under(&out, dik);
    assert!(
        trace
            .first()
            .is_some_and(|l| l.contains("cell") && l.contains("start → 1")),
        "{trace:?}"
    );
    assert!(
        trace.iter().any(|l| l.contains("welding started")),
        "{trace:?}"
    );

    let (code, dot) = falc(&["recipe", "verify", "--dot", "1", &dir]);
    assert_eq!(code, 0, "{dot}");
    assert!(
        dot.starts_with("digraph trace {") && dot.contains("subgraph cluster_0"),
        "{dot}"
    );
}

/// A transport recipe may name only what its station's conveyor has: the
/// checker and the verifier take each transport station's equipment file
/// from the topology, and name the file, the line and what exists.
#[test]
fn a_recipe_naming_a_line_the_equipment_lacks_is_refused() {
    let dir = tempfile::tempdir().expect("temporary directory");
    let small = root().join("common/equipment/tests/fixtures/small.toml");
    let cell = std::fs::read_to_string(root().join("launch/cell.toml")).expect("cell.toml");
    let topology = cell.replace(
        "device = \"127.0.0.1:5020\"\n",
        &format!(
            "device = \"127.0.0.1:5020\"\nequipment = \"{}\"\n",
            small.display()
        ),
    );
    assert_ne!(topology, cell);
    let path = dir.path().join("cell.toml");
    std::fs::write(&path, topology).expect("write");
    let t = path.display().to_string();
    let (code, out) = falc(&["--topology", &t, "recipe", "check", "recipes/transport"]);
    assert_eq!(code, 1, "{out}");
    // STORE: `activate k` on line 8 of the file; the small conveyor has A, B.
    assert!(
        out.lines()
            .any(|l| l
                == "recipes/transport/store.rcp:10: state 1: small has no line K (lines: A, B)"),
        "{out}"
    );
    assert!(
        out.lines()
            .any(|l| l.starts_with("recipes/transport/move_to_man.rcp:")
                && l.contains("small has no place 5 (places: 2, 3)")),
        "{out}"
    );
    let (code, out) = falc(&["--topology", &t, "recipe", "verify", "recipes"]);
    assert_eq!(code, 1, "{out}");
    assert!(out.contains("small has no line K (lines: A, B)"), "{out}");
    // The shipped topology (no `equipment`: the 1992 conveyor) has them all.
    let (code, out) = falc(&["recipe", "check", "recipes"]);
    assert_eq!((code, out.as_str()), (0, ""));
}

/// `falc recipe verify` chains the workstation recipes' `#PRE` and
/// `#POST` across a cell recipe: the shipped dikdroog's jobs on two
/// stations that its conditions do not order are notes (could run in
/// parallel); a cell recipe that runs STORE twice (its POST leaves place
/// 3 occupied, its PRE needs it empty) is a defect with its trace.
#[test]
fn falc_recipe_verify_chains_pre_and_postconditions() {
    let (code, out) = falc(&["recipe", "verify"]);
    assert_eq!(code, 0, "{out}");
    let parallel: Vec<&str> = out
        .lines()
        .filter(|l| {
            l.starts_with("recipes/cell/dikdroog.rcp") && l.contains("could run in parallel")
        })
        .collect();
    assert_eq!(parallel.len(), 2, "{out}");
    assert!(
        parallel[0].contains("state 13")
            && parallel[0]
                .contains("welding's DROOG_DIK could start before transport's MOVE_TO_MAN ends"),
        "{parallel:?}"
    );
    assert!(
        parallel[1].contains("state 17")
            && parallel[1]
                .contains("transport's UNLOAD could start before welding's DROOG_DIK ends"),
        "{parallel:?}"
    );

    let tmp = tempfile::tempdir().expect("tempdir");
    let tree = crate::support::copy_recipes(tmp.path());
    std::fs::write(
        tree.join("cell/twice.rcp"),
        "twice.rcp: STORE, then STORE again.\n\n\
         -1 | start transport store | | gestart    | 2\n\
         -1 | start transport store | | tijdlimiet | 9\n\
         -2 | wait transport 60     | | klaar      | 3\n\
         -2 | wait transport 60     | | tijdlimiet | 9\n\
         -3 | start transport store | | gestart    | 4\n\
         -3 | start transport store | | tijdlimiet | 9\n\
         -4 | wait transport 60     | | klaar      | 0\n\
         -4 | wait transport 60     | | tijdlimiet | 9\n\
         -9 | output er is wat mis  | alarm |      | 0\n",
    )
    .expect("write");
    let (code, out) = falc(&["recipe", "verify", &tree.display().to_string()]);
    assert_eq!(code, 1, "{out}");
    let line = out
        .lines()
        .find(|l| l.contains("twice.rcp:") && l.contains("precondition cannot hold"))
        .unwrap_or_else(|| panic!("{out}"));
    assert!(
        line.contains("state 3:")
            && line.contains("the precondition of transport's STORE (")
            && line.contains(
                "cannot hold: `place 3 empty`, but STORE, done in state 2, leaves place 3 occupied"
            ),
        "{line}"
    );
    let trace = trace_under(&out, line);
    assert!(
        trace
            .iter()
            .any(|l| l.contains("cell state 2: transport ended done → 3"))
            && trace
                .last()
                .is_some_and(|l| l.contains("cell state 3: transport started → 4")),
        "{trace:?}"
    );
}
