//! No report lost across a cut: the reader's half of the stations' kept
//! reports ([`falc_model::mms::journal`]). Each station numbers its reports
//! and job events; the list files them in number order. A station back on
//! the bus, or a number that skips, makes the list read what the station
//! kept after the last one it filed ([`Output::ReadReports`]); what comes
//! back is filed in order with its own time and marked ` (replayed)`, and
//! what fell out of the station's buffer is journalled as lost. While a
//! read is out, live reports of that station are left to it (the station
//! keeps them), so nothing is filed twice or out of order. The cell's job
//! events are the exception: they end orders, so each is taken as it
//! comes and never from a read (a late one could end a later order of the
//! same recipe; one lost in a cut is asked for when the cell is back).
//!
//! The last number filed of each station's run is kept in the records as
//! it is filed ([`Records::report_filed`]): an operator started again
//! begins from there ([`kept_filed`]) and reads back, when each station is
//! on the bus, what it reported while the operator was down.

use super::*;
use falc_model::mms::journal::{KeptReports, Stamp};

/// How long after a failed read the list reads again.
const READ_AGAIN: Duration = Duration::from_secs(1);

/// What a replayed entry's text ends with.
pub const REPLAYED: &str = " (replayed)";

/// What the list has of one station's numbered reports.
#[derive(Debug)]
pub(super) struct Heard {
    /// The station's run the numbers are of.
    run: String,
    /// The last number filed.
    last: u64,
    /// The highest number heard (filed, or left to a read).
    seen: u64,
    reading: Reading,
    /// Numbers up to this one came before the list heard the run.
    base: u64,
    /// Numbers after `base` accounted for: filed (live or read back),
    /// taken as they came (the cell's job events), or reported lost.
    count: u64,
}

impl Heard {
    fn new(run: &str, base: u64, reading: Reading) -> Self {
        Self {
            run: run.to_string(),
            last: base,
            seen: 0,
            reading,
            base,
            count: 0,
        }
    }

    /// The next number in order was filed.
    fn filed(&mut self, no: u64) {
        self.last = no;
        self.count += 1;
    }
}

/// What the records say was filed last of each station: where a list
/// started again begins (nothing asked yet; a station on the bus is read
/// from there). Unreadable records: nothing, as for a new file (logged).
pub(super) fn kept_filed<R: Records>(db: &R) -> BTreeMap<StationName, Heard> {
    match db.reports_filed() {
        Ok(filed) => filed
            .into_iter()
            .filter_map(|(station, run, no)| {
                let station = StationName::new(&station).ok()?;
                Some((station, Heard::new(&run, no, Reading::No)))
            })
            .collect(),
        Err(e) => {
            tracing::error!(
                "{e}: reports the stations made while the operator was down are not read back"
            );
            BTreeMap::new()
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Reading {
    /// Nothing asked.
    No,
    /// A read is out.
    Out,
    /// A read failed: read again at this time.
    Again(Duration),
}

impl<R: Records, S: RecipeSource> OrderList<R, S> {
    /// A station's publication as heard on the bus, numbered or not.
    pub fn handle_heard(&mut self, now: Duration, stamp: Option<Stamp>, u: Unconfirmed) {
        self.tick(now);
        match stamp {
            None => self.publication(now, u),
            Some(stamp) => self.numbered(now, stamp, u),
        }
        self.pump(now);
    }

    fn numbered(&mut self, now: Duration, stamp: Stamp, u: Unconfirmed) {
        let station = u.station().clone();
        // First heard: what came before is not this list's to ask for.
        let h = self
            .heard
            .entry(station.clone())
            .or_insert_with(|| Heard::new(&stamp.run, stamp.no.saturating_sub(1), Reading::No));
        if h.run != stamp.run {
            // The station's node started again: its numbers start again.
            *h = Heard::new(&stamp.run, 0, h.reading);
        }
        h.seen = h.seen.max(stamp.no);
        // The cell's job events end orders: each is taken as it comes,
        // never left to a read (a late replay of one could end a later
        // order of the same recipe; one lost in a cut is asked for, Away).
        if matches!(&u, Unconfirmed::Job { station, .. } if *station == self.cell) {
            if h.reading != Reading::Out && stamp.no > h.last {
                if stamp.no == h.last + 1 {
                    h.filed(stamp.no);
                    self.keep_filed(&station);
                } else {
                    self.read_kept(station);
                }
            }
            return self.publication(now, u);
        }
        if h.reading == Reading::Out || stamp.no <= h.last {
            return;
        }
        if stamp.no == h.last + 1 {
            h.filed(stamp.no);
            self.publication(now, u);
            return self.keep_filed(&station);
        }
        self.read_kept(station);
    }

    /// Keeps in the records the last number filed of `station` (a failed
    /// write stops the list, as any: [`Self::db_failed`]).
    fn keep_filed(&mut self, station: &StationName) {
        let Some(h) = self.heard.get(station) else {
            return;
        };
        let (run, last) = (h.run.clone(), h.last);
        if let Err(e) = self.db.report_filed(station.as_str(), &run, last) {
            self.db_failed(&e);
        }
    }

    /// Asks `station` for what it kept after the last report filed.
    pub(super) fn read_kept(&mut self, station: StationName) {
        let Some(h) = self.heard.get_mut(&station) else {
            return;
        };
        h.reading = Reading::Out;
        let after = h.last;
        self.say(format!(
            "EVENT read-reports station={station} after={after}"
        ));
        self.out.push_back(Output::ReadReports { station, after });
    }

    /// A station is back on the bus: what it reported while it could not
    /// be heard is read, if it ever was heard.
    pub(super) fn heard_back(&mut self, station: &StationName) {
        if self
            .heard
            .get(station)
            .is_some_and(|h| h.reading != Reading::Out)
        {
            self.read_kept(station.clone());
        }
    }

    /// The answer to [`Output::ReadReports`]: what `station` kept, filed
    /// in order, or why it could not be read (read again shortly while it
    /// is on the bus, else when it is back).
    pub fn handle_kept_reports(
        &mut self,
        now: Duration,
        station: StationName,
        answer: Result<KeptReports, String>,
    ) {
        self.tick(now);
        let present = self.present.contains(&station);
        let Some(h) = self.heard.get_mut(&station) else {
            return;
        };
        let kept = match answer {
            Ok(k) => k,
            Err(e) => {
                h.reading = if present {
                    Reading::Again(now + READ_AGAIN)
                } else {
                    Reading::No
                };
                self.say(format!("EVENT read-reports-failed station={station}: {e}"));
                return self.pump(now);
            }
        };
        h.reading = Reading::No;
        if kept.run != h.run {
            // Started again since: its new run is read from the start.
            *h = Heard::new(&kept.run, 0, Reading::No);
        }
        let lost = kept.lost_after(h.last);
        h.last = h.last.max(kept.first.saturating_sub(1));
        h.count += lost;
        if lost > 0 {
            let text = format!("{lost} reports lost while the link was down");
            let order = self.order_of_message(now);
            self.journal(EntryKind::Report, order, station.as_str(), &text);
        }
        let mut filed = 0;
        for (stamp, u) in kept.reports {
            let Some(h) = self.heard.get_mut(&station) else {
                break;
            };
            if stamp.no <= h.last || *u.station() != station {
                continue;
            }
            if stamp.no != h.last + 1 {
                // A station that skips its own numbers: what is missing
                // is missing.
                h.count += stamp.no - h.last - 1;
            }
            h.filed(stamp.no);
            h.seen = h.seen.max(stamp.no);
            filed += 1;
            self.replayed(now, stamp.at_ms, u);
        }
        // What fell out of the buffer counts as filed too: never asked
        // for again.
        self.keep_filed(&station);
        self.say(format!(
            "EVENT replayed station={station} reports={filed} lost={lost}"
        ));
        // An alarm filed late whose condition is gone by now (the station
        // back and operational) is cleared at once, not at its next status.
        if filed > 0 {
            self.settle_alarms(&station);
        }
        // Heard while the read was out, made after it was answered.
        if self.heard.get(&station).is_some_and(|h| h.seen > h.last) {
            self.read_kept(station);
        }
        self.pump(now);
    }

    /// Files a report or job event that was read again, with its own time.
    fn replayed(&mut self, now: Duration, at_ms: i64, u: Unconfirmed) {
        self.replaying = Some(at_ms);
        match u {
            Unconfirmed::Report {
                station,
                severity,
                text,
            } => self.station_report(now, station, severity, text),
            // How the cell's run of an order ended is asked for when the
            // cell is associated again ([`Away`]), not taken from a replay.
            Unconfirmed::Job { station, .. } if station == self.cell => {}
            Unconfirmed::Job {
                station,
                program,
                event,
            } => self.workstation_job(now, station, program, event),
            Unconfirmed::Status { .. } => {}
        }
        self.replaying = None;
    }

    /// The run of `station` the list files, the last number it filed, and
    /// how many numbers before that it never accounted for (filed, taken
    /// as they came, or reported lost): 0 unless a report went missing.
    /// None if it has not heard the station since it started.
    pub fn filed(&self, station: &StationName) -> Option<(&str, u64, u64)> {
        self.heard.get(station).map(|h| {
            let holes = (h.last - h.base).saturating_sub(h.count);
            (h.run.as_str(), h.last, holes)
        })
    }

    /// When a failed read is tried again.
    pub(super) fn read_again_at(&self) -> Option<Duration> {
        self.heard
            .values()
            .filter_map(|h| match h.reading {
                Reading::Again(at) => Some(at),
                _ => None,
            })
            .min()
    }

    /// Reads again where a failed read's time has come.
    pub(super) fn read_again(&mut self, now: Duration) {
        let due: Vec<StationName> = self
            .heard
            .iter()
            .filter(|(_, h)| matches!(h.reading, Reading::Again(at) if at <= now))
            .map(|(s, _)| s.clone())
            .collect();
        for station in due {
            self.read_kept(station);
        }
    }
}
