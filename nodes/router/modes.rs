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
//! zenoh runs a new transport's event handlers while the transport's
//! status lock is held, so the close waits until the transport is whole
//! and the routing tables are told of its end as of any other. Between the
//! two, the remote's first messages may be routed: within its user's
//! rights, as the access control applies to every session.

use std::sync::Arc;
use zenoh::config::WhatAmI;
use zenoh_transport::{
    multicast::TransportMulticast, unicast::TransportUnicast, TransportEventHandler,
    TransportMulticastEventHandler, TransportPeer, TransportPeerEventHandler,
};

/// Whether a remote of this mode may keep its session.
pub fn admitted(mode: WhatAmI) -> bool {
    mode == WhatAmI::Client
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
}

impl ClientsOnly {
    /// A handler whose closes run on `tasks`.
    pub fn new(tasks: tokio::runtime::Handle) -> Self {
        ClientsOnly { tasks }
    }
}

impl TransportEventHandler for ClientsOnly {
    fn new_unicast(
        &self,
        peer: TransportPeer,
        transport: TransportUnicast,
    ) -> zenoh::Result<Arc<dyn TransportPeerEventHandler>> {
        if admitted(peer.whatami) {
            return Err("a client: nothing to do".into());
        }
        let from = peer
            .links
            .first()
            .map(|l| l.dst.to_string())
            .unwrap_or_else(|| "an unknown address".into());
        falc_bus::log_limit::warn(
            host(&from),
            &format!(
                "a session in {} mode from {from} (zenoh id {}) closed: FALC admits clients only (docs/install.md, \"Clients only\")",
                peer.whatami, peer.zid
            ),
        );
        // The close holds the transport from its first poll, here: zenoh
        // keeps only a weak reference in `transport`, and a remote that
        // reconnects at once can have its new transport dropped from
        // zenoh's table by the end of its previous one (seen: the
        // orphan then lived on, unclosed). The first poll takes the
        // strong reference and waits for the transport's status lock,
        // which zenoh holds until the transport is whole.
        let mut close = Box::pin(async move {
            if let Err(e) = transport.close().await {
                tracing::warn!("closing a {} session from {from}: {e}", peer.whatami);
            }
        });
        let mut cx = std::task::Context::from_waker(futures::task::noop_waker_ref());
        if futures::FutureExt::poll_unpin(&mut close, &mut cx).is_pending() {
            self.tasks.spawn(close);
        }
        Err("not a client: closed".into())
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
pub async fn open(cfg: zenoh::Config) -> zenoh::Result<zenoh::Session> {
    use zenoh::internal::runtime::{DynamicRuntime, RuntimeBuilder};
    let mut runtime = RuntimeBuilder::new(cfg).build().await?;
    let dynamic = DynamicRuntime::from(runtime.clone());
    dynamic.new_handler(Arc::new(
        ClientsOnly::new(tokio::runtime::Handle::current()),
    ));
    let session = zenoh::session::init(dynamic).await?;
    runtime.start().await?;
    Ok(session)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_clients_are_admitted() {
        assert!(admitted(WhatAmI::Client));
        assert!(!admitted(WhatAmI::Router));
        assert!(!admitted(WhatAmI::Peer));
    }

    #[test]
    fn a_source_is_the_remote_host_without_its_port() {
        assert_eq!(host("tcp/10.0.0.5:41234"), "tcp/10.0.0.5");
        assert_eq!(host("quic/[::1]:7447"), "quic/[::1]");
        assert_eq!(host("an unknown address"), "an unknown address");
    }
}
