//! What the console prints: each answer of the operator API as text for a
//! person (every field escaped, times in this PC's zone) or as one JSON
//! document for scripts (`--json`: the value itself, without the reply's
//! variant around it).

use crate::clock::time_of_day_ms;
use crate::history;
use falc_bus::operator_service::CallError;
use falc_model::api::{ApiReply, CellStatus, PlantStatus};
use falc_model::ids::printable;
use falc_model::records::{Entry, Order};
use std::process::ExitCode;

pub(crate) fn show_order(o: &Order) -> String {
    let mut line = format!(
        "{:>4}  {:<12} {:<11} by {}",
        o.id,
        printable(&o.recipe),
        o.state,
        printable(&o.added_by)
    );
    if o.priority != 0 {
        line.push_str(&format!("  priority {}", o.priority));
    }
    if let Some(due) = o.due_ms {
        line.push_str(&format!("  due {}", crate::clock::date_time(due)));
    }
    match (&o.cell, &o.wanted) {
        (Some(cell), _) => line.push_str(&format!("  on {}", printable(cell))),
        (None, Some(wanted)) => line.push_str(&format!("  for {}", printable(wanted))),
        (None, None) => {}
    }
    if let Some(job) = &o.job_order {
        line.push_str(&format!("  job order {}", printable(job)));
    }
    if let Some(r) = &o.result {
        line.push_str(&format!("  ({})", printable(r)));
    }
    line
}

/// One journal entry as a line: its text and its author escaped, so that
/// neither a newline nor a terminal escape in them reaches the terminal.
pub(crate) fn show_entry(e: &Entry) -> String {
    let order = e.order.map(|o| format!(" #{o}")).unwrap_or_default();
    format!(
        "{} {:<8}{order} {}: {}",
        time_of_day_ms(e.at_ms),
        e.kind.as_str(),
        printable(&e.who),
        printable(&e.text)
    )
}

/// A plant at a glance: a line per cell (its list, running order, queue,
/// mode, alarm, question, stations), then how to see one cell whole.
pub(crate) fn show_plant(p: &PlantStatus) -> String {
    let mut out = Vec::new();
    for (cell, s) in &p.cells {
        let running = s.running.as_ref().map_or("no order".to_string(), |o| {
            format!("order {} ({})", o.id, printable(&o.recipe))
        });
        let mut line = format!(
            "{:<8} list {:<7} {running}, {} queued, {}",
            cell.as_str(),
            s.list.as_str(),
            s.queued,
            s.mode
        );
        if !s.cell_associated {
            line.push_str(", NOT associated");
        }
        if let Some(a) = &s.alarm {
            line.push_str(&format!("  ALARM: {}", printable(a)));
        }
        if let Some(q) = &s.question {
            line.push_str(&format!(
                "  QUESTION: {}",
                printable(&q.replace('\n', " / "))
            ));
        }
        let stations: Vec<String> = s
            .stations
            .iter()
            .map(|st| {
                let how = if !st.connected {
                    "NO CONNECTION"
                } else if st.status.is_some() {
                    "ok"
                } else {
                    "?"
                };
                format!("{} {how}", st.name)
            })
            .collect();
        line.push_str(&format!("  [{}]", stations.join(", ")));
        out.push(line);
    }
    out.push("one cell whole: falc --cell CELL status".into());
    out.join("\n")
}

pub(crate) fn show_status(s: &CellStatus) -> String {
    let mut out = Vec::new();
    let list = s.list.as_str();
    out.push(match &s.running {
        Some(o) => format!("list {list}; running order {} ({})", o.id, o.recipe),
        None => format!("list {list}; no order running"),
    });
    out.push(format!("queued orders: {}", s.queued));
    out.push(format!("mode: {}", s.mode));
    for st in &s.stations {
        if let Some((v, h)) = st.status.as_ref().and_then(|v| Some((v, v.held.as_ref()?))) {
            let program = v
                .program
                .as_ref()
                .map_or(String::new(), |p| format!("{} ", p.name));
            out.push(format!(
                "STEP: {} {program}state {} waits: {}  (falc step --station {})",
                st.name, h.state, h.command, st.name
            ));
        }
    }
    out.push(if s.cell_associated {
        "cell: associated".to_string()
    } else {
        format!(
            "cell: NOT associated: {}",
            s.problem.as_deref().unwrap_or("not yet tried")
        )
    });
    if let Some(a) = &s.alarm {
        out.push(format!("ALARM: {}  (falc ack)", printable(a)));
    }
    let others = s
        .alarms
        .len()
        .saturating_sub(usize::from(s.alarm.is_some()));
    if others > 0 {
        out.push(format!("{others} more alarm(s) in the list (falc alarms)"));
    }
    if let Some(q) = &s.question {
        out.push(format!(
            "QUESTION: {}  (falc answer …)",
            printable(&q.replace('\n', " / "))
        ));
    }
    if s.shutdown_pending {
        out.push("shutting down when the running order ends".into());
    }
    for st in &s.stations {
        out.push(match &st.status {
            _ if !st.connected => format!("  {:<10} NO CONNECTION", st.name.as_str()),
            Some(v) => format!(
                "  {:<10} {:?}, {:?}, recipe {}{}{}",
                st.name.as_str(),
                v.physical,
                v.logical,
                v.local_detail,
                v.equipment_state
                    .as_ref()
                    .map_or(String::new(), |s| format!(", equipment: {}", printable(s))),
                v.unready
                    .as_ref()
                    .map_or(String::new(), |why| format!(", not ready: {why}"))
            ),
            None => format!("  {:<10} no status seen", st.name.as_str()),
        });
        // Its recipes a Start would refuse now, and why.
        if let Some(v) = st.status.as_ref().filter(|_| st.connected) {
            for why in v.unmet.values() {
                out.push(format!("  {:<10} not startable: {}", "", printable(why)));
            }
        }
    }
    out.join("\n")
}

/// A reply as one JSON document for scripts: the value itself, without the
/// reply's variant around it (`falc status --json` is the status object;
/// `Done` is `{"done": "…"}`).
fn to_json(reply: &ApiReply) -> serde_json::Result<String> {
    match reply {
        ApiReply::Status(s) => serde_json::to_string(s),
        ApiReply::Plant(p) => serde_json::to_string(p),
        ApiReply::Orders(o) => serde_json::to_string(o),
        ApiReply::Order(o) => serde_json::to_string(o),
        ApiReply::Entries(e) => serde_json::to_string(e),
        ApiReply::Done(text) => serde_json::to_string(&serde_json::json!({ "done": text })),
        ApiReply::Recipes(r) => serde_json::to_string(r),
        ApiReply::Recipe(r) => serde_json::to_string(r),
        ApiReply::Versions(v) => serde_json::to_string(v),
        ApiReply::RecipeAt { version, text } => {
            serde_json::to_string(&serde_json::json!({ "version": version, "text": text }))
        }
        ApiReply::OrderRecord(r) => serde_json::to_string(r),
        ApiReply::Figures(f) => serde_json::to_string(f),
    }
}

pub(crate) fn print(reply: &ApiReply, json: bool) {
    if json {
        match to_json(reply) {
            Ok(s) => crate::out!("{s}"),
            Err(e) => eprintln!("falc: cannot write JSON: {e}"),
        }
        return;
    }
    match reply {
        ApiReply::Status(s) => crate::out!("{}", show_status(s)),
        ApiReply::Plant(p) => crate::out!("{}", show_plant(p)),
        ApiReply::Orders(v) if v.is_empty() => crate::out!("the order list is empty"),
        ApiReply::Orders(v) => v.iter().for_each(|o| crate::out!("{}", show_order(o))),
        ApiReply::Order(o) => crate::out!("added: {}", show_order(o)),
        ApiReply::Entries(v) => v.iter().for_each(|e| crate::out!("{}", show_entry(e))),
        ApiReply::Done(text) => crate::out!("{text}"),
        ApiReply::Recipes(v) => v.iter().for_each(|r| {
            crate::out!(
                "{:<28} {}",
                r.file.to_string(),
                r.name.as_deref().unwrap_or("?")
            )
        }),
        ApiReply::Recipe(r) => crate::out!("{}", r.text.trim_end_matches('\n')),
        ApiReply::RecipeAt { text, .. } => crate::out!("{}", text.trim_end_matches('\n')),
        ApiReply::Versions(v) => crate::out!("{}", history::show_versions(v)),
        ApiReply::OrderRecord(r) => crate::out!("{}", history::show_record(r)),
        ApiReply::Figures(f) => crate::out!("{}", crate::figures::show(f)),
    }
}

/// Says why and exits 1.
pub(crate) fn refuse(why: &str) -> ExitCode {
    eprintln!("falc: {}", printable(why));
    ExitCode::FAILURE
}

/// Says why a call brought no reply and exits 1 if the operator refused
/// it, 2 if the operator node could not be reached (or the router refused
/// the call: zenoh cannot tell them apart).
pub(crate) fn fail(why: &CallError) -> ExitCode {
    eprintln!("falc: {}", printable(&why.to_string()));
    match why {
        CallError::Refused(_) => ExitCode::FAILURE,
        CallError::NoReply(_) => ExitCode::from(2),
    }
}
