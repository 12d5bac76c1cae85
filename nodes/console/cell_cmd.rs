//! `falc status|order|start|stop|ack|alarms|answer|messages|journal|shutdown`,
//! `falc mode|step|restart|manual|store`: the
//! operator API from the command line. Human-readable output by default,
//! one JSON document per answer with `--json` (for scripts). Exit status: 0
//! done, 1 refused by the operator node or by the console itself (the
//! reason on stderr), 2 no reply: the operator node could not be reached,
//! or the router's access control refused the call (zenoh cannot tell
//! which; the text on stderr says both).

use crate::clock::time_of_day_ms;
use crate::edit;
use crate::history::{self, VersionCommand};
use crate::tui::Screens;
use clap::{Args, Subcommand};
use falc_bus::operator_service::CallError;
use falc_bus::Bus;
use falc_model::alarm::Alarm;
use falc_model::console::{
    ApiReply, ApiRequest, CellStatus, Entry, Order, Placement, PlantStatus, RecipeFile,
};
use falc_model::ids::printable;
use falc_model::ids::CellId;
use falc_model::ids::StationName;
use falc_model::mode::{CellMode, ManualAction};
use falc_model::plant::Layout;
use falc_model::topology::Topology;
use falc_node::NodeArgs;
use falc_recipe::files::StationKinds;
use std::process::ExitCode;
use std::time::Duration;

pub use falc_bus::operator_service::CALL_LIMIT;
/// How often `--watch` and `--follow` ask again when the operator has
/// said nothing; they ask at once when it publishes a change.
const POLL: Duration = Duration::from_millis(250);

/// How the console reaches the cell.
#[derive(Args, Debug)]
pub struct ConsoleArgs {
    /// The console user (a `[[console]]` of the topology); its credentials
    /// are `<credentials-dir>/<user>.toml`.
    #[arg(long, global = true, default_value = "console")]
    pub user: StationName,
    /// Print JSON instead of text.
    #[arg(long, global = true)]
    pub json: bool,
    #[command(flatten)]
    pub node: NodeArgs,
}

/// An operator API command.
#[derive(Subcommand, Debug)]
pub enum CellCommand {
    /// The cell at a glance: list, running order, question, alarm, stations.
    Status {
        /// Show it again whenever it changes, until Ctrl-C.
        #[arg(long)]
        watch: bool,
    },
    /// The order list.
    #[command(subcommand)]
    Order(OrderCommand),
    /// Start (or resume) working through the order list.
    Start,
    /// Stop the running order and the list.
    Stop,
    /// Acknowledge one alarm of the list (its number), or every one.
    Ack {
        /// The alarm's number (`falc alarms` lists them); all if left out.
        id: Option<i64>,
    },
    /// The alarm list: every station's alarms with class, state, who
    /// acknowledged them; an alarm leaves it once acknowledged and cleared.
    Alarms {
        /// Only this station's alarms.
        #[arg(long)]
        station: Option<StationName>,
    },
    /// Answer the cell's waiting question.
    Answer {
        /// The answer (`ja`, `nee`, …).
        text: String,
    },
    /// The messages: what the cell showed and asked, reports, alarms.
    Messages {
        /// Keep showing new messages, until Ctrl-C.
        #[arg(long)]
        follow: bool,
    },
    /// The journal: orders, alarms, messages, every operator action.
    Journal {
        /// Only this order's entries.
        #[arg(long)]
        order: Option<i64>,
    },
    /// Shut the cell down once the order list is done (at once if idle).
    Shutdown,
    /// The operator's screens: F1 overview, F2 messages, F3 commands, F4
    /// recipe (keyboard only; q quits).
    Tui,
    /// The product records: every order of a range as CSV or JSON.
    #[command(subcommand)]
    Records(history::RecordsCommand),
    /// The ISO 22400-2 figures of a range: time elements, availability,
    /// effectiveness, quality, OEE (in total and per shift), cycle times,
    /// MTBF and MTTR per station, the alarm Pareto.
    Figures(crate::figures::FiguresArgs),
    /// The figures of a range as a self-contained HTML page with charts:
    /// OEE and its factors per shift or day, cycle-time histograms, the
    /// alarm Pareto, a Gantt chart of the last order runs.
    Report {
        #[command(flatten)]
        figures: crate::figures::FiguresArgs,
        /// Where to write the page.
        #[arg(long, default_value = "report.html")]
        out: std::path::PathBuf,
    },
    /// The operator's recipe store: list, show, save (engineers), edit.
    #[command(subcommand)]
    Store(StoreCommand),
    /// Set the cell's mode: auto, step (each recipe step waits for `falc
    /// step`), maintenance (no order runs; a maintainer operates by hand).
    /// Only auto ↔ step while an order runs.
    Mode {
        /// auto, step or maintenance.
        mode: CellMode,
        /// In step mode, a workstation that steps as well as the cell
        /// (repeat for more).
        #[arg(long = "station")]
        stations: Vec<StationName>,
    },
    /// Step mode: carry out the recipe step that waits (`falc status`
    /// shows it), or every step up to state N.
    Step {
        /// The workstation whose step (default: the cell's).
        #[arg(long)]
        station: Option<StationName>,
        /// Go on until this state waits.
        #[arg(long)]
        to: Option<u16>,
    },
    /// Run a failed, stopped or interrupted order again: from state
    /// `--from` of its cell recipe; without it a stopped order goes on
    /// where it stopped, any other from its first state.
    Restart {
        /// The order id.
        order: i64,
        /// The cell recipe's state to begin at.
        #[arg(long)]
        from: Option<u16>,
    },
    /// A manual operation on a workstation (maintainer; the cell in
    /// maintenance mode).
    Manual {
        /// The workstation (`transport`, `welding`).
        station: StationName,
        #[command(subcommand)]
        action: ManualCommand,
    },
}

/// `falc manual STATION …`.
#[derive(Subcommand, Debug)]
pub enum ManualCommand {
    /// Press a conveyor button: a line A–H, J–L or a station 1–3.
    Press {
        /// The button.
        button: String,
    },
    /// Release a conveyor button.
    Release {
        /// The button.
        button: String,
    },
    /// Run one conveyor line for a while (pressed, then released).
    Line {
        /// The line A–H, J–L.
        line: String,
        /// For how many seconds (1–600).
        #[arg(default_value_t = 10)]
        seconds: u32,
    },
    /// Select a robot program.
    Select {
        /// Its number (1–999).
        program: u16,
    },
    /// Start the selected robot program.
    Start,
    /// Stop the robot program.
    Stop,
    /// Confirm the robot's alarm.
    Confirm,
    /// Run one of the station's recipes.
    Run {
        /// The recipe (`home`).
        recipe: String,
    },
    /// Run the station's home recipe: back to the starting layout.
    Home,
}

impl ManualCommand {
    fn action(self) -> ManualAction {
        match self {
            Self::Press { button } => ManualAction::Press(button),
            Self::Release { button } => ManualAction::Release(button),
            Self::Line { line, seconds } => ManualAction::RunLine { line, seconds },
            Self::Select { program } => ManualAction::SelectProgram(program),
            Self::Start => ManualAction::StartProgram,
            Self::Stop => ManualAction::StopProgram,
            Self::Confirm => ManualAction::ConfirmAlarm,
            Self::Run { recipe } => ManualAction::RunRecipe(recipe),
            Self::Home => ManualAction::RunRecipe("home".into()),
        }
    }
}

/// `falc store …`: the recipes the operator delivers (not local files:
/// those are `falc recipe …`).
#[derive(Subcommand, Debug)]
pub enum StoreCommand {
    /// Every recipe file in the store.
    List,
    /// Print one recipe file.
    Show {
        /// The station's directory (`cell`, `welding`, `transport`).
        station: StationName,
        /// The file (`droog_dik.rcp`; `.rcp` may be left out).
        file: String,
    },
    /// Save a local file as a store recipe (engineer): checked with the
    /// whole set first, saved only if clean; the cell gets it at the next
    /// start.
    Put {
        /// The station's directory.
        station: StationName,
        /// The file name in the store.
        file: String,
        /// The local file to send.
        path: std::path::PathBuf,
        /// Create a new recipe (else it must exist and is replaced).
        #[arg(long)]
        new: bool,
        /// Why, for the version's record (`falc store history`).
        #[arg(long, short, default_value = "")]
        message: String,
    },
    /// Draw a store recipe's state diagram with Graphviz `dot`, the state
    /// it is in highlighted if its station runs it now.
    View {
        /// The station's directory.
        station: StationName,
        /// The file name in the store.
        file: String,
        /// `svg` or `png`.
        #[arg(long, default_value = "svg", value_parser = ["svg", "png"])]
        format: String,
        /// Where to write it (default `<file>.<format>` here).
        #[arg(long)]
        out: Option<std::path::PathBuf>,
    },
    /// Edit a store recipe in `$VISUAL`/`$EDITOR` (engineer); a new file if
    /// it does not exist. Saved only when it checks clean; on findings you
    /// may edit again.
    Edit {
        /// The station's directory.
        station: StationName,
        /// The file name in the store.
        file: String,
    },
    #[command(flatten)]
    Versions(VersionCommand),
}

/// `falc order …`.
#[derive(Subcommand, Debug)]
pub enum OrderCommand {
    /// Add an order for a cell recipe: at the end of the list unless a
    /// priority or a due time places it earlier.
    Add {
        /// The cell recipe (`dikdroog`).
        recipe: String,
        /// Only this cell may run it (default: any cell that has the recipe).
        #[arg(long)]
        cell: Option<CellId>,
        /// Higher runs first (-99 to 99).
        #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
        priority: i32,
        /// When it is due, in this PC's time zone (`2026-11-25T14:00`,
        /// `2026-11-25 14:00`, `14:00` for today) or with an offset
        /// (`2026-11-25T14:00+01:00`); of equal priority, the one due first
        /// runs first.
        #[arg(long)]
        due: Option<String>,
        /// How many orders (1 to 100).
        #[arg(long, default_value_t = 1)]
        count: u16,
    },
    /// Remove a queued order.
    Rm {
        /// The order id.
        id: i64,
    },
    /// Show the list.
    List,
    /// What the records say of one order: its runs with the recipe
    /// versions they ran (and what those start), its alarms, its journal.
    Show {
        /// The order id.
        id: i64,
    },
}

fn show_order(o: &Order) -> String {
    let mut line = format!(
        "{:>4}  {:<12} {:<11} by {}",
        o.id,
        printable(&o.recipe),
        o.state,
        printable(&o.added_by)
    );
    if o.priority != 0 {
        line.push_str(&format!("  priority {}", o.priority));
    }
    if let Some(due) = o.due_ms {
        line.push_str(&format!("  due {}", crate::clock::date_time(due)));
    }
    match (&o.cell, &o.wanted) {
        (Some(cell), _) => line.push_str(&format!("  on {}", printable(cell))),
        (None, Some(wanted)) => line.push_str(&format!("  for {}", printable(wanted))),
        (None, None) => {}
    }
    if let Some(r) = &o.result {
        line.push_str(&format!("  ({})", printable(r)));
    }
    line
}

/// One journal entry as a line: its text and its author escaped, so that
/// neither a newline nor a terminal escape in them reaches the terminal.
pub(crate) fn show_entry(e: &Entry) -> String {
    let order = e.order.map(|o| format!(" #{o}")).unwrap_or_default();
    format!(
        "{} {:<8}{order} {}: {}",
        time_of_day_ms(e.at_ms),
        e.kind.as_str(),
        printable(&e.who),
        printable(&e.text)
    )
}

/// One alarm as `falc alarms` prints it: number, time, class, station,
/// order, text, and its state (`active, needs ack`, `acknowledged by …`).
pub fn show_alarm(a: &Alarm) -> String {
    let order = a.order.map(|o| format!(" (order {o})")).unwrap_or_default();
    let state = match &a.acked {
        Some((who, at)) => format!("{} by {who} {}", a.state(), time_of_day_ms(*at)),
        None if a.blocks_start() => format!("{}, needs ack", a.state()),
        None => a.state().to_string(),
    };
    format!(
        "#{:<3} {} {:<13} {:<10} {}{order}  [{}]",
        a.id,
        time_of_day_ms(a.raised_ms),
        a.class.as_str(),
        printable(&a.station),
        printable(&a.text),
        printable(&state)
    )
}

/// `falc alarms [--station S]`: the list, highest priority first.
async fn alarms(
    bus: &Bus,
    operator: &StationName,
    station: Option<&StationName>,
    json: bool,
) -> ExitCode {
    // Each alarm with its cell in a plant (the numbers are the plant's).
    let mut list: Vec<(Option<CellId>, Alarm)> =
        match bus.api(operator, ApiRequest::Status, CALL_LIMIT).await {
            Ok(ApiReply::Status(s)) => s.alarms.into_iter().map(|a| (None, a)).collect(),
            Ok(ApiReply::Plant(p)) => p
                .cells
                .into_iter()
                .flat_map(|(c, s)| s.alarms.into_iter().map(move |a| (Some(c.clone()), a)))
                .collect(),
            Ok(other) => return refuse(&format!("status answered {other:?}")),
            Err(why) => return fail(&why),
        };
    list.retain(|(_, a)| station.map_or(true, |st| a.station == st.as_str()));
    list.sort_by_key(|(_, a)| (a.class.priority(), a.id));
    if json {
        let alarms: Vec<&Alarm> = list.iter().map(|(_, a)| a).collect();
        match serde_json::to_string(&alarms) {
            Ok(t) => crate::out!("{t}"),
            Err(e) => return refuse(&format!("cannot write JSON: {e}")),
        }
    } else if list.is_empty() {
        crate::out!("no alarms");
    } else {
        for (cell, a) in &list {
            match cell {
                Some(c) => crate::out!("{c:<8} {}", show_alarm(a)),
                None => crate::out!("{}", show_alarm(a)),
            }
        }
    }
    ExitCode::SUCCESS
}

/// A plant at a glance: a line per cell (its list, running order, queue,
/// mode, alarm, question, stations), then how to see one cell whole.
fn show_plant(p: &PlantStatus) -> String {
    let mut out = Vec::new();
    for (cell, s) in &p.cells {
        let running = s.running.as_ref().map_or("no order".to_string(), |o| {
            format!("order {} ({})", o.id, printable(&o.recipe))
        });
        let mut line = format!(
            "{:<8} list {:<7} {running}, {} queued, {}",
            cell.as_str(),
            s.list.as_str(),
            s.queued,
            s.mode
        );
        if !s.cell_associated {
            line.push_str(", NOT associated");
        }
        if let Some(a) = &s.alarm {
            line.push_str(&format!("  ALARM: {}", printable(a)));
        }
        if let Some(q) = &s.question {
            line.push_str(&format!(
                "  QUESTION: {}",
                printable(&q.replace('\n', " / "))
            ));
        }
        let stations: Vec<String> = s
            .stations
            .iter()
            .map(|st| {
                let how = if !st.connected {
                    "NO CONNECTION"
                } else if st.status.is_some() {
                    "ok"
                } else {
                    "?"
                };
                format!("{} {how}", st.name)
            })
            .collect();
        line.push_str(&format!("  [{}]", stations.join(", ")));
        out.push(line);
    }
    out.push("one cell whole: falc --cell CELL status".into());
    out.join("\n")
}

fn show_status(s: &CellStatus) -> String {
    let mut out = Vec::new();
    let list = s.list.as_str();
    out.push(match &s.running {
        Some(o) => format!("list {list}; running order {} ({})", o.id, o.recipe),
        None => format!("list {list}; no order running"),
    });
    out.push(format!("queued orders: {}", s.queued));
    out.push(format!("mode: {}", s.mode));
    for st in &s.stations {
        if let Some((v, h)) = st.status.as_ref().and_then(|v| Some((v, v.held.as_ref()?))) {
            let program = v
                .program
                .as_ref()
                .map_or(String::new(), |p| format!("{} ", p.name));
            out.push(format!(
                "STEP: {} {program}state {} waits: {}  (falc step --station {})",
                st.name, h.state, h.command, st.name
            ));
        }
    }
    out.push(if s.cell_associated {
        "cell: associated".to_string()
    } else {
        format!(
            "cell: NOT associated: {}",
            s.problem.as_deref().unwrap_or("not yet tried")
        )
    });
    if let Some(a) = &s.alarm {
        out.push(format!("ALARM: {}  (falc ack)", printable(a)));
    }
    let others = s
        .alarms
        .len()
        .saturating_sub(usize::from(s.alarm.is_some()));
    if others > 0 {
        out.push(format!("{others} more alarm(s) in the list (falc alarms)"));
    }
    if let Some(q) = &s.question {
        out.push(format!(
            "QUESTION: {}  (falc answer …)",
            printable(&q.replace('\n', " / "))
        ));
    }
    if s.shutdown_pending {
        out.push("shutting down when the running order ends".into());
    }
    for st in &s.stations {
        out.push(match &st.status {
            _ if !st.connected => format!("  {:<10} NO CONNECTION", st.name.as_str()),
            Some(v) => format!(
                "  {:<10} {:?}, {:?}, recipe {:?}",
                st.name.as_str(),
                v.physical,
                v.logical,
                v.local_detail
            ),
            None => format!("  {:<10} no status seen", st.name.as_str()),
        });
    }
    out.join("\n")
}

/// A reply as one JSON document for scripts: the value itself, without the
/// reply's variant around it (`falc status --json` is the status object;
/// `Done` is `{"done": "…"}`).
fn to_json(reply: &ApiReply) -> serde_json::Result<String> {
    match reply {
        ApiReply::Status(s) => serde_json::to_string(s),
        ApiReply::Plant(p) => serde_json::to_string(p),
        ApiReply::Orders(o) => serde_json::to_string(o),
        ApiReply::Order(o) => serde_json::to_string(o),
        ApiReply::Entries(e) => serde_json::to_string(e),
        ApiReply::Done(text) => serde_json::to_string(&serde_json::json!({ "done": text })),
        ApiReply::Recipes(r) => serde_json::to_string(r),
        ApiReply::Recipe(r) => serde_json::to_string(r),
        ApiReply::Versions(v) => serde_json::to_string(v),
        ApiReply::RecipeAt { version, text } => {
            serde_json::to_string(&serde_json::json!({ "version": version, "text": text }))
        }
        ApiReply::OrderRecord(r) => serde_json::to_string(r),
        ApiReply::Figures(f) => serde_json::to_string(f),
    }
}

fn print(reply: &ApiReply, json: bool) {
    if json {
        match to_json(reply) {
            Ok(s) => crate::out!("{s}"),
            Err(e) => eprintln!("falc: cannot write JSON: {e}"),
        }
        return;
    }
    match reply {
        ApiReply::Status(s) => crate::out!("{}", show_status(s)),
        ApiReply::Plant(p) => crate::out!("{}", show_plant(p)),
        ApiReply::Orders(v) if v.is_empty() => crate::out!("the order list is empty"),
        ApiReply::Orders(v) => v.iter().for_each(|o| crate::out!("{}", show_order(o))),
        ApiReply::Order(o) => crate::out!("added: {}", show_order(o)),
        ApiReply::Entries(v) => v.iter().for_each(|e| crate::out!("{}", show_entry(e))),
        ApiReply::Done(text) => crate::out!("{text}"),
        ApiReply::Recipes(v) => v.iter().for_each(|r| {
            crate::out!(
                "{:<28} {}",
                r.file.to_string(),
                r.name.as_deref().unwrap_or("?")
            )
        }),
        ApiReply::Recipe(r) => crate::out!("{}", r.text.trim_end_matches('\n')),
        ApiReply::RecipeAt { text, .. } => crate::out!("{}", text.trim_end_matches('\n')),
        ApiReply::Versions(v) => crate::out!("{}", history::show_versions(v)),
        ApiReply::OrderRecord(r) => crate::out!("{}", history::show_record(r)),
        ApiReply::Figures(f) => crate::out!("{}", crate::figures::show(f)),
    }
}

/// Opens the console's session: the bus, and the topology it was read from.
async fn connect(args: &ConsoleArgs) -> Result<(Bus, Topology), String> {
    let topology = args.node.console_topology().map_err(|e| e.to_string())?;
    if topology.console(&args.user).is_none() {
        return Err(format!(
            "`{}` is not a console user of {}: add a [[console]] stanza",
            args.user,
            args.node.topology.display()
        ));
    }
    let settings = args
        .node
        .console_settings(&topology, &args.user)
        .map_err(|e| e.to_string())?;
    let bus = Bus::open(settings).await.map_err(|e| e.to_string())?;
    Ok((bus.for_cell(args.node.cell.clone()), topology))
}

impl StoreCommand {
    /// The recipe file it names, if any.
    fn file(&self) -> Option<Result<RecipeFile, String>> {
        match self {
            Self::List | Self::Versions(_) => None,
            Self::Show { station, file }
            | Self::Put { station, file, .. }
            | Self::View { station, file, .. }
            | Self::Edit { station, file } => Some(RecipeFile::new(station.clone(), file)),
        }
    }
}

/// `falc store …`.
async fn store(
    bus: &Bus,
    operator: &StationName,
    cmd: StoreCommand,
    json: bool,
    kinds: &StationKinds,
) -> ExitCode {
    let cmd = match cmd {
        StoreCommand::Versions(v) => return history::run(bus, operator, v, json).await,
        other => other,
    };
    let file = match cmd.file() {
        None => return once(bus, operator, ApiRequest::RecipeList, json).await,
        Some(Ok(f)) => f,
        Some(Err(e)) => return refuse(&e),
    };
    match cmd {
        StoreCommand::List | StoreCommand::Versions(_) => {
            once(bus, operator, ApiRequest::RecipeList, json).await
        }
        StoreCommand::Show { .. } => {
            once(bus, operator, ApiRequest::RecipeGet { file }, json).await
        }
        StoreCommand::Put {
            path, new, message, ..
        } => {
            let text = match std::fs::read_to_string(&path) {
                Ok(t) => t,
                Err(e) => return refuse(&format!("{}: {e}", path.display())),
            };
            let base = if new {
                None
            } else {
                match edit::fetch(bus, operator, &file).await {
                    Ok(Some(r)) => Some(r.hash),
                    Ok(None) => return refuse(&format!("there is no recipe {file}: use --new")),
                    Err(e) => return fail(&e),
                }
            };
            once(
                bus,
                operator,
                ApiRequest::RecipePut {
                    file,
                    text,
                    base,
                    message,
                },
                json,
            )
            .await
        }
        StoreCommand::View { format, out, .. } => {
            view(bus, operator, &file, &format, out, kinds).await
        }
        StoreCommand::Edit { .. } => edit::interactive(bus, operator, &file).await,
    }
}

/// `falc store view`: the store's text drawn, the running state lit.
async fn view(
    bus: &Bus,
    operator: &StationName,
    file: &RecipeFile,
    format: &str,
    out: Option<std::path::PathBuf>,
    kinds: &StationKinds,
) -> ExitCode {
    let text = match edit::fetch(bus, operator, file).await {
        Ok(Some(r)) => r.text,
        Ok(None) => return refuse(&format!("there is no recipe {file} in the store")),
        Err(e) => return fail(&e),
    };
    let path = std::path::Path::new(file.station().as_str()).join(file.file());
    let entry = match falc_recipe::files::entry_in(&path, None, kinds, text) {
        Ok(e) => e,
        Err(e) => return refuse(&e),
    };
    // The state its station is in, if it runs this recipe now.
    let current = match (
        bus.api(operator, ApiRequest::Status, CALL_LIMIT).await,
        entry.name(),
    ) {
        (Ok(ApiReply::Status(s)), Ok(name)) => s
            .stations
            .iter()
            .find(|v| &v.name == file.station())
            .and_then(|v| v.status.as_ref()?.program.clone())
            .filter(|p| p.name.as_str().eq_ignore_ascii_case(name.as_str()))
            .map(|p| p.state),
        _ => None,
    };
    let dot = match crate::recipe_cmd::dot_of_entry(&entry, current) {
        Ok(d) => d,
        Err(problems) => return refuse(&problems.join("\n")),
    };
    let out = out.unwrap_or_else(|| std::path::PathBuf::from(file.file()).with_extension(format));
    match crate::recipe_cmd::graphviz(&dot, format, &out) {
        Ok(()) => {
            match current {
                Some(s) => crate::out!(
                    "{} (state {s}, where it runs now, highlighted)",
                    out.display()
                ),
                None => crate::out!("{} (not running now)", out.display()),
            }
            ExitCode::SUCCESS
        }
        Err(e) => refuse(&e),
    }
}

/// Says why and exits 1.
pub(crate) fn refuse(why: &str) -> ExitCode {
    eprintln!("falc: {}", printable(why));
    ExitCode::FAILURE
}

/// Says why a call brought no reply and exits 1 if the operator refused
/// it, 2 if the operator node could not be reached (or the router refused
/// the call: zenoh cannot tell them apart).
pub fn fail(why: &CallError) -> ExitCode {
    eprintln!("falc: {}", printable(&why.to_string()));
    match why {
        CallError::Refused(_) => ExitCode::FAILURE,
        CallError::NoReply(_) => ExitCode::from(2),
    }
}

/// One call: printed, or the refusal on stderr.
pub(crate) async fn once(
    bus: &Bus,
    operator: &StationName,
    req: ApiRequest,
    json: bool,
) -> ExitCode {
    match bus.api(operator, req, CALL_LIMIT).await {
        Ok(reply) => {
            print(&reply, json);
            ExitCode::SUCCESS
        }
        Err(why) => fail(&why),
    }
}

/// Runs an operator API command.
pub async fn run(cmd: CellCommand, args: ConsoleArgs) -> ExitCode {
    let (bus, topology) = match connect(&args).await {
        Ok(c) => c,
        Err(e) => {
            eprintln!("falc: {e}");
            return ExitCode::from(2);
        }
    };
    let json = args.json;
    let operator = topology.root().name.clone();
    let req = match cmd {
        CellCommand::Status { watch: true } => return watch(&bus, &operator, json).await,
        CellCommand::Tui => {
            // In a plant the plant overview first, or the cell `--cell`
            // names.
            let shown = match (Layout::load(&args.node.topology), &args.node.cell) {
                (Ok(Layout::Plant(p)), Some(c)) => match p.cell(c) {
                    Some(cell) => Screens::Cell(cell.topology().clone()),
                    None => return refuse(&format!("the plant has no cell {c}")),
                },
                (Ok(Layout::Plant(p)), None) => Screens::Plant(p),
                _ => Screens::Cell(topology),
            };
            return crate::tui::run(&bus, &operator, shown, args.user.clone()).await;
        }
        CellCommand::Messages { follow: true } => return follow(&bus, &operator, json).await,
        CellCommand::Status { watch: false } => ApiRequest::Status,
        CellCommand::Order(OrderCommand::Add {
            recipe,
            cell,
            priority,
            due,
            count,
        }) => {
            let due_ms = match due.as_deref().map(crate::clock::parse_due).transpose() {
                Ok(d) => d,
                Err(e) => return refuse(&e),
            };
            ApiRequest::OrderAdd {
                recipe,
                placement: Placement {
                    cell,
                    priority,
                    due_ms,
                },
                count,
            }
        }
        CellCommand::Order(OrderCommand::Rm { id }) => ApiRequest::OrderRemove { id },
        CellCommand::Order(OrderCommand::List) => ApiRequest::OrderList,
        CellCommand::Order(OrderCommand::Show { id }) => ApiRequest::OrderShow { id },
        CellCommand::Start => ApiRequest::Start,
        CellCommand::Stop => ApiRequest::Stop,
        CellCommand::Ack { id } => ApiRequest::Ack { id },
        CellCommand::Alarms { station } => {
            return alarms(&bus, &operator, station.as_ref(), json).await
        }
        CellCommand::Answer { text } => ApiRequest::Answer { text },
        CellCommand::Messages { follow: false } => {
            return all_entries(&bus, &operator, json, |after| ApiRequest::Messages {
                after,
            })
            .await
        }
        CellCommand::Journal { order } => {
            return all_entries(&bus, &operator, json, |after| ApiRequest::Journal {
                order,
                after,
                last: None,
            })
            .await
        }
        CellCommand::Shutdown => ApiRequest::Shutdown,
        CellCommand::Records(cmd) => return history::export(&bus, &operator, cmd).await,
        CellCommand::Report { figures, out } => {
            return report(&bus, &operator, &figures, &out).await
        }
        CellCommand::Figures(args) => match args.request(crate::clock::now_ms()) {
            Ok(r) => r,
            Err(e) => return refuse(&e),
        },
        CellCommand::Mode { mode, stations } => ApiRequest::Mode { mode, stations },
        CellCommand::Step { station, to } => ApiRequest::Step { station, to },
        CellCommand::Restart { order, from } => ApiRequest::Restart { order, from },
        CellCommand::Manual { station, action } => ApiRequest::Manual {
            station,
            action: action.action(),
        },
        CellCommand::Store(cmd) => {
            let kinds = StationKinds::of(&topology);
            return store(&bus, &operator, cmd, json, &kinds).await;
        }
    };
    once(&bus, &operator, req, json).await
}

/// `falc report`: the figures asked for, drawn into one HTML page.
async fn report(
    bus: &Bus,
    operator: &StationName,
    args: &crate::figures::FiguresArgs,
    out: &std::path::Path,
) -> ExitCode {
    let request = match args.request(crate::clock::now_ms()) {
        Ok(r) => r,
        Err(e) => return refuse(&e),
    };
    let figures = match bus.api(operator, request, CALL_LIMIT).await {
        Ok(ApiReply::Figures(f)) => f,
        Ok(other) => return refuse(&format!("unexpected answer to figures: {other:?}")),
        Err(e) => return fail(&e),
    };
    let page = match crate::report::html(&figures) {
        Ok(p) => p,
        Err(e) => return refuse(&e),
    };
    match std::fs::write(out, page) {
        Ok(()) => {
            crate::out!("{}", out.display());
            ExitCode::SUCCESS
        }
        Err(e) => refuse(&format!("cannot write {}: {e}", out.display())),
    }
}

/// Every entry, page after page (the operator answers a page at a time).
async fn all_entries(
    bus: &Bus,
    operator: &StationName,
    json: bool,
    request: impl Fn(i64) -> ApiRequest,
) -> ExitCode {
    let mut all = Vec::new();
    loop {
        let after = all.last().map_or(0, |e: &falc_model::console::Entry| e.id);
        match bus.api(operator, request(after), CALL_LIMIT).await {
            Ok(ApiReply::Entries(page)) if page.is_empty() => break,
            Ok(ApiReply::Entries(page)) => all.extend(page),
            Ok(other) => {
                print(&other, json);
                return ExitCode::SUCCESS;
            }
            Err(why) => {
                eprintln!("falc: {why}");
                return ExitCode::FAILURE;
            }
        }
    }
    print(&ApiReply::Entries(all), json);
    ExitCode::SUCCESS
}

/// Asks `request(state)` again whenever the operator says its status
/// changed, and every `POLL`, until Ctrl-C or a failure; `show` prints
/// what is new and updates the state.
async fn poll<S>(
    bus: &Bus,
    operator: &StationName,
    mut state: S,
    request: impl Fn(&S) -> ApiRequest,
    mut show: impl FnMut(&mut S, ApiReply),
) -> ExitCode {
    let mut stop = falc_node::Shutdown::new();
    let changed = std::sync::Arc::new(tokio::sync::Notify::new());
    let poke = changed.clone();
    let _changed = match bus.on_changed(operator, move || poke.notify_one()).await {
        Ok(d) => Some(d),
        Err(e) => {
            tracing::warn!("asking every {} ms only: {e}", POLL.as_millis());
            None
        }
    };
    loop {
        tokio::select! {
            r = bus.api(operator, request(&state), CALL_LIMIT) => match r {
                Ok(reply) => show(&mut state, reply),
                Err(why) => {
                    eprintln!("falc: {why}");
                    return ExitCode::FAILURE;
                }
            },
            _ = stop.requested() => return ExitCode::SUCCESS,
        }
        tokio::select! {
            _ = tokio::time::sleep(POLL) => {}
            _ = changed.notified() => {}
            _ = stop.requested() => return ExitCode::SUCCESS,
        }
    }
}

/// `status --watch`: the status whenever it changed.
async fn watch(bus: &Bus, operator: &StationName, json: bool) -> ExitCode {
    let show = |last: &mut Option<ApiReply>, reply: ApiReply| {
        if last.as_ref() != Some(&reply) {
            if !json {
                crate::out!("---");
            }
            print(&reply, json);
            *last = Some(reply);
        }
    };
    poll(bus, operator, None, |_| ApiRequest::Status, show).await
}

/// `messages --follow`: every new message, one per line.
async fn follow(bus: &Bus, operator: &StationName, json: bool) -> ExitCode {
    let show = |after: &mut i64, reply: ApiReply| match reply {
        ApiReply::Entries(v) => {
            for e in v {
                *after = (*after).max(e.id);
                print(&ApiReply::Entries(vec![e]), json);
            }
        }
        other => print(&other, json),
    };
    poll(
        bus,
        operator,
        0,
        |&after| ApiRequest::Messages { after },
        show,
    )
    .await
}
