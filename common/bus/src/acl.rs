//! The router's access control, generated from the topology
//! (docs/architecture.md, "Access control").
//!
//! Default deny. Each station may:
//! - serve its own confirmed services (`svc/<service>`, every key listed
//!   concretely, so that a wildcard query is never allowed);
//! - publish its own `status` and `report` and hold its own liveliness token;
//! - query its direct subordinates' services and read their `status` and
//!   `report`, and the reports they kept (`reports`); the operator (the
//!   root) reads every station's;
//! - watch the liveliness tokens of its commander and its subordinates
//!   (the operator: of every station);
//! - a direct subordinate of the operator (the cell) may query the
//!   operator's `input` and `output` (operator communication).
//!
//! - the operator serves the operator API (`api/<call>/*`); each console
//!   user may query the calls its role allows ([`Call::role`]), each only
//!   under its own name (`api/<call>/<user>`), and nothing else: the router
//!   has authenticated the user, so the key tells the operator who asks.
//!
//! On a `quic/…` router each subject is the usrpwd user *and* the common
//! name of its client certificate, over QUIC links (mutual TLS) only.
//!
//! Everything else is denied by the router: a workstation commanding another
//! or its commander, the operator commanding a workstation, anyone
//! publishing on another station's keys.

use falc_model::api::Call;
use falc_model::ids::StationName;
use falc_model::keys::KeySpace;
use falc_model::mms::pdu::ServiceName;
use falc_model::plant::{Plant, PlantCell};
use falc_model::topology::{Console, StationKind, Topology};
use serde_json::{json, Value};

/// One allow rule for one subject.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rule {
    /// Unique id (`<station>/<purpose>`).
    pub id: String,
    /// Zenoh ACL message kinds.
    pub messages: Vec<&'static str>,
    /// `ingress` (from the node to the router) or `egress` (to the node).
    pub flow: &'static str,
    /// Key expressions.
    pub keys: Vec<String>,
}

fn rule(id: String, flow: &'static str, messages: &[&'static str], keys: Vec<String>) -> Rule {
    Rule {
        id,
        messages: messages.to_vec(),
        flow,
        keys,
    }
}

/// The services a station serves: downward services for its commander, and
/// for the operator also the upward ones.
pub fn served_services(topology: &Topology, station: &StationName) -> Vec<ServiceName> {
    let mut v: Vec<ServiceName> = ServiceName::downward().collect();
    if topology.station(station).map(|s| s.kind) == Some(StationKind::Operator) {
        v.extend(ServiceName::upward());
    }
    v
}

/// Every allow rule of `station`: its part of the hierarchy and, for the
/// operator, serving the operator API.
pub fn rules_of(topology: &Topology, station: &StationName) -> Vec<Rule> {
    let mut out = hierarchy_rules(topology, station);
    if topology.station(station).map(|s| s.kind) == Some(StationKind::Operator) {
        out.extend(api_rules(topology, station));
    }
    out
}

/// The operator's rules for serving the operator API under the
/// topology's name (a cell's, or a plant's) and telling that its status
/// changed.
pub fn api_rules(topology: &Topology, me: &StationName) -> Vec<Rule> {
    let keys = KeySpace::new(topology.cell().clone());
    let api: Vec<String> = Call::ALL.iter().map(|&c| keys.api_any(me, c)).collect();
    vec![
        rule(
            format!("{me}/changed-in"),
            "ingress",
            &["put"],
            vec![keys.changed(me)],
        ),
        rule(
            format!("{me}/changed-out"),
            "egress",
            &["declare_subscriber"],
            vec![keys.changed(me)],
        ),
        rule(
            format!("{me}/api-serve-in"),
            "ingress",
            &["declare_queryable", "reply"],
            api.clone(),
        ),
        rule(format!("{me}/api-serve-out"), "egress", &["query"], api),
    ]
}

/// The rules of `station`'s place in the hierarchy of the topology's
/// cell: serving and publishing its own, commanding its subordinates,
/// asking the operator, watching and reading.
pub fn hierarchy_rules(topology: &Topology, station: &StationName) -> Vec<Rule> {
    let keys = KeySpace::new(topology.cell().clone());
    let svc = |st: &StationName, services: &mut dyn Iterator<Item = ServiceName>| -> Vec<String> {
        services.map(|s| keys.service(st, s)).collect()
    };
    let me = station;
    let mut out = Vec::new();
    let mut own_svc = svc(me, &mut served_services(topology, me).into_iter());
    // The reports it kept, read again by whoever reads its reports.
    own_svc.push(keys.reports(me));
    out.push(rule(
        format!("{me}/serve-in"),
        "ingress",
        &["declare_queryable", "reply"],
        own_svc.clone(),
    ));
    out.push(rule(
        format!("{me}/serve-out"),
        "egress",
        &["query"],
        own_svc,
    ));
    let own_pub = vec![keys.status(me), keys.report(me)];
    out.push(rule(
        format!("{me}/publish-in"),
        "ingress",
        &["put", "liveliness_token"],
        [own_pub.clone(), vec![keys.alive_any(me)]].concat(),
    ));
    out.push(rule(
        format!("{me}/publish-out"),
        "egress",
        &["declare_subscriber"],
        own_pub,
    ));

    let subordinates = topology.subordinates_of(me);
    for sub in &subordinates {
        let keys_sub = svc(sub, &mut ServiceName::downward());
        out.push(rule(
            format!("{me}/command-{sub}-in"),
            "ingress",
            &["query"],
            keys_sub.clone(),
        ));
        out.push(rule(
            format!("{me}/command-{sub}-out"),
            "egress",
            &["reply", "declare_queryable"],
            keys_sub,
        ));
    }
    if let Some(cmd) = topology.commander_of(me) {
        if topology.station(cmd).map(|s| s.kind) == Some(StationKind::Operator) {
            let up = svc(cmd, &mut ServiceName::upward());
            out.push(rule(
                format!("{me}/ask-{cmd}-in"),
                "ingress",
                &["query"],
                up.clone(),
            ));
            out.push(rule(
                format!("{me}/ask-{cmd}-out"),
                "egress",
                &["reply", "declare_queryable"],
                up,
            ));
        }
    }
    // The operator (the root) reads every station's status and watches
    // every station's presence: the consoles show a lost station as such,
    // not with its last status.
    let everyone_else: Vec<&StationName> = topology
        .stations()
        .iter()
        .map(|s| &s.name)
        .filter(|s| *s != me)
        .collect();
    let is_root = topology.commander_of(me).is_none();
    let watched: Vec<&StationName> = if is_root {
        everyone_else.clone()
    } else {
        topology
            .commander_of(me)
            .into_iter()
            .chain(subordinates.iter().copied())
            .collect()
    };
    if !watched.is_empty() {
        let alive: Vec<String> = watched.iter().map(|s| keys.alive_any(s)).collect();
        out.push(rule(
            format!("{me}/watch-in"),
            "ingress",
            &["declare_liveliness_subscriber", "liveliness_query"],
            alive.clone(),
        ));
        out.push(rule(
            format!("{me}/watch-out"),
            "egress",
            &["liveliness_token", "reply"],
            alive,
        ));
    }
    let readable: Vec<&StationName> = if is_root { everyone_else } else { subordinates };
    if !readable.is_empty() {
        let read: Vec<String> = readable
            .iter()
            .flat_map(|s| [keys.status(s), keys.report(s)])
            .collect();
        out.push(rule(
            format!("{me}/read-in"),
            "ingress",
            &["declare_subscriber"],
            read.clone(),
        ));
        out.push(rule(format!("{me}/read-out"), "egress", &["put"], read));
        let kept: Vec<String> = readable.iter().map(|s| keys.reports(s)).collect();
        out.push(rule(
            format!("{me}/read-kept-in"),
            "ingress",
            &["query"],
            kept.clone(),
        ));
        out.push(rule(
            format!("{me}/read-kept-out"),
            "egress",
            &["reply", "declare_queryable"],
            kept,
        ));
    }
    out
}

/// Every allow rule of a console user: its liveliness token, queries on
/// the operator API calls its role allows, and the operator's `changed`
/// publications.
pub fn console_rules(topology: &Topology, console: &Console) -> Vec<Rule> {
    let keys = KeySpace::new(topology.cell().clone());
    let me = &console.name;
    let operator = &topology.root().name;
    let api: Vec<String> = Call::ALL
        .iter()
        .filter(|c| c.role() <= console.role)
        .map(|&c| keys.api(operator, c, me))
        .collect();
    vec![
        rule(
            format!("{me}/alive-in"),
            "ingress",
            &["liveliness_token"],
            vec![keys.alive_any(me)],
        ),
        rule(format!("{me}/api-in"), "ingress", &["query"], api.clone()),
        // Every role may hear that the status changed (it may read it).
        rule(
            format!("{me}/changed-in"),
            "ingress",
            &["declare_subscriber"],
            vec![keys.changed(operator)],
        ),
        rule(
            format!("{me}/changed-out"),
            "egress",
            &["put"],
            vec![keys.changed(operator)],
        ),
        rule(
            format!("{me}/api-out"),
            "egress",
            &["reply", "declare_queryable"],
            api,
        ),
    ]
}

/// The hierarchy matrix as a Markdown table: what each station (row) may do
/// towards each other station (column), read off the generated rules.
pub fn matrix(topology: &Topology) -> String {
    let keys = KeySpace::new(topology.cell().clone());
    let names: Vec<&StationName> = topology.stations().iter().map(|s| &s.name).collect();
    let mut out = format!(
        "| may … → | {} |\n|---|",
        names
            .iter()
            .map(|n| n.as_str())
            .collect::<Vec<_>>()
            .join(" | ")
    );
    out.push_str(&"---|".repeat(names.len()));
    out.push('\n');
    for a in &names {
        let rules = rules_of(topology, a);
        let has = |msg: &str, key: &str| {
            rules.iter().any(|r| {
                r.flow == "ingress" && r.messages.contains(&msg) && r.keys.iter().any(|k| k == key)
            })
        };
        let cells: Vec<String> = names
            .iter()
            .map(|b| {
                if a == b {
                    return "serve own svc, publish own status/report".to_string();
                }
                let mut v = Vec::new();
                if has("query", &keys.service(b, ServiceName::Start)) {
                    v.push("command (svc)");
                }
                if has("query", &keys.service(b, ServiceName::Input)) {
                    v.push("input/output");
                }
                if has("declare_subscriber", &keys.status(b)) {
                    v.push("read status/report");
                }
                if has("query", &keys.reports(b)) {
                    v.push("read kept reports");
                }
                if has("declare_liveliness_subscriber", &keys.alive_any(b)) {
                    v.push("watch alive");
                }
                if v.is_empty() {
                    "—".to_string()
                } else {
                    v.join(", ")
                }
            })
            .collect();
        out.push_str(&format!("| **{a}** | {} |\n", cells.join(" | ")));
    }
    out
}

/// Who a subject of the access control is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Subject {
    /// A user the router authenticated (usrpwd; on a secure router also
    /// the common name of its client certificate, over QUIC only).
    User(String),
    /// A cell router's link up to the factory router, which the cell
    /// router opened itself: the factory router's zenoh id. The cell
    /// router closes every other session that claims that id
    /// (`nodes/router/modes.rs`), so only its own link carries it.
    Uplink {
        /// The factory router's zenoh id ([`crate::config::factory_router_id`]).
        zid: String,
    },
}

/// The `access_control` section of a router's zenoh configuration: default
/// deny, and for each subject its rules.
fn section(secure: bool, entries: Vec<(Subject, Vec<Rule>)>) -> Value {
    let mut rules = Vec::new();
    let mut subjects = Vec::new();
    let mut policies = Vec::new();
    for (who, mine) in entries {
        let (name, mut subject) = match &who {
            Subject::User(name) => (name.clone(), json!({ "usernames": [name] })),
            Subject::Uplink { zid } => ("uplink".to_string(), json!({ "zids": [zid] })),
        };
        subject["id"] = json!(format!("{name}/subject"));
        if secure {
            match &who {
                // The certificate and the password must both be this user's:
                // a stolen password alone, or a certificate alone, opens nothing.
                Subject::User(name) => subject["cert_common_names"] = json!([name]),
                // The link up shows the factory router's server certificate,
                // which no client can present (its key stays on the router
                // PC, and a client certificate must be one for clients).
                Subject::Uplink { .. } => {
                    subject["cert_common_names"] = json!([crate::certificates::ROUTER_COMMON_NAME]);
                }
            }
            subject["link_protocols"] = json!([crate::certificates::SECURE_PROTOCOL]);
        }
        policies.push(json!({
            "id": format!("{name}/policy"),
            "rules": mine.iter().map(|r| r.id.clone()).collect::<Vec<_>>(),
            "subjects": [format!("{name}/subject")],
        }));
        subjects.push(subject);
        rules.extend(mine.into_iter().map(|r| {
            json!({
                "id": r.id,
                "messages": r.messages,
                "flows": [r.flow],
                "permission": "allow",
                "key_exprs": r.keys,
            })
        }));
    }
    json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    })
}

/// The `access_control` section of the cell router's zenoh configuration.
pub fn access_control(topology: &Topology) -> Value {
    let users = topology
        .stations()
        .iter()
        .map(|st| (&st.name, rules_of(topology, &st.name)))
        .chain(
            topology
                .consoles()
                .iter()
                .map(|c| (&c.name, console_rules(topology, c))),
        )
        .map(|(name, rules)| (Subject::User(name.as_str().to_string()), rules))
        .collect();
    section(crate::certificates::is_secure(topology.router()), users)
}

/// Every message kind zenoh's access control knows.
const EVERY_MESSAGE: [&str; 9] = [
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "reply",
    "declare_queryable",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
];

/// `rules` with ids made unique per cell (`<cell>:<id>`): the operator
/// has the same rules in every cell.
fn in_cell(cell: &PlantCell, rules: Vec<Rule>) -> Vec<Rule> {
    rules
        .into_iter()
        .map(|r| Rule {
            id: format!("{}:{}", cell.id(), r.id),
            ..r
        })
        .collect()
}

/// The factory router's access control in a plant:
/// - the operator serves the operator API under the plant's name and has
///   its place at the root of every cell (commanding each cell
///   controller, reading every station, serving operator communication);
/// - each console user reaches the API calls of its role, as in a cell;
/// - each cell router's link carries its own cell's keys, nothing else
///   (`falc/<cell>/**`): within the cell its router holds the hierarchy.
pub fn factory_access_control(plant: &Plant) -> Value {
    let factory = plant.factory();
    let operator = &plant.operator().name;
    let mut operator_rules = api_rules(factory, operator);
    operator_rules.extend(hierarchy_rules(factory, operator));
    for cell in plant.cells() {
        operator_rules.extend(in_cell(cell, hierarchy_rules(cell.topology(), operator)));
    }
    let mut entries = vec![(Subject::User(operator.as_str().to_string()), operator_rules)];
    for c in factory.consoles() {
        entries.push((
            Subject::User(c.name.as_str().to_string()),
            console_rules(factory, c),
        ));
    }
    for cell in plant.cells() {
        let user = cell.router_user().as_str();
        let keys = vec![KeySpace::new(cell.id().clone()).cell_any()];
        entries.push((
            Subject::User(user.to_string()),
            vec![
                rule(
                    format!("{user}/cell-in"),
                    "ingress",
                    &EVERY_MESSAGE,
                    keys.clone(),
                ),
                rule(format!("{user}/cell-out"), "egress", &EVERY_MESSAGE, keys),
            ],
        ));
    }
    section(crate::certificates::is_secure(plant.router()), entries)
}

/// A cell router's access control in a plant: each station of the cell
/// as in a cell of its own, and the link up to the factory router with
/// the operator's rules in this cell (commander traffic only).
pub fn cell_router_access_control(plant: &Plant, cell: &PlantCell) -> Value {
    let topology = cell.topology();
    let operator = &topology.root().name;
    let mut entries: Vec<(Subject, Vec<Rule>)> = topology
        .stations()
        .iter()
        .filter(|st| &st.name != operator)
        .map(|st| {
            (
                Subject::User(st.name.as_str().to_string()),
                rules_of(topology, &st.name),
            )
        })
        .collect();
    entries.push((
        Subject::Uplink {
            zid: crate::config::factory_router_id(plant.name()),
        },
        hierarchy_rules(topology, operator),
    ));
    section(crate::certificates::is_secure(topology.router()), entries)
}

#[cfg(test)]
mod tests {
    use super::*;

    const TOPO: &str = r#"
cell = "falc1"
router = "tcp/127.0.0.1:7447"
[[station]]
name = "operator"
kind = "operator"
[[station]]
name = "cell"
kind = "cell"
commander = "operator"
[[station]]
name = "welding"
kind = "welding"
commander = "cell"
[[station]]
name = "transport"
kind = "transport"
commander = "cell"
"#;

    fn topo() -> Topology {
        Topology::parse(TOPO, "t").expect("valid")
    }

    fn allowed(t: &Topology, who: &str, flow: &str, msg: &str, key: &str) -> bool {
        let who = StationName::new(who).expect("valid");
        rules_of(t, &who)
            .iter()
            .any(|r| r.flow == flow && r.messages.contains(&msg) && r.keys.iter().any(|k| k == key))
    }

    #[test]
    fn the_hierarchy_matrix() {
        let t = topo();
        let q = |who: &str, target: &str, svc: &str| {
            allowed(
                &t,
                who,
                "ingress",
                "query",
                &format!("falc/falc1/{target}/svc/{svc}"),
            )
        };
        assert!(q("operator", "cell", "start"));
        assert!(q("cell", "welding", "start"));
        assert!(q("cell", "transport", "status"));
        assert!(q("cell", "operator", "input"));
        assert!(
            !q("cell", "operator", "status"),
            "the cell does not command the operator"
        );
        assert!(!q("operator", "welding", "start"), "no skipping a level");
        assert!(
            !q("welding", "transport", "start"),
            "workstations do not talk"
        );
        assert!(
            !q("welding", "cell", "start"),
            "no commanding the commander"
        );
        assert!(!q("welding", "operator", "input"));
        let kept = |who: &str, st: &str| {
            allowed(
                &t,
                who,
                "ingress",
                "query",
                &format!("falc/falc1/{st}/reports"),
            )
        };
        assert!(kept("operator", "welding") && kept("operator", "cell"));
        assert!(kept("cell", "welding") && kept("cell", "transport"));
        assert!(!kept("welding", "transport") && !kept("welding", "cell"));
        let put = |who: &str, st: &str| {
            allowed(
                &t,
                who,
                "ingress",
                "put",
                &format!("falc/falc1/{st}/status"),
            )
        };
        assert!(put("welding", "welding"));
        assert!(!put("cell", "welding"));
        // The operator watches every station's presence; a workstation
        // only its commander's.
        let watch = |who: &str, st: &str| {
            allowed(
                &t,
                who,
                "ingress",
                "declare_liveliness_subscriber",
                &format!("falc/falc1/alive/{st}/*"),
            )
        };
        assert!(watch("operator", "welding") && watch("operator", "transport"));
        assert!(watch("welding", "cell"));
        assert!(!watch("welding", "transport"));
        // No wildcard in any rule that lets a station send a query (the
        // operator's API queryable receives `api/<call>/*`: egress only;
        // each console sends on its own concrete key).
        for st in t.stations() {
            for r in rules_of(&t, &st.name) {
                if r.messages.contains(&"query") && r.flow == "ingress" {
                    assert!(r.keys.iter().all(|k| !k.contains('*')), "{r:?}");
                }
            }
        }
    }

    #[test]
    fn generates_a_zenoh_section_with_unique_ids() {
        let v = access_control(&topo());
        let ids: Vec<&str> = v["rules"]
            .as_array()
            .expect("rules")
            .iter()
            .filter_map(|r| r["id"].as_str())
            .collect();
        let unique: std::collections::BTreeSet<_> = ids.iter().collect();
        assert_eq!(ids.len(), unique.len());
        assert_eq!(v["default_permission"], "deny");
        assert_eq!(v["subjects"].as_array().map(|a| a.len()), Some(4));
    }

    #[test]
    fn every_console_hears_that_the_status_changed_and_only_the_operator_says_it() {
        let t = Topology::parse(
            &format!("{TOPO}\n[[console]]\nname = \"olga\"\nrole = \"observer\"\n"),
            "t",
        )
        .expect("valid");
        let key = "falc/falc1/operator/changed";
        let allows = |rules: &[Rule], msg: &str| {
            rules.iter().any(|r| {
                r.flow == "ingress" && r.messages.contains(&msg) && r.keys.iter().any(|k| k == key)
            })
        };
        let olga = t
            .console(&StationName::new("olga").expect("valid"))
            .expect("console");
        assert!(allows(&console_rules(&t, olga), "declare_subscriber"));
        assert!(!allows(&console_rules(&t, olga), "put"));
        let operator = rules_of(&t, &StationName::new("operator").expect("valid"));
        assert!(allows(&operator, "put"));
        for st in ["cell", "welding"] {
            let rules = rules_of(&t, &StationName::new(st).expect("valid"));
            assert!(
                !allows(&rules, "put") && !allows(&rules, "declare_subscriber"),
                "{st}"
            );
        }
    }

    #[test]
    fn consoles_reach_only_the_api_calls_of_their_role() {
        let t = Topology::parse(
            &format!(
                "{TOPO}\n[[console]]\nname = \"olga\"\nrole = \"observer\"\n[[console]]\nname = \"piet\"\nrole = \"operator\"\n[[console]]\nname = \"eva\"\nrole = \"engineer\"\n"
            ),
            "t",
        )
        .expect("valid");
        // `who` may query `call` under the name `as_user`.
        let can_as = |who: &str, call: Call, as_user: &str| {
            let c = t
                .console(&StationName::new(who).expect("valid"))
                .expect("console");
            console_rules(&t, c).iter().any(|r| {
                r.flow == "ingress"
                    && r.messages.contains(&"query")
                    && r.keys
                        .contains(&format!("falc/falc1/operator/api/{call}/{as_user}"))
            })
        };
        let can = |who: &str, call: Call| can_as(who, call, who);
        assert!(can("olga", Call::Status));
        assert!(can("olga", Call::RecipeGet));
        assert!(!can("olga", Call::Start));
        assert!(!can("olga", Call::RecipePut));
        assert!(can("piet", Call::Start));
        assert!(can("piet", Call::Answer));
        assert!(!can("piet", Call::RecipePut));
        assert!(can("eva", Call::RecipePut));
        assert!(can("eva", Call::Start));
        // Nobody may speak in another user's name.
        assert!(!can_as("olga", Call::Status, "piet"));
        assert!(!can_as("eva", Call::Start, "piet"));
        // The operator serves every call; no station may query the API.
        assert!(allowed(
            &t,
            "operator",
            "ingress",
            "declare_queryable",
            "falc/falc1/operator/api/start/*"
        ));
        assert!(!allowed(
            &t,
            "cell",
            "ingress",
            "query",
            "falc/falc1/operator/api/start/cell"
        ));
        let v = access_control(&t);
        assert_eq!(v["subjects"].as_array().map(|a| a.len()), Some(7));
    }

    #[test]
    fn secure_subjects_need_the_certificate_and_the_user() {
        let tcp = Topology::parse(TOPO, "t").expect("valid");
        assert!(access_control(&tcp)["subjects"][0]["cert_common_names"].is_null());
        let t = Topology::parse(&TOPO.replace("tcp/", "quic/"), "t").expect("valid");
        let v = access_control(&t);
        for subject in v["subjects"].as_array().expect("subjects") {
            assert_eq!(
                subject["usernames"], subject["cert_common_names"],
                "{subject}"
            );
            assert_eq!(subject["link_protocols"], json!(["quic"]));
        }
    }

    const PLANT: &str = r#"
plant = "plant"
router = "tcp/127.0.0.1:7440"
[operator]
name = "operator"
[[console]]
name = "olga"
role = "observer"
[[cell]]
cell = "falc1"
router = "tcp/127.0.0.1:7441"
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
router = "tcp/127.0.0.1:7442"
[[cell.station]]
name = "cell"
kind = "cell"
commander = "operator"
"#;

    /// The rules of `subject` in a generated section.
    fn rules_for<'a>(v: &'a Value, subject: &str) -> Vec<&'a Value> {
        let policy = v["policies"]
            .as_array()
            .expect("policies")
            .iter()
            .find(|p| p["subjects"][0] == format!("{subject}/subject"))
            .expect("the subject's policy");
        let ids: Vec<&str> = policy["rules"]
            .as_array()
            .expect("rules")
            .iter()
            .filter_map(|r| r.as_str())
            .collect();
        v["rules"]
            .as_array()
            .expect("rules")
            .iter()
            .filter(|r| r["id"].as_str().is_some_and(|id| ids.contains(&id)))
            .collect()
    }

    fn keys_of(rules: &[&Value]) -> Vec<String> {
        rules
            .iter()
            .flat_map(|r| r["key_exprs"].as_array().expect("keys").iter())
            .filter_map(|k| k.as_str().map(str::to_string))
            .collect()
    }

    #[test]
    fn the_factory_router_scopes_each_cell_router_to_its_cell() {
        let plant = Plant::parse(PLANT, "p").expect("plant");
        let v = factory_access_control(&plant);
        let ids: Vec<&str> = v["rules"]
            .as_array()
            .expect("rules")
            .iter()
            .filter_map(|r| r["id"].as_str())
            .collect();
        let unique: std::collections::BTreeSet<_> = ids.iter().collect();
        assert_eq!(ids.len(), unique.len(), "rule ids are unique");
        // operator, olga, router-falc1, router-falc2
        assert_eq!(v["subjects"].as_array().map(|a| a.len()), Some(4));
        for cell in ["falc1", "falc2"] {
            let keys = keys_of(&rules_for(&v, &format!("router-{cell}")));
            assert_eq!(keys, [format!("falc/{cell}/**"), format!("falc/{cell}/**")]);
        }
        // The operator serves the API under the plant's name and commands
        // each cell controller, never a workstation.
        let op = keys_of(&rules_for(&v, "operator"));
        assert!(op.contains(&"falc/plant/operator/api/start/*".to_string()));
        assert!(op.contains(&"falc/falc1/cell/svc/start".to_string()));
        assert!(op.contains(&"falc/falc2/cell/svc/start".to_string()));
        assert!(!op.iter().any(|k| k.contains("/welding/svc/")), "{op:?}");
        let olga = keys_of(&rules_for(&v, "olga"));
        assert!(olga.contains(&"falc/plant/operator/api/status/olga".to_string()));
        assert!(
            olga.iter().all(|k| k.starts_with("falc/plant/")),
            "{olga:?}"
        );
    }

    #[test]
    fn a_cell_router_takes_its_stations_and_the_operators_traffic_from_the_link_up() {
        let plant = Plant::parse(PLANT, "p").expect("plant");
        let cell = &plant.cells()[0];
        let v = cell_router_access_control(&plant, cell);
        let subjects = v["subjects"].as_array().expect("subjects");
        // cell, welding, the link up; the operator and consoles log in at
        // the factory router, never here.
        assert_eq!(subjects.len(), 3, "{subjects:?}");
        let uplink = subjects
            .iter()
            .find(|s| s["id"] == "uplink/subject")
            .expect("the link up");
        assert_eq!(
            uplink["zids"],
            json!([crate::config::factory_router_id(plant.name())])
        );
        assert!(uplink["usernames"].is_null());
        let up = keys_of(&rules_for(&v, "uplink"));
        assert!(up.contains(&"falc/falc1/cell/svc/start".to_string()));
        assert!(up.contains(&"falc/falc1/operator/svc/input".to_string()));
        assert!(
            up.iter()
                .all(|k| k.starts_with("falc/falc1/") && !k.contains("/api/")),
            "commander traffic of this cell only: {up:?}"
        );
        assert!(!up.iter().any(|k| k.contains("/welding/svc/")), "{up:?}");
        // On the secure transport the link up must also show a router's
        // server certificate.
        let secure = Plant::parse(&PLANT.replace("tcp/", "quic/"), "p").expect("plant");
        let v = cell_router_access_control(&secure, &secure.cells()[0]);
        let uplink = v["subjects"]
            .as_array()
            .expect("subjects")
            .iter()
            .find(|s| s["id"] == "uplink/subject")
            .expect("the link up")
            .clone();
        assert_eq!(
            uplink["cert_common_names"],
            json!([crate::certificates::ROUTER_COMMON_NAME])
        );
        assert_eq!(uplink["link_protocols"], json!(["quic"]));
    }
}
