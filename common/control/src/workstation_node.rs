//! A workstation's node, sans-I/O: everything `falc-welding` and
//! `falc-transport` decide around their device, for any transport and
//! clock. The processes carry its actions over zenoh, a serial line and
//! Modbus TCP; `falc-sim` over its simulated bus and twins; both run this
//! code.
//!
//! It holds the workstation's [`Controller`] around a [`Linked`] device:
//! a device with a link the driver carries (the DNC line to the robot
//! controller, the Modbus link to the conveyor PLC). The driver hands in
//! what comes (the commander's indications with a ticket of its own `T`,
//! associations and aborts, what the link reported, the time) and carries
//! out what [`WorkstationNode::poll`] gives, in order
//! ([`WorkstationAction`]): an answer to the commander, a command for the
//! link, a publication, a line for the node's log. What an indication
//! changed is published before its answer; the commands the recipe's
//! next steps issue go out before what they caused is published (the next
//! station should not wait for a status put).

use crate::controller::{Controller, Device};
use falc_model::alarm::Cause;
use falc_model::ids::{ObjectName, RobotProgram, StationName};
use falc_model::mms::association::Role;
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::{Request, Response, Unconfirmed};
use falc_model::mms::vmd::VmdStatus;
use falc_recipe::commands::RecipeKind;
use std::collections::VecDeque;
use std::time::Duration;

/// A device with a link its driver carries: what it asks the link to do,
/// and what a report of the link means for the controller.
pub trait Linked: Device + Sized {
    /// What the device asks of its link (a telegram, a coil write).
    type Command;
    /// What the link reports (a telegram received, a reading, a fault).
    type LinkEvent;

    /// The next command for the link, in the order issued.
    fn next_command(&mut self) -> Option<Self::Command>;

    /// The node stops on purpose: what the device leaves behind it is
    /// queued for the link ([`Self::next_command`]): each output to its
    /// safe state, a robot's job stopped and its line closed.
    fn stop(&mut self);

    /// Takes in `ev` at `now`: the device's state, the running recipe's
    /// events, an alarm. Returns a line worth the node's log, if any
    /// (`plc-ready`).
    fn take_link_event(
        ctl: &mut Controller<Self>,
        now: Duration,
        ev: Self::LinkEvent,
    ) -> Option<String>;
}

/// What the driver does, in order.
#[derive(Debug)]
pub enum WorkstationAction<T, C> {
    /// Answer the commander's indication `ticket`.
    Answer {
        /// The driver's handle on it.
        ticket: T,
        /// The answer.
        result: Result<Response, ServiceError>,
    },
    /// Hand this to the device's link.
    Command(C),
    /// Publish this (a report, a job event, the status when it changed).
    Publish(Unconfirmed),
    /// A line for the node's log (`EVENT …`).
    Event(String),
}

/// A workstation's node.
pub struct WorkstationNode<D: Linked, T> {
    ctl: Controller<D>,
    /// The status last published (none: publish it at the next poll).
    told: Option<VmdStatus>,
    out: VecDeque<WorkstationAction<T, D::Command>>,
    /// Indications held, in order, while a Start waits for a fresh
    /// reading for its precondition ([`Controller::holds_for_reading`]),
    /// and since when.
    held: VecDeque<(T, Request)>,
    held_since: Duration,
    /// Downloads of robot programs (`PROGRAM_065`) whose confirm waits
    /// until the device delivered the program to its robot.
    delivering: Vec<(T, RobotProgram, ObjectName)>,
}

/// How long a Start waits for the fresh reading its precondition asked
/// for: then it is evaluated on what the device has (a link that
/// answers no more is its own alarm).
pub const FRESH_READING_LIMIT: Duration = Duration::from_secs(1);

impl<D: Linked, T> WorkstationNode<D, T> {
    /// Workstation `me` of `kind` around `device`; a `start` in its
    /// recipes waits `confirm_limit` for the device's confirm; whether it
    /// runs its job on when its commander is lost (`alone`).
    pub fn new(
        me: StationName,
        kind: RecipeKind,
        confirm_limit: Duration,
        device: D,
        alone: bool,
    ) -> Self {
        let ctl = Controller::new(kind, confirm_limit, device)
            .named(me)
            .runs_on_alone(alone);
        Self {
            ctl,
            told: None,
            out: VecDeque::new(),
            held: VecDeque::new(),
            held_since: Duration::ZERO,
            delivering: Vec::new(),
        }
    }

    /// The recipe runtime (its VMD, status, mode).
    pub fn controller(&self) -> &Controller<D> {
        &self.ctl
    }

    /// How many bytes of recipes the station holds at most.
    pub fn set_recipe_memory(&mut self, bytes: usize) {
        self.ctl.set_recipe_memory(bytes);
    }

    /// The commander's indication (an association service aside), with
    /// the driver's handle `ticket` on it: answered at the next poll,
    /// after what it changed is published.
    /// A Start whose precondition needs a fresh reading is held (and
    /// what comes after it, in order) until the reading came.
    pub fn handle_indication(&mut self, now: Duration, ticket: T, request: &Request) {
        if self.held.is_empty() {
            if !self.ctl.holds_for_reading(now, request) {
                return self.answer(now, ticket, request);
            }
            self.held_since = now;
        }
        self.held.push_back((ticket, request.clone()));
    }

    fn answer(&mut self, now: Duration, ticket: T, request: &Request) {
        let mut result = self.ctl.handle_request(now, request);
        // A robot program's text, complete: its confirm waits until the
        // device delivered it to the robot.
        if let (
            Ok(_),
            Request::TerminateDownloadSequence {
                domain,
                discard: None,
            },
        ) = (&result, request)
        {
            if RobotProgram::of_domain(domain).is_some() {
                match self.ctl.deliver_program(domain) {
                    Ok(program) => {
                        self.delivering.push((ticket, program, domain.clone()));
                        self.publish();
                        return;
                    }
                    Err(e) => result = Err(e),
                }
            }
        }
        self.publish();
        self.out
            .push_back(WorkstationAction::Answer { ticket, result });
    }

    /// Answers the downloads whose delivery to the robot ended; one that
    /// failed is taken back out.
    fn delivered(&mut self) {
        while let Some((program, result)) = self.ctl.device.poll_delivered() {
            let Some(at) = self.delivering.iter().position(|(_, p, _)| *p == program) else {
                continue;
            };
            let (ticket, _, domain) = self.delivering.remove(at);
            if result.is_err() {
                self.ctl.discard_domain(&domain);
            }
            let result = result.map(|()| Response::Done);
            self.out
                .push_back(WorkstationAction::Answer { ticket, result });
        }
    }

    /// Answers the held indications once the reading came (or its limit
    /// passed).
    fn release(&mut self, now: Duration) {
        if self.held.is_empty()
            || !(self.ctl.has_fresh_reading() || now >= self.held_since + FRESH_READING_LIMIT)
        {
            return;
        }
        while let Some((ticket, request)) = self.held.pop_front() {
            self.answer(now, ticket, &request);
        }
    }

    /// The commander associated: the status is published again.
    pub fn handle_associated(&mut self, now: Duration) {
        self.ctl.handle_associated(now);
        self.told = None;
    }

    /// The association with `peer` was lost (`role`: what it was to this
    /// station).
    pub fn handle_abort(&mut self, now: Duration, peer: &StationName, role: Role) {
        if role == Role::Commander {
            // What it asked is no more: a held Start is not taken.
            self.held.clear();
        }
        self.ctl.handle_abort(now, peer, role);
    }

    /// What the device's link reported.
    pub fn handle_link(&mut self, now: Duration, ev: D::LinkEvent) {
        if let Some(line) = D::take_link_event(&mut self.ctl, now, ev) {
            self.out.push_back(WorkstationAction::Event(line));
        }
        self.delivered();
        self.release(now);
    }

    /// The device failed outside its link's reports (its link's task
    /// stopped): the running recipe ends in alarm with `cause`, and the
    /// alarm goes up.
    pub fn handle_fault(&mut self, cause: Cause) {
        self.ctl.fault(cause);
    }

    /// When [`Self::handle_timeout`] is due next.
    pub fn poll_timeout(&self) -> Option<Duration> {
        let held = (!self.held.is_empty()).then(|| self.held_since + FRESH_READING_LIMIT);
        match (self.ctl.poll_timeout(), held) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The clock reached `now`.
    pub fn handle_timeout(&mut self, now: Duration) {
        self.ctl.handle_timeout(now);
        self.delivered();
        self.release(now);
    }

    /// The next thing to do; none when all is done.
    pub fn poll(&mut self, now: Duration) -> Option<WorkstationAction<T, D::Command>> {
        if self.out.is_empty() {
            self.settle(now);
        }
        self.out.pop_front()
    }

    /// The node stops on purpose ([`Linked::stop`]): the commands that
    /// leave the device safe, for the driver to send before it lets the
    /// link go. The recipe is not run on.
    pub fn shut_down(&mut self) -> Vec<D::Command> {
        self.ctl.device.stop();
        std::iter::from_fn(|| self.ctl.device.next_command()).collect()
    }

    /// Runs the recipe's next steps, then queues the commands they issued
    /// and what they caused.
    fn settle(&mut self, now: Duration) {
        self.ctl.settle(now);
        while let Some(c) = self.ctl.device.next_command() {
            self.out.push_back(WorkstationAction::Command(c));
        }
        self.publish();
    }

    /// What the controller put out, and its status if it changed.
    fn publish(&mut self) {
        let publications = self.ctl.publications(&mut self.told);
        self.out
            .extend(publications.into_iter().map(WorkstationAction::Publish));
    }
}

#[cfg(test)]
mod tests {
    //! The node on a virtual clock around a fake robot whose link the test
    //! carries: a start goes out as a command, the link's reports come back.

    use super::*;
    use crate::controller::testing::{load, DROOG_DIK};
    use crate::controller::Happening;
    use falc_model::alarm::AlarmClass;
    use falc_model::ids::ObjectName;
    use falc_model::mms::pdu::JobEvent;
    use falc_recipe::check::Job;
    use falc_recipe::engine::{Action, Event, JobEnd};

    /// A robot behind a link: a start is a command; the link says
    /// "started", "ended" or "hello" (a line for the log).
    #[derive(Default)]
    struct Robot {
        queued: VecDeque<String>,
        /// Programs being delivered, and those whose delivery ended.
        delivering: Vec<RobotProgram>,
        delivered: VecDeque<(RobotProgram, Result<(), ServiceError>)>,
    }

    impl Device for Robot {
        fn handle(&mut self, _now: Duration, what: Happening<'_>, _out: &mut Vec<Event>) {
            if let Happening::Act(Action::Start {
                job: Job::Program(p),
                ..
            }) = what
            {
                self.queued.push_back(format!("start {p}"));
            }
        }
        fn unavailable(&self) -> Option<String> {
            None
        }
        fn status(&self, _status: &mut VmdStatus) {}
        fn deliver_program(
            &mut self,
            program: &falc_recipe::robot_program::ProgramText,
        ) -> Result<(), ServiceError> {
            if program.number.number() == 66 {
                return Err(ServiceError::state_conflict("program 66 runs"));
            }
            self.queued.push_back(format!("deliver {}", program.number));
            self.delivering.push(program.number);
            Ok(())
        }
        fn poll_delivered(&mut self) -> Option<(RobotProgram, Result<(), ServiceError>)> {
            self.delivered.pop_front()
        }
    }

    impl Linked for Robot {
        type Command = String;
        type LinkEvent = &'static str;

        fn next_command(&mut self) -> Option<String> {
            self.queued.pop_front()
        }

        fn stop(&mut self) {
            self.queued.push_back("halt".into());
        }

        fn take_link_event(
            ctl: &mut Controller<Self>,
            now: Duration,
            ev: &'static str,
        ) -> Option<String> {
            let rcm = StationName::new("rcm").expect("rcm");
            match ev {
                "started" => ctl.feed(now, vec![Event::Started(rcm)]),
                "ended" => ctl.feed(now, vec![Event::Ended(rcm, JobEnd::Done)]),
                "stored" | "refused" => {
                    let r = if ev == "stored" {
                        Ok(())
                    } else {
                        Err(ServiceError::unreachable("the line closed"))
                    };
                    for p in std::mem::take(&mut ctl.device.delivering) {
                        ctl.device.delivered.push_back((p, r.clone()));
                    }
                }
                other => return Some(other.to_string()),
            }
            None
        }
    }

    type Action_ = WorkstationAction<u32, String>;

    fn node() -> WorkstationNode<Robot, u32> {
        let me = StationName::new("welding").expect("name");
        let limit = Duration::from_secs(10);
        let mut n = WorkstationNode::new(me, RecipeKind::Welding, limit, Robot::default(), false);
        load(&mut n.ctl, "DROOG_DIK", DROOG_DIK);
        n
    }

    fn drain(n: &mut WorkstationNode<Robot, u32>, now: Duration) -> Vec<Action_> {
        std::iter::from_fn(|| n.poll(now)).collect()
    }

    fn start() -> Request {
        Request::Start {
            name: ObjectName::new("DROOG_DIK").expect("name"),
            argument: String::new(),
        }
    }

    fn job_events(acts: &[Action_]) -> Vec<JobEvent> {
        acts.iter()
            .filter_map(|a| match a {
                WorkstationAction::Publish(Unconfirmed::Job { event, .. }) => Some(event.clone()),
                _ => None,
            })
            .collect()
    }

    fn statuses(acts: &[Action_]) -> usize {
        acts.iter()
            .filter(|a| matches!(a, WorkstationAction::Publish(Unconfirmed::Status { .. })))
            .count()
    }

    /// The answers to `ticket` among `acts`.
    fn answers_to(acts: &[Action_], ticket: u32) -> Vec<Result<Response, ServiceError>> {
        acts.iter()
            .filter_map(|a| match a {
                WorkstationAction::Answer { ticket: t, result } if *t == ticket => {
                    Some(result.clone())
                }
                _ => None,
            })
            .collect()
    }

    /// Downloads `text` as domain `name`; the terminate's ticket is 99.
    fn download(n: &mut WorkstationNode<Robot, u32>, name: &str, text: &str) -> Vec<Action_> {
        let name = ObjectName::new(name).expect("name");
        let steps = falc_model::mms::domain::download_steps(&name, text.as_bytes());
        let last = steps.len() - 1;
        for (i, r) in steps.iter().enumerate() {
            let ticket = if i == last { 99 } else { i as u32 };
            n.handle_indication(Duration::ZERO, ticket, r);
        }
        drain(n, Duration::ZERO)
    }

    #[test]
    fn a_robot_programs_download_is_confirmed_once_the_robot_stored_it() {
        let mut n = node();
        let _ = drain(&mut n, Duration::ZERO);
        let p65 = ObjectName::new("PROGRAM_065").expect("name");
        let acts = download(&mut n, "PROGRAM_065", "program 65\nmove home 2\n");
        assert!(
            answers_to(&acts, 99).is_empty(),
            "confirmed early: {acts:?}"
        );
        assert!(
            acts.iter()
                .any(|a| matches!(a, WorkstationAction::Command(c) if c == "deliver 65")),
            "{acts:?}"
        );
        n.handle_link(Duration::ZERO, "stored");
        let acts = drain(&mut n, Duration::ZERO);
        assert_eq!(answers_to(&acts, 99), vec![Ok(Response::Done)]);
        assert!(n.controller().vmd().domain(&p65).is_some());
        // Its program invocation runs no recipe here.
        n.handle_indication(
            Duration::ZERO,
            5,
            &Request::Start {
                name: p65.clone(),
                argument: String::new(),
            },
        );
        let e = answers_to(&drain(&mut n, Duration::ZERO), 5)
            .pop()
            .expect("answered")
            .expect_err("refused");
        assert!(e.description.contains("start rcm 65"), "{e}");

        // Not a program, another program's number, refused by the device,
        // lost on the way: refused, and the domain taken back out.
        for (name, text, then, why) in [
            (
                "PROGRAM_064",
                "program 64\nmove home\n",
                None,
                "is not a step",
            ),
            (
                "PROGRAM_064",
                "program 63\nmove home 1\n",
                None,
                "holds robot program 63",
            ),
            (
                "PROGRAM_066",
                "program 66\nmove home 1\n",
                None,
                "program 66 runs",
            ),
            (
                "PROGRAM_064",
                "program 64\nmove home 1\n",
                Some("refused"),
                "the line closed",
            ),
        ] {
            let mut acts = download(&mut n, name, text);
            if let Some(ev) = then {
                n.handle_link(Duration::ZERO, ev);
                acts.extend(drain(&mut n, Duration::ZERO));
            }
            let e = answers_to(&acts, 99)
                .pop()
                .unwrap_or_else(|| panic!("{name} unanswered: {acts:?}"))
                .expect_err("refused");
            assert!(e.description.contains(why), "{name}: {e}");
            let domain = ObjectName::new(name).expect("name");
            assert!(
                n.controller().vmd().domain(&domain).is_none(),
                "{name} kept"
            );
        }
    }

    #[test]
    fn a_start_is_answered_before_its_command_goes_to_the_link() {
        let mut n = node();
        let _ = drain(&mut n, Duration::ZERO);
        n.handle_indication(Duration::ZERO, 7, &start());
        let acts = drain(&mut n, Duration::ZERO);
        let answer = acts
            .iter()
            .position(|a| {
                matches!(
                    a,
                    WorkstationAction::Answer {
                        ticket: 7,
                        result: Ok(_)
                    }
                )
            })
            .expect("the start answered");
        let command = acts
            .iter()
            .position(|a| matches!(a, WorkstationAction::Command(c) if c == "start 65"))
            .expect("the start sent to the robot");
        assert!(answer < command, "{acts:?}");
        // What the start changed went out before its answer.
        assert!(statuses(&acts[..answer]) >= 1, "{acts:?}");
        // Nothing more until the link reports.
        assert!(drain(&mut n, Duration::ZERO).is_empty());
        assert!(n.controller().is_running());
    }

    #[test]
    fn the_links_reports_run_the_recipe_to_its_end() {
        let mut n = node();
        n.handle_indication(Duration::ZERO, 1, &start());
        let _ = drain(&mut n, Duration::ZERO);
        let t = Duration::from_secs(1);
        n.handle_link(t, "started");
        n.handle_link(t, "ended");
        let acts = drain(&mut n, t);
        assert!(!n.controller().is_running(), "{acts:?}");
        assert!(job_events(&acts).contains(&JobEvent::Done), "{acts:?}");
        assert_eq!(
            statuses(&acts),
            1,
            "one status for the settled end: {acts:?}"
        );
    }

    #[test]
    fn a_line_from_the_link_is_an_event_and_the_status_goes_out_only_when_changed() {
        let mut n = node();
        let first = drain(&mut n, Duration::ZERO);
        assert_eq!(statuses(&first), 1, "{first:?}");
        n.handle_link(Duration::ZERO, "plc-ready");
        let acts = drain(&mut n, Duration::ZERO);
        assert!(
            matches!(&acts[..], [WorkstationAction::Event(l)] if l == "plc-ready"),
            "{acts:?}"
        );
        // An association publishes the unchanged status again.
        n.handle_associated(Duration::ZERO);
        assert_eq!(statuses(&drain(&mut n, Duration::ZERO)), 1);
    }

    #[test]
    fn a_fault_ends_the_job_in_alarm_and_shutting_down_gives_the_stops_commands_and_nothing_more() {
        let mut n = node();
        n.handle_indication(Duration::ZERO, 1, &start());
        let _ = drain(&mut n, Duration::ZERO);
        n.handle_fault(Cause::new(AlarmClass::Device, "the link task stopped"));
        let acts = drain(&mut n, Duration::ZERO);
        assert!(!n.controller().is_running(), "{acts:?}");
        assert!(
            acts.iter().any(|a| matches!(a,
                WorkstationAction::Publish(Unconfirmed::Report { text, .. })
                    if text.contains("the link task stopped"))),
            "{acts:?}"
        );
        assert_eq!(n.shut_down(), vec!["halt".to_string()]);
        assert!(drain(&mut n, Duration::ZERO)
            .iter()
            .all(|a| !matches!(a, WorkstationAction::Command(_))));
    }
}
