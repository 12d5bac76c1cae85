//! The recipe runtime every control level runs, sans-I/O: a workstation
//! around its device (welding, transport), the cell around its
//! workstations. It owns the VMD served to the commander (domains, program
//! invocations), one running recipe at a time, its job events (done, alarm,
//! bad product, failed …) and reports, and the level's status.
//!
//! Quinn-proto style: the driver hands in what happened with the time it
//! happened ([`Controller::handle_request`], [`Controller::feed`],
//! [`Controller::fault`], [`Controller::handle_timeout`]), calls
//! [`Controller::settle`], then publishes what [`Controller::poll_output`]
//! gives and sleeps until [`Controller::poll_timeout`]. Time is a
//! [`Duration`] since the driver's start, so tests run on a virtual clock.
//! The driver on the bus is `falc_node::controller_node`.
//!
//! What differs per level is its [`Device`]: how the engine's device
//! actions (`start rcm`, `activate`, `waitplace`, a cell's `start`) are
//! carried out, why a recipe cannot start now, and what the device adds to
//! the status.

use falc_model::alarm::{AlarmClass, Cause};
use falc_model::ids::{ObjectName, StationName};
use falc_model::mms::error::{DefinitionError, ErrorClass, ServiceError};
use falc_model::mms::pdu::{JobEvent, Request, Response, Severity};
use falc_model::mms::program::{PiCompletion, PiRequest};
use falc_model::mms::vmd::{Identity, ProgramState, RecipeState, Vmd, VmdStatus};
use falc_recipe::check::check;
use falc_recipe::commands::RecipeKind;
use falc_recipe::engine::{Action, Engine, Event, JobEnd, Outcome};
use falc_recipe::syntax::parse;
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Duration;

/// A level's device, as its recipes see it.
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
    fn lost(&mut self, _station: &StationName) {}
    /// The commander associated (and with it every subordinate).
    fn associated(&mut self) {}
}

/// What the controller publishes, in order.
#[derive(Debug, Clone, PartialEq)]
pub enum Output {
    /// A report (operator message) from this station.
    Report {
        /// How bad it is (an alarm carries its class).
        severity: Severity,
        /// What happened.
        text: String,
    },
    /// A job event of a program invocation (done, alarm, bad product …).
    Job {
        /// The program invocation.
        program: ObjectName,
        /// What became of it.
        event: JobEvent,
    },
}

struct Running {
    name: ObjectName,
    engine: Engine,
    /// What the device saw when a limit last ran out.
    timed_out: Option<String>,
}

/// The runtime of one control level.
pub struct Controller<D> {
    vmd: Vmd,
    /// The device.
    pub device: D,
    kind: RecipeKind,
    confirm_limit: Duration,
    running: Option<Running>,
    out: VecDeque<Output>,
}

impl<D: Device> Controller<D> {
    /// A controller of `kind`; a `start` in its recipes waits
    /// `confirm_limit` for the device's confirm.
    pub fn new(kind: RecipeKind, confirm_limit: Duration, device: D) -> Self {
        Self {
            vmd: Vmd::new(Identity {
                vendor: "FALC".into(),
                model: kind.to_string(),
                revision: env!("CARGO_PKG_VERSION").into(),
            }),
            device,
            kind,
            confirm_limit,
            running: None,
            out: VecDeque::new(),
        }
    }

    /// Whether a recipe runs.
    pub fn is_running(&self) -> bool {
        self.running.is_some()
    }

    /// When the running recipe's next limit runs out, if one runs.
    pub fn poll_timeout(&self) -> Option<Duration> {
        self.running.as_ref().and_then(|r| r.engine.poll_timeout())
    }

    /// The clock reached [`Self::poll_timeout`].
    pub fn handle_timeout(&mut self, now: Duration) {
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
    pub fn feed(&mut self, now: Duration, events: Vec<Event>) {
        if let Some(r) = &mut self.running {
            for ev in events {
                r.engine.handle(now, ev);
            }
        }
    }

    /// The device failed: the running recipe ends in alarm with `cause`,
    /// and the alarm goes up (also when no recipe runs).
    pub fn fault(&mut self, cause: Cause) {
        if let Some(r) = &mut self.running {
            r.engine.abort(cause.clone());
        }
        self.report(Severity::Alarm(cause.class), cause.text);
    }

    /// Queues a report (operator message) from this station.
    pub fn report(&mut self, severity: Severity, text: String) {
        self.out.push_back(Output::Report { severity, text });
    }

    /// The next thing to publish, in order.
    pub fn poll_output(&mut self) -> Option<Output> {
        self.out.pop_front()
    }

    /// The status as it is now (the driver publishes it when it changed).
    pub fn status(&self) -> VmdStatus {
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
        status
    }

    /// Runs the engine's actions and finishes the job if it ended: call
    /// after every event.
    pub fn settle(&mut self, now: Duration) {
        while let Some(r) = &mut self.running {
            let Some(action) = r.engine.poll_action() else {
                break;
            };
            match action {
                Action::Alarm(cause) => {
                    let cause = match &r.timed_out {
                        Some(why) => cause.map(|t| format!("{t}: {why}")),
                        None => cause,
                    };
                    self.report(Severity::Alarm(cause.class), cause.text);
                }
                Action::Entered(s) => tracing::debug!(state = %s, "recipe state"),
                a => {
                    let mut out = Vec::new();
                    self.device.act(now, a, &mut out);
                    self.feed(now, out);
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
                self.out.push_back(Output::Job {
                    program: r.name,
                    event,
                });
            }
        }
    }

    /// The association with `peer` was lost (the commander, or a
    /// subordinate of a cell): a running recipe ends in a communication
    /// alarm naming it.
    pub fn handle_abort(&mut self, peer: &StationName) {
        self.device.lost(peer);
        if self.running.is_some() {
            self.fault(Cause::new(
                AlarmClass::Communication,
                format!("no connection with station {peer}"),
            ));
        }
    }

    /// The commander associated (and with it every subordinate).
    pub fn handle_associated(&mut self) {
        self.device.associated();
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

    /// Answers one indication from the commander (the driver sends the
    /// response), and settles.
    pub fn handle_request(
        &mut self,
        now: Duration,
        req: &Request,
    ) -> Result<Response, ServiceError> {
        let Some((result, transition)) = self.vmd.handle(req) else {
            return Err(ServiceError::malformed(format!(
                "{} is not served by a {} station",
                req.service(),
                self.kind
            )));
        };
        let Some(t) = transition else { return result };
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
                    return result;
                }
                PiCompletion::Stopped
            }
            PiRequest::Reset => PiCompletion::ResetDone,
            PiRequest::Delete => return result,
        };
        let state = self.vmd.complete(&t.name, done).unwrap_or_else(|s| s);
        self.settle(now);
        Ok(Response::ProgramInvocationState(state))
    }
}
