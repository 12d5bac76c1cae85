//! Generated zenoh configurations: every node is a client of the router with
//! scouting off and a short lease; the router listens, authenticates every
//! link against the usrpwd dictionary and enforces the generated ACL.
//! Nothing here is copied from a hand-written json5 file.
//!
//! With a `quic/…` endpoint every link is QUIC, whose TLS 1.3 handshake
//! authenticates both ends against the cell CA ([`super::certificates`]),
//! and nothing else is accepted. Handshakes at zenoh's level that do not
//! finish within [`HANDSHAKE_TIMEOUT`] are dropped, and up to
//! [`PENDING_HANDSHAKES`] may be in progress at once. zenoh's QUIC listener
//! itself accepts one QUIC handshake at a time and offers no time-out for
//! it, so strangers are kept off the router's port by its firewall
//! (`falc-router firewall`, docs/install.md).

use super::certificates::{TlsFiles, SECURE_PROTOCOL};
use super::credentials::Credentials;
use falc_model::ids::CellId;
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

/// How long the router waits for a link to finish its zenoh handshake
/// (the usrpwd login) before it drops it (zenoh's default: 10 s).
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

/// The link settings of the secure transport: the certificates, and QUIC
/// as the only protocol.
fn secure(v: &mut Value, tls: &TlsFiles, listen: bool) {
    v["transport"]["link"]["tls"] = tls_section(tls, listen);
    v["transport"]["link"]["protocols"] = json!([SECURE_PROTOCOL]);
}

fn build(value: Value) -> Result<zenoh::Config, ConfigError> {
    zenoh::Config::from_json5(&value.to_string()).map_err(|e| ConfigError(e.to_string()))
}

/// A node's configuration: client of `endpoint`, authenticated by `credentials`
/// (None only to show that an unauthenticated node is refused) and, on a
/// `quic/…` endpoint, by its certificate.
pub fn client(
    endpoint: &str,
    lease: Duration,
    credentials: Option<&Credentials>,
    tls: Option<&TlsFiles>,
    connect_timeout: Duration,
) -> Result<zenoh::Config, ConfigError> {
    let mut v = common("client", lease);
    if let Some(tls) = tls {
        secure(&mut v, tls, false);
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
/// dictionary file (and on `quic/…` the client certificates against the
/// cell CA), enforce `access_control` (see [`super::acl`]).
pub fn router(
    listen: &str,
    lease: Duration,
    dictionary: &Path,
    tls: Option<&TlsFiles>,
    access_control: Value,
    place: Place<'_>,
) -> Result<zenoh::Config, ConfigError> {
    let mut v = common("router", lease);
    if let Some(tls) = tls {
        secure(&mut v, tls, true);
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
    match place {
        Place::Cell => {}
        Place::Factory { plant } => v["id"] = json!(factory_router_id(plant)),
        Place::CellInPlant {
            uplink,
            credentials,
            uplink_tls,
        } => {
            // On the secure transport the link up shows the cell router's
            // own certificate (`router-<cell>`) to the factory router.
            if let Some(up) = uplink_tls {
                let link = &mut v["transport"]["link"]["tls"];
                link["connect_certificate"] = json!(up.cert.display().to_string());
                link["connect_private_key"] = json!(up.key.display().to_string());
            }
            v["connect"] = json!({
                "endpoints": [uplink],
                "exit_on_failure": false,
                // Tried again after 0.5 s, then doubling to at most 2 s.
                "retry": {
                    "period_init_ms": 500,
                    "period_max_ms": 2000,
                    "period_increase_factor": 2,
                },
            });
            v["transport"]["auth"]["usrpwd"]["user"] = json!(credentials.user);
            v["transport"]["auth"]["usrpwd"]["password"] = json!(credentials.password);
        }
    }
    build(v)
}

/// Where a router stands.
#[derive(Debug, Clone, Copy)]
pub enum Place<'a> {
    /// The router of a cell on its own (`launch/cell.toml`).
    Cell,
    /// The factory router of a plant (`launch/factory.toml`): its zenoh id
    /// is [`factory_router_id`], by which each cell router knows its link.
    Factory {
        /// The plant's name.
        plant: &'a CellId,
    },
    /// A cell router of a plant: it also connects to the factory router,
    /// logging in with its own credentials, and keeps trying while the
    /// link is cut.
    CellInPlant {
        /// The factory router's endpoint.
        uplink: &'a str,
        /// The cell router's user at the factory router.
        credentials: &'a Credentials,
        /// On the secure transport, the cell router's client certificate
        /// at the factory router (its CA the router's own).
        uplink_tls: Option<&'a TlsFiles>,
    },
}

/// The factory router's zenoh id, derived from the plant's name (FNV-1a):
/// each cell router's access control names its link up by it.
pub fn factory_router_id(plant: &CellId) -> String {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for b in format!("falc-factory-router/{plant}").bytes() {
        hash ^= u64::from(b);
        hash = hash.wrapping_mul(0x0100_0000_01b3);
    }
    // A leading non-zero digit: zenoh prints an id without leading zeros.
    format!("f{:015x}", hash >> 4)
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
            json!({ "enabled": true, "default_permission": "deny" }),
            Place::Cell,
        )
        .is_ok());
    }

    #[test]
    fn a_secure_router_takes_quic_links_only_with_mutual_tls() {
        let tls = TlsFiles::of(Path::new("/tmp/creds"), "router");
        let cfg = router(
            "quic/0.0.0.0:7447",
            Duration::from_secs(1),
            Path::new("/tmp/dict"),
            Some(&tls),
            json!({ "enabled": true, "default_permission": "deny" }),
            Place::Cell,
        )
        .expect("router config");
        let get = |key: &str| cfg.get_json(key).expect(key);
        assert_eq!(get("transport/link/protocols"), r#"["quic"]"#);
        assert_eq!(get("transport/link/tls/enable_mtls"), "true");
        assert!(get("transport/link/tls/listen_certificate").contains("router.crt"));
        assert_eq!(get("transport/unicast/accept_timeout"), "3000");
        let client = client(
            "quic/10.0.0.1:7447",
            Duration::from_secs(1),
            None,
            Some(&TlsFiles::of(Path::new("/tmp/creds"), "cell")),
            Duration::ZERO,
        )
        .expect("client config");
        assert_eq!(
            client
                .get_json("transport/link/protocols")
                .expect("protocols"),
            r#"["quic"]"#
        );
        assert!(client
            .get_json("transport/link/tls/connect_certificate")
            .expect("certificate")
            .contains("cell.crt"));
    }

    #[test]
    fn a_cell_router_in_a_plant_links_up_and_the_factory_router_has_its_known_id() {
        let plant = CellId::new("plant").expect("id");
        let id = factory_router_id(&plant);
        assert_eq!(id.len(), 16);
        assert!(id.starts_with('f'), "{id}");
        assert_ne!(id, factory_router_id(&CellId::new("plant2").expect("id")));
        let factory = router(
            "tcp/127.0.0.1:7440",
            Duration::from_secs(1),
            Path::new("/tmp/dict"),
            None,
            json!({ "enabled": true, "default_permission": "deny" }),
            Place::Factory { plant: &plant },
        )
        .expect("factory router config");
        assert_eq!(factory.get_json("id").expect("id"), format!("\"{id}\""));
        let up = Credentials {
            user: "router-falc1".into(),
            password: "p".into(),
        };
        let cell = router(
            "tcp/127.0.0.1:7441",
            Duration::from_secs(1),
            Path::new("/tmp/dict"),
            None,
            json!({ "enabled": true, "default_permission": "deny" }),
            Place::CellInPlant {
                uplink: "tcp/127.0.0.1:7440",
                credentials: &up,
                uplink_tls: None,
            },
        )
        .expect("cell router config");
        let get = |key: &str| cell.get_json(key).expect(key);
        assert_eq!(get("connect/endpoints"), r#"["tcp/127.0.0.1:7440"]"#);
        assert_eq!(get("connect/exit_on_failure"), "false");
        assert_eq!(get("transport/auth/usrpwd/user"), r#""router-falc1""#);
        assert!(get("transport/auth/usrpwd/dictionary_file").contains("/tmp/dict"));
        // On the secure transport: the cell's certificate for its
        // stations, the cell router's own for its link up, one CA.
        let dir = Path::new("/etc/falc/credentials");
        let listen = TlsFiles::of(&dir.join("falc1"), crate::certificates::ROUTER);
        let uplink = TlsFiles::of(dir, "router-falc1");
        let cell = router(
            "quic/10.0.1.1:7441",
            Duration::from_secs(1),
            Path::new("/tmp/dict"),
            Some(&listen),
            json!({ "enabled": true, "default_permission": "deny" }),
            Place::CellInPlant {
                uplink: "quic/10.0.0.1:7440",
                credentials: &up,
                uplink_tls: Some(&uplink),
            },
        )
        .expect("secure cell router config");
        let get = |key: &str| cell.get_json(key).expect(key);
        let tls = "transport/link/tls";
        assert!(get(&format!("{tls}/listen_certificate")).contains("falc1/router.crt"));
        assert!(get(&format!("{tls}/connect_certificate")).contains("credentials/router-falc1.crt"));
        assert!(get(&format!("{tls}/connect_private_key")).contains("credentials/router-falc1.key"));
        assert!(get(&format!("{tls}/root_ca_certificate")).contains("falc1/ca.crt"));
        assert_eq!(get("transport/link/protocols"), r#"["quic"]"#);
    }
}
