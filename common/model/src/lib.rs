//! FALC's model, with no I/O: what every level and every console agrees on.
//!
//! - [`ids`]: validated names (stations, cells, MMS objects);
//! - [`topology`]: `launch/cell.toml`, the cell's stations and hierarchy;
//! - [`plant`]: `launch/factory.toml`, several cells under one operator;
//! - [`alarm`]: alarm classes, causes and the operator's alarm record;
//! - [`mms`]: the MMS-equivalent service model, sans-I/O;
//! - [`console`]: what a console asks the operator node and what it answers;
//! - [`figures`]: the shift calendar and the ISO 22400-2 figures;
//! - [`product`]: recipe versions and what the records keep of a product;
//! - [`mode`]: the cell's operating modes and manual operations;
//! - [`keys`]: every zenoh key of a cell, as data;
//! - [`envelope`]: the payload format on the wire.

pub mod alarm;
pub mod console;
pub mod envelope;
pub mod figures;
pub mod ids;
pub mod keys;
pub mod mms;
pub mod mode;
pub mod plant;
pub mod product;
pub mod topology;
