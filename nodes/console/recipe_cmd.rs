//! `falc recipe …`: check recipes (one line per problem, exit 1 if any),
//! list them, and draw one as Graphviz DOT.

use crate::commands::RecipeCommand;
use falc_equipment::Equipment;
use falc_recipe::check::{check, check_set};
use falc_recipe::commands::RecipeKind;
use falc_recipe::dot::to_dot;
use falc_recipe::files::{self, StationKinds};
use falc_recipe::problem::Problem;
use std::path::PathBuf;
use std::process::ExitCode;

/// The recipe kind of each station directory: from the topology at
/// `path` when there is one (a second welding station's `welding2/` holds
/// welding recipes), else from the directory names.
fn station_kinds(path: &std::path::Path) -> StationKinds {
    if !path.exists() {
        return StationKinds::default();
    }
    match falc_model::topology::Topology::load(path) {
        Ok(t) => StationKinds::of(&t),
        Err(e) => {
            eprintln!("falc: {e}; the recipe kinds come from the directory names");
            StationKinds::default()
        }
    }
}

/// What the set's transport recipes name that their station's equipment
/// lacks: each transport station's file as the topology at `path` names
/// it (absent, or no topology: the 1992 conveyor), as the recipe store
/// checks it.
fn equipment_problems(
    path: &std::path::Path,
    programs: &[(falc_model::ids::StationName, falc_recipe::check::Program)],
) -> Result<Vec<Problem>, String> {
    let stations = if path.exists() {
        match falc_model::topology::Topology::load(path) {
            Ok(t) => Equipment::of_topology(&t)?,
            Err(_) => Default::default(),
        }
    } else {
        Default::default()
    };
    Ok(falc_equipment::vocabulary::lacking_in(&stations, programs))
}

/// The programs of a checked set by station, and every problem found.
type Checked = (
    Vec<(falc_model::ids::StationName, falc_recipe::check::Program)>,
    Vec<Problem>,
);

/// The set checked, and its transport recipes against their stations'
/// equipment ([`equipment_problems`]); where a recipe tree of `paths` has
/// a `robot/` directory, its programs are checked and every `start rcm N`
/// must name one of them. The programs and every problem; None (said on
/// stdout) if an equipment file or a robot program does not load.
fn checked(
    entries: &[falc_recipe::check::Entry],
    paths: &[PathBuf],
    topology: &std::path::Path,
) -> Option<Checked> {
    let (programs, mut problems) = check_set(entries);
    match equipment_problems(topology, &programs) {
        Ok(found) => problems.extend(found),
        Err(e) => {
            crate::out!("{e}");
            return None;
        }
    }
    let mut held = None;
    for tree in trees(paths).iter().filter(|p| p.is_dir()) {
        match files::load_robot(tree) {
            Ok(Some(robot)) => held
                .get_or_insert_with(std::collections::BTreeSet::new)
                .extend(robot.iter().map(|r| r.program.number)),
            Ok(None) => {}
            Err(errors) => {
                errors.iter().for_each(|e| crate::out!("{e}"));
                return None;
            }
        }
    }
    if let Some(held) = held {
        problems.extend(falc_recipe::robot_program::lacking(&programs, &held));
    }
    Some((programs, problems))
}

/// The paths a command reads: those given, else `recipes`.
fn trees(paths: &[PathBuf]) -> Vec<PathBuf> {
    if paths.is_empty() {
        vec![PathBuf::from("recipes")]
    } else {
        paths.to_vec()
    }
}

/// The DOT text of one recipe file, or every reason it has none.
fn dot_of(
    file: &std::path::Path,
    kind: Option<RecipeKind>,
    current: Option<u16>,
    kinds: &StationKinds,
) -> Result<String, Vec<String>> {
    let entries = files::load_in(&[file.to_path_buf()], kind, kinds)?;
    let Some(entry) = entries.first() else {
        return Err(vec![format!("{}: no recipe", file.display())]);
    };
    dot_of_entry(entry, current)
}

/// The DOT text of a read recipe, `current` highlighted; or its problems.
pub fn dot_of_entry(
    entry: &falc_recipe::check::Entry,
    current: Option<u16>,
) -> Result<String, Vec<String>> {
    let program = check(&entry.recipe, entry.kind)
        .map_err(|p| p.iter().map(ToString::to_string).collect::<Vec<_>>())?;
    let title = entry
        .name()
        .map_or_else(|_| "recipe".into(), |n| n.to_string());
    Ok(to_dot(
        &program,
        &title,
        current.map(falc_recipe::syntax::StateNo),
    ))
}

/// Draws `dot` to `out`: SVG in this process (layout-rs: no Graphviz
/// needed), PNG with Graphviz `dot`.
pub fn draw(dot: &str, format: &str, out: &std::path::Path) -> Result<(), String> {
    if format != "svg" {
        return graphviz(dot, format, out);
    }
    let svg = svg_of(dot)?;
    std::fs::write(out, svg).map_err(|e| format!("cannot write {}: {e}", out.display()))
}

/// `dot` laid out and drawn as SVG by layout-rs. A diagram it cannot draw
/// is an error, never a crash: layout-rs 0.1.3 gives up by panicking in
/// places, so the drawing runs under `catch_unwind`, with the panic's
/// message kept off the terminal.
pub fn svg_of(dot: &str) -> Result<String, String> {
    use layout::backends::svg::SVGWriter;
    use layout::gv::{DotParser, GraphBuilder};
    let dot = dot.to_string();
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let drawn = std::panic::catch_unwind(move || {
        let mut parser = DotParser::new(&dot);
        let graph = parser
            .process()
            .map_err(|e| format!("the diagram cannot be read: {e}"))?;
        let mut builder = GraphBuilder::new();
        builder.visit_graph(&graph);
        let mut visual = builder.get();
        let mut svg = SVGWriter::new();
        visual.do_it(false, false, false, &mut svg);
        Ok(svg.finalize())
    });
    std::panic::set_hook(hook);
    drawn.unwrap_or_else(|_| Err("the diagram could not be laid out (layout-rs gave up)".into()))
}

/// Runs Graphviz `dot -T<format> -o <out>` on `dot`.
pub fn graphviz(dot: &str, format: &str, out: &std::path::Path) -> Result<(), String> {
    use std::io::Write;
    let mut child = std::process::Command::new("dot")
        .arg(format!("-T{format}"))
        .arg("-o")
        .arg(out)
        .stdin(std::process::Stdio::piped())
        .spawn()
        .map_err(|e| {
            format!(
                "cannot run Graphviz `dot` ({e}): install graphviz (apt-get install graphviz), or use `falc recipe dot FILE` and any DOT viewer"
            )
        })?;
    if let Some(mut stdin) = child.stdin.take() {
        stdin
            .write_all(dot.as_bytes())
            .map_err(|e| format!("writing to `dot`: {e}"))?;
    }
    let status = child.wait().map_err(|e| format!("`dot`: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("`dot` ended with {status}"))
    }
}

/// Loads `paths` (default `recipes`); on failure says each error with `say`.
fn load_or_say(
    paths: &[PathBuf],
    kind: Option<RecipeKind>,
    kinds: &StationKinds,
    say: impl Fn(&str),
) -> Option<Vec<falc_recipe::check::Entry>> {
    match files::load_in(&trees(paths), kind, kinds) {
        Ok(e) => Some(e),
        Err(errors) => {
            errors.iter().for_each(|e| say(e));
            None
        }
    }
}

/// Runs a `falc recipe` command; `topology` tells each station's kind.
pub fn run(cmd: RecipeCommand, topology: &std::path::Path) -> ExitCode {
    let kinds = station_kinds(topology);
    match cmd {
        RecipeCommand::View {
            kind,
            current,
            format,
            out,
            file,
        } => {
            let dot = match dot_of(&file, kind, current, &kinds) {
                Ok(d) => d,
                Err(errors) => {
                    errors.iter().for_each(|e| eprintln!("{e}"));
                    return ExitCode::FAILURE;
                }
            };
            let out = out.unwrap_or_else(|| file.with_extension(&format));
            match draw(&dot, &format, &out) {
                Ok(()) => {
                    crate::out!("{}", out.display());
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("falc: {e}");
                    ExitCode::FAILURE
                }
            }
        }
        RecipeCommand::List { paths } => {
            let Some(entries) = load_or_say(&paths, None, &kinds, |e| eprintln!("{e}")) else {
                return ExitCode::FAILURE;
            };
            let (_, problems) = check_set(&entries);
            for e in &entries {
                let origin = &e.recipe.origin;
                let name = e.name().map_or_else(|_| "?".to_string(), |n| n.to_string());
                let states: std::collections::BTreeSet<_> =
                    e.recipe.rows.iter().map(|r| r.state).collect();
                let n = problems.iter().filter(|p| &p.origin == origin).count();
                let verdict = if n == 0 {
                    "ok".to_string()
                } else {
                    format!("{n} problem(s)")
                };
                crate::out!(
                    "{:<10} {:<14} {:>3} states  {:<14} {origin}",
                    e.station.as_str(),
                    name,
                    states.len(),
                    verdict
                );
            }
            if problems.is_empty() {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            }
        }
        RecipeCommand::Check { kind, paths } => {
            // Problems go to stdout, one per line, for scripts.
            let Some(entries) = load_or_say(&paths, kind, &kinds, |e| crate::out!("{e}")) else {
                return ExitCode::FAILURE;
            };
            let Some((programs, problems)) = checked(&entries, &paths, topology) else {
                return ExitCode::FAILURE;
            };
            for p in &problems {
                crate::out!("{p}");
            }
            if problems.is_empty() {
                eprintln!("{} recipes checked: no problems", programs.len());
                ExitCode::SUCCESS
            } else {
                eprintln!(
                    "{} recipes checked: {} problems",
                    entries.len(),
                    problems.len()
                );
                ExitCode::FAILURE
            }
        }
        RecipeCommand::Verify { limit, dot, paths } => verify(paths, limit, dot, &kinds, topology),
        RecipeCommand::Dot {
            kind,
            current,
            file,
        } => match dot_of(&file, kind, current, &kinds) {
            Ok(d) => {
                crate::out!("{}", d.trim_end_matches('\n'));
                ExitCode::SUCCESS
            }
            Err(errors) => {
                errors.iter().for_each(|e| eprintln!("{e}"));
                ExitCode::FAILURE
            }
        },
    }
}

/// `falc recipe verify`: checks the set first (verification needs clean
/// recipes), then verifies it across levels.
fn verify(
    paths: Vec<PathBuf>,
    limit: usize,
    dot: Option<usize>,
    kinds: &StationKinds,
    topology: &std::path::Path,
) -> ExitCode {
    let Some(entries) = load_or_say(&paths, None, kinds, |e| crate::out!("{e}")) else {
        return ExitCode::FAILURE;
    };
    let Some((programs, problems)) = checked(&entries, &paths, topology) else {
        return ExitCode::FAILURE;
    };
    if !problems.is_empty() {
        for p in &problems {
            crate::out!("{p}");
        }
        eprintln!(
            "{} problems: `falc recipe check` must be clean before the recipes can be verified",
            problems.len()
        );
        return ExitCode::FAILURE;
    }
    let begin = std::time::Instant::now();
    let report = falc_recipe::verify::verify_with_limit(&programs, limit);
    let took = begin.elapsed();
    if let Some(n) = dot {
        return match n.checked_sub(1).and_then(|i| report.findings.get(i)) {
            Some(f) => {
                crate::out!(
                    "{}",
                    falc_recipe::dot::trace_to_dot(&f.trace, &f.to_string()).trim_end()
                );
                ExitCode::SUCCESS
            }
            None => {
                eprintln!("falc: no finding {n}: there are {}", report.findings.len());
                ExitCode::FAILURE
            }
        };
    }
    for (i, f) in report.findings.iter().enumerate() {
        crate::out!("{f}");
        for line in f.trace.lines() {
            crate::out!("    {line}");
        }
        if i + 1 < report.findings.len() {
            crate::out!("");
        }
    }
    for b in &report.bounded {
        eprintln!("{b}");
    }
    let defects = report.defects().count();
    eprintln!(
        "{} recipes verified across levels: {} states explored in {:.1} ms; {defects} defects, {} notes",
        programs.len(),
        report.states,
        took.as_secs_f64() * 1000.0,
        report.findings.len() - defects
    );
    if defects == 0 && report.bounded.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}

#[cfg(test)]
mod tests {
    use super::svg_of;

    #[test]
    fn a_diagram_layout_rs_cannot_draw_is_an_error_not_a_crash() {
        let svg = svg_of("digraph \"T\" {\n  s1 [label=\"1\\nstart rcm 65\"];\n  s1 -> s0;\n}\n")
            .expect("drawn");
        assert!(svg.contains(">start rcm 65</tspan>"), "{svg}");
        for bad in [
            "digraph {",
            "",
            "graph { a -> ",
            "digraph { a [label=\"x\" }",
        ] {
            let e = svg_of(bad).expect_err(bad);
            assert!(e.starts_with("the diagram"), "{bad:?}: {e}");
        }
    }
}
