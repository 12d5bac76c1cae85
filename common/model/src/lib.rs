//! FALC's model, with no I/O: what every level and every console agrees on.
//!
//! - [`ids`]: validated names (stations, cells, MMS objects);
//! - [`topology`]: `launch/cell.toml`, the cell's stations and hierarchy;
//! - [`plant`]: `launch/factory.toml`, several cells under one operator;
//! - [`alarm`]: alarm classes, causes and the operator's alarm record;
//! - [`mms`]: the MMS-equivalent service model, sans-I/O;
//! - [`api`]: the operator API, what a console asks the operator node and
//!   what it answers;
//! - [`records`]: orders and journal entries, as the operator keeps them;
//! - [`recipe_file`]: a recipe file of the operator's store;
//! - [`time`]: times in words, as records write them;
//! - [`calendar`]: the shift calendar, when a cell is planned to work;
//! - [`figures`]: the ISO 22400-2 figures;
//! - [`product`]: recipe versions and what the records keep of a product;
//! - [`mode`]: the cell's operating modes and manual operations;
//! - [`keys`]: every zenoh key of a cell, as data;
//! - [`envelope`]: the payload format on the wire.

pub mod alarm;
pub mod api;
pub mod calendar;
pub mod envelope;
pub mod figures;
pub mod ids;
pub mod keys;
pub mod mms;
pub mod mode;
pub mod plant;
pub mod product;
pub mod recipe_file;
pub mod records;
pub mod time;
pub mod topology;
