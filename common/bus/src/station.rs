//! A station's runtime on the bus: its session, the services it serves, and
//! its associations (the I/O half of [`falc_model::mms::serving`]).
//!
//! [`Station::next`] hands Initiate, Conclude, Abort and lost tokens to the
//! sans-I/O [`Serving`] and carries out what it asks (initiating
//! subordinates before confirming, watching tokens, concluding and
//! aborting subordinates); it hands the node only what it must act on:
//! the other indications, association changes and abort indications.

use super::{
    acl, Bus, BusError, BusEvent, BusSettings, Declaration, Indication, Responder, StatusBoard,
};
use falc_model::ids::StationName;
use falc_model::mms::association::{AbortIndication, Associations};
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::{Peer, Request, Response, Unconfirmed};
use falc_model::mms::serving::{Action, Serving};
use falc_model::mms::vmd::VmdStatus;
use falc_model::topology::Topology;
use std::collections::HashMap;
use std::time::Duration;
use tokio::sync::mpsc::{unbounded_channel, UnboundedReceiver, UnboundedSender};

/// What a node must act on.
#[derive(Debug)]
pub enum StationEvent {
    /// A service request for the node to answer.
    Indication(Indication),
    /// The commander associated (its Initiate was confirmed).
    Associated(Peer),
    /// The commander concluded the association.
    Concluded(Peer),
    /// An association was lost: stop, and report.
    Abort(AbortIndication),
}

/// A node's station runtime.
pub struct Station {
    bus: Bus,
    serving: Serving<u64>,
    /// The responders of the indications [`Self::serving`] holds.
    responders: HashMap<u64, Responder>,
    next_token: u64,
    tx: UnboundedSender<BusEvent>,
    rx: UnboundedReceiver<BusEvent>,
    watches: HashMap<Peer, Declaration>,
    board: StatusBoard,
    _served: Vec<Declaration>,
    deadline: Duration,
}

impl Station {
    /// Connects, serves this station's services and waits for a commander.
    pub async fn open(settings: BusSettings, topology: &Topology) -> Result<Self, BusError> {
        Self::on(Bus::open(settings).await?, topology).await
    }

    /// The same on a session already open (a plant's operator is a station
    /// of every cell on one session: [`Bus::alongside`]).
    pub async fn on(bus: Bus, topology: &Topology) -> Result<Self, BusError> {
        let me = bus.me().station.clone();
        let serving = Serving::of(topology, bus.me().clone());
        let (tx, rx) = unbounded_channel();
        let board = StatusBoard::default();
        let mut served = bus
            .serve(&acl::served_services(topology, &me), &board, tx.clone())
            .await?;
        // What it reports upward, kept for a reader who missed some.
        if topology.commander_of(&me).is_some() {
            served.push(bus.keep_reports().await?);
        }
        bus.sync_with_router().await?;
        Ok(Self {
            bus,
            serving,
            responders: HashMap::new(),
            next_token: 0,
            tx,
            rx,
            watches: HashMap::new(),
            board,
            _served: served,
            deadline: super::DEFAULT_DEADLINE,
        })
    }

    /// The bus (to request services of subordinates, publish, subscribe).
    pub fn bus(&self) -> &Bus {
        &self.bus
    }

    /// Sets this station's status (answered to Status requests) and, if it
    /// changed, publishes it as unsolicited status.
    pub async fn set_status(&self, status: VmdStatus) {
        if self.board.set(&status) {
            self.bus
                .publish(&Unconfirmed::Status {
                    station: self.bus.me().station.clone(),
                    status,
                })
                .await;
        }
    }

    /// Sets this station's status (answered to Status requests) and
    /// publishes it, changed or not: for a node whose core decides when
    /// its status is due (when it changed, and again for a new commander).
    pub async fn put_status(&self, status: VmdStatus) {
        self.board.set(&status);
        self.bus
            .publish(&Unconfirmed::Status {
                station: self.bus.me().station.clone(),
                status,
            })
            .await;
    }

    /// The association state.
    pub fn associations(&self) -> &Associations {
        self.serving.associations()
    }

    /// The next event the node must act on; None when the bus is gone.
    /// Not cancel-safe (an Initiate in progress would be dropped half
    /// done): in a `select!` use [`Station::recv`] and [`Station::handle`].
    pub async fn next(&mut self) -> Option<StationEvent> {
        loop {
            let ev = self.recv().await?;
            if let Some(event) = self.handle(ev).await {
                return Some(event);
            }
        }
    }

    /// The next raw bus event; None when the bus is gone. Cancel-safe: the
    /// branch of a node's `select!`.
    pub async fn recv(&mut self) -> Option<BusEvent> {
        self.rx.recv().await
    }

    /// Handles a raw bus event (association services, lost tokens) and
    /// returns what the node must act on, if anything. Await it to the end
    /// (in the body of a `select!` branch, never as a branch): an Initiate
    /// waits for the subordinates' confirms, and dropping it half done
    /// would leave the association pending and the commander unanswered.
    pub async fn handle(&mut self, ev: BusEvent) -> Option<StationEvent> {
        match ev {
            BusEvent::Indication(ind) => {
                self.next_token += 1;
                let token = self.next_token;
                self.responders.insert(token, ind.responder);
                self.serving.handle_request(token, ind.request);
            }
            BusEvent::PeerLost { peer, reason } => self.serving.handle_lost(&peer, &reason),
        }
        self.carry_out().await
    }

    /// Carries out what [`Serving`] asks, the subordinates' Initiates at
    /// once, until it asks nothing more; what the node must act on (one
    /// at most per event).
    async fn carry_out(&mut self) -> Option<StationEvent> {
        let mut event = None;
        loop {
            let mut initiates = Vec::new();
            while let Some(action) = self.serving.poll() {
                match action {
                    Action::Respond(token, result) => {
                        if let Some(r) = self.responders.remove(&token) {
                            r.respond(result).await;
                        }
                    }
                    Action::Initiate { to, request, limit } => {
                        initiates.push((to, request, limit));
                    }
                    Action::Tell { to, request } => {
                        if let Err(e) = self.bus.request(&to, &request, self.deadline).await {
                            tracing::warn!("{} to {to} not confirmed: {e}", request.service());
                        }
                    }
                    Action::Watch(p) => self.watch(&p).await,
                    Action::Unwatch(p) => {
                        self.watches.remove(&p);
                    }
                    Action::Indication(token, request) => {
                        if let Some(responder) = self.responders.remove(&token) {
                            event =
                                Some(StationEvent::Indication(Indication { request, responder }));
                        }
                    }
                    Action::Associated(p) => event = Some(StationEvent::Associated(p)),
                    Action::Concluded(p) => event = Some(StationEvent::Concluded(p)),
                    Action::Abort(a) => event = Some(StationEvent::Abort(a)),
                }
            }
            if initiates.is_empty() {
                return event;
            }
            let bus = &self.bus;
            let calls = initiates
                .into_iter()
                .map(|(to, request, limit)| async move {
                    let r = bus.request(&to, &request, limit).await;
                    (to, r)
                });
            for (to, result) in futures::future::join_all(calls).await {
                self.serving.handle_initiated(&to, result);
            }
        }
    }

    /// The root (which has no commander) associates its subordinates.
    pub async fn associate_subordinates(&mut self) -> Result<Vec<Peer>, ServiceError> {
        let initiates = self.initiates();
        let results = initiate_all(&self.bus, initiates).await;
        self.record_initiates(results).await
    }

    /// What [`Self::associate_subordinates`] sends, for a driver that sends
    /// it outside its event loop ([`initiate_all`]): every subordinate
    /// ([`Serving::initiates`]), with how long its Initiate may take.
    pub fn initiates(&self) -> Vec<(StationName, Duration)> {
        self.serving.initiates()
    }

    /// Records the outcomes of the root's Initiates: watches the
    /// associations made, or, if any failed, concludes them again and
    /// returns the failure.
    pub async fn record_initiates(
        &mut self,
        results: Vec<(StationName, Result<Response, ServiceError>)>,
    ) -> Result<Vec<Peer>, ServiceError> {
        let made = self.serving.record_initiates(results);
        self.carry_out().await;
        made
    }

    /// The root concludes every subordinate.
    pub async fn conclude_subordinates(&mut self) {
        self.serving.conclude_subordinates();
        self.carry_out().await;
    }

    async fn watch(&mut self, peer: &Peer) {
        match self.bus.watch(peer, self.tx.clone()).await {
            Ok(d) => {
                self.watches.insert(peer.clone(), d);
            }
            Err(e) => {
                // Without a watch a loss would go unnoticed: treat as lost.
                let _ = self.tx.send(BusEvent::PeerLost {
                    peer: peer.clone(),
                    reason: format!("cannot watch {peer}: {e}"),
                });
            }
        }
    }
}

/// Sends Initiate to each station of `initiates` at once, each with its
/// time limit; the confirms, in the same order. Needs only the bus, so a
/// driver can run it outside its event loop.
pub async fn initiate_all(
    bus: &Bus,
    initiates: Vec<(StationName, Duration)>,
) -> Vec<(StationName, Result<Response, ServiceError>)> {
    let request = Request::Initiate {
        calling: bus.me().clone(),
    };
    let calls = initiates.into_iter().map(|(s, limit)| {
        let request = &request;
        async move {
            let r = bus.request(&s, request, limit).await;
            (s, r)
        }
    });
    futures::future::join_all(calls).await
}
