//! `falc-plc-sim`: the digital twin of the conveyor PLC, a Modbus TCP
//! server (tokio-modbus) that honours FALC's I/O map (`falc_plc::map`)
//! and moves two carriers over the conveyor map of `falc_plc::conveyor`, travel times
//! divided by `--time-scale`.
//!
//! On stdout: `falc-plc-sim listening on HOST:PORT`, then one line per
//! event (coil writes with the time since the last input change as
//! `reaction_us`, carriers leaving and arriving, lines stopping).
//!
//! Control lines on stdin (answered `ok …` or `error …`): `estop`,
//! `estop-clear`, `jam <line>`, `unjam <line>`, `stuck <place> 0|1`,
//! `unstuck <place>`, `offline` (connections dropped and refused),
//! `online`, `mute` (requests get no answer), `unmute`, `layout <spot>…`
//! (carrier 1 first, e.g. `layout W2 W2`, `layout S3 W3`), `show`.

use anyhow::{Context as _, Result};
use clap::Parser;
use falc_model::ids::Place;
use falc_node::plc_link::MapArgs;
use falc_node::say;
use falc_plc::conveyor::{Control, Conveyor, Spot};
use falc_plc::map::{IoMap, COILS, INPUTS, LINES};
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
    /// Where the carriers start, carrier 1 first (W2–W6 places, S1–S3 stations).
    #[arg(long, default_value = "W2 W2")]
    layout: String,
    #[command(flatten)]
    map: MapArgs,
}

fn parse_layout(s: &str) -> Result<Vec<Spot>, String> {
    s.split_whitespace()
        .map(|w| {
            Spot::parse(w).ok_or_else(|| format!("`{w}` is not a place W2–W6 or station S1–S3"))
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
            Request::ReadDiscreteInputs(addr, n) => in_range(addr, n, self.map.input_base, INPUTS)
                .map(|o| {
                    let bits = self.conveyor.inputs();
                    Response::ReadDiscreteInputs(bits.bits()[o..o + usize::from(n)].to_vec())
                }),
            Request::ReadCoils(addr, n) => in_range(addr, n, self.map.coil_base, COILS).map(|o| {
                Response::ReadCoils(self.conveyor.coils()[o..o + usize::from(n)].to_vec())
            }),
            Request::WriteSingleCoil(addr, v) => {
                in_range(addr, 1, self.map.coil_base, COILS).map(|o| {
                    self.conveyor.write_coil(now, o as u16, v);
                    Response::WriteSingleCoil(addr, v)
                })
            }
            Request::WriteMultipleCoils(addr, values) => {
                let n = u16::try_from(values.len()).unwrap_or(u16::MAX);
                in_range(addr, n, self.map.coil_base, COILS).map(|o| {
                    for (i, v) in values.iter().enumerate() {
                        self.conveyor.write_coil(now, (o + i) as u16, *v);
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

/// The offset of `addr..addr+n` inside a block of `size` at `base`.
fn in_range(addr: u16, n: u16, base: u16, size: u16) -> Result<usize, ExceptionCode> {
    let o = addr
        .checked_sub(base)
        .ok_or(ExceptionCode::IllegalDataAddress)?;
    if n == 0 || u32::from(o) + u32::from(n) > u32::from(size) {
        return Err(ExceptionCode::IllegalDataAddress);
    }
    Ok(usize::from(o))
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

fn parse_control(line: &str) -> Result<Ctl, String> {
    let words: Vec<&str> = line.split_whitespace().collect();
    let line_letter = |s: &str| {
        let c = s.chars().next().map(|c| c.to_ascii_uppercase());
        match c {
            Some(c) if s.len() == 1 && LINES.contains(&c) => Ok(c),
            _ => Err(format!("`{s}` is not a line (A–H, J–L)")),
        }
    };
    let place = Place::parse;
    Ok(match words.as_slice() {
        ["estop"] => Ctl::Conveyor(Control::EStop),
        ["estop-clear"] => Ctl::Conveyor(Control::EStopClear),
        ["jam", l] => Ctl::Conveyor(Control::Jam(line_letter(l)?)),
        ["unjam", l] => Ctl::Conveyor(Control::Unjam(line_letter(l)?)),
        ["stuck", p, v] => Ctl::Conveyor(Control::Stuck(
            place(p)?,
            match *v {
                "0" => false,
                "1" => true,
                _ => return Err(format!("`{v}` is not 0 or 1")),
            },
        )),
        ["unstuck", p] => Ctl::Conveyor(Control::Unstuck(place(p)?)),
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
    let layout = parse_layout(&cli.layout).map_err(anyhow::Error::msg)?;
    let conveyor = Conveyor::new(&layout, cli.time_scale).map_err(anyhow::Error::msg)?;
    let twin = Arc::new(Mutex::new(Twin {
        conveyor,
        origin: Instant::now(),
        map: cli.map.map()?,
        mute: false,
    }));
    let changed = Arc::new(Notify::new());
    let service = Service {
        twin: twin.clone(),
        changed: changed.clone(),
    };
    let (addr, task) = go_online(cli.listen, service.clone()).await?;
    let mut server = Some(task);
    say(&format!("falc-plc-sim listening on {addr}"));
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
                    let answer = match parse_control(line) {
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
