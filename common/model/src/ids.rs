//! Validated identifiers: cell ids, station names, MMS object names, and the
//! numbers recipes name devices by (robot programs, conveyor places and
//! stations), each range written once.
//!
//! Every name that crosses a process boundary or becomes part of a zenoh key
//! is parsed into one of these newtypes once ("parse, don't validate"). Names
//! are case-insensitive, as in the 1992 cell: station names and cell ids are
//! kept in lower case (they are key chunks), MMS object names (domains,
//! program invocations) in upper case (as `#NAME` lines print them).

use std::fmt;

/// At most this many characters of a refused text are quoted back.
pub const EXCERPT_CHARS: usize = 40;

/// A refused text as an error quotes it: the whole when short, else its
/// first [`EXCERPT_CHARS`] characters and how long it was (an error about
/// a megabyte must not send the megabyte back). Control characters are
/// escaped.
pub fn excerpt(text: &str) -> String {
    let count = text.chars().count();
    let head: String = text
        .chars()
        .take(EXCERPT_CHARS)
        .flat_map(char::escape_debug)
        .collect();
    if count > EXCERPT_CHARS {
        format!("{head}… ({count} characters)")
    } else {
        head
    }
}

/// Whether `c` may not reach a terminal or a log as it is: a control
/// character (ESC, CR, BEL, BS, the C1 controls) or a bidirectional
/// formatting character (U+202E, the right-to-left override, and its
/// kin), which reorders what a person reads.
pub fn unprintable(c: char) -> bool {
    c.is_control()
        || matches!(
            c,
            '\u{061C}' | '\u{200E}' | '\u{200F}' | '\u{202A}'..='\u{202E}' | '\u{2066}'..='\u{2069}'
        )
}

/// `text` with every control character (and bidirectional formatting
/// character, [`unprintable`]) escaped (`\u{1b}`, `\n`, …) and
/// everything else as it is: how a text someone else wrote (a journal
/// entry, a recipe's output, a user name) is printed to a terminal or a
/// log, so that it can neither drive the terminal nor forge a line.
pub fn printable(text: &str) -> std::borrow::Cow<'_, str> {
    if !text.chars().any(unprintable) {
        return std::borrow::Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len() + 8);
    for c in text.chars() {
        if unprintable(c) {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    std::borrow::Cow::Owned(out)
}

/// Why a name was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NameError {
    /// The name is empty.
    #[error("{kind} is empty")]
    Empty {
        /// What kind of name it was meant to be.
        kind: &'static str,
    },
    /// The name is longer than the limit.
    #[error("{kind} `{name}` is longer than {max} characters")]
    TooLong {
        /// What kind of name it was meant to be.
        kind: &'static str,
        /// The offending name.
        name: String,
        /// The limit.
        max: usize,
    },
    /// The name holds a character outside the allowed set.
    #[error("{kind} `{name}` has `{}` at position {at}; allowed are {allowed}", bad.escape_debug())]
    BadCharacter {
        /// What kind of name it was meant to be.
        kind: &'static str,
        /// The offending name.
        name: String,
        /// The first bad character.
        bad: char,
        /// Its position (0-based, in characters).
        at: usize,
        /// A description of the allowed set.
        allowed: &'static str,
    },
    /// The name does not start with a letter.
    #[error("{kind} `{name}` must start with a letter")]
    BadStart {
        /// What kind of name it was meant to be.
        kind: &'static str,
        /// The offending name.
        name: String,
    },
}

/// How a name kind is spelled and normalised.
struct NameRule {
    kind: &'static str,
    max: usize,
    upper: bool,
    allowed: &'static str,
    extra: &'static [char],
}

impl NameRule {
    fn parse(&self, raw: &str) -> Result<String, NameError> {
        let kind = self.kind;
        if raw.is_empty() {
            return Err(NameError::Empty { kind });
        }
        if raw.chars().count() > self.max {
            return Err(NameError::TooLong {
                kind,
                name: excerpt(raw),
                max: self.max,
            });
        }
        for (at, c) in raw.chars().enumerate() {
            if !(c.is_ascii_alphanumeric() || self.extra.contains(&c)) {
                return Err(NameError::BadCharacter {
                    kind,
                    name: excerpt(raw),
                    bad: c,
                    at,
                    allowed: self.allowed,
                });
            }
        }
        if !raw.starts_with(|c: char| c.is_ascii_alphabetic()) {
            return Err(NameError::BadStart {
                kind,
                name: excerpt(raw),
            });
        }
        Ok(if self.upper {
            raw.to_ascii_uppercase()
        } else {
            raw.to_ascii_lowercase()
        })
    }
}

macro_rules! name_newtype {
    ($(#[$doc:meta])* $name:ident, $rule:expr) => {
        $(#[$doc])*
        #[derive(Clone, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize)]
        #[serde(try_from = "String", into = "String")]
        pub struct $name(String);

        impl $name {
            /// Parses and normalises a name.
            pub fn new(raw: &str) -> Result<Self, NameError> {
                $rule.parse(raw).map(Self)
            }

            /// The normalised name.
            pub fn as_str(&self) -> &str {
                &self.0
            }
        }

        impl std::str::FromStr for $name {
            type Err = NameError;
            fn from_str(raw: &str) -> Result<Self, NameError> {
                Self::new(raw)
            }
        }

        impl TryFrom<String> for $name {
            type Error = NameError;
            fn try_from(raw: String) -> Result<Self, NameError> {
                Self::new(&raw)
            }
        }

        impl From<$name> for String {
            fn from(name: $name) -> String {
                name.0
            }
        }

        /// Compared with a text as it is written (a name is normalised:
        /// `WELDING` is no station name `welding` is).
        impl PartialEq<str> for $name {
            fn eq(&self, other: &str) -> bool {
                self.0 == other
            }
        }

        impl PartialEq<&str> for $name {
            fn eq(&self, other: &&str) -> bool {
                self.0 == *other
            }
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(&self.0)
            }
        }

        impl fmt::Debug for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, "{}({:?})", stringify!($name), self.0)
            }
        }
    };
}

const KEY_CHUNK: NameRule = NameRule {
    kind: "station name",
    max: 32,
    upper: false,
    allowed: "letters, digits, `_` and `-`",
    extra: &['_', '-'],
};

name_newtype!(
    /// A station of the cell (`operator`, `cell`, `welding`, …): a zenoh key
    /// chunk and the zenoh user name of the node. Lower case.
    StationName,
    KEY_CHUNK
);

name_newtype!(
    /// The id of a cell (`falc1`): the second chunk of every key. Lower case.
    CellId,
    NameRule {
        kind: "cell id",
        ..KEY_CHUNK
    }
);

name_newtype!(
    /// An MMS object name: a domain (recipe text) or a program invocation
    /// (a runnable recipe, the `#NAME` of a workstation recipe). Upper case.
    ObjectName,
    NameRule {
        kind: "object name",
        max: 32,
        upper: true,
        allowed: "letters, digits, `_` and `$`",
        extra: &['_', '$'],
    }
);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_long_refused_name_is_quoted_by_a_short_excerpt() {
        let huge = "x".repeat(1_000_000);
        let e = ObjectName::new(&huge).expect_err("too long");
        let text = e.to_string();
        assert!(text.len() < 200, "{} bytes", text.len());
        assert!(text.contains("(1000000 characters)"), "{text}");
        assert_eq!(excerpt("ja\nnee"), "ja\\nnee");
        assert_eq!(excerpt("kort"), "kort");
    }

    #[test]
    fn station_names_are_lower_case_key_chunks() {
        assert_eq!(
            StationName::new("Welding").map(|s| s.0),
            Ok("welding".into())
        );
        assert!(matches!(
            StationName::new("wel/ding"),
            Err(NameError::BadCharacter {
                bad: '/',
                at: 3,
                ..
            })
        ));
        assert!(matches!(
            StationName::new("*"),
            Err(NameError::BadCharacter { .. })
        ));
        assert!(matches!(StationName::new(""), Err(NameError::Empty { .. })));
        assert!(matches!(
            StationName::new("1st"),
            Err(NameError::BadStart { .. })
        ));
        assert!(matches!(
            StationName::new(&"a".repeat(33)),
            Err(NameError::TooLong { max: 32, .. })
        ));
    }

    #[test]
    fn io_names_are_short_lower_case_words() {
        assert_eq!(
            IoName::parse("Door_Closed").map(|n| n.to_string()),
            Ok("door_closed".into())
        );
        assert!(IoName::parse("2door").is_err());
        assert!(IoName::parse("door closed").is_err());
        assert!(IoName::parse("").is_err());
        assert!(IoName::parse("a_very_long_name_x")
            .unwrap_err()
            .contains("at most 16"));
        assert_eq!(IoName::parse("beacon"), IoName::parse("BEACON"));
    }

    #[test]
    fn object_names_are_upper_case() {
        assert_eq!(
            ObjectName::new("droog_dik").map(|s| s.0),
            Ok("DROOG_DIK".into())
        );
        assert!(ObjectName::new("droog-dik").is_err());
    }

    #[test]
    fn serde_validates() {
        let ok: Result<StationName, _> = serde_json::from_str("\"Cell\"");
        assert_eq!(ok.map(|s| s.0).ok(), Some("cell".to_string()));
        let bad: Result<StationName, _> = serde_json::from_str("\"a b\"");
        assert!(bad.is_err());
    }
}

macro_rules! number_newtype {
    ($(#[$doc:meta])* $name:ident($ty:ty), $lo:literal..=$hi:literal, $what:literal) => {
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
        pub struct $name($ty);

        impl $name {
            /// The smallest.
            pub const MIN: Self = Self($lo);
            /// The largest.
            pub const MAX: Self = Self($hi);

            /// The number, if in range.
            pub const fn new(n: $ty) -> Option<Self> {
                if n >= $lo && n <= $hi {
                    Some(Self(n))
                } else {
                    None
                }
            }

            /// A number known to be in range (a constant in code or a
            /// test); panics, naming it, if it is not.
            pub const fn of(n: $ty) -> Self {
                match Self::new(n) {
                    Some(s) => s,
                    None => panic!(concat!("not ", $what, " (", $lo, "–", $hi, ")")),
                }
            }

            /// Parses a decimal number; the error says what it is not.
            pub fn parse(s: &str) -> Result<Self, String> {
                s.parse::<$ty>()
                    .ok()
                    .and_then(Self::new)
                    .ok_or_else(|| {
                        format!(concat!("`{}` is not ", $what, " ({}–{})"), excerpt(s), $lo, $hi)
                    })
            }

            /// The number.
            pub const fn number(self) -> $ty {
                self.0
            }

            /// Every one, in order.
            pub fn all() -> impl Iterator<Item = Self> {
                ($lo..=$hi).map(Self)
            }
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, "{}", self.0)
            }
        }
    };
}

/// The name of a plain input or output of a conveyor PLC (`door_closed`,
/// `beacon`): a lower-case word, a letter first, then letters, digits and
/// `_`, at most 16 characters. What a transport recipe's `set` and
/// `waitinput` name, and the equipment file's `output NAME` / `input
/// NAME`. Kept inline (it is `Copy`, like a line letter or a place), so
/// that a signal of any kind is a small value.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct IoName {
    len: u8,
    bytes: [u8; IoName::MAX_LEN],
}

impl IoName {
    /// The longest name.
    pub const MAX_LEN: usize = 16;

    /// Parses a name as a recipe or a file writes it (any case; kept in
    /// lower case); the error says what it is not.
    pub fn parse(s: &str) -> Result<Self, String> {
        let lower = s.trim().to_ascii_lowercase();
        let ok = lower.len() <= Self::MAX_LEN
            && lower.starts_with(|c: char| c.is_ascii_lowercase())
            && lower
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
        if !ok {
            return Err(format!(
                "`{}` is not an input or output name (a word: a letter, then letters, digits \
                 or _, at most {} characters)",
                excerpt(s),
                Self::MAX_LEN
            ));
        }
        let mut bytes = [0u8; Self::MAX_LEN];
        bytes[..lower.len()].copy_from_slice(lower.as_bytes());
        Ok(Self {
            len: lower.len() as u8,
            bytes,
        })
    }

    /// The name.
    pub fn as_str(&self) -> &str {
        // Only ASCII is ever stored (`parse`).
        std::str::from_utf8(&self.bytes[..usize::from(self.len)]).unwrap_or("")
    }
}

impl fmt::Display for IoName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl fmt::Debug for IoName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "IoName({})", self.as_str())
    }
}

number_newtype!(
    /// A robot program number, 1–999: what a welding recipe's `start rcm N`
    /// names and the DNC link's `S` telegram selects.
    RobotProgram(u16), 1..=999, "a robot program number"
);

impl RobotProgram {
    /// Its domain at a welding station (`PROGRAM_065`): a robot program
    /// from the recipe store is delivered as a domain of that name, which
    /// the welding station passes on to its robot controller.
    pub fn domain(self) -> ObjectName {
        ObjectName(format!("PROGRAM_{:03}", self.0))
    }

    /// The program whose domain is `name`, if it is one ([`Self::domain`]).
    pub fn of_domain(name: &ObjectName) -> Option<Self> {
        let digits = name.as_str().strip_prefix("PROGRAM_")?;
        (digits.len() == 3 && digits.bytes().all(|b| b.is_ascii_digit()))
            .then(|| digits.parse().ok().and_then(Self::new))
            .flatten()
    }
}

number_newtype!(
    /// A conveyor place with a presence sensor, 1–99 (`W2`–`W6` on the
    /// thesis' layout): what a transport recipe waits for and the PLC map
    /// reads. Which places a conveyor has is its equipment file's.
    Place(u8), 1..=99, "a place"
);

number_newtype!(
    /// A conveyor station with a button and a busy lamp, 1–99 (`S1`–`S3`
    /// on the thesis' layout); which stations a conveyor has is its
    /// equipment file's.
    PlcStation(u8), 1..=99, "a station"
);

#[cfg(test)]
mod number_tests {
    use super::*;

    #[test]
    fn ranges_are_checked_in_one_place() {
        assert_eq!(RobotProgram::parse("65").map(RobotProgram::number), Ok(65));
        let d = RobotProgram::of(65).domain();
        assert_eq!(d.as_str(), "PROGRAM_065");
        assert_eq!(RobotProgram::of_domain(&d), Some(RobotProgram::of(65)));
        for other in [
            "PROGRAM_65",
            "PROGRAM_000",
            "PROGRAM_0651",
            "DROOG_DIK",
            "WELDING$PROGRAM_065",
        ] {
            let name = ObjectName::new(other).expect("a name");
            assert_eq!(RobotProgram::of_domain(&name), None, "{other}");
        }
        assert_eq!(
            RobotProgram::parse("1000"),
            Err("`1000` is not a robot program number (1–999)".into())
        );
        assert!(RobotProgram::parse("0").is_err() && RobotProgram::parse("x").is_err());
        assert_eq!(
            Place::parse("100"),
            Err("`100` is not a place (1–99)".into())
        );
        assert_eq!(Place::all().count(), 99);
        assert_eq!(PlcStation::new(0), None);
        assert_eq!(PlcStation::MAX.to_string(), "99");
    }

    #[test]
    fn printable_escapes_control_characters_only() {
        assert_eq!(printable("staat blok 1 ë ?"), "staat blok 1 ë ?");
        assert_eq!(
            printable("B\n\u{1b}]0;owned\u{7}\u{1b}[2J"),
            "B\\n\\u{1b}]0;owned\\u{7}\\u{1b}[2J"
        );
        assert!(!printable("\r\t\u{0}").chars().any(char::is_control));
        assert_eq!(
            printable("ja\u{202e}nee\u{2066}\u{9b}2J"),
            "ja\\u{202e}nee\\u{2066}\\u{9b}2J"
        );
    }
}
