//! The cell controller's node, sans-I/O: everything `falc-cell` decides,
//! for any transport and clock. `falc-cell` carries its actions over zenoh
//! and `falc-sim` over its simulated bus; both run this code.
//!
//! It holds the cell's [`Controller`] over its stations
//! ([`coordination::Stations`]), the [`PassOn`] in front of it, and one
//! lane per station: a station's requests go out one at a time, in the
//! order the recipe made them (outputs reach the operator in the recipe's
//! order, a Stop never overtakes its Start).
//!
//! The driver hands in what comes (the commander's indications with a
//! ticket of its own `T`, confirms, the workstations' publications,
//! associations and aborts, the time) and carries out what
//! [`CellNode::poll`] gives, in order ([`CellAction`]): a request to
//! send, an answer to the commander, a request or a delivery to a
//! workstation on the pass-on's behalf, a line for the log, a
//! publication. A publication the cell's answer to an indication caused
//! comes before that answer, as the processes have always sent them.

use crate::controller::Controller;
use crate::coordination::{self, Command, Reply, Stations, CONFIRM_LIMIT};
#[cfg(doc)]
use crate::pass_on::PASS_LIMIT;
use crate::pass_on::{PassOn, Todo};
use falc_model::alarm::AlarmClass;
use falc_model::ids::{ObjectName, StationName};
use falc_model::mms::association::Role;
use falc_model::mms::delivery::Delivery;
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::{Request, Response, Severity, Unconfirmed};
use falc_model::mms::vmd::VmdStatus;
use falc_recipe::commands::RecipeKind;
use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

/// What the driver does, in order.
#[derive(Debug)]
pub enum CellAction<T> {
    /// Send `command.request` to `command.to` within `command.limit`; its
    /// confirm goes to [`CellNode::handle_reply`].
    Request(Command),
    /// Answer the commander's indication `ticket`.
    Answer {
        /// The driver's handle on it.
        ticket: T,
        /// The answer.
        result: Result<Response, ServiceError>,
    },
    /// Ask workstation `to` within [`PASS_LIMIT`]; its confirm goes to
    /// [`CellNode::handle_confirm`] with `id`.
    Ask {
        /// Names the confirm.
        id: u64,
        /// The workstation.
        to: StationName,
        /// What it is asked.
        request: Request,
    },
    /// Carry out `delivery` to its workstation; its outcome goes to
    /// [`CellNode::handle_delivered`] with `id`.
    Deliver {
        /// Names the outcome.
        id: u64,
        /// The recipe's domain and program invocation, all or nothing.
        delivery: Delivery,
    },
    /// Recipe `name` reached workstation `to` (for the log).
    Delivered {
        /// The workstation.
        to: StationName,
        /// The recipe.
        name: ObjectName,
    },
    /// Worth a warning in the log, no more.
    Warn(String),
    /// Publish this (a report, a job event, the status when it changed).
    Publish(Unconfirmed),
}

/// One station's requests: the one out and those waiting for it.
#[derive(Debug, Default)]
struct Lane {
    out: bool,
    waiting: VecDeque<Command>,
}

/// The cell controller's node.
pub struct CellNode<T> {
    /// The recipe runtime over the stations (read it; change it through
    /// the node).
    ctl: Controller<Stations>,
    pass: PassOn<T>,
    lanes: BTreeMap<StationName, Lane>,
    /// The status last published (none: publish it at the next poll).
    told: Option<VmdStatus>,
    out: VecDeque<CellAction<T>>,
}

impl<T> CellNode<T> {
    /// Cell `me`, commanded by `commander`, over `workstations`; whether it
    /// runs its order on when its commander is lost (`alone`).
    pub fn new(
        me: StationName,
        commander: Option<StationName>,
        workstations: Vec<StationName>,
        alone: bool,
    ) -> Self {
        let ctl = Controller::new(RecipeKind::Cell, CONFIRM_LIMIT, Stations::new(commander))
            .named(me)
            .runs_on_alone(alone);
        Self {
            ctl,
            pass: PassOn::new(workstations),
            lanes: BTreeMap::new(),
            told: None,
            out: VecDeque::new(),
        }
    }

    /// The recipe runtime (its VMD, status, mode).
    pub fn controller(&self) -> &Controller<Stations> {
        &self.ctl
    }

    /// The commander's indication (an association service aside), with
    /// the driver's handle `ticket` on it.
    pub fn handle_indication(&mut self, ticket: T, request: Request) {
        self.pass.handle_indication(ticket, request);
    }

    /// The confirm of a [`CellAction::Request`] to `to`: its lane sends
    /// the next.
    pub fn handle_reply(&mut self, now: Duration, to: &StationName, reply: Reply) {
        if let Some(lane) = self.lanes.get_mut(to) {
            lane.out = false;
        }
        coordination::handle_reply(&mut self.ctl, now, reply);
    }

    /// A workstation confirmed what the node asked ([`CellAction::Ask`]).
    pub fn handle_confirm(&mut self, id: u64, result: Result<Response, ServiceError>) {
        self.pass.handle_confirm(id, result);
    }

    /// A delivery the node asked for ended ([`CellAction::Deliver`]).
    pub fn handle_delivered(&mut self, id: u64, result: Result<(), ServiceError>) {
        self.pass.handle_delivered(id, result);
    }

    /// A workstation's publication (its status, job events).
    pub fn handle_publication(&mut self, now: Duration, u: &Unconfirmed) {
        let events = self.ctl.device.unconfirmed(u);
        self.ctl.feed(now, events);
    }

    /// The commander associated: the status is published again, and the
    /// workstations get what they lack and the cell's mode.
    pub fn handle_associated(&mut self, now: Duration) {
        self.ctl.handle_associated(now);
        self.told = None;
        let mode = self.ctl.mode().clone();
        self.pass.handle_associated(self.ctl.vmd(), &mode);
    }

    /// The association with `peer` was lost (`role`: what it was to the
    /// cell).
    pub fn handle_abort(&mut self, now: Duration, peer: &StationName, role: Role) {
        if role == Role::Subordinate {
            self.pass.handle_lost(peer);
        }
        self.ctl.handle_abort(now, peer, role);
    }

    /// When [`Self::handle_timeout`] is due next.
    pub fn poll_timeout(&self) -> Option<Duration> {
        self.ctl.poll_timeout()
    }

    /// The clock reached `now`.
    pub fn handle_timeout(&mut self, now: Duration) {
        self.ctl.handle_timeout(now);
    }

    /// The next thing to do; none when all is done.
    pub fn poll(&mut self, now: Duration) -> Option<CellAction<T>> {
        if self.out.is_empty() {
            self.settle(now);
        }
        self.out.pop_front()
    }

    /// Runs the controller and the pass-on until neither has more to do,
    /// queueing what the driver must carry out.
    fn settle(&mut self, now: Duration) {
        loop {
            self.ctl.settle(now);
            while let Some(cmd) = self.ctl.device.poll_command() {
                let lane = self.lanes.entry(cmd.to.clone()).or_default();
                lane.waiting.push_back(cmd);
            }
            self.send_lanes();
            if let Some(local) = self.ctl.device.poll_local_reply() {
                coordination::handle_reply(&mut self.ctl, now, local);
                continue;
            }
            let mut more = false;
            while let Some(here) = self.pass.poll_here() {
                more = true;
                let result = self.ctl.handle_request(now, &here.request);
                // What the answer changed goes out before the answer.
                self.publish();
                self.pass.handled(here, result, self.ctl.vmd());
            }
            while let Some(todo) = self.pass.poll_todo() {
                more = true;
                let action = match todo {
                    Todo::Discard(domain) => {
                        self.ctl.discard_domain(&domain);
                        continue;
                    }
                    Todo::Alarm(text) => {
                        let alarm = Severity::Alarm(AlarmClass::Communication);
                        self.ctl.report(alarm, text);
                        continue;
                    }
                    Todo::Answer { ticket, result } => CellAction::Answer { ticket, result },
                    Todo::Ask { id, to, request } => CellAction::Ask { id, to, request },
                    Todo::Deliver {
                        id,
                        to,
                        name,
                        content,
                    } => CellAction::Deliver {
                        id,
                        delivery: Delivery::new(to, name, &content, true),
                    },
                    Todo::Delivered { to, name } => CellAction::Delivered { to, name },
                    Todo::Warn(text) => CellAction::Warn(text),
                };
                self.out.push_back(action);
            }
            if !more {
                break;
            }
        }
        self.publish();
    }

    /// Each idle lane's next request.
    fn send_lanes(&mut self) {
        for lane in self.lanes.values_mut() {
            if lane.out {
                continue;
            }
            if let Some(cmd) = lane.waiting.pop_front() {
                lane.out = true;
                self.out.push_back(CellAction::Request(cmd));
            }
        }
    }

    /// What the controller put out, and its status if it changed.
    fn publish(&mut self) {
        let publications = self.ctl.publications(&mut self.told);
        self.out
            .extend(publications.into_iter().map(CellAction::Publish));
    }
}

#[cfg(test)]
mod tests {
    //! The node on a virtual clock: the test is its commander (tickets are
    //! numbers) and answers the requests it sends.

    use super::*;
    use falc_model::ids::ObjectName;
    use falc_model::mms::delivery::{Delivery, DeliveryStep};
    use falc_model::mms::pdu::Response;

    const CELL: &str = crate::controller::testing::CELL_RECIPE;

    fn st(s: &str) -> StationName {
        StationName::new(s).expect("station")
    }

    fn node() -> CellNode<u32> {
        CellNode::new(
            st("cell"),
            Some(st("operator")),
            vec![st("transport")],
            true,
        )
    }

    fn drain(n: &mut CellNode<u32>) -> Vec<CellAction<u32>> {
        std::iter::from_fn(|| n.poll(Duration::ZERO)).collect()
    }

    /// The answer to indication `ticket` among `acts`, and where.
    fn answer(
        acts: &[CellAction<u32>],
        ticket: u32,
    ) -> Option<(
        usize,
        &Result<Response, falc_model::mms::error::ServiceError>,
    )> {
        acts.iter().enumerate().find_map(|(i, a)| match a {
            CellAction::Answer { ticket: t, result } if *t == ticket => Some((i, result)),
            _ => None,
        })
    }

    /// The commander delivers the cell recipe `TEST`, step by step through
    /// the node's door for indications.
    fn deliver(n: &mut CellNode<u32>) {
        let name = ObjectName::new("TEST").expect("name");
        let mut d = Delivery::new(st("cell"), name, CELL.as_bytes(), true);
        let mut step = d.start();
        let mut ticket = 0;
        while let DeliveryStep::Send(request) = step {
            ticket += 1;
            n.handle_indication(ticket, request);
            let acts = drain(n);
            let (_, result) = answer(&acts, ticket).expect("answered");
            step = d.answered(result.clone());
        }
        assert_eq!(step, DeliveryStep::Done(Ok(())));
    }

    #[test]
    fn a_stations_requests_go_one_at_a_time_and_what_a_start_changed_goes_out_before_its_answer() {
        let mut n = node();
        deliver(&mut n);
        n.handle_indication(
            100,
            Request::Start {
                name: ObjectName::new("TEST").expect("name"),
                argument: String::new(),
            },
        );
        let acts = drain(&mut n);
        let (at, result) = answer(&acts, 100).expect("answered");
        assert!(result.is_ok(), "{result:?}");
        let started = acts.iter().position(|a| {
            matches!(a, CellAction::Publish(Unconfirmed::Status { status, .. })
                if status.program.as_ref().is_some_and(|p| p.name.as_str() == "TEST"))
        });
        assert!(started.is_some_and(|s| s < at), "{acts:?}");
        // The output and the question both go to the operator: the
        // question waits for the output's confirm on its lane.
        let requests: Vec<&Command> = acts
            .iter()
            .filter_map(|a| match a {
                CellAction::Request(c) => Some(c),
                _ => None,
            })
            .collect();
        assert_eq!(requests.len(), 1, "{requests:?}");
        assert!(matches!(requests[0].request, Request::Output { .. }));
        let output = requests[0].clone();
        n.handle_reply(
            Duration::ZERO,
            &output.to,
            Reply {
                awaiting: output.awaiting,
                result: Ok(Response::Done),
            },
        );
        let acts = drain(&mut n);
        assert!(
            acts.iter().any(|a| matches!(a, CellAction::Request(c)
                if c.to == st("operator") && matches!(c.request, Request::Input { .. }))),
            "{acts:?}"
        );
    }

    #[test]
    fn the_status_is_published_once_and_again_after_an_association() {
        let mut n = node();
        let statuses = |acts: &[CellAction<u32>]| {
            acts.iter()
                .filter(|a| matches!(a, CellAction::Publish(Unconfirmed::Status { .. })))
                .count()
        };
        assert_eq!(statuses(&drain(&mut n)), 1);
        assert_eq!(statuses(&drain(&mut n)), 0);
        n.handle_associated(Duration::ZERO);
        assert_eq!(statuses(&drain(&mut n)), 1);
    }
}
