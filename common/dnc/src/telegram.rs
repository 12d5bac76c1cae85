//! DNC telegrams carried by 3964R between the welding workstation (host)
//! and the RCM 815: ASCII, one code letter, fixed-width fields.
//!
//! | code | direction | telegram | fields |
//! |---|---|---|---|
//! | `I` | host → RCM | initiate DNC | — |
//! | `C` | host → RCM | close DNC | — |
//! | `S` | host → RCM | select program | program, 3 digits |
//! | `G` | host → RCM | start the selected program | — |
//! | `H` | host → RCM | stop (halt) the program | — |
//! | `Q` | host → RCM | status request | — |
//! | `K` | host → RCM | confirm an alarm (codes the table marks "confirm") | code, 3 digits |
//! | `A` | RCM → host | acknowledgement | the code acknowledged, 1 letter; error, 2 digits (`00` = done) |
//! | `P` | RCM → host | program status | program, 3 digits; state, 1 letter (`I` idle, `L` selected, `R` running, `P` paused, `S` stopped); mode, 1 letter (`M` manual, `A` automatic, `E` automatic-external with DNC) |
//! | `E` | RCM → host | program end | program, 3 digits; result, 1 letter (`O` complete, `B` weld aborted: bad product) |
//! | `M` | RCM → host | alarm message | code, 3 digits |
//!
//! Acknowledgement errors: see [`AckError`]; each maps to an ISO 9506
//! error in [`AckError::to_service_error`].

use falc_model::ids::RobotProgram;
use falc_model::mms::error::{
    DefinitionError, ErrorClass, ServiceError, ServiceErrorCode, VmdStateError,
};

/// The RCM's operating mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Manual (teach pendant).
    Manual,
    /// Automatic, local.
    Automatic,
    /// Automatic external with DNC: the only mode that takes remote commands.
    AutomaticExternal,
}

/// A program's state as the RCM reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProgramState {
    /// No program selected.
    Idle,
    /// Selected, not running.
    Selected,
    /// Running.
    Running,
    /// Motion paused (a person in the work area).
    Paused,
    /// Stopped before its end.
    Stopped,
}

/// How a program ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EndResult {
    /// Complete.
    Complete,
    /// The weld was aborted: the product is bad.
    WeldAborted,
}

/// An acknowledgement error from the RCM.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AckError {
    /// `01`: not in automatic-external mode with DNC.
    NotInDncMode,
    /// `02`: no such program.
    UnknownProgram,
    /// `03`: start without a selected program.
    NoProgramSelected,
    /// `04`: a program is running.
    ProgramRunning,
    /// `05`: no program is running.
    NotRunning,
    /// `06`: emergency stop active.
    EmergencyStop,
    /// `07`: the telegram was not understood.
    Malformed,
    /// Any other code.
    Other(u8),
}

impl AckError {
    fn code(self) -> u8 {
        match self {
            Self::NotInDncMode => 1,
            Self::UnknownProgram => 2,
            Self::NoProgramSelected => 3,
            Self::ProgramRunning => 4,
            Self::NotRunning => 5,
            Self::EmergencyStop => 6,
            Self::Malformed => 7,
            Self::Other(n) => n,
        }
    }

    fn from_code(n: u8) -> Option<Self> {
        Some(match n {
            0 => return None,
            1 => Self::NotInDncMode,
            2 => Self::UnknownProgram,
            3 => Self::NoProgramSelected,
            4 => Self::ProgramRunning,
            5 => Self::NotRunning,
            6 => Self::EmergencyStop,
            7 => Self::Malformed,
            n => Self::Other(n),
        })
    }

    /// Whether a spoilt telegram may have caused this refusal rather than
    /// the RCM's state: 3964R's block check is an XOR, so two flips in one
    /// bit column pass it, and a program number or command spoilt that way
    /// comes back as an unknown program, a start with none selected or a
    /// telegram not understood. Sending the select again is worth it once.
    pub fn may_be_noise(self) -> bool {
        matches!(
            self,
            Self::UnknownProgram | Self::NoProgramSelected | Self::Malformed
        )
    }

    /// The ISO 9506 error the workstation answers with.
    pub fn to_service_error(self) -> ServiceError {
        let (class, text) = match self {
            Self::NotInDncMode => (
                ErrorClass::VmdState(VmdStateError::VmdStateConflict),
                "the RCM is not in automatic-external mode with DNC",
            ),
            Self::UnknownProgram => (
                ErrorClass::Definition(DefinitionError::ObjectUndefined),
                "the RCM has no such program",
            ),
            Self::NoProgramSelected => (
                ErrorClass::Service(ServiceErrorCode::ObjectStateConflict),
                "no program is selected on the RCM",
            ),
            Self::ProgramRunning => (
                ErrorClass::Service(ServiceErrorCode::ObjectStateConflict),
                "a program is running on the RCM",
            ),
            Self::NotRunning => (
                ErrorClass::Service(ServiceErrorCode::ObjectStateConflict),
                "no program is running on the RCM",
            ),
            Self::EmergencyStop => (
                ErrorClass::VmdState(VmdStateError::VmdOperationalProblem),
                "emergency stop is active on the RCM",
            ),
            Self::Malformed => (
                ErrorClass::Service(ServiceErrorCode::Other),
                "the RCM did not understand the telegram",
            ),
            Self::Other(_) => (
                ErrorClass::VmdState(VmdStateError::Other),
                "the RCM refused",
            ),
        };
        ServiceError::new(class, format!("{text} (DNC error {:02})", self.code()))
    }
}

/// A DNC telegram.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Telegram {
    /// `I`.
    InitiateDnc,
    /// `C`.
    CloseDnc,
    /// `S`.
    SelectProgram(RobotProgram),
    /// `G`.
    StartProgram,
    /// `H`.
    StopProgram,
    /// `Q`.
    StatusRequest,
    /// `K`.
    ConfirmAlarm(u16),
    /// `A`: the code acknowledged and the error, if any.
    Ack {
        /// The code letter of the acknowledged telegram.
        of: u8,
        /// The error (None = done).
        error: Option<AckError>,
    },
    /// `P`.
    ProgramStatus {
        /// The program (None when idle: `000`).
        program: Option<RobotProgram>,
        /// Its state.
        state: ProgramState,
        /// The RCM's mode.
        mode: Mode,
    },
    /// `E`.
    ProgramEnd {
        /// The program.
        program: RobotProgram,
        /// How it ended.
        result: EndResult,
    },
    /// `M`.
    Alarm(u16),
}

/// Why bytes are not a telegram.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TelegramError {
    /// No bytes.
    #[error("empty telegram")]
    Empty,
    /// An unknown code letter.
    #[error("unknown telegram code 0x{0:02x}")]
    UnknownCode(u8),
    /// The wrong length for its code.
    #[error("telegram `{code}` must be {expected} bytes, is {found}")]
    Length {
        /// The code letter.
        code: char,
        /// Expected length.
        expected: usize,
        /// Found length.
        found: usize,
    },
    /// A field with a bad value.
    #[error("telegram `{code}`: bad {field} `{value}`")]
    Field {
        /// The code letter.
        code: char,
        /// The field.
        field: &'static str,
        /// Its bytes, escaped.
        value: String,
    },
}

fn digits(code: char, field: &'static str, b: &[u8]) -> Result<u16, TelegramError> {
    let bad = || TelegramError::Field {
        code,
        field,
        value: b.escape_ascii().to_string(),
    };
    if b.is_empty() || !b.iter().all(u8::is_ascii_digit) {
        return Err(bad());
    }
    std::str::from_utf8(b)
        .ok()
        .and_then(|s| s.parse().ok())
        .ok_or_else(bad)
}

impl Telegram {
    /// The bytes of the telegram.
    pub fn encode(&self) -> Vec<u8> {
        let s = match self {
            Self::InitiateDnc => "I".to_string(),
            Self::CloseDnc => "C".to_string(),
            Self::SelectProgram(p) => format!("S{:03}", p.number()),
            Self::StartProgram => "G".to_string(),
            Self::StopProgram => "H".to_string(),
            Self::StatusRequest => "Q".to_string(),
            Self::ConfirmAlarm(c) => format!("K{:03}", c.min(&999)),
            Self::Ack { of, error } => format!(
                "A{}{:02}",
                *of as char,
                error.map_or(0, |e| e.code().min(99))
            ),
            Self::ProgramStatus {
                program,
                state,
                mode,
            } => format!(
                "P{:03}{}{}",
                program.map_or(0, |p| p.number()),
                match state {
                    ProgramState::Idle => 'I',
                    ProgramState::Selected => 'L',
                    ProgramState::Running => 'R',
                    ProgramState::Paused => 'P',
                    ProgramState::Stopped => 'S',
                },
                match mode {
                    Mode::Manual => 'M',
                    Mode::Automatic => 'A',
                    Mode::AutomaticExternal => 'E',
                }
            ),
            Self::ProgramEnd { program, result } => format!(
                "E{:03}{}",
                program.number(),
                match result {
                    EndResult::Complete => 'O',
                    EndResult::WeldAborted => 'B',
                }
            ),
            Self::Alarm(c) => format!("M{:03}", c.min(&999)),
        };
        s.into_bytes()
    }

    /// Decodes a telegram; never panics.
    pub fn decode(b: &[u8]) -> Result<Self, TelegramError> {
        let (&code, rest) = b.split_first().ok_or(TelegramError::Empty)?;
        let c = code as char;
        let len = |n: usize| {
            if b.len() == n {
                Ok(())
            } else {
                Err(TelegramError::Length {
                    code: c,
                    expected: n,
                    found: b.len(),
                })
            }
        };
        let field = |field: &'static str, v: &[u8]| TelegramError::Field {
            code: c,
            field,
            value: v.escape_ascii().to_string(),
        };
        let program = |v: &[u8]| -> Result<RobotProgram, TelegramError> {
            RobotProgram::new(digits(c, "program", v)?).ok_or_else(|| field("program", v))
        };
        Ok(match code {
            b'I' => len(1).map(|()| Self::InitiateDnc)?,
            b'C' => len(1).map(|()| Self::CloseDnc)?,
            b'G' => len(1).map(|()| Self::StartProgram)?,
            b'H' => len(1).map(|()| Self::StopProgram)?,
            b'Q' => len(1).map(|()| Self::StatusRequest)?,
            b'S' => {
                len(4)?;
                Self::SelectProgram(program(rest)?)
            }
            b'K' => {
                len(4)?;
                Self::ConfirmAlarm(digits(c, "alarm code", rest)?)
            }
            b'M' => {
                len(4)?;
                Self::Alarm(digits(c, "alarm code", rest)?)
            }
            b'A' => {
                len(4)?;
                let &[of, ref error @ ..] = rest else {
                    return Err(field("acknowledgement", rest));
                };
                if !of.is_ascii_uppercase() {
                    return Err(field("acknowledged code", &[of]));
                }
                let n = digits(c, "error", error)?;
                Self::Ack {
                    of,
                    error: AckError::from_code(n as u8),
                }
            }
            b'P' => {
                len(6)?;
                let &[p0, p1, p2, state, mode] = rest else {
                    return Err(field("program status", rest));
                };
                let number = [p0, p1, p2];
                let n = digits(c, "program", &number)?;
                let program = if n == 0 {
                    None
                } else {
                    Some(program(&number)?)
                };
                let state = match state {
                    b'I' => ProgramState::Idle,
                    b'L' => ProgramState::Selected,
                    b'R' => ProgramState::Running,
                    b'P' => ProgramState::Paused,
                    b'S' => ProgramState::Stopped,
                    _ => return Err(field("program state", &[state])),
                };
                let mode = match mode {
                    b'M' => Mode::Manual,
                    b'A' => Mode::Automatic,
                    b'E' => Mode::AutomaticExternal,
                    _ => return Err(field("mode", &[mode])),
                };
                Self::ProgramStatus {
                    program,
                    state,
                    mode,
                }
            }
            b'E' => {
                len(5)?;
                let &[p0, p1, p2, result] = rest else {
                    return Err(field("program end", rest));
                };
                let result = match result {
                    b'O' => EndResult::Complete,
                    b'B' => EndResult::WeldAborted,
                    _ => return Err(field("result", &[result])),
                };
                Self::ProgramEnd {
                    program: program(&[p0, p1, p2])?,
                    result,
                }
            }
            other => return Err(TelegramError::UnknownCode(other)),
        })
    }
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn p(n: u16) -> RobotProgram {
        RobotProgram::of(n)
    }

    #[test]
    fn every_telegram_round_trips() {
        let all = [
            Telegram::InitiateDnc,
            Telegram::CloseDnc,
            Telegram::SelectProgram(p(65)),
            Telegram::StartProgram,
            Telegram::StopProgram,
            Telegram::StatusRequest,
            Telegram::ConfirmAlarm(3),
            Telegram::Ack {
                of: b'S',
                error: None,
            },
            Telegram::Ack {
                of: b'G',
                error: Some(AckError::NotInDncMode),
            },
            Telegram::Ack {
                of: b'G',
                error: Some(AckError::Other(42)),
            },
            Telegram::ProgramStatus {
                program: None,
                state: ProgramState::Idle,
                mode: Mode::AutomaticExternal,
            },
            Telegram::ProgramStatus {
                program: Some(p(10)),
                state: ProgramState::Paused,
                mode: Mode::Manual,
            },
            Telegram::ProgramEnd {
                program: p(66),
                result: EndResult::WeldAborted,
            },
            Telegram::Alarm(24),
        ];
        for t in all {
            assert_eq!(Telegram::decode(&t.encode()), Ok(t.clone()), "{t:?}");
        }
        assert_eq!(Telegram::SelectProgram(p(64)).encode(), b"S064");
        assert_eq!(
            Telegram::ProgramEnd {
                program: p(65),
                result: EndResult::Complete
            }
            .encode(),
            b"E065O"
        );
    }

    #[test]
    fn errors_name_what_is_wrong() {
        assert_eq!(Telegram::decode(b""), Err(TelegramError::Empty));
        assert_eq!(
            Telegram::decode(b"Z"),
            Err(TelegramError::UnknownCode(b'Z'))
        );
        assert_eq!(
            Telegram::decode(b"S64"),
            Err(TelegramError::Length {
                code: 'S',
                expected: 4,
                found: 3
            })
        );
        assert!(matches!(
            Telegram::decode(b"S000"),
            Err(TelegramError::Field {
                field: "program",
                ..
            })
        ));
        assert!(matches!(
            Telegram::decode(b"S0x4"),
            Err(TelegramError::Field {
                field: "program",
                ..
            })
        ));
        assert!(matches!(
            Telegram::decode(b"P064XE"),
            Err(TelegramError::Field {
                field: "program state",
                ..
            })
        ));
        assert_eq!(
            AckError::NotInDncMode.to_service_error().to_string(),
            "vmd-state/vmd-state-conflict: the RCM is not in automatic-external mode with DNC (DNC error 01)"
        );
    }

    proptest! {
        #[test]
        fn decode_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..12)) {
            if let Ok(t) = Telegram::decode(&bytes) {
                // Whatever decodes, re-encodes to bytes that decode the same.
                prop_assert_eq!(Telegram::decode(&t.encode()), Ok(t));
            }
        }
    }
}
