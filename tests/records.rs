//! What the cell made, with which recipe, and how well, end to end
//! through the `falc` CLI: five orders (one ended by the robot's
//! emergency stop, one after an engineer saved a new welding recipe, one
//! after a rollback), each order's recipe versions from `falc order
//! show`, the edit from `falc store diff`, and `falc figures` checked
//! against what this test computes itself from the records.

use crate::support::rig::{rig, Rig};
use falc_model::alarm::AlarmClass;
use falc_model::figures::Figures;
use falc_model::product::OrderRecord;
use falc_model::records::{Order, OrderState};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_millis() as i64)
        .expect("clock")
}

/// `ms` as `YYYY-MM-DDTHH:MM+00:00` (whole minutes, as `falc figures`
/// reads them).
fn minute_text(ms: i64) -> String {
    let text = falc_model::time::utc_text(ms);
    format!("{}T{}+00:00", &text[..10], &text[11..16])
}

/// What `falc order show ID` says.
fn show(rig: &Rig, id: i64) -> OrderRecord {
    rig.reply(&["order", "show", &id.to_string()])
}

/// The welding recipe's version each run of an order ran.
fn welding_versions(record: &OrderRecord) -> Vec<(u32, String)> {
    record
        .runs
        .iter()
        .map(|run| {
            let w = run
                .recipes
                .iter()
                .find(|u| u.domain == "WELDING$DROOG_DIK")
                .unwrap_or_else(|| panic!("no welding recipe in {run:?}"));
            (w.version, w.hash.to_string())
        })
        .collect()
}

#[test]
fn five_orders_keep_their_recipe_versions_and_the_figures_match_the_records() {
    let mut rig = rig("10");
    // Whole minutes: the range the figures are asked for.
    let since = now_ms() / 60_000 * 60_000;

    // Orders 1 and 2: the robot's emergency stop mid-weld ends order 1;
    // the way back runs order 2 to done.
    rig.start_list_until_welding(&["dikdroog", "dikdroog"]);
    rig.rcm.control("estop");
    rig.operator().expect_line(
        "EVENT order-ended id=1 state=failed",
        Duration::from_secs(10),
    );
    rig.rcm.control("estop-clear");
    rig.way_back();

    // The engineer saves a new welding recipe: version 2.
    let file = rig.recipes.join("welding/droog_dik.rcp");
    let original = std::fs::read_to_string(&file).expect("read");
    let edited = original.replace("wait rcm 170", "wait rcm 160");
    assert_ne!(edited, original);
    let local = rig.recipes.join("../droog_dik.edited.rcp");
    std::fs::write(&local, &edited).expect("write");
    let local = local.display().to_string();
    let (code, out) = rig.cell.falc_as(
        "engineer",
        &[
            "store",
            "put",
            "welding",
            "droog_dik",
            &local,
            "-m",
            "shorter wait",
        ],
    );
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("version 2"), "{out}");
    rig.next_order_done("dikdroog");

    // Each order names the versions it ran: 1 and 2 the first welding
    // recipe, 3 the edited one.
    let v1 = welding_versions(&show(&rig, 2));
    let v2 = welding_versions(&show(&rig, 3));
    assert_eq!(welding_versions(&show(&rig, 1)), v1);
    assert_eq!(v1.len(), 1, "one run: {v1:?}");
    assert_eq!((v1[0].0, v2[0].0), (1, 2));
    assert_ne!(v1[0].1, v2[0].1);
    let record = show(&rig, 3);
    let cell = &record.runs[0].recipes[0];
    assert_eq!(cell.domain, "DIKDROOG");
    assert!(
        cell.starts.contains(&"WELDING$DROOG_DIK".to_string()),
        "{cell:?}"
    );
    assert_eq!(
        record.runs[0]
            .recipes
            .iter()
            .find(|u| u.domain == "WELDING$DROOG_DIK")
            .map(|u| u.starts.clone()),
        Some(vec!["WELDING$PROGRAM_065".to_string()])
    );
    // Each workstation job of order 3, with start, end and outcome: the
    // conveyor moves and the weld.
    let jobs: Vec<(&str, &str, &str)> = record
        .jobs
        .iter()
        .map(|j| (j.station.as_str(), j.program.as_str(), j.outcome.as_str()))
        .collect();
    assert_eq!(
        jobs,
        vec![
            ("transport", "STORE", "done"),
            ("transport", "MOVE_TO_MAN", "done"),
            ("transport", "UNSTORE", "done"),
            ("welding", "DROOG_DIK", "done"),
            ("transport", "UNLOAD", "done"),
        ],
        "{record:#?}"
    );
    assert!(
        record
            .jobs
            .iter()
            .all(|j| j.started_ms.is_some_and(|s| s <= j.ended_ms)),
        "{record:#?}"
    );
    // The weld the emergency stop ended is kept with how it ended.
    let first = show(&rig, 1);
    assert!(
        first
            .jobs
            .iter()
            .any(|j| j.station == "welding" && j.outcome.starts_with("alarm")),
        "{first:#?}"
    );
    let text = rig.cell.falc(&["order", "show", "3"]);
    println!("falc order show 3:\n{text}");
    assert!(
        text.contains("WELDING$DROOG_DIK") && text.contains("version   2"),
        "{text}"
    );
    // The history and the diff show the edit, with who and why.
    assert_eq!(
        rig.history("welding", "droog_dik"),
        vec![
            (1, "operator".into(), "found in the recipe store".into()),
            (2, "engineer".into(), "shorter wait".into())
        ]
    );
    let diff = rig
        .cell
        .falc(&["recipe", "diff", "welding", "droog_dik", "1", "2"]);
    assert!(
        diff.contains("\n--2 | wait rcm 170")
            && diff.contains("+-2 | wait rcm 160")
            && diff.contains("--- welding/droog_dik.rcp version 1"),
        "{diff}"
    );
    // The operator cannot roll back; the engineer can: version 3 holds
    // version 1's text, and the next order runs it.
    let (code, out) = rig.cell.falc_as(
        "console",
        &["store", "rollback", "welding", "droog_dik", "1"],
    );
    assert_ne!(code, 0, "{out}");
    let (code, out) = rig.cell.falc_as(
        "engineer",
        &[
            "recipe",
            "rollback",
            "welding",
            "droog_dik",
            "1",
            "-m",
            "back",
        ],
    );
    assert_eq!(code, 0, "{out}");
    assert_eq!(std::fs::read_to_string(&file).expect("read"), original);
    rig.next_order_done("dikdroog");
    let v3 = welding_versions(&show(&rig, 4));
    assert_eq!(v3[0].0, 3);
    assert_eq!(v3[0].1, v1[0].1, "the old text's hash");
    rig.next_order_done("dikdroog");

    // The figures of the range, and the same from the records.
    let until = (now_ms() / 60_000 + 2) * 60_000;
    let figures: Figures = rig.reply(&[
        "figures",
        "--since",
        &minute_text(since),
        "--until",
        &minute_text(until),
    ]);
    assert_eq!(figures.cells.len(), 1, "{figures:?}");
    let f = &figures.cells[0];
    let orders: Vec<Order> = rig.orders();
    assert_eq!(orders.len(), 5);
    let states: Vec<OrderState> = orders.iter().map(|o| o.state).collect();
    assert_eq!(
        states,
        vec![
            OrderState::Failed,
            OrderState::Done,
            OrderState::Done,
            OrderState::Done,
            OrderState::Done
        ]
    );
    let span = |o: &Order| (o.started_ms.expect("started"), o.ended_ms.expect("ended"));
    let production: i64 = orders.iter().map(|o| span(o).1 - span(o).0).sum();
    let t = &f.total.time;
    // No shift calendar: planned while the list worked (ran, or was held
    // by the estop's alarm) and every run; never more than the range.
    assert_eq!(
        figures.planned_by,
        falc_model::figures::PlannedBy::ListWorking
    );
    assert!(
        t.planned_busy_ms >= production && t.planned_busy_ms <= until - since,
        "planned while the list worked: {t:?}"
    );
    assert_eq!(t.production_ms, production, "{t:?}");
    assert_eq!((t.setup_ms, t.maintenance_ms), (0, 0));
    // Down: the estop's alarm from its raise until it was gone, where no
    // order ran.
    let alarms: Vec<_> = (1..=5).flat_map(|id| show(&rig, id).alarms).collect();
    let safety: Vec<_> = alarms
        .iter()
        .filter(|a| a.class == AlarmClass::Safety)
        .collect();
    assert_eq!(safety.len(), 1, "{alarms:#?}");
    let (raised, gone) = (
        safety[0].raised_ms,
        safety[0].gone_ms().expect("acknowledged and cleared"),
    );
    let overlap: i64 = orders
        .iter()
        .map(|o| {
            let (s, e) = span(o);
            (e.min(gone) - s.max(raised)).max(0)
        })
        .sum();
    let safety_down = t
        .down_ms
        .iter()
        .find(|(c, _)| *c == AlarmClass::Safety)
        .map_or(0, |(_, ms)| *ms);
    assert_eq!(safety_down, gone - raised - overlap, "{t:?}");
    assert_eq!(
        t.production_ms + t.down_total_ms() + t.idle_ms,
        t.planned_busy_ms
    );
    let q = &f.total.quantities;
    assert_eq!((q.produced, q.good, q.failed), (5, 4, 1));
    // The cycle time of the four done orders, and their median as the
    // planned run time.
    let mut done: Vec<i64> = orders
        .iter()
        .filter(|o| o.state == OrderState::Done)
        .map(|o| span(o).1 - span(o).0)
        .collect();
    done.sort_unstable();
    let ct = &f.cycle[0];
    assert_eq!((ct.recipe.as_str(), ct.count), ("dikdroog", 4));
    assert_eq!(ct.p50_ms, done[1], "nearest rank of 4: the 2nd");
    assert_eq!(ct.p95_ms, done[3]);
    assert_eq!(q.planned_run_ms, 5 * done[1]);
    let availability = production as f64 / t.planned_busy_ms as f64;
    assert!((f.total.availability().expect("defined") - availability).abs() < 1e-12);
    assert_eq!(f.total.quality(), Some(0.8));
    let welding = f
        .reliability
        .iter()
        .find(|r| r.station == "welding")
        .expect("the robot's failure");
    assert_eq!(welding.failures, 1);
    assert_eq!(welding.mttr_ms, Some(gone - raised));
    // The text says the same.
    let text = rig.cell.falc(&[
        "figures",
        "--since",
        &minute_text(since),
        "--until",
        &minute_text(until),
    ]);
    println!("falc figures:\n{text}\nfalc store diff:\n{diff}");

    // The records of the range as JSON and CSV.
    let range = [
        "--since",
        &minute_text(since),
        "--until",
        &minute_text(until),
    ];
    let mut json_args = vec!["records", "export", "--format", "json"];
    json_args.extend(range);
    let exported: Vec<OrderRecord> =
        serde_json::from_str(&rig.cell.falc(&json_args)).expect("JSON records");
    assert_eq!(
        exported.iter().map(|r| r.order.id).collect::<Vec<_>>(),
        vec![1, 2, 3, 4, 5]
    );
    assert_eq!(exported[2], show(&rig, 3));
    let mut csv_args = vec!["records", "export"];
    csv_args.extend(range);
    let csv = rig.cell.falc(&csv_args);
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows.len(), 6, "{csv}");
    assert!(rows[0].starts_with("order,recipe,cell,state"), "{csv}");
    assert!(
        rows[3].starts_with("3,dikdroog,falc1,done,")
            && rows[3].contains("welding/droog_dik.rcp@2:")
            && rows[3].contains("welding/DROOG_DIK:done:"),
        "{csv}"
    );

    // The report: four charts as inline SVG, opened in headless Chromium
    // without a console message; its screenshot is kept for a person.
    let page = rig.recipes.join("../report.html");
    let page_arg = page.display().to_string();
    let said = rig.cell.falc(&[
        "report",
        "--since",
        &minute_text(since),
        "--until",
        &minute_text(until),
        "--out",
        &page_arg,
    ]);
    assert!(said.contains("report.html"), "{said}");
    let html = std::fs::read_to_string(&page).expect("the report");
    for id in [
        "oee-falc1",
        "cycle-falc1-dikdroog",
        "pareto-falc1",
        "gantt-falc1",
    ] {
        assert!(
            html.contains(&format!("<figure id=\"{id}\"><svg")),
            "no chart {id}"
        );
    }
    let shot = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("records-report.png");
    let _ = std::fs::remove_file(&shot);
    let chromium = std::process::Command::new("chromium")
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            // No network: nothing to look up, nothing refused.
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--enable-logging=stderr",
            "--v=0",
            "--window-size=1000,2200",
        ])
        .arg(format!(
            "--user-data-dir={}",
            rig.recipes.join("../chromium-profile").display()
        ))
        .arg(format!("--screenshot={}", shot.display()))
        .arg(format!("file://{}", page.display()))
        .output()
        .expect("chromium: .ci/test installs it (apt-get install chromium)");
    let log = String::from_utf8_lossy(&chromium.stderr);
    assert!(chromium.status.success(), "{log}");
    let console: Vec<&str> = log.lines().filter(|l| l.contains(":CONSOLE")).collect();
    assert!(console.is_empty(), "the report said: {console:#?}");
    let png = std::fs::metadata(&shot).expect("a screenshot").len();
    assert!(png > 20_000, "a screenshot of {png} bytes");
    println!("report screenshot: {} ({png} bytes)", shot.display());

    // The operator again, now serving OpenMetrics: an independent parser
    // reads it, and its counters are the records'.
    drop(rig.operator.take());
    let port = crate::support::free_port();
    let addr = format!("127.0.0.1:{port}");
    rig.start_operator_with(&["--metrics", &addr]);
    let python = std::env::var("FALC_PYTHON").unwrap_or_else(|_| "python3".into());
    let out = std::process::Command::new(python)
        .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/openmetrics.py"))
        .arg(format!("http://{addr}/metrics"))
        .output()
        .expect("python");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let samples: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).expect("a JSON line"))
        .collect();
    let value = |name: &str, labels: &[(&str, &str)]| -> f64 {
        samples
            .iter()
            .find(|s| s["name"] == name && labels.iter().all(|(k, v)| s["labels"][*k] == *v))
            .and_then(|s| s["value"].as_f64())
            .unwrap_or_else(|| panic!("no {name} {labels:?} in {stdout}"))
    };
    let done = |result: &str| {
        value(
            "falc_orders_total",
            &[("recipe", "dikdroog"), ("result", result)],
        )
    };
    assert_eq!((done("done"), done("failed")), (4.0, 1.0));
    assert_eq!(
        value("falc_cycle_time_seconds_count", &[("recipe", "dikdroog")]),
        4.0
    );
    let sum = value("falc_cycle_time_seconds_sum", &[("recipe", "dikdroog")]);
    let records_sum: i64 = orders
        .iter()
        .filter(|o| o.state == OrderState::Done)
        .map(|o| span(o).1 - span(o).0)
        .sum();
    assert!(
        (sum - records_sum as f64 / 1000.0).abs() < 1e-6,
        "{sum} {records_sum}"
    );
    assert_eq!(
        value(
            "falc_alarms_total",
            &[("station", "welding"), ("class", "safety")]
        ),
        1.0
    );
    let execute = value("falc_packml_state_seconds_total", &[("state", "Execute")]);
    assert!(
        (execute - production as f64 / 1000.0).abs() < 1e-6,
        "{execute} {production}"
    );
    assert!(
        text.contains("total") && text.contains("   4/5   ") && text.contains("80.0%"),
        "{text}"
    );
}
