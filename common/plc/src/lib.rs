//! The conveyor PLC's I/O map ([`map`]), the transport workstation's
//! device ([`workstation`]: the PLC as transport recipes see it, poll-style)
//! and the conveyor's twin ([`conveyor`]: carriers, lines and inputs driven
//! by coil writes on an injected clock), sans-I/O; [`feedback`]
//! supervises each actuator's feedback as the equipment file pairs them.
//! The Modbus TCP link to the PLC is `falc_node::plc_link`; `falc-plc-sim`
//! serves [`conveyor`] over Modbus TCP.

pub mod conveyor;
pub mod feedback;
pub mod map;
pub mod workstation;
