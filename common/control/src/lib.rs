//! FALC's controller cores, sans-I/O: events in with the time they happen,
//! commands and publications out, [`controller::Controller::poll_timeout`]
//! for the next deadline. Node binaries drive them through
//! `falc_node::controller_node`.
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
//!   `falc-sim` run);
//! - [`order_list`]: the operator's order list worked through the cell,
//!   with its [`alarm_list`], over its durable [`records`] and the
//!   [`recipe_source`];
//! - [`figures`]: the ISO 22400-2 figures from the records, on any range;
//! - [`plant`]: the factory controller over several cells: one order list
//!   per cell, the API's requests routed to the cells they concern.

pub mod alarm_list;
pub mod cell_node;
pub mod controller;
pub mod coordination;
pub mod figures;
pub mod order_list;
pub mod pass_on;
pub mod plant;
pub mod recipe_source;
pub mod records;
pub mod workstation_node;
