//! The conveyor PLC's I/O map ([`map`]), sans-I/O. The Modbus TCP link to
//! the PLC is `falc_node::plc_link`.

pub mod map;
