//! The MMS-equivalent service model (ISO 9506 names), with no I/O: errors,
//! VMD status and object store, domains, program invocations, the wire
//! messages and the association state machine.

pub mod association;
pub mod domain;
pub mod error;
pub mod pdu;
pub mod program;
pub mod vmd;
