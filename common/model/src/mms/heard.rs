//! What a receiver takes in of a station's publication (sans-I/O), at
//! every receiver (the operator, the cell, the simulation's bus alike):
//!
//! - **The sender is the key.** A publication counts as coming from the
//!   station whose key it arrived on (`falc/<cell>/<st>/status`, `…/report`,
//!   `…/reports`), which the router's access control ties to that station's
//!   credentials. A payload that names another station is refused whole
//!   ([`Refused::Forged`]): a station speaks only for itself.
//! - **Every text is bounded.** A report's text, an alarm's cause, why a
//!   station is not ready, a held step's command: each longer than
//!   [`MAX_PUBLISHED_CHARS`] is cut there and says so (the report keeps
//!   its number, so a reader that reads back finds no gap); more inputs
//!   than [`MAX_INPUTS`] are cut likewise. A run name longer than
//!   [`MAX_RUN_CHARS`] is no run a station makes: refused whole.
//!
//! The driver logs what [`take`] refused or cut, rate-limited per key.

use super::journal::{KeptReports, Publication};
use super::pdu::{JobEvent, Severity, Unconfirmed};
use crate::ids::StationName;

/// The longest text a station may publish in one field, in characters
/// (the cell's output lines have the same bound).
pub const MAX_PUBLISHED_CHARS: usize = crate::api::MAX_OUTPUT_CHARS;
/// The most inputs a status may carry (the 1992 conveyor has 21).
pub const MAX_INPUTS: usize = 256;
/// The longest run name (a bus session id has 32 hex digits).
pub const MAX_RUN_CHARS: usize = 128;

/// Why a publication was not taken in.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Refused {
    /// Its payload names another station than the key it came on.
    #[error(
        "a {kind} on {on}'s key names station {named}: refused (a station speaks only for itself)"
    )]
    Forged {
        /// The station whose key it came on.
        on: StationName,
        /// The station its payload names.
        named: StationName,
        /// What it was (status, job event, report).
        kind: &'static str,
    },
    /// Its number's run is longer than any a station makes.
    #[error("a {kind} on {on}'s key has a run name of {chars} characters (at most {MAX_RUN_CHARS}): refused")]
    Run {
        /// The station whose key it came on.
        on: StationName,
        /// How long the run name was.
        chars: usize,
        /// What it was.
        kind: &'static str,
    },
}

/// What kind of publication `m` is, for a log line.
pub fn kind(m: &Unconfirmed) -> &'static str {
    match m {
        Unconfirmed::Status { .. } => "status",
        Unconfirmed::Job { .. } => "job event",
        Unconfirmed::Report { .. } => "report",
    }
}

/// Takes in `message`, heard on station `on`'s key: refused if its payload
/// names another station; its texts cut to their bounds. The second value
/// says what was cut, for the log (None: nothing).
pub fn take(
    on: &StationName,
    message: Unconfirmed,
) -> Result<(Unconfirmed, Option<String>), Refused> {
    let what = kind(&message);
    if message.station() != on {
        return Err(Refused::Forged {
            on: on.clone(),
            named: message.station().clone(),
            kind: what,
        });
    }
    let mut cuts = Vec::new();
    let mut message = message;
    match &mut message {
        Unconfirmed::Report { text, .. } => cut(text, "its text", &mut cuts),
        Unconfirmed::Job {
            event: JobEvent::Alarm(cause),
            ..
        } => cut(&mut cause.text, "its alarm's cause", &mut cuts),
        Unconfirmed::Job { .. } => {}
        Unconfirmed::Status { status, .. } => {
            if let Some(why) = &mut status.unready {
                cut(why, "why it is not ready", &mut cuts);
            }
            if let Some(held) = &mut status.held {
                cut(&mut held.command, "its held step's command", &mut cuts);
            }
            if status.inputs.len() > MAX_INPUTS {
                cuts.push(format!(
                    "{} inputs cut to {MAX_INPUTS}",
                    status.inputs.len()
                ));
                status.inputs.truncate(MAX_INPUTS);
            }
        }
    }
    let note = (!cuts.is_empty()).then(|| format!("a {what} from {on}: {}", cuts.join("; ")));
    Ok((message, note))
}

/// Takes in a numbered publication heard on `on`'s key ([`take`], and its
/// stamp's run bounded).
pub fn take_publication(
    on: &StationName,
    p: Publication,
) -> Result<(Publication, Option<String>), Refused> {
    if let Some(stamp) = &p.stamp {
        check_run(on, &stamp.run, kind(&p.message))?;
    }
    let (message, note) = take(on, p.message)?;
    Ok((
        Publication {
            stamp: p.stamp,
            message,
        },
        note,
    ))
}

/// Refuses a run name longer than any a station makes.
fn check_run(on: &StationName, run: &str, kind: &'static str) -> Result<(), Refused> {
    let chars = run.chars().count();
    if chars > MAX_RUN_CHARS {
        return Err(Refused::Run {
            on: on.clone(),
            chars,
            kind,
        });
    }
    Ok(())
}

/// Cuts `text` to [`MAX_PUBLISHED_CHARS`] characters, saying so in it and
/// in `cuts`.
fn cut(text: &mut String, what: &str, cuts: &mut Vec<String>) {
    let chars = text.chars().count();
    if chars <= MAX_PUBLISHED_CHARS {
        return;
    }
    let end = text
        .char_indices()
        .nth(MAX_PUBLISHED_CHARS)
        .map_or(text.len(), |(i, _)| i);
    text.truncate(end);
    text.push_str(&format!(
        " … ({chars} characters, cut to {MAX_PUBLISHED_CHARS})"
    ));
    cuts.push(format!(
        "{what} of {chars} characters cut to {MAX_PUBLISHED_CHARS}"
    ));
}

/// What a station's answer of kept reports is taken in as: a
/// run name no station makes refuses it whole; a report naming another
/// station than `station` (the key's) keeps its number but becomes a
/// warning of `station`'s that says what was refused, so that the reader
/// finds no gap to read again; long texts are cut.
pub fn take_kept(station: &StationName, kept: KeptReports) -> Result<KeptReports, Refused> {
    let KeptReports {
        run,
        first,
        reports,
    } = kept;
    check_run(station, &run, "kept report")?;
    let mut taken = Vec::with_capacity(reports.len());
    for (s, m) in reports {
        check_run(station, &s.run, kind(&m))?;
        let m = match take(station, m) {
            Ok((m, _)) => m,
            Err(e) => Unconfirmed::Report {
                station: station.clone(),
                severity: Severity::Warning,
                text: e.to_string(),
            },
        };
        taken.push((s, m));
    }
    Ok(KeptReports {
        run,
        first,
        reports: taken,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::alarm::{AlarmClass, Cause};
    use crate::ids::ObjectName;
    use crate::mms::journal::Stamp;
    use crate::mms::pdu::Severity;
    use crate::mms::vmd::VmdStatus;
    use crate::mode::HeldStep;

    fn st(s: &str) -> StationName {
        StationName::new(s).expect("valid")
    }

    fn every_kind(named: &str) -> Vec<Unconfirmed> {
        vec![
            Unconfirmed::Status {
                station: st(named),
                status: VmdStatus::default(),
            },
            Unconfirmed::Job {
                station: st(named),
                program: ObjectName::new("DIKDROOG").expect("valid"),
                event: JobEvent::Done,
            },
            Unconfirmed::Job {
                station: st(named),
                program: ObjectName::new("DIKDROOG").expect("valid"),
                event: JobEvent::Alarm(Cause::new(AlarmClass::Device, "x")),
            },
            Unconfirmed::Report {
                station: st(named),
                severity: Severity::Alarm(AlarmClass::Safety),
                text: "forged".into(),
            },
        ]
    }

    #[test]
    fn a_payload_naming_another_station_than_its_key_is_refused_whatever_its_kind() {
        for m in every_kind("cell") {
            let k = kind(&m);
            let e = take(&st("welding"), m).expect_err("forged");
            assert_eq!(
                e,
                Refused::Forged {
                    on: st("welding"),
                    named: st("cell"),
                    kind: k
                }
            );
            assert!(e.to_string().contains("names station cell"), "{e}");
        }
        for m in every_kind("welding") {
            let (taken, note) = take(&st("welding"), m.clone()).expect("its own");
            assert_eq!((taken, note), (m, None));
        }
    }

    #[test]
    fn long_texts_are_cut_and_say_so() {
        let long = "é".repeat(16 * 1024 * 1024 / 2);
        let (m, note) = take(
            &st("welding"),
            Unconfirmed::Report {
                station: st("welding"),
                severity: Severity::Info,
                text: long.clone(),
            },
        )
        .expect("its own");
        let Unconfirmed::Report { text, .. } = m else {
            panic!("a report")
        };
        assert!(
            text.chars().count() < MAX_PUBLISHED_CHARS + 60,
            "{}",
            text.len()
        );
        assert!(
            text.ends_with("(8388608 characters, cut to 4096)"),
            "{}",
            &text[text.len() - 80..]
        );
        assert!(note.is_some_and(|n| n.contains("its text of 8388608 characters")));

        let status = VmdStatus {
            unready: Some(long.clone()),
            held: Some(HeldStep {
                state: 1,
                command: long.clone(),
            }),
            inputs: vec![true; 100_000],
            ..VmdStatus::default()
        };
        let (m, note) = take(
            &st("transport"),
            Unconfirmed::Status {
                station: st("transport"),
                status,
            },
        )
        .expect("its own");
        let Unconfirmed::Status { status, .. } = m else {
            panic!("a status")
        };
        assert!(status
            .unready
            .is_some_and(|u| u.len() < 2 * MAX_PUBLISHED_CHARS + 60));
        assert!(status
            .held
            .is_some_and(|h| h.command.len() < 2 * MAX_PUBLISHED_CHARS + 60));
        assert_eq!(status.inputs.len(), MAX_INPUTS);
        let note = note.expect("cut");
        assert!(
            note.contains("why it is not ready") && note.contains("100000 inputs"),
            "{note}"
        );

        let (m, _) = take(
            &st("welding"),
            Unconfirmed::Job {
                station: st("welding"),
                program: ObjectName::new("DROOG_DIK").expect("valid"),
                event: JobEvent::Alarm(Cause::new(AlarmClass::Device, long)),
            },
        )
        .expect("its own");
        assert!(
            matches!(m, Unconfirmed::Job { event: JobEvent::Alarm(c), .. } if c.text.len() < 2 * MAX_PUBLISHED_CHARS + 60)
        );
    }

    #[test]
    fn a_run_name_no_station_makes_is_refused() {
        let p = Publication {
            stamp: Some(Stamp {
                run: "r".repeat(MAX_RUN_CHARS + 1),
                no: 1,
                at_ms: 0,
            }),
            message: every_kind("welding").remove(3),
        };
        assert!(matches!(
            take_publication(&st("welding"), p),
            Err(Refused::Run { chars: 129, .. })
        ));
    }

    #[test]
    fn kept_reports_naming_another_station_become_a_warning_of_the_key_station_with_their_number() {
        let welding = StationName::new("welding").expect("valid");
        let stamp = |no| Stamp {
            run: "run".into(),
            no,
            at_ms: 5,
        };
        let forged = Unconfirmed::Job {
            station: StationName::new("cell").expect("valid"),
            program: ObjectName::new("DIKDROOG").expect("valid"),
            event: JobEvent::Done,
        };
        let own = Unconfirmed::Report {
            station: welding.clone(),
            severity: Severity::Info,
            text: "x".repeat(10_000),
        };
        let kept = KeptReports {
            run: "run".into(),
            first: 1,
            reports: vec![(stamp(1), forged), (stamp(2), own)],
        };
        let taken = take_kept(&welding, kept).expect("taken");
        assert_eq!(taken.reports.len(), 2);
        assert!(matches!(
            &taken.reports[0],
            (s, Unconfirmed::Report { station, severity: Severity::Warning, text })
                if s.no == 1 && *station == welding && text.contains("names station cell")
        ));
        assert!(matches!(
            &taken.reports[1],
            (s, Unconfirmed::Report { text, .. }) if s.no == 2 && text.len() < 4_200
        ));
        let long_run = KeptReports {
            run: "r".repeat(1_000),
            first: 1,
            reports: Vec::new(),
        };
        assert!(take_kept(&welding, long_run).is_err());
    }
}
