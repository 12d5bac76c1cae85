//! FALC's factory controller cores, sans-I/O: what `falc-operator` decides
//! above its cells, for any transport and clock (`falc-sim` runs the same).
//! Events in with the time they happen, calls to the cells and answers to
//! the consoles out; the records take their time from the `now` they are
//! given.
//!
//! - [`order_list`]: the operator's order list worked through the cell,
//!   with its [`alarm_list`], over its durable [`records`] and the
//!   [`recipe_source`];
//! - [`figures`]: the ISO 22400-2 figures from the records, on any range;
//! - [`plant`]: the factory controller over several cells: one order list
//!   per cell, the API's requests routed to the cells they concern.
//!
//! It shares nothing with the levels' runtime (`falc-control`): the two
//! meet only on the bus, through `falc-model`'s service primitives.

pub mod alarm_list;
pub mod figures;
pub mod order_list;
pub mod plant;
pub mod recipe_source;
pub mod records;
