//! The console's command line, as clap reads it: how `falc` reaches the
//! cell ([`ConsoleArgs`]), every operator API command with its arguments
//! ([`CellCommand`] and its subcommands), the recipe file tools
//! ([`RecipeCommand`]), the store's versions ([`VersionCommand`]), the
//! records ([`RecordsCommand`]) and their ranges ([`RangeArgs`]).

use clap::{Args, Subcommand};
use falc_model::ids::{CellId, StationName};
use falc_model::mode::{CellMode, ManualAction};
use falc_model::recipe_file::RecipeFile;
use falc_node::NodeArgs;
use falc_recipe::commands::RecipeKind;
use std::path::PathBuf;

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
    /// Messages: the newest 100 by default (`--last N`, `--all`).
    Messages {
        /// Keep showing new messages, until Ctrl-C.
        #[arg(long)]
        follow: bool,
        /// Only this station's messages (its pane of `falc tui`): a
        /// workstation's jobs, robot programs, line runs and reports.
        #[arg(long)]
        station: Option<StationName>,
        /// How many of the newest messages to show (at most 500).
        #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u16).range(1..=500))]
        last: u16,
        /// Every message since the journal began, page by page.
        #[arg(long, conflicts_with_all = ["last", "follow"])]
        all: bool,
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
    Records(RecordsCommand),
    /// The ISO 22400-2 figures of a range: time elements, availability,
    /// effectiveness, quality, OEE (in total and per shift), cycle times,
    /// MTBF and MTTR per station, the alarm Pareto.
    Figures(crate::commands::FiguresArgs),
    /// The figures of a range as a self-contained HTML page with charts:
    /// OEE and its factors per shift or day, cycle-time histograms, the
    /// alarm Pareto, a Gantt chart of the last order runs.
    Report {
        #[command(flatten)]
        figures: crate::commands::FiguresArgs,
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
    /// Press a conveyor button: a line (a letter) or a station (a number) of
    /// the station's equipment file.
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
        /// The line (a letter).
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
    /// Bring the equipment to one of its named states (`home`), from the
    /// state its inputs show, over its routes; or be told why not.
    Goto {
        /// The state, as its equipment file names it.
        state: String,
    },
}

impl ManualCommand {
    pub(crate) fn action(self) -> ManualAction {
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
            Self::Goto { state } => ManualAction::Goto(state),
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

impl StoreCommand {
    /// The recipe file it names, if any.
    pub(crate) fn file(&self) -> Option<Result<RecipeFile, String>> {
        match self {
            Self::List | Self::Versions(_) => None,
            Self::Show { station, file }
            | Self::Put { station, file, .. }
            | Self::View { station, file, .. }
            | Self::Edit { station, file } => Some(RecipeFile::new(station.clone(), file)),
        }
    }
}

/// `falc recipe check|verify|list|dot|view`: the file tools.
#[derive(Subcommand, Debug)]
pub enum RecipeCommand {
    /// Check recipe files, station directories or a recipe tree; exit 1 and
    /// print `file:line: state N: reason` per problem.
    Check {
        /// The kind of every file given (else the directory name tells).
        #[arg(long)]
        kind: Option<RecipeKind>,
        /// Files or directories (default `recipes`).
        paths: Vec<PathBuf>,
    },
    /// List the recipes of a recipe tree: station, name, states, file, and
    /// whether it checks clean.
    List {
        /// Files or directories (default `recipes`).
        paths: Vec<PathBuf>,
    },
    /// Verify a recipe tree across levels: each cell recipe explored with
    /// the workstation recipes it starts (every outcome they can reach,
    /// every answer, every time-out). Prints `file:line: state N: kind:
    /// finding` with a trace for each (`note:` before those that are
    /// allowed); exit 1 if any defect.
    Verify {
        /// Explore at most this many states per recipe.
        #[arg(long, default_value_t = falc_recipe::verify::STATE_LIMIT)]
        limit: usize,
        /// Print the trace of finding N (from 1) as Graphviz DOT instead.
        #[arg(long, value_name = "N")]
        dot: Option<usize>,
        /// A recipe tree or its station directories (default `recipes`).
        paths: Vec<PathBuf>,
    },
    /// Print a recipe as a Graphviz DOT state diagram.
    Dot {
        /// The kind (else the directory name tells).
        #[arg(long)]
        kind: Option<RecipeKind>,
        /// Highlight this state (a running recipe's).
        #[arg(long)]
        current: Option<u16>,
        /// The recipe file.
        file: PathBuf,
    },
    /// Draw a recipe's state diagram to SVG (no Graphviz needed) or PNG
    /// (with Graphviz `dot`)
    /// (default: next to the recipe, `FILE.svg`).
    View {
        /// The kind (else the directory name tells).
        #[arg(long)]
        kind: Option<RecipeKind>,
        /// Highlight this state (a running recipe's).
        #[arg(long)]
        current: Option<u16>,
        /// `svg` or `png`.
        #[arg(long, default_value = "svg", value_parser = ["svg", "png"])]
        format: String,
        /// Where to write the drawing.
        #[arg(long)]
        out: Option<PathBuf>,
        /// The recipe file.
        file: PathBuf,
    },
}

/// The versions of a store recipe.
#[derive(Subcommand, Debug)]
pub enum VersionCommand {
    /// Every saved version of a store recipe: number, hash, author, time,
    /// message.
    History {
        /// The station's directory (`cell`, `welding`, `transport`).
        station: StationName,
        /// The file (`droog_dik.rcp`; `.rcp` may be left out).
        file: String,
    },
    /// What changed from version V1 to V2 (default: the newest), line by
    /// line (`-` only in V1, `+` only in V2).
    Diff {
        /// The station's directory.
        station: StationName,
        /// The file.
        file: String,
        /// The earlier version.
        v1: u32,
        /// The later version (default: the newest).
        v2: Option<u32>,
    },
    /// Save version V's text again as the newest version (engineer):
    /// checked with the whole set like any save; the cell gets it at the
    /// next start. History is never rewritten: the rollback is a version
    /// of its own.
    Rollback {
        /// The station's directory.
        station: StationName,
        /// The file.
        file: String,
        /// The version whose text comes back.
        version: u32,
        /// Why, for the version's record.
        #[arg(long, short, default_value = "")]
        message: String,
    },
}

/// `falc records …`.
#[derive(Subcommand, Debug)]
pub enum RecordsCommand {
    /// Every order that started in a range, with its recipe versions,
    /// workstation jobs and alarms: JSON (one order record each, as `falc
    /// --json order show`) or CSV (a row per order).
    Export {
        #[command(flatten)]
        range: crate::commands::RangeArgs,
        /// `csv` or `json`.
        #[arg(long, default_value = "csv", value_parser = ["csv", "json"])]
        format: String,
        /// Where to write (default: standard output).
        #[arg(long)]
        out: Option<std::path::PathBuf>,
    },
}

/// A range of the records (`falc figures`, `report`, `records export`).
#[derive(clap::Args, Debug)]
pub struct RangeArgs {
    /// From (`2026-11-23`, `2026-11-23 06:00`, with an offset, or in this
    /// PC's time zone; default: a week before until).
    #[arg(long)]
    pub(crate) since: Option<String>,
    /// Until (default: now).
    #[arg(long)]
    pub(crate) until: Option<String>,
}

/// `falc figures`' options.
#[derive(clap::Args, Debug)]
pub struct FiguresArgs {
    #[command(flatten)]
    pub(crate) range: RangeArgs,
    /// A planned run time in seconds for a recipe (`dikdroog=300`;
    /// repeat for more); a recipe not named has the median of its done
    /// orders in the range.
    #[arg(long = "planned", value_name = "RECIPE=SECONDS")]
    pub(crate) planned: Vec<String>,
}
