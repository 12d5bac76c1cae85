//! The recipe language (docs/the-1992-cell.md §2, recipes/README.md): state tables that
//! operators write and controllers interpret at run time. No I/O here
//! except [`files`], which reads recipe directories.
//!
//! text → [`syntax::parse`] → [`syntax::Recipe`] → [`check::check`] →
//! [`check::Program`] → [`engine::Engine`] (events in, actions out).
//! [`dot::to_dot`] draws a program as Graphviz DOT.

pub mod check;
pub mod commands;
pub mod condition;
pub mod dot;
pub mod engine;
pub mod files;
pub mod problem;
pub mod robot_program;
pub mod syntax;
pub mod verify;
