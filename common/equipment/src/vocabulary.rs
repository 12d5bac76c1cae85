//! What a transport recipe may name on a station with this equipment: the
//! lines, places, stations and plain inputs and outputs of its file. The recipe checker knows the
//! recipe language (a line is a letter, a place a number); this says
//! whether the station's conveyor has what a recipe names, and when not,
//! names what it has. The recipe store runs it on every transport recipe
//! against its station's equipment, and the transport node on every
//! recipe it is asked to start.

use crate::file::names;
use crate::file::Equipment;
use crate::signal::SignalName;
use falc_model::ids::StationName;
use falc_recipe::check::{Button, Command, Program, Signal};
use falc_recipe::commands::RecipeKind;
use falc_recipe::condition::Fact;
use falc_recipe::problem::{Problem, ProblemKind};
use std::collections::BTreeMap;
use std::sync::Arc;

/// What the transport recipes of a set name that their station's
/// equipment lacks (`equipment` by station; a station it has no file for
/// has the 1992 conveyor, the default), as the recipe store, `falc recipe
/// check` and `verify` refuse it.
pub fn lacking_in(
    equipment: &BTreeMap<StationName, Arc<Equipment>>,
    programs: &[(StationName, Program)],
) -> Vec<Problem> {
    programs
        .iter()
        .filter(|(_, p)| p.kind == RecipeKind::Transport)
        .flat_map(|(station, p)| {
            equipment
                .get(station)
                .cloned()
                .unwrap_or_else(Equipment::conveyor_1992)
                .check_program(p)
        })
        .collect()
}

impl Equipment {
    /// Every command of `program` that names a line, place or station
    /// this equipment lacks, as a problem at its state's line.
    pub fn check_program(&self, program: &Program) -> Vec<Problem> {
        let mut out = Vec::new();
        for state in program.states.values() {
            let missing = match &state.command {
                Command::Activate(b) | Command::Reset(b) => self.lacks_button(*b),
                Command::WaitInput { signal, .. } => self.lacks_signal(*signal),
                _ => None,
            };
            if let Some(message) = missing {
                out.push(Problem {
                    origin: program.origin.clone(),
                    line: state.line,
                    state: Some(state.no),
                    kind: ProblemKind::BadArgument,
                    message,
                });
            }
        }
        // Its conditions name inputs too.
        for (which, c) in [("#PRE", &program.pre), ("#POST", &program.post)] {
            let Some(c) = c else { continue };
            for t in &c.terms {
                let Fact::Signal(signal) = t.fact else {
                    continue;
                };
                if let Some(why) = self.lacks_signal(signal) {
                    out.push(Problem {
                        origin: program.origin.clone(),
                        line: c.line,
                        state: None,
                        kind: ProblemKind::BadArgument,
                        message: format!("{which} `{t}`: {why}"),
                    });
                }
            }
        }
        out.sort_by_key(|p| p.line);
        out
    }

    /// Why a recipe may not press `b` here, if it may not.
    pub fn lacks_button(&self, b: Button) -> Option<String> {
        if self.has_button(b) {
            return None;
        }
        Some(match b {
            Button::Line(l) => self.no_line(l),
            Button::Station(s) => format!(
                "{} has no station {s} (stations: {})",
                self.name(),
                names(self.stations().iter().map(|x| x.station))
            ),
            Button::Output(n) => format!(
                "{} has no output {n} (outputs: {})",
                self.name(),
                names(self.plain_outputs())
            ),
        })
    }

    /// Why a recipe may not wait for `s` here, if it may not.
    pub fn lacks_signal(&self, s: Signal) -> Option<String> {
        if self.has_signal(s) {
            return None;
        }
        Some(match s {
            Signal::Line(l) => self.no_line(l),
            Signal::Place(p) => format!(
                "{} has no place {p} (places: {})",
                self.name(),
                names(self.places().iter().map(|x| x.place))
            ),
            Signal::Station(_) => format!(
                "{} has no input `{}` (stations: {})",
                self.name(),
                SignalName(s),
                names(self.stations().iter().map(|x| x.station))
            ),
            Signal::Input(n) => format!(
                "{} has no input {n} (inputs: {})",
                self.name(),
                names(self.plain_inputs())
            ),
        })
    }

    fn no_line(&self, l: char) -> String {
        format!(
            "{} has no line {l} (lines: {})",
            self.name(),
            names(self.lines().iter().map(|x| x.line))
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_recipe::check::{check, Command};
    use falc_recipe::commands::RecipeKind;
    use falc_recipe::syntax::parse;

    const SMALL: &str = include_str!("../tests/fixtures/small.toml");

    /// What `program` names that `e` lacks, as printed.
    fn lacking(e: &Equipment, program: &Program) -> Vec<String> {
        e.check_program(program)
            .iter()
            .map(Problem::to_string)
            .collect()
    }

    #[test]
    fn a_recipe_naming_what_the_conveyor_lacks_is_refused_naming_what_it_has() {
        let e = Equipment::parse(SMALL, "small.toml").expect("loads");
        let text = "#AWAY
-1 | activate c       | | | 2
-2 | waitplace 3 1 40 | | klaar | 3
-2 | waitplace 3 1 40 | | tijdlimiet | 0
-3 | reset c          | | | 4
-4 | waitplace 6 1 40 | | klaar | 0
-4 | waitplace 6 1 40 | | tijdlimiet | 0
";
        let program = check(&parse(text, "transport/away.rcp"), RecipeKind::Transport)
            .expect("the language allows it");
        let found = lacking(&e, &program);
        assert_eq!(
            found,
            [
                "transport/away.rcp:2: state 1: small has no line C (lines: A, B)",
                "transport/away.rcp:5: state 3: small has no line C (lines: A, B)",
                "transport/away.rcp:6: state 4: small has no place 6 (places: 2, 3)",
            ]
        );
        // The 1992 conveyor has them all.
        assert!(Equipment::conveyor_1992()
            .check_program(&program)
            .is_empty());
    }

    /// Plain inputs and outputs (`output beacon`, `input door_closed`):
    /// `set` and `waitinput` name them, the checker reads them as a
    /// button and a signal, and a name the file lacks is refused naming
    /// those it has.
    #[test]
    fn plain_inputs_and_outputs_are_set_and_waited_for_by_name() {
        let e = Equipment::parse(
            include_str!("../../../equipment/conveyor-inout.toml"),
            "inout.toml",
        )
        .expect("loads");
        let text = "#DOOR
-1 | set Beacon 1               | | | 2
-2 | waitinput door_closed 1 30 | | klaar | 3
-2 | waitinput door_closed 1 30 | | tijdlimiet | 0
-3 | set horn 0                 | | | 4
-4 | waitinput smoke 0 5        | | klaar | 0
-4 | waitinput smoke 0 5        | | tijdlimiet | 0
";
        let program =
            check(&parse(text, "transport/door.rcp"), RecipeKind::Transport).expect("checks");
        let commands: Vec<&Command> = program.states.values().map(|s| &s.command).collect();
        let beacon = falc_model::ids::IoName::parse("beacon").expect("a name");
        let door = falc_model::ids::IoName::parse("door_closed").expect("a name");
        assert_eq!(commands[0], &Command::Activate(Button::Output(beacon)));
        assert!(matches!(
            commands[1],
            Command::WaitInput { signal: Signal::Input(n), level: true, .. } if *n == door
        ));
        let found = lacking(&e, &program);
        assert_eq!(
            found,
            [
                "transport/door.rcp:5: state 3: conveyor-inout has no output horn (outputs: beacon, door_lock)",
                "transport/door.rcp:6: state 4: conveyor-inout has no input smoke (inputs: door_closed, door_locked)",
            ]
        );
        // Names the language refuses, at the line.
        let bad = "#BAD\n-1 | set 2beacon 1 | | | 2\n-2 | set beacon on | | | 0\n";
        let problems: Vec<String> = check(&parse(bad, "bad.rcp"), RecipeKind::Transport)
            .expect_err("refused")
            .iter()
            .map(Problem::to_string)
            .collect();
        assert!(
            problems[0].contains("`2beacon` is not an input or output name"),
            "{problems:?}"
        );
        assert!(
            problems[1].contains("`on` is not a level (1 or 0)"),
            "{problems:?}"
        );
    }

    /// A recipe's conditions name inputs of its equipment too.
    #[test]
    fn conditions_naming_what_the_conveyor_lacks_are_refused_at_their_line() {
        let e = Equipment::parse(SMALL, "small.toml").expect("loads");
        let text = "#PARK\n#PRE place 2 occupied, place 6 empty\n#POST line C stopped\n\
                    -1 | activate a | | | 0\n";
        let program = check(&parse(text, "park.rcp"), RecipeKind::Transport).expect("checks");
        assert_eq!(
            lacking(&e, &program),
            [
                "park.rcp:2: #PRE `place 6 empty`: small has no place 6 (places: 2, 3)",
                "park.rcp:3: #POST `line C stopped`: small has no line C (lines: A, B)",
            ]
        );
    }

    /// Four lines and eight places, a station numbered 12, a line M: more
    /// than the 1992 conveyor has, as a file says.
    #[test]
    fn a_conveyor_of_eight_places_is_a_file() {
        let mut text = String::from("name = \"eight\"\n");
        for p in 1..=8 {
            text += &format!("[[place]]\nname = \"{p}\"\n");
            text += &format!("[[input]]\naddress = {p}\nsignal = \"place {p} occupied\"\n");
        }
        for (i, (l, from, to)) in [('A', 1, 8), ('B', 8, 1), ('C', 2, 7), ('M', 7, 2)]
            .into_iter()
            .enumerate()
        {
            text += &format!(
                "[[line]]\nname = \"{l}\"\nfrom = \"W{from}\"\nto = \"W{to}\"\ntravel_s = 2\n\
                 [[coil]]\naddress = {i}\nsignal = \"button line {l}\"\n\
                 [[input]]\naddress = {}\nsignal = \"line {l} running\"\n",
                20 + i
            );
        }
        text += "[[station]]\nname = \"12\"\ntakes_from = \"W8\"\ncycle_s = 1\n\
                 [[coil]]\naddress = 9\nsignal = \"button station 12\"\n\
                 [[input]]\naddress = 30\nsignal = \"station 12 busy\"\n\
                 [[coil]]\naddress = 10\nsignal = \"external control\"\n\
                 [[input]]\naddress = 31\nsignal = \"PLC ready\"\n\
                 [[input]]\naddress = 32\nsignal = \"emergency stop\"\n";
        let e = Equipment::parse(&text, "eight.toml").unwrap_or_else(|p| panic!("{p}"));
        assert_eq!(
            (e.lines().len(), e.places().len(), e.stations().len()),
            (4, 8, 1)
        );
        let text = "#FAR
-1 | activate m       | | | 2
-2 | waitplace 2 1 40 | | klaar | 3
-2 | waitplace 2 1 40 | | tijdlimiet | 3
-3 | reset m          | | | 4
-4 | activate 12      | | | 5
-5 | waitplace 8 0 40 | | klaar | 0
-5 | waitplace 8 0 40 | | tijdlimiet | 0
";
        let program = check(&parse(text, "transport/far.rcp"), RecipeKind::Transport)
            .expect("the language allows it");
        assert!(e.check_program(&program).is_empty());
        let found: Vec<String> = Equipment::conveyor_1992()
            .check_program(&program)
            .iter()
            .map(Problem::to_string)
            .collect();
        for want in [
            "transport/far.rcp:7: state 5: conveyor-1992 has no place 8 (places: 2, 3, 4, 5, 6)",
            "transport/far.rcp:6: state 4: conveyor-1992 has no station 12 (stations: 1, 2, 3)",
            "transport/far.rcp:2: state 1: conveyor-1992 has no line M (lines: A, B, C, D, E, F, G, H, J, K, L)",
        ] {
            assert!(found.iter().any(|f| f == want), "{want}: {found:?}");
        }
    }
}
