//! The zenoh binding: a node's session to the router and the MMS-equivalent
//! primitives on top of it.
//!
//! - confirmed services: [`Bus::request`] sends the request as a zenoh query
//!   on `…/<target>/svc/<service>` and returns the confirm; [`Bus::serve`]
//!   turns queries into [`Indication`]s whose [`Responder`] sends the
//!   response. "No reply" (nobody serves the key, or the router's ACL denied
//!   it: zenoh cannot tell them apart) is `application-reference/
//!   application-unreachable`; a malformed request is answered with an error
//!   by the bus itself, and the server keeps serving.
//! - unconfirmed services: [`Bus::publish`] (status, reports); reports and
//!   job events are numbered and kept ([`falc_model::mms::journal`]), and
//!   [`Bus::keep_reports`] serves them again to a reader who missed some
//!   ([`Bus::read_reports`]);
//! - liveliness: every session holds a token `…/alive/<me>/<session>`;
//!   [`Bus::watch`] reports a peer's lost token as [`BusEvent::PeerLost`].
//!
//! Its keys are `falc_model::keys` (every key), its payloads
//! `falc_model::envelope` (the format). Sub-modules:
//! [`credentials`], [`certificates`] (the cell CA and the secure transport's
//! certificates), [`download`] (recipe delivery), [`operator_service`] (the
//! operator API), [`config`] (generated zenoh configs), [`acl`] (the
//! generated access control), [`station`] (a node's association runtime),
//! [`log_limit`] (warnings others cause, rate-limited per source).

pub mod acl;
pub mod certificates;
pub mod config;
pub mod credentials;
pub mod download;
pub mod log_limit;
pub mod operator_service;
pub mod station;

use credentials::Credentials;
use falc_model::envelope;
use falc_model::ids::StationName;
use falc_model::keys::KeySpace;
use falc_model::mms::error::ServiceError;
use falc_model::mms::heard;
use falc_model::mms::journal::{KeptReports, Publication, ReportLog, ReportsAsked, Stamp};
use falc_model::mms::pdu::{Peer, Request, Response, ServiceName, Unconfirmed};
use falc_model::mms::vmd::VmdStatus;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;
use tokio::sync::mpsc::UnboundedSender;
use zenoh::query::{ConsolidationMode, Query, QueryTarget};
use zenoh::sample::SampleKind;
use zenoh::Wait;

/// The default deadline of a confirmed service.
pub const DEFAULT_DEADLINE: Duration = Duration::from_secs(2);

/// Why the bus could not be opened or a declaration failed.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    /// The zenoh configuration was refused.
    #[error(transparent)]
    Config(#[from] config::ConfigError),
    /// The session could not be opened: router down, wrong credentials …
    #[error(
        "cannot connect to the router at {endpoint} as `{user}`: {message} (is the router running there? A wrong password or a certificate of another cell is refused without a reason here: the router logs a `refused login` line with the reason)"
    )]
    Connect {
        /// The router endpoint.
        endpoint: String,
        /// The zenoh user.
        user: String,
        /// zenoh's message.
        message: String,
    },
    /// A declaration (queryable, token, subscriber) failed.
    #[error("cannot declare {what} on {key}: {message}")]
    Declare {
        /// What was declared.
        what: &'static str,
        /// The key.
        key: String,
        /// zenoh's message.
        message: String,
    },
}

/// How a node reaches the router.
#[derive(Debug, Clone)]
pub struct BusSettings {
    /// The cell's key space.
    pub keys: KeySpace,
    /// This node's station.
    pub me: StationName,
    /// The router endpoint.
    pub endpoint: String,
    /// The zenoh lease.
    pub lease: Duration,
    /// The node's credentials (None only in tests of refusal).
    pub credentials: Option<Credentials>,
    /// The node's certificate, key and the cell CA, for a `quic/…` endpoint.
    pub tls: Option<certificates::TlsFiles>,
    /// How long to keep trying to reach the router at start.
    pub connect_timeout: Duration,
}

/// What a failed declaration of `what` on `key` becomes.
pub(crate) fn declare_failed<'a, E: std::fmt::Display>(
    what: &'static str,
    key: &'a str,
) -> impl FnOnce(E) -> BusError + 'a {
    move |e| BusError::Declare {
        what,
        key: key.to_string(),
        message: e.to_string(),
    }
}

/// Something the bus delivers to a node's event loop.
#[derive(Debug)]
pub enum BusEvent {
    /// A confirmed service request arrived (an indication).
    Indication(Indication),
    /// A watched peer's liveliness token is gone.
    PeerLost {
        /// The peer.
        peer: Peer,
        /// Why.
        reason: String,
    },
}

/// Whether a station has a session on the bus (any liveliness token).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Presence {
    /// The station.
    pub station: StationName,
    /// Whether it holds at least one token now.
    pub present: bool,
}

/// A request that arrived, with the means to answer it.
#[derive(Debug)]
pub struct Indication {
    /// The decoded request.
    pub request: Request,
    /// Answers it.
    pub responder: Responder,
}

/// Sends the response (positive or negative) of one indication.
#[derive(Debug)]
pub struct Responder {
    query: Query,
}

impl Responder {
    /// Sends the response. A failure to send (the querier left) is logged.
    pub async fn respond(self, result: Result<Response, ServiceError>) {
        let key = self.query.key_expr().clone();
        let sent = match &result {
            Ok(r) => self.query.reply(key.clone(), envelope::encode(r)).await,
            Err(e) => self.query.reply_err(envelope::encode(e)).await,
        };
        if let Err(e) = sent {
            tracing::warn!(%key, "response not sent: {e}");
        }
    }
}

/// A station's current VMD status, from which the bus answers the Status
/// service at once, in zenoh's callback: Status stays answered while the
/// node's loop is busy (initiating subordinates, say), and it costs no hop
/// to that loop. The node sets it whenever its status changes.
#[derive(Debug, Clone, Default)]
pub struct StatusBoard(Arc<Mutex<VmdStatus>>);

impl StatusBoard {
    /// The status now.
    pub fn get(&self) -> VmdStatus {
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    /// Replaces the status; true if it changed.
    pub fn set(&self, status: &VmdStatus) -> bool {
        let mut s = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        let changed = *s != *status;
        if changed {
            *s = status.clone();
        }
        changed
    }
}

/// A node's session to the router, with its liveliness token. Clones share
/// the session (to issue requests from tasks); the token lives while any
/// clone does.
#[derive(Clone)]
pub struct Bus {
    session: zenoh::Session,
    keys: KeySpace,
    me: Peer,
    _token: std::sync::Arc<zenoh::liveliness::LivelinessToken>,
    /// The cell of a plant this console's operator API calls are for
    /// ([`Bus::for_cell`]); None: the plant, or the one cell.
    api_cell: Option<falc_model::ids::CellId>,
    /// The reports and job events this node published, numbered.
    kept: Arc<Mutex<ReportLog>>,
}

/// Keeps a declaration alive; dropping it undeclares.
pub struct Declaration(#[allow(dead_code)] Box<dyn Send + Sync>);

impl Bus {
    /// Opens the session and declares this node's liveliness token.
    pub async fn open(settings: BusSettings) -> Result<Self, BusError> {
        let cfg = config::client(
            &settings.endpoint,
            settings.lease,
            settings.credentials.as_ref(),
            settings.tls.as_ref(),
            settings.connect_timeout,
        )?;
        let session = zenoh::open(cfg).await.map_err(|e| BusError::Connect {
            endpoint: settings.endpoint.clone(),
            user: settings
                .credentials
                .as_ref()
                .map_or("<none>".into(), |c| c.user.clone()),
            message: e.to_string(),
        })?;
        let me = Peer {
            station: settings.me.clone(),
            session: session.zid().to_string(),
        };
        let key = settings.keys.alive(&me.station, &me.session);
        let token = session
            .liveliness()
            .declare_token(&key)
            .await
            .map_err(declare_failed("liveliness token", &key))?;
        let kept = Arc::new(Mutex::new(ReportLog::new(me.session.clone())));
        Ok(Self {
            session,
            keys: settings.keys,
            me,
            _token: std::sync::Arc::new(token),
            api_cell: None,
            kept,
        })
    }

    /// The same session in key space `keys` (a plant's operator commands
    /// each cell on one session), with a liveliness token of its own there.
    pub async fn alongside(&self, keys: KeySpace) -> Result<Self, BusError> {
        let key = keys.alive(&self.me.station, &self.me.session);
        let token = self
            .session
            .liveliness()
            .declare_token(&key)
            .await
            .map_err(declare_failed("liveliness token", &key))?;
        Ok(Self {
            session: self.session.clone(),
            keys,
            me: self.me.clone(),
            _token: std::sync::Arc::new(token),
            api_cell: None,
            kept: Arc::new(Mutex::new(ReportLog::new(self.me.session.clone()))),
        })
    }

    /// This bus with its operator API calls for cell `cell` of a plant
    /// (`falc --cell C`; None: the plant, or the one cell).
    pub fn for_cell(mut self, cell: Option<falc_model::ids::CellId>) -> Self {
        self.api_cell = cell;
        self
    }

    /// Returns once the router has processed every declaration this session
    /// made so far (queryables, subscribers, the token): a liveliness query
    /// travels the same link after them, and the query ends with the
    /// router's final reply. (Whether our own token is among the replies is
    /// not reliable, so only a timeout counts as failure.) Nodes call it
    /// before they say "ready", so that a commander's first request never
    /// races their queryables.
    pub async fn sync_with_router(&self) -> Result<(), BusError> {
        let key = self.keys.alive(&self.me.station, &self.me.session);
        let fail = |message: String| BusError::Declare {
            what: "router barrier (liveliness query)",
            key: key.clone(),
            message,
        };
        let replies = self
            .session
            .liveliness()
            .get(&key)
            .timeout(DEFAULT_DEADLINE)
            .await
            .map_err(|e| fail(e.to_string()))?;
        while let Ok(reply) = replies.recv_async().await {
            if let Err(e) = reply.result() {
                return Err(fail(format!(
                    "no final reply from the router: {}",
                    String::from_utf8_lossy(&e.payload().to_bytes())
                )));
            }
        }
        Ok(())
    }

    /// This node as a peer (station and session id).
    pub fn me(&self) -> &Peer {
        &self.me
    }

    /// The key space.
    pub fn keys(&self) -> &KeySpace {
        &self.keys
    }

    /// The zenoh session, for benchmarks and tests that compare with bare zenoh.
    pub fn session(&self) -> &zenoh::Session {
        &self.session
    }

    /// A confirmed service: request → confirm, within `deadline`.
    pub async fn request(
        &self,
        target: &StationName,
        request: &Request,
        deadline: Duration,
    ) -> Result<Response, ServiceError> {
        let key = self.keys.service(target, request.service());
        let what = format!("{} of station {target}", request.service());
        self.request_bytes(&key, envelope::encode(request), deadline, &what)
            .await
    }

    /// Sends raw bytes as a request to `key` (tests send garbage this way).
    pub async fn request_bytes(
        &self,
        key: &str,
        payload: Vec<u8>,
        deadline: Duration,
        what: &str,
    ) -> Result<Response, ServiceError> {
        self.query(key, payload, deadline, what).await
    }

    /// A query on `key` whose one reply is an envelope of `T` (or of a
    /// [`ServiceError`] as an error reply).
    pub(crate) async fn query<T: serde::de::DeserializeOwned>(
        &self,
        key: &str,
        payload: Vec<u8>,
        deadline: Duration,
        what: &str,
    ) -> Result<T, ServiceError> {
        let replies = self
            .session
            .get(key)
            .payload(payload)
            .target(QueryTarget::BestMatching)
            .consolidation(ConsolidationMode::None)
            .timeout(deadline)
            .await
            .map_err(|e| ServiceError::unreachable(format!("{what}: cannot send: {e}")))?;
        let reply = replies.recv_async().await.map_err(|_| {
            ServiceError::unreachable(format!(
                "no reply to {what} (not served, or refused by the router's access control)"
            ))
        })?;
        match reply.result() {
            Ok(sample) => envelope::decode(&sample.payload().to_bytes())
                .map_err(|e| ServiceError::malformed(format!("malformed confirm for {what}: {e}"))),
            Err(err) => {
                let bytes = err.payload().to_bytes();
                match envelope::decode::<ServiceError>(&bytes) {
                    Ok(e) => Err(e),
                    Err(_) if &bytes[..] == b"Timeout" => Err(ServiceError::timeout(format!(
                        "no confirm for {what} within {deadline:?}"
                    ))),
                    Err(e) => Err(ServiceError::malformed(format!(
                        "malformed negative confirm for {what}: {e}"
                    ))),
                }
            }
        }
    }

    /// Serves `services` on this node's keys: Status from `board`, the
    /// others as indications to `events`.
    pub async fn serve(
        &self,
        services: &[ServiceName],
        board: &StatusBoard,
        events: UnboundedSender<BusEvent>,
    ) -> Result<Vec<Declaration>, BusError> {
        let mut out = Vec::with_capacity(services.len());
        for &service in services {
            let key = self.keys.service(&self.me.station, service);
            let tx = events.clone();
            let board = board.clone();
            let q = self
                .session
                .declare_queryable(&key)
                .callback(move |query| on_query(service, query, &board, &tx))
                .await
                .map_err(declare_failed("queryable", &key))?;
            out.push(Declaration(Box::new(q)));
        }
        Ok(out)
    }

    /// Publishes an unconfirmed service on this node's `status` or `report`
    /// key; a report or job event is numbered and kept first (its stamp is
    /// returned), so that it is not lost when the link is down now.
    pub async fn publish(&self, message: &Unconfirmed) -> Option<Stamp> {
        let key = match message {
            Unconfirmed::Status { .. } | Unconfirmed::Job { .. } => {
                self.keys.status(&self.me.station)
            }
            Unconfirmed::Report { .. } => self.keys.report(&self.me.station),
        };
        let at_ms = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX));
        let publication = self
            .kept
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .publication(at_ms, message.clone());
        if let Err(e) = self.session.put(&key, envelope::encode(&publication)).await {
            tracing::warn!(%key, "publication failed: {e}");
        }
        publication.stamp
    }

    /// Serves the reports this node kept on its `reports` key, to a reader
    /// who missed some (the operator after a cut): each query names the
    /// last number the reader has; a malformed one is answered with an
    /// error.
    pub async fn keep_reports(&self) -> Result<Declaration, BusError> {
        let key = self.keys.reports(&self.me.station);
        let kept = self.kept.clone();
        let q = self
            .session
            .declare_queryable(&key)
            .callback(move |query| {
                let asked = query
                    .payload()
                    .map(|p| envelope::decode::<ReportsAsked>(&p.to_bytes()));
                match asked {
                    Some(Ok(asked)) => {
                        let answer = kept
                            .lock()
                            .unwrap_or_else(PoisonError::into_inner)
                            .after(asked);
                        let bytes = envelope::encode(&answer);
                        if let Err(e) = query.reply(query.key_expr().clone(), bytes).wait() {
                            tracing::warn!("kept reports not sent: {e}");
                        }
                    }
                    other => {
                        let text = match other {
                            Some(Err(e)) => format!("malformed query on {}: {e}", query.key_expr()),
                            _ => format!("query on {} carries no payload", query.key_expr()),
                        };
                        log_limit::warn(query.key_expr().as_str(), &text);
                        reply_err_now(&query, &text);
                    }
                }
            })
            .await
            .map_err(declare_failed("queryable", &key))?;
        Ok(Declaration(Box::new(q)))
    }

    /// Reads the reports `station` kept after number `after` of its
    /// current run.
    pub async fn read_reports(
        &self,
        station: &StationName,
        after: u64,
        deadline: Duration,
    ) -> Result<KeptReports, ServiceError> {
        let key = self.keys.reports(station);
        let what = format!("the reports station {station} kept");
        let payload = envelope::encode(&ReportsAsked { after });
        let kept: KeptReports = self.query(&key, payload, deadline, &what).await?;
        heard::take_kept(station, kept).map_err(|e| {
            log_limit::warn(&key, &e.to_string());
            ServiceError::malformed(format!("{what}: {e}"))
        })
    }

    /// Tells the consoles that watch that this operator's status changed
    /// (an empty put on [`KeySpace::changed`]).
    pub async fn publish_changed(&self) {
        let key = self.keys.changed(&self.me.station);
        if let Err(e) = self.session.put(&key, Vec::<u8>::new()).await {
            tracing::warn!(%key, "publication failed: {e}");
        }
    }

    /// Calls `on_change` each time `operator` says its status changed. The
    /// payload is not read: nothing a sender puts there is taken in.
    pub async fn on_changed(
        &self,
        operator: &StationName,
        on_change: impl Fn() + Send + Sync + 'static,
    ) -> Result<Declaration, BusError> {
        let key = self.keys.changed(operator);
        let sub = self
            .session
            .declare_subscriber(&key)
            .callback(move |_| on_change())
            .await
            .map_err(declare_failed("subscriber", &key))?;
        Ok(Declaration(Box::new(sub)))
    }

    /// Subscribes to a station's `status` and `report`; decoded messages
    /// (with their numbers) go to `out`, malformed ones are logged and
    /// dropped, and so is one whose payload names another station than
    /// `station` (the key's); long texts are cut ([`heard`]).
    pub async fn subscribe(
        &self,
        station: &StationName,
        out: UnboundedSender<Publication>,
    ) -> Result<Vec<Declaration>, BusError> {
        let mut v = Vec::new();
        for key in [self.keys.status(station), self.keys.report(station)] {
            let tx = out.clone();
            let k = key.clone();
            let st = station.clone();
            let sub = self
                .session
                .declare_subscriber(&key)
                .callback(move |sample| {
                    match envelope::decode::<Publication>(&sample.payload().to_bytes()) {
                        // The sender is the station of the key, never the
                        // name in the payload (`heard`).
                        Ok(p) => match heard::take_publication(&st, p) {
                            Ok((p, cut)) => {
                                if let Some(cut) = cut {
                                    log_limit::warn(k.as_str(), &format!("{cut} on {k}"));
                                }
                                let _ = tx.send(p);
                            }
                            Err(e) => log_limit::warn(k.as_str(), &format!("{e} on {k}")),
                        },
                        Err(e) => log_limit::warn(
                            k.as_str(),
                            &format!("dropped a malformed publication on {k}: {e}"),
                        ),
                    }
                })
                .await
                .map_err(declare_failed("subscriber", &key))?;
            v.push(Declaration(Box::new(sub)));
        }
        Ok(v)
    }

    /// Watches whether `station` has any session on the bus: every change
    /// goes to `out` (the tokens present now arrive first, as history). A
    /// restarted station's new token may come before its old one goes: the
    /// tokens are counted, so it stays present.
    pub async fn presence(
        &self,
        station: &StationName,
        out: UnboundedSender<Presence>,
    ) -> Result<Declaration, BusError> {
        let key = self.keys.alive_any(station);
        let st = station.clone();
        let tokens = Mutex::new(std::collections::BTreeSet::<String>::new());
        let sub = self
            .session
            .liveliness()
            .declare_subscriber(&key)
            .history(true)
            .callback(move |sample| {
                let mut t = tokens.lock().unwrap_or_else(PoisonError::into_inner);
                let k = sample.key_expr().to_string();
                match sample.kind() {
                    SampleKind::Put => t.insert(k),
                    SampleKind::Delete => t.remove(&k),
                };
                let _ = out.send(Presence {
                    station: st.clone(),
                    present: !t.is_empty(),
                });
            })
            .await
            .map_err(declare_failed("liveliness subscriber", &key))?;
        Ok(Declaration(Box::new(sub)))
    }

    /// Watches `peer`'s liveliness token: its loss (or its absence now) is
    /// sent to `events` as [`BusEvent::PeerLost`].
    pub async fn watch(
        &self,
        peer: &Peer,
        events: UnboundedSender<BusEvent>,
    ) -> Result<Declaration, BusError> {
        let key = self.keys.alive(&peer.station, &peer.session);
        let (p, tx) = (peer.clone(), events.clone());
        let (seen_tx, seen_rx) = tokio::sync::oneshot::channel::<()>();
        let seen_tx = Mutex::new(Some(seen_tx));
        // history(true): the router declares the peer's current token to us
        // (that Put is our proof of presence), and only a token it declared
        // to us is undeclared to us when the peer goes. Without history the
        // Delete was lost at random; a separate liveliness query for
        // presence then returns nothing (both measured with zenoh 1.10.2).
        let sub = self
            .session
            .liveliness()
            .declare_subscriber(&key)
            .history(true)
            .callback(move |sample| match sample.kind() {
                SampleKind::Put => {
                    if let Some(s) = seen_tx
                        .lock()
                        .unwrap_or_else(PoisonError::into_inner)
                        .take()
                    {
                        let _ = s.send(());
                    }
                }
                SampleKind::Delete => {
                    let _ = tx.send(BusEvent::PeerLost {
                        peer: p.clone(),
                        reason: format!("lost the liveliness token of {p}"),
                    });
                }
            })
            .await
            .map_err(declare_failed("liveliness subscriber", &key))?;
        if !matches!(
            tokio::time::timeout(DEFAULT_DEADLINE, seen_rx).await,
            Ok(Ok(()))
        ) {
            let _ = events.send(BusEvent::PeerLost {
                peer: peer.clone(),
                reason: format!("{peer} holds no liveliness token"),
            });
        }
        Ok(Declaration(Box::new(sub)))
    }
}

/// The queryable callback: decode, check the key matches, answer Status
/// from the board, hand the rest over, refuse what is malformed.
fn on_query(
    service: ServiceName,
    query: Query,
    board: &StatusBoard,
    events: &UnboundedSender<BusEvent>,
) {
    let decoded = match query.payload() {
        None => Err(format!(
            "request on {} carries no payload",
            query.key_expr()
        )),
        Some(p) => match envelope::decode::<Request>(&p.to_bytes()) {
            Ok(r) if r.service() == service => r.check_limits().map(|()| r),
            Ok(r) => Err(format!(
                "a {} request was sent to the {service} key {}",
                r.service(),
                query.key_expr()
            )),
            Err(e) => Err(format!("malformed request on {}: {e}", query.key_expr())),
        },
    };
    match decoded {
        Ok(Request::Status) => {
            let bytes = envelope::encode(&Response::Status(board.get()));
            if let Err(e) = query.reply(query.key_expr().clone(), bytes).wait() {
                tracing::warn!("status reply not sent: {e}");
            }
        }
        Ok(request) => {
            let ind = Indication {
                request,
                responder: Responder { query },
            };
            if let Err(e) = events.send(BusEvent::Indication(ind)) {
                // The node is shutting down; refuse rather than leave it unanswered.
                if let BusEvent::Indication(ind) = e.0 {
                    reply_err_now(&ind.responder.query, "the station is shutting down");
                }
            }
        }
        Err(text) => {
            log_limit::warn(query.key_expr().as_str(), &text);
            reply_err_now(&query, &text);
        }
    }
}

fn reply_err_now(query: &Query, text: &str) {
    let err = ServiceError::malformed(text);
    if let Err(e) = query.reply_err(envelope::encode(&err)).wait() {
        tracing::warn!("error reply not sent: {e}");
    }
}
