//! The MMS-equivalent service model (ISO 9506 names), with no I/O: errors,
//! VMD status and object store, the kept reports (journal), domains and their delivery, program invocations, the wire
//! messages, what a receiver takes in of a publication (heard), the
//! association state machine and the station's association services
//! (serving).

pub mod association;
pub mod delivery;
pub mod domain;
pub mod error;
pub mod heard;
pub mod journal;
pub mod pdu;
pub mod program;
pub mod serving;
pub mod vmd;
