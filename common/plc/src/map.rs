//! The conveyor PLC's I/O map: which coil is which button and which
//! discrete input is which lamp, at configurable base addresses. One table
//! for the transport node, the twin and docs/plc.md (`falc-transport io
//! --map` prints it from this code), so a real PLC can be wired to it.
//!
//! | offset | coil (written by FALC) | discrete input (read by FALC) |
//! |---|---|---|
//! | 0–10 | button of line A, B, C, D, E, F, G, H, J, K, L | line A … L running |
//! | 11–15 | button of station 1, 2, 3; external control; – | place 2, 3, 4, 5, 6 occupied |
//! | 16–18 | – | station 1, 2, 3 busy |
//! | 19 | – | PLC ready |
//! | 20 | – | emergency stop active |

use falc_model::ids::{Place, PlcStation};
use falc_recipe::check::{Button, Signal};
use std::fmt;

/// The conveyor lines, in map order (no I: it reads like 1).
pub const LINES: [char; 11] = ['A', 'B', 'C', 'D', 'E', 'F', 'G', 'H', 'J', 'K', 'L'];
/// Number of coils in the map.
pub const COILS: u16 = 15;
/// Number of discrete inputs in the map.
pub const INPUTS: u16 = 21;

/// A place on the conveyor or a station: where a line begins and ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Spot {
    /// Place W2–W6.
    Place(Place),
    /// Station 1–3.
    Station(PlcStation),
}

/// Place `Wn` (a constant of the layout).
#[allow(non_snake_case)]
pub const fn W(n: u8) -> Spot {
    Spot::Place(Place::of(n))
}

/// Station `Sn` (a constant of the layout).
#[allow(non_snake_case)]
pub const fn S(n: u8) -> Spot {
    Spot::Station(PlcStation::of(n))
}

/// Where each line runs, as the conveyor is built (docs/plc.md): from a
/// place or station to another, in [`LINES`] order. The transport
/// supervises its place sensors by it ([`moves_towards`],
/// [`moves_away`]); the twin moves its carriers by it.
pub const ROUTES: [(char, Spot, Spot); 11] = [
    ('A', W(6), W(2)),
    ('B', W(2), W(6)),
    ('C', S(1), W(6)),
    ('D', W(4), W(2)),
    ('E', W(2), W(5)),
    ('F', S(3), W(4)),
    ('G', W(5), W(4)),
    ('H', W(3), W(5)),
    ('J', S(2), W(3)),
    ('K', W(2), W(3)),
    ('L', W(3), W(4)),
];

/// The place a station's button takes its carrier from.
pub fn feed(station: PlcStation) -> Option<Spot> {
    match station.number() {
        1 => Some(W(6)),
        2 => Some(W(3)),
        3 => Some(W(5)),
        _ => None,
    }
}

/// The lines that bring a carrier to `place`.
pub fn moves_towards(place: Place) -> impl Iterator<Item = char> {
    ROUTES
        .iter()
        .filter(move |(_, _, to)| *to == Spot::Place(place))
        .map(|(l, ..)| *l)
}

/// The lines that take a carrier away from `place`.
pub fn moves_away(place: Place) -> impl Iterator<Item = char> {
    ROUTES
        .iter()
        .filter(move |(_, from, _)| *from == Spot::Place(place))
        .map(|(l, ..)| *l)
}

/// Whether a feedback fault of each place's sensor (unrequested or lost)
/// needs an acknowledgement before the next start: a device alarm that
/// holds the list back (true), or a warning that does not (false; it is
/// listed until someone acknowledges it). Every sensor of this conveyor
/// needs one: a carrier where none should be, or gone, is never safe to
/// run on unseen ([`crate::workstation::Plc::with_feedback_ack`] sets
/// another choice).
pub const FEEDBACK_NEEDS_ACK: [(u8, bool); 5] =
    [(2, true), (3, true), (4, true), (5, true), (6, true)];

/// A coil: a button FALC presses on the PLC.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Coil {
    /// A line or station button.
    Button(Button),
    /// External control: 1 = the PLC takes its buttons from these coils.
    ExternalControl,
}

/// A discrete input: a lamp FALC reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Input {
    /// A line, place or station signal a recipe can wait for.
    Signal(Signal),
    /// The PLC is running and accepts buttons.
    Ready,
    /// An emergency stop is active.
    EStop,
}

fn line_index(c: char) -> Option<u16> {
    LINES.iter().position(|l| *l == c).map(|i| i as u16)
}

/// What an output goes to when the workstation can no longer know whether
/// acting on it is safe: its commander lost, the node stopped (SIGTERM, a
/// crash and restart), a job halted or failed, maintenance ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SafeState {
    /// Released: a conveyor line stops (nothing moves unsupervised).
    Off,
    /// Kept as it is: a station's clamp holds its workpiece, since the
    /// robot may still weld it; only a command that comes after the robot
    /// is known to have stopped (the next job's, a maintainer's) releases it.
    Hold,
}

impl Coil {
    /// This output's safe state ([`SafeState`]): a line button is
    /// released; a station button (a clamp) holds; external control holds
    /// too (off, the PLC's local panel would rule the clamps).
    pub fn safe_state(self) -> SafeState {
        match self {
            Coil::Button(Button::Line(_)) => SafeState::Off,
            Coil::Button(Button::Station(_)) | Coil::ExternalControl => SafeState::Hold,
        }
    }

    /// Offset from the coil base, or None for a button outside the map.
    pub fn offset(self) -> Option<u16> {
        match self {
            Coil::Button(Button::Line(c)) => line_index(c),
            Coil::Button(Button::Station(n)) => Some(10 + u16::from(n.number())),
            Coil::ExternalControl => Some(14),
        }
    }

    /// The coil at `offset`.
    pub fn at(offset: u16) -> Option<Coil> {
        match offset {
            0..=10 => Some(Coil::Button(Button::Line(LINES[usize::from(offset)]))),
            11..=13 => {
                PlcStation::new((offset - 10) as u8).map(|n| Coil::Button(Button::Station(n)))
            }
            14 => Some(Coil::ExternalControl),
            _ => None,
        }
    }
}

impl Input {
    /// Offset from the input base, or None for a signal outside the map.
    pub fn offset(self) -> Option<u16> {
        match self {
            Input::Signal(Signal::Line(c)) => line_index(c),
            Input::Signal(Signal::Place(n)) => Some(9 + u16::from(n.number())),
            Input::Signal(Signal::Station(n)) => Some(15 + u16::from(n.number())),
            Input::Ready => Some(19),
            Input::EStop => Some(20),
        }
    }

    /// The input at `offset`.
    pub fn at(offset: u16) -> Option<Input> {
        match offset {
            0..=10 => Some(Input::Signal(Signal::Line(LINES[usize::from(offset)]))),
            11..=15 => Place::new((offset - 9) as u8).map(|n| Input::Signal(Signal::Place(n))),
            16..=18 => {
                PlcStation::new((offset - 15) as u8).map(|n| Input::Signal(Signal::Station(n)))
            }
            19 => Some(Input::Ready),
            20 => Some(Input::EStop),
            _ => None,
        }
    }
}

impl fmt::Display for Coil {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Coil::Button(Button::Line(c)) => write!(f, "button line {c}"),
            Coil::Button(Button::Station(n)) => write!(f, "button station {n}"),
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
        }
    }
}

/// Where the map sits in the PLC's address space (0-based Modbus
/// addresses, as on the wire); default: both at 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct IoMap {
    /// Address of coil offset 0.
    pub coil_base: u16,
    /// Address of discrete input offset 0.
    pub input_base: u16,
}

/// The map does not fit the 16-bit address space at these bases.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("the I/O map does not fit below address 65536 with {what} base {base}")]
pub struct MapError {
    what: &'static str,
    base: u16,
}

impl IoMap {
    /// A map at these bases, if it fits.
    pub fn new(coil_base: u16, input_base: u16) -> Result<Self, MapError> {
        if coil_base.checked_add(COILS - 1).is_none() {
            return Err(MapError {
                what: "coil",
                base: coil_base,
            });
        }
        if input_base.checked_add(INPUTS - 1).is_none() {
            return Err(MapError {
                what: "input",
                base: input_base,
            });
        }
        Ok(Self {
            coil_base,
            input_base,
        })
    }

    /// The Modbus address of `coil`.
    pub fn coil(&self, coil: Coil) -> Option<u16> {
        coil.offset().map(|o| self.coil_base + o)
    }

    /// The coil at Modbus address `address`.
    pub fn coil_at(&self, address: u16) -> Option<Coil> {
        address.checked_sub(self.coil_base).and_then(Coil::at)
    }

    /// The table of the map at these bases, as Markdown (for docs/plc.md
    /// and for commissioning).
    pub fn table(&self) -> String {
        let mut out = String::from("| kind | address | meaning |\n|---|---|---|\n");
        for o in 0..COILS {
            if let Some(c) = Coil::at(o) {
                out += &format!("| coil | {} | {c} |\n", self.coil_base + o);
            }
        }
        for o in 0..INPUTS {
            if let Some(i) = Input::at(o) {
                out += &format!("| discrete input | {} | {i} |\n", self.input_base + o);
            }
        }
        out
    }
}

/// One reading of every discrete input of the map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Inputs {
    bits: [bool; INPUTS as usize],
}

/// A PLC reply that does not fit the map.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("the PLC returned {got} discrete inputs, the map needs {INPUTS}")]
pub struct ShortReply {
    got: usize,
}

impl Inputs {
    /// From the bits of a discrete-input read starting at the input base
    /// (a reply may carry padding bits beyond the map: ignored).
    pub fn from_bits(bits: &[bool]) -> Result<Self, ShortReply> {
        const N: usize = INPUTS as usize;
        let mut out = Self::default();
        match bits.get(..N) {
            Some(b) => out.bits.copy_from_slice(b),
            None => return Err(ShortReply { got: bits.len() }),
        }
        Ok(out)
    }

    /// The bits, in map order.
    pub fn bits(&self) -> &[bool] {
        &self.bits
    }

    /// The value of `input` (false for an input outside the map).
    pub fn get(&self, input: Input) -> bool {
        input
            .offset()
            .and_then(|o| self.bits.get(usize::from(o)))
            .copied()
            .unwrap_or(false)
    }

    /// Sets `input` (for the twin and tests).
    pub fn set(&mut self, input: Input, value: bool) {
        if let Some(b) = input
            .offset()
            .and_then(|o| self.bits.get_mut(usize::from(o)))
        {
            *b = value;
        }
    }

    /// The value of a recipe signal.
    pub fn signal(&self, s: Signal) -> bool {
        self.get(Input::Signal(s))
    }

    /// The inputs that differ between `self` and `other`.
    pub fn changes<'a>(&'a self, other: &'a Inputs) -> impl Iterator<Item = (Input, bool)> + 'a {
        (0..INPUTS).filter_map(move |o| {
            let i = Input::at(o)?;
            (self.get(i) != other.get(i)).then_some((i, other.get(i)))
        })
    }
}

impl fmt::Display for Inputs {
    /// One line: `lines D E | places 2 5 | stations 3 | ready` (what is on).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let on = |v: Vec<String>| {
            if v.is_empty() {
                "-".to_string()
            } else {
                v.join(" ")
            }
        };
        let lines = LINES
            .iter()
            .filter(|c| self.signal(Signal::Line(**c)))
            .map(|c| c.to_string())
            .collect();
        let places = Place::all()
            .filter(|n| self.signal(Signal::Place(*n)))
            .map(|n| n.to_string())
            .collect();
        let stations = PlcStation::all()
            .filter(|n| self.signal(Signal::Station(*n)))
            .map(|n| n.to_string())
            .collect();
        write!(
            f,
            "running {:<22} | occupied {:<9} | busy {:<5} | {}{}",
            on(lines),
            on(places),
            on(stations),
            if self.get(Input::Ready) {
                "ready"
            } else {
                "NOT READY"
            },
            if self.get(Input::EStop) {
                " | EMERGENCY STOP"
            } else {
                ""
            },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn every_offset_maps_back_to_itself() {
        for o in 0..COILS {
            let c = Coil::at(o).expect("coil in map");
            assert_eq!(c.offset(), Some(o), "{c}");
        }
        for o in 0..INPUTS {
            let i = Input::at(o).expect("input in map");
            assert_eq!(i.offset(), Some(o), "{i}");
        }
        assert_eq!(Coil::at(COILS), None);
        assert_eq!(Input::at(INPUTS), None);
    }

    #[test]
    fn documented_addresses() {
        let map = IoMap::new(100, 200).expect("fits");
        assert_eq!(map.coil(Coil::Button(Button::Line('A'))), Some(100));
        assert_eq!(map.coil(Coil::Button(Button::Line('L'))), Some(110));
        assert_eq!(
            map.coil(Coil::Button(Button::Station(PlcStation::of(3)))),
            Some(113)
        );
        assert_eq!(map.coil(Coil::ExternalControl), Some(114));
        assert_eq!(map.coil(Coil::Button(Button::Line('I'))), None);
        assert_eq!(
            Input::Signal(Signal::Place(Place::of(2))).offset(),
            Some(11)
        );
        assert_eq!(
            Input::Signal(Signal::Place(Place::of(6))).offset(),
            Some(15)
        );
        assert_eq!(
            Input::Signal(Signal::Station(PlcStation::of(1))).offset(),
            Some(16)
        );
        assert_eq!(Input::Ready.offset(), Some(19));
        assert_eq!(Input::EStop.offset(), Some(20));
        assert_eq!(map.coil_at(99), None);
        assert_eq!(map.coil_at(104), Some(Coil::Button(Button::Line('E'))));
        assert!(IoMap::new(65530, 0).is_err());
        assert!(IoMap::new(0, 65530).is_err());
        let table = map.table();
        assert!(table.contains("| coil | 114 | external control |"));
        assert!(table.contains("| discrete input | 211 | place 2 occupied |"));
    }

    #[test]
    fn short_reply_is_an_error_padding_is_not() {
        assert_eq!(Inputs::from_bits(&[true; 8]), Err(ShortReply { got: 8 }));
        let i = Inputs::from_bits(&[true; 24]).expect("padded reply");
        assert!(i.get(Input::EStop));
    }

    proptest! {
        #[test]
        fn any_reply_decodes_or_errs(bits in proptest::collection::vec(any::<bool>(), 0..64)) {
            match Inputs::from_bits(&bits) {
                Ok(i) => prop_assert_eq!(i.bits(), &bits[..INPUTS as usize]),
                Err(e) => prop_assert!(bits.len() < INPUTS as usize, "{e}"),
            }
        }
    }
}
