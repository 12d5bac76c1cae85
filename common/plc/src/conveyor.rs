//! The conveyor, sans-I/O: where the carriers are, which lines run, and
//! what the PLC's inputs show, driven by coil writes, control faults and an
//! injected clock (`handle_timeout(now)` / `poll_timeout()`). It plays
//! whatever the equipment file describes ([`falc_equipment::file`]): its
//! lines' routes and travel times, its stations' feed places and cycle
//! times, its places' capacities; the times are divided by a time scale.
//!
//! A place holds its `capacity` of carriers, a station one. With external
//! control on and no emergency stop, pressing a line's button (a rising edge) sends the front carrier at its start along it; the
//! line runs until the carrier reaches its end (the button may be released
//! meanwhile). Pressed with no carrier at its start, the line runs empty
//! for the file's `run_empty_s`, and a carrier that arrives at its start goes straight on.
//! A station's button takes the carrier from its feed place onto the
//! station, which is busy while it holds one; a carrier leaves a station
//! only once its button is released. A carrier whose end is full waits at
//! the end of its line, the line running. An emergency stop halts every
//! line and freezes carriers in travel (they go on when their line is
//! pressed again after the stop is cleared); a jammed line keeps running
//! but its carrier does not move; a stuck sensor or running lamp shows a
//! fixed value. A plain input follows the plain output the file's
//! `[[feedback]]` pairs it with, after half the feedback's time; one
//! paired with none is set by hand (`Control::Input`), and those the
//! file's `[twin] inputs_on` names start on.

use crate::map::{Coil, Coils, Input, Inputs};
use falc_equipment::file::Equipment;
use falc_model::ids::{IoName, Place, PlcStation};
use falc_recipe::check::{Button, Signal};
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::Arc;
use std::time::Duration;

pub use crate::map::Spot;

/// How a carrier travels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Via {
    Line(char),
    Station(PlcStation),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Pos {
    At(Spot),
    /// Travelling: `due` is the arrival time while it moves; None while
    /// frozen (`left` to go) or waiting for a full end (`left` zero).
    Moving {
        via: Via,
        to: Spot,
        due: Option<Duration>,
        left: Duration,
    },
}

#[derive(Debug, Clone, Copy)]
struct Carrier {
    pos: Pos,
    /// Arrival order at its spot (front = smallest).
    seq: u64,
}

#[derive(Debug, Clone, Copy, Default)]
struct Line {
    running: bool,
    /// Running empty until then, waiting for a carrier at its start.
    empty_until: Option<Duration>,
}

/// A fault injected by a person or a test.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Control {
    /// Emergency stop pressed.
    EStop,
    /// … and released.
    EStopClear,
    /// The carrier on this line stops moving (the line keeps running).
    Jam(char),
    /// … moves again.
    Unjam(char),
    /// This place's sensor shows this value whatever is there.
    Stuck(Place, bool),
    /// … shows the truth again.
    Unstuck(Place),
    /// This line's running lamp shows this value whatever the line does.
    StuckLamp(char, bool),
    /// … shows the truth again.
    UnstuckLamp(char),
    /// A plain input set by hand (a door closed, a part handed in).
    Input(IoName, bool),
}

/// The conveyor.
pub struct Conveyor {
    equipment: Arc<Equipment>,
    scale: f64,
    carriers: Vec<Carrier>,
    lines: BTreeMap<char, Line>,
    /// In the equipment's coil order.
    coils: Vec<bool>,
    estop: bool,
    jammed: BTreeSet<char>,
    stuck: BTreeMap<Place, bool>,
    stuck_lamps: BTreeMap<char, bool>,
    seq: u64,
    last_change: Option<Duration>,
    notes: VecDeque<String>,
    /// The plain inputs that are on.
    plain_on: BTreeSet<IoName>,
    /// Plain inputs following their output ([`Equipment::feedback`]):
    /// the value each takes, and when.
    following: Vec<(IoName, bool, Duration)>,
}

impl Conveyor {
    /// The conveyor of `equipment` with carriers at `layout` (carrier 1
    /// first), travel times divided by `scale`.
    pub fn new(equipment: Arc<Equipment>, layout: &[Spot], scale: f64) -> Result<Self, String> {
        let mut c = Self {
            scale: if scale > 0.0 { scale } else { 1.0 },
            carriers: Vec::new(),
            lines: equipment
                .lines()
                .iter()
                .map(|s| (s.line, Line::default()))
                .collect(),
            coils: vec![false; equipment.coils().len()],
            equipment,
            estop: false,
            jammed: BTreeSet::new(),
            stuck: BTreeMap::new(),
            stuck_lamps: BTreeMap::new(),
            seq: 0,
            last_change: None,
            notes: VecDeque::new(),
            plain_on: BTreeSet::new(),
            following: Vec::new(),
        };
        c.plain_on = c.equipment.inputs_on().iter().copied().collect();
        c.set_layout(layout)?;
        Ok(c)
    }

    /// Puts the carriers at `layout` (all lines stopped, coils kept).
    pub fn set_layout(&mut self, layout: &[Spot]) -> Result<(), String> {
        for spot in layout {
            let known = match spot {
                Spot::Place(p) => self.equipment.place(*p).is_some(),
                Spot::Station(s) => self.equipment.station(*s).is_some(),
            };
            if !known {
                return Err(format!(
                    "{spot} is no place or station of {}",
                    self.equipment.name()
                ));
            }
            let n = layout.iter().filter(|s| *s == spot).count();
            let capacity = self.equipment.capacity(*spot);
            if n > capacity {
                return Err(format!("{spot} holds {capacity} carrier(s), not {n}"));
            }
        }
        self.carriers = layout
            .iter()
            .enumerate()
            .map(|(i, s)| Carrier {
                pos: Pos::At(*s),
                seq: i as u64,
            })
            .collect();
        self.seq = layout.len() as u64;
        for l in self.lines.values_mut() {
            *l = Line::default();
        }
        Ok(())
    }

    fn scaled(&self, d: Duration) -> Duration {
        d.div_f64(self.scale)
    }

    /// The equipment it plays.
    pub fn equipment(&self) -> &Arc<Equipment> {
        &self.equipment
    }

    fn note(&mut self, s: String) {
        self.notes.push_back(s);
    }

    /// The next line to print.
    pub fn poll_note(&mut self) -> Option<String> {
        self.notes.pop_front()
    }

    /// Where the carriers are: `carriers: 1@W3 2@K>W3`.
    pub fn describe(&self) -> String {
        let parts: Vec<String> = self
            .carriers
            .iter()
            .enumerate()
            .map(|(i, c)| match c.pos {
                Pos::At(s) => format!("{}@{s}", i + 1),
                Pos::Moving { via, to, .. } => {
                    let v = match via {
                        Via::Line(l) => l.to_string(),
                        Via::Station(n) => format!("S{n}"),
                    };
                    format!("{}@{v}>{to}", i + 1)
                }
            })
            .collect();
        format!("carriers: {}", parts.join(" "))
    }

    /// The PLC's inputs now.
    pub fn inputs(&self) -> Inputs {
        let mut i = Inputs::new(&self.equipment);
        for (c, l) in &self.lines {
            let shown = self.stuck_lamps.get(c).copied().unwrap_or(l.running);
            i.set(Input::Signal(Signal::Line(*c)), shown);
        }
        for p in self.equipment.places() {
            let n = p.place;
            let real = self.count_at(Spot::Place(n)) > 0;
            let shown = self.stuck.get(&n).copied().unwrap_or(real);
            i.set(Input::Signal(Signal::Place(n)), shown);
        }
        for s in self.equipment.stations() {
            let n = s.station;
            i.set(
                Input::Signal(Signal::Station(n)),
                self.count_at(Spot::Station(n)) > 0,
            );
        }
        for n in &self.plain_on {
            i.set(Input::Signal(Signal::Input(*n)), true);
        }
        i.set(Input::Ready, !self.estop);
        i.set(Input::EStop, self.estop);
        i
    }

    /// The coils as last written, in the equipment's order.
    pub fn coils(&self) -> Coils {
        self.equipment
            .coils()
            .iter()
            .zip(&self.coils)
            .map(|(c, v)| (c.coil, *v))
            .collect()
    }

    /// The value of `coil` (false for one the equipment lacks).
    pub fn coil_value(&self, coil: Coil) -> bool {
        self.equipment
            .coil_index(coil)
            .and_then(|i| self.coils.get(i))
            .copied()
            .unwrap_or(false)
    }

    /// The buttons held (coils on), as the twin's `show` prints them:
    /// `buttons held: none`, `buttons held: A 3`.
    pub fn held(&self) -> String {
        let held: Vec<String> = self
            .coils()
            .into_iter()
            .filter(|(_, on)| *on)
            .filter_map(|(c, _)| match c {
                Coil::Button(Button::Line(l)) => Some(l.to_string()),
                Coil::Button(Button::Station(n)) => Some(n.to_string()),
                Coil::Button(Button::Output(n)) => Some(n.to_string()),
                Coil::ExternalControl => None,
            })
            .collect();
        if held.is_empty() {
            "buttons held: none".into()
        } else {
            format!("buttons held: {}", held.join(" "))
        }
    }

    fn count_at(&self, s: Spot) -> usize {
        self.carriers.iter().filter(|c| c.pos == Pos::At(s)).count()
    }

    fn front_at(&self, s: Spot) -> Option<usize> {
        self.carriers
            .iter()
            .enumerate()
            .filter(|(_, c)| c.pos == Pos::At(s))
            .min_by_key(|(_, c)| c.seq)
            .map(|(i, _)| i)
    }

    fn on(&self, via: Via) -> Option<usize> {
        self.carriers
            .iter()
            .position(|c| matches!(c.pos, Pos::Moving { via: v, .. } if v == via))
    }

    fn coil(&self, b: Button) -> bool {
        self.coil_value(Coil::Button(b))
    }

    /// Runs `f`, and if the inputs changed, remembers `at` as the time of
    /// the last input change.
    fn changing(&mut self, at: Duration, f: impl FnOnce(&mut Self)) {
        let before = self.inputs();
        f(self);
        if self.inputs() != before {
            self.last_change = Some(at);
        }
    }

    /// A coil write; false if the equipment has no such coil.
    pub fn write_coil(&mut self, now: Duration, coil: Coil, value: bool) -> bool {
        let Some(index) = self.equipment.coil_index(coil) else {
            return false;
        };
        self.handle_timeout(now);
        let old = self.coils[index];
        self.coils[index] = value;
        if old == value {
            return true;
        }
        let reaction = self
            .last_change
            .map(|t| format!(" reaction_us={}", now.saturating_sub(t).as_micros()))
            .unwrap_or_default();
        self.note(format!("coil {coil} {}{reaction}", u8::from(value)));
        let external = self.coil_value(Coil::ExternalControl);
        if self.estop || !external {
            if value && matches!(coil, Coil::Button(_)) {
                self.note(format!(
                    "ignored {coil}: {}",
                    if self.estop {
                        "emergency stop"
                    } else {
                        "external control off"
                    }
                ));
            }
            return true;
        }
        self.changing(now, |c| match (coil, value) {
            (Coil::Button(Button::Line(l)), true) => c.press_line(now, l),
            (Coil::Button(Button::Station(n)), true) => c.press_station(now, n),
            (Coil::Button(Button::Station(n)), false) => c.release_station(now, n),
            (Coil::Button(Button::Output(_)), _) => c.follow(now, coil, value),
            _ => {}
        });
        true
    }

    /// A plain output set: each plain input the equipment's feedback
    /// pairs with it follows after half the feedback's time.
    fn follow(&mut self, now: Duration, coil: Coil, value: bool) {
        for f in self.equipment.feedback() {
            if let (true, Input::Signal(Signal::Input(n))) = (f.output == coil, f.input) {
                let at = now + self.scaled(f.within / 2);
                self.following.retain(|(m, _, _)| *m != n);
                self.following.push((n, value, at));
            }
        }
    }

    fn press_line(&mut self, now: Duration, l: char) {
        let Some(seg) = self.equipment.line(l).cloned() else {
            return;
        };
        if let Some(i) = self.on(Via::Line(l)) {
            if let Pos::Moving {
                due: None, left, ..
            } = &mut self.carriers[i].pos
            {
                if !left.is_zero() && !self.jammed.contains(&l) {
                    let left = *left;
                    self.resume(now, i, left);
                    self.note(format!("line {l} restarted, carrier {} goes on", i + 1));
                }
            }
            self.lines.entry(l).or_default().running = true;
            return;
        }
        let ready = self.front_at(seg.from).filter(|_| match seg.from {
            Spot::Station(n) => !self.coil(Button::Station(n)),
            Spot::Place(_) => true,
        });
        let line = self.lines.entry(l).or_default();
        line.running = true;
        match ready {
            Some(i) => {
                line.empty_until = None;
                self.depart(now, i, Via::Line(l), seg.to, seg.travel);
            }
            None => {
                line.empty_until = Some(now + self.equipment.run_empty().div_f64(self.scale));
                self.note(format!("line {l} runs empty: no carrier at {}", seg.from));
            }
        }
    }

    fn press_station(&mut self, now: Duration, n: PlcStation) {
        if let Some(i) = self.on(Via::Station(n)) {
            if let Pos::Moving {
                due: None, left, ..
            } = self.carriers[i].pos
            {
                if !left.is_zero() {
                    self.resume(now, i, left);
                }
            }
            return;
        }
        let Some((from, cycle)) = self
            .equipment
            .station(n)
            .map(|s| (Spot::Place(s.takes_from), s.cycle))
        else {
            return;
        };
        if self.count_at(Spot::Station(n)) > 0 {
            return;
        }
        match self.front_at(from) {
            Some(i) => self.depart(now, i, Via::Station(n), Spot::Station(n), cycle),
            None => self.note(format!("station {n}: no carrier at {from}")),
        }
    }

    fn release_station(&mut self, now: Duration, n: PlcStation) {
        // A line waiting empty at this station takes its carrier now.
        let waiting = self
            .equipment
            .lines()
            .iter()
            .find(|s| {
                s.from == Spot::Station(n)
                    && self
                        .lines
                        .get(&s.line)
                        .is_some_and(|l| l.empty_until.is_some())
            })
            .cloned();
        if let (Some(seg), Some(i)) = (waiting, self.front_at(Spot::Station(n))) {
            if let Some(l) = self.lines.get_mut(&seg.line) {
                l.empty_until = None;
            }
            self.depart(now, i, Via::Line(seg.line), seg.to, seg.travel);
        }
    }

    fn resume(&mut self, now: Duration, i: usize, left: Duration) {
        if let Pos::Moving { due, .. } = &mut self.carriers[i].pos {
            *due = Some(now + left);
        }
    }

    fn depart(&mut self, now: Duration, i: usize, via: Via, to: Spot, time: Duration) {
        let Pos::At(from) = self.carriers[i].pos else {
            return;
        };
        let travel = self.scaled(time);
        let jammed = matches!(via, Via::Line(l) if self.jammed.contains(&l));
        self.carriers[i].pos = Pos::Moving {
            via,
            to,
            due: (!jammed).then_some(now + travel),
            left: travel,
        };
        let how = match via {
            Via::Line(l) => format!("on line {l}"),
            Via::Station(n) => format!("onto station {n}"),
        };
        self.note(format!("carrier {} leaves {from} {how} for {to}", i + 1));
        self.admit_waiting(now, from);
    }

    /// A carrier waiting at the end of its line for `spot` comes in.
    fn admit_waiting(&mut self, now: Duration, spot: Spot) {
        let waiting = self.carriers.iter().position(|c| {
            matches!(c.pos, Pos::Moving { to, due: None, left, .. } if to == spot && left.is_zero())
        });
        if let Some(i) = waiting {
            if !self.estop {
                self.arrive(now, i);
            }
        }
    }

    fn arrive(&mut self, now: Duration, i: usize) {
        let Pos::Moving { via, to, .. } = self.carriers[i].pos else {
            return;
        };
        if self.count_at(to) >= self.equipment.capacity(to) {
            self.carriers[i].pos = Pos::Moving {
                via,
                to,
                due: None,
                left: Duration::ZERO,
            };
            self.note(format!("carrier {} waits: {to} is full", i + 1));
            return;
        }
        self.seq += 1;
        self.carriers[i] = Carrier {
            pos: Pos::At(to),
            seq: self.seq,
        };
        if let Via::Line(l) = via {
            if let Some(line) = self.lines.get_mut(&l) {
                line.running = false;
            }
        }
        self.note(format!("carrier {} at {to}", i + 1));
        // A line running empty from here takes it straight on.
        let onward = self
            .equipment
            .lines()
            .iter()
            .find(|s| {
                s.from == to
                    && matches!(to, Spot::Place(_))
                    && self
                        .lines
                        .get(&s.line)
                        .is_some_and(|l| l.empty_until.is_some())
            })
            .cloned();
        if let Some(seg) = onward {
            if let Some(l) = self.lines.get_mut(&seg.line) {
                l.empty_until = None;
            }
            self.depart(now, i, Via::Line(seg.line), seg.to, seg.travel);
        }
    }

    /// When `handle_timeout` must run next.
    pub fn poll_timeout(&self) -> Option<Duration> {
        let arrivals = self.carriers.iter().filter_map(|c| match c.pos {
            Pos::Moving { due, .. } => due,
            Pos::At(_) => None,
        });
        let empty = self.lines.values().filter_map(|l| l.empty_until);
        let following = self.following.iter().map(|(_, _, at)| *at);
        arrivals.chain(empty).chain(following).min()
    }

    /// Carries out everything due by `now`, in time order.
    pub fn handle_timeout(&mut self, now: Duration) {
        while let Some(t) = self.poll_timeout().filter(|t| *t <= now) {
            if let Some(k) = self.following.iter().position(|(_, _, at)| *at == t) {
                let (n, value, _) = self.following.remove(k);
                self.changing(t, |c| {
                    if value {
                        c.plain_on.insert(n);
                    } else {
                        c.plain_on.remove(&n);
                    }
                });
                self.note(format!("input {n} {}", u8::from(value)));
                continue;
            }
            let arriving = self
                .carriers
                .iter()
                .position(|c| matches!(c.pos, Pos::Moving { due: Some(d), .. } if d == t));
            if let Some(i) = arriving {
                self.changing(t, |c| c.arrive(t, i));
                continue;
            }
            let empty = self
                .lines
                .iter()
                .find(|(_, l)| l.empty_until == Some(t))
                .map(|(c, _)| *c);
            if let Some(l) = empty {
                self.changing(t, |c| {
                    if let Some(line) = c.lines.get_mut(&l) {
                        *line = Line::default();
                    }
                });
                self.note(format!("line {l} stopped: no carrier came"));
            }
        }
    }

    /// Injects a fault (or clears it).
    pub fn control(&mut self, now: Duration, control: Control) {
        self.handle_timeout(now);
        self.changing(now, |c| match control {
            Control::EStop => {
                c.estop = true;
                for car in &mut c.carriers {
                    if let Pos::Moving { due, left, .. } = &mut car.pos {
                        if let Some(d) = due.take() {
                            *left = d.saturating_sub(now);
                        }
                    }
                }
                for l in c.lines.values_mut() {
                    *l = Line::default();
                }
            }
            Control::EStopClear => c.estop = false,
            Control::Jam(l) => {
                c.jammed.insert(l);
                if let Some(i) = c.on(Via::Line(l)) {
                    if let Pos::Moving { due, left, .. } = &mut c.carriers[i].pos {
                        if let Some(d) = due.take() {
                            *left = d.saturating_sub(now);
                        }
                    }
                }
            }
            Control::Unjam(l) => {
                c.jammed.remove(&l);
                let running = c.lines.get(&l).is_some_and(|x| x.running);
                if let Some(i) = c.on(Via::Line(l)) {
                    if let Pos::Moving {
                        due: None, left, ..
                    } = c.carriers[i].pos
                    {
                        if running && !left.is_zero() {
                            c.resume(now, i, left);
                        }
                    }
                }
            }
            Control::Stuck(p, v) => {
                c.stuck.insert(p, v);
            }
            Control::Unstuck(p) => {
                c.stuck.remove(&p);
            }
            Control::StuckLamp(l, v) => {
                c.stuck_lamps.insert(l, v);
            }
            Control::UnstuckLamp(l) => {
                c.stuck_lamps.remove(&l);
            }
            Control::Input(n, v) => {
                if v {
                    c.plain_on.insert(n);
                } else {
                    c.plain_on.remove(&n);
                }
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::{S, W};

    fn new(layout: &[Spot]) -> Result<Conveyor, String> {
        Conveyor::new(Equipment::conveyor_1992(), layout, 1.0)
    }

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    /// A conveyor at scale 1 with external control on.
    fn conveyor(layout: &[Spot]) -> Conveyor {
        let mut c = new(layout).expect("layout");
        assert!(c.write_coil(ms(0), Coil::ExternalControl, true));
        c
    }

    fn press(c: &mut Conveyor, t: Duration, b: Button, v: bool) {
        assert!(c.write_coil(t, Coil::Button(b), v));
    }

    fn place(c: &Conveyor, n: u8) -> bool {
        c.inputs().signal(Signal::Place(Place::of(n)))
    }

    fn line(c: &Conveyor, l: char) -> bool {
        c.inputs().signal(Signal::Line(l))
    }

    #[test]
    fn store_moves_the_front_carrier_from_w2_to_w3() {
        let mut c = conveyor(&[W(2), W(2)]);
        press(&mut c, ms(10), Button::Line('K'), true);
        assert!(line(&c, 'K'));
        assert!(place(&c, 2), "carrier 2 still at W2");
        c.handle_timeout(ms(8009));
        assert!(!place(&c, 3));
        c.handle_timeout(ms(8010));
        assert!(place(&c, 3) && !line(&c, 'K'));
        assert_eq!(c.describe(), "carriers: 1@W3 2@W2");
        // The reaction time is measured from the arrival.
        press(&mut c, ms(8015), Button::Line('K'), false);
        let notes: Vec<String> = std::iter::from_fn(|| c.poll_note()).collect();
        assert!(
            notes
                .iter()
                .any(|n| n == "coil button line K 0 reaction_us=5000"),
            "{notes:?}"
        );
    }

    #[test]
    fn move_to_man_then_station_3_takes_the_carrier() {
        let mut c = conveyor(&[W(2), W(2)]);
        press(&mut c, ms(0), Button::Line('E'), true);
        c.handle_timeout(ms(10_000));
        assert!(place(&c, 5));
        press(&mut c, ms(10_000), Button::Line('E'), false);
        press(&mut c, ms(10_000), Button::Station(PlcStation::of(3)), true);
        assert!(!place(&c, 5), "the table takes it at once");
        c.handle_timeout(ms(13_000));
        assert!(c.inputs().signal(Signal::Station(PlcStation::of(3))));
        assert_eq!(c.describe(), "carriers: 1@S3 2@W2");
    }

    #[test]
    fn a_carrier_leaves_a_station_only_once_its_button_is_released() {
        let mut c = conveyor(&[S(3), W(2)]);
        press(&mut c, ms(0), Button::Station(PlcStation::of(3)), true);
        press(&mut c, ms(0), Button::Line('F'), true);
        assert!(line(&c, 'F') && c.inputs().signal(Signal::Station(PlcStation::of(3))));
        press(&mut c, ms(100), Button::Station(PlcStation::of(3)), false);
        assert!(!c.inputs().signal(Signal::Station(PlcStation::of(3))));
        c.handle_timeout(ms(5100));
        assert!(place(&c, 4) && !line(&c, 'F'));
    }

    #[test]
    fn unload_and_load_d_runs_empty_and_takes_the_carrier_on() {
        let mut c = conveyor(&[S(3), W(3)]);
        press(&mut c, ms(0), Button::Line('F'), true);
        press(&mut c, ms(10), Button::Line('D'), true);
        assert!(line(&c, 'D'), "D runs empty");
        c.handle_timeout(ms(5000));
        assert_eq!(c.describe(), "carriers: 1@D>W2 2@W3");
        assert!(!place(&c, 4));
        c.handle_timeout(ms(11_000));
        assert_eq!(c.describe(), "carriers: 1@W2 2@W3");
        assert!(!line(&c, 'D'));
    }

    #[test]
    fn an_empty_line_stops_after_20_s() {
        let mut c = conveyor(&[W(2), W(2)]);
        press(&mut c, ms(0), Button::Line('L'), true);
        c.handle_timeout(ms(19_999));
        assert!(line(&c, 'L'));
        c.handle_timeout(ms(20_000));
        assert!(!line(&c, 'L'));
    }

    #[test]
    fn buttons_need_external_control_and_no_emergency_stop() {
        let mut c = new(&[W(2), W(2)]).expect("layout");
        press(&mut c, ms(0), Button::Line('K'), true);
        assert!(!line(&c, 'K'), "external control is off");
        assert!(c.write_coil(ms(0), Coil::ExternalControl, true));
        press(&mut c, ms(0), Button::Line('K'), false);
        c.control(ms(0), Control::EStop);
        assert!(c.inputs().get(Input::EStop) && !c.inputs().get(Input::Ready));
        press(&mut c, ms(0), Button::Line('K'), true);
        assert!(!line(&c, 'K'));
    }

    #[test]
    fn emergency_stop_freezes_travel_until_the_line_is_pressed_again() {
        let mut c = conveyor(&[W(2), W(2)]);
        press(&mut c, ms(0), Button::Line('K'), true);
        c.control(ms(3000), Control::EStop);
        assert!(!line(&c, 'K'));
        c.handle_timeout(ms(60_000));
        assert_eq!(c.describe(), "carriers: 1@K>W3 2@W2");
        c.control(ms(60_000), Control::EStopClear);
        press(&mut c, ms(60_000), Button::Line('K'), false);
        press(&mut c, ms(60_000), Button::Line('K'), true);
        c.handle_timeout(ms(64_999));
        assert!(!place(&c, 3));
        c.handle_timeout(ms(65_000));
        assert!(place(&c, 3));
    }

    #[test]
    fn a_jammed_line_runs_but_its_carrier_does_not_arrive() {
        let mut c = conveyor(&[W(2), W(2)]);
        c.control(ms(0), Control::Jam('E'));
        press(&mut c, ms(0), Button::Line('E'), true);
        c.handle_timeout(ms(60_000));
        assert!(line(&c, 'E') && !place(&c, 5));
        c.control(ms(60_000), Control::Unjam('E'));
        c.handle_timeout(ms(70_000));
        assert!(place(&c, 5) && !line(&c, 'E'));
    }

    #[test]
    fn a_stuck_sensor_shows_its_value() {
        let mut c = conveyor(&[W(2), W(2)]);
        c.control(ms(0), Control::Stuck(Place::of(3), false));
        press(&mut c, ms(0), Button::Line('K'), true);
        c.handle_timeout(ms(9000));
        assert!(!line(&c, 'K'), "the line stopped: the carrier is there");
        assert!(!place(&c, 3), "but the sensor says empty");
        c.control(ms(9000), Control::Unstuck(Place::of(3)));
        assert!(place(&c, 3));
    }

    #[test]
    fn a_full_place_holds_the_carrier_at_the_end_of_its_line() {
        let mut c = conveyor(&[W(4), W(2)]);
        press(&mut c, ms(0), Button::Line('E'), true);
        c.handle_timeout(ms(10_000));
        press(&mut c, ms(10_000), Button::Line('G'), true);
        c.handle_timeout(ms(14_000));
        assert!(line(&c, 'G'), "W4 is full: G keeps running");
        press(&mut c, ms(14_000), Button::Line('D'), true);
        assert_eq!(c.describe(), "carriers: 1@D>W2 2@W4");
        assert!(!line(&c, 'G'));
    }

    /// The in/out conveyor's plain I/O: the guard door starts closed
    /// (`[twin] inputs_on`), the lock's feedback follows the lock after
    /// half the file's 500 ms, and a door opened by hand shows.
    #[test]
    fn a_plain_input_follows_its_output_and_can_be_set_by_hand() {
        let e = Arc::new(
            Equipment::parse(
                include_str!("../../../equipment/conveyor-inout.toml"),
                "inout.toml",
            )
            .expect("loads"),
        );
        let mut c = Conveyor::new(e, &[W(2)], 1.0).expect("layout");
        assert!(c.write_coil(ms(0), Coil::ExternalControl, true));
        let name = |n: &str| IoName::parse(n).expect("a name");
        let input = |c: &Conveyor, n: &str| c.inputs().signal(Signal::Input(name(n)));
        assert!(input(&c, "door_closed") && !input(&c, "door_locked"));
        let lock = Coil::Button(Button::Output(name("door_lock")));
        assert!(c.write_coil(ms(1000), lock, true));
        assert_eq!(c.poll_timeout(), Some(ms(1250)));
        c.handle_timeout(ms(1249));
        assert!(!input(&c, "door_locked"));
        c.handle_timeout(ms(1250));
        assert!(input(&c, "door_locked"));
        assert_eq!(c.held(), "buttons held: door_lock");
        assert!(c.write_coil(ms(2000), lock, false));
        c.handle_timeout(ms(2250));
        assert!(!input(&c, "door_locked"));
        c.control(ms(3000), Control::Input(name("door_closed"), false));
        assert!(!input(&c, "door_closed"));
        assert!(c.inputs().to_string().ends_with("| on -"), "{}", c.inputs());
    }

    #[test]
    fn layouts_are_checked() {
        assert!(new(&[W(3), W(3)]).is_err());
        assert!(new(&[W(2), W(2)]).is_ok());
        assert_eq!(Spot::parse("s3"), Some(S(3)));
        assert_eq!(Spot::parse("W100"), None);
        assert_eq!(Spot::parse("X"), None);
        let e = new(&[W(7)]).err().unwrap_or_default();
        assert_eq!(e, "W7 is no place or station of conveyor-1992");
    }
}
