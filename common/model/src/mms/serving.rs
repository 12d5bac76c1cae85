//! What a station does with the association services it serves itself,
//! sans-I/O: Initiate (its subordinates first, then the confirm), Conclude,
//! Abort, a lost token, and which other indications it hands its node.
//!
//! [`Serving`] holds the station's [`Associations`] and the Initiate in
//! progress. The driver feeds it indications (each with a token `R` that
//! stands for the way back to the caller: a zenoh responder, or the
//! simulation's request id), the subordinates' answers to the Initiates it
//! asked for, and lost tokens; it polls [`Action`]s: answer, send, watch,
//! or hand the node an indication or an association change. The zenoh
//! station (`falc_bus::station`) and `falc-sim` drive this one machine, so
//! the sequencing and its refusals are one.

use super::association::{
    initiate_limit, AbortIndication, Associations, InitiateOutcome, InitiateStep,
    INITIATE_LEVEL_LIMIT,
};
use super::error::ServiceError;
use super::pdu::{Peer, Request, Response};
use crate::ids::StationName;
use crate::topology::Topology;
use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

/// What the driver must do.
#[derive(Debug, Clone, PartialEq)]
pub enum Action<R> {
    /// Answer the indication `R` with this.
    Respond(R, Result<Response, ServiceError>),
    /// Send `request` (an Initiate) to subordinate `to` within `limit` and
    /// hand its confirm to [`Serving::handle_initiated`].
    Initiate {
        /// The subordinate.
        to: StationName,
        /// The Initiate, calling with this station.
        request: Request,
        /// One [`INITIATE_LEVEL_LIMIT`] per level of `to`'s subtree.
        limit: Duration,
    },
    /// Send `request` (a Conclude or an Abort) to `to`; nothing waits for
    /// its confirm (a failure is only logged).
    Tell {
        /// The subordinate.
        to: StationName,
        /// The request.
        request: Request,
    },
    /// Watch this peer's liveliness token (its loss is
    /// [`Serving::handle_lost`]).
    Watch(Peer),
    /// Stop watching this peer.
    Unwatch(Peer),
    /// Hand the node indication `R`, admitted: it answers it.
    Indication(R, Request),
    /// Hand the node: its commander associated (the Initiate is confirmed).
    Associated(Peer),
    /// Hand the node: its commander concluded the association.
    Concluded(Peer),
    /// Hand the node: an association was lost (stop, and report).
    Abort(AbortIndication),
}

/// The commander's Initiate, held while the subordinates are initiated.
#[derive(Debug)]
struct Initiating<R> {
    /// Its token.
    commander: R,
    /// Who called (unwatched again if the Initiate is refused).
    calling: Peer,
    /// The subordinates asked, not answered yet.
    waiting: Vec<StationName>,
    /// Their answers so far.
    results: Vec<(StationName, Result<Peer, ServiceError>)>,
}

/// A station's association services (see the module).
#[derive(Debug)]
pub struct Serving<R> {
    me: Peer,
    assoc: Associations,
    limits: BTreeMap<StationName, Duration>,
    initiating: Option<Initiating<R>>,
    out: VecDeque<Action<R>>,
}

impl<R> Serving<R> {
    /// Station `me` (this session) of `topology`.
    pub fn of(topology: &Topology, me: Peer) -> Self {
        let limits = topology
            .subordinates_of(&me.station)
            .into_iter()
            .map(|s| (s.clone(), initiate_limit(topology, s)))
            .collect();
        Self {
            assoc: Associations::of(topology, &me.station),
            me,
            limits,
            initiating: None,
            out: VecDeque::new(),
        }
    }

    /// The association state.
    pub fn associations(&self) -> &Associations {
        &self.assoc
    }

    /// This station's session.
    pub fn me(&self) -> &Peer {
        &self.me
    }

    /// What to do next.
    pub fn poll(&mut self) -> Option<Action<R>> {
        self.out.pop_front()
    }

    /// An indication: the association services served here, the others
    /// handed to the node once admitted.
    pub fn handle_request(&mut self, token: R, request: Request) {
        match request {
            Request::Initiate { calling } => self.initiate(token, calling),
            Request::Conclude { calling } => match self.assoc.conclude(&calling) {
                Ok(subs) => {
                    self.out.push_back(Action::Unwatch(calling.clone()));
                    self.conclude_all(subs);
                    self.out
                        .push_back(Action::Respond(token, Ok(Response::Done)));
                    self.out.push_back(Action::Concluded(calling));
                }
                Err(e) => self.out.push_back(Action::Respond(token, Err(e))),
            },
            Request::Abort { calling, reason } => {
                self.out
                    .push_back(Action::Respond(token, Ok(Response::Done)));
                let reason = format!("Abort from {calling}: {reason}");
                self.on_lost(&calling, &reason, true);
            }
            other => match self.assoc.admit(&other) {
                Ok(()) => self.out.push_back(Action::Indication(token, other)),
                Err(e) => self.out.push_back(Action::Respond(token, Err(e))),
            },
        }
    }

    /// A watched peer's liveliness token is gone.
    pub fn handle_lost(&mut self, peer: &Peer, reason: &str) {
        self.on_lost(peer, reason, false);
    }

    /// Subordinate `sub`'s confirm of the Initiate asked for by an
    /// [`Action::Initiate`]; once all have answered, the commander's
    /// Initiate is confirmed or refused.
    pub fn handle_initiated(&mut self, sub: &StationName, result: Result<Response, ServiceError>) {
        let result = responding(sub, result);
        let Some(i) = self.initiating.as_mut() else {
            // The commander's Initiate ended meanwhile (its session was
            // lost): what was made is concluded again.
            if let Ok(p) = result {
                self.conclude_all(vec![p]);
            }
            return;
        };
        let Some(at) = i.waiting.iter().position(|s| s == sub) else {
            return;
        };
        i.waiting.remove(at);
        i.results.push((sub.clone(), result));
        if !i.waiting.is_empty() {
            return;
        }
        let Some(i) = self.initiating.take() else {
            return;
        };
        match self.assoc.subordinates_initiated(i.results) {
            InitiateOutcome::Confirm {
                commander,
                associated,
            } => {
                for p in associated {
                    self.out.push_back(Action::Watch(p));
                }
                self.confirm(i.commander, commander);
            }
            InitiateOutcome::Refuse { error, conclude } => {
                self.out.push_back(Action::Unwatch(i.calling));
                self.conclude_all(conclude);
                self.out.push_back(Action::Respond(i.commander, Err(error)));
            }
        }
    }

    /// The root associates its subordinates: the Initiates to send (each
    /// with how long it may take), to every subordinate, also one
    /// associated already (a repeated Initiate from its commander
    /// re-associates what it lost below: the way back after a lost
    /// workstation); their outcomes go to [`Self::record_initiates`].
    pub fn initiates(&self) -> Vec<(StationName, Duration)> {
        self.limits.iter().map(|(s, l)| (s.clone(), *l)).collect()
    }

    /// The outcomes of the root's Initiates: the associations made (to
    /// watch), or, if any failed, the first failure (the ones made are
    /// concluded again).
    pub fn record_initiates(
        &mut self,
        results: Vec<(StationName, Result<Response, ServiceError>)>,
    ) -> Result<Vec<Peer>, ServiceError> {
        let results = results
            .into_iter()
            .map(|(s, r)| {
                let r = responding(&s, r);
                (s, r)
            })
            .collect();
        match self.assoc.record_subordinates(results) {
            Ok(made) => {
                for p in &made {
                    self.out.push_back(Action::Watch(p.clone()));
                }
                Ok(made)
            }
            Err((e, made)) => {
                self.conclude_all(made);
                Err(e)
            }
        }
    }

    /// The root concludes every subordinate.
    pub fn conclude_subordinates(&mut self) {
        let subs = self.assoc.release_subordinates();
        self.conclude_all(subs);
    }

    fn initiate(&mut self, token: R, calling: Peer) {
        match self.assoc.initiate(calling.clone()) {
            InitiateStep::Refuse(e) => self.out.push_back(Action::Respond(token, Err(e))),
            InitiateStep::Confirm(commander) => self.confirm(token, commander),
            InitiateStep::InitiateSubordinates(subs) => {
                for s in &subs {
                    self.out.push_back(Action::Initiate {
                        to: s.clone(),
                        request: Request::Initiate {
                            calling: self.me.clone(),
                        },
                        limit: self.limit(s),
                    });
                }
                self.initiating = Some(Initiating {
                    commander: token,
                    calling,
                    waiting: subs,
                    results: Vec::new(),
                });
            }
        }
    }

    fn confirm(&mut self, token: R, commander: Peer) {
        self.out.push_back(Action::Watch(commander.clone()));
        let responding = self.me.clone();
        self.out.push_back(Action::Respond(
            token,
            Ok(Response::Initiate { responding }),
        ));
        self.out.push_back(Action::Associated(commander));
    }

    fn on_lost(&mut self, peer: &Peer, reason: &str, sent_abort: bool) {
        self.out.push_back(Action::Unwatch(peer.clone()));
        let Some((indication, abort)) = self.assoc.lost(peer, reason, sent_abort) else {
            return;
        };
        for sub in abort {
            self.out.push_back(Action::Unwatch(sub.clone()));
            self.out.push_back(Action::Tell {
                to: sub.station,
                request: Request::Abort {
                    calling: self.me.clone(),
                    reason: format!("{} lost its commander: {reason}", self.me.station),
                },
            });
        }
        self.out.push_back(Action::Abort(indication));
    }

    fn conclude_all(&mut self, subs: Vec<Peer>) {
        for sub in subs {
            self.out.push_back(Action::Unwatch(sub.clone()));
            self.out.push_back(Action::Tell {
                to: sub.station,
                request: Request::Conclude {
                    calling: self.me.clone(),
                },
            });
        }
    }

    fn limit(&self, sub: &StationName) -> Duration {
        self.limits
            .get(sub)
            .copied()
            .unwrap_or(INITIATE_LEVEL_LIMIT)
    }
}

/// Who confirmed `sub`'s Initiate: its peer, or why the confirm does not
/// do (an error, or a confirm of another station or service).
fn responding(
    sub: &StationName,
    result: Result<Response, ServiceError>,
) -> Result<Peer, ServiceError> {
    match result? {
        Response::Initiate { responding } if &responding.station == sub => Ok(responding),
        other => Err(ServiceError::malformed(format!(
            "station {sub} answered Initiate with {other:?}"
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mms::association::tests::{peer, st};
    use crate::mms::association::Role;
    use crate::mms::error::ErrorClass;

    const TOPOLOGY: &str = include_str!("../../../../launch/cell.toml");

    fn serving(me: &str) -> Serving<u32> {
        let topology = Topology::parse(TOPOLOGY, "launch/cell.toml").expect("the shipped topology");
        Serving::of(&topology, peer(me, "s"))
    }

    fn drain(s: &mut Serving<u32>) -> Vec<Action<u32>> {
        std::iter::from_fn(|| s.poll()).collect()
    }

    fn initiate(from: Peer) -> Request {
        Request::Initiate { calling: from }
    }

    fn confirmed(station: &str) -> Result<Response, ServiceError> {
        Ok(Response::Initiate {
            responding: peer(station, "w"),
        })
    }

    #[test]
    fn a_cell_initiates_its_workstations_before_it_confirms() {
        let mut cell = serving("cell");
        cell.handle_request(1, initiate(peer("operator", "o")));
        let out = drain(&mut cell);
        let asked: Vec<_> = out
            .iter()
            .map(|a| match a {
                Action::Initiate { to, request, limit } => {
                    assert_eq!(request, &initiate(peer("cell", "s")));
                    assert_eq!(*limit, INITIATE_LEVEL_LIMIT);
                    to.to_string()
                }
                other => panic!("answered before its workstations: {other:?}"),
            })
            .collect();
        assert_eq!(asked, ["transport", "welding"]);
        cell.handle_initiated(&st("welding"), confirmed("welding"));
        assert_eq!(drain(&mut cell), [], "one of two answered");
        cell.handle_initiated(&st("transport"), confirmed("transport"));
        assert_eq!(
            drain(&mut cell),
            [
                Action::Watch(peer("welding", "w")),
                Action::Watch(peer("transport", "w")),
                Action::Watch(peer("operator", "o")),
                Action::Respond(
                    1,
                    Ok(Response::Initiate {
                        responding: peer("cell", "s")
                    })
                ),
                Action::Associated(peer("operator", "o")),
            ]
        );
        // Now the node is handed what changes its objects.
        let status = Request::Reset {
            name: crate::ids::ObjectName::new("P").expect("valid"),
        };
        cell.handle_request(2, status.clone());
        assert_eq!(drain(&mut cell), [Action::Indication(2, status)]);
    }

    #[test]
    fn an_unreachable_workstation_refuses_the_initiate_and_concludes_the_other() {
        let mut cell = serving("cell");
        cell.handle_request(1, initiate(peer("operator", "o")));
        drain(&mut cell);
        cell.handle_initiated(&st("welding"), confirmed("welding"));
        cell.handle_initiated(&st("transport"), Err(ServiceError::unreachable("no reply")));
        let out = drain(&mut cell);
        assert!(out.contains(&Action::Tell {
            to: st("welding"),
            request: Request::Conclude {
                calling: peer("cell", "s")
            }
        }));
        let Some(Action::Respond(1, Err(e))) = out.last() else {
            panic!("not refused: {out:?}")
        };
        assert!(
            e.description
                .starts_with("no connection with station transport"),
            "{e}"
        );
        assert!(cell.associations().commander().is_none());
    }

    #[test]
    fn a_confirm_from_another_station_is_malformed() {
        let mut cell = serving("cell");
        cell.handle_request(1, initiate(peer("operator", "o")));
        drain(&mut cell);
        cell.handle_initiated(&st("welding"), confirmed("transport"));
        cell.handle_initiated(&st("transport"), confirmed("transport"));
        let out = drain(&mut cell);
        let Some(Action::Respond(1, Err(e))) = out.last() else {
            panic!("not refused: {out:?}")
        };
        assert!(e.description.contains("answered Initiate with"), "{e}");
    }

    #[test]
    fn a_workstation_refuses_a_second_commander_and_what_needs_one() {
        let mut ws = serving("welding");
        let reset = Request::Reset {
            name: crate::ids::ObjectName::new("P").expect("valid"),
        };
        ws.handle_request(1, reset.clone());
        let [Action::Respond(1, Err(e))] = &drain(&mut ws)[..] else {
            panic!("admitted without a commander")
        };
        assert!(e.description.contains("no associated commander"), "{e}");
        ws.handle_request(2, initiate(peer("cell", "1")));
        assert_eq!(
            drain(&mut ws).last(),
            Some(&Action::Associated(peer("cell", "1")))
        );
        ws.handle_request(3, initiate(peer("cell", "2")));
        let [Action::Respond(3, Err(e))] = &drain(&mut ws)[..] else {
            panic!("a second commander accepted")
        };
        assert_eq!(
            e.class,
            ErrorClass::Initiate(crate::mms::error::InitiateError::Other)
        );
    }

    #[test]
    fn an_abort_is_confirmed_then_taken_as_the_commander_lost() {
        let mut ws = serving("welding");
        ws.handle_request(1, initiate(peer("cell", "1")));
        drain(&mut ws);
        ws.handle_request(
            2,
            Request::Abort {
                calling: peer("cell", "1"),
                reason: "stop".into(),
            },
        );
        let out = drain(&mut ws);
        assert_eq!(out[0], Action::Respond(2, Ok(Response::Done)));
        let Some(Action::Abort(a)) = out.last() else {
            panic!("no abort indication: {out:?}")
        };
        assert_eq!(
            (a.role, a.reason.as_str()),
            (Role::Commander, "Abort from cell (session 1): stop")
        );
        assert!(ws.associations().commander().is_none());
    }

    #[test]
    fn a_cell_aborted_by_its_commander_aborts_its_workstations() {
        let mut cell = serving("cell");
        cell.handle_request(1, initiate(peer("operator", "o")));
        drain(&mut cell);
        cell.handle_initiated(&st("welding"), confirmed("welding"));
        cell.handle_initiated(&st("transport"), confirmed("transport"));
        drain(&mut cell);
        // Its commander's token lost: a cell runs on alone.
        cell.handle_lost(&peer("operator", "o"), "token lost");
        let out = drain(&mut cell);
        assert!(
            !out.iter().any(|a| matches!(a, Action::Tell { .. })),
            "{out:?}"
        );
        assert!(matches!(out.last(), Some(Action::Abort(_))));
        // Back, then an Abort sent: the workstations are aborted too.
        cell.handle_request(2, initiate(peer("operator", "o")));
        drain(&mut cell);
        cell.handle_request(
            3,
            Request::Abort {
                calling: peer("operator", "o"),
                reason: "shutdown".into(),
            },
        );
        let aborts = drain(&mut cell)
            .into_iter()
            .filter(|a| {
                matches!(
                    a,
                    Action::Tell {
                        request: Request::Abort { .. },
                        ..
                    }
                )
            })
            .count();
        assert_eq!(aborts, 2);
    }
}
