//! `falc-demo-station`: a station with no device, for the foundation's
//! multi-process tests and benchmarks. It serves every MMS-equivalent
//! service of its place in the topology from an in-memory VMD (program
//! invocations complete their transitions at once), takes part in
//! associations, and prints one `EVENT …` line per association change on
//! stdout so that tests can follow it. The real nodes replace it.

use anyhow::Result;
use clap::Parser;
use falc_bus::station::{Station, StationEvent};
use falc_model::ids::ObjectName;
use falc_model::ids::StationName;
use falc_model::mms::error::{ErrorClass, ResourceError, ServiceError};
use falc_model::mms::pdu::{JobEvent, Request, Response, Severity, Unconfirmed};
use falc_model::mms::program::{PiCompletion, PiRequest};
use falc_model::mms::vmd::{Identity, RecipeState, Vmd, VmdStatus};
use falc_node::{init_tracing, NodeArgs};

#[derive(Parser, Debug)]
#[command(
    version,
    about = "FALC demo station (no device) for tests and benchmarks"
)]
struct Cli {
    /// The station this process is.
    #[arg(long)]
    station: StationName,
    /// A started program ends by itself (done) after this many ms, as a
    /// recipe would, and says so as a job event; 0: it runs until it is
    /// stopped.
    #[arg(long, default_value_t = 0)]
    job_ms: u64,
    #[command(flatten)]
    node: NodeArgs,
}

fn event(line: std::fmt::Arguments<'_>) {
    falc_node::say(&format!("EVENT {line}"));
}

#[tokio::main]
async fn main() -> Result<()> {
    init_tracing();
    let cli = Cli::parse();
    let topology = cli.node.topology()?;
    let settings = cli.node.settings(&topology, &cli.station)?;
    let mut station = Station::open(settings, &topology).await?;
    let me = station.bus().me().clone();
    let mut vmd = Vmd::new(Identity {
        vendor: "FALC".into(),
        model: "demo-station".into(),
        revision: env!("CARGO_PKG_VERSION").into(),
    });
    let status = |vmd: &Vmd| VmdStatus {
        local_detail: if vmd
            .programs()
            .any(|p| p.state() == falc_model::mms::program::PiState::Running)
        {
            RecipeState::Executing
        } else {
            RecipeState::Idle
        },
        ..VmdStatus::default()
    };
    event(format_args!(
        "ready station={} session={}",
        me.station, me.session
    ));
    // Started programs that end by themselves (`--job-ms`), and when.
    let mut ends: Vec<(tokio::time::Instant, ObjectName)> = Vec::new();
    loop {
        let next_end = ends.iter().map(|(at, _)| *at).min();
        let ended = async {
            match next_end {
                Some(at) => tokio::time::sleep_until(at).await,
                None => std::future::pending().await,
            }
        };
        let ev = tokio::select! {
            ev = station.next() => ev,
            _ = ended => {
                let now = tokio::time::Instant::now();
                let (due, later): (Vec<_>, Vec<_>) = ends.drain(..).partition(|(at, _)| *at <= now);
                ends = later;
                for (_, name) in due {
                    if vmd.complete(&name, PiCompletion::Finished).is_ok() {
                        station.set_status(status(&vmd)).await;
                        station
                            .bus()
                            .publish(&Unconfirmed::Job {
                                station: me.station.clone(),
                                program: name,
                                event: JobEvent::Done,
                            })
                            .await;
                    }
                }
                continue;
            }
            _ = tokio::signal::ctrl_c() => None,
        };
        let Some(ev) = ev else { break };
        match ev {
            StationEvent::Indication(ind) => {
                let result = match &ind.request {
                    Request::Output { lines } => {
                        for l in lines {
                            event(format_args!("output {l}"));
                        }
                        Ok(Response::Done)
                    }
                    Request::Input { .. } => Err(ServiceError::new(
                        ErrorClass::Resource(ResourceError::CapabilityUnavailable),
                        "the demo station has no operator console",
                    )),
                    other => match vmd.handle(other) {
                        Some((result, transition)) => {
                            if let Some(t) = transition {
                                let done = match t.request {
                                    PiRequest::Start => Some(PiCompletion::Started),
                                    PiRequest::Stop => Some(PiCompletion::Stopped),
                                    PiRequest::Resume => Some(PiCompletion::Resumed),
                                    PiRequest::Reset => Some(PiCompletion::ResetDone),
                                    PiRequest::Kill | PiRequest::Delete => None,
                                };
                                if let Some(c) = done {
                                    let _ = vmd.complete(&t.name, c);
                                }
                                if t.request == PiRequest::Start && cli.job_ms > 0 {
                                    let at = tokio::time::Instant::now()
                                        + std::time::Duration::from_millis(cli.job_ms);
                                    ends.push((at, t.name.clone()));
                                } else if matches!(t.request, PiRequest::Stop | PiRequest::Kill) {
                                    ends.retain(|(_, n)| *n != t.name);
                                }
                                station.set_status(status(&vmd)).await;
                            }
                            result
                        }
                        None => Err(ServiceError::malformed(format!(
                            "{} is not served by a demo station",
                            other.service()
                        ))),
                    },
                };
                ind.responder.respond(result).await;
            }
            StationEvent::Associated(p) => {
                event(format_args!("associated commander={}", p.station))
            }
            StationEvent::Concluded(p) => event(format_args!("concluded commander={}", p.station)),
            StationEvent::Abort(a) => {
                event(format_args!(
                    "abort-indication role={:?} peer={} reason={}",
                    a.role, a.peer.station, a.reason
                ));
                station
                    .bus()
                    .publish(&Unconfirmed::Report {
                        station: me.station.clone(),
                        severity: Severity::Alarm(falc_model::alarm::AlarmClass::Communication),
                        text: format!(
                            "no connection with station {}: {}",
                            a.peer.station, a.reason
                        ),
                    })
                    .await;
            }
        }
    }
    event(format_args!("stopped station={}", me.station));
    Ok(())
}
