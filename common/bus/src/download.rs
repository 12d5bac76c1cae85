//! Recipe delivery to a subordinate over zenoh: the steps of
//! [`falc_model::mms::delivery::Delivery`] (replace what was there, all or
//! nothing) sent one by one. The operator delivers to the cell, the cell
//! to its workstations; both skip content they delivered before
//! (`mms::domain::content_hash`).

use super::Bus;
use falc_model::ids::{ObjectName, StationName};
use falc_model::mms::delivery::{Delivery, DeliveryStep, STEP_LIMIT};
use falc_model::mms::error::ServiceError;

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
        self.carry(Delivery::new(station.clone(), name.clone(), content, true))
            .await
    }

    /// Like [`Bus::deliver`] but the domain only, without a program
    /// invocation (a workstation recipe the cell holds to pass on).
    pub async fn deliver_domain(
        &self,
        station: &StationName,
        name: &ObjectName,
        content: &[u8],
    ) -> Result<(), ServiceError> {
        self.carry(Delivery::new(station.clone(), name.clone(), content, false))
            .await
    }

    /// Sends `delivery`'s steps until it ends (to the station it names).
    pub async fn carry(&self, mut delivery: Delivery) -> Result<(), ServiceError> {
        let to = delivery.to().clone();
        let mut step = delivery.start();
        loop {
            match step {
                DeliveryStep::Send(request) => {
                    let result = self.request(&to, &request, STEP_LIMIT).await;
                    step = delivery.answered(result);
                }
                DeliveryStep::Done(result) => return result,
            }
        }
    }
}
