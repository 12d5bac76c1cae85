//! The cell controller's device: its workstations below and the operator
//! above, as a cell recipe sees them. `start` / `stop` become Start / Stop
//! requests to a workstation's program invocation, `output` / `input`
//! become operator-communication requests to the commander; each request
//! runs in its own task and its confirm comes back as a [`Reply`]. Job
//! events and reports published by the workstations come in as
//! [`Unconfirmed`] and become engine events.

use falc_bus::Bus;
use falc_control::controller::Device;
use falc_model::ids::{ObjectName, StationName};
use falc_model::mms::pdu::{JobEvent, Request, Response, Unconfirmed};
use falc_model::mms::vmd::{PhysicalStatus, VmdStatus};
use falc_recipe::check::Job;
use falc_recipe::engine::{Action, Event, JobEnd};
use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;
use tokio::sync::mpsc::UnboundedSender;

/// How long the operator may take to answer an `input`.
const ANSWER_LIMIT: Duration = Duration::from_secs(24 * 3600);
/// How long a workstation may take to confirm a request.
const CONFIRM_LIMIT: Duration = Duration::from_secs(10);

/// The confirm of a request the cell made.
#[derive(Debug)]
pub enum Reply {
    /// A workstation confirmed (or refused) a Start.
    Started(StationName, Result<(), String>),
    /// The operator answered an `input`.
    Answer(Result<String, String>),
    /// The operator confirmed (or refused) an `output`.
    Shown(Result<(), String>),
    /// Anything else (Output, Stop): only a refusal matters.
    Other(String, Result<(), String>),
}

/// The workstations below and the operator above.
pub struct Below {
    bus: Bus,
    operator: Option<StationName>,
    replies: UnboundedSender<Reply>,
    /// The program invocation the running recipe started on each station.
    started: BTreeMap<StationName, ObjectName>,
    /// Stations whose association was lost since the commander associated.
    lost: BTreeSet<StationName>,
    /// One lane per station: its requests go out in order, one at a time
    /// (outputs reach the operator in the recipe's order; a Stop never
    /// overtakes its Start).
    lanes: BTreeMap<StationName, UnboundedSender<Outgoing>>,
    /// Outputs the operator has not confirmed yet: the recipe's end waits
    /// for them, so its last line is journalled under its own order.
    showing: usize,
}

type Outgoing = (
    Request,
    Duration,
    Box<dyn FnOnce(Result<Response, String>) -> Reply + Send>,
);

impl Below {
    /// A cell device on `bus`, answering to `operator`.
    pub fn new(bus: Bus, operator: Option<StationName>, replies: UnboundedSender<Reply>) -> Self {
        Self {
            bus,
            operator,
            replies,
            started: BTreeMap::new(),
            lost: BTreeSet::new(),
            lanes: BTreeMap::new(),
            showing: 0,
        }
    }

    /// The operator confirmed (or refused) one output.
    pub fn shown(&mut self) {
        self.showing = self.showing.saturating_sub(1);
    }

    fn request(
        &mut self,
        to: StationName,
        req: Request,
        limit: Duration,
        done: impl FnOnce(Result<Response, String>) -> Reply + Send + 'static,
    ) {
        let lane = self.lanes.entry(to.clone()).or_insert_with(|| {
            let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<Outgoing>();
            let bus = self.bus.clone();
            let replies = self.replies.clone();
            tokio::spawn(async move {
                while let Some((req, limit, done)) = rx.recv().await {
                    let r = bus
                        .request(&to, &req, limit)
                        .await
                        .map_err(|e| e.to_string());
                    let _ = replies.send(done(r));
                }
            });
            tx
        });
        if lane.send((req, limit, Box::new(done))).is_err() {
            tracing::error!("a request lane stopped");
        }
    }

    /// A publication of a workstation: the engine events it means for the
    /// running recipe (only the job this recipe started there counts).
    pub fn unconfirmed(&self, u: &Unconfirmed) -> Vec<Event> {
        let Unconfirmed::Job {
            station,
            program,
            event,
        } = u
        else {
            return Vec::new();
        };
        if self.started.get(station) != Some(program) {
            return Vec::new();
        }
        let st = station.clone();
        vec![match event {
            JobEvent::Done => Event::Ended(st, JobEnd::Done),
            JobEvent::BadProduct => Event::Ended(st, JobEnd::BadProduct),
            JobEvent::FailedSafe => Event::Ended(st, JobEnd::FailedSafe),
            JobEvent::FailedDanger => Event::Ended(st, JobEnd::FailedDanger),
            JobEvent::Alarm(text) => Event::Ended(st, JobEnd::Alarm(text.clone())),
            JobEvent::Paused => Event::Paused(st),
            JobEvent::Resumed => Event::Resumed(st),
        }]
    }
}

impl Device for Below {
    fn unavailable(&self) -> Option<String> {
        self.lost
            .iter()
            .next()
            .map(|s| format!("no connection with station {}", s.as_str().to_uppercase()))
    }

    fn act(&mut self, _now: Duration, action: Action, _out: &mut Vec<Event>) {
        match action {
            Action::Start {
                target,
                job: Job::Recipe(name),
            } => {
                self.started.insert(target.clone(), name.clone());
                let st = target.clone();
                let req = Request::Start {
                    name,
                    argument: String::new(),
                };
                self.request(target, req, CONFIRM_LIMIT, move |r| {
                    Reply::Started(st, r.map(|_| ()))
                });
            }
            Action::Stop(target) => {
                // Stop, then Reset on the same lane: the program invocation
                // is idle again for the next order (a stopped one refuses
                // Start). A Reset refused because the job had already ended
                // is harmless.
                if let Some(name) = self.started.get(&target).cloned() {
                    let what = format!("Stop of {name} on {target}");
                    let stop = Request::Stop { name: name.clone() };
                    self.request(target.clone(), stop, CONFIRM_LIMIT, move |r| {
                        Reply::Other(what, r.map(|_| ()))
                    });
                    let what = format!("Reset of {name} on {target}");
                    self.request(target, Request::Reset { name }, CONFIRM_LIMIT, move |r| {
                        Reply::Other(what, r.map(|_| ()))
                    });
                }
            }
            Action::Output(text) => {
                if let Some(op) = self.operator.clone() {
                    let req = Request::Output { lines: vec![text] };
                    self.showing += 1;
                    self.request(op, req, CONFIRM_LIMIT, |r| Reply::Shown(r.map(|_| ())));
                }
            }
            Action::Input(prompt) => match self.operator.clone() {
                Some(op) => {
                    let req = Request::Input {
                        prompt,
                        timeout_s: None,
                    };
                    self.request(op, req, ANSWER_LIMIT, |r| {
                        Reply::Answer(r.and_then(|resp| match resp {
                            Response::Answer(a) => Ok(a),
                            other => Err(format!("the operator answered {other:?}")),
                        }))
                    });
                }
                None => {
                    let _ = self
                        .replies
                        .send(Reply::Answer(Err("this cell has no operator".into())));
                }
            },
            other => tracing::warn!("a cell recipe cannot {other:?}"),
        }
    }

    fn halt(&mut self, out: &mut Vec<Event>) {
        let running: Vec<StationName> = self.started.keys().cloned().collect();
        for st in running {
            self.act(Duration::ZERO, Action::Stop(st), out);
        }
    }

    fn settling(&self) -> bool {
        self.showing > 0
    }

    fn finished(&mut self, _outcome: &falc_recipe::engine::Outcome) {
        self.started.clear();
    }

    fn status(&self, status: &mut VmdStatus) {
        if !self.lost.is_empty() {
            status.physical = PhysicalStatus::PartiallyOperational;
        }
    }

    fn lost(&mut self, station: &StationName) {
        if Some(station) != self.operator.as_ref() {
            self.lost.insert(station.clone());
        }
    }

    fn associated(&mut self) {
        self.lost.clear();
    }
}
