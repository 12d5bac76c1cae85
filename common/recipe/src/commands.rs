//! The command sets, as data: one [`CommandSpec`] per command and
//! controller kind (recipes/README.md). Adding a command is one entry here and
//! one [`Handler`] arm in the engine.

use super::syntax::Criterion;
use std::fmt;
use std::str::FromStr;

/// Which controller runs a recipe: decides its command set.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum RecipeKind {
    /// The cell controller.
    Cell,
    /// A welding workstation.
    Welding,
    /// A transport workstation.
    Transport,
}

impl RecipeKind {
    /// Every kind.
    pub const ALL: [RecipeKind; 3] = [RecipeKind::Cell, RecipeKind::Welding, RecipeKind::Transport];

    /// Whether recipes of this kind are started by name (`#NAME` required).
    pub fn is_workstation(self) -> bool {
        self != RecipeKind::Cell
    }
}

impl fmt::Display for RecipeKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Cell => "cell",
            Self::Welding => "welding",
            Self::Transport => "transport",
        })
    }
}

impl FromStr for RecipeKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "cell" => Ok(Self::Cell),
            "welding" => Ok(Self::Welding),
            "transport" => Ok(Self::Transport),
            other => Err(format!(
                "unknown recipe kind `{other}` (cell, welding, transport)"
            )),
        }
    }
}

/// The kind of one argument.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Arg {
    /// A workstation name (cell: `welding`, `transport`, …).
    Station,
    /// The literal `rcm` (welding: the robot controller).
    Rcm,
    /// A workstation recipe name (`#NAME`).
    RecipeName,
    /// A robot program number (1–999).
    Program,
    /// A time limit in seconds (1–86400).
    Seconds,
    /// An optional time limit in seconds, last.
    OptSeconds,
    /// A conveyor line button (a letter), or a station button (a number).
    Button,
    /// A conveyor line (a letter A–Z but I and O).
    Line,
    /// A place with a presence sensor, 1–99.
    Place,
    /// A station 1–99.
    StationNo,
    /// A plain output of the equipment (a word: `beacon`).
    OutputName,
    /// A plain input of the equipment (a word: `door_closed`).
    InputName,
    /// 1 (active, occupied, busy) or 0 (not).
    Level,
    /// Free text (the rest of the column).
    Text,
}

/// What the engine does for a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Handler {
    /// Start a job one level down; criteria started / timeout.
    Start,
    /// Wait for a job one level down to end; done / timeout / failures.
    Wait,
    /// Show text to the operator; no criterion.
    Output,
    /// Ask the operator; answer=… criteria.
    Input,
    /// Press a button on the PLC; no criterion.
    Activate,
    /// Release a button on the PLC; no criterion.
    Reset,
    /// Set a plain output on (1) or off (0); no criterion.
    Set,
    /// Wait for a PLC input to reach a level; done / timeout.
    WaitInput,
    /// Wait until the robot is ready for DNC commands (automatic-external
    /// mode, the DNC link answering); done / timeout.
    WaitReady,
}

impl Handler {
    /// Whether the state waits for something (else it moves on at once).
    pub fn waits(self) -> bool {
        matches!(
            self,
            Self::Start | Self::Wait | Self::Input | Self::WaitInput | Self::WaitReady
        )
    }
}

/// The criteria a command allows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Criteria {
    /// None: exactly one row, no criterion.
    None,
    /// `started`, `timeout`.
    Start,
    /// `done`, `timeout`, `bad_product`, `failed_safe`, `failed_danger`.
    Wait,
    /// `done`, `timeout`.
    DoneOrTimeout,
    /// `answer=…`, `answer=*`.
    Answer,
}

impl Criteria {
    /// Whether `c` is allowed.
    pub fn allows(self, c: &Criterion) -> bool {
        use Criterion as C;
        match self {
            Self::None => false,
            Self::Start => matches!(c, C::Started | C::Timeout),
            Self::Wait => matches!(
                c,
                C::Done | C::Timeout | C::BadProduct | C::FailedSafe | C::FailedDanger
            ),
            Self::DoneOrTimeout => matches!(c, C::Done | C::Timeout),
            Self::Answer => matches!(c, C::Answer(_) | C::AnswerAny),
        }
    }

    /// The criteria every state of this command must have a row for.
    pub fn required(self) -> &'static [Criterion] {
        match self {
            Self::None => &[],
            Self::Start => &[Criterion::Started, Criterion::Timeout],
            Self::Wait | Self::DoneOrTimeout => &[Criterion::Done, Criterion::Timeout],
            Self::Answer => &[Criterion::AnswerAny],
        }
    }

    /// For messages.
    pub fn describe(self) -> &'static str {
        match self {
            Self::None => "no criterion",
            Self::Start => "started (gestart) or timeout (tijdlimiet)",
            Self::Wait => {
                "done (klaar), timeout (tijdlimiet), bad_product, failed_safe or failed_danger"
            }
            Self::DoneOrTimeout => "done (klaar) or timeout (tijdlimiet)",
            Self::Answer => "answer=<text> or answer=*",
        }
    }
}

/// One command of one controller kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommandSpec {
    /// The command word (lower case).
    pub name: &'static str,
    /// Its arguments.
    pub args: &'static [Arg],
    /// Its criteria.
    pub criteria: Criteria,
    /// What the engine does.
    pub handler: Handler,
    /// For the manual.
    pub usage: &'static str,
}

const CELL: &[CommandSpec] = &[
    CommandSpec {
        name: "start",
        args: &[Arg::Station, Arg::RecipeName, Arg::OptSeconds],
        criteria: Criteria::Start,
        handler: Handler::Start,
        usage: "start <station> <recipe> [max_s]",
    },
    CommandSpec {
        name: "wait",
        args: &[Arg::Station, Arg::OptSeconds],
        criteria: Criteria::Wait,
        handler: Handler::Wait,
        usage: "wait <station> [max_s]",
    },
    CommandSpec {
        name: "output",
        args: &[Arg::Text],
        criteria: Criteria::None,
        handler: Handler::Output,
        usage: "output <text>",
    },
    CommandSpec {
        name: "input",
        args: &[Arg::Text],
        criteria: Criteria::Answer,
        handler: Handler::Input,
        usage: "input <prompt>",
    },
];

const WELDING: &[CommandSpec] = &[
    CommandSpec {
        name: "start",
        args: &[Arg::Rcm, Arg::Program, Arg::OptSeconds],
        criteria: Criteria::Start,
        handler: Handler::Start,
        usage: "start rcm <program> [max_s]",
    },
    CommandSpec {
        name: "wait",
        args: &[Arg::Rcm, Arg::OptSeconds],
        criteria: Criteria::Wait,
        handler: Handler::Wait,
        usage: "wait rcm [max_s]",
    },
    CommandSpec {
        name: "waitready",
        args: &[Arg::Rcm, Arg::Seconds],
        criteria: Criteria::DoneOrTimeout,
        handler: Handler::WaitReady,
        usage: "waitready rcm <max_s>",
    },
];

const TRANSPORT: &[CommandSpec] = &[
    CommandSpec {
        name: "activate",
        args: &[Arg::Button],
        criteria: Criteria::None,
        handler: Handler::Activate,
        usage: "activate <line A-Z but I, O | station 1-99>",
    },
    CommandSpec {
        name: "reset",
        args: &[Arg::Button],
        criteria: Criteria::None,
        handler: Handler::Reset,
        usage: "reset <line A-Z but I, O | station 1-99>",
    },
    CommandSpec {
        name: "waitline",
        args: &[Arg::Line, Arg::Level, Arg::Seconds],
        criteria: Criteria::DoneOrTimeout,
        handler: Handler::WaitInput,
        usage: "waitline <line A-Z but I, O> <1 running|0 not> <max_s>",
    },
    CommandSpec {
        name: "waitplace",
        args: &[Arg::Place, Arg::Level, Arg::Seconds],
        criteria: Criteria::DoneOrTimeout,
        handler: Handler::WaitInput,
        usage: "waitplace <place 1-99> <1 occupied|0 empty> <max_s>",
    },
    CommandSpec {
        name: "waitstation",
        args: &[Arg::StationNo, Arg::Level, Arg::Seconds],
        criteria: Criteria::DoneOrTimeout,
        handler: Handler::WaitInput,
        usage: "waitstation <station 1-99> <1 busy|0 not> <max_s>",
    },
    CommandSpec {
        name: "set",
        args: &[Arg::OutputName, Arg::Level],
        criteria: Criteria::None,
        handler: Handler::Set,
        usage: "set <output> <1 on|0 off>",
    },
    CommandSpec {
        name: "waitinput",
        args: &[Arg::InputName, Arg::Level, Arg::Seconds],
        criteria: Criteria::DoneOrTimeout,
        handler: Handler::WaitInput,
        usage: "waitinput <input> <1 on|0 off> <max_s>",
    },
];

/// The command set of a controller kind.
pub fn command_set(kind: RecipeKind) -> &'static [CommandSpec] {
    match kind {
        RecipeKind::Cell => CELL,
        RecipeKind::Welding => WELDING,
        RecipeKind::Transport => TRANSPORT,
    }
}

/// A command by name (lower case) for a kind.
pub fn lookup(kind: RecipeKind, name: &str) -> Option<&'static CommandSpec> {
    command_set(kind).iter().find(|c| c.name == name)
}
