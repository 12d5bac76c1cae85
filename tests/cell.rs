//! The cell controller end to end: a real router, both twins, both
//! workstations and `falc-cell`; this test process is the operator: it
//! associates with the cell (which associates its workstations), downloads
//! a cell recipe and the workstations' recipes (`STATION$NAME`, passed on
//! by the cell), starts the order, and answers the operator-communication
//! requests (`output`, `input`) the cell sends up.

use crate::support::{twin, Commander, Proc, TestCell};
use falc_bus::{BusEvent, StatusBoard};
use falc_model::mms::pdu::{JobEvent, Request, Response, ServiceName};
use std::time::Duration;
use tokio::sync::mpsc::UnboundedReceiver;

struct Rig {
    _cell: TestCell,
    rcm: Proc,
    plc: Proc,
    _welding: Proc,
    transport: Proc,
    _cell_node: Proc,
    operator: Commander,
    indications: UnboundedReceiver<BusEvent>,
    _served: Vec<falc_bus::Declaration>,
    /// What the cell showed the operator.
    outputs: Vec<String>,
}

fn recipe(path: &str) -> String {
    std::fs::read_to_string(format!("{}/recipes/{path}.rcp", env!("CARGO_MANIFEST_DIR")))
        .expect("shipped recipe")
}

async fn rig(rcm_scale: &str) -> Rig {
    let cell = TestCell::start();
    let (rcm, path) = twin(
        env!("CARGO_BIN_EXE_falc-rcm-sim"),
        &["--time-scale", rcm_scale],
        "serial port: ",
    );
    let (plc, address) = twin(
        env!("CARGO_BIN_EXE_falc-plc-sim"),
        &["--listen", "127.0.0.1:0", "--time-scale", "20"],
        "listening on ",
    );
    let welding = cell.start_node(
        env!("CARGO_BIN_EXE_falc-welding"),
        "welding",
        &["--device", &path],
    );
    let mut transport = cell.start_node(
        env!("CARGO_BIN_EXE_falc-transport"),
        "transport",
        &["--plc", &address],
    );
    transport.expect_line("EVENT plc-ready", Duration::from_secs(10));
    let cell_node = cell.start_node(env!("CARGO_BIN_EXE_falc-cell"), "cell", &[]);
    let operator = Commander::associate_as(&cell, "operator", "cell").await;
    // The operator serves operator communication.
    let (tx, indications) = tokio::sync::mpsc::unbounded_channel();
    let served = operator
        .bus
        .serve(
            &[ServiceName::Input, ServiceName::Output],
            &StatusBoard::default(),
            tx,
        )
        .await
        .expect("serve");
    Rig {
        _cell: cell,
        rcm,
        plc,
        _welding: welding,
        transport,
        _cell_node: cell_node,
        operator,
        indications,
        _served: served,
        outputs: Vec::new(),
    }
}

impl Rig {
    /// Downloads the order's cell recipe and every workstation recipe it uses.
    async fn load_dikdroog(&self) {
        for (domain, file) in [
            ("WELDING$DROOG_DIK", "welding/droog_dik"),
            ("TRANSPORT$STORE", "transport/store"),
            ("TRANSPORT$MOVE_TO_MAN", "transport/move_to_man"),
            ("TRANSPORT$UNSTORE", "transport/unstore"),
            ("TRANSPORT$UNLOAD", "transport/unload"),
        ] {
            self.operator.download(domain, &recipe(file)).await;
        }
        self.operator
            .load("dikdroog", &recipe("cell/dikdroog"))
            .await;
    }

    /// Plays the operator for up to `span`: shows `output`s, answers every
    /// `input` with `answer`; the cell's job event if one came.
    async fn drive(&mut self, answer: &str, span: Duration) -> Option<JobEvent> {
        let end = tokio::time::Instant::now() + span;
        loop {
            tokio::select! {
                ind = self.indications.recv() => match ind {
                    Some(BusEvent::Indication(ind)) => {
                        let reply = match &ind.request {
                            Request::Output { lines } => {
                                self.outputs.extend(lines.iter().cloned());
                                Ok(Response::Done)
                            }
                            Request::Input { .. } => Ok(Response::Answer(answer.to_string())),
                            other => panic!("unexpected {other:?}"),
                        };
                        ind.responder.respond(reply).await;
                    }
                    other => panic!("operator services gone: {other:?}"),
                },
                job = self.operator.try_job(span) => return job,
                _ = tokio::time::sleep_until(end) => return None,
            }
        }
    }

    /// Plays the operator until the cell's job ends (and a moment more: the
    /// cell's last outputs may arrive just after its job event).
    async fn run_order(&mut self, answer: &str, within: Duration) -> JobEvent {
        match self.drive(answer, within).await {
            Some(job) => {
                let late = self.drive(answer, Duration::from_millis(300)).await;
                assert_eq!(late, None, "a second job event");
                job
            }
            None => panic!(
                "order not ended within {within:?}; outputs {:?}",
                self.outputs
            ),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dikdroog_runs_as_an_order_to_done() {
    let mut rig = rig("100").await;
    rig.load_dikdroog().await;
    rig.operator.start("dikdroog").await;
    assert_eq!(
        rig.run_order("ja", Duration::from_secs(60)).await,
        JobEvent::Done,
        "outputs {:?}",
        rig.outputs
    );
    assert_eq!(rig.outputs.first().map(String::as_str), Some(""));
    assert!(rig
        .outputs
        .contains(&"staat blok 1 in de uitgangspositie ?".to_string()));
    assert_eq!(
        rig.outputs.last().map(String::as_str),
        Some("einde dikke plaat droog")
    );
    // The robot welded program 65; the carriers are back where they started.
    rig.rcm.expect_line("rx S065", Duration::from_secs(1));
    rig.plc.control("show");
    rig.plc
        .expect_line("carriers: 1@W2 2@W2", Duration::from_secs(5));
    // The same order again (the program invocations are reusable).
    rig.outputs.clear();
    rig.operator.start("dikdroog").await;
    assert_eq!(
        rig.run_order("ja", Duration::from_secs(60)).await,
        JobEvent::Done
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn answering_nee_ends_the_order_cleanly() {
    let mut rig = rig("100").await;
    rig.load_dikdroog().await;
    rig.operator.start("dikdroog").await;
    assert_eq!(
        rig.run_order("nee", Duration::from_secs(30)).await,
        JobEvent::Done
    );
    assert_eq!(rig.outputs.last().map(String::as_str), Some("einde"));
    assert!(
        rig.plc
            .wait_line("coil button", Duration::from_millis(200))
            .is_none(),
        "no transport started"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_workstation_killed_mid_order_stops_the_other_and_raises_a_cell_alarm() {
    // Program 65 takes 12 s here: the transport is killed mid-weld.
    let mut rig = rig("10").await;
    rig.load_dikdroog().await;
    rig.operator.start("dikdroog").await;
    let end = std::time::Instant::now() + Duration::from_secs(30);
    while rig.rcm.wait_line("rx G", Duration::ZERO).is_none() {
        assert!(std::time::Instant::now() < end, "the weld never started");
        assert_eq!(rig.drive("ja", Duration::from_millis(50)).await, None);
    }
    // Mid-weld, with the transport's UNSTORE (started with the weld) done:
    // the cell waits for the welder only. Killed earlier, the cell's Start
    // of UNSTORE may fail first and take the recipe's own failure path.
    while rig
        .transport
        .wait_line("EVENT job program=UNSTORE event=Done", Duration::ZERO)
        .is_none()
    {
        assert!(std::time::Instant::now() < end, "UNSTORE never ended");
        assert_eq!(rig.drive("ja", Duration::from_millis(50)).await, None);
    }
    let killed = std::time::Instant::now();
    rig.transport.kill();
    let job = rig.drive("ja", Duration::from_secs(10)).await;
    let took = killed.elapsed();
    let job = job.expect("a job event within 10 s");
    match job {
        JobEvent::Alarm(text) => assert!(
            text.contains("no connection with station transport"),
            "{text}"
        ),
        other => panic!("{other:?}"),
    }
    println!("SIGKILL of the transport workstation → cell alarm: {took:?}");
    // The welding workstation was stopped: the robot got its stop.
    rig.rcm.expect_line("rx H", Duration::from_secs(5));
}
