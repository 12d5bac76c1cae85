//! Chaos rounds on the whole cell ([`super::rig`]): an order runs, a random
//! node is killed (SIGKILL) at a random moment, it is started again, and
//! the documented way back is taken: carriers set back, `falc ack`, `falc
//! start` (repeated while the cell is still reassociating). Each round then
//! checks that the next order ran to done, that no order was lost or ran
//! twice (the journal), and that no node hung. Used by `tests/chaos.rs` (a
//! few rounds) and `benches/chaos.rs` (as many as asked, with figures).

use super::rig::Rig;
use crate::support::wait::{holds, poll_until, POLL};
use falc_model::records::{EntryKind, OrderState};
use rand::Rng;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::time::{Duration, Instant};

/// A node a round kills.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Victim {
    /// `falc-welding`.
    Welding,
    /// `falc-transport`.
    Transport,
    /// `falc-cell`.
    Cell,
    /// `falc-operator`.
    Operator,
}

impl Victim {
    /// Every victim.
    pub const ALL: [Victim; 4] = [
        Victim::Welding,
        Victim::Transport,
        Victim::Cell,
        Victim::Operator,
    ];

    /// Its node's station name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Welding => "welding",
            Self::Transport => "transport",
            Self::Cell => "cell",
            Self::Operator => "operator",
        }
    }
}

/// What one round saw.
#[derive(Debug)]
pub struct Round {
    /// Who was killed.
    pub victim: Victim,
    /// How long after the order's start.
    pub killed_after: Duration,
    /// Kill → the alarm (or abort indication) that shows it, if one came
    /// (a node killed after its part of the order was done may cause
    /// none until the next start).
    pub detected: Option<Duration>,
    /// The next order ran to done after ack + start alone.
    pub recovered: bool,
    /// How many `start` calls it took (refused while reassociating).
    pub starts: u32,
    /// Orders that are gone or ran twice (goal: none).
    pub lost_or_twice: Vec<String>,
    /// What went wrong, with the last journal entries.
    pub problem: Option<String>,
}

/// How an order that was killed under may end: anything but queued.
fn settled(state: OrderState) -> bool {
    matches!(
        state,
        OrderState::Done | OrderState::Failed | OrderState::Stopped | OrderState::Interrupted
    )
}

fn kill(rig: &mut Rig, v: Victim) {
    let p = match v {
        Victim::Welding => rig.welding.as_mut(),
        Victim::Transport => rig.transport.as_mut(),
        Victim::Cell => Some(&mut rig.cell_node),
        Victim::Operator => rig.operator.as_mut(),
    };
    if let Some(p) = p {
        p.kill();
    }
}

fn restart(rig: &mut Rig, v: Victim) {
    match v {
        Victim::Welding => rig.start_welding(),
        Victim::Transport => rig.start_transport(),
        Victim::Cell => rig.start_cell(),
        Victim::Operator => {
            rig.operator = None;
            rig.start_operator();
        }
    }
}

/// What shows the kill, and where.
fn detection(rig: &mut Rig, v: Victim, within: Duration) -> Option<String> {
    match v {
        Victim::Operator => rig
            .cell_node
            .wait_any(&["EVENT abort-indication peer=operator"], within),
        _ => rig
            .operator
            .as_mut()?
            .wait_any(&["EVENT alarm id=", "EVENT cell-lost"], within),
    }
}

/// Answers questions until `until`, or until the list stops.
fn play(rig: &Rig, until: Instant) {
    while Instant::now() < until {
        let s = rig.status();
        if s.question.is_some() {
            rig.cell.falc_as("console", &["answer", "ja"]);
        } else if s.running.is_none() {
            return;
        }
        // A pace: this plays the operator until `until`.
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// One round: order A runs, `victim` is killed `kill_after` into it and
/// started again, order B is added, ack + start, B must end done.
pub fn round(rig: &mut Rig, victim: Victim, kill_after: Duration) -> Round {
    let mut r = Round {
        victim,
        killed_after: kill_after,
        detected: None,
        recovered: false,
        starts: 0,
        lost_or_twice: Vec::new(),
        problem: None,
    };
    let outcome = catch_unwind(AssertUnwindSafe(|| run(rig, &mut r)));
    let problem = match outcome {
        Ok(Ok(())) => None,
        Ok(Err(e)) => Some(e),
        Err(panic) => Some(
            panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "a panic".into()),
        ),
    };
    if let Some(p) = problem {
        let tail = catch_unwind(AssertUnwindSafe(|| {
            let j = rig.journal(None);
            j.iter()
                .rev()
                .take(25)
                .rev()
                .map(|e| format!("  {} {:?} {}: {}", e.id, e.kind, e.who, e.text))
                .collect::<Vec<_>>()
                .join("\n")
        }))
        .unwrap_or_else(|_| "  (the journal could not be read)".into());
        r.problem = Some(format!("{p}\n  last journal entries:\n{tail}"));
    }
    r
}

fn run(rig: &mut Rig, r: &mut Round) -> Result<(), String> {
    let before = rig.orders().len();
    rig.cell.falc(&["order", "add", "dikdroog"]);
    let (code, out) = rig.cell.falc_as("console", &["start"]);
    if code != 0 {
        return Err(format!("the round's first start was refused: {out}"));
    }
    let a = rig
        .orders()
        .iter()
        .rev()
        .find(|o| o.state == OrderState::Running)
        .map(|o| o.id)
        .ok_or("no order runs after start")?;
    let started = Instant::now();
    play(rig, started + r.killed_after);
    if let Some(p) = rig.operator.as_mut() {
        p.forget("EVENT alarm id=");
        p.forget("EVENT cell-lost");
    }
    rig.cell_node.forget("EVENT abort-indication");
    let killed = Instant::now();
    kill(rig, r.victim);
    r.detected = detection(rig, r.victim, Duration::from_secs(5)).map(|_| killed.elapsed());
    restart(rig, r.victim);
    if r.victim == Victim::Operator {
        // The cell runs order A on without its operator; the operator,
        // back, adopts it and learns how it ends. Only then are the
        // carriers set back (not under a running order).
        poll_until(POLL, Duration::from_secs(120), || {
            let running = rig
                .orders()
                .iter()
                .any(|o| o.id == a && o.state == OrderState::Running);
            if running {
                play(rig, Instant::now() + Duration::from_millis(200));
            }
            holds(!running, || ())
        })
        .map_err(|_| format!("order {a} still running 120 s after the operator came back"))?;
    }
    // The documented way back: carriers to where an order starts, then
    // ack + start, repeated while the cell is reassociating.
    rig.plc.control("layout W2 W2");
    rig.cell.falc(&["order", "add", "dikdroog"]);
    poll_until(Duration::from_millis(300), Duration::from_secs(30), || {
        rig.cell.falc(&["ack"]);
        r.starts += 1;
        let (code, out) = rig.cell.falc_as("console", &["start"]);
        holds(code == 0, || out)
    })
    .map_err(|out| format!("start refused for 30 s: {out}"))?;
    rig.work_list("ja", Duration::from_secs(90));
    let orders = rig.orders();
    let b = orders.last().ok_or("the order list is empty")?.clone();
    if orders.len() != before + 2 {
        r.lost_or_twice
            .push(format!("{} orders, expected {}", orders.len(), before + 2));
    }
    let oa = orders.iter().find(|o| o.id == a);
    match oa {
        Some(o) if settled(o.state) => {}
        other => r.lost_or_twice.push(format!("order {a} is {other:?}")),
    }
    for o in &orders {
        let starts = rig
            .journal(Some(o.id))
            .iter()
            .filter(|e| e.kind == EntryKind::Order && e.text.ends_with(") started"))
            .count();
        if starts > 1 {
            r.lost_or_twice
                .push(format!("order {} started {starts} times", o.id));
        }
        if o.state == OrderState::Queued {
            r.lost_or_twice.push(format!("order {} still queued", o.id));
        }
    }
    let hung: Vec<&str> = [
        ("welding", rig.welding.as_mut().map(|p| p.alive())),
        ("transport", rig.transport.as_mut().map(|p| p.alive())),
        ("cell", Some(rig.cell_node.alive())),
        ("operator", rig.operator.as_mut().map(|p| p.alive())),
    ]
    .into_iter()
    .filter(|(_, alive)| *alive != Some(true))
    .map(|(n, _)| n)
    .collect();
    if !hung.is_empty() {
        return Err(format!("not running after the round: {hung:?}"));
    }
    r.recovered = b.state == OrderState::Done;
    if !r.recovered {
        return Err(format!(
            "the next order {} ended {}: {:?}",
            b.id, b.state, b.result
        ));
    }
    Ok(())
}

/// A random moment in an order: `[0.2 s, max)`.
pub fn moment(rng: &mut impl Rng, max: Duration) -> Duration {
    let lo = 200u64;
    let hi = (max.as_millis() as u64).max(lo + 1);
    Duration::from_millis(rng.gen_range(lo..hi))
}
