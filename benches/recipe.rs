//! Recipe benchmark: parse + check of the whole `recipes/` tree (as the
//! recipe store does at start-up), the interpreter's cost per step (one
//! event in, the state entered, its actions out) on a fake clock, and the
//! verifier across levels: its explored states and time for the shipped
//! set and for 20 generated cell recipes over the shipped workstation
//! recipes.
//!
//! Run: `cargo bench --bench recipe`. Prints medians; asserts nothing
//! about time.

// A benchmark is a test program: it may stop on what it cannot measure.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use falc_model::ids::StationName;
use falc_recipe::check::{check_set, Entry, Program};
use falc_recipe::commands::RecipeKind;
use falc_recipe::engine::{Engine, Event, JobEnd};
use falc_recipe::syntax::parse;
use falc_recipe::verify::verify;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

#[path = "../tests/support/stats.rs"]
#[allow(dead_code)]
mod stats;
use stats::median;

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("recipes");
    // Read once: the figure is parse + check, not the disk.
    let mut texts = Vec::new();
    for kind in RecipeKind::ALL {
        let dir = root.join(kind.to_string());
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .expect("recipes dir")
            .filter_map(Result::ok)
            .map(|e| e.path())
            .collect();
        files.sort();
        for f in files {
            texts.push((
                kind,
                std::fs::read_to_string(&f).expect("readable"),
                f.display().to_string(),
            ));
        }
    }
    let lines: usize = texts.iter().map(|(_, t, _)| t.lines().count()).sum();
    let run = || {
        let entries: Vec<Entry> = texts
            .iter()
            .map(|(kind, text, origin)| Entry {
                station: StationName::new(&kind.to_string()).expect("valid"),
                kind: *kind,
                recipe: parse(text, origin),
                text: text.to_string(),
            })
            .collect();
        check_set(&entries)
    };
    let (programs, problems) = run();
    assert!(problems.is_empty(), "{problems:?}");
    verifier(&programs);
    let samples: Vec<Duration> = (0..200)
        .map(|_| {
            let t = Instant::now();
            std::hint::black_box(run());
            t.elapsed()
        })
        .collect();
    println!(
        "parse + check of recipes/ ({} recipes, {lines} lines), n=200: median {:.1} µs",
        texts.len(),
        median(&samples).as_secs_f64() * 1e6
    );

    // The interpreter: dikdroog's main path, 'ja' answered, every job done.
    let dik: Arc<Program> = Arc::new(
        programs
            .into_iter()
            .find(|(_, p)| p.origin.ends_with("dikdroog.rcp"))
            .map(|(_, p)| p)
            .expect("dikdroog"),
    );
    let st = |s: &str| StationName::new(s).expect("valid");
    let script = [
        Event::Answer("ja".into()),
        Event::Started(st("transport")),
        Event::Ended(st("transport"), JobEnd::Done),
        Event::Started(st("transport")),
        Event::Ended(st("transport"), JobEnd::Done),
        Event::Started(st("welding")),
        Event::Started(st("transport")),
        Event::Ended(st("transport"), JobEnd::Done),
        Event::Ended(st("welding"), JobEnd::Done),
        Event::Started(st("transport")),
        Event::Ended(st("transport"), JobEnd::Done),
    ];
    let mut per_step = Vec::new();
    let mut steps = 0;
    for _ in 0..2000 {
        let t = Instant::now();
        let mut e = Engine::new(dik.clone());
        e.start(Duration::ZERO);
        for (i, ev) in script.iter().enumerate() {
            e.handle(Duration::from_secs(i as u64), ev.clone());
            while let Some(a) = e.poll_action() {
                std::hint::black_box(a);
            }
        }
        let elapsed = t.elapsed();
        assert!(e.outcome().is_some(), "dikdroog did not end");
        steps = e.steps();
        per_step.push(elapsed / steps as u32);
    }
    println!(
        "interpreter, dikdroog main path ({steps} states entered, {} events), n=2000: median {:.0} ns per state",
        script.len(),
        median(&per_step).as_secs_f64() * 1e9
    );
}

/// The verifier on the shipped set, and on 20 generated cell recipes (with
/// the shipped workstation recipes below): states explored, median time.
fn verifier(shipped: &[(StationName, Program)]) {
    let time = |set: &[(StationName, Program)]| {
        let report = verify(set);
        let samples: Vec<Duration> = (0..20)
            .map(|_| {
                let t = Instant::now();
                std::hint::black_box(verify(set));
                t.elapsed()
            })
            .collect();
        (report, median(&samples))
    };
    let (report, took) = time(shipped);
    println!(
        "verify across levels, recipes/ ({} recipes), n=20: {} states, median {:.2} ms; {} defects, {} notes",
        shipped.len(),
        report.states,
        took.as_secs_f64() * 1e3,
        report.defects().count(),
        report.findings.len() - report.defects().count()
    );
    let mut set: Vec<(StationName, Program)> = shipped
        .iter()
        .filter(|(_, p)| p.kind.is_workstation())
        .cloned()
        .collect();
    let cell = StationName::new("cell").expect("valid");
    let mut lines = 0;
    for k in 0..20 {
        let text = generated(k);
        lines += text.lines().count();
        let origin = format!("generated{k}.rcp");
        let p = falc_recipe::check::check(&parse(&text, &origin), RecipeKind::Cell)
            .unwrap_or_else(|e| panic!("{origin}: {e:?}\n{text}"));
        set.push((cell.clone(), p));
    }
    let (report, took) = time(&set);
    println!(
        "verify across levels, 20 generated cell recipes ({lines} lines) + the shipped workstation recipes, n=20: {} states, median {:.2} ms; {} defects, {} notes",
        report.states,
        took.as_secs_f64() * 1e3,
        report.defects().count(),
        report.findings.len() - report.defects().count()
    );
}

/// Cell recipe `k`: 2 + k % 5 rounds of a question, a transport job and a
/// weld running while the carriers move, every failure to an alarm state.
fn generated(k: usize) -> String {
    const MOVES: [&str; 4] = ["store", "move_to_man", "unstore", "unload"];
    const WELDS: [&str; 3] = ["droog_dik", "droog_dun", "droog_pijp"];
    let rounds = 2 + k % 5;
    let alarm = rounds * 8 + 1;
    let mut out = format!("generated cell recipe {k}: {rounds} rounds\n\n");
    for r in 0..rounds {
        let s = r * 8 + 1;
        let next = if r + 1 == rounds { 0 } else { s + 8 };
        let m = MOVES[(k + r) % 4];
        let w = WELDS[(k + r) % 3];
        for line in [
            format!("-{s} | output ronde {r} | | | {}", s + 1),
            format!(
                "-{} | input (ja/nee/opnieuw) | | answer=ja | {}",
                s + 1,
                s + 2
            ),
            format!(
                "-{} | input (ja/nee/opnieuw) | | answer=nee | {alarm}",
                s + 1
            ),
            format!(
                "-{} | input (ja/nee/opnieuw) | | answer=* | {}",
                s + 1,
                s + 1
            ),
            format!("-{} | start transport {m} | | gestart | {}", s + 2, s + 3),
            format!("-{} | start transport {m} | | tijdlimiet | {alarm}", s + 2),
            format!("-{} | wait transport 90 | | klaar | {}", s + 3, s + 4),
            format!("-{} | wait transport 90 | | tijdlimiet | {alarm}", s + 3),
            format!("-{} | start welding {w} 180 | | gestart | {}", s + 4, s + 5),
            format!(
                "-{} | start welding {w} 180 | | tijdlimiet | {alarm}",
                s + 4
            ),
            format!(
                "-{} | start transport unload | | gestart | {}",
                s + 5,
                s + 6
            ),
            format!(
                "-{} | start transport unload | | tijdlimiet | {alarm}",
                s + 5
            ),
            format!("-{} | wait transport 70 | | klaar | {}", s + 6, s + 7),
            format!("-{} | wait transport 70 | | tijdlimiet | {alarm}", s + 6),
            format!("-{} | wait welding | | klaar | {next}", s + 7),
            format!("-{} | wait welding | | bad_product | {s}", s + 7),
            format!("-{} | wait welding | | tijdlimiet | {alarm}", s + 7),
        ] {
            out.push_str(&line);
            out.push('\n');
        }
    }
    out.push_str(&format!("-{alarm} | output er is wat mis | alarm | | 0\n"));
    out
}
