//! Sessions that are not clients. FALC's nodes and consoles are zenoh
//! clients; the router's configuration refuses a session in peer mode
//! (`gateway.south` admits clients only: a peer falls outside it and its
//! transport is refused as it opens). zenoh 1.10.2 has no setting that
//! refuses a *router-mode* session with valid credentials: a router
//! remote that matches no south filter is taken as a neighbour router,
//! and one that matches is a south router region, both admitted
//! (`zenoh/src/net/runtime/region.rs`, `compute_region_of`). Such a
//! session keeps its user's rights (the ACL applies to it as to a client)
//! but takes part in the router network and makes zenoh log errors
//! (rate-limited: `falc_node::zenoh_log`).
//!
//! Until zenoh can refuse it, the router watches its transports once a
//! second and logs each session in router or peer mode at WARN, once, with
//! its zenoh id.

use std::collections::BTreeSet;
use std::time::Duration;
use zenoh::config::{WhatAmI, ZenohId};

/// How often the transports are looked at.
pub const PERIOD: Duration = Duration::from_secs(1);

/// The sessions of `now` that were not in `seen`; `seen` becomes `now`.
pub fn newly_seen(seen: &mut BTreeSet<String>, now: BTreeSet<String>) -> Vec<String> {
    let new = now.difference(seen).cloned().collect();
    *seen = now;
    new
}

/// Watches the router's transports for sessions that are not clients,
/// until the task is aborted.
pub async fn watch(session: zenoh::Session) {
    let mut seen: [BTreeSet<String>; 2] = Default::default();
    let mut tick = tokio::time::interval(PERIOD);
    loop {
        tick.tick().await;
        for (mode, seen) in [WhatAmI::Router, WhatAmI::Peer]
            .into_iter()
            .zip(seen.iter_mut())
        {
            let s = session.clone();
            let now = tokio::task::spawn_blocking(move || zids(&s, mode))
                .await
                .unwrap_or_default();
            for zid in newly_seen(seen, now) {
                tracing::warn!(
                    %zid,
                    "a session in {mode} mode is connected: FALC admits clients only, but zenoh 1.10 cannot refuse a router-mode session with valid credentials; its user's access rights still apply (docs/install.md, \"Clients only\")"
                );
            }
        }
    }
}

fn zids(session: &zenoh::Session, mode: WhatAmI) -> BTreeSet<String> {
    use zenoh::Wait;
    let ids: Box<dyn Iterator<Item = ZenohId> + Send + Sync> = match mode {
        WhatAmI::Router => session.info().routers_zid().wait(),
        _ => session.info().peers_zid().wait(),
    };
    ids.map(|z| z.to_string()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_session_is_reported_once_while_it_stays() {
        let set = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<BTreeSet<_>>();
        let mut seen = BTreeSet::new();
        assert_eq!(newly_seen(&mut seen, set(&["a"])), vec!["a"]);
        assert!(newly_seen(&mut seen, set(&["a"])).is_empty());
        assert_eq!(newly_seen(&mut seen, set(&["a", "b"])), vec!["b"]);
        // Gone and back: reported again.
        assert!(newly_seen(&mut seen, set(&["b"])).is_empty());
        assert_eq!(newly_seen(&mut seen, set(&["a", "b"])), vec!["a"]);
    }
}
