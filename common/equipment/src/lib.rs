//! Equipment in data: a conveyor described by a file (`equipment/*.toml`)
//! rather than by code, so that a cell of another layout needs a file, not
//! Rust. [`mod@file`] reads and checks it (every problem with file and line),
//! [`signal`] names what it holds,
//! [`states`] its named states and the way to one. The transport workstation, its twin
//! (`falc_plc`), the recipe store and the consoles read the same file.

pub mod file;
pub mod signal;
pub mod states;
pub mod vocabulary;

pub use file::{Equipment, Problem, Problems};
