//! `falc-cell`: the cell controller. Accepts the operator as commander and,
//! on its Initiate, associates its workstations first (the 1992 recursive
//! scheme, in `Station`); runs cell recipes (`start`, `wait`, `output`,
//! `input`) through the workstations' services; an abort indication or an
//! alarm from a workstation ends the running recipe in alarm, stops the
//! other workstations' program invocations and reports the cause up.
//!
//! Recipe delivery, modes, steps and manual operations passed on to the
//! workstations and answered with their confirms: the sans-I/O
//! `falc_control::pass_on`, which holds the commander's further
//! indications while a delivery runs.
//!
//! A thin driver: the recipe runtime is `falc_control::controller`, the
//! coordination of the stations below `falc_control::coordination`, the
//! pass-on `falc_control::pass_on` (all sans-I/O), driven by
//! `falc_node::controller_node`; here are the request lanes (one task per
//! station) and a task per request passed on. Nothing in the loop waits on
//! another station.

use anyhow::Result;
use clap::Parser;
use falc_bus::station::{Station, StationEvent};
use falc_bus::{Bus, Responder};
use falc_control::coordination::{self, Command, Reply, Stations};
use falc_control::pass_on::{PassOn, Todo, PASS_LIMIT};
use falc_model::alarm::AlarmClass;
use falc_model::ids::StationName;
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::{Response, Severity};
use falc_node::controller_node::ControllerNode;
use falc_node::{init_tracing, lane, say, NodeArgs};
use falc_recipe::commands::RecipeKind;
use std::collections::BTreeMap;
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

/// What a workstation answered to what the pass-on asked.
enum Came {
    /// The confirm of a [`Todo::Ask`].
    Confirm(u64, Result<Response, ServiceError>),
    /// The outcome of a [`Todo::Deliver`].
    Delivered(u64, Result<(), ServiceError>),
}

/// The cell: its controller, the lanes and the pass-on.
struct Cell {
    ctl: ControllerNode<Stations>,
    lanes: Lanes,
    pass: PassOn<Responder>,
    came: UnboundedSender<Came>,
}

impl Cell {
    /// Settles the controller, sends what its stations must be asked,
    /// carries out the pass-on's work, then publishes (requests first: they
    /// are on the critical path of the recipe, the status put is not).
    async fn settle(&mut self) {
        loop {
            self.ctl.settle_core();
            while let Some(cmd) = self.ctl.core.device.poll_command() {
                self.lanes.send(cmd);
            }
            if let Some(local) = self.ctl.core.device.poll_local_reply() {
                let now = self.ctl.now();
                coordination::handle_reply(&mut self.ctl.core, now, local);
                continue;
            }
            let mut more = false;
            while let Some(here) = self.pass.poll_here() {
                more = true;
                let result = self.ctl.indication(&here.request).await;
                self.pass.handled(here, result, self.ctl.core.vmd());
            }
            while let Some(todo) = self.pass.poll_todo() {
                more = true;
                self.carry_out(todo).await;
            }
            if !more {
                break;
            }
        }
        self.ctl.publish().await;
    }

    /// Carries out what the pass-on asks; what workstations answer comes
    /// back as [`Came`].
    async fn carry_out(&mut self, todo: Todo<Responder>) {
        let bus = self.lanes.bus.clone();
        let came = self.came.clone();
        match todo {
            Todo::Answer { ticket, result } => ticket.respond(result).await,
            Todo::Ask { id, to, request } => {
                tokio::spawn(async move {
                    let result = bus.request(&to, &request, PASS_LIMIT).await;
                    let _ = came.send(Came::Confirm(id, result));
                });
            }
            Todo::Deliver {
                id,
                to,
                name,
                content,
            } => {
                tokio::spawn(async move {
                    let result = bus.deliver(&to, &name, &content).await;
                    let _ = came.send(Came::Delivered(id, result));
                });
            }
            Todo::Delivered { to, name } => {
                say(&format!("EVENT delivered station={to} recipe={name}"));
            }
            Todo::Discard(domain) => self.ctl.core.discard_domain(&domain),
            Todo::Alarm(text) => {
                self.ctl
                    .report(Severity::Alarm(AlarmClass::Communication), text)
                    .await;
            }
            Todo::Warn(text) => tracing::warn!("{text}"),
        }
    }

    /// Acts on what the station hands the cell: indications go through the
    /// pass-on; a lost workstation comes back empty, and returned ones get
    /// their recipes and the cell's mode again.
    async fn on_station(&mut self, ev: StationEvent) {
        match ev {
            StationEvent::Indication(ind) => {
                self.pass.handle_indication(ind.responder, ind.request)
            }
            other => {
                let associated = matches!(other, StationEvent::Associated(_));
                if let StationEvent::Abort(a) = &other {
                    self.pass.handle_lost(&a.peer.station);
                }
                self.ctl.station_event(other).await;
                if associated {
                    let mode = self.ctl.core.mode().clone();
                    self.pass.handle_associated(self.ctl.core.vmd(), &mode);
                }
            }
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
    let (came, mut answers) = unbounded_channel();
    let mut cell = Cell {
        ctl: ControllerNode::new(
            station,
            RecipeKind::Cell,
            coordination::CONFIRM_LIMIT,
            stations,
        ),
        lanes: Lanes {
            bus,
            replies: rtx,
            lanes: BTreeMap::new(),
        },
        pass: PassOn::new(subordinates),
        came,
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
            c = answers.recv() => match c {
                Some(Came::Confirm(id, result)) => cell.pass.handle_confirm(id, result),
                Some(Came::Delivered(id, result)) => cell.pass.handle_delivered(id, result),
                None => break,
            },
            u = publications.recv() => match u {
                Some(u) => {
                    // A workstation's reports reach the operator directly
                    // (it reads every station's reports), under its name.
                    let events = cell.ctl.core.device.unconfirmed(&u.message);
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
