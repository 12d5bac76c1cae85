//! The robot controller's behaviour, sans-I/O: modes, the program table
//! and the programs delivered to it over DNC (stored, listed, uploaded,
//! run step by step with each step's time from its text), the running
//! program on an injected clock, and the faults a test or a person
//! injects. Telegrams in, telegrams out; what it does for a person
//! watching it ([`Robot::poll_note`]).

use crate::telegram::{AckError, EndResult, Mode, ProgramState, Telegram};
use falc_model::ids::RobotProgram;
use falc_recipe::robot_program::{text_hash, ProgramText};
use std::collections::BTreeMap;
use std::collections::VecDeque;
use std::time::Duration;

/// A fault or event injected through the control interface.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Control {
    /// Emergency stop pressed: the program stops, alarm 24.
    EStop,
    /// Emergency stop released.
    EStopClear,
    /// A person enters the work area: motion pauses (alarm 30).
    PersonIn,
    /// … and leaves: motion resumes (31).
    PersonOut,
    /// A hardware limit switch is hit: the program stops (40).
    LimitSwitch,
    /// The weld is aborted: the program ends with a bad product (50).
    AbortWeld,
    /// Any alarm code.
    Alarm(u16),
    /// Change mode.
    Mode(Mode),
    /// The next program end is never sent (as when all its 3964R attempts
    /// failed on a disturbed line): the host must learn it from the status.
    LoseEnd,
    /// The next acknowledgement of a select or a start is never sent (as
    /// when a spoilt answer passes the block check as another telegram):
    /// the host must learn from the status that the step was done.
    LoseAck,
}

#[derive(Debug, Clone)]
struct Run {
    program: RobotProgram,
    left: Duration,
    since: Option<Duration>,
    /// A delivered program's steps (label, scaled time); empty for one of
    /// the built-in table.
    steps: Vec<(String, Duration)>,
    /// Its whole time, scaled.
    total: Duration,
    /// The steps begun (and noted) so far.
    begun: usize,
}

impl Run {
    /// How far the program got at `now`.
    fn elapsed(&self, now: Duration) -> Duration {
        let ran = self.since.map_or(Duration::ZERO, |s| now.saturating_sub(s));
        self.total.saturating_sub(self.left.saturating_sub(ran))
    }

    /// When the next step begins (None when paused, or none is left).
    fn next_step_at(&self) -> Option<Duration> {
        let since = self.since?;
        if self.begun >= self.steps.len() {
            return None;
        }
        let offset: Duration = self.steps.iter().take(self.begun).map(|s| s.1).sum();
        let done_at_since = self.total.saturating_sub(self.left);
        Some(since + offset.saturating_sub(done_at_since))
    }
}

/// A program text being downloaded.
#[derive(Debug, Clone)]
struct Download {
    program: RobotProgram,
    lines: u16,
    hash: u32,
    got: Vec<String>,
}

/// The robot controller.
#[derive(Debug, Clone)]
pub struct Robot {
    mode: Mode,
    estop: bool,
    programs: BTreeMap<u16, Duration>,
    selected: Option<RobotProgram>,
    run: Option<Run>,
    /// The selected program was stopped before its end (stop, emergency
    /// stop, limit switch, aborted weld): reported as `stopped` until the
    /// next select or start.
    stopped: bool,
    lose_end: bool,
    lose_ack: bool,
    /// The time scale the program table and delivered programs run at.
    scale: f64,
    /// The programs delivered over DNC, by number: they replace the
    /// table's.
    delivered: BTreeMap<u16, ProgramText>,
    /// A download under way.
    download: Option<Download>,
    /// What it did, for a person watching it.
    notes: VecDeque<String>,
}

/// The program table: number → duration at time scale 1.
pub fn program_table() -> BTreeMap<u16, Duration> {
    BTreeMap::from([
        (10, Duration::from_secs(30)),  // reference run
        (64, Duration::from_secs(60)),  // DROOG_PIJP
        (65, Duration::from_secs(120)), // DROOG_DIK
        (66, Duration::from_secs(120)), // DROOG_DUN
    ])
}

impl Robot {
    /// A robot in `mode` with the program table scaled by `time_scale`.
    pub fn new(mode: Mode, time_scale: f64) -> Self {
        let scale = time_scale.max(1e-6);
        let programs = program_table()
            .into_iter()
            .map(|(n, d)| (n, d.div_f64(scale)))
            .collect();
        Self {
            mode,
            estop: false,
            programs,
            selected: None,
            run: None,
            stopped: false,
            lose_end: false,
            lose_ack: false,
            scale,
            delivered: BTreeMap::new(),
            download: None,
            notes: VecDeque::new(),
        }
    }

    /// What it did since last asked, for a person watching it: programs
    /// stored, each step of a delivered program as it begins.
    pub fn poll_note(&mut self) -> Option<String> {
        self.notes.pop_front()
    }

    /// The programs delivered to it: number, lines, text hash.
    pub fn delivered(&self) -> impl Iterator<Item = (RobotProgram, usize, u32)> + '_ {
        self.delivered
            .values()
            .map(|p| (p.number, p.lines().len(), p.hash()))
    }

    fn known(&self, n: u16) -> bool {
        self.delivered.contains_key(&n) || self.programs.contains_key(&n)
    }

    /// A download's telegram (`D`, `T`, `F`): the acknowledgement. A
    /// program that runs is never replaced.
    fn transfer(&mut self, t: Telegram) -> Option<AckError> {
        match t {
            Telegram::Text {
                program,
                lines,
                hash,
            } => {
                if self.running() == Some(program) {
                    self.download = None;
                    return Some(AckError::ProgramRunning);
                }
                self.download = Some(Download {
                    program,
                    lines,
                    hash,
                    got: Vec::new(),
                });
                None
            }
            Telegram::Line { no, text } => {
                let Some(d) = &mut self.download else {
                    return Some(AckError::NoDownload);
                };
                if usize::from(no) != d.got.len() + 1 || d.got.len() >= usize::from(d.lines) {
                    self.download = None;
                    return Some(AckError::TextRefused);
                }
                d.got.push(text);
                None
            }
            Telegram::TextEnd(program) => {
                let Some(d) = self.download.take() else {
                    return Some(AckError::NoDownload);
                };
                let text = d.got.join("\n");
                let complete = d.program == program
                    && d.got.len() == usize::from(d.lines)
                    && text_hash(&text) == d.hash;
                if !complete || self.running() == Some(program) {
                    self.notes.push_back(format!(
                        "program {} refused: {}",
                        program.number(),
                        if complete {
                            "it runs"
                        } else {
                            "its text is incomplete or its hash wrong"
                        }
                    ));
                    return Some(if complete {
                        AckError::ProgramRunning
                    } else {
                        AckError::TextRefused
                    });
                }
                match ProgramText::parse(&text, &format!("program {:03}", program.number())) {
                    Ok(p) if p.number == program => {
                        self.notes.push_back(format!(
                            "program {} stored: {} steps, {:.1} s, hash {:08X}",
                            program.number(),
                            p.steps.len(),
                            p.duration().as_secs_f64(),
                            p.hash()
                        ));
                        self.delivered.insert(program.number(), p);
                        None
                    }
                    Ok(p) => {
                        self.notes.push_back(format!(
                            "program {} refused: its text says program {}",
                            program.number(),
                            p.number.number()
                        ));
                        Some(AckError::TextRefused)
                    }
                    Err(problems) => {
                        self.notes.push_back(format!(
                            "program {} refused: {}",
                            program.number(),
                            problems.join("; ")
                        ));
                        Some(AckError::TextRefused)
                    }
                }
            }
            _ => Some(AckError::Malformed),
        }
    }

    /// Notes each step of the running program that began by `now`.
    fn note_steps(&mut self, now: Duration) {
        let Some(r) = &mut self.run else { return };
        let elapsed = r.elapsed(now);
        let mut start = Duration::ZERO;
        for (i, (label, time)) in r.steps.iter().enumerate() {
            if i >= r.begun && start <= elapsed {
                self.notes.push_back(format!(
                    "program {} step {}/{}: {label}",
                    r.program.number(),
                    i + 1,
                    r.steps.len()
                ));
                r.begun = i + 1;
            }
            start += *time;
        }
    }

    /// The program running (or paused) on the robot, if any.
    pub fn running(&self) -> Option<RobotProgram> {
        self.run.as_ref().map(|r| r.program)
    }

    /// Ends the running program before its end.
    fn cut(&mut self) -> Option<Run> {
        let r = self.run.take();
        self.stopped |= r.is_some();
        r
    }

    fn status(&self) -> Telegram {
        let (program, state) = match (&self.run, self.selected) {
            (Some(r), _) if r.since.is_none() => (Some(r.program), ProgramState::Paused),
            (Some(r), _) => (Some(r.program), ProgramState::Running),
            (None, Some(p)) if self.stopped => (Some(p), ProgramState::Stopped),
            (None, Some(p)) => (Some(p), ProgramState::Selected),
            (None, None) => (None, ProgramState::Idle),
        };
        Telegram::ProgramStatus {
            program,
            state,
            mode: self.mode,
        }
    }

    fn refuse(&self, code: u8) -> Option<AckError> {
        if self.mode != Mode::AutomaticExternal && code != b'Q' {
            Some(AckError::NotInDncMode)
        } else if self.estop && matches!(code, b'S' | b'G') {
            Some(AckError::EmergencyStop)
        } else {
            None
        }
    }

    /// A telegram from the host; the replies.
    pub fn handle(&mut self, now: Duration, t: Telegram) -> Vec<Telegram> {
        let code = t.encode().first().copied().unwrap_or(b'?');
        let ack = |error| Telegram::Ack { of: code, error };
        if let Some(e) = self.refuse(code) {
            return vec![ack(Some(e))];
        }
        match t {
            Telegram::InitiateDnc | Telegram::CloseDnc | Telegram::ConfirmAlarm(_) => {
                vec![ack(None)]
            }
            t @ (Telegram::Text { .. } | Telegram::Line { .. } | Telegram::TextEnd(_)) => {
                vec![ack(self.transfer(t))]
            }
            Telegram::Upload(p) => match self.delivered.get(&p.number()) {
                Some(text) => {
                    let lines = text.lines();
                    let mut out = vec![Telegram::Text {
                        program: p,
                        lines: u16::try_from(lines.len()).unwrap_or(u16::MAX),
                        hash: text.hash(),
                    }];
                    out.extend(lines.iter().zip(1u16..).map(|(l, no)| Telegram::Line {
                        no,
                        text: (*l).to_string(),
                    }));
                    out.push(Telegram::TextEnd(p));
                    out
                }
                None => vec![ack(Some(AckError::UnknownProgram))],
            },
            Telegram::List => {
                let mut out: Vec<Telegram> = self
                    .delivered()
                    .map(|(program, lines, hash)| Telegram::Stored {
                        program,
                        lines: u16::try_from(lines).unwrap_or(u16::MAX),
                        hash,
                    })
                    .collect();
                out.push(ack(None));
                out
            }
            Telegram::StatusRequest => vec![self.status()],
            Telegram::SelectProgram(p) => {
                if self.run.is_some() {
                    vec![ack(Some(AckError::ProgramRunning))]
                } else if !self.known(p.number()) {
                    vec![ack(Some(AckError::UnknownProgram))]
                } else {
                    self.selected = Some(p);
                    self.stopped = false;
                    self.acked(ack(None))
                }
            }
            Telegram::StartProgram => match (self.selected, &self.run) {
                (_, Some(_)) => vec![ack(Some(AckError::ProgramRunning))],
                (None, None) => vec![ack(Some(AckError::NoProgramSelected))],
                (Some(p), None) => {
                    self.stopped = false;
                    let (steps, total) = match self.delivered.get(&p.number()) {
                        Some(text) => {
                            let steps: Vec<(String, Duration)> = text
                                .steps
                                .iter()
                                .map(|s| (s.to_string(), s.time.div_f64(self.scale)))
                                .collect();
                            let total = steps.iter().map(|s| s.1).sum();
                            (steps, total)
                        }
                        None => (
                            Vec::new(),
                            self.programs.get(&p.number()).copied().unwrap_or_default(),
                        ),
                    };
                    self.run = Some(Run {
                        program: p,
                        left: total,
                        since: Some(now),
                        steps,
                        total,
                        begun: 0,
                    });
                    self.note_steps(now);
                    let mut out = self.acked(ack(None));
                    out.push(self.status());
                    out
                }
            },
            Telegram::StopProgram => match self.cut() {
                Some(_) => vec![
                    ack(None),
                    Telegram::ProgramStatus {
                        program: self.selected,
                        state: ProgramState::Stopped,
                        mode: self.mode,
                    },
                ],
                None => vec![ack(Some(AckError::NotRunning))],
            },
            // Telegrams only the RCM sends: not understood from the host.
            Telegram::Ack { .. }
            | Telegram::ProgramStatus { .. }
            | Telegram::ProgramEnd { .. }
            | Telegram::Stored { .. }
            | Telegram::Alarm(_) => {
                vec![ack(Some(AckError::Malformed))]
            }
        }
    }

    /// A select's or start's acknowledgement, unless it is to be lost.
    fn acked(&mut self, ack: Telegram) -> Vec<Telegram> {
        if std::mem::take(&mut self.lose_ack) {
            Vec::new()
        } else {
            vec![ack]
        }
    }

    /// When the running program's next step begins or it ends (None when
    /// paused or idle).
    pub fn poll_timeout(&self) -> Option<Duration> {
        let r = self.run.as_ref()?;
        let end = r.since.map(|s| s + r.left)?;
        Some(r.next_step_at().map_or(end, |t| t.min(end)))
    }

    /// The clock reached `now`: a step that is due begins, a program that
    /// is due ends.
    pub fn handle_timeout(&mut self, now: Duration) -> Vec<Telegram> {
        self.note_steps(now);
        let end = self.run.as_ref().and_then(|r| r.since.map(|s| s + r.left));
        if !end.is_some_and(|t| t <= now) {
            return Vec::new();
        }
        let Some(r) = self.run.take() else {
            return Vec::new();
        };
        if std::mem::take(&mut self.lose_end) {
            return Vec::new();
        }
        vec![Telegram::ProgramEnd {
            program: r.program,
            result: EndResult::Complete,
        }]
    }

    /// An injected fault or event; the telegrams it causes.
    pub fn control(&mut self, now: Duration, c: Control) -> Vec<Telegram> {
        match c {
            Control::EStop => {
                self.estop = true;
                self.cut();
                vec![Telegram::Alarm(24)]
            }
            Control::EStopClear => {
                // A real RCM reports its status when it leaves the stop.
                self.estop = false;
                vec![self.status()]
            }
            Control::PersonIn => {
                if let Some(r) = &mut self.run {
                    if let Some(s) = r.since.take() {
                        r.left = r.left.saturating_sub(now.saturating_sub(s));
                    }
                }
                vec![Telegram::Alarm(30)]
            }
            Control::PersonOut => {
                if let Some(r) = &mut self.run {
                    r.since.get_or_insert(now);
                }
                vec![Telegram::Alarm(31)]
            }
            Control::LimitSwitch => {
                self.cut();
                vec![Telegram::Alarm(40)]
            }
            Control::AbortWeld => match self.cut() {
                Some(r) => vec![
                    Telegram::Alarm(50),
                    Telegram::ProgramEnd {
                        program: r.program,
                        result: EndResult::WeldAborted,
                    },
                ],
                None => vec![Telegram::Alarm(50)],
            },
            Control::Alarm(code) => vec![Telegram::Alarm(code)],
            Control::Mode(m) => {
                self.mode = m;
                Vec::new()
            }
            Control::LoseEnd => {
                self.lose_end = true;
                Vec::new()
            }
            Control::LoseAck => {
                self.lose_ack = true;
                Vec::new()
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;

    fn secs(n: u64) -> Duration {
        Duration::from_secs(n)
    }

    fn p(n: u16) -> RobotProgram {
        RobotProgram::of(n)
    }

    #[test]
    fn select_start_end_scaled() {
        let mut r = Robot::new(Mode::AutomaticExternal, 10.0);
        assert_eq!(
            r.handle(secs(0), Telegram::SelectProgram(p(65))),
            vec![Telegram::Ack {
                of: b'S',
                error: None
            }]
        );
        let out = r.handle(secs(1), Telegram::StartProgram);
        assert_eq!(
            out[0],
            Telegram::Ack {
                of: b'G',
                error: None
            }
        );
        assert_eq!(r.poll_timeout(), Some(secs(13)), "120 s at time scale 10");
        assert_eq!(r.handle_timeout(secs(12)), vec![]);
        assert_eq!(
            r.handle_timeout(secs(13)),
            vec![Telegram::ProgramEnd {
                program: p(65),
                result: EndResult::Complete
            }]
        );
    }

    #[test]
    fn remote_commands_need_automatic_external_mode() {
        let mut r = Robot::new(Mode::Manual, 1.0);
        assert_eq!(
            r.handle(secs(0), Telegram::SelectProgram(p(65))),
            vec![Telegram::Ack {
                of: b'S',
                error: Some(AckError::NotInDncMode)
            }]
        );
        assert!(matches!(
            r.handle(secs(0), Telegram::StatusRequest).as_slice(),
            [Telegram::ProgramStatus {
                mode: Mode::Manual,
                ..
            }]
        ));
        assert_eq!(
            r.handle(secs(0), Telegram::SelectProgram(p(99))),
            vec![Telegram::Ack {
                of: b'S',
                error: Some(AckError::NotInDncMode)
            }]
        );
        r.control(secs(0), Control::Mode(Mode::AutomaticExternal));
        assert_eq!(
            r.handle(secs(0), Telegram::SelectProgram(p(99))),
            vec![Telegram::Ack {
                of: b'S',
                error: Some(AckError::UnknownProgram)
            }]
        );
        assert_eq!(
            r.handle(secs(0), Telegram::StartProgram),
            vec![Telegram::Ack {
                of: b'G',
                error: Some(AckError::NoProgramSelected)
            }]
        );
    }

    #[test]
    fn the_status_tells_a_stopped_program_from_a_complete_one() {
        let mut r = Robot::new(Mode::AutomaticExternal, 1.0);
        let status = |r: &mut Robot| r.handle(secs(0), Telegram::StatusRequest);
        let st = |program, state| {
            vec![Telegram::ProgramStatus {
                program: Some(p(program)),
                state,
                mode: Mode::AutomaticExternal,
            }]
        };
        r.handle(secs(0), Telegram::SelectProgram(p(64)));
        r.handle(secs(0), Telegram::StartProgram);
        r.control(secs(1), Control::EStop);
        assert_eq!(status(&mut r), st(64, ProgramState::Stopped));
        assert_eq!(
            r.control(secs(2), Control::EStopClear),
            st(64, ProgramState::Stopped),
            "the status is sent when the stop is cleared"
        );
        // Selected again, run to its end, whose telegram is lost.
        r.handle(secs(2), Telegram::SelectProgram(p(64)));
        r.handle(secs(2), Telegram::StartProgram);
        r.control(secs(3), Control::LoseEnd);
        assert_eq!(r.handle_timeout(secs(62)), vec![]);
        assert_eq!(status(&mut r), st(64, ProgramState::Selected));
        // Only the next end: the one after is sent.
        r.handle(secs(62), Telegram::StartProgram);
        assert_eq!(r.handle_timeout(secs(122)).len(), 1);
    }

    #[test]
    fn a_lost_acknowledgement_is_the_next_select_s_or_start_s_only() {
        let mut r = Robot::new(Mode::AutomaticExternal, 1.0);
        r.control(secs(0), Control::LoseAck);
        // The select is done, its acknowledgement never sent.
        assert_eq!(r.handle(secs(0), Telegram::SelectProgram(p(64))), vec![]);
        let out = r.handle(secs(0), Telegram::StatusRequest);
        assert!(
            matches!(&out[..], [Telegram::ProgramStatus { program: Some(q), state: ProgramState::Selected, .. }] if *q == p(64)),
            "{out:?}"
        );
        // The start's is sent again.
        let out = r.handle(secs(1), Telegram::StartProgram);
        assert_eq!(
            out.first(),
            Some(&Telegram::Ack {
                of: b'G',
                error: None
            })
        );
    }

    #[test]
    fn pause_freezes_the_program_and_estop_stops_it() {
        let mut r = Robot::new(Mode::AutomaticExternal, 1.0);
        r.handle(secs(0), Telegram::SelectProgram(p(64)));
        r.handle(secs(0), Telegram::StartProgram);
        assert_eq!(
            r.control(secs(10), Control::PersonIn),
            vec![Telegram::Alarm(30)]
        );
        assert_eq!(r.poll_timeout(), None);
        r.control(secs(40), Control::PersonOut);
        assert_eq!(
            r.poll_timeout(),
            Some(secs(90)),
            "50 s left after 30 s paused"
        );
        assert_eq!(
            r.control(secs(50), Control::EStop),
            vec![Telegram::Alarm(24)]
        );
        assert_eq!(r.poll_timeout(), None);
        assert_eq!(
            r.handle(secs(51), Telegram::StartProgram),
            vec![Telegram::Ack {
                of: b'G',
                error: Some(AckError::EmergencyStop)
            }]
        );
    }

    /// The telegrams that deliver `text` as program `n` (its hash, or
    /// `hash` instead), and the robot's answers to each.
    fn deliver(
        r: &mut Robot,
        at: Duration,
        n: u16,
        text: &str,
        hash: Option<u32>,
    ) -> Vec<Telegram> {
        let lines: Vec<&str> = text.lines().collect();
        let mut out = r.handle(
            at,
            Telegram::Text {
                program: p(n),
                lines: lines.len() as u16,
                hash: hash.unwrap_or_else(|| text_hash(text)),
            },
        );
        for (l, no) in lines.iter().zip(1u16..) {
            out.extend(r.handle(
                at,
                Telegram::Line {
                    no,
                    text: (*l).to_string(),
                },
            ));
        }
        out.extend(r.handle(at, Telegram::TextEnd(p(n))));
        out
    }

    fn acks(out: &[Telegram]) -> Vec<(char, Option<AckError>)> {
        out.iter()
            .filter_map(|t| match t {
                Telegram::Ack { of, error } => Some((*of as char, *error)),
                _ => None,
            })
            .collect()
    }

    const P65: &str = "program 65\n# delivered\nmove approach 2\nweld seam_1 6\nmove home 2";

    /// A delivered program is stored, listed, uploaded as it came, and
    /// runs its own steps with their times (each step noted as it
    /// begins), in place of the table's; a program that runs is never
    /// replaced, and a text incomplete, with a wrong hash or not a
    /// program is refused, the stored one kept.
    #[test]
    fn a_delivered_program_is_stored_listed_uploaded_and_run_step_by_step() {
        let mut r = Robot::new(Mode::AutomaticExternal, 2.0);
        let out = deliver(&mut r, secs(0), 65, P65, None);
        assert!(acks(&out).iter().all(|(_, e)| e.is_none()), "{out:?}");
        let stored = r.poll_note().expect("noted");
        assert_eq!(
            stored,
            format!(
                "program 65 stored: 3 steps, 10.0 s, hash {:08X}",
                text_hash(P65)
            )
        );
        let listed = r.handle(secs(0), Telegram::List);
        assert_eq!(
            listed,
            [
                Telegram::Stored {
                    program: p(65),
                    lines: 5,
                    hash: text_hash(P65)
                },
                Telegram::Ack {
                    of: b'L',
                    error: None
                }
            ]
        );
        let up = r.handle(secs(0), Telegram::Upload(p(65)));
        assert_eq!(up.len(), 7, "{up:?}");
        assert_eq!(
            up[2],
            Telegram::Line {
                no: 2,
                text: "# delivered".into()
            }
        );
        assert_eq!(up[6], Telegram::TextEnd(p(65)));
        assert_eq!(
            acks(&r.handle(secs(0), Telegram::Upload(p(66)))),
            [('U', Some(AckError::UnknownProgram))]
        );
        // Run at time scale 2: 1 s, 3 s, 1 s.
        r.handle(secs(10), Telegram::SelectProgram(p(65)));
        r.handle(secs(10), Telegram::StartProgram);
        let notes: Vec<String> = std::iter::from_fn(|| r.poll_note()).collect();
        assert_eq!(notes, ["program 65 step 1/3: move approach 2 s"]);
        assert_eq!(r.poll_timeout(), Some(secs(11)));
        // Delivered again while it runs: refused, the running one kept.
        let again = deliver(&mut r, secs(10), 65, &P65.replace("6", "7"), None);
        assert_eq!(acks(&again)[0], ('D', Some(AckError::ProgramRunning)));
        assert_eq!(r.handle_timeout(secs(11)), []);
        assert_eq!(
            r.poll_note().as_deref(),
            Some("program 65 step 2/3: weld seam_1 6 s")
        );
        assert_eq!(r.poll_timeout(), Some(secs(14)));
        assert_eq!(r.handle_timeout(secs(14)), []);
        assert_eq!(
            r.poll_note().as_deref(),
            Some("program 65 step 3/3: move home 2 s")
        );
        assert_eq!(
            r.handle_timeout(secs(15)),
            [Telegram::ProgramEnd {
                program: p(65),
                result: EndResult::Complete
            }]
        );
        // Refused texts: a wrong hash, not a program, another number, a
        // line out of order, a line with no download open.
        let wrong_hash = deliver(&mut r, secs(20), 65, P65, Some(1));
        assert_eq!(
            acks(&wrong_hash).last(),
            Some(&('F', Some(AckError::TextRefused)))
        );
        let not_a_program = deliver(&mut r, secs(20), 65, "program 65\njump 3", None);
        assert_eq!(
            acks(&not_a_program).last(),
            Some(&('F', Some(AckError::TextRefused)))
        );
        assert!(std::iter::from_fn(|| r.poll_note()).any(|n| n.contains("`jump 3` is not a step")));
        let other = deliver(&mut r, secs(20), 65, "program 66\nmove a 1", None);
        assert_eq!(
            acks(&other).last(),
            Some(&('F', Some(AckError::TextRefused)))
        );
        r.handle(
            secs(20),
            Telegram::Text {
                program: p(65),
                lines: 2,
                hash: 0,
            },
        );
        assert_eq!(
            acks(&r.handle(
                secs(20),
                Telegram::Line {
                    no: 2,
                    text: "x".into()
                }
            )),
            [('T', Some(AckError::TextRefused))]
        );
        assert_eq!(
            acks(&r.handle(
                secs(20),
                Telegram::Line {
                    no: 1,
                    text: "x".into()
                }
            )),
            [('T', Some(AckError::NoDownload))]
        );
        // The stored text is the first one still.
        assert!(matches!(
            r.handle(secs(20), Telegram::List).first(),
            Some(Telegram::Stored { hash, .. }) if *hash == text_hash(P65)
        ));
        while r.poll_note().is_some() {}
        // A program the table has and nobody delivered still runs.
        r.handle(secs(30), Telegram::SelectProgram(p(66)));
        r.handle(secs(30), Telegram::StartProgram);
        assert_eq!(r.poll_timeout(), Some(secs(90)), "120 s at time scale 2");
        assert_eq!(r.poll_note(), None, "no steps to note");
    }

    /// A pause holds the steps too: the next begins later by as long.
    #[test]
    fn a_pause_delays_the_next_step() {
        let mut r = Robot::new(Mode::AutomaticExternal, 1.0);
        deliver(&mut r, secs(0), 65, P65, None);
        while r.poll_note().is_some() {}
        r.handle(secs(0), Telegram::SelectProgram(p(65)));
        r.handle(secs(0), Telegram::StartProgram);
        r.control(secs(1), Control::PersonIn);
        assert_eq!(r.poll_timeout(), None);
        r.control(secs(5), Control::PersonOut);
        assert_eq!(r.poll_timeout(), Some(secs(6)), "step 2 at 2 s of running");
        r.handle_timeout(secs(6));
        let notes: Vec<String> = std::iter::from_fn(|| r.poll_note()).collect();
        assert_eq!(
            notes.last().map(String::as_str),
            Some("program 65 step 2/3: weld seam_1 6 s")
        );
        assert_eq!(r.poll_timeout(), Some(secs(12)));
    }

    #[test]
    fn aborted_weld_ends_with_a_bad_product() {
        let mut r = Robot::new(Mode::AutomaticExternal, 1.0);
        r.handle(secs(0), Telegram::SelectProgram(p(66)));
        r.handle(secs(0), Telegram::StartProgram);
        assert_eq!(
            r.control(secs(5), Control::AbortWeld),
            vec![
                Telegram::Alarm(50),
                Telegram::ProgramEnd {
                    program: p(66),
                    result: EndResult::WeldAborted
                }
            ]
        );
    }
}
