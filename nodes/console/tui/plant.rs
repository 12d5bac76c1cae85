//! The plant overview of `falc tui` in a plant, sans-I/O: one line per
//! cell from the operator's `PlantStatus` (mode, list, running order,
//! alarm, stations at a glance), a cursor; keys in, [`PlantIntent`]s out.
//! Enter opens the chosen cell's screens (`app::App`, for that cell), and
//! Esc there comes back here. The driver (`tui::run`) polls the status and
//! draws it with `view::draw_plant`.

use falc_model::api::{ApiReply, ListState, PlantStatus};
use falc_model::ids::{CellId, StationName};
use falc_model::plant::Plant;
use falc_model::topology::{Role, StationKind};
use ratatui::crossterm::event::{KeyCode, KeyEvent, KeyModifiers};

/// What the driver must do for the plant overview.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PlantIntent {
    /// Show this cell's screens.
    Open(CellId),
    /// Leave the TUI.
    Quit,
}

/// The plant overview's state.
pub struct PlantApp {
    /// The plant's name.
    pub plant: CellId,
    /// Who uses it, and as what.
    pub user: StationName,
    /// Its role.
    pub role: Role,
    /// The plant's cells, in file order (shown before the first status).
    pub cells: Vec<CellId>,
    /// Each cell's controller (the station of kind cell).
    controllers: Vec<(CellId, StationName)>,
    /// The cell of a plant of one (which answers `status` as that cell).
    only_cell: Option<CellId>,
    /// The last status, if any.
    pub status: Option<PlantStatus>,
    /// Why the operator node cannot be reached, if it cannot.
    pub unreachable: Option<String>,
    /// The line chosen.
    pub cursor: usize,
}

impl PlantApp {
    /// The overview of `plant` for console user `user`.
    pub fn new(plant: &Plant, user: StationName) -> Self {
        let role = plant
            .factory()
            .console(&user)
            .map(|c| c.role)
            .unwrap_or(Role::Observer);
        Self {
            plant: plant.name().clone(),
            user,
            role,
            cells: plant.cells().iter().map(|c| c.id().clone()).collect(),
            controllers: plant
                .cells()
                .iter()
                .flat_map(|c| {
                    c.topology()
                        .stations()
                        .iter()
                        .filter(|s| s.kind == StationKind::Cell)
                        .map(|s| (c.id().clone(), s.name.clone()))
                })
                .collect(),
            only_cell: match plant.cells() {
                [one] => Some(one.id().clone()),
                _ => None,
            },
            status: None,
            unreachable: None,
            cursor: 0,
        }
    }

    /// The operator's answer to `status` (or why there is none): the
    /// plant's, or in a plant of one cell that cell's.
    pub fn status(&mut self, answer: Result<ApiReply, String>) {
        let status = match answer {
            Ok(ApiReply::Plant(p)) => Ok(p),
            Ok(ApiReply::Status(s)) => match &self.only_cell {
                Some(cell) => Ok(PlantStatus {
                    cells: vec![(cell.clone(), s)],
                }),
                None => Err("unexpected answer to status: one cell's, not the plant's".into()),
            },
            Ok(other) => Err(format!("unexpected answer to status: {other:?}")),
            Err(e) => Err(e),
        };
        match status {
            Ok(s) => {
                self.cells = s.cells.iter().map(|(c, _)| c.clone()).collect();
                self.cursor = self.cursor.min(self.cells.len().saturating_sub(1));
                self.status = Some(s);
                self.unreachable = None;
            }
            Err(e) => self.unreachable = Some(e),
        }
    }

    /// Whether `station` is cell `cell`'s controller.
    pub fn is_controller(&self, cell: &CellId, station: &StationName) -> bool {
        self.controllers
            .iter()
            .any(|(c, s)| c == cell && s == station)
    }

    /// How many cells hold an alarm that waits for `ack`.
    pub fn alarms(&self) -> usize {
        self.status.as_ref().map_or(0, |s| {
            s.cells
                .iter()
                .filter(|(_, c)| c.alarm.is_some() || c.list == ListState::Alarm)
                .count()
        })
    }

    /// A key: ↑/↓ choose a cell, Enter opens it, q or Ctrl-C quits.
    pub fn key(&mut self, k: KeyEvent) -> Option<PlantIntent> {
        if k.modifiers.contains(KeyModifiers::CONTROL) && k.code == KeyCode::Char('c') {
            return Some(PlantIntent::Quit);
        }
        let n = self.cells.len();
        match k.code {
            KeyCode::Char('q') => Some(PlantIntent::Quit),
            KeyCode::Up if n > 0 => {
                self.cursor = (self.cursor + n - 1) % n;
                None
            }
            KeyCode::Down if n > 0 => {
                self.cursor = (self.cursor + 1) % n;
                None
            }
            KeyCode::Enter => self.cells.get(self.cursor).cloned().map(PlantIntent::Open),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_model::api::CellStatus;
    use ratatui::crossterm::event::KeyEvent;

    fn key(code: KeyCode) -> KeyEvent {
        KeyEvent::new(code, KeyModifiers::NONE)
    }

    fn id(s: &str) -> CellId {
        CellId::new(s).expect("valid")
    }

    #[test]
    fn the_cursor_chooses_a_cell_and_enter_opens_it() {
        let plant = Plant::parse(include_str!("../../../launch/factory.toml"), "factory.toml")
            .expect("the shipped plant");
        let user = StationName::new("console").expect("name");
        let mut app = PlantApp::new(&plant, user);
        assert_eq!(app.role, Role::Operator);
        assert_eq!(app.cells, vec![id("falc1"), id("falc2"), id("falc3")]);
        assert!(app.is_controller(&id("falc2"), &StationName::new("cell").expect("name")));
        assert_eq!(app.key(key(KeyCode::Down)), None);
        assert_eq!(
            app.key(key(KeyCode::Enter)),
            Some(PlantIntent::Open(id("falc2")))
        );
        app.key(key(KeyCode::Down));
        app.key(key(KeyCode::Down));
        assert_eq!(app.cursor, 0, "round");
        app.key(key(KeyCode::Up));
        assert_eq!(app.cursor, 2);
        // A status of fewer cells keeps the cursor on one of them.
        let alarmed = CellStatus {
            alarm: Some("no connection with station cell".into()),
            ..CellStatus::default()
        };
        app.status(Ok(ApiReply::Plant(PlantStatus {
            cells: vec![(id("falc1"), alarmed.clone())],
        })));
        assert_eq!((app.cursor, app.alarms()), (0, 1));
        // A plant of one cell answers `status` as that cell.
        app.status(Ok(ApiReply::Status(alarmed)));
        assert!(
            app.unreachable.is_some(),
            "three cells: not the plant's answer"
        );
        let one = Plant::parse(
            &include_str!("../../../launch/factory.toml")
                .split("[[cell]]")
                .take(2)
                .collect::<Vec<_>>()
                .join("[[cell]]"),
            "one cell",
        )
        .expect("a plant of one cell");
        let mut single = PlantApp::new(&one, StationName::new("console").expect("name"));
        single.status(Ok(ApiReply::Status(CellStatus::default())));
        assert_eq!(single.unreachable, None);
        assert_eq!(
            single.status.as_ref().map(|s| s.cells.len()),
            Some(1),
            "{:?}",
            single.status
        );
        app.status(Err("no reply".into()));
        assert_eq!(app.unreachable.as_deref(), Some("no reply"));
        assert!(app.status.is_some(), "the last status stays shown");
        assert_eq!(app.key(key(KeyCode::Char('q'))), Some(PlantIntent::Quit));
    }
}
