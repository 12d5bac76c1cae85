//! `falc status --watch` and `falc messages --follow`: asking again
//! whenever the operator says its status changed, and every [`POLL`],
//! until Ctrl-C.

use crate::call::CALL_LIMIT;
use crate::output::print;
use falc_bus::Bus;
use falc_model::api::{ApiReply, ApiRequest};
use falc_model::ids::StationName;
use std::process::ExitCode;
use std::time::Duration;

/// How often `--watch` and `--follow` ask again when the operator has
/// said nothing; they ask at once when it publishes a change.
const POLL: Duration = Duration::from_millis(250);

/// Asks `request(state)` again whenever the operator says its status
/// changed, and every `POLL`, until Ctrl-C or a failure; `show` prints
/// what is new and updates the state.
async fn poll<S>(
    bus: &Bus,
    operator: &StationName,
    mut state: S,
    request: impl Fn(&S) -> ApiRequest,
    mut show: impl FnMut(&mut S, ApiReply),
) -> ExitCode {
    let mut stop = falc_node::Shutdown::new();
    let changed = std::sync::Arc::new(tokio::sync::Notify::new());
    let poke = changed.clone();
    let _changed = match bus.on_changed(operator, move || poke.notify_one()).await {
        Ok(d) => Some(d),
        Err(e) => {
            tracing::warn!("asking every {} ms only: {e}", POLL.as_millis());
            None
        }
    };
    loop {
        tokio::select! {
            r = bus.api(operator, request(&state), CALL_LIMIT) => match r {
                Ok(reply) => show(&mut state, reply),
                Err(why) => {
                    eprintln!("falc: {why}");
                    return ExitCode::FAILURE;
                }
            },
            _ = stop.requested() => return ExitCode::SUCCESS,
        }
        tokio::select! {
            _ = tokio::time::sleep(POLL) => {}
            _ = changed.notified() => {}
            _ = stop.requested() => return ExitCode::SUCCESS,
        }
    }
}

/// `status --watch`: the status whenever it changed.
pub(crate) async fn watch(bus: &Bus, operator: &StationName, json: bool) -> ExitCode {
    let show = |last: &mut Option<ApiReply>, reply: ApiReply| {
        if last.as_ref() != Some(&reply) {
            if !json {
                crate::out!("---");
            }
            print(&reply, json);
            *last = Some(reply);
        }
    };
    poll(bus, operator, None, |_| ApiRequest::Status, show).await
}

/// `falc messages --follow`: new messages as they come, of `station`
/// only if given.
pub(crate) async fn follow(
    bus: &Bus,
    operator: &StationName,
    json: bool,
    station: Option<&StationName>,
) -> ExitCode {
    let show = |after: &mut i64, reply: ApiReply| match reply {
        ApiReply::Entries(v) => {
            for e in v {
                *after = (*after).max(e.id);
                if station.map_or(true, |s| e.who == s.as_str()) {
                    print(&ApiReply::Entries(vec![e]), json);
                }
            }
        }
        other => print(&other, json),
    };
    poll(
        bus,
        operator,
        0,
        |&after| ApiRequest::Messages { after, last: None },
        show,
    )
    .await
}
