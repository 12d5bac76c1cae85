//! The gateway's front door: every OPC UA client connects here first, and
//! the front knows its address. async-opcua 0.19 gives neither its
//! authenticator nor its session limits a client's address, so the front
//! accepts on the public address, counts per client address (connections
//! open, new connections in the last minute, failed logins), refuses an
//! address over a limit before it costs a handshake, and hands every
//! connection it admits on to the server listening on a loopback port of
//! its own (`Server::run_with`; the endpoint URLs still name the public
//! address, so clients see nothing of it).
//!
//! A failed login is learned of by the task it runs in: async-opcua runs
//! each connection in a tokio task of its own and opens its
//! "Establish TCP channel" span in that task first thing, so
//! [`ConnectionTasks`] (a tracing layer) hears the task of each connection
//! the front hands on, one at a time; the authenticator, running in that
//! same task, asks [`Clients::login_key`] whose login it checks.
//!
//! [`Admission`] is the sans-I/O core (the clock passed in); [`serve`] the
//! driver.

use crate::throttle::{LoginThrottle, Verdict};
use std::collections::{HashMap, VecDeque};
use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;

/// Connections one client address may hold open at once, by default.
pub const PER_ADDRESS: u32 = 10;
/// New connections one client address may open in a minute, by default
/// (a client asking for the endpoints and then logging in opens two).
pub const PER_MINUTE: u32 = 300;
/// The window of [`Limits::per_minute`].
const MINUTE: Duration = Duration::from_secs(60);
/// How long the front waits to hear which task the server runs a
/// connection in (it takes well under a millisecond).
const TASK_WAIT: Duration = Duration::from_secs(2);
/// The login key of a connection whose task the front did not hear of.
pub const NO_ADDRESS: &str = "(address unknown)";
/// The name of the span async-opcua opens first in each connection's task.
const CONNECTION_SPAN: &str = "Establish TCP channel";

/// OPC UA's status for a client refused for its connections
/// (BadTcpServerTooBusy) and for its failed logins (BadUserAccessDenied).
const TOO_BUSY: u32 = 0x807D_0000;
const ACCESS_DENIED: u32 = 0x801F_0000;

/// The OPC UA TCP Error message (OPC 10000-6, 7.1.2.5) a refused client
/// is sent before the front closes its connection: its status and why.
pub fn error_message(why: Refusal) -> Vec<u8> {
    let status = match why {
        Refusal::Locked(_) => ACCESS_DENIED,
        Refusal::Open(_) | Refusal::Fast(_) => TOO_BUSY,
    };
    let reason = format!("refused by falc-opcua: {why}");
    let len = u32::try_from(reason.len()).unwrap_or(0);
    let size = 16 + len;
    let mut m = Vec::with_capacity(size as usize);
    m.extend_from_slice(b"ERRF");
    m.extend_from_slice(&size.to_le_bytes());
    m.extend_from_slice(&status.to_le_bytes());
    m.extend_from_slice(&len.to_le_bytes());
    m.extend_from_slice(reason.as_bytes());
    m
}

/// The per-address limits.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Connections open at once.
    pub per_address: u32,
    /// New connections in any minute.
    pub per_minute: u32,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            per_address: PER_ADDRESS,
            per_minute: PER_MINUTE,
        }
    }
}

/// Why the front refused a connection.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// The address holds this many connections open already.
    Open(u32),
    /// The address opened this many in the last minute.
    Fast(u32),
    /// The address failed too many logins: refused for this long yet.
    Locked(Duration),
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refusal::Open(n) => write!(f, "it holds {n} connections open already (the limit)"),
            Refusal::Fast(n) => write!(
                f,
                "it opened {n} connections in the last minute (the limit)"
            ),
            Refusal::Locked(left) => write!(
                f,
                "it failed {} logins: refused for {} s more",
                crate::throttle::LOCK_AFTER,
                left.as_secs().max(1)
            ),
        }
    }
}

#[derive(Debug, Default)]
struct Address {
    open: u32,
    opened: VecDeque<Instant>,
}

/// Every client address's connections and failed logins (sans-I/O).
#[derive(Debug)]
pub struct Admission {
    limits: Limits,
    addresses: HashMap<IpAddr, Address>,
    logins: LoginThrottle,
}

impl Admission {
    /// Nothing counted yet; an address failing too many logins is locked
    /// for `lockout`.
    pub fn new(limits: Limits, lockout: Duration) -> Self {
        Self {
            limits,
            addresses: HashMap::new(),
            logins: LoginThrottle::new(lockout),
        }
    }

    /// A connection from `ip` at `now`: admitted (and counted until
    /// [`Self::closed`]) or refused.
    pub fn admit(&mut self, now: Instant, ip: IpAddr) -> Result<(), Refusal> {
        if let Verdict::Locked(left) = self.logins.check(now, &ip.to_string()) {
            return Err(Refusal::Locked(left));
        }
        self.addresses
            .retain(|_, a| a.open > 0 || a.opened.back().is_some_and(|t| now - *t < MINUTE));
        let a = self.addresses.entry(ip).or_default();
        while a.opened.front().is_some_and(|t| now - *t >= MINUTE) {
            a.opened.pop_front();
        }
        if a.open >= self.limits.per_address {
            return Err(Refusal::Open(a.open));
        }
        let opened = u32::try_from(a.opened.len()).unwrap_or(u32::MAX);
        if opened >= self.limits.per_minute {
            return Err(Refusal::Fast(opened));
        }
        a.open += 1;
        a.opened.push_back(now);
        Ok(())
    }

    /// A connection from `ip` ended.
    pub fn closed(&mut self, ip: IpAddr) {
        if let Some(a) = self.addresses.get_mut(&ip) {
            a.open = a.open.saturating_sub(1);
        }
    }

    /// Before a login by the client of `key` (its address) is checked.
    pub fn check_login(&mut self, now: Instant, key: &str) -> Verdict {
        self.logins.check(now, key)
    }

    /// A login of `key` failed: its failures in a row, and how long to
    /// wait before answering ([`LoginThrottle::failed`]).
    pub fn failed_login(&mut self, now: Instant, key: &str) -> (u32, Duration) {
        self.logins.failed(now, key)
    }
}

/// The front's counts shared with the authenticator, and which connection
/// task serves which client address.
#[derive(Debug)]
pub struct Clients {
    admission: Mutex<Admission>,
    tasks: Mutex<HashMap<tokio::task::Id, IpAddr>>,
}

impl Clients {
    /// Nothing counted yet.
    pub fn new(limits: Limits, lockout: Duration) -> Self {
        Self {
            admission: Mutex::new(Admission::new(limits, lockout)),
            tasks: Mutex::new(HashMap::new()),
        }
    }

    fn with<T>(&self, f: impl FnOnce(&mut Admission) -> T) -> Option<T> {
        self.admission.lock().ok().map(|mut a| f(&mut a))
    }

    /// The address whose login the calling task checks (the server's
    /// connection task), as the login throttle's key; [`NO_ADDRESS`] for a
    /// task the front did not hand on.
    pub fn login_key(&self) -> String {
        tokio::task::try_id()
            .and_then(|t| self.tasks.lock().ok()?.get(&t).copied())
            .map_or_else(|| NO_ADDRESS.to_string(), |ip| ip.to_string())
    }

    /// [`Admission::check_login`] now.
    pub fn check_login(&self, key: &str) -> Verdict {
        self.with(|a| a.check_login(Instant::now(), key))
            .unwrap_or(Verdict::Check)
    }

    /// [`Admission::failed_login`] now.
    pub fn failed_login(&self, key: &str) -> (u32, Duration) {
        self.with(|a| a.failed_login(Instant::now(), key))
            .unwrap_or((0, crate::throttle::MAX_DELAY))
    }

    fn task(&self, task: tokio::task::Id, ip: Option<IpAddr>) {
        if let Ok(mut t) = self.tasks.lock() {
            match ip {
                Some(ip) => t.insert(task, ip),
                None => t.remove(&task),
            };
        }
    }
}

/// A tracing layer telling the front the task of each connection the
/// server starts (filter it with [`ConnectionTasks::filter`], so that
/// nothing else reaches it).
pub struct ConnectionTasks(mpsc::UnboundedSender<tokio::task::Id>);

impl ConnectionTasks {
    /// The layer, and where the tasks it hears of arrive.
    pub fn new() -> (Self, mpsc::UnboundedReceiver<tokio::task::Id>) {
        let (tx, rx) = mpsc::unbounded_channel();
        (Self(tx), rx)
    }

    /// Lets only async-opcua's connection span through.
    pub fn filter(m: &tracing::Metadata<'_>) -> bool {
        m.is_span() && m.name() == CONNECTION_SPAN && m.target().starts_with("opcua_server")
    }
}

impl<S: tracing::Subscriber> tracing_subscriber::Layer<S> for ConnectionTasks {
    fn on_new_span(
        &self,
        attrs: &tracing::span::Attributes<'_>,
        _id: &tracing::span::Id,
        _ctx: tracing_subscriber::layer::Context<'_, S>,
    ) {
        if Self::filter(attrs.metadata()) {
            if let Some(task) = tokio::task::try_id() {
                let _ = self.0.send(task);
            }
        }
    }
}

/// Refused connections being told why at once, at most; beyond these a
/// refused connection is closed without a word.
const REFUSING: usize = 64;
/// How long a refused client's Hello is waited for before it is told why.
const HELLO_WAIT: Duration = Duration::from_secs(1);

/// Tells a refused client why, as the answer to its Hello (a client that
/// hears an Error before it said Hello may miss it and wait out its own
/// timeout), then closes its connection.
fn refuse(mut client: TcpStream, why: Refusal, refusing: &Arc<tokio::sync::Semaphore>) {
    let Ok(permit) = refusing.clone().try_acquire_owned() else {
        return;
    };
    tokio::spawn(async move {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let mut hello = [0u8; 256];
        let _ = tokio::time::timeout(HELLO_WAIT, client.read(&mut hello)).await;
        let _ = client.write_all(&error_message(why)).await;
        let _ = client.shutdown().await;
        drop(permit);
    });
}

/// Accepts clients on `public`, admits them by [`Clients`], and hands each
/// one admitted on to the server at `inner` (on loopback), one at a time
/// so that the task the server starts for it is known. Runs until it is
/// aborted.
pub async fn serve(
    public: TcpListener,
    inner: SocketAddr,
    clients: Arc<Clients>,
    mut tasks: mpsc::UnboundedReceiver<tokio::task::Id>,
) {
    let refusing = Arc::new(tokio::sync::Semaphore::new(REFUSING));
    loop {
        let (client, peer) = match public.accept().await {
            Ok(c) => c,
            Err(e) => {
                // Out of file descriptors and the like: wait, then go on.
                falc_bus::log_limit::warn("opcua front", &format!("cannot accept a client: {e}"));
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let ip = peer.ip();
        let admitted = clients
            .with(|a| a.admit(Instant::now(), ip))
            .unwrap_or(Ok(()));
        if let Err(why) = admitted {
            falc_bus::log_limit::warn(
                &format!("opcua front {ip}"),
                &format!("OPC UA client {ip} refused: {why}"),
            );
            refuse(client, why, &refusing);
            continue;
        }
        // A task heard of after its wait timed out belongs to nobody now.
        while tasks.try_recv().is_ok() {}
        let server = match TcpStream::connect(inner).await {
            Ok(s) => s,
            Err(e) => {
                clients.with(|a| a.closed(ip));
                tracing::error!("the OPC UA server at {inner} does not take a connection: {e}");
                continue;
            }
        };
        let task = match tokio::time::timeout(TASK_WAIT, tasks.recv()).await {
            Ok(Some(task)) => {
                clients.task(task, Some(ip));
                Some(task)
            }
            _ => {
                falc_bus::log_limit::warn(
                    "opcua front task",
                    &format!(
                        "the OPC UA server's task for client {ip} was not heard of: its failed logins count as {NO_ADDRESS}"
                    ),
                );
                None
            }
        };
        let clients = clients.clone();
        tokio::spawn(async move {
            let _ = client.set_nodelay(true);
            let _ = server.set_nodelay(true);
            let (mut client, mut server) = (client, server);
            let _ = tokio::io::copy_bidirectional(&mut client, &mut server).await;
            if let Some(task) = task {
                clients.task(task, None);
            }
            clients.with(|a| a.closed(ip));
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::throttle::LOCK_AFTER;

    fn ip(s: &str) -> IpAddr {
        s.parse().expect("address")
    }

    #[test]
    fn an_address_may_hold_so_many_connections_open_and_open_so_many_a_minute() {
        let t0 = Instant::now();
        let mut a = Admission::new(
            Limits {
                per_address: 2,
                per_minute: 3,
            },
            Duration::from_secs(60),
        );
        let (x, y) = (ip("10.0.0.2"), ip("10.0.0.3"));
        assert_eq!(a.admit(t0, x), Ok(()));
        assert_eq!(a.admit(t0, x), Ok(()));
        assert_eq!(a.admit(t0, x), Err(Refusal::Open(2)));
        // Another address is counted apart.
        assert_eq!(a.admit(t0, y), Ok(()));
        a.closed(x);
        assert_eq!(a.admit(t0, x), Ok(()));
        a.closed(x);
        a.closed(x);
        // Three opened this minute: the fourth waits for the window.
        assert_eq!(a.admit(t0, x), Err(Refusal::Fast(3)));
        let later = t0 + MINUTE;
        assert_eq!(a.admit(later, x), Ok(()));
        a.closed(x);
        // The closed ones are open no more; the minute counts all three.
        assert_eq!(a.admit(later, x), Ok(()));
        assert_eq!(a.admit(later, x), Ok(()));
        assert_eq!(a.admit(later, x), Err(Refusal::Open(2)));
        a.closed(x);
        assert_eq!(a.admit(later, x), Err(Refusal::Fast(3)));
    }

    #[test]
    fn failed_logins_lock_their_address_only_and_the_lock_ends() {
        let t0 = Instant::now();
        let lockout = Duration::from_secs(30);
        let mut a = Admission::new(Limits::default(), lockout);
        let (bad, good) = (ip("127.0.0.2"), ip("127.0.0.1"));
        for n in 1..=LOCK_AFTER {
            assert_eq!(a.check_login(t0, &bad.to_string()), Verdict::Check);
            assert_eq!(a.failed_login(t0, &bad.to_string()).0, n);
        }
        assert!(matches!(
            a.check_login(t0, &bad.to_string()),
            Verdict::Locked(_)
        ));
        assert_eq!(a.admit(t0, bad), Err(Refusal::Locked(lockout)));
        // The other address logs in and connects as before.
        assert_eq!(a.check_login(t0, &good.to_string()), Verdict::Check);
        assert_eq!(a.admit(t0, good), Ok(()));
        // After the lockout the address may come again.
        assert_eq!(a.admit(t0 + lockout, bad), Ok(()));
        assert_eq!(
            a.check_login(t0 + lockout, &bad.to_string()),
            Verdict::Check
        );
    }

    #[test]
    fn a_refused_client_is_sent_an_opc_ua_error_message() {
        let m = error_message(Refusal::Locked(Duration::from_secs(5)));
        assert_eq!(&m[..4], b"ERRF");
        let word = |at: usize| u32::from_le_bytes([m[at], m[at + 1], m[at + 2], m[at + 3]]);
        assert_eq!(word(4) as usize, m.len());
        assert_eq!(word(8), ACCESS_DENIED);
        assert_eq!(word(12) as usize, m.len() - 16);
        let reason = std::str::from_utf8(&m[16..]).expect("text");
        assert!(reason.contains("failed 10 logins"), "{reason}");
        let busy = error_message(Refusal::Fast(60));
        assert_eq!(&busy[8..12], &TOO_BUSY.to_le_bytes());
    }

    #[test]
    fn refusals_say_why() {
        assert!(Refusal::Open(10)
            .to_string()
            .contains("10 connections open"));
        assert!(Refusal::Fast(300)
            .to_string()
            .contains("300 connections in the last minute"));
        assert!(Refusal::Locked(Duration::from_secs(42))
            .to_string()
            .contains("42 s more"));
    }
}
