//! Every zenoh key FALC uses, built in one place (DESIGN.md §3).
//!
//! | key | primitive |
//! |---|---|
//! | `falc/<cell>/<st>/svc/<service>` | queryable: confirmed service |
//! | `falc/<cell>/<st>/status` | put: unsolicited status |
//! | `falc/<cell>/<st>/report` | put: information reports |
//! | `falc/<cell>/alive/<st>/<session>` | liveliness token |
//!
//! The liveliness key carries the session id as a last chunk so that an
//! abort indication always refers to the one session that was associated,
//! even while a restarted node already holds a new token.

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

    /// The cell id.
    pub fn cell(&self) -> &CellId {
        &self.cell
    }

    /// `falc/<cell>/<st>/svc/<service>`.
    pub fn service(&self, station: &StationName, service: ServiceName) -> String {
        format!("falc/{}/{station}/svc/{service}", self.cell)
    }

    /// Parses a service key of this cell back into station and service.
    pub fn parse_service(&self, key: &str) -> Option<(StationName, ServiceName)> {
        let mut parts = key.split('/');
        match (
            parts.next(),
            parts.next(),
            parts.next(),
            parts.next(),
            parts.next(),
            parts.next(),
        ) {
            (Some("falc"), Some(cell), Some(st), Some("svc"), Some(svc), None)
                if cell == self.cell.as_str() =>
            {
                Some((StationName::new(st).ok()?, ServiceName::from_key(svc)?))
            }
            _ => None,
        }
    }

    /// `falc/<cell>/<st>/status`.
    pub fn status(&self, station: &StationName) -> String {
        format!("falc/{}/{station}/status", self.cell)
    }

    /// `falc/<cell>/<st>/report`.
    pub fn report(&self, station: &StationName) -> String {
        format!("falc/{}/{station}/report", self.cell)
    }

    /// `falc/<cell>/alive/<st>/<session>`: one session's token.
    pub fn alive(&self, station: &StationName, session: &str) -> String {
        format!("falc/{}/alive/{station}/{session}", self.cell)
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
    fn service_keys_round_trip() {
        let k = KeySpace::new(CellId::new("falc1").expect("valid"));
        let w = StationName::new("welding").expect("valid");
        let key = k.service(&w, ServiceName::InitiateDownloadSequence);
        assert_eq!(key, "falc/falc1/welding/svc/initiate-download-sequence");
        assert_eq!(
            k.parse_service(&key),
            Some((w, ServiceName::InitiateDownloadSequence))
        );
        assert_eq!(k.parse_service("falc/other/welding/svc/status"), None);
        assert_eq!(k.parse_service("falc/falc1/welding/svc/nope"), None);
        assert_eq!(k.parse_service("falc/falc1/welding/svc/status/x"), None);
    }
}
