//! `falc-welding`: the welding workstation. Serves the MMS-equivalent
//! services to its commander (domains, program invocations, status), runs
//! welding recipes (`start rcm N [max_s]`, `wait rcm [max_s]`) and bridges
//! to the robot controller over the DNC serial link. Job events (done,
//! alarm, paused, bad product, failed) go up as unsolicited status.
//!
//! A thin driver: the recipe runtime is `falc_control::controller`
//! (driven by `falc_node::controller_node`); the device is
//! `falc_dnc::workstation` (poll-style: this loop hands its telegrams to
//! the 3964R task of `falc_node::dnc_link`; stopping, it closes the DNC
//! link, `C`, before it lets go of the port), the rules of the link
//! `falc_dnc::host` (DNC ↔ engine, and its supervision, which the
//! runtime's clock drives through `Device::poll_timeout`).

use anyhow::{Context, Result};
use clap::Parser;
use falc_bus::station::Station;
use falc_dnc::procedure::{Link, LinkEvent, Priority, Timing};
use falc_dnc::telegram::Telegram;
use falc_dnc::workstation::{self, LineEvent, Welding};
use falc_model::ids::StationName;
use falc_node::controller_node::ControllerNode;
use falc_node::dnc_link;
use falc_node::{init_tracing, say, NodeArgs};
use falc_recipe::commands::RecipeKind;
use std::time::Duration;
use tokio::sync::mpsc::UnboundedSender;

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
    memory: falc_node::controller_node::MemoryArgs,
    #[command(flatten)]
    node: NodeArgs,
}

/// Hands a telegram the node decided on to the link's task (dropped
/// while the line is closed: the device applied that failure already).
fn send_telegram(dnc: &Option<UnboundedSender<Vec<u8>>>, t: Telegram) {
    if let Some(d) = dnc {
        if d.send(t.encode()).is_err() {
            tracing::warn!("the DNC link task is gone");
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
    let (mut dnc, mut dnc_events) = match dnc_link::open_serial(&line) {
        Ok(port) => {
            let h = dnc_link::spawn(port, workstation_end(timing));
            (Some(h.send), Some(h.events))
        }
        Err(e) => {
            tracing::warn!("{e}; retrying every second");
            (None, None)
        }
    };
    let robot = Welding::new(&line.path, &timing);
    let limit = workstation::confirm_limit(&timing);
    let mut ws = ControllerNode::new(station, RecipeKind::Welding, limit, robot);
    ws.node.set_recipe_memory(cli.memory.recipe_memory);
    if dnc.is_some() {
        ws.link(LineEvent::Opened);
    }
    ws.carry(|t| send_telegram(&dnc, t)).await;
    say(&format!(
        "EVENT ready station={} device={}",
        cli.station, line.path
    ));
    let mut reopen = tokio::time::interval(Duration::from_secs(1));
    let mut shutdown = falc_node::Shutdown::new();
    loop {
        let deadline = ws.deadline();
        tokio::select! {
            ev = ws.station_recv() => if !ws.station_step(ev).await { break },
            ev = async { match &mut dnc_events { Some(e) => e.recv().await, None => std::future::pending().await } } => {
                match ev {
                    Some(ev) => ws.link(LineEvent::Link(ev)),
                    None => {
                        dnc_events = None;
                        dnc = None;
                        ws.link(LineEvent::Closed);
                    }
                }
            },
            _ = reopen.tick(), if dnc.is_none() => {
                if let Ok(port) = dnc_link::open_serial(&line) {
                    tracing::info!(path = %line.path, "line to the RCM open again");
                    let h = dnc_link::spawn(port, workstation_end(timing));
                    dnc = Some(h.send);
                    dnc_events = Some(h.events);
                    ws.link(LineEvent::Opened);
                }
            }
            _ = tokio::time::sleep_until(deadline) => ws.on_timeout(),
            _ = shutdown.requested() => break,
        }
        ws.carry(|t| send_telegram(&dnc, t)).await;
    }
    // A job's program stopped (`H`) and the DNC link closed (`C`) before
    // the port is let go: the RCM knows nobody commands it (the twin says
    // `rx C`).
    for t in ws.node.shut_down() {
        send_telegram(&dnc, t);
    }
    if let Some(events) = dnc_events.as_mut() {
        let close = workstation::CLOSE.encode();
        // At most the link's own budget for a telegram, retries included.
        let went = tokio::time::timeout(timing.silent_after(), async {
            while let Some(ev) = events.recv().await {
                if matches!(&ev, LinkEvent::Sent(t) | LinkEvent::Failed { telegram: t, .. } if *t == close)
                {
                    return matches!(ev, LinkEvent::Sent(_));
                }
            }
            false
        })
        .await;
        if !matches!(went, Ok(true)) {
            tracing::warn!("the DNC link's close (C) did not reach the RCM");
        }
    }
    say("EVENT stopped");
    Ok(())
}

/// The workstation's end of the DNC line: low priority, and the RCM
/// answers every telegram it is sent, so an acknowledgement delay without
/// a byte after one went is a silence ([`Link::awaiting_answers`]).
fn workstation_end(timing: Timing) -> Link {
    Link::new(Priority::Low, timing).awaiting_answers()
}
