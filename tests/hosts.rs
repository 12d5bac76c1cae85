//! The cell as separate hosts: the router, the operator, the cell and each
//! workstation in a network namespace of its own, joined by veth links to a
//! bridge, every link QUIC with mutual TLS, the router's PC behind the
//! firewall `falc-router firewall` makes (`support::hosts`). An order runs
//! to done, and what crossed the bridge holds none of the recipe text,
//! questions, answers or keys, while a control text sent in clear is seen.
//! The strangers of `secure` try from the operator's PC and are refused. A
//! link 150 ms slow each way runs an order without an alarm. Then links
//! are cut mid-order, for 3, 10 and 30 s, and delayed 3 s (beyond the
//! lease) for 5 s: each is an alarm within the lease, the station rejoins
//! by itself, and `ack` + `start` run the next order. No report is lost
//! across a cut: what the station reported meanwhile (its alarm, the
//! robot's messages) is in the journal after the rejoin, in order, marked
//! replayed, with the station's own time.
//!
//! Apart: a stranger on the cell's segment floods the router's port with
//! 1,000 silent QUIC handshakes, then with 100 failing ones a second for
//! 30 s; the firewall drops them, and a console still logs in within 2 s.
//!
//! Needs root (namespaces, nftables); without it the tests say so and do
//! nothing else.

use crate::secure::strangers_are_refused;
use crate::support::flood;
use crate::support::hosts::{Hosts, ROUTER_ADDRESS};
use crate::support::rig::{rig_hosts, Rig};
use crate::support::wait::{holds, wait_until};
use crate::support::TestCell;
use falc_model::records::OrderState;
use std::net::SocketAddr;
use std::time::{Duration, Instant};

fn hosts_or_say_why() -> Option<Hosts> {
    match Hosts::create() {
        Ok(h) => Some(h),
        Err(e) => {
            eprintln!(
                "NOT RUN: the cell as separate hosts needs root to create network namespaces and veth links: {e}"
            );
            None
        }
    }
}

/// Waits until `falc status` names an unacknowledged alarm of `station`
/// (an acknowledged one of an earlier cut does not count); how long it
/// took.
fn alarm_of(rig: &Rig, station: &str, within: Duration) -> Duration {
    let begin = Instant::now();
    wait_until(&format!("an alarm naming {station}"), within, || {
        let s = rig.status();
        let named = s
            .alarms
            .iter()
            .any(|a| a.acked.is_none() && a.text.contains(station));
        holds(named, || s)
    });
    begin.elapsed()
}

/// Waits until every station is on the bus again.
fn all_back(rig: &Rig, within: Duration) -> Duration {
    let begin = Instant::now();
    wait_until("every station rejoined", within, || {
        let s = rig.status();
        holds(s.stations.iter().all(|v| v.connected), || s)
    });
    begin.elapsed()
}

/// The delay of a slow link within the lease (1 s).
const SLOW: Duration = Duration::from_millis(150);
/// The delay of a spike beyond the lease.
const SPIKE: Duration = Duration::from_secs(3);

/// A fault on a station's link.
#[derive(Clone, Copy)]
enum Fault {
    /// The link down: nothing passes.
    Cut,
    /// Everything the station sends and receives held back this long
    /// (welding only: its link runs through the delay line).
    Delay(Duration),
}

impl Fault {
    fn name(self) -> String {
        match self {
            Fault::Cut => "cut".into(),
            Fault::Delay(d) => format!("delayed {} ms", d.as_millis()),
        }
    }

    fn begin(self, rig: &Rig, host: &str) {
        match self {
            Fault::Cut => rig.cell.hosts.as_ref().expect("hosts").cut(host),
            Fault::Delay(d) => rig.welding_line.as_ref().expect("delay line").set_delay(d),
        }
    }

    fn end(self, rig: &Rig, host: &str) {
        match self {
            Fault::Cut => rig.cell.hosts.as_ref().expect("hosts").mend(host),
            Fault::Delay(_) => rig
                .welding_line
                .as_ref()
                .expect("delay line")
                .set_delay(Duration::ZERO),
        }
    }
}

#[test]
fn the_cell_as_separate_hosts_on_the_secure_transport_runs_orders_and_rides_out_cut_links() {
    let Some(hosts) = hosts_or_say_why() else {
        return;
    };
    let capture = hosts.capture();
    // The control: a text sent in clear across the bridge is seen.
    let control = "FALC capture control, sent in clear";
    let mut rig = rig_hosts(hosts, "20");
    if let Some(h) = rig.cell.hosts.as_ref() {
        h.send_in_clear("operator", &format!("{ROUTER_ADDRESS}:7447"), control);
    }
    let begin = Instant::now();
    rig.cell.falc(&["order", "add", "dikdroog"]);
    rig.cell.falc(&["start"]);
    let questions = rig.work_list("ja", Duration::from_secs(120));
    let order = begin.elapsed();
    assert!(!questions.is_empty(), "the order asked nothing");
    assert_eq!(
        rig.orders()[0].state,
        OrderState::Done,
        "{:?}",
        rig.orders()
    );

    // What crossed the wire: enough to have carried the order, and none of
    // it readable.
    let bytes = capture.bytes();
    assert!(bytes.len() > 20_000, "captured only {} bytes", bytes.len());
    assert!(
        bytes
            .windows(control.len())
            .any(|w| w == control.as_bytes()),
        "the capture did not see the control text: it could not see a secret either"
    );
    let recipe = std::fs::read_to_string(rig.recipes.join("cell/dikdroog.rcp")).expect("recipe");
    let mut secrets: Vec<&str> = vec!["falc/falc1", "operator/api", "DROOG_DIK", "DIKDROOG"];
    secrets.extend(questions.iter().map(|q| q.as_str()));
    secrets.extend(recipe.lines().filter(|l| l.len() > 20));
    for secret in secrets {
        let needle = secret.as_bytes();
        assert!(
            !bytes.windows(needle.len()).any(|w| w == needle),
            "`{secret}` crossed the bridge in clear"
        );
    }
    println!(
        "captured {} bytes on the bridge: no recipe text, question, answer or key in clear",
        bytes.len()
    );

    // Strangers with the cell's PC but not its credentials are refused by
    // the router, and it says so.
    strangers_are_refused(&rig.cell, "operator");
    let refused = rig
        .cell
        .router
        .expect_line("refused login", Duration::from_secs(10));
    assert!(refused.contains("WARN"), "{refused}");

    // A slow link that stays within the lease: the welding workstation's
    // traffic 150 ms late each way for a whole order, which runs to done
    // without an alarm.
    let line = rig.welding_line.as_ref().expect("the welding delay line");
    line.set_delay(SLOW);
    let alarms_before = rig.status().alarms.len();
    let begin = Instant::now();
    rig.cell.falc(&["order", "add", "dikdroog"]);
    rig.cell.falc(&["start"]);
    rig.work_list("ja", Duration::from_secs(120));
    let slow_order = begin.elapsed();
    let orders = rig.orders();
    assert_eq!(
        orders.last().map(|o| o.state),
        Some(OrderState::Done),
        "{orders:?}"
    );
    let status = rig.status();
    assert_eq!(status.alarms.len(), alarms_before, "{:?}", status.alarms);
    println!(
        "welding link {} ms late each way: dikdroog done in {:.1} s ({:.1} s without the delay), no alarm",
        SLOW.as_millis(),
        slow_order.as_secs_f64(),
        order.as_secs_f64()
    );
    if let Some(line) = rig.welding_line.as_ref() {
        line.set_delay(Duration::ZERO);
    }

    for (host, fault, lasting) in [
        ("welding", Fault::Cut, 3),
        ("transport", Fault::Cut, 3),
        ("welding", Fault::Cut, 10),
        ("welding", Fault::Cut, 30),
        ("welding", Fault::Delay(SPIKE), 5),
    ] {
        // The first order is hit, the second runs after the way back.
        rig.cell.falc(&["order", "add", "dikdroog"]);
        rig.cell.falc(&["order", "add", "dundroog"]);
        rig.rcm.forget("rx G");
        rig.cell.falc(&["start"]);
        rig.until_welding();
        let journal_before = rig.status().journal_head;
        let reported_before = reports_of(&mut rig, host).len();
        rig.plc.forget("coil button station 3");
        rig.rcm.forget("rx H");
        fault.begin(&rig, host);
        let noticed = alarm_of(&rig, host, Duration::from_secs(5));
        // The robot goes on reporting while its station is cut off: an
        // information message every half second (RCM codes 60–99), each
        // a report of the welding station nobody can hear now.
        let mut talked = Duration::ZERO;
        if host == "welding" && matches!(fault, Fault::Cut) {
            for code in 61..64 {
                rig.rcm.control(&format!("alarm {code}"));
                std::thread::sleep(Duration::from_millis(500));
                talked += Duration::from_millis(500);
            }
        }
        // The fault lasts `lasting` s in all.
        std::thread::sleep(
            Duration::from_secs(lasting)
                .saturating_sub(noticed)
                .saturating_sub(talked),
        );
        fault.end(&rig, host);
        let mended_ms = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_millis() as i64);
        let back = all_back(&rig, Duration::from_secs(30));
        if host == "transport" {
            // Its commander lost mid-weld, the transport cannot know whether
            // the robot still welds: the clamp on station 3 holds (its safe
            // state) while the cell has the robot halted.
            rig.rcm.expect_line("rx H", Duration::from_secs(5));
            assert_eq!(
                rig.plc.wait_line("coil button station 3 0", Duration::ZERO),
                None,
                "the clamp let go while the transport's link was cut"
            );
        }
        if matches!(fault, Fault::Cut) {
            let since = (journal_before, reported_before);
            no_report_lost(&mut rig, host, since, mended_ms, lasting);
        }
        println!(
            "{host} {} for {lasting} s mid-order: alarm after {} ms, back {} ms after the link was mended",
            fault.name(),
            noticed.as_millis(),
            back.as_millis()
        );
        let orders = rig.orders();
        let cut_order = &orders[orders.len() - 2];
        assert_eq!(cut_order.state, OrderState::Failed, "{orders:?}");
        rig.way_back();
        let orders = rig.orders();
        assert_eq!(
            orders.last().map(|o| o.state),
            Some(OrderState::Done),
            "after {host} {} for {lasting} s: {orders:?}",
            fault.name()
        );
    }
}

/// What `station`'s node published numbered so far, in the order it
/// numbered it: (number, the text of a report; None for a job event) from
/// its `EVENT report … no=N text=T` and `EVENT job … no=N` lines.
fn reports_of(rig: &mut Rig, station: &str) -> Vec<(u64, Option<String>)> {
    let node = match station {
        "welding" => rig.welding.as_mut(),
        _ => rig.transport.as_mut(),
    };
    let Some(node) = node else {
        return Vec::new();
    };
    node.drain();
    node.lines_containing(" no=")
        .iter()
        .filter_map(|l| {
            if let Some(rest) = l.strip_prefix("EVENT report ") {
                let (_, rest) = rest.split_once(" no=")?;
                let (no, text) = rest.split_once(" text=")?;
                Some((no.parse().ok()?, Some(text.to_string())))
            } else if l.starts_with("EVENT job ") {
                let (_, no) = l.rsplit_once(" no=")?;
                Some((no.parse().ok()?, None))
            } else {
                None
            }
        })
        .collect()
}

/// Every report `station` made from its `from`th on (those made while its
/// link was cut among them) is in the journal under it after entry
/// `head`, in the order it made them; those it made while cut are marked
/// replayed and keep their own time (before the link was mended at
/// `mended_ms`). The welding workstation's job is cut mid-weld: some of
/// its reports must have been replayed.
fn no_report_lost(
    rig: &mut Rig,
    station: &str,
    (head, from): (i64, usize),
    mended_ms: i64,
    lasting: u64,
) {
    let published = reports_of(rig, station).split_off(from);
    let numbers: Vec<u64> = published.iter().map(|(no, _)| *no).collect();
    assert!(
        numbers.windows(2).all(|w| w[1] == w[0] + 1),
        "{station} numbered its reports and job events with gaps: {numbers:?}"
    );
    let made: Vec<(u64, String)> = published
        .into_iter()
        .filter_map(|(no, text)| Some((no, text?)))
        .collect();
    assert!(!made.is_empty(), "{station} reported nothing since the cut");
    let filed = wait_until(
        &format!("every report {station} made since the cut in the journal, in order"),
        Duration::from_secs(20),
        || {
            let journal: Vec<_> = rig
                .journal(None)
                .into_iter()
                .filter(|e| e.who == station && e.id > head)
                .collect();
            // Each report, in order, as a subsequence of the journal.
            let mut at = 0;
            let mut filed = Vec::new();
            for (no, text) in &made {
                let replayed = format!("{text} (replayed)");
                match journal[at..]
                    .iter()
                    .position(|e| e.text == *text || e.text == replayed)
                {
                    Some(k) => {
                        at += k + 1;
                        filed.push((*no, journal[at - 1].clone()));
                    }
                    None => {
                        return Err(format!(
                            "report {no} ({text:?}) of {station} missing or out of order in {journal:#?}"
                        ))
                    }
                }
            }
            Ok(filed)
        },
    );
    let replayed: Vec<_> = filed
        .iter()
        .filter(|(_, e)| e.text.ends_with(" (replayed)"))
        .collect();
    // Welding: its alarm and the robot's three messages at least.
    assert!(
        station != "welding" || replayed.len() >= 4,
        "too few of {station}'s reports were made while its link was cut: {filed:#?}"
    );
    if station == "welding" {
        for code in 61..64 {
            assert!(
                replayed
                    .iter()
                    .any(|(_, e)| e.text.contains(&format!("RCM message {code}"))),
                "the robot's message {code} was not replayed: {filed:#?}"
            );
        }
    }
    for (no, e) in &replayed {
        assert!(
            e.at_ms < mended_ms,
            "replayed report {no} is filed at {} ms, after the link was mended at {mended_ms} ms: not its own time",
            e.at_ms
        );
    }
    let operator = rig.operator();
    operator.drain();
    let line = operator
        .lines_containing(&format!("EVENT replayed station={station}"))
        .pop()
        .unwrap_or_default();
    println!(
        "{station} cut for {lasting} s: {} reports made since, all in the journal in order, {} of them replayed ({line})",
        filed.len(),
        replayed.len()
    );
}

/// How long a console on the operator's PC takes to log in (its session
/// open), or why it could not within 2 s.
fn console_login(cell: &TestCell) -> Result<Duration, String> {
    let mut settings = cell.settings("console");
    settings.connect_timeout = Duration::from_secs(2);
    let hosts = cell.hosts.as_ref().expect("hosts");
    hosts
        .on("operator", move || {
            let rt = tokio::runtime::Runtime::new().expect("runtime");
            rt.block_on(async move {
                let begin = Instant::now();
                let bus = falc_bus::Bus::open(settings)
                    .await
                    .map_err(|e| e.to_string())?;
                let took = begin.elapsed();
                let _ = bus.session().close().await;
                Ok(took)
            })
        })
        .join()
        .expect("the console's thread")?
}

/// The packets the router's firewall dropped so far (its counter).
fn dropped(cell: &TestCell) -> u64 {
    let out = cell
        .command("router", "nft")
        .args(["list", "chain", "inet", "falc_router", "router_port"])
        .output()
        .expect("nft list");
    let text = String::from_utf8_lossy(&out.stdout);
    text.split("counter packets ")
        .nth(1)
        .and_then(|t| t.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no counter in the router's firewall: {text}"))
}

/// Silent handshakes a stranger holds open.
const SILENT: usize = 1_000;

#[test]
fn strangers_flooding_the_routers_port_do_not_keep_a_console_out() {
    let Some(hosts) = hosts_or_say_why() else {
        return;
    };
    let cell = TestCell::start_hosts(hosts);
    let hosts = cell.hosts.as_ref().expect("hosts");
    let router: SocketAddr = format!("{ROUTER_ADDRESS}:7447").parse().expect("address");
    let quiet = console_login(&cell).expect("a console logs in with no flood");
    println!("no flood: console logged in in {:.1} ms", ms(quiet));

    // 1,000 silent handshakes, held open while the console logs in.
    let before = dropped(&cell);
    let held = hosts
        .on("stranger", move || flood::silent_handshakes(router, SILENT))
        .join()
        .expect("stranger thread")
        .expect("on the stranger's PC");
    let took = console_login(&cell);
    let knocked = dropped(&cell) - before;
    assert!(
        knocked >= SILENT as u64,
        "the firewall saw {knocked} of the {SILENT} strangers' packets"
    );
    let took = took.unwrap_or_else(|e| {
        panic!("a console could not log in while {SILENT} silent handshakes were held: {e}")
    });
    println!(
        "{SILENT} silent QUIC handshakes held: {knocked} packets dropped by the firewall, console logged in in {:.1} ms",
        ms(took)
    );
    drop(held);

    // 100 failing handshakes a second for 30 s; the console logs in every
    // 5 s meanwhile.
    let before = dropped(&cell);
    let flood = hosts.on("stranger", move || {
        flood::failing_handshakes(router, 100, Duration::from_secs(30))
    });
    let mut logins = Vec::new();
    for _ in 0..5 {
        std::thread::sleep(Duration::from_secs(5));
        let took = console_login(&cell).unwrap_or_else(|e| {
            panic!("a console could not log in under 100 failing handshakes a second: {e}")
        });
        logins.push(ms(took));
    }
    let failed = flood
        .join()
        .expect("stranger thread")
        .expect("on the stranger's PC");
    let knocked = dropped(&cell) - before;
    assert!(
        failed.begun >= 2500 && failed.answered == 0,
        "the strangers began {} handshakes, {} answered: the firewall must answer none",
        failed.begun,
        failed.answered
    );
    assert!(
        knocked >= failed.begun,
        "{knocked} dropped of {}",
        failed.begun
    );
    println!(
        "{} failing QUIC handshakes in 30 s: {knocked} packets dropped, console logins in {logins:.1?} ms",
        failed.begun
    );
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}
