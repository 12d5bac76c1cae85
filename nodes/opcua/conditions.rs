//! Every alarm of the alarm list as an OPC UA Alarms & Conditions
//! condition (OPC 10000-9, `AlarmConditionType`), sans-I/O: the alarm
//! lists the gateway looks at go in, the condition states to send as
//! events come out, and the two methods a client calls on a condition are
//! checked here (Acknowledge names a condition and one of its events;
//! ConditionRefresh asks for every condition still retained).
//!
//! One condition per alarm, its id (`FALC.Conditions.7`, in a plant
//! `FALC.falc2.Conditions.7`) in the gateway's namespace:
//! - ActiveState is true while the alarm's cause lasts (not cleared);
//! - AckedState is true once someone acknowledged it (`falc ack N`, the
//!   Acknowledge method, a console);
//! - Retain is true while it is active or unacknowledged; an alarm that
//!   left the list (acknowledged and cleared) is sent once more with
//!   Retain false, then forgotten;
//! - Severity by its class ([`crate::space::severity`]), source its
//!   station.
//!
//! Each state sent is an event of its own with an EventId of its own
//! (`<condition>#<n>`); Acknowledge must name one of the condition's.

use crate::space::{self, Scope};
use falc_model::alarm::{Alarm, AlarmClass};
use std::collections::BTreeMap;

/// The state of one condition, as the event that says it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Condition {
    /// Its node id (in the gateway's namespace).
    pub node: String,
    /// The object of the scope it belongs to (`FALC`, `FALC.falc2`).
    pub root: String,
    /// The scope it belongs to (an index of the gateway's scopes).
    pub scope: usize,
    /// The alarm's number (`falc ack N`).
    pub alarm: i64,
    /// The alarm's class.
    pub class: AlarmClass,
    /// The station that raised it.
    pub station: String,
    /// The station's node (its `Stations.<station>` object; the scope's
    /// object for a station the topology does not name).
    pub source: String,
    /// Severity 1–1000.
    pub severity: u16,
    /// The alarm in a line ([`space::alarm_text`]).
    pub text: String,
    /// Its cause lasts.
    pub active: bool,
    /// Someone acknowledged it.
    pub acked: bool,
    /// Who acknowledged it.
    pub acked_by: Option<String>,
    /// When this state began (ms since the Unix epoch).
    pub time_ms: i64,
    /// The number of the event saying this state.
    pub seq: u64,
}

impl Condition {
    /// Whether a client must keep it in its alarm view.
    pub fn retain(&self) -> bool {
        self.active || !self.acked
    }

    /// The EventId of the event saying this state.
    pub fn event_id(&self) -> String {
        format!("{}#{}", self.node, self.seq)
    }

    /// Its event's message.
    pub fn message(&self) -> String {
        let state = match (self.active, self.acked) {
            (true, false) => "active",
            (true, true) => "acknowledged",
            (false, false) => "cleared, unacknowledged",
            (false, true) => "acknowledged and cleared",
        };
        format!("alarm {state}: {}", self.text)
    }
}

/// Why an Acknowledge is refused before FALC is asked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum AckRefusal {
    /// No such condition (or it left the list).
    Unknown,
    /// The EventId is none of this condition's.
    EventId,
    /// It is acknowledged already.
    Acked,
}

/// Every condition the gateway knows of, by node id.
#[derive(Debug, Default)]
pub struct Conditions {
    by_node: BTreeMap<String, Condition>,
    seq: u64,
}

impl Conditions {
    /// Scope `at`'s alarm list now (`now_ms` for a state whose time the
    /// alarm does not tell): the conditions whose state changed, each a
    /// new event. Only for a list the operator gave: when it does not
    /// answer, nothing is known to have changed.
    pub fn update(
        &mut self,
        at: usize,
        scope: &Scope,
        alarms: &[Alarm],
        now_ms: i64,
    ) -> Vec<Condition> {
        let mut out = Vec::new();
        let mut listed = Vec::with_capacity(alarms.len());
        for a in alarms {
            let node = scope.id(&format!("Conditions.{}", a.id));
            let active = a.cleared_ms.is_none();
            let acked = a.acked.is_some();
            listed.push(node.clone());
            let changed = self
                .by_node
                .get(&node)
                .map_or(true, |c| c.active != active || c.acked != acked);
            if !changed {
                continue;
            }
            let time_ms = match (&a.acked, a.cleared_ms) {
                (Some((_, at)), Some(c)) => (*at).max(c),
                (Some((_, at)), None) => *at,
                (None, Some(c)) => c,
                (None, None) => a.raised_ms,
            };
            self.seq += 1;
            let c = Condition {
                node: node.clone(),
                root: scope.root.clone(),
                scope: at,
                alarm: a.id,
                class: a.class,
                station: a.station.to_string(),
                source: source_of(scope, a),
                severity: space::severity(a.class),
                text: space::alarm_text(a),
                active,
                acked,
                acked_by: a.acked.as_ref().map(|(who, _)| who.clone()),
                time_ms: if time_ms > 0 { time_ms } else { now_ms },
                seq: self.seq,
            };
            self.by_node.insert(node, c.clone());
            out.push(c);
        }
        // An alarm leaves the list once acknowledged and cleared: its
        // condition says so once, no longer retained.
        let gone: Vec<String> = self
            .by_node
            .values()
            .filter(|c| c.scope == at && !listed.contains(&c.node))
            .map(|c| c.node.clone())
            .collect();
        for node in gone {
            if let Some(mut c) = self.by_node.remove(&node) {
                self.seq += 1;
                c.active = false;
                c.acked = true;
                c.time_ms = now_ms;
                c.seq = self.seq;
                out.push(c);
            }
        }
        out
    }

    /// Every condition a client must keep in its alarm view (what
    /// ConditionRefresh sends), in the order of their node ids.
    pub fn retained(&self) -> Vec<Condition> {
        self.by_node
            .values()
            .filter(|c| c.retain())
            .cloned()
            .collect()
    }

    /// Whether Acknowledge may ask FALC to acknowledge condition `node`
    /// for event `event_id`: its scope and alarm if so.
    pub fn acknowledge(&self, node: &str, event_id: &[u8]) -> Result<(usize, i64), AckRefusal> {
        let c = self.by_node.get(node).ok_or(AckRefusal::Unknown)?;
        let ours = std::str::from_utf8(event_id)
            .ok()
            .and_then(|e| e.strip_prefix(node))
            .and_then(|rest| rest.strip_prefix('#'))
            .and_then(|n| n.parse::<u64>().ok())
            .is_some_and(|n| n <= c.seq);
        if !ours {
            return Err(AckRefusal::EventId);
        }
        if c.acked {
            return Err(AckRefusal::Acked);
        }
        Ok((c.scope, c.alarm))
    }
}

/// The node of the station that raised `a`: its object under the scope's
/// `Stations`, or the scope's object for a station the topology does not
/// name (the operator, a cell's own alarms).
fn source_of(scope: &Scope, a: &Alarm) -> String {
    match &scope.part {
        space::Part::Cell { stations, .. } if stations.iter().any(|(s, _)| *s == a.station) => {
            space::station_id(scope, &a.station)
        }
        _ => scope.root.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_model::ids::StationName;
    use falc_model::topology::StationKind;

    fn scope() -> Scope {
        let st = |s: &str| StationName::new(s).expect("name");
        Scope::one_cell(vec![
            (st("cell"), StationKind::Cell),
            (st("welding"), StationKind::Welding),
        ])
        .remove(0)
    }

    fn estop(id: i64) -> Alarm {
        Alarm {
            id,
            station: StationName::new("welding").expect("name"),
            class: AlarmClass::Safety,
            text: "emergency stop".into(),
            order: None,
            raised_ms: 1_000,
            acked: None,
            cleared_ms: None,
        }
    }

    #[test]
    fn an_alarm_is_a_condition_through_its_life_and_is_retained_until_acked_and_cleared() {
        let s = scope();
        let mut c = Conditions::default();
        let mut a = estop(7);
        let raised = c.update(0, &s, &[a.clone()], 5);
        assert_eq!(raised.len(), 1);
        let r = &raised[0];
        assert_eq!(r.node, "FALC.Conditions.7");
        assert_eq!(r.source, "FALC.Stations.welding");
        assert_eq!((r.active, r.acked, r.retain()), (true, false, true));
        assert_eq!(r.severity, 1000);
        assert_eq!(r.time_ms, 1_000);
        assert!(
            r.message().starts_with("alarm active: #7 welding"),
            "{}",
            r.message()
        );
        // The same list again: nothing to say.
        assert!(c.update(0, &s, &[a.clone()], 6).is_empty());
        assert_eq!(c.retained().len(), 1);
        // Cleared, unacknowledged: still retained.
        a.cleared_ms = Some(2_000);
        let cleared = c.update(0, &s, &[a.clone()], 7);
        assert_eq!((cleared[0].active, cleared[0].acked), (false, false));
        assert!(cleared[0].retain());
        assert!(cleared[0].seq > r.seq);
        // Acknowledged (it leaves the list): said once, no longer retained.
        let gone = c.update(0, &s, &[], 8);
        assert_eq!(gone.len(), 1);
        assert_eq!(
            (gone[0].active, gone[0].acked, gone[0].retain()),
            (false, true, false)
        );
        assert!(c.retained().is_empty());
        assert!(c.update(0, &s, &[], 9).is_empty());
    }

    #[test]
    fn acknowledge_names_a_known_condition_and_one_of_its_events() {
        let s = scope();
        let mut c = Conditions::default();
        let mut a = estop(3);
        let first = c.update(0, &s, &[a.clone()], 5).remove(0);
        let event = first.event_id();
        assert_eq!(
            c.acknowledge("FALC.Conditions.3", event.as_bytes()),
            Ok((0, 3))
        );
        assert_eq!(
            c.acknowledge("FALC.Conditions.4", event.as_bytes()),
            Err(AckRefusal::Unknown)
        );
        for bad in ["FALC.Conditions.3#99", "FALC.Conditions.30#1", "junk", ""] {
            assert_eq!(
                c.acknowledge("FALC.Conditions.3", bad.as_bytes()),
                Err(AckRefusal::EventId),
                "{bad}"
            );
        }
        assert_eq!(
            c.acknowledge("FALC.Conditions.3", &[0xff, 0xfe]),
            Err(AckRefusal::EventId)
        );
        a.acked = Some(("console".into(), 3_000));
        let acked = c.update(0, &s, &[a], 6).remove(0);
        assert_eq!(acked.acked_by.as_deref(), Some("console"));
        assert_eq!(acked.time_ms, 3_000);
        assert_eq!(
            c.acknowledge("FALC.Conditions.3", acked.event_id().as_bytes()),
            Err(AckRefusal::Acked)
        );
        // Acknowledged but active: still retained.
        assert_eq!(c.retained().len(), 1);
    }

    #[test]
    fn each_scope_keeps_its_own_conditions() {
        let plant = Scope::plant(vec![
            ("falc1".parse().expect("cell"), vec![]),
            ("falc2".parse().expect("cell"), vec![]),
        ]);
        let mut c = Conditions::default();
        let one = c.update(1, &plant[1], &[estop(1)], 5);
        let two = c.update(2, &plant[2], &[estop(1)], 5);
        assert_eq!(one[0].node, "FALC.falc1.Conditions.1");
        assert_eq!(two[0].node, "FALC.falc2.Conditions.1");
        // A station the cell's topology does not name: the cell's object.
        assert_eq!(two[0].source, "FALC.falc2");
        // Cell 2's list going empty leaves cell 1's condition alone.
        assert_eq!(c.update(2, &plant[2], &[], 6).len(), 1);
        assert_eq!(c.retained().len(), 1);
        assert_eq!(c.retained()[0].root, "FALC.falc1");
    }
}
