//! Every MMS-equivalent message on the wire, by direction.
//!
//! - [`Request`]: commander → subordinate (a confirmed service's request; it
//!   arrives at the server as the indication). The one upward exception is
//!   operator communication (`Input`, `Output`): cell → operator.
//! - [`Response`]: subordinate → commander (the positive confirm). A negative
//!   confirm is a [`ServiceError`](super::error::ServiceError).
//! - [`Unconfirmed`]: published upward without a reply: unsolicited status
//!   and information reports.
//!
//! Each confirmed service has its own key (`…/svc/<service>`), named by
//! [`ServiceName`], so that the router's ACL can allow or deny it exactly.

use super::domain::DomainAttributes;
use super::program::PiState;
use super::vmd::{Identity, VmdStatus};
use crate::ids::{ObjectName, StationName};
use crate::mode::{ManualAction, ModeSetting};
use serde::{Deserialize, Serialize};
use std::fmt;

/// The version of this message set; the envelope carries it.
pub const PROTOCOL_VERSION: u8 = 2;

macro_rules! services {
    ($($variant:ident => $key:literal),+ $(,)?) => {
        /// The name of a confirmed service: the last chunk of its key.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
        #[allow(missing_docs)]
        pub enum ServiceName { $($variant),+ }

        impl ServiceName {
            /// Every confirmed service.
            pub const ALL: &'static [ServiceName] = &[$(ServiceName::$variant),+];

            /// The key chunk (`status`, `initiate-download-sequence`, …).
            pub fn as_str(self) -> &'static str {
                match self { $(ServiceName::$variant => $key),+ }
            }

            /// Parses a key chunk.
            pub fn from_key(chunk: &str) -> Option<Self> {
                match chunk { $($key => Some(ServiceName::$variant),)+ _ => None }
            }
        }
    };
}

services! {
    Initiate => "initiate",
    Conclude => "conclude",
    Abort => "abort",
    Status => "status",
    Identify => "identify",
    GetNameList => "get-name-list",
    InitiateDownloadSequence => "initiate-download-sequence",
    DownloadSegment => "download-segment",
    TerminateDownloadSequence => "terminate-download-sequence",
    InitiateUploadSequence => "initiate-upload-sequence",
    UploadSegment => "upload-segment",
    TerminateUploadSequence => "terminate-upload-sequence",
    DeleteDomain => "delete-domain",
    GetDomainAttributes => "get-domain-attributes",
    CreateProgramInvocation => "create-program-invocation",
    DeleteProgramInvocation => "delete-program-invocation",
    Start => "start",
    Stop => "stop",
    Resume => "resume",
    Reset => "reset",
    Kill => "kill",
    GetProgramInvocationAttributes => "get-program-invocation-attributes",
    Input => "input",
    Output => "output",
    Mode => "mode",
    Step => "step",
    Manual => "manual",
}

impl ServiceName {
    /// Services a commander requests of its subordinate.
    pub fn downward() -> impl Iterator<Item = ServiceName> {
        Self::ALL.iter().copied().filter(|s| !s.is_upward())
    }

    /// Operator communication: the cell requests these of the operator.
    pub fn upward() -> impl Iterator<Item = ServiceName> {
        Self::ALL.iter().copied().filter(|s| s.is_upward())
    }

    fn is_upward(self) -> bool {
        matches!(self, ServiceName::Input | ServiceName::Output)
    }
}

impl fmt::Display for ServiceName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The object classes GetNameList can list.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ObjectClass {
    /// Domains.
    Domain,
    /// Program invocations.
    ProgramInvocation,
}

/// Who asks for an association: the calling station and its zenoh session.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Peer {
    /// The station (AR name).
    pub station: StationName,
    /// Its zenoh session id (hex), naming its liveliness token.
    pub session: String,
}

impl fmt::Display for Peer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} (session {})", self.station, self.session)
    }
}

/// A confirmed service request (commander → subordinate; cell → operator
/// for `Input`/`Output`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum Request {
    /// Associate: the caller becomes this node's commander.
    Initiate {
        /// The caller.
        calling: Peer,
    },
    /// End the association in order.
    Conclude {
        /// The caller (the commander).
        calling: Peer,
    },
    /// End the association at once (the commander is stopping).
    Abort {
        /// The caller (the commander).
        calling: Peer,
        /// Why, for the journal.
        reason: String,
    },
    /// VMD status.
    Status,
    /// Vendor, model, revision.
    Identify,
    /// Names of the objects of a class.
    GetNameList(ObjectClass),
    /// Begin a domain download.
    InitiateDownloadSequence {
        /// The domain.
        domain: ObjectName,
    },
    /// One segment of a domain download.
    DownloadSegment {
        /// The domain.
        domain: ObjectName,
        /// The bytes.
        data: Vec<u8>,
        /// Whether more segments follow.
        more_follows: bool,
    },
    /// End a domain download.
    TerminateDownloadSequence {
        /// The domain.
        domain: ObjectName,
        /// Set to discard the download, with the reason.
        discard: Option<String>,
    },
    /// Begin a domain upload.
    InitiateUploadSequence {
        /// The domain.
        domain: ObjectName,
    },
    /// Next segment of an upload.
    UploadSegment {
        /// The upload state machine id from InitiateUploadSequence.
        ulsm: u32,
    },
    /// End an upload.
    TerminateUploadSequence {
        /// The upload state machine id.
        ulsm: u32,
    },
    /// Delete a domain.
    DeleteDomain {
        /// The domain.
        domain: ObjectName,
    },
    /// Attributes of a domain.
    GetDomainAttributes {
        /// The domain.
        domain: ObjectName,
    },
    /// Create a program invocation over domains.
    CreateProgramInvocation {
        /// Its name.
        name: ObjectName,
        /// The domains it uses.
        domains: Vec<ObjectName>,
        /// Whether it returns to idle when it ends.
        reusable: bool,
    },
    /// Delete a program invocation.
    DeleteProgramInvocation {
        /// Its name.
        name: ObjectName,
    },
    /// Start a program invocation.
    Start {
        /// Its name.
        name: ObjectName,
        /// The execution argument (free text).
        argument: String,
    },
    /// Stop a running program invocation.
    Stop {
        /// Its name.
        name: ObjectName,
    },
    /// Resume a stopped program invocation.
    Resume {
        /// Its name.
        name: ObjectName,
    },
    /// Reset a stopped program invocation to idle.
    Reset {
        /// Its name.
        name: ObjectName,
    },
    /// Kill a program invocation (it becomes unrunnable).
    Kill {
        /// Its name.
        name: ObjectName,
    },
    /// Attributes of a program invocation.
    GetProgramInvocationAttributes {
        /// Its name.
        name: ObjectName,
    },
    /// Operator communication: ask and wait for the answer.
    Input {
        /// The prompt.
        prompt: String,
        /// How long to wait, if limited.
        timeout_s: Option<u32>,
    },
    /// Operator communication: show lines.
    Output {
        /// The lines.
        lines: Vec<String>,
    },
    /// The cell's operating mode (operator → cell → every workstation).
    Mode(ModeSetting),
    /// Step mode: carry out the step that waits for confirmation, on
    /// `station` (None: the receiver), and (`to`) go on until that state.
    Step {
        /// The station whose step (None: the receiver's own).
        station: Option<StationName>,
        /// Run until this state waits, instead of one step.
        to: Option<u16>,
    },
    /// A manual operation on a workstation (maintenance mode), passed down
    /// by the cell.
    Manual {
        /// The workstation.
        station: StationName,
        /// What.
        action: ManualAction,
        /// The console user who asked (for the station's report).
        by: String,
    },
}

/// The longest text a request may carry in one field (an Abort's reason, a
/// Start's argument, a discard's reason, an output line, a prompt), in
/// characters.
pub const MAX_REQUEST_TEXT_CHARS: usize = crate::api::MAX_OUTPUT_CHARS;
/// The most lines one Output may carry.
pub const MAX_REQUEST_LINES: usize = crate::api::MAX_OUTPUT_LINES;
/// The most stations a mode may name as stepping (more than any cell has).
pub const MAX_STEPPING: usize = 64;

impl Request {
    /// Refuses what is beyond the bounds a station takes, whoever sent it
    /// (the operator's API bounds what consoles send; this bounds what a
    /// caller with a commander's credentials sends to the service): texts
    /// of at most [`MAX_REQUEST_TEXT_CHARS`], at most [`MAX_REQUEST_LINES`]
    /// output lines, a mode naming each station once and at most
    /// [`MAX_STEPPING`]. The refusal quotes a short excerpt only.
    pub fn check_limits(&self) -> Result<(), String> {
        use crate::ids::excerpt;
        let text = |what: &str, t: &str| {
            let n = t.chars().count();
            if n > MAX_REQUEST_TEXT_CHARS {
                Err(format!(
                    "{} refused: its {what} \"{}\" is longer than {MAX_REQUEST_TEXT_CHARS} characters",
                    self.service(),
                    excerpt(t)
                ))
            } else {
                Ok(())
            }
        };
        match self {
            Self::Abort { reason, .. } => text("reason", reason),
            Self::Start { argument, .. } => text("argument", argument),
            Self::TerminateDownloadSequence {
                discard: Some(why), ..
            } => text("reason to discard", why),
            Self::Input { prompt, .. } => text("prompt", prompt),
            Self::Output { lines } if lines.len() > MAX_REQUEST_LINES => Err(format!(
                "Output refused: {} lines, at most {MAX_REQUEST_LINES}",
                lines.len()
            )),
            Self::Output { lines } => lines.iter().try_for_each(|l| text("line", l)),
            Self::Mode(m) => {
                if m.stepping.len() > MAX_STEPPING {
                    return Err(format!(
                        "Mode refused: {} stations named, at most {MAX_STEPPING}",
                        m.stepping.len()
                    ));
                }
                let mut seen = std::collections::BTreeSet::new();
                match m.stepping.iter().find(|s| !seen.insert(*s)) {
                    Some(s) => Err(format!("Mode refused: {s} is named more than once")),
                    None => Ok(()),
                }
            }
            Self::Manual { by, action, .. } => {
                text("user", by)?;
                match action {
                    crate::mode::ManualAction::Press(t)
                    | crate::mode::ManualAction::Release(t)
                    | crate::mode::ManualAction::RunLine { line: t, .. }
                    | crate::mode::ManualAction::RunRecipe(t)
                    | crate::mode::ManualAction::Goto(t) => text("operand", t),
                    _ => Ok(()),
                }
            }
            _ => Ok(()),
        }
    }

    /// The service this request belongs to (its key's last chunk).
    pub fn service(&self) -> ServiceName {
        use ServiceName as S;
        match self {
            Self::Initiate { .. } => S::Initiate,
            Self::Conclude { .. } => S::Conclude,
            Self::Abort { .. } => S::Abort,
            Self::Status => S::Status,
            Self::Identify => S::Identify,
            Self::GetNameList(_) => S::GetNameList,
            Self::InitiateDownloadSequence { .. } => S::InitiateDownloadSequence,
            Self::DownloadSegment { .. } => S::DownloadSegment,
            Self::TerminateDownloadSequence { .. } => S::TerminateDownloadSequence,
            Self::InitiateUploadSequence { .. } => S::InitiateUploadSequence,
            Self::UploadSegment { .. } => S::UploadSegment,
            Self::TerminateUploadSequence { .. } => S::TerminateUploadSequence,
            Self::DeleteDomain { .. } => S::DeleteDomain,
            Self::GetDomainAttributes { .. } => S::GetDomainAttributes,
            Self::CreateProgramInvocation { .. } => S::CreateProgramInvocation,
            Self::DeleteProgramInvocation { .. } => S::DeleteProgramInvocation,
            Self::Start { .. } => S::Start,
            Self::Stop { .. } => S::Stop,
            Self::Resume { .. } => S::Resume,
            Self::Reset { .. } => S::Reset,
            Self::Kill { .. } => S::Kill,
            Self::GetProgramInvocationAttributes { .. } => S::GetProgramInvocationAttributes,
            Self::Input { .. } => S::Input,
            Self::Output { .. } => S::Output,
            Self::Mode(_) => S::Mode,
            Self::Step { .. } => S::Step,
            Self::Manual { .. } => S::Manual,
        }
    }
}

/// Attributes of a program invocation.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct PiAttributes {
    /// Its state.
    pub state: PiState,
    /// The domains it uses.
    pub domains: Vec<ObjectName>,
    /// Whether it returns to idle when it ends.
    pub reusable: bool,
    /// Whether Delete is allowed.
    pub deletable: bool,
    /// How its last run ended, until the next Start (a commander that was
    /// cut off while it ran learns the end here).
    pub last_end: Option<JobEvent>,
}

/// A positive confirm (subordinate → commander; operator → cell).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum Response {
    /// The association is made; the responder's identity.
    Initiate {
        /// The responder.
        responding: Peer,
    },
    /// Done, nothing to report (Conclude, Abort, download steps, Delete…, Output).
    Done,
    /// VMD status.
    Status(VmdStatus),
    /// Identify.
    Identify(Identity),
    /// GetNameList.
    NameList(Vec<ObjectName>),
    /// InitiateUploadSequence: the upload's id and total size.
    UploadStarted {
        /// The upload state machine id.
        ulsm: u32,
        /// The domain's size in bytes.
        size: u64,
    },
    /// UploadSegment.
    Segment {
        /// The bytes.
        data: Vec<u8>,
        /// Whether more segments follow.
        more_follows: bool,
    },
    /// GetDomainAttributes.
    DomainAttributes(DomainAttributes),
    /// Start, Stop, Resume, Reset, Kill: the state the invocation is now in.
    ProgramInvocationState(PiState),
    /// GetProgramInvocationAttributes.
    PiAttributes(PiAttributes),
    /// Input: the operator's answer.
    Answer(String),
}

/// Severity of an information report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Severity {
    /// For the record.
    Info,
    /// Something a person should look at.
    Warning,
    /// An alarm of its class: it goes into the operator's alarm list
    /// (and a running job ends in alarm: the cell stops).
    Alarm(crate::alarm::AlarmClass),
}

/// What happened to a running job (a started program invocation), as its
/// commander's `wait` needs it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum JobEvent {
    /// Paused (a person in the work area): time limits freeze.
    Paused,
    /// Going on after a pause.
    Resumed,
    /// Ended normally.
    Done,
    /// Ended, the product is bad (weld aborted).
    BadProduct,
    /// Failed without danger.
    FailedSafe,
    /// Failed with danger (outside its own work area).
    FailedDanger,
    /// Ended in alarm, with the cause (its class set where it was raised).
    Alarm(crate::alarm::Cause),
    /// A workstation's run began (numbered like every job event, so a
    /// reader who missed it while a link was down reads it back with its
    /// time; the status says so too, but is not kept).
    Started,
}

/// An unconfirmed service, published upward (`…/<st>/status`, `…/<st>/report`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum Unconfirmed {
    /// Unsolicited status.
    Status {
        /// Who reports.
        station: StationName,
        /// Its status.
        status: VmdStatus,
    },
    /// A job event (on `…/<st>/status`): the commander's `wait` criteria.
    Job {
        /// Who reports.
        station: StationName,
        /// The program invocation.
        program: ObjectName,
        /// What happened.
        event: JobEvent,
    },
    /// An information report (message, alarm).
    Report {
        /// Who reports.
        station: StationName,
        /// How serious.
        severity: Severity,
        /// What happened, for a person.
        text: String,
    },
}

impl Unconfirmed {
    /// Who publishes it.
    pub fn station(&self) -> &StationName {
        match self {
            Self::Status { station, .. }
            | Self::Job { station, .. }
            | Self::Report { station, .. } => station,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_beyond_their_bounds_are_refused_at_the_service_with_a_short_quote() {
        use crate::ids::{ObjectName, StationName};
        use crate::mode::{CellMode, ModeSetting};
        let peer = Peer {
            station: StationName::new("cell").expect("valid"),
            session: "s".into(),
        };
        let huge = "x".repeat(1_000_000);
        for r in [
            Request::Abort {
                calling: peer.clone(),
                reason: huge.clone(),
            },
            Request::Start {
                name: ObjectName::new("STORE").expect("valid"),
                argument: "a".repeat(100_000),
            },
            Request::Output {
                lines: vec![huge.clone()],
            },
            Request::Output {
                lines: vec!["l".into(); 101],
            },
            Request::Mode(ModeSetting {
                mode: CellMode::Step,
                stepping: vec![StationName::new("welding").expect("valid"); 5_000],
            }),
            Request::Mode(ModeSetting {
                mode: CellMode::Step,
                stepping: vec![
                    StationName::new("welding").expect("valid"),
                    StationName::new("welding").expect("valid"),
                ],
            }),
        ] {
            let e = r.check_limits().expect_err("refused");
            assert!(e.len() < 300, "a short refusal: {}", e.len());
            assert!(
                e.starts_with(r.service().as_str()) || e.contains("refused"),
                "{e}"
            );
        }
        assert!(Request::Start {
            name: ObjectName::new("DIKDROOG").expect("valid"),
            argument: "from 9".into(),
        }
        .check_limits()
        .is_ok());
        assert!(Request::Mode(ModeSetting {
            mode: CellMode::Step,
            stepping: vec![StationName::new("welding").expect("valid")],
        })
        .check_limits()
        .is_ok());
    }

    #[test]
    fn service_keys_round_trip_and_are_unique() {
        let mut seen = std::collections::BTreeSet::new();
        for &s in ServiceName::ALL {
            assert_eq!(ServiceName::from_key(s.as_str()), Some(s));
            assert!(seen.insert(s.as_str()), "duplicate key {s}");
            assert!(!s.as_str().contains(['*', '/', '$', '?', '#']));
        }
        assert_eq!(ServiceName::upward().count(), 2);
        assert_eq!(ServiceName::downward().count(), ServiceName::ALL.len() - 2);
    }
}
