//! The factory controller over several cells, sans-I/O: one
//! [`OrderList`] per cell, all over the plant's one order table and
//! journal (each cell's list takes the next order it may run whenever it
//! is free: [`crate::records::Records::next_queued`]), and the operator
//! API's requests routed to the cells they concern.
//!
//! - A request for one cell (`falc --cell C …`) goes to that cell's list
//!   as it is, and is answered as a cell of its own answers it.
//! - Without a cell, in a plant of one cell: the same, to the one cell.
//! - Without a cell, in a plant of several: `status` answers every cell
//!   at a glance ([`PlantStatus`]); the order list, the journal and the
//!   recipes are the plant's (any list answers them); `order add` goes
//!   to a cell that may run the order; `start`, `stop`, `shutdown` and
//!   `ack` (all) go to every cell, answered once all have (one line per
//!   cell); `ack N` to the cell whose alarm N is, `restart N` to the cell
//!   order N ran on, `answer` to the one cell that asks; `mode`, `step`
//!   and `manual` need the cell.
//!
//! An alarm in one cell stops that cell's list only; the others run on,
//! and take the orders that cell would have run unless they were added
//! for it.

use crate::order_list::{OrderList, Output, Ticket};
use crate::recipe_source::RecipeSource;
use crate::records::Records;
use falc_model::api::{ApiReply, ApiRequest, ApiResult, PlantStatus};
use falc_model::ids::{CellId, StationName};
use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

/// Tickets the plant makes for the part of a request one cell answers;
/// the node's own tickets stay below.
const SUB_TICKETS: u64 = 1 << 62;

/// What the node must do.
#[derive(Debug)]
pub enum PlantOutput {
    /// What cell `cell`'s list put out for its cell and its stations: a
    /// call to its cell controller, an answer to one of its indications,
    /// a line to say, a change of its status.
    Cell(usize, Output),
    /// Answer a console's request.
    Reply {
        /// Which.
        ticket: Ticket,
        /// The answer.
        result: Box<ApiResult>,
    },
}

/// A console request that several cells answer.
#[derive(Debug)]
struct Fan {
    waiting: usize,
    answers: Vec<(usize, ApiResult)>,
}

/// The factory controller: every cell's order list.
pub struct Plant<R: Records, S: RecipeSource> {
    lists: Vec<OrderList<R, S>>,
    fans: BTreeMap<Ticket, Fan>,
    /// A cell's part → the console's request it belongs to.
    parts: BTreeMap<Ticket, Ticket>,
    next_part: u64,
    out: VecDeque<PlantOutput>,
}

impl<R: Records, S: RecipeSource> Plant<R, S> {
    /// The plant of these cells' lists, in the plant file's order.
    pub fn new(lists: Vec<OrderList<R, S>>) -> Self {
        Plant {
            lists,
            fans: BTreeMap::new(),
            parts: BTreeMap::new(),
            next_part: SUB_TICKETS,
            out: VecDeque::new(),
        }
    }

    /// How many cells.
    pub fn len(&self) -> usize {
        self.lists.len()
    }

    /// Whether the plant has no cell (never, once built from a plant file).
    pub fn is_empty(&self) -> bool {
        self.lists.is_empty()
    }

    /// Cell `i`'s order list, for the events of its cell and stations.
    pub fn list(&mut self, i: usize) -> Option<&mut OrderList<R, S>> {
        self.lists.get_mut(i)
    }

    /// Cell `i`'s order list, to read.
    pub fn list_at(&self, i: usize) -> Option<&OrderList<R, S>> {
        self.lists.get(i)
    }

    /// The cells' ids, in order.
    pub fn cells(&self) -> Vec<CellId> {
        self.lists.iter().map(|l| l.cell().clone()).collect()
    }

    /// The next thing the node must do.
    pub fn poll_output(&mut self) -> Option<PlantOutput> {
        loop {
            if let Some(out) = self.out.pop_front() {
                return Some(out);
            }
            let mut any = false;
            for i in 0..self.lists.len() {
                while let Some(out) = self.lists[i].poll_output() {
                    any = true;
                    self.out.push_back(PlantOutput::Cell(i, out));
                }
                while let Some((ticket, result)) = self.lists[i].poll_reply() {
                    any = true;
                    self.answered(i, ticket, result);
                }
                // The queue and the journal are the plant's, but a change
                // one list made is told by that list alone: `changed` is
                // the plant's word, and the others compute nothing (their
                // statuses are read afresh when a console asks).
            }
            if !any && self.out.is_empty() {
                return None;
            }
        }
    }

    /// When the earliest list wants to be woken.
    pub fn poll_timeout(&self) -> Option<Duration> {
        self.lists.iter().filter_map(|l| l.poll_timeout()).min()
    }

    /// The time passed: every list looks at its own.
    pub fn handle_timeout(&mut self, now: Duration) {
        for l in &mut self.lists {
            l.handle_timeout(now);
        }
    }

    /// Whether the node may stop: every cell's list is shut down.
    pub fn should_stop(&self) -> bool {
        !self.lists.is_empty() && self.lists.iter().all(|l| l.should_stop())
    }

    /// One operator API request of console user `user`, for cell `cell`
    /// or the plant; answered through [`PlantOutput::Reply`] under
    /// `ticket`.
    pub fn handle_api(
        &mut self,
        now: Duration,
        ticket: Ticket,
        user: &StationName,
        cell: Option<&CellId>,
        request: ApiRequest,
    ) {
        let to = match cell {
            Some(id) => match self.lists.iter().position(|l| l.cell() == id) {
                Some(i) => Route::Cell(i),
                None => Route::Refuse(format!(
                    "there is no cell {id}; the plant has {}",
                    self.names()
                )),
            },
            None if self.lists.len() == 1 => Route::One(0),
            None => self.route(&request),
        };
        match to {
            Route::One(i) => self.lists[i].handle_api(now, ticket, user, request),
            Route::Cell(i) => self.lists[i].handle_cell_api(now, ticket, user, request),
            Route::Every => {
                self.fans.insert(
                    ticket,
                    Fan {
                        waiting: self.lists.len(),
                        answers: Vec::new(),
                    },
                );
                for i in 0..self.lists.len() {
                    let part = Ticket(self.next_part);
                    self.next_part += 1;
                    self.parts.insert(part, ticket);
                    self.lists[i].handle_api(now, part, user, request.clone());
                }
            }
            Route::Status => {
                let mut cells = Vec::new();
                let mut failed = None;
                for l in &self.lists {
                    match l.status() {
                        Ok(s) => cells.push((l.cell().clone(), s)),
                        Err(e) => failed = Some(e.to_string()),
                    }
                }
                let result = match failed {
                    Some(e) => Err(e),
                    None => Ok(ApiReply::Plant(PlantStatus { cells })),
                };
                self.reply(ticket, result);
            }
            Route::Refuse(why) => self.reply(ticket, Err(why)),
        }
    }

    /// Where a request without a cell goes in a plant of several.
    fn route(&self, request: &ApiRequest) -> Route {
        let needs_cell = |what: &str| {
            Route::Refuse(format!(
                "`{what}` is for one cell: give --cell (the plant has {})",
                self.names()
            ))
        };
        match request {
            ApiRequest::Status => Route::Status,
            ApiRequest::OrderList
            | ApiRequest::Messages { .. }
            | ApiRequest::Journal { .. }
            | ApiRequest::OrderRemove { .. }
            | ApiRequest::RecipeList
            | ApiRequest::RecipeGet { .. }
            | ApiRequest::RecipePut { .. }
            | ApiRequest::RecipeHistory { .. }
            | ApiRequest::RecipeVersion { .. }
            | ApiRequest::RecipeRollback { .. }
            | ApiRequest::OrderShow { .. }
            | ApiRequest::Figures(_) => Route::One(0),
            ApiRequest::OrderAdd {
                recipe, placement, ..
            } => match &placement.cell {
                Some(id) => match self.lists.iter().position(|l| l.cell() == id) {
                    Some(i) => Route::One(i),
                    None => Route::Refuse(format!(
                        "there is no cell {id}; the plant has {}",
                        self.names()
                    )),
                },
                // Any cell that knows the recipe checks and adds it (the
                // first, when none does: it says so).
                None => Route::One(
                    self.lists
                        .iter()
                        .position(|l| l.knows_recipe(recipe))
                        .unwrap_or(0),
                ),
            },
            ApiRequest::Start | ApiRequest::Stop | ApiRequest::Shutdown => Route::Every,
            ApiRequest::Ack { id: None } => Route::Every,
            ApiRequest::Ack { id: Some(id) } => Route::One(
                self.lists
                    .iter()
                    .position(|l| l.has_alarm(*id))
                    .unwrap_or(0),
            ),
            ApiRequest::Restart { order, .. } => {
                match self.lists.iter().position(|l| l.ran(*order)) {
                    Some(i) => Route::One(i),
                    None => Route::Refuse(format!(
                        "order {order} ran on no cell of this plant: nothing to restart"
                    )),
                }
            }
            ApiRequest::Answer { .. } => {
                let asking: Vec<usize> = (0..self.lists.len())
                    .filter(|&i| self.lists[i].question_waiting())
                    .collect();
                match asking.as_slice() {
                    [] => Route::Refuse("no question is waiting for an answer".into()),
                    [i] => Route::One(*i),
                    many => Route::Refuse(format!(
                        "cells {} ask: answer with --cell",
                        many.iter()
                            .map(|&i| self.lists[i].cell().to_string())
                            .collect::<Vec<_>>()
                            .join(", ")
                    )),
                }
            }
            ApiRequest::Mode { .. } => needs_cell("mode"),
            ApiRequest::Step { .. } => needs_cell("step"),
            ApiRequest::Manual { .. } => needs_cell("manual"),
        }
    }

    fn names(&self) -> String {
        self.lists
            .iter()
            .map(|l| l.cell().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    }

    fn reply(&mut self, ticket: Ticket, result: ApiResult) {
        self.out.push_back(PlantOutput::Reply {
            ticket,
            result: Box::new(result),
        });
    }

    /// Cell `i`'s list answered `ticket`: the console's answer, or one
    /// cell's part of it (answered once every cell's part is in).
    fn answered(&mut self, i: usize, ticket: Ticket, result: ApiResult) {
        let Some(parent) = self.parts.remove(&ticket) else {
            return self.reply(ticket, result);
        };
        let Some(fan) = self.fans.get_mut(&parent) else {
            return;
        };
        fan.answers.push((i, result));
        fan.waiting = fan.waiting.saturating_sub(1);
        if fan.waiting > 0 {
            return;
        }
        let Some(mut fan) = self.fans.remove(&parent) else {
            return;
        };
        fan.answers.sort_by_key(|(i, _)| *i);
        let any_done = fan.answers.iter().any(|(_, r)| r.is_ok());
        let lines: Vec<String> = fan
            .answers
            .iter()
            .map(|(i, r)| {
                let cell = self.lists[*i].cell();
                match r {
                    Ok(ApiReply::Done(text)) => format!("{cell}: {text}"),
                    Ok(_) => format!("{cell}: done"),
                    Err(why) => format!("{cell}: {why}"),
                }
            })
            .collect();
        let text = lines.join("\n");
        self.reply(
            parent,
            if any_done {
                Ok(ApiReply::Done(text))
            } else {
                Err(text)
            },
        );
    }
}

/// Where a console request goes.
enum Route {
    /// To one cell's list, as the plant's request.
    One(usize),
    /// To one cell's list, as a request for that cell (`--cell`).
    Cell(usize),
    Every,
    Status,
    Refuse(String),
}

#[cfg(test)]
mod tests {
    //! Two cells' lists over shared records in memory, on a virtual clock;
    //! the test plays both cell controllers and the consoles.

    use super::*;
    use crate::order_list::CellCall;
    use crate::recipe_source::fake::{set, Source};
    use crate::records::shared::{self, Shared};
    use falc_model::alarm::{AlarmClass, Cause};
    use falc_model::api::{ListState, Placement};
    use falc_model::ids::ObjectName;
    use falc_model::mms::pdu::{JobEvent, Request, Response, Unconfirmed};
    use falc_model::mode::CellMode;
    use falc_model::records::OrderState;
    use falc_model::topology::Topology;

    fn st(s: &str) -> StationName {
        StationName::new(s).expect("station")
    }

    fn topology(cell: &str) -> Topology {
        let text = format!(
            "cell = \"{cell}\"\nrouter = \"tcp/127.0.0.1:7447\"\n\
             [[station]]\nname = \"operator\"\nkind = \"operator\"\n\
             [[station]]\nname = \"cell\"\nkind = \"cell\"\ncommander = \"operator\"\n\
             [[station]]\nname = \"welding\"\nkind = \"welding\"\ncommander = \"cell\"\n\
             [[console]]\nname = \"console\"\nrole = \"operator\"\n"
        );
        Topology::parse(&text, "test").expect("topology")
    }

    struct Rig {
        plant: Plant<Shared, Source>,
        records: Shared,
        tickets: u64,
        now: Duration,
    }

    impl Rig {
        fn new() -> Self {
            let mut views = shared::plant(&["falc1", "falc2", "falc1"]);
            let records = views.pop().expect("a view to read");
            let lists = ["falc1", "falc2"]
                .into_iter()
                .zip(views)
                .map(|(c, db)| {
                    OrderList::new(
                        st("operator"),
                        st("cell"),
                        topology(c),
                        db,
                        Source::default(),
                        set(),
                    )
                })
                .collect();
            Rig {
                plant: Plant::new(lists),
                records,
                tickets: 0,
                now: Duration::ZERO,
            }
        }

        /// A console request; the answer once the cells answered every
        /// call they were given (the test plays both cell controllers).
        fn ask(&mut self, cell: Option<&str>, req: ApiRequest) -> ApiResult {
            self.tickets += 1;
            let t = Ticket(self.tickets);
            let cell = cell.map(|c| CellId::new(c).expect("id"));
            self.plant
                .handle_api(self.now, t, &st("console"), cell.as_ref(), req);
            loop {
                let mut calls = Vec::new();
                while let Some(out) = self.plant.poll_output() {
                    match out {
                        PlantOutput::Reply { ticket, result } if ticket == t => return *result,
                        PlantOutput::Cell(i, Output::Cell(call)) => calls.push((i, call)),
                        _ => {}
                    }
                }
                assert!(!calls.is_empty(), "no answer and no call");
                for (i, _) in calls {
                    let list = self.plant.list(i).expect("list");
                    list.handle_cell_answer(self.now, Ok(Response::Done));
                }
            }
        }

        /// Cell `i`'s controller publishes the end of its job.
        fn job(&mut self, i: usize, event: JobEvent) -> Vec<(usize, CellCall)> {
            let list = self.plant.list(i).expect("list");
            list.handle_heard(
                self.now,
                None,
                Unconfirmed::Job {
                    station: st("cell"),
                    program: ObjectName::new("DIKDROOG").expect("name"),
                    event,
                },
            );
            let mut calls = Vec::new();
            while let Some(out) = self.plant.poll_output() {
                if let PlantOutput::Cell(i, Output::Cell(call)) = out {
                    calls.push((i, call));
                }
            }
            calls
        }

        fn order(&self, id: i64) -> (OrderState, Option<String>) {
            let orders = self.records.orders().expect("orders");
            let o = orders.iter().find(|o| o.id == id).expect("order");
            (o.state, o.cell.clone())
        }

        fn status(&mut self) -> PlantStatus {
            match self.ask(None, ApiRequest::Status) {
                Ok(ApiReply::Plant(p)) => p,
                other => panic!("{other:?}"),
            }
        }
    }

    fn add(cell: Option<&str>) -> ApiRequest {
        ApiRequest::OrderAdd {
            recipe: "dikdroog".into(),
            placement: Placement {
                cell: cell.map(|c| CellId::new(c).expect("id")),
                ..Placement::default()
            },
            count: 1,
        }
    }

    /// Which cells' lists told a changed status, draining what came out.
    fn told(r: &mut Rig) -> Vec<usize> {
        let mut told = Vec::new();
        while let Some(out) = r.plant.poll_output() {
            if let PlantOutput::Cell(i, Output::Changed) = out {
                told.push(i);
            }
        }
        told
    }

    /// A list computes its status when something happened to it, not at
    /// every poll; an order one cell's list queues moves the plant's queue
    /// and journal, told once, by that list (the others compute nothing:
    /// every list computing its status again and telling it at every
    /// journal entry of any cell cost the operator and the factory router
    /// a quarter of their CPU at 16 cells). The plant's status, read
    /// afresh, shows it in every cell.
    #[test]
    fn a_status_is_told_when_something_changed_it_in_any_cell() {
        let mut r = Rig::new();
        told(&mut r);
        assert_eq!(told(&mut r), Vec::<usize>::new(), "nothing happened");
        // An order for falc1, added through falc1's list.
        r.tickets += 1;
        let cell = CellId::new("falc1").expect("id");
        let t = Ticket(r.tickets);
        r.plant
            .handle_api(r.now, t, &st("console"), Some(&cell), add(Some("falc1")));
        assert_eq!(told(&mut r), [0], "the list that queued it tells it, once");
        assert_eq!(told(&mut r), Vec::<usize>::new());
        let s = r.status();
        let seen: Vec<(usize, i64)> = s
            .cells
            .iter()
            .map(|(_, c)| (c.queued, c.journal_head))
            .collect();
        assert_eq!(
            seen[0], seen[1],
            "both cells show the plant's queue and journal"
        );
        assert_eq!(seen[0].0, 1);
    }

    /// Both cells run in parallel from one list; an order for a cell waits
    /// for it; an alarm in one cell stops its list only and the other
    /// takes the orders it could have run; `ack` and `start` for that
    /// cell are its way back.
    #[test]
    fn the_cells_work_through_one_list_in_parallel_and_an_alarm_stops_one_cell() {
        let mut r = Rig::new();
        assert!(r.ask(None, add(None)).is_ok());
        assert!(r.ask(None, add(None)).is_ok());
        assert!(r.ask(None, add(Some("falc1"))).is_ok());
        assert!(r.ask(None, add(None)).is_ok());
        let started = r.ask(None, ApiRequest::Start);
        assert_eq!(
            started,
            Ok(ApiReply::Done(
                "falc1: order 1 (dikdroog) started\nfalc2: order 2 (dikdroog) started".into()
            ))
        );
        assert_eq!(r.order(1), (OrderState::Running, Some("falc1".into())));
        assert_eq!(r.order(2), (OrderState::Running, Some("falc2".into())));
        let s = r.status();
        let lists: Vec<ListState> = s.cells.iter().map(|(_, c)| c.list).collect();
        assert_eq!(lists, [ListState::Running, ListState::Running]);

        // An alarm in falc2: its list stops; falc1 ends its order and
        // takes the next, the one added for it.
        r.job(
            1,
            JobEvent::Alarm(Cause::new(
                AlarmClass::Safety,
                "RCM message 24: emergency stop",
            )),
        );
        assert_eq!(r.order(2).0, OrderState::Failed);
        let calls = r.job(0, JobEvent::Done);
        assert!(
            calls
                .iter()
                .any(|(i, c)| *i == 0 && matches!(c, CellCall::Start { .. })),
            "falc1 starts the next order: {calls:?}"
        );
        r.plant
            .list(0)
            .expect("list")
            .handle_cell_answer(r.now, Ok(Response::Done));
        assert_eq!(r.order(1).0, OrderState::Done);
        assert_eq!(r.order(3), (OrderState::Running, Some("falc1".into())));
        let s = r.status();
        let lists: Vec<ListState> = s.cells.iter().map(|(_, c)| c.list).collect();
        assert_eq!(lists, [ListState::Running, ListState::Alarm]);
        assert!(s.cells[1].1.alarm.is_some() && s.cells[0].1.alarm.is_none());

        // The way back in falc2: its alarm acknowledged by number (found
        // in falc2), then `start` for falc2 takes order 4.
        let id = s.cells[1].1.alarms[0].id;
        let acked = r.ask(None, ApiRequest::Ack { id: Some(id) });
        assert!(acked.is_ok(), "{acked:?}");
        let restarted = r.ask(Some("falc2"), ApiRequest::Start);
        assert_eq!(
            restarted,
            Ok(ApiReply::Done("order 4 (dikdroog) started".into()))
        );
        assert_eq!(r.order(4), (OrderState::Running, Some("falc2".into())));
    }

    /// What needs one cell is refused without one, naming the cells; an
    /// unknown cell is refused; `answer` goes to the one cell that asks.
    #[test]
    fn requests_for_one_cell_are_routed_or_refused_with_the_cells_named() {
        let mut r = Rig::new();
        let mode = ApiRequest::Mode {
            mode: CellMode::Maintenance,
            stations: Vec::new(),
        };
        let e = r.ask(None, mode).unwrap_err();
        assert!(
            e.contains("give --cell") && e.contains("falc1, falc2"),
            "{e}"
        );
        let e = r.ask(Some("falc9"), ApiRequest::Start).unwrap_err();
        assert!(
            e.contains("there is no cell falc9; the plant has falc1, falc2"),
            "{e}"
        );
        let e = r.ask(None, add(Some("falc9"))).unwrap_err();
        assert!(e.contains("there is no cell falc9"), "{e}");
        let e = r
            .ask(None, ApiRequest::Answer { text: "ja".into() })
            .unwrap_err();
        assert!(e.contains("no question"), "{e}");
        // falc2's cell asks.
        assert!(r.ask(None, add(Some("falc2"))).is_ok());
        assert!(r.ask(Some("falc2"), ApiRequest::Start).is_ok());
        let list = r.plant.list(1).expect("list");
        list.handle_cell_request(
            r.now,
            Ticket(99),
            Request::Input {
                prompt: "Gereed?".into(),
                timeout_s: None,
            },
        );
        let answered = r.ask(None, ApiRequest::Answer { text: "ja".into() });
        assert_eq!(answered, Ok(ApiReply::Done("answered ja".into())));
        // The journal: the plant's whole, or one cell's with --cell
        // (an order added through falc1 is journalled in falc1).
        assert!(r.ask(Some("falc1"), add(None)).is_ok());
        let cells_of = |r: &mut Rig, cell: Option<&str>| -> Vec<Option<String>> {
            match r.ask(
                cell,
                ApiRequest::Journal {
                    order: None,
                    after: 0,
                    last: None,
                },
            ) {
                Ok(ApiReply::Entries(v)) => v.into_iter().map(|e| e.cell).collect(),
                other => panic!("{other:?}"),
            }
        };
        let all = cells_of(&mut r, None);
        assert!(all.contains(&Some("falc1".into())) && all.contains(&Some("falc2".into())));
        let two = cells_of(&mut r, Some("falc2"));
        assert!(!two.is_empty() && two.iter().all(|c| c.as_deref() == Some("falc2")));
        // Start: falc1 takes the order added through it, falc2 runs on.
        let e = r.ask(None, ApiRequest::Start);
        assert_eq!(
            e,
            Ok(ApiReply::Done(
                "falc1: order 2 (dikdroog) started\nfalc2: the list is running".into()
            ))
        );
        // Start with nothing anywhere: refused by every cell, refused.
        let mut idle = Rig::new();
        let e = idle.ask(None, ApiRequest::Start).unwrap_err();
        assert_eq!(
            e,
            "falc1: the order list holds no queued order\nfalc2: the order list holds no queued order"
        );
    }
}
