//! `falc-transport`: the transport workstation. Serves the MMS-equivalent
//! services to its commander (domains, program invocations, status), runs
//! transport recipes (`activate`, `reset`, `waitline`, `waitplace`,
//! `waitstation`) against the conveyor PLC over Modbus TCP, polling its
//! inputs (default every 10 ms). Link faults, Modbus exceptions, timeouts
//! and an emergency stop become alarms naming the cause; the link
//! reconnects by itself.
//!
//! `falc-transport io [--watch] [--map]` is the commissioning check: it
//! shows the live inputs (and never writes a coil).
//!
//! A thin driver: the recipe runtime is `falc_control::controller`
//! (driven by `falc_node::controller_node`), the Modbus link
//! `falc_node::plc_link`, the recipe ↔ I/O rules `falc_plc::workstation`
//! (poll-style: this loop hands its commands to the link's task).

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use falc_bus::station::Station;
use falc_model::alarm::{AlarmClass, Cause};
use falc_model::ids::StationName;
use falc_model::topology::Topology;
use falc_node::controller_node::ControllerNode;
use falc_node::plc_link::{self, PlcArgs, PlcSettings};
use falc_node::{init_tracing, say, NodeArgs};
use falc_plc::workstation::{Plc, PlcCommand, PlcEvent};
use falc_recipe::commands::RecipeKind;
use falc_recipe::engine::START_CONFIRM_LIMIT;
use std::path::PathBuf;
use std::time::Duration;

#[derive(Parser, Debug)]
#[command(
    version,
    about = "FALC transport workstation: recipes and the Modbus TCP link to the conveyor PLC"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Cmd>,
    /// The station this process is (a station of kind transport).
    #[arg(long, default_value = "transport")]
    station: StationName,
    #[command(flatten)]
    plc: PlcArgs,
    #[command(flatten)]
    memory: falc_node::controller_node::MemoryArgs,
    #[command(flatten)]
    node: NodeArgs,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Commissioning: read the PLC's inputs and show them (writes nothing).
    Io {
        /// Keep showing every change, with its time, until Ctrl-C.
        #[arg(long)]
        watch: bool,
        /// Print the equipment's I/O map (addresses at the given bases) and
        /// its layout, and exit.
        #[arg(long)]
        map: bool,
        /// The station whose `device` is the PLC's address.
        #[arg(long, default_value = "transport")]
        station: StationName,
        /// The cell topology file (for the PLC's address).
        #[arg(long, default_value = "launch/cell.toml")]
        topology: PathBuf,
        #[command(flatten)]
        plc: PlcArgs,
    },
}

fn plc_settings(
    plc: &PlcArgs,
    topology: Option<&Topology>,
    station: &StationName,
) -> Result<PlcSettings> {
    let stanza = topology.and_then(|t| t.station(station));
    let device = stanza.and_then(|s| s.device.clone());
    let equipment = stanza.and_then(|s| s.equipment.as_deref());
    plc.settings(device, equipment).map_err(anyhow::Error::msg)
}

/// `io`: show the inputs once, or every change with `--watch`.
async fn io(mut settings: PlcSettings, watch: bool) -> Result<()> {
    // Commissioning watches at the busy period throughout.
    settings.idle_poll = settings.poll;
    let address = settings.address.clone();
    let mut link = plc_link::spawn(settings);
    let start = tokio::time::Instant::now();
    let mut last = None;
    loop {
        let ev = tokio::select! {
            ev = link.events.recv() => ev,
            _ = tokio::signal::ctrl_c() => return Ok(()),
        };
        match ev {
            Some(PlcEvent::Connected { .. }) => say(&format!("connected to {address}")),
            Some(PlcEvent::Inputs { inputs, .. }) => {
                if let (Some(before), true) = (last, watch) {
                    let changes: Vec<String> = falc_plc::map::Inputs::changes(&before, &inputs)
                        .map(|(i, v)| format!("{i} {}", u8::from(v)))
                        .collect();
                    say(&format!(
                        "{:>9.3} s  {inputs}   ({})",
                        start.elapsed().as_secs_f64(),
                        changes.join(", ")
                    ));
                } else {
                    say(&format!(
                        "{:>9.3} s  {inputs}",
                        start.elapsed().as_secs_f64()
                    ));
                }
                if !watch {
                    return Ok(());
                }
                last = Some(inputs);
            }
            Some(PlcEvent::Fault(why)) => {
                say(&format!("fault: {why}"));
                if !watch {
                    anyhow::bail!(why);
                }
            }
            None => anyhow::bail!("the PLC link stopped"),
        }
    }
}

/// Hands a command the node decided on to the link's task.
fn send_command(link: &tokio::sync::mpsc::UnboundedSender<PlcCommand>, c: PlcCommand) {
    if link.send(c).is_err() {
        tracing::error!("the PLC link task is gone");
    }
}

#[tokio::main]
async fn main() -> Result<()> {
    init_tracing();
    let cli = Cli::parse();
    if let Some(Cmd::Io {
        watch,
        map,
        station,
        topology,
        plc,
    }) = &cli.command
    {
        let topology = Topology::load(topology).ok();
        if *map {
            let stanza = topology
                .as_ref()
                .and_then(|t| t.station(station))
                .and_then(|s| s.equipment.as_deref());
            let map = plc.map.map(stanza).map_err(anyhow::Error::msg)?;
            let e = map.equipment();
            println!("{} ({}): {}\n", e.name(), e.origin(), e.title());
            print!("{}\n{}", map.table(), e.layout_table());
            return Ok(());
        }
        return io(plc_settings(plc, topology.as_ref(), station)?, *watch).await;
    }
    let topology = cli.node.topology()?;
    let settings = cli.node.settings(&topology, &cli.station)?;
    let plc_settings =
        plc_settings(&cli.plc, Some(&topology), &cli.station).context("no PLC address")?;
    let address = plc_settings.address.clone();
    let poll = plc_settings.poll;
    let equipment = plc_settings.map.equipment().clone();
    let station = Station::open(settings, &topology).await?;
    let mut link = plc_link::spawn(plc_settings);
    let plc = Plc::new(address.clone(), equipment.clone()).with_busy_poll(poll);
    let mut ws = ControllerNode::new(station, RecipeKind::Transport, START_CONFIRM_LIMIT, plc);
    ws.node.set_recipe_memory(cli.memory.recipe_memory);
    ws.carry(|c| send_command(&link.commands, c)).await;
    say(&format!(
        "EVENT ready station={} plc={address} poll_ms={} equipment={}",
        cli.station,
        poll.as_millis(),
        equipment.name()
    ));
    let mut shutdown = falc_node::Shutdown::new();
    loop {
        let deadline = ws.deadline();
        tokio::select! {
            ev = ws.station_recv() => if !ws.station_step(ev).await { break },
            ev = link.events.recv() => match ev {
                Some(ev) => ws.link(ev),
                None => {
                    ws.fault(Cause::new(AlarmClass::Device, "the PLC link task stopped"));
                    ws.carry(|c| send_command(&link.commands, c)).await;
                    break;
                }
            },
            _ = tokio::time::sleep_until(deadline) => ws.on_timeout(),
            _ = shutdown.requested() => break,
        }
        ws.carry(|c| send_command(&link.commands, c)).await;
    }
    // Leave the conveyor safe (each output's safe state): no line running,
    // a clamp still holding its workpiece, since this node cannot know
    // whether the robot still welds.
    for c in ws.node.shut_down() {
        send_command(&link.commands, c);
    }
    let issued = ws.node.controller().device.issued();
    let _ = tokio::time::timeout(Duration::from_millis(500), async {
        while let Some(ev) = link.events.recv().await {
            if matches!(ev, PlcEvent::Inputs { commands_done, .. } if commands_done >= issued)
                || matches!(ev, PlcEvent::Fault(_))
            {
                break;
            }
        }
    })
    .await;
    say("EVENT stopped");
    Ok(())
}
