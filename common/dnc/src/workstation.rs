//! The welding workstation's device, sans-I/O and poll-style: the robot
//! controller behind its DNC line as welding recipes see it. The engine's
//! `start rcm N` and stops go to the [`Host`]; the telegrams it wants sent
//! come out of [`Welding::poll_telegram`] (the welding node hands them to
//! its 3964R task, the simulation to its in-memory line); what the link
//! reports comes in through [`Welding::link_event`], [`Welding::opened`]
//! and [`Welding::closed`]. Alarms no job owns (a lost line while idle, a
//! program nobody started) go up through [`Device::poll_report`], with what
//! the robot does: each program started and ended, its information
//! messages. A `waitready rcm` waits until the robot takes DNC commands
//! (automatic-external mode, the link answering: [`Welding::readiness`]);
//! a robot known to be in another mode, or a line that is not open, makes
//! the workstation unavailable, so a Start is refused naming it.
//!
//! A robot program's text is delivered through [`Welding::deliver`], its
//! end polled with [`Welding::poll_delivered`].
//!
//! The host's link asks the robot's status at open and while a program
//! runs, not while idle: a mode changed at the robot's panel is known at
//! the next status (a `waitready`, `falc manual welding home`, asks one).

use crate::telegram::Mode;

use crate::host::{Host, Out};
use crate::procedure::{LinkEvent, Timing};
use crate::telegram::Telegram;
use falc_control::controller::{Controller, Device, Happening};
use falc_control::workstation_node::Linked;
use falc_model::ids::RobotProgram;
use falc_model::mms::error::ServiceError;
use falc_model::mms::pdu::Severity;
use falc_model::mms::vmd::{PhysicalStatus, RobotStatusDetail, VmdStatus};
use falc_model::mode::ManualAction;
use falc_recipe::check::Job;
use falc_recipe::condition::{Fact, RobotFact};
use falc_recipe::engine::{Action, Event, Outcome};
use falc_recipe::robot_program::ProgramText;
use std::collections::VecDeque;
use std::time::Duration;

/// How long a welding recipe's `start` waits for the robot's confirm:
/// select and start are two telegrams, each given up after the dead-line
/// limit on a dead line, so the link's own, clearer failure comes first.
pub fn confirm_limit(timing: &Timing) -> Duration {
    2 * timing.dead_line_after() + Duration::from_secs(6)
}

/// The close telegram ([`Welding::close`]): a driver waits until the link
/// sent it (or gave it up) before it lets go of the port.
pub const CLOSE: Telegram = Telegram::CloseDnc;

/// The robot controller behind its DNC line, as welding recipes see it.
pub struct Welding {
    /// The rules of the link; it knows whether the line is open.
    host: Host,
    /// Telegrams for the line, oldest first ([`Welding::poll_telegram`]).
    outbox: VecDeque<Telegram>,
    detail: Option<RobotStatusDetail>,
    /// What the robot did and alarms no job owns (a lost line while idle,
    /// a program found running nobody's), not yet reported.
    reports: VecDeque<(Severity, String)>,
    /// A `waitready` waits until the robot is ready.
    watching_ready: bool,
    /// Deliveries of robot programs that ended ([`Welding::poll_delivered`]).
    delivered: VecDeque<(RobotProgram, Result<(), ServiceError>)>,
}

impl Welding {
    /// The robot on serial line `line` (its path, for messages), whose
    /// link runs with `timing`; the line is not open yet.
    pub fn new(line: &str, timing: &Timing) -> Self {
        Self {
            host: Host::new(line, timing),
            outbox: VecDeque::new(),
            detail: None,
            reports: VecDeque::new(),
            watching_ready: false,
            delivered: VecDeque::new(),
        }
    }

    /// Delivers `program`'s text to the robot ([`Host::deliver`]); how it
    /// ended comes out of [`Self::poll_delivered`]. Refused at once (no
    /// telegram sent) while the line is not open, the robot is known not to
    /// be in AUE, another delivery is under way, or a job of ours runs that
    /// program.
    pub fn deliver(&mut self, program: &ProgramText) -> Result<(), ServiceError> {
        // A robot known not to take DNC commands would refuse it (`01`).
        if let Some(why) = self.unready() {
            return Err(ServiceError::state_conflict(format!(
                "robot program {} not delivered: {why}",
                program.number
            )));
        }
        let outs = self.host.deliver(program)?;
        // Only telegrams: no engine event comes of a delivery's start.
        let mut none = Vec::new();
        self.apply(outs, &mut none);
        Ok(())
    }

    /// A delivery that ended: the program, and whether the robot stored it.
    pub fn poll_delivered(&mut self) -> Option<(RobotProgram, Result<(), ServiceError>)> {
        self.delivered.pop_front()
    }

    /// Whether the robot takes DNC commands now: the line open, the RCM
    /// answering, automatic-external mode; else what is missing.
    pub fn readiness(&self) -> Result<(), String> {
        let line = self.host.line();
        if !self.host.is_open() {
            return Err(format!("the DNC line {line} is not open"));
        }
        if !self.host.answered() {
            return Err(format!("the RCM on {line} does not answer DNC"));
        }
        match self.host.mode() {
            Some(Mode::AutomaticExternal) => Ok(()),
            Some(other) => Err(not_aue(line, other)),
            None => Err(format!("the RCM on {line} has not told its mode yet")),
        }
    }

    /// A `waitready` that waits, told once the robot is ready.
    fn ready_now(&mut self, out: &mut Vec<Event>) {
        if self.watching_ready && self.readiness().is_ok() {
            self.watching_ready = false;
            out.push(Event::InputReached);
        }
    }

    /// The robot program a job of ours runs, as far as the host knows.
    pub fn program(&self) -> Option<falc_model::ids::RobotProgram> {
        self.host.running()
    }

    /// The next telegram for the line, in order: the driver hands each to
    /// the 3964R link after every event.
    pub fn poll_telegram(&mut self) -> Option<Telegram> {
        self.outbox.pop_front()
    }

    /// Queues `t` for the line; false (and the link's failure applied) if
    /// the line is not open.
    fn send(&mut self, t: Telegram, out: &mut Vec<Event>) -> bool {
        let sent = self.host.is_open();
        if sent {
            self.outbox.push_back(t);
        } else {
            let why = format!(
                "no connection with RCM on {}: the line is not open",
                self.host.line()
            );
            let outs = self.host.link_failed(why);
            self.apply(outs, out);
        }
        sent
    }

    /// Carries out host outputs; engine events go to `out`.
    fn apply(&mut self, outs: Vec<Out>, out: &mut Vec<Event>) {
        for o in outs {
            match o {
                Out::Telegram(t) => {
                    self.send(t, out);
                }
                Out::Engine(ev) => out.push(ev),
                Out::Detail(d) => self.detail = Some(d),
                Out::Info(text) => {
                    tracing::info!("{text}");
                    self.reports.push_back((Severity::Info, text));
                }
                Out::Alarm(cause) => {
                    tracing::warn!("{cause}");
                    self.reports
                        .push_back((Severity::Alarm(cause.class), cause.text));
                }
                Out::Delivered(program, result) => {
                    if let Err(e) = &result {
                        tracing::warn!("{e}");
                    }
                    self.delivered.push_back((program, result));
                }
            }
        }
    }

    /// What the 3964R link reported: engine events for the running recipe.
    pub fn link_event(&mut self, now: Duration, ev: LinkEvent) -> Vec<Event> {
        let mut out = Vec::new();
        match ev {
            LinkEvent::Received(bytes) => match Telegram::decode(&bytes) {
                Ok(t) => {
                    tracing::debug!(?t, "from the RCM");
                    let outs = self.host.telegram(now, t);
                    self.apply(outs, &mut out);
                    self.ready_now(&mut out);
                }
                Err(e) => tracing::warn!("undecodable telegram from the RCM: {e}"),
            },
            LinkEvent::Failed { telegram, error } => {
                tracing::warn!(
                    "telegram {} to the RCM given up: {error}",
                    telegram.escape_ascii()
                );
                let why = format!("no connection with RCM on {}: {error}", self.host.line());
                let outs = self.host.gave_up(&telegram, why);
                self.apply(outs, &mut out);
            }
            LinkEvent::Refused(why) => tracing::debug!("block refused: {why}"),
            LinkEvent::Silent(waited) => {
                let outs = self.host.silent(now, waited);
                self.apply(outs, &mut out);
            }
            LinkEvent::Sent(telegram) => self.host.sent(now, &telegram),
        }
        out
    }

    /// The line was (re)opened: initiate DNC and ask the robot's status.
    pub fn opened(&mut self, now: Duration) {
        let mut out = Vec::new();
        let outs = self.host.connected(now);
        self.apply(outs, &mut out);
    }

    /// The node stops, or closes the port on purpose: a job's program
    /// selected, starting or running is stopped (`H`), then the DNC link is
    /// closed (`C`),
    /// so the RCM knows nobody commands it until the next initiate (`I`,
    /// sent when the line opens again: [`Self::opened`]). The driver sends
    /// what [`Self::poll_telegram`] gives and waits until `C` went out
    /// ([`CLOSE`]). Nothing is sent on a line that is not open.
    pub fn close(&mut self) {
        if self.host.has_job() {
            self.halt(&mut Vec::new());
        }
        if self.host.is_open() {
            self.outbox.push_back(Telegram::CloseDnc);
        }
    }

    /// The line closed: engine events for the running recipe.
    pub fn closed(&mut self) -> Vec<Event> {
        self.outbox.clear();
        let why = format!(
            "no connection with RCM on {}: the line closed",
            self.host.line()
        );
        tracing::warn!("{why}");
        let mut out = Vec::new();
        let outs = self.host.closed(why);
        self.apply(outs, &mut out);
        out
    }
}

/// What the device does when something happens ([`Device::handle`]).
impl Welding {
    fn act(&mut self, now: Duration, action: Action, out: &mut Vec<Event>) {
        match action {
            Action::Start {
                job: Job::Program(p),
                ..
            } => {
                let outs = self.host.start(p);
                self.apply(outs, out);
            }
            Action::Stop(_) => self.halt(out),
            // The mode is asked anew: it may have changed at the panel.
            Action::WatchReady => {
                self.watching_ready = true;
                if self.host.is_open() {
                    let outs = self.host.ask_status(now);
                    self.apply(outs, out);
                }
            }
            Action::Unwatch => self.watching_ready = false,
            other => tracing::warn!("a welding recipe cannot {other:?}"),
        }
    }

    /// Stops the robot program (the commander stopped or killed the
    /// recipe, or the node closes the line).
    fn halt(&mut self, out: &mut Vec<Event>) {
        let outs = self.host.stop();
        self.apply(outs, out);
    }

    fn finished(&mut self, outcome: &Outcome) {
        // A recipe that ended badly (its own time limit, say) while the
        // robot still runs its program: the robot is stopped.
        if *outcome != Outcome::Done && self.host.running().is_some() {
            let mut out = Vec::new();
            self.halt(&mut out);
        }
    }

    fn handle_timeout(&mut self, now: Duration, out: &mut Vec<Event>) {
        let outs = self.host.handle_timeout(now);
        self.apply(outs, out);
    }
}

/// What happened on the DNC line, as the workstation's node takes it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LineEvent {
    /// The line was (re)opened ([`Welding::opened`]).
    Opened,
    /// The 3964R link reported this ([`Welding::link_event`]).
    Link(LinkEvent),
    /// The line closed ([`Welding::closed`]).
    Closed,
}

impl Linked for Welding {
    type Command = Telegram;
    type LinkEvent = LineEvent;

    fn next_command(&mut self) -> Option<Telegram> {
        self.poll_telegram()
    }

    fn stop(&mut self) {
        self.close();
    }

    fn take_link_event(ctl: &mut Controller<Self>, now: Duration, ev: LineEvent) -> Option<String> {
        let events = match ev {
            LineEvent::Opened => {
                ctl.device.opened(now);
                return None;
            }
            LineEvent::Link(ev) => ctl.device.link_event(now, ev),
            LineEvent::Closed => ctl.device.closed(),
        };
        ctl.feed(now, events);
        None
    }
}

impl Device for Welding {
    fn deliver_program(&mut self, program: &ProgramText) -> Result<(), ServiceError> {
        self.deliver(program)
    }
    fn poll_delivered(&mut self) -> Option<(RobotProgram, Result<(), ServiceError>)> {
        Welding::poll_delivered(self)
    }
    fn handle(&mut self, now: Duration, what: Happening<'_>, out: &mut Vec<Event>) {
        match what {
            Happening::Act(action) => self.act(now, action, out),
            Happening::Halt => self.halt(out),
            Happening::Finished(outcome) => self.finished(outcome),
            Happening::Clock => self.handle_timeout(now, out),
            Happening::Lost(_) | Happening::Associated | Happening::Mode(_) => {}
        }
    }

    /// A line that is not open: nothing can go to the robot.
    fn unavailable(&self) -> Option<String> {
        (!self.host.is_open()).then(|| format!("the DNC line {} is not open", self.host.line()))
    }

    /// Also a robot whose last status said it is not in automatic-external
    /// mode (its own recipes still run: `home` asks the mode anew; a
    /// robot not heard yet is not refused here, its link supervision
    /// speaks for it).
    fn unready(&self) -> Option<String> {
        self.unavailable().or_else(|| match self.host.mode() {
            Some(m) if m != Mode::AutomaticExternal => Some(not_aue(self.host.line(), m)),
            _ => None,
        })
    }

    fn manual(&mut self, _now: Duration, action: &ManualAction) -> Result<String, String> {
        let (telegram, done) = self.host.manual(action)?;
        // No recipe runs in maintenance: a link failure has no job to end.
        let mut events = Vec::new();
        if self.send(telegram, &mut events) {
            Ok(done)
        } else {
            Err(format!("the DNC line {} is not open", self.host.line()))
        }
    }

    fn explain_timeout(&self, now: Duration) -> Option<String> {
        self.host.explain_timeout(now)
    }

    /// The supervision's clock (status requests, the silence limit).
    fn poll_timeout(&self) -> Option<Duration> {
        self.host.poll_timeout()
    }

    fn poll_report(&mut self) -> Option<(Severity, String)> {
        self.reports.pop_front()
    }

    /// The robot's facts as the link knows them: ready when it takes DNC
    /// commands; running while a program of ours runs (unknown while
    /// the line is closed or the robot has not answered).
    fn observes(&self, fact: Fact) -> Option<bool> {
        match fact {
            Fact::Robot(RobotFact::Ready) => Some(self.readiness().is_ok()),
            Fact::Robot(RobotFact::Running) => {
                (self.host.is_open() && self.host.answered()).then(|| self.host.running().is_some())
            }
            Fact::Signal(_) => None,
        }
    }

    fn status(&self, status: &mut VmdStatus) {
        status.additional = self.detail;
        // Inoperable while the line is closed or the RCM has not answered
        // since it was (re)opened or went silent: an alarm about the link
        // clears only once the robot answers again.
        if !self.host.answered() {
            status.physical = PhysicalStatus::Inoperable;
        }
    }
}

/// Why a robot in mode `m` takes no DNC commands, and the way out.
fn not_aue(line: &str, m: Mode) -> String {
    let mode = match m {
        Mode::Manual => "manual",
        Mode::Automatic => "automatic",
        Mode::AutomaticExternal => "automatic-external",
    };
    format!(
        "the robot on {line} is in {mode} mode, not automatic-external (AUE) with DNC: \
         set it to AUE, then falc manual welding home"
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_model::ids::RobotProgram;

    fn drain(w: &mut Welding) -> Vec<Telegram> {
        std::iter::from_fn(|| w.poll_telegram()).collect()
    }

    /// A delivery's telegrams go out of the outbox one at a time, each
    /// after its acknowledgement came over the link; its end is polled.
    #[test]
    fn a_delivered_program_goes_out_line_by_line_and_its_end_is_polled() {
        let mut w = Welding::new("/dev/ttyS0", &Timing::default());
        let text = "program 10\nmove home 1\n";
        let p = ProgramText::parse(text, "010.prg").expect("clean");
        assert!(w.deliver(&p).is_err(), "a closed line");
        w.opened(Duration::ZERO);
        w.link_event(Duration::ZERO, status_of(Mode::AutomaticExternal));
        drain(&mut w);
        w.deliver(&p).expect("a delivery");
        let mut sent = Vec::new();
        while let Some(t) = w.poll_telegram() {
            let code = t.encode().first().copied().unwrap_or(0);
            sent.push(t);
            let ack = Telegram::Ack {
                of: code,
                error: None,
            };
            w.link_event(Duration::ZERO, LinkEvent::Received(ack.encode()));
        }
        let ten = RobotProgram::of(10);
        assert_eq!(
            sent,
            vec![
                Telegram::Text {
                    program: ten,
                    lines: 2,
                    hash: p.hash()
                },
                Telegram::Line {
                    no: 1,
                    text: "program 10".into()
                },
                Telegram::Line {
                    no: 2,
                    text: "move home 1".into()
                },
                Telegram::TextEnd(ten),
            ]
        );
        assert_eq!(w.poll_delivered(), Some((ten, Ok(()))));
        assert_eq!(w.poll_delivered(), None);
    }

    #[test]
    fn closing_stops_a_running_program_then_closes_dnc_and_reopening_initiates_again() {
        let timing = Timing::default();
        let mut w = Welding::new("/dev/ttyS0", &timing);
        w.opened(Duration::ZERO);
        assert_eq!(
            drain(&mut w),
            vec![Telegram::InitiateDnc, Telegram::StatusRequest]
        );
        // Idle: only the close.
        w.close();
        assert_eq!(drain(&mut w), vec![CLOSE]);
        // A job's program runs: stopped first. (The RCM answered first:
        // a job's select waits for that.)
        w.link_event(Duration::ZERO, status_of(Mode::AutomaticExternal));
        drain(&mut w);
        let p = RobotProgram::of(65);
        let mut out = Vec::new();
        w.handle(
            Duration::ZERO,
            Happening::Act(Action::Start {
                target: falc_model::ids::StationName::new("rcm").expect("valid"),
                job: Job::Program(p),
            }),
            &mut out,
        );
        assert_eq!(drain(&mut w), vec![Telegram::SelectProgram(p)]);
        for ack in [b'S', b'G'] {
            let t = Telegram::Ack {
                of: ack,
                error: None,
            };
            w.link_event(Duration::ZERO, LinkEvent::Received(t.encode()));
        }
        drain(&mut w);
        w.close();
        assert_eq!(drain(&mut w), vec![Telegram::StopProgram, CLOSE]);
        // A closed line gets nothing; opened again, it is initiated again.
        w.closed();
        w.close();
        assert_eq!(drain(&mut w), vec![]);
        w.opened(Duration::from_secs(1));
        assert_eq!(
            drain(&mut w),
            vec![Telegram::InitiateDnc, Telegram::StatusRequest]
        );
    }

    fn status_of(mode: Mode) -> LinkEvent {
        let t = Telegram::ProgramStatus {
            program: None,
            state: crate::telegram::ProgramState::Idle,
            mode,
        };
        LinkEvent::Received(t.encode())
    }

    #[test]
    fn a_robot_not_in_aue_is_unready_and_waitready_asks_its_mode_again_until_it_is() {
        let timing = Timing::default();
        let mut w = Welding::new("/dev/ttyS0", &timing);
        assert_eq!(
            w.unready().as_deref(),
            Some("the DNC line /dev/ttyS0 is not open")
        );
        w.opened(Duration::ZERO);
        drain(&mut w);
        // Not heard yet: not refused (the link supervision speaks).
        assert_eq!(w.unready(), None);
        assert!(w.readiness().is_err());
        w.link_event(Duration::ZERO, status_of(Mode::Manual));
        let why = w.unready().expect("unready in manual mode");
        assert!(why.contains("manual mode") && why.contains("AUE"), "{why}");
        // Its own recipes still start (home checks the mode itself).
        assert_eq!(w.unavailable(), None);
        // waitready: the status is asked; manual still, nothing yet.
        let mut out = Vec::new();
        w.handle(secs(1), Happening::Act(Action::WatchReady), &mut out);
        assert_eq!(drain(&mut w), vec![Telegram::StatusRequest]);
        assert!(out.is_empty());
        let out = w.link_event(secs(2), status_of(Mode::Manual));
        assert!(out.is_empty(), "{out:?}");
        // The maintainer set AUE at the panel: the next status says so.
        let out = w.link_event(secs(3), status_of(Mode::AutomaticExternal));
        assert_eq!(out, vec![Event::InputReached]);
        assert_eq!((w.unready(), w.readiness()), (None, Ok(())));
        // Told once.
        let out = w.link_event(secs(4), status_of(Mode::AutomaticExternal));
        assert!(out.is_empty());
    }

    #[test]
    fn waitready_on_a_ready_robot_is_told_at_its_next_status_and_unwatch_ends_it() {
        let timing = Timing::default();
        let mut w = Welding::new("/dev/ttyS0", &timing);
        w.opened(Duration::ZERO);
        w.link_event(Duration::ZERO, status_of(Mode::AutomaticExternal));
        drain(&mut w);
        let mut out = Vec::new();
        w.handle(secs(1), Happening::Act(Action::WatchReady), &mut out);
        w.handle(secs(1), Happening::Act(Action::Unwatch), &mut out);
        let out = w.link_event(secs(2), status_of(Mode::AutomaticExternal));
        assert!(out.is_empty(), "no longer watched: {out:?}");
    }

    fn secs(s: u64) -> Duration {
        Duration::from_secs(s)
    }
}
