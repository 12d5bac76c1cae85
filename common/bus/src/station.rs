//! A station's runtime on the bus: its session, the services it serves, and
//! its associations (the I/O half of [`falc_model::mms::association`]).
//!
//! [`Station::next`] handles Initiate, Conclude, Abort and lost tokens
//! itself (initiating subordinates before confirming, watching tokens,
//! aborting subordinates when the commander is lost) and hands the node only
//! what it must act on: the other indications, association changes and
//! abort indications.

use super::{
    acl, Bus, BusError, BusEvent, BusSettings, Declaration, Indication, Responder, StatusBoard,
};
use falc_model::ids::StationName;
use falc_model::mms::association::{
    initiate_limit, AbortIndication, Associations, InitiateOutcome, InitiateStep,
};
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::{Peer, Request, Response, Unconfirmed};
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
    assoc: Associations,
    tx: UnboundedSender<BusEvent>,
    rx: UnboundedReceiver<BusEvent>,
    watches: HashMap<Peer, Declaration>,
    board: StatusBoard,
    _served: Vec<Declaration>,
    deadline: Duration,
    /// How long an Initiate of each subordinate may take: one deadline per
    /// level of its subtree (it initiates its own subordinates first).
    initiate_limits: HashMap<StationName, Duration>,
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
        let assoc = Associations::of(topology, &me);
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
        let initiate_limits = topology
            .subordinates_of(&me)
            .into_iter()
            .map(|sub| (sub.clone(), initiate_limit(topology, sub)))
            .collect();
        Ok(Self {
            bus,
            assoc,
            tx,
            rx,
            watches: HashMap::new(),
            board,
            _served: served,
            deadline: super::DEFAULT_DEADLINE,
            initiate_limits,
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

    /// Publishes the current status again, changed or not (a new commander
    /// and the operator see it at once, not at the next change).
    pub async fn republish_status(&self) {
        self.bus
            .publish(&Unconfirmed::Status {
                station: self.bus.me().station.clone(),
                status: self.board.get(),
            })
            .await;
    }

    /// The association state.
    pub fn associations(&self) -> &Associations {
        &self.assoc
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
            BusEvent::Indication(ind) => self.on_indication(ind).await,
            BusEvent::PeerLost { peer, reason } => self.on_lost(&peer, &reason, false).await,
        }
    }

    async fn on_indication(&mut self, ind: Indication) -> Option<StationEvent> {
        match ind.request {
            Request::Initiate { calling } => self.on_initiate(calling, ind.responder).await,
            Request::Conclude { calling } => match self.assoc.conclude(&calling) {
                Ok(subs) => {
                    self.unwatch(&calling);
                    for sub in subs {
                        self.conclude_one(&sub).await;
                    }
                    ind.responder.respond(Ok(Response::Done)).await;
                    Some(StationEvent::Concluded(calling))
                }
                Err(e) => {
                    ind.responder.respond(Err(e)).await;
                    None
                }
            },
            Request::Abort { calling, reason } => {
                ind.responder.respond(Ok(Response::Done)).await;
                self.on_lost(&calling, &format!("Abort from {calling}: {reason}"), true)
                    .await
            }
            ref r => match self.assoc.admit(r) {
                Ok(()) => Some(StationEvent::Indication(ind)),
                Err(e) => {
                    ind.responder.respond(Err(e)).await;
                    None
                }
            },
        }
    }

    async fn on_initiate(&mut self, calling: Peer, responder: Responder) -> Option<StationEvent> {
        let commander = match self.assoc.initiate(calling) {
            InitiateStep::Refuse(e) => {
                responder.respond(Err(e)).await;
                return None;
            }
            InitiateStep::Confirm(p) => p,
            InitiateStep::InitiateSubordinates(subs) => {
                let results = initiate_all(&self.bus, self.with_limits(subs)).await;
                match self.assoc.subordinates_initiated(results) {
                    InitiateOutcome::Confirm {
                        commander,
                        associated,
                    } => {
                        for p in associated {
                            self.watch(&p).await;
                        }
                        commander
                    }
                    InitiateOutcome::Refuse { error, conclude } => {
                        for p in conclude {
                            self.conclude_one(&p).await;
                        }
                        let me = self.bus.me().clone();
                        self.watches.retain(|p, _| *p == me);
                        responder.respond(Err(error)).await;
                        return None;
                    }
                }
            }
        };
        self.watch(&commander).await;
        responder
            .respond(Ok(Response::Initiate {
                responding: self.bus.me().clone(),
            }))
            .await;
        Some(StationEvent::Associated(commander))
    }

    async fn on_lost(
        &mut self,
        peer: &Peer,
        reason: &str,
        sent_abort: bool,
    ) -> Option<StationEvent> {
        self.unwatch(peer);
        let (indication, abort) = self.assoc.lost(peer, reason, sent_abort)?;
        for sub in abort {
            self.unwatch(&sub);
            let req = Request::Abort {
                calling: self.bus.me().clone(),
                reason: format!("{} lost its commander: {reason}", self.bus.me().station),
            };
            if let Err(e) = self.bus.request(&sub.station, &req, self.deadline).await {
                tracing::warn!("Abort to {sub} not confirmed: {e}");
            }
        }
        Some(StationEvent::Abort(indication))
    }

    /// The root (which has no commander) associates every missing subordinate.
    pub async fn associate_subordinates(&mut self) -> Result<Vec<Peer>, ServiceError> {
        let initiates = self.initiates_due();
        let results = initiate_all(&self.bus, initiates).await;
        self.record_initiates(results).await
    }

    /// What [`Self::associate_subordinates`] sends, for a driver that sends
    /// it outside its event loop ([`initiate_all`]): every missing
    /// subordinate, with how long its Initiate may take.
    pub fn initiates_due(&self) -> Vec<(StationName, Duration)> {
        self.with_limits(self.assoc.missing_subordinates())
    }

    /// Records the outcomes of the root's Initiates: watches the
    /// associations made, or, if any failed, concludes them again and
    /// returns the failure.
    pub async fn record_initiates(
        &mut self,
        results: Vec<(StationName, Result<Peer, ServiceError>)>,
    ) -> Result<Vec<Peer>, ServiceError> {
        match self.assoc.record_subordinates(results) {
            Ok(made) => {
                for p in &made {
                    self.watch(p).await;
                }
                Ok(made)
            }
            Err((e, made)) => {
                for p in made {
                    self.conclude_one(&p).await;
                }
                Err(e)
            }
        }
    }

    /// Each of `subs` with how long its Initiate may take: one deadline
    /// per level of its subtree.
    fn with_limits(&self, subs: Vec<StationName>) -> Vec<(StationName, Duration)> {
        subs.into_iter()
            .map(|s| {
                let limit = self.initiate_limits.get(&s).copied();
                (s, limit.unwrap_or(self.deadline))
            })
            .collect()
    }

    /// The root concludes every subordinate.
    pub async fn conclude_subordinates(&mut self) {
        for p in self.assoc.release_subordinates() {
            self.unwatch(&p);
            self.conclude_one(&p).await;
        }
    }

    async fn conclude_one(&mut self, sub: &Peer) {
        self.unwatch(sub);
        let req = Request::Conclude {
            calling: self.bus.me().clone(),
        };
        if let Err(e) = self.bus.request(&sub.station, &req, self.deadline).await {
            tracing::warn!("Conclude of {sub} not confirmed: {e}");
        }
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

    fn unwatch(&mut self, peer: &Peer) {
        self.watches.remove(peer);
    }
}

/// Sends Initiate to each station of `initiates` at once, each with its
/// time limit; the outcomes, in the same order. Needs only the bus, so a
/// driver can run it outside its event loop.
pub async fn initiate_all(
    bus: &Bus,
    initiates: Vec<(StationName, Duration)>,
) -> Vec<(StationName, Result<Peer, ServiceError>)> {
    let calls = initiates.into_iter().map(|(s, limit)| async move {
        let r = initiate_one(bus, &s, limit).await;
        (s, r)
    });
    futures::future::join_all(calls).await
}

async fn initiate_one(bus: &Bus, sub: &StationName, limit: Duration) -> Result<Peer, ServiceError> {
    let req = Request::Initiate {
        calling: bus.me().clone(),
    };
    match bus.request(sub, &req, limit).await? {
        Response::Initiate { responding } if &responding.station == sub => Ok(responding),
        other => Err(ServiceError::malformed(format!(
            "station {sub} answered Initiate with {other:?}"
        ))),
    }
}
