//! `falc-launch`: the whole cell on one machine. Starts, bottom-up, the
//! router, a digital twin per device (`falc-rcm-sim` on a pty for a welding
//! station, `falc-plc-sim` on Modbus TCP for a transport station), every
//! workstation, the cell and the operator, all from `launch/cell.toml`;
//! or a whole plant from `launch/factory.toml` (the factory router, then
//! each cell's router, twins and nodes, then the one operator);
//! prefixes each node's log lines with its name; says when the cell is
//! ready and how to operate it; routes `rcm …` / `plc …` lines typed on its
//! stdin to the twins' control interfaces; and stops everything (SIGTERM,
//! then SIGKILL after 3 s) on Ctrl-C, SIGTERM, or as soon as any node dies.
//!
//! `launch/run` builds the binaries and runs this; the one-node-per-PC
//! deployment uses the systemd units in `launch/systemd/` instead.

use anyhow::{bail, Context, Result};
use clap::Parser;
use falc_model::plant::{Layout, Plant};
use falc_model::topology::{StationKind, Topology};
use falc_node::say;
use std::path::{Path, PathBuf};
use std::process::{ExitCode, Stdio};
use std::time::{Duration, Instant};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::process::{Child, ChildStdin, Command};
use tokio::sync::mpsc::{unbounded_channel, UnboundedReceiver, UnboundedSender};

#[derive(Parser, Debug)]
#[command(
    version,
    about = "FALC all-in-one: router, twins, workstations, cell and operator on this machine"
)]
struct Cli {
    /// The cell topology, or a plant's (`launch/factory.toml`: the factory
    /// router, every cell's router, twins and nodes, one operator).
    #[arg(long, default_value = "launch/cell.toml")]
    topology: PathBuf,
    /// Directory of credential files (created by the router if missing).
    #[arg(long, default_value = "launch/credentials")]
    credentials_dir: PathBuf,
    /// The router endpoint; overrides the topology's `router`.
    #[arg(long)]
    router: Option<String>,
    /// The twins run this many times faster than the real cell.
    #[arg(long, default_value_t = 1.0)]
    time_scale: f64,
    /// The recipe tree the operator delivers.
    #[arg(long, default_value = "recipes")]
    recipes: PathBuf,
    /// The operator's order list and journal.
    #[arg(long, default_value = "var/falc.db")]
    db: PathBuf,
    /// Where the FALC binaries are; default: next to this one.
    #[arg(long)]
    bin_dir: Option<PathBuf>,
    /// Modbus address for the first transport station's twin (default: its
    /// topology `device` when that is a host:port; another transport
    /// station's twin listens at its own device, else at a free port).
    #[arg(long)]
    plc_listen: Option<String>,
    /// Also start the OPC UA gateway (`falc-opcua`, console user `opcua`),
    /// listening at this host:port (`127.0.0.1:4840`); in a plant it
    /// serves the plant and each of its cells.
    #[arg(long)]
    opcua: Option<String>,
}

/// A line from a child, for the launcher's loop.
enum Line {
    Out(usize, String),
    Exited(usize, String),
}

struct Node {
    name: String,
    child: Child,
    stdin: Option<ChildStdin>,
}

/// Everything started so far; stopped in reverse order.
struct Cell {
    nodes: Vec<Node>,
    tx: UnboundedSender<Line>,
    rx: UnboundedReceiver<Line>,
    bin_dir: PathBuf,
}

impl Cell {
    fn spawn(&mut self, name: &str, bin: &str, args: &[String]) -> Result<usize> {
        let path = self.bin_dir.join(bin);
        let mut command = Command::new(&path);
        // If the launcher dies without stopping the cell (SIGKILL, a crash),
        // each node gets SIGTERM and stops safely instead of running on
        // without its launcher. The launcher runs on one thread (the one
        // that forks), so "parent died" means the launcher died.
        let launcher = nix::unistd::getpid();
        // SAFETY: the closure runs in the child between fork and exec and
        // makes only async-signal-safe system calls (prctl, getppid).
        unsafe {
            command.pre_exec(move || {
                nix::sys::prctl::set_pdeathsig(nix::sys::signal::Signal::SIGTERM)
                    .map_err(std::io::Error::from)?;
                // The launcher died before the signal was armed.
                if nix::unistd::getppid() != launcher {
                    return Err(std::io::Error::other("falc-launch is gone"));
                }
                Ok(())
            });
        }
        // A process group of its own: Ctrl-C in the terminal reaches the
        // launcher alone, which then stops the nodes top-down (the
        // transport leaves the conveyor safe while its PLC twin still runs).
        let mut child = command
            .args(args)
            .process_group(0)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .kill_on_drop(true)
            .spawn()
            .with_context(|| {
                format!(
                    "cannot start {} (build it first: launch/run does)",
                    path.display()
                )
            })?;
        let id = self.nodes.len();
        for stream in [
            child
                .stdout
                .take()
                .map(|s| Box::new(s) as Box<dyn tokio::io::AsyncRead + Unpin + Send>),
            child
                .stderr
                .take()
                .map(|s| Box::new(s) as Box<dyn tokio::io::AsyncRead + Unpin + Send>),
        ]
        .into_iter()
        .flatten()
        {
            let tx = self.tx.clone();
            tokio::spawn(async move {
                let mut lines = BufReader::new(stream).lines();
                while let Ok(Some(l)) = lines.next_line().await {
                    let _ = tx.send(Line::Out(id, l));
                }
            });
        }
        self.nodes.push(Node {
            name: name.to_string(),
            stdin: child.stdin.take(),
            child,
        });
        Ok(id)
    }

    /// Prints lines until one from node `id` contains `needle`; returns it.
    /// Fails if any node exits meanwhile or nothing comes within `limit`.
    async fn wait_for(&mut self, id: usize, needle: &str, limit: Duration) -> Result<String> {
        let end = tokio::time::Instant::now() + limit;
        loop {
            self.check_exits();
            let line = tokio::time::timeout_at(end, self.next_line()).await;
            match line {
                Err(_) => bail!(
                    "{} did not say `{needle}` within {limit:?}",
                    self.nodes[id].name
                ),
                Ok(Line::Exited(who, status)) => {
                    bail!("{} stopped: {status}", self.nodes[who].name)
                }
                Ok(Line::Out(who, text)) => {
                    let hit = who == id && text.contains(needle);
                    self.print(who, &text);
                    if hit {
                        return Ok(text);
                    }
                }
            }
        }
    }

    fn print(&self, who: usize, text: &str) {
        say(&format!("[{:<9}] {text}", self.nodes[who].name));
    }

    fn check_exits(&mut self) {
        for (i, n) in self.nodes.iter_mut().enumerate() {
            if let Ok(Some(status)) = n.child.try_wait() {
                let _ = self.tx.send(Line::Exited(i, status.to_string()));
            }
        }
    }

    async fn next_line(&mut self) -> Line {
        loop {
            tokio::select! {
                l = self.rx.recv() => if let Some(l) = l { return l },
                _ = tokio::time::sleep(Duration::from_millis(200)) => self.check_exits(),
            }
        }
    }

    /// Sends a control line to the first node whose name starts with `to`.
    async fn control(&mut self, to: &str, line: &str) -> bool {
        let Some(n) = self.nodes.iter_mut().find(|n| n.name.starts_with(to)) else {
            return false;
        };
        match n.stdin.as_mut() {
            Some(s) => s.write_all(format!("{line}\n").as_bytes()).await.is_ok(),
            None => false,
        }
    }

    /// Stops the nodes top-down (newest first: operator, cell, workstations,
    /// twins, router), each with SIGTERM and 3 s to go before SIGKILL, so
    /// each can still conclude with the ones below it.
    async fn stop(&mut self) {
        for n in self.nodes.iter_mut().rev() {
            if let Some(pid) = n.child.id().and_then(|p| i32::try_from(p).ok()) {
                let _ = nix::sys::signal::kill(
                    nix::unistd::Pid::from_raw(pid),
                    nix::sys::signal::Signal::SIGTERM,
                );
            }
            if tokio::time::timeout(Duration::from_secs(3), n.child.wait())
                .await
                .is_err()
            {
                let _ = n.child.kill().await;
            }
        }
        // What the nodes said while stopping.
        while let Ok(l) = self.rx.try_recv() {
            if let Line::Out(who, text) = l {
                self.print(who, &text);
            }
        }
    }
}

fn node_args(cli: &Cli, topology_path: &Path, station: &str, router: &str) -> Vec<String> {
    vec![
        "--station".into(),
        station.into(),
        "--topology".into(),
        topology_path.display().to_string(),
        "--credentials-dir".into(),
        cli.credentials_dir.display().to_string(),
        "--router".into(),
        router.into(),
    ]
}

async fn start(cli: &Cli, cell: &mut Cell) -> Result<Duration> {
    match Layout::load(&cli.topology)? {
        Layout::Cell(_) => start_cell(cli, cell).await,
        Layout::Plant(plant) => start_plant(cli, cell, &plant).await,
    }
}

async fn start_cell(cli: &Cli, cell: &mut Cell) -> Result<Duration> {
    let t0 = Instant::now();
    let mut topology = Topology::load(&cli.topology)?;
    if let Some(r) = &cli.router {
        topology.set_router(r.clone());
    }
    let router = topology.router().to_string();
    let listen = router.clone();
    let id = cell.spawn(
        "router",
        "falc-router",
        &[
            "--topology".into(),
            cli.topology.display().to_string(),
            "--credentials-dir".into(),
            cli.credentials_dir.display().to_string(),
            "run".into(),
            "--listen".into(),
            listen,
        ],
    )?;
    cell.wait_for(id, "falc-router ready", Duration::from_secs(20))
        .await?;
    let args = |station: &str| node_args(cli, &cli.topology, station, &router);
    let mut plc_taken = false;
    start_stations(cli, cell, &topology, "", &args, &mut plc_taken).await?;
    start_operator(cli, cell, &args("operator"), 1).await?;
    start_opcua(cli, cell, Some(&router)).await?;
    Ok(t0.elapsed())
}

/// Starts the OPC UA gateway when `--opcua` asks for it (for the cell, or
/// the plant and each of its cells), logging in at `router` (None: the
/// topology's).
async fn start_opcua(cli: &Cli, cell: &mut Cell, router: Option<&str>) -> Result<()> {
    let Some(listen) = &cli.opcua else {
        return Ok(());
    };
    let mut args = vec![
        "--topology".to_string(),
        cli.topology.display().to_string(),
        "--credentials-dir".into(),
        cli.credentials_dir.display().to_string(),
        "--listen".into(),
        listen.clone(),
    ];
    if let Some(router) = router {
        args.extend(["--router".to_string(), router.to_string()]);
    }
    let id = cell.spawn("opcua", "falc-opcua", &args)?;
    cell.wait_for(id, "EVENT ready", LIMIT).await?;
    Ok(())
}

/// How long a node may take to say it is ready.
const LIMIT: Duration = Duration::from_secs(30);

/// A plant (`launch/factory.toml`): the factory router, then per cell its
/// router, twins, workstations and cell controller (named `<cell>/<station>`,
/// twins `rcm-<cell>-<station>`, `plc-<cell>-<station>`), then the operator
/// of every cell.
async fn start_plant(cli: &Cli, cell: &mut Cell, plant: &Plant) -> Result<Duration> {
    let t0 = Instant::now();
    if cli.router.is_some() {
        bail!("--router takes one cell's topology, not a plant's");
    }
    let plant_args = |more: &[&str]| -> Vec<String> {
        let mut v = vec![
            "--plant".to_string(),
            cli.topology.display().to_string(),
            "--credentials-dir".into(),
            cli.credentials_dir.display().to_string(),
            "run".into(),
        ];
        v.extend(more.iter().map(|s| s.to_string()));
        v
    };
    let id = cell.spawn("router", "falc-router", &plant_args(&[]))?;
    cell.wait_for(id, "falc-router ready", Duration::from_secs(20))
        .await?;
    let mut plc_taken = false;
    for c in plant.cells() {
        let cid = c.id().as_str();
        let id = cell.spawn(
            &format!("router-{cid}"),
            "falc-router",
            &plant_args(&["--cell", cid]),
        )?;
        cell.wait_for(id, "falc-router ready", Duration::from_secs(20))
            .await?;
        let args = |station: &str| {
            vec![
                "--station".to_string(),
                station.into(),
                "--cell".into(),
                cid.into(),
                "--topology".into(),
                cli.topology.display().to_string(),
                "--credentials-dir".into(),
                cli.credentials_dir.display().to_string(),
            ]
        };
        start_stations(cli, cell, c.topology(), cid, &args, &mut plc_taken).await?;
    }
    let operator = plant.operator().name.as_str();
    let args = vec![
        "--station".to_string(),
        operator.into(),
        "--topology".into(),
        cli.topology.display().to_string(),
        "--credentials-dir".into(),
        cli.credentials_dir.display().to_string(),
    ];
    start_operator(cli, cell, &args, plant.cells().len()).await?;
    start_opcua(cli, cell, None).await?;
    Ok(t0.elapsed())
}

/// Starts the operator with `args` and waits until each of its `cells`
/// is ready (associated, recipes delivered).
async fn start_operator(cli: &Cli, cell: &mut Cell, args: &[String], cells: usize) -> Result<()> {
    let mut args = args.to_vec();
    args.extend([
        "--recipes".into(),
        cli.recipes.display().to_string(),
        "--db".into(),
        cli.db.display().to_string(),
    ]);
    let id = cell.spawn("operator", "falc-operator", &args)?;
    cell.wait_for(id, "EVENT ready", LIMIT).await?;
    for _ in 0..cells {
        cell.wait_for(id, "EVENT cell-ready", LIMIT).await?;
    }
    Ok(())
}

/// Starts the workstations of `topology` (each with its twin), then its
/// cell controller; names are prefixed with `prefix/` in a plant.
async fn start_stations(
    cli: &Cli,
    cell: &mut Cell,
    topology: &Topology,
    prefix: &str,
    node_args: &dyn Fn(&str) -> Vec<String>,
    plc_taken: &mut bool,
) -> Result<()> {
    let scale = cli.time_scale.to_string();
    let named = |name: &str| {
        if prefix.is_empty() {
            name.to_string()
        } else {
            format!("{prefix}/{name}")
        }
    };
    let twin = |kind: &str, name: &str| {
        if prefix.is_empty() {
            format!("{kind}-{name}")
        } else {
            format!("{kind}-{prefix}-{name}")
        }
    };
    // Workstations (with their twins) first, then the cell.
    for kind in [
        StationKind::Welding,
        StationKind::Transport,
        StationKind::Cell,
    ] {
        for st in topology.stations().iter().filter(|s| s.kind == kind) {
            let name = st.name.as_str();
            let mut args = node_args(name);
            let bin = match kind {
                StationKind::Welding => {
                    let id = cell.spawn(
                        &twin("rcm", name),
                        "falc-rcm-sim",
                        &["--time-scale".into(), scale.clone()],
                    )?;
                    let line = cell.wait_for(id, "serial port: ", LIMIT).await?;
                    let port = line.rsplit(' ').next().unwrap_or_default().to_string();
                    args.extend(["--device".into(), port]);
                    "falc-welding"
                }
                StationKind::Transport => {
                    // `--plc-listen` is the first transport station's; a
                    // second one listens at its own device, else anywhere.
                    let first = !*plc_taken;
                    *plc_taken = true;
                    let own = st
                        .device
                        .clone()
                        .filter(|d| d.parse::<std::net::SocketAddr>().is_ok());
                    let at = if first {
                        cli.plc_listen.clone().or(own)
                    } else {
                        own
                    }
                    .unwrap_or_else(|| "127.0.0.1:0".into());
                    // The twin plays the station's equipment file (the
                    // node reads the same stanza).
                    let mut plc_args =
                        vec!["--listen".into(), at, "--time-scale".into(), scale.clone()];
                    if let Some(e) = &st.equipment {
                        plc_args.extend(["--equipment".into(), e.display().to_string()]);
                    }
                    let id = cell.spawn(&twin("plc", name), "falc-plc-sim", &plc_args)?;
                    let line = cell.wait_for(id, "listening on ", LIMIT).await?;
                    let address = line.rsplit(' ').next().unwrap_or_default().to_string();
                    args.extend(["--plc".into(), address]);
                    "falc-transport"
                }
                StationKind::Cell => "falc-cell",
                StationKind::Operator => continue,
            };
            let id = cell.spawn(&named(name), bin, &args)?;
            cell.wait_for(id, "EVENT ready", LIMIT).await?;
        }
    }
    Ok(())
}

/// How to operate the launched plant: the consoles take the plant file,
/// and `--cell C` for one cell.
fn plant_help(bin_dir: &Path, topology: &Path) -> String {
    let falc = bin_dir.join("falc");
    let (falc, plant) = (falc.display(), topology.display());
    format!(
        "\
operate the plant from another terminal (in this directory):
  {falc} --topology {plant} status             every cell at a glance
  {falc} --topology {plant} order add dikdroog --count 3
  {falc} --topology {plant} start              every cell takes orders
  {falc} --topology {plant} --cell falc2 answer ja
  {falc} --topology {plant} --cell falc2 tui   one cell's screens
type here to disturb a cell's twins: `rcm-falc2 estop`, `plc-falc2 show` …;
Ctrl-C stops the plant."
    )
}

/// How to operate the launched cell, with the console next to this binary.
fn help(bin_dir: &Path) -> String {
    let falc = bin_dir.join("falc");
    let falc = falc.display();
    format!(
        "\
operate it from another terminal (in this directory):
  {falc} tui                the operator's screens (F1 overview, F2 messages,
                            F3 commands, F4 recipe; q quits)
  {falc} status             the cell at a glance (--watch to follow)
  {falc} order add dikdroog  (also dundroog, pipdroog)
  {falc} start              work through the order list
  {falc} messages --follow
  {falc} answer ja          answer the cell's question
  {falc} ack                acknowledge an alarm
  {falc} journal
  {falc} shutdown           stop when the order list is done
  {falc} --user engineer store edit transport store   edit a recipe
type here to disturb the twins: `rcm estop`, `rcm estop-clear`, `plc jam K`,
`plc unjam K`, `plc show`, `plc layout W2 W2` … (`rcm-welding2 estop`,
`plc-transport2 show` for a second station's); Ctrl-C stops the cell."
    )
}

// One thread: the nodes' parent-death signal follows the thread that forked
// them, which must live as long as the launcher.
#[tokio::main(flavor = "current_thread")]
async fn main() -> ExitCode {
    falc_node::init_tracing();
    let cli = Cli::parse();
    let bin_dir = match cli.bin_dir.clone().or_else(|| {
        std::env::current_exe()
            .ok()
            .and_then(|p| p.parent().map(Path::to_path_buf))
    }) {
        Some(d) => d,
        None => {
            eprintln!("falc-launch: cannot tell where the binaries are; give --bin-dir");
            return ExitCode::FAILURE;
        }
    };
    let (tx, rx) = unbounded_channel();
    let mut cell = Cell {
        nodes: Vec::new(),
        tx,
        rx,
        bin_dir,
    };
    let code = run(&cli, &mut cell).await;
    cell.stop().await;
    say("falc-launch: every node stopped");
    code
}

async fn run(cli: &Cli, cell: &mut Cell) -> ExitCode {
    let mut shutdown = falc_node::Shutdown::new();
    let started = tokio::select! {
        r = start(cli, cell) => r,
        _ = shutdown.requested() => return ExitCode::SUCCESS,
    };
    match started {
        Ok(took) => {
            let plant = matches!(Layout::load(&cli.topology), Ok(Layout::Plant(_)));
            say(&format!(
                "falc-launch: {} ready in {} ms (time scale {})",
                if plant { "plant" } else { "cell" },
                took.as_millis(),
                cli.time_scale
            ));
            let help = if plant {
                plant_help(&cell.bin_dir, &cli.topology)
            } else {
                help(&cell.bin_dir)
            };
            // One `say` a line: `say` escapes line breaks.
            for line in help.lines() {
                say(line);
            }
        }
        Err(e) => {
            say(&format!("falc-launch: the cell did not start: {e:#}"));
            return ExitCode::FAILURE;
        }
    }
    let mut stdin = stdin_lines();
    let mut stdin_open = true;
    loop {
        tokio::select! {
            l = cell.next_line() => match l {
                Line::Out(who, text) => cell.print(who, &text),
                Line::Exited(who, status) => {
                    say(&format!(
                        "falc-launch: {} stopped ({status}): stopping the cell",
                        cell.nodes[who].name
                    ));
                    return if cell.nodes[who].name == "operator" && status.contains("exit status: 0") {
                        ExitCode::SUCCESS
                    } else {
                        ExitCode::FAILURE
                    };
                }
            },
            line = stdin.recv(), if stdin_open => match line {
                Some(line) => {
                    let line = line.trim();
                    let (to, rest) = line.split_once(' ').unwrap_or((line, ""));
                    if !(to.starts_with("rcm") || to.starts_with("plc")) || !cell.control(to, rest).await {
                        say(&format!("falc-launch: `{line}`: type `rcm <control>` or `plc <control>` (`rcm-<station> …`, `plc-<station> …` for another station's twin)"));
                    }
                }
                None => stdin_open = false,
            },
            _ = shutdown.requested() => return ExitCode::SUCCESS,
        }
    }
}

/// The launcher's standard input, line by line, read on a thread of its
/// own. Not tokio's `stdin()`: it reads on the runtime's blocking pool, and
/// the runtime's shutdown waits for that read, so the launcher stopped by
/// Ctrl-C would hang until Enter was pressed. A plain thread blocked in a
/// read does not keep the process from ending when `main` returns.
fn stdin_lines() -> UnboundedReceiver<String> {
    let (tx, rx) = unbounded_channel();
    let spawned = std::thread::Builder::new()
        .name("stdin".into())
        .spawn(move || {
            use std::io::BufRead;
            for line in std::io::stdin().lock().lines() {
                let Ok(line) = line else { break };
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
    if let Err(e) = spawned {
        tracing::warn!("no reader of standard input: {e}");
    }
    rx
}
