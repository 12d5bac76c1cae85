//! Drawing the TUI: the top line (running order and recipe state), the
//! layer bar, the layer itself, and the bottom line with the last outcome
//! and the alarm lamp. Colours keep the 1992 meanings: normal black on
//! white, active white on black, idle light blue, busy dark blue, alarm
//! bright white on red.

use super::app::{App, Command, Layer, Pick};
use super::plant::PlantApp;
use crate::clock::time_of_day;
use falc_model::api::CellStatus;
use falc_model::ids::{printable, PlcStation};
use falc_model::mms::vmd::{PhysicalStatus, RecipeState, NO_NAMED_STATE};
use falc_model::topology::StationKind;
use falc_plc::map::Input;
use falc_recipe::check::Signal;
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::style::{Color, Modifier, Style};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Borders, Paragraph, Wrap};
use ratatui::Frame;

const NORMAL: Style = Style::new().fg(Color::Black).bg(Color::White);
const ACTIVE: Style = Style::new().fg(Color::White).bg(Color::Black);
const IDLE: Style = Style::new().fg(Color::LightBlue).bg(Color::White);
const BUSY: Style = Style::new()
    .fg(Color::Blue)
    .bg(Color::White)
    .add_modifier(Modifier::BOLD);
const ALARM: Style = Style::new()
    .fg(Color::White)
    .bg(Color::Red)
    .add_modifier(Modifier::BOLD);
const DIM: Style = Style::new().fg(Color::DarkGray).bg(Color::White);

/// How a station looks in the overview.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Look {
    /// No recipe runs.
    Idle,
    /// A recipe runs.
    Busy,
    /// In alarm, or its device is inoperable.
    Alarm,
    /// Not on the bus, or no status seen yet.
    Off,
}

impl Look {
    fn style(self) -> Style {
        match self {
            Self::Idle => IDLE,
            Self::Busy => BUSY,
            Self::Alarm => ALARM,
            Self::Off => DIM,
        }
    }

    fn word(self) -> &'static str {
        match self {
            Self::Idle => "IDLE",
            Self::Busy => "BUSY",
            Self::Alarm => "ALARM",
            Self::Off => "NO CONNECTION",
        }
    }

    /// The word in a plant overview's line (where space is short).
    fn short(self) -> &'static str {
        match self {
            Self::Off => "OFF",
            other => other.word(),
        }
    }
}

/// Station `name`'s recipe state as the operator shows it, while it is
/// on the bus.
fn recipe_state(app: &App, name: &falc_model::ids::StationName) -> Option<RecipeState> {
    app.status
        .as_ref()?
        .stations
        .iter()
        .find(|v| &v.name == name && v.connected)
        .and_then(|v| v.status.as_ref())
        .map(|v| v.local_detail)
}

/// How station `i` (of [`App::stations`]) looks.
pub fn look(app: &App, name: &falc_model::ids::StationName) -> Look {
    match &app.status {
        Some(s) => look_in(s, name, app.is_cell(name)),
        None => Look::Off,
    }
}

/// How station `name` looks in a cell's status `s` (`is_cell`: it is the
/// cell controller, which shows the list's alarm).
fn look_in(s: &CellStatus, name: &falc_model::ids::StationName, is_cell: bool) -> Look {
    if is_cell && s.alarm.is_some() {
        return Look::Alarm;
    }
    if s.alarms
        .iter()
        .any(|a| a.station == *name && a.blocks_start())
    {
        return Look::Alarm;
    }
    let Some(v) = s
        .stations
        .iter()
        .find(|v| &v.name == name && v.connected)
        .and_then(|v| v.status.as_ref())
    else {
        return Look::Off;
    };
    if v.physical == PhysicalStatus::Inoperable || v.local_detail == RecipeState::Error {
        Look::Alarm
    } else if matches!(
        v.local_detail,
        RecipeState::Executing | RecipeState::WaitAck | RecipeState::Pending
    ) {
        Look::Busy
    } else {
        Look::Idle
    }
}

/// Draws the whole screen.
pub fn draw(f: &mut Frame, app: &App) {
    let area = f.area();
    f.render_widget(Block::new().style(NORMAL), area);
    let [top, bar, main, bottom] = Layout::vertical([
        Constraint::Length(1),
        Constraint::Length(1),
        Constraint::Min(5),
        Constraint::Length(1),
    ])
    .areas(area);
    f.render_widget(Paragraph::new(top_line(app)).style(ACTIVE), top);
    f.render_widget(Paragraph::new(layer_bar(app)), bar);
    match app.layer {
        Layer::Overview => overview(f, app, main),
        Layer::Messages => messages(f, app, main),
        Layer::Commands => commands(f, app, main),
        Layer::Recipe => recipe(f, app, main),
        Layer::Figures => figures(f, app, main),
    }
    bottom_line(f, app, bottom);
}

/// Draws the plant overview: a line per cell, the chosen one marked.
pub fn draw_plant(f: &mut Frame, app: &PlantApp) {
    let area = f.area();
    f.render_widget(Block::new().style(NORMAL), area);
    let [top, bar, main, bottom] = Layout::vertical([
        Constraint::Length(1),
        Constraint::Length(1),
        Constraint::Min(3),
        Constraint::Length(1),
    ])
    .areas(area);
    let top_text = format!(
        " FALC plant {} │ {} cells │ {} ({:?})",
        app.plant,
        app.cells.len(),
        app.user,
        app.role
    );
    f.render_widget(Paragraph::new(top_text).style(ACTIVE), top);
    f.render_widget(
        Paragraph::new(" ↑↓ choose a cell · Enter its screens (Esc back here) · q quit").style(DIM),
        bar,
    );
    let mut lines = vec![Line::styled(
        format!(
            "   {:<8}{:<12}{:<8}{:<19}{:<22}stations (OFF: no status)",
            "cell", "mode", "list", "running order", "alarm"
        ),
        DIM,
    )];
    for (i, cell) in app.cells.iter().enumerate() {
        let status = app
            .status
            .as_ref()
            .and_then(|p| p.cells.iter().find(|(c, _)| c == cell))
            .map(|(_, s)| s);
        let chosen = i == app.cursor;
        let style = if chosen { ACTIVE } else { NORMAL };
        let mark = if chosen { " ▶ " } else { "   " };
        let Some(s) = status else {
            lines.push(Line::styled(
                format!("{mark}{:<8}(no status yet)", cell.as_str()),
                style,
            ));
            continue;
        };
        let running = s.running.as_ref().map_or("-".to_string(), |o| {
            format!("order {} {}", o.id, printable(&o.recipe))
        });
        let alarm = match (&s.alarm, s.cell_associated) {
            (Some(a), _) => printable(a).into_owned(),
            (None, false) => "NOT associated".to_string(),
            (None, true) if s.question.is_some() => "QUESTION waiting".to_string(),
            (None, true) => "-".to_string(),
        };
        let mut spans = vec![Span::styled(
            format!(
                "{mark}{:<8}{:<12}{:<8}{:<19}{:<22}",
                clip(cell.as_str(), 7),
                s.mode.as_str().to_uppercase(),
                s.list.as_str(),
                clip(&running, 18),
                clip(&alarm, 21)
            ),
            if s.alarm.is_some() && !chosen {
                ALARM
            } else {
                style
            },
        )];
        for v in &s.stations {
            let is_cell = app.is_controller(cell, &v.name);
            let look = look_in(s, &v.name, is_cell);
            spans.push(Span::styled(
                format!("{} {}", v.name, look.short()),
                look.style(),
            ));
            spans.push(Span::styled(" ", NORMAL));
        }
        lines.push(Line::from(spans));
    }
    f.render_widget(
        Paragraph::new(lines).block(Block::new().borders(Borders::TOP).title(" cells ")),
        main,
    );
    let [text, lamp] =
        Layout::horizontal([Constraint::Min(10), Constraint::Length(9)]).areas(bottom);
    if let Some(e) = &app.unreachable {
        f.render_widget(
            Paragraph::new(format!(" {}", first_line(e))).style(ALARM),
            text,
        );
    }
    let (word, style) = if app.alarms() > 0 {
        (" ALARM ", ALARM)
    } else {
        ("  ---  ", DIM)
    };
    f.render_widget(Paragraph::new(word).style(style), lamp);
}

/// At most `n` characters of `text` (an ellipsis marks the cut).
fn clip(text: &str, n: usize) -> String {
    if text.chars().count() <= n {
        text.to_string()
    } else {
        let mut s: String = text.chars().take(n.saturating_sub(1)).collect();
        s.push('…');
        s
    }
}

fn top_line(app: &App) -> Line<'static> {
    let cell = app.topology.cell().to_string();
    let what = match &app.status {
        None => "waiting for the operator node".to_string(),
        Some(s) => match &s.running {
            Some(o) => {
                let state = app
                    .stations()
                    .iter()
                    .filter(|n| app.is_cell(n))
                    .find_map(|n| app.running_program(n))
                    .map(|(p, st)| format!(" · {p} state {st}"))
                    .unwrap_or_default();
                format!("order {} {}{state}", o.id, o.recipe)
            }
            None => match app.last_ended() {
                Some(o) => format!(
                    "no recipe chosen · last: order {} {} {}",
                    o.id, o.recipe, o.state
                ),
                None => "no recipe chosen".to_string(),
            },
        },
    };
    let mode = app
        .cell_mode()
        .map(|m| format!(" │ mode {}", m.as_str().to_uppercase()))
        .unwrap_or_default();
    Line::from(format!(
        " FALC {cell} │ {what}{mode} │ {} ({:?})",
        app.user, app.role
    ))
}

fn layer_bar(app: &App) -> Line<'static> {
    let item = |layer: Layer, text: String, lit: bool| {
        let style = if app.layer == layer {
            ACTIVE
        } else if lit {
            ALARM
        } else {
            NORMAL
        };
        vec![Span::styled(text, style), Span::styled(" ", NORMAL)]
    };
    let question = app.status.as_ref().is_some_and(|s| s.question.is_some());
    let f2 = if app.unread() || question {
        " F2 messages * ".to_string()
    } else {
        " F2 messages ".to_string()
    };
    let mut spans = Vec::new();
    spans.extend(item(Layer::Overview, " F1 overview ".into(), false));
    spans.extend(item(Layer::Messages, f2, app.unread() || question));
    spans.extend(item(Layer::Commands, " F3 commands ".into(), false));
    spans.extend(item(Layer::Recipe, " F4 recipe ".into(), false));
    spans.extend(item(Layer::Figures, " F5 figures ".into(), false));
    if app.in_plant {
        spans.push(Span::styled(" Esc plant ·", DIM));
    }
    spans.push(Span::styled(" q quit", DIM));
    Line::from(spans)
}

fn bottom_line(f: &mut Frame, app: &App, area: Rect) {
    let [text, lamp] = Layout::horizontal([Constraint::Min(10), Constraint::Length(9)]).areas(area);
    let said = if let Some(e) = &app.unreachable {
        Span::styled(format!(" {e}"), ALARM)
    } else {
        match &app.said {
            Some((true, t)) => Span::styled(format!(" {}", first_line(t)), NORMAL),
            Some((false, t)) => Span::styled(format!(" refused: {}", first_line(t)), ALARM),
            None => Span::styled(String::new(), NORMAL),
        }
    };
    f.render_widget(Paragraph::new(Line::from(said)), text);
    let alarm = app.status.as_ref().is_some_and(|s| s.alarm.is_some());
    let (word, style) = if alarm {
        (" ALARM ", ALARM)
    } else {
        ("  ---  ", DIM)
    };
    f.render_widget(Paragraph::new(word).style(style), lamp);
}

/// The last `n` lines of `t`, joined with " / ".
fn tail(t: &str, n: usize) -> String {
    let v: Vec<&str> = t.lines().filter(|l| !l.trim().is_empty()).collect();
    v[v.len().saturating_sub(n)..].join(" / ")
}

fn first_line(t: &str) -> String {
    let mut lines = t.lines();
    let first = lines.next().unwrap_or("").to_string();
    match lines.count() {
        0 => first,
        n => format!("{first} (+{n} lines: F3)"),
    }
}

fn station_box(title: String, look: Look) -> Block<'static> {
    Block::new()
        .borders(Borders::ALL)
        .title(Span::styled(
            format!(" {title} {} ", look.word()),
            look.style(),
        ))
        .border_style(look.style())
        .style(NORMAL)
}

fn lamp(on: bool) -> &'static str {
    if on {
        "[■]"
    } else {
        "[ ]"
    }
}

/// The box of transport station `transport`'s conveyor: its PLC's inputs
/// and the recipe it runs.
fn conveyor_box<'a>(app: &App, transport: Option<&falc_model::ids::StationName>) -> Paragraph<'a> {
    let inputs = transport.map(|t| app.inputs_of(t)).transpose();
    let t_look = transport.map_or(Look::Off, |t| look(app, t));
    let mut lines = Vec::new();
    match inputs {
        Ok(Some(Some(i))) => {
            let e = i.equipment();
            let places: Vec<String> = e
                .places()
                .iter()
                .map(|p| format!("W{} {}", p.place, lamp(i.signal(Signal::Place(p.place)))))
                .collect();
            lines.push(Line::from(format!("places    {}", places.join("  "))));
            let st: Vec<String> = e
                .stations()
                .iter()
                .map(|s| {
                    format!(
                        "S{} {}",
                        s.station,
                        lamp(i.signal(Signal::Station(s.station)))
                    )
                })
                .collect();
            lines.push(Line::from(format!("stations  {}", st.join("  "))));
            let running: Vec<String> = e
                .lines()
                .iter()
                .filter(|l| i.signal(Signal::Line(l.line)))
                .map(|l| l.line.to_string())
                .collect();
            lines.push(Line::from(format!(
                "lines running: {}",
                if running.is_empty() {
                    "none".to_string()
                } else {
                    running.join(", ")
                }
            )));
            let plain: Vec<String> = e
                .plain_inputs()
                .map(|n| format!("{n} {}", lamp(i.signal(Signal::Input(n)))))
                .collect();
            if !plain.is_empty() {
                lines.push(Line::from(format!("inputs    {}", plain.join("  "))));
            }
            let mut plc = vec![Span::raw(if i.get(Input::Ready) {
                "PLC ready"
            } else {
                "PLC NOT ready"
            })];
            if i.get(Input::EStop) {
                plc.push(Span::styled("  EMERGENCY STOP", ALARM));
            }
            // The named state the station says its inputs show.
            match transport.and_then(|t| app.equipment_state_of(t)) {
                Some(NO_NAMED_STATE) => plc.push(Span::raw(format!("  {NO_NAMED_STATE}"))),
                Some(name) => plc.push(Span::raw(format!("  state {name}"))),
                None => {}
            }
            lines.push(Line::from(plc));
        }
        Ok(_) => lines.push(Line::from("no reading of the conveyor PLC")),
        Err(why) => lines.push(Line::styled(why, ALARM)),
    }
    if let Some((p, s)) = transport.and_then(|t| app.running_program(t)) {
        lines.push(Line::from(format!("recipe {p}, state {s}")));
    }
    let name = transport.map_or("conveyor".to_string(), |t| format!("{t} (conveyor)"));
    Paragraph::new(lines).block(station_box(name, t_look))
}

fn overview(f: &mut Frame, app: &App, area: Rect) {
    let [upper, conveyor, row, hint] = Layout::vertical([
        Constraint::Length(7),
        Constraint::Length(7),
        Constraint::Length(3),
        Constraint::Min(0),
    ])
    .areas(area);
    let stations = app.stations();
    let of_kind = |k: StationKind| {
        stations
            .iter()
            .filter(move |n| app.topology.station(n).is_some_and(|s| s.kind == k))
            .cloned()
            .collect::<Vec<_>>()
    };
    let transport = of_kind(StationKind::Transport).into_iter().next();
    let inputs = transport
        .as_ref()
        .and_then(|t| app.inputs_of(t).ok().flatten());

    // Robot(s) and the manipulator table, side by side.
    let robots = of_kind(StationKind::Welding);
    let n = robots.len() + 1;
    let cols = Layout::horizontal(vec![Constraint::Ratio(1, n as u32); n]).split(upper);
    for (i, r) in robots.iter().enumerate() {
        let look = look(app, r);
        let mut lines = vec![Line::from(format!("robot controller of {r}"))];
        lines.push(Line::from(match app.running_program(r) {
            Some((p, s)) => format!("recipe {p}, state {s}"),
            None => "no recipe running".into(),
        }));
        if let Some(d) = app
            .status
            .as_ref()
            .and_then(|s| s.stations.iter().find(|v| &v.name == r))
            .and_then(|v| v.status.as_ref())
            .and_then(|s| s.additional)
        {
            lines.push(Line::from(format!("robot {:?}", d.state)));
        }
        f.render_widget(
            Paragraph::new(lines).block(station_box(format!("{r} (robot)"), look)),
            cols[i],
        );
    }
    let table = inputs.map(|i| i.signal(Signal::Station(PlcStation::of(3))));
    let table_look = match (table, transport.as_ref().map(|t| look(app, t))) {
        (_, Some(Look::Off)) | (None, _) => Look::Off,
        (_, Some(Look::Alarm)) => Look::Alarm,
        (Some(true), _) => Look::Busy,
        _ => Look::Idle,
    };
    f.render_widget(
        Paragraph::new(vec![
            Line::from(format!("station 3 {}", lamp(table.unwrap_or(false)))),
            Line::from(if table == Some(true) {
                "a carrier is on the table"
            } else {
                "empty"
            }),
        ])
        .block(station_box("manipulator table".into(), table_look)),
        cols[n - 1],
    );

    // The conveyor of each transport station, side by side.
    let transports = of_kind(StationKind::Transport);
    if transports.is_empty() {
        f.render_widget(conveyor_box(app, None), conveyor);
    } else {
        let n = transports.len();
        let cols = Layout::horizontal(vec![Constraint::Ratio(1, n as u32); n]).split(conveyor);
        for (i, t) in transports.iter().enumerate() {
            f.render_widget(conveyor_box(app, Some(t)), cols[i]);
        }
    }

    // Every station in a row.
    let mut spans = vec![Span::raw(" ")];
    for s in &stations {
        let l = look(app, s);
        // The thesis' recipe state beside the look (LOADED, READY,
        // PENDING, WAIT_ACK …).
        let recipe = recipe_state(app, s).map_or(String::new(), |r| format!("{r} "));
        spans.push(Span::styled(
            format!(" {s} {} {recipe}", l.word()),
            l.style(),
        ));
        spans.push(Span::raw("  "));
    }
    f.render_widget(
        Paragraph::new(Line::from(spans))
            .block(Block::new().borders(Borders::ALL).title(" stations ")),
        row,
    );
    let mut notes = Vec::new();
    if let Some(s) = &app.status {
        if let Some(q) = &s.question {
            notes.push(Line::styled(
                format!("QUESTION waiting (F2): {}", tail(q, 2)),
                BUSY,
            ));
        }
        for (i, (station, _, h)) in app.held_steps().into_iter().enumerate() {
            let hint = if i == 0 {
                "  (Enter: carry it out)"
            } else {
                ""
            };
            notes.push(Line::styled(
                format!(
                    "STEP: {station} state {} waits: {}{hint}",
                    h.state, h.command
                ),
                BUSY,
            ));
        }
        if !s.alarms.is_empty() {
            // The alarm list, highest priority first; those that hold the
            // cell back in the alarm colours.
            let mut list: Vec<_> = s.alarms.iter().collect();
            list.sort_by_key(|a| (a.class.priority(), a.id));
            notes.push(Line::styled(
                format!(
                    "ALARMS: {} in the list  (F3, a: acknowledge all; falc ack N for one)",
                    list.len()
                ),
                ALARM,
            ));
            for a in list {
                let style = if a.blocks_start() {
                    ALARM
                } else {
                    Style::new()
                };
                notes.push(Line::styled(format!("  {}", crate::lines::alarm(a)), style));
            }
        }
        if !s.cell_associated {
            notes.push(Line::styled(
                format!(
                    "cell not associated: {}",
                    s.problem.as_deref().unwrap_or("not yet tried")
                ),
                ALARM,
            ));
        }
        notes.push(Line::from(format!(
            "order list {:?}, {} queued{}",
            s.list,
            s.queued,
            if s.shutdown_pending {
                ", shutting down when done"
            } else {
                ""
            }
        )));
    }
    f.render_widget(Paragraph::new(notes).wrap(Wrap { trim: false }), hint);
}

fn messages(f: &mut Frame, app: &App, area: Rect) {
    let question = app.question_here();
    let [tabs, body, ask] = Layout::vertical([
        Constraint::Length(1),
        Constraint::Min(3),
        Constraint::Length(if question { 4 } else { 0 }),
    ])
    .areas(area);
    let mut spans = vec![Span::raw(" ← ")];
    for (i, p) in app.panes.iter().enumerate() {
        let name = p.station.as_ref().map_or("?".into(), |s| s.to_string());
        let text = if p.unread > 0 {
            format!(" {name} ({} new) ", p.unread)
        } else {
            format!(" {name} ")
        };
        let style = if i == app.pane {
            ACTIVE
        } else if p.unread > 0 {
            ALARM
        } else {
            NORMAL
        };
        spans.push(Span::styled(text, style));
        spans.push(Span::raw(" "));
    }
    spans.push(Span::raw("→"));
    f.render_widget(Paragraph::new(Line::from(spans)), tabs);
    let pane = app.panes.get(app.pane);
    let height = body.height.saturating_sub(2) as usize;
    let lines: Vec<Line> = pane
        .map(|p| {
            let skip = p.entries.len().saturating_sub(height);
            p.entries[skip..]
                .iter()
                .map(|e| {
                    let style = match e.kind {
                        falc_model::records::EntryKind::Alarm => ALARM,
                        falc_model::records::EntryKind::Question => BUSY,
                        _ => NORMAL,
                    };
                    Line::styled(
                        format!(
                            "{} {:<8} {}: {}",
                            time_of_day(e.at_ms),
                            e.kind.as_str(),
                            e.who,
                            e.text
                        ),
                        style,
                    )
                })
                .collect()
        })
        .unwrap_or_default();
    let title = pane
        .and_then(|p| p.station.as_ref())
        .map_or(" messages ".into(), |s| format!(" messages of {s} "));
    f.render_widget(
        Paragraph::new(lines).block(Block::new().borders(Borders::ALL).title(title)),
        body,
    );
    if question {
        let q = app
            .status
            .as_ref()
            .and_then(|s| s.question.clone())
            .unwrap_or_default();
        f.render_widget(
            Paragraph::new(vec![
                Line::styled(format!("QUESTION: {}", tail(&q, 2)), BUSY),
                Line::from(format!("answer: {}_   (Enter sends)", app.answer)),
            ])
            .block(Block::new().borders(Borders::ALL).border_style(BUSY)),
            ask,
        );
    }
}

fn commands(f: &mut Frame, app: &App, area: Rect) {
    let [menu, side] =
        Layout::horizontal([Constraint::Length(60), Constraint::Min(20)]).areas(area);
    let lines: Vec<Line> = Command::ALL
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let (key, label) = c.label();
            let allowed = app.role >= c.role();
            let text = if allowed {
                format!(" {key}  {label}")
            } else {
                format!(" {key}  {label} (needs {:?})", c.role())
            };
            let style = if i == app.cursor && app.pick.is_none() {
                ACTIVE
            } else if allowed {
                NORMAL
            } else {
                DIM
            };
            Line::styled(text, style)
        })
        .collect();
    f.render_widget(
        Paragraph::new(lines).block(
            Block::new()
                .borders(Borders::ALL)
                .title(" commands (↑↓ Enter, or the key) "),
        ),
        menu,
    );
    let (title, items): (String, Vec<String>) = match &app.pick {
        Some(Pick::OrderRecipe(v)) => ("pick a cell recipe (Esc: back)".into(), v.clone()),
        Some(Pick::Order(v)) => (
            "pick the order to remove".into(),
            v.iter().map(|o| format!("{} {}", o.id, o.recipe)).collect(),
        ),
        Some(Pick::Station(v, _)) => (
            "pick a station".into(),
            v.iter().map(|s| s.to_string()).collect(),
        ),
        Some(Pick::Recipe(v, Command::Edit)) => (
            "pick a recipe, or make a new one".into(),
            v.iter()
                .enumerate()
                .map(|(i, r)| {
                    if i == 0 {
                        "(new recipe)".into()
                    } else {
                        r.to_string()
                    }
                })
                .collect(),
        ),
        Some(Pick::Recipe(v, _)) => (
            "pick a recipe".into(),
            v.iter().map(|r| r.to_string()).collect(),
        ),
        Some(Pick::Mode(v)) => (
            "pick the cell's mode".into(),
            v.iter().map(|m| m.to_string()).collect(),
        ),
        Some(Pick::Home(v)) => (
            "pick the workstation to bring home (maintenance mode)".into(),
            v.iter().map(|s| s.to_string()).collect(),
        ),
        Some(Pick::NewName(s, name)) => (
            format!("name of the new recipe of {s} (Enter)"),
            vec![format!("{name}_")],
        ),
        Some(Pick::ConfirmShutdown) => ("shut the cell down? y / n".into(), Vec::new()),
        Some(Pick::EditAgain) => (
            "recipe NOT saved".into(),
            app.said
                .as_ref()
                .map(|(_, t)| t.lines().map(str::to_string).collect())
                .unwrap_or_default(),
        ),
        None => {
            let mut v: Vec<String> = app
                .orders
                .iter()
                .rev()
                .take(area.height.saturating_sub(2) as usize)
                .map(|o| {
                    format!(
                        "{:>4} {:<10} {:<11}{}",
                        o.id,
                        o.recipe,
                        o.state.as_str(),
                        o.result
                            .as_deref()
                            .map(|r| format!(" {r}"))
                            .unwrap_or_default()
                    )
                })
                .collect();
            v.reverse();
            if let Some((ok, text)) = &app.said {
                v.push(String::new());
                v.push(if *ok {
                    "last command:".into()
                } else {
                    "refused:".into()
                });
                v.extend(text.lines().map(|l| format!("  {l}")));
            }
            ("orders".into(), v)
        }
    };
    let picking = app.pick.is_some() && app.pick != Some(Pick::EditAgain);
    let lines: Vec<Line> = items
        .into_iter()
        .enumerate()
        .map(|(i, t)| {
            if picking && i == app.pick_cursor {
                Line::styled(format!(" {t}"), ACTIVE)
            } else {
                Line::styled(format!(" {t}"), NORMAL)
            }
        })
        .collect();
    f.render_widget(
        Paragraph::new(lines).wrap(Wrap { trim: false }).block(
            Block::new()
                .borders(Borders::ALL)
                .title(format!(" {title} ")),
        ),
        side,
    );
}

/// F5: OEE and its factors per period as bars (the newest periods that
/// fit), the totals, cycle times and the alarm Pareto.
fn figures(f: &mut Frame, app: &App, area: Rect) {
    use falc_model::figures::Percent;
    use ratatui::widgets::{Bar, BarChart, BarGroup};
    let Some(cell) = app.figures.as_ref().and_then(|f| f.cells.first()) else {
        let p = Paragraph::new("asking the operator for the figures of the last week …")
            .block(Block::default().borders(Borders::ALL).title(" figures "));
        f.render_widget(p, area);
        return;
    };
    let [chart, lists] =
        Layout::vertical([Constraint::Percentage(55), Constraint::Min(6)]).areas(area);
    // Each group four bars wide and a gap: as many periods as fit.
    let fit = usize::from(chart.width.saturating_sub(2) / 19).max(1);
    let skip = cell.periods.len().saturating_sub(fit);
    let pct = |r: Option<f64>| r.map_or(0, |r| (r * 100.0).round().clamp(0.0, 999.0) as u64);
    let mut bars = BarChart::default()
        .block(
            Block::default()
                .borders(Borders::ALL)
                .title(" OEE · availability · effectiveness · quality per period (%) "),
        )
        .bar_width(4)
        .bar_gap(0)
        .group_gap(3);
    for p in &cell.periods[skip..] {
        let bar = |label: &str, v: Option<f64>, color: Color| {
            Bar::default()
                .label(Line::from(label.to_string()))
                .value(pct(v))
                .style(Style::new().fg(color))
        };
        let label = p.label.get(5..).unwrap_or(&p.label).to_string();
        bars = bars.data(BarGroup::default().label(Line::from(label)).bars(&[
            bar("O", p.oee(), Color::Black),
            bar("A", p.availability(), Color::Blue),
            bar("E", p.effectiveness(), Color::Yellow),
            bar("Q", p.quality(), Color::Green),
        ]));
    }
    f.render_widget(bars, chart);
    let [left, right] =
        Layout::horizontal([Constraint::Percentage(50), Constraint::Percentage(50)]).areas(lists);
    let t = &cell.total;
    let mut lines = vec![
        Line::from(format!(
            "the week: OEE {}  availability {}",
            Percent(t.oee()),
            Percent(t.availability()),
        )),
        Line::from(format!(
            "effectiveness {}  quality {}",
            Percent(t.effectiveness()),
            Percent(t.quality())
        )),
        Line::from(format!(
            "made {}, good {}, failed {}, stopped {}",
            t.quantities.produced, t.quantities.good, t.quantities.failed, t.quantities.stopped
        )),
        Line::from("cycle time        done      p50      p95"),
    ];
    for ct in &cell.cycle {
        lines.push(Line::from(format!(
            "  {:<14} {:>5} {:>7.1}s {:>7.1}s",
            printable(&ct.recipe),
            ct.count,
            ct.p50_ms as f64 / 1000.0,
            ct.p95_ms as f64 / 1000.0
        )));
    }
    f.render_widget(
        Paragraph::new(lines).block(Block::default().borders(Borders::ALL).title(" totals ")),
        left,
    );
    let pareto: Vec<Line> = cell
        .pareto
        .iter()
        .map(|l| {
            Line::from(format!(
                "{:<10} {:<13} {:>4}  {:>8.1} min",
                printable(&l.station),
                l.class.to_string(),
                l.count,
                l.ms as f64 / 60_000.0
            ))
        })
        .collect();
    f.render_widget(
        Paragraph::new(pareto).block(
            Block::default()
                .borders(Borders::ALL)
                .title(" alarms, most down time first "),
        ),
        right,
    );
}

fn recipe(f: &mut Frame, app: &App, area: Rect) {
    let station = app
        .panes
        .get(app.view_station)
        .and_then(|p| p.station.clone());
    let running = station.as_ref().and_then(|s| app.running_program(s));
    let title = match (&station, &running) {
        (Some(s), Some((p, st))) => format!(" ← {s} → runs {p}, state {st} "),
        (Some(s), None) => format!(" ← {s} → runs nothing "),
        _ => " recipe ".into(),
    };
    let mut lines = Vec::new();
    let mut first_current = None;
    match &app.viewed {
        None => lines.push(Line::from(
            "no recipe to show: a station's running recipe appears here; F3 v views any",
        )),
        Some(v) => {
            let current = running
                .as_ref()
                .filter(|(p, _)| v.is_program(p))
                .map(|(_, s)| *s);
            lines.push(Line::styled(
                format!(
                    "{}{}",
                    v.recipe.file,
                    current
                        .map(|s| format!("  (current state {s} highlighted)"))
                        .unwrap_or_default()
                ),
                BUSY,
            ));
            for (text, state) in v.recipe.text.lines().zip(&v.states) {
                let style = match (state, current) {
                    (Some(s), Some(c)) if *s == c => ACTIVE,
                    (Some(_), _) => NORMAL,
                    (None, _) => DIM,
                };
                if style == ACTIVE && first_current.is_none() {
                    first_current = Some(lines.len());
                }
                let marker = if style == ACTIVE { "▶ " } else { "  " };
                lines.push(Line::styled(format!("{marker}{text}"), style));
            }
        }
    }
    // Keep the current state in view, a few lines below the top.
    let height = usize::from(area.height.saturating_sub(2));
    let scroll = first_current
        .filter(|&i| i + 3 > height)
        .map_or(0, |i| i.saturating_sub(3));
    f.render_widget(
        Paragraph::new(lines)
            .scroll((u16::try_from(scroll).unwrap_or(u16::MAX), 0))
            .block(Block::new().borders(Borders::ALL).title(title)),
        area,
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_model::ids::StationName;
    use falc_model::topology::Topology;
    use ratatui::backend::TestBackend;
    use ratatui::Terminal;

    /// What a test terminal shows, as one string.
    fn screen_of(terminal: &Terminal<TestBackend>) -> String {
        terminal
            .backend()
            .buffer()
            .content()
            .iter()
            .map(|c| c.symbol())
            .collect()
    }

    /// A cell grown by two stanzas: every workstation gets its box.
    #[test]
    fn the_overview_draws_a_box_for_every_workstation_of_the_topology() {
        let text = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("launch/cell.toml"),
        )
        .expect("the shipped topology");
        let grown = format!(
            "{text}\n[[station]]\nname = \"welding2\"\nkind = \"welding\"\ncommander = \"cell\"\n\n[[station]]\nname = \"transport2\"\nkind = \"transport\"\ncommander = \"cell\"\n"
        );
        let topology = Topology::parse(&grown, "grown.toml").expect("valid topology");
        let app = App::new(topology, StationName::new("console").expect("valid"));
        let mut terminal = Terminal::new(TestBackend::new(160, 40)).expect("terminal");
        terminal
            .draw(|f| overview(f, &app, f.area()))
            .expect("drawn");
        let screen = screen_of(&terminal);
        for title in [
            "welding (robot)",
            "welding2 (robot)",
            "transport (conveyor)",
            "transport2 (conveyor)",
        ] {
            assert!(screen.contains(title), "no box `{title}`:\n{screen}");
        }
    }

    #[test]
    fn f5_draws_the_figures_fetched_and_asks_for_them_again_when_the_journal_moved() {
        use falc_factory::figures::{compute, FigureInputs, RunSpan};
        use falc_model::api::ApiReply;
        use falc_model::calendar::Calendar;
        use falc_model::figures::FigureQuery;
        use falc_model::records::OrderState;
        use ratatui::crossterm::event::{KeyCode, KeyEvent, KeyModifiers};
        let topology = Topology::load(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("launch/cell.toml"),
        )
        .expect("shipped topology");
        let mut app = App::new(topology, StationName::new("console").expect("valid"));
        assert_eq!(app.wanted_figures(0), None, "only on F5");
        app.key(KeyEvent::new(KeyCode::F(5), KeyModifiers::NONE));
        let Some(r) = app.wanted_figures(1_000_000_000) else {
            panic!("F5 asks for the figures")
        };
        let intent = app.request(r);
        let runs = (0..4)
            .map(|i| RunSpan {
                order: i,
                recipe: "dikdroog".into(),
                cell: "falc1".into(),
                start_ms: i * 100_000,
                end_ms: Some(i * 100_000 + 60_000),
                state: if i == 2 {
                    OrderState::Failed
                } else {
                    OrderState::Done
                },
            })
            .collect();
        let query = FigureQuery {
            since_ms: 0,
            until_ms: Some(400_000),
            planned: Vec::new(),
        };
        let inputs = FigureInputs {
            runs,
            ..Default::default()
        };
        let figures = compute(&inputs, &Calendar::default(), &["falc1"], &query, 400_000);
        assert!(matches!(intent, super::super::app::Intent::Call(_)));
        app.answered(Ok(ApiReply::Figures(Box::new(figures))));
        assert_eq!(app.wanted_figures(1_000_000_000), None, "fetched");
        let mut terminal = Terminal::new(TestBackend::new(120, 40)).expect("terminal");
        terminal.draw(|f| draw(f, &app)).expect("drawn");
        let screen = screen_of(&terminal);
        for text in [
            "F5 figures",
            "OEE · availability",
            "quality 75.0%",
            "made 4, good 3",
            "dikdroog",
        ] {
            assert!(screen.contains(text), "no `{text}`:\n{screen}");
        }
        // The journal moved: asked again.
        app.orders(Vec::new());
        assert!(app.wanted_figures(1_000_000_000).is_some());
    }
}
