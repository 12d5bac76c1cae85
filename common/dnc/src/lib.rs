//! The DNC link between the welding workstation and the robot controller
//! (RCM 815), sans-I/O: the 3964R procedure ([`procedure`]), the DNC
//! telegrams on top ([`telegram`]) and the table that turns RCM message
//! numbers into `RobotStatusDetail` and recipe criteria ([`alarms`]). The
//! serial port driver is `falc_node::dnc_link`.

// A codec reads bytes from outside: no index may panic.
#![warn(clippy::indexing_slicing)]

pub mod alarms;
pub mod procedure;
pub mod telegram;
