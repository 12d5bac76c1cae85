//! Generated zenoh configurations: every node is a client of the router with
//! scouting off and a short lease; the router listens, authenticates every
//! link against the usrpwd dictionary and enforces the generated ACL.
//! Nothing here is copied from a hand-written json5 file.
//!
//! With a `tls/…` endpoint every link is TLS 1.3 with mutual authentication
//! against the cell CA ([`super::certificates`]), and nothing else is
//! accepted. The router is hardened against strangers holding connections
//! open: handshakes that do not finish within [`HANDSHAKE_TIMEOUT`] are
//! dropped, and up to [`PENDING_HANDSHAKES`] may be in progress at once, so
//! that hundreds of silent connections cannot keep a node out.

use super::certificates::TlsFiles;
use super::credentials::Credentials;
use serde_json::{json, Value};
use std::path::Path;
use std::time::Duration;

/// Why a zenoh configuration could not be built.
#[derive(Debug, thiserror::Error)]
#[error("zenoh configuration refused: {0}")]
pub struct ConfigError(String);

fn common(mode: &str, lease: Duration) -> Value {
    json!({
        "mode": mode,
        "scouting": {
            "multicast": { "enabled": false },
            "gossip": { "enabled": false },
        },
        "transport": {
            "link": { "tx": { "lease": lease.as_millis() as u64, "keep_alive": 4 } },
        },
    })
}

/// How long the router waits for a connection to finish its TLS and zenoh
/// handshakes before it drops it (zenoh's default: 10 s).
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(3);

/// How many connections may be in their zenoh handshake at once (zenoh's
/// default, 100, let 150 silent connections lock new logins out).
pub const PENDING_HANDSHAKES: usize = 4096;

fn tls_section(tls: &TlsFiles, listen: bool) -> Value {
    let (cert, key) = if listen {
        ("listen_certificate", "listen_private_key")
    } else {
        ("connect_certificate", "connect_private_key")
    };
    json!({
        "root_ca_certificate": tls.ca.display().to_string(),
        cert: tls.cert.display().to_string(),
        key: tls.key.display().to_string(),
        "enable_mtls": true,
        "verify_name_on_connect": true,
        // An expired certificate is refused at the next connection; a
        // link open when it expires stays (certificates run to 2045, and a
        // replaced one is withdrawn by its new password).
        "close_link_on_expiration": false,
    })
}

fn build(value: Value) -> Result<zenoh::Config, ConfigError> {
    zenoh::Config::from_json5(&value.to_string()).map_err(|e| ConfigError(e.to_string()))
}

/// A node's configuration: client of `endpoint`, authenticated by `credentials`
/// (None only to show that an unauthenticated node is refused) and, on a
/// `tls/…` endpoint, by its certificate.
pub fn client(
    endpoint: &str,
    lease: Duration,
    credentials: Option<&Credentials>,
    tls: Option<&TlsFiles>,
    connect_timeout: Duration,
) -> Result<zenoh::Config, ConfigError> {
    let mut v = common("client", lease);
    if let Some(tls) = tls {
        v["transport"]["link"]["tls"] = tls_section(tls, false);
        v["transport"]["link"]["protocols"] = json!(["tls"]);
    }
    v["connect"] = json!({
        "endpoints": [endpoint],
        "timeout_ms": connect_timeout.as_millis() as u64,
        "exit_on_failure": true,
    });
    if let Some(c) = credentials {
        v["transport"]["auth"] = json!({ "usrpwd": { "user": c.user, "password": c.password } });
    }
    build(v)
}

/// The router's configuration: listen on `listen`, authenticate against the
/// dictionary file (and on `tls/…` the client certificates against the
/// cell CA), enforce `access_control` (see [`super::acl`]).
pub fn router(
    listen: &str,
    lease: Duration,
    dictionary: &Path,
    tls: Option<&TlsFiles>,
    access_control: Value,
) -> Result<zenoh::Config, ConfigError> {
    let mut v = common("router", lease);
    let mut listen = listen.to_string();
    if let Some(tls) = tls {
        v["transport"]["link"]["tls"] = tls_section(tls, true);
        v["transport"]["link"]["protocols"] = json!(["tls"]);
        // An endpoint may carry its own configuration (`#a=1;b=2`); the
        // time-out is added to it unless it sets one.
        if !listen.contains("tls_handshake_timeout_ms") {
            let sep = if listen.contains('#') { ';' } else { '#' };
            listen = format!(
                "{listen}{sep}tls_handshake_timeout_ms={}",
                HANDSHAKE_TIMEOUT.as_millis()
            );
        }
    }
    v["transport"]["unicast"] = json!({
        "accept_timeout": HANDSHAKE_TIMEOUT.as_millis() as u64,
        "accept_pending": PENDING_HANDSHAKES,
    });
    // Clients only: a peer-mode node is refused when its transport opens
    // (it falls outside the one south region, which admits clients).
    v["gateway"] = json!({ "south": [ { "filters": [ { "modes": ["client"] } ] } ] });
    v["listen"] = json!({ "endpoints": [listen] });
    v["connect"] = json!({ "endpoints": [] });
    v["transport"]["auth"] = json!({
        "usrpwd": { "dictionary_file": dictionary.display().to_string() }
    });
    v["access_control"] = access_control;
    build(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn configs_are_accepted_by_zenoh() {
        let c = Credentials {
            user: "cell".into(),
            password: "p".into(),
        };
        let cfg = client(
            "tcp/127.0.0.1:7447",
            Duration::from_secs(1),
            Some(&c),
            None,
            Duration::ZERO,
        )
        .expect("client config");
        let text = format!("{cfg}");
        assert!(text.contains("\"client\""), "{text}");
        assert!(router(
            "tcp/127.0.0.1:7447",
            Duration::from_secs(1),
            Path::new("/tmp/dict"),
            None,
            json!({ "enabled": true, "default_permission": "deny" })
        )
        .is_ok());
    }

    #[test]
    fn a_tls_listen_endpoint_gets_the_handshake_time_out_unless_it_sets_one() {
        let tls = TlsFiles::of(Path::new("/tmp/creds"), "router");
        let listen = |endpoint: &str| {
            let cfg = router(
                endpoint,
                Duration::from_secs(1),
                Path::new("/tmp/dict"),
                Some(&tls),
                json!({ "enabled": true, "default_permission": "deny" }),
            )
            .expect("router config");
            cfg.get_json("listen/endpoints").expect("endpoints")
        };
        assert!(
            listen("tls/0.0.0.0:7447").contains("tls/0.0.0.0:7447#tls_handshake_timeout_ms=3000"),
            "{}",
            listen("tls/0.0.0.0:7447")
        );
        let own = listen("tls/0.0.0.0:7447#iface=eth0");
        assert!(
            own.contains("iface=eth0;tls_handshake_timeout_ms=3000"),
            "{own}"
        );
        let set = listen("tls/0.0.0.0:7447#tls_handshake_timeout_ms=500");
        assert!(
            set.contains("tls_handshake_timeout_ms=500") && !set.contains("3000"),
            "{set}"
        );
    }
}
