//! The equipment's named states (`[[state]]` in its file) and the way to
//! one. A named state is a row of an output table: the inputs that show
//! it (`on`, `off`; an input it does not list may be either). Which one
//! the equipment is in is the first whose inputs the live reading matches
//! ([`Equipment::state_shown`]).
//!
//! The way to a state ([`Equipment::way_to`]) is planned from what the
//! inputs show, over the layout's routes: each lit place sensor or busy
//! station is a carrier (a sensor cannot count: a place of capacity 2 that
//! is lit holds one or two), and each carrier standing where the state
//! wants nothing goes, nearest first, along the shortest route whose every
//! next spot is free, to a place the state wants occupied; then a place
//! the state wants occupied and no carrier reached is filled from a place
//! the state leaves open. A line running is no starting point (its carrier
//! is somewhere on it): the planner refuses until it stopped. The way is
//! a transport recipe ([`Way::recipe`]): every button released, each move
//! a press, a wait for its end and a release, and at last a wait for
//! every input the state lists, so that the engine that runs every recipe
//! runs this one too, with its limits and alarms.

use crate::file::{names, Equipment};
use crate::signal::{Coil, Input, Spot};
use falc_model::ids::{Place, PlcStation};
use falc_recipe::check::{Button, Signal};
use std::collections::{BTreeMap, VecDeque};
use std::fmt;
use std::fmt::Write as _;
use std::time::Duration;

/// A named state: the inputs that show it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NamedState {
    /// Its name (a lower-case word: `home`).
    pub name: String,
    /// What it is, for people.
    pub title: String,
    /// Inputs that are on in it.
    pub on: Vec<Input>,
    /// Inputs that are off in it.
    pub off: Vec<Input>,
}

impl NamedState {
    /// Whether the inputs `seen` show this state.
    pub fn shown_by(&self, seen: impl Fn(Input) -> bool) -> bool {
        self.unmet(seen).is_empty()
    }

    /// The inputs that `seen` shows otherwise than this state, named
    /// (`place 3 occupied is on`).
    pub fn unmet(&self, seen: impl Fn(Input) -> bool) -> Vec<String> {
        let on = self
            .on
            .iter()
            .filter(|&&i| !seen(i))
            .map(|i| format!("{i} is off"));
        let off = self
            .off
            .iter()
            .filter(|&&i| seen(i))
            .map(|i| format!("{i} is on"));
        on.chain(off).collect()
    }
}

/// One move of a way: what carries a carrier from one spot to the next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Move {
    /// A line runs its carrier from its start to its end.
    Line(char),
    /// A station takes the carrier of its place on.
    Onto(PlcStation),
}

impl fmt::Display for Move {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Move::Line(l) => write!(f, "line {l}"),
            Move::Onto(s) => write!(f, "station {s}"),
        }
    }
}

/// The way to a named state from what the inputs showed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Way {
    /// The state.
    pub state: NamedState,
    /// Where carriers were seen (a lit sensor, a busy station).
    pub from: Vec<Spot>,
    /// The moves, in order, each with where its carrier goes.
    pub moves: Vec<(Move, Spot)>,
}

/// One step of a route in the layout.
#[derive(Debug, Clone, Copy)]
struct Edge {
    how: Move,
    from: Spot,
    to: Spot,
    /// A limit for the move: three times the twin's time, 30 s at least.
    limit_s: u64,
}

fn limit(d: Duration) -> u64 {
    (d.as_secs_f64() * 3.0).ceil().max(30.0) as u64
}

impl Equipment {
    /// The state named `name`, if the file defines it.
    pub fn named_state(&self, name: &str) -> Option<&NamedState> {
        self.states()
            .iter()
            .find(|s| s.name.eq_ignore_ascii_case(name.trim()))
    }

    /// The first named state the inputs `seen` show, if any.
    pub fn state_shown(&self, seen: impl Fn(Input) -> bool) -> Option<&NamedState> {
        self.states().iter().find(|s| s.shown_by(&seen))
    }

    fn edges(&self) -> Vec<Edge> {
        let lines = self.lines().iter().map(|l| Edge {
            how: Move::Line(l.line),
            from: l.from,
            to: l.to,
            limit_s: limit(l.travel),
        });
        let stations = self.stations().iter().map(|s| Edge {
            how: Move::Onto(s.station),
            from: Spot::Place(s.takes_from),
            to: Spot::Station(s.station),
            limit_s: limit(s.cycle),
        });
        lines.chain(stations).collect()
    }

    /// The way to state `name` from the inputs `seen`, or why there is
    /// none (naming the carrier that cannot move, or the signal that
    /// stands in the way).
    pub fn way_to(&self, name: &str, seen: impl Fn(Input) -> bool) -> Result<Way, String> {
        let state = self.named_state(name).ok_or_else(|| {
            let known: Vec<&str> = self.states().iter().map(|s| s.name.as_str()).collect();
            format!(
                "{} has no state `{}` (it has: {})",
                self.name(),
                name.trim(),
                if known.is_empty() {
                    "none".to_string()
                } else {
                    known.join(", ")
                }
            )
        })?;
        // Whether the state wants `what` on, off, or leaves it open.
        let wanted = |what: Signal| {
            let i = Input::Signal(what);
            if state.on.contains(&i) {
                Some(true)
            } else if state.off.contains(&i) {
                Some(false)
            } else {
                None
            }
        };
        // What a way cannot make: a line running, a station busy, a
        // PLC signal.
        for &i in &state.on {
            if !matches!(i, Input::Signal(Signal::Place(_))) {
                return Err(format!(
                    "state {} needs `{i}` on: a way moves carriers to places, it cannot leave \
                     that on",
                    state.name
                ));
            }
        }
        // … nor change an input no carrier shows (a plain input, the
        // PLC's own): the state's as it is, or no way.
        let carried = |i: Input| {
            matches!(
                i,
                Input::Signal(Signal::Place(_) | Signal::Station(_) | Signal::Line(_))
            )
        };
        let beyond = NamedState {
            on: Vec::new(),
            off: state.off.iter().copied().filter(|&i| !carried(i)).collect(),
            ..state.clone()
        }
        .unmet(&seen);
        if !beyond.is_empty() {
            return Err(format!(
                "state {} needs what no carrier's move makes: {}",
                state.name,
                beyond.join(", ")
            ));
        }
        if let Some(l) = self
            .lines()
            .iter()
            .find(|l| seen(Input::Signal(Signal::Line(l.line))))
        {
            return Err(format!(
                "line {} is running (a carrier may be on it): a way is planned from carriers \
                 standing still; wait until it stops, or release it (falc manual transport \
                 release {})",
                l.line, l.line
            ));
        }
        // Carriers as the sensors show them.
        let mut count: BTreeMap<Spot, usize> = BTreeMap::new();
        for p in self.places() {
            if seen(Input::Signal(Signal::Place(p.place))) {
                count.insert(Spot::Place(p.place), 1);
            }
        }
        for s in self.stations() {
            if seen(Input::Signal(Signal::Station(s.station))) {
                count.insert(Spot::Station(s.station), 1);
            }
        }
        let from: Vec<Spot> = count.keys().copied().collect();
        let signal = |spot: Spot| match spot {
            Spot::Place(p) => Signal::Place(p),
            Spot::Station(s) => Signal::Station(s),
        };
        let need: Vec<Place> = state
            .on
            .iter()
            .filter_map(|i| match i {
                Input::Signal(Signal::Place(p)) => Some(*p),
                _ => None,
            })
            .collect();
        let edges = self.edges();
        let mut moves = Vec::new();
        // Each round moves one carrier to where the state wants one; at
        // most one round per carrier and place wanted.
        for _ in 0..=(from.len() + need.len()) {
            let occupied = |c: &BTreeMap<Spot, usize>, s: Spot| c.get(&s).copied().unwrap_or(0);
            let misplaced: Vec<Spot> = count
                .iter()
                .filter(|(s, n)| **n > 0 && wanted(signal(**s)) == Some(false))
                .map(|(s, _)| *s)
                .collect();
            let empty_need: Vec<Spot> = need
                .iter()
                .map(|p| Spot::Place(*p))
                .filter(|s| occupied(&count, *s) == 0)
                .collect();
            let (movers, goals): (Vec<Spot>, Vec<Spot>) = if !misplaced.is_empty() {
                let goals = need
                    .iter()
                    .map(|p| Spot::Place(*p))
                    .filter(|s| occupied(&count, *s) < self.capacity(*s))
                    .collect();
                (misplaced, goals)
            } else if !empty_need.is_empty() {
                let spare = count
                    .iter()
                    .filter(|(s, n)| **n > 0 && wanted(signal(**s)).is_none())
                    .map(|(s, _)| *s)
                    .collect::<Vec<_>>();
                if spare.is_empty() {
                    return Err(format!(
                        "state {} needs a carrier at {}, and none is seen that may leave \
                         where it stands (carriers seen at: {})",
                        state.name,
                        names(empty_need.iter()),
                        names(count.keys())
                    ));
                }
                (spare, empty_need)
            } else {
                return Ok(Way {
                    state: state.clone(),
                    from,
                    moves,
                });
            };
            // A state that wants places empty and none occupied: a
            // carrier goes to any place it leaves open.
            let goals = if goals.is_empty() && need.is_empty() {
                self.places()
                    .iter()
                    .map(|p| Spot::Place(p.place))
                    .filter(|s| {
                        wanted(signal(*s)).is_none() && occupied(&count, *s) < self.capacity(*s)
                    })
                    .collect()
            } else {
                goals
            };
            let mut best: Option<Vec<Edge>> = None;
            for &c in &movers {
                match route(&edges, c, &goals, |s| {
                    occupied(&count, s) < self.capacity(s)
                }) {
                    Some(r) if best.as_ref().map_or(true, |b| r.len() < b.len()) => best = Some(r),
                    Some(_) => {}
                    None if route(&edges, c, &goals, |_| true).is_none() => {
                        return Err(format!(
                            "the carrier at {c} cannot reach state {}: no route from {c} leads \
                             to {} ({})",
                            state.name,
                            if goals.is_empty() {
                                "a place with room".to_string()
                            } else {
                                names(goals.iter())
                            },
                            match edges.iter().filter(|e| e.from == c).count() {
                                0 => format!("no line or station starts at {c}"),
                                _ => format!(
                                    "from {c} run: {}",
                                    edges
                                        .iter()
                                        .filter(|e| e.from == c)
                                        .map(|e| format!("{} to {}", e.how, e.to))
                                        .collect::<Vec<_>>()
                                        .join(", ")
                                ),
                            }
                        ));
                    }
                    None => {}
                }
            }
            let Some(path) = best else {
                return Err(format!(
                    "the carriers at {} cannot move towards state {}: every route is blocked \
                     by a carrier standing on it (carriers seen at: {})",
                    names(movers.iter()),
                    state.name,
                    names(count.keys())
                ));
            };
            if let (Some(first), Some(last)) = (path.first(), path.last()) {
                if let Some(n) = count.get_mut(&first.from) {
                    *n = n.saturating_sub(1);
                }
                *count.entry(last.to).or_default() += 1;
            }
            moves.extend(path.iter().map(|e| (e.how, e.to)));
        }
        Err(format!(
            "no way to state {} found in {} moves (carriers seen at: {})",
            state.name,
            moves.len(),
            names(from.iter())
        ))
    }
}

/// The shortest route from `start` to one of `goals`, through spots
/// `free` allows (the goal too).
fn route(
    edges: &[Edge],
    start: Spot,
    goals: &[Spot],
    free: impl Fn(Spot) -> bool,
) -> Option<Vec<Edge>> {
    let mut came: BTreeMap<Spot, Edge> = BTreeMap::new();
    let mut queue = VecDeque::from([start]);
    while let Some(at) = queue.pop_front() {
        if at != start && goals.contains(&at) {
            let mut path = Vec::new();
            let mut s = at;
            while s != start {
                let e = came[&s];
                path.push(e);
                s = e.from;
            }
            path.reverse();
            return Some(path);
        }
        for e in edges.iter().filter(|e| e.from == at) {
            if e.to != start && !came.contains_key(&e.to) && free(e.to) {
                came.insert(e.to, *e);
                queue.push_back(e.to);
            }
        }
    }
    None
}

impl fmt::Display for Way {
    /// `to home from W5, S3: line G to W4, line D to W2, …`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "to {} from carriers seen at {}: ",
            self.state.name,
            names(self.from.iter())
        )?;
        if self.moves.is_empty() {
            return f.write_str("no move needed");
        }
        let moves: Vec<String> = self
            .moves
            .iter()
            .map(|(m, to)| format!("{m} to {to}"))
            .collect();
        f.write_str(&moves.join(", "))
    }
}

impl Way {
    /// The way as a transport recipe named `GOTO_<STATE>`: every line
    /// and station button of `equipment` released and every line waited for to stand still;
    /// each move pressed, waited for and released; at last each input the
    /// state lists waited for (5 s), an alarm naming the first that is not
    /// as the state says.
    pub fn recipe(&self, equipment: &Equipment) -> String {
        // The states in order, each a command and whether it waits.
        let mut states: Vec<(String, bool)> = Vec::new();
        // The buttons of lines and stations (a plain output, a beacon or a
        // lock, is not the way's to touch).
        for c in equipment.coils() {
            if let Coil::Button(b @ (Button::Line(_) | Button::Station(_))) = c.coil {
                states.push((format!("reset {}", word(b)), false));
            }
        }
        // Every line still before the first move: a carrier a line was
        // taking along when the way was planned is at its end now (and
        // the last check below finds it if the way did not count it).
        let edges = equipment.edges();
        for l in equipment.lines() {
            let limit_s = limit(l.travel);
            states.push((
                format!("waitline {} 0 {limit_s}", l.line.to_ascii_lowercase()),
                true,
            ));
        }
        for (how, to) in &self.moves {
            let limit_s = edges
                .iter()
                .find(|e| e.how == *how)
                .map_or(60, |e| e.limit_s);
            match how {
                Move::Line(l) => {
                    let l = l.to_ascii_lowercase();
                    states.push((format!("activate {l}"), false));
                    states.push((format!("reset {l}"), false));
                    if let Spot::Place(p) = to {
                        states.push((format!("waitplace {p} 1 {limit_s}"), true));
                    }
                    states.push((format!("waitline {l} 0 {limit_s}"), true));
                }
                Move::Onto(s) => {
                    states.push((format!("activate {s}"), false));
                    states.push((format!("waitstation {s} 1 {limit_s}"), true));
                    states.push((format!("reset {s}"), false));
                }
            }
        }
        for (inputs, level) in [(&self.state.on, 1), (&self.state.off, 0)] {
            for i in inputs.iter() {
                if let Input::Signal(s) = i {
                    states.push((format!("{} {level} 5", wait_of(*s)), true));
                }
            }
        }
        let mut out = String::new();
        let name = self.state.name.to_uppercase();
        let _ = writeln!(out, "#GOTO_{name}");
        let _ = writeln!(
            out,
            "Generated by `goto {}`: the way {self}.",
            self.state.name
        );
        let _ = writeln!(out);
        let last = states.len();
        for (k, (command, waits)) in states.iter().enumerate() {
            let n = k + 1;
            let next = if n == last { 0 } else { n + 1 };
            if *waits {
                let _ = writeln!(out, "-{n} | {command} | | klaar | {next}");
                let _ = writeln!(out, "-{n} | {command} | | tijdlimiet | 999");
            } else {
                let _ = writeln!(out, "-{n} | {command} | | | {next}");
            }
        }
        let _ = writeln!(out, "-999 | | alarm | | 0");
        out
    }
}

/// A button as a recipe writes it.
fn word(b: Button) -> String {
    match b {
        Button::Line(l) => l.to_ascii_lowercase().to_string(),
        Button::Station(s) => s.to_string(),
        Button::Output(n) => n.to_string(),
    }
}

/// The recipe command that waits for `s` and the name it waits with.
fn wait_of(s: Signal) -> String {
    match s {
        Signal::Line(l) => format!("waitline {}", l.to_ascii_lowercase()),
        Signal::Place(p) => format!("waitplace {p}"),
        Signal::Station(n) => format!("waitstation {n}"),
        Signal::Input(n) => format!("waitinput {n}"),
    }
}

impl fmt::Display for NamedState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let on: Vec<String> = self.on.iter().map(|i| i.to_string()).collect();
        let off: Vec<String> = self.off.iter().map(|i| i.to_string()).collect();
        write!(
            f,
            "{}: on {}; off {}",
            self.name,
            on.join(", "),
            off.join(", ")
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::signal::{S, W};
    use falc_recipe::check::{check, Command};
    use falc_recipe::commands::RecipeKind;
    use falc_recipe::syntax::parse;
    use std::collections::BTreeSet;

    /// What the sensors show: carriers at `spots`, lines `running`.
    fn seen(spots: &[Spot], running: &[char]) -> impl Fn(Input) -> bool {
        let spots: BTreeSet<Spot> = spots.iter().copied().collect();
        let running: Vec<char> = running.to_vec();
        move |i| match i {
            Input::Signal(Signal::Place(p)) => spots.contains(&Spot::Place(p)),
            Input::Signal(Signal::Station(s)) => spots.contains(&Spot::Station(s)),
            Input::Signal(Signal::Line(l)) => running.contains(&l),
            Input::Signal(Signal::Input(_)) => false,
            Input::Ready => true,
            Input::EStop => false,
        }
    }

    fn lines(w: &Way) -> Vec<String> {
        w.moves.iter().map(|(m, to)| format!("{m}>{to}")).collect()
    }

    #[test]
    fn the_1992_conveyor_shows_home_only_with_its_carriers_at_w2_and_nothing_running() {
        let e = Equipment::conveyor_1992();
        let home = |spots: &[Spot], running: &[char]| {
            e.state_shown(seen(spots, running)).map(|s| s.name.clone())
        };
        assert_eq!(home(&[W(2)], &[]).as_deref(), Some("home"));
        assert_eq!(home(&[W(2), W(5)], &[]), None);
        assert_eq!(home(&[W(2)], &['B']), None);
        assert_eq!(home(&[W(2), S(3)], &[]), None);
        let s = e.named_state("HOME").expect("home");
        assert_eq!(
            s.unmet(seen(&[W(5)], &['G'])),
            [
                "place 2 occupied is off",
                "place 5 occupied is on",
                "line G running is on"
            ]
        );
    }

    #[test]
    fn the_way_home_runs_the_nearest_carrier_first_over_the_layouts_routes() {
        let e = Equipment::conveyor_1992();
        // Nothing to do: home already.
        let w = e.way_to("home", seen(&[W(2)], &[])).expect("way");
        assert!(w.moves.is_empty());
        // A carrier at W5 (MOVE_TO_MAN done) and one at W4: W4's first,
        // so that W4 is free for the other.
        let w = e.way_to("home", seen(&[W(5), W(4)], &[])).expect("way");
        assert_eq!(lines(&w), ["line D>W2", "line G>W4", "line D>W2"]);
        // On the table (station 3): off it by line F, then D.
        let w = e.way_to("home", seen(&[W(2), S(3)], &[])).expect("way");
        assert_eq!(lines(&w), ["line F>W4", "line D>W2"]);
        // At W3: L, D (two moves) rather than H, G, D.
        let w = e.way_to("home", seen(&[W(3), W(2)], &[])).expect("way");
        assert_eq!(lines(&w), ["line L>W4", "line D>W2"]);
        // Both carriers away, neither at W2: both come.
        let w = e.way_to("home", seen(&[W(6), W(3)], &[])).expect("way");
        assert_eq!(lines(&w), ["line A>W2", "line L>W4", "line D>W2"]);
    }

    #[test]
    fn a_station_is_a_step_of_a_route_when_no_line_leaves_a_place() {
        // The in/out cell: no line starts at W3; its carrier goes onto the
        // table, off it by line B, then by C home.
        let text = include_str!("../../../equipment/conveyor-inout.toml");
        let e = Equipment::parse(text, "inout.toml").expect("loads");
        let w = e.way_to("home", seen(&[W(3)], &[])).expect("way");
        assert_eq!(lines(&w), ["station 3>S3", "line B>W4", "line C>W2"]);
    }

    #[test]
    fn no_way_is_planned_while_a_line_runs_or_to_where_no_route_leads() {
        let e = Equipment::conveyor_1992();
        let why = e.way_to("home", seen(&[W(2)], &['G'])).unwrap_err();
        assert!(why.starts_with("line G is running"), "{why}");
        // An input no move of a carrier changes: refused at once, naming it.
        let text = include_str!("../../../equipment/conveyor-inout.toml").replace(
            "\"station 1 busy\", \"station 3 busy\",",
            "\"station 1 busy\", \"station 3 busy\", \"input door_locked\",",
        );
        let inout = Equipment::parse(&text, "inout.toml").expect("loads");
        let locked = |i: Input| {
            i == Input::Signal(Signal::Input(
                falc_model::ids::IoName::parse("door_locked").expect("a name"),
            )) || seen(&[W(3)], &[])(i)
        };
        assert_eq!(
            inout.way_to("home", locked).unwrap_err(),
            "state home needs what no carrier's move makes: input door_locked is on"
        );
        let why = e.way_to("lunch", seen(&[W(2)], &[])).unwrap_err();
        assert_eq!(why, "conveyor-1992 has no state `lunch` (it has: home)");
        // A dead end: place 7 where no line starts.
        let text = include_str!("../../../equipment/conveyor-1992.toml")
            .replace(
                "# A line runs a carrier",
                "[[place]]\nname = \"7\"\n\n# A line runs a carrier",
            )
            .replace(
                "[[coil]]\naddress = 0\n",
                "[[input]]\naddress = 40\nsignal = \"place 7 occupied\"\n\n[[coil]]\naddress = 0\n",
            )
            .replace(
                "\"place 6 occupied\",\n",
                "\"place 6 occupied\", \"place 7 occupied\",\n",
            );
        let e = Equipment::parse(&text, "dead-end.toml").expect("loads");
        let why = e.way_to("home", seen(&[W(2), W(7)], &[])).unwrap_err();
        assert_eq!(
            why,
            "the carrier at W7 cannot reach state home: no route from W7 leads to W2 \
             (no line or station starts at W7)"
        );
        // Blocked: the in/out cell's only carrier on the in/out station
        // with W2 wanted empty would go round; a state wanting W3 and W4
        // with one carrier seen cannot be made.
        let text = include_str!("../../../equipment/conveyor-inout.toml").replace(
            "name = \"home\"",
            "name = \"both\"\non = [\"place 3 occupied\", \"place 4 occupied\"]\n\n[[state]]\nname = \"home\"",
        );
        let e = Equipment::parse(&text, "inout.toml").expect("loads");
        let why = e.way_to("both", seen(&[W(3)], &[])).unwrap_err();
        assert!(
            why.starts_with("state both needs a carrier at W4, and none is seen"),
            "{why}"
        );
    }

    #[test]
    fn the_way_is_a_transport_recipe_the_checker_takes() {
        let e = Equipment::conveyor_1992();
        let w = e.way_to("home", seen(&[W(2), S(3)], &[])).expect("way");
        let text = w.recipe(&e);
        let program = check(&parse(&text, "GOTO_HOME"), RecipeKind::Transport)
            .unwrap_or_else(|p| panic!("{p:?}\n{text}"));
        assert!(e.check_program(&program).is_empty(), "{text}");
        let commands: Vec<String> = program.states.values().map(|s| s.text.clone()).collect();
        // Every button released first (14 of them), every line waited for
        // to stand still (11), then the moves, then the state's inputs
        // waited for.
        assert!(
            commands[..14].iter().all(|c| c.starts_with("reset ")),
            "{commands:?}"
        );
        assert!(
            commands[14..25]
                .iter()
                .all(|c| c.starts_with("waitline ") && c.contains(" 0 ")),
            "{commands:?}"
        );
        let moves: Vec<&str> = commands[25..].iter().map(String::as_str).collect();
        assert_eq!(
            moves[..8],
            [
                "activate f",
                "reset f",
                "waitplace 4 1 30",
                "waitline f 0 30",
                "activate d",
                "reset d",
                "waitplace 2 1 30",
                "waitline d 0 30",
            ]
        );
        assert!(moves.contains(&"waitplace 2 1 5"), "{moves:?}");
        assert!(moves.contains(&"waitstation 3 0 5"), "{moves:?}");
        let waits = program
            .states
            .values()
            .filter(|s| matches!(s.command, Command::WaitInput { .. }))
            .count();
        assert_eq!(waits, 11 + 4 + 19);
        assert!(text.starts_with(
            "#GOTO_HOME\nGenerated by `goto home`: the way to home from carriers seen at W2, S3: \
             line F to W4, line D to W2.\n"
        ), "{text}");
    }
}
