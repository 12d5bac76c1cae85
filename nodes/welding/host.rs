//! The welding workstation's side of the DNC link, sans-I/O: turns the
//! recipe engine's `start rcm N` / stop into telegrams (select, then start),
//! and the RCM's acknowledgements, program ends and alarm messages into
//! engine events and robot status (through the alarm table).

use falc_common::dnc::alarms::{self, Effect};
use falc_common::dnc::telegram::{EndResult, Program, Telegram};
use falc_common::ids::StationName;
use falc_common::mms::vmd::RobotStatusDetail;
use falc_common::recipe::engine::{Event, JobEnd};

/// What the host wants done.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Out {
    /// Send a telegram to the RCM.
    Telegram(Telegram),
    /// Feed the recipe engine.
    Engine(Event),
    /// The robot's status changed.
    Detail(RobotStatusDetail),
    /// Tell people (information report).
    Info(String),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Pending {
    Select(Program),
    Start,
}

/// The host's state.
#[derive(Debug)]
pub struct Host {
    rcm: StationName,
    pending: Option<Pending>,
}

impl Host {
    /// A host with nothing pending.
    pub fn new() -> Self {
        Self {
            rcm: StationName::new("rcm").unwrap_or_else(|_| unreachable!("`rcm` is a valid name")),
            pending: None,
        }
    }

    /// The engine wants robot program `program` started.
    pub fn start(&mut self, program: Program) -> Vec<Out> {
        self.pending = Some(Pending::Select(program));
        vec![Out::Telegram(Telegram::SelectProgram(program))]
    }

    /// The engine (or the commander) wants the robot stopped.
    pub fn stop(&mut self) -> Vec<Out> {
        self.pending = None;
        vec![Out::Telegram(Telegram::StopProgram)]
    }

    /// The link could not deliver a telegram: the job cannot go on.
    pub fn link_failed(&mut self, why: String) -> Vec<Out> {
        self.pending = None;
        vec![Out::Engine(Event::Ended(
            self.rcm.clone(),
            JobEnd::Alarm(why),
        ))]
    }

    /// A telegram from the RCM.
    pub fn telegram(&mut self, t: Telegram) -> Vec<Out> {
        let rcm = self.rcm.clone();
        match (t, self.pending) {
            (
                Telegram::Ack {
                    of: b'S',
                    error: None,
                },
                Some(Pending::Select(_)),
            ) => {
                self.pending = Some(Pending::Start);
                vec![Out::Telegram(Telegram::StartProgram)]
            }
            (
                Telegram::Ack {
                    of: b'G',
                    error: None,
                },
                Some(Pending::Start),
            ) => {
                self.pending = None;
                vec![Out::Engine(Event::Started(rcm))]
            }
            (Telegram::Ack { error: Some(e), .. }, Some(_)) => {
                self.pending = None;
                vec![Out::Engine(Event::StartFailed(
                    rcm,
                    e.to_service_error().to_string(),
                ))]
            }
            (Telegram::Ack { .. }, _) => Vec::new(),
            (
                Telegram::ProgramEnd {
                    result: EndResult::Complete,
                    ..
                },
                _,
            ) => {
                vec![Out::Engine(Event::Ended(rcm, JobEnd::Done))]
            }
            (
                Telegram::ProgramEnd {
                    result: EndResult::WeldAborted,
                    ..
                },
                _,
            ) => {
                vec![Out::Engine(Event::Ended(rcm, JobEnd::BadProduct))]
            }
            (Telegram::Alarm(code), _) => {
                let entry = alarms::lookup(code);
                let mut out: Vec<Out> = entry.detail().map(Out::Detail).into_iter().collect();
                let text = format!("RCM message {code}: {}", entry.meaning);
                out.push(match entry.effect {
                    Effect::Alarm => Out::Engine(Event::Ended(rcm, JobEnd::Alarm(text))),
                    Effect::Confirm => Out::Telegram(Telegram::ConfirmAlarm(code)),
                    Effect::Paused => Out::Engine(Event::Paused(rcm)),
                    Effect::Resumed => Out::Engine(Event::Resumed(rcm)),
                    Effect::FailedDanger => Out::Engine(Event::Ended(rcm, JobEnd::FailedDanger)),
                    Effect::FailedSafe => Out::Engine(Event::Ended(rcm, JobEnd::FailedSafe)),
                    // The program-end telegram that follows carries it.
                    Effect::BadProduct | Effect::Info => Out::Info(text),
                });
                out
            }
            (Telegram::ProgramStatus { .. }, _) => Vec::new(),
            (other, _) => vec![Out::Info(format!(
                "unexpected telegram from the RCM: {other:?}"
            ))],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_common::dnc::telegram::AckError;

    fn rcm() -> StationName {
        StationName::new("rcm").expect("valid")
    }

    #[test]
    fn select_then_start_then_started() {
        let mut h = Host::new();
        let p = Program::new(65).expect("valid");
        assert_eq!(h.start(p), vec![Out::Telegram(Telegram::SelectProgram(p))]);
        assert_eq!(
            h.telegram(Telegram::Ack {
                of: b'S',
                error: None
            }),
            vec![Out::Telegram(Telegram::StartProgram)]
        );
        assert_eq!(
            h.telegram(Telegram::Ack {
                of: b'G',
                error: None
            }),
            vec![Out::Engine(Event::Started(rcm()))]
        );
        assert_eq!(
            h.telegram(Telegram::ProgramEnd {
                program: p,
                result: EndResult::Complete
            }),
            vec![Out::Engine(Event::Ended(rcm(), JobEnd::Done))]
        );
    }

    #[test]
    fn refusals_and_alarms_become_engine_events() {
        let mut h = Host::new();
        h.start(Program::new(65).expect("valid"));
        match h
            .telegram(Telegram::Ack {
                of: b'S',
                error: Some(AckError::NotInDncMode),
            })
            .as_slice()
        {
            [Out::Engine(Event::StartFailed(_, why))] => {
                assert!(why.contains("automatic-external"), "{why}")
            }
            other => panic!("{other:?}"),
        }
        let estop = h.telegram(Telegram::Alarm(24));
        assert!(
            matches!(&estop[0], Out::Detail(d) if d.specific & RobotStatusDetail::SAFETY_INTERLOCKS_VIOLATED != 0)
        );
        assert!(
            matches!(&estop[1], Out::Engine(Event::Ended(_, JobEnd::Alarm(t))) if t.contains("emergency stop"))
        );
        assert!(matches!(
            h.telegram(Telegram::Alarm(30)).last(),
            Some(Out::Engine(Event::Paused(_)))
        ));
        assert!(matches!(
            h.telegram(Telegram::Alarm(40)).last(),
            Some(Out::Engine(Event::Ended(_, JobEnd::FailedDanger)))
        ));
        assert_eq!(
            h.telegram(Telegram::Alarm(3)).last(),
            Some(&Out::Telegram(Telegram::ConfirmAlarm(3)))
        );
    }
}
