//! `falc-welding`: the welding workstation. Serves the MMS-equivalent
//! services to its commander (domains, program invocations, status), runs
//! welding recipes (`start rcm N [max_s]`, `wait rcm [max_s]`) and bridges
//! to the robot controller over the DNC serial link. Job events (done,
//! alarm, paused, bad product, failed) go up as unsolicited status.
//!
//! A thin driver: the rules live in `host` (DNC ↔ engine), the recipe
//! engine, the VMD and the 3964R procedure.

mod host;

use anyhow::{Context, Result};
use clap::Parser;
use falc_common::bus::station::{Station, StationEvent};
use falc_common::dnc::driver::{self, DncHandle, LineSettings};
use falc_common::dnc::procedure::{LinkEvent, Priority, Timing};
use falc_common::dnc::telegram::{Program, Telegram};
use falc_common::ids::{ObjectName, StationName};
use falc_common::mms::error::{DefinitionError, ErrorClass, ServiceError};
use falc_common::mms::pdu::{JobEvent, Request, Response, Severity, Unconfirmed};
use falc_common::mms::program::{PiCompletion, PiRequest};
use falc_common::mms::vmd::{Identity, RecipeState, Vmd, VmdStatus};
use falc_common::node::{init_tracing, say, NodeArgs};
use falc_common::recipe::check::{check, Job};
use falc_common::recipe::commands::RecipeKind;
use falc_common::recipe::engine::{Action, Engine, JobEnd, Outcome};
use falc_common::recipe::syntax::parse;
use host::{Host, Out};
use std::sync::Arc;
use std::time::Duration;
use tokio::time::Instant;

#[derive(Parser, Debug)]
#[command(
    version,
    about = "FALC welding workstation: recipes and the DNC link to the robot controller"
)]
struct Cli {
    /// The station this process is (a station of kind welding).
    #[arg(long, default_value = "welding")]
    station: StationName,
    /// The robot controller's serial line; the device defaults to the
    /// topology's `device` of this station.
    #[command(flatten)]
    line: falc_common::dnc::driver::LineArgs,
    #[command(flatten)]
    node: NodeArgs,
}

struct Running {
    name: ObjectName,
    engine: Engine,
}

struct Node {
    station: Station,
    vmd: Vmd,
    host: Host,
    dnc: Option<DncHandle>,
    line: LineSettings,
    running: Option<Running>,
    status: VmdStatus,
    origin: Instant,
    /// A link failure not yet reported.
    link_alarm: Option<String>,
}

impl Node {
    fn now(&self) -> Duration {
        Instant::now().duration_since(self.origin)
    }

    async fn publish_status(&mut self) {
        self.status.local_detail = if self.running.is_some() {
            RecipeState::Executing
        } else {
            RecipeState::Idle
        };
        self.station.set_status(self.status).await;
    }

    async fn job_event(&self, program: &ObjectName, event: JobEvent) {
        let me = self.station.bus().me().station.clone();
        self.station
            .bus()
            .publish(&Unconfirmed::Job {
                station: me,
                program: program.clone(),
                event,
            })
            .await;
    }

    async fn report(&self, severity: Severity, text: String) {
        let me = self.station.bus().me().station.clone();
        self.station
            .bus()
            .publish(&Unconfirmed::Report {
                station: me,
                severity,
                text,
            })
            .await;
    }

    fn send(&mut self, t: Telegram) {
        let sent = self
            .dnc
            .as_ref()
            .map(|d| d.send.send(t.encode()).is_ok())
            .unwrap_or(false);
        if !sent {
            let why = format!(
                "no connection with RCM on {}: the line is not open",
                self.line.path
            );
            let outs = self.host.link_failed(why);
            self.apply_now(outs);
        }
    }

    /// Applies host outputs that need no await (telegrams, engine events).
    fn apply_now(&mut self, outs: Vec<Out>) {
        let now = self.now();
        for o in outs {
            match o {
                Out::Telegram(t) => self.send(t),
                Out::Engine(ev) => {
                    if let Some(r) = &mut self.running {
                        r.engine.handle(now, ev);
                    }
                }
                Out::Detail(d) => self.status.additional = Some(d),
                Out::Info(text) => tracing::info!("{text}"),
            }
        }
    }

    /// Runs the engine's actions and finishes the job when it ended.
    async fn pump(&mut self) {
        loop {
            let Some(r) = &mut self.running else { return };
            let Some(action) = r.engine.poll_action() else {
                break;
            };
            match action {
                Action::Start {
                    job: Job::Program(n),
                    ..
                } => match Program::new(n) {
                    Some(p) => {
                        let outs = self.host.start(p);
                        self.apply_now(outs);
                    }
                    None => tracing::warn!("program {n} out of range"),
                },
                Action::Stop(_) => {
                    let outs = self.host.stop();
                    self.apply_now(outs);
                }
                Action::Alarm(text) => self.report(Severity::Alarm, text).await,
                Action::Entered(s) => tracing::debug!(state = %s, "recipe state"),
                other => tracing::warn!("a welding recipe cannot {other:?}"),
            }
        }
        let ended = self
            .running
            .as_ref()
            .and_then(|r| r.engine.outcome().cloned());
        let Some(outcome) = ended else { return };
        // Only now, with the outcome known, is the job taken out.
        if let Some(r) = self.running.take() {
            let _ = self.vmd.complete(&r.name, PiCompletion::Finished);
            let event = match outcome {
                Outcome::Done => JobEvent::Done,
                Outcome::Alarm(c) => JobEvent::Alarm(c),
                Outcome::Failed(JobEnd::BadProduct) => JobEvent::BadProduct,
                Outcome::Failed(JobEnd::FailedSafe) => JobEvent::FailedSafe,
                Outcome::Failed(JobEnd::FailedDanger) => JobEvent::FailedDanger,
                Outcome::Failed(other) => JobEvent::Alarm(format!("{other:?}")),
            };
            say(&format!("EVENT job program={} event={event:?}", r.name));
            self.job_event(&r.name, event).await;
            self.publish_status().await;
        }
    }

    /// Builds the engine for program invocation `name` from its domain.
    fn engine_for(&self, name: &ObjectName) -> Result<Engine, ServiceError> {
        let text = self
            .vmd
            .program(name)
            .and_then(|p| p.domains().first())
            .and_then(|d| self.vmd.domain(d))
            .map(|d| String::from_utf8_lossy(d.content()).into_owned())
            .ok_or_else(|| {
                ServiceError::undefined(format!("program invocation {name} has no recipe domain"))
            })?;
        let recipe = parse(&text, name.as_str());
        let program = check(&recipe, RecipeKind::Welding).map_err(|problems| {
            let lines: Vec<String> = problems.iter().map(|p| p.to_string()).collect();
            ServiceError::new(
                ErrorClass::Definition(DefinitionError::ObjectAttributeInconsistent),
                format!("error in recipe {name}: {}", lines.join("; ")),
            )
        })?;
        // select + start: 2 telegrams, each up to 6 × 2 s on a dead line.
        Ok(Engine::new(Arc::new(program)).with_confirm_limit(Duration::from_secs(30)))
    }

    async fn indication(&mut self, req: &Request) -> Result<Response, ServiceError> {
        let Some((result, transition)) = self.vmd.handle(req) else {
            return Err(ServiceError::malformed(format!(
                "{} is not served by a welding station",
                req.service()
            )));
        };
        let Some(t) = transition else { return result };
        let now = self.now();
        let done = match t.request {
            PiRequest::Start | PiRequest::Resume => {
                if self.running.is_some() {
                    let _ = self.vmd.complete(&t.name, PiCompletion::StartFailed);
                    return Err(ServiceError::state_conflict(
                        "another welding recipe is running",
                    ));
                }
                match self.engine_for(&t.name) {
                    Ok(mut engine) => {
                        engine.start(now);
                        self.running = Some(Running {
                            name: t.name.clone(),
                            engine,
                        });
                        if t.request == PiRequest::Start {
                            PiCompletion::Started
                        } else {
                            PiCompletion::Resumed
                        }
                    }
                    Err(e) => {
                        let _ = self.vmd.complete(&t.name, PiCompletion::StartFailed);
                        return Err(e);
                    }
                }
            }
            PiRequest::Stop | PiRequest::Kill => {
                if let Some(r) = &mut self.running {
                    r.engine.abort(&format!("{:?} by the commander", t.request));
                }
                let outs = self.host.stop();
                self.apply_now(outs);
                if t.request == PiRequest::Kill {
                    self.running = None;
                    self.publish_status().await;
                    return result;
                }
                self.running = None;
                PiCompletion::Stopped
            }
            PiRequest::Reset => PiCompletion::ResetDone,
            PiRequest::Delete => return result,
        };
        let state = self.vmd.complete(&t.name, done).unwrap_or_else(|s| s);
        self.pump().await;
        self.publish_status().await;
        Ok(Response::ProgramInvocationState(state))
    }

    fn dnc_event(&mut self, ev: LinkEvent) {
        match ev {
            LinkEvent::Received(bytes) => match Telegram::decode(&bytes) {
                Ok(t) => {
                    tracing::debug!(?t, "from the RCM");
                    let outs = self.host.telegram(t);
                    tracing::debug!(?outs, running = self.running.is_some(), "host");
                    self.apply_now(outs);
                }
                Err(e) => tracing::warn!("undecodable telegram from the RCM: {e}"),
            },
            LinkEvent::Failed { error, .. } => {
                let why = format!("no connection with RCM on {}: {error}", self.line.path);
                tracing::warn!("{why}");
                self.link_alarm = Some(why.clone());
                let outs = self.host.link_failed(why);
                self.apply_now(outs);
            }
            LinkEvent::Refused(why) => tracing::debug!("block refused: {why}"),
            LinkEvent::Sent(_) => {}
        }
    }
}

#[tokio::main]
async fn main() -> Result<()> {
    init_tracing();
    let cli = Cli::parse();
    let topology = cli.node.topology()?;
    let settings = cli.node.settings(&topology, &cli.station)?;
    let line = cli
        .line
        .settings(
            topology
                .station(&cli.station)
                .and_then(|s| s.device.clone()),
        )
        .context("no serial port: give --device or a `device` in the topology")?;
    let station = Station::open(settings, &topology).await?;
    let dnc = match driver::open_serial(&line) {
        Ok(port) => Some(driver::spawn(port, Priority::Low, Timing::default())),
        Err(e) => {
            tracing::warn!("{e}; retrying every second");
            None
        }
    };
    let mut node = Node {
        station,
        vmd: Vmd::new(Identity {
            vendor: "FALC".into(),
            model: "welding".into(),
            revision: env!("CARGO_PKG_VERSION").into(),
        }),
        host: Host::new(),
        dnc,
        line,
        running: None,
        status: VmdStatus::default(),
        origin: Instant::now(),
        link_alarm: None,
    };
    node.publish_status().await;
    say(&format!(
        "EVENT ready station={} device={}",
        cli.station, node.line.path
    ));
    let mut reopen = tokio::time::interval(Duration::from_secs(1));
    loop {
        let deadline = node
            .running
            .as_ref()
            .and_then(|r| r.engine.poll_timeout())
            .map_or(Instant::now() + Duration::from_secs(3600), |t| {
                node.origin + t
            });
        tokio::select! {
            ev = node.station.next() => match ev {
                Some(StationEvent::Indication(ind)) => {
                    let result = node.indication(&ind.request).await;
                    ind.responder.respond(result).await;
                }
                Some(StationEvent::Abort(a)) => {
                    say(&format!("EVENT abort-indication peer={}", a.peer.station));
                    if let Some(r) = &mut node.running {
                        r.engine.abort(&format!("no connection with station {}", a.peer.station));
                    }
                }
                Some(StationEvent::Associated(p)) => say(&format!("EVENT associated commander={}", p.station)),
                Some(StationEvent::Concluded(_)) => {}
                None => break,
            },
            ev = async { match &mut node.dnc { Some(d) => d.events.recv().await, None => std::future::pending().await } } => match ev {
                Some(ev) => node.dnc_event(ev),
                None => {
                    let why = format!("no connection with RCM on {}: the line closed", node.line.path);
                    tracing::warn!("{why}");
                    node.dnc = None;
                    let outs = node.host.link_failed(why);
                    node.apply_now(outs);
                }
            },
            _ = reopen.tick(), if node.dnc.is_none() => {
                if let Ok(port) = driver::open_serial(&node.line) {
                    tracing::info!(path = %node.line.path, "line to the RCM open again");
                    node.dnc = Some(driver::spawn(port, Priority::Low, Timing::default()));
                }
            }
            _ = tokio::time::sleep_until(deadline) => {
                let now = node.now();
                if let Some(r) = &mut node.running { r.engine.handle_timeout(now); }
            }
            _ = tokio::signal::ctrl_c() => break,
        }
        node.pump().await;
        if let Some(why) = node.link_alarm.take() {
            node.report(Severity::Alarm, why).await;
        }
        node.publish_status().await;
    }
    if node.running.is_some() {
        let outs = node.host.stop();
        node.apply_now(outs);
    }
    say("EVENT stopped");
    Ok(())
}
