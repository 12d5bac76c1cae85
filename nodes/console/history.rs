//! `falc store history|diff|rollback` (also as `falc recipe …`), `falc
//! order show` and `falc records export`: the saved versions of a store
//! recipe, what changed between two, an earlier one saved again; what the
//! records say of one order (the recipe versions of each run, each
//! workstation job, its journal, its alarms), and of every order of a
//! range as CSV or JSON.

use crate::call::CALL_LIMIT;
use crate::clock::date_time;
use crate::commands::{RecordsCommand, VersionCommand};
use crate::lines;
use crate::output::fail;
use crate::output::show_entry;
use falc_bus::Bus;
use falc_model::api::{ApiReply, ApiRequest};
use falc_model::ids::{printable, StationName};
use falc_model::product::{line_diff, OrderRecord, RecipeVersion};
use falc_model::recipe_file::RecipeFile;
use std::process::ExitCode;

/// Lines of context around each change in a diff.
const CONTEXT: usize = 2;

impl VersionCommand {
    fn file(&self) -> Result<RecipeFile, String> {
        match self {
            Self::History { station, file }
            | Self::Diff { station, file, .. }
            | Self::Rollback { station, file, .. } => RecipeFile::new(station.clone(), file),
        }
    }
}

/// A CSV field, quoted when it must be (RFC 4180).
fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}

/// The CSV header of [`csv_row`].
const CSV_HEADER: &str =
    "order,recipe,cell,state,started_utc,ended_utc,result,recipe_versions,jobs,alarms";

/// One order record as a CSV row: its recipe versions as
/// `file@version:hash` and its jobs as `station/program:outcome:seconds`,
/// each list `;`-separated.
fn csv_row(r: &OrderRecord) -> String {
    let o = &r.order;
    let utc = |ms: Option<i64>| ms.map(falc_model::time::utc_text).unwrap_or_default();
    let versions: Vec<String> = r
        .runs
        .iter()
        .flat_map(|run| &run.recipes)
        .map(|u| format!("{}@{}:{}", u.file, u.version, u.hash.short()))
        .collect();
    let jobs: Vec<String> = r
        .jobs
        .iter()
        .map(|j| {
            let secs = j
                .started_ms
                .map(|s| format!("{:.1}", (j.ended_ms - s) as f64 / 1000.0))
                .unwrap_or_default();
            format!("{}/{}:{}:{secs}", j.station, j.program, j.outcome)
        })
        .collect();
    let alarms: Vec<String> = r
        .alarms
        .iter()
        .map(|a| format!("{} {}: {}", a.class, a.station, a.text))
        .collect();
    [
        o.id.to_string(),
        o.recipe.clone(),
        o.cell.clone().unwrap_or_default(),
        o.state.to_string(),
        utc(o.started_ms),
        utc(o.ended_ms),
        o.result.clone().unwrap_or_default(),
        versions.join(";"),
        jobs.join(";"),
        alarms.join(";"),
    ]
    .iter()
    .map(|f| csv_field(f))
    .collect::<Vec<_>>()
    .join(",")
}

/// `falc records export`.
pub async fn export(bus: &Bus, operator: &StationName, cmd: RecordsCommand) -> ExitCode {
    let RecordsCommand::Export { range, format, out } = cmd;
    let now = crate::clock::now_ms();
    let (since, until) = match range.range(now) {
        Ok((since, until)) => (since, until.unwrap_or(now)),
        Err(e) => return crate::output::refuse(&e),
    };
    let orders = match bus.api(operator, ApiRequest::OrderList, CALL_LIMIT).await {
        Ok(ApiReply::Orders(o)) => o,
        Ok(other) => {
            return crate::output::refuse(&format!("unexpected answer to order-list: {other:?}"))
        }
        Err(e) => return fail(&e),
    };
    let mut records = Vec::new();
    for o in orders
        .iter()
        .filter(|o| o.started_ms.is_some_and(|s| (since..until).contains(&s)))
    {
        match bus
            .api(operator, ApiRequest::OrderShow { id: o.id }, CALL_LIMIT)
            .await
        {
            Ok(ApiReply::OrderRecord(r)) => records.push(*r),
            Ok(other) => {
                return crate::output::refuse(&format!(
                    "unexpected answer to order-show: {other:?}"
                ))
            }
            Err(e) => return fail(&e),
        }
    }
    let text = if format == "json" {
        match serde_json::to_string_pretty(&records) {
            Ok(t) => t,
            Err(e) => return crate::output::refuse(&format!("cannot write JSON: {e}")),
        }
    } else {
        std::iter::once(CSV_HEADER.to_string())
            .chain(records.iter().map(csv_row))
            .collect::<Vec<_>>()
            .join("\n")
    };
    match out {
        Some(path) => match std::fs::write(&path, format!("{text}\n")) {
            Ok(()) => {
                crate::out!("{} orders to {}", records.len(), path.display());
                ExitCode::SUCCESS
            }
            Err(e) => crate::output::refuse(&format!("cannot write {}: {e}", path.display())),
        },
        None => {
            crate::out!("{text}");
            ExitCode::SUCCESS
        }
    }
}

/// Runs a version command against the operator's store.
pub async fn run(bus: &Bus, operator: &StationName, cmd: VersionCommand, json: bool) -> ExitCode {
    let file = match cmd.file() {
        Ok(f) => f,
        Err(e) => return crate::output::refuse(&e),
    };
    let request = match cmd {
        VersionCommand::History { .. } => ApiRequest::RecipeHistory { file },
        VersionCommand::Rollback {
            version, message, ..
        } => ApiRequest::RecipeRollback {
            file,
            version,
            message,
        },
        VersionCommand::Diff { v1, v2, .. } => {
            return diff(bus, operator, file, v1, v2, json).await
        }
    };
    crate::call::once(bus, operator, request, json).await
}

/// Version `version` of `file` and its text.
async fn fetch(
    bus: &Bus,
    operator: &StationName,
    file: &RecipeFile,
    version: u32,
) -> Result<(RecipeVersion, String), ExitCode> {
    let request = ApiRequest::RecipeVersion {
        file: file.clone(),
        version,
    };
    match bus.api(operator, request, CALL_LIMIT).await {
        Ok(ApiReply::RecipeAt { version, text }) => Ok((version, text)),
        Ok(other) => Err(crate::output::refuse(&format!(
            "unexpected answer to recipe-version: {other:?}"
        ))),
        Err(e) => Err(fail(&e)),
    }
}

/// `diff`: both texts fetched, compared here.
async fn diff(
    bus: &Bus,
    operator: &StationName,
    file: RecipeFile,
    v1: u32,
    v2: Option<u32>,
    json: bool,
) -> ExitCode {
    let v2 = match v2 {
        Some(v) => v,
        None => match bus
            .api(
                operator,
                ApiRequest::RecipeHistory { file: file.clone() },
                CALL_LIMIT,
            )
            .await
        {
            Ok(ApiReply::Versions(v)) => v.last().map_or(v1, |v| v.version),
            Ok(other) => {
                return crate::output::refuse(&format!(
                    "unexpected answer to recipe-history: {other:?}"
                ))
            }
            Err(e) => return fail(&e),
        },
    };
    let (a, b) = match (
        fetch(bus, operator, &file, v1).await,
        fetch(bus, operator, &file, v2).await,
    ) {
        (Ok(a), Ok(b)) => (a, b),
        (Err(code), _) | (_, Err(code)) => return code,
    };
    let lines = line_diff(&a.1, &b.1);
    if json {
        let doc = serde_json::json!({
            "from": a.0,
            "to": b.0,
            "lines": lines.iter().map(|(c, l)| format!("{c}{l}")).collect::<Vec<_>>(),
        });
        crate::out!("{doc}");
        return ExitCode::SUCCESS;
    }
    crate::out!("--- {file} version {} ({})", a.0.version, a.0.hash.short());
    crate::out!("+++ {file} version {} ({})", b.0.version, b.0.hash.short());
    for line in hunks(&lines) {
        crate::out!("{line}");
    }
    ExitCode::SUCCESS
}

/// The changed lines of a diff with [`CONTEXT`] lines around each, a
/// `@@ line N` before each run (N: the line in the later text).
fn hunks(lines: &[(char, &str)]) -> Vec<String> {
    let near = |i: usize| {
        let lo = i.saturating_sub(CONTEXT);
        let hi = (i + CONTEXT + 1).min(lines.len());
        lines[lo..hi].iter().any(|(c, _)| *c != ' ')
    };
    let mut out = Vec::new();
    let mut line_new = 0;
    let mut shown_last = false;
    for (i, (c, l)) in lines.iter().enumerate() {
        if *c != '-' {
            line_new += 1;
        }
        if near(i) {
            if !shown_last {
                out.push(format!("@@ line {line_new}"));
            }
            out.push(format!("{c}{}", printable(l)));
            shown_last = true;
        } else {
            shown_last = false;
        }
    }
    if out.is_empty() {
        out.push("(the same text)".into());
    }
    out
}

/// `history`: a version a line.
pub fn show_versions(versions: &[RecipeVersion]) -> String {
    versions
        .iter()
        .map(|v| {
            let message = if v.message.is_empty() {
                String::new()
            } else {
                format!("  {}", printable(&v.message))
            };
            format!(
                "{:>3}  {}  {}  {:<10}{message}",
                v.version,
                v.hash.short(),
                date_time(v.at_ms),
                printable(&v.author)
            )
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// `order show`: the order, each run with its recipe versions, the
/// alarms, the journal.
pub fn show_record(r: &OrderRecord) -> String {
    let o = &r.order;
    let mut out = vec![format!(
        "order {}  {}  {}  added by {}",
        o.id,
        printable(&o.recipe),
        o.state,
        printable(&o.added_by)
    )];
    let when = |ms: Option<i64>| ms.map_or_else(|| "-".into(), date_time);
    out.push(format!(
        "  started {}  ended {}{}",
        when(o.started_ms),
        when(o.ended_ms),
        o.cell
            .as_deref()
            .map(|c| format!("  on {}", printable(c)))
            .unwrap_or_default()
    ));
    if let Some(job) = &o.job_order {
        out.push(format!("  job order: {}", printable(job)));
    }
    if let Some(result) = &o.result {
        out.push(format!("  result: {}", printable(result)));
    }
    for (n, run) in r.runs.iter().enumerate() {
        out.push(format!("run {} from {}:", n + 1, date_time(run.started_ms)));
        for u in &run.recipes {
            let starts = if u.starts.is_empty() {
                String::new()
            } else {
                format!("  starts {}", printable(&u.starts.join(", ")))
            };
            out.push(format!(
                "  {:<22} {:<26} version {:>3}  {}{starts}",
                printable(&u.domain),
                u.file.to_string(),
                u.version,
                u.hash.short()
            ));
        }
    }
    if r.runs.is_empty() {
        out.push(
            "no run recorded (not started, or started before recipe versions were kept)".into(),
        );
    }
    if !r.jobs.is_empty() {
        out.push("workstation jobs:".into());
        for j in &r.jobs {
            let took = j
                .started_ms
                .map(|s| format!("{:.1} s", (j.ended_ms - s) as f64 / 1000.0))
                .unwrap_or_else(|| "start not seen".into());
            out.push(format!(
                "  {:<10} {:<14} {}  {:>10}  {}",
                printable(&j.station),
                printable(&j.program),
                crate::clock::time_of_day(j.ended_ms),
                took,
                printable(&j.outcome)
            ));
        }
    }
    if !r.alarms.is_empty() {
        out.push("alarms:".into());
        out.extend(r.alarms.iter().map(|a| format!("  {}", lines::alarm(a))));
    }
    out.push("journal:".into());
    out.extend(r.entries.iter().map(|e| format!("  {}", show_entry(e))));
    out.join("\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_csv_field_is_quoted_only_when_it_must_be() {
        assert_eq!(csv_field("plain"), "plain");
        assert_eq!(csv_field("a,b"), "\"a,b\"");
        assert_eq!(csv_field("say \"ja\"\nnow"), "\"say \"\"ja\"\"\nnow\"");
    }

    #[test]
    fn a_diff_shows_the_changes_with_their_context_only() {
        let old: String = (1..=20).map(|i| format!("line {i}\n")).collect();
        let new = old.replace("line 10\n", "line ten\n");
        let lines = line_diff(&old, &new);
        let shown = hunks(&lines);
        assert_eq!(
            shown,
            vec![
                "@@ line 8",
                " line 8",
                " line 9",
                "-line 10",
                "+line ten",
                " line 11",
                " line 12"
            ]
        );
        assert_eq!(hunks(&line_diff(&old, &old)), vec!["(the same text)"]);
    }
}
