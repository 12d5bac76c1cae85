//! The operator's alarm list: every alarm of every station (and the
//! operator's own), with its class, state and who acknowledged it. Rules:
//! - the same text from the same station while unacknowledged is one alarm,
//!   and so is a commander's alarm that only passes a subordinate's on
//!   ("alarm from welding: T" while welding's "T" waits): one fault, one
//!   alarm to acknowledge, under the station where it happened;
//! - a process alarm (a recipe's alarm state, a failed order) has no
//!   lasting condition: it is raised cleared and waits only for its
//!   acknowledgement;
//! - safety, device and communication alarms clear when the station that
//!   raised them shows its condition gone ([`condition_holds`]: present,
//!   operational, the robot's status without an intervention);
//! - an alarm leaves the list once acknowledged and cleared;
//! - every class but a warning holds `start` back until acknowledged.
//!
//! The list is kept in the [`Records`]; a write that fails keeps the change
//! in memory (an alarm not stored gets a negative number) and returns the
//! error for the caller to stop the cell.

use crate::records::Records;
use falc_model::alarm::{passed_on_from, Alarm, AlarmClass, UNSTORED_ALARM_IDS};
use falc_model::ids::StationName;
use falc_model::mms::vmd::{PhysicalStatus, RobotStatusDetail, RobotVmdState, VmdStatus};

/// What raising an alarm did.
#[derive(Debug)]
pub enum Raised {
    /// A new alarm.
    New(Alarm),
    /// The same alarm is already waiting for its acknowledgement.
    Repeated(i64),
}

/// The alarms in the list, oldest first.
#[derive(Debug, Default)]
pub struct AlarmList {
    listed: Vec<Alarm>,
    /// How many alarms the database could not keep (numbered from
    /// [`UNSTORED_ALARM_IDS`]).
    unstored: i64,
}

/// Whether the condition behind `alarm` still holds, from the raising
/// station's latest status and presence.
pub fn condition_holds(alarm: &Alarm, status: Option<&VmdStatus>, present: bool) -> bool {
    match alarm.class {
        AlarmClass::Process => false,
        AlarmClass::Safety
        | AlarmClass::Device
        | AlarmClass::Communication
        | AlarmClass::Warning => {
            let Some(s) = status else { return true };
            let robot_needs_a_person = s.additional.is_some_and(|d| {
                d.state == RobotVmdState::ManualInterventionRequired
                    || d.specific & RobotStatusDetail::SAFETY_INTERLOCKS_VIOLATED != 0
            });
            !present || s.physical != PhysicalStatus::Operational || robot_needs_a_person
        }
    }
}

/// Whether `text` says that `station` cannot be reached ("no connection
/// with station WELDING", also inside a passed-on alarm), not another
/// station whose name begins the same.
pub fn names_lost(text: &str, station: &str) -> bool {
    let text = text.to_lowercase();
    let needle = format!("no connection with station {}", station.to_lowercase());
    text.match_indices(&needle).any(|(at, _)| {
        !text[at + needle.len()..]
            .chars()
            .next()
            .is_some_and(|c| c.is_alphanumeric() || c == '_' || c == '-')
    })
}

impl AlarmList {
    /// The list as the database holds it.
    pub fn load<R: Records>(db: &R) -> Result<Self, R::Error> {
        Ok(Self {
            listed: db.listed_alarms()?,
            unstored: 0,
        })
    }

    /// Every alarm in the list, oldest first.
    pub fn listed(&self) -> &[Alarm] {
        &self.listed
    }

    /// The alarm that holds `start` back: the highest priority, then the
    /// oldest, of those waiting for an acknowledgement.
    pub fn blocking(&self) -> Option<&Alarm> {
        self.listed
            .iter()
            .filter(|a| a.blocks_start())
            .min_by_key(|a| (a.class.priority(), a.id))
    }

    /// Raises an alarm of `station`. On a database failure the alarm is kept
    /// in memory and the error returned with it.
    pub fn raise<R: Records>(
        &mut self,
        db: &mut R,
        station: &StationName,
        class: AlarmClass,
        text: &str,
        order: Option<i64>,
    ) -> (Raised, Option<R::Error>) {
        // `upper` is `lower`'s alarm passed on by its commander.
        let passes_on =
            |upper: &str, from: &str, lower: &str| passed_on_from(upper, from) == Some(lower);
        if let Some(a) = self.listed.iter().find(|a| {
            a.acked.is_none()
                && ((a.station == *station && a.text == text)
                    || passes_on(text, a.station.as_str(), &a.text)
                    || passes_on(&a.text, station.as_str(), text))
        }) {
            return (Raised::Repeated(a.id), None);
        }
        let (alarm, error) = match db.raise_alarm(station, class, text, order) {
            Ok(a) => (a, None),
            Err(e) => {
                self.unstored += 1;
                let a = Alarm {
                    id: UNSTORED_ALARM_IDS + self.unstored,
                    station: station.clone(),
                    class,
                    text: text.to_string(),
                    order,
                    raised_ms: db.now_ms(),
                    acked: None,
                    cleared_ms: None,
                };
                (a, Some(e))
            }
        };
        let id = alarm.id;
        self.listed.push(alarm);
        let mut error = error;
        if class == AlarmClass::Process {
            error = error.or(self.clear_where(db, |a| a.id == id).1);
        }
        let alarm = self
            .listed
            .iter()
            .find(|a| a.id == id)
            .cloned()
            .unwrap_or_else(|| unreachable!("alarm #{id} was just listed"));
        (Raised::New(alarm), error)
    }

    /// Acknowledges alarm `id`, or every unacknowledged one (`None`), for
    /// `who`. Returns the alarms acknowledged now (none is not an error),
    /// or why not: no such alarm.
    pub fn ack<R: Records>(
        &mut self,
        db: &mut R,
        id: Option<i64>,
        who: &str,
    ) -> Result<(Vec<Alarm>, Option<R::Error>), String> {
        if let Some(id) = id {
            if !self.listed.iter().any(|a| a.id == id) {
                let known: Vec<String> = self.listed.iter().map(|a| format!("#{}", a.id)).collect();
                return Err(format!(
                    "there is no alarm #{id} in the list{}",
                    if known.is_empty() {
                        " (it is empty)".to_string()
                    } else {
                        format!(" ({})", known.join(", "))
                    }
                ));
            }
        }
        Ok(self.mark(
            db,
            |a| a.acked.is_none() && id.map_or(true, |i| i == a.id),
            |a, at| a.acked = Some((who.to_string(), at)),
            |db, id, at| db.ack_alarm(id, who, at),
        ))
    }

    /// Clears the alarms of `station` whose condition no longer holds.
    /// Returns those cleared now.
    pub fn settle<R: Records>(
        &mut self,
        db: &mut R,
        station: &StationName,
        status: Option<&VmdStatus>,
        present: bool,
    ) -> (Vec<Alarm>, Option<R::Error>) {
        self.clear_where(db, |a| {
            a.station == *station && !condition_holds(a, status, present)
        })
    }

    /// Clears the communication alarms that say `station` cannot be
    /// reached, whoever raised them (the operator, or the cell passing its
    /// lost workstation on): the station is back on the bus.
    pub fn settle_reached<R: Records>(
        &mut self,
        db: &mut R,
        station: &str,
    ) -> (Vec<Alarm>, Option<R::Error>) {
        self.clear_where(db, |a| {
            a.class == AlarmClass::Communication && names_lost(&a.text, station)
        })
    }

    /// Clears every uncleared alarm `which` selects (its condition is
    /// known to be gone: the cell is back, the database can be written);
    /// those leave the list that are acknowledged too. Returns those
    /// cleared now.
    pub fn clear_where<R: Records>(
        &mut self,
        db: &mut R,
        which: impl Fn(&Alarm) -> bool,
    ) -> (Vec<Alarm>, Option<R::Error>) {
        self.mark(
            db,
            |a| a.cleared_ms.is_none() && which(a),
            |a, at| a.cleared_ms = Some(at),
            |db: &mut R, id, at| db.clear_alarm(id, at),
        )
    }

    /// Sets what `set` sets on every alarm `which` selects, and writes it
    /// with `write` (not for an alarm the database never kept); drops what
    /// is acknowledged and cleared from the list. Returns those changed.
    fn mark<R: Records>(
        &mut self,
        db: &mut R,
        which: impl Fn(&Alarm) -> bool,
        set: impl Fn(&mut Alarm, i64),
        write: impl Fn(&mut R, i64, i64) -> Result<(), R::Error>,
    ) -> (Vec<Alarm>, Option<R::Error>) {
        let at = db.now_ms();
        let mut error = None;
        let mut changed = Vec::new();
        for a in self.listed.iter_mut().filter(|a| which(a)) {
            if a.id < UNSTORED_ALARM_IDS {
                if let Err(e) = write(db, a.id, at) {
                    // Not written, not changed here either: the list and
                    // the records agree, and the change is made at the next
                    // chance (the next settle, the next ack). Found by
                    // falc-sim: a clear the full disk refused left the alarm
                    // open in the records for good, gone from the list.
                    error.get_or_insert(e);
                    continue;
                }
            }
            set(a, at);
            changed.push(a.clone());
        }
        self.listed.retain(Alarm::listed);
        (changed, error)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::records::memory::Memory;

    fn st(s: &str) -> StationName {
        StationName::new(s).expect("station name")
    }

    fn status(physical: PhysicalStatus) -> VmdStatus {
        VmdStatus {
            physical,
            ..VmdStatus::default()
        }
    }

    #[test]
    fn a_change_the_records_refuse_is_not_made_in_the_list_either() {
        let mut s = Memory::default();
        let mut l = AlarmList::load(&s).expect("load");
        let (r, _) = l.raise(
            &mut s,
            &st("welding"),
            AlarmClass::Communication,
            "silent",
            Some(1),
        );
        let Raised::New(a) = r else { panic!("{r:?}") };
        let (acked, e) = l.ack(&mut s, None, "console").expect("listed");
        assert!(e.is_none() && acked.len() == 1);
        // The disk is full when the condition goes: not cleared anywhere.
        s.failing = true;
        let (cleared, e) = l.clear_where(&mut s, |x| x.id == a.id);
        assert!(cleared.is_empty() && e.is_some());
        assert!(
            l.listed().iter().any(|x| x.id == a.id),
            "listed as the records hold it"
        );
        // Room again: the next chance clears it in both.
        s.failing = false;
        let (cleared, e) = l.clear_where(&mut s, |x| x.id == a.id);
        assert!(e.is_none() && cleared.len() == 1);
        assert!(l.listed().is_empty());
        assert!(!s.alarms.iter().any(Alarm::listed));
    }

    #[test]
    fn raise_repeat_ack_and_clear() {
        let mut s = Memory::default();
        let mut l = AlarmList::load(&s).expect("load");
        let (r, e) = l.raise(
            &mut s,
            &st("transport"),
            AlarmClass::Safety,
            "estop",
            Some(1),
        );
        assert!(e.is_none());
        let Raised::New(a) = r else { panic!("{r:?}") };
        // The same again while unacknowledged: one alarm.
        assert!(matches!(
            l.raise(&mut s, &st("transport"), AlarmClass::Safety, "estop", Some(1)).0,
            Raised::Repeated(id) if id == a.id
        ));
        let (p, _) = l.raise(
            &mut s,
            &st("cell"),
            AlarmClass::Process,
            "alarm in state 19",
            Some(1),
        );
        let Raised::New(p) = p else { panic!() };
        assert!(
            p.cleared_ms.is_some(),
            "a process alarm has no lasting condition"
        );
        // Safety first, whatever came later.
        assert_eq!(l.blocking().map(|b| b.id), Some(a.id));
        // Still in emergency stop: not cleared.
        let (c, _) = l.settle(
            &mut s,
            &st("transport"),
            Some(&status(PhysicalStatus::Inoperable)),
            true,
        );
        assert!(c.is_empty());
        let (acked, _) = l.ack(&mut s, Some(a.id), "ann").expect("ack");
        assert_eq!(acked.len(), 1);
        assert_eq!(l.blocking().map(|b| b.id), Some(p.id));
        assert_eq!(l.listed().len(), 2, "acknowledged, the stop still pressed");
        let (c, _) = l.settle(
            &mut s,
            &st("transport"),
            Some(&status(PhysicalStatus::Operational)),
            true,
        );
        assert_eq!(c.len(), 1);
        assert_eq!(l.listed().len(), 1, "acknowledged and cleared: gone");
        assert!(l.ack(&mut s, Some(99), "ann").is_err());
        let (acked, _) = l.ack(&mut s, None, "bob").expect("ack all");
        assert_eq!(acked.len(), 1);
        assert!(l.listed().is_empty() && l.blocking().is_none());
        // The database agrees.
        assert!(AlarmList::load(&s).expect("load").listed().is_empty());
    }

    #[test]
    fn an_alarm_passed_up_is_the_same_alarm() {
        let mut s = Memory::default();
        let mut l = AlarmList::load(&s).expect("load");
        let (r, _) = l.raise(
            &mut s,
            &st("welding"),
            AlarmClass::Safety,
            "RCM message 24",
            Some(1),
        );
        let Raised::New(w) = r else { panic!() };
        let text = "alarm from welding: RCM message 24";
        assert!(matches!(
            l.raise(&mut s, &st("cell"), AlarmClass::Safety, text, Some(1)).0,
            Raised::Repeated(id) if id == w.id
        ));
        assert_eq!(l.listed().len(), 1);
        // Whichever arrives first.
        let (_, _) = l.raise(
            &mut s,
            &st("cell"),
            AlarmClass::Device,
            "alarm from transport: jam",
            None,
        );
        assert!(matches!(
            l.raise(&mut s, &st("transport"), AlarmClass::Device, "jam", None)
                .0,
            Raised::Repeated(_)
        ));
        assert_eq!(l.listed().len(), 2);
        // Once acknowledged, a new fault is a new alarm.
        l.ack(&mut s, None, "ann").expect("ack");
        assert!(matches!(
            l.raise(&mut s, &st("cell"), AlarmClass::Safety, text, Some(2))
                .0,
            Raised::New(_)
        ));
    }

    #[test]
    fn conditions_by_class() {
        let mk = |class| Alarm {
            id: 1,
            station: st("welding"),
            class,
            text: "x".into(),
            order: None,
            raised_ms: 0,
            acked: None,
            cleared_ms: None,
        };
        let ok = status(PhysicalStatus::Operational);
        let mut robot = ok.clone();
        robot.additional = Some(RobotStatusDetail {
            state: RobotVmdState::ManualInterventionRequired,
            specific: RobotStatusDetail::SAFETY_INTERLOCKS_VIOLATED,
            mask: 0,
        });
        let safety = mk(AlarmClass::Safety);
        assert!(condition_holds(&safety, Some(&robot), true));
        assert!(!condition_holds(&safety, Some(&ok), true));
        assert!(
            condition_holds(&safety, Some(&ok), false),
            "gone from the bus"
        );
        assert!(condition_holds(&safety, None, true), "no status yet");
        assert!(!condition_holds(&mk(AlarmClass::Process), None, false));
    }

    #[test]
    fn a_store_that_fails_keeps_the_alarm_in_memory() {
        let mut s = Memory::default();
        let mut l = AlarmList::load(&s).expect("load");
        // Every write fails from now on.
        s.failing = true;
        let (r, e) = l.raise(
            &mut s,
            &st("operator"),
            AlarmClass::Device,
            "disk full",
            None,
        );
        assert!(e.is_some());
        let Raised::New(a) = r else { panic!() };
        assert_eq!(a.id, UNSTORED_ALARM_IDS + 1, "not stored, positive: {a:?}");
        assert_eq!(l.blocking().map(|b| b.id), Some(a.id));
        let (acked, e) = l.ack(&mut s, None, "ann").expect("ack");
        assert_eq!(acked.len(), 1);
        assert!(e.is_none(), "nothing to write for an unstored alarm");
    }
}
