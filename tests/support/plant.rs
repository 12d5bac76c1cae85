//! A plant under test: a plant file with free ports, the factory router
//! and one router per cell (real `falc-router` processes), killed on drop;
//! on one network, or each cell on a network of its own
//! ([`TestPlant::start_in_namespaces`]).

use super::hosts::Hosts;
use super::{free_port, Proc};
use crate::support::wait::{holds, wait_until};
use falc_bus::{credentials, Bus, BusError, BusSettings};
use falc_model::ids::{CellId, StationName};
use falc_model::keys::KeySpace;
use falc_model::plant::Plant;
use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

/// A plant file: the operator and three console users (the OPC UA
/// gateway's too), then each cell of `cells` (its id and its workstations,
/// under its cell controller), the routers' endpoints left as `FACTORY`
/// and `ROUTER<n>`.
pub fn plant_text(cells: &[(&str, &[&str])]) -> String {
    let mut text = String::from(
        "plant = \"plant\"\nrouter = \"FACTORY\"\nlease_ms = 1000\n\
         [operator]\nname = \"operator\"\n\
         [[console]]\nname = \"console\"\nrole = \"operator\"\n\
         [[console]]\nname = \"observer\"\nrole = \"observer\"\n\
         [[console]]\nname = \"opcua\"\nrole = \"operator\"\n",
    );
    for (n, (cell, workstations)) in cells.iter().enumerate() {
        text.push_str(&format!(
            "[[cell]]\ncell = \"{cell}\"\nrouter = \"ROUTER{}\"\n\
             [[cell.station]]\nname = \"cell\"\nkind = \"cell\"\ncommander = \"operator\"\n",
            n + 1
        ));
        for ws in *workstations {
            text.push_str(&format!(
                "[[cell.station]]\nname = \"{ws}\"\nkind = \"{ws}\"\ncommander = \"cell\"\n"
            ));
        }
    }
    text
}

/// Two cells under one operator: `falc1` (cell, welding) and `falc2`
/// (cell, transport).
pub fn plant_of_demo_stations() -> String {
    plant_text(&[("falc1", &["welding"]), ("falc2", &["transport"])])
}

/// Two whole cells (cell, welding, transport each) under one operator.
pub fn whole_plant() -> String {
    plant_text(&[
        ("falc1", &["welding", "transport"]),
        ("falc2", &["welding", "transport"]),
    ])
}

/// `plant` with each router placeholder (`FACTORY`, `ROUTER<n>`) a free
/// localhost endpoint.
pub fn with_free_ports(plant: &str) -> String {
    let cells = plant.matches("router = \"ROUTER").count();
    let mut text = plant.to_string();
    for n in 1..=cells {
        text = text.replace(
            &format!("\"ROUTER{n}\""),
            &format!("\"tcp/127.0.0.1:{}\"", free_port()),
        );
    }
    text.replace("\"FACTORY\"", &format!("\"tcp/127.0.0.1:{}\"", free_port()))
}

pub struct TestPlant {
    pub dir: tempfile::TempDir,
    pub plant: Plant,
    pub path: PathBuf,
    /// The cell routers, then the factory router (dropped in that order).
    pub routers: Vec<Proc>,
    /// The namespaces when each cell is on its own network (removed last,
    /// after every process of the plant stopped).
    pub hosts: Option<Hosts>,
}

impl TestPlant {
    /// Writes [`plant_of_demo_stations`] with free ports and starts every
    /// router.
    pub fn start() -> TestPlant {
        Self::start_text(&plant_of_demo_stations())
    }

    /// A plant of `cells` whole cells (`falc1` …, each cell, welding and
    /// transport), its routers started.
    pub fn start_cells(cells: usize) -> TestPlant {
        let names: Vec<String> = (1..=cells).map(|i| format!("falc{i}")).collect();
        let whole: &[&str] = &["welding", "transport"];
        let layout: Vec<(&str, &[&str])> = names.iter().map(|n| (n.as_str(), whole)).collect();
        Self::start_text(&plant_text(&layout))
    }

    /// The plant file `plant` (from [`plant_text`]) with free ports, and
    /// every router started.
    pub fn start_text(plant: &str) -> TestPlant {
        Self::start_on(&with_free_ports(plant), None)
    }

    /// The plant file `plant` (from [`plant_text`]) with each cell on a
    /// network of its own: a namespace for the factory (its router, the
    /// operator, the consoles) holding a bridge, and one per cell (its
    /// router, its nodes and twins) joined to that bridge by a veth link
    /// ([`Hosts::create_named`]), every router started; or why the
    /// namespaces cannot be made (not root).
    pub fn start_in_namespaces(plant: &str) -> Result<TestPlant, String> {
        let cells = plant.matches("router = \"ROUTER").count();
        let mut names = vec!["factory".to_string()];
        names.extend((1..=cells).map(|n| format!("falc{n}")));
        let names: Vec<&str> = names.iter().map(String::as_str).collect();
        let hosts = Hosts::create_named(&names, "10.78.0")?;
        // Each cell's router on its own network's loopback; the factory
        // router on the bridge, where the cell routers reach it.
        let mut text = plant.replace(
            "\"FACTORY\"",
            &format!("\"tcp/{}:7440\"", hosts.address("factory")),
        );
        for n in 1..=cells {
            text = text.replace(&format!("\"ROUTER{n}\""), "\"tcp/127.0.0.1:7441\"");
        }
        Ok(Self::start_on(&text, Some(hosts)))
    }

    /// The plant file `plant` with free ports on the secure transport
    /// (every router on `quic/`), every router started.
    pub fn start_secure(plant: &str) -> TestPlant {
        Self::start_on(&with_free_ports(plant).replace("\"tcp/", "\"quic/"), None)
    }

    fn start_on(text: &str, hosts: Option<Hosts>) -> TestPlant {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("factory.toml");
        std::fs::write(&path, text).expect("write plant");
        let plant = Plant::parse(text, "test").expect("valid plant");
        let mut tp = TestPlant {
            dir,
            plant,
            path,
            routers: Vec::new(),
            hosts,
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
        let mut cmd = self.command(
            cell.map_or("factory", CellId::as_str),
            env!("CARGO_BIN_EXE_falc-router"),
        );
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

    /// `bin` to be run on the network of cell `host` (or `factory`), or
    /// here when the plant is on one network.
    pub fn command(&self, host: &str, bin: &str) -> Command {
        match &self.hosts {
            Some(h) => h.command(host, bin),
            None => Command::new(bin),
        }
    }

    pub fn credentials_dir(&self) -> PathBuf {
        self.dir.path().join("credentials")
    }

    pub fn cell_id(&self, cell: &str) -> CellId {
        CellId::new(cell).expect("valid cell id")
    }

    /// Starts a demo station `station` of cell `cell`.
    pub fn demo_station(&self, cell: &str, station: &str) -> Proc {
        self.demo_station_with(cell, station, &[])
    }

    /// The same with more arguments (`--job-ms N`).
    pub fn demo_station_with(&self, cell: &str, station: &str, args: &[&str]) -> Proc {
        self.node(cell, env!("CARGO_BIN_EXE_falc-demo-station"), station, args)
    }

    /// Bus settings of `user` with the credentials file `creds` (relative
    /// to the credentials directory) at the router `endpoint`, in the key
    /// space of `keys` (a cell's, or the plant's).
    pub fn settings(&self, user: &str, creds: &str, endpoint: &str, keys: &str) -> BusSettings {
        let path = self.credentials_dir().join(creds);
        let credentials = credentials::load(&path).expect("credentials written by the router");
        // On the secure transport the certificate beside the password.
        let tls = falc_bus::certificates::is_secure(endpoint)
            .then(|| falc_bus::certificates::TlsFiles::beside(&path));
        BusSettings {
            keys: KeySpace::new(CellId::new(keys).expect("valid id")),
            me: StationName::new(user).expect("valid user"),
            endpoint: endpoint.to_string(),
            lease: self.plant.lease(),
            credentials: Some(credentials),
            tls,
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

/// The real nodes of one cell of a plant and their twins.
pub struct CellNodes {
    pub rcm: Proc,
    pub plc: Proc,
    pub welding: Proc,
    pub transport: Proc,
    pub cell: Proc,
}

impl TestPlant {
    /// Node binary `bin` as `station` of cell `cell` (with `args`), ready.
    pub fn node(&self, cell: &str, bin: &str, station: &str, args: &[&str]) -> Proc {
        let mut cmd = self.command(cell, bin);
        cmd.args(["--station", station, "--cell", cell])
            .args(args)
            .arg("--topology")
            .arg(&self.path)
            .arg("--credentials-dir")
            .arg(self.credentials_dir());
        let mut p = Proc::spawn(&format!("{cell}/{station}"), cmd);
        p.expect_line("EVENT ready", Duration::from_secs(20));
        p
    }

    /// Cell `cell`'s twins (the robot at `rcm_scale`), workstations and
    /// cell controller.
    pub fn start_cell_nodes(&self, cell: &str, rcm_scale: &str) -> CellNodes {
        let twin = |bin: &str, args: &[&str], announces: &str| {
            let mut cmd = self.command(cell, bin);
            cmd.args(args);
            super::twin_from(cmd, bin, announces)
        };
        let (rcm, rcm_path) = twin(
            env!("CARGO_BIN_EXE_falc-rcm-sim"),
            &["--time-scale", rcm_scale],
            "serial port: ",
        );
        let (plc, plc_address) = twin(
            env!("CARGO_BIN_EXE_falc-plc-sim"),
            &["--listen", "127.0.0.1:0", "--time-scale", "20"],
            "listening on ",
        );
        let welding = self.node(
            cell,
            env!("CARGO_BIN_EXE_falc-welding"),
            "welding",
            &["--device", &rcm_path],
        );
        let mut transport = self.node(
            cell,
            env!("CARGO_BIN_EXE_falc-transport"),
            "transport",
            &["--plc", &plc_address],
        );
        transport.expect_line("EVENT plc-ready", Duration::from_secs(10));
        let node = self.node(cell, env!("CARGO_BIN_EXE_falc-cell"), "cell", &[]);
        CellNodes {
            rcm,
            plc,
            welding,
            transport,
            cell: node,
        }
    }

    /// Starts the plant's OPC UA gateway on a free port of 127.0.0.1
    /// and waits until it is ready: the process and its `--listen`.
    pub fn start_gateway(&self) -> (Proc, String) {
        let listen = format!("127.0.0.1:{}", free_port());
        let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_falc-opcua"));
        cmd.arg("--topology")
            .arg(&self.path)
            .arg("--credentials-dir")
            .arg(self.credentials_dir())
            .args(["--listen", &listen]);
        let mut gateway = Proc::spawn("opcua", cmd);
        gateway.expect_line("EVENT ready", Duration::from_secs(30));
        (gateway, listen)
    }

    /// The operator of the whole plant (recipes copied into the test's
    /// directory, the order list there); ready once every cell has its
    /// recipes.
    pub fn start_operator(&self) -> Proc {
        let mut p = self.spawn_operator();
        p.expect_line("EVENT ready", Duration::from_secs(30));
        for _ in self.plant.cells() {
            p.take_line("EVENT delivered recipe=PIPDROOG", Duration::from_secs(60));
        }
        p
    }

    /// The operator process, just spawned.
    pub fn spawn_operator(&self) -> Proc {
        let recipes = super::copy_recipes(self.dir.path());
        let mut cmd = self.command("factory", env!("CARGO_BIN_EXE_falc-operator"));
        cmd.arg("--recipes")
            .arg(&recipes)
            .arg("--db")
            .arg(self.dir.path().join("var/falc.db"))
            .arg("--topology")
            .arg(&self.path)
            .arg("--credentials-dir")
            .arg(self.credentials_dir());
        Proc::spawn("operator", cmd)
    }

    /// `falc ARGS` as console user `user` of the plant, for cell `cell`
    /// (None: the plant); exit code and output.
    pub fn falc_as(&self, user: &str, cell: Option<&str>, args: &[&str]) -> (i32, String) {
        let mut all = vec![
            "--topology".to_string(),
            self.path.display().to_string(),
            "--credentials-dir".into(),
            self.credentials_dir().display().to_string(),
            "--user".into(),
            user.into(),
        ];
        if let Some(c) = cell {
            all.extend(["--cell".to_string(), c.to_string()]);
        }
        super::run_falc_with(
            self.command("factory", env!("CARGO_BIN_EXE_falc")),
            &all,
            args,
        )
    }

    /// `falc ARGS` as `console`; must succeed; its output.
    pub fn falc(&self, cell: Option<&str>, args: &[&str]) -> String {
        let (code, text) = self.falc_as("console", cell, args);
        assert_eq!(code, 0, "falc {cell:?} {args:?}: {text}");
        text
    }

    /// What `falc --json ARGS` prints, as `T`.
    pub fn reply<T: serde::de::DeserializeOwned>(&self, cell: Option<&str>, args: &[&str]) -> T {
        let mut all = vec!["--json"];
        all.extend_from_slice(args);
        let text = self.falc(cell, &all);
        serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("{e}: {text}"))
    }

    /// The plant at a glance.
    pub fn status(&self) -> falc_model::api::PlantStatus {
        self.reply(None, &["status"])
    }

    /// Every order of the plant.
    pub fn orders(&self) -> Vec<falc_model::records::Order> {
        self.reply(None, &["order", "list"])
    }

    /// The journal holds one start of each of `orders`: none ran twice.
    pub fn assert_each_started_once(&self, orders: &[falc_model::records::Order]) {
        use falc_model::records::{Entry, EntryKind};
        let journal: Vec<Entry> = self.reply(None, &["journal"]);
        for o in orders {
            let starts = journal
                .iter()
                .filter(|e| {
                    e.kind == EntryKind::Order
                        && e.order == Some(o.id)
                        && e.text.contains("started")
                })
                .count();
            assert_eq!(starts, 1, "order {}: {journal:#?}", o.id);
        }
    }

    /// Answers every cell's question with `answer` until no order is
    /// queued or running, or `within` passed; the questions answered.
    pub fn work_list(&self, answer: &str, within: Duration) -> Vec<(String, String)> {
        use falc_model::records::OrderState;
        let mut asked = Vec::new();
        wait_until("the plant's list done", within, || {
            let status = self.status();
            for (cell, s) in &status.cells {
                if let Some(q) = &s.question {
                    let (code, _) =
                        self.falc_as("console", Some(cell.as_str()), &["answer", answer]);
                    if code == 0 {
                        asked.push((cell.to_string(), q.clone()));
                    }
                }
            }
            let busy = self
                .orders()
                .iter()
                .any(|o| matches!(o.state, OrderState::Queued | OrderState::Running));
            let running = status.cells.iter().any(|(_, s)| s.running.is_some());
            holds(!busy && !running, || status)
        });
        asked
    }
}

impl TestPlant {
    /// Answers every cell's question with `ja` until `nodes`' robot starts
    /// its program (its twin receives `G`): that cell's order is mid-weld.
    pub fn until_welding(&self, nodes: &mut CellNodes) {
        self.answer_until(Duration::from_secs(60), "the weld", || {
            nodes.rcm.wait_line("rx G", Duration::ZERO).is_some()
        });
    }

    /// Answers every cell's question with `ja` until `done` holds, or
    /// panics after `within` naming `what`.
    pub fn answer_until(&self, within: Duration, what: &str, mut done: impl FnMut() -> bool) {
        wait_until(what, within, || {
            if done() {
                return Ok(());
            }
            let status = self.status();
            for (cell, s) in &status.cells {
                if s.question.is_some() {
                    self.falc_as("console", Some(cell.as_str()), &["answer", "ja"]);
                }
            }
            Err(status)
        });
    }
}
