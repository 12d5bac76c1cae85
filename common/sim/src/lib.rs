//! `falc-sim`: the whole cell, or a plant of cells, in one process on one
//! virtual clock, the way FoundationDB and TigerBeetle test themselves. It
//! wires the very cores the nodes run (the operator's plant of order lists
//! with records in memory; in each cell the cell controller, the welding
//! and transport workstations with their devices, the robot controller's
//! twin behind the 3964R procedure at both ends of a serial line, the
//! conveyor's twin behind the I/O map) on an in-memory bus with latency,
//! loss and cuts per link, and a router per cell joined by its uplink in a
//! plant ([`bus`], [`world`]).
//!
//! A run ([`scenario`]) works through orders as an operator would,
//! injects faults from a seed (a crashed process, the robot's
//! emergency stop and limit switch, an unplugged or noisy serial line, a
//! jammed carrier, a stuck sensor, a cut link or uplink, a full disk), takes the
//! documented way back after each, and checks the invariants after every
//! step. A broken invariant comes with the events that led there; the same
//! seed replays it. No tokio, no zenoh, no sockets, no wall clock.

pub mod bus;
pub mod cell;
pub mod recipes;
pub mod scenario;
pub mod world;

pub use scenario::{Config, Fault, Run, Summary, Violation};
