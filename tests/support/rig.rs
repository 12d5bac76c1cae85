//! The whole cell for tests that drive it through the `falc` CLI: a real
//! router, both twins (time-scaled), both workstations, `falc-cell` and
//! `falc-operator` (recipes from a copy of `recipes/`, order list and
//! journal in a SQLite file in the test's temp dir). Nodes can be killed
//! and started again one by one.

use super::{Proc, TestCell};
use crate::support::wait::{holds, wait_until};
use falc_model::api::{CellStatus, ListState};
use falc_model::records::{Entry, EntryKind, Order};
use std::path::PathBuf;
use std::time::Duration;

pub struct Rig {
    pub cell: TestCell,
    pub rcm: Proc,
    pub plc: Proc,
    pub rcm_path: String,
    pub plc_address: String,
    pub welding: Option<Proc>,
    pub transport: Option<Proc>,
    pub cell_node: Proc,
    pub operator: Option<Proc>,
    pub recipes: PathBuf,
    pub db: PathBuf,
    /// The welding workstation's link through a delay line (the cell as
    /// separate hosts only).
    pub welding_line: Option<super::hosts::DelayLine>,
    /// Workstations beyond `welding` and `transport` (a grown topology):
    /// name → (its twin, its node).
    pub more: Vec<(String, Proc, Proc)>,
}

pub fn rig(rcm_scale: &str) -> Rig {
    rig_with_db(rcm_scale, None)
}

/// The cell with the operator's database at `db` (default: in the temp dir).
pub fn rig_with_db(rcm_scale: &str, db: Option<PathBuf>) -> Rig {
    rig_in(TestCell::start(), rcm_scale, db)
}

/// The whole cell on the secure transport (QUIC, mutual TLS) on localhost.
pub fn rig_secure(rcm_scale: &str) -> Rig {
    rig_in(TestCell::start_secure(), rcm_scale, None)
}

/// The whole cell as separate hosts on the secure transport.
/// The welding workstation reaches the router through a delay line
/// (no delay until the test sets one).
pub fn rig_hosts(hosts: super::hosts::Hosts, rcm_scale: &str) -> Rig {
    let line = hosts.delay_line();
    rig_in_with(TestCell::start_hosts(hosts), rcm_scale, None, Some(line))
}

fn rig_in(cell: TestCell, rcm_scale: &str, db: Option<PathBuf>) -> Rig {
    rig_in_with(cell, rcm_scale, db, None)
}

/// The cell grown by the stanzas `extra` (TOML): every workstation of the
/// topology beyond `welding` and `transport` gets its twin and node; then
/// `recipes` may add to the recipe tree before the operator starts.
pub fn rig_grown(extra: &str, rcm_scale: &str, recipes: impl FnOnce(&std::path::Path)) -> Rig {
    let mut rig = assemble(TestCell::start_grown(extra), rcm_scale, None, None);
    let more: Vec<_> = rig
        .cell
        .topology
        .stations()
        .iter()
        .filter(|s| !["welding", "transport"].contains(&s.name.as_str()))
        .map(|s| (s.name.to_string(), s.kind))
        .collect();
    for (name, kind) in more {
        use falc_model::topology::StationKind;
        let (twin, node) = match kind {
            StationKind::Welding => {
                let (twin, path) = rig.cell.twin(
                    &name,
                    env!("CARGO_BIN_EXE_falc-rcm-sim"),
                    &["--time-scale", rcm_scale],
                    "serial port: ",
                );
                let node = rig.cell.start_node(
                    env!("CARGO_BIN_EXE_falc-welding"),
                    &name,
                    &["--device", &path],
                );
                (twin, node)
            }
            StationKind::Transport => {
                let (twin, address) = rig.cell.twin(
                    &name,
                    env!("CARGO_BIN_EXE_falc-plc-sim"),
                    &["--listen", "127.0.0.1:0", "--time-scale", "20"],
                    "listening on ",
                );
                let mut node = rig.cell.start_node(
                    env!("CARGO_BIN_EXE_falc-transport"),
                    &name,
                    &["--plc", &address],
                );
                node.expect_line("EVENT plc-ready", Duration::from_secs(10));
                (twin, node)
            }
            _ => continue,
        };
        rig.more.push((name, twin, node));
    }
    recipes(&rig.recipes);
    rig.start_operator();
    rig
}

fn rig_in_with(
    cell: TestCell,
    rcm_scale: &str,
    db: Option<PathBuf>,
    welding_line: Option<super::hosts::DelayLine>,
) -> Rig {
    let mut rig = assemble(cell, rcm_scale, db, welding_line);
    rig.start_operator();
    rig
}

/// The twins, the welding, transport and cell nodes: all but the operator.
fn assemble(
    cell: TestCell,
    rcm_scale: &str,
    db: Option<PathBuf>,
    welding_line: Option<super::hosts::DelayLine>,
) -> Rig {
    let (rcm, rcm_path) = cell.twin(
        "welding",
        env!("CARGO_BIN_EXE_falc-rcm-sim"),
        &["--time-scale", rcm_scale],
        "serial port: ",
    );
    let (plc, plc_address) = cell.twin(
        "transport",
        env!("CARGO_BIN_EXE_falc-plc-sim"),
        &["--listen", "127.0.0.1:0", "--time-scale", "20"],
        "listening on ",
    );
    let recipes = super::copy_recipes(cell.dir.path());
    let db = db.unwrap_or_else(|| cell.dir.path().join("var/falc.db"));
    let mut rig = Rig {
        rcm,
        plc,
        rcm_path,
        plc_address,
        welding: None,
        transport: None,
        cell_node: cell.start_node(env!("CARGO_BIN_EXE_falc-cell"), "cell", &[]),
        operator: None,
        recipes,
        db,
        cell,
        welding_line,
        more: Vec::new(),
    };
    rig.start_welding();
    rig.start_transport();
    rig
}

impl Rig {
    /// Starts the cell node again (after it was killed).
    pub fn start_cell(&mut self) {
        self.cell_node = self
            .cell
            .start_node(env!("CARGO_BIN_EXE_falc-cell"), "cell", &[]);
    }

    pub fn start_welding(&mut self) {
        let mut args = vec!["--device".to_string(), self.rcm_path.clone()];
        if let Some(line) = &self.welding_line {
            args.extend(["--router".to_string(), line.endpoint()]);
        }
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        self.welding = Some(self.cell.start_node(
            env!("CARGO_BIN_EXE_falc-welding"),
            "welding",
            &args,
        ));
    }

    pub fn start_transport(&mut self) {
        self.start_transport_with(&[]);
    }

    /// [`Self::start_transport`] with more arguments for `falc-transport`.
    pub fn start_transport_with(&mut self, more: &[&str]) {
        let mut args = vec!["--plc", &self.plc_address];
        args.extend_from_slice(more);
        let mut t = self
            .cell
            .start_node(env!("CARGO_BIN_EXE_falc-transport"), "transport", &args);
        t.expect_line("EVENT plc-ready", Duration::from_secs(10));
        self.transport = Some(t);
    }

    pub fn operator_command(&self) -> std::process::Command {
        let mut cmd = self
            .cell
            .command("operator", env!("CARGO_BIN_EXE_falc-operator"));
        cmd.arg("--recipes")
            .arg(&self.recipes)
            .arg("--db")
            .arg(&self.db)
            .arg("--topology")
            .arg(&self.cell.topology_path)
            .arg("--credentials-dir")
            .arg(self.cell.credentials_dir());
        cmd
    }

    /// Starts the operator node; returns once it delivered the recipes.
    pub fn start_operator(&mut self) {
        self.start_operator_with(&[]);
    }

    /// [`Self::start_operator`] with more arguments for `falc-operator`.
    pub fn start_operator_with(&mut self, args: &[&str]) {
        let mut cmd = self.operator_command();
        cmd.args(args);
        self.run_operator(Proc::spawn("operator", cmd));
    }

    /// [`Self::start_operator`] with the operator's log among its lines.
    pub fn start_operator_logged(&mut self) {
        self.run_operator(Proc::spawn_logged("operator", self.operator_command()));
    }

    fn run_operator(&mut self, mut p: Proc) {
        p.expect_line("EVENT ready", Duration::from_secs(20));
        p.expect_line("EVENT delivered recipe=PIPDROOG", Duration::from_secs(20));
        self.operator = Some(p);
    }

    pub fn operator(&mut self) -> &mut Proc {
        self.operator.as_mut().expect("operator running")
    }

    /// Queues `recipes` as orders, starts the list and answers `ja` until
    /// the first order is mid-weld.
    pub fn start_list_until_welding(&mut self, recipes: &[&str]) {
        for recipe in recipes {
            self.cell.falc(&["order", "add", recipe]);
        }
        self.cell.falc(&["start"]);
        self.until_welding();
    }

    /// Answers questions with `ja` until the robot starts its program (the
    /// twin receives `G`): the order is mid-weld.
    pub fn until_welding(&mut self) {
        wait_until("the weld started", Duration::from_secs(30), || {
            if let Some(line) = self.rcm.wait_line("rx G", Duration::ZERO) {
                return Ok(line);
            }
            let s = self.status();
            if s.question.is_some() {
                self.cell.falc(&["answer", "ja"]);
            }
            Err(Box::new(s))
        });
        // The running order says since when (`falc status --json`).
        let running = self.status().running;
        assert!(
            running.as_ref().is_some_and(|o| o.started_ms.is_some()),
            "the running order has no start time: {running:?}"
        );
    }

    /// What `falc --json ARGS` prints: the value itself (no reply variant
    /// around it).
    pub fn reply<T: serde::de::DeserializeOwned>(&self, args: &[&str]) -> T {
        let mut all = vec!["--json"];
        all.extend_from_slice(args);
        let text = self.cell.falc(&all);
        serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("{e}: {text}"))
    }

    pub fn status(&self) -> CellStatus {
        self.reply(&["status"])
    }

    /// Waits (10 s at most) until `falc status` shows `station` connected
    /// (`on`) or not.
    pub fn station_connected(&self, station: &str, on: bool) {
        let what = format!("{station} connected: {on}");
        wait_until(&what, Duration::from_secs(10), || {
            let s = self.status();
            let seen = s
                .stations
                .iter()
                .any(|v| v.name.as_str() == station && v.connected == on);
            holds(seen, || s.stations.clone())
        });
    }

    /// `falc store history STATION FILE`: each version's number, author
    /// and message.
    pub fn history(&self, station: &str, file: &str) -> Vec<(u32, String, String)> {
        let versions: Vec<falc_model::product::RecipeVersion> =
            self.reply(&["store", "history", station, file]);
        versions
            .into_iter()
            .map(|v| (v.version, v.author, v.message))
            .collect()
    }

    pub fn orders(&self) -> Vec<Order> {
        self.reply(&["order", "list"])
    }

    /// Asserts the orders of the list are in `states`, in order.
    pub fn orders_are(&self, states: &[falc_model::records::OrderState]) {
        let orders = self.orders();
        assert_eq!(
            orders.iter().map(|o| o.state).collect::<Vec<_>>(),
            states,
            "{orders:?}"
        );
    }

    pub fn journal(&self, order: Option<i64>) -> Vec<Entry> {
        let id = order.map(|o| o.to_string());
        let mut args = vec!["journal"];
        if let Some(id) = &id {
            args.extend(["--order", id]);
        }
        self.reply(&args)
    }

    /// Order `id`'s journal, checked: nothing the cell or a station said
    /// for it comes before "order `id` … started".
    pub fn journal_after_start(&self, id: i64) -> Vec<Entry> {
        let j = self.journal(Some(id));
        let started = j
            .iter()
            .position(|e| e.kind == EntryKind::Order && e.text.ends_with(" started"))
            .unwrap_or_else(|| panic!("order {id} has no start: {j:#?}"));
        let early: Vec<_> = j[..started]
            .iter()
            .filter(|e| {
                matches!(
                    e.kind,
                    EntryKind::Message | EntryKind::Question | EntryKind::Report
                )
            })
            .collect();
        assert!(early.is_empty(), "before order {id} started: {early:#?}");
        j
    }

    /// The documented way back after a fault, once its cause is cleared:
    /// the carriers set back where an order starts, `falc ack`, `falc
    /// start`, then the list worked with `ja`. Returns what start said.
    pub fn way_back(&mut self) -> String {
        self.plc.control("layout W2 W2");
        self.cell.falc(&["ack"]);
        let out = self.cell.falc(&["start"]);
        self.work_list("ja", Duration::from_secs(120));
        out
    }

    /// The way back after a conveyor fault as docs/operation.md gives it:
    /// once the conveyor stands still (what the maintainer sees: no
    /// carrier on a line), `ack`; the cell in maintenance mode; `falc
    /// manual transport goto home` (asked again while a line still runs
    /// out), run to its end; back to auto; `start`, the list worked with
    /// `ja`.
    pub fn way_back_by_goto(&mut self) {
        wait_until("the conveyor still", Duration::from_secs(30), || {
            self.plc.control("show");
            let carriers = self.plc.take_line("carriers: ", Duration::from_secs(5));
            holds(!carriers.contains('>'), || carriers)
        });
        self.cell.falc(&["ack"]);
        self.cell.falc(&["mode", "maintenance"]);
        wait_until("goto home taken", Duration::from_secs(30), || {
            let (code, out) = self
                .cell
                .falc_as("maintainer", &["manual", "transport", "goto", "home"]);
            holds(code == 0, || out)
        });
        self.transport
            .as_mut()
            .expect("transport node")
            .expect_line(
                "EVENT job program=GOTO_HOME event=Done",
                Duration::from_secs(120),
            );
        wait_until("falc status shows home", Duration::from_secs(5), || {
            let status = self.cell.falc(&["status"]);
            holds(status.contains(", equipment: home"), || status)
        });
        self.cell.falc(&["mode", "auto"]);
        self.cell.falc(&["start"]);
        self.work_list("ja", Duration::from_secs(120));
    }

    /// The way back once a node was started again: `ack` and `start`,
    /// repeated while it reassociates (30 s at most), then the list worked
    /// with `ja`; its last order must end done, none left running. Returns
    /// the orders.
    pub fn start_again_until_done(&self) -> Vec<Order> {
        self.ack_until_started();
        self.work_list("ja", Duration::from_secs(120));
        let orders = self.last_order_done();
        assert!(
            orders
                .iter()
                .all(|o| o.state != falc_model::records::OrderState::Running),
            "{orders:?}"
        );
        orders
    }

    /// `ack` and `start`, repeated until the start is taken (30 s at
    /// most: a node started again reassociates, an alarm's cause clears).
    pub fn ack_until_started(&self) {
        wait_until("start taken", Duration::from_secs(30), || {
            self.cell.falc(&["ack"]);
            let (code, out) = self.cell.falc_as("console", &["start"]);
            holds(code == 0, || out)
        });
    }

    /// The way forward after any way back: `recipe` queued, the list
    /// started and worked with `ja`; the order must end done.
    pub fn next_order_done(&self, recipe: &str) {
        self.cell.falc(&["order", "add", recipe]);
        self.cell.falc(&["start"]);
        self.work_list("ja", Duration::from_secs(120));
        self.last_order_done();
    }

    /// The orders, the last of which must be done.
    pub fn last_order_done(&self) -> Vec<Order> {
        let orders = self.orders();
        assert_eq!(
            orders.last().map(|o| o.state),
            Some(falc_model::records::OrderState::Done),
            "{orders:?}"
        );
        orders
    }

    /// The robot's line plugged in again after a silence mid-program:
    /// the program nobody watched meanwhile is stopped (`rx H` at the
    /// twin), and the line's alarm `alarm` clears once the robot answers.
    pub fn replug_until_cleared(&mut self, alarm: i64) {
        use falc_model::alarm::AlarmState;
        self.rcm.forget("rx H");
        self.rcm.control("replug");
        self.rcm.expect_line("rx H", Duration::from_secs(15));
        self.until_status(Duration::from_secs(15), "the line's alarm cleared", |s| {
            s.alarms
                .iter()
                .any(|x| x.id == alarm && x.state() == AlarmState::Cleared)
        });
    }

    /// How often the journal says order `id` started.
    pub fn starts(&self, id: i64) -> usize {
        let needle = format!("order {id} (");
        self.journal(Some(id))
            .iter()
            .filter(|e| e.kind == EntryKind::Order && e.text.starts_with(&needle))
            .filter(|e| e.text.ends_with(") started"))
            .count()
    }

    /// Waits until `pred` holds for the status, or fails with the last one.
    pub fn until_status(
        &self,
        within: Duration,
        what: &str,
        pred: impl Fn(&CellStatus) -> bool,
    ) -> CellStatus {
        wait_until(what, within, || {
            let s = self.status();
            if pred(&s) {
                Ok(s)
            } else {
                Err(Box::new(s))
            }
        })
    }

    /// Plays the operator through the CLI until the list stops running:
    /// answers every question with `answer`. Returns the questions seen.
    pub fn work_list(&self, answer: &str, within: Duration) -> Vec<String> {
        let mut questions = Vec::new();
        wait_until("the list ended", within, || {
            let s = self.status();
            if let Some(q) = &s.question {
                questions.push(q.clone());
                self.cell.falc(&["answer", answer]);
                return Err(Box::new(s));
            }
            holds(s.list != ListState::Running && s.running.is_none(), || s)
        });
        questions
    }
}
