//! The DNC link between the welding workstation and the robot controller
//! (RCM 815), sans-I/O: the 3964R procedure ([`procedure`]), the DNC
//! telegrams on top ([`telegram`]), the table that turns RCM message
//! numbers into `RobotStatusDetail` and recipe criteria ([`alarms`]); the
//! welding workstation's side of the link ([`host`]) and the robot
//! controller's twin ([`robot`]), both on an injected clock. The serial
//! port driver is `falc_node::dnc_link`; `falc-welding` and `falc-rcm-sim`
//! drive [`host`] and [`robot`].

// A codec reads bytes from outside: no index may panic.
#![warn(clippy::indexing_slicing)]

pub mod alarms;
pub mod host;
pub mod procedure;
pub mod robot;
pub mod telegram;
