//! Delivering a recipe to a subordinate, sans-I/O: the requests in order
//! and what a refusal means, all or nothing.
//!
//! A delivery replaces what was there: it deletes the program invocation
//! and the domain of that name (absent is fine), downloads the content
//! ([`download_steps`]) and, for a recipe the receiver runs, creates its
//! reusable program invocation. A refused step of the download or the
//! invocation deletes the domain again (leaving nothing half there), and
//! the delivery fails naming the recipe, the station and the refusal.
//!
//! The driver sends each [`DeliveryStep::Send`] with [`STEP_LIMIT`] and
//! hands its confirm to [`Delivery::answered`], until
//! [`DeliveryStep::Done`]. The operator and the cell deliver over zenoh
//! (`falc_bus::download`); `falc-sim` carries the same steps over its
//! simulated bus.

use super::domain::{content_hash, download_steps};
use super::error::{DefinitionError, ErrorClass, ServiceError};
use super::pdu::{Request, Response};
use crate::ids::{ObjectName, StationName};
use std::collections::VecDeque;
use std::time::Duration;

/// How long each step of a delivery may take.
pub const STEP_LIMIT: Duration = Duration::from_secs(10);

/// What the driver does next.
#[derive(Debug, Clone, PartialEq)]
pub enum DeliveryStep {
    /// Send this request to the receiver; its confirm goes to
    /// [`Delivery::answered`].
    Send(Request),
    /// The delivery ended.
    Done(Result<(), ServiceError>),
}

/// What a step is for: what its refusal means.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Purpose {
    /// Clearing what was there: a refusal is fine (it was absent).
    Clear,
    /// The recipe itself: a refusal fails the delivery.
    Load,
    /// Taking a failed delivery back: whatever it answers, the delivery
    /// has failed.
    TakeBack,
}

/// One delivery under way.
#[derive(Debug, Clone)]
pub struct Delivery {
    to: StationName,
    name: ObjectName,
    /// The content's [`content_hash`].
    hash: u64,
    steps: VecDeque<(Request, Purpose)>,
    /// What the request out is for (none out: not started or done).
    out: Option<Purpose>,
    failed: Option<ServiceError>,
}

impl Delivery {
    /// Delivering `content` to `to` as domain `name`, with its reusable
    /// program invocation if `with_program` (a workstation's recipe the
    /// cell only holds to pass on has none).
    pub fn new(to: StationName, name: ObjectName, content: &[u8], with_program: bool) -> Self {
        let mut steps: VecDeque<(Request, Purpose)> = [
            Request::DeleteProgramInvocation { name: name.clone() },
            Request::DeleteDomain {
                domain: name.clone(),
            },
        ]
        .into_iter()
        .map(|r| (r, Purpose::Clear))
        .collect();
        steps.extend(
            download_steps(&name, content)
                .into_iter()
                .map(|r| (r, Purpose::Load)),
        );
        if with_program {
            steps.push_back((
                Request::CreateProgramInvocation {
                    name: name.clone(),
                    domains: vec![name.clone()],
                    reusable: true,
                },
                Purpose::Load,
            ));
        }
        Self {
            to,
            name,
            hash: content_hash(content),
            steps,
            out: None,
            failed: None,
        }
    }

    /// The station it goes to.
    pub fn to(&self) -> &StationName {
        &self.to
    }

    /// The recipe's domain.
    pub fn name(&self) -> &ObjectName {
        &self.name
    }

    /// The [`content_hash`] of what it delivers: a receiver that confirmed
    /// it holds a domain of its name with this hash.
    pub fn content_hash(&self) -> u64 {
        self.hash
    }

    /// The first step.
    pub fn start(&mut self) -> DeliveryStep {
        self.next()
    }

    /// The confirm of the step sent last; the next step.
    pub fn answered(&mut self, result: Result<Response, ServiceError>) -> DeliveryStep {
        if let (Some(Purpose::Load), Err(e)) = (self.out, result) {
            self.failed = Some(ServiceError::new(
                ErrorClass::Definition(DefinitionError::ObjectAttributeInconsistent),
                format!(
                    "recipe {} cannot be created on WS {}: {e}",
                    self.name,
                    self.to.as_str().to_uppercase()
                ),
            ));
            self.steps.clear();
            self.steps.push_back((
                Request::DeleteDomain {
                    domain: self.name.clone(),
                },
                Purpose::TakeBack,
            ));
        }
        self.next()
    }

    fn next(&mut self) -> DeliveryStep {
        match self.steps.pop_front() {
            Some((request, purpose)) => {
                self.out = Some(purpose);
                DeliveryStep::Send(request)
            }
            None => {
                self.out = None;
                DeliveryStep::Done(self.failed.take().map_or(Ok(()), Err))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn name(s: &str) -> ObjectName {
        ObjectName::new(s).expect("valid")
    }

    fn welding() -> StationName {
        StationName::new("welding").expect("valid")
    }

    /// Runs `d` against a receiver answering each request with `answer`;
    /// the requests sent and the outcome.
    fn run(
        mut d: Delivery,
        mut answer: impl FnMut(&Request) -> Result<Response, ServiceError>,
    ) -> (Vec<Request>, Result<(), ServiceError>) {
        let mut sent = Vec::new();
        let mut step = d.start();
        loop {
            match step {
                DeliveryStep::Send(r) => {
                    let a = answer(&r);
                    sent.push(r);
                    step = d.answered(a);
                }
                DeliveryStep::Done(r) => return (sent, r),
            }
        }
    }

    fn kinds(sent: &[Request]) -> Vec<&'static str> {
        sent.iter().map(|r| r.service().as_str()).collect()
    }

    #[test]
    fn clears_downloads_and_creates_the_invocation() {
        let d = Delivery::new(welding(), name("DIKDROOG"), b"state s", true);
        let (sent, result) = run(d, |_| Ok(Response::Done));
        assert_eq!(result, Ok(()));
        assert_eq!(
            kinds(&sent),
            [
                "delete-program-invocation",
                "delete-domain",
                "initiate-download-sequence",
                "download-segment",
                "terminate-download-sequence",
                "create-program-invocation"
            ]
        );
    }

    #[test]
    fn nothing_there_before_is_fine_and_a_domain_only_has_no_invocation() {
        let d = Delivery::new(welding(), name("DIKDROOG"), b"state s", false);
        let (sent, result) = run(d, |r| match r {
            Request::DeleteProgramInvocation { .. } | Request::DeleteDomain { .. } => {
                Err(ServiceError::undefined("no such object"))
            }
            _ => Ok(Response::Done),
        });
        assert_eq!(result, Ok(()));
        assert_eq!(kinds(&sent).last(), Some(&"terminate-download-sequence"));
    }

    #[test]
    fn a_refused_step_takes_the_domain_back_and_names_recipe_station_and_cause() {
        let d = Delivery::new(welding(), name("DIKDROOG"), b"state s", true);
        let (sent, result) = run(d, |r| match r {
            Request::DownloadSegment { .. } => Err(ServiceError::state_conflict("disk full")),
            // The take-back refused too: the first refusal is the one told.
            Request::DeleteDomain { .. } => Err(ServiceError::undefined("gone")),
            _ => Ok(Response::Done),
        });
        assert_eq!(
            kinds(&sent),
            [
                "delete-program-invocation",
                "delete-domain",
                "initiate-download-sequence",
                "download-segment",
                "delete-domain"
            ]
        );
        let e = result.expect_err("refused");
        assert_eq!(
            e.class,
            ErrorClass::Definition(DefinitionError::ObjectAttributeInconsistent)
        );
        assert!(
            e.description
                .starts_with("recipe DIKDROOG cannot be created on WS WELDING: ")
                && e.description.contains("disk full"),
            "{}",
            e.description
        );
    }

    #[test]
    fn a_refused_invocation_fails_the_delivery_too() {
        let d = Delivery::new(welding(), name("DIKDROOG"), b"state s", true);
        let (sent, result) = run(d, |r| match r {
            Request::CreateProgramInvocation { .. } => {
                Err(ServiceError::state_conflict("program running"))
            }
            _ => Ok(Response::Done),
        });
        assert!(result.is_err());
        assert_eq!(kinds(&sent).last(), Some(&"delete-domain"));
    }
}
