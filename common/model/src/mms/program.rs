//! Program invocations (ISO 9506-1 §11): a runnable recipe and its state
//! machine. Requests (Start, Stop, Resume, Reset, Kill, Delete) move it into a
//! transitional state; the executor's completions (`started`, `stopped`, …)
//! finish the transition. A refused request answers with the current state.

use super::error::{ServiceError, ServiceSpecific};
use super::pdu::JobEvent;
use crate::ids::ObjectName;
use serde::{Deserialize, Serialize};
use std::fmt;

/// The program-invocation states of ISO 9506-1.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[allow(missing_docs)]
pub enum PiState {
    NonExistent,
    Unrunnable,
    Idle,
    Starting,
    Running,
    Stopping,
    Stopped,
    Resuming,
    Resetting,
}

impl fmt::Display for PiState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::NonExistent => "non-existent",
            Self::Unrunnable => "unrunnable",
            Self::Idle => "idle",
            Self::Starting => "starting",
            Self::Running => "running",
            Self::Stopping => "stopping",
            Self::Stopped => "stopped",
            Self::Resuming => "resuming",
            Self::Resetting => "resetting",
        })
    }
}

/// A request from the commander.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[allow(missing_docs)]
pub enum PiRequest {
    Start,
    Stop,
    Resume,
    Reset,
    Kill,
    Delete,
}

/// A completion reported by whatever executes the program.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum PiCompletion {
    /// Starting finished: the program runs.
    Started,
    /// Starting failed: back to idle.
    StartFailed,
    /// Stopping finished.
    Stopped,
    /// Resuming finished: the program runs again.
    Resumed,
    /// Resetting finished: idle again.
    ResetDone,
    /// The program ended by itself.
    Finished,
}

/// A program invocation: its name, the domains it uses and its state.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProgramInvocation {
    name: ObjectName,
    domains: Vec<ObjectName>,
    reusable: bool,
    deletable: bool,
    state: PiState,
    /// How its last run ended, until the next Start: what a commander that
    /// was away when it ended asks for ([`Self::last_end`]).
    last_end: Option<JobEvent>,
}

impl ProgramInvocation {
    /// Creates it: idle when every domain it uses is ready, else unrunnable.
    pub fn create(
        name: ObjectName,
        domains: Vec<ObjectName>,
        reusable: bool,
        domains_ready: bool,
    ) -> Self {
        Self {
            name,
            domains,
            reusable,
            deletable: true,
            state: if domains_ready {
                PiState::Idle
            } else {
                PiState::Unrunnable
            },
            last_end: None,
        }
    }

    /// Its name.
    pub fn name(&self) -> &ObjectName {
        &self.name
    }

    /// The domains it uses.
    pub fn domains(&self) -> &[ObjectName] {
        &self.domains
    }

    /// Whether it returns to idle when it ends (else it becomes unrunnable).
    pub fn reusable(&self) -> bool {
        self.reusable
    }

    /// Whether Delete is allowed.
    pub fn deletable(&self) -> bool {
        self.deletable
    }

    /// Its current state.
    pub fn state(&self) -> PiState {
        self.state
    }

    /// How its last run ended (None while it runs, and before it ever ran).
    pub fn last_end(&self) -> Option<&JobEvent> {
        self.last_end.as_ref()
    }

    /// Records how the run ended (the executor, with
    /// [`PiCompletion::Finished`]).
    pub fn record_end(&mut self, end: JobEvent) {
        self.last_end = Some(end);
    }

    /// Applies a commander's request; on refusal the error carries the
    /// current state (`service/object-state-conflict`).
    pub fn request(&mut self, request: PiRequest) -> Result<PiState, ServiceError> {
        use PiState::*;
        let next = match (request, self.state) {
            (PiRequest::Start, Idle) => {
                self.last_end = None;
                Starting
            }
            (PiRequest::Stop, Running) => Stopping,
            (PiRequest::Resume, Stopped) => Resuming,
            (PiRequest::Reset, Stopped) => Resetting,
            (
                PiRequest::Kill,
                Idle | Starting | Running | Stopping | Stopped | Resuming | Resetting,
            ) => Unrunnable,
            (PiRequest::Delete, Idle | Stopped | Unrunnable) if self.deletable => NonExistent,
            (request, state) => {
                return Err(ServiceError::state_conflict(format!(
                    "{request:?} refused: program invocation {} is {state}",
                    self.name
                ))
                .with(ServiceSpecific::ProgramInvocationState(state)))
            }
        };
        self.state = next;
        Ok(next)
    }

    /// Applies the executor's completion; `Err` names the state it did not
    /// fit (a completion out of sequence changes nothing).
    pub fn complete(&mut self, completion: PiCompletion) -> Result<PiState, PiState> {
        use PiState::*;
        let next = match (completion, self.state) {
            (PiCompletion::Started, Starting) => Running,
            (PiCompletion::StartFailed, Starting) => Idle,
            (PiCompletion::Stopped, Stopping) => Stopped,
            (PiCompletion::Resumed, Resuming) => Running,
            (PiCompletion::ResetDone, Resetting) => Idle,
            (PiCompletion::Finished, Running | Stopping | Resuming) if self.reusable => Idle,
            (PiCompletion::Finished, Running | Stopping | Resuming) => Unrunnable,
            (_, state) => return Err(state),
        };
        self.state = next;
        Ok(next)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use PiState::*;

    fn pi(state: PiState) -> ProgramInvocation {
        let mut p = ProgramInvocation::create(
            ObjectName::new("DROOG_DIK").expect("valid"),
            vec![],
            true,
            true,
        );
        p.state = state;
        p
    }

    const ALL: [PiState; 9] = [
        NonExistent,
        Unrunnable,
        Idle,
        Starting,
        Running,
        Stopping,
        Stopped,
        Resuming,
        Resetting,
    ];

    /// Every (request, state) pair: the allowed ones move to the expected
    /// state, every other one is refused with the current state.
    #[test]
    fn requests_transition_by_transition() {
        let allowed = |r: PiRequest, s: PiState| -> Option<PiState> {
            match (r, s) {
                (PiRequest::Start, Idle) => Some(Starting),
                (PiRequest::Stop, Running) => Some(Stopping),
                (PiRequest::Resume, Stopped) => Some(Resuming),
                (PiRequest::Reset, Stopped) => Some(Resetting),
                (PiRequest::Kill, NonExistent | Unrunnable) => None,
                (PiRequest::Kill, _) => Some(Unrunnable),
                (PiRequest::Delete, Idle | Stopped | Unrunnable) => Some(NonExistent),
                _ => None,
            }
        };
        for request in [
            PiRequest::Start,
            PiRequest::Stop,
            PiRequest::Resume,
            PiRequest::Reset,
            PiRequest::Kill,
            PiRequest::Delete,
        ] {
            for state in ALL {
                let mut p = pi(state);
                match (allowed(request, state), p.request(request)) {
                    (Some(want), Ok(got)) => {
                        assert_eq!(want, got, "{request:?} in {state}");
                        assert_eq!(p.state(), want);
                    }
                    (None, Err(e)) => {
                        assert_eq!(
                            e.specific,
                            Some(ServiceSpecific::ProgramInvocationState(state)),
                            "{request:?} in {state}"
                        );
                        assert_eq!(e.class.to_string(), "service/object-state-conflict");
                        assert_eq!(p.state(), state, "a refusal changes nothing");
                    }
                    (want, got) => panic!("{request:?} in {state}: want {want:?}, got {got:?}"),
                }
            }
        }
    }

    #[test]
    fn completions_transition_by_transition() {
        let table = [
            (PiCompletion::Started, Starting, Ok(Running)),
            (PiCompletion::StartFailed, Starting, Ok(Idle)),
            (PiCompletion::Stopped, Stopping, Ok(Stopped)),
            (PiCompletion::Resumed, Resuming, Ok(Running)),
            (PiCompletion::ResetDone, Resetting, Ok(Idle)),
            (PiCompletion::Finished, Running, Ok(Idle)),
            (PiCompletion::Finished, Stopping, Ok(Idle)),
            (PiCompletion::Started, Idle, Err(Idle)),
            (PiCompletion::Stopped, Running, Err(Running)),
            (PiCompletion::Finished, Idle, Err(Idle)),
            (PiCompletion::ResetDone, Stopped, Err(Stopped)),
        ];
        for (completion, from, want) in table {
            let mut p = pi(from);
            assert_eq!(p.complete(completion), want, "{completion:?} in {from}");
        }
        let mut once = pi(Running);
        once.reusable = false;
        assert_eq!(once.complete(PiCompletion::Finished), Ok(Unrunnable));
    }

    #[test]
    fn a_full_cycle() {
        let p = ProgramInvocation::create(
            ObjectName::new("store").expect("valid"),
            vec![],
            true,
            false,
        );
        assert_eq!(p.state(), Unrunnable);
        let mut p = pi(Idle);
        assert_eq!(p.request(PiRequest::Start), Ok(Starting));
        assert_eq!(p.complete(PiCompletion::Started), Ok(Running));
        assert_eq!(p.request(PiRequest::Stop), Ok(Stopping));
        assert_eq!(p.complete(PiCompletion::Stopped), Ok(Stopped));
        assert_eq!(p.request(PiRequest::Resume), Ok(Resuming));
        assert_eq!(p.complete(PiCompletion::Resumed), Ok(Running));
        assert_eq!(p.request(PiRequest::Stop), Ok(Stopping));
        assert_eq!(p.complete(PiCompletion::Stopped), Ok(Stopped));
        assert_eq!(p.request(PiRequest::Reset), Ok(Resetting));
        assert_eq!(p.complete(PiCompletion::ResetDone), Ok(Idle));
        assert_eq!(p.request(PiRequest::Delete), Ok(NonExistent));
    }
}
