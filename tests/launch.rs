//! The all-in-one launcher: `falc-launch` starts router, twins, both
//! workstations, cell and operator from a topology, an order runs through
//! the `falc` CLI, and the launcher stops every node on SIGINT, or on its
//! own as soon as one node dies.

use crate::support::wait::{holds, wait_until};
use crate::support::{children, copy_dir, free_port, launcher, launcher_of, Proc};
use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

struct Launched {
    dir: tempfile::TempDir,
    launcher: Proc,
}

fn launch() -> Launched {
    let dir = tempfile::tempdir().expect("tempdir");
    let (cmd, _) = launcher(dir.path(), "50");
    let mut launcher = Proc::spawn("falc-launch", cmd);
    launcher.expect_line("falc-launch: cell ready in", Duration::from_secs(60));
    Launched { dir, launcher }
}

impl Launched {
    fn falc(&self, args: &[&str]) -> String {
        falc_in(self.dir.path(), "cell.toml", None, args)
    }
}

/// `falc ARGS` with the topology `topology` and the credentials of
/// launcher directory `dir`, for cell `cell` of a plant; must succeed.
fn falc_in(dir: &Path, topology: &str, cell: Option<&str>, args: &[&str]) -> String {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_falc"));
    cmd.arg("--topology")
        .arg(dir.join(topology))
        .arg("--credentials-dir")
        .arg(dir.join("credentials"));
    if let Some(c) = cell {
        cmd.args(["--cell", c]);
    }
    let out = cmd.args(args).output().expect("run falc");
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "falc {args:?}: {text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    text
}

/// The launcher's child processes.
fn nodes(launcher: u32) -> Vec<u32> {
    children(launcher).into_iter().map(|(pid, _)| pid).collect()
}

fn gone(pid: u32) -> bool {
    !Path::new(&format!("/proc/{pid}")).exists()
}

#[test]
fn nodes_stop_when_the_launcher_is_killed() {
    let mut l = launch();
    let nodes = nodes(l.launcher.pid());
    assert_eq!(nodes.len(), 7);
    l.launcher.kill();
    wait_until(
        "no node left running after SIGKILL of falc-launch",
        Duration::from_secs(10),
        || {
            let left: Vec<_> = nodes.iter().filter(|&&p| !gone(p)).collect();
            holds(left.is_empty(), || left)
        },
    );
}

#[test]
fn the_launched_cell_runs_an_order_and_ctrl_c_stops_every_node() {
    let mut l = launch();
    let nodes = nodes(l.launcher.pid());
    assert_eq!(
        nodes.len(),
        7,
        "router, 2 twins, 2 workstations, cell, operator"
    );
    // Every node's lines come prefixed with its name.
    l.launcher
        .expect_line("[transport] EVENT ready", Duration::ZERO);
    l.falc(&["order", "add", "dikdroog"]);
    l.falc(&["start"]);
    wait_until("the order done", Duration::from_secs(60), || {
        let status = l.falc(&["status"]);
        if status.contains("QUESTION") {
            l.falc(&["answer", "ja"]);
        }
        holds(status.contains("list idle"), || status)
    });
    assert!(l.falc(&["order", "list"]).contains("done"));
    kill(Pid::from_raw(l.launcher.pid() as i32), Signal::SIGINT).expect("SIGINT");
    l.launcher
        .expect_line("every node stopped", Duration::from_secs(30));
    for pid in nodes {
        assert!(gone(pid), "node {pid} still runs");
    }
    // Its standard input is still open (as a terminal's is): the launcher
    // returns all the same, without waiting for a line.
    wait_until(
        "falc-launch returned after Ctrl-C with its stdin open",
        Duration::from_secs(5),
        || holds(!l.launcher.alive(), || "still running"),
    );
}

/// Issue 43: the in/out cell of `launch/cell-inout.toml`, defined by data
/// alone (its equipment file, topology and recipe tree), runs three orders
/// to done with every process of its own: router, both twins (the
/// conveyor's playing its equipment file), both workstations, cell and
/// operator. The 1992 cell runs on unchanged beside it in
/// `the_launched_cell_runs_an_order_and_ctrl_c_stops_every_node`.
#[test]
fn the_in_out_cell_defined_by_data_runs_three_orders_to_done() {
    let dir = tempfile::tempdir().expect("tempdir");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let shipped = std::fs::read_to_string(root.join("launch/cell-inout.toml")).expect("topology");
    let equipment = root.join("equipment/conveyor-inout.toml");
    let topology = shipped
        .replace(
            "router = \"tcp/127.0.0.1:7447\"",
            &format!("router = \"tcp/127.0.0.1:{}\"", free_port()),
        )
        .replace(
            "equipment = \"equipment/conveyor-inout.toml\"",
            &format!("equipment = \"{}\"", equipment.display()),
        );
    assert!(
        topology.contains(&equipment.display().to_string()),
        "{topology}"
    );
    std::fs::write(dir.path().join("cell.toml"), topology).expect("write");
    let recipes = dir.path().join("recipes");
    for sub in ["cell", "welding", "transport"] {
        copy_dir(&root.join("recipes-inout").join(sub), &recipes.join(sub));
    }
    let cmd = launcher_of(dir.path(), &dir.path().join("cell.toml"), &recipes, "50");
    let mut launcher = Proc::spawn("falc-launch", cmd);
    launcher.expect_line("falc-launch: cell ready in", Duration::from_secs(60));
    launcher.expect_line(
        "falc-plc-sim of conveyor-inout listening on",
        Duration::ZERO,
    );
    launcher.expect_line("equipment=conveyor-inout", Duration::ZERO);
    let l = Launched { dir, launcher };
    l.falc(&["order", "add", "--count", "3", "inoutlas"]);
    l.falc(&["start"]);
    let mut answered = 0;
    wait_until("three orders done", Duration::from_secs(120), || {
        let status = l.falc(&["status"]);
        if status.contains("QUESTION") {
            l.falc(&["answer", "ja"]);
            answered += 1;
        }
        let list = l.falc(&["order", "list"]);
        holds(
            status.contains("list idle") && list.matches("(done)").count() == 3,
            || format!("{status}\n{list}"),
        )
    });
    // Each order asked twice: hand the part in, take it out.
    assert!(answered >= 6, "{answered} answers");
    let list = l.falc(&["order", "list"]);
    assert!(!list.contains("failed"), "{list}");
    let journal = l.falc(&["journal"]);
    for line in [
        "LOAD",
        "TO_TABLE",
        "TO_OUT",
        "UNLOAD",
        "line A runs",
        "line D runs",
    ] {
        assert!(
            journal.contains(line),
            "{line} missing from the journal:\n{journal}"
        );
    }
}

#[test]
fn the_launcher_stops_the_cell_when_a_node_dies() {
    let mut l = launch();
    let nodes = nodes(l.launcher.pid());
    let cell = nodes
        .iter()
        .copied()
        .find(|p| {
            std::fs::read(format!("/proc/{p}/cmdline"))
                .map(|c| String::from_utf8_lossy(&c).contains("falc-cell"))
                .unwrap_or(false)
        })
        .expect("the cell controller process");
    kill(Pid::from_raw(cell as i32), Signal::SIGKILL).expect("SIGKILL");
    let line = l
        .launcher
        .expect_line("stopping the cell", Duration::from_secs(10));
    assert!(line.starts_with("falc-launch: cell stopped"), "{line}");
    l.launcher
        .expect_line("every node stopped", Duration::from_secs(30));
    for pid in nodes {
        assert!(gone(pid), "node {pid} still runs");
    }
}

/// `falc-launch` with a plant file: the factory router, per cell its
/// router, twins, workstations and cell controller, then the operator and
/// the OPC UA gateway of the plant; two orders run, one on each cell;
/// Ctrl-C stops every node.
#[test]
fn the_launched_plant_runs_an_order_on_each_cell_and_ctrl_c_stops_every_node() {
    use crate::support::copy_recipes;
    use crate::support::plant::{whole_plant, with_free_ports};
    let dir = tempfile::tempdir().expect("tempdir");
    let plant = dir.path().join("factory.toml");
    std::fs::write(&plant, with_free_ports(&whole_plant())).expect("plant");
    let recipes = copy_recipes(dir.path());
    let bin_dir = Path::new(env!("CARGO_BIN_EXE_falc"))
        .parent()
        .expect("bin dir");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_falc-launch"));
    cmd.arg("--topology")
        .arg(&plant)
        .arg("--credentials-dir")
        .arg(dir.path().join("credentials"))
        .arg("--db")
        .arg(dir.path().join("falc.db"))
        .arg("--recipes")
        .arg(recipes)
        .arg("--bin-dir")
        .arg(bin_dir)
        .args(["--plc-listen", "127.0.0.1:0", "--time-scale", "50"])
        .args([
            "--opcua",
            &format!("127.0.0.1:{}", crate::support::free_port()),
        ]);
    let mut launcher = Proc::spawn("falc-launch", cmd);
    launcher.expect_line("falc-launch: plant ready in", Duration::from_secs(90));
    let nodes = nodes(launcher.pid());
    assert_eq!(
        nodes.len(),
        1 + 2 * 6 + 2,
        "factory router; per cell a router, 2 twins, 2 workstations, a cell; the operator, the gateway"
    );
    launcher.expect_line("EVENT ready opc.tcp://", Duration::ZERO);
    launcher.expect_line("[falc2/transport] EVENT ready", Duration::ZERO);
    let falc = |cell: Option<&str>, args: &[&str]| falc_in(dir.path(), "factory.toml", cell, args);
    falc(None, &["order", "add", "dikdroog", "--count", "2"]);
    let out = falc(None, &["start"]);
    assert!(
        out.contains("falc1: order") && out.contains("falc2: order"),
        "{out}"
    );
    wait_until("both orders done", Duration::from_secs(90), || {
        let status = falc(None, &["status"]);
        for cell in ["falc1", "falc2"] {
            let line = status
                .lines()
                .find(|l| l.starts_with(cell))
                .unwrap_or_default();
            if line.contains("QUESTION") {
                falc(Some(cell), &["answer", "ja"]);
            }
        }
        let idle = status.lines().filter(|l| l.contains("list idle")).count();
        holds(idle == 2, || status)
    });
    let list = falc(None, &["order", "list"]);
    assert_eq!(
        list.lines().filter(|l| l.ends_with("(done)")).count(),
        2,
        "{list}"
    );
    assert!(
        list.contains("on falc1") && list.contains("on falc2"),
        "{list}"
    );
    kill(Pid::from_raw(launcher.pid() as i32), Signal::SIGINT).expect("SIGINT");
    launcher.expect_line("every node stopped", Duration::from_secs(60));
    for pid in nodes {
        assert!(gone(pid), "node {pid} still runs");
    }
}
