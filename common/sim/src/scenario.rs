//! A seeded run: orders added and worked through as an operator would
//! (answering each cell's questions with `ja`, at a console per cell in a
//! plant), faults injected while orders run, each followed by the
//! documented way back (clear the cause, carriers home, `ack`, `start`),
//! and the invariants checked after every step, those across the cells of
//! a plant too. The same seed gives the same run.

use crate::bus::{Link, Node, Role};
use crate::world::{shipped_cell, World};
use falc_control::controller::Device;
use falc_dnc::robot::Control as Rcm;
use falc_factory::order_list::Ticket;
use falc_model::alarm::Alarm;
use falc_model::api::{ApiRequest, ListState};
use falc_model::ids::Place;
use falc_model::mms::vmd::PhysicalStatus;
use falc_model::plant::Layout;
use falc_model::records::{Entry, EntryKind, Order, OrderState};
use falc_plc::conveyor::Control as Plc;
use falc_plc::map::Coil;
use rand::seq::SliceRandom;
use rand::Rng;
use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::path::PathBuf;
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
    /// A cell's uplink to the factory router is cut for a while (a plant
    /// only: a cell of its own has none, and skips it).
    Uplink,
}

impl Fault {
    /// Every kind.
    pub const ALL: [Fault; 11] = [
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
        Fault::Uplink,
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
            Fault::Uplink => "uplink",
        }
    }

    /// How long it lasts before the operator clears its cause, in ms: a
    /// cable or a link stays out until somebody finds it.
    fn lasts(self) -> std::ops::Range<u64> {
        match self {
            Fault::Unplug | Fault::Partition | Fault::Crash | Fault::Uplink => 2_000..20_000,
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
    /// The topology file, a cell's or a plant's (None: the shipped
    /// `launch/cell.toml`, compiled in).
    pub topology: Option<PathBuf>,
    /// A recipe tree with a directory per station (None: the shipped
    /// recipes, compiled in), for a topology of other stations.
    pub recipe_dir: Option<PathBuf>,
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
            topology: None,
            recipe_dir: None,
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
    /// Of the crashes and partitions, those of the operator's process or
    /// link (which reach every cell).
    pub operator_faults: u32,
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
    /// In a plant, each cell's orders: (cell, done, ended otherwise).
    pub cells: Vec<(String, usize, usize)>,
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
            "faults: {}{}",
            if faults.is_empty() {
                "none".into()
            } else {
                faults.join(", ")
            },
            match self.operator_faults {
                0 => String::new(),
                n => format!(" ({n} of the crashes and partitions the operator's)"),
            }
        )?;
        if !self.cells.is_empty() {
            let cells: Vec<String> = self
                .cells
                .iter()
                .map(|(c, done, failed)| format!("{c} {done} done, {failed} failed"))
                .collect();
            writeln!(f, "cells: {}", cells.join("; "))?;
        }
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
    /// The cell it was injected in.
    cell: usize,
    /// What it needs cleared (a node, a line, a place).
    node: Option<Node>,
    line: Option<char>,
    place: Option<Place>,
}

impl Active {
    /// Whether it reaches every cell (the operator's process or link, its
    /// disk), not its own cell only.
    fn plant_wide(&self) -> bool {
        self.fault == Fault::DiskFull || self.node.is_some_and(Node::is_operator)
    }
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

/// The operator at one cell's console: what it waits for, and the
/// invariants kept per cell.
#[derive(Debug, Default)]
struct Desk {
    /// The running order a fault was already planned for.
    planned_for: Option<i64>,
    /// The way back is to be taken: carriers home before the next start.
    way_back: bool,
    /// After a way back: the faults that reached this cell so far and the
    /// last order it started before it. The first order it ends after the
    /// way back must end done unless another fault reaches it.
    production_since: Option<(Duration, u32, i64)>,
    /// Faults that reached this cell so far.
    hits: u32,
    /// The cell is clean (no fault reached it since its last way back):
    /// the orders it starts after this one owe nothing to a fault.
    clean_after: Option<i64>,
    console: Option<Ticket>,
    /// The console request out is an order's add.
    adding: bool,
    /// The console request out is a start; a refused one is tried again
    /// no sooner than this.
    starting: bool,
    start_after: Duration,
    /// Per workstation (by number): since when a robot program runs with
    /// no job, since when its line is unplugged under a weld, unseen, and
    /// since when a line button is held with no job.
    orphan_since: Vec<Option<Duration>>,
    silent_since: Vec<Option<Duration>>,
    held_since: Vec<Option<Duration>>,
    answered: Option<String>,
    /// Since when an order runs at the cell after a write for it failed.
    behind_since: Option<Duration>,
    /// The cell's writes refused before the disk last filled.
    refused: u64,
    /// The records' refusals of every cell when last looked at, and this
    /// cell's then (looked up again only when the first moved).
    refused_seen: (u64, u64),
}

/// An order that must end done: it ran on a clean cell (no fault reached
/// it since its way back) when a fault came to another cell.
#[derive(Debug, Clone)]
struct Spared {
    order: i64,
    cell: usize,
    /// The cell's [`Desk::hits`] then: another fault there excuses it.
    hits: u32,
    /// What it was spared from, for the report.
    fault: String,
}

/// One run.
pub struct Run {
    /// The cell, or plant.
    pub world: World,
    cfg: Config,
    added: usize,
    /// Kinds in turn, shuffled once per round.
    deck: Vec<Fault>,
    active: Option<Active>,
    /// A fault is due at this time, in this cell.
    fault_at: Option<(Duration, usize)>,
    /// Faults injected so far.
    injected: u32,
    next_tick: Duration,
    /// Ticks so far.
    ticks: u64,
    /// Each cell's console.
    desks: Vec<Desk>,
    summary: Summary,
    /// Journal entries checked so far, and ends seen per order.
    checked: usize,
    ends: BTreeMap<i64, u32>,
    last_end: Duration,
    /// The records' alarms not yet both acknowledged and cleared (their
    /// index, and when first seen), and how many of the records' alarms
    /// were looked at.
    open_alarms: Vec<(usize, Duration)>,
    alarms_seen: usize,
    /// Orders a fault elsewhere must not fail.
    spared: Vec<Spared>,
    /// The order a cut-off cell ran when its uplink was cut: no end of it
    /// may be recorded while the operator cannot hear the cell.
    cut_off: Option<(usize, i64)>,
}

impl Run {
    /// A run of `cfg` on a fresh cell or plant; a configuration that
    /// cannot run is refused, saying why.
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
        let layout = match &cfg.topology {
            None => shipped_cell()?,
            Some(path) => Layout::load(path).map_err(|e| e.to_string())?,
        };
        let recipes = cfg.recipe_dir.as_deref();
        let world = World::new(&layout, recipes, cfg.seed, cfg.time_scale, Link::default())?;
        let desks = (0..world.cell_count())
            .map(|_| Desk {
                clean_after: Some(0),
                ..Desk::default()
            })
            .collect();
        Ok(Self {
            world,
            cfg,
            added: 0,
            deck: Vec::new(),
            active: None,
            fault_at: None,
            injected: 0,
            next_tick: Duration::ZERO,
            ticks: 0,
            desks,
            summary: Summary::default(),
            checked: 0,
            ends: BTreeMap::new(),
            last_end: Duration::ZERO,
            open_alarms: Vec::new(),
            alarms_seen: 0,
            spared: Vec::new(),
            cut_off: None,
        })
    }

    /// Runs to the end: every order ended, or an invariant broken.
    pub fn run(mut self) -> Result<Summary, Box<Violation>> {
        loop {
            let until = [
                Some(self.next_tick),
                self.fault_at.map(|f| f.0),
                self.active.map(|a| a.clear_at),
            ]
            .into_iter()
            .flatten()
            .min()
            .unwrap_or(self.next_tick);
            self.world.step(until);
            let now = self.world.now;
            if let Some((_, c)) = self.fault_at.filter(|f| f.0 <= now) {
                self.fault_at = None;
                self.inject(c);
            }
            if self.active.is_some_and(|a| a.clear_at <= now) {
                self.clear();
            }
            if self.next_tick <= now {
                self.next_tick = now + TICK;
                // The consoles in turn, a different one first each tick
                // (the first to see a running order plans the fault).
                let n = self.desks.len();
                self.ticks += 1;
                for k in 0..n {
                    self.operate((self.ticks as usize + k) % n);
                }
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
        let done = |o: &&Order| o.state == OrderState::Done;
        self.summary.done = rec.orders.iter().filter(done).count();
        self.summary.failed = rec.orders.len() - self.summary.done;
        if self.world.cell_count() > 1 {
            self.summary.cells = (0..self.world.cell_count())
                .map(|c| {
                    let id = self.world.cell_id(c).to_string();
                    let of = |o: &&Order| o.cell.as_deref() == Some(id.as_str());
                    let ran: Vec<&Order> = rec.orders.iter().filter(of).collect();
                    let done = ran.iter().filter(|o| done(o)).count();
                    (id, done, ran.len() - done)
                })
                .collect();
        }
        Ok(self.summary)
    }

    fn finished(&self) -> bool {
        self.added >= self.cfg.orders
            && self.active.is_none()
            && self.desks.iter().all(|d| d.console.is_none())
            && self.world.records.borrow().orders.iter().all(is_ended)
            && (0..self.world.cell_count()).all(|c| {
                self.world
                    .order_list(c)
                    .status()
                    .is_ok_and(|s| s.running.is_none() && s.queued == 0)
            })
    }

    fn violation(&self, what: String) -> Box<Violation> {
        Box::new(Violation {
            what,
            step: self.world.steps,
            at: self.world.now,
            trace: self.world.trace.iter().cloned().collect(),
        })
    }

    /// The console request of cell `c`'s desk: for the cell in a plant,
    /// with no `--cell` in a cell of its own.
    fn ask(&mut self, c: usize, request: ApiRequest) -> Ticket {
        let cell = (self.world.cell_count() > 1).then_some(c);
        self.world.api("console", cell, request)
    }

    /// The operator at cell `c`'s console.
    fn operate(&mut self, c: usize) {
        let Some(desk) = self.desks.get_mut(c) else {
            return;
        };
        if let Some(t) = desk.console {
            match self.world.reply(t) {
                Some(r) => {
                    if let Err(e) = r {
                        self.world.note(format!("console: refused: {e}"));
                        if desk.adding {
                            // Refused (a full disk): added again later.
                            self.added -= 1;
                        }
                        if desk.starting {
                            // The operator reads why before trying again.
                            desk.start_after = self.world.now + START_AGAIN;
                        }
                    }
                    desk.console = None;
                    desk.adding = false;
                    desk.starting = false;
                }
                None => return,
            }
        }
        let Ok(s) = self.world.order_list(c).status() else {
            return;
        };
        if let Some(q) = &s.question {
            if desk.answered.as_deref() != Some(q.as_str()) {
                desk.answered = Some(q.clone());
                let t = self.ask(c, ApiRequest::Answer { text: "ja".into() });
                self.desks[c].console = Some(t);
                return;
            }
        } else {
            desk.answered = None;
        }
        // Plan a fault for a running order.
        let room = self.cfg.fault_limit.map_or(true, |l| self.injected < l);
        let part = self.world.part(c);
        let welding = |k: &usize| part.welding_parts(*k).map(|w| w.controller());
        let moment = !self.cfg.at_weld
            || part
                .weldings()
                .iter()
                .filter_map(welding)
                .any(|w| w.device.program().is_some());
        if let Some(o) = &s.running {
            if desk.planned_for != Some(o.id)
                && self.active.is_none()
                && self.fault_at.is_none()
                && room
                && moment
            {
                desk.planned_for = Some(o.id);
                if !self.deck_kinds().is_empty() && self.world.rng.gen_bool(self.cfg.fault_rate) {
                    let delay = match self.cfg.at_weld {
                        true => 0,
                        false => self.world.rng.gen_range(0..20_000u64),
                    };
                    self.fault_at = Some((self.world.now + Duration::from_millis(delay), c));
                }
            }
        }
        // Orders are added for any cell: the plant's queue is kept at two
        // per cell.
        if self.added < self.cfg.orders && s.queued < 2 * self.desks.len() {
            // Not empty (Run::new).
            let turn = self.added % self.cfg.recipes.len().max(1);
            let recipe = self.cfg.recipes.get(turn).cloned().unwrap_or_default();
            self.added += 1;
            let t = self
                .world
                .api("console", None, ApiRequest::order_add(&recipe));
            let desk = &mut self.desks[c];
            desk.adding = true;
            desk.console = Some(t);
            return;
        }
        let desk = &mut self.desks[c];
        // A full recipe memory is found by starting: the start is refused
        // saying so (the other faults are seen, and cleared first).
        let unseen = self.active.is_some_and(|a| a.fault == Fault::Memory);
        if s.running.is_some() || s.list == ListState::Running || (self.active.is_some() && !unseen)
        {
            return;
        }
        let blocking: Vec<&Alarm> = s.alarms.iter().filter(|a| a.blocks_start()).collect();
        if !blocking.is_empty() || s.list == ListState::Alarm {
            desk.way_back = true;
        }
        if desk.way_back {
            // Carriers home, then ack, then start.
            desk.way_back = false;
            let last = self.world.last_started.get(c).copied().unwrap_or(0);
            desk.production_since = Some((self.world.now, desk.hits, last));
            desk.clean_after = Some(last);
            for k in self.world.part(c).transports() {
                let Some(t) = self.world.part_mut(c).transport_mut(k) else {
                    continue;
                };
                let home = t.conveyor.equipment().carriers().to_vec();
                if let Err(e) = t.conveyor.set_layout(&home) {
                    self.world.note(format!("operator: carriers not home: {e}"));
                }
            }
            if s.alarms.iter().any(|a| a.acked.is_none()) {
                let t = self.ask(c, ApiRequest::Ack { id: None });
                self.desks[c].console = Some(t);
                return;
            }
        }
        if (s.queued > 0 || s.list == ListState::Alarm) && self.world.now >= desk.start_after {
            let t = self.ask(c, ApiRequest::Start);
            let desk = &mut self.desks[c];
            desk.starting = true;
            desk.console = Some(t);
        }
    }

    /// The kinds of fault this run injects: those asked that the layout
    /// has (a cell of its own has no uplink).
    fn deck_kinds(&self) -> Vec<Fault> {
        let plant = self.world.cell_count() > 1;
        let applies = |f: &&Fault| plant || **f != Fault::Uplink;
        self.cfg.faults.iter().filter(applies).copied().collect()
    }

    /// A fault, in cell `c`.
    fn inject(&mut self, c: usize) {
        if self.deck.is_empty() {
            self.deck = self.deck_kinds();
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
            cell: c,
            node: None,
            line: None,
            place: None,
        };
        let at = w.cell_id(c).to_string();
        w.note(format!("FAULT {fault} in {at}"));
        let cut_order = running_order(w, c);
        // The workstations a fault of the robot or conveyor can reach (a
        // choice only where the cell has more than one).
        let weldings = w.part(c).weldings();
        let robot = pick(&mut w.rng, &weldings).map(|k| Node::workstation(c, k));
        let belt = |w: &mut World| {
            let transports = w.part(c).transports();
            pick(&mut w.rng, &transports).map(|k| Node::workstation(c, k))
        };
        match fault {
            Fault::Crash => {
                let n = w.nodes_of(c).choose(&mut w.rng).copied();
                a.node = n;
                if let Some(n) = n {
                    w.crash(n);
                }
            }
            Fault::EStop | Fault::LimitSwitch | Fault::Unplug | Fault::Noise => {
                a.node = robot;
                let Some(n) = robot else {
                    a.clear_at = now;
                    w.note(format!("{at} has no welding station: nothing to {fault}"));
                    self.active = Some(a);
                    return;
                };
                match fault {
                    Fault::EStop => {
                        if let Some(r) = rcm(w, n) {
                            r.rcm.control(now, Rcm::EStop);
                        }
                    }
                    Fault::LimitSwitch => {
                        if let Some(r) = rcm(w, n) {
                            r.rcm.control(now, Rcm::LimitSwitch);
                        }
                    }
                    Fault::Unplug => {
                        if let Some(r) = rcm(w, n) {
                            r.plugged = false;
                        }
                    }
                    _ => {
                        let n_bytes = w.rng.gen_range(1..40);
                        let noise: Vec<u8> = (0..n_bytes).map(|_| w.rng.gen()).collect();
                        w.noise(n, noise);
                        a.clear_at = now;
                    }
                }
            }
            Fault::Jam | Fault::Stuck => {
                let t = belt(w);
                a.node = t;
                let Some(n) = t else {
                    a.clear_at = now;
                    w.note(format!("{at} has no transport station: nothing to {fault}"));
                    self.active = Some(a);
                    return;
                };
                let Some(equipment) = conveyor(w, n).map(|t| t.conveyor.equipment().clone()) else {
                    return;
                };
                let control = if fault == Fault::Jam {
                    let l = equipment.lines().choose(&mut w.rng).map_or('A', |l| l.line);
                    a.line = Some(l);
                    Plc::Jam(l)
                } else {
                    let places = equipment.places();
                    // One draw from as many as there are places (the same
                    // draw as `2..=6` over the 1992 conveyor's five).
                    let k = w
                        .rng
                        .gen_range(0..u8::try_from(places.len()).unwrap_or(u8::MAX));
                    let Some(p) = places.get(usize::from(k)).map(|p| p.place) else {
                        return;
                    };
                    let v = w.rng.gen_bool(0.5);
                    a.place = Some(p);
                    Plc::Stuck(p, v)
                };
                if let Some(t) = conveyor(w, n) {
                    t.conveyor.control(now, control);
                }
            }
            Fault::Partition => {
                let n = w.nodes_of(c).choose(&mut w.rng).copied();
                a.node = n;
                if let Some(n) = n {
                    w.cut(n, true);
                }
            }
            Fault::DiskFull => w.records.borrow_mut().failing = true,
            Fault::Memory => {
                let ws: Vec<Node> = w
                    .part(c)
                    .workstations()
                    .map(|k| Node::workstation(c, k))
                    .collect();
                let n = ws.choose(&mut w.rng).copied();
                a.node = n;
                if let Some(n) = n {
                    w.set_recipe_memory(n, Some(SMALL_MEMORY));
                    w.crash(n);
                    w.restart(n);
                }
            }
            Fault::Uplink => w.cut_uplink(c, true),
        }
        if a.node.is_some_and(Node::is_operator) {
            self.summary.operator_faults += 1;
        }
        // Who it reaches; the orders it must spare.
        let reached: Vec<usize> = match a.plant_wide() {
            true => (0..self.desks.len()).collect(),
            false => vec![c],
        };
        for d in &reached {
            if let Some(desk) = self.desks.get_mut(*d) {
                desk.hits += 1;
                desk.clean_after = None;
            }
        }
        let what = format!("{fault} in {at}");
        for (d, desk) in self.desks.iter().enumerate() {
            if reached.contains(&d) {
                continue;
            }
            let clean = |o: i64| desk.clean_after.is_some_and(|after| o > after);
            if let Some(order) = running_order(&self.world, d).filter(|o| clean(*o)) {
                self.spared.push(Spared {
                    order,
                    cell: d,
                    hits: desk.hits,
                    fault: what.clone(),
                });
            }
        }
        if fault == Fault::Uplink {
            self.cut_off = cut_order.map(|o| (c, o));
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
        let c = a.cell;
        let w = &mut self.world;
        w.note(format!("CLEARED {}", a.fault));
        match (a.fault, a.node) {
            (_, None) => {}
            (Fault::Crash, Some(n)) => w.restart(n),
            (Fault::EStop, Some(n)) => {
                if let Some(r) = rcm(w, n) {
                    r.rcm.control(now, Rcm::EStopClear);
                }
            }
            (Fault::LimitSwitch | Fault::Noise, _) => {}
            (Fault::Unplug, Some(n)) => {
                if let Some(r) = rcm(w, n) {
                    r.plugged = true;
                }
            }
            (Fault::Jam, Some(n)) => {
                let l = a.line.unwrap_or('A');
                if let Some(t) = conveyor(w, n) {
                    t.conveyor.control(now, Plc::Unjam(l));
                }
            }
            (Fault::Stuck, Some(n)) => {
                if let (Some(p), Some(t)) = (a.place, conveyor(w, n)) {
                    t.conveyor.control(now, Plc::Unstuck(p));
                }
            }
            (Fault::Partition, Some(n)) => w.cut(n, false),
            (Fault::DiskFull | Fault::Uplink, _) => {}
            (Fault::Memory, Some(n)) => w.set_recipe_memory(n, None),
        }
        match a.fault {
            Fault::DiskFull => w.records.borrow_mut().failing = false,
            Fault::Uplink => {
                w.cut_uplink(c, false);
                self.cut_off = None;
            }
            _ => {}
        }
        for (d, desk) in self.desks.iter_mut().enumerate() {
            if a.plant_wide() || d == c {
                desk.way_back = true;
            }
        }
        self.world.pump();
    }

    /// The index of the cell called `id`.
    fn cell_index(&self, id: Option<&str>) -> Option<usize> {
        let id = id?;
        (0..self.world.cell_count()).find(|c| self.world.cell_id(*c).as_str() == id)
    }

    /// The invariants, after every step.
    fn check(&mut self) -> Result<(), Box<Violation>> {
        let now = self.world.now;
        // No order runs twice, on any cell.
        if let Some((id, n)) = self.world.started_twice {
            return Err(self.violation(format!("order {id} was started {n} times at the cells")));
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
        // Each order end entry since the last step: the order, whether it
        // is done, and its cell.
        let ended: Vec<(i64, bool, Option<String>)> = rec
            .journal
            .iter()
            .skip(self.checked)
            .filter(|e| e.kind == EntryKind::Order)
            .filter_map(|e| end_of(&e.text))
            .map(|id| {
                let o = rec.orders.iter().rev().find(|o| o.id == id);
                let done = o.is_some_and(|o| o.state == OrderState::Done);
                (id, done, o.and_then(|o| o.cell.clone()))
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
        for (id, done, cell) in ended {
            let n = {
                let n = self.ends.entry(id).or_default();
                *n += 1;
                *n
            };
            if n > 1 {
                return Err(self.violation(format!("order {id} ended {n} times in the journal")));
            }
            self.last_end = now;
            // A cell cut off keeps its order: nobody can know how it ended
            // until the cell is heard again.
            if self.cut_off.is_some_and(|(_, o)| o == id) {
                let at = self.cut_off.map_or(0, |c| c.0);
                return Err(self.violation(format!(
                    "order {id} was ended in the records while its cell {} was cut off",
                    self.world.cell_id(at)
                )));
            }
            let c = self.cell_index(cell.as_deref());
            // A fault in one cell fails no order of another.
            if let Some(k) = self.spared.iter().position(|s| s.order == id) {
                let s = self.spared.swap_remove(k);
                let untouched = self.desks.get(s.cell).is_some_and(|d| d.hits == s.hits);
                if !done && untouched && c == Some(s.cell) {
                    return Err(self.violation(format!(
                        "order {id} on {} did not end done though the only fault was elsewhere ({})",
                        self.world.cell_id(s.cell),
                        s.fault
                    )));
                }
            }
            let Some(desk) = c.and_then(|c| self.desks.get_mut(c)) else {
                continue;
            };
            if let Some((_, hits, before)) = desk.production_since {
                if id > before {
                    if !done && hits == desk.hits && self.active.is_none() {
                        return Err(self.violation(format!(
                            "order {id}, the first after the way back, did not end done though no fault came"
                        )));
                    }
                    desk.production_since = None;
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
        for c in 0..self.desks.len() {
            self.check_cell(c, now)?;
        }
        if now.saturating_sub(self.last_end) > STUCK && self.active.is_none() && !self.finished() {
            return Err(self.violation(format!("no order ended in {} s", STUCK.as_secs())));
        }
        Ok(())
    }

    /// Cell `c`'s own invariants: its equipment, and its return to
    /// production after the way back.
    fn check_cell(&mut self, c: usize, now: Duration) -> Result<(), Box<Violation>> {
        let w = &self.world;
        let Some(desk) = self.desks.get_mut(c) else {
            return Ok(());
        };
        let p = w.part(c);
        let n = p.workstations().end;
        for v in [
            &mut desk.held_since,
            &mut desk.orphan_since,
            &mut desk.silent_since,
        ] {
            v.resize(n, None);
        }
        // No line button stays pressed while the conveyor is idle.
        let mut held = None;
        for k in p.workstations() {
            let Some(t) = p.transport_parts(k) else {
                continue;
            };
            let idle = w.is_running(Node::workstation(c, k))
                && !t.controller().is_running()
                && t.controller().device.unavailable().is_none();
            let line = t.conveyor.equipment().lines().iter().find_map(|l| {
                let coil = Coil::Button(falc_recipe::check::Button::Line(l.line));
                t.conveyor.coil_value(coil).then_some(l.line)
            });
            let since = &mut desk.held_since[k];
            if lasting(since, idle && line.is_some(), now) > HELD {
                held = line.map(|l| (k, l));
            }
        }
        let (mut orphan, mut silent) = (None, None);
        for k in p.workstations() {
            let Some(r) = p.welding_parts(k) else {
                continue;
            };
            let runs = w.is_running(Node::workstation(c, k));
            // No robot program runs without a job that owns it.
            let orphaned =
                r.rcm.robot.running().is_some() && !(runs && r.controller().is_running());
            if lasting(&mut desk.orphan_since[k], orphaned, now) > ORPHAN {
                orphan = Some(k);
            }
            // A dead serial line is seen while a program of a job runs.
            let unseen = !r.plugged
                && runs
                && r.controller().device.program().is_some()
                && r.controller().status().physical != PhysicalStatus::Inoperable;
            if lasting(&mut desk.silent_since[k], unseen, now) > SILENT {
                silent = Some(k);
            }
        }
        // A write that fails stops the cell: no order runs on with the
        // journal behind.
        let (refused, failing) = {
            let rec = w.records.borrow();
            let total = rec.refused();
            if total != desk.refused_seen.0 {
                desk.refused_seen = (total, rec.refused_of(w.cell_id(c).as_str()));
            }
            (desk.refused_seen.1, rec.failing)
        };
        let behind = refused > desk.refused && p.controller().is_running();
        if !failing {
            desk.refused = refused;
        }
        let behind_for = lasting(&mut desk.behind_since, behind, now);
        // The order list returns to production after the way back.
        let since = desk.production_since.map(|p| p.0);
        let at = if w.cell_count() > 1 {
            format!(" on {}", w.cell_id(c))
        } else {
            String::new()
        };
        let station = |k: usize| {
            let n = Node::workstation(c, k);
            match w.cell_count() {
                1 => String::new(),
                _ => format!(" ({})", w.label(n)),
            }
        };
        if let Some((k, l)) = held {
            let at = station(k);
            return Err(self.violation(format!("line button {l} held with no transport job{at}")));
        }
        if let Some(k) = orphan {
            let at = station(k);
            return Err(self.violation(format!("a robot program runs with no job owning it{at}")));
        }
        if let Some(k) = silent {
            let at = station(k);
            return Err(self.violation(format!(
                "the serial line is unplugged under a running program and the welding station has not seen it in {} s{at}",
                SILENT.as_secs()
            )));
        }
        if behind_for > BEHIND {
            return Err(self.violation(format!(
                "an order runs{at} while the records cannot be written"
            )));
        }
        if let Some(since) = since {
            if now.saturating_sub(since) > STUCK && self.active.is_none() {
                return Err(self.violation(format!(
                    "no order done{at} in {} s after the way back",
                    STUCK.as_secs()
                )));
            }
        }
        Ok(())
    }
}

/// One of `of`, drawn only where there is a choice (a cell of one welding
/// station draws nothing, as before there could be two).
fn pick(rng: &mut impl Rng, of: &[usize]) -> Option<usize> {
    match of {
        [one] => Some(*one),
        many => many.choose(rng).copied(),
    }
}

/// Workstation `n`'s welding parts (its robot's twin, its line).
fn rcm(w: &mut World, n: Node) -> Option<&mut crate::cell::WeldingParts> {
    let Role::Workstation(k) = n.role else {
        return None;
    };
    w.part_mut(n.cell).welding_mut(k)
}

/// Workstation `n`'s transport parts (its conveyor's twin).
fn conveyor(w: &mut World, n: Node) -> Option<&mut crate::cell::TransportParts> {
    let Role::Workstation(k) = n.role else {
        return None;
    };
    w.part_mut(n.cell).transport_mut(k)
}

/// The order cell `c`'s list runs, if any.
fn running_order(world: &World, c: usize) -> Option<i64> {
    let s = world.order_list(c).status().ok()?;
    s.running.map(|o| o.id)
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
    let listed: BTreeSet<i64> = (0..world.cell_count())
        .flat_map(|c| world.order_list(c).listed_alarms())
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
