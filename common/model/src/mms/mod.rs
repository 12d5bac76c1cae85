//! The MMS-equivalent service model (ISO 9506 names), with no I/O: errors,
//! VMD status and object store, the kept reports (journal), domains, program invocations, the wire
//! messages and the association state machine.

pub mod association;
pub mod domain;
pub mod error;
pub mod journal;
pub mod pdu;
pub mod program;
pub mod vmd;
