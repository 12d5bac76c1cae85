//! The robot controller's behaviour, sans-I/O: modes, the program table,
//! the running program on an injected clock, and the faults a test or a
//! person injects. Telegrams in, telegrams out.

use crate::telegram::{AckError, EndResult, Mode, ProgramState, Telegram};
use falc_model::ids::RobotProgram;
use std::collections::BTreeMap;
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
        let programs = program_table()
            .into_iter()
            .map(|(n, d)| (n, d.div_f64(time_scale.max(1e-6))))
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
            Telegram::StatusRequest => vec![self.status()],
            Telegram::SelectProgram(p) => {
                if self.run.is_some() {
                    vec![ack(Some(AckError::ProgramRunning))]
                } else if !self.programs.contains_key(&p.number()) {
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
                    let left = self.programs.get(&p.number()).copied().unwrap_or_default();
                    self.run = Some(Run {
                        program: p,
                        left,
                        since: Some(now),
                    });
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

    /// When the running program ends (None when paused or idle).
    pub fn poll_timeout(&self) -> Option<Duration> {
        self.run.as_ref().and_then(|r| r.since.map(|s| s + r.left))
    }

    /// The clock reached `now`: a program that is due ends.
    pub fn handle_timeout(&mut self, now: Duration) -> Vec<Telegram> {
        if self.poll_timeout().is_some_and(|t| t <= now) {
            if let Some(r) = self.run.take() {
                if std::mem::take(&mut self.lose_end) {
                    return Vec::new();
                }
                return vec![Telegram::ProgramEnd {
                    program: r.program,
                    result: EndResult::Complete,
                }];
            }
        }
        Vec::new()
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
