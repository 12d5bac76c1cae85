//! The conveyor PLC's I/O map: which coil is which button and which
//! discrete input is which lamp. The addresses come from the equipment
//! file ([`falc_equipment::file`]); [`IoMap`] places them in the PLC (moved by
//! a base, for a PLC whose FALC area starts elsewhere), [`Inputs`] is one
//! reading of every discrete input. One map for the transport node, the
//! twin and docs/plc.md (`falc-transport io --map` prints it), so a real
//! PLC can be wired to it.

pub use falc_equipment::signal::{Coil, Input, SafeState, SignalName, Spot, S, W};
use falc_equipment::Equipment;
use falc_recipe::check::Signal;
use std::fmt;
use std::sync::Arc;

/// The equipment's map placed in the PLC's address space (0-based Modbus
/// addresses, as on the wire): the file's addresses, each moved by a base
/// (0 by default).
#[derive(Debug, Clone, PartialEq)]
pub struct IoMap {
    equipment: Arc<Equipment>,
    /// Added to every coil address of the file.
    pub coil_base: u16,
    /// Added to every discrete input address of the file.
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
    /// The map of `equipment` at these bases, if it fits.
    pub fn new(
        equipment: Arc<Equipment>,
        coil_base: u16,
        input_base: u16,
    ) -> Result<Self, MapError> {
        let (lo, n) = equipment.coil_span();
        if n > 0 && coil_base.checked_add(lo + n - 1).is_none() {
            return Err(MapError {
                what: "coil",
                base: coil_base,
            });
        }
        let (lo, n) = equipment.input_span();
        if n > 0 && input_base.checked_add(lo + n - 1).is_none() {
            return Err(MapError {
                what: "input",
                base: input_base,
            });
        }
        Ok(Self {
            equipment,
            coil_base,
            input_base,
        })
    }

    /// The 1992 conveyor at bases 0.
    pub fn conveyor_1992() -> Self {
        Self {
            equipment: Equipment::conveyor_1992(),
            coil_base: 0,
            input_base: 0,
        }
    }

    /// The equipment.
    pub fn equipment(&self) -> &Arc<Equipment> {
        &self.equipment
    }

    /// The Modbus address of `coil`.
    pub fn coil(&self, coil: Coil) -> Option<u16> {
        self.equipment
            .coil(coil)
            .map(|c| self.coil_base + c.address)
    }

    /// The coil at Modbus address `address`.
    pub fn coil_at(&self, address: u16) -> Option<Coil> {
        address
            .checked_sub(self.coil_base)
            .and_then(|a| self.equipment.coil_at(a))
    }

    /// The first coil address and how many addresses up to the last.
    pub fn coil_span(&self) -> (u16, u16) {
        let (lo, n) = self.equipment.coil_span();
        (self.coil_base + lo, n)
    }

    /// The first discrete input address and how many up to the last.
    pub fn input_span(&self) -> (u16, u16) {
        let (lo, n) = self.equipment.input_span();
        (self.input_base + lo, n)
    }

    /// The table of the map at these bases, as Markdown (for docs/plc.md
    /// and for commissioning).
    pub fn table(&self) -> String {
        self.equipment.table(self.coil_base, self.input_base)
    }

    /// A reading from the bits of one discrete-input read over
    /// [`IoMap::input_span`] (a reply may carry padding bits beyond it:
    /// ignored).
    pub fn inputs_from_wire(&self, bits: &[bool]) -> Result<Inputs, ShortReply> {
        let (_, n) = self.equipment.input_span();
        if bits.len() < usize::from(n) {
            return Err(ShortReply {
                got: bits.len(),
                needs: usize::from(n),
            });
        }
        let (lo, _) = self.equipment.input_span();
        let values = self
            .equipment
            .inputs()
            .iter()
            .map(|i| bits[usize::from(i.address - lo)])
            .collect();
        Ok(Inputs {
            equipment: self.equipment.clone(),
            bits: values,
        })
    }

    /// The coils of one read over [`IoMap::coil_span`], as (coil, value)
    /// in the equipment's order.
    pub fn coils_from_wire(&self, bits: &[bool]) -> Result<Coils, ShortReply> {
        let (lo, n) = self.equipment.coil_span();
        if bits.len() < usize::from(n) {
            return Err(ShortReply {
                got: bits.len(),
                needs: usize::from(n),
            });
        }
        Ok(self
            .equipment
            .coils()
            .iter()
            .map(|c| (c.coil, bits[usize::from(c.address - lo)]))
            .collect())
    }

    /// The runs of consecutive addresses `coils` fill, each with its
    /// first address and values: one write per run (addresses between the
    /// equipment's coils are never written).
    pub fn coil_runs(&self, coils: &Coils) -> Vec<(u16, Vec<bool>)> {
        let mut runs: Vec<(u16, Vec<bool>)> = Vec::new();
        let mut addressed: Vec<(u16, bool)> = coils
            .iter()
            .filter_map(|(c, v)| self.coil(*c).map(|a| (a, *v)))
            .collect();
        addressed.sort_by_key(|(a, _)| *a);
        for (a, v) in addressed {
            match runs.last_mut() {
                Some((start, values))
                    if u32::from(*start) + values.len() as u32 == u32::from(a) =>
                {
                    values.push(v)
                }
                _ => runs.push((a, vec![v])),
            }
        }
        runs
    }
}

/// Every coil of the map with a value, in the equipment's order.
pub type Coils = Vec<(Coil, bool)>;

/// A PLC reply that does not fit the map.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("the PLC returned {got} bits, the map needs {needs}")]
pub struct ShortReply {
    got: usize,
    needs: usize,
}

/// One reading of every discrete input of the map, in the equipment's
/// order ([`Equipment::inputs`]).
#[derive(Debug, Clone)]
pub struct Inputs {
    equipment: Arc<Equipment>,
    bits: Vec<bool>,
}

impl PartialEq for Inputs {
    fn eq(&self, other: &Self) -> bool {
        self.bits == other.bits
    }
}

impl Eq for Inputs {}

impl Inputs {
    /// Every input off.
    pub fn new(equipment: &Arc<Equipment>) -> Self {
        Self {
            equipment: equipment.clone(),
            bits: vec![false; equipment.inputs().len()],
        }
    }

    /// From bits in the equipment's order (a station's status carries
    /// them so); None if they do not fit it.
    pub fn from_bits(equipment: &Arc<Equipment>, bits: &[bool]) -> Option<Self> {
        (bits.len() == equipment.inputs().len()).then(|| Self {
            equipment: equipment.clone(),
            bits: bits.to_vec(),
        })
    }

    /// The bits, in the equipment's order.
    pub fn bits(&self) -> &[bool] {
        &self.bits
    }

    /// The equipment read.
    pub fn equipment(&self) -> &Arc<Equipment> {
        &self.equipment
    }

    /// The value of `input` (false for an input outside the map).
    pub fn get(&self, input: Input) -> bool {
        self.equipment
            .input_index(input)
            .and_then(|i| self.bits.get(i))
            .copied()
            .unwrap_or(false)
    }

    /// Sets `input` (for the twin and tests).
    pub fn set(&mut self, input: Input, value: bool) {
        if let Some(b) = self
            .equipment
            .input_index(input)
            .and_then(|i| self.bits.get_mut(i))
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
        self.equipment
            .inputs()
            .iter()
            .zip(self.bits.iter().zip(other.bits.iter()))
            .filter(|(_, (a, b))| a != b)
            .map(|(i, (_, b))| (i.input, *b))
    }

    /// The inputs that are on.
    pub fn lit(&self) -> impl Iterator<Item = Input> + '_ {
        self.equipment
            .inputs()
            .iter()
            .zip(self.bits.iter())
            .filter(|(_, on)| **on)
            .map(|(i, _)| i.input)
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
        let (mut lines, mut places, mut stations) = (Vec::new(), Vec::new(), Vec::new());
        let mut plain = Vec::new();
        for i in self.lit() {
            match i {
                Input::Signal(Signal::Line(c)) => lines.push(c.to_string()),
                Input::Signal(Signal::Place(n)) => places.push(n.to_string()),
                Input::Signal(Signal::Station(n)) => stations.push(n.to_string()),
                Input::Signal(Signal::Input(n)) => plain.push(n.to_string()),
                Input::Ready | Input::EStop => {}
            }
        }
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
        )?;
        // Plain inputs, for an equipment that has them.
        if self.equipment.plain_inputs().next().is_some() {
            write!(f, " | on {}", on(plain))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_model::ids::{Place, PlcStation};
    use falc_recipe::check::Button;
    use proptest::prelude::*;

    #[test]
    fn documented_addresses() {
        let map = IoMap::new(Equipment::conveyor_1992(), 100, 200).expect("fits");
        assert_eq!(map.coil(Coil::Button(Button::Line('A'))), Some(100));
        assert_eq!(map.coil(Coil::Button(Button::Line('L'))), Some(110));
        assert_eq!(
            map.coil(Coil::Button(Button::Station(PlcStation::of(3)))),
            Some(113)
        );
        assert_eq!(map.coil(Coil::ExternalControl), Some(114));
        assert_eq!(map.coil(Coil::Button(Button::Line('M'))), None);
        assert_eq!(map.coil_at(99), None);
        assert_eq!(map.coil_at(104), Some(Coil::Button(Button::Line('E'))));
        assert_eq!(map.coil_span(), (100, 15));
        assert_eq!(map.input_span(), (200, 21));
        assert!(IoMap::new(Equipment::conveyor_1992(), 65530, 0).is_err());
        assert!(IoMap::new(Equipment::conveyor_1992(), 0, 65530).is_err());
        let table = map.table();
        assert!(
            table.contains("| coil | 114 | external control | hold |"),
            "{table}"
        );
        assert!(
            table.contains("| discrete input | 211 | place 2 occupied | |"),
            "{table}"
        );
        let mut wire = vec![false; 21];
        wire[11] = true;
        wire[20] = true;
        let i = map.inputs_from_wire(&wire).expect("fits");
        assert!(i.signal(Signal::Place(Place::of(2))) && i.get(Input::EStop));
        assert!(!i.get(Input::Ready));
    }

    #[test]
    fn coil_writes_skip_the_gaps_between_the_equipments_coils() {
        let map = IoMap::conveyor_1992();
        let coils: Coils = vec![
            (Coil::Button(Button::Line('A')), true),
            (Coil::Button(Button::Line('B')), false),
            (Coil::ExternalControl, true),
        ];
        assert_eq!(
            map.coil_runs(&coils),
            vec![(0, vec![true, false]), (14, vec![true])]
        );
    }

    #[test]
    fn short_reply_is_an_error_padding_is_not() {
        let map = IoMap::conveyor_1992();
        assert_eq!(
            map.inputs_from_wire(&[true; 8]),
            Err(ShortReply { got: 8, needs: 21 })
        );
        let i = map.inputs_from_wire(&[true; 24]).expect("padded reply");
        assert!(i.get(Input::EStop));
    }

    proptest! {
        #[test]
        fn any_reply_decodes_or_errs(bits in proptest::collection::vec(any::<bool>(), 0..64)) {
            let map = IoMap::conveyor_1992();
            match map.inputs_from_wire(&bits) {
                Ok(i) => prop_assert_eq!(i.bits(), &bits[..21]),
                Err(e) => prop_assert!(bits.len() < 21, "{e}"),
            }
        }
    }
}
