//! Drives a workstation's sans-I/O node ([`WorkstationNode`]) on the bus:
//! the thin async shell around it. It owns the station (association,
//! indications) and the clock (time since start), and carries out what the
//! node decides: answers, commands to the device's link, publications
//! (reports and job events as unsolicited status, the status when it
//! changed), log lines.
//!
//! A node's loop: `select!` on [`ControllerNode::station_recv`] (handled
//! by [`ControllerNode::station_step`]), its link's events
//! ([`ControllerNode::link`]) and `sleep_until(`[`ControllerNode::deadline`]`)`
//! → [`ControllerNode::on_timeout`]; then [`ControllerNode::carry`].

use crate::say;
use falc_bus::station::{Station, StationEvent};
use falc_bus::BusEvent;
use falc_bus::Responder;
use falc_control::workstation_node::{Linked, WorkstationAction, WorkstationNode};
use falc_model::alarm::Cause;
use falc_model::mms::pdu::Unconfirmed;
use falc_recipe::commands::RecipeKind;
use std::time::Duration;
use tokio::time::Instant;

/// A workstation's recipe memory, on its command line.
#[derive(clap::Args, Debug, Clone, Copy)]
pub struct MemoryArgs {
    /// How many bytes of recipes (domains) the station holds at most; a
    /// delivery past it is refused with `resource/memory-unavailable` and
    /// taken back.
    #[arg(long, default_value_t = falc_model::mms::vmd::RECIPE_MEMORY)]
    pub recipe_memory: usize,
}

/// A workstation's node on its station.
pub struct ControllerNode<D: Linked> {
    station: Station,
    /// The sans-I/O node.
    pub node: WorkstationNode<D, Responder>,
    origin: Instant,
}

impl<D: Linked> ControllerNode<D> {
    /// A workstation of `kind` on `station`; a `start` in its recipes
    /// waits `confirm_limit` for the device's confirm.
    pub fn new(station: Station, kind: RecipeKind, confirm_limit: Duration, device: D) -> Self {
        let me = station.bus().me().station.clone();
        // Whether it runs its job on when its commander is lost: the
        // station's associations say so (from its kind in the topology).
        let alone = station.associations().runs_alone();
        Self {
            station,
            node: WorkstationNode::new(me, kind, confirm_limit, device, alone),
            origin: Instant::now(),
        }
    }

    /// Time since start (the core's clock).
    pub fn now(&self) -> Duration {
        Instant::now().duration_since(self.origin)
    }

    /// The next raw bus event of the station (cancel-safe: a `select!`
    /// branch); None when the bus is gone.
    pub async fn station_recv(&mut self) -> Option<BusEvent> {
        self.station.recv().await
    }

    /// Handles a raw bus event to the end (in a branch's body, never as a
    /// branch): indications, aborts and associations go to the node;
    /// false when the bus is gone.
    pub async fn station_step(&mut self, ev: Option<BusEvent>) -> bool {
        let Some(ev) = ev else { return false };
        let Some(e) = self.station.handle(ev).await else {
            return true;
        };
        let now = self.now();
        match e {
            StationEvent::Indication(ind) => {
                self.node
                    .handle_indication(now, ind.responder, &ind.request);
            }
            StationEvent::Abort(a) => {
                say(&format!("EVENT abort-indication peer={}", a.peer.station));
                self.node.handle_abort(now, &a.peer.station, a.role);
            }
            StationEvent::Associated(p) => {
                say(&format!("EVENT associated commander={}", p.station));
                self.node.handle_associated(now);
            }
            StationEvent::Concluded(_) => {}
        }
        true
    }

    /// What the device's link reported.
    pub fn link(&mut self, ev: D::LinkEvent) {
        let now = self.now();
        self.node.handle_link(now, ev);
    }

    /// The device failed outside its link's reports: the running recipe
    /// ends in alarm with `cause`, and the alarm goes up.
    pub fn fault(&mut self, cause: Cause) {
        self.node.handle_fault(cause);
    }

    /// When the running recipe's next limit runs out (far away if none).
    pub fn deadline(&self) -> Instant {
        self.node
            .poll_timeout()
            .map_or(Instant::now() + Duration::from_secs(3600), |t| {
                self.origin + t
            })
    }

    /// The clock reached the deadline.
    pub fn on_timeout(&mut self) {
        let now = self.now();
        self.node.handle_timeout(now);
    }

    /// Carries out what the node decided, in order: answers to the
    /// commander, commands to the link (`send`), publications, log lines.
    /// Call after every event.
    pub async fn carry(&mut self, mut send: impl FnMut(D::Command)) {
        let now = self.now();
        while let Some(action) = self.node.poll(now) {
            match action {
                WorkstationAction::Answer { ticket, result } => ticket.respond(result).await,
                WorkstationAction::Command(c) => send(c),
                WorkstationAction::Publish(u) => publish(&self.station, u).await,
                WorkstationAction::Event(line) => say(&format!("EVENT {line}")),
            }
        }
    }
}

/// Publishes `u` from `station`, as its sans-I/O node decided: a status
/// through its status board (the node says when one is due: changed, or
/// for a new commander), a report or job event numbered, with its `EVENT`
/// line (`no=` its number).
pub async fn publish(station: &Station, u: Unconfirmed) {
    if let Unconfirmed::Status { status, .. } = u {
        station.put_status(status).await;
        return;
    }
    let no = station.bus().publish(&u).await.map_or(0, |s| s.no);
    match u {
        Unconfirmed::Report { severity, text, .. } => {
            say(&format!(
                "EVENT report severity={severity:?} no={no} text={text}"
            ));
        }
        Unconfirmed::Job { program, event, .. } => {
            say(&format!(
                "EVENT job program={program} event={event:?} no={no}"
            ));
        }
        Unconfirmed::Status { .. } => {}
    }
}
