//! Passing workstation recipes on: a domain the operator downloads to the
//! cell as `STATION$NAME` is `STATION`'s recipe `NAME`. When its download
//! ends the cell delivers it to that workstation (domain and program
//! invocation), and confirms only when the workstation has it; unchanged
//! content is not sent again. A workstation that was lost comes back empty:
//! when it is associated again, everything it should hold is sent again.
//!
//! Deliveries run in one task of their own, one at a time and in the order
//! asked ([`Deliveries`]), so the cell's loop never waits on one: it goes
//! on serving replies, publications and time limits, and holds back only
//! the commander's next indications until the deliveries are done.

use falc_bus::{Bus, Responder};
use falc_control::coordination::workstation_domain;
use falc_model::ids::{ObjectName, StationName};
use falc_model::mms::domain::content_hash;
use falc_model::mms::error::ServiceError;
use falc_model::mms::vmd::Vmd;
use falc_node::say;
use std::collections::BTreeMap;
use tokio::sync::mpsc::{unbounded_channel, UnboundedReceiver, UnboundedSender};

/// What the delivery task is asked to do.
enum Job {
    /// Deliver one recipe; the download's indication waits for it.
    PassOn(Box<PassOn>),
    /// A workstation was lost: it will come back empty.
    Forget(StationName),
    /// Send every recipe a workstation does not hold.
    CatchUp(Vec<(StationName, ObjectName, Vec<u8>)>),
}

/// One recipe to deliver, and the download that waits for it.
struct PassOn {
    domain: ObjectName,
    station: StationName,
    name: ObjectName,
    content: Vec<u8>,
    responder: Responder,
}

/// A delivery that ended.
pub enum Delivered {
    /// The recipe of this domain is at its workstation, or not: the
    /// download's indication is answered now.
    PassedOn {
        /// The cell's domain `STATION$NAME`.
        domain: ObjectName,
        /// Ok, or why not (the cell drops its copy too).
        result: Result<(), ServiceError>,
        /// Answers the download.
        responder: Responder,
    },
    /// A catch-up ended; one text per recipe that could not be sent.
    CaughtUp(Vec<String>),
}

/// The delivery task's handle.
pub struct Deliveries {
    jobs: UnboundedSender<Job>,
    /// Deliveries asked and not ended.
    in_flight: usize,
}

impl Deliveries {
    /// Starts the delivery task on `bus`; what ends comes out of the
    /// receiver.
    pub fn spawn(bus: Bus) -> (Self, UnboundedReceiver<Delivered>) {
        let (jobs, mut rx) = unbounded_channel::<Job>();
        let (done, out) = unbounded_channel();
        tokio::spawn(async move {
            let mut passer = Passer::default();
            while let Some(job) = rx.recv().await {
                let ended = match job {
                    Job::PassOn(p) => Delivered::PassedOn {
                        result: passer.pass_on(&bus, &p.station, &p.name, &p.content).await,
                        domain: p.domain,
                        responder: p.responder,
                    },
                    Job::Forget(st) => {
                        passer.forget(&st);
                        continue;
                    }
                    Job::CatchUp(todo) => {
                        let mut failed = Vec::new();
                        for (st, name, content) in todo {
                            if let Err(e) = passer.pass_on(&bus, &st, &name, &content).await {
                                failed.push(e.description);
                            }
                        }
                        Delivered::CaughtUp(failed)
                    }
                };
                if done.send(ended).is_err() {
                    break;
                }
            }
        });
        (Self { jobs, in_flight: 0 }, out)
    }

    /// Whether a delivery is under way.
    pub fn busy(&self) -> bool {
        self.in_flight > 0
    }

    /// One asked delivery ended (call for each [`Delivered`]).
    pub fn ended(&mut self) {
        self.in_flight = self.in_flight.saturating_sub(1);
    }

    /// Hands the task a job; `counts` if its end will come back as a
    /// [`Delivered`]. A task that is gone drops the job (a download's
    /// responder with it: the commander sees no reply) and the cell's loop
    /// stops on the closed channel.
    fn ask(&mut self, job: Job, counts: bool) {
        if self.jobs.send(job).is_err() {
            tracing::error!("the delivery task stopped");
        } else if counts {
            self.in_flight += 1;
        }
    }

    /// Delivers `content` of `domain` as `station`'s recipe `name`; the
    /// download is answered when it ends.
    pub fn pass_on(
        &mut self,
        domain: ObjectName,
        station: StationName,
        name: ObjectName,
        content: Vec<u8>,
        responder: Responder,
    ) {
        let job = Job::PassOn(Box::new(PassOn {
            domain,
            station,
            name,
            content,
            responder,
        }));
        self.ask(job, true);
    }

    /// A workstation was lost: it will come back empty.
    pub fn forget(&mut self, station: &StationName) {
        self.ask(Job::Forget(station.clone()), false);
    }

    /// Sends every `STATION$NAME` domain of `vmd` that its workstation
    /// does not hold (after the workstations were associated again).
    pub fn catch_up(&mut self, vmd: &Vmd) {
        let todo: Vec<(StationName, ObjectName, Vec<u8>)> = vmd
            .domains()
            .filter_map(|d| {
                let (st, name) = workstation_domain(d.name())?;
                Some((st, name, d.content().to_vec()))
            })
            .collect();
        if !todo.is_empty() {
            self.ask(Job::CatchUp(todo), true);
        }
    }
}

/// What each workstation holds: content hash per recipe.
#[derive(Debug, Default)]
struct Passer {
    delivered: BTreeMap<(StationName, ObjectName), u64>,
}

impl Passer {
    /// Delivers `content` as `station`'s recipe `name` unless it has it.
    async fn pass_on(
        &mut self,
        bus: &Bus,
        station: &StationName,
        name: &ObjectName,
        content: &[u8],
    ) -> Result<(), ServiceError> {
        let hash = content_hash(content);
        let key = (station.clone(), name.clone());
        if self.delivered.get(&key) == Some(&hash) {
            return Ok(());
        }
        match bus.deliver(station, name, content).await {
            Ok(()) => {
                say(&format!("EVENT delivered station={station} recipe={name}"));
                self.delivered.insert(key, hash);
                Ok(())
            }
            Err(e) => {
                self.delivered.remove(&key);
                Err(e)
            }
        }
    }

    /// A workstation was lost: it will come back empty.
    fn forget(&mut self, station: &StationName) {
        self.delivered.retain(|(st, _), _| st != station);
    }
}
