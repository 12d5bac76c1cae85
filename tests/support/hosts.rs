//! The cell as separate hosts on one machine: a network namespace per PC
//! (router, operator, cell, welding, transport), each joined to a bridge in
//! the router's namespace by a veth link of its own, addresses in
//! 10.77.0.0/24 inside those namespaces only. Links can be cut and mended
//! from the router's side, and the bridge's traffic captured. Everything is
//! removed on drop (deleting a namespace deletes its links). Needs root.

use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// The PCs, each a namespace; the router's holds the bridge.
pub const HOSTS: [&str; 5] = ["router", "operator", "cell", "welding", "transport"];

/// The router's address on the bridge.
pub const ROUTER_ADDRESS: &str = "10.77.0.1";

/// The namespaces of one test.
pub struct Hosts {
    prefix: String,
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
        let hosts = Hosts {
            prefix: format!("falc{}", std::process::id()),
        };
        // Hosts drops (and deletes what exists) if any step fails.
        for h in HOSTS {
            ip(&["netns", "add", &hosts.ns(h)])?;
            ip(&["-n", &hosts.ns(h), "link", "set", "lo", "up"])?;
        }
        let r = hosts.ns("router");
        ip(&["-n", &r, "link", "add", "br0", "type", "bridge"])?;
        ip(&[
            "-n",
            &r,
            "addr",
            "add",
            &format!("{ROUTER_ADDRESS}/24"),
            "dev",
            "br0",
        ])?;
        ip(&["-n", &r, "link", "set", "br0", "up"])?;
        for (i, h) in HOSTS.iter().enumerate().skip(1) {
            let ns = hosts.ns(h);
            let port = Self::port_of(h);
            ip(&[
                "link", "add", "name", "eth0", "netns", &ns, "type", "veth", "peer", "name", &port,
                "netns", &r,
            ])?;
            ip(&["-n", &r, "link", "set", &port, "master", "br0", "up"])?;
            let address = format!("10.77.0.{}/24", 10 + i);
            ip(&["-n", &ns, "addr", "add", &address, "dev", "eth0"])?;
            ip(&["-n", &ns, "link", "set", "eth0", "up"])?;
        }
        Ok(hosts)
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

    fn set_port(&self, host: &str, state: &str) {
        let router = self.ns("router");
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

    /// Sends `text` in clear from `host` to `address` over TCP (what the
    /// capture must see, so that a capture without the cell's texts means
    /// something).
    pub fn send_in_clear(&self, host: &str, address: &str, text: &str) {
        let path = self.ns_path(host);
        let (address, text) = (address.to_string(), text.to_string());
        let sent = std::thread::spawn(move || -> Result<(), String> {
            use std::io::Write;
            enter(&path)?;
            let mut stream =
                std::net::TcpStream::connect(&address).map_err(|e| format!("{address}: {e}"))?;
            stream
                .write_all(text.as_bytes())
                .map_err(|e| format!("write: {e}"))
        })
        .join()
        .expect("sending thread");
        if let Err(e) = sent {
            panic!("cannot send in clear from {host}: {e}");
        }
    }

    fn ns_path(&self, host: &str) -> String {
        format!("/var/run/netns/{}", self.ns(host))
    }
}

/// Moves the calling thread (only it) into the network namespace at `path`.
fn enter(path: &str) -> Result<(), String> {
    let file = std::fs::File::open(path).map_err(|e| format!("{path}: {e}"))?;
    nix::sched::setns(&file, nix::sched::CloneFlags::CLONE_NEWNET)
        .map_err(|e| format!("setns {path}: {e}"))
}

impl Drop for Hosts {
    fn drop(&mut self) {
        for h in HOSTS {
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
