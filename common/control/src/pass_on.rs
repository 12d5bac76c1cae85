//! The cell's pass-on, sans-I/O: what the cell hands its workstations on
//! its commander's behalf, and when it answers the commander.
//!
//! - **Requests passed on.** A mode goes to the cell's controller first,
//!   then to every workstation; a step on a workstation or a manual
//!   operation goes to the one it names ([`route`]). The commander's
//!   indication is answered once every workstation asked confirmed: done,
//!   or the refusals, named, joined in the workstations' order.
//! - **A mode is all or nothing.** Refused by one workstation, it is taken
//!   back at the cell's controller and at every workstation, and the
//!   refusal says the mode stays. The cell's mode also goes to its
//!   workstations whenever they are associated (a cell started again, a
//!   workstation back); one that refuses it there, or refuses to take a
//!   mode back, is not in the cell's mode, and a Start is refused naming
//!   it until a mode it takes ([`PassOn::handle_confirm`]).
//! - **Recipe deliveries.** A domain the commander downloads as
//!   `STATION$NAME` is workstation `STATION`'s recipe `NAME`: once the cell's
//!   controller has it, it is delivered to that workstation (domain and
//!   program invocation) and the download is answered only when the
//!   workstation has it. A delivery that fails is thrown away: the cell
//!   drops its copy too ([`Todo::Discard`]) and the download is refused
//!   with the workstation's error, so a recipe is never half-applied.
//!   Unchanged content is not sent again. A workstation that was lost
//!   comes back empty: when the workstations are associated again, every
//!   recipe one should hold is sent again, and each that cannot be is a
//!   communication alarm, and owed: sent again before the commander's next
//!   indication is taken (the way back's `start`), also one held behind a
//!   delivery. A recipe delivered is owed no more. A workstation lost
//!   during a delivery ends it at once (no waiting for a confirm that
//!   cannot come): the commander's download is refused, a catch-up of its
//!   recipes waits for its return. A Start or Resume that finds a recipe
//!   still owed once that is done is refused naming it and why: an order
//!   never starts on a workstation that lacks its recipes.
//! - **Order.** Deliveries run one at a time in the order asked; while one
//!   runs, the commander's further indications are held and taken in
//!   order once it ended, as if the cell had waited (a Start must not
//!   overtake the delivery of its recipe). Nothing else waits.
//!
//! The driver hands in the commander's indications
//! ([`PassOn::handle_indication`]) with a ticket of its own (`T`: whatever
//! answers the indication), answers those [`PassOn::poll_here`] gives with
//! the cell's controller ([`PassOn::handled`]), carries out what
//! [`PassOn::poll_todo`] gives, and hands back the workstations' confirms
//! ([`PassOn::handle_confirm`], [`PassOn::handle_delivered`]) and the
//! associations' changes ([`PassOn::handle_lost`],
//! [`PassOn::handle_associated`]). The driver on the bus is `falc-cell`;
//! `falc-sim` drives the same core.

use crate::coordination::{route, workstation_domain, Route};
use falc_model::ids::{ObjectName, StationName};
use falc_model::mms::domain::content_hash;
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::{Request, Response};
use falc_model::mms::vmd::Vmd;
use falc_model::mode::ModeSetting;
use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

/// How long a workstation may take to confirm a mode, step or manual
/// operation passed on.
pub const PASS_LIMIT: Duration = Duration::from_secs(10);

/// How many recipes still owed a refused start names (the rest counted).
const OWED_SAID: usize = 3;

/// An indication the cell's own controller answers first.
#[derive(Debug)]
pub struct Here<T> {
    /// The driver's handle on the indication (none: the pass-on's own, a
    /// refused mode change taken back, which nobody waits for).
    pub ticket: Option<T>,
    /// What the commander asked.
    pub request: Request,
    /// Passed on to every workstation once the controller accepted it.
    then_all: bool,
}

/// What the driver carries out, in order.
#[derive(Debug, PartialEq)]
pub enum Todo<T> {
    /// Answer the commander's indication.
    Answer {
        /// The driver's handle on it.
        ticket: T,
        /// The answer.
        result: Result<Response, ServiceError>,
    },
    /// Ask workstation `to` (limit [`PASS_LIMIT`]); its confirm goes to
    /// [`PassOn::handle_confirm`] with `id`.
    Ask {
        /// Names the confirm.
        id: u64,
        /// The workstation.
        to: StationName,
        /// What it is asked.
        request: Request,
    },
    /// Deliver recipe `name` to workstation `to` (its domain and program
    /// invocation, all or nothing); the outcome goes to
    /// [`PassOn::handle_delivered`] with `id`.
    Deliver {
        /// Names the outcome.
        id: u64,
        /// The workstation.
        to: StationName,
        /// The recipe's name there.
        name: ObjectName,
        /// Its content.
        content: Vec<u8>,
    },
    /// The recipe is at its workstation (the driver says so).
    Delivered {
        /// The workstation.
        to: StationName,
        /// The recipe.
        name: ObjectName,
    },
    /// Drop the cell's domain: its delivery was thrown away.
    Discard(ObjectName),
    /// A communication alarm to report up (a recipe a returned workstation
    /// could not be given again).
    Alarm(String),
    /// Worth a warning in the log, no more (a workstation that did not
    /// take the cell's mode when it came back: the next order's start
    /// finds it).
    Warn(String),
}

/// One recipe for a workstation.
#[derive(Debug, Clone)]
struct Recipe {
    station: StationName,
    name: ObjectName,
    content: Vec<u8>,
}

/// A delivery job: one recipe a download waits for, or a catch-up.
#[derive(Debug)]
struct Job<T> {
    /// The download that waits, with the cell's domain (none: a catch-up).
    download: Option<(T, ObjectName)>,
    /// Recipes not sent yet.
    todo: VecDeque<Recipe>,
    /// The one under way, and its id.
    sending: Option<(u64, Recipe)>,
    /// Each recipe that failed, and why.
    failed: Vec<(Recipe, ServiceError)>,
}

/// A request passed on, waiting for its workstations' confirms.
#[derive(Debug)]
struct Pass<T> {
    /// The indication answered at the end (none: the cell's own, a mode
    /// for a returned workstation or taken back).
    ticket: Option<T>,
    /// The confirms awaited, by id, in the workstations' order.
    waiting: Vec<u64>,
    /// The workstation each confirm is of.
    to: BTreeMap<u64, StationName>,
    /// The refusals so far, by id.
    refused: BTreeMap<u64, String>,
    /// A mode passed on: a workstation that takes it is in the cell's mode.
    mode: bool,
    /// The commander's mode change: the mode the cell had before, to take
    /// it back if any workstation refuses (all or nothing).
    before: Option<ModeSetting>,
}

/// The cell's pass-on ([module docs](self)).
#[derive(Debug)]
pub struct PassOn<T> {
    workstations: Vec<StationName>,
    /// What each workstation holds: content hash per recipe.
    holds: BTreeMap<(StationName, ObjectName), u64>,
    /// Deliveries asked and not ended, the first under way.
    jobs: VecDeque<Job<T>>,
    /// The commander's indications held while a delivery runs, each with
    /// whether the recipes owed were sent again for it already.
    held: VecDeque<(T, Request, bool)>,
    /// Indications for the cell's controller.
    here: VecDeque<Here<T>>,
    /// Recipes a returned workstation could not be given (a communication
    /// alarm said so): sent again before the commander's next indication
    /// is taken, so the way back (`ack`, `start`) delivers them first.
    owed: Vec<(Recipe, ServiceError)>,
    /// Requests passed on: id of the pass → the pass.
    passes: BTreeMap<u64, Pass<T>>,
    /// The mode the cell's controller last took.
    mode: ModeSetting,
    /// Workstations known not to be in the cell's mode: one refused a mode
    /// the cell could not take back, or the cell's mode when it was
    /// associated (a job by hand runs there); why. A start is refused while
    /// any is listed; a mode it takes clears it.
    not_in_mode: BTreeMap<StationName, String>,
    /// Confirm id → its pass.
    asked: BTreeMap<u64, u64>,
    next_id: u64,
    out: VecDeque<Todo<T>>,
}

impl<T> PassOn<T> {
    /// The pass-on of a cell over `workstations`.
    pub fn new(workstations: Vec<StationName>) -> Self {
        Self {
            workstations,
            holds: BTreeMap::new(),
            jobs: VecDeque::new(),
            held: VecDeque::new(),
            here: VecDeque::new(),
            owed: Vec::new(),
            passes: BTreeMap::new(),
            mode: ModeSetting::default(),
            not_in_mode: BTreeMap::new(),
            asked: BTreeMap::new(),
            next_id: 0,
            out: VecDeque::new(),
        }
    }

    /// Whether a delivery is under way (the commander's indications wait).
    pub fn busy(&self) -> bool {
        !self.jobs.is_empty()
    }

    fn id(&mut self) -> u64 {
        self.next_id += 1;
        self.next_id
    }

    /// The commander's indication: held while a delivery runs, else routed.
    /// Recipes owed to a workstation are sent first (the indication waits
    /// for them).
    pub fn handle_indication(&mut self, ticket: T, request: Request) {
        let sent = !self.owed.is_empty() && !self.busy();
        if sent {
            self.send_owed();
        }
        if self.busy() || !self.held.is_empty() {
            // Sent again for it now, or else once the deliveries ended.
            self.held.push_back((ticket, request, sent));
        } else {
            self.route(ticket, request);
        }
    }

    fn route(&mut self, ticket: T, request: Request) {
        let starts = matches!(request, Request::Start { .. } | Request::Resume { .. });
        match route(&request, &self.workstations) {
            Route::Here if starts && !self.owed.is_empty() => {
                // The deliveries' refusals name recipe and workstation.
                let mut why: Vec<String> = self
                    .owed
                    .iter()
                    .take(OWED_SAID)
                    .map(|(_, e)| e.description.clone())
                    .collect();
                if self.owed.len() > OWED_SAID {
                    why.push(format!("{} more recipes", self.owed.len() - OWED_SAID));
                }
                self.out.push_back(Todo::Answer {
                    ticket,
                    result: Err(ServiceError::state_conflict(format!(
                        "{}; the cell starts no order until its workstations hold their recipes \
                         (sent again at the next start)",
                        why.join("; ")
                    ))),
                });
            }
            Route::Here if starts && !self.not_in_mode.is_empty() => {
                let why: Vec<String> = self
                    .not_in_mode
                    .iter()
                    .map(|(st, why)| format!("{st} is not in the cell's mode {}: {why}", self.mode))
                    .collect();
                self.out.push_back(Todo::Answer {
                    ticket,
                    result: Err(ServiceError::state_conflict(format!(
                        "{}; set the mode again once it can take it (falc mode {})",
                        why.join("; "),
                        self.mode.mode
                    ))),
                });
            }
            Route::Here => self.here.push_back(Here {
                ticket: Some(ticket),
                request,
                then_all: false,
            }),
            Route::HereThenAll => self.here.push_back(Here {
                ticket: Some(ticket),
                request,
                then_all: true,
            }),
            Route::To(st) => self.pass(Some(ticket), vec![st], request),
            Route::Refused(e) => self.out.push_back(Todo::Answer {
                ticket,
                result: Err(e),
            }),
        }
    }

    /// The next indication for the cell's controller; answer it with
    /// [`Self::handled`]. Held indications are taken here, in order, once
    /// no delivery runs.
    pub fn poll_here(&mut self) -> Option<Here<T>> {
        while self.here.is_empty() && !self.busy() {
            let (ticket, request, retried) = self.held.pop_front()?;
            if !retried && !self.owed.is_empty() {
                // Held behind a delivery that left recipes owed: they go
                // again first, as for an indication that finds them owed.
                self.held.push_front((ticket, request, true));
                self.send_owed();
                continue;
            }
            self.route(ticket, request);
        }
        self.here.pop_front()
    }

    /// The cell's controller answered `here` with `result`; `vmd` is the
    /// cell's (a download it accepted is delivered from it).
    pub fn handled(&mut self, here: Here<T>, result: Result<Response, ServiceError>, vmd: &Vmd) {
        let Here {
            ticket,
            request,
            then_all,
        } = here;
        let Some(ticket) = ticket else {
            // The cell's own mode taken back: nobody waits for it.
            match (result, &request) {
                (Ok(_), Request::Mode(m)) => self.mode = m.clone(),
                (Err(e), _) => tracing::warn!("the cell's mode not taken back: {e}"),
                _ => {}
            }
            return;
        };
        match (result, &request) {
            (Err(e), _) => self.out.push_back(Todo::Answer {
                ticket,
                result: Err(e),
            }),
            (Ok(_), Request::Mode(m)) if then_all => {
                // All or nothing: taken back here and where it was taken if
                // any workstation refuses ([`Self::pass_ended`]).
                let before = std::mem::replace(&mut self.mode, m.clone());
                let to = self.workstations.clone();
                self.pass_mode(Some(ticket), to, m.clone(), Some(before));
            }
            (Ok(_), _) if then_all => {
                let to = self.workstations.clone();
                self.pass(Some(ticket), to, request);
            }
            (
                Ok(_),
                Request::TerminateDownloadSequence {
                    domain,
                    discard: None,
                },
            ) => self.downloaded(ticket, domain, vmd),
            (Ok(r), _) => self.out.push_back(Todo::Answer {
                ticket,
                result: Ok(r),
            }),
        }
    }

    /// The cell's controller holds domain `domain` (its download ended):
    /// a workstation's recipe is delivered before the download is
    /// answered; the cell's own is answered at once.
    pub fn downloaded(&mut self, ticket: T, domain: &ObjectName, vmd: &Vmd) {
        let Some((station, name)) = workstation_domain(domain) else {
            self.out.push_back(Todo::Answer {
                ticket,
                result: Ok(Response::Done),
            });
            return;
        };
        if !self.workstations.contains(&station) {
            self.out.push_back(Todo::Discard(domain.clone()));
            self.out.push_back(Todo::Answer {
                ticket,
                result: Err(ServiceError::undefined(format!(
                    "recipe {domain}: {station} is not a workstation of this cell"
                ))),
            });
            return;
        }
        let content = vmd
            .domain(domain)
            .map(|d| d.content().to_vec())
            .unwrap_or_default();
        let recipe = Recipe {
            station,
            name,
            content,
        };
        self.deliver(Some((ticket, domain.clone())), VecDeque::from([recipe]));
    }

    /// Passes `request` on to workstations `to`.
    fn pass(&mut self, ticket: Option<T>, to: Vec<StationName>, request: Request) {
        self.pass_with(ticket, to, request, None);
    }

    /// Passes mode `mode` on to workstations `to`; `before`: the cell's
    /// mode before, taken back if any refuses.
    fn pass_mode(
        &mut self,
        ticket: Option<T>,
        to: Vec<StationName>,
        mode: ModeSetting,
        before: Option<ModeSetting>,
    ) {
        self.pass_with(ticket, to, Request::Mode(mode), before);
    }

    fn pass_with(
        &mut self,
        ticket: Option<T>,
        to: Vec<StationName>,
        request: Request,
        before: Option<ModeSetting>,
    ) {
        let pass = self.id();
        let mut waiting = Vec::new();
        let mut asked = BTreeMap::new();
        for st in to {
            let id = self.id();
            waiting.push(id);
            self.asked.insert(id, pass);
            asked.insert(id, st.clone());
            self.out.push_back(Todo::Ask {
                id,
                to: st,
                request: request.clone(),
            });
        }
        let p = Pass {
            ticket,
            waiting,
            to: asked,
            refused: BTreeMap::new(),
            mode: matches!(request, Request::Mode(_)),
            before,
        };
        self.passes.insert(pass, p);
        self.pass_ended(pass);
    }

    /// A workstation confirmed the request of [`Todo::Ask`] `id`.
    pub fn handle_confirm(&mut self, id: u64, result: Result<Response, ServiceError>) {
        let Some(pass) = self.asked.remove(&id) else {
            return;
        };
        if let Some(p) = self.passes.get_mut(&pass) {
            p.waiting.retain(|w| *w != id);
            match result {
                Err(e) => {
                    p.refused.insert(id, e.description);
                }
                // A mode taken: this workstation is in the cell's mode.
                Ok(_) if p.mode => {
                    if let Some(st) = p.to.get(&id) {
                        self.not_in_mode.remove(st);
                    }
                }
                Ok(_) => {}
            }
        }
        self.pass_ended(pass);
    }

    /// Answers pass `pass` if no confirm is awaited.
    fn pass_ended(&mut self, pass: u64) {
        if !self.passes.get(&pass).is_some_and(|p| p.waiting.is_empty()) {
            return;
        }
        let Some(p) = self.passes.remove(&pass) else {
            return;
        };
        // Taken back everywhere: one that refused is asked too (harmless,
        // it has that mode), since one whose answer never came may have
        // taken the mode all the same.
        let asked: Vec<StationName> = p.to.values().cloned().collect();
        let refusers: Vec<(StationName, String)> = p
            .refused
            .iter()
            .filter_map(|(id, why)| Some((p.to.get(id)?.clone(), why.clone())))
            .collect();
        let refused: Vec<String> = p.refused.into_values().collect();
        match (p.ticket, refused.is_empty(), p.before) {
            (Some(ticket), true, _) => self.out.push_back(Todo::Answer {
                ticket,
                result: Ok(Response::Done),
            }),
            // A mode is all or nothing: refused by one, it is taken back
            // at the cell and at every workstation that took it, so that
            // no station runs in another mode than the cell's.
            (Some(ticket), false, Some(before)) => {
                let to = std::mem::replace(&mut self.mode, before.clone());
                self.here.push_back(Here {
                    ticket: None,
                    request: Request::Mode(before.clone()),
                    then_all: false,
                });
                self.pass_mode(None, asked, before.clone(), None);
                self.out.push_back(Todo::Answer {
                    ticket,
                    result: Err(ServiceError::state_conflict(format!(
                        "{}: the mode stays {before} (not {to}) at the cell and every workstation",
                        refused.join("; ")
                    ))),
                });
            }
            (Some(ticket), false, None) => self.out.push_back(Todo::Answer {
                ticket,
                result: Err(ServiceError::state_conflict(refused.join("; "))),
            }),
            // The cell's mode passed on by itself (a returned workstation,
            // or a mode taken back): a workstation that refused it is not
            // in the cell's mode, and a start is refused until it is.
            (None, _, _) => {
                for (st, why) in refusers {
                    self.out.push_back(Todo::Warn(format!("mode: {why}")));
                    self.not_in_mode.insert(st, why);
                }
            }
        }
    }

    /// Sends every recipe owed again (one catch-up delivery).
    fn send_owed(&mut self) {
        let todo = std::mem::take(&mut self.owed)
            .into_iter()
            .map(|(r, _)| r)
            .collect();
        self.deliver(None, todo);
    }

    /// Queues a delivery of `todo` (for the commander's `download`, or
    /// none: recipes owed or caught up) and goes on with the deliveries.
    fn deliver(&mut self, download: Option<(T, ObjectName)>, todo: VecDeque<Recipe>) {
        self.jobs.push_back(Job {
            download,
            todo,
            sending: None,
            failed: Vec::new(),
        });
        self.next_delivery();
    }

    /// Sends the first job's next recipe its workstation lacks, or ends
    /// the job (and begins the next) when none is left.
    fn next_delivery(&mut self) {
        loop {
            let Some(job) = self.jobs.front_mut() else {
                return;
            };
            if job.sending.is_some() {
                return;
            }
            if let Some(r) = job.todo.pop_front() {
                let key = (r.station.clone(), r.name.clone());
                if self.holds.get(&key) == Some(&content_hash(&r.content)) {
                    continue;
                }
                self.next_id += 1;
                let id = self.next_id;
                self.out.push_back(Todo::Deliver {
                    id,
                    to: r.station.clone(),
                    name: r.name.clone(),
                    content: r.content.clone(),
                });
                job.sending = Some((id, r));
                return;
            }
            let Some(job) = self.jobs.pop_front() else {
                return;
            };
            match job.download {
                Some((ticket, domain)) => {
                    let result = match job.failed.into_iter().next() {
                        None => Ok(Response::Done),
                        Some((_, e)) => {
                            self.out.push_back(Todo::Discard(domain));
                            Err(e)
                        }
                    };
                    self.out.push_back(Todo::Answer { ticket, result });
                }
                None => {
                    for (recipe, e) in job.failed {
                        self.out.push_back(Todo::Alarm(e.description.clone()));
                        // The latest failure stands for the recipe.
                        self.owed.retain(|(r, _)| {
                            (&r.station, &r.name) != (&recipe.station, &recipe.name)
                        });
                        self.owed.push((recipe, e));
                    }
                }
            }
        }
    }

    /// The delivery of [`Todo::Deliver`] `id` ended.
    pub fn handle_delivered(&mut self, id: u64, result: Result<(), ServiceError>) {
        let Some(job) = self.jobs.front_mut() else {
            return;
        };
        let Some((sending, recipe)) = job.sending.take() else {
            return;
        };
        if sending != id {
            job.sending = Some((sending, recipe));
            return;
        }
        let key = (recipe.station.clone(), recipe.name.clone());
        match result {
            Ok(()) => {
                // Delivered: no longer owed, whatever failed before.
                self.owed
                    .retain(|(r, _)| (&r.station, &r.name) != (&recipe.station, &recipe.name));
                self.holds.insert(key, content_hash(&recipe.content));
                self.out.push_back(Todo::Delivered {
                    to: recipe.station,
                    name: recipe.name,
                });
            }
            Err(e) => {
                // What it holds now is not known.
                self.holds.remove(&key);
                job.failed.push((recipe, e));
            }
        }
        self.next_delivery();
    }

    /// Workstation `station`'s association was lost: it will come back
    /// empty. A delivery to it under way fails now (its confirm, if one
    /// still comes, is stale), and the catch-ups queued for it are dropped:
    /// when it is associated again it is sent everything it should hold.
    pub fn handle_lost(&mut self, station: &StationName) {
        self.holds.retain(|(st, _), _| st != station);
        for job in self.jobs.iter_mut().filter(|j| j.download.is_none()) {
            job.todo.retain(|r| &r.station != station);
        }
        let Some(job) = self.jobs.front_mut() else {
            return;
        };
        if job
            .sending
            .as_ref()
            .is_some_and(|(_, r)| &r.station == station)
        {
            // A catch-up's recipe goes again at the next association; the
            // commander's download is refused.
            if let Some((_, recipe)) = job.sending.take().filter(|_| job.download.is_some()) {
                let e = ServiceError::unreachable(format!(
                    "recipe {} not delivered to {station}: the association was lost during the \
                     delivery",
                    recipe.name
                ));
                job.failed.push((recipe, e));
            }
            self.next_delivery();
        }
    }

    /// The workstations were associated (again): each gets every recipe of
    /// the cell's `vmd` it does not hold, and the cell's `mode` (also
    /// automatic: a cell restarted, or a workstation that kept its own
    /// mode while it was away, comes to one mode with its workstations; one
    /// that refuses it keeps a start refused, [`Self::handle_confirm`]).
    pub fn handle_associated(&mut self, vmd: &Vmd, mode: &ModeSetting) {
        self.mode = mode.clone();
        let todo: VecDeque<Recipe> = vmd
            .domains()
            .filter_map(|d| {
                let (station, name) = workstation_domain(d.name())?;
                self.workstations.contains(&station).then(|| Recipe {
                    station,
                    name,
                    content: d.content().to_vec(),
                })
            })
            .collect();
        if !todo.is_empty() {
            self.deliver(None, todo);
        }
        let to = self.workstations.clone();
        self.pass_mode(None, to, mode.clone(), None);
    }

    /// The next thing to carry out.
    pub fn poll_todo(&mut self) -> Option<Todo<T>> {
        self.out.pop_front()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_model::mms::domain::download_steps;
    use falc_model::mms::vmd::Identity;
    use falc_model::mode::{CellMode, ManualAction};

    fn st(s: &str) -> StationName {
        StationName::new(s).unwrap()
    }

    fn name(s: &str) -> ObjectName {
        ObjectName::new(s).unwrap()
    }

    /// A cell's VMD holding `domain` with `content`.
    fn cell_with(vmd: &mut Vmd, domain: &str, content: &[u8]) {
        let _ = vmd.handle(&Request::DeleteDomain {
            domain: name(domain),
        });
        for req in download_steps(&name(domain), content) {
            let (result, _) = vmd.handle(&req).expect("a download step");
            result.unwrap();
        }
    }

    fn terminate(domain: &str) -> Request {
        Request::TerminateDownloadSequence {
            domain: name(domain),
            discard: None,
        }
    }

    fn rig() -> (PassOn<u32>, Vmd) {
        let p = PassOn::new(vec![st("welding"), st("transport")]);
        let vmd = Vmd::new(Identity {
            vendor: "FALC".into(),
            model: "cell".into(),
            revision: "test".into(),
        });
        (p, vmd)
    }

    /// Answers every indication for the controller with `Done`.
    fn answer_here(p: &mut PassOn<u32>, vmd: &Vmd) -> Vec<u32> {
        let mut seen = Vec::new();
        while let Some(h) = p.poll_here() {
            seen.extend(h.ticket);
            p.handled(h, Ok(Response::Done), vmd);
        }
        seen
    }

    fn todos(p: &mut PassOn<u32>) -> Vec<Todo<u32>> {
        std::iter::from_fn(|| p.poll_todo()).collect()
    }

    fn answers(todos: &[Todo<u32>]) -> Vec<(u32, Result<Response, ServiceError>)> {
        todos
            .iter()
            .filter_map(|t| match t {
                Todo::Answer { ticket, result } => Some((*ticket, result.clone())),
                _ => None,
            })
            .collect()
    }

    fn delivery(todos: &[Todo<u32>]) -> Option<(u64, String, String)> {
        todos.iter().find_map(|t| match t {
            Todo::Deliver { id, to, name, .. } => Some((*id, to.to_string(), name.to_string())),
            _ => None,
        })
    }

    #[test]
    fn a_download_is_answered_once_its_workstation_has_it_and_unchanged_content_is_not_sent_again()
    {
        let (mut p, mut vmd) = rig();
        cell_with(&mut vmd, "welding$weld1", b"1 start rcm 1");
        p.handle_indication(1, terminate("welding$weld1"));
        assert_eq!(answer_here(&mut p, &vmd), vec![1]);
        let out = todos(&mut p);
        let (id, to, recipe) = delivery(&out).expect("a delivery");
        assert_eq!((to.as_str(), recipe.as_str()), ("welding", "WELD1"));
        assert!(
            answers(&out).is_empty(),
            "answered before delivered: {out:?}"
        );
        assert!(p.busy());
        p.handle_delivered(id, Ok(()));
        let out = todos(&mut p);
        assert_eq!(answers(&out), vec![(1, Ok(Response::Done))]);
        assert!(out.contains(&Todo::Delivered {
            to: st("welding"),
            name: name("weld1")
        }));
        assert!(!p.busy());
        // The same again: answered at once, nothing sent.
        p.handle_indication(2, terminate("welding$weld1"));
        answer_here(&mut p, &vmd);
        let out = todos(&mut p);
        assert_eq!(delivery(&out), None);
        assert_eq!(answers(&out), vec![(2, Ok(Response::Done))]);
        // Changed content goes again.
        cell_with(&mut vmd, "welding$weld1", b"1 start rcm 2");
        p.handle_indication(3, terminate("welding$weld1"));
        answer_here(&mut p, &vmd);
        assert!(delivery(&todos(&mut p)).is_some());
    }

    #[test]
    fn a_delivery_that_fails_is_thrown_away_at_the_cell_too_and_sent_again_next_time() {
        let (mut p, mut vmd) = rig();
        cell_with(&mut vmd, "transport$move", b"1 activate 1");
        p.handle_indication(7, terminate("transport$move"));
        answer_here(&mut p, &vmd);
        let (id, ..) = delivery(&todos(&mut p)).expect("a delivery");
        let refusal = ServiceError::unreachable("no connection with station transport");
        p.handle_delivered(id, Err(refusal.clone()));
        let out = todos(&mut p);
        assert_eq!(
            out,
            vec![
                Todo::Discard(name("transport$move")),
                Todo::Answer {
                    ticket: 7,
                    result: Err(refusal)
                }
            ]
        );
        // Downloaded again, it is sent again.
        p.handle_indication(8, terminate("transport$move"));
        answer_here(&mut p, &vmd);
        let (id, ..) = delivery(&todos(&mut p)).expect("sent again");
        p.handle_delivered(id, Ok(()));
        assert_eq!(answers(&todos(&mut p)), vec![(8, Ok(Response::Done))]);
    }

    #[test]
    fn a_recipe_for_a_station_that_is_no_workstation_of_the_cell_is_refused_and_dropped() {
        let (mut p, mut vmd) = rig();
        cell_with(&mut vmd, "painting$coat", b"1 start rcm 1");
        p.handle_indication(1, terminate("painting$coat"));
        answer_here(&mut p, &vmd);
        let out = todos(&mut p);
        assert_eq!(out[0], Todo::Discard(name("painting$coat")));
        let (_, result) = &answers(&out)[0];
        let e = result.clone().unwrap_err();
        assert!(
            e.description.contains("painting is not a workstation"),
            "{e}"
        );
        assert!(!p.busy());
        // A cell recipe is answered at once.
        cell_with(&mut vmd, "dikdroog", b"1 start welding weld1");
        p.handle_indication(2, terminate("dikdroog"));
        answer_here(&mut p, &vmd);
        assert_eq!(answers(&todos(&mut p)), vec![(2, Ok(Response::Done))]);
    }

    #[test]
    fn indications_during_a_delivery_wait_and_are_taken_in_order_after_it() {
        let (mut p, mut vmd) = rig();
        cell_with(&mut vmd, "welding$weld1", b"1 start rcm 1");
        p.handle_indication(1, terminate("welding$weld1"));
        answer_here(&mut p, &vmd);
        let (id, ..) = delivery(&todos(&mut p)).expect("a delivery");
        let start = Request::Start {
            name: name("dikdroog"),
            argument: "order 1".into(),
        };
        p.handle_indication(2, start.clone());
        p.handle_indication(3, Request::Status);
        assert!(p.poll_here().is_none(), "a start overtook its recipe");
        p.handle_delivered(id, Ok(()));
        assert_eq!(answers(&todos(&mut p)), vec![(1, Ok(Response::Done))]);
        let h = p.poll_here().expect("the start, now");
        assert_eq!((h.ticket, &h.request), (Some(2), &start));
        p.handled(h, Ok(Response::Done), &vmd);
        assert_eq!(answer_here(&mut p, &vmd), vec![3]);
        assert_eq!(
            answers(&todos(&mut p)),
            vec![(2, Ok(Response::Done)), (3, Ok(Response::Done))]
        );
    }

    #[test]
    fn a_mode_passes_to_every_workstation_and_is_answered_with_the_refusals_named() {
        let (mut p, vmd) = rig();
        let mode = Request::Mode(ModeSetting {
            mode: CellMode::Step,
            ..Default::default()
        });
        p.handle_indication(1, mode.clone());
        let h = p.poll_here().expect("the cell's controller first");
        // The cell refuses: nothing is passed on.
        p.handled(h, Err(ServiceError::state_conflict("a recipe runs")), &vmd);
        let out = todos(&mut p);
        assert_eq!(out.len(), 1);
        assert!(answers(&out)[0].1.is_err());
        // The cell accepts: both workstations are asked.
        p.handle_indication(2, mode.clone());
        answer_here(&mut p, &vmd);
        let asked: Vec<(u64, String)> = todos(&mut p)
            .into_iter()
            .filter_map(|t| match t {
                Todo::Ask { id, to, request } if request == mode => Some((id, to.to_string())),
                _ => None,
            })
            .collect();
        assert_eq!(asked.len(), 2, "{asked:?}");
        assert_eq!(
            (asked[0].1.as_str(), asked[1].1.as_str()),
            ("welding", "transport")
        );
        p.handle_confirm(
            asked[1].0,
            Err(ServiceError::timeout("transport: no confirm")),
        );
        assert!(todos(&mut p).is_empty(), "answered before every confirm");
        p.handle_confirm(asked[0].0, Ok(Response::Done));
        let out = todos(&mut p);
        let e = answers(&out)[0].1.clone().unwrap_err();
        assert!(
            e.description
                .starts_with("transport: no confirm: the mode stays auto (not step)"),
            "{e}"
        );
    }

    /// The workstations asked `request`, with their confirm ids.
    fn asked(out: &[Todo<u32>], request: &Request) -> Vec<(u64, String)> {
        out.iter()
            .filter_map(|t| match t {
                Todo::Ask { id, to, request: r } if r == request => Some((*id, to.to_string())),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn a_mode_one_workstation_refuses_is_taken_back_at_the_cell_and_everywhere() {
        let (mut p, vmd) = rig();
        let maintenance = ModeSetting {
            mode: CellMode::Maintenance,
            ..Default::default()
        };
        let auto = ModeSetting::default();
        // Maintenance, taken by all.
        p.handle_indication(1, Request::Mode(maintenance.clone()));
        answer_here(&mut p, &vmd);
        for (id, _) in asked(&todos(&mut p), &Request::Mode(maintenance.clone())) {
            p.handle_confirm(id, Ok(Response::Done));
        }
        assert_eq!(answers(&todos(&mut p)), vec![(1, Ok(Response::Done))]);
        // Auto: the cell takes it, transport too, welding runs a job by
        // hand and refuses.
        p.handle_indication(2, Request::Mode(auto.clone()));
        assert_eq!(answer_here(&mut p, &vmd), vec![2]);
        let ids = asked(&todos(&mut p), &Request::Mode(auto.clone()));
        assert_eq!(ids.len(), 2);
        p.handle_confirm(ids[1].0, Ok(Response::Done));
        p.handle_confirm(
            ids[0].0,
            Err(ServiceError::state_conflict(
                "the mode cannot change from maintenance to auto while DROOG_DIK runs",
            )),
        );
        let out = todos(&mut p);
        let e = answers(&out)[0].1.clone().unwrap_err();
        assert!(
            e.description.contains("while DROOG_DIK runs")
                && e.description.contains("the mode stays maintenance"),
            "{e}"
        );
        // Taken back: at every workstation, and at the cell's controller.
        let back = asked(&out, &Request::Mode(maintenance.clone()));
        assert_eq!(
            back.iter().map(|(_, s)| s.as_str()).collect::<Vec<_>>(),
            ["welding", "transport"]
        );
        let here = p.poll_here().expect("the cell's own mode taken back");
        assert_eq!(
            (here.ticket, &here.request),
            (None, &Request::Mode(maintenance.clone()))
        );
        p.handled(here, Ok(Response::Done), &vmd);
        for (id, _) in back {
            p.handle_confirm(id, Ok(Response::Done));
        }
        assert!(answers(&todos(&mut p)).is_empty(), "nobody waits for it");
        // Nothing keeps a start back: every station is in maintenance, as
        // the cell (whose controller refuses a start in maintenance).
        p.handle_indication(
            3,
            Request::Start {
                name: name("DIKDROOG"),
                argument: String::new(),
            },
        );
        assert_eq!(answer_here(&mut p, &vmd), vec![3]);
    }

    #[test]
    fn a_workstation_that_refuses_the_cells_mode_on_association_keeps_a_start_refused() {
        let (mut p, vmd) = rig();
        // A cell started again (in auto) finds welding in maintenance with
        // a job by hand: it refuses auto.
        p.handle_associated(&vmd, &ModeSetting::default());
        let ids = asked(&todos(&mut p), &Request::Mode(ModeSetting::default()));
        p.handle_confirm(
            ids[0].0,
            Err(ServiceError::state_conflict("welding: HOME runs")),
        );
        p.handle_confirm(ids[1].0, Ok(Response::Done));
        assert_eq!(
            todos(&mut p),
            vec![Todo::Warn("mode: welding: HOME runs".into())]
        );
        let start = Request::Start {
            name: name("DIKDROOG"),
            argument: String::new(),
        };
        p.handle_indication(1, start.clone());
        assert!(p.poll_here().is_none(), "refused here");
        let e = answers(&todos(&mut p))[0].1.clone().unwrap_err();
        assert!(
            e.description
                .contains("welding is not in the cell's mode auto: welding: HOME runs")
                && e.description.contains("falc mode auto"),
            "{e}"
        );
        // The way back: the job by hand ended, `falc mode auto` taken by
        // all, the start goes to the cell's controller.
        p.handle_indication(2, Request::Mode(ModeSetting::default()));
        answer_here(&mut p, &vmd);
        for (id, _) in asked(&todos(&mut p), &Request::Mode(ModeSetting::default())) {
            p.handle_confirm(id, Ok(Response::Done));
        }
        assert_eq!(answers(&todos(&mut p)), vec![(2, Ok(Response::Done))]);
        p.handle_indication(3, start);
        assert_eq!(answer_here(&mut p, &vmd), vec![3]);
    }

    #[test]
    fn a_manual_operation_goes_to_the_workstation_it_names_or_is_refused() {
        let (mut p, _) = rig();
        let manual = |station: &str| Request::Manual {
            station: st(station),
            action: ManualAction::RunRecipe("home".into()),
            by: "maint".into(),
        };
        p.handle_indication(1, manual("transport"));
        assert!(p.poll_here().is_none(), "not the cell's own");
        let out = todos(&mut p);
        let Todo::Ask { id, to, .. } = &out[0] else {
            panic!("{out:?}")
        };
        assert_eq!(to.as_str(), "transport");
        p.handle_confirm(*id, Ok(Response::Done));
        assert_eq!(answers(&todos(&mut p)), vec![(1, Ok(Response::Done))]);
        p.handle_indication(2, manual("cell"));
        let out = todos(&mut p);
        let e = answers(&out)[0].1.clone().unwrap_err();
        assert!(
            e.description.contains("not a workstation of this cell"),
            "{e}"
        );
    }

    #[test]
    fn a_workstation_lost_gets_its_recipes_again_and_one_that_cannot_be_sent_is_an_alarm() {
        let (mut p, mut vmd) = rig();
        for (domain, content) in [
            ("welding$weld1", b"1 start rcm 1".as_slice()),
            ("transport$move", b"1 activate 1".as_slice()),
        ] {
            cell_with(&mut vmd, domain, content);
            p.handle_indication(1, terminate(domain));
            answer_here(&mut p, &vmd);
            let (id, ..) = delivery(&todos(&mut p)).expect("a delivery");
            p.handle_delivered(id, Ok(()));
            todos(&mut p);
        }
        // Associated again with nothing lost: no recipe is sent, only the
        // cell's mode (auto too), which both take.
        p.handle_associated(&vmd, &ModeSetting::default());
        let out = todos(&mut p);
        assert!(delivery(&out).is_none(), "{out:?}");
        for t in out {
            let Todo::Ask { id, request, .. } = t else {
                panic!("{t:?}")
            };
            assert_eq!(request, Request::Mode(ModeSetting::default()));
            p.handle_confirm(id, Ok(Response::Done));
        }
        assert!(todos(&mut p).is_empty());
        assert!(!p.busy());
        // The welding workstation was lost: only its recipe goes again.
        p.handle_lost(&st("welding"));
        let step = ModeSetting {
            mode: CellMode::Step,
            ..Default::default()
        };
        p.handle_associated(&vmd, &step);
        let out = todos(&mut p);
        let (id, to, recipe) = delivery(&out).expect("a catch-up");
        assert_eq!((to.as_str(), recipe.as_str()), ("welding", "WELD1"));
        // The cell's mode goes to both.
        let modes: Vec<u64> = out
            .iter()
            .filter_map(|t| match t {
                Todo::Ask { id, request, .. } if *request == Request::Mode(step.clone()) => {
                    Some(*id)
                }
                _ => None,
            })
            .collect();
        assert_eq!(modes.len(), 2);
        // Indications wait for the catch-up, and for the owed recipe sent
        // again once it failed.
        p.handle_indication(5, Request::Status);
        assert!(p.poll_here().is_none());
        p.handle_delivered(id, Err(ServiceError::timeout("no confirm from welding")));
        assert_eq!(
            todos(&mut p),
            vec![Todo::Alarm("no confirm from welding".into())]
        );
        assert!(p.poll_here().is_none(), "taken before the owed recipe");
        let (id, ..) = delivery(&todos(&mut p)).expect("the owed recipe again");
        p.handle_delivered(id, Err(ServiceError::timeout("no confirm from welding")));
        assert_eq!(answer_here(&mut p, &vmd), vec![5]);
        let out = todos(&mut p);
        assert_eq!(
            out.first(),
            Some(&Todo::Alarm("no confirm from welding".into())),
            "{out:?}"
        );
        assert_eq!(answers(&out), vec![(5, Ok(Response::Done))]);
        // A start that finds it owed still is refused, naming it.
        let start = Request::Start {
            name: ObjectName::new("DIKDROOG").expect("valid"),
            argument: String::new(),
        };
        p.handle_indication(9, start);
        let out = todos(&mut p);
        let (id, ..) = delivery(&out).expect("the owed recipe again");
        p.handle_delivered(id, Err(ServiceError::timeout("no confirm from welding")));
        assert!(p.poll_here().is_none(), "the start reached the controller");
        let out = todos(&mut p);
        let refusal = out.iter().find_map(|t| match t {
            Todo::Answer {
                ticket: 9,
                result: Err(e),
            } => Some(e.description.clone()),
            _ => None,
        });
        assert_eq!(
            refusal.as_deref(),
            Some(
                "no confirm from welding; the cell starts no order until its workstations hold \
                 their recipes (sent again at the next start)"
            ),
            "{out:?}"
        );
        // The way back: the next indication (the operator's start) waits
        // until the owed recipe went out again.
        p.handle_indication(6, Request::Status);
        assert!(p.poll_here().is_none(), "taken before the owed recipe");
        let out = todos(&mut p);
        let (id, to, recipe) = delivery(&out).expect("the owed recipe again");
        assert_eq!((to.as_str(), recipe.as_str()), ("welding", "WELD1"));
        p.handle_delivered(id, Ok(()));
        assert_eq!(answer_here(&mut p, &vmd), vec![6]);
        // Given: nothing owed any more.
        p.handle_indication(7, Request::Status);
        assert_eq!(answer_here(&mut p, &vmd), vec![7]);
        // A mode refused by a returned workstation is a warning, no answer.
        p.handle_confirm(modes[0], Err(ServiceError::state_conflict("welding: busy")));
        p.handle_confirm(modes[1], Ok(Response::Done));
        let out = todos(&mut p);
        assert!(
            out.contains(&Todo::Warn("mode: welding: busy".into())),
            "{out:?}"
        );
    }

    #[test]
    fn a_workstation_lost_during_a_delivery_ends_it_at_once_and_owes_nothing_delivered_later() {
        let (mut p, mut vmd) = rig();
        cell_with(&mut vmd, "welding$weld1", b"1 start rcm 1");
        let start = Request::Start {
            name: name("DIKDROOG"),
            argument: String::new(),
        };
        // A catch-up under way when welding goes: it ends now, nothing is
        // owed and no alarm raised (welding gets it when it is back).
        p.handle_associated(&vmd, &ModeSetting::default());
        let (first, ..) = delivery(&todos(&mut p)).expect("a catch-up");
        p.handle_lost(&st("welding"));
        assert!(!p.busy(), "a delivery waits for a workstation that is gone");
        assert!(todos(&mut p).is_empty());
        // Back: the catch-up again, and a start held behind it.
        p.handle_associated(&vmd, &ModeSetting::default());
        let (second, ..) = delivery(&todos(&mut p)).expect("the catch-up again");
        p.handle_indication(1, start.clone());
        assert!(p.poll_here().is_none(), "the start overtook the catch-up");
        // The first delivery's confirm, late, is stale.
        p.handle_delivered(first, Err(ServiceError::timeout("no confirm")));
        assert!(p.busy());
        p.handle_delivered(second, Ok(()));
        assert_eq!(answer_here(&mut p, &vmd), vec![1]);

        // A catch-up that fails leaves the recipe owed; a start held behind
        // it has it sent again first, and runs once it is delivered.
        p.handle_lost(&st("welding"));
        p.handle_associated(&vmd, &ModeSetting::default());
        let (id, ..) = delivery(&todos(&mut p)).expect("a catch-up");
        p.handle_indication(2, start.clone());
        p.handle_delivered(id, Err(ServiceError::timeout("no confirm from welding")));
        assert!(p.poll_here().is_none(), "started with a recipe owed");
        let out = todos(&mut p);
        assert!(out.contains(&Todo::Alarm("no confirm from welding".into())));
        let (id, to, recipe) = delivery(&out).expect("the owed recipe again");
        assert_eq!((to.as_str(), recipe.as_str()), ("welding", "WELD1"));
        p.handle_delivered(id, Ok(()));
        assert_eq!(answer_here(&mut p, &vmd), vec![2]);

        // The commander's download to a workstation lost during it is
        // refused at once, and the cell drops its copy.
        cell_with(&mut vmd, "welding$weld2", b"1 start rcm 2");
        p.handle_indication(3, terminate("welding$weld2"));
        assert_eq!(answer_here(&mut p, &vmd), vec![3]);
        assert!(delivery(&todos(&mut p)).is_some());
        p.handle_lost(&st("welding"));
        let out = todos(&mut p);
        assert!(
            out.contains(&Todo::Discard(name("welding$weld2"))),
            "{out:?}"
        );
        let e = answers(&out)[0].1.clone().unwrap_err();
        assert!(
            e.description
                .contains("recipe WELD2 not delivered to welding: the association was lost"),
            "{e}"
        );
    }

    #[test]
    fn a_stale_outcome_changes_nothing() {
        let (mut p, mut vmd) = rig();
        cell_with(&mut vmd, "welding$weld1", b"1 start rcm 1");
        p.handle_indication(1, terminate("welding$weld1"));
        answer_here(&mut p, &vmd);
        let (id, ..) = delivery(&todos(&mut p)).expect("a delivery");
        p.handle_delivered(id + 100, Ok(()));
        p.handle_confirm(id + 100, Ok(Response::Done));
        assert!(todos(&mut p).is_empty());
        assert!(p.busy());
    }
}
