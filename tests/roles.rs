//! Console roles, enforced by the router's generated ACL (not the console):
//! an observer reads everything and changes nothing, an operator runs
//! orders but cannot change recipes, an engineer can (checked on save), no
//! user can speak in another's name, and every action is journalled with
//! the user who did it. Against the all-in-one cell started by
//! `falc-launch`, through the `falc` CLI.

use crate::support::LaunchedCell;
use falc_bus::operator_service::CallError;
use falc_bus::{credentials, Bus, BusSettings};
use falc_model::api::ApiRequest;
use falc_model::ids::StationName;
use falc_model::keys::KeySpace;
use falc_model::topology::Topology;
use std::time::Duration;

/// What the router's refusal looks like to `falc`: no reply at all (the
/// operator's own refusals have words of their own).
const ROUTER_REFUSED: &str = "refused by the router's access control";

#[test]
fn roles_are_enforced_by_the_router_and_every_action_names_its_user() {
    let cell = LaunchedCell::start("50");
    let recipes = cell.dir.path().join("recipes");
    let store = recipes.join("transport/store.rcp");
    let original = std::fs::read_to_string(&store).expect("store.rcp");
    let edited = cell.dir.path().join("edited.rcp");
    std::fs::write(&edited, format!("{original}\nEdited by the engineer.\n")).expect("write");
    let broken = cell.dir.path().join("broken.rcp");
    std::fs::write(&broken, original.replace("waitplace", "waitplase")).expect("write");
    let edited = edited.display().to_string();
    let broken = broken.display().to_string();

    // The observer reads everything …
    for read in [
        &["status"][..],
        &["order", "list"],
        &["messages"],
        &["journal"],
        &["store", "list"],
        &["store", "show", "transport", "store"],
    ] {
        let (code, out) = cell.falc_as("observer", read);
        assert_eq!(code, 0, "observer {read:?}: {out}");
    }
    // A store recipe drawn (SVG needs no Graphviz).
    let svg = cell.dir.path().join("store.svg");
    let svg_arg = svg.display().to_string();
    let (code, out) = cell.falc_as(
        "observer",
        &["store", "view", "transport", "store", "--out", &svg_arg],
    );
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("not running now"), "{out}");
    let text = std::fs::read_to_string(&svg).expect("svg");
    assert!(
        text.contains("<svg") && text.contains(">1</tspan>"),
        "{text}"
    );
    // … and changes nothing: each refused by the router.
    cell.falc_as("console", &["order", "add", "dikdroog"]);
    for change in [
        &["order", "add", "dikdroog"][..],
        &["order", "rm", "1"],
        &["start"],
        &["stop"],
        &["ack"],
        &["answer", "ja"],
        &["shutdown"],
        &["store", "put", "--new", "transport", "mine", &edited],
    ] {
        let (code, out) = cell.falc_as("observer", change);
        // No reply (the router refused the call): exit status 2.
        assert_eq!(code, 2, "observer {change:?} must be refused: {out}");
        assert!(out.contains(ROUTER_REFUSED), "observer {change:?}: {out}");
    }

    // The operator runs orders but cannot change a recipe.
    let (code, out) = cell.falc_as("console", &["store", "put", "transport", "store", &edited]);
    assert_eq!(code, 2, "{out}");
    assert!(out.contains(ROUTER_REFUSED), "{out}");
    assert_eq!(std::fs::read_to_string(&store).expect("read"), original);
    let (code, out) = cell.falc_as("console", &["order", "rm", "1"]);
    assert_eq!(code, 0, "{out}");

    // The engineer can: a defect is refused with file, line and reason and
    // nothing is saved; a clean edit is saved.
    let (code, out) = cell.falc_as("engineer", &["store", "put", "transport", "store", &broken]);
    assert_eq!(code, 1, "{out}");
    assert!(
        out.contains("NOT saved") && out.contains("store.rcp:") && out.contains("waitplase"),
        "{out}"
    );
    assert_eq!(std::fs::read_to_string(&store).expect("read"), original);
    let (code, out) = cell.falc_as("engineer", &["store", "put", "transport", "store", &edited]);
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("saved"), "{out}");
    assert!(std::fs::read_to_string(&store)
        .expect("read")
        .contains("Edited by the engineer."));
    // A new cell recipe can be ordered at once (delivered at the start).
    let mine = cell.dir.path().join("mine.rcp");
    std::fs::copy(recipes.join("cell/dundroog.rcp"), &mine).expect("copy");
    let mine = mine.display().to_string();
    let (code, out) = cell.falc_as("console", &["order", "add", "mine"]);
    assert_eq!(code, 1, "not a recipe yet: {out}");
    let (code, out) = cell.falc_as(
        "engineer",
        &["store", "put", "--new", "cell", "mine", &mine],
    );
    assert_eq!(code, 0, "{out}");
    let (code, out) = cell.falc_as("console", &["order", "add", "mine"]);
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("mine"), "{out}");

    // Nobody speaks in another user's name: the observer's session asking
    // for `start` under the operator's name gets no reply.
    let topology = Topology::load(&cell.dir.path().join("cell.toml")).expect("topology");
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        let observer = StationName::new("observer").expect("valid");
        let creds = credentials::load(&cell.dir.path().join("credentials/observer.toml"))
            .expect("credentials");
        let bus = Bus::open(BusSettings {
            keys: KeySpace::new(topology.cell().clone()),
            me: observer,
            endpoint: topology.router().to_string(),
            lease: topology.lease(),
            credentials: Some(creds),
            tls: None,
            connect_timeout: Duration::from_secs(5),
        })
        .await
        .expect("observer session");
        let operator = topology.root().name.clone();
        let console = StationName::new("console").expect("valid");
        let forged = bus
            .api_as(
                &operator,
                None,
                ApiRequest::Start,
                &console,
                Duration::from_secs(2),
            )
            .await;
        assert!(
            matches!(&forged, Err(CallError::NoReply(e)) if e.contains(ROUTER_REFUSED)),
            "{forged:?}"
        );
    });

    // Every action in the journal names the user who did it.
    let (code, journal) = cell.falc_as("observer", &["journal"]);
    assert_eq!(code, 0, "{journal}");
    let actions: Vec<&str> = journal.lines().filter(|l| l.contains(" action ")).collect();
    for done in [
        "console: added order 1 (dikdroog)",
        "console: removed order 1",
        "engineer: recipe transport/store.rcp changed",
        "engineer: recipe cell/mine.rcp created",
        "console: added order 2 (mine)",
    ] {
        assert!(
            actions.iter().any(|l| l.contains(done)),
            "{done}: {actions:#?}"
        );
    }
    assert!(
        !journal.contains("observer:"),
        "nothing the observer tried reached the journal:\n{journal}"
    );
    assert!(!journal.contains("started the list"), "{journal}");
}
