//! `falc-welding`: the welding workstation. Serves the MMS-equivalent
//! services to its commander (domains, program invocations, status), runs
//! welding recipes (`start rcm N [max_s]`, `wait rcm [max_s]`) and bridges
//! to the robot controller over the DNC serial link. Job events (done,
//! alarm, paused, bad product, failed) go up as unsolicited status.
//!
//! A thin driver: the recipe runtime is `falc_control::controller`
//! (driven by `falc_node::controller_node`), the rules of the link live in
//! `falc_dnc::host` (DNC ↔ engine, and its supervision, which the runtime's clock
//! drives through `Device::poll_timeout`) and the 3964R procedure.

use anyhow::{Context, Result};
use clap::Parser;
use falc_bus::station::Station;
use falc_control::controller::Device;
use falc_dnc::host::{Host, Out};
use falc_dnc::procedure::{LinkEvent, Priority, Timing};
use falc_dnc::telegram::Telegram;
use falc_model::alarm::Cause;
use falc_model::ids::StationName;
use falc_model::mms::vmd::{RobotStatusDetail, VmdStatus};
use falc_model::mode::ManualAction;
use falc_node::controller_node::ControllerNode;
use falc_node::dnc_link::{self, LineSettings};
use falc_node::{init_tracing, say, NodeArgs};
use falc_recipe::check::Job;
use falc_recipe::commands::RecipeKind;
use falc_recipe::engine::{Action, Event};
use std::collections::VecDeque;
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
    line: falc_node::dnc_link::LineArgs,
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
    /// Alarms no job owns (a lost line while idle, a program found
    /// running nobody's), not yet reported.
    alarms: VecDeque<Cause>,
}

impl Robot {
    /// Sends `t`; false (and the link's failure applied) if the line is
    /// not open.
    fn send(&mut self, t: Telegram, out: &mut Vec<Event>) -> bool {
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
        sent
    }

    /// Carries out host outputs; engine events go to `out`.
    fn apply(&mut self, outs: Vec<Out>, out: &mut Vec<Event>) {
        for o in outs {
            match o {
                Out::Telegram(t) => {
                    self.send(t, out);
                }
                Out::Engine(ev) => out.push(ev),
                Out::Detail(d) => self.detail = Some(d),
                Out::Info(text) => tracing::info!("{text}"),
                Out::Alarm(text) => {
                    tracing::warn!("{text}");
                    self.alarms.push_back(text);
                }
            }
        }
    }

    fn dnc_event(&mut self, now: Duration, ev: LinkEvent) -> Vec<Event> {
        let mut out = Vec::new();
        match ev {
            LinkEvent::Received(bytes) => match Telegram::decode(&bytes) {
                Ok(t) => {
                    tracing::debug!(?t, "from the RCM");
                    let outs = self.host.telegram(now, t);
                    self.apply(outs, &mut out);
                }
                Err(e) => tracing::warn!("undecodable telegram from the RCM: {e}"),
            },
            LinkEvent::Failed { telegram, error } => {
                tracing::warn!(
                    "telegram {} to the RCM given up: {error}",
                    telegram.escape_ascii()
                );
                let why = format!("no connection with RCM on {}: {error}", self.line.path);
                let outs = self.host.gave_up(&telegram, why);
                self.apply(outs, &mut out);
            }
            LinkEvent::Refused(why) => tracing::debug!("block refused: {why}"),
            LinkEvent::Sent(telegram) => self.host.sent(&telegram),
        }
        out
    }

    /// The line was (re)opened: initiate DNC and ask the robot's status.
    fn connected(&mut self, now: Duration) {
        let mut out = Vec::new();
        let outs = self.host.connected(now);
        self.apply(outs, &mut out);
    }

    /// The line closed.
    fn closed(&mut self) -> Vec<Event> {
        self.dnc = None;
        let why = format!(
            "no connection with RCM on {}: the line closed",
            self.line.path
        );
        tracing::warn!("{why}");
        let mut out = Vec::new();
        let outs = self.host.closed(why);
        self.apply(outs, &mut out);
        out
    }
}

impl Device for Robot {
    fn unavailable(&self) -> Option<String> {
        None
    }

    fn act(&mut self, _now: Duration, action: Action, out: &mut Vec<Event>) {
        match action {
            Action::Start {
                job: Job::Program(p),
                ..
            } => {
                let outs = self.host.start(p);
                self.apply(outs, out);
            }
            Action::Stop(_) => self.halt(out),
            other => tracing::warn!("a welding recipe cannot {other:?}"),
        }
    }

    fn manual(&mut self, _now: Duration, action: &ManualAction) -> Result<String, String> {
        let (telegram, done) = self.host.manual(action)?;
        // No recipe runs in maintenance: a link failure has no job to end.
        let mut events = Vec::new();
        if self.send(telegram, &mut events) {
            Ok(done)
        } else {
            Err(format!("the DNC line {} is not open", self.line.path))
        }
    }

    fn halt(&mut self, out: &mut Vec<Event>) {
        let outs = self.host.stop();
        self.apply(outs, out);
    }

    fn finished(&mut self, outcome: &falc_recipe::engine::Outcome) {
        // A recipe that ended badly (its own time limit, say) while the
        // robot still runs its program: the robot is stopped.
        if *outcome != falc_recipe::engine::Outcome::Done && self.host.running().is_some() {
            let mut out = Vec::new();
            self.halt(&mut out);
        }
    }

    fn explain_timeout(&self, now: Duration) -> Option<String> {
        self.host.explain_timeout(now)
    }

    /// The supervision's clock (status requests, the silence limit).
    fn poll_timeout(&self) -> Option<Duration> {
        self.host.poll_timeout()
    }

    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Event>) {
        let outs = self.host.handle_timeout(now);
        self.apply(outs, out);
    }

    fn poll_alarm(&mut self) -> Option<Cause> {
        self.alarms.pop_front()
    }

    fn status(&self, status: &mut VmdStatus) {
        status.additional = self.detail;
        // Inoperable while the line is closed or the RCM has not answered
        // since it was (re)opened or went silent: an alarm about the link
        // clears only once the robot answers again.
        if !self.host.answered() {
            status.physical = falc_model::mms::vmd::PhysicalStatus::Inoperable;
        }
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
    let timing = Timing::default();
    let (dnc, mut dnc_events) = match dnc_link::open_serial(&line) {
        Ok(port) => {
            let h = dnc_link::spawn(port, Priority::Low, timing);
            (Some(h.send), Some(h.events))
        }
        Err(e) => {
            tracing::warn!("{e}; retrying every second");
            (None, None)
        }
    };
    let robot = Robot {
        host: Host::new(&line.path, &timing),
        dnc,
        line,
        detail: None,
        alarms: VecDeque::new(),
    };
    // select + start: 2 telegrams, each failing after 6 × 2 s on a dead
    // line, so the link's own, clearer failure arrives before the confirm
    // limit.
    let confirm_limit = 2 * timing.dead_line_after() + Duration::from_secs(6);
    let mut ws = ControllerNode::new(station, RecipeKind::Welding, confirm_limit, robot);
    if ws.core.device.dnc.is_some() {
        let now = ws.now();
        ws.core.device.connected(now);
    }
    ws.publish_status().await;
    say(&format!(
        "EVENT ready station={} device={}",
        cli.station, ws.core.device.line.path
    ));
    let mut reopen = tokio::time::interval(Duration::from_secs(1));
    let mut shutdown = falc_node::Shutdown::new();
    loop {
        let deadline = ws.deadline();
        tokio::select! {
            ev = ws.station_recv() => if !ws.station_step(ev).await { break },
            ev = async { match &mut dnc_events { Some(e) => e.recv().await, None => std::future::pending().await } } => {
                let events = match ev {
                    Some(ev) => { let now = ws.now(); ws.core.device.dnc_event(now, ev) }
                    None => {
                        dnc_events = None;
                        ws.core.device.closed()
                    }
                };
                ws.feed(events);
            },
            _ = reopen.tick(), if ws.core.device.dnc.is_none() => {
                if let Ok(port) = dnc_link::open_serial(&ws.core.device.line) {
                    tracing::info!(path = %ws.core.device.line.path, "line to the RCM open again");
                    let h = dnc_link::spawn(port, Priority::Low, timing);
                    ws.core.device.dnc = Some(h.send);
                    dnc_events = Some(h.events);
                    let now = ws.now();
                    ws.core.device.connected(now);
                }
            }
            _ = tokio::time::sleep_until(deadline) => ws.on_timeout(),
            _ = shutdown.requested() => break,
        }
        ws.settle().await;
    }
    if ws.core.is_running() {
        let mut out = Vec::new();
        ws.core.device.halt(&mut out);
    }
    say("EVENT stopped");
    Ok(())
}
