//! The OPC UA companion specifications the gateway serves, as
//! async-opcua-codegen 0.19.0 generated them from the OPC Foundation's
//! published NodeSet2 files (`codegen.yml`, `regenerate`; the versions
//! are named in docs/opcua.md): OPC 10000-100 Devices (DI) 1.04.0,
//! OPC 40001-1 Machinery 1.03.0, OPC 10031-4 ISA-95 Job Control 2.0.0,
//! OPC 40001-3 Machinery Job Management 1.0.1 and OPC 40001-101 Machinery
//! Result Transfer 1.00.0. Nothing under
//! `src/generated` is written by hand; regenerate it instead of editing
//! it. ISA-95's, Job Management's and Result Transfer's data types are not
//! generated as Rust types (async-opcua-codegen 0.19 ignores optional
//! fields, which their structures have): the gateway decodes and encodes
//! them from their DataTypeDefinitions at run time.
#![allow(
    missing_docs,
    non_camel_case_types,
    unused_imports,
    clippy::all,
    clippy::pedantic,
    clippy::unwrap_used,
    clippy::expect_used
)]

#[path = "generated/di/ids.rs"]
#[doc(hidden)]
pub mod di_ids;
#[path = "generated/di/nodeset/mod.rs"]
mod di_nodeset;
#[path = "generated/di/types/mod.rs"]
#[doc(hidden)]
pub mod di_types;
#[path = "generated/isa95/ids.rs"]
#[doc(hidden)]
pub mod isa95_ids;
#[path = "generated/isa95/nodeset/mod.rs"]
mod isa95_nodeset;
#[path = "generated/jobs/ids.rs"]
#[doc(hidden)]
pub mod jobs_ids;
#[path = "generated/jobs/nodeset/mod.rs"]
mod jobs_nodeset;
#[path = "generated/machinery/ids.rs"]
#[doc(hidden)]
pub mod machinery_ids;
#[path = "generated/machinery/nodeset/mod.rs"]
mod machinery_nodeset;
#[path = "generated/result/ids.rs"]
#[doc(hidden)]
pub mod result_ids;
#[path = "generated/result/nodeset/mod.rs"]
mod result_nodeset;

/// OPC 10000-100 Devices: the Identification building blocks.
pub mod di {
    /// Its node ids (namespace 0 in the `From` impls: give the server's
    /// index of [`URI`] instead).
    pub use crate::di_ids as ids;
    pub use crate::di_nodeset::DiNamespace;
    /// Its data types.
    pub use crate::di_types as types;
    /// Its namespace URI.
    pub const URI: &str = "http://opcfoundation.org/UA/DI/";
}

/// OPC 40001-1 Machinery: machines, their identification and states.
pub mod machinery {
    /// Its node ids (namespace 0 in the `From` impls: give the server's
    /// index of [`URI`] instead).
    pub use crate::machinery_ids as ids;
    pub use crate::machinery_nodeset::MachineryNamespace;
    /// Its namespace URI.
    pub const URI: &str = "http://opcfoundation.org/UA/Machinery/";
}

/// OPC 10031-4 ISA-95 Job Control: job orders, their states and responses.
pub mod isa95 {
    /// Its node ids (namespace 0 in the `From` impls: give the server's
    /// index of [`URI`] instead).
    pub use crate::isa95_ids as ids;
    pub use crate::isa95_nodeset::Isa95JobControlNamespace;
    /// Its namespace URI.
    pub const URI: &str = "http://opcfoundation.org/UA/ISA95-JOBCONTROL_V2/";
}

/// OPC 40001-3 Machinery Job Management: a machine's JobManagement.
pub mod jobs {
    /// Its node ids (namespace 0 in the `From` impls: give the server's
    /// index of [`URI`] instead).
    pub use crate::jobs_ids as ids;
    pub use crate::jobs_nodeset::MachineryJobsNamespace;
    /// Its namespace URI.
    pub const URI: &str = "http://opcfoundation.org/UA/Machinery/Jobs/";
}

/// OPC 40001-101 Machinery Result Transfer: a machine's results.
pub mod result {
    /// Its node ids (namespace 0 in the `From` impls: give the server's
    /// index of [`URI`] instead).
    pub use crate::result_ids as ids;
    pub use crate::result_nodeset::MachineryResultNamespace;
    /// Its namespace URI.
    pub const URI: &str = "http://opcfoundation.org/UA/Machinery/Result/";
}
