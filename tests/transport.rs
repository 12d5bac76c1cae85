//! The transport workstation end to end: a real router, `falc-plc-sim` on
//! Modbus TCP (a free port), `falc-transport`, and this test process as its
//! commander (the cell): it downloads transport recipes as domains, starts
//! them, and reads the job events; the twin's `show` tells where the
//! carriers went.

use crate::support::wait::{holds, wait_until_async};
use crate::support::{twin, Commander, Proc, TestCell};
use falc_model::ids::ObjectName;
use falc_model::mms::pdu::{JobEvent, Request, Response};
use falc_model::mms::program::PiState;
use std::time::Duration;

const SCALE: &str = "20";
const RUN: Duration = Duration::from_secs(30);

struct Rig {
    cell: TestCell,
    plc: Proc,
    address: String,
    transport: Proc,
    commander: Commander,
}

fn plc_sim(extra: &[&str]) -> (Proc, String) {
    let mut args = vec!["--listen", "127.0.0.1:0", "--time-scale", SCALE];
    args.extend(extra);
    twin(env!("CARGO_BIN_EXE_falc-plc-sim"), &args, "listening on ")
}

fn transport(cell: &TestCell, address: &str, extra: &[&str]) -> Proc {
    let mut args = vec!["--plc", address];
    args.extend(extra);
    cell.start_node(env!("CARGO_BIN_EXE_falc-transport"), "transport", &args)
}

async fn rig_with(plc_args: &[&str], node_args: &[&str]) -> Rig {
    let cell = TestCell::start();
    let (plc, address) = plc_sim(plc_args);
    let transport = transport(&cell, &address, node_args);
    let commander = Commander::associate(&cell, "transport").await;
    Rig {
        cell,
        plc,
        address,
        transport,
        commander,
    }
}

async fn rig() -> Rig {
    let mut r = rig_with(&[], &[]).await;
    r.transport
        .expect_line("EVENT plc-ready", Duration::from_secs(10));
    r.transport.forget("EVENT plc-ready");
    r
}

fn shipped(name: &str) -> String {
    std::fs::read_to_string(format!(
        "{}/recipes/transport/{name}.rcp",
        env!("CARGO_MANIFEST_DIR")
    ))
    .expect("shipped recipe")
}

impl Rig {
    /// The carriers as the twin shows them now.
    fn carriers(&mut self) -> String {
        self.plc.control("show");
        self.plc.take_line("carriers: ", Duration::from_secs(5))
    }

    /// Waits until the twin shows `want` (a line still running may take a
    /// carrier on after a recipe ended).
    async fn carriers_become(&mut self, want: &str) {
        let want = format!("carriers: {want}");
        wait_until_async(&want, Duration::from_secs(10), || {
            let now = self.carriers();
            let want = &want;
            async move { holds(&now == want, || now.clone()) }
        })
        .await;
    }

    /// After a fault cleared: the node says the PLC is ready again, and
    /// STORE runs to done from the start layout.
    async fn recovers(&mut self) {
        self.transport
            .expect_line("EVENT plc-ready", Duration::from_secs(5));
        self.transport.forget("EVENT plc-ready");
        self.layout_for("W2 W2", "store").await;
        assert_eq!(self.run("store").await, JobEvent::Done);
        assert_eq!(self.carriers(), "carriers: 1@W3 2@W2");
    }

    /// Waits until the node's published status shows the equipment in
    /// named state `want`; returns it.
    async fn equipment_state_becomes(&mut self, want: &str) -> String {
        self.status_becomes(want, |s| s.equipment_state.as_deref() == Some(want))
            .await;
        want.to_string()
    }

    /// Waits until the node publishes a status that `holds` (`what`, for
    /// the failure).
    async fn status_becomes(
        &mut self,
        what: &str,
        holds: impl Fn(&falc_model::mms::vmd::VmdStatus) -> bool,
    ) {
        let within = Duration::from_secs(10);
        let end = tokio::time::Instant::now() + within;
        let mut seen = false;
        loop {
            match self.commander.status_after(end, seen).await {
                Some(s) if holds(&s) => return,
                Some(_) => seen = true,
                None => panic!(
                    "the status did not show {what} within {within:?}: {:?}",
                    self.commander.last_status
                ),
            }
        }
    }

    /// Sets the twin's carriers (`layout …`) for recipe `name`, and waits
    /// until the node's status shows its #PRE holds: the node evaluates
    /// a precondition on a reading at most one busy poll old, and one
    /// taken just before a layout set within that poll would miss it
    /// (as an operator checks `falc status` before `start`).
    async fn layout_for(&mut self, spots: &str, name: &str) {
        self.plc.control(&format!("layout {spots}"));
        let recipe = name.to_uppercase();
        self.status_becomes(&format!("{recipe}'s #PRE true"), |s| {
            !s.unmet.keys().any(|k| k.as_str() == recipe)
        })
        .await;
    }

    async fn run(&mut self, name: &str) -> JobEvent {
        self.commander.start(name).await;
        self.commander.job(RUN).await
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_five_shipped_recipes_do_what_their_names_say() {
    let mut rig = rig().await;
    for name in [
        "store",
        "move_to_man",
        "unstore",
        "unload",
        "unload_and_load",
    ] {
        rig.commander.load(name, &shipped(name)).await;
    }
    assert_eq!(rig.carriers(), "carriers: 1@W2 2@W2", "the thesis' start");
    // dikdroog's order: store one carrier, bring the other to the robot,
    // take the stored one back, unload the welded one.
    assert_eq!(rig.run("store").await, JobEvent::Done);
    assert_eq!(rig.carriers(), "carriers: 1@W3 2@W2");
    assert_eq!(rig.run("move_to_man").await, JobEvent::Done);
    assert_eq!(rig.carriers(), "carriers: 1@W3 2@S3");
    assert_eq!(rig.run("unstore").await, JobEvent::Done);
    assert_eq!(rig.carriers(), "carriers: 1@W2 2@S3");
    assert_eq!(rig.run("unload").await, JobEvent::Done);
    assert_eq!(
        rig.carriers(),
        "carriers: 1@W2 2@W2",
        "both back at the start"
    );
    // Unload and load: the welded carrier leaves the table, the stored one
    // takes its place.
    rig.layout_for("S3 W3", "unload_and_load").await;
    assert_eq!(rig.run("unload_and_load").await, JobEvent::Done);
    rig.carriers_become("1@W2 2@S3").await;
    // The buttons the recipes pressed: each one released again, but
    // station 3's (it holds the carrier on the table).
    for line in ["K", "E", "L", "D", "F", "H"] {
        rig.plc
            .expect_line(&format!("coil button line {line} 0"), RUN);
    }
}

/// MOVE_TO_MAN with 2 s limits: a jammed carrier runs them out.
const MOVE_SHORT: &str = "#MOVE_SHORT
-1 | activate e        | | | 2
-2 | waitplace 5 1 2   | | klaar | 3
-2 | waitplace 5 1 2   | | tijdlimiet | 7
-3 | reset e           | | | 4
-4 | activate 3        | | | 5
-5 | waitstation 3 1 2 | | klaar | 0
-5 | waitstation 3 1 2 | | tijdlimiet | 6
-6 | reset 3           | alarm | | 0
-7 | reset e           | alarm | | 0
";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_jammed_carrier_runs_out_the_limit_takes_the_failure_path_and_recovers() {
    let mut rig = rig().await;
    rig.commander.load("move_short", MOVE_SHORT).await;
    rig.plc.control("jam E");
    rig.commander.start("move_short").await;
    let text = rig.commander.alarm(RUN).await;
    assert!(
        text.contains("alarm in state 7"),
        "the failure path: {text}"
    );
    assert!(
        text.contains("place 5 still empty, line E still running: carrier jammed on line E"),
        "{text}"
    );
    // State 7 released line E's button.
    rig.plc
        .expect_line("coil button line E 0", Duration::from_secs(5));
    rig.plc.control("unjam E");
    rig.carriers_become("1@W5 2@W2").await;
    rig.plc.control("layout W2 W2");
    assert_eq!(rig.run("move_short").await, JobEvent::Done);
    assert_eq!(rig.carriers(), "carriers: 1@S3 2@W2");
}

const STORE_SHORT: &str = "#STORE_SHORT
-1 | activate k       | | | 2
-2 | waitplace 3 1 2  | | klaar | 3
-2 | waitplace 3 1 2  | | tijdlimiet | 4
-3 | reset k          | | | 0
-4 | reset k          | alarm | | 0
";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stuck_sensor_is_named_in_the_alarm() {
    let mut rig = rig().await;
    rig.commander.load("store_short", STORE_SHORT).await;
    rig.plc.control("stuck 3 0");
    rig.commander.start("store_short").await;
    let text = rig.commander.alarm(RUN).await;
    assert!(
        text.contains("place 3 still empty though line K stopped: sensor of place 3 faulty"),
        "{text}"
    );
    rig.plc.control("unstuck 3");
    rig.plc.control("layout W2 W2");
    assert_eq!(rig.run("store_short").await, JobEvent::Done);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn emergency_stop_ends_in_alarm_refuses_starts_and_recovers() {
    let mut rig = rig().await;
    rig.commander.load("store", &shipped("store")).await;
    rig.commander.start("store").await;
    rig.plc
        .expect_line("carrier 1 leaves W2 on line K", Duration::from_secs(5));
    rig.plc.control("estop");
    let text = rig.commander.alarm(Duration::from_secs(5)).await;
    assert_eq!(
        text,
        format!("emergency stop on the conveyor PLC at {}", rig.address)
    );
    let refused = rig.commander.try_start("store").await;
    assert!(
        matches!(&refused, Err(e) if e.to_string().contains("emergency stop on the conveyor PLC")),
        "{refused:?}"
    );
    rig.plc.control("estop-clear");
    rig.recovers().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plc_offline_ends_in_alarm_and_the_node_reconnects() {
    let mut rig = rig().await;
    rig.commander.load("store", &shipped("store")).await;
    rig.commander.start("store").await;
    rig.plc
        .expect_line("carrier 1 leaves W2 on line K", Duration::from_secs(5));
    rig.plc.control("offline");
    let text = rig.commander.alarm(Duration::from_secs(5)).await;
    assert!(
        text.contains(&format!("the conveyor PLC at {}", rig.address)),
        "{text}"
    );
    // While it is away, a start is refused, naming the PLC.
    let no_connection = format!("no connection with the conveyor PLC at {}", rig.address);
    rig.commander
        .report(&no_connection, Duration::from_secs(5))
        .await;
    let refused = rig.commander.try_start("store").await;
    assert!(
        matches!(&refused, Err(e) if e.to_string().contains(&no_connection)),
        "{refused:?}"
    );
    rig.plc.control("online");
    rig.recovers().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_plc_that_stops_answering_times_out_into_an_alarm() {
    let mut rig = rig_with(&[], &["--modbus-timeout-ms", "200"]).await;
    rig.transport
        .expect_line("EVENT plc-ready", Duration::from_secs(10));
    rig.transport.forget("EVENT plc-ready");
    rig.commander.load("store", &shipped("store")).await;
    rig.commander.start("store").await;
    rig.plc.control("mute");
    let text = rig.commander.alarm(Duration::from_secs(5)).await;
    // Whichever request met the mute first: the next poll, or (on a
    // loaded machine) the write of STORE's `activate k` still in flight.
    let who = format!("the conveyor PLC at {} did not answer the ", rig.address);
    assert!(
        text.contains(&who)
            && text.contains(" within 200ms")
            && (text.contains("read of discrete inputs 0..20")
                || text.contains("write of button line K := 1")),
        "{text}"
    );
    rig.plc.control("unmute");
    rig.recovers().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_map_sits_at_configurable_bases_and_a_wrong_one_is_a_clear_alarm() {
    // The PLC has the map at coils 100.., inputs 200..; a node that looks
    // at 0.. gets Modbus exceptions, named in its alarm.
    let bases = ["--coil-base", "100", "--input-base", "200"];
    let mut rig = rig_with(&bases, &[]).await;
    rig.commander.load("store", &shipped("store")).await;
    // The fault is reported once, when it begins (maybe before this
    // commander subscribed): read it from the node's own event line; a
    // start meanwhile is refused with the same cause.
    let line = rig
        .transport
        .expect_line("EVENT report severity=Alarm", Duration::from_secs(10));
    let prefix = format!("the conveyor PLC at {} answered the ", rig.address);
    let exception = "with Modbus exception Illegal data address";
    assert!(
        line.contains(&prefix)
            && line.ends_with(exception)
            && (line.contains("read of discrete inputs 0..20")
                || line.contains("write of all coils 0..14")),
        "{line}"
    );
    let refused = rig.commander.try_start("store").await;
    assert!(
        matches!(&refused, Err(e) if e.to_string().contains(exception)),
        "{refused:?}"
    );
    rig.transport.kill();
    drop(rig.commander);
    let mut right = transport(&rig.cell, &rig.address, &bases);
    right.expect_line("EVENT plc-ready", Duration::from_secs(10));
    let mut commander = Commander::associate(&rig.cell, "transport").await;
    commander.load("store", &shipped("store")).await;
    commander.start("store").await;
    assert_eq!(commander.job(RUN).await, JobEvent::Done);
    rig.plc
        .expect_line("coil button line K 1", Duration::from_secs(5));
}

/// A plain Modbus TCP server with the map's coils and inputs and no
/// conveyor at all: the test plays the PLC by setting inputs itself.
mod plain_plc {
    use falc_equipment::Equipment;
    use std::future::Future;
    use std::pin::Pin;
    use std::sync::{Arc, Mutex};
    use tokio_modbus::server::tcp::{accept_tcp_connection, Server};
    use tokio_modbus::{ExceptionCode, Request, Response, SlaveRequest};

    /// The coils and inputs of the 1992 conveyor's equipment file, by
    /// address.
    pub struct Image {
        pub coils: Vec<bool>,
        pub inputs: Vec<bool>,
    }

    impl Default for Image {
        fn default() -> Self {
            let e = Equipment::conveyor_1992();
            Self {
                coils: vec![false; usize::from(e.coil_span().1)],
                inputs: vec![false; usize::from(e.input_span().1)],
            }
        }
    }

    #[derive(Clone)]
    struct Service(Arc<Mutex<Image>>);

    fn range(addr: u16, n: usize, size: usize) -> Result<std::ops::Range<usize>, ExceptionCode> {
        let (a, end) = (usize::from(addr), usize::from(addr) + n);
        if n == 0 || end > size {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        Ok(a..end)
    }

    impl tokio_modbus::server::Service for Service {
        type Request = SlaveRequest<'static>;
        type Response = Response;
        type Exception = ExceptionCode;
        type Future = Pin<Box<dyn Future<Output = Result<Response, ExceptionCode>> + Send>>;

        fn call(&self, req: Self::Request) -> Self::Future {
            let mut img = self.0.lock().expect("image");
            let r = match req.request {
                Request::ReadDiscreteInputs(a, n) => range(a, n.into(), img.inputs.len())
                    .map(|r| Response::ReadDiscreteInputs(img.inputs[r].to_vec())),
                Request::WriteSingleCoil(a, v) => range(a, 1, img.coils.len()).map(|r| {
                    img.coils[r.start] = v;
                    Response::WriteSingleCoil(a, v)
                }),
                Request::WriteMultipleCoils(a, vs) => {
                    range(a, vs.len(), img.coils.len()).map(|r| {
                        img.coils[r].copy_from_slice(&vs);
                        Response::WriteMultipleCoils(a, vs.len() as u16)
                    })
                }
                _ => Err(ExceptionCode::IllegalFunction),
            };
            Box::pin(std::future::ready(r))
        }
    }

    /// Serves `image` on a free port until the test ends; its address.
    pub async fn serve(image: Arc<Mutex<Image>>) -> String {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
            .await
            .expect("bind");
        let addr = listener.local_addr().expect("address");
        tokio::spawn(async move {
            let service = Service(image);
            let on_connected = |stream, peer| {
                let s = service.clone();
                async move { accept_tcp_connection(stream, peer, move |_| Ok(Some(s.clone()))) }
            };
            let _ = Server::new(listener).serve(&on_connected, |_| {}).await;
        });
        addr.to_string()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_node_needs_nothing_but_the_documented_map() {
    use falc_equipment::Equipment;
    use falc_plc::map::{Coil, Input};
    use falc_recipe::check::{Button, Signal};
    use std::sync::{Arc, Mutex};
    let image = Arc::new(Mutex::new(plain_plc::Image::default()));
    let e = Equipment::conveyor_1992();
    let offset = |i: Input| {
        let spec = e.inputs().iter().find(|s| s.input == i);
        usize::from(spec.expect("in the equipment file").address)
    };
    let coil = |c: Coil| usize::from(e.coil(c).expect("in the equipment file").address);
    image.lock().expect("image").inputs[offset(Input::Ready)] = true;
    // A carrier at W2, as STORE's #PRE needs.
    image.lock().expect("image").inputs
        [offset(Input::Signal(Signal::Place(falc_model::ids::Place::of(2))))] = true;
    let address = plain_plc::serve(image.clone()).await;
    let cell = TestCell::start();
    let mut node = transport(&cell, &address, &[]);
    node.expect_line("EVENT plc-ready", Duration::from_secs(10));
    let mut commander = Commander::associate(&cell, "transport").await;
    commander.load("store", &shipped("store")).await;
    commander.start("store").await;
    // The node takes external control and presses K …
    let k = coil(Coil::Button(Button::Line('K')));
    wait_until_async("button K pressed", Duration::from_secs(5), || {
        let pressed = {
            let img = image.lock().expect("image");
            img.coils[k] && img.coils[coil(Coil::ExternalControl)]
        };
        async move { holds(pressed, || "not pressed") }
    })
    .await;
    // … and when place 3 reports occupied, releases it and is done.
    image.lock().expect("image").inputs
        [offset(Input::Signal(Signal::Place(falc_model::ids::Place::of(3))))] = true;
    assert_eq!(commander.job(Duration::from_secs(5)).await, JobEvent::Done);
    assert!(!image.lock().expect("image").coils[k], "K released");
}

/// Store one carrier, then wait for place 5 (the test puts a carrier there).
const PARK: &str = "#PARK
-1 | activate k        | | | 2
-2 | waitplace 3 1 40  | | klaar | 3
-2 | waitplace 3 1 40  | | tijdlimiet | 9
-3 | reset k           | | | 4
-4 | waitplace 5 1 600 | | klaar | 0
-4 | waitplace 5 1 600 | | tijdlimiet | 9
-9 |                   | alarm | | 0
";

/// The transport's program and the state its recipe is in, as its status
/// says.
async fn program_state(rig: &Rig) -> Option<(String, u16)> {
    match rig.commander.call(Request::Status).await {
        Ok(Response::Status(s)) => s.program.map(|p| (p.name.to_string(), p.state)),
        other => panic!("status: {other:?}"),
    }
}

/// ISO 9506 Stop then Resume: the program invocation goes on at the state
/// it stopped in (here 4), not at state 1 (which would send a carrier
/// along line K again).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stop_then_resume_of_a_transport_job_continues_at_its_state() {
    let mut rig = rig().await;
    rig.commander.load("park", PARK).await;
    rig.commander.start("park").await;
    wait_until_async("PARK in state 4", RUN, || async {
        let state = program_state(&rig).await;
        holds(state == Some(("PARK".into(), 4)), || state.clone())
    })
    .await;
    assert_eq!(rig.carriers(), "carriers: 1@W3 2@W2");
    let name = ObjectName::new("park").expect("valid");
    let r = rig
        .commander
        .call(Request::Stop { name: name.clone() })
        .await;
    assert_eq!(r, Ok(Response::ProgramInvocationState(PiState::Stopped)));
    assert_eq!(program_state(&rig).await, None, "stopped: nothing runs");
    rig.plc.expect_line("coil button line K 0", RUN);
    rig.plc.forget("coil button line K");
    let r = rig.commander.call(Request::Resume { name }).await;
    assert_eq!(r, Ok(Response::ProgramInvocationState(PiState::Running)));
    assert_eq!(program_state(&rig).await, Some(("PARK".into(), 4)));
    // A carrier at W5 ends the wait: done, and line K was not pressed again.
    rig.plc.control("layout W3 W5");
    assert_eq!(rig.commander.job(RUN).await, JobEvent::Done);
    assert!(
        rig.plc
            .wait_line("coil button line K 1", Duration::from_millis(500))
            .is_none(),
        "state 1 ran again"
    );
    assert_eq!(rig.carriers(), "carriers: 1@W3 2@W5");
}

/// A broken equipment file stops the transport node, the twin and `io
/// --map` before they touch a PLC, each naming the file, the line and what
/// exists; a good one of another layout is printed as its map.
#[test]
fn an_equipment_file_is_checked_before_anything_runs() {
    use std::process::Command;
    let dir = tempfile::tempdir().expect("temporary directory");
    let good = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("equipment/conveyor-1992.toml"),
    )
    .expect("the shipped equipment file");
    // Line K ends at a place this conveyor lacks.
    let bad = good.replace(
        "name = \"K\"\nfrom = \"W2\"\nto = \"W3\"",
        "name = \"K\"\nfrom = \"W2\"\nto = \"W9\"",
    );
    assert_ne!(bad, good);
    let line = bad
        .lines()
        .position(|l| l == "to = \"W9\"")
        .expect("the changed line")
        + 1;
    let path = dir.path().join("broken.toml");
    std::fs::write(&path, &bad).expect("write");
    let file = path.display().to_string();
    let want = format!(
        "{file}:{line}: line K runs to `W9`, which is no place or station of this equipment \
         (there are: W2, W3, W4, W5, W6, S1, S2, S3)"
    );
    for (bin, args) in [
        (
            env!("CARGO_BIN_EXE_falc-transport"),
            vec!["io", "--map", "--equipment", &file],
        ),
        (
            env!("CARGO_BIN_EXE_falc-plc-sim"),
            vec!["--listen", "127.0.0.1:0", "--equipment", &file],
        ),
    ] {
        let out = Command::new(bin).args(&args).output().expect("runs");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{bin} accepted {file}");
        assert!(err.contains(&want), "{bin}: {err}");
    }
    // A conveyor of two places and one line each way: its own map.
    let small = dir.path().join("small.toml");
    std::fs::write(
        &small,
        "name = \"small\"\n\
         [[place]]\nname = \"2\"\n[[place]]\nname = \"3\"\n\
         [[line]]\nname = \"A\"\nfrom = \"W2\"\nto = \"W3\"\ntravel_s = 2\n\
         [[line]]\nname = \"B\"\nfrom = \"W3\"\nto = \"W2\"\ntravel_s = 2\n\
         [[coil]]\naddress = 100\nsignal = \"button line A\"\n\
         [[coil]]\naddress = 101\nsignal = \"button line B\"\n\
         [[coil]]\naddress = 110\nsignal = \"external control\"\n\
         [[input]]\naddress = 7\nsignal = \"line A running\"\n\
         [[input]]\naddress = 8\nsignal = \"line B running\"\n\
         [[input]]\naddress = 9\nsignal = \"place 2 occupied\"\n\
         [[input]]\naddress = 10\nsignal = \"place 3 occupied\"\n\
         [[input]]\naddress = 11\nsignal = \"PLC ready\"\n\
         [[input]]\naddress = 12\nsignal = \"emergency stop\"\n",
    )
    .expect("write");
    let out = Command::new(env!("CARGO_BIN_EXE_falc-transport"))
        .args(["io", "--map", "--equipment"])
        .arg(&small)
        .output()
        .expect("runs");
    let map = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{map}");
    for row in [
        "| coil | 100 | button line A | drop |",
        "| coil | 110 | external control | hold |",
        "| discrete input | 10 | place 3 occupied | |",
        "| B | W3 | W2 | 2 s |",
    ] {
        assert!(map.contains(row), "{row} missing from:\n{map}");
    }
    assert!(!map.contains("line C"), "{map}");
}

/// Issue 43: a PLC nobody here wrote. Python's pymodbus serves a simple
/// conveyor set up from the equipment file alone (its addresses, lines,
/// places and stations: `tests/fixtures/foreign_plc.py`); the transport
/// node runs STORE against it to done. The file is all a PLC programmer
/// needs. (`.ci/test` installs pymodbus beside asyncua, `FALC_PYTHON`.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_foreign_plc_set_up_from_the_equipment_file_runs_store() {
    let python = std::env::var("FALC_PYTHON").unwrap_or_else(|_| "python3".into());
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let script = root.join("tests/fixtures/foreign_plc.py");
    let equipment = root.join("equipment/conveyor-1992.toml");
    let port = crate::support::free_port().to_string();
    let (script, equipment) = (
        script.display().to_string(),
        equipment.display().to_string(),
    );
    let (mut plc, address) = twin(
        &python,
        &[&script, &equipment, &port, SCALE],
        "listening on ",
    );
    let cell = TestCell::start();
    let mut node = transport(&cell, &address, &[]);
    node.expect_line("EVENT plc-ready", Duration::from_secs(20));
    let mut commander = Commander::associate(&cell, "transport").await;
    commander.load("store", &shipped("store")).await;
    commander.start("store").await;
    assert_eq!(commander.job(RUN).await, JobEvent::Done);
    plc.expect_line(
        "carrier ('place', '2') -> ('place', '3') on line k",
        Duration::from_secs(5),
    );
}

/// The equipment's named states (`[[state]]`), end to end on the twin:
/// `goto home` in maintenance mode runs, from a carrier left mid-conveyor
/// (W5) and one on the table (S3), over the layout's routes to `home`
/// (both at W2), and the station's status shows the state before and
/// after; from a carrier where no route starts (place 7 of a conveyor
/// that has one) it is refused naming the carrier, and nothing is pressed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn goto_home_runs_from_carriers_left_mid_conveyor_or_refuses_naming_the_carrier() {
    use falc_model::mode::{CellMode, ManualAction, ModeSetting};
    let dir = tempfile::tempdir().expect("temporary directory");
    // The 1992 conveyor and a dead end: place 7, no line leaves it.
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("equipment/conveyor-1992.toml"),
    )
    .expect("the shipped equipment file")
    .replace(
        "# A line runs a carrier",
        "[[place]]\nname = \"7\"\n\n[[line]]\nname = \"M\"\nfrom = \"W6\"\nto = \"W7\"\ntravel_s = 3\n\n# A line runs a carrier",
    )
    .replace(
        "[[coil]]\naddress = 0\n",
        "[[coil]]\naddress = 40\nsignal = \"button line M\"\n\n[[input]]\naddress = 40\nsignal = \"line M running\"\n\n[[input]]\naddress = 41\nsignal = \"place 7 occupied\"\n\n[[coil]]\naddress = 0\n",
    )
    .replace(
        "\"place 6 occupied\",\n",
        "\"place 6 occupied\", \"place 7 occupied\",\n",
    );
    let path = dir.path().join("dead-end.toml");
    std::fs::write(&path, &text).expect("write");
    let file = path.display().to_string();
    let mut rig = rig_with(&["--equipment", &file], &["--equipment", &file]).await;
    rig.transport
        .expect_line("EVENT plc-ready", Duration::from_secs(10));
    let by = |action: ManualAction| Request::Manual {
        station: falc_model::ids::StationName::new("transport").expect("name"),
        action,
        by: "maintainer".into(),
    };
    let goto = || by(ManualAction::Goto("home".into()));
    // Outside maintenance mode: refused.
    let r = rig.commander.call(goto()).await;
    assert!(
        r.as_ref().is_err_and(|e| e
            .to_string()
            .contains("manual operation needs maintenance mode")),
        "{r:?}"
    );
    let maintenance = Request::Mode(ModeSetting {
        mode: CellMode::Maintenance,
        stepping: Vec::new(),
    });
    assert!(rig.commander.call(maintenance).await.is_ok());

    // A carrier at W5 (MOVE_TO_MAN left it there) and one on the table.
    rig.plc.control("layout W5 S3");
    let state = rig.equipment_state_becomes("no named state").await;
    assert_eq!(state, "no named state");
    let r = rig.commander.call(goto()).await;
    assert!(matches!(r, Ok(Response::Done)), "{r:?}");
    let started = rig
        .commander
        .report("GOTO_HOME started", Duration::from_secs(5))
        .await;
    assert!(
        started.contains("the way to home from carriers seen at W5, S3:"),
        "{started}"
    );
    assert_eq!(rig.commander.job(RUN).await, JobEvent::Done);
    rig.carriers_become("1@W2 2@W2").await;
    rig.equipment_state_becomes("home").await;
    // Nothing left pressed.
    rig.plc.control("show");
    rig.plc
        .expect_line("buttons held: none", Duration::from_secs(5));

    // From place 7, where no line starts: refused, naming the carrier.
    rig.plc.control("layout W2 W7");
    rig.equipment_state_becomes("no named state").await;
    rig.plc.forget("coil button");
    let r = rig.commander.call(goto()).await;
    let why = r.expect_err("refused").to_string();
    assert!(
        why.contains(
            "the carrier at W7 cannot reach state home: no route from W7 leads to W2 \
             (no line or station starts at W7)"
        ),
        "{why}"
    );
    assert!(
        rig.plc
            .wait_line("coil button", Duration::from_millis(500))
            .is_none(),
        "a refused goto presses nothing"
    );
    // A state the file lacks: refused, naming the ones it has.
    let r = rig
        .commander
        .call(by(ManualAction::Goto("lunch".into())))
        .await;
    let why = r.expect_err("refused").to_string();
    assert!(why.contains("has no state `lunch` (it has: home)"), "{why}");
}

/// Plain inputs and outputs by name (`set`, `waitinput`), end to end on
/// the in/out conveyor's twin: with the guard door open the job that
/// waits for it ends in an alarm naming the input; closed, the lock is
/// set and its feedback (the twin's, after half the file's 500 ms) is
/// waited for, and the beacon lights; a recipe naming an output the file
/// lacks is refused at its Start, naming those it has. The way back is
/// the door closed and the job started again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plain_inputs_and_outputs_are_set_and_waited_for_by_name() {
    let file = format!(
        "{}/equipment/conveyor-inout.toml",
        env!("CARGO_MANIFEST_DIR")
    );
    let mut rig = rig_with(&["--equipment", &file], &["--equipment", &file]).await;
    rig.transport
        .expect_line("EVENT plc-ready", Duration::from_secs(10));
    let lock = "#LOCK
The guard door closed, locked, the beacon lit.

-1 | waitinput door_closed 1 2 |       | klaar      | 2
-1 | waitinput door_closed 1 2 |       | tijdlimiet | 9
-2 | set door_lock 1           |       |            | 3
-3 | waitinput door_locked 1 2 |       | klaar      | 4
-3 | waitinput door_locked 1 2 |       | tijdlimiet | 9
-4 | set beacon 1              |       |            | 0
-9 |                           | alarm |            | 0
";
    rig.commander.load("lock", lock).await;
    // The door open (once the node read it): the job ends in an alarm
    // naming the input.
    let equipment = falc_equipment::Equipment::load(std::path::Path::new(&file)).expect("loads");
    let door = equipment
        .input_index(falc_equipment::signal::Input::Signal(
            falc_recipe::check::Signal::Input(
                falc_model::ids::IoName::parse("door_closed").expect("a name"),
            ),
        ))
        .expect("the door's input");
    rig.plc.control("input door_closed 0");
    rig.status_becomes("the door open", |s| s.inputs.get(door) == Some(&false))
        .await;
    let alarm = match rig.run("lock").await {
        JobEvent::Alarm(cause) => cause.text,
        other => panic!("expected an alarm, got {other:?}"),
    };
    assert!(
        alarm.contains("input door_closed = 1") && alarm.contains("input door_closed still off"),
        "{alarm}"
    );
    if let Some(l) = rig.plc.wait_line("coil output door_lock 1", Duration::ZERO) {
        panic!("locked with the door open: {l}");
    }
    // The way back: the door closed, the job again.
    rig.plc.control("input door_closed 1");
    rig.status_becomes("the door closed", |s| s.inputs.get(door) == Some(&true))
        .await;
    assert_eq!(rig.run("lock").await, JobEvent::Done);
    rig.plc
        .expect_line("coil output door_lock 1", Duration::from_secs(5));
    rig.plc
        .expect_line("input door_locked 1", Duration::from_secs(5));
    rig.plc
        .expect_line("coil output beacon 1", Duration::from_secs(5));
    rig.plc.control("show");
    let inputs = rig.plc.take_line("inputs: ", Duration::from_secs(5));
    assert!(inputs.ends_with("| on door_closed door_locked"), "{inputs}");
    rig.plc
        .expect_line("buttons held: beacon door_lock", Duration::from_secs(5));
    // An output the file lacks: the Start is refused naming those it has.
    let horn = "#HORN\n-1 | set horn 1 | | | 0\n";
    rig.commander.load("horn", horn).await;
    let refused = rig.commander.try_start("horn").await;
    let why = refused.expect_err("refused").to_string();
    assert!(
        why.contains("conveyor-inout has no output horn (outputs: beacon, door_lock)"),
        "{why}"
    );
}

/// `#PRE` and `#POST` end to end (issue 44, item 1, on the transport):
/// with a carrier where the precondition says there is none, the Start
/// is refused naming the term and no coil is written (the twin's log);
/// with the carriers home the job runs to done; a sensor stuck dark
/// breaks the postcondition, and the job ends in an alarm naming it;
/// the sensor mended and the carriers home, the next run is done.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_precondition_refuses_the_start_and_a_postcondition_fails_the_job() {
    let mut rig = rig().await;
    let park = "#PARK
One carrier from W2 to W3 along K.
#PRE place 2 occupied, place 3 empty
#POST place 3 occupied, line K stopped

-1 | activate k      |       |            | 2
-2 | reset k         |       |            | 3
-3 | waitline k 0 30 |       | klaar      | 0
-3 | waitline k 0 30 |       | tijdlimiet | 4
-4 |                 | alarm |            | 0
";
    rig.commander.load("park", park).await;
    let equipment = falc_equipment::Equipment::conveyor_1992();
    let w3 = equipment
        .input_index(falc_equipment::signal::Input::Signal(
            falc_recipe::check::Signal::Place(falc_model::ids::Place::of(3)),
        ))
        .expect("place 3's sensor");
    // A carrier at W3 already: refused, nothing written.
    rig.plc.control("layout W2 W3");
    rig.status_becomes("W3 occupied", |s| s.inputs.get(w3) == Some(&true))
        .await;
    rig.plc.forget("coil button");
    let refused = rig.commander.try_start("park").await;
    let why = refused.expect_err("refused").to_string();
    assert!(
        why.contains("precondition of PARK: place 3 empty is false"),
        "{why}"
    );
    if let Some(l) = rig.plc.wait_line("coil button", Duration::from_millis(500)) {
        panic!("a refused start wrote {l}");
    }
    // Carriers home: done, and the postcondition holds. (Each wait for
    // W3 empty follows one for W3 occupied: a status showing it empty is
    // then the node's reading after the layout, not one from before.)
    rig.plc.control("layout W2 W2");
    rig.status_becomes("W3 empty", |s| s.inputs.get(w3) == Some(&false))
        .await;
    assert_eq!(rig.run("park").await, JobEvent::Done);
    assert_eq!(rig.carriers(), "carriers: 1@W3 2@W2");
    // W3's sensor stuck dark: the carrier arrives unseen, the job fails
    // naming the postcondition.
    rig.status_becomes("W3 occupied", |s| s.inputs.get(w3) == Some(&true))
        .await;
    rig.plc.control("layout W2 W2");
    rig.status_becomes("W3 empty", |s| s.inputs.get(w3) == Some(&false))
        .await;
    rig.plc.control("stuck 3 0");
    rig.commander.start("park").await;
    let alarm = rig.commander.alarm(RUN).await;
    assert_eq!(alarm, "postcondition of PARK: place 3 occupied is false");
    assert_eq!(rig.carriers(), "carriers: 1@W3 2@W2");
    // The way back: the sensor mended, the carriers home, the next run.
    rig.plc.control("unstuck 3");
    rig.status_becomes("W3 occupied", |s| s.inputs.get(w3) == Some(&true))
        .await;
    rig.plc.control("layout W2 W2");
    rig.status_becomes("W3 empty", |s| s.inputs.get(w3) == Some(&false))
        .await;
    assert_eq!(rig.run("park").await, JobEvent::Done);
}
