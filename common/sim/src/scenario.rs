//! A seeded run: orders added and worked through as an operator would
//! (answering the cell's questions with `ja`), faults injected while
//! orders run, each followed by the documented way back (clear the cause,
//! carriers home, `ack`, `start`), and the invariants checked after every
//! step. The same seed gives the same run.

use crate::bus::{Link, Node};
use crate::world::{World, HOME};
use falc_control::controller::Device;
use falc_dnc::robot::Control as Rcm;
use falc_factory::order_list::Ticket;
use falc_model::alarm::Alarm;
use falc_model::console::{ApiRequest, Entry, EntryKind, ListState, Order, OrderState};
use falc_model::ids::Place;
use falc_model::mms::vmd::PhysicalStatus;
use falc_plc::conveyor::{Control as Plc, Spot};
use falc_plc::map::{Coil, LINES};
use rand::seq::SliceRandom;
use rand::Rng;
use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::time::Duration;

/// A kind of fault the simulation injects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Fault {
    /// A process (operator, cell or workstation) is killed and started
    /// again.
    Crash,
    /// The robot's emergency stop.
    EStop,
    /// The robot runs into a limit switch.
    LimitSwitch,
    /// The serial line is unplugged for a while.
    Unplug,
    /// Noise on the serial line.
    Noise,
    /// A carrier jams on its line.
    Jam,
    /// A place's sensor sticks.
    Stuck,
    /// A node's link to the router is cut for a while.
    Partition,
    /// The operator's disk is full.
    DiskFull,
    /// A workstation is started again with too little recipe memory for
    /// its recipes (a controller replaced): the cell's deliveries to it
    /// are refused until it has enough.
    Memory,
}

impl Fault {
    /// Every kind.
    pub const ALL: [Fault; 10] = [
        Fault::Crash,
        Fault::EStop,
        Fault::LimitSwitch,
        Fault::Unplug,
        Fault::Noise,
        Fault::Jam,
        Fault::Stuck,
        Fault::Partition,
        Fault::DiskFull,
        Fault::Memory,
    ];

    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Fault::Crash => "crash",
            Fault::EStop => "estop",
            Fault::LimitSwitch => "limit-switch",
            Fault::Unplug => "unplug",
            Fault::Noise => "noise",
            Fault::Jam => "jam",
            Fault::Stuck => "stuck",
            Fault::Partition => "partition",
            Fault::DiskFull => "disk-full",
            Fault::Memory => "memory",
        }
    }

    /// How long it lasts before the operator clears its cause, in ms: a
    /// cable or a link stays out until somebody finds it.
    fn lasts(self) -> std::ops::Range<u64> {
        match self {
            Fault::Unplug | Fault::Partition | Fault::Crash => 2_000..20_000,
            _ => 2_000..8_000,
        }
    }

    /// The kind named `s`.
    pub fn parse(s: &str) -> Option<Fault> {
        Fault::ALL.into_iter().find(|f| f.name() == s)
    }
}

impl fmt::Display for Fault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// What a run is asked to do.
#[derive(Debug, Clone)]
pub struct Config {
    /// Drives every random choice.
    pub seed: u64,
    /// Orders to work through.
    pub orders: usize,
    /// The kinds of fault to inject (none: a clean run).
    pub faults: Vec<Fault>,
    /// Chance that an order meets a fault.
    pub fault_rate: f64,
    /// The twins' time scale.
    pub time_scale: f64,
    /// The cell recipes ordered, in turn.
    pub recipes: Vec<String>,
    /// Keep the journal's lines in the summary.
    pub keep_journal: bool,
    /// A fault comes when the robot runs a job's program (mid-weld), not
    /// at a random moment of the order.
    pub at_weld: bool,
    /// At most this many faults in the run.
    pub fault_limit: Option<u32>,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            seed: 1,
            orders: 10,
            faults: Fault::ALL.to_vec(),
            fault_rate: 0.8,
            time_scale: 20.0,
            recipes: vec!["dikdroog".into(), "dundroog".into(), "pipdroog".into()],
            keep_journal: false,
            at_weld: false,
            fault_limit: None,
        }
    }
}

/// An invariant that did not hold.
#[derive(Debug, Clone)]
pub struct Violation {
    /// Which, and what was seen.
    pub what: String,
    /// The step it was seen after.
    pub step: u64,
    /// Virtual time then.
    pub at: Duration,
    /// The events that led there.
    pub trace: Vec<String>,
}

impl fmt::Display for Violation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "invariant broken at step {} ({:.3} s): {}",
            self.step,
            self.at.as_secs_f64(),
            self.what
        )?;
        writeln!(f, "the events that led there:")?;
        for l in &self.trace {
            writeln!(f, "  {l}")?;
        }
        Ok(())
    }
}

/// What a run did.
#[derive(Debug, Clone, Default)]
pub struct Summary {
    /// Orders ended done.
    pub done: usize,
    /// Orders ended otherwise.
    pub failed: usize,
    /// Faults injected, by kind.
    pub faults: BTreeMap<Fault, u32>,
    /// Steps taken.
    pub steps: u64,
    /// Virtual time of production.
    pub simulated: Duration,
    /// Alarms raised.
    pub alarms: usize,
    /// Journal entries written.
    pub journal: usize,
    /// Of those, reports read back from a station after a cut or a
    /// crash (marked replayed), and lines saying some were lost.
    pub replayed: usize,
    /// Every journal entry's kind, in order (for comparing runs).
    pub kinds: Vec<EntryKind>,
    /// The journal's lines (`order kind who: text`), if kept.
    pub lines: Vec<String>,
    /// The journal's entries, if kept (for comparing runs).
    pub entries: Vec<Entry>,
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "orders: {} done, {} failed; {} alarms; {} journal entries ({} replayed)",
            self.done, self.failed, self.alarms, self.journal, self.replayed
        )?;
        let faults: Vec<String> = self
            .faults
            .iter()
            .map(|(k, n)| format!("{k} {n}"))
            .collect();
        writeln!(
            f,
            "faults: {}",
            if faults.is_empty() {
                "none".into()
            } else {
                faults.join(", ")
            }
        )?;
        write!(
            f,
            "{} steps over {:.1} s of simulated production",
            self.steps,
            self.simulated.as_secs_f64()
        )
    }
}

/// A fault in force, and when the operator finds and clears its cause.
#[derive(Debug, Clone, Copy)]
struct Active {
    fault: Fault,
    clear_at: Duration,
    /// What it needs cleared (a node, a line, a place).
    node: Option<Node>,
    line: Option<char>,
    place: Option<Place>,
}

/// The recipe memory of a workstation under [`Fault::Memory`]: less than
/// any of its recipes.
const SMALL_MEMORY: usize = 64;
/// How long the operator waits after a refused start before the next.
const START_AGAIN: Duration = Duration::from_secs(5);
/// How often the operator looks at the cell.
const TICK: Duration = Duration::from_millis(250);
/// No order may take longer to end than this (a stuck cell).
const STUCK: Duration = Duration::from_secs(1800);
/// An orphan robot program is stopped within this.
const ORPHAN: Duration = Duration::from_secs(20);
/// A line button held with no transport job for longer than this.
const HELD: Duration = Duration::from_secs(2);
/// An unplugged serial line is seen within this while a program of a job
/// runs: nothing heard for an acknowledgement delay (2 s) after the next
/// status request (at most a status period, 0.5 s, away).
const SILENT: Duration = Duration::from_secs(3);
/// A failed write stops the running order at the cell within this (the
/// list halts it); a full disk is only known at the next write.
const BEHIND: Duration = Duration::from_secs(2);

/// One run.
pub struct Run {
    /// The cell.
    pub world: World,
    cfg: Config,
    added: usize,
    /// Kinds in turn, shuffled once per round.
    deck: Vec<Fault>,
    active: Option<Active>,
    /// A fault is due at this time.
    fault_at: Option<Duration>,
    /// The running order a fault was already planned for.
    planned_for: Option<i64>,
    /// The way back is to be taken: carriers home before the next start.
    way_back: bool,
    /// After a way back: the faults injected so far and the last order
    /// started before it. The first order started after it must end done
    /// unless another fault comes.
    production_since: Option<(Duration, u32, i64)>,
    /// Faults injected so far.
    injected: u32,
    next_tick: Duration,
    console: Option<Ticket>,
    /// The console request out is an order's add.
    adding: bool,
    /// The console request out is a start; a refused one is tried again
    /// no sooner than this.
    starting: bool,
    start_after: Duration,
    summary: Summary,
    /// Journal entries checked so far, and ends seen per order.
    checked: usize,
    ends: BTreeMap<i64, u32>,
    last_end: Duration,
    orphan_since: Option<Duration>,
    /// Since when the line is unplugged under a weld, unseen.
    silent_since: Option<Duration>,
    /// The records' alarms not yet both acknowledged and cleared (their
    /// index, and when first seen), and how many of the records' alarms
    /// were looked at.
    open_alarms: Vec<(usize, Duration)>,
    alarms_seen: usize,
    /// Since when an order runs at the cell after a write failed.
    behind_since: Option<Duration>,
    /// Writes refused before the disk last filled.
    refused: u64,
    held_since: Option<Duration>,
    answered: Option<String>,
}

impl Run {
    /// A run of `cfg` on a fresh cell; a configuration that cannot run is
    /// refused, saying why.
    pub fn new(cfg: Config) -> Result<Self, String> {
        if cfg.recipes.is_empty() {
            return Err("no cell recipe to order".into());
        }
        if !(0.0..=1.0).contains(&cfg.fault_rate) {
            return Err(format!("a fault rate of {} (0 to 1)", cfg.fault_rate));
        }
        if !(cfg.time_scale.is_finite() && cfg.time_scale > 0.0) {
            return Err(format!("a time scale of {} (above 0)", cfg.time_scale));
        }
        let world = World::new(cfg.seed, cfg.time_scale, Link::default())?;
        Ok(Self {
            world,
            cfg,
            added: 0,
            deck: Vec::new(),
            active: None,
            fault_at: None,
            planned_for: None,
            way_back: false,
            production_since: None,
            injected: 0,
            next_tick: Duration::ZERO,
            console: None,
            adding: false,
            starting: false,
            start_after: Duration::ZERO,
            summary: Summary::default(),
            checked: 0,
            ends: BTreeMap::new(),
            last_end: Duration::ZERO,
            orphan_since: None,
            behind_since: None,
            open_alarms: Vec::new(),
            alarms_seen: 0,
            silent_since: None,
            refused: 0,
            held_since: None,
            answered: None,
        })
    }

    /// Runs to the end: every order ended, or an invariant broken.
    pub fn run(mut self) -> Result<Summary, Box<Violation>> {
        loop {
            let until = [
                Some(self.next_tick),
                self.fault_at,
                self.active.map(|a| a.clear_at),
            ]
            .into_iter()
            .flatten()
            .min()
            .unwrap_or(self.next_tick);
            self.world.step(until);
            let now = self.world.now;
            if self.fault_at.is_some_and(|t| t <= now) {
                self.fault_at = None;
                self.inject();
            }
            if self.active.is_some_and(|a| a.clear_at <= now) {
                self.clear();
            }
            if self.next_tick <= now {
                self.next_tick = now + TICK;
                self.operate();
            }
            self.check()?;
            if self.finished() {
                break;
            }
        }
        // Settled (reads of kept reports answered): every report of each
        // running station's current run is in the journal.
        let settle = self.world.now + Duration::from_secs(10);
        while self.world.now < settle {
            self.world.step(settle);
        }
        if let Some(what) = self.world.unfiled().into_iter().next() {
            return Err(self.violation(format!("reports not filed: {what}")));
        }
        let rec = self.world.records.borrow();
        self.summary.steps = self.world.steps;
        self.summary.simulated = self.world.now;
        self.summary.alarms = rec.alarms.len();
        self.summary.journal = rec.journal.len();
        self.summary.replayed = rec
            .journal
            .iter()
            .filter(|e| e.text.ends_with(" (replayed)"))
            .count();
        self.summary.kinds = rec.journal.iter().map(|e| e.kind).collect();
        if self.cfg.keep_journal {
            self.summary.lines = rec
                .journal
                .iter()
                .map(|e| {
                    let order = e.order.map_or("-".to_string(), |o| o.to_string());
                    format!("{order:>5} {:?} {}: {}", e.kind, e.who, e.text)
                })
                .collect();
            self.summary.entries = rec.journal.clone();
        }
        self.summary.done = rec
            .orders
            .iter()
            .filter(|o| o.state == OrderState::Done)
            .count();
        self.summary.failed = rec.orders.len() - self.summary.done;
        Ok(self.summary)
    }

    fn finished(&self) -> bool {
        self.added >= self.cfg.orders
            && self.active.is_none()
            && self.console.is_none()
            && self.world.records.borrow().orders.iter().all(is_ended)
            && self
                .world
                .order_list()
                .status()
                .is_ok_and(|s| s.running.is_none() && s.queued == 0)
    }

    fn violation(&self, what: String) -> Box<Violation> {
        Box::new(Violation {
            what,
            step: self.world.steps,
            at: self.world.now,
            trace: self.world.trace.iter().cloned().collect(),
        })
    }

    /// The operator at the console.
    fn operate(&mut self) {
        if let Some(t) = self.console {
            match self.world.reply(t) {
                Some(r) => {
                    if let Err(e) = r {
                        self.world.note(format!("console: refused: {e}"));
                        if self.adding {
                            // Refused (a full disk): added again later.
                            self.added -= 1;
                        }
                        if self.starting {
                            // The operator reads why before trying again.
                            self.start_after = self.world.now + START_AGAIN;
                        }
                    }
                    self.console = None;
                    self.adding = false;
                    self.starting = false;
                }
                None => return,
            }
        }
        let Ok(s) = self.world.order_list().status() else {
            return;
        };
        if let Some(q) = &s.question {
            if self.answered.as_deref() != Some(q.as_str()) {
                self.answered = Some(q.clone());
                self.console = Some(
                    self.world
                        .api("console", ApiRequest::Answer { text: "ja".into() }),
                );
                return;
            }
        } else {
            self.answered = None;
        }
        // Plan a fault for a running order.
        let room = self.cfg.fault_limit.map_or(true, |l| self.injected < l);
        let moment = !self.cfg.at_weld || self.world.welding().device.program().is_some();
        if let Some(o) = &s.running {
            if self.planned_for != Some(o.id)
                && self.active.is_none()
                && self.fault_at.is_none()
                && room
                && moment
            {
                self.planned_for = Some(o.id);
                if !self.cfg.faults.is_empty() && self.world.rng.gen_bool(self.cfg.fault_rate) {
                    let delay = match self.cfg.at_weld {
                        true => 0,
                        false => self.world.rng.gen_range(0..20_000u64),
                    };
                    self.fault_at = Some(self.world.now + Duration::from_millis(delay));
                }
            }
        }
        if self.added < self.cfg.orders && s.queued < 2 {
            // Not empty (Run::new).
            let turn = self.added % self.cfg.recipes.len().max(1);
            let recipe = self.cfg.recipes.get(turn).cloned().unwrap_or_default();
            self.added += 1;
            self.adding = true;
            self.console = Some(self.world.api("console", ApiRequest::order_add(&recipe)));
            return;
        }
        // A full recipe memory is found by starting: the start is refused
        // saying so (the other faults are seen, and cleared first).
        let unseen = self.active.is_some_and(|a| a.fault == Fault::Memory);
        if s.running.is_some() || s.list == ListState::Running || (self.active.is_some() && !unseen)
        {
            return;
        }
        let blocking: Vec<&Alarm> = s.alarms.iter().filter(|a| a.blocks_start()).collect();
        if !blocking.is_empty() || s.list == ListState::Alarm {
            self.way_back = true;
        }
        if self.way_back {
            // Carriers home, then ack, then start.
            let home: Vec<Spot> = HOME.iter().filter_map(|h| Spot::parse(h)).collect();
            if let Err(e) = self.world.conveyor.set_layout(&home) {
                self.world.note(format!("operator: carriers not home: {e}"));
            }
            self.way_back = false;
            let last = self.world.starts.keys().next_back().copied().unwrap_or(0);
            self.production_since = Some((self.world.now, self.injected, last));
            if s.alarms.iter().any(|a| a.acked.is_none()) {
                self.console = Some(self.world.api("console", ApiRequest::Ack { id: None }));
                return;
            }
        }
        if (s.queued > 0 || s.list == ListState::Alarm) && self.world.now >= self.start_after {
            self.starting = true;
            self.console = Some(self.world.api("console", ApiRequest::Start));
        }
    }

    fn inject(&mut self) {
        if self.deck.is_empty() {
            self.deck = self.cfg.faults.clone();
            self.deck.shuffle(&mut self.world.rng);
        }
        let Some(fault) = self.deck.pop() else {
            return;
        };
        *self.summary.faults.entry(fault).or_default() += 1;
        self.injected += 1;
        let now = self.world.now;
        let w = &mut self.world;
        let mut a = Active {
            fault,
            clear_at: now + Duration::from_millis(w.rng.gen_range(fault.lasts())),
            node: None,
            line: None,
            place: None,
        };
        w.note(format!("FAULT {fault}"));
        match fault {
            Fault::Crash => {
                let n = *Node::ALL.choose(&mut w.rng).unwrap_or(&Node::Welding);
                a.node = Some(n);
                w.crash(n);
            }
            Fault::EStop => w.rcm.control(now, Rcm::EStop),
            Fault::LimitSwitch => w.rcm.control(now, Rcm::LimitSwitch),
            Fault::Unplug => w.plugged = false,
            Fault::Noise => {
                let n = w.rng.gen_range(1..40);
                let noise: Vec<u8> = (0..n).map(|_| w.rng.gen()).collect();
                w.noise(noise);
                a.clear_at = now;
            }
            Fault::Jam => {
                let l = *LINES.choose(&mut w.rng).unwrap_or(&'A');
                a.line = Some(l);
                w.conveyor.control(now, Plc::Jam(l));
            }
            Fault::Stuck => {
                let p = Place::of(w.rng.gen_range(2..=6));
                let v = w.rng.gen_bool(0.5);
                a.place = Some(p);
                w.conveyor.control(now, Plc::Stuck(p, v));
            }
            Fault::Partition => {
                let n = *Node::ALL.choose(&mut w.rng).unwrap_or(&Node::Welding);
                a.node = Some(n);
                w.cut(n, true);
            }
            Fault::DiskFull => w.records.borrow_mut().failing = true,
            Fault::Memory => {
                let n = *[Node::Welding, Node::Transport]
                    .choose(&mut w.rng)
                    .unwrap_or(&Node::Welding);
                a.node = Some(n);
                w.set_recipe_memory(n, Some(SMALL_MEMORY));
                w.crash(n);
                w.restart(n);
            }
        }
        self.active = Some(a);
        self.world.pump();
    }

    /// The operator finds the cause and clears it.
    fn clear(&mut self) {
        let Some(a) = self.active.take() else {
            return;
        };
        let now = self.world.now;
        let w = &mut self.world;
        w.note(format!("CLEARED {}", a.fault));
        match a.fault {
            Fault::Crash => w.restart(a.node.unwrap_or(Node::Welding)),
            Fault::EStop => w.rcm.control(now, Rcm::EStopClear),
            Fault::LimitSwitch | Fault::Noise => {}
            Fault::Unplug => w.plugged = true,
            Fault::Jam => w.conveyor.control(now, Plc::Unjam(a.line.unwrap_or('A'))),
            Fault::Stuck => {
                if let Some(p) = a.place {
                    w.conveyor.control(now, Plc::Unstuck(p));
                }
            }
            Fault::Partition => w.cut(a.node.unwrap_or(Node::Welding), false),
            Fault::DiskFull => w.records.borrow_mut().failing = false,
            Fault::Memory => w.set_recipe_memory(a.node.unwrap_or(Node::Welding), None),
        }
        self.way_back = true;
        self.world.pump();
    }

    /// The invariants, after every step.
    fn check(&mut self) -> Result<(), Box<Violation>> {
        let now = self.world.now;
        // No order runs twice.
        if let Some((id, n)) = self.world.started_twice {
            return Err(self.violation(format!("order {id} was started {n} times at the cell")));
        }
        // What a station confirmed as delivered, it holds; and no order
        // starts while a workstation lacks its recipes.
        if let Some(what) = self.world.false_delivery.clone() {
            return Err(self.violation(what));
        }
        if let Some(what) = self.world.started_lacking.clone() {
            return Err(self.violation(what));
        }
        // Every order ends in the journal exactly once (entries so far).
        let rec = self.world.records.borrow();
        // Each order end entry since the last step, and whether it is done.
        let ended: Vec<(i64, bool)> = rec
            .journal
            .iter()
            .skip(self.checked)
            .filter(|e| e.kind == EntryKind::Order)
            .filter_map(|e| end_of(&e.text))
            .map(|id| {
                let done = rec
                    .orders
                    .iter()
                    .rev()
                    .find(|o| o.id == id)
                    .is_some_and(|o| o.state == OrderState::Done);
                (id, done)
            })
            .collect();
        self.checked = rec.journal.len();
        // Every alarm is listed until acknowledged and cleared (the ones
        // not yet both, kept from step to step: once both, for good).
        self.open_alarms
            .extend((self.alarms_seen..rec.alarms.len()).map(|i| (i, now)));
        self.alarms_seen = rec.alarms.len();
        self.open_alarms
            .retain(|(i, _)| rec.alarms.get(*i).is_some_and(Alarm::listed));
        let open: Vec<Alarm> = self
            .open_alarms
            .iter()
            .filter_map(|(i, _)| rec.alarms.get(*i).cloned())
            .collect();
        // … and leaves it once its cause is gone and it was acknowledged:
        // the way back acknowledges every alarm and clears every cause.
        let stale = self
            .open_alarms
            .iter()
            .find(|(_, since)| now.saturating_sub(*since) > STUCK)
            .and_then(|(i, _)| rec.alarms.get(*i).cloned());
        let all_ended = self.added >= self.cfg.orders && rec.orders.iter().all(is_ended);
        drop(rec);
        let unlisted = unlisted_alarm(open, &self.world);
        if let Some(a) = stale.filter(|_| self.active.is_none()) {
            return Err(self.violation(format!(
                "alarm #{} ({}) is still listed {} s after it was raised",
                a.id,
                a.text,
                STUCK.as_secs()
            )));
        }
        for (id, done) in ended {
            let n = {
                let n = self.ends.entry(id).or_default();
                *n += 1;
                *n
            };
            if n > 1 {
                return Err(self.violation(format!("order {id} ended {n} times in the journal")));
            }
            self.last_end = now;
            if let Some((_, faults, before)) = self.production_since {
                if id > before {
                    if !done && faults == self.injected && self.active.is_none() {
                        return Err(self.violation(format!(
                            "order {id}, the first after the way back, did not end done though no fault came"
                        )));
                    }
                    self.production_since = None;
                }
            }
        }
        if let Some(a) = unlisted {
            return Err(self.violation(format!(
                "alarm #{} ({}) is not listed though not acknowledged and cleared",
                a.id, a.text
            )));
        }
        if all_ended && !self.world.records.borrow().failing {
            let rec = self.world.records.borrow();
            if let Some(o) = rec
                .orders
                .iter()
                .find(|o| self.ends.get(&o.id).copied().unwrap_or(0) != 1)
            {
                let what = format!(
                    "order {} ended {} times in the journal",
                    o.id,
                    self.ends.get(&o.id).copied().unwrap_or(0)
                );
                drop(rec);
                return Err(self.violation(what));
            }
        }
        // No line button stays pressed while the conveyor is idle.
        let idle = self.world.is_running(Node::Transport)
            && !self.world.transport().is_running()
            && self.world.transport().device.unavailable().is_none();
        let held = LINES.iter().find(|l| {
            Coil::Button(falc_recipe::check::Button::Line(**l))
                .offset()
                .and_then(|o| self.world.conveyor.coils().get(usize::from(o)).copied())
                .unwrap_or(false)
        });
        if let (true, Some(l)) = (
            lasting(&mut self.held_since, idle && held.is_some(), now) > HELD,
            held,
        ) {
            return Err(self.violation(format!("line button {l} held with no transport job")));
        }
        // No robot program runs without a job that owns it.
        let orphan = self.world.rcm.robot.running().is_some()
            && !(self.world.is_running(Node::Welding) && self.world.welding().is_running());
        if lasting(&mut self.orphan_since, orphan, now) > ORPHAN {
            return Err(self.violation("a robot program runs with no job owning it".into()));
        }
        // A dead serial line is seen while a program of a job runs.
        let unseen = !self.world.plugged
            && self.world.is_running(Node::Welding)
            && self.world.welding().device.program().is_some()
            && self.world.welding().status().physical != PhysicalStatus::Inoperable;
        if lasting(&mut self.silent_since, unseen, now) > SILENT {
            return Err(self.violation(format!(
                "the serial line is unplugged under a running program and the welding station has not seen it in {} s",
                SILENT.as_secs()
            )));
        }
        // A write that fails stops the cell: no order runs on with the
        // journal behind.
        let refused = self.world.records.borrow().refused();
        let behind = refused > self.refused && self.world.cell.controller().is_running();
        if !self.world.records.borrow().failing {
            self.refused = refused;
        }
        if lasting(&mut self.behind_since, behind, now) > BEHIND {
            return Err(self.violation(
                "an order runs at the cell while the records cannot be written".into(),
            ));
        }
        // The order list returns to production after the way back.
        if let Some((since, _, _)) = self.production_since {
            if now.saturating_sub(since) > STUCK && self.active.is_none() {
                return Err(self.violation(format!(
                    "no order done in {} s after the way back",
                    STUCK.as_secs()
                )));
            }
        }
        if now.saturating_sub(self.last_end) > STUCK && self.active.is_none() && !self.finished() {
            return Err(self.violation(format!("no order ended in {} s", STUCK.as_secs())));
        }
        Ok(())
    }
}

/// How long a condition has held: `since` keeps when it began.
fn lasting(since: &mut Option<Duration>, holds: bool, now: Duration) -> Duration {
    if holds {
        now.saturating_sub(*since.get_or_insert(now))
    } else {
        *since = None;
        Duration::ZERO
    }
}

/// Whether `o` ended (done, failed, stopped, or interrupted: its cell
/// kept no end of its run).
fn is_ended(o: &Order) -> bool {
    matches!(
        o.state,
        OrderState::Done | OrderState::Failed | OrderState::Stopped | OrderState::Interrupted
    )
}

/// The order an end entry ends (`order 3 (dikdroog) done: …`, `order 3
/// failed: … (written late)`).
fn end_of(text: &str) -> Option<i64> {
    let rest = text.strip_prefix("order ")?;
    let (id, rest) = rest.split_once(' ')?;
    let id = id.parse().ok()?;
    let rest = match rest.strip_prefix('(') {
        Some(r) => r.split_once(") ")?.1,
        None => rest,
    };
    ["done:", "failed:", "stopped:", "interrupted:"]
        .iter()
        .any(|w| rest.starts_with(w))
        .then_some(id)
}

/// Of the alarms the records hold as not both acknowledged and cleared
/// (`open`), one the order list does not list.
fn unlisted_alarm(open: Vec<Alarm>, world: &World) -> Option<Alarm> {
    if open.is_empty() {
        return None;
    }
    // Once per step, not per alarm: a run that piles alarms up stays fast
    // enough to reach the invariant that catches it.
    let listed: BTreeSet<i64> = world
        .order_list()
        .listed_alarms()
        .iter()
        .map(|a| a.id)
        .collect();
    open.into_iter().find(|a| !listed.contains(&a.id))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn end_entries_are_told_from_others() {
        assert_eq!(end_of("order 3 (dikdroog) done: einde"), Some(3));
        assert_eq!(end_of("order 12 failed: halted (written late)"), Some(12));
        assert_eq!(
            end_of("order 98 (dundroog) interrupted: the cell kept no end"),
            Some(98)
        );
        assert_eq!(end_of("order 3 (dikdroog) started"), None);
        assert_eq!(end_of("order 3 (dikdroog) not started: no"), None);
    }
}
