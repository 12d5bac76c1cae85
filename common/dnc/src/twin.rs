//! The robot controller's twin at its end of the serial line, sans-I/O:
//! the [`Robot`] behind the 3964R procedure at high priority. Bytes from
//! the line in ([`RcmTwin::handle_bytes`]), bytes to the line out
//! ([`RcmTwin::poll_transmit`]), faults injected with
//! [`RcmTwin::control`], and what a person watching the twin reads
//! ([`RcmTwin::poll_note`]: each telegram received, and what went wrong).
//! `falc-rcm-sim` drives it on a serial port, `falc-sim` on an in-memory
//! line.

use crate::procedure::{Link, LinkEvent, Priority, Timing};
use crate::robot::{Control, Robot};
use crate::telegram::{AckError, Telegram};
use std::collections::VecDeque;
use std::time::Duration;

/// What the twin tells the person watching it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Note {
    /// A telegram came from the host.
    Received(Telegram),
    /// Something went wrong on the line (a telegram undecodable or lost).
    Trouble(String),
    /// What the robot did: a program stored, a step of a delivered
    /// program begun ([`Robot::poll_note`]).
    Robot(String),
}

/// The robot controller and its end of the link.
#[derive(Debug)]
pub struct RcmTwin {
    /// The robot (its mode, programs, faults).
    pub robot: Robot,
    link: Link,
    notes: VecDeque<Note>,
}

impl RcmTwin {
    /// `robot` on a link with `timing`.
    pub fn new(robot: Robot, timing: Timing) -> Self {
        Self {
            robot,
            link: Link::new(Priority::High, timing),
            notes: VecDeque::new(),
        }
    }

    /// Bytes arrived from the line.
    pub fn handle_bytes(&mut self, now: Duration, bytes: &[u8]) {
        self.link.handle_bytes(now, bytes);
        self.events(now);
    }

    /// The next bytes for the line.
    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.link.poll_transmit()
    }

    /// When the clock is next needed (the link's limits, the program's end).
    pub fn poll_timeout(&self) -> Option<Duration> {
        [self.link.poll_timeout(), self.robot.poll_timeout()]
            .into_iter()
            .flatten()
            .min()
    }

    /// The clock reached [`Self::poll_timeout`].
    pub fn handle_timeout(&mut self, now: Duration) {
        self.link.handle_timeout(now);
        for t in self.robot.handle_timeout(now) {
            self.link.send(now, t.encode());
        }
        self.events(now);
    }

    /// A fault or event injected by a person or a test.
    pub fn control(&mut self, now: Duration, c: Control) {
        for t in self.robot.control(now, c) {
            self.link.send(now, t.encode());
        }
    }

    /// The next note for the twin's log.
    pub fn poll_note(&mut self) -> Option<Note> {
        self.notes
            .pop_front()
            .or_else(|| self.robot.poll_note().map(Note::Robot))
    }

    fn events(&mut self, now: Duration) {
        while let Some(ev) = self.link.poll_event() {
            match ev {
                LinkEvent::Received(bytes) => match Telegram::decode(&bytes) {
                    Ok(t) => {
                        self.notes.push_back(Note::Received(t.clone()));
                        for reply in self.robot.handle(now, t) {
                            self.link.send(now, reply.encode());
                        }
                    }
                    Err(e) => {
                        self.notes
                            .push_back(Note::Trouble(format!("undecodable telegram: {e}")));
                        let of = bytes.first().copied().unwrap_or(b'?');
                        let nak = Telegram::Ack {
                            of,
                            error: Some(AckError::Malformed),
                        };
                        self.link.send(now, nak.encode());
                    }
                },
                LinkEvent::Failed { telegram, error } => self.notes.push_back(Note::Trouble(
                    format!("telegram {} lost: {error}", telegram.escape_ascii()),
                )),
                LinkEvent::Sent(_) | LinkEvent::Refused(_) | LinkEvent::Silent(_) => {}
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::telegram::Mode;

    #[test]
    fn a_malformed_telegram_is_refused_and_noted() {
        let mut twin = RcmTwin::new(Robot::new(Mode::AutomaticExternal, 1.0), Timing::default());
        let mut host = Link::new(Priority::Low, Timing::default());
        let now = Duration::ZERO;
        host.send(now, b"Z??".to_vec());
        // Exchange bytes until both links are quiet.
        for _ in 0..20 {
            while let Some(b) = host.poll_transmit() {
                twin.handle_bytes(now, &b);
            }
            while let Some(b) = twin.poll_transmit() {
                host.handle_bytes(now, &b);
            }
        }
        let note = twin.poll_note();
        assert!(
            matches!(&note, Some(Note::Trouble(t)) if t.starts_with("undecodable telegram")),
            "{note:?}"
        );
        let mut got = Vec::new();
        while let Some(ev) = host.poll_event() {
            if let LinkEvent::Received(b) = ev {
                got.push(Telegram::decode(&b));
            }
        }
        assert!(
            got.iter().any(|t| matches!(
                t,
                Ok(Telegram::Ack {
                    error: Some(AckError::Malformed),
                    ..
                })
            )),
            "{got:?}"
        );
    }
}
