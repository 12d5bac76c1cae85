//! The cell as separate hosts on one machine: a network namespace per PC
//! (router, operator, cell, welding, transport) and one for a stranger on
//! the same segment, each joined to a bridge in the router's namespace by a
//! veth link of its own, addresses in 10.77.0.0/24 inside those namespaces
//! only. Links can be cut and mended from the router's side, the bridge's
//! traffic captured, and the router's firewall rules applied in its
//! namespace. A plant the same way ([`Hosts::create_named`]): the factory's
//! namespace holds the bridge, each cell a namespace of its own on it.
//! Everything is removed on drop (deleting a namespace deletes its links
//! and rules). Needs root.

use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// The PCs, each a namespace; the router's holds the bridge. The last is
/// no PC of the cell's: the topology does not name it.
pub const HOSTS: [&str; 6] = [
    "router",
    "operator",
    "cell",
    "welding",
    "transport",
    "stranger",
];

/// The router's address on the bridge.
pub const ROUTER_ADDRESS: &str = "10.77.0.1";

/// The namespaces of one test.
pub struct Hosts {
    prefix: String,
    /// The hosts; the first holds the bridge.
    names: Vec<String>,
    /// The bridge's network (`10.77.0`): the first host is `.1`, the
    /// others `.11`, `.12` …
    net: String,
}

fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("cannot run `ip`: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

impl Hosts {
    /// Creates the namespaces and links, or says why it cannot (not root,
    /// no `ip`).
    pub fn create() -> Result<Hosts, String> {
        Self::create_named(&HOSTS, "10.77.0")
    }

    /// Namespaces for `names` on network `net` (`10.78.0`), the first
    /// holding the bridge at `<net>.1`, the others at `<net>.11`, `.12` …;
    /// or why they cannot be made.
    pub fn create_named(names: &[&str], net: &str) -> Result<Hosts, String> {
        let hosts = Hosts {
            prefix: format!("falc{}", std::process::id()),
            names: names.iter().map(|n| n.to_string()).collect(),
            net: net.to_string(),
        };
        // Hosts drops (and deletes what exists) if any step fails.
        for h in names {
            ip(&["netns", "add", &hosts.ns(h)])?;
            ip(&["-n", &hosts.ns(h), "link", "set", "lo", "up"])?;
        }
        let r = hosts.ns(names[0]);
        let bridge = format!("{}/24", hosts.address(names[0]));
        ip(&["-n", &r, "link", "add", "br0", "type", "bridge"])?;
        ip(&["-n", &r, "addr", "add", &bridge, "dev", "br0"])?;
        ip(&["-n", &r, "link", "set", "br0", "up"])?;
        for h in names.iter().skip(1) {
            let ns = hosts.ns(h);
            let port = Self::port_of(h);
            ip(&[
                "link", "add", "name", "eth0", "netns", &ns, "type", "veth", "peer", "name", &port,
                "netns", &r,
            ])?;
            ip(&["-n", &r, "link", "set", &port, "master", "br0", "up"])?;
            let address = format!("{}/24", hosts.address(h));
            ip(&["-n", &ns, "addr", "add", &address, "dev", "eth0"])?;
            ip(&["-n", &ns, "link", "set", "eth0", "up"])?;
        }
        Ok(hosts)
    }

    /// Runs `f` on a thread that entered `host`'s namespace; what it
    /// returned, or why it could not run there.
    pub fn on<T: Send + 'static>(
        &self,
        host: &str,
        f: impl FnOnce() -> T + Send + 'static,
    ) -> std::thread::JoinHandle<Result<T, String>> {
        let path = self.ns_path(host);
        std::thread::spawn(move || {
            enter(&path)?;
            Ok(f())
        })
    }

    /// Applies nftables rules (`nft -f -`) in `host`'s namespace, or says
    /// why it could not.
    pub fn nft(&self, host: &str, rules: &str) -> Result<(), String> {
        use std::io::Write;
        let mut child = self
            .command(host, "nft")
            .args(["-f", "-"])
            .stdin(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .map_err(|e| format!("cannot run nft: {e}"))?;
        if let Some(mut stdin) = child.stdin.take() {
            stdin
                .write_all(rules.as_bytes())
                .map_err(|e| format!("nft stdin: {e}"))?;
        }
        let out = child.wait_with_output().map_err(|e| format!("nft: {e}"))?;
        if out.status.success() {
            Ok(())
        } else {
            Err(format!(
                "nft -f: {}",
                String::from_utf8_lossy(&out.stderr).trim()
            ))
        }
    }

    /// The namespace of `host`.
    pub fn ns(&self, host: &str) -> String {
        format!("{}-{host}", self.prefix)
    }

    /// The bridge port (in the router's namespace) of `host`'s link.
    fn port_of(host: &str) -> String {
        format!("v-{host}")
    }

    /// `bin` to be run on `host`.
    pub fn command(&self, host: &str, bin: &str) -> Command {
        let mut cmd = Command::new("ip");
        cmd.args(["netns", "exec", &self.ns(host), bin]);
        cmd
    }

    /// Cuts `host`'s link (its bridge port down: nothing passes).
    pub fn cut(&self, host: &str) {
        self.set_port(host, "down");
    }

    /// Mends `host`'s link.
    pub fn mend(&self, host: &str) {
        self.set_port(host, "up");
    }

    /// The address of `host` on the bridge.
    pub fn address(&self, host: &str) -> String {
        match self.names.iter().position(|h| h == host) {
            Some(0) | None => format!("{}.1", self.net),
            Some(i) => format!("{}.{}", self.net, 10 + i),
        }
    }

    fn set_port(&self, host: &str, state: &str) {
        let router = self.ns(&self.names[0]);
        let port = Self::port_of(host);
        if let Err(e) = ip(&["-n", &router, "link", "set", &port, state]) {
            panic!("{host}'s link {state}: {e}");
        }
    }

    /// Starts capturing every frame on the bridge (a raw packet socket in
    /// the router's namespace, opened by a thread that entered it).
    pub fn capture(&self) -> Capture {
        let path = self.ns_path("router");
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = stop.clone();
        let thread = std::thread::spawn(move || {
            enter(&path)?;
            capture_on_bridge(&stopped)
        });
        Capture { stop, thread }
    }

    /// Sends `text` in clear from `host` to `address` in a UDP datagram
    /// (what the capture must see, so that a capture without the cell's
    /// texts means something).
    pub fn send_in_clear(&self, host: &str, address: &str, text: &str) {
        let (address, text) = (address.to_string(), text.to_string());
        let sent = self
            .on(host, move || -> Result<usize, String> {
                let socket =
                    std::net::UdpSocket::bind("0.0.0.0:0").map_err(|e| format!("bind: {e}"))?;
                socket
                    .send_to(text.as_bytes(), &address)
                    .map_err(|e| format!("{address}: {e}"))
            })
            .join()
            .expect("sending thread");
        if let Err(e) = sent.and_then(|r| r) {
            panic!("cannot send in clear from {host}: {e}");
        }
    }

    /// A delay line in the router's namespace: a UDP relay listening on
    /// the router's address, port [`DELAY_LINE_PORT`], to the router's
    /// port 7447. A node told to reach the router there (`--router
    /// <DelayLine::endpoint>`) keeps its QUIC connection end to end; what it
    /// sends and receives is held back by the line's delay (none at
    /// first), in order, like a slow link.
    pub fn delay_line(&self) -> DelayLine {
        let path = self.ns_path("router");
        let delay = Arc::new(std::sync::atomic::AtomicU64::new(0));
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let (ready_tx, ready) = std::sync::mpsc::channel();
        let line_delay = delay.clone();
        std::thread::spawn(move || {
            let run = || -> Result<(), String> {
                enter(&path)?;
                let rt = tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()
                    .map_err(|e| format!("runtime: {e}"))?;
                rt.block_on(async {
                    let listener = tokio::net::UdpSocket::bind((ROUTER_ADDRESS, DELAY_LINE_PORT))
                        .await
                        .map_err(|e| format!("delay line listen: {e}"))?;
                    let _ = ready_tx.send(Ok(()));
                    tokio::select! {
                        _ = stopped => Ok(()),
                        r = relay(listener, line_delay) => r,
                    }
                })
            };
            if let Err(e) = run() {
                let _ = ready_tx.send(Err(e));
            }
        });
        match ready.recv() {
            Ok(Ok(())) => DelayLine { delay, _stop: stop },
            Ok(Err(e)) => panic!("cannot start the delay line: {e}"),
            Err(e) => panic!("the delay line thread ended: {e}"),
        }
    }

    fn ns_path(&self, host: &str) -> String {
        format!("/var/run/netns/{}", self.ns(host))
    }
}

/// The port of the delay line on the router's address.
pub const DELAY_LINE_PORT: u16 = 7448;

/// A relay that delays a link ([`Hosts::delay_line`]); stops on drop.
pub struct DelayLine {
    delay: Arc<std::sync::atomic::AtomicU64>,
    _stop: tokio::sync::oneshot::Sender<()>,
}

impl DelayLine {
    /// The router endpoint through the line.
    pub fn endpoint(&self) -> String {
        format!("quic/{ROUTER_ADDRESS}:{DELAY_LINE_PORT}")
    }

    /// Delays every byte from now on by `delay`, each way.
    pub fn set_delay(&self, delay: std::time::Duration) {
        let ms = u64::try_from(delay.as_millis()).unwrap_or(u64::MAX);
        self.delay.store(ms, Ordering::Relaxed);
    }
}

/// Relays datagrams between each node (by its source address) and the
/// router, each through a delayed pump; a node's relay socket stays for
/// the line's life.
async fn relay(
    near: tokio::net::UdpSocket,
    delay: Arc<std::sync::atomic::AtomicU64>,
) -> Result<(), String> {
    use std::collections::HashMap;
    use std::net::SocketAddr;
    let near = Arc::new(near);
    let mut far_of: HashMap<SocketAddr, tokio::sync::mpsc::UnboundedSender<Delayed>> =
        HashMap::new();
    let mut buf = vec![0u8; 65536];
    loop {
        let (n, node) = near
            .recv_from(&mut buf)
            .await
            .map_err(|e| format!("delay line receive: {e}"))?;
        let due = due_in(&delay);
        let to_router = match far_of.entry(node) {
            std::collections::hash_map::Entry::Occupied(known) => known.into_mut(),
            std::collections::hash_map::Entry::Vacant(new) => {
                let far = tokio::net::UdpSocket::bind((ROUTER_ADDRESS, 0))
                    .await
                    .map_err(|e| format!("delay line bind: {e}"))?;
                far.connect((ROUTER_ADDRESS, 7447))
                    .await
                    .map_err(|e| format!("delay line connect: {e}"))?;
                let far = Arc::new(far);
                let (to_router, queued) = tokio::sync::mpsc::unbounded_channel::<Delayed>();
                tokio::spawn(send_when_due(queued, far.clone(), None));
                let (to_node, back) = tokio::sync::mpsc::unbounded_channel::<Delayed>();
                tokio::spawn(send_when_due(back, near.clone(), Some(node)));
                let delay = delay.clone();
                tokio::spawn(async move {
                    let mut buf = vec![0u8; 65536];
                    while let Ok(n) = far.recv(&mut buf).await {
                        if to_node.send((due_in(&delay), buf[..n].to_vec())).is_err() {
                            return;
                        }
                    }
                });
                new.insert(to_router)
            }
        };
        let _ = to_router.send((due, buf[..n].to_vec()));
    }
}

/// A datagram and when it is due.
type Delayed = (tokio::time::Instant, Vec<u8>);

fn due_in(delay: &std::sync::atomic::AtomicU64) -> tokio::time::Instant {
    tokio::time::Instant::now() + std::time::Duration::from_millis(delay.load(Ordering::Relaxed))
}

/// Sends each queued datagram when it is due, in order: on `socket`'s
/// connected peer, or to `to`.
async fn send_when_due(
    mut queued: tokio::sync::mpsc::UnboundedReceiver<Delayed>,
    socket: Arc<tokio::net::UdpSocket>,
    to: Option<std::net::SocketAddr>,
) {
    while let Some((due, datagram)) = queued.recv().await {
        tokio::time::sleep_until(due).await;
        let _ = match to {
            Some(to) => socket.send_to(&datagram, to).await,
            None => socket.send(&datagram).await,
        };
    }
}

/// The address of `host` on the bridge (the router's, or 10.77.0.1X).
pub fn address_of(host: &str) -> String {
    match HOSTS.iter().position(|h| *h == host) {
        Some(0) | None => ROUTER_ADDRESS.to_string(),
        Some(i) => format!("10.77.0.{}", 10 + i),
    }
}

/// `topology` with the address of each station's PC (`host = …`), and the
/// operator's PC for every console user (consoles run there).
pub fn with_hosts(topology: &str) -> String {
    let mut out = String::new();
    for line in topology.lines() {
        out.push_str(line);
        out.push('\n');
        if let Some(name) = line
            .strip_prefix("name = \"")
            .and_then(|n| n.strip_suffix('"'))
        {
            let pc = if HOSTS.contains(&name) {
                name
            } else {
                "operator"
            };
            out.push_str(&format!("host = \"{}\"\n", address_of(pc)));
        }
    }
    out
}

/// Moves the calling thread (only it) into the network namespace at `path`.
fn enter(path: &str) -> Result<(), String> {
    let file = std::fs::File::open(path).map_err(|e| format!("{path}: {e}"))?;
    nix::sched::setns(&file, nix::sched::CloneFlags::CLONE_NEWNET)
        .map_err(|e| format!("setns {path}: {e}"))
}

impl Drop for Hosts {
    fn drop(&mut self) {
        for h in &self.names {
            let _ = ip(&["netns", "del", &self.ns(h)]);
        }
    }
}

/// A capture running until [`Capture::bytes`].
pub struct Capture {
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<Result<Vec<u8>, String>>,
}

impl Capture {
    /// Stops and returns every captured frame, concatenated.
    pub fn bytes(self) -> Vec<u8> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread
            .join()
            .expect("capture thread")
            .expect("capture on the bridge")
    }
}

/// Every frame on the interfaces of the calling thread's namespace until
/// `stop`.
fn capture_on_bridge(stop: &AtomicBool) -> Result<Vec<u8>, String> {
    use nix::sys::socket::{
        recv, socket, AddressFamily, MsgFlags, SockFlag, SockProtocol, SockType,
    };
    let sock = socket(
        AddressFamily::Packet,
        SockType::Raw,
        SockFlag::empty(),
        SockProtocol::EthAll,
    )
    .map_err(|e| format!("packet socket: {e}"))?;
    nix::sys::socket::setsockopt(
        &sock,
        nix::sys::socket::sockopt::ReceiveTimeout,
        &nix::sys::time::TimeVal::new(0, 100_000),
    )
    .map_err(|e| format!("timeout: {e}"))?;
    let mut all = Vec::new();
    let mut buf = vec![0u8; 65536];
    while !stop.load(Ordering::Relaxed) {
        match recv(
            std::os::fd::AsRawFd::as_raw_fd(&sock),
            &mut buf,
            MsgFlags::empty(),
        ) {
            Ok(n) => all.extend_from_slice(&buf[..n]),
            Err(nix::errno::Errno::EAGAIN | nix::errno::Errno::EINTR) => {}
            Err(e) => return Err(format!("recv: {e}")),
        }
    }
    Ok(all)
}
