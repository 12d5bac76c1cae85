//! What the order list keeps durably, as the [`order_list`](crate::order_list)
//! core sees it: the orders, the journal, the alarms and every saved
//! version of each recipe file with the versions each order ran. The operator node's
//! SQLite file implements [`Records`]; unit tests use [`memory::Memory`].
//! Each call is one write or read of local storage, with its own time stamp
//! (ms since the Unix epoch) taken by the records; a failed write returns
//! the error and changes nothing.

use crate::figures::FigureInputs;
use falc_model::alarm::{Alarm, AlarmClass};
use falc_model::api::Placement;
use falc_model::ids::StationName;
use falc_model::mode::CellMode;
use falc_model::product::{JobRecord, OrderRecord, RecipeVersion, UsedRecipe};
use falc_model::recipe_file::RecipeFile;
use falc_model::records::{Entry, EntryKind, Order, OrderState};
use std::fmt::Display;

/// Which journal entries to read ([`Records::entries`]): those after
/// `after` (of `order`; messages only; of cell `cell`, with those written
/// before entries had a cell), oldest first, at most `limit` of them: the
/// oldest, or the `newest`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EntryQuery<'a> {
    /// Only entries with a larger id.
    pub after: i64,
    /// Only this order's.
    pub order: Option<i64>,
    /// Only messages ([`EntryKind::is_message`]).
    pub messages_only: bool,
    /// Only this cell's (and those of before cells).
    pub cell: Option<&'a str>,
    /// At most this many.
    pub limit: usize,
    /// The newest `limit` rather than the oldest.
    pub newest: bool,
}

impl EntryQuery<'_> {
    /// The oldest `limit` entries after `after`, of every kind, order and
    /// cell.
    pub fn page(after: i64, limit: usize) -> Self {
        Self {
            after,
            order: None,
            messages_only: false,
            cell: None,
            limit,
            newest: false,
        }
    }

    /// Whether `e` is one of them (all but the limit).
    pub fn matches(&self, e: &Entry) -> bool {
        e.id > self.after
            && self.order.map_or(true, |o| e.order == Some(o))
            && (!self.messages_only || e.kind.is_message())
            && self
                .cell
                .map_or(true, |c| e.cell.as_deref().map_or(true, |x| x == c))
    }
}

/// The order list's durable records.
pub trait Records {
    /// A failed read or write, saying of what.
    type Error: Display;

    /// The time every record is stamped with, in milliseconds since the
    /// Unix epoch: the time last given ([`Records::set_now`]). The records
    /// read no clock of their own: the order list gives them its `now`
    /// before it handles anything, so the processes and `falc-sim` stamp
    /// their records by the one clock each runs on.
    fn now_ms(&self) -> i64;
    /// Gives the records the time (milliseconds since the Unix epoch).
    fn set_now(&mut self, at_ms: i64);
    /// Adds a queued order of cell recipe `recipe`, placed as `placement`
    /// says.
    fn add_order(
        &mut self,
        recipe: &str,
        who: &str,
        placement: &Placement,
    ) -> Result<Order, Self::Error>;
    /// Every order, lowest id first.
    fn orders(&self) -> Result<Vec<Order>, Self::Error>;
    /// The queued order cell `cell` runs next ([`Order::dispatch_key`]
    /// among those it may run).
    fn next_queued(&self, cell: &str) -> Result<Option<Order>, Self::Error>;
    /// The id of the newest journal entry (0 for an empty journal).
    fn journal_head(&self) -> Result<i64, Self::Error>;
    /// How many orders are queued.
    fn queued(&self) -> Result<usize, Self::Error>;
    /// Removes a queued order; why not for any other.
    fn remove_order(&mut self, id: i64) -> Result<Result<Order, String>, Self::Error>;
    /// Marks an order running on cell `cell` with the recipe versions
    /// `recipes` (kept as one more run of it); when it started.
    fn set_running(
        &mut self,
        id: i64,
        cell: &str,
        recipes: &[UsedRecipe],
    ) -> Result<i64, Self::Error>;
    /// Puts a running order back in the queue (the cell refused it), for
    /// any cell again unless it was added for one.
    fn requeue(&mut self, id: i64) -> Result<(), Self::Error>;
    /// Ends an order with `state` and `result`.
    fn end_order(&mut self, id: i64, state: OrderState, result: &str) -> Result<(), Self::Error>;
    /// Appends a journal entry, made now.
    fn journal(
        &mut self,
        kind: EntryKind,
        order: Option<i64>,
        who: &str,
        text: &str,
    ) -> Result<Entry, Self::Error> {
        let at_ms = self.now_ms();
        self.journal_at(at_ms, kind, order, who, text)
    }
    /// Appends a journal entry made at `at_ms` (a station's report filed
    /// late, with its own time).
    fn journal_at(
        &mut self,
        at_ms: i64,
        kind: EntryKind,
        order: Option<i64>,
        who: &str,
        text: &str,
    ) -> Result<Entry, Self::Error>;
    /// The journal entries `query` asks for, oldest first.
    fn entries(&self, query: &EntryQuery) -> Result<Vec<Entry>, Self::Error>;
    /// Records a new alarm, active.
    fn raise_alarm(
        &mut self,
        station: &StationName,
        class: AlarmClass,
        text: &str,
        order: Option<i64>,
    ) -> Result<Alarm, Self::Error>;
    /// Records who acknowledged alarm `id`, and when.
    fn ack_alarm(&mut self, id: i64, who: &str, at_ms: i64) -> Result<(), Self::Error>;
    /// Records that alarm `id`'s condition is gone.
    fn clear_alarm(&mut self, id: i64, at_ms: i64) -> Result<(), Self::Error>;
    /// The alarms still listed (not both acknowledged and cleared).
    fn listed_alarms(&self) -> Result<Vec<Alarm>, Self::Error>;
    /// Keeps `text` as the newest version of `file`, saved by `who` with
    /// `message`, unless it is the newest already: that version, and
    /// whether it is new. Versions are never changed or removed.
    fn add_version(
        &mut self,
        file: &RecipeFile,
        text: &str,
        who: &str,
        message: &str,
    ) -> Result<(RecipeVersion, bool), Self::Error>;
    /// Every version of `file`, oldest first.
    fn versions(&self, file: &RecipeFile) -> Result<Vec<RecipeVersion>, Self::Error>;
    /// Version `version` of `file` with its text.
    fn version(
        &self,
        file: &RecipeFile,
        version: u32,
    ) -> Result<Option<(RecipeVersion, String)>, Self::Error>;
    /// What the records say of order `id` (its first [`RECORD_ENTRIES`]
    /// journal entries); None if there is no such order.
    fn order_record(&self, id: i64) -> Result<Option<OrderRecord>, Self::Error>;
    /// Keeps a workstation's job that ended, as part of order `order`.
    fn record_job(&mut self, order: Option<i64>, job: &JobRecord) -> Result<(), Self::Error>;
    /// Keeps that this cell is in `mode` from now on, unless that is the
    /// newest mode kept for it already.
    fn record_mode(&mut self, mode: CellMode) -> Result<(), Self::Error>;
    /// The runs and alarms that overlap `[since, until)` and every mode
    /// change before `until`, of every cell: what the figures are
    /// computed from.
    fn figure_inputs(&self, since: i64, until: i64) -> Result<FigureInputs, Self::Error>;
    /// Keeps that this cell's order list works (`true`: running, or held
    /// by an alarm until it is acknowledged) from now on, unless that is
    /// what was kept last for it: without a shift calendar, the figures
    /// plan the cell busy while it worked.
    fn record_working(&mut self, working: bool) -> Result<(), Self::Error>;
    /// The last report filed of each station of this cell: the station,
    /// its run and the report's number. An operator started again reads
    /// back from there what the stations reported while it was down.
    fn reports_filed(&self) -> Result<Vec<(String, String, u64)>, Self::Error>;
    /// Report number `no` of `station`'s run `run` is filed.
    fn report_filed(&mut self, station: &str, run: &str, no: u64) -> Result<(), Self::Error>;

    /// The orders marked running (of any cell).
    fn running_orders(&self) -> Result<Vec<Order>, Self::Error> {
        Ok(self
            .orders()?
            .into_iter()
            .filter(|o| o.state == OrderState::Running)
            .collect())
    }

    /// An operator node starting again: the orders its records hold as
    /// running are adopted or interrupted as [`recovery`] says, and
    /// journalled so. The SQLite records do it in one transaction.
    fn recover(&mut self, cells: &[&str]) -> Result<Recovered, Self::Error> {
        let r = recovery(self.running_orders()?, cells);
        for o in &r.adopted {
            self.journal(EntryKind::Order, Some(o.id), "operator", &adopted_text(o))?;
        }
        for o in &r.interrupted {
            self.end_order(o.id, OrderState::Interrupted, INTERRUPTED_RESULT)?;
            let text = interrupted_text(o);
            self.journal(EntryKind::Order, Some(o.id), "operator", &text)?;
        }
        Ok(r)
    }
}

/// What an operator node starting again does with the orders its records
/// hold as running ([`Records::recover`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Recovered {
    /// One order per cell, still running, for the cell's list to adopt.
    pub adopted: Vec<Order>,
    /// The others, now interrupted.
    pub interrupted: Vec<Order>,
}

/// The result an interrupted order keeps.
pub const INTERRUPTED_RESULT: &str = "interrupted: the operator node stopped while it ran";

/// Which of the `running` orders the lists of `cells` adopt: the newest of
/// each cell, which the cell is asked about; every other (an older one, or
/// one of a cell not served) is interrupted, never run again by itself.
pub fn recovery(mut running: Vec<Order>, cells: &[&str]) -> Recovered {
    running.sort_by_key(|o| std::cmp::Reverse(o.id));
    let mut r = Recovered::default();
    for o in running {
        let cell = o.cell.as_deref().filter(|c| cells.contains(c));
        let taken = cell.is_some_and(|c| r.adopted.iter().any(|a| a.cell.as_deref() == Some(c)));
        if cell.is_some() && !taken {
            r.adopted.push(o);
        } else {
            r.interrupted.push(Order {
                state: OrderState::Interrupted,
                ..o
            });
        }
    }
    r
}

/// The journal line of an adopted order.
pub fn adopted_text(o: &Order) -> String {
    format!(
        "order {} ({}) was running on {} when the operator node stopped: the cell is asked \
         how it ended",
        o.id,
        o.recipe,
        o.cell.as_deref().unwrap_or_default()
    )
}

/// The journal line of an interrupted order.
pub fn interrupted_text(o: &Order) -> String {
    format!(
        "order {} ({}) interrupted: the operator node stopped while it ran; not restarted",
        o.id, o.recipe
    )
}

/// At most this many journal entries go with an order's record (its
/// whole journal stays readable page by page: `falc journal --order N`).
pub const RECORD_ENTRIES: usize = 2000;

/// In-memory records for unit tests of the cores and the whole-cell
/// simulation (`falc-sim`): they keep what the SQLite file keeps, and a
/// write fails while [`memory::Memory::failing`] is set (a full disk).
pub mod memory {
    use super::*;

    /// The cell of the alarms and modes kept in memory (the shipped
    /// topology's).
    pub const MEMORY_CELL: &str = "falc1";

    /// Records in memory; `failing` makes every write fail (a full disk).
    #[derive(Debug, Default)]
    pub struct Memory {
        /// Every write fails while set.
        pub failing: bool,
        /// The orders.
        pub orders: Vec<Order>,
        /// The journal.
        pub journal: Vec<Entry>,
        /// Every alarm ever raised.
        pub alarms: Vec<Alarm>,
        /// The highest id of a removed order.
        removed: i64,
        /// Every version kept, with its text.
        pub versions: Vec<(RecipeVersion, String)>,
        /// Each order's runs.
        pub runs: Vec<(i64, falc_model::product::OrderRun)>,
        /// Each run's span, as the figures read it.
        pub spans: Vec<crate::figures::RunSpan>,
        /// The mode changes kept.
        pub modes: Vec<crate::figures::ModeChange>,
        /// The changes of the order list's working kept.
        pub lists: Vec<crate::figures::ListChange>,
        /// The workstation jobs kept, with their order.
        pub jobs: Vec<(Option<i64>, JobRecord)>,
        /// The time given ([`Records::set_now`]).
        now: i64,
        refused: std::cell::Cell<u64>,
        /// Set: the alarms cannot be read (a row the records refuse),
        /// with why.
        pub unreadable_alarms: Option<String>,
        /// The cell the last write was for (a [`shared`] view sets it),
        /// and the writes refused per cell.
        pub(super) writer: String,
        refused_by: std::cell::RefCell<std::collections::BTreeMap<String, u64>>,
        /// The ids of the orders not ended (queued or running): what the
        /// queue is looked up in, so a long history costs nothing.
        live: std::collections::BTreeSet<i64>,
        /// The last report filed per (cell, station): its run and number.
        filed: std::collections::BTreeMap<(String, String), (String, u64)>,
    }

    impl Memory {
        fn write(&self) -> Result<(), String> {
            if self.failing {
                self.refused.set(self.refused.get() + 1);
                *self
                    .refused_by
                    .borrow_mut()
                    .entry(self.writer.clone())
                    .or_default() += 1;
                Err("disk full".into())
            } else {
                Ok(())
            }
        }
        /// How many writes were refused so far.
        pub fn refused(&self) -> u64 {
            self.refused.get()
        }
        /// How many writes for cell `cell` were refused so far (through
        /// its [`shared`] view).
        pub fn refused_of(&self, cell: &str) -> u64 {
            self.refused_by.borrow().get(cell).copied().unwrap_or(0)
        }
        /// Orders are kept by ascending id (added so, removed in place).
        fn order_mut(&mut self, id: i64) -> Option<&mut Order> {
            let i = self.orders.binary_search_by_key(&id, |o| o.id).ok()?;
            self.orders.get_mut(i)
        }
        fn order(&self, id: i64) -> Option<&Order> {
            let i = self.orders.binary_search_by_key(&id, |o| o.id).ok()?;
            self.orders.get(i)
        }
        /// The queued orders, by id.
        fn queue(&self) -> impl Iterator<Item = &Order> {
            self.live
                .iter()
                .filter_map(|id| self.order(*id))
                .filter(|o| o.state == OrderState::Queued)
        }
        /// The journal's texts, in order.
        pub fn texts(&self) -> Vec<String> {
            self.journal.iter().map(|e| e.text.clone()).collect()
        }
        /// [`Records::reports_filed`] of cell `cell`.
        pub fn reports_filed_of(&self, cell: &str) -> Vec<(String, String, u64)> {
            self.filed
                .iter()
                .filter(|((c, _), _)| c == cell)
                .map(|((_, st), (run, no))| (st.clone(), run.clone(), *no))
                .collect()
        }
        /// [`Records::report_filed`] of cell `cell`.
        pub fn report_filed_of(
            &mut self,
            cell: &str,
            station: &str,
            run: &str,
            no: u64,
        ) -> Result<(), String> {
            self.write()?;
            self.filed
                .insert((cell.into(), station.into()), (run.into(), no));
            Ok(())
        }
    }

    impl Records for Memory {
        type Error = String;
        fn now_ms(&self) -> i64 {
            self.now
        }
        fn set_now(&mut self, at_ms: i64) {
            self.now = at_ms;
        }
        fn add_order(
            &mut self,
            recipe: &str,
            who: &str,
            placement: &Placement,
        ) -> Result<Order, String> {
            self.write()?;
            // Like AUTOINCREMENT: never an id a removed order had.
            let id = self.orders.last().map_or(0, |o| o.id).max(self.removed) + 1;
            let o = Order {
                id,
                recipe: recipe.into(),
                state: OrderState::Queued,
                added_by: who.into(),
                started_ms: None,
                ended_ms: None,
                result: None,
                cell: None,
                wanted: placement.cell.as_ref().map(|c| c.to_string()),
                priority: placement.priority,
                due_ms: placement.due_ms,
                job_order: placement.job_order.clone(),
            };
            self.orders.push(o.clone());
            self.live.insert(id);
            Ok(o)
        }
        fn orders(&self) -> Result<Vec<Order>, String> {
            Ok(self.orders.clone())
        }
        fn running_orders(&self) -> Result<Vec<Order>, String> {
            Ok(self
                .live
                .iter()
                .filter_map(|id| self.order(*id))
                .filter(|o| o.state == OrderState::Running)
                .cloned()
                .collect())
        }
        fn next_queued(&self, cell: &str) -> Result<Option<Order>, String> {
            Ok(self
                .queue()
                .filter(|o| o.may_run_on(cell))
                .min_by_key(|o| o.dispatch_key())
                .cloned())
        }
        fn journal_head(&self) -> Result<i64, String> {
            Ok(self.journal.len() as i64)
        }
        fn queued(&self) -> Result<usize, String> {
            Ok(self.queue().count())
        }
        fn remove_order(&mut self, id: i64) -> Result<Result<Order, String>, String> {
            self.write()?;
            match self.orders.iter().position(|o| o.id == id) {
                Some(i) if self.orders[i].state == OrderState::Queued => {
                    self.removed = self.removed.max(id);
                    self.live.remove(&id);
                    Ok(Ok(self.orders.remove(i)))
                }
                Some(_) => Ok(Err(format!("order {id} is not queued"))),
                None => Ok(Err(format!("there is no order {id}"))),
            }
        }
        fn set_running(
            &mut self,
            id: i64,
            cell: &str,
            recipes: &[UsedRecipe],
        ) -> Result<i64, String> {
            self.write()?;
            let at = self.now_ms();
            let run = falc_model::product::OrderRun {
                started_ms: at,
                recipes: recipes.to_vec(),
            };
            self.runs.push((id, run));
            let recipe = self.order(id).map(|o| o.recipe.clone()).unwrap_or_default();
            self.spans.push(crate::figures::RunSpan {
                order: id,
                recipe,
                cell: cell.into(),
                start_ms: at,
                end_ms: None,
                state: OrderState::Running,
            });
            if let Some(o) = self.order_mut(id) {
                o.state = OrderState::Running;
                o.started_ms = Some(at);
                o.cell = Some(cell.into());
                self.live.insert(id);
            }
            Ok(at)
        }
        fn requeue(&mut self, id: i64) -> Result<(), String> {
            self.write()?;
            if let Some(o) = self
                .order_mut(id)
                .filter(|o| o.state == OrderState::Running)
            {
                o.state = OrderState::Queued;
                o.started_ms = None;
                o.cell = None;
                // The run that never began goes with it.
                if let Some(i) = self.runs.iter().rposition(|(o, _)| *o == id) {
                    self.runs.remove(i);
                }
                if let Some(i) = self.spans.iter().rposition(|s| s.order == id) {
                    self.spans.remove(i);
                }
            }
            Ok(())
        }
        fn end_order(&mut self, id: i64, state: OrderState, result: &str) -> Result<(), String> {
            self.write()?;
            let at = self.now_ms();
            if let Some(s) = self
                .spans
                .iter_mut()
                .rev()
                .find(|s| s.order == id && s.end_ms.is_none())
            {
                s.end_ms = Some(at);
                s.state = state;
            }
            if let Some(o) = self.order_mut(id) {
                o.state = state;
                o.ended_ms = Some(at);
                o.result = Some(result.into());
            }
            if !matches!(state, OrderState::Queued | OrderState::Running) {
                self.live.remove(&id);
            }
            Ok(())
        }
        fn journal_at(
            &mut self,
            at_ms: i64,
            kind: EntryKind,
            order: Option<i64>,
            who: &str,
            text: &str,
        ) -> Result<Entry, String> {
            self.write()?;
            let e = Entry {
                id: self.journal.len() as i64 + 1,
                at_ms,
                order,
                kind,
                who: who.into(),
                text: text.into(),
                cell: None,
            };
            self.journal.push(e.clone());
            Ok(e)
        }
        fn entries(&self, query: &EntryQuery) -> Result<Vec<Entry>, String> {
            let all: Vec<Entry> = self
                .journal
                .iter()
                .filter(|e| query.matches(e))
                .cloned()
                .collect();
            let (n, limit) = (all.len(), query.limit);
            Ok(if query.newest {
                all[n.saturating_sub(limit)..].to_vec()
            } else {
                all[..n.min(limit)].to_vec()
            })
        }
        fn raise_alarm(
            &mut self,
            station: &StationName,
            class: AlarmClass,
            text: &str,
            order: Option<i64>,
        ) -> Result<Alarm, String> {
            self.write()?;
            let a = Alarm {
                id: self.alarms.len() as i64 + 1,
                station: station.clone(),
                class,
                text: text.into(),
                order,
                raised_ms: self.now_ms(),
                acked: None,
                cleared_ms: None,
            };
            self.alarms.push(a.clone());
            Ok(a)
        }
        fn ack_alarm(&mut self, id: i64, who: &str, at_ms: i64) -> Result<(), String> {
            self.write()?;
            if let Some(a) = self.alarms.iter_mut().find(|a| a.id == id) {
                a.acked = Some((who.into(), at_ms));
            }
            Ok(())
        }
        fn clear_alarm(&mut self, id: i64, at_ms: i64) -> Result<(), String> {
            self.write()?;
            if let Some(a) = self.alarms.iter_mut().find(|a| a.id == id) {
                a.cleared_ms = Some(at_ms);
            }
            Ok(())
        }
        fn listed_alarms(&self) -> Result<Vec<Alarm>, String> {
            if let Some(why) = &self.unreadable_alarms {
                return Err(why.clone());
            }
            Ok(self.alarms.iter().filter(|a| a.listed()).cloned().collect())
        }
        fn add_version(
            &mut self,
            file: &RecipeFile,
            text: &str,
            who: &str,
            message: &str,
        ) -> Result<(RecipeVersion, bool), String> {
            let hash = falc_model::product::VersionHash::of(text.as_bytes());
            let newest = self.versions.iter().rev().find(|(v, _)| &v.file == file);
            if let Some((v, _)) = newest.filter(|(v, _)| v.hash == hash) {
                return Ok((v.clone(), false));
            }
            self.write()?;
            let v = RecipeVersion {
                file: file.clone(),
                version: newest.map_or(1, |(v, _)| v.version + 1),
                hash,
                author: who.into(),
                at_ms: self.now_ms(),
                message: message.into(),
            };
            self.versions.push((v.clone(), text.into()));
            Ok((v, true))
        }
        fn versions(&self, file: &RecipeFile) -> Result<Vec<RecipeVersion>, String> {
            Ok(self
                .versions
                .iter()
                .filter(|(v, _)| &v.file == file)
                .map(|(v, _)| v.clone())
                .collect())
        }
        fn version(
            &self,
            file: &RecipeFile,
            version: u32,
        ) -> Result<Option<(RecipeVersion, String)>, String> {
            Ok(self
                .versions
                .iter()
                .find(|(v, _)| &v.file == file && v.version == version)
                .cloned())
        }
        fn order_record(&self, id: i64) -> Result<Option<OrderRecord>, String> {
            let Some(order) = self.orders.iter().find(|o| o.id == id).cloned() else {
                return Ok(None);
            };
            Ok(Some(OrderRecord {
                order,
                runs: self
                    .runs
                    .iter()
                    .filter(|(o, _)| *o == id)
                    .map(|(_, r)| r.clone())
                    .collect(),
                jobs: self
                    .jobs
                    .iter()
                    .filter(|(o, _)| *o == Some(id))
                    .map(|(_, j)| j.clone())
                    .collect(),
                entries: self
                    .journal
                    .iter()
                    .filter(|e| e.order == Some(id))
                    .take(RECORD_ENTRIES)
                    .cloned()
                    .collect(),
                alarms: self
                    .alarms
                    .iter()
                    .filter(|a| a.order == Some(id))
                    .cloned()
                    .collect(),
            }))
        }
        fn record_job(&mut self, order: Option<i64>, job: &JobRecord) -> Result<(), String> {
            self.write()?;
            self.jobs.push((order, job.clone()));
            Ok(())
        }
        fn record_working(&mut self, working: bool) -> Result<(), String> {
            if self.lists.last().map(|l| l.working) == Some(working) {
                return Ok(());
            }
            self.write()?;
            let at_ms = self.now_ms();
            self.lists.push(crate::figures::ListChange {
                cell: MEMORY_CELL.into(),
                at_ms,
                working,
            });
            Ok(())
        }
        fn reports_filed(&self) -> Result<Vec<(String, String, u64)>, String> {
            Ok(self.reports_filed_of(MEMORY_CELL))
        }
        fn report_filed(&mut self, station: &str, run: &str, no: u64) -> Result<(), String> {
            self.report_filed_of(MEMORY_CELL, station, run, no)
        }
        fn record_mode(&mut self, mode: CellMode) -> Result<(), String> {
            if self.modes.last().map(|m| m.mode) == Some(mode) {
                return Ok(());
            }
            self.write()?;
            let at_ms = self.now_ms();
            self.modes.push(crate::figures::ModeChange {
                cell: MEMORY_CELL.into(),
                at_ms,
                mode,
            });
            Ok(())
        }
        fn figure_inputs(&self, since: i64, until: i64) -> Result<FigureInputs, String> {
            let overlaps =
                |start: i64, end: Option<i64>| start < until && end.map_or(true, |e| e > since);
            Ok(FigureInputs {
                runs: self
                    .spans
                    .iter()
                    .filter(|s| overlaps(s.start_ms, s.end_ms))
                    .cloned()
                    .collect(),
                alarms: self
                    .alarms
                    .iter()
                    .filter(|a| overlaps(a.raised_ms, a.gone_ms()))
                    .map(|a| crate::figures::AlarmSpan {
                        cell: MEMORY_CELL.into(),
                        station: a.station.to_string(),
                        class: a.class,
                        raised_ms: a.raised_ms,
                        gone_ms: a.gone_ms(),
                    })
                    .collect(),
                modes: self
                    .modes
                    .iter()
                    .filter(|m| m.at_ms < until)
                    .cloned()
                    .collect(),
                lists: self
                    .lists
                    .iter()
                    .filter(|l| l.at_ms < until)
                    .cloned()
                    .collect(),
            })
        }
    }
}

/// The plant's records in memory, for unit tests of several cells'
/// lists: one [`memory::Memory`] shared, each cell's view of it listing
/// its own alarms, as each cell's connection to the SQLite file does. The
/// simulation reads the records through it while the order list writes.
pub mod shared {
    use super::memory::Memory;
    use super::*;
    use falc_model::api::Placement;
    use std::cell::RefCell;
    use std::collections::BTreeMap;
    use std::rc::Rc;

    /// One cell's view of the shared records; a clone is a second handle
    /// on the same records (an operator node started again opens the same
    /// file).
    #[derive(Clone)]
    pub struct Shared {
        /// The plant's records.
        pub all: Rc<RefCell<Memory>>,
        /// Which cell raised each alarm.
        owners: Rc<RefCell<BTreeMap<i64, String>>>,
        cell: String,
    }

    /// A view for each of `cells`, over one set of records.
    pub fn plant(cells: &[&str]) -> Vec<Shared> {
        let all = Rc::new(RefCell::new(Memory::default()));
        let owners = Rc::new(RefCell::new(BTreeMap::new()));
        cells
            .iter()
            .map(|c| Shared {
                all: all.clone(),
                owners: owners.clone(),
                cell: c.to_string(),
            })
            .collect()
    }

    impl Shared {
        /// The records, to write on behalf of this view's cell (a write
        /// refused is counted against it: [`Memory::refused_of`]).
        fn writing(&self) -> std::cell::RefMut<'_, Memory> {
            let mut m = self.all.borrow_mut();
            if m.writer != self.cell {
                m.writer.clone_from(&self.cell);
            }
            m
        }
    }

    impl Records for Shared {
        type Error = String;
        fn now_ms(&self) -> i64 {
            self.all.borrow().now_ms()
        }
        fn set_now(&mut self, at_ms: i64) {
            self.writing().set_now(at_ms);
        }
        fn add_order(&mut self, recipe: &str, who: &str, p: &Placement) -> Result<Order, String> {
            self.writing().add_order(recipe, who, p)
        }
        fn orders(&self) -> Result<Vec<Order>, String> {
            self.all.borrow().orders()
        }
        fn running_orders(&self) -> Result<Vec<Order>, String> {
            self.all.borrow().running_orders()
        }
        fn next_queued(&self, cell: &str) -> Result<Option<Order>, String> {
            self.all.borrow().next_queued(cell)
        }
        fn journal_head(&self) -> Result<i64, String> {
            self.all.borrow().journal_head()
        }
        fn queued(&self) -> Result<usize, String> {
            self.all.borrow().queued()
        }
        fn remove_order(&mut self, id: i64) -> Result<Result<Order, String>, String> {
            self.writing().remove_order(id)
        }
        fn set_running(
            &mut self,
            id: i64,
            cell: &str,
            recipes: &[UsedRecipe],
        ) -> Result<i64, String> {
            self.writing().set_running(id, cell, recipes)
        }
        fn requeue(&mut self, id: i64) -> Result<(), String> {
            self.writing().requeue(id)
        }
        fn end_order(&mut self, id: i64, state: OrderState, result: &str) -> Result<(), String> {
            self.writing().end_order(id, state, result)
        }
        fn journal_at(
            &mut self,
            at_ms: i64,
            kind: EntryKind,
            order: Option<i64>,
            who: &str,
            text: &str,
        ) -> Result<Entry, String> {
            let mut all = self.writing();
            let mut e = all.journal_at(at_ms, kind, order, who, text)?;
            e.cell = Some(self.cell.clone());
            if let Some(last) = all.journal.last_mut() {
                last.cell = e.cell.clone();
            }
            Ok(e)
        }
        fn entries(&self, query: &EntryQuery) -> Result<Vec<Entry>, String> {
            self.all.borrow().entries(query)
        }
        fn raise_alarm(
            &mut self,
            station: &StationName,
            class: AlarmClass,
            text: &str,
            order: Option<i64>,
        ) -> Result<Alarm, String> {
            let a = self
                .all
                .borrow_mut()
                .raise_alarm(station, class, text, order)?;
            self.owners.borrow_mut().insert(a.id, self.cell.clone());
            Ok(a)
        }
        fn ack_alarm(&mut self, id: i64, who: &str, at_ms: i64) -> Result<(), String> {
            self.writing().ack_alarm(id, who, at_ms)
        }
        fn clear_alarm(&mut self, id: i64, at_ms: i64) -> Result<(), String> {
            self.writing().clear_alarm(id, at_ms)
        }
        fn listed_alarms(&self) -> Result<Vec<Alarm>, String> {
            let owners = self.owners.borrow();
            Ok(self
                .all
                .borrow()
                .listed_alarms()?
                .into_iter()
                .filter(|a| owners.get(&a.id) == Some(&self.cell))
                .collect())
        }
        fn add_version(
            &mut self,
            file: &RecipeFile,
            text: &str,
            who: &str,
            message: &str,
        ) -> Result<(RecipeVersion, bool), String> {
            self.writing().add_version(file, text, who, message)
        }
        fn versions(&self, file: &RecipeFile) -> Result<Vec<RecipeVersion>, String> {
            self.all.borrow().versions(file)
        }
        fn version(
            &self,
            file: &RecipeFile,
            version: u32,
        ) -> Result<Option<(RecipeVersion, String)>, String> {
            self.all.borrow().version(file, version)
        }
        fn order_record(&self, id: i64) -> Result<Option<OrderRecord>, String> {
            self.all.borrow().order_record(id)
        }
        fn record_job(&mut self, order: Option<i64>, job: &JobRecord) -> Result<(), String> {
            self.writing().record_job(order, job)
        }
        fn record_mode(&mut self, mode: CellMode) -> Result<(), String> {
            self.writing().record_mode(mode)
        }
        fn record_working(&mut self, working: bool) -> Result<(), String> {
            self.writing().record_working(working)
        }
        fn reports_filed(&self) -> Result<Vec<(String, String, u64)>, String> {
            Ok(self.all.borrow().reports_filed_of(&self.cell))
        }
        fn report_filed(&mut self, station: &str, run: &str, no: u64) -> Result<(), String> {
            self.all
                .borrow_mut()
                .report_filed_of(&self.cell, station, run, no)
        }
        fn figure_inputs(&self, since: i64, until: i64) -> Result<FigureInputs, String> {
            self.all.borrow().figure_inputs(since, until)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::memory::Memory;
    use super::Records;
    use falc_model::api::Placement;
    use falc_model::ids::CellId;

    #[test]
    fn a_restarted_operator_adopts_the_newest_running_order_of_its_cell_and_interrupts_the_rest() {
        use falc_model::records::{EntryKind, OrderState};
        let mut m = Memory::default();
        let p = Placement::default();
        let ids: Vec<i64> = (0..3)
            .map(|_| m.add_order("dikdroog", "ann", &p).expect("added").id)
            .collect();
        m.set_running(ids[0], "falc1", &[]).expect("running");
        m.set_running(ids[1], "falc1", &[]).expect("running");
        let r = m.recover(&["falc1"]).expect("recovered");
        assert_eq!(
            r.adopted.iter().map(|o| o.id).collect::<Vec<_>>(),
            vec![ids[1]]
        );
        assert_eq!(
            r.interrupted.iter().map(|o| o.id).collect::<Vec<_>>(),
            vec![ids[0]]
        );
        let states: Vec<OrderState> = m.orders.iter().map(|o| o.state).collect();
        assert_eq!(
            states,
            vec![
                OrderState::Interrupted,
                OrderState::Running,
                OrderState::Queued
            ]
        );
        let lines: Vec<&str> = m
            .journal
            .iter()
            .filter(|e| e.kind == EntryKind::Order)
            .map(|e| e.text.as_str())
            .collect();
        assert!(
            lines.iter().any(|l| l.contains("was running on falc1")),
            "{lines:?}"
        );
        assert!(lines.iter().any(|l| l.contains("interrupted")), "{lines:?}");
        // A full disk: the recovery fails, and says so.
        m.failing = true;
        m.set_running(ids[2], "falc1", &[]).ok();
        assert!(m.recover(&["falc1"]).is_err());
    }

    #[test]
    fn the_fake_never_reuses_an_order_id() {
        let mut m = Memory::default();
        let p = Placement::default();
        let a = m.add_order("dikdroog", "ann", &p).map(|o| o.id);
        let b = m.add_order("dikdroog", "ann", &p).map(|o| o.id);
        assert_eq!((a, b), (Ok(1), Ok(2)));
        assert!(m.remove_order(2).is_ok_and(|r| r.is_ok()));
        assert_eq!(m.add_order("dikdroog", "ann", &p).map(|o| o.id), Ok(3));
    }

    /// The dispatch order: priority, then due time (none last), then the
    /// order added first; an order added for a cell runs there only, and a
    /// refused start puts an order for any cell back for any cell.
    #[test]
    fn the_next_order_goes_by_priority_due_time_and_age_on_the_cells_it_may_run_on() {
        let mut m = Memory::default();
        let place = |cell: Option<&str>, priority: i32, due_ms: Option<i64>| Placement {
            cell: cell.map(|c| CellId::new(c).expect("id")),
            priority,
            due_ms,
            job_order: None,
        };
        let mut add = |p: Placement| m.add_order("dikdroog", "ann", &p).expect("add").id;
        let plain = add(place(None, 0, None));
        let due_late = add(place(None, 0, Some(2_000)));
        let due_soon = add(place(None, 0, Some(1_000)));
        let urgent = add(place(None, 5, None));
        let for_two = add(place(Some("falc2"), 9, None));
        let next = |m: &Memory, cell: &str| m.next_queued(cell).expect("read").map(|o| o.id);
        assert_eq!(next(&m, "falc2"), Some(for_two));
        assert_eq!(
            next(&m, "falc1"),
            Some(urgent),
            "falc1 may not take falc2's"
        );
        m.set_running(urgent, "falc1", &[]).expect("run");
        assert_eq!(next(&m, "falc1"), Some(due_soon));
        m.set_running(due_soon, "falc1", &[]).expect("run");
        assert_eq!(next(&m, "falc1"), Some(due_late));
        m.set_running(due_late, "falc1", &[]).expect("run");
        assert_eq!(next(&m, "falc1"), Some(plain));
        // A refused start: back in the queue, for any cell.
        m.requeue(urgent).expect("requeue");
        assert_eq!(next(&m, "falc3"), Some(urgent));
        let o = m.orders().expect("orders");
        assert_eq!(
            o.iter()
                .find(|o| o.id == urgent)
                .and_then(|o| o.cell.clone()),
            None
        );
        assert_eq!(
            o.iter()
                .find(|o| o.id == due_late)
                .and_then(|o| o.cell.clone())
                .as_deref(),
            Some("falc1")
        );
    }
}
