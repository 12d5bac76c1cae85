//! `falc status|order|start|stop|ack|alarms|answer|messages|journal|shutdown`,
//! `falc mode|step|restart|manual|store|figures|report|records`: the
//! operator API from the command line, each command carried out (the
//! commands and their arguments are `commands`, what is printed `output`,
//! `--watch` and `--follow` `watch`). Human-readable output by default,
//! one JSON document per answer with `--json` (for scripts). Exit status: 0
//! done, 1 refused by the operator node or by the console itself (the
//! reason on stderr), 2 no reply: the operator node could not be reached,
//! or the router's access control refused the call (zenoh cannot tell
//! which; the text on stderr says both).

use crate::call::{once, CALL_LIMIT};
use crate::commands::{CellCommand, ConsoleArgs, OrderCommand, StoreCommand};
use crate::edit;
use crate::history;
use crate::lines;
use crate::output::{fail, print, refuse};
use crate::tui::Screens;
use crate::watch::{follow, watch};
use falc_bus::Bus;
use falc_model::alarm::Alarm;
use falc_model::api::{ApiReply, ApiRequest, Placement};
use falc_model::ids::CellId;
use falc_model::ids::StationName;
use falc_model::plant::Layout;
use falc_model::recipe_file::RecipeFile;
use falc_model::records::Entry;
use falc_model::topology::Topology;
use falc_recipe::files::StationKinds;
use std::process::ExitCode;

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
        CellCommand::Messages {
            follow: true,
            station,
            ..
        } => return follow(&bus, &operator, json, station.as_ref()).await,
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
                    job_order: None,
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
        CellCommand::Messages {
            follow: false,
            station,
            last,
            all,
        } => {
            let keep = |e: &Entry| station.as_ref().map_or(true, |s| e.who == s.as_str());
            // By default one page, the newest; --all reads page after page.
            let last = (!all).then_some(last);
            return all_entries(&bus, &operator, json, keep, |after| {
                (after == 0 || last.is_none()).then_some(ApiRequest::Messages { after, last })
            })
            .await;
        }
        CellCommand::Journal { order } => {
            return all_entries(
                &bus,
                &operator,
                json,
                |_| true,
                |after| {
                    Some(ApiRequest::Journal {
                        order,
                        after,
                        last: None,
                    })
                },
            )
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
    list.retain(|(_, a)| station.map_or(true, |st| a.station == *st));
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
                Some(c) => crate::out!("{c:<8} {}", lines::alarm(a)),
                None => crate::out!("{}", lines::alarm(a)),
            }
        }
    }
    ExitCode::SUCCESS
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
    match crate::recipe_cmd::draw(&dot, format, &out) {
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

/// `falc report`: the figures asked for, drawn into one HTML page.
async fn report(
    bus: &Bus,
    operator: &StationName,
    args: &crate::commands::FiguresArgs,
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

/// Entries page after page (the operator answers a page at a time), as
/// long as `request` gives the next page's request for the last id read.
async fn all_entries(
    bus: &Bus,
    operator: &StationName,
    json: bool,
    keep: impl Fn(&Entry) -> bool,
    request: impl Fn(i64) -> Option<ApiRequest>,
) -> ExitCode {
    let mut all = Vec::new();
    loop {
        let after = all.last().map_or(0, |e: &Entry| e.id);
        let Some(next) = request(after) else { break };
        match bus.api(operator, next, CALL_LIMIT).await {
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
    all.retain(|e| keep(e));
    print(&ApiReply::Entries(all), json);
    ExitCode::SUCCESS
}
