//! Recipe benchmark: parse + check of the whole `recipes/` tree (as the
//! recipe store does at start-up), and the interpreter's cost per step
//! (one event in, the state entered, its actions out) on a fake clock.
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
