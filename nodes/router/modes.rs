//! Clients only. FALC's nodes and consoles are zenoh clients; a session
//! in router or peer mode is closed by the router as soon as it is
//! established.
//!
//! - *Peer mode* is refused by the configuration: `gateway.south` admits
//!   clients only, a peer falls outside it and its transport is refused as
//!   it opens.
//! - *Router mode* has no setting in zenoh 1.10.2: a router remote that
//!   matches no south filter is taken as a neighbour router, one that
//!   matches is a south router region, both admitted
//!   (`zenoh/src/net/runtime/region.rs`, `compute_region_of`). So the
//!   router builds its zenoh runtime itself (zenoh's `internal` API) and
//!   adds a transport-event handler ([`ClientsOnly`]): every new transport
//!   whose remote is not a client is closed at once and logged, rate-limited
//!   per address ([`falc_bus::log_limit::warn`]).
//!
//! A link between a plant's routers is logged when it opens (`router …
//! linked`) and when it closes (`router … link closed`): a cell's link up
//! lost is in its router's log.
//!
//! zenoh runs a new transport's event handlers while the transport's
//! status lock is held, so the close waits until the transport is whole
//! and the routing tables are told of its end as of any other. Between the
//! two, the remote's first messages may be routed: within its user's
//! rights, as the access control applies to every session.

use std::collections::BTreeSet;
use std::sync::Arc;
use zenoh::config::WhatAmI;
use zenoh_link::Link;
use zenoh_protocol::network::NetworkMessageMut;
use zenoh_transport::{
    multicast::TransportMulticast, unicast::TransportUnicast, TransportEventHandler,
    TransportMulticastEventHandler, TransportPeer, TransportPeerEventHandler,
};

/// Which routers a router admits besides clients: none in a cell of its
/// own; in a plant, the factory router admits each cell router (by the
/// user it logged in with), and a cell router its own link up to the
/// factory router (which it opened: no user logged in on it).
#[derive(Debug, Clone, Default)]
pub struct Admit {
    /// The cell routers' users (at the factory router).
    pub routers: BTreeSet<String>,
    /// The factory router's zenoh id (at a cell router).
    pub uplink: Option<String>,
}

/// Whether a remote may keep its session: a client, unless it claims the
/// factory router's id (only the link the cell router opened may carry
/// it, and that one has no user), or a router the plant names.
pub fn admitted(admit: &Admit, mode: WhatAmI, user: Option<&str>, zid: &str) -> bool {
    let is_uplink = admit.uplink.as_deref() == Some(zid);
    match mode {
        WhatAmI::Client => !is_uplink,
        WhatAmI::Router => match user {
            Some(user) => admit.routers.contains(user),
            None => is_uplink,
        },
        WhatAmI::Peer => false,
    }
}

/// Whether a session's certificate and its login name one user: over QUIC
/// each node's certificate's common name is its user, so a certificate of
/// one user with another's password (`cert`, `user`) is refused, even
/// though the access control would let it reach nothing. Either missing
/// (plain tcp, a router's link up): nothing to compare.
pub fn one_user(user: Option<&str>, cert: Option<&str>) -> bool {
    match (user, cert) {
        (Some(u), Some(c)) => u == c,
        _ => true,
    }
}

/// The host part of a locator (`tcp/10.0.0.5:41234` → `tcp/10.0.0.5`): a
/// remote that reconnects comes from a new port each time but is one
/// source of log lines.
pub fn host(locator: &str) -> &str {
    locator.rsplit_once(':').map_or(locator, |(host, _)| host)
}

/// The transport-event handler that closes every session not in client
/// mode. It is one of the runtime's extra handlers: what it returns is not
/// used by zenoh beyond being told of links and the end.
pub struct ClientsOnly {
    tasks: tokio::runtime::Handle,
    admit: Admit,
}

impl ClientsOnly {
    /// A handler whose closes run on `tasks`, admitting clients and the
    /// routers `admit` names.
    pub fn new(tasks: tokio::runtime::Handle, admit: Admit) -> Self {
        ClientsOnly { tasks, admit }
    }
}

/// Closes `transport` (from `from`, in mode `mode`) on `tasks`.
fn close(
    tasks: &tokio::runtime::Handle,
    transport: TransportUnicast,
    from: String,
    mode: WhatAmI,
) -> zenoh::Result<Arc<dyn TransportPeerEventHandler>> {
    // The close holds the transport from its first poll, here: zenoh
    // keeps only a weak reference in `transport`, and a remote that
    // reconnects at once can have its new transport dropped from
    // zenoh's table by the end of its previous one (seen: the
    // orphan then lived on, unclosed). The first poll takes the
    // strong reference and waits for the transport's status lock,
    // which zenoh holds until the transport is whole.
    let mut close = Box::pin(async move {
        if let Err(e) = transport.close().await {
            tracing::warn!("closing a {mode} session from {from}: {e}");
        }
    });
    let mut cx = std::task::Context::from_waker(futures::task::noop_waker_ref());
    if futures::FutureExt::poll_unpin(&mut close, &mut cx).is_pending() {
        tasks.spawn(close);
    }
    Err("refused: closed".into())
}

/// A link between routers of a plant, watched for its end: the log says
/// when a cell's link up (or a cell router's link, at the factory router)
/// closed, as it says when it linked.
struct RouterLink {
    zid: String,
    what: String,
}

impl TransportPeerEventHandler for RouterLink {
    fn handle_message(&self, _msg: NetworkMessageMut) -> zenoh::Result<()> {
        Ok(())
    }
    fn new_link(&self, _link: Link) {}
    fn del_link(&self, _link: Link) {}
    fn closed(&self) {
        tracing::info!("router {} link closed ({})", self.zid, self.what);
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

impl TransportEventHandler for ClientsOnly {
    fn new_unicast(
        &self,
        peer: TransportPeer,
        transport: TransportUnicast,
    ) -> zenoh::Result<Arc<dyn TransportPeerEventHandler>> {
        let user = transport
            .get_auth_ids()
            .ok()
            .and_then(|ids| ids.username().cloned());
        let cert = transport.get_auth_ids().ok().and_then(|ids| {
            ids.link_auth_ids()
                .iter()
                .find_map(|l| l.get_cert_common_name().map(str::to_string))
        });
        let zid = peer.zid.to_string();
        if !one_user(user.as_deref(), cert.as_deref()) {
            let from = peer
                .links
                .first()
                .map(|l| l.dst.to_string())
                .unwrap_or_else(|| "an unknown address".into());
            falc_bus::log_limit::warn(
                host(&from),
                &format!(
                    "refused login: a session from {from} logged in as {} with the certificate of {} (zenoh id {zid}) closed: a node's certificate names its own user",
                    falc_model::ids::printable(user.as_deref().unwrap_or_default()),
                    falc_model::ids::printable(cert.as_deref().unwrap_or_default()),
                ),
            );
            return close(&self.tasks, transport, from, peer.whatami);
        }
        if admitted(&self.admit, peer.whatami, user.as_deref(), &zid) {
            if peer.whatami == WhatAmI::Router {
                let what = user
                    .as_deref()
                    .unwrap_or("the link up to the factory router")
                    .to_string();
                tracing::info!("router {zid} linked ({what})");
                return Ok(Arc::new(RouterLink { zid, what }));
            }
            return Err("admitted: nothing to do".into());
        }
        let from = peer
            .links
            .first()
            .map(|l| l.dst.to_string())
            .unwrap_or_else(|| "an unknown address".into());
        let who = user
            .as_deref()
            .map(|u| format!(" as {}", falc_model::ids::printable(u)))
            .unwrap_or_default();
        falc_bus::log_limit::warn(
            host(&from),
            &format!(
                "a session in {} mode from {from}{who} (zenoh id {zid}) closed: FALC admits clients only, and in a plant the routers it names (docs/install.md, \"Clients only\")",
                peer.whatami
            ),
        );
        close(&self.tasks, transport, from, peer.whatami)
    }

    fn new_multicast(
        &self,
        _transport: TransportMulticast,
    ) -> zenoh::Result<Arc<dyn TransportMulticastEventHandler>> {
        Err("the router has no multicast transport".into())
    }
}

/// Opens the router's zenoh session on `cfg` with [`ClientsOnly`] in place
/// before it listens.
pub async fn open(cfg: zenoh::Config, admit: Admit) -> zenoh::Result<zenoh::Session> {
    use zenoh::internal::runtime::{DynamicRuntime, RuntimeBuilder};
    let mut runtime = RuntimeBuilder::new(cfg).build().await?;
    let dynamic = DynamicRuntime::from(runtime.clone());
    dynamic.new_handler(Arc::new(ClientsOnly::new(
        tokio::runtime::Handle::current(),
        admit,
    )));
    let session = zenoh::session::init(dynamic).await?;
    runtime.start().await?;
    Ok(session)
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_certificate_must_name_the_user_that_logged_in() {
        assert!(super::one_user(Some("console"), Some("console")));
        assert!(!super::one_user(Some("cell"), Some("observer")));
        // Plain tcp (no certificate), a router's link up (no login).
        assert!(super::one_user(Some("cell"), None));
        assert!(super::one_user(None, Some("falc-router")));
    }

    use super::*;

    #[test]
    fn only_clients_are_admitted() {
        let cell = Admit::default();
        assert!(admitted(&cell, WhatAmI::Client, Some("welding"), "a1"));
        assert!(!admitted(&cell, WhatAmI::Router, Some("welding"), "a1"));
        assert!(!admitted(&cell, WhatAmI::Router, None, "a1"));
        assert!(!admitted(&cell, WhatAmI::Peer, Some("welding"), "a1"));
    }

    #[test]
    fn in_a_plant_the_named_routers_are_admitted_and_nobody_else_as_the_factory() {
        let factory = Admit {
            routers: ["router-falc1".to_string()].into(),
            uplink: None,
        };
        assert!(admitted(
            &factory,
            WhatAmI::Router,
            Some("router-falc1"),
            "c1"
        ));
        assert!(!admitted(&factory, WhatAmI::Router, Some("operator"), "c1"));
        assert!(!admitted(
            &factory,
            WhatAmI::Peer,
            Some("router-falc1"),
            "c1"
        ));
        assert!(admitted(&factory, WhatAmI::Client, Some("operator"), "b2"));
        let cell = Admit {
            routers: Default::default(),
            uplink: Some("f123".into()),
        };
        // Its own link up: a router with no user logged in (it opened it).
        assert!(admitted(&cell, WhatAmI::Router, None, "f123"));
        assert!(!admitted(&cell, WhatAmI::Router, None, "f999"));
        // A station that claims the factory router's id is closed, in
        // any mode: the access control names the link up by that id.
        assert!(!admitted(&cell, WhatAmI::Client, Some("welding"), "f123"));
        assert!(!admitted(&cell, WhatAmI::Router, Some("welding"), "f123"));
        assert!(admitted(&cell, WhatAmI::Client, Some("welding"), "a1"));
    }

    #[test]
    fn a_source_is_the_remote_host_without_its_port() {
        assert_eq!(host("tcp/10.0.0.5:41234"), "tcp/10.0.0.5");
        assert_eq!(host("quic/[::1]:7447"), "quic/[::1]");
        assert_eq!(host("an unknown address"), "an unknown address");
    }
}
