//! The VMD (virtual manufacturing device) of one station: its status (ISO
//! 9506 logical and physical status, local detail = recipe state, additional
//! detail = `RobotStatusDetail` for a robot station), its identity, and its
//! object store of domains and program invocations.
//!
//! [`Vmd::handle`] answers every domain and program-invocation service and
//! GetNameList/Identify, with no I/O. What a program invocation *does* when
//! it starts is the node's business: the node reads the transition and calls
//! [`Vmd::complete`] when its executor has finished it.
//!
//! Its recipe memory is bounded ([`Vmd::set_memory`], [`RECIPE_MEMORY`]
//! unless told): a download that would hold more is refused with
//! `resource/memory-unavailable`, saying how much is used.

use super::domain::{Domain, DomainState, MAX_SEGMENT_BYTES};
use super::error::{DefinitionError, ErrorClass, ResourceError, ServiceError};
use super::pdu::{JobEvent, ObjectClass, PiAttributes, Request, Response};
use super::program::{PiCompletion, PiRequest, PiState, ProgramInvocation};
use crate::ids::ObjectName;
use crate::mode::{CellMode, HeldStep};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt;

/// ISO 9506 VMD logical status.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[allow(missing_docs)]
pub enum LogicalStatus {
    StateChangesAllowed,
    NoStateChangesAllowed,
    LimitedServicesPermitted,
    SupportServicesAllowed,
}

/// ISO 9506 VMD physical status.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[allow(missing_docs)]
pub enum PhysicalStatus {
    Operational,
    PartiallyOperational,
    Inoperable,
    NeedsCommissioning,
}

/// The recipe state: the local detail of the VMD status, each
/// controller's own for its own recipe.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum RecipeState {
    /// No recipe loaded.
    Idle,
    /// A recipe loaded that a Start could not run now (maintenance mode,
    /// the device not ready).
    Loaded,
    /// A recipe loaded that a Start would run now.
    Ready,
    /// A recipe runs, waiting for nothing from the level below.
    Executing,
    /// A recipe runs and waits for a job it started one level down to
    /// end (`wait`).
    Pending,
    /// After an alarm until a run starts or a program invocation is
    /// reset.
    Error,
    /// A recipe runs and waits for the confirm of a Start it sent one
    /// level down (`start`).
    WaitAck,
}

impl fmt::Display for RecipeState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Idle => "IDLE",
            Self::Loaded => "LOADED",
            Self::Ready => "READY",
            Self::Executing => "EXECUTING",
            Self::Pending => "PENDING",
            Self::Error => "ERROR",
            Self::WaitAck => "WAIT_ACK",
        })
    }
}

/// `robotVMDState` of ISO 9506-3.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[allow(missing_docs)]
pub enum RobotVmdState {
    Idle = 0,
    Loaded = 1,
    Ready = 2,
    Executing = 3,
    MotionPaused = 4,
    ManualInterventionRequired = 5,
}

/// `RobotStatusDetail` of ISO 9506-3: the state and the specific-status bit
/// string (bit 0 = safetyInterlocksViolated … bit 4 = unitsOfMeasure) with
/// its mask.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct RobotStatusDetail {
    /// The robot's VMD state.
    pub state: RobotVmdState,
    /// The specific-status bits.
    pub specific: u8,
    /// Which bits are meaningful (default all five).
    pub mask: u8,
}

impl RobotStatusDetail {
    /// Bit: safety interlocks violated.
    pub const SAFETY_INTERLOCKS_VIOLATED: u8 = 1 << 0;
    /// Bit: any physical resource powered on.
    pub const ANY_POWER_ON: u8 = 1 << 1;
    /// Bit: all physical resources calibrated.
    pub const ALL_CALIBRATED: u8 = 1 << 2;
    /// Bit: under local control.
    pub const LOCAL_CONTROL: u8 = 1 << 3;
    /// Bit: units of measure.
    pub const UNITS_OF_MEASURE: u8 = 1 << 4;
}

/// The VMD status (Status service, unsolicited status).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct VmdStatus {
    /// Logical status.
    pub logical: LogicalStatus,
    /// Physical status.
    pub physical: PhysicalStatus,
    /// Local detail: the recipe state.
    pub local_detail: RecipeState,
    /// Additional detail: the robot's status, for a robot station.
    pub additional: Option<RobotStatusDetail>,
    /// The running program invocation and the state its recipe is in (not
    /// in ISO 9506: what the 1992 overview's top line showed, and what a
    /// recipe view highlights).
    pub program: Option<ProgramState>,
    /// The device's inputs in its I/O map's order (the conveyor PLC's
    /// lamps, `plc::map::Input::at`); empty for other devices. What the
    /// overview draws the conveyor from.
    pub inputs: Vec<bool>,
    /// The cell's operating mode, as this station has it.
    #[serde(default)]
    pub mode: CellMode,
    /// Step mode: the step of the running recipe that waits for `falc
    /// step` before it is carried out.
    #[serde(default)]
    pub held: Option<HeldStep>,
    /// Why the station is not ready for its commander's work, if so (no
    /// DNC link, the robot not in automatic-external mode, an emergency
    /// stop): the cell refuses a start while a workstation says so.
    #[serde(default)]
    pub unready: Option<String>,
    /// The named state the device's inputs show (a conveyor's `home`),
    /// or [`NO_NAMED_STATE`]; None for a device without named states or
    /// with no reading.
    #[serde(default)]
    pub equipment_state: Option<String>,
    /// The loaded recipes whose `#PRE` does not hold now, each with the
    /// refusal a Start of it would get ("precondition of UNSTORE: place 3
    /// occupied is false"): a restart from a state that starts one is
    /// refused before anything runs. Empty while the station runs a
    /// recipe (no Start is taken then).
    #[serde(default)]
    pub unmet: BTreeMap<ObjectName, String>,
}

/// [`VmdStatus::equipment_state`] of equipment in none of its named
/// states (a state's name is a word: this cannot be one).
pub const NO_NAMED_STATE: &str = "no named state";

/// A running program invocation and its recipe's current state.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ProgramState {
    /// The program invocation (`STORE`, `DIKDROOG`).
    pub name: ObjectName,
    /// The recipe state it is in.
    pub state: u16,
}

impl Default for VmdStatus {
    fn default() -> Self {
        Self {
            logical: LogicalStatus::StateChangesAllowed,
            physical: PhysicalStatus::Operational,
            local_detail: RecipeState::Idle,
            additional: None,
            program: None,
            inputs: Vec::new(),
            mode: CellMode::Auto,
            held: None,
            unready: None,
            equipment_state: None,
            unmet: BTreeMap::new(),
        }
    }
}

/// Identify: who this VMD is.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Identity {
    /// Vendor.
    pub vendor: String,
    /// Model (the station kind).
    pub model: String,
    /// Software revision.
    pub revision: String,
}

/// How many bytes of domains a station holds unless told otherwise
/// (sixteen recipes of the largest size).
pub const RECIPE_MEMORY: usize = 16 * super::domain::MAX_DOMAIN_BYTES;

/// A station's object store.
#[derive(Debug, Clone)]
pub struct Vmd {
    identity: Identity,
    /// How many bytes of domain content it holds at most.
    memory: usize,
    domains: BTreeMap<ObjectName, Domain>,
    programs: BTreeMap<ObjectName, ProgramInvocation>,
    uploads: BTreeMap<u32, (ObjectName, usize)>,
    next_ulsm: u32,
}

/// What [`Vmd::handle`] did to a program invocation, for the node to act on.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Transition {
    /// The program invocation.
    pub name: ObjectName,
    /// The request that moved it.
    pub request: PiRequest,
    /// Its new state.
    pub state: PiState,
    /// The start argument, for Start.
    pub argument: String,
}

impl Vmd {
    /// An empty VMD.
    pub fn new(identity: Identity) -> Self {
        Self {
            identity,
            memory: RECIPE_MEMORY,
            domains: BTreeMap::new(),
            programs: BTreeMap::new(),
            uploads: BTreeMap::new(),
            next_ulsm: 1,
        }
    }

    /// Its recipe memory holds `bytes` from now on (what it holds stays).
    pub fn set_memory(&mut self, bytes: usize) {
        self.memory = bytes;
    }

    /// A domain by name.
    pub fn domain(&self, name: &ObjectName) -> Option<&Domain> {
        self.domains.get(name)
    }

    /// Every domain.
    pub fn domains(&self) -> impl Iterator<Item = &Domain> {
        self.domains.values()
    }

    /// A program invocation by name.
    pub fn program(&self, name: &ObjectName) -> Option<&ProgramInvocation> {
        self.programs.get(name)
    }

    /// Every program invocation.
    pub fn programs(&self) -> impl Iterator<Item = &ProgramInvocation> {
        self.programs.values()
    }

    /// Answers a service request that the object store owns; `None` for the
    /// others (association, status, operator communication), which the node
    /// answers itself. A program-invocation request that succeeded also
    /// returns its [`Transition`].
    pub fn handle(
        &mut self,
        request: &Request,
    ) -> Option<(Result<Response, ServiceError>, Option<Transition>)> {
        let plain = |r: Result<Response, ServiceError>| Some((r, None));
        match request {
            Request::Identify => plain(Ok(Response::Identify(self.identity.clone()))),
            Request::GetNameList(class) => plain(Ok(Response::NameList(match class {
                ObjectClass::Domain => self.domains.keys().cloned().collect(),
                ObjectClass::ProgramInvocation => self.programs.keys().cloned().collect(),
            }))),
            Request::InitiateDownloadSequence { domain } => plain(self.initiate_download(domain)),
            Request::DownloadSegment {
                domain,
                data,
                more_follows,
            } => plain(
                self.room_for(domain, data.len())
                    .and_then(|()| self.domain_mut(domain))
                    .and_then(|d| d.download_segment(data, *more_follows))
                    .map(|()| Response::Done),
            ),
            Request::TerminateDownloadSequence { domain, discard } => plain(
                self.domain_mut(domain)
                    .and_then(|d| d.terminate_download(discard.as_deref()))
                    .map(|()| Response::Done),
            ),
            Request::InitiateUploadSequence { domain } => plain(self.initiate_upload(domain)),
            Request::UploadSegment { ulsm } => plain(self.upload_segment(*ulsm)),
            Request::TerminateUploadSequence { ulsm } => plain(self.terminate_upload(*ulsm)),
            Request::DeleteDomain { domain } => plain(self.delete_domain(domain)),
            Request::GetDomainAttributes { domain } => plain(
                self.domain_ref(domain)
                    .map(|d| Response::DomainAttributes(d.attributes())),
            ),
            Request::CreateProgramInvocation {
                name,
                domains,
                reusable,
            } => plain(self.create_program(name, domains, *reusable)),
            Request::DeleteProgramInvocation { name } => plain(
                self.pi_request(name, PiRequest::Delete, "")
                    .map(|_| Response::Done),
            ),
            Request::Start { name, argument } => {
                Some(self.transition(name, PiRequest::Start, argument))
            }
            Request::Stop { name } => Some(self.transition(name, PiRequest::Stop, "")),
            Request::Resume { name } => Some(self.transition(name, PiRequest::Resume, "")),
            Request::Reset { name } => Some(self.transition(name, PiRequest::Reset, "")),
            Request::Kill { name } => Some(self.transition(name, PiRequest::Kill, "")),
            Request::GetProgramInvocationAttributes { name } => plain(
                self.programs
                    .get(name)
                    .map(|p| {
                        Response::PiAttributes(PiAttributes {
                            state: p.state(),
                            domains: p.domains().to_vec(),
                            reusable: p.reusable(),
                            deletable: p.deletable(),
                            last_end: p.last_end().cloned(),
                        })
                    })
                    .ok_or_else(|| undefined_pi(name)),
            ),
            Request::Initiate { .. }
            | Request::Conclude { .. }
            | Request::Abort { .. }
            | Request::Status
            | Request::Input { .. }
            | Request::Output { .. }
            | Request::Mode(_)
            | Request::Step { .. }
            | Request::Manual { .. } => None,
        }
    }

    /// The executor finished a transition (or the program ended).
    pub fn complete(
        &mut self,
        name: &ObjectName,
        completion: PiCompletion,
    ) -> Result<PiState, PiState> {
        match self.programs.get_mut(name) {
            Some(p) => p.complete(completion),
            None => Err(PiState::NonExistent),
        }
    }

    /// The executor's record of how a run of `name` ended (kept until its
    /// next Start; see [`ProgramInvocation::last_end`]).
    pub fn record_end(&mut self, name: &ObjectName, end: JobEvent) {
        if let Some(p) = self.programs.get_mut(name) {
            p.record_end(end);
        }
    }

    fn transition(
        &mut self,
        name: &ObjectName,
        request: PiRequest,
        argument: &str,
    ) -> (Result<Response, ServiceError>, Option<Transition>) {
        match self.pi_request(name, request, argument) {
            Ok(t) => (Ok(Response::ProgramInvocationState(t.state)), Some(t)),
            Err(e) => (Err(e), None),
        }
    }

    fn pi_request(
        &mut self,
        name: &ObjectName,
        request: PiRequest,
        argument: &str,
    ) -> Result<Transition, ServiceError> {
        let pi = self
            .programs
            .get_mut(name)
            .ok_or_else(|| undefined_pi(name))?;
        let state = pi.request(request)?;
        if state == PiState::NonExistent {
            if let Some(p) = self.programs.remove(name) {
                for d in p.domains() {
                    if let Some(domain) = self.domains.get_mut(d) {
                        domain.detach(name);
                    }
                }
            }
        }
        Ok(Transition {
            name: name.clone(),
            request,
            state,
            argument: argument.to_string(),
        })
    }

    fn domain_ref(&self, name: &ObjectName) -> Result<&Domain, ServiceError> {
        self.domains
            .get(name)
            .ok_or_else(|| ServiceError::undefined(format!("domain {name} does not exist")))
    }

    /// Whether `more` bytes of `domain` fit in the recipe memory.
    fn room_for(&self, domain: &ObjectName, more: usize) -> Result<(), ServiceError> {
        let used: usize = self.domains.values().map(|d| d.content().len()).sum();
        if used.saturating_add(more) <= self.memory {
            return Ok(());
        }
        Err(ServiceError::new(
            ErrorClass::Resource(ResourceError::MemoryUnavailable),
            format!(
                "the recipe memory is full: {used} of {} bytes used, {more} more asked for domain {domain}; delete a recipe or give the station more memory",
                self.memory
            ),
        ))
    }

    fn domain_mut(&mut self, name: &ObjectName) -> Result<&mut Domain, ServiceError> {
        self.domains
            .get_mut(name)
            .ok_or_else(|| ServiceError::undefined(format!("domain {name} does not exist")))
    }

    fn initiate_download(&mut self, name: &ObjectName) -> Result<Response, ServiceError> {
        if let Some(d) = self.domains.get(name) {
            return Err(ServiceError::new(
                ErrorClass::Definition(DefinitionError::ObjectExists),
                format!(
                    "domain {name} already exists ({}); delete it first",
                    d.state()
                ),
            ));
        }
        self.domains
            .insert(name.clone(), Domain::initiate_download(name.clone()));
        Ok(Response::Done)
    }

    fn delete_domain(&mut self, name: &ObjectName) -> Result<Response, ServiceError> {
        self.domain_ref(name)?.check_delete()?;
        self.domains.remove(name);
        Ok(Response::Done)
    }

    fn initiate_upload(&mut self, name: &ObjectName) -> Result<Response, ServiceError> {
        let domain = self.domain_mut(name)?;
        domain.begin_upload()?;
        let size = domain.content().len() as u64;
        let ulsm = self.next_ulsm;
        self.next_ulsm = self.next_ulsm.wrapping_add(1).max(1);
        self.uploads.insert(ulsm, (name.clone(), 0));
        Ok(Response::UploadStarted { ulsm, size })
    }

    fn upload_segment(&mut self, ulsm: u32) -> Result<Response, ServiceError> {
        let (name, offset) = self
            .uploads
            .get_mut(&ulsm)
            .ok_or_else(|| ServiceError::undefined(format!("upload {ulsm} is not in progress")))?;
        let content = self
            .domains
            .get(name)
            .map(|d| d.content())
            .ok_or_else(|| ServiceError::undefined(format!("domain {name} does not exist")))?;
        let end = (*offset + MAX_SEGMENT_BYTES).min(content.len());
        let data = content[*offset..end].to_vec();
        *offset = end;
        Ok(Response::Segment {
            data,
            more_follows: end < content.len(),
        })
    }

    fn terminate_upload(&mut self, ulsm: u32) -> Result<Response, ServiceError> {
        let (name, _) = self
            .uploads
            .remove(&ulsm)
            .ok_or_else(|| ServiceError::undefined(format!("upload {ulsm} is not in progress")))?;
        if let Some(d) = self.domains.get_mut(&name) {
            d.end_upload();
        }
        Ok(Response::Done)
    }

    fn create_program(
        &mut self,
        name: &ObjectName,
        domains: &[ObjectName],
        reusable: bool,
    ) -> Result<Response, ServiceError> {
        if self.programs.contains_key(name) {
            return Err(ServiceError::new(
                ErrorClass::Definition(DefinitionError::ObjectExists),
                format!("program invocation {name} already exists"),
            ));
        }
        for d in domains {
            self.domain_ref(d)?;
        }
        let ready = domains.iter().all(|d| {
            self.domains
                .get(d)
                .is_some_and(|d| matches!(d.state(), DomainState::Ready | DomainState::InUse))
        });
        if ready {
            for d in domains {
                self.domain_mut(d)?.attach(name)?;
            }
        }
        self.programs.insert(
            name.clone(),
            ProgramInvocation::create(name.clone(), domains.to_vec(), reusable, ready),
        );
        Ok(Response::Done)
    }
}

fn undefined_pi(name: &ObjectName) -> ServiceError {
    ServiceError::undefined(format!("program invocation {name} does not exist"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn name(s: &str) -> ObjectName {
        ObjectName::new(s).expect("valid")
    }

    fn vmd() -> Vmd {
        Vmd::new(Identity {
            vendor: "FALC".into(),
            model: "test".into(),
            revision: "0".into(),
        })
    }

    fn ok(v: &mut Vmd, r: Request) -> Response {
        match v.handle(&r) {
            Some((Ok(resp), _)) => resp,
            other => panic!("{r:?}: {other:?}"),
        }
    }

    fn download(v: &mut Vmd, domain: &str, text: &[u8]) {
        let domain = name(domain);
        ok(
            v,
            Request::InitiateDownloadSequence {
                domain: domain.clone(),
            },
        );
        ok(
            v,
            Request::DownloadSegment {
                domain: domain.clone(),
                data: text.to_vec(),
                more_follows: false,
            },
        );
        ok(
            v,
            Request::TerminateDownloadSequence {
                domain,
                discard: None,
            },
        );
    }

    #[test]
    fn a_download_past_the_recipe_memory_is_refused_and_a_deletion_makes_room() {
        let mut v = vmd();
        v.set_memory(100);
        download(&mut v, "A", &[b'a'; 60]);
        ok(
            &mut v,
            Request::InitiateDownloadSequence { domain: name("B") },
        );
        let seg = Request::DownloadSegment {
            domain: name("B"),
            data: vec![b'b'; 41],
            more_follows: false,
        };
        let Some((Err(e), None)) = v.handle(&seg) else {
            panic!("41 bytes more fitted in 40")
        };
        assert_eq!(
            e.class,
            ErrorClass::Resource(ResourceError::MemoryUnavailable)
        );
        assert!(
            e.description.starts_with(
                "the recipe memory is full: 60 of 100 bytes used, 41 more asked for domain B"
            ),
            "{e}"
        );
        ok(&mut v, Request::DeleteDomain { domain: name("A") });
        ok(&mut v, seg);
    }

    #[test]
    fn download_create_start_complete_upload() {
        let mut v = vmd();
        download(&mut v, "STORE", b"#STORE\n-1 | activate k | | | 0\n");
        ok(
            &mut v,
            Request::CreateProgramInvocation {
                name: name("STORE"),
                domains: vec![name("STORE")],
                reusable: true,
            },
        );
        assert_eq!(
            v.domain(&name("STORE")).map(|d| d.state()),
            Some(DomainState::InUse)
        );
        let (resp, t) = v
            .handle(&Request::Start {
                name: name("STORE"),
                argument: "x".into(),
            })
            .expect("handled");
        assert_eq!(
            resp,
            Ok(Response::ProgramInvocationState(PiState::Starting))
        );
        assert_eq!(
            t.map(|t| (t.request, t.argument)),
            Some((PiRequest::Start, "x".into()))
        );
        assert_eq!(
            v.complete(&name("STORE"), PiCompletion::Started),
            Ok(PiState::Running)
        );
        // A second Start answers with the current state.
        let (resp, _) = v
            .handle(&Request::Start {
                name: name("STORE"),
                argument: String::new(),
            })
            .expect("handled");
        let err = resp.expect_err("refused");
        assert_eq!(
            err.specific,
            Some(super::super::error::ServiceSpecific::ProgramInvocationState(PiState::Running))
        );
        // Upload returns the same bytes.
        let Response::UploadStarted { ulsm, size } = ok(
            &mut v,
            Request::InitiateUploadSequence {
                domain: name("STORE"),
            },
        ) else {
            panic!("no upload")
        };
        assert_eq!(size, 31);
        let Response::Segment { data, more_follows } = ok(&mut v, Request::UploadSegment { ulsm })
        else {
            panic!("no segment")
        };
        assert!(!more_follows);
        assert_eq!(data, b"#STORE\n-1 | activate k | | | 0\n");
        ok(&mut v, Request::TerminateUploadSequence { ulsm });
        // In use: delete refused; after the invocation is deleted it works.
        assert!(matches!(
            v.handle(&Request::DeleteDomain {
                domain: name("STORE")
            }),
            Some((Err(_), _))
        ));
        assert_eq!(
            v.complete(&name("STORE"), PiCompletion::Finished),
            Ok(PiState::Idle)
        );
        ok(
            &mut v,
            Request::DeleteProgramInvocation {
                name: name("STORE"),
            },
        );
        ok(
            &mut v,
            Request::DeleteDomain {
                domain: name("STORE"),
            },
        );
        assert_eq!(
            ok(&mut v, Request::GetNameList(ObjectClass::Domain)),
            Response::NameList(vec![])
        );
    }

    #[test]
    fn errors_name_the_object() {
        let mut v = vmd();
        let Some((Err(e), _)) = v.handle(&Request::Start {
            name: name("NOPE"),
            argument: String::new(),
        }) else {
            panic!("not refused")
        };
        assert_eq!(
            e.to_string(),
            "definition/object-undefined: program invocation NOPE does not exist"
        );
        download(&mut v, "A", b"x");
        let Some((Err(e), _)) = v.handle(&Request::InitiateDownloadSequence { domain: name("A") })
        else {
            panic!("not refused")
        };
        assert_eq!(e.class.to_string(), "definition/object-exists");
        assert!(v.handle(&Request::Status).is_none(), "status is the node's");
    }
}
