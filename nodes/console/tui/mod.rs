//! `falc tui`: the operator's screens (docs/the-1992-cell.md §6): F1 overview, F2
//! messages per station, F3 commands, F4 a recipe's state table; in a
//! plant first the plant overview, a line per cell, whose Enter opens one
//! cell's screens (Esc comes back). This is the driver: it owns the
//! terminal and the bus, polls the operator API (the status every 250 ms;
//! new messages and the order list when the status says the journal
//! moved), feeds keys and answers to the sans-I/O [`app::App`] (a cell)
//! and [`plant::PlantApp`] (the plant) and draws them with [`view`].
//! Keyboard only, plain ANSI: works over SSH and in tmux.

mod app;
mod plant;
mod view;

use crate::edit::Session;
use app::{App, Intent, Pick};
use falc_bus::Bus;
use falc_model::api::{ApiReply, ApiRequest};
use falc_model::ids::StationName;
use falc_model::plant::Plant;
use falc_model::topology::Topology;
use plant::{PlantApp, PlantIntent};
use ratatui::crossterm::event::{self, Event, KeyEvent, KeyEventKind};
use ratatui::DefaultTerminal;
use std::process::ExitCode;
use std::time::{Duration, Instant};

/// How often the status and new messages are asked for.
const POLL: Duration = Duration::from_millis(250);
/// How long one call from the TUI may take (it is not drawn meanwhile).
const CALL_LIMIT: Duration = Duration::from_secs(5);

/// What the screens show: one cell (a cell of its own, or the cell of a
/// plant `--cell` names), or a plant (its overview first).
pub enum Screens {
    /// This cell's screens.
    Cell(Topology),
    /// The plant overview, each cell's screens from there.
    Plant(Plant),
}

/// How a cell's screens were left.
enum Exit {
    Quit,
    Back,
}

/// Runs the TUI until `q`, Ctrl-C, SIGINT or SIGTERM.
pub async fn run(
    bus: &Bus,
    operator: &StationName,
    screens: Screens,
    user: StationName,
) -> ExitCode {
    let mut terminal = match ratatui::try_init() {
        Ok(t) => t,
        Err(e) => {
            eprintln!("falc: the TUI needs a terminal: {e}");
            return ExitCode::from(2);
        }
    };
    let outcome = match screens {
        Screens::Cell(topology) => {
            let mut tui = Tui::new(bus.clone(), operator, App::new(topology, user));
            tui.main_loop(&mut terminal).await.map(|_| ())
        }
        Screens::Plant(p) => plant_loop(bus, operator, &p, user, &mut terminal).await,
    };
    ratatui::restore();
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("falc: {e}");
            ExitCode::FAILURE
        }
    }
}

/// The plant overview until `q`; Enter runs the chosen cell's screens
/// until they are left with Esc (back here) or `q`.
async fn plant_loop(
    bus: &Bus,
    operator: &StationName,
    plant: &Plant,
    user: StationName,
    terminal: &mut DefaultTerminal,
) -> Result<(), String> {
    let mut shutdown = falc_node::Shutdown::new();
    let mut app = PlantApp::new(plant, user.clone());
    let mut next_poll = Instant::now();
    let mut dirty = true;
    loop {
        if dirty {
            terminal
                .draw(|f| view::draw_plant(f, &app))
                .map_err(|e| format!("cannot draw: {e}"))?;
            dirty = false;
        }
        while let Some(ev) = next_event()? {
            dirty = true;
            let Some(k) = ev else { continue };
            match app.key(k) {
                Some(PlantIntent::Quit) => return Ok(()),
                Some(PlantIntent::Open(cell)) => {
                    let Some(c) = plant.cell(&cell) else { continue };
                    let mut screens = App::new(c.topology().clone(), user.clone());
                    screens.in_plant = true;
                    let for_cell = bus.clone().for_cell(Some(cell));
                    let mut tui = Tui::new(for_cell, operator, screens);
                    match tui.main_loop(terminal).await? {
                        Exit::Quit => return Ok(()),
                        Exit::Back => terminal.clear().map_err(|e| format!("terminal: {e}"))?,
                    }
                    next_poll = Instant::now();
                }
                None => {}
            }
        }
        if Instant::now() >= next_poll {
            dirty = true;
            next_poll = Instant::now() + POLL;
            let status = bus
                .api(operator, ApiRequest::Status, CALL_LIMIT)
                .await
                .map_err(|e| e.to_string());
            app.status(status);
        }
        tokio::select! {
            _ = tokio::time::sleep(Duration::from_millis(25)) => {}
            _ = shutdown.requested() => return Ok(()),
        }
    }
}

/// The next terminal event waiting, if any: `Some(Some(key))` for a key
/// pressed, `Some(None)` for anything else (a resize: redraw).
fn next_event() -> Result<Option<Option<KeyEvent>>, String> {
    if !event::poll(Duration::ZERO).map_err(|e| format!("terminal: {e}"))? {
        return Ok(None);
    }
    match event::read().map_err(|e| format!("terminal: {e}"))? {
        Event::Key(k) if k.kind == KeyEventKind::Press => Ok(Some(Some(k))),
        _ => Ok(Some(None)),
    }
}

struct Tui<'a> {
    /// The bus (for a cell of a plant, one whose every call names it).
    bus: Bus,
    operator: &'a StationName,
    app: App,
    /// A recipe edit whose text the checker refused (kept to edit again).
    session: Option<Session>,
    /// The journal head when messages and orders were last fetched.
    seen_head: Option<i64>,
}

impl<'a> Tui<'a> {
    fn new(bus: Bus, operator: &'a StationName, app: App) -> Self {
        Self {
            bus,
            operator,
            app,
            session: None,
            seen_head: None,
        }
    }

    async fn call(&self, r: ApiRequest) -> Result<ApiReply, String> {
        self.bus
            .api(self.operator, r, CALL_LIMIT)
            .await
            .map_err(|e| e.to_string())
    }

    async fn main_loop(&mut self, terminal: &mut DefaultTerminal) -> Result<Exit, String> {
        let mut shutdown = falc_node::Shutdown::new();
        let mut next_poll = Instant::now();
        let intent = self.app.request(ApiRequest::RecipeList);
        self.carry_out(intent, terminal).await?;
        // Drawn when something changed: a key, an answer, a poll, a resize.
        let mut dirty = true;
        loop {
            if dirty {
                terminal
                    .draw(|f| view::draw(f, &self.app))
                    .map_err(|e| format!("cannot draw: {e}"))?;
                dirty = false;
            }
            while let Some(ev) = next_event()? {
                dirty = true;
                let Some(k) = ev else { continue };
                match self.app.key(k) {
                    Some(Intent::Quit) => return Ok(Exit::Quit),
                    Some(Intent::Back) => return Ok(Exit::Back),
                    Some(i) => {
                        self.carry_out(i, terminal).await?;
                        terminal
                            .draw(|f| view::draw(f, &self.app))
                            .map_err(|e| format!("cannot draw: {e}"))?;
                    }
                    None => {}
                }
            }
            if Instant::now() >= next_poll {
                dirty = true;
                next_poll = Instant::now() + POLL;
                self.poll().await;
                if let Some(r) = self.app.wanted_recipe() {
                    let intent = self.app.request(r);
                    self.carry_out(intent, terminal).await?;
                }
                if let Some(r) = self.app.wanted_figures(crate::clock::now_ms()) {
                    let intent = self.app.request(r);
                    self.carry_out(intent, terminal).await?;
                }
            }
            tokio::select! {
                _ = tokio::time::sleep(Duration::from_millis(25)) => {}
                _ = shutdown.requested() => return Ok(Exit::Quit),
            }
        }
    }

    /// The status; new messages and the order list only when the journal
    /// moved (every order change and message is journalled).
    async fn poll(&mut self) {
        let status = match self.call(ApiRequest::Status).await {
            Ok(ApiReply::Status(s)) => Ok(s),
            Ok(other) => Err(format!("unexpected answer to status: {other:?}")),
            Err(e) => Err(e),
        };
        let head = status.as_ref().map(|s| s.journal_head).ok();
        self.app.status(status);
        if head.is_none() || head == self.seen_head {
            return;
        }
        // Every page of new messages (the operator answers a page a time).
        loop {
            let after = self.app.last_entry;
            match self.call(ApiRequest::Messages { after, last: None }).await {
                Ok(ApiReply::Entries(v)) if v.is_empty() => break,
                Ok(ApiReply::Entries(v)) => self.app.entries(v),
                // Asked again at the next poll.
                _ => return,
            }
        }
        if let Ok(ApiReply::Orders(o)) = self.call(ApiRequest::OrderList).await {
            self.app.orders(o);
            self.seen_head = head;
        }
    }

    async fn carry_out(
        &mut self,
        intent: Intent,
        terminal: &mut DefaultTerminal,
    ) -> Result<(), String> {
        match intent {
            Intent::Quit | Intent::Back => {}
            Intent::Call(r) => {
                let answer = self.call(r).await;
                self.app.answered(answer);
            }
            Intent::Edit(file) => {
                if let Some(old) = self.session.take() {
                    old.discard();
                }
                match Session::open(&self.bus, self.operator, &file).await {
                    Ok(s) => self.edit(s, terminal).await?,
                    Err(e) => self.app.said = Some((false, e.to_string())),
                }
            }
            Intent::EditAgain => {
                if let Some(s) = self.session.take() {
                    self.edit(s, terminal).await?;
                }
            }
            Intent::Discard => {
                if let Some(s) = self.session.take() {
                    self.app.said =
                        Some((true, format!("{}: edit discarded, nothing saved", s.file)));
                    s.discard();
                }
            }
        }
        Ok(())
    }

    /// Hands the terminal to the editor, then saves what was written.
    async fn edit(
        &mut self,
        session: Session,
        terminal: &mut DefaultTerminal,
    ) -> Result<(), String> {
        ratatui::restore();
        let edited = session.run_editor();
        *terminal =
            ratatui::try_init().map_err(|e| format!("cannot take the terminal back: {e}"))?;
        terminal.clear().map_err(|e| format!("terminal: {e}"))?;
        if let Err(e) = edited {
            self.app.said = Some((
                false,
                format!("{e}; your text is in {}", session.copy.display()),
            ));
            return Ok(());
        }
        match session.edited() {
            Err(e) => self.app.said = Some((false, e)),
            Ok(None) => {
                self.app.said = Some((
                    true,
                    format!("{}: nothing changed, nothing saved", session.file),
                ));
                session.discard();
            }
            Ok(Some(text)) => match session.save(&self.bus, self.operator, text).await {
                Ok(said) => {
                    self.app.said = Some((true, said));
                    // The new list (a new recipe appears in the pickers).
                    let _ = self.app.request(ApiRequest::RecipeList);
                    let answer = self.call(ApiRequest::RecipeList).await;
                    self.app.answered(answer);
                }
                Err(why) => {
                    self.app.said = Some((false, format!("{why}\ne: edit again · Esc: discard")));
                    self.app.pick = Some(Pick::EditAgain);
                    self.session = Some(session);
                }
            },
        }
        Ok(())
    }
}
