//! `ServiceError`: the ISO 9506-2 error classes and codes, with a readable
//! description of what went wrong and, where the standard defines one, the
//! service-specific information (a refused Start answers with the program
//! invocation's current state).

use serde::{Deserialize, Serialize};
use std::fmt;

macro_rules! error_codes {
    ($(#[$doc:meta])* $name:ident { $($variant:ident = $num:literal => $text:literal),+ $(,)? }) => {
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
        #[allow(missing_docs)]
        pub enum $name { $($variant),+ }

        impl $name {
            /// Every code of this class, in numeric order.
            pub const ALL: &'static [$name] = &[$($name::$variant),+];

            /// The code's number in ISO 9506-2.
            pub fn number(self) -> u8 {
                match self { $($name::$variant => $num),+ }
            }

            /// The code's ISO 9506 spelling.
            pub fn as_str(self) -> &'static str {
                match self { $($name::$variant => $text),+ }
            }
        }
    };
}

error_codes!(
    /// `vmd-state` errors.
    VmdStateError {
        Other = 0 => "other",
        VmdStateConflict = 1 => "vmd-state-conflict",
        VmdOperationalProblem = 2 => "vmd-operational-problem",
        DomainTransferProblem = 3 => "domain-transfer-problem",
        StateMachineIdInvalid = 4 => "state-machine-id-invalid",
    }
);
error_codes!(
    /// `application-reference` errors.
    ApplicationReferenceError {
        Other = 0 => "other",
        ApplicationUnreachable = 1 => "application-unreachable",
        ConnectionLost = 2 => "connection-lost",
        ApplicationReferenceInvalid = 3 => "application-reference-invalid",
        ContextUnsupported = 4 => "context-unsupported",
    }
);
error_codes!(
    /// `definition` errors.
    DefinitionError {
        Other = 0 => "other",
        ObjectUndefined = 1 => "object-undefined",
        InvalidAddress = 2 => "invalid-address",
        TypeUnsupported = 3 => "type-unsupported",
        TypeInconsistent = 4 => "type-inconsistent",
        ObjectExists = 5 => "object-exists",
        ObjectAttributeInconsistent = 6 => "object-attribute-inconsistent",
    }
);
error_codes!(
    /// `resource` errors.
    ResourceError {
        Other = 0 => "other",
        MemoryUnavailable = 1 => "memory-unavailable",
        ProcessorResourceUnavailable = 2 => "processor-resource-unavailable",
        MassStorageUnavailable = 3 => "mass-storage-unavailable",
        CapabilityUnavailable = 4 => "capability-unavailable",
        CapabilityUnknown = 5 => "capability-unknown",
    }
);
error_codes!(
    /// `service` errors.
    ServiceErrorCode {
        Other = 0 => "other",
        PrimitivesOutOfSequence = 1 => "primitives-out-of-sequence",
        ObjectStateConflict = 2 => "object-state-conflict",
        PduSize = 3 => "pdu-size",
        ContinuationInvalid = 4 => "continuation-invalid",
        ObjectConstraintConflict = 5 => "object-constraint-conflict",
    }
);
error_codes!(
    /// `service-preempt` errors.
    ServicePreemptError {
        Other = 0 => "other",
        Timeout = 1 => "timeout",
        Deadlock = 2 => "deadlock",
        Cancel = 3 => "cancel",
    }
);
error_codes!(
    /// `time-resolution` errors.
    TimeResolutionError {
        Other = 0 => "other",
        UnsupportableTimeResolution = 1 => "unsupportable-time-resolution",
    }
);
error_codes!(
    /// `access` errors.
    AccessError {
        Other = 0 => "other",
        ObjectAccessUnsupported = 1 => "object-access-unsupported",
        ObjectNonExistent = 2 => "object-non-existent",
        ObjectAccessDenied = 3 => "object-access-denied",
        ObjectInvalidated = 4 => "object-invalidated",
    }
);
error_codes!(
    /// `initiate` errors.
    InitiateError {
        Other = 0 => "other",
        VersionIncompatible = 1 => "version-incompatible",
        MaxSegmentInsufficient = 2 => "max-segment-insufficient",
        MaxServicesOutstandingCallingInsufficient = 3 => "max-services-outstanding-calling-insufficient",
        MaxServicesOutstandingCalledInsufficient = 4 => "max-services-outstanding-called-insufficient",
        ServiceCbbInsufficient = 5 => "service-CBB-insufficient",
        ParameterCbbInsufficient = 6 => "parameter-CBB-insufficient",
        NestingLevelInsufficient = 7 => "nesting-level-insufficient",
    }
);
error_codes!(
    /// `conclude` errors.
    ConcludeError {
        Other = 0 => "other",
        FurtherCommunicationRequired = 1 => "further-communication-required",
    }
);
error_codes!(
    /// `cancel` errors.
    CancelError {
        Other = 0 => "other",
        InvalidInvokeId = 1 => "invalid-invokeID",
        CancelNotPossible = 2 => "cancel-not-possible",
    }
);
error_codes!(
    /// `file` errors.
    FileError {
        Other = 0 => "other",
        FilenameAmbiguous = 1 => "filename-ambiguous",
        FileBusy = 2 => "file-busy",
        FilenameSyntaxError = 3 => "filename-syntax-error",
        ContentTypeInvalid = 4 => "content-type-invalid",
        PositionInvalid = 5 => "position-invalid",
        FileAccessDenied = 6 => "file-access-denied",
        FileNonExistent = 7 => "file-non-existent",
        DuplicateFilename = 8 => "duplicate-filename",
        InsufficientSpaceInFilestore = 9 => "insufficient-space-in-filestore",
    }
);

/// An ISO 9506-2 error class together with its code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[allow(missing_docs)]
pub enum ErrorClass {
    VmdState(VmdStateError),
    ApplicationReference(ApplicationReferenceError),
    Definition(DefinitionError),
    Resource(ResourceError),
    Service(ServiceErrorCode),
    ServicePreempt(ServicePreemptError),
    TimeResolution(TimeResolutionError),
    Access(AccessError),
    Initiate(InitiateError),
    Conclude(ConcludeError),
    Cancel(CancelError),
    File(FileError),
    /// `others`: an integer code outside the classes above.
    Others(i32),
}

impl ErrorClass {
    /// The class's ISO 9506 spelling.
    pub fn class_name(self) -> &'static str {
        match self {
            Self::VmdState(_) => "vmd-state",
            Self::ApplicationReference(_) => "application-reference",
            Self::Definition(_) => "definition",
            Self::Resource(_) => "resource",
            Self::Service(_) => "service",
            Self::ServicePreempt(_) => "service-preempt",
            Self::TimeResolution(_) => "time-resolution",
            Self::Access(_) => "access",
            Self::Initiate(_) => "initiate",
            Self::Conclude(_) => "conclude",
            Self::Cancel(_) => "cancel",
            Self::File(_) => "file",
            Self::Others(_) => "others",
        }
    }

    /// The class's tag number in the ASN.1 of ISO 9506-2 (0 … 12).
    pub fn class_number(self) -> u8 {
        match self {
            Self::VmdState(_) => 0,
            Self::ApplicationReference(_) => 1,
            Self::Definition(_) => 2,
            Self::Resource(_) => 3,
            Self::Service(_) => 4,
            Self::ServicePreempt(_) => 5,
            Self::TimeResolution(_) => 6,
            Self::Access(_) => 7,
            Self::Initiate(_) => 8,
            Self::Conclude(_) => 9,
            Self::Cancel(_) => 10,
            Self::File(_) => 11,
            Self::Others(_) => 12,
        }
    }

    /// The code's ISO 9506 spelling (`others` codes print as numbers).
    pub fn code_name(self) -> String {
        match self {
            Self::VmdState(c) => c.as_str().into(),
            Self::ApplicationReference(c) => c.as_str().into(),
            Self::Definition(c) => c.as_str().into(),
            Self::Resource(c) => c.as_str().into(),
            Self::Service(c) => c.as_str().into(),
            Self::ServicePreempt(c) => c.as_str().into(),
            Self::TimeResolution(c) => c.as_str().into(),
            Self::Access(c) => c.as_str().into(),
            Self::Initiate(c) => c.as_str().into(),
            Self::Conclude(c) => c.as_str().into(),
            Self::Cancel(c) => c.as_str().into(),
            Self::File(c) => c.as_str().into(),
            Self::Others(n) => n.to_string(),
        }
    }
}

impl fmt::Display for ErrorClass {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.class_name(), self.code_name())
    }
}

/// Service-specific information carried by some errors (ISO 9506-2 §7.4).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum ServiceSpecific {
    /// Start, Stop, Resume, Reset: the program invocation's current state.
    ProgramInvocationState(crate::mms::program::PiState),
    /// Domain services: the domain's current state.
    DomainState(crate::mms::domain::DomainState),
}

/// A negative confirm: the class/code, what went wrong in words, and any
/// service-specific information.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, thiserror::Error)]
#[error("{class}: {description}")]
pub struct ServiceError {
    /// The ISO 9506 class and code.
    pub class: ErrorClass,
    /// What went wrong, for a person.
    pub description: String,
    /// Service-specific information.
    pub specific: Option<ServiceSpecific>,
}

impl ServiceError {
    /// An error without service-specific information.
    pub fn new(class: ErrorClass, description: impl Into<String>) -> Self {
        Self {
            class,
            description: description.into(),
            specific: None,
        }
    }

    /// Adds service-specific information.
    pub fn with(mut self, specific: ServiceSpecific) -> Self {
        self.specific = Some(specific);
        self
    }

    /// `application-reference/application-unreachable`: nobody answered.
    pub fn unreachable(description: impl Into<String>) -> Self {
        Self::new(
            ErrorClass::ApplicationReference(ApplicationReferenceError::ApplicationUnreachable),
            description,
        )
    }

    /// Whether this is [`Self::unreachable`]: nobody answered (the router
    /// refuses a request its access control does not allow this way).
    pub fn is_unreachable(&self) -> bool {
        matches!(
            self.class,
            ErrorClass::ApplicationReference(ApplicationReferenceError::ApplicationUnreachable)
        )
    }

    /// `application-reference/connection-lost`: the association was aborted.
    pub fn connection_lost(description: impl Into<String>) -> Self {
        Self::new(
            ErrorClass::ApplicationReference(ApplicationReferenceError::ConnectionLost),
            description,
        )
    }

    /// Whether no answer came (unreachable, connection lost, time-out):
    /// the request may or may not have been carried out.
    pub fn unanswered(&self) -> bool {
        matches!(
            self.class,
            ErrorClass::ApplicationReference(
                ApplicationReferenceError::ApplicationUnreachable
                    | ApplicationReferenceError::ConnectionLost
            ) | ErrorClass::ServicePreempt(ServicePreemptError::Timeout)
        )
    }

    /// `service-preempt/timeout`: the confirm did not come in time.
    pub fn timeout(description: impl Into<String>) -> Self {
        Self::new(
            ErrorClass::ServicePreempt(ServicePreemptError::Timeout),
            description,
        )
    }

    /// `definition/object-undefined`.
    pub fn undefined(description: impl Into<String>) -> Self {
        Self::new(
            ErrorClass::Definition(DefinitionError::ObjectUndefined),
            description,
        )
    }

    /// `service/object-state-conflict`.
    pub fn state_conflict(description: impl Into<String>) -> Self {
        Self::new(
            ErrorClass::Service(ServiceErrorCode::ObjectStateConflict),
            description,
        )
    }

    /// `service/other`: a request that could not be understood.
    pub fn malformed(description: impl Into<String>) -> Self {
        Self::new(ErrorClass::Service(ServiceErrorCode::Other), description)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_numbers_are_dense_and_in_order() {
        fn dense(numbers: impl Iterator<Item = u8>) -> bool {
            numbers.enumerate().all(|(i, n)| i == n as usize)
        }
        assert!(dense(VmdStateError::ALL.iter().map(|c| c.number())));
        assert!(dense(
            ApplicationReferenceError::ALL.iter().map(|c| c.number())
        ));
        assert!(dense(DefinitionError::ALL.iter().map(|c| c.number())));
        assert!(dense(ResourceError::ALL.iter().map(|c| c.number())));
        assert!(dense(ServiceErrorCode::ALL.iter().map(|c| c.number())));
        assert!(dense(ServicePreemptError::ALL.iter().map(|c| c.number())));
        assert!(dense(TimeResolutionError::ALL.iter().map(|c| c.number())));
        assert!(dense(AccessError::ALL.iter().map(|c| c.number())));
        assert!(dense(InitiateError::ALL.iter().map(|c| c.number())));
        assert!(dense(ConcludeError::ALL.iter().map(|c| c.number())));
        assert!(dense(CancelError::ALL.iter().map(|c| c.number())));
        assert!(dense(FileError::ALL.iter().map(|c| c.number())));
        assert_eq!(FileError::ALL.len(), 10);
    }

    #[test]
    fn displays_class_code_and_description() {
        let e = ServiceError::unreachable("no reply from station welding");
        assert_eq!(
            e.to_string(),
            "application-reference/application-unreachable: no reply from station welding"
        );
        assert_eq!(e.class.class_number(), 1);
        assert!(e.is_unreachable() && e.unanswered());
        let lost = ServiceError::connection_lost("aborted");
        assert!(!lost.is_unreachable() && lost.unanswered());
        assert_eq!(ErrorClass::Others(42).to_string(), "others/42");
        assert_eq!(
            ErrorClass::Initiate(InitiateError::ServiceCbbInsufficient).to_string(),
            "initiate/service-CBB-insufficient"
        );
    }
}
