//! Multi-process test harness: a cell on free localhost ports with a real
//! `falc-router` and real node processes. Every process is killed when its
//! guard drops, also when a test fails.

#![allow(dead_code)]

pub mod chaos;
pub mod flood;
pub mod hosts;
pub mod noise;
pub mod opcua;
pub mod plant;
pub mod rig;
pub mod stats;
pub mod wait;

use falc_bus::{certificates, credentials};
use falc_bus::{Bus, BusError, BusSettings, DEFAULT_DEADLINE};
use falc_model::ids::{ObjectName, StationName};
use falc_model::keys::KeySpace;
use falc_model::mms::error::ServiceError;
use falc_model::mms::journal::Publication;
use falc_model::mms::pdu::{JobEvent, Request, Response, Unconfirmed};
use falc_model::topology::Topology;
use std::io::Write;
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

/// The topology the foundation tests use: operator → cell → welding, transport.
pub const TOPOLOGY: &str = r#"
cell = "falc1"
router = "ROUTER"
lease_ms = 1000
[identification]
model = "FALC welding and assembly cell"
serial_number = "FALC-1992-0001"
[[station]]
name = "operator"
kind = "operator"
[[station]]
name = "cell"
kind = "cell"
commander = "operator"
[[station]]
name = "welding"
kind = "welding"
commander = "cell"
[[station]]
name = "transport"
kind = "transport"
commander = "cell"
[[console]]
name = "console"
role = "operator"
[[console]]
name = "observer"
role = "observer"
[[console]]
name = "engineer"
role = "engineer"
[[console]]
name = "maintainer"
role = "maintainer"
[[console]]
name = "opcua"
role = "operator"
"#;

/// A port on 127.0.0.1 free for both TCP and UDP (QUIC).
pub fn free_port() -> u16 {
    for _ in 0..100 {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .expect("a free port on 127.0.0.1");
        if std::net::UdpSocket::bind(("127.0.0.1", port)).is_ok() {
            return port;
        }
    }
    panic!("no port free for both TCP and UDP on 127.0.0.1")
}

/// How many established TCP connections this test process holds to `port`
/// (its sockets in `/proc/self/fd`, matched with `/proc/net/tcp`).
pub fn tcp_connections_to(port: u16) -> usize {
    let ours: std::collections::HashSet<String> = std::fs::read_dir("/proc/self/fd")
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| std::fs::read_link(e.path()).ok())
        .filter_map(|l| {
            let l = l.to_string_lossy().into_owned();
            l.strip_prefix("socket:[")
                .and_then(|i| i.strip_suffix(']'))
                .map(str::to_string)
        })
        .collect();
    let remote = format!(":{port:04X}");
    std::fs::read_to_string("/proc/net/tcp")
        .unwrap_or_default()
        .lines()
        .skip(1)
        .map(|l| l.split_whitespace().collect::<Vec<_>>())
        // local, remote, state (01 established), …, inode
        .filter(|f| f.len() > 9 && f[2].ends_with(&remote) && f[3] == "01")
        .filter(|f| ours.contains(f[9]))
        .count()
}

/// A child process, killed on drop, with its stdout lines on a channel.
pub struct Proc {
    pub name: String,
    child: Child,
    stdin: Option<ChildStdin>,
    lines: Receiver<String>,
    seen: Vec<String>,
}

impl Proc {
    pub fn spawn(name: &str, cmd: Command) -> Proc {
        Self::spawn_with(name, cmd, false)
    }

    /// The same, with its log (stderr) lines among the lines too (and
    /// still echoed to the test's stderr).
    pub fn spawn_logged(name: &str, cmd: Command) -> Proc {
        Self::spawn_with(name, cmd, true)
    }

    fn spawn_with(name: &str, mut cmd: Command, logged: bool) -> Proc {
        cmd.stdout(Stdio::piped())
            .stderr(if logged {
                Stdio::piped()
            } else {
                Stdio::inherit()
            })
            .stdin(Stdio::piped());
        let mut child = cmd
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        let stdin = child.stdin.take();
        let stdout = child.stdout.take().expect("piped stdout");
        let (tx, rx) = channel();
        if let Some(stderr) = child.stderr.take() {
            let tx = tx.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                    eprintln!("{line}");
                    if tx.send(line).is_err() {
                        break;
                    }
                }
            });
        }
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Proc {
            name: name.to_string(),
            child,
            stdin,
            lines: rx,
            seen: Vec::new(),
        }
    }

    /// Waits for a stdout line containing `needle`; returns it.
    pub fn expect_line(&mut self, needle: &str, timeout: Duration) -> String {
        match self.wait_line(needle, timeout) {
            Some(l) => l,
            None => panic!(
                "{}: no line containing {needle:?} within {timeout:?}; saw {:?}",
                self.name, self.seen
            ),
        }
    }

    /// Waits for a stdout line containing `needle`, or None at the timeout.
    pub fn wait_line(&mut self, needle: &str, timeout: Duration) -> Option<String> {
        if let Some(l) = self.seen.iter().find(|l| l.contains(needle)) {
            return Some(l.clone());
        }
        let end = Instant::now() + timeout;
        loop {
            let left = end.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(l) => {
                    self.seen.push(l.clone());
                    if l.contains(needle) {
                        return Some(l);
                    }
                }
                Err(RecvTimeoutError::Timeout | RecvTimeoutError::Disconnected) => return None,
            }
        }
    }

    /// The next stdout line not read before, or None at the timeout.
    pub fn next_line(&mut self, timeout: Duration) -> Option<String> {
        let l = self.lines.recv_timeout(timeout).ok()?;
        self.seen.push(l.clone());
        Some(l)
    }

    /// Waits for a stdout line containing any of `needles`; None at the
    /// timeout.
    pub fn wait_any(&mut self, needles: &[&str], timeout: Duration) -> Option<String> {
        let end = Instant::now() + timeout;
        loop {
            for n in needles {
                if let Some(l) = self.wait_line(n, Duration::ZERO) {
                    return Some(l);
                }
            }
            let left = end.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return None;
            }
            match self.lines.recv_timeout(left.min(Duration::from_millis(5))) {
                Ok(l) => self.seen.push(l),
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => return None,
            }
        }
    }

    /// Takes in every line the process printed so far (for
    /// [`Self::lines_containing`]).
    pub fn drain(&mut self) {
        while let Ok(l) = self.lines.try_recv() {
            self.seen.push(l);
        }
    }

    /// The lines seen so far that contain `needle`.
    pub fn lines_containing(&self, needle: &str) -> Vec<String> {
        self.seen
            .iter()
            .filter(|l| l.contains(needle))
            .cloned()
            .collect()
    }

    /// Whether the process still runs.
    pub fn alive(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(None))
    }

    /// Like `expect_line`, but removes the line it found, so that the next
    /// call needs a new one (counting repeated lines).
    pub fn take_line(&mut self, needle: &str, timeout: Duration) -> String {
        let line = self.expect_line(needle, timeout);
        if let Some(i) = self.seen.iter().position(|l| *l == line) {
            self.seen.remove(i);
        }
        line
    }

    /// Forgets the lines printed so far that contain `needle` (those not
    /// read yet too), so that the next `expect_line` waits for a new one.
    pub fn forget(&mut self, needle: &str) {
        self.drain();
        self.seen.retain(|l| !l.contains(needle));
    }

    /// Writes a line to the process's stdin (a twin's control interface)
    /// and waits for its `ok` answer.
    pub fn control(&mut self, line: &str) {
        self.send(line);
        self.expect_line(&format!("ok {line}"), Duration::from_secs(10));
        // Answered lines are consumed, so the same control can be sent again.
        self.seen.retain(|l| l != &format!("ok {line}"));
    }

    /// Writes one line to its stdin.
    pub fn send(&mut self, line: &str) {
        let stdin = self.stdin.as_mut().expect("stdin piped");
        writeln!(stdin, "{line}").expect("line written");
        stdin.flush().expect("flushed");
    }

    /// SIGTERM: the process stops its own way (it is reaped on drop).
    pub fn terminate(&self) {
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(self.child.id() as i32),
            nix::sys::signal::Signal::SIGTERM,
        );
    }

    /// SIGKILL, and reap.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Starts a twin (`bin` with `args`) and reads where to reach it from its
/// first line, `… <announces> <where>` (a pty path, a Modbus address).
pub fn twin(bin: &str, args: &[&str], announces: &str) -> (Proc, String) {
    let mut cmd = Command::new(bin);
    cmd.args(args);
    twin_from(cmd, bin, announces)
}

/// `bin` run on `host` of `hosts`, or here.
fn on(hosts: Option<&hosts::Hosts>, host: &str, bin: &str) -> Command {
    match hosts {
        Some(h) => h.command(host, bin),
        None => Command::new(bin),
    }
}

fn twin_from(cmd: Command, bin: &str, announces: &str) -> (Proc, String) {
    let name = std::path::Path::new(bin)
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| bin.to_string());
    let mut p = Proc::spawn(&name, cmd);
    let line = p.expect_line(announces, Duration::from_secs(10));
    let at = line.rsplit(' ').next().unwrap_or_default().to_string();
    (p, at)
}

/// Copies the shipped recipe tree to `dir/recipes` (tests may edit it).
pub fn copy_recipes(dir: &std::path::Path) -> PathBuf {
    let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("recipes");
    let to = dir.join("recipes");
    for sub in ["cell", "welding", "transport", "robot"] {
        copy_dir(&src.join(sub), &to.join(sub));
    }
    to
}

/// Copies every file of `from` into `to` (created; modes kept).
pub fn copy_dir(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).expect("mkdir");
    for e in std::fs::read_dir(from).expect("dir") {
        let p = e.expect("entry").path();
        std::fs::copy(&p, to.join(p.file_name().expect("name"))).expect("copy");
    }
}

/// A `falc-launch` command for a whole cell in `dir`: the topology written
/// there with a free router port (returned), credentials and database
/// there, a copy of the shipped recipes in `dir/recipes`, the twins at
/// `time_scale`.
pub fn launcher(dir: &std::path::Path, time_scale: &str) -> (Command, String) {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let topology = dir.join("cell.toml");
    std::fs::write(&topology, TOPOLOGY.replace("ROUTER", &endpoint)).expect("topology");
    let recipes = copy_recipes(dir);
    (launcher_of(dir, &topology, &recipes, time_scale), endpoint)
}

/// A `falc-launch` command for the cell of `topology` with the recipe tree
/// `recipes`, credentials and database in `dir`, the twins at `time_scale`.
pub fn launcher_of(
    dir: &std::path::Path,
    topology: &std::path::Path,
    recipes: &std::path::Path,
    time_scale: &str,
) -> Command {
    let bin_dir = std::path::Path::new(env!("CARGO_BIN_EXE_falc"))
        .parent()
        .expect("bin dir")
        .to_path_buf();
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_falc-launch"));
    cmd.arg("--topology")
        .arg(topology)
        .arg("--credentials-dir")
        .arg(dir.join("credentials"))
        .arg("--db")
        .arg(dir.join("falc.db"))
        .arg("--recipes")
        .arg(recipes)
        .arg("--bin-dir")
        .arg(bin_dir)
        .args(["--plc-listen", "127.0.0.1:0", "--time-scale", time_scale]);
    cmd
}

/// Runs `falc` with `cell` (how to reach the cell, as whom) and `args`:
/// exit code, stdout (and stderr when it failed).
pub fn run_falc(cell: &[String], args: &[&str]) -> (i32, String) {
    run_falc_with(Command::new(env!("CARGO_BIN_EXE_falc")), cell, args)
}

/// [`run_falc`] with the `falc` command given (run on another host).
pub fn run_falc_with(mut falc: Command, cell: &[String], args: &[&str]) -> (i32, String) {
    let out = falc.args(cell).args(args).output().expect("run falc");
    let mut text = String::from_utf8_lossy(&out.stdout).into_owned();
    if !out.status.success() {
        text.push_str(&String::from_utf8_lossy(&out.stderr));
    }
    (out.status.code().unwrap_or(-1), text)
}

/// A whole cell started by `falc-launch` in a temporary directory. Dropped
/// (also when a test fails): SIGTERM to the launcher, which stops every node
/// top-down; whatever is left after 10 s is killed.
pub struct LaunchedCell {
    /// Where topology, credentials, database and recipes are.
    pub dir: tempfile::TempDir,
    /// The launcher (its stdout carries every node's prefixed lines).
    pub launcher: Proc,
}

impl LaunchedCell {
    /// Starts the cell at `time_scale` and waits until it is ready.
    pub fn start(time_scale: &str) -> Self {
        Self::start_with(time_scale, &[])
    }

    /// [`LaunchedCell::start`] with more launcher arguments (`--opcua …`).
    pub fn start_with(time_scale: &str, args: &[&str]) -> Self {
        let dir = tempfile::tempdir().expect("tempdir");
        let (mut cmd, _) = launcher(dir.path(), time_scale);
        cmd.args(args);
        let mut launcher = Proc::spawn("falc-launch", cmd);
        launcher.expect_line("falc-launch: cell ready in", Duration::from_secs(60));
        Self { dir, launcher }
    }

    /// `falc` as console user `user` with `args`: exit code, stdout (and
    /// stderr when it failed).
    pub fn falc_as(&self, user: &str, args: &[&str]) -> (i32, String) {
        run_falc(&self.falc_args(user), args)
    }

    /// Bus settings for a session of console user `user` from this
    /// process.
    pub fn settings(&self, user: &str) -> BusSettings {
        let topology = Topology::load(&self.dir.path().join("cell.toml")).expect("topology");
        let endpoint = topology.router().to_string();
        settings_in(
            &topology,
            &endpoint,
            &self.dir.path().join("credentials"),
            user,
        )
    }

    /// The arguments that make `falc` talk to this cell as `user`.
    pub fn falc_args(&self, user: &str) -> Vec<String> {
        vec![
            "--topology".into(),
            self.dir.path().join("cell.toml").display().to_string(),
            "--credentials-dir".into(),
            self.dir.path().join("credentials").display().to_string(),
            "--user".into(),
            user.into(),
        ]
    }
}

/// Bus settings for a session of `station` of `topology` from this
/// process, at router `endpoint`, its credentials in `credentials_dir`.
pub fn settings_in(
    topology: &Topology,
    endpoint: &str,
    credentials_dir: &std::path::Path,
    station: &str,
) -> BusSettings {
    let me = StationName::new(station).expect("valid station");
    let creds = credentials::load(&credentials_dir.join(format!("{station}.toml")))
        .expect("credentials written by the router");
    let tls = certificates::is_secure(endpoint)
        .then(|| certificates::TlsFiles::of(credentials_dir, station));
    BusSettings {
        keys: KeySpace::new(topology.cell().clone()),
        me,
        endpoint: endpoint.to_string(),
        lease: topology.lease(),
        credentials: Some(creds),
        tls,
        connect_timeout: Duration::ZERO,
    }
}

impl Drop for LaunchedCell {
    fn drop(&mut self) {
        let pid = self.launcher.pid();
        let nodes = children(pid);
        let _ = nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(pid as i32),
            nix::sys::signal::Signal::SIGTERM,
        );
        // Its own way out first; whatever is left is killed below.
        let _ = wait::poll_until(wait::POLL, Duration::from_secs(10), || {
            let exited = matches!(self.launcher.child.try_wait(), Ok(Some(_)))
                || !std::path::Path::new(&format!("/proc/{pid}/status")).exists();
            wait::holds(exited, || ())
        });
        for (p, _) in nodes {
            let _ = nix::sys::signal::kill(
                nix::unistd::Pid::from_raw(p as i32),
                nix::sys::signal::Signal::SIGKILL,
            );
        }
        self.launcher.kill();
    }
}

/// The child processes of `parent` (pid and command name), from /proc.
pub fn children(parent: u32) -> Vec<(u32, String)> {
    let mut v = Vec::new();
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return v;
    };
    for e in dir.flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(e.path().join("stat")) else {
            continue;
        };
        // pid (comm) state ppid …; comm may hold spaces: split at the last ')'.
        let Some((head, rest)) = stat.rsplit_once(')') else {
            continue;
        };
        let ppid = rest.split_whitespace().nth(1).and_then(|p| p.parse().ok());
        if ppid == Some(parent) {
            let name = head.split_once('(').map_or("?", |x| x.1).to_string();
            v.push((pid, name));
        }
    }
    v.sort();
    v
}

/// A cell under test: a temp dir with topology and credentials, and a router.
pub struct TestCell {
    pub dir: tempfile::TempDir,
    pub topology: Topology,
    pub topology_path: PathBuf,
    pub endpoint: String,
    pub router: Proc,
    /// The namespaces when the cell runs as separate hosts (removed after
    /// the router stopped).
    pub hosts: Option<hosts::Hosts>,
}

impl TestCell {
    /// The router's socket address (its endpoint without the protocol).
    pub fn address(&self) -> std::net::SocketAddr {
        self.endpoint
            .split_once('/')
            .and_then(|(_, a)| a.parse().ok())
            .expect("the endpoint is protocol/address:port")
    }

    /// The router's port.
    pub fn port(&self) -> u16 {
        self.endpoint
            .rsplit_once(':')
            .and_then(|(_, p)| p.parse().ok())
            .expect("the endpoint ends in a port")
    }

    /// Writes the topology with a free router port and starts the router.
    pub fn start() -> TestCell {
        Self::start_on("tcp")
    }

    /// The same on the secure transport (`quic/127.0.0.1:PORT`, mutual
    /// TLS): the router creates the cell CA and every certificate.
    pub fn start_secure() -> TestCell {
        Self::start_on("quic")
    }

    /// The cell as separate hosts on the secure transport: each node on a
    /// network namespace of its own ([`hosts::Hosts`]); the consoles on the
    /// operator's. The topology names each PC's address (`host`), so the
    /// router's firewall rules can be made from it.
    /// The router's firewall (`falc-router firewall`) is applied in its
    /// namespace, as the install guide applies it on the router's PC.
    pub fn start_hosts(hosts: hosts::Hosts) -> TestCell {
        let endpoint = format!("quic/{}:7447", hosts::ROUTER_ADDRESS);
        let cell = Self::start_text(endpoint, Some(hosts), &hosts::with_hosts(TOPOLOGY));
        let out = Command::new(env!("CARGO_BIN_EXE_falc-router"))
            .arg("--topology")
            .arg(&cell.topology_path)
            .arg("firewall")
            .output()
            .expect("falc-router firewall");
        assert!(out.status.success(), "falc-router firewall: {out:?}");
        let rules = String::from_utf8(out.stdout).expect("rules are text");
        if let Some(h) = cell.hosts.as_ref() {
            if let Err(e) = h.nft("router", &rules) {
                panic!("cannot apply the router's firewall: {e}\n{rules}");
            }
        }
        cell
    }

    /// The cell with more stanzas (`extra`, TOML) after [`TOPOLOGY`]'s.
    pub fn start_grown(extra: &str) -> TestCell {
        let endpoint = format!("tcp/127.0.0.1:{}", free_port());
        Self::start_text(endpoint, None, &format!("{TOPOLOGY}\n{extra}"))
    }

    fn start_on(protocol: &str) -> TestCell {
        Self::start_text(
            format!("{protocol}/127.0.0.1:{}", free_port()),
            None,
            TOPOLOGY,
        )
    }

    fn start_text(endpoint: String, hosts: Option<hosts::Hosts>, topology: &str) -> TestCell {
        let dir = tempfile::tempdir().expect("tempdir");
        let text = topology.replace("ROUTER", &endpoint);
        let topology_path = dir.path().join("cell.toml");
        std::fs::write(&topology_path, &text).expect("write topology");
        let topology = Topology::parse(&text, "test").expect("valid topology");
        let mut cmd = on(hosts.as_ref(), "router", env!("CARGO_BIN_EXE_falc-router"));
        cmd.arg("--topology")
            .arg(&topology_path)
            .arg("--credentials-dir")
            .arg(dir.path().join("credentials"))
            .arg("run");
        // Its log too: tests read the refused-login lines.
        let mut router = Proc::spawn_logged("falc-router", cmd);
        router.expect_line("falc-router ready", Duration::from_secs(20));
        TestCell {
            hosts,
            dir,
            topology,
            topology_path,
            endpoint,
            router,
        }
    }

    pub fn credentials_dir(&self) -> PathBuf {
        self.dir.path().join("credentials")
    }

    /// `bin` as a command on `host` (this machine, unless the cell runs
    /// as separate hosts).
    pub fn command(&self, host: &str, bin: &str) -> Command {
        on(self.hosts.as_ref(), host, bin)
    }

    /// Starts a twin on `host` (see [`twin`]).
    pub fn twin(&self, host: &str, bin: &str, args: &[&str], announces: &str) -> (Proc, String) {
        let mut cmd = self.command(host, bin);
        cmd.args(args);
        twin_from(cmd, bin, announces)
    }

    /// Starts node binary `bin` as `station` of this cell (with `args`) and
    /// waits until it says it is ready.
    pub fn start_node(&self, bin: &str, station: &str, args: &[&str]) -> Proc {
        let mut cmd = self.command(station, bin);
        cmd.args(["--station", station])
            .args(args)
            .arg("--topology")
            .arg(&self.topology_path)
            .arg("--credentials-dir")
            .arg(self.credentials_dir());
        let mut p = Proc::spawn(station, cmd);
        p.expect_line("EVENT ready", Duration::from_secs(20));
        p
    }

    /// Runs the console `falc` as console user `user` with `args`; its exit
    /// code and stdout (stderr is appended to the text on failure).
    pub fn falc_as(&self, user: &str, args: &[&str]) -> (i32, String) {
        let cell = vec![
            "--topology".to_string(),
            self.topology_path.display().to_string(),
            "--credentials-dir".into(),
            self.credentials_dir().display().to_string(),
            "--user".into(),
            user.into(),
        ];
        run_falc_with(
            self.command("operator", env!("CARGO_BIN_EXE_falc")),
            &cell,
            args,
        )
    }

    /// `falc` as the operator console user; must succeed; its stdout.
    pub fn falc(&self, args: &[&str]) -> String {
        let (code, text) = self.falc_as("console", args);
        assert_eq!(code, 0, "falc {args:?}: {text}");
        text
    }

    /// Starts a demo station process and waits until it is on the bus.
    pub fn demo_station(&self, station: &str) -> Proc {
        self.start_node(env!("CARGO_BIN_EXE_falc-demo-station"), station, &[])
    }

    /// Bus settings for a session of `station` from this process.
    pub fn settings(&self, station: &str) -> BusSettings {
        settings_in(
            &self.topology,
            &self.endpoint,
            &self.credentials_dir(),
            station,
        )
    }

    /// Sends `count` malformed operator API calls (`status`, a payload
    /// that is no request) as the console user `console`: the operator API
    /// key they went to, and how many were answered (with an error).
    pub fn malformed_api_calls(&self, count: u32) -> (String, u32) {
        let settings = self.settings("console");
        let keys = KeySpace::new(self.topology.cell().clone());
        let key = keys.api(
            &self.topology.root().name,
            falc_model::api::Call::Status,
            &settings.me,
        );
        let rt = tokio::runtime::Runtime::new().expect("runtime");
        let answered = rt.block_on(async {
            let bus = Bus::open(settings).await.expect("console");
            let mut answered = 0;
            for i in 0..count {
                let replies = bus
                    .session()
                    .get(&key)
                    .payload(format!("not a request {i}").into_bytes())
                    .timeout(Duration::from_secs(2))
                    .await
                    .expect("get");
                if replies.recv_async().await.is_ok() {
                    answered += 1;
                }
            }
            let _ = bus.session().close().await;
            answered
        });
        (key, answered)
    }

    /// The zenoh configuration of `user`'s session, as its console or node
    /// makes it, but in zenoh `mode` (what a stranger with stolen
    /// credentials might try) and listening nowhere.
    pub fn session_config(&self, user: &str, mode: &str) -> zenoh::Config {
        let settings = self.settings(user);
        let mut cfg = falc_bus::config::client(
            &settings.endpoint,
            settings.lease,
            settings.credentials.as_ref(),
            settings.tls.as_ref(),
            Duration::from_secs(2),
        )
        .expect("config");
        cfg.insert_json5("mode", &format!("\"{mode}\""))
            .expect("mode");
        cfg.insert_json5("listen/endpoints", "[]").expect("listen");
        cfg
    }

    /// A session of `station` from this test process.
    pub async fn bus(&self, station: &str) -> Result<Bus, BusError> {
        Bus::open(self.settings(station)).await
    }
}

pub fn st(s: &str) -> StationName {
    StationName::new(s).expect("valid station")
}

/// This test process as a workstation's commander (the cell's part):
/// associated, subscribed to the station's status and reports.
pub struct Commander {
    pub bus: Bus,
    station: StationName,
    events: tokio::sync::mpsc::UnboundedReceiver<Publication>,
    /// The last status the station published (kept while other waits
    /// read past it).
    pub last_status: Option<falc_model::mms::vmd::VmdStatus>,
    /// Publications read ahead (to find the newest status) and not yet
    /// taken, statuses but for the newest dropped, oldest first.
    ahead: std::collections::VecDeque<Publication>,
    _subs: Vec<falc_bus::Declaration>,
}

impl Commander {
    /// Opens a `cell` session and associates with `station`.
    pub async fn associate(cell: &TestCell, station: &str) -> Commander {
        Self::associate_as(cell, "cell", station).await
    }

    /// Opens a session of `me` and associates with `station`.
    pub async fn associate_as(cell: &TestCell, me: &str, station: &str) -> Commander {
        let bus = cell.bus(me).await.expect("session");
        let r = bus
            .request(
                &st(station),
                &Request::Initiate {
                    calling: bus.me().clone(),
                },
                DEFAULT_DEADLINE,
            )
            .await;
        assert!(matches!(r, Ok(Response::Initiate { .. })), "{r:?}");
        let (tx, events) = tokio::sync::mpsc::unbounded_channel();
        let subs = bus.subscribe(&st(station), tx).await.expect("subscribe");
        Commander {
            bus,
            station: st(station),
            events,
            last_status: None,
            ahead: std::collections::VecDeque::new(),
            _subs: subs,
        }
    }

    /// The next publication before `end` (one read ahead first), noting
    /// a status.
    async fn next(
        &mut self,
        end: tokio::time::Instant,
    ) -> Result<Option<Publication>, tokio::time::error::Elapsed> {
        if let Some(p) = self.ahead.pop_front() {
            return Ok(Some(p));
        }
        let p = tokio::time::timeout_at(end, self.events.recv()).await;
        if let Ok(Some(Publication {
            message: Unconfirmed::Status { status, .. },
            ..
        })) = &p
        {
            self.last_status = Some(status.clone());
        }
        p
    }

    /// With `seen` false, the newest status published so far (what came
    /// already is read ahead: its statuses noted, the rest kept for the
    /// other waits); else, or if none came yet, the next status before
    /// `end`.
    pub async fn status_after(
        &mut self,
        end: tokio::time::Instant,
        seen: bool,
    ) -> Option<falc_model::mms::vmd::VmdStatus> {
        if !seen {
            while let Ok(p) = self.events.try_recv() {
                match p.message {
                    Unconfirmed::Status { status, .. } => self.last_status = Some(status),
                    _ => self.ahead.push_back(p),
                }
            }
            if let Some(s) = &self.last_status {
                return Some(s.clone());
            }
        }
        loop {
            match self.next(end).await {
                Ok(Some(Publication {
                    message: Unconfirmed::Status { status, .. },
                    ..
                })) => return Some(status),
                Ok(Some(_)) => continue,
                _ => return None,
            }
        }
    }

    pub async fn call(&self, r: Request) -> Result<Response, ServiceError> {
        self.bus.request(&self.station, &r, DEFAULT_DEADLINE).await
    }

    /// Downloads `text` as domain `name` and creates its program invocation.
    pub async fn load(&self, name: &str, text: &str) {
        self.download(name, text).await;
        let name = ObjectName::new(name).expect("valid");
        let r = self
            .call(Request::CreateProgramInvocation {
                name: name.clone(),
                domains: vec![name.clone()],
                reusable: true,
            })
            .await;
        assert_eq!(r, Ok(Response::Done), "create {name}");
    }

    /// Downloads `text` as domain `name`.
    pub async fn download(&self, name: &str, text: &str) {
        let name = ObjectName::new(name).expect("valid");
        let steps = [
            Request::InitiateDownloadSequence {
                domain: name.clone(),
            },
            Request::DownloadSegment {
                domain: name.clone(),
                data: text.as_bytes().to_vec(),
                more_follows: false,
            },
            Request::TerminateDownloadSequence {
                domain: name.clone(),
                discard: None,
            },
        ];
        for s in steps {
            let r = self.call(s.clone()).await;
            assert_eq!(r, Ok(Response::Done), "{s:?}");
        }
    }

    /// Starts program invocation `name`.
    pub async fn try_start(&self, name: &str) -> Result<Response, ServiceError> {
        self.call(Request::Start {
            name: ObjectName::new(name).expect("valid"),
            argument: String::new(),
        })
        .await
    }

    /// Starts program invocation `name`; it must be confirmed.
    pub async fn start(&self, name: &str) {
        let r = self.try_start(name).await;
        assert!(
            matches!(r, Ok(Response::ProgramInvocationState(_))),
            "{r:?}"
        );
    }

    /// The next job event.
    pub async fn job(&mut self, within: Duration) -> JobEvent {
        match self.try_job(within).await {
            Some(job) => job,
            None => panic!("no job event within {within:?}"),
        }
    }

    /// The next job event, if one comes within `within`. A run's start is
    /// passed over: what a commander's `wait` waits for is what ends or
    /// pauses it.
    pub async fn try_job(&mut self, within: Duration) -> Option<JobEvent> {
        let end = tokio::time::Instant::now() + within;
        loop {
            match self.next(end).await {
                Ok(Some(Publication {
                    message: Unconfirmed::Job { event, .. },
                    ..
                })) if event != JobEvent::Started => return Some(event),
                Ok(Some(_)) => continue,
                Ok(None) => panic!("the subscription ended"),
                Err(_) => return None,
            }
        }
    }

    /// The next job event, which must be an alarm: its text.
    pub async fn alarm(&mut self, within: Duration) -> String {
        match self.job(within).await {
            JobEvent::Alarm(cause) => cause.text,
            other => panic!("expected an alarm, got {other:?}"),
        }
    }

    /// Waits for a report whose text contains `needle`; returns the text.
    pub async fn report(&mut self, needle: &str, within: Duration) -> String {
        let end = tokio::time::Instant::now() + within;
        loop {
            match self.next(end).await {
                Ok(Some(Publication {
                    message: Unconfirmed::Report { text, .. },
                    ..
                })) if text.contains(needle) => return text,
                Ok(Some(_)) => continue,
                other => panic!("no report with {needle:?} within {within:?}: {other:?}"),
            }
        }
    }
}
