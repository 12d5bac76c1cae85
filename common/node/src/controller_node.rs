//! Drives a [`Controller`] on the bus: the thin async shell around the
//! sans-I/O core. It owns the station (association, indications), the
//! clock (time since start), and publishes what the core puts out: reports
//! and job events as unsolicited status, the status when it changed.
//!
//! A node's loop: `select!` on [`ControllerNode::station_recv`], its
//! device's events (fed with [`ControllerNode::feed`] /
//! [`ControllerNode::fault`]) and `sleep_until(`[`ControllerNode::deadline`]`)`
//! → [`ControllerNode::on_timeout`]; then [`ControllerNode::settle`].

use crate::say;
use falc_bus::station::{Station, StationEvent};
use falc_bus::BusEvent;
use falc_control::controller::{Controller, Device, Reading};
use falc_model::alarm::Cause;
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::{Request, Response, Severity, Unconfirmed};
use falc_recipe::commands::RecipeKind;
use falc_recipe::engine::Event;
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

/// A controller core on its station.
pub struct ControllerNode<D> {
    station: Station,
    /// The sans-I/O core (its device is `core.device`).
    pub core: Controller<D>,
    origin: Instant,
}

impl<D: Device> ControllerNode<D> {
    /// A controller of `kind` on `station`; a `start` in its recipes waits
    /// `confirm_limit` for the device's confirm.
    pub fn new(station: Station, kind: RecipeKind, confirm_limit: Duration, device: D) -> Self {
        let me = station.bus().me().station.clone();
        // A cell runs its order on when its commander is lost; the
        // station's associations say so (from its kind in the topology).
        let alone = station.associations().runs_alone();
        Self {
            station,
            core: Controller::new(kind, confirm_limit, device)
                .named(me)
                .runs_on_alone(alone),
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
    /// branch): what the node must act on, if anything.
    pub async fn station_handle(&mut self, ev: BusEvent) -> Option<StationEvent> {
        self.station.handle(ev).await
    }

    /// Receives and handles the next bus event as a workstation does
    /// (indications answered, aborts and associations taken in); false
    /// when the bus is gone.
    pub async fn station_step(&mut self, ev: Option<BusEvent>) -> bool {
        let Some(ev) = ev else { return false };
        if let Some(e) = self.station_handle(ev).await {
            self.station_event(e).await;
        }
        true
    }

    /// When the running recipe's next limit runs out (far away if none).
    pub fn deadline(&self) -> Instant {
        self.core
            .poll_timeout()
            .map_or(Instant::now() + Duration::from_secs(3600), |t| {
                self.origin + t
            })
    }

    /// The clock reached the deadline.
    pub fn on_timeout(&mut self) {
        let now = self.now();
        self.core.handle_timeout(now);
    }

    /// Feeds device events to the running recipe.
    pub fn feed(&mut self, events: Vec<Event>) {
        let now = self.now();
        self.core.feed(now, events);
    }

    /// The device failed: the running recipe ends in alarm with `cause`,
    /// and the alarm goes up (also when no recipe runs).
    pub async fn fault(&mut self, cause: Cause) {
        self.core.fault(cause);
        self.flush().await;
    }

    /// Takes in what one reading of the device means
    /// ([`Controller::take_reading`]) and publishes it; true when the
    /// device became usable again with it.
    pub async fn take_reading(&mut self, reading: Reading) -> bool {
        let now = self.now();
        let ready = self.core.take_reading(now, reading);
        self.flush().await;
        ready
    }

    /// Publishes a report (operator message) from this station.
    pub async fn report(&mut self, severity: Severity, text: String) {
        self.core.report(severity, text);
        self.flush().await;
    }

    /// Publishes what the core put out, in order ([`publish`]).
    async fn flush(&mut self) {
        let me = self.station.bus().me().station.clone();
        while let Some(out) = self.core.poll_output() {
            publish(&self.station, out.publication(me.clone())).await;
        }
    }

    /// Publishes the status if it changed.
    pub async fn publish_status(&mut self) {
        self.station.set_status(self.core.status()).await;
    }

    /// Runs the engine's actions, finishes the job if it ended, publishes
    /// what came of it and the status: call after every event.
    pub async fn settle(&mut self) {
        self.settle_core();
        self.publish().await;
    }

    /// The first half of [`Self::settle`]: runs the engine's actions in the
    /// core, publishes nothing yet (a driver with commands to send sends
    /// them first: the next station should not wait for a status put).
    pub fn settle_core(&mut self) {
        let now = self.now();
        self.core.settle(now);
    }

    /// The second half of [`Self::settle`]: publishes what the core put out
    /// and the status.
    pub async fn publish(&mut self) {
        self.flush().await;
        self.publish_status().await;
    }

    /// Handles what the station hands the node.
    pub async fn station_event(&mut self, ev: StationEvent) {
        match ev {
            StationEvent::Indication(ind) => {
                let result = self.indication(&ind.request).await;
                ind.responder.respond(result).await;
            }
            StationEvent::Abort(a) => {
                say(&format!("EVENT abort-indication peer={}", a.peer.station));
                let now = self.now();
                self.core.handle_abort(now, &a.peer.station, a.role);
                self.flush().await;
            }
            StationEvent::Associated(p) => {
                say(&format!("EVENT associated commander={}", p.station));
                let now = self.now();
                self.core.handle_associated(now);
                self.publish_status().await;
                self.station.republish_status().await;
            }
            StationEvent::Concluded(_) => {}
        }
    }

    /// Answers one indication (the node answers it to the commander).
    pub async fn indication(&mut self, req: &Request) -> Result<Response, ServiceError> {
        let now = self.now();
        let result = self.core.handle_request(now, req);
        self.flush().await;
        self.publish_status().await;
        result
    }
}

/// Publishes `u` from `station`: a status through its status board (sent
/// when it changed), a report or job event numbered, with its `EVENT` line
/// (`no=` its number).
pub async fn publish(station: &Station, u: Unconfirmed) {
    if let Unconfirmed::Status { status, .. } = u {
        station.set_status(status).await;
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
