//! The recipe language (DESIGN.md §6, SEED-NOTES.md §2): state tables that
//! operators write and controllers interpret at run time. No I/O here
//! except [`files`], which reads recipe directories.
//!
//! text → [`syntax::parse`] → [`syntax::Recipe`] → [`check::check`] →
//! [`check::Program`] → [`engine::Engine`] (events in, actions out).
//! [`dot::to_dot`] draws a program as Graphviz DOT.

pub mod check;
pub mod commands;
pub mod dot;
pub mod engine;
pub mod files;
pub mod problem;
pub mod syntax;
pub mod verify;
