//! A conveyor's signals and places as FALC names them: where a carrier can
//! be ([`Spot`]), a coil ([`Coil`]: a button FALC presses), a discrete
//! input ([`Input`]: a lamp FALC reads) and what an output goes to when
//! FALC can no longer know that acting on it is safe ([`SafeState`]). The
//! equipment file ([`crate::file`]) says which of them a conveyor has and
//! at which address.

use falc_model::ids::{Place, PlcStation};
use falc_recipe::check::{Button, Signal};
use std::fmt;

/// A place on the conveyor or a station: where a line begins and ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Spot {
    /// Place W2–W6.
    Place(Place),
    /// Station 1–99.
    Station(PlcStation),
}

/// Place `Wn` (for tests and examples).
#[allow(non_snake_case)]
pub const fn W(n: u8) -> Spot {
    Spot::Place(Place::of(n))
}

/// Station `Sn` (for tests and examples).
#[allow(non_snake_case)]
pub const fn S(n: u8) -> Spot {
    Spot::Station(PlcStation::of(n))
}

impl fmt::Display for Spot {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Spot::Place(n) => write!(f, "W{n}"),
            Spot::Station(n) => write!(f, "S{n}"),
        }
    }
}

/// A coil: a button FALC presses on the PLC.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Coil {
    /// A line or station button, or a plain output.
    Button(Button),
    /// External control: 1 = the PLC takes its buttons from these coils.
    ExternalControl,
}

/// A discrete input: a lamp FALC reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Input {
    /// A line, place or station signal, or a plain input: what a recipe
    /// can wait for.
    Signal(Signal),
    /// The PLC is running and accepts buttons.
    Ready,
    /// An emergency stop is active.
    EStop,
}

/// What an output goes to when the workstation can no longer know whether
/// acting on it is safe (the equipment file says it per coil and occasion:
/// [`crate::file::SafeStates`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SafeState {
    /// Released (`drop`): a conveyor line stops (nothing moves
    /// unsupervised).
    Off,
    /// Kept as it is (`hold`): a station's clamp holds its workpiece, since
    /// the robot may still weld it; only a command that comes after the
    /// robot is known to have stopped (the next job's, a maintainer's)
    /// releases it.
    Hold,
}

impl fmt::Display for Coil {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Coil::Button(Button::Line(c)) => write!(f, "button line {c}"),
            Coil::Button(Button::Station(n)) => write!(f, "button station {n}"),
            Coil::Button(Button::Output(n)) => write!(f, "output {n}"),
            Coil::ExternalControl => f.write_str("external control"),
        }
    }
}

impl fmt::Display for Input {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Input::Signal(s) => write!(f, "{}", SignalName(*s)),
            Input::Ready => f.write_str("PLC ready"),
            Input::EStop => f.write_str("emergency stop"),
        }
    }
}

/// A recipe signal named for people: `line E running`, `place 5 occupied`.
#[derive(Debug, Clone, Copy)]
pub struct SignalName(pub Signal);

impl fmt::Display for SignalName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            Signal::Line(c) => write!(f, "line {c} running"),
            Signal::Place(n) => write!(f, "place {n} occupied"),
            Signal::Station(n) => write!(f, "station {n} busy"),
            Signal::Input(n) => write!(f, "input {n}"),
        }
    }
}
