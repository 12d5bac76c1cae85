//! Passing workstation recipes on: a domain the operator downloads to the
//! cell as `STATION$NAME` is `STATION`'s recipe `NAME`. When its download
//! ends the cell delivers it to that workstation (domain and program
//! invocation), and confirms only when the workstation has it; unchanged
//! content is not sent again. A workstation that was lost comes back empty:
//! when it is associated again, everything it should hold is sent again.

use falc_bus::Bus;
use falc_model::ids::{ObjectName, StationName};
use falc_model::mms::domain::content_hash;
use falc_model::mms::error::ServiceError;
use falc_model::mms::vmd::Vmd;
use falc_node::say;
use std::collections::BTreeMap;

/// `STATION$NAME` → the workstation and the recipe's name there.
pub fn workstation_domain(domain: &ObjectName) -> Option<(StationName, ObjectName)> {
    let (st, name) = domain.as_str().split_once('$')?;
    Some((StationName::new(st).ok()?, ObjectName::new(name).ok()?))
}

/// What each workstation holds: content hash per recipe.
#[derive(Debug, Default)]
pub struct Passer {
    delivered: BTreeMap<(StationName, ObjectName), u64>,
}

impl Passer {
    /// Delivers `content` as `station`'s recipe `name` unless it has it.
    pub async fn pass_on(
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
    pub fn forget(&mut self, station: &StationName) {
        self.delivered.retain(|(st, _), _| st != station);
    }

    /// Sends every `STATION$NAME` domain of `vmd` that its workstation
    /// does not hold (after a workstation was associated again). Failures
    /// are returned as text, one per recipe.
    pub async fn catch_up(&mut self, bus: &Bus, vmd: &Vmd) -> Vec<String> {
        let todo: Vec<(StationName, ObjectName, Vec<u8>)> = vmd
            .domains()
            .filter_map(|d| {
                let (st, name) = workstation_domain(d.name())?;
                Some((st, name, d.content().to_vec()))
            })
            .collect();
        let mut failed = Vec::new();
        for (st, name, content) in todo {
            if let Err(e) = self.pass_on(bus, &st, &name, &content).await {
                failed.push(e.description);
            }
        }
        failed
    }
}
