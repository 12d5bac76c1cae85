//! A workstation node's recipe runtime, shared by the welding and the
//! transport node: the VMD (domains, program invocations) served to the
//! commander, one running recipe at a time, its job events (done, alarm,
//! bad product, failed …) published as unsolicited status, alarms reported
//! up, and the node's status kept current.
//!
//! What differs per workstation is its [`Device`]: how the engine's device
//! actions (`start rcm`, `activate`, `waitplace` …) are carried out, why a
//! recipe cannot start now, and what the device adds to the status. The
//! node's main loop feeds device events in ([`Workstation::feed`],
//! [`Workstation::fault`]) and calls [`Workstation::settle`] after each.

use crate::alarm::{AlarmClass, Cause};
use crate::bus::station::{Station, StationEvent};
use crate::bus::BusEvent;
use crate::ids::ObjectName;
use crate::mms::error::{DefinitionError, ErrorClass, ServiceError};
use crate::mms::pdu::{JobEvent, Request, Response, Severity, Unconfirmed};
use crate::mms::program::{PiCompletion, PiRequest};
use crate::mms::vmd::{Identity, ProgramState, RecipeState, Vmd, VmdStatus};
use crate::node::say;
use crate::recipe::check::check;
use crate::recipe::commands::RecipeKind;
use crate::recipe::engine::{Action, Engine, Event, JobEnd, Outcome};
use crate::recipe::syntax::parse;
use std::sync::Arc;
use std::time::Duration;
use tokio::time::Instant;

/// A workstation's device, as its recipes see it.
pub trait Device {
    /// Why no recipe can start now (no link, emergency stop), if so.
    fn unavailable(&self) -> Option<String>;
    /// Carries out a device action of the running recipe (`Start`, `Stop`,
    /// `Activate`, `Reset`, `Watch`, `Unwatch`, `Output`, `Input`); events
    /// that follow at once go into `out`.
    fn act(&mut self, now: Duration, action: Action, out: &mut Vec<Event>);
    /// The commander stopped or killed the recipe: stop the device.
    fn halt(&mut self, out: &mut Vec<Event>);
    /// The recipe ended: leave the device safe.
    fn finished(&mut self, _outcome: &Outcome) {}
    /// Whether outputs the recipe issued are not carried out yet: a job
    /// that ended well is reported done only once they are (the commander
    /// must not start the next job while, say, a coil write is in flight).
    fn settling(&self) -> bool {
        false
    }
    /// A limit is about to run out: what the device sees, for the alarm
    /// text (e.g. which input was not reached, which line still runs).
    fn explain_timeout(&self, _now: Duration) -> Option<String> {
        None
    }
    /// The device's part of the status (physical status, additional detail).
    fn status(&self, status: &mut VmdStatus);
    /// An association was lost (the commander, or a subordinate of a cell).
    fn lost(&mut self, _station: &crate::ids::StationName) {}
    /// The commander associated (and with it every subordinate).
    fn associated(&mut self) {}
}

struct Running {
    name: ObjectName,
    engine: Engine,
    /// What the device saw when a limit last ran out.
    timed_out: Option<String>,
}

/// The runtime of one workstation node.
pub struct Workstation<D> {
    station: Station,
    vmd: Vmd,
    /// The device.
    pub device: D,
    kind: RecipeKind,
    confirm_limit: Duration,
    running: Option<Running>,
    origin: Instant,
}

impl<D: Device> Workstation<D> {
    /// A workstation of `kind` on `station`; a `start` in its recipes waits
    /// `confirm_limit` for the device's confirm.
    pub fn new(station: Station, kind: RecipeKind, confirm_limit: Duration, device: D) -> Self {
        Self {
            station,
            vmd: Vmd::new(Identity {
                vendor: "FALC".into(),
                model: kind.to_string(),
                revision: env!("CARGO_PKG_VERSION").into(),
            }),
            device,
            kind,
            confirm_limit,
            running: None,
            origin: Instant::now(),
        }
    }

    /// Time since start (the engines' clock).
    pub fn now(&self) -> Duration {
        Instant::now().duration_since(self.origin)
    }

    /// Whether a recipe runs.
    pub fn is_running(&self) -> bool {
        self.running.is_some()
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
        match self.station_handle(ev).await {
            Some(e) => self.station_event(Some(e)).await,
            None => true,
        }
    }

    /// When the running recipe's next limit runs out (far away if none).
    pub fn deadline(&self) -> Instant {
        self.running
            .as_ref()
            .and_then(|r| r.engine.poll_timeout())
            .map_or(Instant::now() + Duration::from_secs(3600), |t| {
                self.origin + t
            })
    }

    /// The clock reached the deadline.
    pub fn on_timeout(&mut self) {
        let now = self.now();
        let explained = self.device.explain_timeout(now);
        if let Some(r) = &mut self.running {
            if r.engine.poll_timeout().is_some_and(|d| d <= now) {
                if let Some(e) = &explained {
                    tracing::info!(state = %r.engine.state(), "limit ran out: {e}");
                }
                r.timed_out = explained;
                r.engine.handle_timeout(now);
            }
        }
    }

    /// Feeds device events to the running recipe.
    pub fn feed(&mut self, events: Vec<Event>) {
        let now = self.now();
        if let Some(r) = &mut self.running {
            for ev in events {
                r.engine.handle(now, ev);
            }
        }
    }

    /// The device failed: the running recipe ends in alarm with `cause`,
    /// and the alarm goes up (also when no recipe runs).
    pub async fn fault(&mut self, cause: Cause) {
        if let Some(r) = &mut self.running {
            r.engine.abort(cause.clone());
        }
        self.report(Severity::Alarm(cause.class), cause.text).await;
    }

    /// Publishes a report (operator message) from this station.
    pub async fn report(&self, severity: Severity, text: String) {
        say(&format!("EVENT report severity={severity:?} text={text}"));
        let me = self.station.bus().me().station.clone();
        self.station
            .bus()
            .publish(&Unconfirmed::Report {
                station: me,
                severity,
                text,
            })
            .await;
    }

    async fn job_event(&self, program: &ObjectName, event: JobEvent) {
        say(&format!("EVENT job program={program} event={event:?}"));
        let me = self.station.bus().me().station.clone();
        self.station
            .bus()
            .publish(&Unconfirmed::Job {
                station: me,
                program: program.clone(),
                event,
            })
            .await;
    }

    /// Publishes the status if it changed.
    pub async fn publish_status(&mut self) {
        let mut status = VmdStatus {
            local_detail: if self.running.is_some() {
                RecipeState::Executing
            } else {
                RecipeState::Idle
            },
            program: self.running.as_ref().map(|r| ProgramState {
                name: r.name.clone(),
                state: r.engine.state().0,
            }),
            ..VmdStatus::default()
        };
        self.device.status(&mut status);
        self.station.set_status(status).await;
    }

    /// Runs the engine's actions, finishes the job if it ended, and
    /// publishes the status: call after every event.
    pub async fn settle(&mut self) {
        loop {
            let now = self.now();
            let Some(r) = &mut self.running else { break };
            let Some(action) = r.engine.poll_action() else {
                break;
            };
            match action {
                Action::Alarm(cause) => {
                    let cause = match &r.timed_out {
                        Some(why) => cause.map(|t| format!("{t}: {why}")),
                        None => cause,
                    };
                    self.report(Severity::Alarm(cause.class), cause.text).await;
                }
                Action::Entered(s) => tracing::debug!(state = %s, "recipe state"),
                a => {
                    let mut out = Vec::new();
                    self.device.act(now, a, &mut out);
                    self.feed(out);
                }
            }
        }
        let ended = self
            .running
            .as_ref()
            .and_then(|r| r.engine.outcome().cloned())
            .filter(|o| *o != Outcome::Done || !self.device.settling());
        if let Some(outcome) = ended {
            // Only now, with the outcome known, is the job taken out.
            if let Some(r) = self.running.take() {
                self.device.finished(&outcome);
                let _ = self.vmd.complete(&r.name, PiCompletion::Finished);
                let event = match outcome {
                    Outcome::Done => JobEvent::Done,
                    Outcome::Alarm(c) => JobEvent::Alarm(match r.timed_out {
                        Some(why) => c.map(|t| format!("{t}: {why}")),
                        None => c,
                    }),
                    Outcome::Failed(JobEnd::BadProduct) => JobEvent::BadProduct,
                    Outcome::Failed(JobEnd::FailedSafe) => JobEvent::FailedSafe,
                    Outcome::Failed(JobEnd::FailedDanger) => JobEvent::FailedDanger,
                    Outcome::Failed(other) => JobEvent::Alarm(Cause::process(format!("{other:?}"))),
                };
                self.job_event(&r.name, event).await;
            }
        }
        self.publish_status().await;
    }

    /// Handles what the station hands the node; false when the bus is gone.
    pub async fn station_event(&mut self, ev: Option<StationEvent>) -> bool {
        match ev {
            Some(StationEvent::Indication(ind)) => {
                let result = self.indication(&ind.request).await;
                ind.responder.respond(result).await;
            }
            Some(StationEvent::Abort(a)) if self.running.is_some() => {
                say(&format!("EVENT abort-indication peer={}", a.peer.station));
                let why = Cause::new(
                    AlarmClass::Communication,
                    format!("no connection with station {}", a.peer.station),
                );
                self.device.lost(&a.peer.station);
                self.fault(why).await;
            }
            Some(StationEvent::Abort(a)) => {
                say(&format!("EVENT abort-indication peer={}", a.peer.station));
                self.device.lost(&a.peer.station);
            }
            Some(StationEvent::Associated(p)) => {
                say(&format!("EVENT associated commander={}", p.station));
                self.device.associated();
                self.publish_status().await;
                self.station.republish_status().await;
            }
            Some(StationEvent::Concluded(_)) => {}
            None => return false,
        }
        true
    }

    /// Builds the engine for program invocation `name` from its domain.
    fn engine_for(&self, name: &ObjectName) -> Result<Engine, ServiceError> {
        let text = self
            .vmd
            .program(name)
            .and_then(|p| p.domains().first())
            .and_then(|d| self.vmd.domain(d))
            .map(|d| String::from_utf8_lossy(d.content()).into_owned())
            .ok_or_else(|| {
                ServiceError::undefined(format!("program invocation {name} has no recipe domain"))
            })?;
        let recipe = parse(&text, name.as_str());
        let program = check(&recipe, self.kind).map_err(|problems| {
            let lines: Vec<String> = problems.iter().map(|p| p.to_string()).collect();
            ServiceError::new(
                ErrorClass::Definition(DefinitionError::ObjectAttributeInconsistent),
                format!("error in recipe {name}: {}", lines.join("; ")),
            )
        })?;
        Ok(Engine::new(Arc::new(program)).with_confirm_limit(self.confirm_limit))
    }

    /// The object store (domains, program invocations).
    pub fn vmd(&self) -> &Vmd {
        &self.vmd
    }

    /// Takes a domain back out (a delivery that failed).
    pub fn discard_domain(&mut self, name: &ObjectName) {
        let _ = self.vmd.handle(&Request::DeleteDomain {
            domain: name.clone(),
        });
    }

    /// Answers one indication (the node answers it to the commander).
    pub async fn indication(&mut self, req: &Request) -> Result<Response, ServiceError> {
        let Some((result, transition)) = self.vmd.handle(req) else {
            return Err(ServiceError::malformed(format!(
                "{} is not served by a {} station",
                req.service(),
                self.kind
            )));
        };
        let Some(t) = transition else { return result };
        let now = self.now();
        let done = match t.request {
            PiRequest::Start | PiRequest::Resume => {
                let refused = if self.running.is_some() {
                    Some(ServiceError::state_conflict(format!(
                        "another {} recipe is running",
                        self.kind
                    )))
                } else {
                    self.device.unavailable().map(ServiceError::state_conflict)
                };
                let engine = match refused {
                    Some(e) => Err(e),
                    None => self.engine_for(&t.name),
                };
                match engine {
                    Ok(mut engine) => {
                        engine.start(now);
                        self.running = Some(Running {
                            name: t.name.clone(),
                            engine,
                            timed_out: None,
                        });
                        if t.request == PiRequest::Start {
                            PiCompletion::Started
                        } else {
                            PiCompletion::Resumed
                        }
                    }
                    Err(e) => {
                        let _ = self.vmd.complete(&t.name, PiCompletion::StartFailed);
                        return Err(e);
                    }
                }
            }
            PiRequest::Stop | PiRequest::Kill => {
                // The device stops first: `finished` forgets what runs (a
                // cell forgets which workstations its recipe started).
                let mut out = Vec::new();
                self.device.halt(&mut out);
                if let Some(mut r) = self.running.take() {
                    let why = Cause::process(format!("{:?} by the commander", t.request));
                    r.engine.abort(why.clone());
                    self.device.finished(&Outcome::Alarm(why));
                }
                if t.request == PiRequest::Kill {
                    self.publish_status().await;
                    return result;
                }
                PiCompletion::Stopped
            }
            PiRequest::Reset => PiCompletion::ResetDone,
            PiRequest::Delete => return result,
        };
        let state = self.vmd.complete(&t.name, done).unwrap_or_else(|s| s);
        self.settle().await;
        Ok(Response::ProgramInvocationState(state))
    }
}
