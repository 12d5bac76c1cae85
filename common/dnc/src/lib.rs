//! The DNC link between the welding workstation and the robot controller
//! (RCM 815), sans-I/O: the 3964R procedure ([`procedure`]), the DNC
//! telegrams on top ([`telegram`]) that also deliver a robot program's
//! text (`falc_recipe::robot_program`), the table that turns RCM message
//! numbers into `RobotStatusDetail` and recipe criteria ([`alarms`]); the
//! welding workstation's side of the link ([`host`]) and its device as
//! welding recipes see it ([`workstation`], poll-style), the robot
//! controller's twin ([`robot`]) and the twin at its end of the line
//! ([`twin`]), all on an injected clock. The serial port driver is
//! `falc_node::dnc_link`; `falc-welding` drives [`workstation`],
//! `falc-rcm-sim` drives [`twin`], and `falc-sim` both on one virtual clock.

// A codec reads bytes from outside: no index may panic.
#![warn(clippy::indexing_slicing)]

pub mod alarms;
pub mod host;
pub mod procedure;
pub mod robot;
pub mod telegram;
pub mod twin;
pub mod workstation;
