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
