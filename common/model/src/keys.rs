//! Every zenoh key FALC uses, built in one place (docs/architecture.md, "Key space").
//!
//! | key | primitive |
//! |---|---|
//! | `falc/<cell>/<st>/svc/<service>` | queryable: confirmed service |
//! | `falc/<cell>/<st>/status` | put: unsolicited status |
//! | `falc/<cell>/<st>/report` | put: information reports |
//! | `falc/<cell>/<st>/reports` | queryable: the reports it kept (read again after a cut) |
//! | `falc/<cell>/alive/<st>/<session>` | liveliness token |
//! | `falc/<cell>/<operator>/api/<call>` | queryable: operator API |
//! | `falc/<cell>/<operator>/changed` | put: the operator's status changed (empty) |
//!
//! In a plant (`launch/factory.toml`) every cell has its own key space, and
//! the operator API and `changed` are under the plant's name.
//!
//! The liveliness key carries the session id as a last chunk so that an
//! abort indication always refers to the one session that was associated,
//! even while a restarted node already holds a new token.

use crate::api::Call;
use crate::ids::{CellId, StationName};
use crate::mms::pdu::ServiceName;

/// The key space of one cell.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct KeySpace {
    cell: CellId,
}

impl KeySpace {
    /// The key space of cell `cell`.
    pub fn new(cell: CellId) -> Self {
        Self { cell }
    }

    /// `falc/<cell>/<st>/svc/<service>`.
    pub fn service(&self, station: &StationName, service: ServiceName) -> String {
        format!("falc/{}/{station}/svc/{service}", self.cell)
    }

    /// `falc/<cell>/<st>/status`.
    pub fn status(&self, station: &StationName) -> String {
        format!("falc/{}/{station}/status", self.cell)
    }

    /// `falc/<cell>/<st>/report`.
    pub fn report(&self, station: &StationName) -> String {
        format!("falc/{}/{station}/report", self.cell)
    }

    /// `falc/<cell>/<st>/reports`: the reports and job events a station
    /// kept, for a reader who missed some ([`crate::mms::journal`]).
    pub fn reports(&self, station: &StationName) -> String {
        format!("falc/{}/{station}/reports", self.cell)
    }

    /// `falc/<cell>/alive/<st>/<session>`: one session's token.
    pub fn alive(&self, station: &StationName, session: &str) -> String {
        format!("falc/{}/alive/{station}/{session}", self.cell)
    }

    /// `falc/<cell>/<operator>/api/<call>/<user>`: one operator API call by
    /// one console user. The router lets each user query only keys ending
    /// in its own name, so the operator knows who asks from the key.
    pub fn api(&self, operator: &StationName, call: Call, user: &StationName) -> String {
        format!("falc/{}/{operator}/api/{call}/{user}", self.cell)
    }

    /// `falc/<cell>/<operator>/changed`: an empty publication each time
    /// what the operator's `status` answers changed. Consoles that watch
    /// (the OPC UA gateway, `falc status --watch`) ask again when it comes.
    pub fn changed(&self, operator: &StationName) -> String {
        format!("falc/{}/{operator}/changed", self.cell)
    }

    /// `falc/<cell>/<operator>/api/<call>/*`: a call by any user (the
    /// operator's queryable and its ACL rules).
    pub fn api_any(&self, operator: &StationName, call: Call) -> String {
        format!("falc/{}/{operator}/api/{call}/*", self.cell)
    }

    /// `falc/<cell>/**`: every key of the cell (a cell router's link to
    /// the factory router carries nothing else).
    pub fn cell_any(&self) -> String {
        format!("falc/{}/**", self.cell)
    }

    /// `falc/<cell>/alive/<st>/*`: every token of a station (ACL rules).
    pub fn alive_any(&self, station: &StationName) -> String {
        format!("falc/{}/alive/{station}/*", self.cell)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn service_keys() {
        let k = KeySpace::new(CellId::new("falc1").expect("valid"));
        let w = StationName::new("welding").expect("valid");
        assert_eq!(
            k.service(&w, ServiceName::InitiateDownloadSequence),
            "falc/falc1/welding/svc/initiate-download-sequence"
        );
        assert_eq!(k.alive(&w, "ab12"), "falc/falc1/alive/welding/ab12");
        assert_eq!(k.reports(&w), "falc/falc1/welding/reports");
        assert_eq!(k.alive_any(&w), "falc/falc1/alive/welding/*");
        let op = StationName::new("operator").expect("valid");
        let olga = StationName::new("olga").expect("valid");
        assert_eq!(
            k.api(&op, Call::OrderAdd, &olga),
            "falc/falc1/operator/api/order-add/olga"
        );
        assert_eq!(
            k.api_any(&op, Call::OrderAdd),
            "falc/falc1/operator/api/order-add/*"
        );
    }
}
