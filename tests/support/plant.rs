//! A plant under test: a plant file with free ports, the factory router
//! and one router per cell (real `falc-router` processes), killed on drop.

use super::{free_port, Proc};
use falc_bus::{credentials, Bus, BusError, BusSettings};
use falc_model::ids::{CellId, StationName};
use falc_model::keys::KeySpace;
use falc_model::plant::Plant;
use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

/// Two cells under one operator: `falc1` (cell, welding) and `falc2`
/// (cell, transport); `FACTORY`, `ROUTER1`, `ROUTER2` are replaced by
/// endpoints.
pub const PLANT: &str = r#"
plant = "plant"
router = "FACTORY"
lease_ms = 1000
[operator]
name = "operator"
[[console]]
name = "console"
role = "operator"
[[console]]
name = "observer"
role = "observer"
[[cell]]
cell = "falc1"
router = "ROUTER1"
[[cell.station]]
name = "cell"
kind = "cell"
commander = "operator"
[[cell.station]]
name = "welding"
kind = "welding"
commander = "cell"
[[cell]]
cell = "falc2"
router = "ROUTER2"
[[cell.station]]
name = "cell"
kind = "cell"
commander = "operator"
[[cell.station]]
name = "transport"
kind = "transport"
commander = "cell"
"#;

pub struct TestPlant {
    pub dir: tempfile::TempDir,
    pub plant: Plant,
    pub path: PathBuf,
    /// The cell routers, then the factory router (dropped in that order).
    pub routers: Vec<Proc>,
}

impl TestPlant {
    /// Writes [`PLANT`] with free ports and starts every router.
    pub fn start() -> TestPlant {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut text = PLANT.to_string();
        for name in ["FACTORY", "ROUTER1", "ROUTER2"] {
            text = text.replace(name, &format!("tcp/127.0.0.1:{}", free_port()));
        }
        let path = dir.path().join("factory.toml");
        std::fs::write(&path, &text).expect("write plant");
        let plant = Plant::parse(&text, "test").expect("valid plant");
        let mut tp = TestPlant {
            dir,
            plant,
            path,
            routers: Vec::new(),
        };
        let factory = tp.router(None);
        let cells: Vec<CellId> = tp.plant.cells().iter().map(|c| c.id().clone()).collect();
        for id in cells {
            let r = tp.router(Some(&id));
            tp.routers.push(r);
        }
        tp.routers.push(factory);
        tp
    }

    /// Starts the factory router (None) or a cell's, and waits until it
    /// is ready.
    pub fn router(&self, cell: Option<&CellId>) -> Proc {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_falc-router"));
        cmd.arg("--plant")
            .arg(&self.path)
            .arg("--credentials-dir")
            .arg(self.credentials_dir())
            .arg("run");
        if let Some(id) = cell {
            cmd.arg("--cell").arg(id.as_str());
        }
        let name = cell.map_or("factory-router".to_string(), |c| format!("router-{c}"));
        let mut p = Proc::spawn_logged(&name, cmd);
        p.expect_line("falc-router ready", Duration::from_secs(20));
        p
    }

    pub fn credentials_dir(&self) -> PathBuf {
        self.dir.path().join("credentials")
    }

    pub fn cell_id(&self, cell: &str) -> CellId {
        CellId::new(cell).expect("valid cell id")
    }

    /// Starts a demo station `station` of cell `cell`.
    pub fn demo_station(&self, cell: &str, station: &str) -> Proc {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_falc-demo-station"));
        cmd.args(["--station", station, "--cell", cell])
            .arg("--topology")
            .arg(&self.path)
            .arg("--credentials-dir")
            .arg(self.credentials_dir());
        let mut p = Proc::spawn(&format!("{cell}/{station}"), cmd);
        p.expect_line("EVENT ready", Duration::from_secs(20));
        p
    }

    /// Bus settings of `user` with the credentials file `creds` (relative
    /// to the credentials directory) at the router `endpoint`, in the key
    /// space of `keys` (a cell's, or the plant's).
    pub fn settings(&self, user: &str, creds: &str, endpoint: &str, keys: &str) -> BusSettings {
        let credentials = credentials::load(&self.credentials_dir().join(creds))
            .expect("credentials written by the router");
        BusSettings {
            keys: KeySpace::new(CellId::new(keys).expect("valid id")),
            me: StationName::new(user).expect("valid user"),
            endpoint: endpoint.to_string(),
            lease: self.plant.lease(),
            credentials: Some(credentials),
            tls: None,
            connect_timeout: Duration::ZERO,
        }
    }

    /// The operator's session at the factory router, in cell `cell`'s keys.
    pub async fn operator_in(&self, cell: &str) -> Bus {
        Bus::open(self.settings("operator", "operator.toml", self.plant.router(), cell))
            .await
            .expect("the operator logs in at the factory router")
    }

    /// Station `station` of cell `cell` at router `endpoint` (its own
    /// cell's router, or any other), in key space `keys`.
    pub async fn station_at(
        &self,
        cell: &str,
        station: &str,
        endpoint: &str,
        keys: &str,
    ) -> Result<Bus, BusError> {
        Bus::open(self.settings(station, &format!("{cell}/{station}.toml"), endpoint, keys)).await
    }

    /// Cell `cell`'s router endpoint.
    pub fn cell_router(&self, cell: &str) -> String {
        self.plant
            .cell(&self.cell_id(cell))
            .expect("cell")
            .topology()
            .router()
            .to_string()
    }
}
