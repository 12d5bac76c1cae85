//! The conveyor PLC: its I/O map ([`map`]) and the Modbus TCP link to it
//! ([`driver`]).

pub mod driver;
pub mod map;
