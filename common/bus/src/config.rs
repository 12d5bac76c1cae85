//! Generated zenoh configurations: every node is a client of the router with
//! scouting off and a short lease; the router listens, authenticates every
//! link against the usrpwd dictionary and enforces the generated ACL.
//! Nothing here is copied from a hand-written json5 file.

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

fn build(value: Value) -> Result<zenoh::Config, ConfigError> {
    zenoh::Config::from_json5(&value.to_string()).map_err(|e| ConfigError(e.to_string()))
}

/// A node's configuration: client of `endpoint`, authenticated by `credentials`
/// (None only to show that an unauthenticated node is refused).
pub fn client(
    endpoint: &str,
    lease: Duration,
    credentials: Option<&Credentials>,
    connect_timeout: Duration,
) -> Result<zenoh::Config, ConfigError> {
    let mut v = common("client", lease);
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
/// dictionary file, enforce `access_control` (see [`super::acl`]).
pub fn router(
    listen: &str,
    lease: Duration,
    dictionary: &Path,
    access_control: Value,
) -> Result<zenoh::Config, ConfigError> {
    let mut v = common("router", lease);
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
            Duration::ZERO,
        )
        .expect("client config");
        let text = format!("{cfg}");
        assert!(text.contains("\"client\""), "{text}");
        assert!(router(
            "tcp/127.0.0.1:7447",
            Duration::from_secs(1),
            Path::new("/tmp/dict"),
            json!({ "enabled": true, "default_permission": "deny" })
        )
        .is_ok());
    }
}
