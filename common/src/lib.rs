//! FALC shared library: everything the node binaries have in common.
//!
//! - [`alarm`]: alarm classes, causes and the operator's alarm record;
//! - [`api`]: the operator API consoles use (requests, orders, journal);
//! - [`ids`]: validated names (stations, cells, MMS objects);
//! - [`topology`]: `launch/cell.toml`, the cell's stations and hierarchy;
//! - [`mms`]: the MMS-equivalent service model, sans-I/O;
//! - [`node`]: what every node binary does at start (arguments, logs);
//! - [`dnc`]: the DNC link to the robot controller (3964R, telegrams);
//! - [`plc`]: the conveyor PLC's I/O map and its Modbus TCP link;
//! - [`recipe`]: the recipe language: parser, checker, engine, diagrams;
//! - [`workstation`]: a workstation node's recipe runtime (welding,
//!   transport), around its device;
//! - [`bus`]: the zenoh binding: keys, envelope, sessions, credentials, ACL,
//!   service client and server, stations with their associations.

pub mod alarm;
pub mod api;
pub mod bus;
pub mod dnc;
pub mod ids;
pub mod mms;
pub mod node;
pub mod plc;
pub mod recipe;
pub mod topology;
pub mod workstation;
