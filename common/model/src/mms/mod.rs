//! The MMS-equivalent service model (ISO 9506 names), with no I/O: errors,
//! VMD status and object store, the kept reports (journal), domains and their delivery, program invocations, the wire
//! messages, what a receiver takes in of a publication (heard) and the
//! association state machine.

pub mod association;
pub mod delivery;
pub mod domain;
pub mod error;
pub mod heard;
pub mod journal;
pub mod pdu;
pub mod program;
pub mod vmd;
