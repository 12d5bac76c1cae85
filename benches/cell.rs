//! Whole-cell benchmark, through `falc-launch` (release binaries): router,
//! both twins, both workstations, cell and operator on this machine.
//!
//! Prints:
//! - start-up time of the all-in-one cell to ready (spawn → operator
//!   associated with the cell and every recipe delivered), median of runs;
//! - control overhead per recipe step, p50/p99: the time between two
//!   consecutive `output` steps of dikdroog (states 1→5), each one cell
//!   engine step, an Output request to the operator, its journal entry
//!   (SQLite, synchronous FULL) and the confirm;
//! - the hand-over between workstation jobs, p50/p99: STORE done at the
//!   transport → MOVE_TO_MAN's first coil write at the PLC twin (a cell
//!   `wait` step, a cell `start` step, a transport `activate` step, the
//!   Modbus write);
//! - a dikdroog order's wall time next to the twins' simulated time (the
//!   union of the intervals in which a carrier moved or the robot welded),
//!   and what is left: control plus operator answers (the bench answers
//!   each question as soon as it sees it);
//! - each node's idle CPU and RSS after the orders, then the operator's,
//!   the router's and the TUI's with one `falc tui` open (if tmux is
//!   installed).
//!
//! - first, in process on the controller core: a transport Start run to
//!   its end with its `#PRE` and `#POST` evaluated, next to the same
//!   recipe without them, p50 per start and the ratio (interleaved, one
//!   run).
//!
//! Run: `cargo bench --bench cell`. Prints figures; asserts nothing about
//! time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/support/mod.rs"]
mod support;

use falc_bus::credentials;
use falc_bus::{Bus, BusSettings};
use falc_model::api::ApiRequest;
use falc_model::ids::{CellId, StationName};
use falc_model::keys::KeySpace;
use std::io::{BufRead, BufReader};
use std::process::{Child, Stdio};
use std::sync::mpsc::{channel, Receiver};
use std::time::{Duration, Instant};
use support::stats::{cpu_ticks, median, percentile, rss_mib, tail};
use support::{children, launcher};

const SCALE: &str = "100";
const ORDERS: usize = 10;
const STARTS: usize = 5;

struct Launched {
    dir: tempfile::TempDir,
    child: Child,
    lines: Receiver<(Instant, String)>,
    spawned: Instant,
    endpoint: String,
}

impl Drop for Launched {
    fn drop(&mut self) {
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(self.child.id() as i32),
            nix::sys::signal::Signal::SIGINT,
        );
        let _ = self.child.wait();
    }
}

fn launch() -> Launched {
    let dir = tempfile::tempdir().expect("tempdir");
    let (mut cmd, endpoint) = launcher(dir.path(), SCALE);
    let spawned = Instant::now();
    let mut child = cmd
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .env("RUST_LOG", "warn")
        .spawn()
        .expect("falc-launch");
    let (tx, lines) = channel();
    let out = child.stdout.take().expect("stdout");
    std::thread::spawn(move || {
        for l in BufReader::new(out).lines().map_while(Result::ok) {
            if tx.send((Instant::now(), l)).is_err() {
                break;
            }
        }
    });
    Launched {
        dir,
        child,
        lines,
        spawned,
        endpoint,
    }
}

impl Launched {
    fn until(&self, needle: &str) -> Instant {
        loop {
            match self.lines.recv_timeout(Duration::from_secs(60)) {
                Ok((t, l)) if l.contains(needle) => return t,
                Ok(_) => {}
                Err(e) => panic!("no `{needle}`: {e}"),
            }
        }
    }

    async fn console(&self) -> Bus {
        let creds = credentials::load(&self.dir.path().join("credentials/console.toml"))
            .expect("console credentials");
        Bus::open(BusSettings {
            keys: KeySpace::new(CellId::new("falc1").expect("valid")),
            me: StationName::new("console").expect("valid"),
            endpoint: self.endpoint.clone(),
            lease: Duration::from_secs(1),
            credentials: Some(creds),
            tls: None,
            connect_timeout: Duration::from_secs(5),
        })
        .await
        .expect("console session")
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

/// Length of the union of intervals.
fn union(mut v: Vec<(Instant, Instant)>) -> Duration {
    v.sort_by_key(|i| i.0);
    let mut total = Duration::ZERO;
    let mut cur: Option<(Instant, Instant)> = None;
    for (a, b) in v {
        cur = match cur {
            Some((s, e)) if a <= e => Some((s, e.max(b))),
            Some((s, e)) => {
                total += e - s;
                Some((a, b))
            }
            None => Some((a, b)),
        };
    }
    if let Some((s, e)) = cur {
        total += e - s;
    }
    total
}

/// A conveyor as the controller core sees it: every input at the level
/// the conditions below need, every write taken at once.
struct Conveyor;

impl falc_control::controller::Device for Conveyor {
    fn handle(
        &mut self,
        _now: Duration,
        _what: falc_control::controller::Happening<'_>,
        _out: &mut Vec<falc_recipe::engine::Event>,
    ) {
    }
    fn unavailable(&self) -> Option<String> {
        None
    }
    fn status(&self, _status: &mut falc_model::mms::vmd::VmdStatus) {}
    fn observes(&self, fact: falc_recipe::condition::Fact) -> Option<bool> {
        use falc_recipe::check::Signal;
        use falc_recipe::condition::Fact;
        match fact {
            Fact::Signal(Signal::Place(p)) => Some(p.number() != 3),
            Fact::Signal(_) => Some(false),
            Fact::Robot(_) => None,
        }
    }
}

/// p50 of a Start run to done on the controller core (with the status
/// published after it, as the node does), for `recipe` named PARK.
fn starts_p50(with: &str, without: &str, n: usize) -> (f64, f64) {
    use falc_control::controller::Controller;
    use falc_model::ids::ObjectName;
    use falc_model::mms::delivery::{Delivery, DeliveryStep};
    use falc_model::mms::pdu::Request;
    use falc_recipe::commands::RecipeKind;
    let controller = |text: &str| {
        let mut c = Controller::new(RecipeKind::Transport, Duration::from_secs(5), Conveyor);
        let name = ObjectName::new("park").expect("name");
        let me = StationName::new("transport").expect("station");
        let mut d = Delivery::new(me, name, text.as_bytes(), true);
        let mut step = d.start();
        while let DeliveryStep::Send(req) = step {
            step = d.answered(c.handle_request(Duration::ZERO, &req));
        }
        assert_eq!(step, DeliveryStep::Done(Ok(())), "delivered");
        c
    };
    let (mut a, mut b) = (controller(with), controller(without));
    let start = Request::Start {
        name: ObjectName::new("park").expect("name"),
        argument: "order 1".into(),
    };
    let run = |c: &mut Controller<Conveyor>, told: &mut Option<_>| {
        let t = Instant::now();
        c.handle_request(Duration::ZERO, &start).expect("started");
        while c.poll_output().is_some() {}
        c.publications(told);
        assert!(!c.is_running(), "ran to its end");
        t.elapsed().as_secs_f64() * 1e6
    };
    let (mut ta, mut tb) = (None, None);
    let (mut va, mut vb) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for _ in 0..n {
        va.push(run(&mut a, &mut ta));
        vb.push(run(&mut b, &mut tb));
    }
    (median(&va), median(&vb))
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    // 0. A start with its conditions evaluated, next to one without.
    let body = "-1 | activate k | | | 2\n-2 | reset k | | | 3\n-3 | activate l | | | 4\n-4 | reset l | | | 0\n";
    let with = format!(
        "#PARK\n#PRE place 2 occupied, place 3 empty, line K stopped\n#POST place 2 occupied\n{body}"
    );
    let without = format!("#PARK\n{body}");
    let (p_with, p_without) = starts_p50(&with, &without, 20_000);
    println!(
        "a transport Start run to its end on the controller core (4 steps, status published): with #PRE (3 terms) and #POST evaluated p50 {p_with:.2} µs, without {p_without:.2} µs; ratio {:.3}; per step {:.2} µs vs {:.2} µs (n=20000 each, interleaved; goal: within 5 %)",
        p_with / p_without,
        p_with / 4.0,
        p_without / 4.0
    );

    // 1. Start-up to ready.
    let mut starts = Vec::new();
    for _ in 0..STARTS {
        let l = launch();
        let t = l.until("falc-launch: cell ready in");
        starts.push(ms(t - l.spawned));
    }
    println!(
        "start-up of the all-in-one cell to ready (router, 2 twins, 2 workstations, cell, operator; recipes delivered): median {:.0} ms, max {:.0} ms (n={STARTS}; goal ≤ 3000 ms)",
        median(&starts),
        percentile(&starts, 1.0)
    );

    // 2. Orders.
    let l = launch();
    l.until("falc-launch: cell ready in");
    let bus = l.console().await;
    let operator = StationName::new("operator").expect("valid");
    let api = |r: ApiRequest| {
        let bus = bus.clone();
        let operator = operator.clone();
        async move {
            bus.api(&operator, r, Duration::from_secs(10))
                .await
                .expect("API call")
        }
    };
    for _ in 0..ORDERS {
        api(ApiRequest::order_add("dikdroog")).await;
    }
    let mut steps = Vec::new();
    let mut handovers = Vec::new();
    let mut walls = Vec::new();
    let mut busy = Vec::new();
    api(ApiRequest::Start).await;
    for n in 1..=ORDERS {
        let begin = l.until(&format!("EVENT order-started id={n}"));
        let mut outputs: Vec<Instant> = Vec::new();
        let mut moving: std::collections::BTreeMap<String, Instant> = Default::default();
        let mut intervals = Vec::new();
        let mut weld: Option<Instant> = None;
        let mut transport_done: Option<Instant> = None;
        let end = loop {
            let (t, line) = l.lines.recv_timeout(Duration::from_secs(60)).expect("line");
            if line.contains("JOURNAL") && line.contains(" message cell:") && outputs.len() < 5 {
                outputs.push(t);
            } else if line.contains("EVENT question") {
                api(ApiRequest::Answer { text: "ja".into() }).await;
            } else if let Some(rest) = line.split("] carrier ").nth(1) {
                let carrier = rest.split(' ').next().unwrap_or("?").to_string();
                if rest.contains(" leaves ") {
                    moving.insert(carrier, t);
                } else if rest.contains(" at ") {
                    if let Some(s) = moving.remove(&carrier) {
                        intervals.push((s, t));
                    }
                }
            } else if line.contains("rx G") {
                weld = Some(t);
            } else if line.contains("[welding  ] EVENT job") && line.contains("Done") {
                if let Some(s) = weld.take() {
                    intervals.push((s, t));
                }
            } else if line.contains("[transport] EVENT job program=STORE event=Done") {
                // dikdroog starts MOVE_TO_MAN right after STORE (states 10, 11).
                transport_done = Some(t);
            } else if line.contains("coil button line")
                && (line.ends_with(" 1") || line.contains(" 1 reaction"))
            {
                if let Some(d) = transport_done.take() {
                    handovers.push(ms(t - d));
                }
            } else if line.contains(&format!("EVENT order-ended id={n}")) {
                assert!(line.contains("state=done"), "{line}");
                break t;
            }
        };
        steps.extend(outputs.windows(2).map(|w| ms(w[1] - w[0])));
        walls.push(ms(end - begin));
        busy.push(ms(union(intervals)));
    }
    let (st_name, st_tail) = tail(&steps);
    println!(
        "control overhead per recipe step (cell output step: engine → Output → operator journal → confirm): p50 {:.2} ms, {st_name} {st_tail:.2} ms (n={}; goal p50 ≤ 2 ms)",
        median(&steps),
        steps.len()
    );
    let (ho_name, ho_tail) = tail(&handovers);
    println!(
        "hand-over between workstation jobs (STORE done → MOVE_TO_MAN's first coil write at the PLC): p50 {:.2} ms, {ho_name} {ho_tail:.2} ms (n={})",
        median(&handovers),
        handovers.len()
    );
    let (w50, b50) = (median(&walls), median(&busy));
    println!(
        "dikdroog order at time scale {SCALE}: wall time median {w50:.0} ms; twins' simulated time (carriers moving or robot welding) median {b50:.0} ms; ratio {:.2}; the rest ({:.0} ms) is recipe steps, PLC polling and the bench's answers (n={ORDERS})",
        w50 / b50,
        w50 - b50
    );

    // 3. Idle.
    tokio::time::sleep(Duration::from_secs(2)).await;
    let nodes = children(l.child.id());
    let ticks: Vec<u64> = nodes.iter().map(|(p, _)| cpu_ticks(*p)).collect();
    let window = Duration::from_secs(10);
    tokio::time::sleep(window).await;
    // /proc reports CPU time in USER_HZ ticks, 100 per second on Linux.
    let hz = 100.0;
    let (mut cpu_total, mut rss_total) = (0.0, 0.0);
    println!(
        "idle, {} s after the orders, over {} s:",
        2,
        window.as_secs()
    );
    for ((pid, name), t0) in nodes.iter().zip(ticks) {
        let cpu = (cpu_ticks(*pid).saturating_sub(t0)) as f64 / hz / window.as_secs_f64() * 100.0;
        let rss = rss_mib(*pid);
        cpu_total += cpu;
        rss_total += rss;
        println!("  {name:<16} CPU {cpu:5.2} %  RSS {rss:6.1} MiB");
    }
    println!(
        "  all {} nodes      CPU {cpu_total:5.2} %  RSS {rss_total:6.1} MiB (goals < 2 %, ≤ 150 MB)",
        nodes.len()
    );
    tui_load(&l, &nodes, window);
}

/// The same window with one `falc tui` open (in tmux, if installed): what
/// a console costs the operator and the router, and the TUI itself.
fn tui_load(l: &Launched, nodes: &[(u32, String)], window: Duration) {
    let socket = format!("falc-bench-{}", std::process::id());
    let tmux = |args: &[&str]| {
        std::process::Command::new("tmux")
            .args(["-L", &socket])
            .args(args)
            .output()
    };
    let dir = l.dir.path();
    let command = format!(
        "exec {} --topology {} --credentials-dir {} tui",
        env!("CARGO_BIN_EXE_falc"),
        dir.join("cell.toml").display(),
        dir.join("credentials").display()
    );
    match tmux(&[
        "new-session",
        "-d",
        "-s",
        "b",
        "-x",
        "110",
        "-y",
        "34",
        &command,
    ]) {
        Ok(o) if o.status.success() => {}
        _ => {
            println!("with a falc tui open: not measured (tmux not installed)");
            return;
        }
    }
    std::thread::sleep(Duration::from_secs(2));
    let pane: Option<u32> = tmux(&["list-panes", "-t", "b", "-F", "#{pane_pid}"])
        .ok()
        .and_then(|o| String::from_utf8_lossy(&o.stdout).trim().parse().ok());
    let mut watched: Vec<(u32, String)> = nodes
        .iter()
        .filter(|(_, n)| n.contains("operator") || n.contains("router"))
        .cloned()
        .collect();
    if let Some(p) = pane {
        watched.push((p, "falc tui".into()));
    }
    let t0: Vec<u64> = watched.iter().map(|(p, _)| cpu_ticks(*p)).collect();
    std::thread::sleep(window);
    let hz = 100.0;
    println!(
        "with one falc tui open (status every 250 ms), over {} s:",
        window.as_secs()
    );
    for ((pid, name), t) in watched.iter().zip(t0) {
        let cpu = (cpu_ticks(*pid).saturating_sub(t)) as f64 / hz / window.as_secs_f64() * 100.0;
        println!(
            "  {name:<16} CPU {cpu:5.2} %  RSS {:6.1} MiB",
            rss_mib(*pid)
        );
    }
    let _ = tmux(&["kill-server"]);
}
