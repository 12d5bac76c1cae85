//! `falc figures`: the ISO 22400-2 figures of a range as the operator
//! computes them from its records, printed as tables (or JSON): the
//! total and each shift with its time elements and KPIs, cycle times per
//! recipe, MTBF and MTTR per station, the alarm Pareto.

use crate::clock::{date_time, parse_due};
use crate::commands::{FiguresArgs, RangeArgs};
use falc_model::api::ApiRequest;
use falc_model::figures::{CellFigures, FigureQuery, Figures, Percent, Period};
use falc_model::ids::printable;

/// How far back `falc figures` looks by default: a week.
const DEFAULT_RANGE_MS: i64 = 7 * 86_400_000;

impl RangeArgs {
    /// From and until (None: now), ms since the Unix epoch.
    pub fn range(&self, now_ms: i64) -> Result<(i64, Option<i64>), String> {
        let until_ms = self.until.as_deref().map(moment).transpose()?;
        let since_ms = match self.since.as_deref() {
            Some(s) => moment(s)?,
            None => until_ms.unwrap_or(now_ms) - DEFAULT_RANGE_MS,
        };
        Ok((since_ms, until_ms))
    }
}

/// A day alone (`2026-11-23`) is its midnight.
fn moment(text: &str) -> Result<i64, String> {
    let t = text.trim();
    if t.len() == 10 && t.as_bytes().get(4) == Some(&b'-') {
        return parse_due(&format!("{t} 00:00"));
    }
    parse_due(t)
}

impl FiguresArgs {
    /// The request, or why not.
    pub fn request(&self, now_ms: i64) -> Result<ApiRequest, String> {
        let (since_ms, until_ms) = self.range.range(now_ms)?;
        let mut planned = Vec::new();
        for p in &self.planned {
            let (recipe, secs) = p
                .split_once('=')
                .ok_or_else(|| format!("--planned {p}: give RECIPE=SECONDS"))?;
            let secs: u32 = secs
                .trim()
                .parse()
                .map_err(|_| format!("--planned {p}: {secs} is not a number of seconds"))?;
            planned.push((recipe.trim().to_string(), secs));
        }
        let request = ApiRequest::Figures(FigureQuery {
            since_ms,
            until_ms,
            planned,
        });
        request.check_limits()?;
        Ok(request)
    }
}

/// A duration as `H:MM:SS` (`12.3 s` under a minute).
fn hours(ms: i64) -> String {
    if ms < 60_000 {
        return seconds(ms);
    }
    let s = ms / 1000;
    format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

fn seconds(ms: i64) -> String {
    format!("{:.1} s", ms as f64 / 1000.0)
}

/// One period as a table line.
fn period_line(p: &Period) -> String {
    let t = &p.time;
    format!(
        "{:<22} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}  {:>4}/{:<4} {:>6} {:>6} {:>6} {:>6}",
        printable(&p.label),
        hours(t.planned_busy_ms),
        hours(t.production_ms),
        hours(t.down_total_ms()),
        hours(t.setup_ms),
        hours(t.maintenance_ms),
        hours(t.idle_ms),
        p.quantities.good,
        p.quantities.produced,
        Percent(p.availability()).to_string(),
        Percent(p.effectiveness()).to_string(),
        Percent(p.quality()).to_string(),
        Percent(p.oee()).to_string(),
    )
}

fn cell_text(c: &CellFigures) -> Vec<String> {
    let mut out = vec![format!("cell {}", printable(&c.cell))];
    out.push(format!(
        "{:<22} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}  {:>9} {:>6} {:>6} {:>6} {:>6}",
        "period",
        "planned",
        "running",
        "down",
        "setup",
        "maint.",
        "idle",
        "good/made",
        "avail",
        "effect",
        "qual",
        "OEE"
    ));
    out.extend(c.periods.iter().map(period_line));
    if c.periods_left_out > 0 {
        out.push(format!(
            "  … and {} more periods not shown (a reply is a page: give a shorter range)",
            c.periods_left_out
        ));
    }
    out.push(period_line(&c.total));
    let down: Vec<String> = c
        .total
        .time
        .down_ms
        .iter()
        .filter(|(_, ms)| *ms > 0)
        .map(|(class, ms)| format!("{class} {}", hours(*ms)))
        .collect();
    if !down.is_empty() {
        out.push(format!("down by class: {}", down.join(", ")));
    }
    if !c.cycle.is_empty() {
        out.push("cycle time per recipe:".into());
        for ct in &c.cycle {
            out.push(format!(
                "  {:<14} {:>4} done  p50 {:>9}  p95 {:>9}  planned {:>9} ({})",
                printable(&ct.recipe),
                ct.count,
                seconds(ct.p50_ms),
                seconds(ct.p95_ms),
                seconds(ct.planned_ms),
                if ct.planned_set { "set" } else { "median" }
            ));
        }
    }
    if !c.reliability.is_empty() {
        out.push("per station:".into());
        for r in &c.reliability {
            let or_dash = |v: Option<i64>| v.map_or_else(|| "-".into(), seconds);
            out.push(format!(
                "  {:<14} {:>4} failures  MTBF {:>10}  MTTR {:>10}",
                printable(&r.station),
                r.failures,
                or_dash(r.mtbf_ms),
                or_dash(r.mttr_ms)
            ));
        }
    }
    if !c.pareto.is_empty() {
        out.push("alarms, most down time first:".into());
        for l in &c.pareto {
            out.push(format!(
                "  {:<14} {:<14} {:>4}  {:>9}",
                printable(&l.station),
                l.class.to_string(),
                l.count,
                hours(l.ms)
            ));
        }
    }
    out
}

/// The figures as text.
pub fn show(f: &Figures) -> String {
    let mut out = vec![
        format!(
            "figures from {} until {} (ISO 22400-2)",
            date_time(f.since_ms),
            date_time(f.until_ms)
        ),
        f.planned_by.describe().to_string(),
    ];
    for c in &f.cells {
        out.push(String::new());
        out.extend(cell_text(c));
    }
    out.join("\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn planned_run_times_and_ranges_are_read_or_refused_by_what_is_wrong() {
        let args = |planned: &[&str], since: Option<&str>| FiguresArgs {
            range: RangeArgs {
                since: since.map(String::from),
                until: None,
            },
            planned: planned.iter().map(|p| p.to_string()).collect(),
        };
        let Ok(ApiRequest::Figures(q)) = args(&["dikdroog=300"], None).request(1_000_000_000)
        else {
            panic!("a request")
        };
        assert_eq!(q.planned, vec![("dikdroog".to_string(), 300)]);
        assert_eq!(q.since_ms, 1_000_000_000 - DEFAULT_RANGE_MS);
        let e = args(&["dikdroog"], None).request(0).expect_err("refused");
        assert!(e.contains("RECIPE=SECONDS"), "{e}");
        let e = args(&["dikdroog=x"], None).request(0).expect_err("refused");
        assert!(e.contains("not a number"), "{e}");
        assert!(args(&[], Some("yesterday")).request(0).is_err());
        assert!(args(&[], Some("2026-11-23")).request(0).is_ok());
    }

    #[test]
    fn durations_read_as_seconds_or_hours_minutes_seconds() {
        assert_eq!(hours(12_345), "12.3 s");
        assert_eq!(hours(3_600_000 + 61_000), "1:01:01");
        assert_eq!(hours(30 * 3_600_000), "30:00:00");
    }
}
