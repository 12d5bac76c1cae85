//! The Modbus TCP link to the conveyor PLC: a task that owns the connection,
//! polls the discrete inputs of the [`IoMap`] every poll period, writes
//! coils on command, and reconnects by itself. Everything that goes wrong
//! (refused or lost connection, timeout, Modbus exception, a reply that does
//! not fit the map) comes out as one [`PlcEvent::Fault`] naming the PLC, the
//! request and the cause; the task then retries every second.
//!
//! Each [`PlcEvent::Inputs`] says how many commands were carried out before
//! its read began, so a reader can tell a reading taken before its own last
//! coil write from one taken after.

use falc_equipment::{Equipment, Problems};
use falc_plc::map::{Coils, Inputs, IoMap, MapError};
use falc_plc::workstation::{Pace, PlcCommand, PlcEvent};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio_modbus::client::{Client, Context, Reader, Writer};
use tokio_modbus::Slave;

/// How long to wait before retrying after a fault.
pub const RETRY: Duration = Duration::from_secs(1);

/// The equipment and where its map sits in the PLC (shared by the
/// transport node and the twin).
#[derive(Debug, Clone, clap::Args)]
pub struct MapArgs {
    /// The equipment file (the conveyor's layout, signals and addresses);
    /// default: the station's `equipment` in the topology, else the 1992
    /// conveyor (`equipment/conveyor-1992.toml`, built in).
    #[arg(long)]
    pub equipment: Option<PathBuf>,
    /// Added to every coil address of the equipment file (for a PLC whose
    /// FALC area starts elsewhere).
    #[arg(long, default_value_t = 0)]
    pub coil_base: u16,
    /// Added to every discrete input address of the equipment file.
    #[arg(long, default_value_t = 0)]
    pub input_base: u16,
}

impl MapArgs {
    /// The equipment: `--equipment`, else `stanza` (the topology's), else
    /// the 1992 conveyor. Every problem of the file names its line.
    pub fn equipment(&self, stanza: Option<&Path>) -> Result<Arc<Equipment>, Problems> {
        Equipment::of_stanza(self.equipment.as_deref().or(stanza))
    }

    /// The map of the equipment ([`MapArgs::equipment`]).
    pub fn map(&self, stanza: Option<&Path>) -> Result<IoMap, String> {
        let equipment = self.equipment(stanza).map_err(|e| e.to_string())?;
        IoMap::new(equipment, self.coil_base, self.input_base).map_err(|e: MapError| e.to_string())
    }
}

/// How to reach the PLC.
#[derive(Debug, Clone, clap::Args)]
pub struct PlcArgs {
    /// The PLC's Modbus TCP address (host:port); default: the topology's
    /// `device` of this station.
    #[arg(long)]
    pub plc: Option<String>,
    /// Modbus unit (slave) id.
    #[arg(long, default_value_t = 1)]
    pub unit: u8,
    /// Poll period of the discrete inputs while a recipe runs, in ms.
    #[arg(long, default_value_t = falc_plc::workstation::POLL_MS)]
    pub poll_ms: u64,
    /// Poll period while no recipe runs, in ms (an idle cell costs little;
    /// an emergency stop or a lost PLC is still seen within this).
    #[arg(long, default_value_t = falc_plc::workstation::IDLE_POLL_MS)]
    pub idle_poll_ms: u64,
    /// How long one Modbus request may take, in ms.
    #[arg(long, default_value_t = 500)]
    pub modbus_timeout_ms: u64,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub map: MapArgs,
}

/// Settings of the link.
#[derive(Debug, Clone)]
pub struct PlcSettings {
    /// host:port.
    pub address: String,
    /// Modbus unit id.
    pub unit: u8,
    /// The I/O map.
    pub map: IoMap,
    /// Poll period while busy (a recipe runs).
    pub poll: Duration,
    /// Poll period while idle.
    pub idle_poll: Duration,
    /// Per-request limit.
    pub timeout: Duration,
}

impl PlcArgs {
    /// The settings, with `device` and `equipment` (the topology's) as
    /// the defaults.
    pub fn settings(
        &self,
        device: Option<String>,
        equipment: Option<&Path>,
    ) -> Result<PlcSettings, String> {
        let address = self
            .plc
            .clone()
            .or(device)
            .ok_or("no PLC address: give --plc HOST:PORT or a `device` in the topology")?;
        if self.poll_ms == 0 {
            return Err("--poll-ms must be at least 1".into());
        }
        Ok(PlcSettings {
            address,
            unit: self.unit,
            map: self.map.map(equipment)?,
            poll: Duration::from_millis(self.poll_ms),
            idle_poll: Duration::from_millis(self.idle_poll_ms.max(self.poll_ms)),
            timeout: Duration::from_millis(self.modbus_timeout_ms.max(1)),
        })
    }
}

/// The link task's two ends.
#[derive(Debug)]
pub struct PlcHandle {
    /// Commands in.
    pub commands: mpsc::UnboundedSender<PlcCommand>,
    /// Events out.
    pub events: mpsc::UnboundedReceiver<PlcEvent>,
}

/// Starts the link task.
pub fn spawn(settings: PlcSettings) -> PlcHandle {
    let (commands, rx) = mpsc::unbounded_channel();
    let (tx, events) = mpsc::unbounded_channel();
    tokio::spawn(Link::new(settings, tx).run(rx));
    PlcHandle { commands, events }
}

/// A Modbus client error in words (a closed socket reads as "Success").
fn describe(e: &tokio_modbus::Error) -> String {
    use std::io::ErrorKind;
    match e {
        tokio_modbus::Error::Transport(io)
            if io.raw_os_error() == Some(0)
                || matches!(
                    io.kind(),
                    ErrorKind::UnexpectedEof | ErrorKind::ConnectionReset | ErrorKind::BrokenPipe
                ) =>
        {
            "the PLC closed the connection".into()
        }
        other => other.to_string(),
    }
}

struct Link {
    s: PlcSettings,
    events: mpsc::UnboundedSender<PlcEvent>,
    done: u64,
    last: Option<Inputs>,
    fault: Option<String>,
    pace: Pace,
}

/// Why one request failed, and whether the connection is still usable.
struct Failure {
    why: String,
    connection_lost: bool,
}

impl Link {
    fn new(s: PlcSettings, events: mpsc::UnboundedSender<PlcEvent>) -> Self {
        Self {
            s,
            events,
            done: 0,
            last: None,
            fault: None,
            pace: Pace::Idle,
        }
    }

    fn emit(&self, e: PlcEvent) -> bool {
        self.events.send(e).is_ok()
    }

    /// Reports a fault once (the same fault again stays quiet).
    fn fault(&mut self, why: String) -> bool {
        if self.fault.as_ref() != Some(&why) {
            tracing::warn!("{why}");
            self.fault = Some(why.clone());
            self.last = None;
            return self.emit(PlcEvent::Fault(why));
        }
        true
    }

    async fn connect(&self) -> Result<Context, String> {
        let who = format!("no connection with the conveyor PLC at {}", self.s.address);
        let addr: SocketAddr = tokio::net::lookup_host(&self.s.address)
            .await
            .map_err(|e| format!("{who}: {e}"))?
            .next()
            .ok_or_else(|| format!("{who}: the name resolves to no address"))?;
        match tokio::time::timeout(
            self.s.timeout,
            tokio_modbus::client::tcp::connect_slave(addr, Slave(self.s.unit)),
        )
        .await
        {
            Ok(Ok(ctx)) => Ok(ctx),
            Ok(Err(e)) => Err(format!("{who}: {e}")),
            Err(_) => Err(format!(
                "{who}: connect timed out after {:?}",
                self.s.timeout
            )),
        }
    }

    /// Carries out one request against the PLC, bounded by the timeout.
    async fn call<T, F>(&self, what: String, f: F) -> Result<T, Failure>
    where
        F: std::future::Future<Output = tokio_modbus::Result<T>>,
    {
        let at = &self.s.address;
        match tokio::time::timeout(self.s.timeout, f).await {
            Ok(Ok(Ok(v))) => Ok(v),
            Ok(Ok(Err(exception))) => Err(Failure {
                why: format!(
                    "the conveyor PLC at {at} answered {what} with Modbus exception {exception}"
                ),
                connection_lost: false,
            }),
            Ok(Err(e)) => Err(Failure {
                why: format!(
                    "connection with the conveyor PLC at {at} lost during {what}: {}",
                    describe(&e)
                ),
                connection_lost: true,
            }),
            Err(_) => Err(Failure {
                why: format!(
                    "the conveyor PLC at {at} did not answer {what} within {:?}",
                    self.s.timeout
                ),
                connection_lost: true,
            }),
        }
    }

    async fn write(&self, ctx: &mut Context, c: &PlcCommand) -> Result<(), Failure> {
        let map = &self.s.map;
        match c {
            PlcCommand::Write(coil, value) => {
                let Some(addr) = map.coil(*coil) else {
                    return Err(Failure {
                        why: format!("{coil} is not in the I/O map"),
                        connection_lost: false,
                    });
                };
                let what = format!("the write of {coil} := {} (coil {addr})", u8::from(*value));
                self.call(what, ctx.write_single_coil(addr, *value)).await
            }
            PlcCommand::Pace(_) | PlcCommand::Read => Ok(()),
            PlcCommand::WriteAll(values) => {
                // One write per run of consecutive addresses: an address
                // between the equipment's coils is not FALC's to write.
                let runs = map.coil_runs(values);
                let all = if runs.len() == 1 {
                    "all coils"
                } else {
                    "coils"
                };
                for (start, run) in runs {
                    let what = format!(
                        "the write of {all} {start}..{}",
                        usize::from(start) + run.len() - 1
                    );
                    self.call(what, ctx.write_multiple_coils(start, &run))
                        .await?;
                }
                Ok(())
            }
        }
    }

    /// The coils of the map as the PLC holds them.
    async fn read_coils(&self, ctx: &mut Context) -> Result<Coils, Failure> {
        let (base, n) = self.s.map.coil_span();
        let what = format!(
            "the read of coils {base}..{}",
            usize::from(base) + usize::from(n) - 1
        );
        let bits = self.call(what, ctx.read_coils(base, n)).await?;
        self.s.map.coils_from_wire(&bits).map_err(|e| Failure {
            why: format!("the conveyor PLC at {}: {e}", self.s.address),
            connection_lost: false,
        })
    }

    async fn read(&self, ctx: &mut Context) -> Result<Inputs, Failure> {
        let (base, n) = self.s.map.input_span();
        let what = format!(
            "the read of discrete inputs {base}..{}",
            usize::from(base) + usize::from(n) - 1
        );
        let bits = self.call(what, ctx.read_discrete_inputs(base, n)).await?;
        self.s.map.inputs_from_wire(&bits).map_err(|e| Failure {
            why: format!("the conveyor PLC at {}: {e}", self.s.address),
            connection_lost: false,
        })
    }

    /// Waits out a retry period, dropping commands that cannot be carried out.
    async fn pause(&mut self, rx: &mut mpsc::UnboundedReceiver<PlcCommand>) -> bool {
        let until = tokio::time::Instant::now() + RETRY;
        loop {
            tokio::select! {
                c = rx.recv() => match c {
                    Some(PlcCommand::Pace(p)) => self.pace = p,
                    Some(c) => {
                        tracing::warn!(?c, "PLC link down: command dropped");
                        self.done += 1;
                    }
                    None => return false,
                },
                _ = tokio::time::sleep_until(until) => return true,
            }
        }
    }

    async fn run(mut self, mut rx: mpsc::UnboundedReceiver<PlcCommand>) {
        loop {
            let mut ctx = match self.connect().await {
                Ok(ctx) => ctx,
                Err(why) => {
                    if !self.fault(why) || !self.pause(&mut rx).await {
                        return;
                    }
                    continue;
                }
            };
            tracing::info!(address = %self.s.address, "connected to the conveyor PLC");
            let coils = match self.read_coils(&mut ctx).await {
                Ok(coils) => Some(coils),
                Err(f) if f.connection_lost => {
                    if !self.fault(f.why) || !self.pause(&mut rx).await {
                        return;
                    }
                    continue;
                }
                Err(f) => {
                    tracing::warn!("{}: the coils are taken as unknown", f.why);
                    None
                }
            };
            if !self.emit(PlcEvent::Connected { coils }) {
                return;
            }
            self.last = None;
            let period = |pace: Pace| match pace {
                Pace::Busy => self.s.poll,
                Pace::Idle => self.s.idle_poll,
            };
            let mut tick = tokio::time::interval(period(self.pace));
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            let failure = loop {
                let mut wrote = false;
                tokio::select! {
                    biased;
                    c = rx.recv() => {
                        let Some(c) = c else { return };
                        let mut next = Some(c);
                        let mut failed = None;
                        while let Some(c) = next.take() {
                            if let PlcCommand::Pace(p) = c {
                                // Not a write: not counted in `done`.
                                if p != self.pace {
                                    self.pace = p;
                                    tick = tokio::time::interval(period(p));
                                    tick.set_missed_tick_behavior(
                                        tokio::time::MissedTickBehavior::Delay,
                                    );
                                }
                                next = rx.try_recv().ok();
                                continue;
                            }
                            let r = self.write(&mut ctx, &c).await;
                            self.done += 1;
                            if let Err(f) = r {
                                failed = Some(f);
                                break;
                            }
                            next = rx.try_recv().ok();
                        }
                        if let Some(f) = failed {
                            break f;
                        }
                        wrote = true;
                    }
                    _ = tick.tick() => {}
                }
                let done = self.done;
                match self.read(&mut ctx).await {
                    Ok(inputs) => {
                        self.fault = None;
                        if wrote || self.last.as_ref() != Some(&inputs) {
                            self.last = Some(inputs.clone());
                            if !self.emit(PlcEvent::Inputs {
                                inputs,
                                commands_done: done,
                            }) {
                                return;
                            }
                        }
                    }
                    Err(f) => break f,
                }
            };
            if !self.fault(failure.why) {
                return;
            }
            if failure.connection_lost {
                drop(ctx);
                if !self.pause(&mut rx).await {
                    return;
                }
                continue;
            }
            // The PLC refused a request but the connection stands: retry
            // after the pause on a fresh connection all the same (a clean
            // start for both ends).
            let _ = ctx.disconnect().await;
            if !self.pause(&mut rx).await {
                return;
            }
        }
    }
}
