//! The integration tests, as one test binary (one link against zenoh for
//! all of them): real `falc-router`, real node processes and twins on free
//! localhost ports, started by [`support`] and killed on drop. One module
//! per area; docs/testing.md says what each covers.

// A test stops on what it did not expect.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod support;

mod cell;
mod chaos;
mod conditions;
mod dnc;
mod fuzz;
mod hierarchy;
mod hosts;
mod identity;
mod launch;
mod limits;
mod lost;
mod manual;
mod modes;
mod noise;
mod opcua;
mod operator;
mod plant;
mod programs;
mod recipes;
mod records;
mod recovery;
mod restart;
mod roles;
mod safe_state;
mod secure;
mod services;
mod stanzas;
mod states;
mod transport;
mod tui;
mod welding;
