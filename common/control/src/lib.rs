//! FALC's controller cores, sans-I/O: the recipe runtime every control
//! level runs below the operator. Events in with the time they happen,
//! commands and publications out, [`controller::Controller::poll_timeout`]
//! for the next deadline. The node binaries carry their actions
//! (`falc_node::controller_node`, `falc-cell`); the device protocol crates
//! (`falc-dnc`, `falc-plc`) depend on this runtime only.
//!
//! - [`controller`]: the recipe runtime every level runs (a workstation
//!   around its device, the cell around its workstations): the VMD served
//!   to the commander, one running recipe, its job events and reports;
//! - [`coordination`]: the cell's device: its workstations below and the
//!   operator above, requests out as commands, confirms and job events in;
//! - [`pass_on`]: the cell's pass-on of modes, steps, manual operations
//!   and workstation recipes to its workstations;
//! - [`cell_node`]: the cell controller's node: the controller over its
//!   stations, the pass-on in front of it, a request lane per station
//!   (what `falc-cell` and `falc-sim` both run);
//! - [`workstation_node`]: a workstation's node: the controller around a
//!   device with a link (what `falc-welding`, `falc-transport` and
//!   `falc-sim` run).
//!
//! The operator's cores (order list, plant, records, figures) are
//! `falc-factory`'s.

pub mod cell_node;
pub mod controller;
pub mod coordination;
pub mod pass_on;
pub mod workstation_node;
