//! `falc`: the operator's console. `recipe` (check, draw) works on files
//! alone (`recipe_cmd`); every other command talks to the operator node
//! through the operator API as a console user (`cell_cmd` carries them
//! out, `commands` reads them, `output` prints the answers, `watch`
//! follows), `falc tui`
//! draws the operator's screens (`tui`), `falc store edit` and the TUI
//! edit store recipes in `$EDITOR` (`edit`), and `falc store
//! history|diff|rollback` and `falc order show` read recipe versions and
//! an order's record (`history`); `falc figures` prints the ISO 22400-2
//! figures (`figures`) and `falc report` draws them into HTML (`report`).

mod call;
mod cell_cmd;
mod clock;
mod commands;
mod edit;
mod figures;
mod history;
mod lines;
mod output;
mod recipe_cmd;
mod report;
mod tui;
mod watch;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser, Debug)]
#[command(
    name = "falc",
    version,
    about = "FALC console: run the cell (orders, answers, alarms, journal) and check recipes"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    #[command(flatten)]
    console: commands::ConsoleArgs,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Recipe tools: check, draw; the store's versions.
    #[command(subcommand)]
    Recipe(RecipeCommand),
    #[command(flatten)]
    Cell(commands::CellCommand),
}

/// `falc recipe …`: the file tools, and the store's versions (the same as
/// `falc store history|diff|rollback`: these ask the operator).
#[derive(Subcommand, Debug)]
enum RecipeCommand {
    #[command(flatten)]
    Files(commands::RecipeCommand),
    #[command(flatten)]
    Versions(commands::VersionCommand),
}

/// `println!` that ends the program quietly when the reader of stdout has
/// gone (`falc journal | head`), as Unix tools do, and with a word and exit
/// status 1 when stdout cannot be written otherwise (a full disk behind a
/// redirection): output is never lost without saying so. SIGPIPE itself
/// stays ignored (Rust's default): with its default action a router that
/// closes the connection (a refused certificate) killed `falc` without a
/// word.
macro_rules! out {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        // The last guard of the terminal: whatever a field brought, no
        // control character but the line breaks the console itself makes
        // reaches it (the fields are escaped with `printable` already).
        let text = format!($($arg)*);
        let text: String = text
            .split('\n')
            .map(|line| falc_model::ids::printable(line).into_owned())
            .collect::<Vec<_>>()
            .join("\n");
        let mut stdout = std::io::stdout().lock();
        if let Err(e) = writeln!(stdout, "{text}").and_then(|()| stdout.flush()) {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                std::process::exit(0);
            }
            eprintln!("falc: cannot write to standard output: {e}");
            std::process::exit(1);
        }
    }};
}
pub(crate) use out;

fn main() -> ExitCode {
    falc_node::init_tracing();
    let cli = Cli::parse();
    match cli.command {
        // The store's versions, also under `falc recipe`: a console call.
        Command::Recipe(RecipeCommand::Versions(v)) => on_runtime(
            commands::CellCommand::Store(commands::StoreCommand::Versions(v)),
            cli.console,
        ),
        Command::Recipe(RecipeCommand::Files(r)) => recipe_cmd::run(r, &cli.console.node.topology),
        Command::Cell(c) => on_runtime(c, cli.console),
    }
}

/// Runs an operator API command on a runtime of its own.
fn on_runtime(c: commands::CellCommand, console: commands::ConsoleArgs) -> ExitCode {
    match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
    {
        Ok(rt) => rt.block_on(cell_cmd::run(c, console)),
        Err(e) => {
            eprintln!("falc: cannot start the async runtime: {e}");
            ExitCode::from(2)
        }
    }
}
