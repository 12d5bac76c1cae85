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
    /// When the device's own supervision next needs the clock (a status
    /// request due, a silence limit), if ever. The controller sleeps until
    /// the earlier of this and the recipe's limit.
    fn poll_timeout(&self) -> Option<Duration> {
        None
    }
    /// The clock reached [`Device::poll_timeout`]; events for the running
    /// recipe go into `out`.
    fn handle_timeout(&mut self, _now: Duration, _out: &mut Vec<Event>) {}
    /// An alarm the device raised that no recipe step owns (a lost line
    /// while idle, a program found running that nobody started): reported
    /// once, when the controller settles.
    fn poll_alarm(&mut self) -> Option<Cause> {
        None
    }
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

    /// When the clock is next needed: the running recipe's next limit or
    /// the device's supervision, whichever comes first.
    pub fn poll_timeout(&self) -> Option<Duration> {
        let recipe = self.running.as_ref().and_then(|r| r.engine.poll_timeout());
        match (recipe, self.device.poll_timeout()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The clock reached [`Self::poll_timeout`]: the device's supervision
    /// and the recipe's limit, each if due.
    pub fn handle_timeout(&mut self, now: Duration) {
        if self.device.poll_timeout().is_some_and(|d| d <= now) {
            let mut out = Vec::new();
            self.device.handle_timeout(now, &mut out);
            self.feed(now, out);
        }
        let due = self
            .running
            .as_ref()
            .and_then(|r| r.engine.poll_timeout())
            .is_some_and(|d| d <= now);
        if !due {
            return;
        }
        let explained = self.device.explain_timeout(now);
        if let Some(r) = &mut self.running {
            if let Some(e) = &explained {
                tracing::info!(state = %r.engine.state(), "limit ran out: {e}");
            }
            r.timed_out = explained;
            r.engine.handle_timeout(now);
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
        while let Some(cause) = self.device.poll_alarm() {
            self.report(Severity::Alarm(cause.class), cause.text);
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

/// What the unit tests of the controller cores share: loading a recipe as
/// the commander's delivery does, and draining the outputs.
#[cfg(test)]
pub(crate) mod testing {
    use super::*;
    use falc_model::mms::domain::download_steps;

    /// Delivers `text` as domain and reusable program invocation `name`,
    /// as `falc_bus::download` does.
    pub fn load<D: Device>(c: &mut Controller<D>, name: &str, text: &str) {
        let n = ObjectName::new(name).unwrap();
        let mut steps = download_steps(&n, text.as_bytes());
        steps.push(Request::CreateProgramInvocation {
            name: n.clone(),
            domains: vec![n],
            reusable: true,
        });
        for req in steps {
            c.handle_request(Duration::ZERO, &req).unwrap();
        }
    }

    /// Everything put out so far, in order.
    pub fn outputs<D: Device>(c: &mut Controller<D>) -> Vec<Output> {
        std::iter::from_fn(|| c.poll_output()).collect()
    }
}

#[cfg(test)]
mod tests {
    //! The runtime on a virtual clock, with a fake device that records what
    //! the recipe made it do: the paths the multi-process tests cover
    //! (done, time limit, lost association, refusal, stop, settling).

    use super::testing::{load, outputs};
    use super::*;
    use falc_model::ids::RobotProgram;
    use falc_model::mms::program::PiState;
    use falc_recipe::check::Job;

    const DROOG_DIK: &str = "#DROOG_DIK\n\
        -1 | start rcm 65 |       | gestart    | 2\n\
        -1 | start rcm 65 |       | tijdlimiet | 3\n\
        -2 | wait rcm 170  |       | klaar      | 0\n\
        -2 | wait rcm 170  |       | tijdlimiet | 3\n\
        -3 |              | alarm |            | 0\n";

    #[derive(Default)]
    struct Fake {
        acts: Vec<Action>,
        halted: usize,
        finished: Vec<Outcome>,
        down: Option<String>,
        settling: bool,
        lost: Vec<StationName>,
        /// Its supervision's next deadline, and when it ran.
        supervise_at: Option<Duration>,
        supervised: Vec<Duration>,
        /// Raised by the supervision: a line gone silent.
        alarms: std::collections::VecDeque<Cause>,
    }

    impl Device for Fake {
        fn unavailable(&self) -> Option<String> {
            self.down.clone()
        }
        fn act(&mut self, _now: Duration, action: Action, _out: &mut Vec<Event>) {
            self.acts.push(action);
        }
        fn halt(&mut self, _out: &mut Vec<Event>) {
            self.halted += 1;
        }
        fn finished(&mut self, outcome: &Outcome) {
            self.finished.push(outcome.clone());
        }
        fn settling(&self) -> bool {
            self.settling
        }
        fn explain_timeout(&self, _now: Duration) -> Option<String> {
            Some("robot program 65 still runs".into())
        }
        fn status(&self, _status: &mut VmdStatus) {}
        fn lost(&mut self, station: &StationName) {
            self.lost.push(station.clone());
        }
        fn poll_timeout(&self) -> Option<Duration> {
            self.supervise_at
        }
        fn handle_timeout(&mut self, now: Duration, _out: &mut Vec<Event>) {
            self.supervised.push(now);
            self.supervise_at = None;
            self.alarms.push_back(Cause::new(
                AlarmClass::Communication,
                "status request unanswered".to_string(),
            ));
        }
        fn poll_alarm(&mut self) -> Option<Cause> {
            self.alarms.pop_front()
        }
    }

    fn name(s: &str) -> ObjectName {
        ObjectName::new(s).unwrap()
    }

    fn rcm() -> StationName {
        StationName::new("rcm").unwrap()
    }

    fn secs(s: u64) -> Duration {
        Duration::from_secs(s)
    }

    /// A welding controller holding `droog_dik` as a program invocation.
    fn loaded() -> Controller<Fake> {
        let mut c = Controller::new(RecipeKind::Welding, secs(30), Fake::default());
        load(&mut c, "droog_dik", DROOG_DIK);
        c
    }

    fn start(c: &mut Controller<Fake>, now: Duration) -> Result<Response, ServiceError> {
        c.handle_request(
            now,
            &Request::Start {
                name: name("droog_dik"),
                argument: String::new(),
            },
        )
    }

    fn job_events(outs: &[Output]) -> Vec<JobEvent> {
        outs.iter()
            .filter_map(|o| match o {
                Output::Job { event, .. } => Some(event.clone()),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn a_recipe_runs_to_done_and_its_job_event_goes_up() {
        let mut c = loaded();
        let r = start(&mut c, secs(1)).unwrap();
        assert_eq!(r, Response::ProgramInvocationState(PiState::Running));
        assert!(c.is_running());
        assert_eq!(
            c.device.acts,
            vec![Action::Start {
                target: rcm(),
                job: Job::Program(RobotProgram::of(65))
            }]
        );
        assert_eq!(c.status().program.map(|p| p.state), Some(1));
        c.feed(secs(2), vec![Event::Started(rcm())]);
        c.settle(secs(2));
        assert_eq!(c.status().program.map(|p| p.state), Some(2));
        // The wait's limit: 170 s from entering state 2.
        assert_eq!(c.poll_timeout(), Some(secs(172)));
        c.feed(secs(60), vec![Event::Ended(rcm(), JobEnd::Done)]);
        c.settle(secs(60));
        assert!(!c.is_running());
        assert_eq!(job_events(&outputs(&mut c)), vec![JobEvent::Done]);
        assert_eq!(c.device.finished, vec![Outcome::Done]);
        assert_eq!(c.poll_timeout(), None);
        assert_eq!(c.status().local_detail, RecipeState::Idle);
    }

    #[test]
    fn a_limit_that_runs_out_is_an_alarm_naming_what_the_device_saw() {
        let mut c = loaded();
        start(&mut c, Duration::ZERO).unwrap();
        c.feed(secs(1), vec![Event::Started(rcm())]);
        c.settle(secs(1));
        let deadline = c.poll_timeout().unwrap();
        // Not yet: an early wake-up changes nothing.
        c.handle_timeout(deadline - secs(1));
        c.settle(deadline - secs(1));
        assert!(c.is_running());
        c.handle_timeout(deadline);
        c.settle(deadline);
        assert!(!c.is_running());
        let outs = outputs(&mut c);
        let alarm = outs.iter().find_map(|o| match o {
            Output::Report {
                severity: Severity::Alarm(class),
                text,
            } => Some((*class, text.clone())),
            _ => None,
        });
        let (class, text) = alarm.unwrap();
        assert_eq!(class, AlarmClass::Process);
        assert!(text.contains("robot program 65 still runs"), "{text}");
        match job_events(&outs).as_slice() {
            [JobEvent::Alarm(cause)] => {
                assert!(
                    cause.text.contains("robot program 65 still runs"),
                    "{cause:?}"
                )
            }
            other => panic!("expected one alarm job event, got {other:?}"),
        }
    }

    #[test]
    fn a_lost_commander_ends_the_running_recipe_in_a_communication_alarm() {
        let mut c = loaded();
        start(&mut c, Duration::ZERO).unwrap();
        let cell = StationName::new("cell").unwrap();
        c.handle_abort(&cell);
        c.settle(secs(1));
        assert!(!c.is_running());
        assert_eq!(c.device.lost, vec![cell.clone()]);
        let outs = outputs(&mut c);
        let expected = Cause::new(
            AlarmClass::Communication,
            "no connection with station cell".to_string(),
        );
        assert!(outs.contains(&Output::Report {
            severity: Severity::Alarm(AlarmClass::Communication),
            text: expected.text.clone(),
        }));
        assert_eq!(job_events(&outs), vec![JobEvent::Alarm(expected)]);
        // Lost while idle: the device hears of it, nothing is reported.
        c.handle_abort(&cell);
        assert_eq!(outputs(&mut c), vec![]);
        assert_eq!(c.device.lost.len(), 2);
    }

    #[test]
    fn a_device_that_cannot_start_refuses_and_a_second_start_is_refused_while_one_runs() {
        let mut c = loaded();
        c.device.down = Some("emergency stop pressed".into());
        let e = start(&mut c, Duration::ZERO).unwrap_err();
        assert!(e.description.contains("emergency stop pressed"), "{e:?}");
        assert!(!c.is_running());
        assert!(c.device.acts.is_empty());
        c.device.down = None;
        start(&mut c, secs(1)).unwrap();
        let e = start(&mut c, secs(2)).unwrap_err();
        assert!(e.description.contains("is running"), "{e:?}");
        assert_eq!(
            c.device.acts.len(),
            1,
            "the running recipe is not started twice"
        );
    }

    #[test]
    fn a_stop_halts_the_device_and_forgets_the_job() {
        let mut c = loaded();
        start(&mut c, Duration::ZERO).unwrap();
        let r = c
            .handle_request(
                secs(3),
                &Request::Stop {
                    name: name("droog_dik"),
                },
            )
            .unwrap();
        assert_eq!(r, Response::ProgramInvocationState(PiState::Stopped));
        assert_eq!(c.device.halted, 1);
        assert!(!c.is_running());
        assert!(matches!(c.device.finished.as_slice(), [Outcome::Alarm(_)]));
        // A late end of the robot's program changes nothing.
        c.feed(secs(4), vec![Event::Ended(rcm(), JobEnd::Done)]);
        c.settle(secs(4));
        assert_eq!(job_events(&outputs(&mut c)), vec![]);
    }

    #[test]
    fn done_waits_until_the_device_has_carried_out_its_outputs() {
        let mut c = loaded();
        start(&mut c, Duration::ZERO).unwrap();
        c.feed(secs(1), vec![Event::Started(rcm())]);
        c.device.settling = true;
        c.feed(secs(5), vec![Event::Ended(rcm(), JobEnd::Done)]);
        c.settle(secs(5));
        assert!(c.is_running(), "done is held back while outputs settle");
        assert_eq!(job_events(&outputs(&mut c)), vec![]);
        c.device.settling = false;
        c.settle(secs(6));
        assert_eq!(job_events(&outputs(&mut c)), vec![JobEvent::Done]);
    }

    #[test]
    fn a_recipe_with_an_error_is_refused_with_its_line_and_the_invocation_stays_usable() {
        let mut c = Controller::new(RecipeKind::Welding, secs(30), Fake::default());
        load(&mut c, "bad", "#BAD\n-1 | frobnicate |  |  | 0\n");
        let n = name("bad");
        let e = c
            .handle_request(
                secs(1),
                &Request::Start {
                    name: n.clone(),
                    argument: String::new(),
                },
            )
            .unwrap_err();
        assert!(e.description.starts_with("error in recipe BAD:"), "{e:?}");
        assert!(e.description.contains("BAD:2: state 1"), "{e:?}");
        assert!(!c.is_running());
        // Refused, not stuck: the next Start meets the same check again.
        let again = c
            .handle_request(
                secs(2),
                &Request::Start {
                    name: n,
                    argument: String::new(),
                },
            )
            .unwrap_err();
        assert_eq!(again.description, e.description);
    }

    #[test]
    fn a_fault_without_a_recipe_is_still_reported() {
        let mut c = loaded();
        c.fault(Cause::new(AlarmClass::Safety, "emergency stop".to_string()));
        assert_eq!(
            outputs(&mut c),
            vec![Output::Report {
                severity: Severity::Alarm(AlarmClass::Safety),
                text: "emergency stop".into()
            }]
        );
    }

    #[test]
    fn the_device_supervision_shares_the_clock_and_its_alarms_are_reported() {
        let mut c = loaded();
        // Idle: only the device wants the clock.
        c.device.supervise_at = Some(secs(1));
        assert_eq!(c.poll_timeout(), Some(secs(1)));
        c.handle_timeout(secs(1));
        c.settle(secs(1));
        assert_eq!(c.device.supervised, vec![secs(1)]);
        assert_eq!(
            outputs(&mut c),
            vec![Output::Report {
                severity: Severity::Alarm(AlarmClass::Communication),
                text: "status request unanswered".into()
            }]
        );
        // Running: the earlier of the recipe's limit and the device's.
        start(&mut c, secs(2)).unwrap();
        c.feed(secs(2), vec![Event::Started(rcm())]);
        c.settle(secs(2));
        assert_eq!(c.poll_timeout(), Some(secs(172)));
        c.device.supervise_at = Some(secs(3));
        assert_eq!(c.poll_timeout(), Some(secs(3)));
        c.handle_timeout(secs(3));
        c.settle(secs(3));
        assert_eq!(c.device.supervised, vec![secs(1), secs(3)]);
        assert!(c.is_running(), "the recipe's own limit is not due yet");
        assert_eq!(c.poll_timeout(), Some(secs(172)));
    }
}
