//! The 3964R link procedure, sans-I/O: bytes and the clock in, bytes and
//! events out (`handle_bytes`, `handle_timeout` / `poll_transmit`,
//! `poll_event`, `poll_timeout`). The driver owns the serial port.
//!
//! The rules (Siemens 3964R, as the RCM 815 DNC link uses it):
//! - to send, a station sends STX and waits for DLE within the
//!   acknowledgement delay (2 s); then the block, every DLE doubled, closed
//!   by DLE ETX and the BCC (XOR of every byte after STX, DLE ETX
//!   included); then waits for DLE within the acknowledgement delay;
//! - NAK, a wrong character or no answer: the connection (STX) is tried up
//!   to 6 times, the transmission (block) up to 6 times, then the telegram
//!   fails; after NAK or a wrong character the sender first waits for a
//!   quiet line (two character delays without a byte; an STX from the
//!   partner is taken), so a burst of noise costs one attempt, not all six
//!   at once, and a late NAK of the partner's own timeout cannot meet every
//!   new STX (with a back-off equal to the character delay they resonate);
//! - the receiver answers STX with DLE, takes characters with at most the
//!   character delay (220 ms) between them, checks the BCC and answers DLE,
//!   or NAK on a bad BCC, a timeout or an overflow;
//! - an idle end that hears anything but STX or NAK (an STX spoilt by
//!   noise) waits until the line has been quiet for the character delay
//!   and answers NAK, so a sender on a live line always hears something
//!   within the acknowledgement delay: only a dead line (or partner) is
//!   silent, and the link says so ([`LinkEvent::Silent`]) the first time
//!   an acknowledgement delay passes without a byte;
//! - initialisation conflict (both send STX): the low-priority station
//!   (FALC's workstation) answers the other's STX with DLE and sends its own
//!   telegram afterwards; the high-priority station (the RCM) waits on.

use std::collections::VecDeque;
use std::time::Duration;

/// Start of text.
pub const STX: u8 = 0x02;
/// End of text.
pub const ETX: u8 = 0x03;
/// Data link escape: positive acknowledgement, and escape in the block.
pub const DLE: u8 = 0x10;
/// Negative acknowledgement.
pub const NAK: u8 = 0x15;

/// The procedure's timing and limits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timing {
    /// Character delay (ZVZ): the longest gap inside a received block.
    pub char_delay: Duration,
    /// Acknowledgement delay (QVZ): how long a sender waits for DLE.
    pub ack_delay: Duration,
    /// Connection attempts (STX → DLE).
    pub connect_attempts: u8,
    /// Transmission attempts (block → DLE).
    pub transmit_attempts: u8,
    /// The longest block accepted.
    pub max_block: usize,
}

impl Default for Timing {
    fn default() -> Self {
        Self {
            char_delay: Duration::from_millis(220),
            ack_delay: Duration::from_secs(2),
            connect_attempts: 6,
            transmit_attempts: 6,
            max_block: 1024,
        }
    }
}

/// How many attempts a supervised request and its answer may lose on the
/// way before the line counts as silent ([`Timing::silent_after`]).
pub const SUPERVISED_LOSSES: u32 = 2;

impl Timing {
    /// The longest one lost attempt costs before the next begins: the
    /// acknowledgement delay (no answer), or a NAK or wrong character and
    /// the quiet line after it (two character delays).
    pub fn lost_attempt(&self) -> Duration {
        self.ack_delay + 2 * self.char_delay
    }

    /// How long a request and its answer may take on a line that loses
    /// `lost` attempts on the way (of either telegram), with one
    /// acknowledgement delay for the partner to answer: what a supervisor
    /// allows before it calls the line silent. Defaults, `lost` = 2:
    /// 2 s + 2 × 2.44 s = 6.88 s.
    pub fn exchange_limit(&self, lost: u32) -> Duration {
        self.ack_delay + self.lost_attempt() * lost
    }

    /// How long a supervisor waits for the answer to a request before it
    /// calls the line silent: [`Self::exchange_limit`] of
    /// [`SUPERVISED_LOSSES`], so a noisy line that needs a retry or two is
    /// never taken for a dead one (6.88 s with the defaults).
    pub fn silent_after(&self) -> Duration {
        self.exchange_limit(SUPERVISED_LOSSES)
    }

    /// The longest a telegram takes to fail on a dead line: every
    /// connection attempt unanswered.
    pub fn dead_line_after(&self) -> Duration {
        self.ack_delay * u32::from(self.connect_attempts)
    }
}

/// Which side wins an initialisation conflict.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Priority {
    /// The robot controller.
    High,
    /// The workstation.
    Low,
}

/// Why a telegram could not be sent.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SendError {
    /// No DLE to STX in every connection attempt.
    #[error("no connection: no DLE to STX after {attempts} attempts ({last})")]
    NoConnection {
        /// Attempts made.
        attempts: u8,
        /// What happened last.
        last: String,
    },
    /// No DLE to the block in every transmission attempt.
    #[error("not acknowledged: no DLE to the block after {attempts} attempts ({last})")]
    NotAcknowledged {
        /// Attempts made.
        attempts: u8,
        /// What happened last.
        last: String,
    },
}

/// What the procedure reports.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinkEvent {
    /// A telegram arrived intact (DLEs undoubled, without DLE ETX BCC).
    Received(Vec<u8>),
    /// A telegram of ours was acknowledged.
    Sent(Vec<u8>),
    /// A telegram of ours failed.
    Failed {
        /// The telegram.
        telegram: Vec<u8>,
        /// Why.
        error: SendError,
    },
    /// A received block was refused with NAK (bad BCC, timeout, overflow),
    /// or noise on an idle line was answered with NAK.
    Refused(String),
    /// An acknowledgement delay passed while this end waited for the
    /// partner and not one byte came: the line or the partner is dead (a
    /// live partner answers even a spoilt byte, with NAK). Told once per
    /// silence; any byte heard ends it.
    Silent(Duration),
}

#[derive(Debug, Clone, PartialEq, Eq)]
enum State {
    Idle,
    /// STX sent, waiting for DLE.
    AwaitStartAck {
        deadline: Duration,
    },
    /// Block sent, waiting for DLE.
    AwaitFinalAck {
        deadline: Duration,
    },
    /// After NAK or a wrong character: wait, then STX again.
    Backoff {
        until: Duration,
    },
    /// Idle, a character other than STX or NAK heard: NAK once the line
    /// has been quiet for the character delay.
    Noise {
        first: u8,
        deadline: Duration,
    },
    /// Receiving a block.
    Receiving {
        buf: Vec<u8>,
        escaped: bool,
        deadline: Duration,
    },
    /// DLE ETX received, waiting for the BCC.
    AwaitBcc {
        buf: Vec<u8>,
        bcc: u8,
        deadline: Duration,
    },
}

/// The block bytes of a telegram: data with every DLE doubled, DLE ETX,
/// and the BCC.
pub fn frame(data: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(data.len() + 4);
    for &b in data {
        out.push(b);
        if b == DLE {
            out.push(DLE);
        }
    }
    out.extend([DLE, ETX]);
    let bcc = out.iter().fold(0u8, |a, b| a ^ b);
    out.push(bcc);
    out
}

/// Which kind of attempt failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Attempt {
    /// STX → DLE.
    Connect,
    /// Block → DLE.
    Transmit,
}

/// One end of a 3964R link.
#[derive(Debug, Clone)]
pub struct Link {
    timing: Timing,
    priority: Priority,
    state: State,
    queue: VecDeque<Vec<u8>>,
    connect_tries: u8,
    transmit_tries: u8,
    out: VecDeque<u8>,
    events: VecDeque<LinkEvent>,
    /// The current silence was told ([`LinkEvent::Silent`]); a byte heard
    /// clears it.
    silence_told: bool,
    /// Whether the partner answers every telegram of ours
    /// ([`Link::awaiting_answers`]).
    answered: bool,
    /// Until when a byte is awaited after a telegram of ours went (the
    /// partner's answer): none heard by then is a silence.
    answer_due: Option<Duration>,
}

impl Link {
    /// A link end with `priority` and `timing`.
    pub fn new(priority: Priority, timing: Timing) -> Self {
        Self {
            timing,
            priority,
            state: State::Idle,
            queue: VecDeque::new(),
            connect_tries: 0,
            transmit_tries: 0,
            out: VecDeque::new(),
            events: VecDeque::new(),
            silence_told: false,
            answered: false,
            answer_due: None,
        }
    }

    /// An end whose partner answers every telegram it is sent (the DNC
    /// host: the RCM acknowledges each command and answers each status
    /// request). Once a telegram went, an acknowledgement delay without
    /// one byte from the partner is a silence ([`LinkEvent::Silent`]), as
    /// while waiting for a DLE: a line that dies just after a telegram
    /// went is told then, not only when the next telegram's STX goes
    /// unanswered. Noise is bytes, and ends the wait like an answer.
    pub fn awaiting_answers(mut self) -> Self {
        self.answered = true;
        self
    }

    /// Queues a telegram; it is sent when the link is free.
    pub fn send(&mut self, now: Duration, telegram: Vec<u8>) {
        self.queue.push_back(telegram);
        self.start_next(now);
    }

    /// Whether nothing is being sent or received and nothing is queued.
    pub fn is_idle(&self) -> bool {
        self.state == State::Idle && self.queue.is_empty()
    }

    /// Bytes to write to the line.
    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        if self.out.is_empty() {
            None
        } else {
            Some(self.out.drain(..).collect())
        }
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<LinkEvent> {
        self.events.pop_front()
    }

    /// When `handle_timeout` must be called next.
    pub fn poll_timeout(&self) -> Option<Duration> {
        match &self.state {
            State::Idle => self.answer_due,
            State::AwaitStartAck { deadline }
            | State::AwaitFinalAck { deadline }
            | State::Backoff { until: deadline }
            | State::Noise { deadline, .. }
            | State::Receiving { deadline, .. }
            | State::AwaitBcc { deadline, .. } => Some(*deadline),
        }
    }

    fn start_next(&mut self, now: Duration) {
        if self.state == State::Idle && !self.queue.is_empty() {
            self.connect_tries = 1;
            self.transmit_tries = 1;
            self.send_stx(now);
        }
    }

    fn send_stx(&mut self, now: Duration) {
        self.out.push_back(STX);
        self.state = State::AwaitStartAck {
            deadline: now + self.timing.ack_delay,
        };
    }

    /// A connection attempt (STX → DLE) failed: try again or give up.
    fn retry_connect(&mut self, now: Duration, why: &str) {
        self.retry(now, why, Attempt::Connect, false)
    }

    /// A transmission attempt (block → DLE) failed: the whole telegram
    /// again, from STX, or give up.
    fn retry_transmit(&mut self, now: Duration, why: &str) {
        self.retry(now, why, Attempt::Transmit, false)
    }

    /// Counts a failed attempt of `kind`; the next STX goes at once, or
    /// after one character delay when the line must settle (`settle`:
    /// after NAK or a wrong character); past the limit the telegram fails.
    fn retry(&mut self, now: Duration, why: &str, kind: Attempt, settle: bool) {
        let (tries, limit) = match kind {
            Attempt::Connect => (self.connect_tries, self.timing.connect_attempts),
            Attempt::Transmit => (self.transmit_tries, self.timing.transmit_attempts),
        };
        if tries >= limit {
            let last = why.to_string();
            let error = match kind {
                Attempt::Connect => SendError::NoConnection {
                    attempts: tries,
                    last,
                },
                Attempt::Transmit => SendError::NotAcknowledged {
                    attempts: tries,
                    last,
                },
            };
            self.fail(now, error);
            return;
        }
        match kind {
            Attempt::Connect => self.connect_tries += 1,
            Attempt::Transmit => {
                self.transmit_tries += 1;
                self.connect_tries = 1;
            }
        }
        if settle {
            self.state = State::Backoff {
                until: now + 2 * self.timing.char_delay,
            };
        } else {
            self.send_stx(now);
        }
    }

    fn fail(&mut self, now: Duration, error: SendError) {
        self.state = State::Idle;
        if let Some(telegram) = self.queue.pop_front() {
            self.events.push_back(LinkEvent::Failed { telegram, error });
        }
        self.start_next(now);
    }

    fn refuse(&mut self, now: Duration, why: String) {
        self.out.push_back(NAK);
        self.events.push_back(LinkEvent::Refused(why));
        self.state = State::Idle;
        self.start_next(now);
    }

    fn begin_receive(&mut self, now: Duration) {
        self.out.push_back(DLE);
        self.state = State::Receiving {
            buf: Vec::new(),
            escaped: false,
            deadline: now + self.timing.char_delay,
        };
    }

    /// The clock reached `now`.
    pub fn handle_timeout(&mut self, now: Duration) {
        if !self.poll_timeout().is_some_and(|d| d <= now) {
            return;
        }
        match self.state {
            State::AwaitStartAck { .. } => {
                self.silent();
                self.retry_connect(now, "no answer within the acknowledgement delay")
            }
            State::AwaitFinalAck { .. } => {
                self.silent();
                self.retry_transmit(now, "no answer within the acknowledgement delay")
            }
            State::Backoff { .. } => self.send_stx(now),
            State::Noise { first, .. } => {
                self.refuse(now, format!("0x{first:02x} on an idle line"))
            }
            State::Receiving { .. } | State::AwaitBcc { .. } => {
                self.refuse(now, "character delay exceeded inside a block".into())
            }
            State::Idle => {
                // The partner's answer did not begin within the delay.
                self.answer_due = None;
                self.silent();
            }
        }
    }

    /// An acknowledgement delay passed without a byte from the partner
    /// (any byte would have left the waiting state): told once.
    fn silent(&mut self) {
        if !std::mem::replace(&mut self.silence_told, true) {
            self.events
                .push_back(LinkEvent::Silent(self.timing.ack_delay));
        }
    }

    /// Bytes arrived from the line.
    pub fn handle_bytes(&mut self, now: Duration, bytes: &[u8]) {
        if !bytes.is_empty() {
            self.silence_told = false;
            self.answer_due = None;
        }
        for &b in bytes {
            self.handle_byte(now, b);
        }
    }

    fn handle_byte(&mut self, now: Duration, b: u8) {
        let char_deadline = now + self.timing.char_delay;
        match std::mem::replace(&mut self.state, State::Idle) {
            State::Idle => match b {
                STX => self.begin_receive(now),
                // A late NAK (of a telegram given up) asks nothing.
                NAK => {}
                // Noise, or the partner's STX spoilt: NAK once quiet.
                first => {
                    self.state = State::Noise {
                        first,
                        deadline: char_deadline,
                    }
                }
            },
            State::Noise { first, .. } => {
                if b == STX {
                    self.begin_receive(now);
                } else {
                    self.state = State::Noise {
                        first,
                        deadline: char_deadline,
                    };
                }
            }
            State::AwaitStartAck { deadline } => match b {
                DLE => {
                    let block = self.queue.front().map(|t| frame(t)).unwrap_or_default();
                    self.out.extend(block);
                    self.state = State::AwaitFinalAck {
                        deadline: now + self.timing.ack_delay,
                    };
                }
                STX if self.priority == Priority::Low => {
                    // Initialisation conflict: the other side has priority.
                    // Receive its telegram; ours goes afterwards, afresh.
                    self.begin_receive(now);
                }
                STX => self.state = State::AwaitStartAck { deadline },
                NAK => self.retry(now, "NAK to STX", Attempt::Connect, true),
                other => self.retry(
                    now,
                    &format!("0x{other:02x} instead of DLE to STX"),
                    Attempt::Connect,
                    true,
                ),
            },
            State::AwaitFinalAck { .. } => match b {
                DLE => {
                    self.state = State::Idle;
                    if self.answered {
                        self.answer_due = Some(now + self.timing.ack_delay);
                    }
                    if let Some(t) = self.queue.pop_front() {
                        self.events.push_back(LinkEvent::Sent(t));
                    }
                    self.start_next(now);
                }
                NAK => self.retry(now, "NAK to the block", Attempt::Transmit, true),
                other => self.retry(
                    now,
                    &format!("0x{other:02x} instead of DLE to the block"),
                    Attempt::Transmit,
                    true,
                ),
            },
            State::Backoff { .. } => {
                if b == STX && self.priority == Priority::Low {
                    // The partner wants to send: take its telegram first.
                    self.begin_receive(now);
                } else {
                    // The end with priority keeps its turn (3964R's
                    // initialisation conflict): were both to yield, both
                    // would receive, refuse and yield again for ever.
                    // Either way the line is not quiet yet: wait again
                    // from this byte.
                    self.state = State::Backoff {
                        until: now + 2 * self.timing.char_delay,
                    };
                }
            }
            State::Receiving {
                mut buf, escaped, ..
            } => {
                if escaped {
                    match b {
                        DLE => {
                            buf.push(DLE);
                            self.state = State::Receiving {
                                buf,
                                escaped: false,
                                deadline: char_deadline,
                            };
                        }
                        ETX => {
                            let bcc = buf
                                .iter()
                                .flat_map(|&x| if x == DLE { vec![DLE, DLE] } else { vec![x] })
                                .fold(0u8, |a, x| a ^ x)
                                ^ DLE
                                ^ ETX;
                            self.state = State::AwaitBcc {
                                buf,
                                bcc,
                                deadline: char_deadline,
                            };
                        }
                        other => self
                            .refuse(now, format!("DLE followed by 0x{other:02x} inside a block")),
                    }
                } else if b == DLE {
                    self.state = State::Receiving {
                        buf,
                        escaped: true,
                        deadline: char_deadline,
                    };
                } else if buf.len() >= self.timing.max_block {
                    self.refuse(
                        now,
                        format!("block longer than {} bytes", self.timing.max_block),
                    );
                } else {
                    buf.push(b);
                    self.state = State::Receiving {
                        buf,
                        escaped: false,
                        deadline: char_deadline,
                    };
                }
            }
            State::AwaitBcc { buf, bcc, .. } => {
                if b == bcc {
                    self.out.push_back(DLE);
                    self.events.push_back(LinkEvent::Received(buf));
                    self.start_next(now);
                } else {
                    self.refuse(now, format!("bad BCC: 0x{b:02x}, expected 0x{bcc:02x}"));
                }
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn low() -> Link {
        Link::new(Priority::Low, Timing::default())
    }

    fn tx(l: &mut Link) -> Vec<u8> {
        l.poll_transmit().unwrap_or_default()
    }

    fn events(l: &mut Link) -> Vec<LinkEvent> {
        std::iter::from_fn(|| l.poll_event()).collect()
    }

    #[test]
    fn dle_is_doubled_and_bcc_covers_dle_etx() {
        let f = frame(&[0x41, DLE, 0x42]);
        assert_eq!(&f[..6], &[0x41, DLE, DLE, 0x42, DLE, ETX]);
        assert_eq!(f[6], 0x41 ^ DLE ^ DLE ^ 0x42 ^ DLE ^ ETX);
        assert_eq!(frame(&[]), vec![DLE, ETX, DLE ^ ETX]);
    }

    #[test]
    fn a_telegram_is_sent_and_acknowledged() {
        let mut l = low();
        l.send(ms(0), b"S064".to_vec());
        assert_eq!(tx(&mut l), vec![STX]);
        assert_eq!(l.poll_timeout(), Some(ms(2000)));
        l.handle_bytes(ms(5), &[DLE]);
        assert_eq!(tx(&mut l), frame(b"S064"));
        l.handle_bytes(ms(30), &[DLE]);
        assert_eq!(events(&mut l), vec![LinkEvent::Sent(b"S064".to_vec())]);
        assert!(l.is_idle());
    }

    /// Found by `falc-sim` (seeds 1, 4, 6, 9–12 of 3,000 orders): a line
    /// unplugged just after a status request went left the robot's program
    /// unwatched until the host's 6.88 s limit; the link now tells the
    /// silence an acknowledgement delay after the telegram went.
    #[test]
    fn a_partner_that_answers_every_telegram_is_silent_when_no_byte_follows_one() {
        let delivered = |l: &mut Link| {
            l.send(ms(0), b"Q".to_vec());
            tx(l);
            l.handle_bytes(ms(5), &[DLE]);
            tx(l);
            l.handle_bytes(ms(10), &[DLE]);
            assert_eq!(events(l), vec![LinkEvent::Sent(b"Q".to_vec())]);
        };
        let mut l = low().awaiting_answers();
        delivered(&mut l);
        assert_eq!(l.poll_timeout(), Some(ms(2010)));
        l.handle_timeout(ms(2009));
        assert_eq!(events(&mut l), vec![]);
        l.handle_timeout(ms(2010));
        assert_eq!(events(&mut l), vec![LinkEvent::Silent(ms(2000))]);
        assert_eq!(l.poll_timeout(), None, "told once");
        // The answer begins (or noise comes: bytes either way): no silence.
        let mut l = low().awaiting_answers();
        delivered(&mut l);
        l.handle_bytes(ms(400), &[0x55]);
        l.handle_timeout(ms(2010));
        assert!(!events(&mut l).contains(&LinkEvent::Silent(ms(2000))));
        // A partner that answers nothing is never awaited.
        let mut l = low();
        delivered(&mut l);
        assert_eq!(l.poll_timeout(), None);
    }

    #[test]
    fn a_telegram_is_received_with_dle_undoubled() {
        let mut l = low();
        l.handle_bytes(ms(0), &[0x55, STX]); // an STX right after noise is taken
        assert_eq!(tx(&mut l), vec![DLE]);
        let block = frame(&[b'M', DLE, b'7']);
        l.handle_bytes(ms(10), &block);
        assert_eq!(tx(&mut l), vec![DLE]);
        assert_eq!(
            events(&mut l),
            vec![LinkEvent::Received(vec![b'M', DLE, b'7'])]
        );
    }

    #[test]
    fn bad_bcc_is_refused_with_nak() {
        let mut l = low();
        l.handle_bytes(ms(0), &[STX]);
        tx(&mut l);
        let mut block = frame(b"E065");
        let last = block.len() - 1;
        block[last] ^= 0xff;
        l.handle_bytes(ms(10), &block);
        assert_eq!(tx(&mut l), vec![NAK]);
        assert!(
            matches!(events(&mut l).as_slice(), [LinkEvent::Refused(why)] if why.starts_with("bad BCC"))
        );
    }

    #[test]
    fn character_delay_exceeded_is_refused() {
        let mut l = low();
        l.handle_bytes(ms(0), &[STX, b'A']);
        tx(&mut l);
        assert_eq!(l.poll_timeout(), Some(ms(220)));
        l.handle_timeout(ms(219));
        assert_eq!(tx(&mut l), Vec::<u8>::new());
        l.handle_timeout(ms(220));
        assert_eq!(tx(&mut l), vec![NAK]);
        assert!(l.is_idle());
    }

    #[test]
    fn overflow_is_refused() {
        let mut l = Link::new(
            Priority::Low,
            Timing {
                max_block: 4,
                ..Timing::default()
            },
        );
        l.handle_bytes(ms(0), &[STX, 1, 2, 3, 4, 5]);
        assert_eq!(tx(&mut l), vec![DLE, NAK]);
    }

    #[test]
    fn six_connection_attempts_then_failure() {
        let mut l = low();
        l.send(ms(0), b"G".to_vec());
        let mut now = ms(0);
        let mut stx_sent = 0;
        for _ in 0..10 {
            if tx(&mut l) == vec![STX] {
                stx_sent += 1;
            }
            match l.poll_timeout() {
                Some(t) => {
                    now = t;
                    l.handle_timeout(now);
                }
                None => break,
            }
        }
        assert_eq!(stx_sent, 6);
        assert_eq!(now, ms(12_000), "6 × the acknowledgement delay");
        match events(&mut l).as_slice() {
            // The silence is told once, at the first acknowledgement delay.
            [LinkEvent::Silent(waited), LinkEvent::Failed {
                telegram,
                error: SendError::NoConnection { attempts: 6, .. },
            }] => {
                assert_eq!(*waited, ms(2000));
                assert_eq!(telegram, b"G")
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn noise_on_an_idle_line_is_answered_with_nak_once_the_line_is_quiet() {
        let mut l = low();
        l.handle_bytes(ms(0), &[0x12]); // an STX with a bit flipped
        assert_eq!(tx(&mut l), Vec::<u8>::new());
        assert_eq!(l.poll_timeout(), Some(ms(220)));
        // More noise: the wait starts again from the last byte.
        l.handle_bytes(ms(100), &[0x7f]);
        assert_eq!(l.poll_timeout(), Some(ms(320)));
        // A telegram queued meanwhile waits for the NAK.
        l.send(ms(150), b"Q".to_vec());
        assert_eq!(tx(&mut l), Vec::<u8>::new());
        l.handle_timeout(ms(320));
        assert_eq!(tx(&mut l), vec![NAK, STX]);
        assert!(
            matches!(events(&mut l).as_slice(), [LinkEvent::Refused(why)] if why == "0x12 on an idle line")
        );
        // A late NAK on an idle line asks nothing (no NAK ping-pong).
        let mut l = low();
        l.handle_bytes(ms(0), &[NAK]);
        assert_eq!(l.poll_timeout(), None);
        // An STX after noise is the partner's telegram.
        l.handle_bytes(ms(10), &[0x33, STX]);
        assert_eq!(tx(&mut l), vec![DLE]);
    }

    #[test]
    fn a_live_partner_answers_a_spoilt_stx_and_only_a_dead_one_is_silent() {
        let mut ws = low();
        let mut rcm = Link::new(Priority::High, Timing::default());
        ws.send(ms(0), b"Q".to_vec());
        assert_eq!(tx(&mut ws), vec![STX]);
        // The STX arrives spoilt: the RCM answers NAK after a character
        // delay, well inside the workstation's acknowledgement delay.
        rcm.handle_bytes(ms(1), &[STX ^ 0x40]);
        rcm.handle_timeout(ms(221));
        assert_eq!(tx(&mut rcm), vec![NAK]);
        ws.handle_bytes(ms(222), &[NAK]);
        // Quiet line, STX again, and this time it goes through.
        ws.handle_timeout(ms(662));
        assert_eq!(tx(&mut ws), vec![STX]);
        rcm.handle_bytes(ms(663), &[STX]);
        ws.handle_bytes(ms(664), &tx(&mut rcm));
        rcm.handle_bytes(ms(665), &tx(&mut ws));
        ws.handle_bytes(ms(666), &tx(&mut rcm));
        assert_eq!(events(&mut ws), vec![LinkEvent::Sent(b"Q".to_vec())]);
        assert_eq!(
            events(&mut rcm).last(),
            Some(&LinkEvent::Received(b"Q".to_vec()))
        );
        // The partner gone: one acknowledgement delay without a byte is
        // told, once, and the attempts go on.
        ws.send(ms(1000), b"Q".to_vec());
        tx(&mut ws);
        ws.handle_timeout(ms(2999));
        assert_eq!(events(&mut ws), vec![]);
        ws.handle_timeout(ms(3000));
        assert_eq!(events(&mut ws), vec![LinkEvent::Silent(ms(2000))]);
        assert_eq!(tx(&mut ws), vec![STX]);
        ws.handle_timeout(ms(5000));
        assert_eq!(events(&mut ws), vec![]);
        // A byte heard ends the silence; the next one is told again.
        ws.handle_bytes(ms(5100), &[0x7f]);
        let quiet = ws.poll_timeout().unwrap_or_default();
        ws.handle_timeout(quiet);
        tx(&mut ws);
        ws.handle_timeout(quiet + ms(2000));
        assert_eq!(events(&mut ws), vec![LinkEvent::Silent(ms(2000))]);
    }

    #[test]
    fn nak_to_stx_retries_the_connection_after_the_line_is_quiet() {
        let mut l = low();
        l.send(ms(0), b"G".to_vec());
        tx(&mut l);
        l.handle_bytes(ms(1), &[NAK]);
        assert_eq!(tx(&mut l), Vec::<u8>::new(), "the line settles first");
        assert_eq!(l.poll_timeout(), Some(ms(441)), "two character delays");
        l.handle_bytes(ms(50), &[0x7f, 0x55]);
        assert_eq!(
            l.poll_timeout(),
            Some(ms(490)),
            "each byte restarts the wait"
        );
        l.handle_timeout(ms(490));
        assert_eq!(tx(&mut l), vec![STX], "second attempt on a quiet line");
        l.handle_bytes(ms(491), &[0x7f, 0x7f, 0x7f]);
        assert_eq!(
            tx(&mut l),
            Vec::<u8>::new(),
            "a burst of noise costs one attempt"
        );
        l.handle_timeout(ms(931));
        assert_eq!(tx(&mut l), vec![STX], "third attempt");
        l.handle_bytes(ms(932), &[DLE]);
        assert_eq!(tx(&mut l), frame(b"G"));
    }

    #[test]
    fn an_stx_while_backing_off_is_received() {
        let mut l = low();
        l.send(ms(0), b"G".to_vec());
        tx(&mut l);
        l.handle_bytes(ms(1), &[NAK, STX]);
        assert_eq!(tx(&mut l), vec![DLE], "the partner's telegram first");
        l.handle_bytes(ms(5), &frame(b"M024"));
        assert_eq!(tx(&mut l), vec![DLE, STX], "then ours, afresh");
    }

    #[test]
    fn six_transmission_attempts_then_failure() {
        let mut l = low();
        l.send(ms(0), b"H".to_vec());
        let mut blocks = 0;
        for i in 0..20u64 {
            let out = tx(&mut l);
            if out == vec![STX] {
                l.handle_bytes(ms(i), &[DLE]);
            } else if !out.is_empty() {
                blocks += 1;
                // Lost acknowledgement on odd rounds, NAK on even ones.
                if blocks % 2 == 0 {
                    l.handle_bytes(ms(i), &[NAK]);
                }
                if let Some(t) = l.poll_timeout() {
                    l.handle_timeout(t);
                }
            } else {
                break;
            }
        }
        assert_eq!(blocks, 6);
        let evs = events(&mut l);
        // Each lost acknowledgement is a silence of its own (the DLE to
        // each STX was heard in between).
        let silences = evs
            .iter()
            .filter(|e| matches!(e, LinkEvent::Silent(_)))
            .count();
        assert_eq!(silences, 3, "{evs:?}");
        assert!(matches!(
            evs.last(),
            Some(LinkEvent::Failed {
                error: SendError::NotAcknowledged { attempts: 6, .. },
                ..
            })
        ));
    }

    #[test]
    fn initialisation_conflict_goes_to_the_rcm() {
        // Both ends send STX at once.
        let mut ws = low();
        let mut rcm = Link::new(Priority::High, Timing::default());
        ws.send(ms(0), b"S065".to_vec());
        rcm.send(ms(0), b"E064".to_vec());
        let (a, b) = (tx(&mut ws), tx(&mut rcm));
        assert_eq!(
            (a.as_slice(), b.as_slice()),
            ([STX].as_slice(), [STX].as_slice())
        );
        // Each sees the other's STX.
        ws.handle_bytes(ms(1), &b);
        rcm.handle_bytes(ms(1), &a);
        // The workstation yields with DLE; the RCM keeps waiting.
        let ws_out = tx(&mut ws);
        assert_eq!(ws_out, vec![DLE]);
        assert_eq!(tx(&mut rcm), Vec::<u8>::new());
        // Shuttle bytes both ways until both are quiet.
        let mut now = ms(2);
        let mut to_rcm = ws_out;
        for _ in 0..20 {
            rcm.handle_bytes(now, &to_rcm);
            let to_ws = tx(&mut rcm);
            ws.handle_bytes(now, &to_ws);
            to_rcm = tx(&mut ws);
            now += ms(1);
            if ws.is_idle() && rcm.is_idle() && to_rcm.is_empty() {
                break;
            }
        }
        assert_eq!(
            events(&mut ws),
            vec![
                LinkEvent::Received(b"E064".to_vec()),
                LinkEvent::Sent(b"S065".to_vec())
            ]
        );
        assert_eq!(
            events(&mut rcm),
            vec![
                LinkEvent::Sent(b"E064".to_vec()),
                LinkEvent::Received(b"S065".to_vec())
            ]
        );
    }

    mod prop {
        use super::*;
        use proptest::prelude::*;

        /// Two link ends wired back to back, on a virtual clock.
        fn exchange(ws: &mut Link, rcm: &mut Link, now: &mut Duration) {
            for _ in 0..10_000 {
                let a = tx(ws);
                let b = tx(rcm);
                if a.is_empty() && b.is_empty() {
                    match [ws.poll_timeout(), rcm.poll_timeout()]
                        .into_iter()
                        .flatten()
                        .min()
                    {
                        Some(t) => {
                            *now = t;
                            ws.handle_timeout(t);
                            rcm.handle_timeout(t);
                            continue;
                        }
                        None => return,
                    }
                }
                *now += ms(1);
                rcm.handle_bytes(*now, &a);
                ws.handle_bytes(*now, &b);
            }
        }

        #[test]
        fn noise_that_makes_both_ends_receive_at_once_does_not_lock_the_line() {
            // Found by falc-sim (seed 5): an STX in noise reached both ends
            // at once; each answered DLE, took the other's DLE for data,
            // refused with NAK and sent its own STX, backed off on the NAK
            // and yielded to the other's STX, every round the same:
            // both ends received forever and nothing was sent.
            let mut ws = Link::new(Priority::Low, Timing::default());
            let mut rcm = Link::new(Priority::High, Timing::default());
            let mut now = Duration::ZERO;
            ws.handle_bytes(now, &[STX]);
            rcm.handle_bytes(now, &[STX]);
            ws.send(now, b"Q".to_vec());
            rcm.send(now, b"E066O".to_vec());
            exchange(&mut ws, &mut rcm, &mut now);
            let received = |l: &mut Link| -> Vec<Vec<u8>> {
                events(l)
                    .into_iter()
                    .filter_map(|e| match e {
                        LinkEvent::Received(t) => Some(t),
                        _ => None,
                    })
                    .collect()
            };
            assert_eq!(received(&mut rcm), vec![b"Q".to_vec()]);
            assert_eq!(received(&mut ws), vec![b"E066O".to_vec()]);
            assert!(now < Duration::from_secs(10), "took {now:?}");
        }

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(500))]
            #[test]
            fn never_panics_on_any_input(chunks in proptest::collection::vec((proptest::collection::vec(any::<u8>(), 0..16), 0u64..3000), 0..40)) {
                let mut l = Link::new(Priority::Low, Timing::default());
                l.send(Duration::ZERO, b"S065".to_vec());
                let mut now = Duration::ZERO;
                for (bytes, dt) in chunks {
                    now += ms(dt);
                    l.handle_timeout(now);
                    l.handle_bytes(now, &bytes);
                    while l.poll_event().is_some() {}
                    let _ = l.poll_transmit();
                }
            }

            #[test]
            fn any_telegram_arrives_intact(data in proptest::collection::vec(any::<u8>(), 0..200), noise in proptest::collection::vec(any::<u8>(), 0..8)) {
                let mut ws = Link::new(Priority::Low, Timing::default());
                let mut rcm = Link::new(Priority::High, Timing::default());
                let mut now = Duration::ZERO;
                // Noise on an idle line is answered with NAK once quiet (an
                // STX in it starts a block that then times out with NAK;
                // that must not hurt).
                rcm.handle_bytes(now, &noise);
                let _ = tx(&mut rcm);
                if let Some(t) = rcm.poll_timeout() { now = t; rcm.handle_timeout(t); }
                let _ = tx(&mut rcm);
                while rcm.poll_event().is_some() {}
                ws.send(now, data.clone());
                exchange(&mut ws, &mut rcm, &mut now);
                prop_assert_eq!(events(&mut rcm), vec![LinkEvent::Received(data.clone())]);
                prop_assert_eq!(events(&mut ws), vec![LinkEvent::Sent(data)]);
            }
        }
    }
}
