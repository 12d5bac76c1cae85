//! Strangers at the router's port, for the flood tests and benchmarks:
//! QUIC handshakes begun and left silent ([`silent_handshakes`]), QUIC
//! handshakes that fail by the hundred ([`failing_handshakes`]), and TCP
//! connections that say nothing, opened again as the router drops them
//! ([`silent_tcp_connections`]). None holds any of the cell's credentials. Each runs on the calling thread's network
//! namespace (see `hosts::Hosts::on`), against an address the test made.

use quinn::rustls;
use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Every ALPN zenoh's QUIC link offers, so that a stranger's hello is one
/// the router goes on with.
const ZENOH_ALPN: [&[u8]; 5] = [b"zenoh-ms-mr", b"zenoh-ms", b"zenoh-mr", b"zenoh", b"hq-29"];

/// A TLS client configuration that trusts a CA of its own making only:
/// the router's certificate fails it, so every handshake fails.
fn stranger_tls() -> rustls::ClientConfig {
    let key = rcgen::KeyPair::generate().expect("key");
    let mut params = rcgen::CertificateParams::new(Vec::<String>::new()).expect("params");
    params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
    let ca = params.self_signed(&key).expect("stranger CA");
    let mut roots = rustls::RootCertStore::empty();
    roots.add(ca.der().clone()).expect("root");
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let mut tls = rustls::ClientConfig::builder_with_provider(provider)
        .with_protocol_versions(&[&rustls::version::TLS13])
        .expect("TLS 1.3")
        .with_root_certificates(roots)
        .with_no_client_auth();
    tls.alpn_protocols = ZENOH_ALPN.iter().map(|a| a.to_vec()).collect();
    tls
}

fn client_config() -> quinn::ClientConfig {
    let quic = quinn::crypto::rustls::QuicClientConfig::try_from(stranger_tls()).expect("QUIC TLS");
    quinn::ClientConfig::new(Arc::new(quic))
}

/// Any port on any address of the family of `router`.
fn any_port(router: SocketAddr) -> SocketAddr {
    let any: std::net::IpAddr = if router.is_ipv4() {
        std::net::Ipv4Addr::UNSPECIFIED.into()
    } else {
        std::net::Ipv6Addr::UNSPECIFIED.into()
    };
    SocketAddr::new(any, 0)
}

/// `count` strangers, each from a UDP socket of its own, send the first
/// flight of a QUIC handshake (the Initial with a valid hello) to `router`
/// and never answer. The sockets are returned to be held as long as the
/// handshakes should stay open.
pub fn silent_handshakes(router: SocketAddr, count: usize) -> Vec<UdpSocket> {
    let bind = any_port(router);
    (0..count)
        .map(|_| {
            let mut endpoint = quinn_proto::Endpoint::new(
                Arc::new(quinn_proto::EndpointConfig::default()),
                None,
                false,
                None,
            );
            let now = Instant::now();
            let (_, mut conn) = endpoint
                .connect(now, client_config(), router, "falc-router")
                .expect("a QUIC hello");
            let socket = UdpSocket::bind(bind).expect("udp socket");
            let mut buf = Vec::new();
            while let Some(t) = conn.poll_transmit(now, 1, &mut buf) {
                // A firewall may drop it; the stranger does not care.
                let _ = socket.send_to(&buf[..t.size], t.destination);
                buf.clear();
            }
            socket
        })
        .collect()
}

/// What [`failing_handshakes`] did.
#[derive(Debug, Clone, Copy, Default)]
pub struct Failed {
    /// Handshakes begun.
    pub begun: u64,
    /// Handshakes the router answered (and the stranger then failed).
    pub answered: u64,
}

/// Strangers begin `per_second` QUIC handshakes a second for `lasting`,
/// each failing (the router's certificate is not one they trust), each
/// given up after 2 s if unanswered. Runs on a runtime of its own.
pub fn failing_handshakes(router: SocketAddr, per_second: u32, lasting: Duration) -> Failed {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async move {
        let bind = any_port(router);
        let mut tasks = tokio::task::JoinSet::new();
        let mut tick = tokio::time::interval(Duration::from_secs(1) / per_second.max(1));
        let end = tokio::time::Instant::now() + lasting;
        let mut failed = Failed::default();
        while tokio::time::Instant::now() < end {
            tick.tick().await;
            // A socket of its own each, as strangers from many ports.
            let Ok(mut endpoint) = quinn::Endpoint::client(bind) else {
                continue;
            };
            endpoint.set_default_client_config(client_config());
            failed.begun += 1;
            tasks.spawn(async move {
                let Ok(connecting) = endpoint.connect(router, "falc-router") else {
                    return false;
                };
                let answered = matches!(
                    tokio::time::timeout(Duration::from_secs(2), connecting).await,
                    Ok(Err(_))
                );
                endpoint.close(0u32.into(), b"");
                answered
            });
            while let Some(done) = tasks.try_join_next() {
                failed.answered += u64::from(matches!(done, Ok(true)));
            }
        }
        while let Some(done) = tasks.join_next().await {
            failed.answered += u64::from(matches!(done, Ok(true)));
        }
        failed
    })
}

/// Holds `count` silent TCP connections open at `router` until `until`:
/// each one the router drops (its login limit) is opened again at once,
/// the strangers looking twice a second. Returns how many were opened.
/// Raises this process's open-file limit to its hard limit first.
pub fn silent_tcp_connections(router: SocketAddr, count: usize, until: Instant) -> u64 {
    raise_open_files();
    let mut held: Vec<std::net::TcpStream> = Vec::new();
    let mut opened = 0u64;
    while Instant::now() < until {
        // Keep those still open; open new ones up to `count`.
        held.retain(|c| {
            let mut b = [0u8; 1];
            let _ = c.set_nonblocking(true);
            match c.peek(&mut b) {
                // Closed by the router.
                Ok(0) => false,
                Ok(_) => true,
                // Open and silent.
                Err(e) => e.kind() == std::io::ErrorKind::WouldBlock,
            }
        });
        while held.len() < count {
            match std::net::TcpStream::connect(router) {
                Ok(c) => {
                    held.push(c);
                    opened += 1;
                }
                Err(_) => break,
            }
        }
        // A pace: the strangers look at their connections twice a second.
        std::thread::sleep(Duration::from_millis(500));
    }
    opened
}

/// Raises this process's open-file limit to the hard limit (a thousand
/// connections held).
fn raise_open_files() {
    use nix::sys::resource::{getrlimit, setrlimit, Resource};
    if let Ok((soft, hard)) = getrlimit(Resource::RLIMIT_NOFILE) {
        if soft < hard {
            let _ = setrlimit(Resource::RLIMIT_NOFILE, hard, hard);
        }
    }
}
