//! The order list on a virtual clock, with records in memory and a
//! recipe source in memory; the test plays the cell (answering each
//! [`CellCall`]) and the consoles.

use super::*;
use crate::recipe_source::fake::{set, Source};
use crate::records::memory::Memory;
use falc_model::alarm::Cause;

/// The cell as shipped (console users `console`, an operator, and
/// `observer`).
const TOPOLOGY: &str = include_str!("../../../../launch/cell.toml");

fn name(s: &str) -> ObjectName {
    ObjectName::new(s).expect("a valid name")
}

fn st(s: &str) -> StationName {
    StationName::new(s).expect("a valid station")
}

struct Rig {
    list: OrderList<Memory, Source>,
    now: Duration,
    tickets: u64,
    /// Every line the list said, in order.
    said: Vec<String>,
    /// The consoles' answers not taken yet.
    replies: std::collections::BTreeMap<Ticket, ApiResult>,
}

impl Rig {
    fn new() -> Self {
        Self::with(Memory::default())
    }

    /// The list over `records` (an operator started again on its file).
    fn with(records: Memory) -> Self {
        Self::with_recipes(records, set())
    }

    /// The list over `records`, delivering `recipes` (each also the
    /// source's text, should the list read them again).
    fn with_recipes(records: Memory, recipes: crate::recipe_source::RecipeSet) -> Self {
        let source = Source::default();
        for d in &recipes.deliveries {
            let text = String::from_utf8_lossy(&d.content).into_owned();
            source.saved.borrow_mut().push((d.file.clone(), text));
        }
        let topology = Topology::parse(TOPOLOGY, "test").expect("topology");
        let list = OrderList::new(
            st("operator"),
            st("cell"),
            topology,
            records,
            source,
            recipes,
        );
        Self {
            list,
            now: Duration::ZERO,
            tickets: 0,
            said: Vec::new(),
            replies: Default::default(),
        }
    }

    fn outputs(&mut self) -> Vec<Output> {
        let out: Vec<Output> = std::iter::from_fn(|| self.list.poll_output()).collect();
        while let Some((t, result)) = self.list.poll_reply() {
            self.replies.insert(t, result);
        }
        for o in &out {
            if let Output::Say(l) = o {
                self.said.push(l.clone());
            }
        }
        out
    }

    /// The answer to console request `t`, if it came.
    fn reply(&mut self, t: Ticket) -> Option<ApiResult> {
        self.replies.remove(&t)
    }

    fn ticket(&mut self) -> Ticket {
        self.tickets += 1;
        Ticket(self.tickets)
    }

    /// Sends a console request; its ticket and what came out.
    fn api(&mut self, user: &str, req: ApiRequest) -> (Ticket, Vec<Output>) {
        let t = self.ticket();
        self.list.handle_api(self.now, t, &st(user), req);
        (t, self.outputs())
    }

    /// A console request answered at once.
    fn ask(&mut self, user: &str, req: ApiRequest) -> ApiResult {
        let (t, out) = self.api(user, req);
        self.reply(t)
            .unwrap_or_else(|| panic!("no answer at once: {out:?}"))
    }

    fn status(&mut self) -> CellStatus {
        match self.ask("console", ApiRequest::Status) {
            Ok(ApiReply::Status(s)) => s,
            other => panic!("{other:?}"),
        }
    }

    /// The cell answers the call that is out (an error is a refusal).
    fn answer(&mut self, result: Result<(), &str>) -> Vec<Output> {
        let result = result.map_err(ServiceError::state_conflict);
        self.list
            .handle_cell_answer(self.now, result.map(|()| Response::Done));
        self.outputs()
    }

    /// No answer comes to the call that is out.
    fn no_reply(&mut self) -> Vec<Output> {
        let e = ServiceError::unreachable("no reply from cell");
        self.list.handle_cell_answer(self.now, Err(e));
        self.outputs()
    }

    /// The cell answers the [`CellCall::Ask`] that is out, and every
    /// call that follows (deliveries) with success.
    fn tell(&mut self, answer: Result<Response, ServiceError>) -> Vec<Output> {
        self.list.handle_cell_answer(self.now, answer);
        let mut all = self.outputs();
        let mut more = call(&all).is_some();
        while more {
            let out = self.answer(Ok(()));
            more = call(&out).is_some();
            all.extend(out);
        }
        all
    }

    /// The cell asks the operator `prompt`; the question's ticket.
    fn question(&mut self, prompt: &str) -> Ticket {
        let q = self.ticket();
        let input = Request::Input {
            prompt: prompt.into(),
            timeout_s: None,
        };
        self.list.handle_cell_request(self.now, q, input);
        self.outputs();
        q
    }

    fn publish(&mut self, u: Unconfirmed) -> Vec<Output> {
        self.list.handle_heard(self.now, None, u);
        self.outputs()
    }

    fn job(&mut self, event: JobEvent) -> Vec<Output> {
        self.publish(Unconfirmed::Job {
            station: st("cell"),
            program: name("dikdroog"),
            event,
        })
    }

    fn add(&mut self, n: usize) {
        for _ in 0..n {
            let r = self.ask("console", ApiRequest::order_add("dikdroog"));
            assert!(matches!(r, Ok(ApiReply::Order(_))), "{r:?}");
        }
    }

    /// `start` through association, delivery, an Initiate if one is due, and the
    /// cell's Start; the start's answer.
    fn start(&mut self) -> ApiResult {
        let (t, mut out) = self.api("console", ApiRequest::Start);
        loop {
            if let Some(r) = self.reply(t) {
                return r;
            }
            assert!(
                call(&out).is_some(),
                "neither an answer nor a call: {out:?}"
            );
            out = self.answer(Ok(()));
        }
    }

    /// `start` through association and delivery up to the cell's
    /// Start, which is left out; the start's ticket.
    fn start_until_the_cells_start(&mut self) -> Ticket {
        let (t, mut out) = self.api("console", ApiRequest::Start);
        while !matches!(call(&out), Some(CellCall::Start { .. })) {
            out = self.answer(Ok(()));
        }
        t
    }

    fn order(&mut self, id: i64) -> Order {
        let orders = self.list.records().orders.clone();
        orders
            .into_iter()
            .find(|o| o.id == id)
            .unwrap_or_else(|| panic!("no order {id}"))
    }
}

fn call(out: &[Output]) -> Option<CellCall> {
    out.iter().find_map(|o| match o {
        Output::Cell(c) => Some(c.clone()),
        _ => None,
    })
}

fn said(out: &[Output], what: &str) -> bool {
    out.iter()
        .any(|o| matches!(o, Output::Say(l) if l.contains(what)))
}

#[test]
fn whether_the_list_works_is_kept_in_the_records_for_the_figures() {
    let mut r = Rig::new();
    let working = |r: &mut Rig| r.list.records().lists.last().map(|l| l.working);
    r.add(2);
    assert_eq!(working(&mut r), Some(false));
    assert!(r.start().is_ok());
    assert_eq!(working(&mut r), Some(true));
    // An alarm ends the order and stops the list: still meant to work
    // (its down time is planned) until it is acknowledged.
    r.job(JobEvent::Alarm(Cause::new(AlarmClass::Safety, "estop")));
    let lists = r.list.records().lists.clone();
    assert_eq!(working(&mut r), Some(true), "{lists:?}");
    let ack = r.ask("console", ApiRequest::Ack { id: None });
    assert!(ack.is_ok(), "{ack:?}");
    assert_eq!(working(&mut r), Some(false));
    let changes: Vec<bool> = r.list.records().lists.iter().map(|l| l.working).collect();
    assert_eq!(changes, [false, true, false], "each change kept once");
}

#[test]
fn a_workstation_s_job_start_and_end_are_journalled_under_it_with_the_order() {
    use falc_model::mms::vmd::ProgramState;
    let mut r = Rig::new();
    r.add(1);
    assert!(r.start().is_ok());
    let status = |program: Option<&str>| Unconfirmed::Status {
        station: st("welding"),
        status: VmdStatus {
            program: program.map(|p| ProgramState {
                name: name(p),
                state: 1,
            }),
            ..VmdStatus::default()
        },
    };
    r.publish(status(Some("droog_dik")));
    // Told again (a status put on every change): one line.
    r.publish(status(Some("droog_dik")));
    r.publish(Unconfirmed::Job {
        station: st("welding"),
        program: name("droog_dik"),
        event: JobEvent::BadProduct,
    });
    r.publish(status(None));
    let lines: Vec<(String, Option<i64>, String)> = r
        .list
        .records()
        .journal
        .iter()
        .filter(|e| e.kind == EntryKind::Report)
        .map(|e| (e.who.clone(), e.order, e.text.clone()))
        .collect();
    assert_eq!(
        lines,
        vec![
            ("welding".into(), Some(1), "job DROOG_DIK started".into()),
            (
                "welding".into(),
                Some(1),
                "job DROOG_DIK ended: bad product".into()
            ),
        ]
    );
}

#[test]
fn a_start_associates_delivers_and_starts_and_status_is_answered_meanwhile() {
    let mut r = Rig::new();
    r.add(1);
    let (start, out) = r.api("console", ApiRequest::Start);
    assert_eq!(call(&out), Some(CellCall::Associate));
    // The loop does not wait for the cell: status is answered now.
    assert!(!r.status().cell_associated);
    let out = r.answer(Ok(()));
    assert!(said(&out, "EVENT associated station=cell"));
    let Some(CellCall::Deliver(d)) = call(&out) else {
        panic!("{out:?}")
    };
    assert_eq!(
        d.domain,
        name("WELDING$DROOG_DIK"),
        "workstation recipes first"
    );
    let out = r.answer(Ok(()));
    assert!(matches!(call(&out), Some(CellCall::Deliver(d)) if d.is_cell));
    let out = r.answer(Ok(()));
    assert!(said(&out, "EVENT cell-ready recipes=2"));
    // Just associated: no Initiate again.
    assert_eq!(
        call(&out),
        Some(CellCall::Start {
            name: name("dikdroog"),
            argument: "order 1".into()
        })
    );
    assert_eq!(
        r.order(1).state,
        OrderState::Running,
        "durably running before the cell is asked"
    );
    assert!(
        r.reply(start).is_none(),
        "answered only when the cell confirmed"
    );
    r.answer(Ok(()));
    assert_eq!(
        r.reply(start),
        Some(Ok(ApiReply::Done("order 1 (dikdroog) started".into())))
    );
    assert_eq!(r.status().list, ListState::Running);
    let out = r.job(JobEvent::Done);
    assert!(said(&out, "EVENT order-ended id=1 state=done"));
    assert!(said(&out, "EVENT list-done"));
    assert_eq!(r.order(1).state, OrderState::Done);
    assert_eq!(r.status().list, ListState::Idle);
    // A second start: nothing to deliver again, the association
    // stands: the order starts.
    r.add(1);
    let (_, out) = r.api("console", ApiRequest::Start);
    assert!(
        matches!(call(&out), Some(CellCall::Start { .. })),
        "{out:?}"
    );
    r.answer(Ok(()));
    r.job(JobEvent::Done);
    // A workstation left the bus and came back while an order ran (no
    // rejoin then): the next start Initiates the cell first.
    r.add(1);
    let (_, out) = r.api("console", ApiRequest::Start);
    assert!(matches!(call(&out), Some(CellCall::Start { .. })));
    r.answer(Ok(()));
    let now = r.now;
    r.list.handle_presence(now, st("welding"), false);
    r.list.handle_presence(now, st("welding"), true);
    r.outputs();
    r.job(JobEvent::Done);
    r.add(1);
    let (start, out) = r.api("console", ApiRequest::Start);
    assert_eq!(call(&out), Some(CellCall::Initiate));
    let out = r.answer(Err("welding: not associated"));
    assert!(matches!(r.reply(start), Some(Err(_))), "{out:?}");
    // Refused: the next start tries again; once it went through, the
    // association stands.
    let (_, out) = r.api("console", ApiRequest::Start);
    assert_eq!(call(&out), Some(CellCall::Initiate));
    let out = r.answer(Ok(()));
    assert!(matches!(call(&out), Some(CellCall::Start { .. })));
}

#[test]
fn each_run_records_the_versions_it_ran_and_a_save_or_rollback_is_a_new_version() {
    let mut r = Rig::new();
    // At start-up the store's texts are kept as versions 1.
    let welding = RecipeFile::new(st("welding"), "droog_dik").expect("file");
    let cell = RecipeFile::new(st("cell"), "dikdroog").expect("file");
    let kept = r.list.records().versions.clone();
    assert_eq!(kept.len(), 2);
    assert!(kept
        .iter()
        .all(|(v, _)| v.version == 1 && v.author == "operator"));
    r.add(1);
    assert!(r.start().is_ok());
    r.job(JobEvent::Done);
    // The engineer saves a new welding text, with a message.
    let base = r.list.source.get(&welding).expect("get").hash;
    let put = ApiRequest::RecipePut {
        file: welding.clone(),
        text: "thicker".into(),
        base: Some(base),
        message: "more current".into(),
    };
    let said = r.ask("engineer", put).expect("saved");
    assert!(
        matches!(&said, ApiReply::Done(t) if t.contains("version 2")),
        "{said:?}"
    );
    let history = r.ask(
        "console",
        ApiRequest::RecipeHistory {
            file: welding.clone(),
        },
    );
    let Ok(ApiReply::Versions(v)) = history else {
        panic!("{history:?}")
    };
    assert_eq!(
        v.iter()
            .map(|v| (v.version, v.author.as_str(), v.message.as_str()))
            .collect::<Vec<_>>(),
        vec![
            (1, "operator", "found in the recipe store"),
            (2, "engineer", "more current")
        ]
    );
    // A save with a finding is no version.
    let bad = ApiRequest::RecipePut {
        file: welding.clone(),
        text: "defect".into(),
        base: Some(r.list.source.get(&welding).expect("get").hash),
        message: String::new(),
    };
    assert!(r.ask("engineer", bad).is_err());
    r.add(1);
    assert!(r.start().is_ok());
    r.job(JobEvent::Done);
    // Roll back to 1: version 3 with version 1's text.
    let back = ApiRequest::RecipeRollback {
        file: welding.clone(),
        version: 1,
        message: "scrap rate".into(),
    };
    assert!(r.ask("engineer", back.clone()).is_ok());
    let again = r.ask("engineer", back);
    assert!(
        matches!(&again, Err(e) if e.contains("nothing to roll back")),
        "{again:?}"
    );
    r.add(1);
    assert!(r.start().is_ok());
    r.job(JobEvent::Done);
    let used = |r: &mut Rig, id: i64| -> Vec<(String, u32)> {
        let Ok(ApiReply::OrderRecord(rec)) = r.ask("console", ApiRequest::OrderShow { id }) else {
            panic!("no record of order {id}")
        };
        assert_eq!(rec.runs.len(), 1);
        rec.runs[0]
            .recipes
            .iter()
            .map(|u| (u.file.to_string(), u.version))
            .collect()
    };
    let c = cell.to_string();
    let w = welding.to_string();
    assert_eq!(used(&mut r, 1), vec![(c.clone(), 1), (w.clone(), 1)]);
    assert_eq!(used(&mut r, 2), vec![(c.clone(), 1), (w.clone(), 2)]);
    assert_eq!(used(&mut r, 3), vec![(c, 1), (w.clone(), 3)]);
    let hashes: Vec<_> = r
        .list
        .records()
        .runs
        .iter()
        .map(|(_, run)| run.recipes[1].hash.clone())
        .collect();
    assert_eq!(hashes[0], hashes[2], "the rollback's text is the first's");
    assert_ne!(hashes[0], hashes[1]);
    let text = r.ask(
        "console",
        ApiRequest::RecipeVersion {
            file: welding,
            version: 2,
        },
    );
    assert!(matches!(text, Ok(ApiReply::RecipeAt { text, .. }) if text == "thicker"));
    let none = r.ask("console", ApiRequest::OrderShow { id: 99 });
    assert!(matches!(none, Err(e) if e.contains("no order 99")));
}

#[test]
fn the_list_goes_on_and_a_start_the_cell_refuses_puts_the_order_back() {
    let mut r = Rig::new();
    r.add(2);
    assert!(r.start().is_ok());
    let out = r.job(JobEvent::Done);
    assert!(matches!(call(&out), Some(CellCall::Start { argument, .. }) if argument == "order 2"));
    let out = r.answer(Err("vmd-state/program invocation busy"));
    assert!(said(&out, "EVENT alarm"), "{out:?}");
    assert_eq!(
        r.order(2).state,
        OrderState::Queued,
        "never lost, never run"
    );
    let s = r.status();
    assert_eq!(s.list, ListState::Alarm);
    assert!(s
        .alarm
        .is_some_and(|a| a.contains("order 2 (dikdroog) not started")));
    // The way back: ack, start, done.
    assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
    assert!(r.start().is_ok());
    r.job(JobEvent::Done);
    assert_eq!(r.order(2).state, OrderState::Done);
}

#[test]
fn while_the_cell_is_away_it_is_tried_again_every_second() {
    let mut r = Rig::new();
    assert_eq!(r.list.poll_timeout(), Some(Duration::ZERO));
    r.list.handle_timeout(r.now);
    assert_eq!(call(&r.outputs()), Some(CellCall::Associate));
    assert_eq!(r.list.poll_timeout(), None, "nothing while a call is out");
    let out = r.answer(Err("no reply from cell"));
    assert!(said(&out, "EVENT not-associated no reply from cell"));
    assert_eq!(r.status().problem.as_deref(), Some("no reply from cell"));
    assert_eq!(r.list.poll_timeout(), Some(RETRY));
    r.now = Duration::from_millis(500);
    r.list.handle_timeout(r.now);
    assert!(call(&r.outputs()).is_none(), "not yet");
    r.now = RETRY;
    r.list.handle_timeout(r.now);
    assert_eq!(call(&r.outputs()), Some(CellCall::Associate));
    let out = r.answer(Err("no reply from cell"));
    assert!(
        !said(&out, "not-associated"),
        "the same refusal is said once"
    );
    r.now = RETRY * 2;
    r.list.handle_timeout(r.now);
    r.outputs();
    // Associated; a delivery the cell refuses is tried again too.
    let out = r.answer(Ok(()));
    assert!(matches!(call(&out), Some(CellCall::Deliver(_))));
    r.answer(Err("disk full at the cell"));
    assert!(r
        .list
        .records()
        .texts()
        .iter()
        .any(|t| t == "disk full at the cell"));
    assert_eq!(r.list.poll_timeout(), Some(RETRY * 3));
    r.now = RETRY * 3;
    r.list.handle_timeout(r.now);
    assert!(matches!(call(&r.outputs()), Some(CellCall::Deliver(_))));
    r.answer(Ok(()));
    let out = r.answer(Ok(()));
    assert!(said(&out, "EVENT cell-ready"));
    assert_eq!(r.list.poll_timeout(), None, "all delivered");
}

#[test]
fn a_change_of_status_is_told_once_and_a_look_is_no_change() {
    let changed = |out: &[Output]| out.iter().filter(|o| matches!(o, Output::Changed)).count();
    let mut r = Rig::new();
    let _ = r.outputs();
    // A station's status: told once, with the rest of what came out.
    let status = VmdStatus {
        logical: falc_model::mms::vmd::LogicalStatus::NoStateChangesAllowed,
        ..VmdStatus::default()
    };
    let publish = |r: &mut Rig| {
        r.publish(Unconfirmed::Status {
            station: st("welding"),
            status: status.clone(),
        })
    };
    assert_eq!(changed(&publish(&mut r)), 1);
    // The same status again, and a console's look: no change.
    assert_eq!(changed(&publish(&mut r)), 0);
    let (_, out) = r.api("console", ApiRequest::Status);
    assert_eq!(changed(&out), 0, "{out:?}");
    // A station gone and an order added: each a change.
    r.list.handle_presence(r.now, st("welding"), false);
    let _ = r.outputs();
    r.list.handle_presence(r.now, st("welding"), true);
    assert_eq!(changed(&r.outputs()), 1);
    let (_, out) = r.api("console", ApiRequest::order_add("dikdroog"));
    assert_eq!(changed(&out), 1, "{out:?}");
}

#[test]
fn a_failed_write_halts_the_running_order_and_no_order_runs_twice() {
    let mut r = Rig::new();
    r.add(2);
    assert!(r.start().is_ok());
    let q = r.question("weld (ja/nee)?");
    r.list.records().failing = true;
    let out = r.publish(Unconfirmed::Report {
        station: st("welding"),
        severity: Severity::Info,
        text: "seam 1 done".into(),
    });
    assert!(said(&out, "EVENT store-error disk full"));
    let out: Vec<&Output> = out
        .iter()
        .filter(|o| !matches!(o, Output::Changed))
        .collect();
    assert!(
        matches!(&out[..], [.., Output::Respond { ticket, result: Err(_) }, Output::Cell(CellCall::Stop { .. })] if *ticket == q),
        "the question refused, the order stopped at the cell: {out:?}"
    );
    let out = r.answer(Ok(()));
    assert!(said(&out, "EVENT order-halted id=1"));
    assert_eq!(
        r.order(1).state,
        OrderState::Running,
        "its end could not be written"
    );
    let s = r.status();
    assert_eq!((s.list, s.running), (ListState::Alarm, None));
    let refused = r.ask("console", ApiRequest::Start);
    assert!(refused.is_err_and(|e| e.contains("cannot be written")));
    // The disk is freed: ack, start; the held end is written first.
    r.list.records().failing = false;
    assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
    assert_eq!(
        r.start(),
        Ok(ApiReply::Done("order 2 (dikdroog) started".into()))
    );
    assert_eq!(r.order(1).state, OrderState::Failed);
    assert!(r
        .list
        .records()
        .texts()
        .iter()
        .any(|t| t.contains("(written late)")));
    let texts = r.list.records().texts();
    for id in [1, 2] {
        let line = format!("order {id} (dikdroog) started");
        let n = texts.iter().filter(|t| **t == line).count();
        assert_eq!(n, 1, "order {id} started once");
    }
}

#[test]
fn an_order_ended_with_danger_leaves_the_alarm_list_once_acknowledged() {
    let mut r = Rig::new();
    r.add(2);
    assert!(r.start().is_ok());
    r.job(JobEvent::FailedDanger);
    let s = r.status();
    assert_eq!(s.list, ListState::Alarm);
    let alarm = s
        .alarms
        .iter()
        .find(|a| a.text.contains("ended with failed_danger"))
        .cloned()
        .unwrap_or_else(|| panic!("{:?}", s.alarms));
    assert!(alarm.blocks_start(), "a safety alarm waits for its ack");
    assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
    let s = r.status();
    assert!(
        !s.alarms.iter().any(|a| a.id == alarm.id),
        "acknowledged, nothing left to clear: {:?}",
        s.alarms
    );
    assert!(r.start().is_ok(), "the way back: ack, start");
    r.job(JobEvent::Done);
    assert_eq!(r.order(2).state, OrderState::Done);
}

#[test]
fn an_ack_the_full_disk_refuses_is_not_taken_and_the_way_back_runs_the_next_order() {
    let mut r = Rig::new();
    r.add(2);
    assert!(r.start().is_ok());
    r.job(JobEvent::FailedDanger);
    r.list.records().failing = true;
    let refused = r.ask("console", ApiRequest::Ack { id: None });
    assert!(
        refused
            .as_ref()
            .is_err_and(|e| e.contains("not acknowledged")),
        "{refused:?}"
    );
    let s = r.status();
    assert!(
        s.alarms
            .iter()
            .any(|a| a.text.contains("failed_danger") && a.acked.is_none()),
        "not acknowledged in the list either: {:?}",
        s.alarms
    );
    assert!(r.ask("console", ApiRequest::Start).is_err());
    // Room again: ack (both alarms), start, the next order done.
    r.list.records().failing = false;
    assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
    assert!(r.status().alarms.is_empty(), "{:?}", r.status().alarms);
    assert!(r.start().is_ok());
    r.job(JobEvent::Done);
    assert_eq!(r.order(2).state, OrderState::Done);
}

#[test]
fn the_last_orders_held_end_is_written_at_the_ack_without_a_start() {
    // Found by falc-sim: the list's last order halted by a full disk
    // stayed `running` in the records, since only a start wrote it.
    let mut r = Rig::new();
    r.add(1);
    assert!(r.start().is_ok());
    r.list.records().failing = true;
    r.publish(Unconfirmed::Report {
        station: st("welding"),
        severity: Severity::Info,
        text: "seam 1 done".into(),
    });
    let out = r.answer(Ok(()));
    assert!(said(&out, "EVENT order-halted id=1"));
    assert_eq!(r.order(1).state, OrderState::Running);
    // Still full: the ack is taken, the end stays held, a new alarm.
    assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
    assert_eq!(r.order(1).state, OrderState::Running);
    assert_eq!(r.status().list, ListState::Alarm);
    // Room again: the ack writes it.
    r.list.records().failing = false;
    assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
    assert_eq!(r.order(1).state, OrderState::Failed);
    let late = r.list.records().texts();
    assert_eq!(
        late.iter().filter(|t| t.contains("(written late)")).count(),
        1,
        "{late:?}"
    );
    assert_eq!(r.status().list, ListState::Idle);
}

/// The cell answers the [`CellCall::Ask`] that is out with attributes
/// (`state`, `last_end`).
fn attributes(state: PiState, last_end: Option<JobEvent>) -> Result<Response, ServiceError> {
    Ok(Response::PiAttributes(falc_model::mms::pdu::PiAttributes {
        state,
        domains: vec![name("dikdroog")],
        reusable: true,
        deletable: true,
        last_end,
    }))
}

/// A cut: order 1 runs with a question waiting, the cell is lost.
fn cut_mid_order(r: &mut Rig) {
    r.add(2);
    assert!(r.start().is_ok());
    let q = r.question("ok?");
    r.list.handle_abort(r.now, "lease expired");
    let out = r.outputs();
    assert!(out
        .iter()
        .any(|o| matches!(o, Output::Forget(t) if *t == q)));
    assert!(!said(&out, "EVENT order-ended"), "{out:?}");
    assert_eq!(r.order(1).state, OrderState::Running);
    let s = r.status();
    assert_eq!(s.list, ListState::Alarm);
    assert_eq!(
        s.problem.as_deref(),
        Some("no connection with station cell")
    );
    // While the cell is away, the retry associates it, and then asks
    // how the order's run stands before anything else.
    r.now += RETRY;
    r.list.handle_timeout(r.now);
    assert_eq!(call(&r.outputs()), Some(CellCall::Associate));
    let out = r.answer(Ok(()));
    assert_eq!(
        call(&out),
        Some(CellCall::Ask {
            name: name("dikdroog")
        })
    );
    assert!(
        r.status().alarms.iter().all(|a| a.cleared_ms.is_some()),
        "the cell is back"
    );
}

#[test]
fn a_cut_off_cell_s_order_ends_as_the_cell_says_once_it_is_back() {
    let mut r = Rig::new();
    cut_mid_order(&mut r);
    let out = r.tell(attributes(PiState::Idle, Some(JobEvent::Done)));
    assert!(said(&out, "EVENT order-ended id=1 state=done"), "{out:?}");
    assert_eq!(r.order(1).state, OrderState::Done);
    assert_eq!(
        r.order(2).state,
        OrderState::Queued,
        "the list waits for ack"
    );
    assert!(r.list.records().journal.iter().any(|e| e
        .text
        .contains("ended at cell while the connection was lost")));
    // The way back: ack, start; the next order runs once.
    assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
    assert!(r.start().is_ok());
    r.job(JobEvent::Done);
    assert_eq!(r.order(2).state, OrderState::Done);
    let starts = r
        .list
        .records()
        .journal
        .iter()
        .filter(|e| e.text.ends_with(") started"))
        .count();
    assert_eq!(starts, 2, "each order started once");
}

#[test]
fn a_cell_back_on_the_bus_is_associated_at_once() {
    let mut r = Rig::new();
    r.add(1);
    assert!(r.start().is_ok());
    r.list.handle_presence(r.now, st("cell"), true);
    r.outputs();
    r.list.handle_abort(r.now, "lease expired");
    r.list.handle_presence(r.now, st("cell"), false);
    r.outputs();
    r.list.handle_presence(r.now, st("cell"), true);
    assert_eq!(call(&r.outputs()), Some(CellCall::Associate));
}

#[test]
fn a_cut_off_cell_whose_order_still_runs_is_followed_again() {
    let mut r = Rig::new();
    cut_mid_order(&mut r);
    let out = r.tell(attributes(PiState::Running, None));
    assert!(said(&out, "EVENT order-followed id=1"), "{out:?}");
    assert_eq!(r.order(1).state, OrderState::Running);
    // A recipe in use is not delivered again under the running order.
    r.now += RETRY;
    r.list.handle_timeout(r.now);
    assert_eq!(call(&r.outputs()), None);
    r.job(JobEvent::Alarm(falc_model::alarm::Cause::process(
        "robot estop",
    )));
    assert_eq!(r.order(1).state, OrderState::Failed);
    assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
    assert!(r.start().is_ok());
    r.job(JobEvent::Done);
    assert_eq!(r.order(2).state, OrderState::Done);
}

#[test]
fn a_cell_that_restarted_while_cut_off_kept_no_end_and_the_order_is_interrupted() {
    let mut r = Rig::new();
    cut_mid_order(&mut r);
    let unknown = ServiceError::undefined("program invocation dikdroog is not defined");
    let out = r.tell(Err(unknown));
    assert!(
        said(&out, "EVENT order-ended id=1 state=interrupted"),
        "{out:?}"
    );
    // Recipes go to the restarted cell again, then the way back.
    assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
    assert!(r.start().is_ok());
    r.job(JobEvent::Done);
    assert_eq!(r.order(2).state, OrderState::Done);
    assert_eq!(r.order(1).state, OrderState::Interrupted);
}

#[test]
fn a_start_that_was_never_confirmed_is_queued_again_only_if_the_cell_never_began_it() {
    for began in [false, true] {
        let mut r = Rig::new();
        r.add(1);
        let t = r.start_until_the_cells_start();
        let out = r.no_reply();
        assert!(r.reply(t).is_some_and(|a| a.is_err()), "{out:?}");
        assert_eq!(
            r.order(1).state,
            OrderState::Running,
            "not queued again yet"
        );
        r.now += RETRY;
        r.list.handle_timeout(r.now);
        assert_eq!(call(&r.outputs()), Some(CellCall::Associate));
        assert!(matches!(
            call(&r.answer(Ok(()))),
            Some(CellCall::Ask { .. })
        ));
        let answer = if began {
            attributes(PiState::Idle, Some(JobEvent::Done))
        } else {
            attributes(PiState::Idle, None)
        };
        r.tell(answer);
        let expected = if began {
            OrderState::Done
        } else {
            OrderState::Queued
        };
        assert_eq!(r.order(1).state, expected, "began: {began}");
    }
}

#[test]
fn an_order_running_when_the_operator_stopped_is_adopted_and_asked_for() {
    let mut r = Rig::new();
    r.add(1);
    assert!(r.start().is_ok());
    let order = r.order(1);
    let records = std::mem::take(r.list.records());
    let topology = Topology::parse(TOPOLOGY, "test").expect("topology");
    let mut list = OrderList::new(
        st("operator"),
        st("cell"),
        topology,
        records,
        Source::default(),
        set(),
    )
    .adopting(order);
    list.handle_timeout(Duration::ZERO);
    let out: Vec<Output> = std::iter::from_fn(|| list.poll_output()).collect();
    assert_eq!(call(&out), Some(CellCall::Associate));
    list.handle_cell_answer(Duration::ZERO, Ok(Response::Done));
    let out: Vec<Output> = std::iter::from_fn(|| list.poll_output()).collect();
    assert!(matches!(call(&out), Some(CellCall::Ask { .. })), "{out:?}");
    list.handle_cell_answer(
        Duration::ZERO,
        attributes(PiState::Idle, Some(JobEvent::Done)),
    );
    let out: Vec<Output> = std::iter::from_fn(|| list.poll_output()).collect();
    assert!(said(&out, "EVENT order-ended id=1 state=done"), "{out:?}");
}

#[test]
fn a_job_event_before_the_start_is_confirmed_is_kept_for_it() {
    let mut r = Rig::new();
    r.add(1);
    let t = r.start_until_the_cells_start();
    let early = r.job(JobEvent::Alarm(Cause::new(
        AlarmClass::Process,
        "alarm in state 2",
    )));
    assert!(early.is_empty(), "{early:?}");
    let out = r.answer(Ok(()));
    assert!(r.reply(t).is_some_and(|r| r.is_ok()));
    assert!(said(&out, "EVENT order-ended id=1 state=failed"));
    assert_eq!(r.order(1).state, OrderState::Failed);
}

#[test]
fn messages_before_the_start_is_confirmed_are_journalled_after_it() {
    let mut r = Rig::new();
    r.add(1);
    let t = r.start_until_the_cells_start();
    // The cell runs the recipe before its Start confirm arrives: its
    // first output, a step-mode report and a question come first.
    let o = r.ticket();
    let lines = vec!["lassen begint".to_string()];
    r.list
        .handle_cell_request(r.now, o, Request::Output { lines });
    let answered = r.outputs();
    assert!(
        answered
            .iter()
            .any(|x| matches!(x, Output::Respond { ticket, result: Ok(_) } if *ticket == o)),
        "the output is answered at once: {answered:?}"
    );
    r.publish(Unconfirmed::Report {
        station: st("cell"),
        severity: Severity::Info,
        text: "state 1 waits".into(),
    });
    let q = r.question("verder?");
    r.answer(Ok(()));
    assert!(r.reply(t).is_some_and(|r| r.is_ok()));
    let journal = r
        .list
        .records()
        .entries(&EntryQuery::page(0, 100))
        .expect("journal");
    let started = journal
        .iter()
        .position(|e| e.text.contains("order 1 (dikdroog) started"))
        .expect("the start is journalled");
    for text in ["lassen begint", "state 1 waits", "verder?"] {
        let at = journal
            .iter()
            .position(|e| e.text == text)
            .unwrap_or_else(|| panic!("{text} not journalled: {journal:?}"));
        assert!(at > started, "{text} before the start: {journal:?}");
        assert_eq!(journal[at].order, Some(1), "{text} without its order");
    }
    // The question still waits for its answer.
    let (a, out) = r.api("console", ApiRequest::Answer { text: "ja".into() });
    assert!(r.reply(a).is_some_and(|r| r.is_ok()), "{out:?}");
    assert!(out
        .iter()
        .any(|x| matches!(x, Output::Respond { ticket, .. } if *ticket == q)));
}

#[test]
fn stop_ends_the_order_and_roles_are_checked_again() {
    let mut r = Rig::new();
    r.add(1);
    let refused = r.ask("observer", ApiRequest::Start);
    assert!(refused.is_err_and(|e| e.contains("needs")));
    assert!(r.ask("mallory", ApiRequest::Status).is_err());
    assert!(r.start().is_ok());
    let (t, out) = r.api("console", ApiRequest::Stop);
    assert_eq!(
        call(&out),
        Some(CellCall::Stop {
            name: name("dikdroog")
        })
    );
    assert_eq!(r.status().running, None);
    let out = r.answer(Err("no reply from cell"));
    let Some(Ok(ApiReply::Done(text))) = r.reply(t) else {
        panic!("{out:?}")
    };
    assert!(text.contains("the cell did not confirm the stop"), "{text}");
    assert_eq!(r.order(1).state, OrderState::Stopped);
    // A late end of the stopped job changes nothing.
    assert!(r.job(JobEvent::Done).is_empty());
    assert_eq!(r.order(1).state, OrderState::Stopped);
}

#[test]
fn a_stopped_order_resumes_at_the_cell_and_a_refused_restart_leaves_it_as_it_was() {
    let mut r = Rig::new();
    r.add(2);
    assert!(r.start().is_ok());
    let (_, _) = r.api("console", ApiRequest::Stop);
    r.answer(Ok(()));
    assert_eq!(r.order(1).state, OrderState::Stopped);
    let restart = |order, from| ApiRequest::Restart { order, from };
    // Without --from, a stopped order resumes where it stopped.
    let (t, out) = r.api("console", restart(1, None));
    assert_eq!(
        call(&out),
        Some(CellCall::Pass(Request::Resume {
            name: name("dikdroog")
        }))
    );
    assert_eq!(r.order(1).state, OrderState::Running);
    // The cell refuses: back to stopped, never queued (it ran).
    let out = r.answer(Err("Resume refused"));
    assert!(r.reply(t).is_some_and(|r| r.is_err()), "{out:?}");
    assert_eq!(r.order(1).state, OrderState::Stopped);
    assert_eq!(r.order(2).state, OrderState::Queued);
    // From a state: the recipe must have it.
    let e = r.ask("console", restart(1, Some(9))).unwrap_err();
    assert!(e.contains("dikdroog has no state 9"), "{e}");
    let e = r.ask("console", restart(2, None)).unwrap_err();
    assert!(e.contains("order 2 is queued: falc start runs it"), "{e}");
    let e = r.ask("console", restart(7, None)).unwrap_err();
    assert!(e.contains("there is no order 7"), "{e}");
    let e = r.ask("observer", restart(1, None)).unwrap_err();
    assert!(e.contains("needs Operator"), "{e}");
}

/// `falc restart N --from S` where state S starts a workstation job
/// whose `#PRE` its station last said does not hold is refused naming
/// it, the order left as it was; once the station says it holds, the
/// same restart goes to the cell.
#[test]
fn a_restart_from_a_state_whose_job_s_precondition_is_false_is_refused() {
    let mut recipes = set();
    for d in recipes.deliveries.iter_mut().filter(|d| d.is_cell) {
        d.content = include_bytes!("../../../../recipes/cell/dikdroog.rcp").to_vec();
    }
    let mut r = Rig::with_recipes(Memory::default(), recipes);
    r.add(1);
    assert!(r.start().is_ok());
    let (_, _) = r.api("console", ApiRequest::Stop);
    r.answer(Ok(()));
    assert_eq!(r.order(1).state, OrderState::Stopped);
    let why = "precondition of UNSTORE: place 3 occupied is false";
    let transport = |unmet: &[(&str, &str)]| Unconfirmed::Status {
        station: st("transport"),
        status: VmdStatus {
            unmet: unmet
                .iter()
                .map(|(n, w)| (name(n), w.to_string()))
                .collect(),
            ..VmdStatus::default()
        },
    };
    r.publish(transport(&[("UNSTORE", why)]));
    // State 14 of dikdroog starts transport's UNSTORE.
    let restart = ApiRequest::Restart {
        order: 1,
        from: Some(14),
    };
    let e = r.ask("console", restart.clone()).unwrap_err();
    assert_eq!(
        e,
        format!(
            "state 14 starts transport's UNSTORE, and transport says: {why} (set it right, or \
             restart from another state)"
        )
    );
    assert_eq!(r.order(1).state, OrderState::Stopped);
    // Another job's precondition, or a state that waits first: no matter.
    let (_, out) = r.api(
        "console",
        ApiRequest::Restart {
            order: 1,
            from: Some(1),
        },
    );
    assert!(
        matches!(call(&out), Some(CellCall::Start { .. })),
        "{out:?}"
    );
    r.answer(Err("refused for the test"));
    r.publish(transport(&[]));
    let (_, out) = r.api("console", restart);
    assert_eq!(
        call(&out),
        Some(CellCall::Start {
            name: name("dikdroog"),
            argument: "order 1 from 14".into()
        })
    );
}

#[test]
fn modes_pass_to_the_cell_and_maintenance_waits_until_no_order_runs() {
    let mut r = Rig::new();
    r.add(1);
    assert!(r.start().is_ok());
    let mode = |mode, stations: Vec<&str>| ApiRequest::Mode {
        mode,
        stations: stations.into_iter().map(st).collect(),
    };
    let e = r
        .ask("console", mode(CellMode::Maintenance, vec![]))
        .unwrap_err();
    assert!(e.contains("only when no order runs"), "{e}");
    let e = r
        .ask("console", mode(CellMode::Auto, vec!["welding"]))
        .unwrap_err();
    assert!(e.contains("only in step mode"), "{e}");
    let e = r
        .ask("console", mode(CellMode::Step, vec!["operator"]))
        .unwrap_err();
    assert!(e.contains("operator is not a workstation of cell"), "{e}");
    let e = r
        .ask("console", mode(CellMode::Step, vec!["welding"; 5000]))
        .unwrap_err();
    assert!(e.contains("welding is named more than once"), "{e}");
    assert!(e.len() < 100, "{e}");
    let (t, out) = r.api("console", mode(CellMode::Step, vec!["welding"]));
    assert_eq!(
        call(&out),
        Some(CellCall::Pass(Request::Mode(ModeSetting {
            mode: CellMode::Step,
            stepping: vec![st("cell"), st("welding")],
        })))
    );
    let out = r.answer(Ok(()));
    let Some(Ok(ApiReply::Done(text))) = r.reply(t) else {
        panic!("{out:?}")
    };
    assert_eq!(text, "mode step (cell, welding)");
    let journal = &r.list.records().journal;
    assert!(journal
        .iter()
        .any(|e| e.who == "console" && e.text == "mode step (cell, welding)"));
    // A manual operation is the maintainer's, passed on as it is.
    let manual = ApiRequest::Manual {
        station: st("transport"),
        action: falc_model::mode::ManualAction::Press("A".into()),
    };
    let e = r.ask("console", manual.clone()).unwrap_err();
    assert!(e.contains("needs Maintainer"), "{e}");
    let (_, out) = r.api("maintainer", manual);
    assert!(matches!(
        call(&out),
        Some(CellCall::Pass(Request::Manual { by, .. })) if by == "maintainer"
    ));
}

#[test]
fn a_defective_recipe_set_refuses_the_start_and_delivers_nothing() {
    let mut r = Rig::new();
    r.add(1);
    r.list.source.broken = true;
    let (t, out) = r.api("console", ApiRequest::Start);
    assert!(call(&out).is_none(), "nothing delivered");
    let e = r.reply(t).and_then(|r| r.err()).unwrap_or_default();
    assert!(e.contains("cell/dikdroog.rcp:3: unknown state 9"), "{e}");
    assert_eq!(r.order(1).state, OrderState::Queued);
}

#[test]
fn the_list_takes_at_most_its_limit_of_waiting_orders() {
    let mut r = Rig::new();
    r.list = std::mem::replace(&mut r.list, Rig::new().list).with_max_queued(2);
    r.add(2);
    let e = r
        .ask("console", ApiRequest::order_add("dikdroog"))
        .unwrap_err();
    assert!(e.contains("holds 2 queued orders, its limit"), "{e}");
    assert_eq!(r.list.db.orders().map(|o| o.len()), Ok(2));
    // Removing one makes room.
    assert!(r.ask("console", ApiRequest::OrderRemove { id: 1 }).is_ok());
    r.add(1);
}

/// `order add` with a count, a priority, a due time and a cell: the
/// orders added and journalled; the start takes the highest priority,
/// then the one due first; a cell the list does not run on, and more
/// than the limit holds, are refused with nothing added.
#[test]
fn placed_orders_run_by_priority_and_due_time_and_a_foreign_cell_is_refused() {
    use falc_model::api::Placement;
    use falc_model::ids::CellId;
    let mut r = Rig::new();
    r.list = std::mem::replace(&mut r.list, Rig::new().list).with_max_queued(6);
    let add =
        |priority: i32, due_ms: Option<i64>, cell: Option<&str>, count: u16| ApiRequest::OrderAdd {
            recipe: "dikdroog".into(),
            placement: Placement {
                cell: cell.map(|c| CellId::new(c).expect("id")),
                priority,
                due_ms,
                job_order: None,
            },
            count,
        };
    let three = r.ask("console", add(0, None, None, 3));
    assert!(
        matches!(&three, Ok(ApiReply::Orders(v)) if v.iter().map(|o| o.id).eq(1..=3)),
        "{three:?}"
    );
    let due = r.ask("console", add(0, Some(1_795_611_600_000), Some("falc1"), 1));
    assert!(
        matches!(&due, Ok(ApiReply::Order(o)) if o.id == 4),
        "{due:?}"
    );
    let urgent = r.ask("console", add(5, None, None, 1));
    assert!(
        matches!(&urgent, Ok(ApiReply::Order(o)) if o.id == 5),
        "{urgent:?}"
    );
    let texts = r.list.db.texts();
    assert!(
        texts
            .iter()
            .any(|t| t == "added order 4 (dikdroog, due 2026-11-25 13:00 UTC, for falc1)"),
        "{texts:?}"
    );
    assert!(texts
        .iter()
        .any(|t| t == "added order 5 (dikdroog, priority 5)"));
    let e = r
        .ask("console", add(0, None, Some("falc2"), 1))
        .unwrap_err();
    assert!(e.contains("there is no cell falc2"), "{e}");
    let e = r.ask("console", add(0, None, None, 2)).unwrap_err();
    assert!(e.contains("2 more do not fit"), "{e}");
    assert_eq!(
        r.list.db.orders().map(|o| o.len()),
        Ok(5),
        "none of them added"
    );
    assert!(r.start().is_ok());
    let running = r.status().running.map(|o| (o.id, o.cell));
    assert_eq!(
        running,
        Some((5, Some("falc1".into()))),
        "the urgent one first"
    );
    assert_eq!(r.order(4).state, OrderState::Queued);
}

#[test]
fn a_manual_operation_with_a_huge_argument_is_refused_with_a_quote() {
    use falc_model::mode::ManualAction;
    let mut r = Rig::new();
    let e = r
        .ask(
            "maintainer",
            ApiRequest::Manual {
                station: st("transport"),
                action: ManualAction::Press("A".repeat(60_000)),
            },
        )
        .unwrap_err();
    assert!(e.contains("60000 characters") && e.len() < 200, "{e}");
    assert!(
        r.list.db.texts().iter().all(|t| t.len() < 200),
        "nothing of it journalled"
    );
}

#[test]
fn a_workstation_lost_while_idle_is_an_alarm_that_clears_when_it_returns() {
    let mut r = Rig::new();
    r.list.handle_presence(r.now, st("welding"), true);
    r.list.handle_presence(r.now, st("welding"), false);
    let s = r.status();
    let lost: Vec<_> = s
        .alarms
        .iter()
        .filter(|a| a.station == "welding" && a.class == AlarmClass::Communication)
        .collect();
    assert_eq!(lost.len(), 1, "{:?}", s.alarms);
    assert_eq!(lost[0].text, "no connection with station welding");
    assert_eq!(s.list, ListState::Alarm, "start waits for the ack");
    // The cell passing the same loss on, still listed: both clear when
    // welding is back; a station named alike is not welding.
    r.list.handle_heard(
        r.now,
        None,
        Unconfirmed::Report {
            station: st("cell"),
            severity: Severity::Alarm(AlarmClass::Communication),
            text: "alarm in state 13: no connection with station WELDING".into(),
        },
    );
    r.list.handle_presence(r.now, st("welding2"), true);
    assert!(r.status().alarms.iter().all(|a| a.cleared_ms.is_none()));
    r.list.handle_presence(r.now, st("welding"), true);
    let s = r.status();
    assert_eq!(s.alarms.len(), 2, "{:?}", s.alarms);
    assert!(
        s.alarms.iter().all(|a| a.cleared_ms.is_some()),
        "{:?}",
        s.alarms
    );
    assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
    assert!(r.status().alarms.is_empty(), "acknowledged and cleared");
    // The cell is no workstation: its loss is the association's alarm.
    r.list.handle_presence(r.now, st("cell"), false);
    assert!(r.status().alarms.is_empty());
}

#[test]
fn what_the_cell_shows_and_asks_is_bounded() {
    let mut r = Rig::new();
    r.add(1);
    assert!(r.start().is_ok());
    let output = |r: &mut Rig, lines: Vec<String>| {
        let t = r.ticket();
        r.list
            .handle_cell_request(r.now, t, Request::Output { lines });
        r.outputs().into_iter().find_map(|o| match o {
            Output::Respond { ticket, result } if ticket == t => Some(result),
            _ => None,
        })
    };
    let many = output(&mut r, vec!["x".into(); MAX_OUTPUT_LINES + 1]);
    assert!(
        matches!(&many, Some(Err(e)) if e.to_string().contains("at most 100")),
        "{many:?}"
    );
    let long = output(&mut r, vec!["y".repeat(MAX_OUTPUT_CHARS + 1)]);
    let Some(Err(e)) = long else {
        panic!("{long:?}")
    };
    assert!(e.to_string().len() < 300, "quoted short: {e}");
    // 30 lines, then a question: it carries the newest 20, the
    // journal all 30.
    for i in 0..30 {
        assert_eq!(
            output(&mut r, vec![format!("line {i}")]),
            Some(Ok(Response::Done))
        );
    }
    r.question("ok?");
    let q = r.status().question.expect("a question");
    assert_eq!(q.lines().count(), QUESTION_WINDOW_LINES + 1, "{q}");
    assert!(q.starts_with("line 10\n") && q.ends_with("ok?"), "{q}");
    let journalled = r.list.db.texts();
    assert!(
        journalled.iter().any(|t| t.contains("line 0")),
        "{journalled:?}"
    );
    let huge = r.ticket();
    r.list.handle_cell_request(
        r.now,
        huge,
        Request::Input {
            prompt: "z".repeat(MAX_OUTPUT_CHARS + 1),
            timeout_s: None,
        },
    );
    assert!(r
        .outputs()
        .iter()
        .any(|o| matches!(o, Output::Respond { ticket, result: Err(_) } if *ticket == huge)));
    assert!(r.status().question.is_some_and(|q| q.ends_with("ok?")));
}

#[test]
fn a_workstation_back_on_the_bus_is_associated_again_through_the_cell() {
    let mut r = Rig::new();
    r.add(1);
    assert!(r.start().is_ok());
    r.job(JobEvent::Done);
    // Its first appearance (the cell associated): the cell is
    // initiated again, harmlessly.
    r.list.handle_presence(r.now, st("transport"), true);
    assert_eq!(call(&r.outputs()), Some(CellCall::Initiate));
    r.answer(Ok(()));
    r.list.handle_presence(r.now, st("transport"), false);
    r.list.handle_presence(r.now, st("transport"), true);
    let out = r.outputs();
    assert_eq!(call(&out), Some(CellCall::Initiate), "{out:?}");
    let out = r.answer(Ok(()));
    assert!(said(&out, "EVENT rejoined station=transport"), "{out:?}");
}

/// Seen in `falc-sim` (seed 2 of 1,000 orders): a workstation that came
/// back while an order ran is not initiated then; once the order ended,
/// the recipes the cell's new association owed went through the cell to
/// a workstation nobody had associated again, were refused, and the list
/// tried them again for good, never initiating the cell.
#[test]
fn a_workstation_back_while_an_order_ran_is_associated_again_before_the_recipes_go() {
    let mut r = Rig::new();
    cut_mid_order(&mut r);
    let out = r.tell(attributes(PiState::Running, None));
    assert!(said(&out, "EVENT order-followed id=1"), "{out:?}");
    r.list.handle_presence(r.now, st("welding"), true);
    r.outputs();
    r.list.handle_presence(r.now, st("welding"), false);
    r.list.handle_presence(r.now, st("welding"), true);
    assert_eq!(call(&r.outputs()), None, "not while the order runs");
    r.job(JobEvent::Done);
    r.now += RETRY;
    r.list.handle_timeout(r.now);
    let out = r.outputs();
    assert_eq!(call(&out), Some(CellCall::Initiate), "{out:?}");
    let out = r.answer(Ok(()));
    assert!(
        matches!(call(&out), Some(CellCall::Deliver(_))),
        "the recipes go once it is whole: {out:?}"
    );
}

/// A numbered report of `station` made at `at_ms`, in run `run`.
fn numbered(station: &str, run: &str, no: u64, text: &str) -> (Stamp, Unconfirmed) {
    let stamp = Stamp {
        run: run.into(),
        no,
        at_ms: 1_000 + no as i64,
    };
    let u = Unconfirmed::Report {
        station: st(station),
        severity: Severity::Info,
        text: text.into(),
    };
    (stamp, u)
}

fn reads(out: &[Output]) -> Vec<(StationName, u64)> {
    out.iter()
        .filter_map(|o| match o {
            Output::ReadReports { station, after } => Some((station.clone(), *after)),
            _ => None,
        })
        .collect()
}

impl Rig {
    fn hear(&mut self, (stamp, u): (Stamp, Unconfirmed)) -> Vec<Output> {
        self.list.handle_heard(self.now, Some(stamp), u);
        self.outputs()
    }

    /// The station's journal lines, with their times.
    fn lines_of(&mut self, station: &str) -> Vec<(i64, String)> {
        self.list
            .records()
            .journal
            .iter()
            .filter(|e| e.who == station && e.kind == EntryKind::Report)
            .filter(|e| !e.text.starts_with("alarm #"))
            .map(|e| (e.at_ms, e.text.clone()))
            .collect()
    }
}

use falc_model::mms::journal::{KeptReports, Stamp};

#[test]
fn reports_missed_across_a_cut_are_read_back_filed_in_order_with_their_times_and_marked() {
    let mut r = Rig::new();
    r.list.handle_presence(r.now, st("welding"), true);
    r.outputs();
    for no in 1..=2 {
        assert!(reads(&r.hear(numbered("welding", "a", no, &format!("r{no}")))).is_empty());
    }
    // The link is cut; 3 and 4 are made meanwhile and never heard.
    r.list.handle_presence(r.now, st("welding"), false);
    r.list.handle_presence(r.now, st("welding"), true);
    let out = r.outputs();
    assert_eq!(reads(&out), vec![(st("welding"), 2)], "{out:?}");
    // 5 is heard live while the read is out: left to the read.
    assert!(reads(&r.hear(numbered("welding", "a", 5, "r5"))).is_empty());
    let kept = KeptReports {
        run: "a".into(),
        first: 1,
        reports: (3..=4)
            .map(|no| numbered("welding", "a", no, &format!("r{no}")))
            .collect(),
    };
    r.list
        .handle_kept_reports(r.now, st("welding"), Ok(kept.clone()));
    // 5 came after the answer was made: read again from 4.
    let out = r.outputs();
    assert_eq!(reads(&out), vec![(st("welding"), 4)], "{out:?}");
    let mut kept = kept;
    kept.reports.push(numbered("welding", "a", 5, "r5"));
    r.list.handle_kept_reports(r.now, st("welding"), Ok(kept));
    assert!(reads(&r.outputs()).is_empty());
    // A duplicate and the next live one.
    r.hear(numbered("welding", "a", 4, "r4"));
    r.hear(numbered("welding", "a", 6, "r6"));
    let lines = r.lines_of("welding");
    let texts: Vec<&str> = lines.iter().map(|(_, t)| t.as_str()).collect();
    assert_eq!(
        texts,
        [
            "r1",
            "r2",
            "r3 (replayed)",
            "r4 (replayed)",
            "r5 (replayed)",
            "r6"
        ]
    );
    // The replayed ones keep the station's time.
    assert_eq!(lines[2].0, 1_003);
    assert_eq!(lines[4].0, 1_005);
}

#[test]
fn a_list_started_again_reads_back_from_the_last_report_its_records_say_was_filed() {
    let mut r = Rig::new();
    r.list.handle_presence(r.now, st("welding"), true);
    for no in 1..=3 {
        r.hear(numbered("welding", "a", no, &format!("r{no}")));
    }
    // Each report filed is kept in the records as it is filed.
    assert_eq!(
        r.list.records().reports_filed(),
        Ok(vec![("welding".to_string(), "a".to_string(), 3)])
    );
    // The operator is killed; welding makes 4 and 5 meanwhile. The list
    // started again on the same records reads from 3 once welding is
    // heard on the bus.
    let mut records = Memory::default();
    records
        .report_filed("welding", "a", 3)
        .expect("a write in memory");
    let mut r = Rig::with(records);
    r.outputs();
    r.list.handle_presence(r.now, st("welding"), true);
    let out = r.outputs();
    assert_eq!(reads(&out), vec![(st("welding"), 3)], "{out:?}");
    let kept = KeptReports {
        run: "a".into(),
        first: 1,
        reports: (1..=5)
            .map(|no| numbered("welding", "a", no, &format!("r{no}")))
            .collect(),
    };
    r.list.handle_kept_reports(r.now, st("welding"), Ok(kept));
    r.outputs();
    let texts: Vec<String> = r.lines_of("welding").into_iter().map(|(_, t)| t).collect();
    assert_eq!(texts, ["r4 (replayed)", "r5 (replayed)"]);
    assert_eq!(
        r.list.records().reports_filed(),
        Ok(vec![("welding".to_string(), "a".to_string(), 5)])
    );
}

#[test]
fn a_gap_in_the_numbers_is_read_back_and_what_fell_out_of_the_buffer_is_reported_lost() {
    let mut r = Rig::new();
    r.hear(numbered("transport", "a", 7, "first heard"));
    // 8 .. 400 never heard: 401 says so.
    let out = r.hear(numbered("transport", "a", 401, "r401"));
    assert_eq!(reads(&out), vec![(st("transport"), 7)], "{out:?}");
    let kept = KeptReports {
        run: "a".into(),
        first: 320,
        reports: (320..=401)
            .map(|no| numbered("transport", "a", no, &format!("r{no}")))
            .collect(),
    };
    r.list.handle_kept_reports(r.now, st("transport"), Ok(kept));
    let out = r.outputs();
    assert!(
        said(&out, "EVENT replayed station=transport reports=82 lost=312"),
        "{out:?}"
    );
    let lines = r.lines_of("transport");
    assert_eq!(lines[1].1, "312 reports lost while the link was down");
    assert_eq!(lines[2].1, "r320 (replayed)");
    assert_eq!(lines.last().map(|l| l.1.as_str()), Some("r401 (replayed)"));
    assert_eq!(lines.len(), 2 + 82);
}

#[test]
fn a_failed_read_is_tried_again_and_a_restarted_station_is_read_from_its_new_run() {
    let mut r = Rig::new();
    r.list.handle_presence(r.now, st("welding"), true);
    r.outputs();
    r.hear(numbered("welding", "a", 1, "old run"));
    r.list.handle_presence(r.now, st("welding"), false);
    r.list.handle_presence(r.now, st("welding"), true);
    assert_eq!(reads(&r.outputs()), vec![(st("welding"), 1)]);
    r.list
        .handle_kept_reports(r.now, st("welding"), Err("no reply".into()));
    r.now += Duration::from_millis(500);
    r.list.handle_timeout(r.now);
    assert!(reads(&r.outputs()).is_empty(), "read again too soon");
    r.now += Duration::from_millis(500);
    assert!(r.list.poll_timeout().is_some_and(|t| t <= r.now));
    r.list.handle_timeout(r.now);
    assert_eq!(reads(&r.outputs()), vec![(st("welding"), 1)]);
    // The node started again meanwhile: its new run is filed from 1.
    let kept = KeptReports {
        run: "b".into(),
        first: 1,
        reports: vec![numbered("welding", "b", 1, "new run")],
    };
    r.list.handle_kept_reports(r.now, st("welding"), Ok(kept));
    r.hear(numbered("welding", "b", 2, "live again"));
    let texts: Vec<String> = r.lines_of("welding").into_iter().map(|l| l.1).collect();
    assert_eq!(texts, ["old run", "new run (replayed)", "live again"]);
}

#[test]
fn a_replayed_job_end_is_recorded_with_the_station_s_time() {
    let mut r = Rig::new();
    r.hear(numbered("welding", "a", 1, "hello"));
    let kept = KeptReports {
        run: "a".into(),
        first: 1,
        reports: vec![(
            Stamp {
                run: "a".into(),
                no: 2,
                at_ms: 4_242,
            },
            Unconfirmed::Job {
                station: st("welding"),
                program: name("DROOG_DIK"),
                event: JobEvent::BadProduct,
            },
        )],
    };
    r.list.handle_presence(r.now, st("welding"), true);
    r.outputs();
    r.list.handle_kept_reports(r.now, st("welding"), Ok(kept));
    let lines = r.lines_of("welding");
    assert_eq!(
        lines.last(),
        Some(&(
            4_242,
            "job DROOG_DIK ended: bad product (replayed)".to_string()
        ))
    );
    let jobs = r.list.records().jobs.clone();
    assert_eq!(
        jobs.last().map(|(_, j)| j.ended_ms),
        Some(4_242),
        "{jobs:?}"
    );
}

#[test]
fn a_job_started_while_its_station_was_cut_off_is_read_back_with_its_start_time() {
    let mut r = Rig::new();
    r.hear(numbered("welding", "a", 1, "hello"));
    let job = |no: u64, at_ms: i64, event: JobEvent| {
        (
            Stamp {
                run: "a".into(),
                no,
                at_ms,
            },
            Unconfirmed::Job {
                station: st("welding"),
                program: name("DROOG_DIK"),
                event,
            },
        )
    };
    // Back on the bus: its status (the job still runs) comes before the
    // read; the start read back keeps one line and corrects the time.
    r.list.handle_presence(r.now, st("welding"), true);
    r.outputs();
    r.publish(Unconfirmed::Status {
        station: st("welding"),
        status: VmdStatus {
            program: Some(falc_model::mms::vmd::ProgramState {
                name: name("DROOG_DIK"),
                state: 2,
            }),
            ..VmdStatus::default()
        },
    });
    let kept = KeptReports {
        run: "a".into(),
        first: 1,
        reports: vec![
            job(2, 4_000, JobEvent::Started),
            job(3, 9_000, JobEvent::Done),
        ],
    };
    r.list.handle_kept_reports(r.now, st("welding"), Ok(kept));
    let texts: Vec<String> = r.lines_of("welding").into_iter().map(|l| l.1).collect();
    let started = texts
        .iter()
        .filter(|t| t.starts_with("job DROOG_DIK started"))
        .count();
    assert_eq!(started, 1, "{texts:?}");
    let jobs = r.list.records().jobs.clone();
    assert_eq!(
        jobs.last().map(|(_, j)| (j.started_ms, j.ended_ms)),
        Some((Some(4_000), 9_000)),
        "{jobs:?}"
    );
    // A start heard live with no status before it: one line, its time.
    r.hear(job(4, 10_000, JobEvent::Started));
    let texts: Vec<String> = r.lines_of("welding").into_iter().map(|l| l.1).collect();
    assert_eq!(
        texts.last().map(String::as_str),
        Some("job DROOG_DIK started")
    );
}

/// The recipe state shown for a station is the one it publishes, as its
/// own controller produced it (WAIT_ACK and PENDING are its recipe's
/// waits for the level below); an alarm waiting for acknowledgement is
/// shown as the alarm it is, and changes no recipe state.
#[test]
fn the_recipe_state_shown_is_the_station_s_own_and_an_alarm_is_no_recipe_state() {
    use falc_model::mms::vmd::RecipeState;
    let mut r = Rig::new();
    let cell_status = |state: RecipeState| Unconfirmed::Status {
        station: st("cell"),
        status: VmdStatus {
            local_detail: state,
            ..VmdStatus::default()
        },
    };
    let shown = |r: &mut Rig| {
        r.list
            .status()
            .expect("status")
            .stations
            .iter()
            .find(|v| v.name == st("cell"))
            .and_then(|v| v.status.as_ref())
            .map(|s| s.local_detail)
    };
    r.publish(cell_status(RecipeState::Ready));
    assert_eq!(shown(&mut r), Some(RecipeState::Ready));
    r.add(2);
    r.start_until_the_cells_start();
    r.outputs();
    // The operator's start under way is the list's, not the cell's state.
    assert_eq!(shown(&mut r), Some(RecipeState::Ready));
    r.answer(Ok(()));
    for state in [
        RecipeState::Executing,
        RecipeState::WaitAck,
        RecipeState::Pending,
    ] {
        r.publish(cell_status(state));
        assert_eq!(shown(&mut r), Some(state));
    }
    // The order ends in alarm (the job event first, as the cell publishes
    // it): the cell is in ERROR, and its alarm waits, shown as the alarm.
    r.job(JobEvent::Alarm(Cause::new(
        AlarmClass::Safety,
        "emergency stop".to_string(),
    )));
    r.publish(cell_status(RecipeState::Error));
    assert_eq!(shown(&mut r), Some(RecipeState::Error));
    let status = r.list.status().expect("status");
    assert!(
        status
            .alarm
            .as_deref()
            .is_some_and(|a| a.contains("emergency stop")),
        "{status:?}"
    );
    assert!(r.ask("console", ApiRequest::Ack { id: None }).is_ok());
    r.outputs();
    assert_eq!(shown(&mut r), Some(RecipeState::Error));
    let states: Vec<&str> = r
        .said
        .iter()
        .filter(|l| l.starts_with("EVENT recipe-state station=cell "))
        .filter_map(|l| l.rsplit_once("state=").map(|(_, s)| s))
        .collect();
    assert_eq!(
        states,
        ["READY", "EXECUTING", "WAIT_ACK", "PENDING", "ERROR"]
    );
}

#[test]
fn a_replayed_alarm_whose_condition_is_gone_is_cleared_at_once() {
    let mut r = Rig::new();
    r.list.handle_presence(r.now, st("welding"), true);
    r.publish(Unconfirmed::Status {
        station: st("welding"),
        status: VmdStatus::default(),
    });
    r.hear(numbered("welding", "a", 1, "hello"));
    r.list.handle_presence(r.now, st("welding"), false);
    r.list.handle_presence(r.now, st("welding"), true);
    r.outputs();
    let alarm = Unconfirmed::Report {
        station: st("welding"),
        severity: Severity::Alarm(AlarmClass::Communication),
        text: "no connection with station cell".into(),
    };
    let stamp = Stamp {
        run: "a".into(),
        no: 2,
        at_ms: 77,
    };
    let kept = KeptReports {
        run: "a".into(),
        first: 1,
        reports: vec![(stamp, alarm)],
    };
    r.list.handle_kept_reports(r.now, st("welding"), Ok(kept));
    let out = r.outputs();
    let listed = r.status().alarms;
    let a = listed
        .iter()
        .find(|a| a.text == "no connection with station cell")
        .unwrap_or_else(|| panic!("the replayed alarm is listed: {listed:?}"));
    assert!(a.cleared_ms.is_some(), "{a:?}");
    assert!(said(&out, "EVENT alarm-cleared"), "{out:?}");
}

#[test]
fn the_cells_job_event_is_taken_as_it_comes_while_a_read_is_out_and_never_from_a_replay() {
    let mut r = Rig::new();
    r.add(2);
    assert!(r.start().is_ok());
    r.list.handle_presence(r.now, st("cell"), true);
    r.outputs();
    r.hear(numbered("cell", "c", 1, "dikke plaat droog"));
    // The cell's link was cut and is back: a read goes out.
    r.list.handle_presence(r.now, st("cell"), false);
    r.list.handle_presence(r.now, st("cell"), true);
    assert_eq!(reads(&r.outputs()), vec![(st("cell"), 1)]);
    let done = |no| {
        let stamp = Stamp {
            run: "c".into(),
            no,
            at_ms: 5,
        };
        let u = Unconfirmed::Job {
            station: st("cell"),
            program: name("dikdroog"),
            event: JobEvent::Done,
        };
        (stamp, u)
    };
    // The order's end comes live meanwhile: taken at once.
    r.hear(done(3));
    assert_eq!(r.order(1).state, OrderState::Done);
    // The read brings 2 and the same end again: 2 is filed, the end is
    // not taken twice (order 2 would end with it).
    let kept = KeptReports {
        run: "c".into(),
        first: 1,
        reports: vec![numbered("cell", "c", 2, "klaar"), done(3)],
    };
    r.list.handle_kept_reports(r.now, st("cell"), Ok(kept));
    r.outputs();
    assert!(r
        .lines_of("cell")
        .iter()
        .any(|(_, t)| t == "klaar (replayed)"));
    assert_ne!(r.order(2).state, OrderState::Done);
    assert_eq!(r.list.filed(&st("cell")), Some(("c", 3, 0)));
}

#[test]
fn numbers_at_the_end_of_their_range_from_a_station_crash_nothing() {
    let mut r = Rig::new();
    r.list.handle_presence(r.now, st("welding"), true);
    r.outputs();
    // A station (or a forged stamp) at the top of the range.
    r.hear(numbered("welding", "a", u64::MAX - 1, "one"));
    r.hear(numbered("welding", "a", u64::MAX, "two"));
    r.hear(numbered("welding", "a", u64::MAX, "again"));
    let kept = KeptReports {
        run: "a".into(),
        first: u64::MAX,
        reports: vec![numbered("welding", "a", u64::MAX, "two")],
    };
    r.list.handle_presence(r.now, st("welding"), false);
    r.list.handle_presence(r.now, st("welding"), true);
    r.list.handle_kept_reports(r.now, st("welding"), Ok(kept));
    let texts: Vec<String> = r.lines_of("welding").into_iter().map(|l| l.1).collect();
    assert_eq!(texts, ["one", "two"]);
    assert_eq!(r.list.filed(&st("welding")), Some(("a", u64::MAX, 0)));
}

#[test]
fn one_question_waits_with_the_newest_lines_shown_before_it() {
    let mut q = Questions::default();
    q.show((0..25).map(|i| format!("line {i}")).collect());
    assert!(q.ask("klopt het?", Ticket(1)).is_none());
    let prompt = q.prompt().unwrap_or_default().to_string();
    let lines: Vec<&str> = prompt.lines().collect();
    assert_eq!(lines.len(), QUESTION_WINDOW_LINES + 1, "{prompt}");
    assert_eq!(lines.first(), Some(&"line 5"));
    assert_eq!(lines.last(), Some(&"klopt het?"));
    // A newer question replaces it (handed back) and shows no old line.
    let older = q.ask("nog eens?", Ticket(2));
    assert_eq!(older.map(|o| o.ticket), Some(Ticket(1)));
    assert_eq!(q.prompt(), Some("nog eens?"));
    // A new order's question shows none of the last order's lines.
    q.show(vec!["van de vorige".into()]);
    q.new_order();
    assert_eq!(q.take().map(|o| o.ticket), Some(Ticket(2)));
    assert!(q.ask("ja?", Ticket(3)).is_none());
    assert_eq!(q.prompt(), Some("ja?"));
}

/// An alarm row the records cannot read (a file edited by hand) does not
/// leave the list silently empty: the list starts with an alarm of its
/// own naming why, which holds `start` until it is acknowledged; then the
/// next order runs to done.
#[test]
fn alarms_that_cannot_be_read_are_an_alarm_that_holds_the_start() {
    let mut records = Memory::default();
    records.unreadable_alarms = Some("alarm row 12: `Weld ing!` is no station name".into());
    let mut r = Rig::with(records);
    let s = r.status();
    let a = s
        .alarms
        .iter()
        .find(|a| a.text.contains("could not be read"))
        .unwrap_or_else(|| panic!("no alarm: {s:?}"));
    assert!(a.text.contains("alarm row 12"), "{}", a.text);
    assert!(a.blocks_start(), "{a:?}");
    assert_eq!(a.station, "operator");
    assert!(
        r.said
            .iter()
            .any(|l| l.starts_with("EVENT alarm") && l.contains("could not be read")),
        "{:?}",
        r.said
    );
    // It holds the cell: an order waits until someone acknowledged it.
    r.add(1);
    assert!(r.start().is_err(), "started over an unacknowledged alarm");
    assert_eq!(r.order(1).state, OrderState::Queued);
    // The way back: acknowledged, started, the next order done.
    r.ask("console", ApiRequest::Ack { id: None })
        .unwrap_or_else(|e| panic!("{e}"));
    let s = r.status();
    assert!(s.alarms.iter().all(|a| !a.blocks_start()), "{s:?}");
    assert!(r.start().is_ok());
    let out = r.job(JobEvent::Done);
    assert!(said(&out, "EVENT order-ended id=1 state=done"), "{out:?}");
    assert_eq!(r.order(1).state, OrderState::Done);
}
