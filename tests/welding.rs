//! The welding workstation end to end: a real router, `falc-rcm-sim` on a
//! pty, `falc-welding`, and this test process as its commander (the cell):
//! it associates, downloads a welding recipe as a domain, creates the
//! program invocation, starts it and reads the job events.

use crate::support::{twin, Commander, Proc, TestCell};
use falc_dnc::procedure::Timing;
use falc_model::ids::ObjectName;
use falc_model::mms::pdu::{JobEvent, Request, Response};
use std::time::Duration;

struct Rig {
    cell: TestCell,
    rcm: Proc,
    path: String,
    welding: Proc,
    commander: Commander,
}

async fn rig(time_scale: &str) -> Rig {
    let cell = TestCell::start();
    let (rcm, path) = twin(
        env!("CARGO_BIN_EXE_falc-rcm-sim"),
        &["--time-scale", time_scale],
        "serial port: ",
    );
    let welding = cell.start_node(
        env!("CARGO_BIN_EXE_falc-welding"),
        "welding",
        &["--device", &path],
    );
    let commander = Commander::associate(&cell, "welding").await;
    Rig {
        cell,
        rcm,
        path,
        welding,
        commander,
    }
}

impl Rig {
    async fn call(&self, r: Request) -> Result<Response, falc_model::mms::error::ServiceError> {
        self.commander.call(r).await
    }

    async fn load(&self, name: &str, text: &str) {
        self.commander.load(name, text).await
    }

    async fn start(&self, name: &str) {
        self.commander.start(name).await
    }

    async fn job(&mut self, within: Duration) -> JobEvent {
        self.commander.job(within).await
    }
}

/// Stopping, the workstation closes the DNC link (`C`) before it lets go of
/// the line, a running program stopped first (`H`); started again, it
/// initiates DNC again (`I`). The twin logs each.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stopping_workstation_closes_the_dnc_link_and_a_new_one_initiates_it_again() {
    let mut rig = rig("10").await;
    rig.rcm.take_line("rx I", Duration::from_secs(10));
    rig.load("droog_dik", &droog_dik()).await;
    rig.start("droog_dik").await;
    rig.rcm.take_line("rx G", Duration::from_secs(10));
    rig.welding.terminate();
    rig.welding
        .expect_line("EVENT stopped", Duration::from_secs(15));
    rig.rcm.take_line("rx H", Duration::from_secs(5));
    rig.rcm.take_line("rx C", Duration::from_secs(5));
    let _again = rig.cell.start_node(
        env!("CARGO_BIN_EXE_falc-welding"),
        "welding",
        &["--device", &rig.path],
    );
    rig.rcm.take_line("rx I", Duration::from_secs(10));
}

fn droog_dik() -> String {
    std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/recipes/welding/droog_dik.rcp"
    ))
    .expect("shipped recipe")
}

/// A recipe with a short limit, to see it frozen while a person is in the area.
const SHORT: &str = "#SHORT\n-1 | start rcm 65 | | gestart | 2\n-1 | start rcm 65 | | tijdlimiet | 3\n-2 | wait rcm 3 | | klaar | 0\n-2 | wait rcm 3 | | tijdlimiet | 3\n-3 | | alarm | | 0\n";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn droog_dik_runs_to_done_despite_line_noise() {
    let mut rig = rig("100").await;
    rig.load("droog_dik", &droog_dik()).await;
    rig.start("droog_dik").await;
    // A burst of noise in the middle of the select/start exchange …
    for _ in 0..3 {
        rig.rcm.control("noise 16");
    }
    // … and more while the program runs, the line idle between telegrams.
    rig.rcm.take_line("rx G", Duration::from_secs(10)); // the program runs
    for _ in 0..3 {
        rig.rcm.control("noise 16");
    }
    assert_eq!(rig.job(Duration::from_secs(20)).await, JobEvent::Done);
    // Reusable: it runs again.
    rig.start("droog_dik").await;
    assert_eq!(rig.job(Duration::from_secs(20)).await, JobEvent::Done);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_person_in_the_area_pauses_and_the_limit_freezes() {
    // Program 65 takes 1.2 s here; the recipe allows 3 s; the pause lasts 4 s.
    let mut rig = rig("100").await;
    rig.load("short", SHORT).await;
    rig.start("short").await;
    rig.rcm.take_line("rx G", Duration::from_secs(10)); // the program runs
    rig.rcm.control("person-in");
    // The fault's duration.
    tokio::time::sleep(Duration::from_secs(4)).await;
    rig.rcm.control("person-out");
    assert_eq!(
        rig.job(Duration::from_secs(10)).await,
        JobEvent::Done,
        "the 3 s limit stood still"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn emergency_stop_limit_switch_and_aborted_weld() {
    let mut rig = rig("10").await;
    rig.load("droog_dik", &droog_dik()).await;
    rig.start("droog_dik").await;
    rig.rcm.take_line("rx G", Duration::from_secs(10)); // the program runs
    rig.rcm.control("estop");
    match rig.job(Duration::from_secs(10)).await {
        JobEvent::Alarm(text) => assert!(text.contains("emergency stop"), "{text}"),
        other => panic!("{other:?}"),
    }
    rig.rcm.control("estop-clear");
    rig.start("droog_dik").await;
    rig.rcm.take_line("rx G", Duration::from_secs(10)); // the program runs
    rig.rcm.control("limit-switch");
    assert_eq!(
        rig.job(Duration::from_secs(10)).await,
        JobEvent::FailedDanger
    );
    rig.start("droog_dik").await;
    rig.rcm.take_line("rx G", Duration::from_secs(10)); // the program runs
    rig.rcm.control("abort-weld");
    assert_eq!(rig.job(Duration::from_secs(10)).await, JobEvent::BadProduct);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unplugged_line_ends_in_alarm_and_the_station_recovers() {
    let mut rig = rig("100").await;
    rig.load("droog_dik", &droog_dik()).await;
    rig.rcm.control("unplug");
    rig.start("droog_dik").await;
    // 6 connection attempts × 2 s acknowledgement delay.
    match rig.job(Duration::from_secs(30)).await {
        JobEvent::Alarm(text) => {
            assert!(
                text.contains(&format!("no connection with RCM on {}", rig.path)),
                "{text}"
            )
        }
        other => panic!("{other:?}"),
    }
    rig.rcm.control("replug");
    rig.start("droog_dik").await;
    assert_eq!(rig.job(Duration::from_secs(20)).await, JobEvent::Done);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stop_and_kill_from_the_commander_reach_the_robot() {
    use falc_model::mms::program::PiState;
    let mut rig = rig("1").await; // 120 s programs: they are still running when stopped
    rig.load("droog_dik", &droog_dik()).await;
    rig.start("droog_dik").await;
    rig.rcm.take_line("rx G", Duration::from_secs(10));
    let name = ObjectName::new("droog_dik").expect("valid");
    let r = rig.call(Request::Stop { name: name.clone() }).await;
    assert_eq!(r, Ok(Response::ProgramInvocationState(PiState::Stopped)));
    rig.rcm.take_line("rx H", Duration::from_secs(10));
    // Reset, start again, and kill: the robot is stopped again.
    assert_eq!(
        rig.call(Request::Reset { name: name.clone() }).await,
        Ok(Response::ProgramInvocationState(PiState::Idle))
    );
    rig.start("droog_dik").await;
    rig.rcm.take_line("rx G", Duration::from_secs(10));
    let r = rig.call(Request::Kill { name: name.clone() }).await;
    assert_eq!(r, Ok(Response::ProgramInvocationState(PiState::Unrunnable)));
    // A second, new `rx H`: the kill reached the robot too.
    rig.rcm.take_line("rx H", Duration::from_secs(10));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_line_mid_weld_is_an_alarm_within_the_links_budget_and_the_orphan_program_is_stopped(
) {
    // Program 65 takes 12 s here: it still runs when the line returns.
    let mut rig = rig("10").await;
    rig.load("droog_dik", &droog_dik()).await;
    rig.start("droog_dik").await;
    rig.rcm.take_line("rx G", Duration::from_secs(10));
    // A point in the scenario, not a wait: unplugged 0.3 s into the weld,
    // mid status period (a status request's answer cut off would shorten
    // the silence the test measures).
    tokio::time::sleep(Duration::from_millis(300)).await;
    rig.rcm.control("unplug");
    let silent = std::time::Instant::now();
    let text = match rig.job(Duration::from_secs(15)).await {
        JobEvent::Alarm(text) => text,
        other => panic!("{other:?}"),
    };
    let took = silent.elapsed();
    println!("silent DNC line → alarm: {took:?} ({text})");
    assert!(text.contains(&rig.path), "names the device: {text}");
    assert!(text.contains("nothing heard for 2.0 s"), "{text}");
    // Nothing heard for an acknowledgement delay after the next status
    // request (at most a status period away), or after the one that went
    // just before the cut: not before the delay is spent, less the few
    // milliseconds a status answer takes on the line (the cut may fall
    // between a request's delivery and its answer), and within 3 s of the
    // line going dead.
    let ack_delay = Timing::default().ack_delay;
    assert!(took >= ack_delay - Duration::from_millis(100), "{took:?}");
    assert!(
        took < ack_delay + falc_dnc::host::STATUS_PERIOD + Duration::from_millis(500),
        "{took:?}"
    );
    // The line is back: the robot still runs program 65, which no job
    // owns any more; the workstation finds it by its status and stops it.
    rig.rcm.forget("rx");
    rig.rcm.control("replug");
    rig.rcm.take_line("rx Q", Duration::from_secs(10));
    rig.rcm.take_line("rx H", Duration::from_secs(10));
    let report = rig
        .commander
        .report("no job of this workstation", Duration::from_secs(5))
        .await;
    assert!(report.contains("robot program 65"), "{report}");
    // And the next job runs.
    rig.start("droog_dik").await;
    assert_eq!(rig.job(Duration::from_secs(30)).await, JobEvent::Done);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lost_program_end_is_recovered_from_the_robot_status() {
    let mut rig = rig("100").await;
    rig.load("droog_dik", &droog_dik()).await;
    // The status request of the workstation's start-up, then no other.
    rig.rcm.take_line("rx Q", Duration::from_secs(10));
    rig.rcm.forget("rx Q");
    rig.rcm.control("lose-end");
    rig.start("droog_dik").await;
    // 1.2 s of program, then at most a status period and its answer: the
    // end telegram never comes, the status shows the program ended.
    assert_eq!(rig.job(Duration::from_secs(10)).await, JobEvent::Done);
    rig.rcm.take_line("rx Q", Duration::ZERO);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_lost_acknowledgement_of_the_select_is_asked_for_and_the_job_runs_to_done() {
    let mut rig = rig("100").await;
    rig.load("droog_dik", &droog_dik()).await;
    rig.rcm.control("lose-ack");
    rig.rcm.forget("rx ");
    rig.start("droog_dik").await;
    // The select is done at the robot, its acknowledgement never sent.
    // After the link's budget for an answer (6.88 s) the workstation asks
    // the status, finds program 65 selected and starts it.
    rig.rcm.take_line("rx S", Duration::from_secs(10));
    rig.rcm.take_line("rx Q", Duration::from_secs(10));
    rig.rcm.take_line("rx G", Duration::from_secs(5));
    let report = rig
        .commander
        .report("acknowledgement of the selection", Duration::from_secs(5))
        .await;
    assert!(report.contains("robot program 65"), "{report}");
    assert_eq!(rig.job(Duration::from_secs(15)).await, JobEvent::Done);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restarted_welding_node_stops_a_program_no_job_owns() {
    let mut rig = rig("1").await; // 120 s programs
    rig.load("droog_dik", &droog_dik()).await;
    rig.start("droog_dik").await;
    rig.rcm.take_line("rx G", Duration::from_secs(10));
    rig.welding.kill();
    rig.rcm.forget("rx");
    rig.welding = rig.cell.start_node(
        env!("CARGO_BIN_EXE_falc-welding"),
        "welding",
        &["--device", &rig.path],
    );
    // Initiate DNC, status request, then the stop of the orphan program.
    rig.rcm.take_line("rx I", Duration::from_secs(10));
    rig.rcm.take_line("rx Q", Duration::from_secs(10));
    rig.rcm.take_line("rx H", Duration::from_secs(10));
    rig.welding
        .expect_line("no job of this workstation", Duration::from_secs(5));
}
