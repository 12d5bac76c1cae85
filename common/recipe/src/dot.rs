//! Graphviz DOT of a recipe, drawn as the thesis draws them: one node per
//! state showing its number, command and report, edges labelled with the
//! criteria; state 0 is the end. An alarm state is drawn red; `current`
//! (a running recipe's state) is filled.

use super::check::Program;
use super::syntax::{Report, StateNo};
use std::fmt::Write;

fn escape(s: &str) -> String {
    s.replace('\\', "\\\\").replace('"', "\\\"")
}

/// The DOT text of `program`, highlighting `current` if given.
pub fn to_dot(program: &Program, title: &str, current: Option<StateNo>) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "digraph \"{}\" {{", escape(title));
    let _ = writeln!(out, "  rankdir=TB;\n  node [shape=box, style=rounded, fontname=\"Helvetica\"];\n  edge [fontname=\"Helvetica\", fontsize=10];");
    let _ = writeln!(out, "  s0 [label=\"0\\nend\", shape=doublecircle];");
    for st in program.states.values() {
        let mut label = format!("{}", st.no);
        if !st.text.is_empty() {
            label.push_str("\\n");
            label.push_str(&escape(&st.text));
        }
        let mut attrs = String::new();
        if st.report == Some(Report::Alarm) {
            label.push_str("\\n| alarm");
            attrs.push_str(", color=red, fontcolor=red");
        }
        if Some(st.no) == current {
            attrs.push_str(", style=\"rounded,filled\", fillcolor=lightblue");
        }
        let _ = writeln!(out, "  s{} [label=\"{label}\"{attrs}];", st.no);
    }
    for st in program.states.values() {
        for (c, next) in &st.branches {
            match c {
                Some(c) => {
                    let _ = writeln!(
                        out,
                        "  s{} -> s{next} [label=\"{}\"];",
                        st.no,
                        escape(&c.to_string())
                    );
                }
                None => {
                    let _ = writeln!(out, "  s{} -> s{next};", st.no);
                }
            }
        }
    }
    out.push_str("}\n");
    out
}

/// The DOT text of a verifier's counterexample: the states of each level
/// in order, edges labelled with the events, each job's own trace in a box
/// of its own joined to the step it explains; `finding` titles it.
pub fn trace_to_dot(trace: &super::verify::Trace, finding: &str) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "digraph trace {{");
    let _ = writeln!(
        out,
        "  label=\"{}\";\n  labelloc=t;\n  rankdir=TB;\n  node [shape=box, style=rounded, fontname=\"Helvetica\"];\n  edge [fontname=\"Helvetica\", fontsize=10];",
        escape(finding)
    );
    let mut next = 0usize;
    let _ = trace_cluster(trace, &mut out, &mut next);
    let _ = writeln!(out, "}}");
    out
}

/// Writes `trace` as a cluster (node ids from `next` on); returns the id
/// of its start node.
fn trace_cluster(trace: &super::verify::Trace, out: &mut String, next: &mut usize) -> usize {
    let cluster = *next;
    *next += 1;
    let _ = writeln!(
        out,
        "  subgraph cluster_{cluster} {{\n    label=\"{} {}\";",
        escape(&trace.level),
        escape(&trace.origin)
    );
    let path = super::verify::path_text;
    let first = *next;
    *next += 1;
    let _ = writeln!(
        out,
        "    n{first} [label=\"start → {}\"];",
        path(&trace.start)
    );
    let mut ids = Vec::new();
    let mut last = first;
    for step in &trace.steps {
        let id = *next;
        *next += 1;
        let _ = writeln!(
            out,
            "    n{id} [label=\"{}\"];",
            escape(&path(&step.entered))
        );
        let _ = writeln!(
            out,
            "    n{last} -> n{id} [label=\"state {}: {}\"];",
            step.at,
            escape(&step.event.to_string())
        );
        ids.push(id);
        last = id;
    }
    if let Some(e) = trace.ending {
        let id = *next;
        *next += 1;
        let _ = writeln!(
            out,
            "    n{id} [label=\"ends {}\", shape=doublecircle];",
            escape(&e.to_string())
        );
        let _ = writeln!(out, "    n{last} -> n{id};");
    }
    let _ = writeln!(out, "  }}");
    for (step, id) in trace.steps.iter().zip(&ids) {
        if let Some(below) = &step.below {
            let start = trace_cluster(below, out, next);
            let _ = writeln!(
                out,
                "  n{start} -> n{id} [style=dashed, label=\"explains\"];"
            );
        }
    }
    first
}
