//! The operator API on the bus: the operator node serves one queryable per
//! [`Call`] (`falc/<cell>/<operator>/api/<call>/*`), a console queries its
//! call under its own user name (`…/api/<call>/<user>`). The router's ACL
//! decides which console user may query which call (by role) and lets each
//! query only under its own, authenticated, name: so the user the operator
//! journals is the last key chunk, never a claim in the payload. A refused
//! call ends like a call nobody serves: "no reply". Payloads are
//! [`envelope`]s of [`ApiRequest`] and [`ApiResult`]; a malformed request is
//! answered with an error by the bus.

use super::{declare_failed, Bus, BusError, Declaration};
use falc_model::api::{ApiReply, ApiRequest, ApiResult, Call, MAX_REQUEST_BYTES};
use falc_model::envelope;
use falc_model::ids::{CellId, StationName};
use std::time::Duration;
use tokio::sync::mpsc::UnboundedSender;
use zenoh::query::Query;
use zenoh::Wait;

/// How long a client of the operator API (the console, the OPC UA gateway)
/// waits for the answer to a call that changes something.
pub const CALL_LIMIT: Duration = Duration::from_secs(15);

/// A console's request that arrived at the operator node.
#[derive(Debug)]
pub struct ApiIndication {
    /// The console user who asks (authenticated by the router; named in the
    /// journal).
    pub user: StationName,
    /// The cell it is for (`?cell=C` on the key), in a plant; None: the
    /// plant's, or the one cell's.
    pub cell: Option<CellId>,
    /// The request.
    pub request: ApiRequest,
    /// Answers it.
    pub responder: ApiResponder,
}

/// The selector parameter that names the cell a request is for.
const CELL_PARAMETER: &str = "cell";

/// Sends the answer to one API request.
#[derive(Debug)]
pub struct ApiResponder {
    query: Query,
}

impl ApiResponder {
    /// Sends the answer; a failure to send (the console left) is logged.
    pub async fn respond(self, result: ApiResult) {
        let key = self.query.key_expr().clone();
        if let Err(e) = self
            .query
            .reply(key.clone(), envelope::encode(&result))
            .await
        {
            tracing::warn!(%key, "API answer not sent: {e}");
        }
    }
}

fn answer_now(query: &Query, result: &ApiResult) {
    if let Err(e) = query
        .reply(query.key_expr().clone(), envelope::encode(result))
        .wait()
    {
        tracing::warn!("API answer not sent: {e}");
    }
}

fn on_query(call: Call, query: Query, tx: &UnboundedSender<ApiIndication>) {
    let key = query.key_expr().as_str();
    let user = key
        .rsplit('/')
        .next()
        .and_then(|u| StationName::new(u).ok())
        .ok_or_else(|| format!("API request on {key} names no valid user"));
    let cell = match query.parameters().get(CELL_PARAMETER) {
        None => Ok(None),
        Some(c) => CellId::new(c)
            .map(Some)
            .map_err(|e| format!("API request on {key}: {e}")),
    };
    let request = query
        .payload()
        .ok_or_else(|| format!("API request on {key} carries no payload"))
        .and_then(|p| {
            if p.len() > MAX_REQUEST_BYTES {
                return Err(format!(
                    "API request on {key} is {} bytes, more than the {MAX_REQUEST_BYTES} the operator takes: refused",
                    p.len()
                ));
            }
            envelope::decode::<ApiRequest>(&p.to_bytes())
                .map_err(|e| format!("malformed API request on {key}: {e}"))
        })
        .and_then(|r| r.check_limits().map(|()| r))
        .and_then(|r| {
            if r.call() == call {
                Ok(r)
            } else {
                Err(format!(
                    "a {} request was sent to the {call} key {key}",
                    r.call()
                ))
            }
        });
    match user.and_then(|u| cell.and_then(|c| request.map(|r| (u, c, r)))) {
        Ok((user, cell, request)) => {
            let ind = ApiIndication {
                user,
                cell,
                request,
                responder: ApiResponder { query },
            };
            if let Err(e) = tx.send(ind) {
                answer_now(
                    &e.0.responder.query,
                    &Err("the operator node is shutting down".into()),
                );
            }
        }
        Err(text) => {
            crate::log_limit::warn(query.key_expr().as_str(), &text);
            answer_now(&query, &Err(text));
        }
    }
}

/// Why an operator API call brought no reply. Its text says which call and
/// why, ready for a console to show.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CallError {
    /// No reply: the operator node is not there, or the router's ACL
    /// refused the call (zenoh cannot tell which).
    #[error("{0}")]
    NoReply(String),
    /// The operator node answered: refused, and why.
    #[error("{0}")]
    Refused(String),
}

impl Bus {
    /// Serves every operator API call of this (operator) node; requests go
    /// to `tx`.
    pub async fn serve_api(
        &self,
        tx: UnboundedSender<ApiIndication>,
    ) -> Result<Vec<Declaration>, BusError> {
        let mut out = Vec::with_capacity(Call::ALL.len());
        for &call in Call::ALL {
            let key = self.keys.api_any(&self.me.station, call);
            let tx = tx.clone();
            let q = self
                .session
                .declare_queryable(&key)
                .callback(move |query| on_query(call, query, &tx))
                .await
                .map_err(declare_failed("API queryable", &key))?;
            out.push(Declaration(Box::new(q)));
        }
        Ok(out)
    }

    /// Makes an operator API call as this session's user (for the cell of
    /// [`Bus::for_cell`]); the reply, or why there is none: no reply, or
    /// the operator's refusal.
    pub async fn api(
        &self,
        operator: &StationName,
        request: ApiRequest,
        deadline: Duration,
    ) -> Result<ApiReply, CallError> {
        let me = self.me.station.clone();
        let cell = self.api_cell.clone();
        self.api_as(operator, cell.as_ref(), request, &me, deadline)
            .await
    }

    /// Makes an operator API call on the key of console user `user`. The
    /// router answers nothing unless `user` is this session's own user:
    /// what the ACL tests try.
    pub async fn api_as(
        &self,
        operator: &StationName,
        cell: Option<&CellId>,
        request: ApiRequest,
        user: &StationName,
        deadline: Duration,
    ) -> Result<ApiReply, CallError> {
        let call = request.call();
        let mut key = self.keys.api(operator, call, user);
        if let Some(cell) = cell {
            key = format!("{key}?{CELL_PARAMETER}={cell}");
        }
        let payload = envelope::encode(&request);
        let what = format!("`{call}` of the operator API ({key})");
        match self
            .query::<ApiResult>(&key, payload, deadline, &what)
            .await
        {
            Ok(result) => result.map_err(CallError::Refused),
            Err(e) => Err(CallError::NoReply(e.description)),
        }
    }
}
