//! `falc-cell`: the cell controller. Accepts the operator as commander and,
//! on its Initiate, associates its workstations first (the 1992 recursive
//! scheme, in `Station`); runs cell recipes (`start`, `wait`, `output`,
//! `input`) through the workstations' services; an abort indication or an
//! alarm from a workstation ends the running recipe in alarm, stops the
//! other workstations' program invocations and reports the cause up.
//!
//! Recipe delivery: a domain the operator downloads as `STATION$NAME` is a
//! workstation's recipe: the cell passes it on to that workstation as
//! domain `NAME` with its program invocation, and confirms the download
//! only when the workstation has it (else the cell drops its copy too: a
//! recipe is never half-applied). Unchanged content is not sent again.
//!
//! A thin driver: the recipe runtime is `falc_common::workstation`, the
//! requests and job events of the level below live in `below`.

mod below;

use anyhow::Result;
use below::{Below, Reply};
use clap::Parser;
use falc_common::bus::station::{Station, StationEvent};
use falc_common::bus::Bus;
use falc_common::ids::{ObjectName, StationName};
use falc_common::mms::error::{DefinitionError, ErrorClass, ServiceError};
use falc_common::mms::pdu::{Request, Response, Severity, Unconfirmed};
use falc_common::node::{init_tracing, say, NodeArgs};
use falc_common::recipe::commands::RecipeKind;
use falc_common::workstation::Workstation;
use std::collections::{hash_map::DefaultHasher, BTreeMap};
use std::hash::{Hash, Hasher};
use std::time::Duration;

#[derive(Parser, Debug)]
#[command(
    version,
    about = "FALC cell controller: cell recipes over the workstations"
)]
struct Cli {
    /// The station this process is (a station of kind cell).
    #[arg(long, default_value = "cell")]
    station: StationName,
    #[command(flatten)]
    node: NodeArgs,
}

/// Download segments to a workstation are at most this long.
const SEGMENT: usize = 8 * 1024;

/// What was last delivered to each workstation: content hash per domain.
type Delivered = BTreeMap<(StationName, ObjectName), u64>;

/// `STATION$NAME` → the workstation and the recipe's name there.
fn workstation_domain(domain: &ObjectName) -> Option<(StationName, ObjectName)> {
    let (st, name) = domain.as_str().split_once('$')?;
    Some((StationName::new(st).ok()?, ObjectName::new(name).ok()?))
}

/// Passes `content` on to `station` as domain `name` with a reusable
/// program invocation of the same name, replacing what was there.
async fn deliver(
    bus: &Bus,
    station: &StationName,
    name: &ObjectName,
    content: &[u8],
) -> Result<(), ServiceError> {
    let limit = Duration::from_secs(10);
    // What was there before goes first (absent is fine).
    for req in [
        Request::DeleteProgramInvocation { name: name.clone() },
        Request::DeleteDomain {
            domain: name.clone(),
        },
    ] {
        let _ = bus.request(station, &req, limit).await;
    }
    let mut steps = vec![Request::InitiateDownloadSequence {
        domain: name.clone(),
    }];
    let chunks: Vec<&[u8]> = if content.is_empty() {
        vec![content]
    } else {
        content.chunks(SEGMENT).collect()
    };
    let n = chunks.len();
    for (i, c) in chunks.into_iter().enumerate() {
        steps.push(Request::DownloadSegment {
            domain: name.clone(),
            data: c.to_vec(),
            more_follows: i + 1 < n,
        });
    }
    steps.push(Request::TerminateDownloadSequence {
        domain: name.clone(),
        discard: None,
    });
    steps.push(Request::CreateProgramInvocation {
        name: name.clone(),
        domains: vec![name.clone()],
        reusable: true,
    });
    for req in steps {
        if let Err(e) = bus.request(station, &req, limit).await {
            // Leave nothing half there.
            let _ = bus
                .request(
                    station,
                    &Request::DeleteDomain {
                        domain: name.clone(),
                    },
                    limit,
                )
                .await;
            return Err(ServiceError::new(
                ErrorClass::Definition(DefinitionError::ObjectAttributeInconsistent),
                format!(
                    "recipe {name} cannot be created on WS {}: {e}",
                    station.as_str().to_uppercase()
                ),
            ));
        }
    }
    Ok(())
}

#[tokio::main]
async fn main() -> Result<()> {
    init_tracing();
    let cli = Cli::parse();
    let topology = cli.node.topology()?;
    let settings = cli.node.settings(&topology, &cli.station)?;
    let station = Station::open(settings, &topology).await?;
    let bus = station.bus().clone();
    let subordinates: Vec<StationName> = topology
        .subordinates_of(&cli.station)
        .into_iter()
        .cloned()
        .collect();
    let (utx, mut publications) = tokio::sync::mpsc::unbounded_channel();
    let mut subscriptions = Vec::new();
    for st in &subordinates {
        subscriptions.extend(bus.subscribe(st, utx.clone()).await?);
    }
    let (rtx, mut replies) = tokio::sync::mpsc::unbounded_channel();
    let below = Below::new(
        bus.clone(),
        topology.commander_of(&cli.station).cloned(),
        rtx,
    );
    let mut ws = Workstation::new(station, RecipeKind::Cell, Duration::from_secs(10), below);
    let mut delivered = Delivered::new();
    ws.publish_status().await;
    say(&format!("EVENT ready station={}", cli.station));
    loop {
        let deadline = ws.deadline();
        tokio::select! {
            ev = ws.station_next() => match ev {
                Some(StationEvent::Indication(ind)) => {
                    let mut result = ws.indication(&ind.request).await;
                    if let (Ok(_), Request::TerminateDownloadSequence { domain, discard: None }) = (&result, &ind.request) {
                        if let Some((st, name)) = workstation_domain(domain) {
                            result = if !subordinates.contains(&st) {
                                ws.discard_domain(domain);
                                Err(ServiceError::undefined(format!(
                                    "recipe {domain}: {st} is not a workstation of this cell"
                                )))
                            } else {
                                let content = ws.vmd().domain(domain).map(|d| d.content().to_vec()).unwrap_or_default();
                                let mut h = DefaultHasher::new();
                                content.hash(&mut h);
                                let hash = h.finish();
                                let key = (st.clone(), name.clone());
                                if delivered.get(&key) == Some(&hash) {
                                    Ok(Response::Done)
                                } else {
                                    match deliver(&bus, &st, &name, &content).await {
                                        Ok(()) => {
                                            say(&format!("EVENT delivered station={st} recipe={name}"));
                                            delivered.insert(key, hash);
                                            Ok(Response::Done)
                                        }
                                        Err(e) => {
                                            ws.discard_domain(domain);
                                            delivered.remove(&key);
                                            Err(e)
                                        }
                                    }
                                }
                            };
                        }
                    }
                    ind.responder.respond(result).await;
                }
                other => {
                    if matches!(other, Some(StationEvent::Abort(_))) {
                        // A workstation that comes back starts empty.
                        if let Some(StationEvent::Abort(a)) = &other {
                            delivered.retain(|(st, _), _| *st != a.peer.station);
                        }
                    }
                    if !ws.station_event(other).await { break }
                }
            },
            r = replies.recv() => match r {
                Some(Reply::Started(st, Ok(()))) => ws.feed(vec![falc_common::recipe::engine::Event::Started(st)]),
                Some(Reply::Started(st, Err(e))) => {
                    ws.report(Severity::Alarm, format!("start on {st} refused: {e}")).await;
                    ws.feed(vec![falc_common::recipe::engine::Event::StartFailed(st, e)]);
                }
                Some(Reply::Answer(Ok(a))) => ws.feed(vec![falc_common::recipe::engine::Event::Answer(a)]),
                Some(Reply::Answer(Err(e))) => ws.fault(&format!("no answer from the operator: {e}")).await,
                Some(Reply::Other(what, Err(e))) => tracing::warn!("{what} refused: {e}"),
                Some(Reply::Other(_, Ok(()))) => {}
                None => break,
            },
            u = publications.recv() => match u {
                Some(u) => {
                    if let Unconfirmed::Report { station, severity, text } = &u {
                        // Passed up, so the operator reads every cause in one place.
                        ws.report(*severity, format!("{station}: {text}")).await;
                    }
                    let events = ws.device.unconfirmed(&u);
                    ws.feed(events);
                }
                None => break,
            },
            _ = tokio::time::sleep_until(deadline) => ws.on_timeout(),
            _ = tokio::signal::ctrl_c() => break,
        }
        ws.settle().await;
    }
    drop(subscriptions);
    say("EVENT stopped");
    Ok(())
}
