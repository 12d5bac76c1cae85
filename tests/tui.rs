//! `falc tui` driven in tmux (send-keys / capture-pane) against the
//! all-in-one cell: queue dikdroog from the command layer, start it, answer
//! `ja` in the message layer, watch the overview go busy and back to idle,
//! and the order end done; an engineer edits a recipe, the checker's
//! findings are shown, edited again and saved. tmux is required (`.ci/run`
//! installs it).

use crate::support::wait::wait_until;
use crate::support::LaunchedCell;
use std::process::Command;
use std::time::Duration;

/// A screen as text, shown as it looks when a wait fails.
struct Screen(String);

impl std::fmt::Debug for Screen {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "\n{}", self.0)
    }
}

/// A tmux server of its own (its own socket), killed on drop.
struct Tmux {
    socket: String,
}

impl Tmux {
    fn start(command: &str) -> Self {
        static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let socket = format!("falc-test-{}-{n}", std::process::id());
        let status = Command::new("tmux")
            .args([
                "-L",
                &socket,
                "new-session",
                "-d",
                "-s",
                "tui",
                "-x",
                "110",
                "-y",
                "34",
            ])
            .arg(command)
            .status()
            .unwrap_or_else(|e| panic!("tmux is needed for this test (apt-get install tmux): {e}"));
        assert!(status.success(), "tmux new-session failed");
        Self { socket }
    }

    fn keys(&self, keys: &[&str]) {
        for k in keys {
            let ok = Command::new("tmux")
                .args(["-L", &self.socket, "send-keys", "-t", "tui", k])
                .status()
                .expect("tmux send-keys");
            assert!(ok.success());
            // A pace, not a wait: keys sent at once can reach the TUI as
            // one escape sequence.
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn screen(&self) -> String {
        let out = Command::new("tmux")
            .args(["-L", &self.socket, "capture-pane", "-p", "-t", "tui"])
            .output()
            .expect("tmux capture-pane");
        String::from_utf8_lossy(&out.stdout).into_owned()
    }

    /// Waits until the screen shows every one of `needles`; the screen.
    fn wait_for(&self, needles: &[&str], within: Duration) -> String {
        wait_until(&format!("the screen showing {needles:?}"), within, || {
            let s = self.screen();
            if needles.iter().all(|n| s.contains(n)) {
                Ok(s)
            } else {
                Err(Screen(s))
            }
        })
    }
}

impl Drop for Tmux {
    fn drop(&mut self) {
        let _ = Command::new("tmux")
            .args(["-L", &self.socket, "kill-server"])
            .status();
    }
}

#[test]
fn an_operator_runs_dikdroog_from_the_tui() {
    let cell = LaunchedCell::start("50");
    let args = cell.falc_args("console").join(" ");
    let tmux = Tmux::start(&format!("{} {args} tui", env!("CARGO_BIN_EXE_falc")));
    let s = tmux.wait_for(
        &["F1 overview", "cell IDLE", "PLC ready  state home"],
        Duration::from_secs(20),
    );
    assert!(s.contains("no recipe chosen"), "{s}");

    // F3: order → pick dikdroog → start.
    tmux.keys(&["F3", "o"]);
    tmux.wait_for(
        &["pick a cell recipe", "dikdroog", "pipdroog"],
        Duration::from_secs(10),
    );
    tmux.keys(&["Enter"]);
    tmux.wait_for(&["added order 1 (dikdroog)"], Duration::from_secs(10));
    tmux.keys(&["s"]);
    tmux.wait_for(&["order 1 (dikdroog) started"], Duration::from_secs(10));

    // F1: the cell is busy and asks; the F2 label lights.
    tmux.keys(&["F1"]);
    let s = tmux.wait_for(
        &["cell BUSY", "QUESTION waiting", "F2 messages *"],
        Duration::from_secs(20),
    );
    assert!(s.contains("order 1 dikdroog · DIKDROOG state"), "{s}");

    // F4: the cell's recipe, the state it waits in marked (the question
    // holds it there, so the view is not a race with a fast twin).
    tmux.keys(&["F4"]);
    let s = tmux.wait_for(
        &[
            "← cell → runs DIKDROOG, state 6",
            "cell/dikdroog.rcp  (current state 6",
            "▶ -6",
        ],
        Duration::from_secs(20),
    );
    assert!(s.contains("highlighted"), "{s}");

    // F2: the question in the cell's pane, answered in place.
    tmux.keys(&["F2"]);
    tmux.wait_for(
        &["messages of cell", "dikke plaat droog", "answer: _"],
        Duration::from_secs(10),
    );
    tmux.keys(&["j", "a", "Enter"]);
    tmux.wait_for(&["answered ja"], Duration::from_secs(10));

    // F1: the robot and the table busy, then everything idle and done.
    tmux.keys(&["F1"]);
    let s = tmux.wait_for(
        &["welding BUSY", "recipe DROOG_DIK, state"],
        Duration::from_secs(60),
    );
    assert!(
        s.contains("station 3 [■]"),
        "a carrier on the table while welding:\n{s}"
    );
    let s = tmux.wait_for(
        &[
            "last: order 1 dikdroog done",
            "cell IDLE",
            "welding IDLE",
            "transport IDLE",
        ],
        Duration::from_secs(60),
    );
    assert!(!s.contains("ALARM"), "{s}");

    // F2 → →: each workstation's pane tells what it did, job by job.
    tmux.keys(&["F2", "Right"]);
    tmux.wait_for(
        &[
            "messages of welding",
            "job DROOG_DIK started",
            "robot program 65 started",
            "robot program 65 ended: complete",
            "job DROOG_DIK ended: done",
        ],
        Duration::from_secs(10),
    );
    tmux.keys(&["Right"]);
    tmux.wait_for(
        &[
            "messages of transport",
            " runs",
            "carrier arrived at W",
            "ended: done",
        ],
        Duration::from_secs(10),
    );
    // The same from the command line, one station's.
    let (code, welding) = cell.falc_as("console", &["messages", "--station", "welding"]);
    assert_eq!(code, 0, "{welding}");
    assert!(welding.contains("robot program 65 started"), "{welding}");
    assert!(!welding.contains("carrier arrived"), "{welding}");

    // The journal has the answer by the TUI's user.
    let (code, journal) = cell.falc_as("console", &["journal", "--order", "1"]);
    assert_eq!(code, 0, "{journal}");
    assert!(journal.contains("answer   #1 console: ja"), "{journal}");
    assert!(
        journal.contains("console: added order 1 (dikdroog)"),
        "{journal}"
    );
    tmux.keys(&["q"]);
}

#[test]
fn an_engineer_edits_a_recipe_in_the_tui_checked_on_save() {
    let cell = LaunchedCell::start("50");
    // The "editor": first a typo, then (edit again) the typo mended and a
    // comment added.
    let dir = cell.dir.path();
    let editor = dir.join("editor.sh");
    std::fs::write(
        &editor,
        format!(
            "#!/bin/sh\nif [ -f {once} ]; then\n  sed -i s/waitplase/waitplace/ \"$1\"\n  echo 'Edited in the TUI.' >> \"$1\"\nelse\n  touch {once}\n  sed -i s/waitplace/waitplase/ \"$1\"\nfi\n",
            once = dir.join("once").display()
        ),
    )
    .expect("editor script");
    let args = cell.falc_args("engineer").join(" ");
    let tmux = Tmux::start(&format!(
        "EDITOR='sh {}' {} {args} tui",
        editor.display(),
        env!("CARGO_BIN_EXE_falc")
    ));
    tmux.wait_for(
        &["F1 overview", "engineer (Engineer)"],
        Duration::from_secs(20),
    );
    // F3 → e → station transport → store.rcp.
    tmux.keys(&["F3", "e"]);
    tmux.wait_for(&["pick a station", "transport"], Duration::from_secs(10));
    tmux.keys(&["Down", "Down", "Enter"]);
    tmux.wait_for(
        &["(new recipe)", "transport/store.rcp"],
        Duration::from_secs(10),
    );
    // (new recipe), home, move_to_man, store.
    tmux.keys(&["Down", "Down", "Down", "Enter"]);
    let s = tmux.wait_for(&["recipe NOT saved", "waitplase"], Duration::from_secs(10));
    assert!(
        s.contains("store.rcp:"),
        "the finding names file and line:\n{s}"
    );
    let store = dir.join("recipes/transport/store.rcp");
    assert!(!std::fs::read_to_string(&store)
        .expect("read")
        .contains("waitplase"));
    // Edit again: mended, saved.
    tmux.keys(&["e"]);
    tmux.wait_for(
        &["saved as version 2", "it checks clean"],
        Duration::from_secs(10),
    );
    assert!(std::fs::read_to_string(&store)
        .expect("read")
        .contains("Edited in the TUI."));
    let (code, journal) = cell.falc_as("observer", &["journal"]);
    assert_eq!(code, 0, "{journal}");
    assert!(
        journal.contains("engineer: recipe transport/store.rcp changed"),
        "{journal}"
    );
    tmux.keys(&["q"]);
}

#[test]
fn step_mode_and_a_maintenance_action_in_the_tui() {
    let cell = LaunchedCell::start("50");
    let falc = env!("CARGO_BIN_EXE_falc");
    let args = cell.falc_args("console").join(" ");
    let tmux = Tmux::start(&format!("{falc} {args} tui"));
    tmux.wait_for(
        &["F1 overview", "cell IDLE", "mode AUTO"],
        Duration::from_secs(20),
    );
    // F3 → m → step.
    tmux.keys(&["F3", "m"]);
    tmux.wait_for(
        &["pick the cell's mode", "maintenance"],
        Duration::from_secs(10),
    );
    tmux.keys(&["Down", "Enter"]);
    tmux.wait_for(&["mode step (cell)", "mode STEP"], Duration::from_secs(10));
    tmux.keys(&["o"]);
    tmux.wait_for(&["pick a cell recipe", "dikdroog"], Duration::from_secs(10));
    tmux.keys(&["Enter"]);
    tmux.wait_for(&["added order 1 (dikdroog)"], Duration::from_secs(10));
    tmux.keys(&["s"]);
    tmux.wait_for(&["order 1 (dikdroog) started"], Duration::from_secs(10));
    // F1: the first step waits; Enter carries it out, the next one waits.
    tmux.keys(&["F1"]);
    tmux.wait_for(
        &["STEP: cell state 1 waits: output", "Enter: carry it out"],
        Duration::from_secs(20),
    );
    tmux.keys(&["Enter"]);
    tmux.wait_for(
        &["STEP: cell state 2 waits: output dikke plaat droog"],
        Duration::from_secs(20),
    );
    // Back to auto while the order runs: it goes on by itself.
    tmux.keys(&["F3", "m"]);
    tmux.wait_for(&["pick the cell's mode"], Duration::from_secs(10));
    tmux.keys(&["Enter"]);
    tmux.wait_for(&["mode auto", "mode AUTO"], Duration::from_secs(10));
    tmux.keys(&["F2"]);
    tmux.wait_for(&["answer: _"], Duration::from_secs(20));
    tmux.keys(&["j", "a", "Enter"]);
    tmux.keys(&["F1"]);
    tmux.wait_for(
        &["last: order 1 dikdroog done", "cell IDLE"],
        Duration::from_secs(60),
    );
    tmux.keys(&["q"]);

    // A maintainer: maintenance mode, then the conveyor home.
    let args = cell.falc_args("maintainer").join(" ");
    let tmux = Tmux::start(&format!("{falc} {args} tui"));
    tmux.wait_for(
        &["maintainer (Maintainer)", "mode AUTO"],
        Duration::from_secs(20),
    );
    tmux.keys(&["F3", "m"]);
    tmux.wait_for(&["pick the cell's mode"], Duration::from_secs(10));
    tmux.keys(&["Down", "Down", "Enter"]);
    tmux.wait_for(
        &["mode maintenance", "mode MAINTENANCE"],
        Duration::from_secs(10),
    );
    tmux.keys(&["h"]);
    tmux.wait_for(
        &["pick the workstation to bring home", "transport"],
        Duration::from_secs(10),
    );
    tmux.keys(&["Down", "Enter"]);
    tmux.wait_for(
        &["manual on transport: run recipe home"],
        Duration::from_secs(10),
    );
    let (code, journal) = cell.falc_as("maintainer", &["journal"]);
    assert_eq!(code, 0, "{journal}");
    assert!(
        journal.contains("maintainer: manual on transport: run recipe home"),
        "{journal}"
    );
    assert!(journal.contains("console: step on cell"), "{journal}");
    assert!(journal.contains("console: mode step (cell)"), "{journal}");
    tmux.keys(&["q"]);
}

/// In a plant, `falc tui` opens on the plant overview: a line per cell
/// with its mode, list and stations. ↓ and Enter open cell 2's screens
/// (its own overview, F3 acting on it), Esc comes back to the plant.
#[test]
fn the_plant_overview_shows_each_cell_and_opens_one() {
    use crate::support::plant::TestPlant;
    let plant = TestPlant::start_cells(2);
    let _stations: Vec<_> = ["falc1", "falc2"]
        .iter()
        .flat_map(|c| ["welding", "transport", "cell"].map(|s| plant.demo_station(c, s)))
        .collect();
    let mut operator = plant.spawn_operator();
    operator.expect_line("EVENT ready", Duration::from_secs(60));
    for _ in 0..2 {
        operator.take_line("EVENT delivered recipe=PIPDROOG", Duration::from_secs(60));
    }
    let tmux = Tmux::start(&format!(
        "{} --topology {} --credentials-dir {} --user console tui",
        env!("CARGO_BIN_EXE_falc"),
        plant.path.display(),
        plant.credentials_dir().display()
    ));
    let s = tmux.wait_for(
        &[
            "FALC plant plant",
            "2 cells",
            " ▶ falc1",
            "falc2",
            "transport",
        ],
        Duration::from_secs(20),
    );
    let one = s.lines().find(|l| l.contains("falc1")).unwrap_or_default();
    assert!(
        one.contains("AUTO")
            && one.contains("idle")
            && one.contains("cell")
            && one.contains("welding"),
        "{s}"
    );
    // An order for cell 2 shows on its line once it runs.
    plant.falc(None, &["order", "add", "dikdroog", "--cell", "falc2"]);
    plant.falc(Some("falc2"), &["start"]);
    let s = tmux.wait_for(&["order 1 dikdroog"], Duration::from_secs(20));
    eprintln!("the plant overview:\n{s}");
    let line = s
        .lines()
        .find(|l| l.contains("falc2"))
        .unwrap_or_default()
        .to_string();
    assert!(line.contains("order 1 dikdroog"), "{s}");
    tmux.keys(&["Down", "Enter"]);
    tmux.wait_for(
        &["FALC falc2", "F1 overview", "Esc plant"],
        Duration::from_secs(20),
    );
    tmux.keys(&["Escape"]);
    tmux.wait_for(&["FALC plant plant", " ▶ falc2"], Duration::from_secs(10));
    tmux.keys(&["q"]);
}
