//! The independent OPC UA client of the gateway's tests and benchmark:
//! `tests/opcua_client.py` (Python asyncua) run against a launched cell's
//! `falc-opcua`, its JSON lines read back.

use super::{LaunchedCell, Proc};
use serde_json::Value;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

/// The Python interpreter that has asyncua (`.ci/run` installs it).
pub fn python() -> Command {
    let python = std::env::var("FALC_PYTHON").unwrap_or_else(|_| "python3".into());
    let ok = Command::new(&python)
        .args(["-c", "import asyncua"])
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        ok,
        "the OPC UA tests need Python with asyncua: pip install asyncua (.ci/run does), \
         or set FALC_PYTHON"
    );
    Command::new(python)
}

/// The client script doing `what` against the gateway of `cell` at `url`
/// (its users file and PKI directory in the cell's credentials), with
/// `extra` arguments (`watch`'s nodes).
pub fn client(cell: &LaunchedCell, what: &str, url: &str, extra: &[&str]) -> Proc {
    let credentials = cell.dir.path().join("credentials");
    client_of(
        what,
        url,
        &credentials,
        &cell.dir.path().join("opcua-client"),
        extra,
    )
}

/// The client script doing `what` against `url`, with the gateway's users
/// file and PKI directory under `credentials` and its own files in `work`.
pub fn client_of(what: &str, url: &str, credentials: &Path, work: &Path, extra: &[&str]) -> Proc {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/opcua_client.py");
    let mut cmd = python();
    cmd.arg(script)
        .arg(what)
        .arg(url)
        .arg(credentials)
        .arg(work)
        .args(extra);
    Proc::spawn_logged(&format!("opcua client {what}"), cmd)
}

/// The JSON line of step `step`.
pub fn step(p: &mut Proc, step: &str, within: Duration) -> Value {
    let line = p.expect_line(&format!("\"step\": \"{step}\""), within);
    serde_json::from_str(&line).unwrap_or_else(|e| panic!("{line}: {e}"))
}
