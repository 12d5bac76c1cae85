//! Recipe delivery to a subordinate: a domain download (Initiate, segments,
//! Terminate) and its reusable program invocation, replacing what was
//! there, all or nothing. The operator delivers to the cell, the cell to
//! its workstations; both skip content they delivered before
//! (`mms::domain::content_hash`). The requests themselves are
//! `falc_model::mms::domain::download_steps`.

use super::Bus;
use falc_model::ids::{ObjectName, StationName};
use falc_model::mms::domain::download_steps;
use falc_model::mms::error::{DefinitionError, ErrorClass, ServiceError};
use falc_model::mms::pdu::Request;
use std::time::Duration;

/// How long each step of a delivery may take.
const STEP_LIMIT: Duration = Duration::from_secs(10);

impl Bus {
    /// Delivers `content` to `station` as domain `name` with a reusable
    /// program invocation of the same name, replacing what was there. On
    /// failure nothing of it is left there, and the error says which recipe
    /// on which station and why.
    pub async fn deliver(
        &self,
        station: &StationName,
        name: &ObjectName,
        content: &[u8],
    ) -> Result<(), ServiceError> {
        self.deliver_as(station, name, content, true).await
    }

    /// Like [`Bus::deliver`] but the domain only, without a program
    /// invocation (a workstation recipe the cell holds to pass on).
    pub async fn deliver_domain(
        &self,
        station: &StationName,
        name: &ObjectName,
        content: &[u8],
    ) -> Result<(), ServiceError> {
        self.deliver_as(station, name, content, false).await
    }

    async fn deliver_as(
        &self,
        station: &StationName,
        name: &ObjectName,
        content: &[u8],
        with_program: bool,
    ) -> Result<(), ServiceError> {
        // What was there before goes first (absent is fine).
        for req in [
            Request::DeleteProgramInvocation { name: name.clone() },
            Request::DeleteDomain {
                domain: name.clone(),
            },
        ] {
            let _ = self.request(station, &req, STEP_LIMIT).await;
        }
        let mut steps = download_steps(name, content);
        if with_program {
            steps.push(Request::CreateProgramInvocation {
                name: name.clone(),
                domains: vec![name.clone()],
                reusable: true,
            });
        }
        for req in steps {
            if let Err(e) = self.request(station, &req, STEP_LIMIT).await {
                // Leave nothing half there.
                let _ = self
                    .request(
                        station,
                        &Request::DeleteDomain {
                            domain: name.clone(),
                        },
                        STEP_LIMIT,
                    )
                    .await;
                return Err(ServiceError::new(
                    ErrorClass::Definition(DefinitionError::ObjectAttributeInconsistent),
                    format!(
                        "recipe {name} cannot be created on WS {}: {e}",
                        station.as_str().to_uppercase()
                    ),
                ));
            }
        }
        Ok(())
    }
}
