//! Associations, sans-I/O: who this node's commander is, which of its
//! subordinates are associated, and what a lost peer means.
//!
//! The rules (docs/architecture.md, "Associations"; the 1992 scheme):
//! - a node accepts exactly one commander, the one the topology names; a
//!   second Initiate (another session) is refused with an `initiate` error;
//! - a node with subordinates initiates them before it confirms its own
//!   Initiate, so the highest node builds the whole tree; if one cannot be
//!   reached, the Initiate is refused with "no connection with station …"
//!   and the ones already associated are concluded again;
//! - a repeated Initiate from the same commander re-associates any
//!   subordinate that was lost (this is how "start" rebuilds the cell after
//!   an alarm);
//! - a lost liveliness token (or an Abort) is an abort indication: losing the
//!   commander frees this node and aborts its subordinates; losing a
//!   subordinate is reported to the node, which stops;
//! - except that a node that runs on without its commander
//!   ([`Associations::runs_on_alone`]: a cell, whose recipe coordinates its
//!   workstations by itself) keeps its subordinates when its commander's
//!   token is lost (the link up was cut, or the operator's process died):
//!   its running order ends as its recipe decides, and the commander, back,
//!   associates again and asks how it ended. An Abort the commander sends
//!   still aborts the whole subtree.
//!
//! The driver (`bus::station`) does the I/O: it sends the Initiates this core
//! asks for, watches tokens, and feeds results back.

use super::error::{ApplicationReferenceError, ErrorClass, InitiateError, ServiceError};
use super::pdu::{Peer, Request};
use crate::ids::StationName;
use crate::topology::Topology;
use std::collections::BTreeMap;
use std::time::Duration;

/// How long one level of the hierarchy may take to confirm an Initiate.
pub const INITIATE_LEVEL_LIMIT: Duration = Duration::from_secs(2);

/// How long an Initiate of `sub` may take: one
/// [`INITIATE_LEVEL_LIMIT`] per level of its subtree (it initiates its own
/// subordinates first).
pub fn initiate_limit(topology: &Topology, sub: &StationName) -> Duration {
    let levels = 1 + topology.height(sub);
    INITIATE_LEVEL_LIMIT * levels
}

/// Which end of an association was lost.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// Our commander.
    Commander,
    /// One of our subordinates.
    Subordinate,
}

/// An abort indication: the association with `peer` is gone.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AbortIndication {
    /// The peer that was lost.
    pub peer: Peer,
    /// Its role towards us.
    pub role: Role,
    /// Why (token lost, Abort received …).
    pub reason: String,
}

/// What the driver must do next for an Initiate indication.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum InitiateStep {
    /// Answer now with this error.
    Refuse(ServiceError),
    /// Initiate these subordinates, then call [`Associations::subordinates_initiated`].
    InitiateSubordinates(Vec<StationName>),
    /// Confirm; watch the commander's token.
    Confirm(Peer),
}

/// What the driver must do once the subordinates have answered.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum InitiateOutcome {
    /// Confirm the commander's Initiate; watch the new subordinates' tokens.
    Confirm {
        /// The commander.
        commander: Peer,
        /// Subordinates newly associated (to watch).
        associated: Vec<Peer>,
    },
    /// Refuse the commander's Initiate, after concluding `conclude`.
    Refuse {
        /// The error for the commander.
        error: ServiceError,
        /// Subordinates associated during this attempt, to conclude again.
        conclude: Vec<Peer>,
    },
}

#[derive(Debug, Clone, PartialEq, Eq)]
enum CommanderSlot {
    Free,
    Pending(Peer),
    Associated(Peer),
}

/// The association state of one node.
#[derive(Debug, Clone)]
pub struct Associations {
    me: StationName,
    commander_name: Option<StationName>,
    commander: CommanderSlot,
    subordinates: BTreeMap<StationName, Option<Peer>>,
    runs_on_alone: bool,
}

impl Associations {
    /// A node named `me`, commanded by `commander` (None for the root), with
    /// these direct subordinates.
    pub fn new(
        me: StationName,
        commander: Option<StationName>,
        subordinates: impl IntoIterator<Item = StationName>,
    ) -> Self {
        Self {
            me,
            commander_name: commander,
            commander: CommanderSlot::Free,
            subordinates: subordinates.into_iter().map(|s| (s, None)).collect(),
            runs_on_alone: false,
        }
    }

    /// Station `me` of `topology`: its commander, its subordinates, and
    /// whether it runs on alone (by its kind).
    pub fn of(topology: &Topology, me: &StationName) -> Self {
        let alone = topology.station(me).is_some_and(|s| s.kind.runs_on_alone());
        Self::new(
            me.clone(),
            topology.commander_of(me).cloned(),
            topology.subordinates_of(me).into_iter().cloned(),
        )
        .runs_on_alone(alone)
    }

    /// Whether `request` may be served now: a service that changes the
    /// VMD's objects only under an associated commander.
    pub fn admit(&self, request: &Request) -> Result<(), ServiceError> {
        if changes_state(request) && self.commander().is_none() {
            return Err(ServiceError::new(
                ErrorClass::ApplicationReference(ApplicationReferenceError::Other),
                format!(
                    "{} refused: {} has no associated commander (Initiate first)",
                    request.service(),
                    self.me
                ),
            ));
        }
        Ok(())
    }

    /// A node that keeps its subordinates when its commander's token is
    /// lost (see the module's rules).
    pub fn runs_on_alone(mut self, yes: bool) -> Self {
        self.runs_on_alone = yes;
        self
    }

    /// Whether this node runs on alone when its commander is lost
    /// ([`Self::runs_on_alone`]).
    pub fn runs_alone(&self) -> bool {
        self.runs_on_alone
    }

    /// The associated commander, if any.
    pub fn commander(&self) -> Option<&Peer> {
        match &self.commander {
            CommanderSlot::Associated(p) => Some(p),
            _ => None,
        }
    }

    /// The associated subordinate `name`, if associated.
    pub fn subordinate(&self, name: &StationName) -> Option<&Peer> {
        self.subordinates.get(name).and_then(|p| p.as_ref())
    }

    /// Every associated subordinate.
    pub fn associated_subordinates(&self) -> Vec<Peer> {
        self.subordinates.values().flatten().cloned().collect()
    }

    fn refuse(&self, text: String) -> InitiateStep {
        InitiateStep::Refuse(ServiceError::new(
            ErrorClass::Initiate(InitiateError::Other),
            text,
        ))
    }

    /// An Initiate indication from `from`.
    pub fn initiate(&mut self, from: Peer) -> InitiateStep {
        if self.commander_name.as_ref() != Some(&from.station) {
            let expected = self
                .commander_name
                .as_ref()
                .map_or("none, it is the root".to_string(), |c| c.to_string());
            return self.refuse(format!(
                "station {} is not the commander of {} (its commander: {expected})",
                from.station, self.me
            ));
        }
        match &self.commander {
            CommanderSlot::Associated(p) | CommanderSlot::Pending(p) if *p != from => {
                return self.refuse(format!(
                    "{} already has a commander: {p}; a subordinate accepts one",
                    self.me
                ))
            }
            CommanderSlot::Pending(_) => {
                return self.refuse(format!("an Initiate from {from} is already in progress"))
            }
            CommanderSlot::Associated(_) | CommanderSlot::Free => {}
        }
        let missing = self.missing_subordinates();
        if missing.is_empty() {
            self.commander = CommanderSlot::Associated(from.clone());
            InitiateStep::Confirm(from)
        } else {
            self.commander = CommanderSlot::Pending(from);
            InitiateStep::InitiateSubordinates(missing)
        }
    }

    /// The subordinates' answers to the Initiates asked for by [`Self::initiate`].
    pub fn subordinates_initiated(
        &mut self,
        results: Vec<(StationName, Result<Peer, ServiceError>)>,
    ) -> InitiateOutcome {
        let commander = match std::mem::replace(&mut self.commander, CommanderSlot::Free) {
            CommanderSlot::Pending(p) | CommanderSlot::Associated(p) => p,
            CommanderSlot::Free => {
                // The commander vanished meanwhile: undo what was made.
                let conclude = results.into_iter().filter_map(|(_, r)| r.ok()).collect();
                return InitiateOutcome::Refuse {
                    error: ServiceError::connection_lost("the commander was lost during Initiate"),
                    conclude,
                };
            }
        };
        match self.record_subordinates(results) {
            Ok(associated) => {
                self.commander = CommanderSlot::Associated(commander.clone());
                InitiateOutcome::Confirm {
                    commander,
                    associated,
                }
            }
            Err((error, mut conclude)) => {
                // No commander, no subordinates: release the older ones too.
                conclude.extend(self.take_subordinates());
                InitiateOutcome::Refuse { error, conclude }
            }
        }
    }

    /// Subordinates not associated now.
    pub fn missing_subordinates(&self) -> Vec<StationName> {
        self.subordinates
            .iter()
            .filter(|(_, p)| p.is_none())
            .map(|(s, _)| s.clone())
            .collect()
    }

    /// Records the answers of subordinates to Initiate: all associated, or
    /// the first failure ("no connection with station …") and the ones made
    /// in this attempt, which must be concluded again (nothing half-made:
    /// none of those asked counts as associated then).
    pub fn record_subordinates(
        &mut self,
        results: Vec<(StationName, Result<Peer, ServiceError>)>,
    ) -> Result<Vec<Peer>, (ServiceError, Vec<Peer>)> {
        let first_error = results.iter().find_map(|(station, r)| {
            r.as_ref().err().map(|e| {
                ServiceError::new(
                    ErrorClass::Initiate(InitiateError::Other),
                    format!("no connection with station {station}: {e}"),
                )
            })
        });
        let asked: Vec<StationName> = results.iter().map(|(s, _)| s.clone()).collect();
        let made: Vec<(StationName, Peer)> = results
            .into_iter()
            .filter_map(|(s, r)| r.ok().map(|p| (s, p)))
            .collect();
        if let Some(error) = first_error {
            // Nothing half-made, also for one associated before this
            // (repeated) Initiate: one that refused freed its commander,
            // one that did not answer is unknown, and the ones made are
            // concluded again.
            for station in &asked {
                self.subordinates.insert(station.clone(), None);
            }
            return Err((error, made.into_iter().map(|(_, p)| p).collect()));
        }
        for (s, p) in &made {
            self.subordinates.insert(s.clone(), Some(p.clone()));
        }
        Ok(made.into_iter().map(|(_, p)| p).collect())
    }

    /// The root concludes its subordinates: the ones to conclude.
    pub fn release_subordinates(&mut self) -> Vec<Peer> {
        self.take_subordinates()
    }

    /// A Conclude indication: the subordinates to conclude first, or the
    /// refusal when `from` is not our commander.
    pub fn conclude(&mut self, from: &Peer) -> Result<Vec<Peer>, ServiceError> {
        match &self.commander {
            CommanderSlot::Associated(p) if p == from => {
                self.commander = CommanderSlot::Free;
                Ok(self.take_subordinates())
            }
            _ => Err(ServiceError::new(
                ErrorClass::Conclude(super::error::ConcludeError::Other),
                format!("{from} is not associated with {}", self.me),
            )),
        }
    }

    fn take_subordinates(&mut self) -> Vec<Peer> {
        self.subordinates
            .values_mut()
            .filter_map(|p| p.take())
            .collect()
    }

    /// A peer's liveliness token is gone (`sent_abort` false), or it sent
    /// Abort: the abort indication (None if it was not associated with
    /// us), and the subordinates to abort in turn when it was our
    /// commander (none when this node runs on alone and only the token
    /// was lost).
    pub fn lost(
        &mut self,
        peer: &Peer,
        reason: &str,
        sent_abort: bool,
    ) -> Option<(AbortIndication, Vec<Peer>)> {
        let indication = |role| AbortIndication {
            peer: peer.clone(),
            role,
            reason: reason.to_string(),
        };
        if matches!(&self.commander, CommanderSlot::Associated(p) | CommanderSlot::Pending(p) if p == peer)
        {
            self.commander = CommanderSlot::Free;
            let abort = if self.runs_on_alone && !sent_abort {
                Vec::new()
            } else {
                self.take_subordinates()
            };
            return Some((indication(Role::Commander), abort));
        }
        let slot = self
            .subordinates
            .values_mut()
            .find(|p| p.as_ref() == Some(peer))?;
        *slot = None;
        Some((indication(Role::Subordinate), Vec::new()))
    }
}

/// Services that change a VMD's objects: only an associated commander may.
fn changes_state(r: &Request) -> bool {
    matches!(
        r,
        Request::InitiateDownloadSequence { .. }
            | Request::DownloadSegment { .. }
            | Request::TerminateDownloadSequence { .. }
            | Request::DeleteDomain { .. }
            | Request::CreateProgramInvocation { .. }
            | Request::DeleteProgramInvocation { .. }
            | Request::Start { .. }
            | Request::Stop { .. }
            | Request::Resume { .. }
            | Request::Reset { .. }
            | Request::Kill { .. }
    )
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) fn st(s: &str) -> StationName {
        StationName::new(s).expect("valid")
    }

    pub(crate) fn peer(s: &str, session: &str) -> Peer {
        Peer {
            station: st(s),
            session: session.into(),
        }
    }

    fn cell() -> Associations {
        Associations::new(
            st("cell"),
            Some(st("operator")),
            [st("welding"), st("transport")],
        )
    }

    fn initiate_all(a: &mut Associations, from: Peer) -> InitiateOutcome {
        let InitiateStep::InitiateSubordinates(subs) = a.initiate(from) else {
            panic!("expected subordinates first")
        };
        a.subordinates_initiated(
            subs.into_iter()
                .map(|s| {
                    let p = peer(s.as_str(), "5");
                    (s, Ok(p))
                })
                .collect(),
        )
    }

    #[test]
    fn only_an_associated_commander_may_change_objects_and_reading_needs_none() {
        let mut a = cell();
        let start = Request::Start {
            name: crate::ids::ObjectName::new("DIKDROOG").expect("valid"),
            argument: String::new(),
        };
        let e = a.admit(&start).expect_err("no commander yet");
        assert_eq!(
            e.class,
            ErrorClass::ApplicationReference(ApplicationReferenceError::Other)
        );
        assert_eq!(
            e.description,
            "start refused: cell has no associated commander (Initiate first)"
        );
        assert_eq!(a.admit(&Request::Status), Ok(()));
        assert!(matches!(
            initiate_all(&mut a, peer("operator", "1")),
            InitiateOutcome::Confirm { .. }
        ));
        assert_eq!(a.admit(&start), Ok(()));
    }

    #[test]
    fn leaf_confirms_at_once() {
        let mut a = Associations::new(st("welding"), Some(st("cell")), []);
        assert_eq!(
            a.initiate(peer("cell", "1")),
            InitiateStep::Confirm(peer("cell", "1"))
        );
        assert_eq!(a.commander(), Some(&peer("cell", "1")));
    }

    #[test]
    fn subordinates_before_confirm() {
        let mut a = cell();
        let out = initiate_all(&mut a, peer("operator", "1"));
        assert!(
            matches!(out, InitiateOutcome::Confirm { ref associated, .. } if associated.len() == 2)
        );
        assert_eq!(a.associated_subordinates().len(), 2);
    }

    #[test]
    fn second_commander_refused_with_initiate_error() {
        let mut a = Associations::new(st("welding"), Some(st("cell")), []);
        assert!(matches!(
            a.initiate(peer("cell", "1")),
            InitiateStep::Confirm(_)
        ));
        let InitiateStep::Refuse(e) = a.initiate(peer("cell", "2")) else {
            panic!("accepted a second commander")
        };
        assert_eq!(e.class.class_name(), "initiate");
        assert!(e.description.contains("already has a commander"), "{e}");
        // The same commander again is fine (idempotent).
        assert!(matches!(
            a.initiate(peer("cell", "1")),
            InitiateStep::Confirm(_)
        ));
    }

    #[test]
    fn wrong_station_refused() {
        let mut a = Associations::new(st("welding"), Some(st("cell")), []);
        let InitiateStep::Refuse(e) = a.initiate(peer("transport", "1")) else {
            panic!("accepted a non-commander")
        };
        assert!(
            e.description.contains("not the commander of welding"),
            "{e}"
        );
    }

    #[test]
    fn unreachable_subordinate_refuses_and_concludes_the_others() {
        let mut a = cell();
        let InitiateStep::InitiateSubordinates(_) = a.initiate(peer("operator", "1")) else {
            panic!()
        };
        let out = a.subordinates_initiated(vec![
            (st("welding"), Ok(peer("welding", "7"))),
            (st("transport"), Err(ServiceError::unreachable("no reply"))),
        ]);
        let InitiateOutcome::Refuse { error, conclude } = out else {
            panic!("confirmed without transport")
        };
        assert!(
            error
                .description
                .starts_with("no connection with station transport"),
            "{error}"
        );
        assert_eq!(conclude, vec![peer("welding", "7")]);
        assert_eq!(a.commander(), None);
        assert!(a.associated_subordinates().is_empty());
    }

    #[test]
    fn lost_commander_aborts_subordinates() {
        let mut a = cell();
        initiate_all(&mut a, peer("operator", "1"));
        let (ind, abort) = a
            .lost(&peer("operator", "1"), "token lost", false)
            .expect("associated");
        assert_eq!(ind.role, Role::Commander);
        assert_eq!(abort.len(), 2);
        assert_eq!(a.commander(), None);
        // A new commander session may now associate.
        assert!(matches!(
            initiate_all(&mut a, peer("operator", "9")),
            InitiateOutcome::Confirm { .. }
        ));
    }

    #[test]
    fn lost_subordinate_is_reassociated_by_a_repeated_initiate() {
        let mut a = cell();
        initiate_all(&mut a, peer("operator", "1"));
        let (ind, abort) = a
            .lost(&peer("welding", "5"), "token lost", false)
            .expect("associated");
        assert_eq!(ind.role, Role::Subordinate);
        assert!(abort.is_empty());
        assert_eq!(
            a.commander(),
            Some(&peer("operator", "1")),
            "the commander stays"
        );
        assert_eq!(
            a.initiate(peer("operator", "1")),
            InitiateStep::InitiateSubordinates(vec![st("welding")])
        );
        assert!(a.lost(&peer("nobody", "0"), "x", false).is_none());
    }

    #[test]
    fn a_cell_that_runs_on_alone_keeps_its_workstations_while_its_commander_is_away() {
        let mut a = cell().runs_on_alone(true);
        initiate_all(&mut a, peer("operator", "1"));
        let (ind, abort) = a
            .lost(&peer("operator", "1"), "token lost", false)
            .expect("associated");
        assert_eq!(ind.role, Role::Commander);
        assert!(abort.is_empty(), "{abort:?}");
        assert_eq!(a.commander(), None);
        assert_eq!(a.associated_subordinates().len(), 2);
        // Back (a new session, or the same after the link returned): it
        // associates at once, the workstations still being associated.
        assert_eq!(
            a.initiate(peer("operator", "2")),
            InitiateStep::Confirm(peer("operator", "2"))
        );
        // An Abort the commander sends takes the whole subtree down.
        let (_, abort) = a
            .lost(&peer("operator", "2"), "Abort from operator", true)
            .expect("associated");
        assert_eq!(abort.len(), 2);
        assert!(a.associated_subordinates().is_empty());
    }

    #[test]
    fn conclude_only_from_the_commander() {
        let mut a = cell();
        initiate_all(&mut a, peer("operator", "1"));
        assert!(a.conclude(&peer("operator", "2")).is_err());
        assert_eq!(a.conclude(&peer("operator", "1")).map(|v| v.len()), Ok(2));
        assert_eq!(a.commander(), None);
    }
}
