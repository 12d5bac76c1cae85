//! Domains (ISO 9506-1 §10): named recipe texts, downloaded in segments
//! pushed by the commander and uploaded back on request. A domain is
//! `ready` only after a complete download; a program invocation that uses
//! it makes it `in-use`, and an in-use domain cannot be deleted.
//!
//! Deviation from MMS: segments are pushed by the client (the commander), so
//! requests keep flowing down the hierarchy.

use super::error::{
    DefinitionError, ErrorClass, ResourceError, ServiceError, ServiceErrorCode, ServiceSpecific,
};
use super::pdu::Request;
use crate::ids::ObjectName;
use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
use std::fmt;

/// The largest domain accepted (a recipe is a few KiB).
pub const MAX_DOMAIN_BYTES: usize = 1 << 20;
/// The largest segment, in either direction.
pub const MAX_SEGMENT_BYTES: usize = 16 * 1024;

/// The domain states of ISO 9506-1 used here.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[allow(missing_docs)]
pub enum DomainState {
    NonExistent,
    Loading,
    Complete,
    Incomplete,
    Ready,
    InUse,
}

impl fmt::Display for DomainState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::NonExistent => "non-existent",
            Self::Loading => "loading",
            Self::Complete => "complete",
            Self::Incomplete => "incomplete",
            Self::Ready => "ready",
            Self::InUse => "in-use",
        })
    }
}

/// What GetDomainAttributes answers.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct DomainAttributes {
    /// The domain's state.
    pub state: DomainState,
    /// Its size in bytes.
    pub size: u64,
    /// Its content hash (FNV-1a 64 over the bytes), to resend only what changed.
    pub content_hash: u64,
    /// Whether Delete is allowed.
    pub deletable: bool,
    /// The program invocations that use it.
    pub program_invocations: Vec<ObjectName>,
    /// Uploads in progress.
    pub uploads_in_progress: u32,
}

/// FNV-1a 64: the content hash of a domain (change detection, not security).
pub fn content_hash(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// One domain.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Domain {
    name: ObjectName,
    state: DomainState,
    content: Vec<u8>,
    users: BTreeSet<ObjectName>,
    uploads: u32,
}

impl Domain {
    /// InitiateDownloadSequence: a new domain in `loading`.
    pub fn initiate_download(name: ObjectName) -> Self {
        Self {
            name,
            state: DomainState::Loading,
            content: Vec::new(),
            users: BTreeSet::new(),
            uploads: 0,
        }
    }

    /// Its name.
    pub fn name(&self) -> &ObjectName {
        &self.name
    }

    /// Its state.
    pub fn state(&self) -> DomainState {
        self.state
    }

    /// Its bytes.
    pub fn content(&self) -> &[u8] {
        &self.content
    }

    fn conflict(&self, what: &str) -> ServiceError {
        ServiceError::state_conflict(format!(
            "{what} refused: domain {} is {}",
            self.name, self.state
        ))
        .with(ServiceSpecific::DomainState(self.state))
    }

    /// DownloadSegment: appends; the last segment (`more_follows = false`)
    /// makes the domain `complete`.
    pub fn download_segment(
        &mut self,
        data: &[u8],
        more_follows: bool,
    ) -> Result<(), ServiceError> {
        if self.state != DomainState::Loading {
            return Err(self.conflict("DownloadSegment"));
        }
        if data.len() > MAX_SEGMENT_BYTES {
            return Err(ServiceError::new(
                ErrorClass::Service(ServiceErrorCode::PduSize),
                format!(
                    "segment of {} bytes for domain {} exceeds {MAX_SEGMENT_BYTES}",
                    data.len(),
                    self.name
                ),
            ));
        }
        if self.content.len() + data.len() > MAX_DOMAIN_BYTES {
            self.state = DomainState::Incomplete;
            return Err(ServiceError::new(
                ErrorClass::Resource(ResourceError::MemoryUnavailable),
                format!("domain {} exceeds {MAX_DOMAIN_BYTES} bytes", self.name),
            ));
        }
        self.content.extend_from_slice(data);
        if !more_follows {
            self.state = DomainState::Complete;
        }
        Ok(())
    }

    /// TerminateDownloadSequence: `complete` becomes `ready`; a download
    /// discarded or terminated before its last segment becomes `incomplete`
    /// (and can only be deleted).
    pub fn terminate_download(&mut self, discard: Option<&str>) -> Result<(), ServiceError> {
        match (self.state, discard) {
            (DomainState::Complete, None) => {
                self.state = DomainState::Ready;
                Ok(())
            }
            (DomainState::Loading | DomainState::Complete, Some(reason)) => {
                self.state = DomainState::Incomplete;
                Err(ServiceError::new(
                    ErrorClass::VmdState(super::error::VmdStateError::DomainTransferProblem),
                    format!("download of domain {} discarded: {reason}", self.name),
                ))
            }
            (DomainState::Loading, None) => {
                self.state = DomainState::Incomplete;
                Err(ServiceError::new(
                    ErrorClass::Service(ServiceErrorCode::PrimitivesOutOfSequence),
                    format!(
                        "download of domain {} terminated before its last segment",
                        self.name
                    ),
                ))
            }
            _ => Err(self.conflict("TerminateDownloadSequence")),
        }
    }

    /// Whether DeleteDomain is allowed now (else the refusal).
    pub fn check_delete(&self) -> Result<(), ServiceError> {
        match self.state {
            DomainState::InUse => Err(self.conflict("DeleteDomain")),
            _ if self.uploads > 0 => Err(self.conflict("DeleteDomain during an upload")),
            _ => Ok(()),
        }
    }

    /// A program invocation starts using it: `ready` → `in-use`.
    pub fn attach(&mut self, pi: &ObjectName) -> Result<(), ServiceError> {
        match self.state {
            DomainState::Ready | DomainState::InUse => {
                self.users.insert(pi.clone());
                self.state = DomainState::InUse;
                Ok(())
            }
            _ => Err(ServiceError::new(
                ErrorClass::Definition(DefinitionError::ObjectAttributeInconsistent),
                format!(
                    "program invocation {pi} cannot use domain {}: it is {}",
                    self.name, self.state
                ),
            )
            .with(ServiceSpecific::DomainState(self.state))),
        }
    }

    /// A program invocation stops using it: `in-use` → `ready` when none is left.
    pub fn detach(&mut self, pi: &ObjectName) {
        self.users.remove(pi);
        if self.users.is_empty() && self.state == DomainState::InUse {
            self.state = DomainState::Ready;
        }
    }

    /// InitiateUploadSequence: allowed on a loaded domain.
    pub fn begin_upload(&mut self) -> Result<(), ServiceError> {
        match self.state {
            DomainState::Ready | DomainState::InUse => {
                self.uploads += 1;
                Ok(())
            }
            _ => Err(self.conflict("InitiateUploadSequence")),
        }
    }

    /// TerminateUploadSequence.
    pub fn end_upload(&mut self) {
        self.uploads = self.uploads.saturating_sub(1);
    }

    /// GetDomainAttributes.
    pub fn attributes(&self) -> DomainAttributes {
        DomainAttributes {
            state: self.state,
            size: self.content.len() as u64,
            content_hash: content_hash(&self.content),
            deletable: true,
            program_invocations: self.users.iter().cloned().collect(),
            uploads_in_progress: self.uploads,
        }
    }
}

/// Download segments are at most this long.
pub const SEGMENT: usize = 8 * 1024;

/// The requests that download `content` as domain `name`, in order.
pub fn download_steps(name: &ObjectName, content: &[u8]) -> Vec<Request> {
    let mut steps = vec![Request::InitiateDownloadSequence {
        domain: name.clone(),
    }];
    let chunks: Vec<&[u8]> = if content.is_empty() {
        vec![content]
    } else {
        content.chunks(SEGMENT).collect()
    };
    let n = chunks.len();
    for (i, c) in chunks.into_iter().enumerate() {
        steps.push(Request::DownloadSegment {
            domain: name.clone(),
            data: c.to_vec(),
            more_follows: i + 1 < n,
        });
    }
    steps.push(Request::TerminateDownloadSequence {
        domain: name.clone(),
        discard: None,
    });
    steps
}

#[cfg(test)]
mod tests {
    use super::*;

    fn name(s: &str) -> ObjectName {
        ObjectName::new(s).expect("valid")
    }

    #[test]
    fn download_loading_complete_ready() {
        let mut d = Domain::initiate_download(name("store"));
        assert_eq!(d.state(), DomainState::Loading);
        assert_eq!(d.download_segment(b"-1 | activate k", true), Ok(()));
        assert_eq!(d.state(), DomainState::Loading);
        assert_eq!(d.download_segment(b" | | 0\n", false), Ok(()));
        assert_eq!(d.state(), DomainState::Complete);
        assert_eq!(d.terminate_download(None), Ok(()));
        assert_eq!(d.state(), DomainState::Ready);
        assert_eq!(d.content(), b"-1 | activate k | | 0\n");
        assert_eq!(
            d.attributes().content_hash,
            content_hash(b"-1 | activate k | | 0\n")
        );
    }

    #[test]
    fn segment_after_complete_is_refused_with_state() {
        let mut d = Domain::initiate_download(name("store"));
        assert_eq!(d.download_segment(b"x", false), Ok(()));
        let e = d.download_segment(b"y", false).expect_err("refused");
        assert_eq!(
            e.specific,
            Some(ServiceSpecific::DomainState(DomainState::Complete))
        );
        assert_eq!(d.content(), b"x", "nothing appended");
    }

    #[test]
    fn early_terminate_or_discard_leaves_incomplete() {
        let mut d = Domain::initiate_download(name("a"));
        assert_eq!(d.download_segment(b"x", true), Ok(()));
        let e = d.terminate_download(None).expect_err("early");
        assert_eq!(e.class.to_string(), "service/primitives-out-of-sequence");
        assert_eq!(d.state(), DomainState::Incomplete);
        assert!(
            d.attach(&name("P")).is_err(),
            "an incomplete domain cannot be used"
        );
        assert_eq!(d.check_delete(), Ok(()));

        let mut d = Domain::initiate_download(name("b"));
        assert_eq!(d.download_segment(b"x", false), Ok(()));
        assert!(d.terminate_download(Some("checker found errors")).is_err());
        assert_eq!(d.state(), DomainState::Incomplete);
        assert!(
            d.terminate_download(None).is_err(),
            "incomplete stays incomplete"
        );
    }

    #[test]
    fn in_use_cannot_be_deleted_until_detached() {
        let mut d = Domain::initiate_download(name("a"));
        assert_eq!(d.download_segment(b"x", false), Ok(()));
        assert_eq!(d.terminate_download(None), Ok(()));
        assert_eq!(d.attach(&name("P1")), Ok(()));
        assert_eq!(d.attach(&name("P2")), Ok(()));
        assert_eq!(d.state(), DomainState::InUse);
        assert!(d.check_delete().is_err());
        d.detach(&name("P1"));
        assert_eq!(d.state(), DomainState::InUse);
        d.detach(&name("P2"));
        assert_eq!(d.state(), DomainState::Ready);
        assert_eq!(d.check_delete(), Ok(()));
    }

    #[test]
    fn upload_only_when_loaded_and_blocks_delete() {
        let mut d = Domain::initiate_download(name("a"));
        assert!(d.begin_upload().is_err());
        assert_eq!(d.download_segment(b"x", false), Ok(()));
        assert_eq!(d.terminate_download(None), Ok(()));
        assert_eq!(d.begin_upload(), Ok(()));
        assert!(d.check_delete().is_err());
        d.end_upload();
        assert_eq!(d.check_delete(), Ok(()));
    }

    #[test]
    fn size_limits() {
        let mut d = Domain::initiate_download(name("a"));
        let big = vec![b'x'; MAX_SEGMENT_BYTES + 1];
        assert_eq!(
            d.download_segment(&big, true)
                .map_err(|e| e.class.to_string()),
            Err("service/pdu-size".to_string())
        );
        let seg = vec![b'x'; MAX_SEGMENT_BYTES];
        let mut result = Ok(());
        for _ in 0..=(MAX_DOMAIN_BYTES / MAX_SEGMENT_BYTES) {
            result = d.download_segment(&seg, true);
            if result.is_err() {
                break;
            }
        }
        assert_eq!(
            result.map_err(|e| e.class.to_string()),
            Err("resource/memory-unavailable".to_string())
        );
        assert_eq!(d.state(), DomainState::Incomplete);
    }

    #[test]
    fn steps_cut_content_into_segments() {
        let name = ObjectName::new("store").expect("valid");
        let steps = download_steps(&name, &vec![b'x'; SEGMENT * 2 + 1]);
        assert_eq!(steps.len(), 5);
        assert!(matches!(
            steps[3],
            Request::DownloadSegment {
                more_follows: false,
                ..
            }
        ));
        assert_eq!(download_steps(&name, b"").len(), 3);
    }
}
