//! `falc-plc-sim`: the digital twin of the conveyor PLC, a Modbus TCP
//! server (tokio-modbus) that plays the conveyor of an equipment file
//! (`--equipment FILE`, default the 1992 conveyor): its I/O map
//! (`falc_plc::map`), its carriers moved over its lines by
//! `falc_plc::conveyor`, travel times divided by `--time-scale`.
//!
//! On stdout: `falc-plc-sim of <equipment> listening on HOST:PORT`, then one line per
//! event (coil writes with the time since the last input change as
//! `reaction_us`, carriers leaving and arriving, lines stopping).
//!
//! Control lines on stdin (answered `ok …` or `error …`): `estop`,
//! `estop-clear`, `jam <line>`, `unjam <line>`, `stuck <place> 0|1`,
//! `unstuck <place>`, `stuck-lamp <line> 0|1` (its running lamp shows
//! that), `unstuck-lamp <line>`, `input <name> 0|1` (a plain input set
//! by hand: a door closed), `offline` (connections dropped and refused),
//! `online`, `mute` (requests get no answer), `unmute`, `layout <spot>…`
//! (carrier 1 first, e.g. `layout W2 W2`, `layout S3 W3`), `show`.
//!
//! A read or write must lie within the span of the equipment's coils (or
//! inputs); an address in a gap between them reads 0 and ignores writes.

use anyhow::{Context as _, Result};
use clap::Parser;
use falc_equipment::Equipment;
use falc_model::ids::{IoName, Place};
use falc_node::plc_link::MapArgs;
use falc_node::say;
use falc_plc::conveyor::{Control, Conveyor, Spot};
use falc_plc::map::IoMap;
use falc_recipe::check::{level, Signal};
use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::net::TcpListener;
use tokio::sync::Notify;
use tokio::task::JoinHandle;
use tokio::time::Instant;
use tokio_modbus::server::tcp::{accept_tcp_connection, Server};
use tokio_modbus::{ExceptionCode, Request, Response, SlaveRequest};

#[derive(Parser, Debug)]
#[command(
    version,
    about = "Digital twin of the conveyor PLC (Modbus TCP server, FALC I/O map)"
)]
struct Cli {
    /// Address to listen on (port 0: any free port, printed at start).
    #[arg(long, default_value = "127.0.0.1:5020")]
    listen: SocketAddr,
    /// Travel times are divided by this (10 = ten times faster).
    #[arg(long, default_value_t = 1.0)]
    time_scale: f64,
    /// Where the carriers start, carrier 1 first (`W3` a place, `S1` a
    /// station); default: the equipment file's `[twin] carriers`.
    #[arg(long)]
    layout: Option<String>,
    #[command(flatten)]
    map: MapArgs,
}

fn parse_layout(s: &str) -> Result<Vec<Spot>, String> {
    s.split_whitespace()
        .map(|w| {
            Spot::parse(w).ok_or_else(|| format!("`{w}` is not a place (`W3`) or a station (`S1`)"))
        })
        .collect()
}

/// The twin's state shared by the Modbus connections, the clock and stdin.
struct Twin {
    conveyor: Conveyor,
    origin: Instant,
    map: IoMap,
    mute: bool,
}

impl Twin {
    fn now(&self) -> Duration {
        self.origin.elapsed()
    }

    fn flush_notes(&mut self) {
        while let Some(n) = self.conveyor.poll_note() {
            say(&n);
        }
    }

    /// Carries out a control line that concerns the conveyor.
    fn control(&mut self, c: Ctl) -> Result<(), String> {
        let now = self.now();
        let r = match c {
            Ctl::Conveyor(c) => {
                self.conveyor.control(now, c);
                Ok(())
            }
            Ctl::Mute(m) => {
                self.mute = m;
                Ok(())
            }
            Ctl::Show => {
                self.conveyor.handle_timeout(now);
                say(&self.conveyor.describe());
                say(&format!("inputs: {}", self.conveyor.inputs()));
                say(&self.conveyor.held());
                Ok(())
            }
            Ctl::Layout(l) => self.conveyor.set_layout(&l),
            Ctl::Offline | Ctl::Online => Ok(()),
        };
        self.flush_notes();
        r
    }

    /// Serves one Modbus request; None: no answer (muted).
    fn serve(&mut self, req: Request<'_>) -> Option<Result<Response, ExceptionCode>> {
        if self.mute {
            return None;
        }
        let now = self.now();
        self.conveyor.handle_timeout(now);
        let r = match req {
            Request::ReadDiscreteInputs(addr, n) => {
                in_range(addr, n, self.map.input_span()).map(|()| {
                    let inputs = self.conveyor.inputs();
                    let mut bits = vec![false; usize::from(n)];
                    let e = self.map.equipment();
                    for (spec, on) in e.inputs().iter().zip(inputs.bits()) {
                        let a = self.map.input_base + spec.address;
                        if let Some(b) = a
                            .checked_sub(addr)
                            .and_then(|o| bits.get_mut(usize::from(o)))
                        {
                            *b = *on;
                        }
                    }
                    Response::ReadDiscreteInputs(bits)
                })
            }
            Request::ReadCoils(addr, n) => in_range(addr, n, self.map.coil_span()).map(|()| {
                let bits = (addr..addr + n)
                    .map(|a| {
                        self.map
                            .coil_at(a)
                            .is_some_and(|c| self.conveyor.coil_value(c))
                    })
                    .collect();
                Response::ReadCoils(bits)
            }),
            Request::WriteSingleCoil(addr, v) => {
                in_range(addr, 1, self.map.coil_span()).map(|()| {
                    if let Some(c) = self.map.coil_at(addr) {
                        self.conveyor.write_coil(now, c, v);
                    }
                    Response::WriteSingleCoil(addr, v)
                })
            }
            Request::WriteMultipleCoils(addr, values) => {
                let n = u16::try_from(values.len()).unwrap_or(u16::MAX);
                in_range(addr, n, self.map.coil_span()).map(|()| {
                    for (a, v) in (addr..).zip(values.iter()) {
                        if let Some(c) = self.map.coil_at(a) {
                            self.conveyor.write_coil(now, c, *v);
                        }
                    }
                    Response::WriteMultipleCoils(addr, n)
                })
            }
            _ => Err(ExceptionCode::IllegalFunction),
        };
        self.flush_notes();
        Some(r)
    }
}

fn lock(twin: &Mutex<Twin>) -> Result<std::sync::MutexGuard<'_, Twin>> {
    twin.lock()
        .map_err(|_| anyhow::anyhow!("the twin's state is poisoned (a thread panicked)"))
}

/// Whether `addr..addr+n` lies inside the span `(base, size)`.
fn in_range(addr: u16, n: u16, (base, size): (u16, u16)) -> Result<(), ExceptionCode> {
    let o = addr
        .checked_sub(base)
        .ok_or(ExceptionCode::IllegalDataAddress)?;
    if n == 0 || u32::from(o) + u32::from(n) > u32::from(size) {
        return Err(ExceptionCode::IllegalDataAddress);
    }
    Ok(())
}

#[derive(Clone)]
struct Service {
    twin: Arc<Mutex<Twin>>,
    changed: Arc<Notify>,
}

impl tokio_modbus::server::Service for Service {
    type Request = SlaveRequest<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = Pin<Box<dyn Future<Output = Result<Option<Response>, ExceptionCode>> + Send>>;

    fn call(&self, req: Self::Request) -> Self::Future {
        let answer = match self.twin.lock() {
            Ok(mut t) => t.serve(req.request),
            Err(_) => Some(Err(ExceptionCode::ServerDeviceFailure)),
        };
        self.changed.notify_one();
        Box::pin(async move {
            match answer {
                Some(r) => r.map(Some),
                // Muted: never answer (the client's timeout is what is tested).
                None => std::future::pending().await,
            }
        })
    }
}

/// Binds and serves until the returned task is aborted (offline).
async fn go_online(addr: SocketAddr, service: Service) -> Result<(SocketAddr, JoinHandle<()>)> {
    let listener = TcpListener::bind(addr)
        .await
        .with_context(|| format!("cannot listen on {addr}"))?;
    let local = listener.local_addr()?;
    let server = Server::new(listener);
    let task = tokio::spawn(async move {
        let on_connected = |stream, peer: SocketAddr| {
            let service = service.clone();
            async move {
                tracing::info!(%peer, "Modbus client connected");
                accept_tcp_connection(stream, peer, move |_| Ok(Some(service.clone())))
            }
        };
        let on_error = |e| tracing::warn!("Modbus connection: {e}");
        if let Err(e) = server.serve(&on_connected, on_error).await {
            tracing::error!("Modbus server stopped: {e}");
        }
    });
    Ok((local, task))
}

fn parse_control(line: &str, equipment: &Equipment) -> Result<Ctl, String> {
    let words: Vec<&str> = line.split_whitespace().collect();
    // A name the recipe language allows, and the equipment has.
    let line_letter = |s: &str| {
        let c = falc_recipe::check::line_letter(s)?;
        equipment.lacks_signal(Signal::Line(c)).map_or(Ok(c), Err)
    };
    let place = |s: &str| {
        let p = Place::parse(s)?;
        equipment.lacks_signal(Signal::Place(p)).map_or(Ok(p), Err)
    };
    Ok(match words.as_slice() {
        ["estop"] => Ctl::Conveyor(Control::EStop),
        ["estop-clear"] => Ctl::Conveyor(Control::EStopClear),
        ["jam", l] => Ctl::Conveyor(Control::Jam(line_letter(l)?)),
        ["unjam", l] => Ctl::Conveyor(Control::Unjam(line_letter(l)?)),
        ["stuck", p, v] => Ctl::Conveyor(Control::Stuck(place(p)?, level(v)?)),
        ["unstuck", p] => Ctl::Conveyor(Control::Unstuck(place(p)?)),
        ["stuck-lamp", l, v] => Ctl::Conveyor(Control::StuckLamp(line_letter(l)?, level(v)?)),
        ["unstuck-lamp", l] => Ctl::Conveyor(Control::UnstuckLamp(line_letter(l)?)),
        ["input", n, v] => {
            let name = IoName::parse(n)?;
            equipment
                .lacks_signal(Signal::Input(name))
                .map_or(Ok(()), Err)?;
            Ctl::Conveyor(Control::Input(name, level(v)?))
        }
        ["offline"] => Ctl::Offline,
        ["online"] => Ctl::Online,
        ["mute"] => Ctl::Mute(true),
        ["unmute"] => Ctl::Mute(false),
        ["show"] => Ctl::Show,
        ["layout", rest @ ..] => Ctl::Layout(parse_layout(&rest.join(" "))?),
        _ => return Err(format!("unknown control `{line}`")),
    })
}

enum Ctl {
    Conveyor(Control),
    Offline,
    Online,
    Mute(bool),
    Show,
    Layout(Vec<Spot>),
}

#[tokio::main]
async fn main() -> Result<()> {
    falc_node::init_tracing();
    let cli = Cli::parse();
    let map = cli.map.map(None).map_err(anyhow::Error::msg)?;
    let equipment = map.equipment().clone();
    let layout = match &cli.layout {
        Some(l) => parse_layout(l).map_err(anyhow::Error::msg)?,
        None => equipment.carriers().to_vec(),
    };
    let conveyor =
        Conveyor::new(equipment.clone(), &layout, cli.time_scale).map_err(anyhow::Error::msg)?;
    let twin = Arc::new(Mutex::new(Twin {
        conveyor,
        origin: Instant::now(),
        map,
        mute: false,
    }));
    let changed = Arc::new(Notify::new());
    let service = Service {
        twin: twin.clone(),
        changed: changed.clone(),
    };
    let (addr, task) = go_online(cli.listen, service.clone()).await?;
    let mut server = Some(task);
    // The address last: scripts take the line's last word.
    say(&format!(
        "falc-plc-sim of {} listening on {addr}",
        equipment.name()
    ));
    let mut stdin = BufReader::new(tokio::io::stdin()).lines();
    let mut stdin_open = true;
    let mut shutdown = falc_node::Shutdown::new();
    loop {
        let deadline = {
            let t = lock(&twin)?;
            t.conveyor
                .poll_timeout()
                .map_or(Instant::now() + Duration::from_secs(3600), |d| t.origin + d)
        };
        tokio::select! {
            _ = tokio::time::sleep_until(deadline) => {}
            _ = changed.notified() => {}
            line = stdin.next_line(), if stdin_open => match line {
                Ok(Some(line)) if line.trim().is_empty() => {}
                Ok(Some(line)) => {
                    let line = line.trim();
                    let answer = match parse_control(line, &equipment) {
                        Ok(Ctl::Offline) => {
                            if let Some(task) = server.take() {
                                task.abort();
                                let _ = task.await;
                            }
                            Ok(())
                        }
                        Ok(Ctl::Online) => {
                            if server.is_none() {
                                server = Some(go_online(addr, service.clone()).await?.1);
                            }
                            Ok(())
                        }
                        Ok(other) => lock(&twin)?.control(other),
                        Err(e) => Err(e),
                    };
                    match answer {
                        Ok(()) => say(&format!("ok {line}")),
                        Err(e) => say(&format!("error {e}")),
                    }
                }
                Ok(None) | Err(_) => stdin_open = false,
            },
            _ = shutdown.requested() => break,
        }
        let mut t = lock(&twin)?;
        let now = t.now();
        t.conveyor.handle_timeout(now);
        t.flush_notes();
    }
    Ok(())
}
