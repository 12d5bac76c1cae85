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
//! | `D` | both | program text follows (a download, or an upload's answer) | program, 3 digits; lines, 3 digits; text hash, 8 hex digits |
//! | `T` | both | one line of the text | line number, 3 digits (from 001); the line, 0–60 bytes of printable ASCII |
//! | `F` | both | the text is complete: store it (download) / end of the text (upload) | program, 3 digits |
//! | `U` | host → RCM | upload a program's text | program, 3 digits |
//! | `L` | host → RCM | list the stored programs | — |
//! | `N` | RCM → host | one stored program (one per program, then `A L 00`) | program, 3 digits; lines, 3 digits; text hash, 8 hex digits |
//!
//! The program-transfer telegrams (`D` … `N`) are FALC's, not the 1992
//! set's: docs/dnc.md specifies them.
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
    /// `08`: a program text refused (lines missing, its hash wrong, not a
    /// program).
    TextRefused,
    /// `09`: a line or an end with no download open.
    NoDownload,
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
            Self::TextRefused => 8,
            Self::NoDownload => 9,
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
            8 => Self::TextRefused,
            9 => Self::NoDownload,
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
            Self::TextRefused => (
                ErrorClass::Definition(DefinitionError::ObjectAttributeInconsistent),
                "the RCM refused the program text",
            ),
            Self::NoDownload => (
                ErrorClass::Service(ServiceErrorCode::ObjectStateConflict),
                "no program download is open on the RCM",
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
    /// `D`: a program's text follows.
    Text {
        /// The program.
        program: RobotProgram,
        /// How many lines (`T`) follow.
        lines: u16,
        /// The text's hash ([`falc_recipe::robot_program::text_hash`]).
        hash: u32,
    },
    /// `T`: one line of a text.
    Line {
        /// Its number, from 1.
        no: u16,
        /// The line.
        text: String,
    },
    /// `F`: the text of the program is complete.
    TextEnd(RobotProgram),
    /// `U`: send me the program's text.
    Upload(RobotProgram),
    /// `L`: list the stored programs.
    List,
    /// `N`: one stored program.
    Stored {
        /// The program.
        program: RobotProgram,
        /// Its lines.
        lines: u16,
        /// Its text's hash.
        hash: u32,
    },
}

/// The longest line a `T` telegram carries.
pub const MAX_LINE: usize = falc_recipe::robot_program::MAX_LINE;

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
            Self::Text {
                program,
                lines,
                hash,
            } => format!("D{:03}{:03}{hash:08X}", program.number(), lines.min(&999)),
            Self::Line { no, text } => format!("T{:03}{text}", no.min(&999)),
            Self::TextEnd(p) => format!("F{:03}", p.number()),
            Self::Upload(p) => format!("U{:03}", p.number()),
            Self::List => "L".to_string(),
            Self::Stored {
                program,
                lines,
                hash,
            } => format!("N{:03}{:03}{hash:08X}", program.number(), lines.min(&999)),
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
            b'L' => len(1).map(|()| Self::List)?,
            b'F' => {
                len(4)?;
                Self::TextEnd(program(rest)?)
            }
            b'U' => {
                len(4)?;
                Self::Upload(program(rest)?)
            }
            b'D' | b'N' => {
                len(15)?;
                let (p, more) = rest.split_at(3);
                let (lines, hash) = more.split_at(3);
                let program = program(p)?;
                let lines = digits(c, "lines", lines)?;
                let hash = std::str::from_utf8(hash)
                    .ok()
                    .filter(|h| h.bytes().all(|b| b.is_ascii_hexdigit()))
                    .and_then(|h| u32::from_str_radix(h, 16).ok())
                    .ok_or_else(|| field("hash", hash))?;
                if code == b'D' {
                    Self::Text {
                        program,
                        lines,
                        hash,
                    }
                } else {
                    Self::Stored {
                        program,
                        lines,
                        hash,
                    }
                }
            }
            b'T' => {
                if b.len() < 4 || b.len() > 4 + MAX_LINE {
                    return Err(TelegramError::Length {
                        code: c,
                        expected: if b.len() < 4 { 4 } else { 4 + MAX_LINE },
                        found: b.len(),
                    });
                }
                let (no, text) = rest.split_at(3);
                let no = digits(c, "line number", no)?;
                if no == 0 {
                    return Err(field("line number", b"000"));
                }
                if !text.iter().all(|b| b.is_ascii_graphic() || *b == b' ') {
                    return Err(field("line", text));
                }
                Self::Line {
                    no,
                    text: String::from_utf8_lossy(text).into_owned(),
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

    /// The program-transfer telegrams: their framing, a line's length
    /// and characters, a hash that is not hex, a line numbered 0, and the
    /// RCM's refusals as ISO 9506 errors.
    #[test]
    fn the_program_transfer_telegrams_frame_and_refuse_what_is_wrong() {
        let all = [
            Telegram::Text {
                program: p(65),
                lines: 5,
                hash: 0x0A1B_2C3D,
            },
            Telegram::Line {
                no: 1,
                text: "program 65".into(),
            },
            Telegram::Line {
                no: 999,
                text: String::new(),
            },
            Telegram::TextEnd(p(65)),
            Telegram::Upload(p(7)),
            Telegram::List,
            Telegram::Stored {
                program: p(65),
                lines: 5,
                hash: 0xFFFF_FFFF,
            },
            Telegram::Ack {
                of: b'F',
                error: Some(AckError::TextRefused),
            },
            Telegram::Ack {
                of: b'T',
                error: Some(AckError::NoDownload),
            },
        ];
        for t in all {
            assert_eq!(Telegram::decode(&t.encode()), Ok(t.clone()), "{t:?}");
        }
        let text = Telegram::Text {
            program: p(65),
            lines: 5,
            hash: 0x0A1B_2C3D,
        };
        assert_eq!(text.encode(), b"D0650050A1B2C3D");
        assert_eq!(
            Telegram::Line {
                no: 3,
                text: "weld seam_1 100".into()
            }
            .encode(),
            b"T003weld seam_1 100"
        );
        // Bad lengths.
        assert_eq!(
            Telegram::decode(b"D065005A1B2C3D"),
            Err(TelegramError::Length {
                code: 'D',
                expected: 15,
                found: 14
            })
        );
        assert!(matches!(
            Telegram::decode(b"T01"),
            Err(TelegramError::Length { code: 'T', .. })
        ));
        let long = format!("T001{}", "x".repeat(MAX_LINE + 1));
        assert_eq!(
            Telegram::decode(long.as_bytes()),
            Err(TelegramError::Length {
                code: 'T',
                expected: 4 + MAX_LINE,
                found: 5 + MAX_LINE
            })
        );
        assert!(matches!(
            Telegram::decode(b"L1"),
            Err(TelegramError::Length { code: 'L', .. })
        ));
        // Bad fields.
        assert!(matches!(
            Telegram::decode(b"D065005ZZ1B2C3D"),
            Err(TelegramError::Field { field: "hash", .. })
        ));
        assert!(matches!(
            Telegram::decode(b"T000move a 1"),
            Err(TelegramError::Field {
                field: "line number",
                ..
            })
        ));
        assert!(matches!(
            Telegram::decode(b"T001move\ta 1"),
            Err(TelegramError::Field { field: "line", .. })
        ));
        assert!(matches!(
            Telegram::decode(b"F000"),
            Err(TelegramError::Field {
                field: "program",
                ..
            })
        ));
        assert_eq!(
            AckError::TextRefused.to_service_error().to_string(),
            "definition/object-attribute-inconsistent: the RCM refused the program text (DNC error 08)"
        );
    }

    proptest! {
        #[test]
        fn decode_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..70)) {
            if let Ok(t) = Telegram::decode(&bytes) {
                // Whatever decodes, re-encodes to bytes that decode the same.
                prop_assert_eq!(Telegram::decode(&t.encode()), Ok(t));
            }
        }
    }
}
