//! The transport workstation's device: the conveyor PLC as its recipes see
//! it. Turns the engine's `activate` / `reset` into coil writes and
//! `waitline` / `waitplace` / `waitstation` into watches on the polled
//! inputs; says why no recipe can start (no link, emergency stop, PLC not
//! ready); turns a rising emergency stop into an alarm; and, when a wait
//! runs out, says what the inputs show (a line still running: a jammed
//! carrier; a line that stopped without the place filling: a faulty
//! sensor). It knows only the documented I/O map and the conveyor's
//! routes in it (which line runs from where to where), so it works with
//! any PLC and conveyor that honour the map.
//!
//! **Feedback supervision** while a job runs (a carrier set by hand
//! between jobs, the way back after an alarm, is no fault): a place sensor
//! that lights while no line runs towards its place is *unrequested
//! feedback*; one that goes dark while no line runs away from its place
//! and no station takes its carrier is *lost feedback*. Each is an alarm
//! at once, in the reading that shows it, naming the sensor; the
//! equipment file says per place whether it needs an acknowledgement (its
//! `sensor_fault`). The routes are the file's too.
//!
//! The buttons' state is defined at every step (docs/plc.md's wiring guide
//! states the same rule):
//! - **on the first connection** of the process (a restart of the
//!   workstation, perhaps mid-weld) the coils are read back and adopted:
//!   the station buttons the PLC holds stay held (a workpiece stays
//!   clamped) until the commander says otherwise (bumpless restart); a
//!   line button held is released (no job of this process runs a line);
//!   nothing else is written but external control if it is off;
//! - **on a reconnection** (the link came back) the node's own state
//!   stands: each coil the PLC holds otherwise is written to it; where the
//!   PLC does not read its coils back, every button is released and
//!   external control taken, in one write;
//! - **`activate`** always gives the PLC a rising edge: a button this node
//!   already holds (a station button kept across an alarm, say) is
//!   released and pressed again, so the PLC never waits for an edge that
//!   cannot come;
//! - **after an alarm, a failed job, or a stop or kill by the commander**,
//!   **when the commander is lost**, **when the node stops** and **on its
//!   first connection after a restart**, each coil goes to its safe state
//!   for that occasion, as the equipment file says ([`falc_equipment::file::SafeStates`]):
//!   for the 1992 conveyor the line buttons are released (nothing moves)
//!   and the station buttons stay (a workpiece stays clamped on its
//!   station while people look, the robot may still weld it);
//! - **after `ack`** nothing is written: the operator sets the carriers
//!   back by hand and the next job's `activate` presses afresh.
//!
//! Sans-I/O and poll-style: what the link must do comes out of
//! [`Plc::poll_command`] (the transport node hands it to its Modbus task,
//! the simulation to the twin's map); readings and the link's state come in
//! through [`Plc::connected`], [`Plc::reading`] and [`Plc::link_down`].

use crate::feedback::Supervision;
use crate::map::{Coil, Coils, Input, Inputs, SafeState, SignalName, Spot};
use falc_control::controller::{Controller, Device, Happening, Reading};
use falc_control::workstation_node::Linked;
use falc_equipment::file::{Equipment, Occasion};
use falc_model::alarm::{AlarmClass, Cause};
use falc_model::ids::Place;
use falc_model::mms::pdu::Severity;
use falc_model::mms::vmd::{PhysicalStatus, VmdStatus, NO_NAMED_STATE};
use falc_model::mode::{CellMode, ManualAction};
use falc_recipe::check::{Button, Program, Signal};
use falc_recipe::condition::Fact;
use falc_recipe::engine::{Action, Event, Outcome};
use falc_recipe::problem::Problem;
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Duration;

/// What the link to the PLC is asked to do.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PlcCommand {
    /// Write one coil.
    Write(Coil, bool),
    /// Write every coil of the map at once.
    WriteAll(Coils),
    /// Poll at the busy or the idle period from now on (no Modbus request).
    Pace(Pace),
    /// Read the inputs now (no write): counted as a command carried out,
    /// so the reading after it says it was taken after it.
    Read,
}

/// What the link reports.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PlcEvent {
    /// Connected (again), with the coils the PLC holds as it reads them
    /// back, or None if it would not say (a Modbus exception to the read).
    Connected {
        /// The coils, read back.
        coils: Option<Coils>,
    },
    /// A reading of the inputs (sent when it differs from the last one, and
    /// after every coil write).
    Inputs {
        /// The inputs.
        inputs: Inputs,
        /// Commands carried out (or dropped) before this read began.
        commands_done: u64,
    },
    /// The link failed or the PLC refused a request; the link retries.
    Fault(String),
}

/// The link's poll period while a recipe runs, in ms (its default).
pub const POLL_MS: u64 = 10;
/// … and while none runs: an idle cell costs little, an emergency stop or
/// a lost PLC is still seen within this.
pub const IDLE_POLL_MS: u64 = 100;

/// How fast the link polls.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pace {
    /// A recipe runs: every `poll`.
    Busy,
    /// Nothing runs: every `idle_poll`.
    Idle,
}

#[derive(Debug, Clone, Copy)]
struct Watch {
    signal: Signal,
    level: bool,
    since: Duration,
    /// Commands issued before the watch: a reading must come after them.
    after: u64,
}

/// The conveyor PLC behind its link.
pub struct Plc {
    address: String,
    equipment: Arc<Equipment>,
    /// Commands for the link, oldest first ([`Plc::poll_command`]).
    commands: VecDeque<PlcCommand>,
    issued: u64,
    /// The link's fault, while it lasts.
    down: Option<String>,
    inputs: Option<Inputs>,
    /// Commands carried out before `inputs` was read.
    inputs_after: u64,
    watch: Option<Watch>,
    /// Buttons this node holds pressed.
    pressed: Vec<Button>,
    /// Whether this node's process was connected to the PLC before (its
    /// own state of the coils stands) or not yet (the PLC's is adopted).
    known: bool,
    /// The line last pressed by the running recipe.
    last_line: Option<char>,
    /// Whether the link polls at the busy period.
    busy: bool,
    /// A line a maintainer runs by hand, and when it is released.
    manual_line: Option<(char, Duration)>,
    /// What the conveyor did (a line run, a carrier arriving), not yet
    /// reported ([`Device::poll_report`]).
    reports: VecDeque<(Severity, String)>,
    /// The actuators' feedback ([`crate::feedback`]), also between jobs.
    actuators: Supervision,
    /// A fault the actuators' supervision found on the clock, for the
    /// controller ([`Device::poll_fault`]).
    fault: Option<Cause>,
    /// The time of what is being handled (a write's, a reading's).
    clock: Duration,
    /// Feedback is supervised between readings both taken after this
    /// many commands: the running job's first write. What changed before
    /// (carriers set by hand just before a start, seen late at the idle
    /// pace) is the job's starting point, not a fault.
    supervise_from: u64,
    /// When the last reading came.
    read_at: Option<Duration>,
    /// A precondition waits for a reading taken after this many commands
    /// ([`Device::ask_fresh_reading`]).
    fresh_from: Option<u64>,
    /// The link's poll period while a recipe runs: a reading that came
    /// this recently, taken after every command issued, is fresh enough
    /// for a precondition (a start right after the previous job's end
    /// needs no read of its own).
    busy_poll: Duration,
}

impl Plc {
    /// The PLC of `equipment` at `address` (for messages), not connected
    /// yet.
    pub fn new(address: String, equipment: Arc<Equipment>) -> Self {
        Self {
            address,
            actuators: Supervision::new(equipment.feedback()),
            fault: None,
            clock: Duration::ZERO,
            equipment,
            commands: VecDeque::new(),
            issued: 0,
            down: Some("not connected to the conveyor PLC yet".into()),
            inputs: None,
            inputs_after: 0,
            watch: None,
            pressed: Vec::new(),
            known: false,
            last_line: None,
            busy: false,
            manual_line: None,
            reports: VecDeque::new(),
            supervise_from: 0,
            read_at: None,
            fresh_from: None,
            busy_poll: Duration::from_millis(POLL_MS),
        }
    }

    /// Its link polls every `period` while a recipe runs (the node's
    /// `--poll-ms`; default [`POLL_MS`]).
    pub fn with_busy_poll(mut self, period: Duration) -> Self {
        self.busy_poll = period;
        self
    }

    /// Polls fast while a recipe runs, slowly while the node is idle.
    fn pace(&mut self, busy: bool) {
        if self.busy != busy {
            self.busy = busy;
            if busy {
                self.supervise_from = self.issued + 1;
            }
            // Not counted in `issued`: a watch waits for writes, not for this.
            let pace = if busy { Pace::Busy } else { Pace::Idle };
            self.commands.push_back(PlcCommand::Pace(pace));
        }
    }

    fn send(&mut self, c: PlcCommand) {
        self.issued += 1;
        self.commands.push_back(c);
    }

    /// The next command for the link, in the order issued: the driver
    /// hands each to the link after every event.
    pub fn poll_command(&mut self) -> Option<PlcCommand> {
        self.commands.pop_front()
    }

    fn write(&mut self, b: Button, value: bool) {
        self.actuators.wrote(Coil::Button(b), value, self.clock);
        // A button held already is released first, so the PLC sees a
        // rising edge; a plain output set on again just stays on.
        let edge = !matches!(b, Button::Output(_));
        if value && edge && self.pressed.contains(&b) {
            self.send(PlcCommand::Write(Coil::Button(b), false));
        }
        self.pressed.retain(|p| *p != b);
        if value {
            self.pressed.push(b);
            if let Button::Line(l) = b {
                self.last_line = Some(l);
            }
        }
        self.send(PlcCommand::Write(Coil::Button(b), value));
    }

    /// (Re)connected, with the coils the PLC holds (`held`, read back):
    /// adopted on the process's first connection, corrected to this node's
    /// own state on a later one; unknown, every button is released and
    /// external control taken, in one write.
    pub fn connected(&mut self, held: Option<Coils>) {
        self.down = None;
        let first = !self.known;
        self.known = true;
        let Some(held) = held else {
            self.pressed.clear();
            self.actuators.rest();
            let all = self
                .equipment
                .coils()
                .iter()
                .map(|c| (c.coil, c.coil == Coil::ExternalControl))
                .collect();
            self.send(PlcCommand::WriteAll(all));
            return;
        };
        let on = |c: Coil| held.iter().any(|(h, v)| *h == c && *v);
        if first {
            self.pressed = held
                .iter()
                .filter_map(|(c, v)| match c {
                    Coil::Button(b) if *v => Some(*b),
                    _ => None,
                })
                .collect();
            // What the dead process held goes to its safe state after a
            // crash: a line it ran has no job now and is released, so
            // nothing moves unsupervised (found by falc-sim: a transport
            // killed mid-move left its line running after the restart).
            self.go_safe(Occasion::Crash);
        } else {
            for (coil, _) in &held {
                if let Coil::Button(b) = *coil {
                    let want = self.pressed.contains(&b);
                    if on(*coil) != want {
                        self.send(PlcCommand::Write(*coil, want));
                    }
                }
            }
        }
        if !on(Coil::ExternalControl) {
            self.send(PlcCommand::Write(Coil::ExternalControl, true));
        }
    }

    /// The link failed: `why` is the alarm.
    pub fn link_down(&mut self, why: &str) {
        self.down = Some(why.to_string());
        self.inputs = None;
    }

    /// A new reading ([`Plc::reading`]). Returns what it means for the running recipe, and an
    /// alarm if the PLC went into emergency stop (safety) or out of ready
    /// (device).
    fn inputs(&mut self, inputs: Inputs, commands_done: u64) -> (Vec<Event>, Option<Cause>) {
        let before = self.inputs.replace(inputs.clone());
        if self.unavailable().is_some() {
            self.actuators.rest();
        } else {
            let pressed = &self.pressed;
            self.actuators
                .reading(&inputs, self.clock, |c| holds(pressed, c));
        }
        let before_after = std::mem::replace(&mut self.inputs_after, commands_done);
        let supervised = self.busy && before_after >= self.supervise_from;
        // A carrier arriving: a place sensor lighting (an edge, not every
        // poll; not the first reading, which finds carriers standing).
        // While a job runs, each edge must have a cause.
        let mut feedback = None;
        if let Some(b) = &before {
            for p in self.equipment.places().iter().map(|p| p.place) {
                let s = Signal::Place(p);
                let (was, is) = (b.signal(s), inputs.signal(s));
                if is && !was {
                    self.reports
                        .push_back((Severity::Info, format!("carrier arrived at W{p}")));
                }
                if was != is && supervised && feedback.is_none() {
                    feedback = self.feedback_fault(p, is, b, &inputs);
                }
            }
        }
        let mut events = Vec::new();
        if self.watch_met() {
            self.watch = None;
            events.push(Event::InputReached);
        }
        let was = |i: Input| before.as_ref().is_some_and(|b| b.get(i));
        let alarm = if inputs.get(Input::EStop) && !was(Input::EStop) {
            Some(Cause::new(
                AlarmClass::Safety,
                format!("emergency stop on the conveyor PLC at {}", self.address),
            ))
        } else if !inputs.get(Input::Ready)
            && !inputs.get(Input::EStop)
            && (was(Input::Ready) || before.is_none())
        {
            Some(Cause::new(
                AlarmClass::Device,
                format!(
                    "the conveyor PLC at {} is not ready (input `PLC ready` off)",
                    self.address
                ),
            ))
        } else {
            feedback.or_else(|| self.actuator_fault())
        };
        (events, alarm)
    }

    /// A place sensor of `place` that changed to `lit` between readings
    /// `before` and `now` while a job runs: a fault unless something moves
    /// a carrier there (a line towards it lights it; a line away from it,
    /// or a station this node presses that is fed from it, darkens it).
    fn feedback_fault(
        &self,
        place: Place,
        lit: bool,
        before: &Inputs,
        now: &Inputs,
    ) -> Option<Cause> {
        let runs = |l: char| before.signal(Signal::Line(l)) || now.signal(Signal::Line(l));
        let sensor = format!("sensor `place {place} occupied` (W{place})");
        let text = if lit {
            if self.equipment.moves_towards(place).any(runs) {
                return None;
            }
            format!(
                "unrequested feedback: {sensor} lit while no line runs towards W{place} \
                 (conveyor PLC at {})",
                self.address
            )
        } else {
            let taken = self.pressed.iter().any(|b| match b {
                Button::Station(n) => self.equipment.feed(*n) == Some(Spot::Place(place)),
                Button::Line(_) | Button::Output(_) => false,
            });
            if taken || self.equipment.moves_away(place).any(runs) {
                return None;
            }
            format!(
                "lost feedback: {sensor} went dark while nothing moves its carrier \
                 (conveyor PLC at {})",
                self.address
            )
        };
        // The place's `sensor_fault` (a place the file lacks: an alarm).
        let class = self
            .equipment
            .place(place)
            .map_or(AlarmClass::Device, |p| p.sensor_fault.alarm_class());
        Some(Cause::new(class, text))
    }

    /// A mismatch of an actuator and its feedback due now, if the PLC can
    /// act ([`Supervision::check`]).
    fn actuator_fault(&mut self) -> Option<Cause> {
        if self.unavailable().is_some() {
            return None;
        }
        let pressed = &self.pressed;
        self.actuators
            .check(self.clock, |c| holds(pressed, c), &self.address)
    }

    /// A new reading as a driver takes it: `Plc::inputs`, and the line
    /// to report when the PLC became usable with it (linked, ready, no
    /// emergency stop) after it was not.
    pub fn reading(&mut self, inputs: Inputs, commands_done: u64) -> Reading {
        let was_down = self.unavailable().is_some();
        let (events, alarm) = self.inputs(inputs, commands_done);
        let ready = (alarm.is_none() && was_down && self.unavailable().is_none())
            .then(|| format!("conveyor PLC at {} ready", self.address));
        Reading {
            events,
            alarm,
            ready,
        }
    }

    fn watch_met(&self) -> bool {
        match (self.watch, &self.inputs) {
            (Some(w), Some(i)) => self.inputs_after >= w.after && i.signal(w.signal) == w.level,
            _ => false,
        }
    }

    /// Brings every button this node holds to its safe state on
    /// `occasion` (the equipment's `safe`): for the 1992 conveyor the lines
    /// stop, the clamps hold their workpiece (the robot may still weld it).
    fn go_safe(&mut self, occasion: Occasion) {
        let equipment = self.equipment.clone();
        self.release(|b| equipment.safe(Coil::Button(*b), occasion) == SafeState::Off);
    }

    /// Releases the buttons this node holds that `which` selects.
    fn release(&mut self, which: impl Fn(&Button) -> bool) {
        let held: Vec<Button> = self.pressed.iter().copied().filter(which).collect();
        for b in held {
            self.write(b, false);
        }
    }

    /// The node stops: every output to its safe state in one write, what
    /// this node does not know to be pressed released (the lines stop; a
    /// clamp it holds stays, and so does external control, so that the
    /// PLC's panel does not take the clamps over).
    pub fn shutdown(&mut self) {
        if self.down.is_none() {
            let stop = |c: Coil| self.equipment.safe(c, Occasion::Stop);
            let all = self
                .equipment
                .coils()
                .iter()
                .map(|c| {
                    let keep = c.safe.stop == SafeState::Hold
                        && match c.coil {
                            Coil::Button(b) => self.pressed.contains(&b),
                            Coil::ExternalControl => true,
                        };
                    (c.coil, keep)
                })
                .collect();
            self.pressed
                .retain(|b| stop(Coil::Button(*b)) == SafeState::Hold);
            self.send(PlcCommand::WriteAll(all));
        }
    }

    /// The last reading, while the PLC can act on what it shows; else
    /// why not ([`Device::unavailable`]).
    fn live(&self) -> Result<&Inputs, String> {
        match (self.unavailable(), &self.inputs) {
            (None, Some(inputs)) => Ok(inputs),
            (why, _) => Err(why.unwrap_or_else(|| {
                format!("no reading from the conveyor PLC at {} yet", self.address)
            })),
        }
    }

    /// Commands issued so far (to wait until the link carried them out).
    pub fn issued(&self) -> u64 {
        self.issued
    }
}

/// Whether FALC holds `coil` (external control: always, once connected).
fn holds(pressed: &[Button], coil: Coil) -> bool {
    match coil {
        Coil::Button(b) => pressed.contains(&b),
        Coil::ExternalControl => true,
    }
}

fn on_off(v: bool) -> &'static str {
    if v {
        "on"
    } else {
        "off"
    }
}

/// What the device does when something happens ([`Device::handle`]).
impl Plc {
    fn act(&mut self, now: Duration, action: Action, out: &mut Vec<Event>) {
        self.pace(true);
        match action {
            Action::Activate(b) => {
                if let Button::Line(l) = b {
                    self.reports
                        .push_back((Severity::Info, format!("line {l} runs")));
                }
                self.write(b, true)
            }
            Action::Reset(b) => self.write(b, false),
            Action::Watch { signal, level } => {
                self.watch = Some(Watch {
                    signal,
                    level,
                    since: now,
                    after: self.issued,
                });
                if self.watch_met() {
                    self.watch = None;
                    out.push(Event::InputReached);
                }
            }
            Action::Unwatch => self.watch = None,
            other => tracing::warn!("a transport recipe cannot {other:?}"),
        }
    }

    fn mode_changed(&mut self, mode: CellMode) {
        if mode != CellMode::Maintenance {
            // A line a maintainer left running stops as maintenance ends; a
            // clamp stays (a mode also comes with a reassociation, when the
            // robot may still weld): the next job's `activate` or `reset`
            // sets it, or `home`.
            self.manual_line = None;
            self.go_safe(Occasion::Error);
        }
    }

    fn handle_timeout(&mut self, now: Duration) {
        if let Some((l, until)) = self.manual_line {
            if until <= now {
                self.manual_line = None;
                self.write(Button::Line(l), false);
            }
        }
        if let Some(cause) = self.actuator_fault() {
            self.fault = Some(cause);
        }
    }

    fn halt(&mut self) {
        self.watch = None;
        self.go_safe(Occasion::Error);
    }

    fn lost(&mut self) {
        // The commander is gone: this node cannot know whether the robot
        // still welds (its workstation may not have heard yet, or may be
        // cut off too). Every output to its safe state: the lines stop, a
        // clamp holds until a command after the robot's stop releases it.
        self.go_safe(Occasion::Loss);
    }

    fn finished(&mut self, outcome: &Outcome) {
        self.watch = None;
        self.pace(false);
        if *outcome != Outcome::Done {
            self.go_safe(Occasion::Error);
        }
        self.last_line = None;
    }
}

impl Device for Plc {
    fn handle(&mut self, now: Duration, what: Happening<'_>, out: &mut Vec<Event>) {
        self.clock = now;
        match what {
            Happening::Act(action) => self.act(now, action, out),
            Happening::Mode(mode) => self.mode_changed(mode),
            Happening::Clock => self.handle_timeout(now),
            Happening::Halt => self.halt(),
            Happening::Lost(_) => self.lost(),
            Happening::Finished(outcome) => self.finished(outcome),
            Happening::Associated => {}
        }
    }

    fn unavailable(&self) -> Option<String> {
        if let Some(why) = &self.down {
            return Some(why.clone());
        }
        let Some(i) = &self.inputs else {
            return Some(format!(
                "no reading from the conveyor PLC at {} yet",
                self.address
            ));
        };
        if i.get(Input::EStop) {
            return Some(format!(
                "emergency stop on the conveyor PLC at {}",
                self.address
            ));
        }
        if !i.get(Input::Ready) {
            return Some(format!("the conveyor PLC at {} is not ready", self.address));
        }
        None
    }

    fn poll_report(&mut self) -> Option<(Severity, String)> {
        self.reports.pop_front()
    }

    fn check_program(&self, program: &Program) -> Vec<Problem> {
        self.equipment.check_program(program)
    }

    fn manual(&mut self, now: Duration, action: &ManualAction) -> Result<String, String> {
        self.clock = now;
        if let Some(why) = self.unavailable() {
            return Err(why);
        }
        match action {
            ManualAction::Press(b) | ManualAction::Release(b) => {
                let button: Button = b.parse()?;
                self.equipment.lacks_button(button).map_or(Ok(()), Err)?;
                let press = matches!(action, ManualAction::Press(_));
                self.write(button, press);
                if press {
                    Ok(format!("{button} pressed"))
                } else {
                    if self
                        .manual_line
                        .is_some_and(|(l, _)| button == Button::Line(l))
                    {
                        self.manual_line = None;
                    }
                    Ok(format!("{button} released"))
                }
            }
            ManualAction::RunLine { line, seconds } => {
                let Ok(Button::Line(l)) = line.parse::<Button>() else {
                    return Err(format!("`{line}` is not a conveyor line (a letter)"));
                };
                self.equipment
                    .lacks_button(Button::Line(l))
                    .map_or(Ok(()), Err)?;
                if !(1..=600).contains(seconds) {
                    return Err(format!("{seconds} s: a line runs by hand for 1–600 s"));
                }
                if let Some((other, _)) = self.manual_line {
                    if other != l {
                        self.write(Button::Line(other), false);
                    }
                }
                self.write(Button::Line(l), true);
                self.manual_line = Some((l, now + Duration::from_secs(u64::from(*seconds))));
                Ok(format!("line {l} runs for {seconds} s"))
            }
            other => Err(format!("a transport station cannot {other}")),
        }
    }

    fn poll_timeout(&self) -> Option<Duration> {
        let line = self.manual_line.map(|(_, until)| until);
        let feedback = self
            .unavailable()
            .is_none()
            .then(|| self.actuators.poll_timeout())
            .flatten();
        match (line, feedback) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    fn poll_fault(&mut self) -> Option<Cause> {
        self.fault.take()
    }

    fn settling(&self) -> bool {
        // Dropped commands count as carried out; a link that is down never
        // holds a job back (its fault is the alarm).
        self.down.is_none() && self.inputs_after < self.issued
    }

    fn explain_timeout(&self, now: Duration) -> Option<String> {
        let w = self.watch?;
        let Some(i) = &self.inputs else {
            return Some(format!(
                "{} not seen: no reading from the conveyor PLC",
                SignalName(w.signal)
            ));
        };
        let line = self.last_line.map(|l| (l, i.signal(Signal::Line(l))));
        let what = match (w.signal, w.level) {
            (Signal::Place(p), true) => match line {
                Some((l, true)) => format!(
                    "place {p} still empty, line {l} still running: carrier jammed on line {l}?"
                ),
                Some((l, false)) => format!(
                    "place {p} still empty though line {l} stopped: sensor of place {p} faulty, or the carrier did not arrive"
                ),
                None => format!("place {p} still empty"),
            },
            (Signal::Place(p), false) => match line {
                Some((l, true)) => format!(
                    "place {p} still occupied, line {l} running: carrier jammed leaving place {p}?"
                ),
                _ => format!(
                    "place {p} still occupied with no line running: sensor of place {p} stuck, or the carrier did not leave"
                ),
            },
            (Signal::Line(l), true) => format!(
                "line {l} did not start (button line {l} {}): does the PLC have external control?",
                on_off(self.pressed.contains(&Button::Line(l)))
            ),
            (Signal::Line(l), false) => format!(
                "line {l} still running: carrier jammed on line {l}, or its end place full?"
            ),
            (Signal::Input(n), v) => format!(
                "input {n} still {}: does the equipment give it? (its wiring, its sensor)",
                if v { "off" } else { "on" }
            ),
            (Signal::Station(n), v) => format!(
                "station {n} still {} (button station {n} {})",
                if v { "not busy" } else { "busy" },
                on_off(self.pressed.contains(&Button::Station(n)))
            ),
        };
        Some(format!(
            "waited {:.1} s for {} = {}: {what}",
            now.saturating_sub(w.since).as_secs_f64(),
            SignalName(w.signal),
            u8::from(w.level)
        ))
    }

    fn status(&self, status: &mut VmdStatus) {
        status.physical = if self.unavailable().is_some() {
            PhysicalStatus::Inoperable
        } else {
            PhysicalStatus::Operational
        };
        status.inputs = self
            .inputs
            .as_ref()
            .map(|i| i.bits().to_vec())
            .unwrap_or_default();
        status.equipment_state = self
            .inputs
            .as_ref()
            .filter(|_| !self.equipment.states().is_empty())
            .map(|i| {
                self.equipment
                    .state_shown(|s| i.get(s))
                    .map_or_else(|| NO_NAMED_STATE.to_string(), |s| s.name.clone())
            });
    }

    /// A reading older than the busy poll period, or taken before a
    /// command, may miss what changed since (carriers set by hand at the
    /// idle pace): ask one now.
    fn ask_fresh_reading(&mut self, now: Duration) -> bool {
        if self.live().is_err() {
            return false;
        }
        let recent = self
            .read_at
            .is_some_and(|t| now.saturating_sub(t) <= self.busy_poll);
        if recent && self.inputs_after >= self.issued {
            return false;
        }
        self.send(PlcCommand::Read);
        self.fresh_from = Some(self.issued);
        true
    }

    /// The reading asked for came, or none can (the link is down).
    fn has_fresh_reading(&self) -> bool {
        self.down.is_some() || self.fresh_from.map_or(true, |n| self.inputs_after >= n)
    }

    fn observes(&self, fact: Fact) -> Option<bool> {
        let Fact::Signal(signal) = fact else {
            return None;
        };
        let inputs = self.live().ok()?;
        self.equipment
            .has_signal(signal)
            .then(|| inputs.signal(signal))
    }

    fn way_to(&self, state: &str) -> Result<(String, String), String> {
        let inputs = self.live()?;
        let way = self.equipment.way_to(state, |i| inputs.get(i))?;
        Ok((way.recipe(&self.equipment), way.to_string()))
    }
}

impl Linked for Plc {
    type Command = PlcCommand;
    type LinkEvent = PlcEvent;

    fn next_command(&mut self) -> Option<PlcCommand> {
        self.poll_command()
    }

    fn stop(&mut self) {
        self.shutdown();
    }

    /// A connection adopts or corrects the coils; a reading goes to the
    /// running recipe (`plc-ready` when the PLC became usable with it); a
    /// fault is a communication alarm.
    fn take_link_event(ctl: &mut Controller<Self>, now: Duration, ev: PlcEvent) -> Option<String> {
        match ev {
            PlcEvent::Connected { coils } => {
                ctl.device.connected(coils);
                Some(format!("plc-connected address={}", ctl.device.address))
            }
            PlcEvent::Inputs {
                inputs,
                commands_done,
            } => {
                ctl.device.clock = now;
                ctl.device.read_at = Some(now);
                let reading = ctl.device.reading(inputs, commands_done);
                ctl.take_reading(now, reading)
                    .then(|| "plc-ready".to_string())
            }
            PlcEvent::Fault(why) => {
                ctl.device.link_down(&why);
                ctl.fault(Cause::new(AlarmClass::Communication, why));
                None
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_equipment::file::FaultClass;
    use falc_model::ids::{Place, PlcStation};
    fn plc() -> Plc {
        Plc::new("plc:502".into(), Equipment::conveyor_1992())
    }

    fn ready() -> Inputs {
        let mut i = Inputs::new(&Equipment::conveyor_1992());
        i.set(Input::Ready, true);
        i
    }

    fn drain(p: &mut Plc) -> Vec<PlcCommand> {
        std::iter::from_fn(|| p.poll_command()).collect()
    }

    fn act(p: &mut Plc, now: u64, a: Action) -> Vec<Event> {
        let mut out = Vec::new();
        p.handle(Duration::from_secs(now), Happening::Act(a), &mut out);
        out
    }

    /// A Start of a recipe with a `#PRE` is held until a reading taken
    /// after it came (a carrier set by hand just before is seen), then
    /// answered; right after a job's end the last reading is fresh and it
    /// is answered at once; a reading that never comes holds it at most
    /// [`FRESH_READING_LIMIT`].
    #[test]
    fn a_precondition_is_evaluated_on_a_reading_taken_after_the_start() {
        use falc_control::workstation_node::{
            WorkstationAction, WorkstationNode, FRESH_READING_LIMIT,
        };
        use falc_model::ids::{ObjectName, StationName};
        use falc_model::mms::delivery::{Delivery, DeliveryStep};
        use falc_model::mms::pdu::{Request, Response};
        use falc_recipe::commands::RecipeKind;
        let ms = Duration::from_millis;
        let mut node: WorkstationNode<Plc, u32> = WorkstationNode::new(
            StationName::new("transport").expect("name"),
            RecipeKind::Transport,
            Duration::from_secs(5),
            plc(),
            false,
        );
        let name = ObjectName::new("park").expect("name");
        let text = "#PARK\n#PRE place 2 occupied\n-1 | activate k | | | 2\n-2 | reset k | | | 0\n";
        let mut d = Delivery::new(
            StationName::new("cell").expect("name"),
            name.clone(),
            text.as_bytes(),
            true,
        );
        let mut step = d.start();
        let mut ticket = 0;
        while let DeliveryStep::Send(req) = step {
            ticket += 1;
            node.handle_indication(Duration::ZERO, ticket, &req);
            let answer = std::iter::from_fn(|| node.poll(Duration::ZERO)).find_map(|a| match a {
                WorkstationAction::Answer { result, .. } => Some(result),
                _ => None,
            });
            step = d.answered(answer.expect("answered"));
        }
        assert_eq!(step, DeliveryStep::Done(Ok(())));
        node.handle_link(ms(0), PlcEvent::Connected { coils: None });
        let settle = |node: &mut WorkstationNode<Plc, u32>, now| {
            let mut answers = Vec::new();
            let mut reads = 0;
            while let Some(a) = node.poll(now) {
                match a {
                    WorkstationAction::Answer { result, .. } => answers.push(result),
                    WorkstationAction::Command(PlcCommand::Read) => reads += 1,
                    _ => {}
                }
            }
            (answers, reads)
        };
        let reading = |place2: bool| {
            let mut i = ready();
            i.set(Input::Signal(Signal::Place(Place::of(2))), place2);
            i
        };
        node.handle_link(
            ms(0),
            PlcEvent::Inputs {
                inputs: reading(false),
                commands_done: 0,
            },
        );
        settle(&mut node, ms(0));
        let start = Request::Start {
            name: name.clone(),
            argument: "order 1".into(),
        };
        // The carrier set on W2 at 900 ms, the Start at 1 s: held, a read
        // asked.
        node.handle_indication(ms(1000), 1, &start);
        let (answers, reads) = settle(&mut node, ms(1000));
        assert!(answers.is_empty(), "{answers:?}");
        assert_eq!(reads, 1);
        let mut done = node.controller().device.issued();
        node.handle_link(
            ms(1005),
            PlcEvent::Inputs {
                inputs: reading(true),
                commands_done: done,
            },
        );
        let (answers, _) = settle(&mut node, ms(1005));
        assert!(
            matches!(
                answers.as_slice(),
                [Ok(Response::ProgramInvocationState(_))]
            ),
            "{answers:?}"
        );
        // The job: K pressed, released; the reading after the writes ends it.
        done = node.controller().device.issued();
        node.handle_link(
            ms(1020),
            PlcEvent::Inputs {
                inputs: reading(true),
                commands_done: done,
            },
        );
        settle(&mut node, ms(1020));
        assert!(!node.controller().is_running());
        // Right after, the last reading is fresh: answered at once.
        node.handle_indication(ms(1025), 2, &start);
        let (answers, reads) = settle(&mut node, ms(1025));
        assert_eq!((answers.len(), reads), (1, 0), "{answers:?}");
        done = node.controller().device.issued();
        node.handle_link(
            ms(1040),
            PlcEvent::Inputs {
                inputs: reading(false),
                commands_done: done,
            },
        );
        settle(&mut node, ms(1040));
        // A read that never comes: the Start waits its limit, then is
        // evaluated on what there is (W2 empty now): refused.
        node.handle_indication(ms(5000), 3, &start);
        assert_eq!(settle(&mut node, ms(5000)).0.len(), 0);
        assert_eq!(node.poll_timeout(), Some(ms(5000) + FRESH_READING_LIMIT));
        node.handle_timeout(ms(5000) + FRESH_READING_LIMIT);
        let (answers, _) = settle(&mut node, ms(5000) + FRESH_READING_LIMIT);
        assert!(
            matches!(answers.as_slice(), [Err(e)] if e.description == "precondition of PARK: place 2 occupied is false"),
            "{answers:?}"
        );
    }

    #[test]
    fn a_running_lamp_that_does_not_follow_its_button_is_a_fault_on_the_clock() {
        let mut p = plc();
        p.connected(None);
        p.reading(ready(), 0);
        drain(&mut p);
        act(&mut p, 10, Action::Activate(Button::Line('K')));
        p.clock = Duration::from_millis(10_010);
        p.reading(ready(), p.issued());
        assert_eq!(p.poll_timeout(), Some(Duration::from_secs(11)));
        let mut out = Vec::new();
        p.handle(Duration::from_millis(10_999), Happening::Clock, &mut out);
        assert_eq!(p.poll_fault(), None);
        p.handle(Duration::from_secs(11), Happening::Clock, &mut out);
        let fault = p.poll_fault().expect("the lamp did not follow");
        assert_eq!(fault.class, AlarmClass::Device);
        assert!(
            fault.text.starts_with(
                "feedback: `line K running` not on 1000 ms after `button line K` was pressed"
            ),
            "{}",
            fault.text
        );
    }

    #[test]
    fn a_line_run_and_a_carrier_arriving_are_reported_once_not_every_poll() {
        let mut p = plc();
        p.reading(ready(), 0);
        act(&mut p, 0, Action::Activate(Button::Line('K')));
        let mut at_w3 = ready();
        at_w3.set(Input::Signal(Signal::Place(Place::of(3))), true);
        for n in 1..=5 {
            p.reading(at_w3.clone(), n);
        }
        let reports: Vec<(Severity, String)> = std::iter::from_fn(|| p.poll_report()).collect();
        assert_eq!(
            reports,
            vec![
                (Severity::Info, "line K runs".to_string()),
                (Severity::Info, "carrier arrived at W3".to_string()),
            ]
        );
        // A restarted node's first reading finds carriers standing: no
        // arrival.
        let mut fresh = plc();
        fresh.reading(at_w3, 0);
        assert_eq!(fresh.poll_report(), None);
    }

    #[test]
    fn a_maintainer_presses_buttons_and_runs_a_line_for_a_while() {
        let mut p = plc();
        let press = |b: &str| ManualAction::Press(b.into());
        assert!(
            p.manual(Duration::ZERO, &press("A")).is_err(),
            "not connected"
        );
        p.connected(None);
        p.inputs(ready(), 1);
        drain(&mut p);
        assert_eq!(
            p.manual(Duration::ZERO, &press("3")).as_deref(),
            Ok("station button 3 pressed")
        );
        let e = p.manual(Duration::ZERO, &press("I")).unwrap_err();
        assert!(e.contains("`I` is not a conveyor line"), "{e}");
        let run = |line: &str, seconds| ManualAction::RunLine {
            line: line.into(),
            seconds,
        };
        assert!(p.manual(Duration::ZERO, &run("B", 0)).is_err());
        assert!(p.manual(Duration::ZERO, &run("3", 5)).is_err());
        assert!(p
            .manual(Duration::ZERO, &ManualAction::StartProgram)
            .unwrap_err()
            .contains("transport station cannot"));
        assert_eq!(
            p.manual(Duration::from_secs(1), &run("b", 5)).as_deref(),
            Ok("line B runs for 5 s")
        );
        // Line B's lamp is due first (the file's 1 s after the press);
        // once a reading shows it and station 3 busy, the line's end.
        assert_eq!(p.poll_timeout(), Some(Duration::from_secs(2)));
        let mut lit = ready();
        lit.set(Input::Signal(Signal::Line('B')), true);
        lit.set(Input::Signal(Signal::Station(PlcStation::of(3))), true);
        p.clock = Duration::from_secs(1);
        p.reading(lit, p.issued());
        assert_eq!(p.poll_timeout(), Some(Duration::from_secs(6)));
        let line_b = Coil::Button(Button::Line('B'));
        let station_3 = Coil::Button(Button::Station(PlcStation::of(3)));
        assert_eq!(
            drain(&mut p),
            vec![
                PlcCommand::Write(station_3, true),
                PlcCommand::Write(line_b, true)
            ]
        );
        p.handle(Duration::from_secs(6), Happening::Clock, &mut Vec::new());
        assert_eq!(drain(&mut p), vec![PlcCommand::Write(line_b, false)]);
        assert_eq!(p.poll_timeout(), None);
        // Leaving maintenance stops a line a maintainer left pressed; a
        // clamp holds (its safe state) until a command releases it.
        assert!(p.manual(Duration::from_secs(7), &press("K")).is_ok());
        drain(&mut p);
        p.handle(
            Duration::ZERO,
            Happening::Mode(CellMode::Auto),
            &mut Vec::new(),
        );
        let line_k = Coil::Button(Button::Line('K'));
        assert_eq!(drain(&mut p), vec![PlcCommand::Write(line_k, false)]);
    }

    #[test]
    fn unavailable_until_connected_and_read_and_while_estop() {
        let mut p = plc();
        assert!(p.unavailable().is_some());
        p.connected(None);
        let all = holding(&[Coil::ExternalControl]);
        assert_eq!(
            drain(&mut p),
            vec![PlcCommand::WriteAll(all)],
            "buttons off, external control on"
        );
        assert_eq!(
            p.unavailable().as_deref(),
            Some("no reading from the conveyor PLC at plc:502 yet")
        );
        assert_eq!(p.inputs(ready(), 1), (vec![], None));
        assert_eq!(p.unavailable(), None);
        let mut stop = ready();
        stop.set(Input::EStop, true);
        stop.set(Input::Ready, false);
        let (_, alarm) = p.inputs(stop.clone(), 1);
        assert_eq!(
            alarm,
            Some(Cause::new(
                AlarmClass::Safety,
                "emergency stop on the conveyor PLC at plc:502"
            ))
        );
        assert!(p
            .unavailable()
            .is_some_and(|w| w.contains("emergency stop")));
        // Still stopped: no second alarm.
        assert_eq!(p.inputs(stop, 1).1, None);
        p.link_down("gone");
        assert_eq!(p.unavailable().as_deref(), Some("gone"));
    }

    #[test]
    fn a_watch_only_counts_readings_taken_after_its_own_writes() {
        let mut p = plc();
        p.connected(None);
        p.inputs(ready(), 1);
        assert!(act(&mut p, 0, Action::Activate(Button::Line('D'))).is_empty());
        let mut running = ready();
        running.set(Input::Signal(Signal::Line('D')), true);
        // Wait for D to stop: the last reading (before the press) shows it
        // stopped, but it was read before the write: no event yet.
        let watch = Action::Watch {
            signal: Signal::Line('D'),
            level: false,
        };
        assert!(act(&mut p, 0, watch).is_empty());
        // A reading from before the press arrives late: still not enough.
        assert_eq!(p.inputs(ready(), 1).0, vec![]);
        // After the press, D runs; then it stops.
        assert_eq!(p.inputs(running, 2).0, vec![]);
        assert_eq!(p.inputs(ready(), 2).0, vec![Event::InputReached]);
        assert_eq!(
            drain(&mut p).last(),
            Some(&PlcCommand::Write(Coil::Button(Button::Line('D')), true))
        );
    }

    #[test]
    fn a_met_watch_fires_at_once() {
        let mut p = plc();
        p.connected(None);
        let mut i = ready();
        i.set(Input::Signal(Signal::Place(Place::of(3))), true);
        p.inputs(i, 1);
        let watch = Action::Watch {
            signal: Signal::Place(Place::of(3)),
            level: true,
        };
        assert_eq!(act(&mut p, 0, watch), vec![Event::InputReached]);
    }

    /// A workstation whose recipe clamped station 3 and runs line E.
    fn clamped_and_moving() -> Plc {
        let mut p = plc();
        p.connected(None);
        p.inputs(ready(), 1);
        act(
            &mut p,
            0,
            Action::Activate(Button::Station(PlcStation::of(3))),
        );
        act(&mut p, 0, Action::Activate(Button::Line('E')));
        drain(&mut p);
        p
    }

    #[test]
    fn an_alarm_releases_line_buttons_but_not_station_buttons() {
        let mut p = clamped_and_moving();
        p.handle(
            Duration::ZERO,
            Happening::Finished(&Outcome::Alarm(Cause::process("x"))),
            &mut Vec::new(),
        );
        assert_eq!(
            drain(&mut p),
            vec![
                PlcCommand::Pace(Pace::Idle),
                PlcCommand::Write(Coil::Button(Button::Line('E')), false)
            ]
        );
        // Done leaves everything as the recipe left it.
        act(&mut p, 0, Action::Activate(Button::Line('K')));
        assert_eq!(
            drain(&mut p),
            vec![
                PlcCommand::Pace(Pace::Busy),
                PlcCommand::Write(Coil::Button(Button::Line('K')), true)
            ],
            "a running recipe polls at the busy period"
        );
        // Done is reported only once the PLC has the writes.
        assert!(p.settling(), "the write of K is in flight");
        p.inputs(ready(), p.issued());
        assert!(!p.settling());
        p.handle(
            Duration::ZERO,
            Happening::Finished(&Outcome::Done),
            &mut Vec::new(),
        );
        assert_eq!(drain(&mut p), vec![PlcCommand::Pace(Pace::Idle)]);
        // The commander lost: every output to its safe state, the line
        // stops and the clamp on station 3 holds (the robot may still weld).
        let cell = falc_model::ids::StationName::new("cell").expect("valid");
        p.handle(Duration::ZERO, Happening::Lost(&cell), &mut Vec::new());
        assert_eq!(
            drain(&mut p),
            vec![PlcCommand::Write(Coil::Button(Button::Line('K')), false)]
        );
        assert!(p.pressed.contains(&Button::Station(PlcStation::of(3))));
    }

    #[test]
    fn the_node_stopping_stops_the_lines_and_holds_the_clamp_and_external_control() {
        let mut p = clamped_and_moving();
        p.shutdown();
        let want = holding(&[
            Coil::Button(Button::Station(PlcStation::of(3))),
            Coil::ExternalControl,
        ]);
        assert_eq!(drain(&mut p), vec![PlcCommand::WriteAll(want)]);
        // Each output's safe state is the equipment file's.
        let e = Equipment::conveyor_1992();
        assert_eq!(
            e.safe(Coil::Button(Button::Line('A')), Occasion::Stop),
            SafeState::Off
        );
        assert_eq!(
            e.safe(
                Coil::Button(Button::Station(PlcStation::of(1))),
                Occasion::Stop
            ),
            SafeState::Hold
        );
    }

    #[test]
    fn activate_of_a_held_button_gives_a_rising_edge() {
        let mut p = plc();
        p.connected(None);
        p.inputs(ready(), 1);
        act(
            &mut p,
            0,
            Action::Activate(Button::Station(PlcStation::of(3))),
        );
        // An alarm keeps the station button; the next job presses it again.
        p.handle(
            Duration::ZERO,
            Happening::Finished(&Outcome::Alarm(Cause::new(AlarmClass::Safety, "estop"))),
            &mut Vec::new(),
        );
        drain(&mut p);
        act(
            &mut p,
            0,
            Action::Activate(Button::Station(PlcStation::of(3))),
        );
        assert_eq!(
            drain(&mut p),
            vec![
                PlcCommand::Pace(Pace::Busy),
                PlcCommand::Write(Coil::Button(Button::Station(PlcStation::of(3))), false),
                PlcCommand::Write(Coil::Button(Button::Station(PlcStation::of(3))), true),
            ]
        );
        // A watch after it waits for both writes.
        assert!(p.settling());
        p.inputs(ready(), p.issued() - 1);
        assert!(p.settling(), "the press itself is not carried out yet");
    }

    #[test]
    fn timeouts_are_explained_from_the_inputs() {
        let mut p = plc();
        p.connected(None);
        p.inputs(ready(), 1);
        act(&mut p, 10, Action::Activate(Button::Line('E')));
        let watch = Action::Watch {
            signal: Signal::Place(Place::of(5)),
            level: true,
        };
        act(&mut p, 10, watch);
        let mut jam = ready();
        jam.set(Input::Signal(Signal::Line('E')), true);
        p.inputs(jam, 2);
        assert_eq!(
            p.explain_timeout(Duration::from_secs(70)).as_deref(),
            Some("waited 60.0 s for place 5 occupied = 1: place 5 still empty, line E still running: carrier jammed on line E?")
        );
        p.inputs(ready(), 2);
        let text = p
            .explain_timeout(Duration::from_secs(70))
            .unwrap_or_default();
        assert!(
            text.contains("though line E stopped: sensor of place 5 faulty"),
            "{text}"
        );
        act(&mut p, 70, Action::Unwatch);
        assert_eq!(p.explain_timeout(Duration::from_secs(70)), None);
    }

    /// The coils as a PLC holding `on` reads them back.
    fn holding(on: &[Coil]) -> Coils {
        Equipment::conveyor_1992()
            .coils()
            .iter()
            .map(|c| (c.coil, on.contains(&c.coil)))
            .collect()
    }

    #[test]
    fn a_restarted_workstation_releases_a_line_it_finds_running() {
        let mut p = plc();
        let station_3 = Coil::Button(Button::Station(PlcStation::of(3)));
        let line_l = Coil::Button(Button::Line('L'));
        // Killed mid-move: the PLC still runs line L and clamps station 3.
        p.connected(Some(holding(&[station_3, line_l, Coil::ExternalControl])));
        assert_eq!(drain(&mut p), vec![PlcCommand::Write(line_l, false)]);
        assert!(p.pressed.contains(&Button::Station(PlcStation::of(3))));
        assert!(!p.pressed.contains(&Button::Line('L')));
    }

    #[test]
    fn a_restarted_workstation_adopts_the_coils_and_a_reconnected_one_restores_its_own() {
        let mut p = plc();
        let station_3 = Coil::Button(Button::Station(PlcStation::of(3)));
        let line_e = Coil::Button(Button::Line('E'));
        // A restart mid-weld: the PLC holds station 3 and external control.
        let held = holding(&[station_3, Coil::ExternalControl]);
        p.connected(Some(held));
        assert_eq!(
            drain(&mut p),
            vec![],
            "nothing written: the workpiece stays clamped"
        );
        assert!(p.pressed.contains(&Button::Station(PlcStation::of(3))));
        // A fresh PLC (external control off): only that is written.
        let mut q = plc();
        q.connected(Some(holding(&[])));
        assert_eq!(
            drain(&mut q),
            vec![PlcCommand::Write(Coil::ExternalControl, true)]
        );
        // The link comes back later: the node's own state stands, and only
        // what the PLC holds otherwise is written.
        let back = holding(&[line_e, Coil::ExternalControl]);
        p.connected(Some(back));
        let mut written = drain(&mut p);
        written.sort_by_key(|c| format!("{c:?}"));
        assert_eq!(
            written,
            vec![
                PlcCommand::Write(line_e, false),
                PlcCommand::Write(station_3, true)
            ]
        );
    }

    /// The readings of a job: `lit` places occupied, `running` lines.
    fn showing(lit: &[u8], running: &[char]) -> Inputs {
        let mut i = ready();
        for p in lit {
            i.set(Input::Signal(Signal::Place(Place::of(*p))), true);
        }
        for l in running {
            i.set(Input::Signal(Signal::Line(*l)), true);
        }
        i
    }

    #[test]
    fn feedback_nothing_asked_for_and_feedback_lost_while_a_job_runs_are_alarms_naming_the_sensor()
    {
        // Place 2's sensor fault a warning, as its file says.
        let text = include_str!("../../../equipment/conveyor-1992.toml").replacen(
            "name = \"2\"\ncapacity = 2        # the start place: both carriers wait here\nsensor_fault = \"alarm\"",
            "name = \"2\"\ncapacity = 2\nsensor_fault = \"warning\"",
            1,
        );
        let e = Equipment::parse(&text, "w2-warning.toml").expect("loads");
        assert_eq!(
            e.place(Place::of(2)).map(|p| p.sensor_fault),
            Some(FaultClass::Warning)
        );
        let mut p = Plc::new("plc:502".into(), Arc::new(e));
        p.connected(None);
        // Between jobs a carrier set by hand is no fault.
        p.inputs(showing(&[2], &[]), 1);
        assert_eq!(p.inputs(showing(&[2, 4], &[]), 1).1, None);
        assert_eq!(p.inputs(showing(&[2], &[]), 1).1, None);
        // A job runs line K (W2 → W3): W3 lighting is asked for.
        act(&mut p, 0, Action::Activate(Button::Line('K')));
        assert_eq!(p.inputs(showing(&[2], &['K']), 2).1, None);
        assert_eq!(p.inputs(showing(&[2, 3], &[]), 2).1, None);
        // W6 lights: no line runs towards it (A, B, C).
        let (_, alarm) = p.inputs(showing(&[2, 3, 6], &[]), 2);
        let alarm = alarm.expect("unrequested feedback");
        assert_eq!(alarm.class, AlarmClass::Device);
        assert!(
            alarm.text.starts_with(
                "unrequested feedback: sensor `place 6 occupied` (W6) lit while no line runs towards W6"
            ),
            "{alarm:?}"
        );
        // W3 goes dark while line E (W2 → W5) runs: lost.
        let (_, alarm) = p.inputs(showing(&[2, 6], &['E']), 2);
        let alarm = alarm.expect("lost feedback");
        assert!(
            alarm.text.starts_with(
                "lost feedback: sensor `place 3 occupied` (W3) went dark while nothing moves its carrier"
            ),
            "{alarm:?}"
        );
        // W2 dark as line E (W2 → W5) took its carrier: asked for.
        assert_eq!(p.inputs(showing(&[6], &[]), 2).1, None);
        // W2 lighting with no line towards it (A, D): its sensor is set to
        // need no acknowledgement here, so it only warns.
        let (_, alarm) = p.inputs(showing(&[2, 6], &[]), 2);
        assert_eq!(alarm.map(|a| a.class), Some(AlarmClass::Warning));
    }

    #[test]
    fn a_station_taking_its_carrier_and_a_line_taking_it_away_are_asked_for() {
        let mut p = plc();
        p.connected(None);
        p.inputs(showing(&[3, 5], &[]), 1);
        // Station 3 (fed from W5) takes the carrier at W5.
        act(
            &mut p,
            0,
            Action::Activate(Button::Station(PlcStation::of(3))),
        );
        assert_eq!(p.inputs(showing(&[3, 5], &[]), 2).1, None);
        assert_eq!(p.inputs(showing(&[3], &[]), 2).1, None);
        // Line L (W3 → W4) takes W3's carrier away and brings it to W4.
        act(&mut p, 0, Action::Activate(Button::Line('L')));
        assert_eq!(p.inputs(showing(&[], &['L']), 3).1, None);
        assert_eq!(p.inputs(showing(&[4], &[]), 3).1, None);
        // Once the job ended, nothing is supervised.
        p.handle(
            Duration::ZERO,
            Happening::Finished(&Outcome::Done),
            &mut Vec::new(),
        );
        assert_eq!(p.inputs(showing(&[2, 4], &[]), 3).1, None);
    }

    #[test]
    fn carriers_set_by_hand_just_before_a_start_are_the_jobs_starting_point() {
        let mut p = plc();
        p.connected(None);
        p.inputs(showing(&[3, 6], &[]), 1);
        // Set home by hand (W2), then the job starts at once: the idle
        // pace's next reading comes after the start, yet before the job's
        // first write took effect. It is the job's starting point.
        act(&mut p, 0, Action::Activate(Button::Line('K')));
        assert_eq!(p.inputs(showing(&[2], &[]), 1).1, None);
        assert_eq!(p.inputs(showing(&[2], &['K']), 2).1, None);
        // From then on each change needs a cause.
        let (_, alarm) = p.inputs(showing(&[2, 6], &['K']), 2);
        assert!(alarm.is_some_and(|a| a.text.contains("(W6)")));
    }
}
