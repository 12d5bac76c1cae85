//! The TUI's state, sans-I/O: what the operator node last said (status,
//! orders, messages), which layer and pane are shown, what is being typed
//! or picked; keys in, [`Intent`]s out. The driver (`tui::run`) does the
//! calls and feeds the answers back; `tui::view` draws it.

use falc_equipment::Equipment;
use falc_model::api::{ApiReply, ApiRequest, CellStatus};
use falc_model::ids::StationName;
use falc_model::mode::{CellMode, HeldStep, ManualAction};
use falc_model::recipe_file::{RecipeFile, RecipeInfo, RecipeText};
use falc_model::records::{Entry, Order, OrderState};
use falc_model::topology::{Role, StationKind, Topology};
use falc_plc::map::Inputs;
use falc_recipe::syntax::parse;
use ratatui::crossterm::event::{KeyCode, KeyEvent, KeyModifiers};
use std::collections::BTreeMap;
use std::sync::Arc;

/// The layers of the 1992 interface, and the recipe view.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layer {
    /// F1: the cell drawn schematically.
    Overview,
    /// F2: messages, one pane per station.
    Messages,
    /// F3: commands.
    Commands,
    /// F4: a recipe's state table, the current state highlighted.
    Recipe,
    /// F5: the figures of the last week (OEE and its factors per shift or
    /// day, cycle times, the alarm Pareto).
    Figures,
}

/// How far back F5 looks: a week.
pub const FIGURES_RANGE_MS: i64 = 7 * 86_400_000;

/// What the driver must do for the app.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Intent {
    /// Make this call and hand the answer to [`App::answered`].
    Call(ApiRequest),
    /// Edit this recipe in `$EDITOR` (suspend the screen meanwhile).
    Edit(RecipeFile),
    /// Edit the refused text again.
    EditAgain,
    /// Drop the refused text.
    Discard,
    /// Leave the TUI.
    Quit,
    /// Back to the plant overview (a cell of a plant).
    Back,
}

/// A command of the F3 layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// Add an order (pick a cell recipe).
    Order,
    /// Remove a queued order (pick it).
    Remove,
    /// Start the list.
    Start,
    /// Stop the list.
    Stop,
    /// Acknowledge the alarm.
    Ack,
    /// Shut down once the list is done.
    Shutdown,
    /// Edit a recipe (pick a station, then a recipe or new).
    Edit,
    /// Show a recipe in the recipe view.
    View,
    /// Set the cell's mode (pick one).
    Mode,
    /// Step mode: carry out the cell's step that waits.
    Step,
    /// Maintenance: run a workstation's home recipe (pick one).
    Home,
}

impl Command {
    /// Every command, in menu order.
    pub const ALL: [Command; 11] = [
        Self::Order,
        Self::Remove,
        Self::Start,
        Self::Stop,
        Self::Ack,
        Self::Shutdown,
        Self::Edit,
        Self::View,
        Self::Mode,
        Self::Step,
        Self::Home,
    ];

    /// The key that picks it, and its label.
    pub fn label(self) -> (char, &'static str) {
        match self {
            Self::Order => ('o', "order: add an order for a cell recipe"),
            Self::Remove => ('r', "remove a queued order"),
            Self::Start => ('s', "start the order list"),
            Self::Stop => ('t', "stop the running order and the list"),
            Self::Ack => ('a', "acknowledge the alarm"),
            Self::Shutdown => ('d', "shut down when the list is done"),
            Self::Edit => ('e', "recipe: edit one, or make a new one"),
            Self::View => ('v', "recipe: view one's state table"),
            Self::Mode => ('m', "mode: auto, step or maintenance"),
            Self::Step => ('n', "next step (step mode; Enter on F1 too)"),
            Self::Home => ('h', "home: a workstation back to its start"),
        }
    }

    /// The least role that may do it (the router enforces it; shown here).
    pub fn role(self) -> Role {
        match self {
            Self::Edit => Role::Engineer,
            Self::View => Role::Observer,
            Self::Home => Role::Maintainer,
            _ => Role::Operator,
        }
    }
}

/// A choice being made in the F3 layer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Pick {
    /// A cell recipe for a new order.
    OrderRecipe(Vec<String>),
    /// A queued order to remove.
    Order(Vec<Order>),
    /// A station whose recipe to edit or view.
    Station(Vec<StationName>, Command),
    /// A recipe of that station (edit: the first item is "new").
    Recipe(Vec<RecipeFile>, Command),
    /// The name of a new recipe file, being typed.
    NewName(StationName, String),
    /// Shut down? y/n.
    ConfirmShutdown,
    /// The checker refused an edit: edit again (e) or discard (Esc).
    EditAgain,
    /// The cell's new mode.
    Mode(Vec<CellMode>),
    /// The workstation to bring home.
    Home(Vec<StationName>),
}

/// Messages of one station.
#[derive(Debug, Clone, Default)]
pub struct Pane {
    /// The station.
    pub station: Option<StationName>,
    /// Its entries, oldest first.
    pub entries: Vec<Entry>,
    /// How many came since the pane was last shown.
    pub unread: usize,
}

/// A recipe as the F4 view shows it, read once when it came: its name
/// and which state each line belongs to.
#[derive(Debug, Clone)]
pub struct Viewed {
    /// The recipe as the store sent it.
    pub recipe: RecipeText,
    /// The program it names (its file's name when it names none).
    pub program: String,
    /// Per line of its text, the state it belongs to (none: a comment, a
    /// blank or a line that does not parse).
    pub states: Vec<Option<u16>>,
}

impl Viewed {
    /// Reads `recipe`.
    pub fn of(recipe: RecipeText) -> Self {
        let parsed = parse(&recipe.text, &recipe.file.to_string());
        let program = parsed.name.as_ref().map_or_else(
            || recipe.file.file().trim_end_matches(".rcp").to_string(),
            |(n, _)| n.as_str().to_string(),
        );
        let mut states = vec![None; recipe.text.lines().count()];
        for row in &parsed.rows {
            if let Some(s) = row.line.checked_sub(1).and_then(|i| states.get_mut(i)) {
                *s = Some(row.state.0);
            }
        }
        Self {
            recipe,
            program,
            states,
        }
    }

    /// Whether it is program `p`'s recipe.
    pub fn is_program(&self, p: &str) -> bool {
        self.program.eq_ignore_ascii_case(p)
    }
}

/// The whole TUI state.
pub struct App {
    /// Who uses it, and as what.
    pub user: StationName,
    /// Its role.
    pub role: Role,
    /// The cell's stations (panes, overview boxes).
    pub topology: Topology,
    /// Its transport stations' equipment (what their inputs are), or why
    /// a file of it did not load.
    pub equipment: Result<BTreeMap<StationName, Arc<Equipment>>, String>,
    /// The layer shown.
    pub layer: Layer,
    /// The last status, if any.
    pub status: Option<CellStatus>,
    /// Why the operator node cannot be reached, if it cannot.
    pub unreachable: Option<String>,
    /// The order list.
    pub orders: Vec<Order>,
    /// One pane per station.
    pub panes: Vec<Pane>,
    /// The pane shown in F2.
    pub pane: usize,
    /// The answer being typed.
    pub answer: String,
    /// The F3 cursor.
    pub cursor: usize,
    /// The choice being made, if any.
    pub pick: Option<Pick>,
    /// The last outcome of a command, in words (ok, text).
    pub said: Option<(bool, String)>,
    /// The recipe list, when fetched.
    pub recipes: Vec<RecipeInfo>,
    /// The recipe the F4 view shows when its station runs nothing.
    pub viewed: Option<Viewed>,
    /// The station whose running recipe F4 shows.
    pub view_station: usize,
    /// The last message id seen.
    pub last_entry: i64,
    /// The F3 pickers' cursor.
    pub pick_cursor: usize,
    /// Whether these are one cell's screens of a plant (Esc goes back to
    /// the plant overview).
    pub in_plant: bool,
    /// The figures F5 shows, when fetched.
    pub figures: Option<falc_model::figures::Figures>,
    /// Whether the journal moved since the figures were fetched.
    figures_stale: bool,
    /// What the last call was (to route its answer).
    pending: Option<ApiRequest>,
    /// The station picked for a recipe edit or view.
    pending_station: Option<StationName>,
}

impl App {
    /// A new TUI state for `user` in `topology`.
    pub fn new(topology: Topology, user: StationName) -> Self {
        let role = topology
            .console(&user)
            .map(|c| c.role)
            .unwrap_or(Role::Observer);
        let panes = topology
            .stations()
            .iter()
            .filter(|s| s.kind != StationKind::Operator)
            .map(|s| Pane {
                station: Some(s.name.clone()),
                ..Pane::default()
            })
            .collect();
        Self {
            user,
            role,
            equipment: Equipment::of_topology(&topology),
            topology,
            layer: Layer::Overview,
            status: None,
            unreachable: None,
            orders: Vec::new(),
            panes,
            pane: 0,
            answer: String::new(),
            cursor: 0,
            pick: None,
            said: None,
            recipes: Vec::new(),
            viewed: None,
            view_station: 0,
            last_entry: 0,
            pick_cursor: 0,
            in_plant: false,
            figures: None,
            figures_stale: true,
            pending: None,
            pending_station: None,
        }
    }

    /// The last reading of transport station `t`'s inputs, if any; Err:
    /// its equipment file did not load, and why.
    pub fn inputs_of(&self, t: &StationName) -> Result<Option<Inputs>, String> {
        let equipment = match &self.equipment {
            Ok(e) => e
                .get(t)
                .ok_or_else(|| format!("{t} is not a transport station"))?,
            Err(why) => return Err(why.clone()),
        };
        Ok(self
            .status
            .as_ref()
            .and_then(|s| s.stations.iter().find(|v| &v.name == t))
            .and_then(|v| v.status.as_ref())
            .and_then(|s| Inputs::from_bits(equipment, &s.inputs)))
    }

    /// The named state transport station `t` says its equipment is in
    /// ([`falc_model::mms::vmd::VmdStatus::equipment_state`]).
    pub fn equipment_state_of(&self, t: &StationName) -> Option<&str> {
        self.status
            .as_ref()?
            .stations
            .iter()
            .find(|v| &v.name == t)?
            .status
            .as_ref()?
            .equipment_state
            .as_deref()
    }

    /// Whether any pane has unread messages (F2's label lights).
    pub fn unread(&self) -> bool {
        self.panes.iter().any(|p| p.unread > 0)
    }

    /// The stations below the operator (overview, F4), in topology order.
    pub fn stations(&self) -> Vec<StationName> {
        self.panes
            .iter()
            .filter_map(|p| p.station.clone())
            .collect()
    }

    /// The pane an entry belongs to: its station's, else (an answer by a
    /// console user, the operator's own alarms) the cell's.
    fn pane_of(&self, e: &Entry) -> usize {
        let by_name = self
            .panes
            .iter()
            .position(|p| p.station.as_ref().is_some_and(|s| s.as_str() == e.who));
        by_name.unwrap_or_else(|| self.cell_pane().unwrap_or(0))
    }

    /// New messages arrived.
    pub fn entries(&mut self, entries: Vec<Entry>) {
        for e in entries {
            self.last_entry = self.last_entry.max(e.id);
            let i = self.pane_of(&e);
            let shown = self.layer == Layer::Messages && self.pane == i;
            if let Some(p) = self.panes.get_mut(i) {
                if !shown {
                    p.unread += 1;
                }
                p.entries.push(e);
                let excess = p.entries.len().saturating_sub(500);
                p.entries.drain(..excess);
            }
        }
    }

    /// A fresh status (or why there is none).
    pub fn status(&mut self, status: Result<CellStatus, String>) {
        match status {
            Ok(s) => {
                if s.question.is_none() {
                    self.answer.clear();
                }
                self.status = Some(s);
                self.unreachable = None;
            }
            Err(e) => self.unreachable = Some(e),
        }
    }

    /// The order list.
    pub fn orders(&mut self, orders: Vec<Order>) {
        // The journal moved: what F5 shows is older than it.
        self.figures_stale = true;
        self.orders = orders;
    }

    /// The last order that ended, if any.
    pub fn last_ended(&self) -> Option<&Order> {
        self.orders
            .iter()
            .filter(|o| !matches!(o.state, OrderState::Queued | OrderState::Running))
            .max_by_key(|o| o.ended_ms.unwrap_or(0))
    }

    fn call(&mut self, r: ApiRequest) -> Option<Intent> {
        self.pending = Some(r.clone());
        Some(Intent::Call(r))
    }

    /// The answer to the last [`Intent::Call`].
    pub fn answered(&mut self, result: Result<ApiReply, String>) {
        let request = self.pending.take();
        match (request, result) {
            (Some(ApiRequest::RecipeList), Ok(ApiReply::Recipes(list))) => {
                self.recipes = list;
                self.pick = match self.pick.take() {
                    Some(Pick::OrderRecipe(_)) => Some(Pick::OrderRecipe(
                        self.recipes
                            .iter()
                            .filter(|r| r.file.station().as_str() == "cell")
                            .filter_map(|r| r.name.as_ref().map(|n| n.to_lowercase()))
                            .collect(),
                    )),
                    Some(Pick::Recipe(_, cmd)) => Some(Pick::Recipe(Vec::new(), cmd)),
                    other => other,
                };
                self.fill_recipe_pick();
            }
            (Some(ApiRequest::OrderList), Ok(ApiReply::Orders(v))) => {
                if let Some(Pick::Order(_)) = self.pick {
                    self.pick = Some(Pick::Order(
                        v.iter()
                            .filter(|o| o.state == OrderState::Queued)
                            .cloned()
                            .collect(),
                    ));
                }
                self.orders = v;
            }
            (Some(ApiRequest::Figures(_)), Ok(ApiReply::Figures(f))) => {
                self.figures = Some(*f);
                self.figures_stale = false;
            }
            (Some(ApiRequest::RecipeGet { .. }), Ok(ApiReply::Recipe(r))) => {
                self.viewed = Some(Viewed::of(r));
                self.layer = Layer::Recipe;
            }
            (_, Ok(ApiReply::Done(text))) => self.said = Some((true, text)),
            (_, Ok(ApiReply::Order(o))) => {
                self.said = Some((true, format!("added order {} ({})", o.id, o.recipe)))
            }
            (_, Ok(_)) => {}
            (_, Err(why)) => {
                self.pick = None;
                self.said = Some((false, why));
            }
        }
    }

    /// The recipe picker's items once the list is known.
    fn fill_recipe_pick(&mut self) {
        let Some(Pick::Recipe(items, cmd)) = &mut self.pick else {
            return;
        };
        let Some(station) = self.pending_station.clone() else {
            return;
        };
        *items = self
            .recipes
            .iter()
            .filter(|r| r.file.station() == &station)
            .map(|r| r.file.clone())
            .collect();
        if *cmd == Command::Edit {
            if let Ok(new) = RecipeFile::new(station, "new") {
                items.insert(0, new);
            }
        }
    }
}

impl App {
    /// A key: what to do, if anything.
    pub fn key(&mut self, k: KeyEvent) -> Option<Intent> {
        if k.modifiers.contains(KeyModifiers::CONTROL) && k.code == KeyCode::Char('c') {
            return Some(Intent::Quit);
        }
        match k.code {
            KeyCode::F(1) => return self.show(Layer::Overview),
            KeyCode::F(2) => return self.show(Layer::Messages),
            KeyCode::F(3) => return self.show(Layer::Commands),
            KeyCode::F(4) => return self.show(Layer::Recipe),
            KeyCode::F(5) => return self.show(Layer::Figures),
            _ => {}
        }
        if self.pick.is_some() {
            return self.pick_key(k);
        }
        let typing = self.layer == Layer::Messages && self.question_here();
        if typing {
            match k.code {
                KeyCode::Char(c) => {
                    self.answer.push(c);
                    return None;
                }
                KeyCode::Backspace => {
                    self.answer.pop();
                    return None;
                }
                KeyCode::Enter if !self.answer.trim().is_empty() => {
                    let text = std::mem::take(&mut self.answer).trim().to_string();
                    return self.call(ApiRequest::Answer { text });
                }
                _ => {}
            }
        }
        match (self.layer, k.code) {
            (_, KeyCode::Char('q')) => Some(Intent::Quit),
            (_, KeyCode::Esc) if self.in_plant => Some(Intent::Back),
            (_, KeyCode::Char(c @ '1'..='5')) => self.show(match c {
                '1' => Layer::Overview,
                '2' => Layer::Messages,
                '3' => Layer::Commands,
                '4' => Layer::Recipe,
                _ => Layer::Figures,
            }),
            (Layer::Messages, KeyCode::Left) => {
                self.pane = (self.pane + self.panes.len().max(1) - 1) % self.panes.len().max(1);
                self.mark_read();
                None
            }
            (Layer::Messages, KeyCode::Right) => {
                self.pane = (self.pane + 1) % self.panes.len().max(1);
                self.mark_read();
                None
            }
            (Layer::Recipe, KeyCode::Left) => {
                let n = self.panes.len().max(1);
                self.view_station = (self.view_station + n - 1) % n;
                None
            }
            (Layer::Overview, KeyCode::Enter) if !self.held_steps().is_empty() => {
                // The cell's step first, else the first workstation's.
                let station = self
                    .held_steps()
                    .first()
                    .and_then(|(name, cell, _)| (!cell).then(|| (*name).clone()));
                self.call(ApiRequest::Step { station, to: None })
            }
            (Layer::Recipe, KeyCode::Right) => {
                self.view_station = (self.view_station + 1) % self.panes.len().max(1);
                None
            }
            (Layer::Commands, KeyCode::Up) => {
                self.cursor = self.cursor.saturating_sub(1);
                None
            }
            (Layer::Commands, KeyCode::Down) => {
                self.cursor = (self.cursor + 1).min(Command::ALL.len() - 1);
                None
            }
            (Layer::Commands, KeyCode::Enter) => {
                let c = Command::ALL[self.cursor.min(Command::ALL.len() - 1)];
                self.command(c)
            }
            (Layer::Commands, KeyCode::Char(ch)) => {
                let c = Command::ALL.into_iter().find(|c| c.label().0 == ch)?;
                self.cursor = Command::ALL.iter().position(|x| *x == c).unwrap_or(0);
                self.command(c)
            }
            _ => None,
        }
    }

    /// The figures F5 should show and does not have yet, or that are
    /// older than the journal: those of the week up to `now_ms`.
    pub fn wanted_figures(&self, now_ms: i64) -> Option<ApiRequest> {
        (self.layer == Layer::Figures && (self.figures.is_none() || self.figures_stale)).then(
            || {
                ApiRequest::Figures(falc_model::figures::FigureQuery {
                    since_ms: now_ms - FIGURES_RANGE_MS,
                    until_ms: None,
                    planned: Vec::new(),
                })
            },
        )
    }

    /// The recipe F4 should show and does not have yet: the one the
    /// chosen station runs.
    pub fn wanted_recipe(&self) -> Option<ApiRequest> {
        if self.layer != Layer::Recipe {
            return None;
        }
        let station = self.panes.get(self.view_station)?.station.as_ref()?;
        let program = self.running_program(station)?;
        let info = self.recipes.iter().find(|r| {
            r.file.station() == station
                && r.name
                    .as_deref()
                    .is_some_and(|n| n.eq_ignore_ascii_case(program.0.as_str()))
        })?;
        if self.viewed.as_ref().map(|v| &v.recipe.file) == Some(&info.file) {
            return None;
        }
        Some(ApiRequest::RecipeGet {
            file: info.file.clone(),
        })
    }

    /// The cell's mode, once the operator answered.
    pub fn cell_mode(&self) -> Option<CellMode> {
        self.status.as_ref().map(|s| s.mode)
    }

    /// The steps that wait for confirmation (step mode), the cell's first:
    /// the station, whether it is the cell, the step.
    pub fn held_steps(&self) -> Vec<(&StationName, bool, &HeldStep)> {
        let Some(s) = &self.status else {
            return Vec::new();
        };
        let mut held: Vec<_> = s
            .stations
            .iter()
            .filter_map(|v| {
                let h = v.status.as_ref()?.held.as_ref()?;
                Some((&v.name, self.is_cell(&v.name), h))
            })
            .collect();
        held.sort_by_key(|(_, cell, _)| !cell);
        held
    }

    /// The program a station runs and its recipe state.
    pub fn running_program(&self, station: &StationName) -> Option<(String, u16)> {
        let s = self.status.as_ref()?;
        let v = s.stations.iter().find(|v| &v.name == station)?;
        let p = v.status.as_ref()?.program.as_ref()?;
        Some((p.name.to_string(), p.state))
    }

    /// Makes a call the driver asks for on the app's behalf (its answer
    /// goes to [`App::answered`]).
    pub fn request(&mut self, r: ApiRequest) -> Intent {
        self.pending = Some(r.clone());
        Intent::Call(r)
    }

    /// Whether the shown pane holds the waiting question.
    pub fn question_here(&self) -> bool {
        self.status.as_ref().is_some_and(|s| s.question.is_some())
            && self.cell_pane() == Some(self.pane)
    }

    /// Whether `name` is the cell (not a workstation).
    pub fn is_cell(&self, name: &StationName) -> bool {
        self.topology
            .station(name)
            .is_some_and(|st| st.kind == StationKind::Cell)
    }

    /// The cell's message pane.
    fn cell_pane(&self) -> Option<usize> {
        self.panes
            .iter()
            .position(|p| p.station.as_ref().is_some_and(|s| self.is_cell(s)))
    }

    fn show(&mut self, layer: Layer) -> Option<Intent> {
        self.layer = layer;
        self.pick = None;
        if layer == Layer::Messages {
            // Open on the question if one waits, else where unread is.
            if self.status.as_ref().is_some_and(|s| s.question.is_some()) {
                if let Some(i) = self.cell_pane() {
                    self.pane = i;
                }
            } else if self.panes.get(self.pane).is_some_and(|p| p.unread == 0) {
                if let Some(i) = self.panes.iter().position(|p| p.unread > 0) {
                    self.pane = i;
                }
            }
            self.mark_read();
        }
        None
    }

    fn mark_read(&mut self) {
        if let Some(p) = self.panes.get_mut(self.pane) {
            p.unread = 0;
        }
    }

    fn command(&mut self, c: Command) -> Option<Intent> {
        self.said = None;
        self.pick_cursor = 0;
        match c {
            Command::Order => {
                self.pick = Some(Pick::OrderRecipe(Vec::new()));
                self.call(ApiRequest::RecipeList)
            }
            Command::Remove => {
                self.pick = Some(Pick::Order(Vec::new()));
                self.call(ApiRequest::OrderList)
            }
            Command::Start => self.call(ApiRequest::Start),
            Command::Stop => self.call(ApiRequest::Stop),
            Command::Ack => self.call(ApiRequest::Ack { id: None }),
            Command::Shutdown => {
                self.pick = Some(Pick::ConfirmShutdown);
                None
            }
            Command::Edit | Command::View => {
                self.pick = Some(Pick::Station(self.stations(), c));
                None
            }
            Command::Mode => {
                self.pick = Some(Pick::Mode(CellMode::ALL.to_vec()));
                None
            }
            Command::Step => self.call(ApiRequest::Step {
                station: None,
                to: None,
            }),
            Command::Home => {
                let below: Vec<StationName> = self
                    .stations()
                    .into_iter()
                    .filter(|s| !self.is_cell(s))
                    .collect();
                self.pick = Some(Pick::Home(below));
                None
            }
        }
    }

    fn pick_key(&mut self, k: KeyEvent) -> Option<Intent> {
        let pick = self.pick.clone()?;
        if pick == Pick::EditAgain {
            return match k.code {
                KeyCode::Char('e') => {
                    self.pick = None;
                    Some(Intent::EditAgain)
                }
                KeyCode::Esc => {
                    self.pick = None;
                    Some(Intent::Discard)
                }
                _ => None,
            };
        }
        if k.code == KeyCode::Esc {
            self.pick = None;
            return None;
        }
        if let Pick::NewName(station, mut name) = pick {
            match k.code {
                KeyCode::Char(c) => name.push(c),
                KeyCode::Backspace => {
                    name.pop();
                }
                KeyCode::Enter => {
                    self.pick = None;
                    return match RecipeFile::new(station, &name) {
                        Ok(f) => Some(Intent::Edit(f)),
                        Err(e) => {
                            self.said = Some((false, e));
                            None
                        }
                    };
                }
                _ => {}
            }
            self.pick = Some(Pick::NewName(station, name));
            return None;
        }
        if pick == Pick::ConfirmShutdown {
            self.pick = None;
            return match k.code {
                KeyCode::Char('y') | KeyCode::Char('j') => self.call(ApiRequest::Shutdown),
                _ => {
                    self.said = Some((true, "not shut down".into()));
                    None
                }
            };
        }
        let len = match &pick {
            Pick::OrderRecipe(v) => v.len(),
            Pick::Order(v) => v.len(),
            Pick::Station(v, _) => v.len(),
            Pick::Recipe(v, _) => v.len(),
            Pick::Mode(v) => v.len(),
            Pick::Home(v) => v.len(),
            _ => 0,
        };
        match k.code {
            KeyCode::Up => {
                self.pick_cursor = self.pick_cursor.saturating_sub(1);
                None
            }
            KeyCode::Down => {
                self.pick_cursor = (self.pick_cursor + 1).min(len.saturating_sub(1));
                None
            }
            KeyCode::Enter if len > 0 => {
                let i = self.pick_cursor.min(len - 1);
                self.pick_cursor = 0;
                self.pick = None;
                match pick {
                    Pick::OrderRecipe(v) => self.call(ApiRequest::order_add(&v[i])),
                    Pick::Order(v) => self.call(ApiRequest::OrderRemove { id: v[i].id }),
                    Pick::Station(v, cmd) => {
                        self.pending_station = Some(v[i].clone());
                        self.pick = Some(Pick::Recipe(Vec::new(), cmd));
                        self.call(ApiRequest::RecipeList)
                    }
                    Pick::Recipe(v, Command::Edit) if i == 0 => {
                        self.pick = Some(Pick::NewName(v[0].station().clone(), String::new()));
                        None
                    }
                    Pick::Recipe(v, Command::Edit) => Some(Intent::Edit(v[i].clone())),
                    Pick::Recipe(v, _) => self.call(ApiRequest::RecipeGet { file: v[i].clone() }),
                    Pick::Mode(v) => self.call(ApiRequest::Mode {
                        mode: v[i],
                        stations: Vec::new(),
                    }),
                    Pick::Home(v) => self.call(ApiRequest::Manual {
                        station: v[i].clone(),
                        action: ManualAction::RunRecipe("home".into()),
                    }),
                    _ => None,
                }
            }
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_model::api::ListState;

    fn app() -> App {
        let t = Topology::load(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("launch/cell.toml"),
        )
        .expect("shipped topology");
        App::new(t, StationName::new("console").expect("valid"))
    }

    #[test]
    fn a_viewed_recipe_is_read_once_its_program_and_the_state_of_each_line() {
        let text = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("recipes/welding/droog_dik.rcp"),
        )
        .expect("shipped recipe");
        let welding = StationName::new("welding").expect("valid");
        let v = Viewed::of(RecipeText {
            file: RecipeFile::new(welding.clone(), "droog_dik.rcp").expect("valid"),
            text: text.clone(),
            hash: 0,
        });
        assert!(v.is_program("droog_dik"), "{}", v.program);
        assert_eq!(v.states.len(), text.lines().count());
        let line = |prefix: &str| {
            let at = text.lines().position(|l| l.starts_with(prefix));
            v.states[at.expect("in the recipe")]
        };
        assert_eq!(line("#DROOG_DIK"), None);
        assert_eq!(line("-1 |"), Some(1));
        assert_eq!(line("-3 |"), Some(3));
        // No name line: the file's name is the program's.
        let v = Viewed::of(RecipeText {
            file: RecipeFile::new(welding, "home.rcp").expect("valid"),
            text: "-1 | | | | 0".into(),
            hash: 0,
        });
        assert!(v.is_program("HOME"));
        assert_eq!(v.states, vec![Some(1)]);
    }

    fn key(c: KeyCode) -> KeyEvent {
        KeyEvent::new(c, KeyModifiers::NONE)
    }

    fn entry(id: i64, kind: EntryKind, who: &str) -> Entry {
        Entry {
            id,
            at_ms: 0,
            order: Some(1),
            kind,
            who: who.into(),
            text: format!("entry {id}"),
            cell: None,
        }
    }

    fn status(question: Option<&str>) -> CellStatus {
        CellStatus {
            list: ListState::Running,
            cell_associated: true,
            question: question.map(String::from),
            ..CellStatus::default()
        }
    }

    use falc_model::records::EntryKind;

    #[test]
    fn enter_on_the_overview_carries_out_the_cells_step_first_then_a_workstations() {
        use falc_model::api::StationView;
        use falc_model::mms::vmd::VmdStatus;
        let view = |name: &str, state: Option<u16>| StationView {
            name: StationName::new(name).expect("valid"),
            status: Some(VmdStatus {
                mode: CellMode::Step,
                held: state.map(|state| HeldStep {
                    state,
                    command: "activate k".into(),
                }),
                ..VmdStatus::default()
            }),
            connected: true,
        };
        let mut a = app();
        assert_eq!(a.key(key(KeyCode::Enter)), None, "nothing waits");
        let mut s = status(None);
        s.mode = CellMode::Step;
        s.stations = vec![view("transport", Some(1)), view("cell", Some(9))];
        a.status(Ok(s.clone()));
        assert_eq!(a.cell_mode(), Some(CellMode::Step));
        assert_eq!(
            a.key(key(KeyCode::Enter)),
            Some(Intent::Call(ApiRequest::Step {
                station: None,
                to: None
            }))
        );
        s.stations = vec![view("transport", Some(1)), view("cell", None)];
        a.status(Ok(s));
        assert_eq!(
            a.key(key(KeyCode::Enter)),
            Some(Intent::Call(ApiRequest::Step {
                station: Some(StationName::new("transport").expect("valid")),
                to: None
            }))
        );
    }

    #[test]
    fn messages_go_to_their_station_pane_and_count_as_unread_until_shown() {
        let mut a = app();
        let names: Vec<String> = a.stations().iter().map(|s| s.to_string()).collect();
        assert_eq!(
            names,
            ["cell", "welding", "transport"],
            "one pane per station"
        );
        a.entries(vec![
            entry(1, EntryKind::Message, "cell"),
            entry(2, EntryKind::Report, "transport"),
            entry(3, EntryKind::Answer, "console"),
        ]);
        assert_eq!(a.last_entry, 3);
        assert_eq!(
            a.panes[0].unread, 2,
            "the answer belongs with the cell's question"
        );
        assert_eq!(a.panes[2].unread, 1);
        assert!(a.unread());
        a.key(key(KeyCode::F(2)));
        assert_eq!(a.panes[0].unread, 0);
        a.key(key(KeyCode::Right));
        a.key(key(KeyCode::Right));
        assert!(!a.unread());
    }

    #[test]
    fn a_question_is_answered_in_the_cell_pane() {
        let mut a = app();
        a.status(Ok(status(Some("staat blok 1 goed?\n(ja/nee)"))));
        a.key(key(KeyCode::F(2)));
        assert!(a.question_here());
        assert_eq!(a.key(key(KeyCode::Char('j'))), None);
        assert_eq!(a.key(key(KeyCode::Char('a'))), None);
        assert_eq!(
            a.key(key(KeyCode::Enter)),
            Some(Intent::Call(ApiRequest::Answer { text: "ja".into() }))
        );
        a.answered(Ok(ApiReply::Done("answered ja".into())));
        assert_eq!(a.said, Some((true, "answered ja".into())));
    }

    #[test]
    fn commands_pick_then_call_and_refusals_are_shown() {
        let mut a = app();
        a.key(key(KeyCode::F(3)));
        assert_eq!(
            a.key(key(KeyCode::Char('o'))),
            Some(Intent::Call(ApiRequest::RecipeList))
        );
        let w = |s: &str, f: &str, n: &str| RecipeInfo {
            file: RecipeFile::new(StationName::new(s).expect("v"), f).expect("v"),
            name: Some(n.into()),
        };
        a.answered(Ok(ApiReply::Recipes(vec![
            w("cell", "dikdroog", "DIKDROOG"),
            w("cell", "dundroog", "DUNDROOG"),
            w("welding", "droog_dik", "DROOG_DIK"),
        ])));
        assert_eq!(
            a.pick,
            Some(Pick::OrderRecipe(vec![
                "dikdroog".into(),
                "dundroog".into()
            ]))
        );
        a.key(key(KeyCode::Down));
        assert_eq!(
            a.key(key(KeyCode::Enter)),
            Some(Intent::Call(ApiRequest::order_add("dundroog")))
        );
        a.answered(Err(
            "no reply (refused by the router's access control)".into()
        ));
        assert_eq!(a.said.as_ref().map(|s| s.0), Some(false));
        // Shut down asks first.
        assert_eq!(a.key(key(KeyCode::Char('d'))), None);
        assert_eq!(
            a.key(key(KeyCode::Char('y'))),
            Some(Intent::Call(ApiRequest::Shutdown))
        );
        // Editing: station, then recipe or new, then a name.
        a.key(key(KeyCode::Char('e')));
        assert_eq!(a.key(key(KeyCode::Down)), None, "the station picker moves");
        assert_eq!(
            a.key(key(KeyCode::Enter)),
            Some(Intent::Call(ApiRequest::RecipeList))
        );
        a.answered(Ok(ApiReply::Recipes(vec![w(
            "welding",
            "droog_dik",
            "DROOG_DIK",
        )])));
        let Some(Pick::Recipe(items, Command::Edit)) = &a.pick else {
            panic!("{:?}", a.pick)
        };
        assert_eq!(items.len(), 2, "new, and the one recipe of welding");
        a.key(key(KeyCode::Down));
        assert_eq!(
            a.key(key(KeyCode::Enter)),
            Some(Intent::Edit(
                RecipeFile::new(StationName::new("welding").expect("v"), "droog_dik").expect("v")
            ))
        );
    }
}
