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
//! Modes, steps and manual operations: where each goes is
//! `coordination::route`; what is passed on is answered with the
//! workstations' confirms (`Cell::pass_on`).
//!
//! A thin driver: the recipe runtime is `falc_control::controller`, the
//! coordination of the stations below `falc_control::coordination` (both
//! sans-I/O), driven by `falc_node::controller_node`; here are the request
//! lanes (one task per station) and the delivery task (`delivery`). Nothing
//! in the loop waits on another station.

mod delivery;

use anyhow::Result;
use clap::Parser;
use delivery::{Delivered, Deliveries};
use falc_bus::station::{Station, StationEvent};
use falc_bus::{Bus, Indication};
use falc_control::coordination::{self, workstation_domain, Command, Reply, Route, Stations};
use falc_model::alarm::AlarmClass;
use falc_model::ids::StationName;
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::{Request, Response, Severity};
use falc_model::mode::CellMode;
use falc_node::controller_node::ControllerNode;
use falc_node::{init_tracing, lane, say, NodeArgs};
use falc_recipe::commands::RecipeKind;
use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

/// How long a workstation may take to confirm a mode, step or manual
/// operation passed on.
const PASS_LIMIT: Duration = Duration::from_secs(10);
use tokio::sync::mpsc::{unbounded_channel, UnboundedSender};

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

/// One lane per station: its requests go out in order, one at a time, and
/// each confirm comes back as a [`Reply`].
struct Lanes {
    bus: Bus,
    replies: UnboundedSender<Reply>,
    lanes: BTreeMap<StationName, UnboundedSender<Command>>,
}

impl Lanes {
    fn send(&mut self, cmd: Command) {
        let lane = self.lanes.entry(cmd.to.clone()).or_insert_with(|| {
            let bus = self.bus.clone();
            lane::spawn(self.replies.clone(), move |cmd: Command| {
                let bus = bus.clone();
                async move {
                    let result = bus.request(&cmd.to, &cmd.request, cmd.limit).await;
                    Reply {
                        awaiting: cmd.awaiting,
                        result,
                    }
                }
            })
        });
        if lane.send(cmd).is_err() {
            tracing::error!("a request lane stopped");
        }
    }
}

/// The cell: its controller, the lanes and the deliveries.
struct Cell {
    ctl: ControllerNode<Stations>,
    lanes: Lanes,
    deliveries: Deliveries,
    subordinates: Vec<StationName>,
    /// The commander's indications that came while a delivery was under
    /// way: answered in order once it ended, as if the loop had waited.
    held: VecDeque<Indication>,
}

impl Cell {
    /// Settles the controller, sends what its stations must be asked, then
    /// publishes (requests first: they are on the critical path of the
    /// recipe, the status put is not).
    async fn settle(&mut self) {
        loop {
            self.ctl.settle_core();
            while let Some(cmd) = self.ctl.core.device.poll_command() {
                self.lanes.send(cmd);
            }
            let Some(local) = self.ctl.core.device.poll_local_reply() else {
                break;
            };
            let now = self.ctl.now();
            coordination::handle_reply(&mut self.ctl.core, now, local);
        }
        self.ctl.publish().await;
    }

    /// Acts on what the station hands the cell: indications (a finished
    /// download of `STATION$NAME` is passed on to that workstation before
    /// it is confirmed), aborts (a lost workstation comes back empty) and
    /// associations (a returned workstation gets its recipes again).
    async fn on_station(&mut self, ev: StationEvent) {
        match ev {
            StationEvent::Indication(ind) if self.deliveries.busy() => self.held.push_back(ind),
            StationEvent::Indication(ind) => self.indication(ind).await,
            other => {
                let associated = matches!(other, StationEvent::Associated(_));
                if let StationEvent::Abort(a) = &other {
                    self.deliveries.forget(&a.peer.station);
                }
                self.ctl.station_event(other).await;
                if associated {
                    self.deliveries.catch_up(self.ctl.core.vmd());
                    if self.ctl.core.mode().mode != CellMode::Auto {
                        for st in self.subordinates.clone() {
                            self.mode_to(st);
                        }
                    }
                }
            }
        }
    }

    async fn indication(&mut self, ind: Indication) {
        match coordination::route(&ind.request, &self.subordinates) {
            Route::Here => {}
            Route::HereThenAll => {
                let result = self.ctl.indication(&ind.request).await;
                if result.is_err() {
                    return ind.responder.respond(result).await;
                }
                let to = self.subordinates.clone();
                return self.pass_on(to, ind);
            }
            Route::To(st) => return self.pass_on(vec![st], ind),
            Route::Refused(e) => return ind.responder.respond(Err(e)).await,
        }
        let result = self.ctl.indication(&ind.request).await;
        if let (
            Ok(_),
            Request::TerminateDownloadSequence {
                domain,
                discard: None,
            },
        ) = (&result, &ind.request)
        {
            if let Some((st, name)) = workstation_domain(domain) {
                if !self.subordinates.contains(&st) {
                    self.ctl.core.discard_domain(domain);
                    let e = ServiceError::undefined(format!(
                        "recipe {domain}: {st} is not a workstation of this cell"
                    ));
                    ind.responder.respond(Err(e)).await;
                    return;
                }
                let content = self
                    .ctl
                    .core
                    .vmd()
                    .domain(domain)
                    .map(|d| d.content().to_vec())
                    .unwrap_or_default();
                // Answered when the workstation has it (`delivered`).
                self.deliveries
                    .pass_on(domain.clone(), st, name, content, ind.responder);
                return;
            }
        }
        ind.responder.respond(result).await;
    }

    /// Passes the commander's request on to workstations `to` (a mode to
    /// every one, a step or a manual operation to the one it names) and
    /// answers it with their confirms: the first refusal, named.
    fn pass_on(&self, to: Vec<StationName>, ind: Indication) {
        let bus = self.lanes.bus.clone();
        tokio::spawn(async move {
            let mut refused = Vec::new();
            for st in to {
                if let Err(e) = bus.request(&st, &ind.request, PASS_LIMIT).await {
                    refused.push(e.description);
                }
            }
            let result = match refused.is_empty() {
                true => Ok(Response::Done),
                false => Err(ServiceError::state_conflict(refused.join("; "))),
            };
            ind.responder.respond(result).await;
        });
    }

    /// A workstation associated again: it gets the cell's mode.
    fn mode_to(&self, st: StationName) {
        let bus = self.lanes.bus.clone();
        let mode = Request::Mode(self.ctl.core.mode().clone());
        tokio::spawn(async move {
            if let Err(e) = bus.request(&st, &mode, PASS_LIMIT).await {
                tracing::warn!("the mode did not reach {st}: {e}");
            }
        });
    }

    /// A delivery ended: answer its download, then what was held back.
    async fn delivered(&mut self, d: Delivered) {
        self.deliveries.ended();
        match d {
            Delivered::PassedOn {
                domain,
                result,
                responder,
            } => {
                if result.is_err() {
                    self.ctl.core.discard_domain(&domain);
                }
                responder.respond(result.map(|()| Response::Done)).await;
            }
            Delivered::CaughtUp(failures) => {
                for failure in failures {
                    self.ctl
                        .report(Severity::Alarm(AlarmClass::Communication), failure)
                        .await;
                }
            }
        }
        while !self.deliveries.busy() {
            let Some(ind) = self.held.pop_front() else {
                break;
            };
            self.indication(ind).await;
        }
    }
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
    let (utx, mut publications) = unbounded_channel();
    let mut subscriptions = Vec::new();
    for st in &subordinates {
        subscriptions.extend(bus.subscribe(st, utx.clone()).await?);
    }
    let (rtx, mut replies) = unbounded_channel();
    let stations = Stations::new(topology.commander_of(&cli.station).cloned());
    let (deliveries, mut delivered) = Deliveries::spawn(bus.clone());
    let mut cell = Cell {
        ctl: ControllerNode::new(station, RecipeKind::Cell, Duration::from_secs(10), stations),
        lanes: Lanes {
            bus,
            replies: rtx,
            lanes: BTreeMap::new(),
        },
        deliveries,
        subordinates,
        held: VecDeque::new(),
    };
    cell.ctl.publish_status().await;
    say(&format!("EVENT ready station={}", cli.station));
    let mut shutdown = falc_node::Shutdown::new();
    loop {
        let deadline = cell.ctl.deadline();
        tokio::select! {
            ev = cell.ctl.station_recv() => {
                let Some(ev) = ev else { break };
                if let Some(ev) = cell.ctl.station_handle(ev).await {
                    cell.on_station(ev).await;
                }
            }
            r = replies.recv() => match r {
                Some(r) => {
                    let now = cell.ctl.now();
                    coordination::handle_reply(&mut cell.ctl.core, now, r);
                }
                None => break,
            },
            d = delivered.recv() => match d {
                Some(d) => cell.delivered(d).await,
                None => break,
            },
            u = publications.recv() => match u {
                Some(u) => {
                    // A workstation's reports reach the operator directly
                    // (it reads every station's reports), under its name.
                    let events = cell.ctl.core.device.unconfirmed(&u);
                    cell.ctl.feed(events);
                }
                None => break,
            },
            _ = tokio::time::sleep_until(deadline) => cell.ctl.on_timeout(),
            _ = shutdown.requested() => break,
        }
        cell.settle().await;
    }
    drop(subscriptions);
    say("EVENT stopped");
    Ok(())
}
