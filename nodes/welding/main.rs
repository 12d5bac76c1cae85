//! `falc-welding`: the welding workstation. Serves the MMS-equivalent
//! services to its commander (domains, program invocations, status), runs
//! welding recipes (`start rcm N [max_s]`, `wait rcm [max_s]`) and bridges
//! to the robot controller over the DNC serial link. Job events (done,
//! alarm, paused, bad product, failed) go up as unsolicited status.
//!
//! A thin driver: the recipe runtime is `falc_common::workstation`, the
//! rules of the link live in `host` (DNC ↔ engine) and the 3964R procedure.

mod host;

use anyhow::{Context, Result};
use clap::Parser;
use falc_common::bus::station::Station;
use falc_common::dnc::driver::{self, LineSettings};
use falc_common::dnc::procedure::{LinkEvent, Priority, Timing};
use falc_common::dnc::telegram::{Program, Telegram};
use falc_common::ids::StationName;
use falc_common::mms::vmd::{RobotStatusDetail, VmdStatus};
use falc_common::node::{init_tracing, say, NodeArgs};
use falc_common::recipe::check::Job;
use falc_common::recipe::commands::RecipeKind;
use falc_common::recipe::engine::{Action, Event};
use falc_common::workstation::{Device, Workstation};
use host::{Host, Out};
use std::time::Duration;

#[derive(Parser, Debug)]
#[command(
    version,
    about = "FALC welding workstation: recipes and the DNC link to the robot controller"
)]
struct Cli {
    /// The station this process is (a station of kind welding).
    #[arg(long, default_value = "welding")]
    station: StationName,
    /// The robot controller's serial line; the device defaults to the
    /// topology's `device` of this station.
    #[command(flatten)]
    line: falc_common::dnc::driver::LineArgs,
    #[command(flatten)]
    node: NodeArgs,
}

/// The robot controller behind its DNC line.
struct Robot {
    host: Host,
    /// Telegrams to the line (None while the port is closed).
    dnc: Option<tokio::sync::mpsc::UnboundedSender<Vec<u8>>>,
    line: LineSettings,
    detail: Option<RobotStatusDetail>,
    /// A link failure not yet reported.
    link_alarm: Option<String>,
}

impl Robot {
    fn send(&mut self, t: Telegram, out: &mut Vec<Event>) {
        let sent = self
            .dnc
            .as_ref()
            .map(|d| d.send(t.encode()).is_ok())
            .unwrap_or(false);
        if !sent {
            let why = format!(
                "no connection with RCM on {}: the line is not open",
                self.line.path
            );
            let outs = self.host.link_failed(why);
            self.apply(outs, out);
        }
    }

    /// Carries out host outputs; engine events go to `out`.
    fn apply(&mut self, outs: Vec<Out>, out: &mut Vec<Event>) {
        for o in outs {
            match o {
                Out::Telegram(t) => self.send(t, out),
                Out::Engine(ev) => out.push(ev),
                Out::Detail(d) => self.detail = Some(d),
                Out::Info(text) => tracing::info!("{text}"),
            }
        }
    }

    fn dnc_event(&mut self, ev: LinkEvent) -> Vec<Event> {
        let mut out = Vec::new();
        match ev {
            LinkEvent::Received(bytes) => match Telegram::decode(&bytes) {
                Ok(t) => {
                    tracing::debug!(?t, "from the RCM");
                    let outs = self.host.telegram(t);
                    self.apply(outs, &mut out);
                }
                Err(e) => tracing::warn!("undecodable telegram from the RCM: {e}"),
            },
            LinkEvent::Failed { error, .. } => {
                let why = format!("no connection with RCM on {}: {error}", self.line.path);
                self.lost(why, &mut out);
            }
            LinkEvent::Refused(why) => tracing::debug!("block refused: {why}"),
            LinkEvent::Sent(_) => {}
        }
        out
    }

    fn lost(&mut self, why: String, out: &mut Vec<Event>) {
        tracing::warn!("{why}");
        self.link_alarm = Some(why.clone());
        let outs = self.host.link_failed(why);
        self.apply(outs, out);
    }
}

impl Device for Robot {
    fn unavailable(&self) -> Option<String> {
        None
    }

    fn act(&mut self, _now: Duration, action: Action, out: &mut Vec<Event>) {
        match action {
            Action::Start {
                job: Job::Program(n),
                ..
            } => match Program::new(n) {
                Some(p) => {
                    let outs = self.host.start(p);
                    self.apply(outs, out);
                }
                None => tracing::warn!("program {n} out of range"),
            },
            Action::Stop(_) => self.halt(out),
            other => tracing::warn!("a welding recipe cannot {other:?}"),
        }
    }

    fn halt(&mut self, out: &mut Vec<Event>) {
        let outs = self.host.stop();
        self.apply(outs, out);
    }

    fn status(&self, status: &mut VmdStatus) {
        status.additional = self.detail;
    }
}

#[tokio::main]
async fn main() -> Result<()> {
    init_tracing();
    let cli = Cli::parse();
    let topology = cli.node.topology()?;
    let settings = cli.node.settings(&topology, &cli.station)?;
    let line = cli
        .line
        .settings(
            topology
                .station(&cli.station)
                .and_then(|s| s.device.clone()),
        )
        .context("no serial port: give --device or a `device` in the topology")?;
    let station = Station::open(settings, &topology).await?;
    let (dnc, mut dnc_events) = match driver::open_serial(&line) {
        Ok(port) => {
            let h = driver::spawn(port, Priority::Low, Timing::default());
            (Some(h.send), Some(h.events))
        }
        Err(e) => {
            tracing::warn!("{e}; retrying every second");
            (None, None)
        }
    };
    let robot = Robot {
        host: Host::new(),
        dnc,
        line,
        detail: None,
        link_alarm: None,
    };
    // select + start: 2 telegrams, each up to 6 × 2 s on a dead line, so
    // the link's own, clearer failure arrives before the confirm limit.
    let mut ws = Workstation::new(station, RecipeKind::Welding, Duration::from_secs(30), robot);
    ws.publish_status().await;
    say(&format!(
        "EVENT ready station={} device={}",
        cli.station, ws.device.line.path
    ));
    let mut reopen = tokio::time::interval(Duration::from_secs(1));
    let mut shutdown = falc_common::node::Shutdown::new();
    loop {
        let deadline = ws.deadline();
        tokio::select! {
            ev = ws.station_recv() => if !ws.station_step(ev).await { break },
            ev = async { match &mut dnc_events { Some(e) => e.recv().await, None => std::future::pending().await } } => {
                let events = match ev {
                    Some(ev) => ws.device.dnc_event(ev),
                    None => {
                        ws.device.dnc = None;
                        dnc_events = None;
                        let why = format!("no connection with RCM on {}: the line closed", ws.device.line.path);
                        let mut out = Vec::new();
                        ws.device.lost(why, &mut out);
                        out
                    }
                };
                ws.feed(events);
            },
            _ = reopen.tick(), if ws.device.dnc.is_none() => {
                if let Ok(port) = driver::open_serial(&ws.device.line) {
                    tracing::info!(path = %ws.device.line.path, "line to the RCM open again");
                    let h = driver::spawn(port, Priority::Low, Timing::default());
                    ws.device.dnc = Some(h.send);
                    dnc_events = Some(h.events);
                }
            }
            _ = tokio::time::sleep_until(deadline) => ws.on_timeout(),
            _ = shutdown.requested() => break,
        }
        ws.settle().await;
        if let Some(why) = ws.device.link_alarm.take() {
            ws.report(falc_common::mms::pdu::Severity::Alarm, why).await;
        }
    }
    if ws.is_running() {
        let mut out = Vec::new();
        ws.device.halt(&mut out);
    }
    say("EVENT stopped");
    Ok(())
}
