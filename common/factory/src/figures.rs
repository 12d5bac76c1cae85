//! The ISO 22400-2 figures, sans-I/O: from the records' order runs,
//! alarms and mode changes (what [`Records::figure_inputs`] reads) and
//! each cell's shift calendar, the time elements of every planned busy
//! period, what it produced, cycle times, MTBF and MTTR per station and
//! the alarm Pareto ([`falc_model::figures`] says what each is).
//!
//! Each instant of planned busy time is counted once, in this order of
//! precedence: maintenance mode, step mode (setup), an order running
//! (production), an alarm holding the cell (down, by its strictest
//! class), idle. A run's product belongs to the period its run ended in;
//! the total counts every run that ended in the range.
//!
//! [`Records::figure_inputs`]: crate::records::Records::figure_inputs

use falc_model::alarm::AlarmClass;
use falc_model::calendar::Calendar;
use falc_model::figures::{
    CellFigures, CycleTime, FigureQuery, Figures, ParetoLine, Period, PlannedBy, Quantities,
    Reliability, RunBar, RunCount, TimeElements, MAX_PERIODS,
};
use falc_model::mode::CellMode;
use falc_model::records::OrderState;
use std::collections::{BTreeMap, BTreeSet};

/// How many of the newest runs go with a cell's figures (the Gantt chart).
pub const RUN_BARS: usize = 50;

/// At most this many run times per recipe go with an answer of the
/// operator API (`CycleTime::runs_ms`, the histogram's; its count and
/// percentiles are of every run).
pub const ANSWERED_RUN_TIMES: usize = 5000;

/// Keeps each recipe's newest [`ANSWERED_RUN_TIMES`] run times: an
/// answer over a long range stays small.
pub fn keep_newest_runs(f: &mut Figures) {
    for ct in f.cells.iter_mut().flat_map(|c| c.cycle.iter_mut()) {
        let excess = ct.runs_ms.len().saturating_sub(ANSWERED_RUN_TIMES);
        ct.runs_ms.drain(..excess);
    }
}

/// One run of an order, as the records keep it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunSpan {
    /// The order.
    pub order: i64,
    /// Its cell recipe.
    pub recipe: String,
    /// The cell it ran on.
    pub cell: String,
    /// When it started (ms since the Unix epoch).
    pub start_ms: i64,
    /// When it ended (None: it runs).
    pub end_ms: Option<i64>,
    /// How it ended (`Running` while it runs).
    pub state: OrderState,
}

/// One alarm, as the records keep it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AlarmSpan {
    /// The cell it was raised in.
    pub cell: String,
    /// The station that raised it.
    pub station: String,
    /// Its class.
    pub class: AlarmClass,
    /// When it was raised.
    pub raised_ms: i64,
    /// When it was gone: acknowledged and cleared (warnings: cleared).
    /// None: it still holds.
    pub gone_ms: Option<i64>,
}

/// A cell's mode, from `at_ms` on.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModeChange {
    /// The cell.
    pub cell: String,
    /// From when.
    pub at_ms: i64,
    /// Its mode.
    pub mode: CellMode,
}

/// Whether a cell's order list worked, from `at_ms` on: running, or
/// stopped by an alarm until it was acknowledged. Without a shift calendar
/// that is when the cell was meant to work.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ListChange {
    /// The cell.
    pub cell: String,
    /// From when.
    pub at_ms: i64,
    /// Working from then on.
    pub working: bool,
}

/// What the figures are computed from.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct FigureInputs {
    /// The runs that overlap the range.
    pub runs: Vec<RunSpan>,
    /// The alarms that overlap the range.
    pub alarms: Vec<AlarmSpan>,
    /// Every mode change before the range's end, oldest first.
    pub modes: Vec<ModeChange>,
    /// Every change of the order list's working before the range's end,
    /// oldest first.
    pub lists: Vec<ListChange>,
}

/// Sorted, disjoint half-open intervals of ms.
type Set = Vec<(i64, i64)>;

fn normalize(mut v: Set) -> Set {
    v.retain(|(a, b)| a < b);
    v.sort_unstable();
    let mut out: Set = Vec::with_capacity(v.len());
    for (a, b) in v {
        match out.last_mut() {
            Some(last) if a <= last.1 => last.1 = last.1.max(b),
            _ => out.push((a, b)),
        }
    }
    out
}

fn length(v: &Set) -> i64 {
    v.iter().map(|(a, b)| b - a).sum()
}

/// The first interval of `y` that does not end before `x` begins: the
/// set operations start there (a period's elements cost the log of the
/// whole range's intervals, not their number).
fn start_in(x: &Set, y: &Set) -> usize {
    x.first()
        .map_or(0, |first| y.partition_point(|s| s.1 <= first.0))
}

fn intersect(x: &Set, y: &Set) -> Set {
    let (mut i, mut j, mut out) = (0, start_in(x, y), Vec::new());
    while i < x.len() && j < y.len() {
        let (a, b) = (x[i].0.max(y[j].0), x[i].1.min(y[j].1));
        if a < b {
            out.push((a, b));
        }
        if x[i].1 < y[j].1 {
            i += 1;
        } else {
            j += 1;
        }
    }
    out
}

fn subtract(x: &Set, y: &Set) -> Set {
    let mut out = Vec::new();
    let mut j = start_in(x, y);
    for &(mut a, b) in x {
        while j < y.len() && y[j].1 <= a {
            j += 1;
        }
        let mut k = j;
        while k < y.len() && y[k].0 < b {
            if y[k].0 > a {
                out.push((a, y[k].0));
            }
            a = a.max(y[k].1);
            k += 1;
        }
        if a < b {
            out.push((a, b));
        }
    }
    out
}

/// Median and 95th percentile (nearest rank) of `v`, sorted here.
fn percentiles(v: &mut [i64]) -> (i64, i64) {
    if v.is_empty() {
        return (0, 0);
    }
    v.sort_unstable();
    let rank = |p: f64| {
        let r = (p * v.len() as f64).ceil() as usize;
        v[r.clamp(1, v.len()) - 1]
    };
    (rank(0.5), rank(0.95))
}

/// What one cell's records say, as interval sets over the whole range.
struct Cell<'a> {
    maintenance: Set,
    setup: Set,
    production: Set,
    down: Vec<(AlarmClass, Set)>,
    runs: Vec<&'a RunSpan>,
    alarms: Vec<&'a AlarmSpan>,
    /// When its first mode change was kept.
    first_mode: Option<i64>,
    /// When it was meant to work: its list working, and its runs.
    working: Set,
}

impl<'a> Cell<'a> {
    fn new(cell: &str, inputs: &'a FigureInputs, since: i64, until: i64) -> Self {
        // The mode intervals: each change holds until the next (auto
        // before the first).
        let changes: Vec<&ModeChange> = inputs.modes.iter().filter(|m| m.cell == cell).collect();
        let mut maintenance = Vec::new();
        let mut setup = Vec::new();
        for (i, m) in changes.iter().enumerate() {
            let end = changes.get(i + 1).map_or(until, |n| n.at_ms);
            let span = (m.at_ms.max(since), end.min(until));
            match m.mode {
                CellMode::Maintenance => maintenance.push(span),
                CellMode::Step => setup.push(span),
                CellMode::Auto => {}
            }
        }
        let runs: Vec<&RunSpan> = inputs.runs.iter().filter(|r| r.cell == cell).collect();
        let production: Set = runs
            .iter()
            .map(|r| (r.start_ms.max(since), r.end_ms.unwrap_or(until).min(until)))
            .collect();
        let lists: Vec<&ListChange> = inputs.lists.iter().filter(|l| l.cell == cell).collect();
        let mut working = production.clone();
        for (i, l) in lists.iter().enumerate().filter(|(_, l)| l.working) {
            let end = lists.get(i + 1).map_or(until, |n| n.at_ms);
            working.push((l.at_ms.max(since), end.min(until)));
        }
        let alarms: Vec<&AlarmSpan> = inputs.alarms.iter().filter(|a| a.cell == cell).collect();
        let down = AlarmClass::ALL
            .into_iter()
            .filter(|c| *c != AlarmClass::Warning)
            .map(|class| {
                let spans = alarms
                    .iter()
                    .filter(|a| a.class == class)
                    .map(|a| {
                        (
                            a.raised_ms.max(since),
                            a.gone_ms.unwrap_or(until).min(until),
                        )
                    })
                    .collect();
                (class, normalize(spans))
            })
            .collect();
        Self {
            first_mode: changes.first().map(|m| m.at_ms),
            maintenance: normalize(maintenance),
            setup: normalize(setup),
            production: normalize(production),
            working: normalize(working),
            down,
            runs,
            alarms,
        }
    }

    /// The time elements of `busy` (disjoint, sorted).
    fn time(&self, busy: &Set) -> TimeElements {
        let maintenance = intersect(busy, &self.maintenance);
        let rest = subtract(busy, &maintenance);
        let setup = intersect(&rest, &self.setup);
        let rest = subtract(&rest, &setup);
        let production = intersect(&rest, &self.production);
        let mut rest = subtract(&rest, &production);
        let mut down_ms = Vec::new();
        for (class, spans) in &self.down {
            let down = intersect(&rest, spans);
            down_ms.push((*class, length(&down)));
            rest = subtract(&rest, &down);
        }
        TimeElements {
            planned_busy_ms: length(busy),
            production_ms: length(&production),
            down_ms,
            setup_ms: length(&setup),
            maintenance_ms: length(&maintenance),
            idle_ms: length(&rest),
        }
    }

    /// What the runs that ended within each of `spans` (disjoint, in time
    /// order) produced, in one pass over the runs.
    fn quantities(&self, spans: &[(i64, i64)], planned: &BTreeMap<String, i64>) -> Vec<Quantities> {
        let mut out = vec![Quantities::default(); spans.len()];
        for r in &self.runs {
            let Some(end) = r.end_ms else {
                continue;
            };
            let i = spans.partition_point(|s| s.1 <= end);
            let Some(q) = spans
                .get(i)
                .filter(|s| s.0 <= end)
                .and_then(|_| out.get_mut(i))
            else {
                continue;
            };
            match r.state {
                OrderState::Done => q.good += 1,
                OrderState::Failed => q.failed += 1,
                OrderState::Stopped | OrderState::Interrupted => q.stopped += 1,
                OrderState::Queued | OrderState::Running => continue,
            }
            if matches!(r.state, OrderState::Done | OrderState::Failed) {
                q.produced += 1;
                q.planned_run_ms += planned.get(&r.recipe.to_lowercase()).copied().unwrap_or(0);
            }
        }
        out
    }

    /// When this cell's records begin (None: it has none).
    fn first_record(&self) -> Option<i64> {
        let runs = self.runs.iter().map(|r| r.start_ms);
        let alarms = self.alarms.iter().map(|a| a.raised_ms);
        runs.chain(alarms).chain(self.first_mode).min()
    }
}

/// The figures of `query`, up to `now` unless it says until when (ms
/// since the Unix epoch): each of `cells` and each cell in the inputs,
/// planned against `calendar` (a plant's shifts are every cell's).
pub fn compute(
    inputs: &FigureInputs,
    calendar: &Calendar,
    cells: &[&str],
    query: &FigureQuery,
    now: i64,
) -> Figures {
    let since = query.since_ms;
    let until = query.until_ms.unwrap_or(now).max(since);
    let planned_by = if calendar.always() {
        PlannedBy::ListWorking
    } else {
        PlannedBy::Calendar
    };
    let names: BTreeSet<&str> = inputs
        .runs
        .iter()
        .map(|r| r.cell.as_str())
        .chain(inputs.alarms.iter().map(|a| a.cell.as_str()))
        .chain(inputs.modes.iter().map(|m| m.cell.as_str()))
        .chain(cells.iter().copied())
        .collect();
    let cells = names
        .into_iter()
        .map(|name| cell_figures(name, inputs, calendar, planned_by, query, since, until))
        .collect();
    Figures {
        since_ms: since,
        until_ms: until,
        cells,
        planned_by,
    }
}

fn cell_figures(
    name: &str,
    inputs: &FigureInputs,
    calendar: &Calendar,
    planned_by: PlannedBy,
    query: &FigureQuery,
    since: i64,
    until: i64,
) -> CellFigures {
    let cell = Cell::new(name, inputs, since, until);
    let ended_in_range = |r: &&&RunSpan| r.end_ms.is_some_and(|e| (since..until).contains(&e));
    // Cycle times of the done runs; the planned run time per recipe as
    // set, else their median.
    // Recipe names as orders and consoles write them, in any case.
    let mut by_recipe: BTreeMap<String, Vec<i64>> = BTreeMap::new();
    for r in cell.runs.iter().filter(ended_in_range) {
        if r.state == OrderState::Done {
            let end = r.end_ms.unwrap_or(r.start_ms);
            by_recipe
                .entry(r.recipe.to_lowercase())
                .or_default()
                .push(end - r.start_ms);
        }
    }
    let set: BTreeMap<String, i64> = query
        .planned
        .iter()
        .map(|(recipe, s)| (recipe.to_lowercase(), i64::from(*s) * 1000))
        .collect();
    let mut planned: BTreeMap<String, i64> = BTreeMap::new();
    let mut cycle = Vec::new();
    for (recipe, runs_ms) in &by_recipe {
        let mut sorted = runs_ms.clone();
        let (p50, p95) = percentiles(&mut sorted);
        let planned_ms = set.get(recipe).copied().unwrap_or(p50);
        planned.insert(recipe.clone(), planned_ms);
        cycle.push(CycleTime {
            recipe: recipe.to_string(),
            count: runs_ms.len() as u64,
            p50_ms: p50,
            p95_ms: p95,
            planned_ms,
            planned_set: set.contains_key(recipe),
            runs_ms: runs_ms.clone(),
        });
    }
    for (recipe, ms) in &set {
        planned.entry(recipe.clone()).or_insert(*ms);
    }
    let busy_periods = calendar.periods(since, until);
    let mut busy: Set = normalize(busy_periods.iter().map(|(a, b, _)| (*a, *b)).collect());
    // No shift calendar: planned is when the cell was meant to work.
    let planned_in = |span: Set| {
        if planned_by == PlannedBy::ListWorking {
            intersect(&span, &cell.working)
        } else {
            span
        }
    };
    busy = planned_in(busy);
    // A period is shown from the cell's first record on: before it the
    // records say nothing (all time is thousands of empty days).
    let first = cell.first_record().unwrap_or(until);
    let mut shown: Vec<&(i64, i64, String)> = busy_periods.iter().filter(|p| p.1 > first).collect();
    // A reply is a page: 1970–2100 would be tens of thousands of days.
    let periods_left_out = shown.len().saturating_sub(MAX_PERIODS) as u64;
    shown.truncate(MAX_PERIODS);
    let spans: Vec<(i64, i64)> = shown.iter().map(|p| (p.0, p.1)).collect();
    let periods: Vec<Period> = shown
        .iter()
        .zip(cell.quantities(&spans, &planned))
        .map(|((from, to, label), quantities)| Period {
            label: label.clone(),
            start_ms: *from,
            end_ms: *to,
            time: cell.time(&planned_in(vec![(*from, *to)])),
            quantities,
        })
        .collect();
    let total = Period {
        label: "total".into(),
        start_ms: since,
        end_ms: until,
        time: cell.time(&busy),
        quantities: cell
            .quantities(&[(since, until)], &planned)
            .pop()
            .unwrap_or_default(),
    };
    // Per station: failures (not warnings) raised in the range.
    let raised = |a: &&&AlarmSpan| (since..until).contains(&a.raised_ms);
    let mut stations: BTreeMap<&str, (u64, Vec<i64>)> = BTreeMap::new();
    let mut pareto: BTreeMap<(&str, AlarmClass), (u64, i64)> = BTreeMap::new();
    for a in cell.alarms.iter().filter(raised) {
        let span = vec![(a.raised_ms, a.gone_ms.unwrap_or(until).min(until))];
        let line = pareto.entry((a.station.as_str(), a.class)).or_default();
        line.0 += 1;
        line.1 += length(&intersect(&normalize(span), &busy));
        if a.class == AlarmClass::Warning {
            continue;
        }
        let s = stations.entry(a.station.as_str()).or_default();
        s.0 += 1;
        if let Some(gone) = a.gone_ms {
            s.1.push(gone - a.raised_ms);
        }
    }
    let production = total.time.production_ms;
    let reliability = stations
        .into_iter()
        .map(|(station, (failures, repairs))| Reliability {
            station: station.to_string(),
            failures,
            mtbf_ms: (failures > 0).then(|| production / failures as i64),
            mttr_ms: (!repairs.is_empty())
                .then(|| repairs.iter().sum::<i64>() / repairs.len() as i64),
        })
        .collect();
    let mut pareto: Vec<ParetoLine> = pareto
        .into_iter()
        .map(|((station, class), (count, ms))| ParetoLine {
            station: station.to_string(),
            class,
            count,
            ms,
        })
        .collect();
    pareto.sort_by(|a, b| b.ms.cmp(&a.ms).then(b.count.cmp(&a.count)));
    let mut bars: Vec<&RunSpan> = cell.runs.clone();
    bars.sort_by_key(|r| r.start_ms);
    let skip = bars.len().saturating_sub(RUN_BARS);
    let runs = bars[skip..]
        .iter()
        .map(|r| RunBar {
            order: r.order,
            recipe: r.recipe.clone(),
            start_ms: r.start_ms,
            end_ms: r.end_ms.unwrap_or(until).min(until),
            state: r.state.as_str().to_string(),
        })
        .collect();
    let mut ended: BTreeMap<(String, &str), u64> = BTreeMap::new();
    for r in cell.runs.iter().filter(ended_in_range) {
        *ended
            .entry((r.recipe.to_lowercase(), r.state.as_str()))
            .or_default() += 1;
    }
    let ended = ended
        .into_iter()
        .map(|((recipe, result), count)| RunCount {
            recipe,
            result: result.to_string(),
            count,
        })
        .collect();
    CellFigures {
        cell: name.to_string(),
        ended,
        total,
        periods,
        periods_left_out,
        cycle,
        reliability,
        pareto,
        runs,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_model::calendar::RawShift;

    const H: i64 = 3_600_000;
    const M: i64 = 60_000;
    /// 2026-11-25 00:00 UTC, a Wednesday.
    const WED: i64 = 1_795_564_800_000;

    fn run(order: i64, start: i64, end: Option<i64>, state: OrderState) -> RunSpan {
        RunSpan {
            order,
            recipe: "dikdroog".into(),
            cell: "falc1".into(),
            start_ms: start,
            end_ms: end,
            state,
        }
    }

    fn alarm(station: &str, class: AlarmClass, raised: i64, gone: Option<i64>) -> AlarmSpan {
        AlarmSpan {
            cell: "falc1".into(),
            station: station.into(),
            class,
            raised_ms: raised,
            gone_ms: gone,
        }
    }

    fn mode(at: i64, mode: CellMode) -> ModeChange {
        ModeChange {
            cell: "falc1".into(),
            at_ms: at,
            mode,
        }
    }

    /// Two shifts a day, 06–14 and 14–22 UTC.
    fn two_shifts() -> Calendar {
        let shift = |name: &str, start: &str, end: &str| RawShift {
            name: name.into(),
            start: start.into(),
            end: end.into(),
            days: Vec::new(),
        };
        Calendar::new(
            None,
            &[
                shift("early", "06:00", "14:00"),
                shift("late", "14:00", "22:00"),
            ],
        )
        .expect("valid")
    }

    fn query(since: i64, until: i64) -> FigureQuery {
        FigureQuery {
            since_ms: since,
            until_ms: Some(until),
            planned: Vec::new(),
        }
    }

    fn down(t: &TimeElements, class: AlarmClass) -> i64 {
        t.down_ms
            .iter()
            .find(|(c, _)| *c == class)
            .map_or(0, |(_, ms)| *ms)
    }

    /// Every element together is the planned busy time.
    fn partitions(t: &TimeElements) {
        assert_eq!(
            t.production_ms + t.down_total_ms() + t.setup_ms + t.maintenance_ms + t.idle_ms,
            t.planned_busy_ms,
            "{t:?}"
        );
    }

    #[test]
    fn only_shift_time_is_planned_and_a_run_across_shifts_counts_in_each() {
        let inputs = FigureInputs {
            // 13:00–15:00: an hour in each shift; 23:00–23:30 outside.
            runs: vec![
                run(1, WED + 13 * H, Some(WED + 15 * H), OrderState::Done),
                run(
                    2,
                    WED + 23 * H,
                    Some(WED + 23 * H + 30 * M),
                    OrderState::Done,
                ),
            ],
            ..Default::default()
        };
        let f = compute(&inputs, &two_shifts(), &[], &query(WED, WED + 24 * H), 0);
        let c = &f.cells[0];
        assert_eq!(c.total.time.planned_busy_ms, 16 * H);
        assert_eq!(c.total.time.production_ms, 2 * H);
        let labels: Vec<&str> = c.periods.iter().map(|p| p.label.as_str()).collect();
        assert_eq!(labels, vec!["2026-11-25 early", "2026-11-25 late"]);
        assert_eq!(c.periods[0].time.production_ms, H);
        assert_eq!(c.periods[1].time.production_ms, H);
        // The product belongs to the shift its run ended in; the total
        // counts the one made outside the shifts too.
        assert_eq!(c.periods[0].quantities.produced, 0);
        assert_eq!(c.periods[1].quantities.produced, 1);
        assert_eq!(c.total.quantities.produced, 2);
        for p in c.periods.iter().chain([&c.total]) {
            partitions(&p.time);
        }
    }

    #[test]
    fn an_alarm_spanning_a_shift_change_is_down_time_in_both_by_its_strictest_class() {
        let inputs = FigureInputs {
            runs: vec![run(1, WED + 12 * H, Some(WED + 13 * H), OrderState::Failed)],
            alarms: vec![
                // The estop ended the run at 13:00; gone at 15:00.
                alarm(
                    "welding",
                    AlarmClass::Safety,
                    WED + 13 * H,
                    Some(WED + 15 * H),
                ),
                // A device alarm under it, 12:30–16:00: down only where
                // no run and no safety alarm holds.
                alarm(
                    "transport",
                    AlarmClass::Device,
                    WED + 12 * H + 30 * M,
                    Some(WED + 16 * H),
                ),
                // A warning is never down time.
                alarm(
                    "welding",
                    AlarmClass::Warning,
                    WED + 17 * H,
                    Some(WED + 18 * H),
                ),
            ],
            ..Default::default()
        };
        let f = compute(&inputs, &two_shifts(), &[], &query(WED, WED + 24 * H), 0);
        let c = &f.cells[0];
        let (early, late) = (&c.periods[0].time, &c.periods[1].time);
        assert_eq!(down(early, AlarmClass::Safety), H);
        assert_eq!(down(late, AlarmClass::Safety), H);
        assert_eq!(down(early, AlarmClass::Device), 0);
        assert_eq!(down(late, AlarmClass::Device), H);
        assert_eq!(down(&c.total.time, AlarmClass::Warning), 0);
        assert_eq!(c.total.time.down_total_ms(), 3 * H);
        partitions(early);
        partitions(late);
        // MTTR: 2 h and 3.5 h; MTBF: 1 h of production per 2 failures.
        let r = |s: &str| {
            c.reliability
                .iter()
                .find(|r| r.station == s)
                .expect("station")
        };
        assert_eq!(r("welding").failures, 1, "the warning is no failure");
        assert_eq!(r("welding").mttr_ms, Some(2 * H));
        assert_eq!(r("transport").mttr_ms, Some(3 * H + 30 * M));
        assert_eq!(r("welding").mtbf_ms, Some(H));
        // The Pareto: most down time first, warnings listed.
        let p: Vec<(&str, AlarmClass, i64)> = c
            .pareto
            .iter()
            .map(|l| (l.station.as_str(), l.class, l.ms))
            .collect();
        assert_eq!(
            p,
            vec![
                ("transport", AlarmClass::Device, 3 * H + 30 * M),
                ("welding", AlarmClass::Safety, 2 * H),
                ("welding", AlarmClass::Warning, H),
            ]
        );
        assert_eq!(c.total.quantities.failed, 1);
        assert_eq!(c.total.quality(), Some(0.0));
    }

    #[test]
    fn maintenance_and_step_mode_take_precedence_over_what_runs_then() {
        let inputs = FigureInputs {
            runs: vec![run(1, WED + 7 * H, Some(WED + 9 * H), OrderState::Done)],
            alarms: vec![alarm("cell", AlarmClass::Process, WED + 10 * H, None)],
            modes: vec![
                mode(WED - 24 * H, CellMode::Auto),
                // Step mode 08:00–08:30 while the order ran (commissioning).
                mode(WED + 8 * H, CellMode::Step),
                mode(WED + 8 * H + 30 * M, CellMode::Auto),
                // Maintenance 11:00–12:00 while the alarm still held.
                mode(WED + 11 * H, CellMode::Maintenance),
                mode(WED + 12 * H, CellMode::Auto),
            ],
            lists: Vec::new(),
        };
        let f = compute(&inputs, &two_shifts(), &[], &query(WED, WED + 14 * H), 0);
        let t = &f.cells[0].periods[0].time;
        assert_eq!(t.planned_busy_ms, 8 * H);
        assert_eq!(t.setup_ms, 30 * M);
        assert_eq!(t.production_ms, H + 30 * M);
        assert_eq!(t.maintenance_ms, H);
        // The alarm never went: down from 10:00 to the range's end, but
        // for the hour of maintenance.
        assert_eq!(down(t, AlarmClass::Process), 3 * H);
        assert_eq!(t.idle_ms, 8 * H - 30 * M - 90 * M - H - 3 * H);
        partitions(t);
        let r = &f.cells[0].reliability[0];
        assert_eq!(
            (r.failures, r.mttr_ms),
            (1, None),
            "not gone: no repair time"
        );
    }

    #[test]
    fn an_order_stopped_and_restarted_is_one_product_and_its_runs_count_apart() {
        let inputs = FigureInputs {
            runs: vec![
                run(
                    1,
                    WED + 6 * H,
                    Some(WED + 6 * H + 10 * M),
                    OrderState::Stopped,
                ),
                run(1, WED + 7 * H, Some(WED + 7 * H + 20 * M), OrderState::Done),
                run(2, WED + 8 * H, Some(WED + 8 * H + 40 * M), OrderState::Done),
                run(3, WED + 9 * H, Some(WED + 9 * H + 30 * M), OrderState::Done),
                run(4, WED + 13 * H, None, OrderState::Running),
            ],
            ..Default::default()
        };
        let until = WED + 14 * H;
        let f = compute(&inputs, &two_shifts(), &[], &query(WED, until), 0);
        let c = &f.cells[0];
        let q = &c.total.quantities;
        assert_eq!((q.produced, q.good, q.stopped), (3, 3, 1));
        let ended: Vec<(&str, &str, u64)> = c
            .ended
            .iter()
            .map(|e| (e.recipe.as_str(), e.result.as_str(), e.count))
            .collect();
        assert_eq!(
            ended,
            vec![("dikdroog", "done", 3), ("dikdroog", "stopped", 1)]
        );
        // Cycle time of the done runs: 20, 40, 30 min; PRI learned as the
        // median, 30 min: effectiveness 90 min of 160 min running (the
        // stopped run and the one still running count as production).
        let ct = &c.cycle[0];
        assert_eq!((ct.count, ct.p50_ms, ct.p95_ms), (3, 30 * M, 40 * M));
        assert!(!ct.planned_set);
        assert_eq!(
            c.total.time.production_ms,
            10 * M + 20 * M + 40 * M + 30 * M + H
        );
        assert_eq!(q.planned_run_ms, 90 * M);
        let e = c.total.effectiveness().expect("defined");
        assert!((e - 90.0 / 160.0).abs() < 1e-9, "{e}");
        assert_eq!(
            c.runs.last().map(|b| (b.end_ms, b.state.as_str())),
            Some((until, "running"))
        );
        // A planned run time set by hand wins.
        let mut set = query(WED, until);
        set.planned = vec![("dikdroog".into(), 600)];
        let f = compute(&inputs, &two_shifts(), &[], &set, 0);
        assert_eq!(f.cells[0].total.quantities.planned_run_ms, 30 * M);
        assert!(f.cells[0].cycle[0].planned_set);
    }

    #[test]
    fn a_range_to_2100_is_one_page_of_periods_and_says_how_many_were_left_out() {
        let inputs = FigureInputs {
            runs: vec![run(1, WED + 7 * H, Some(WED + 8 * H), OrderState::Done)],
            ..Default::default()
        };
        let latest = falc_model::api::LATEST_FIGURES_MS;
        let f = compute(&inputs, &two_shifts(), &[], &query(0, latest), 0);
        let c = &f.cells[0];
        assert_eq!(c.periods.len(), MAX_PERIODS);
        // Two shifts a day from 2026-11-25 to 2100: the rest left out.
        assert!(c.periods_left_out > 50_000, "{}", c.periods_left_out);
        assert!(
            c.periods[0].label.starts_with("2026-11-25"),
            "{}",
            c.periods[0].label
        );
        // On the wire (the envelope): a page, not megabytes.
        let bytes = falc_model::envelope::encode(&f).len();
        assert!(bytes < 300_000, "one page: {bytes} bytes");
    }

    #[test]
    fn without_a_calendar_the_cell_is_planned_busy_while_its_list_worked() {
        let list = |at: i64, working: bool| ListChange {
            cell: "falc1".into(),
            at_ms: at,
            working,
        };
        // The list ran 2 h (7:00-9:00), one order of 1 h in it, an alarm
        // held it 30 min more (9:00-9:30); a run outside any list (the
        // operator's records before lists were kept) counts as planned.
        let inputs = FigureInputs {
            runs: vec![
                run(1, WED + 7 * H, Some(WED + 8 * H), OrderState::Done),
                run(
                    2,
                    WED + 12 * H,
                    Some(WED + 12 * H + 30 * M),
                    OrderState::Done,
                ),
            ],
            alarms: vec![AlarmSpan {
                cell: "falc1".into(),
                station: "welding".into(),
                class: AlarmClass::Safety,
                raised_ms: WED + 9 * H,
                gone_ms: Some(WED + 9 * H + 30 * M),
            }],
            lists: vec![list(WED + 7 * H, true), list(WED + 9 * H + 30 * M, false)],
            ..Default::default()
        };
        let f = compute(
            &inputs,
            &Calendar::default(),
            &[],
            &query(WED, WED + 24 * H),
            0,
        );
        assert_eq!(f.planned_by, PlannedBy::ListWorking);
        let t = &f.cells[0].total.time;
        assert_eq!(t.planned_busy_ms, 2 * H + 30 * M + 30 * M);
        assert_eq!(t.production_ms, H + 30 * M);
        assert_eq!(t.down_total_ms(), 30 * M);
        partitions(t);
        // 1.5 h of production in 3 h meant to work: 50 %, where the whole
        // day planned said 6 %.
        let a = f.cells[0].total.availability().expect("defined");
        assert!((a - 0.5).abs() < 1e-9, "{a}");
        // The day's period says the same.
        assert_eq!(f.cells[0].periods[0].time.planned_busy_ms, 3 * H);
        // With a calendar, the shifts are planned.
        let f = compute(&inputs, &two_shifts(), &[], &query(WED, WED + 24 * H), 0);
        assert_eq!(f.planned_by, PlannedBy::Calendar);
    }

    #[test]
    fn all_time_shows_the_periods_from_the_first_record_and_plans_what_the_list_worked() {
        let inputs = FigureInputs {
            runs: vec![run(1, WED + 7 * H, Some(WED + 8 * H), OrderState::Done)],
            ..Default::default()
        };
        // Since 1970, until the day after: one day of records.
        let f = compute(
            &inputs,
            &Calendar::default(),
            &[],
            &query(0, WED + 2 * H * 24),
            0,
        );
        let c = &f.cells[0];
        let labels: Vec<&str> = c.periods.iter().map(|p| p.label.as_str()).collect();
        assert_eq!(labels, vec!["2026-11-25", "2026-11-26"]);
        // No list kept working: the order's run alone was planned.
        assert_eq!(c.total.time.planned_busy_ms, H);
        assert_eq!(c.periods[0].quantities.good, 1);
        assert_eq!(c.total.quantities.good, 1);
        partitions(&c.total.time);
        // An answer keeps the newest run times only; count and p50 stay.
        let many = FigureInputs {
            runs: (0..ANSWERED_RUN_TIMES as i64 + 10)
                .map(|i| run(i, i * 10, Some(i * 10 + 5), OrderState::Done))
                .collect(),
            ..Default::default()
        };
        let mut f = compute(&many, &Calendar::default(), &[], &query(0, H), 0);
        keep_newest_runs(&mut f);
        let ct = &f.cells[0].cycle[0];
        assert_eq!(
            (ct.runs_ms.len(), ct.count),
            (ANSWERED_RUN_TIMES, ANSWERED_RUN_TIMES as u64 + 10)
        );
        // A cell with no record shows no period, and nothing planned.
        let none = compute(
            &FigureInputs::default(),
            &Calendar::default(),
            &["falc1"],
            &query(0, H),
            0,
        );
        assert!(none.cells[0].periods.is_empty());
        assert_eq!(none.cells[0].total.time.planned_busy_ms, 0);
    }

    #[test]
    fn interval_sets_subtract_and_intersect() {
        let x = normalize(vec![(0, 10), (5, 15), (20, 30)]);
        assert_eq!(x, vec![(0, 15), (20, 30)]);
        let y = vec![(3, 4), (12, 22), (25, 26)];
        assert_eq!(subtract(&x, &y), vec![(0, 3), (4, 12), (22, 25), (26, 30)]);
        assert_eq!(
            intersect(&x, &y),
            vec![(3, 4), (12, 15), (20, 22), (25, 26)]
        );
        assert_eq!(
            length(&subtract(&x, &y)) + length(&intersect(&x, &y)),
            length(&x)
        );
    }
}
