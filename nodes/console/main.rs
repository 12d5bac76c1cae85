//! `falc`: the operator's console. For now the recipe tools; the operator
//! API commands (status, orders, answers) and the TUI come with the
//! operator node.

mod recipe_cmd;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser, Debug)]
#[command(
    name = "falc",
    version,
    about = "FALC console: recipes, and (soon) the cell"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Recipe tools: check, draw.
    #[command(subcommand)]
    Recipe(recipe_cmd::RecipeCommand),
}

fn main() -> ExitCode {
    falc_common::node::init_tracing();
    let cli = Cli::parse();
    match cli.command {
        Command::Recipe(r) => recipe_cmd::run(r),
    }
}
