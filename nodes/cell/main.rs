//! `falc-cell`: the cell controller. Accepts the operator as commander and,
//! on its Initiate, associates its workstations first (the 1992 recursive
//! scheme, in `Station`); runs cell recipes (`start`, `wait`, `output`,
//! `input`) through the workstations' services; an abort indication or an
//! alarm from a workstation ends the running recipe in alarm, stops the
//! other workstations' program invocations and reports the cause up.
//!
//! Recipe delivery: a domain the operator downloads as `STATION$NAME` is a
//! workstation's recipe: the cell passes it on to that workstation as
//! domain `NAME` with its program invocation, and confirms the download
//! only when the workstation has it (else the cell drops its copy too: a
//! recipe is never half-applied). Unchanged content is not sent again.
//!
//! A thin driver: the recipe runtime is `falc_control::controller`, driven by `falc_node::controller_node`, the
//! requests and job events of the level below live in `below`.

mod below;
mod delivery;

use anyhow::Result;
use below::{Below, Reply};
use clap::Parser;
use delivery::{workstation_domain, Passer};
use falc_bus::station::{Station, StationEvent};
use falc_bus::Bus;
use falc_model::alarm::{AlarmClass, Cause};
use falc_model::ids::StationName;
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::{Request, Response, Severity};
use falc_node::controller_node::ControllerNode;
use falc_node::{init_tracing, say, NodeArgs};
use falc_recipe::commands::RecipeKind;
use std::time::Duration;

#[derive(Parser, Debug)]
#[command(
    version,
    about = "FALC cell controller: cell recipes over the workstations"
)]
struct Cli {
    /// The station this process is (a station of kind cell).
    #[arg(long, default_value = "cell")]
    station: StationName,
    #[command(flatten)]
    node: NodeArgs,
}

/// Acts on what the station hands the cell: indications (a finished
/// download of `STATION$NAME` is passed on to that workstation before it is
/// confirmed), aborts (a lost workstation comes back empty) and
/// associations (a returned workstation gets its recipes again). False
/// when the bus is gone.
async fn on_station(
    ws: &mut ControllerNode<Below>,
    passer: &mut Passer,
    bus: &Bus,
    subordinates: &[StationName],
    ev: StationEvent,
) -> bool {
    let ind = match ev {
        StationEvent::Indication(ind) => ind,
        other => {
            let associated = matches!(other, StationEvent::Associated(_));
            if let StationEvent::Abort(a) = &other {
                passer.forget(&a.peer.station);
            }
            if !ws.station_event(Some(other)).await {
                return false;
            }
            if associated {
                for failure in passer.catch_up(bus, ws.vmd()).await {
                    ws.report(Severity::Alarm(AlarmClass::Communication), failure)
                        .await;
                }
            }
            return true;
        }
    };
    let mut result = ws.indication(&ind.request).await;
    if let (
        Ok(_),
        Request::TerminateDownloadSequence {
            domain,
            discard: None,
        },
    ) = (&result, &ind.request)
    {
        if let Some((st, name)) = workstation_domain(domain) {
            result = if !subordinates.contains(&st) {
                ws.discard_domain(domain);
                Err(ServiceError::undefined(format!(
                    "recipe {domain}: {st} is not a workstation of this cell"
                )))
            } else {
                let content = ws
                    .vmd()
                    .domain(domain)
                    .map(|d| d.content().to_vec())
                    .unwrap_or_default();
                match passer.pass_on(bus, &st, &name, &content).await {
                    Ok(()) => Ok(Response::Done),
                    Err(e) => {
                        ws.discard_domain(domain);
                        Err(e)
                    }
                }
            };
        }
    }
    ind.responder.respond(result).await;
    true
}

#[tokio::main]
async fn main() -> Result<()> {
    init_tracing();
    let cli = Cli::parse();
    let topology = cli.node.topology()?;
    let settings = cli.node.settings(&topology, &cli.station)?;
    let station = Station::open(settings, &topology).await?;
    let bus = station.bus().clone();
    let subordinates: Vec<StationName> = topology
        .subordinates_of(&cli.station)
        .into_iter()
        .cloned()
        .collect();
    let (utx, mut publications) = tokio::sync::mpsc::unbounded_channel();
    let mut subscriptions = Vec::new();
    for st in &subordinates {
        subscriptions.extend(bus.subscribe(st, utx.clone()).await?);
    }
    let (rtx, mut replies) = tokio::sync::mpsc::unbounded_channel();
    let below = Below::new(
        bus.clone(),
        topology.commander_of(&cli.station).cloned(),
        rtx,
    );
    let mut ws = ControllerNode::new(station, RecipeKind::Cell, Duration::from_secs(10), below);
    let mut passer = Passer::default();
    ws.publish_status().await;
    say(&format!("EVENT ready station={}", cli.station));
    let mut shutdown = falc_node::Shutdown::new();
    loop {
        let deadline = ws.deadline();
        tokio::select! {
            ev = ws.station_recv() => {
                let Some(ev) = ev else { break };
                if let Some(ev) = ws.station_handle(ev).await {
                    if !on_station(&mut ws, &mut passer, &bus, &subordinates, ev).await {
                        break;
                    }
                }
            }
            r = replies.recv() => match r {
                Some(Reply::Started(st, Ok(()))) => ws.feed(vec![falc_recipe::engine::Event::Started(st)]),
                Some(Reply::Started(st, Err(e))) => {
                    // The recipe takes its failure path; an alarm state there names this.
                    ws.report(Severity::Warning, format!("start on {st} refused: {e}")).await;
                    ws.feed(vec![falc_recipe::engine::Event::StartFailed(st, e)]);
                }
                Some(Reply::Answer(Ok(a))) => ws.feed(vec![falc_recipe::engine::Event::Answer(a)]),
                Some(Reply::Answer(Err(e))) => ws.fault(Cause::new(AlarmClass::Communication, format!("no answer from the operator: {e}"))).await,
                Some(Reply::Shown(r)) => {
                    ws.core.device.shown();
                    if let Err(e) = r {
                        tracing::warn!("output to the operator refused: {e}");
                    }
                }
                Some(Reply::Other(what, Err(e))) => tracing::warn!("{what} refused: {e}"),
                Some(Reply::Other(_, Ok(()))) => {}
                None => break,
            },
            u = publications.recv() => match u {
                Some(u) => {
                    // A workstation's reports reach the operator directly
                    // (it reads every station's reports), under its name.
                    let events = ws.core.device.unconfirmed(&u);
                    ws.feed(events);
                }
                None => break,
            },
            _ = tokio::time::sleep_until(deadline) => ws.on_timeout(),
            _ = shutdown.requested() => break,
        }
        ws.settle().await;
    }
    drop(subscriptions);
    say("EVENT stopped");
    Ok(())
}
