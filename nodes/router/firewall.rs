//! `falc-router firewall`: the nftables rules that make the router's port
//! a conduit in the IEC 62443 sense. Only the cell's own PCs (the `host`
//! of each station and console in the topology; in a plant, a cell
//! router's own stations, or for the factory router the operator's, the
//! consoles' and each cell router's `host`) reach the port, each
//! opening at most [`NEW_FLOWS_PER_SECOND`] new flows a second; strangers
//! are dropped and a sample of them logged with their address (the kernel
//! log line starts with [`LOG_PREFIX`]), which is where a refused
//! stranger's address comes from, since zenoh names none (zenoh#2712).
//!
//! Why a firewall: zenoh's QUIC listener (zenoh-link-commons 1.10,
//! `accept_task`) waits for each QUIC handshake before it takes the next
//! and has no time-out for it but QUIC's idle time-out, and sleeps 100 ms
//! after a failed one (upstream zenoh#2719 and #2685), so strangers that
//! start handshakes and go quiet, or fail them by the hundred, hold every
//! login back. No zenoh setting changes that; keeping strangers off the
//! port does. Plain text out, no I/O: apply with `nft -f`.

use falc_model::plant::{Plant, PlantCell};
use falc_model::topology::Topology;
use std::net::IpAddr;

/// The nftables table the rules live in (replaced whole on every apply).
pub const TABLE: &str = "falc_router";
/// The prefix of the kernel log line for a dropped stranger.
pub const LOG_PREFIX: &str = "falc-router stranger: ";
/// New flows (QUIC connections, TCP connections) one cell host may open
/// per second; a node opens one per login.
pub const NEW_FLOWS_PER_SECOND: u32 = 20;
/// Dropped strangers logged per second, all sources together.
pub const LOGGED_PER_SECOND: u32 = 5;

/// Why no rules could be made.
#[derive(Debug, thiserror::Error)]
pub enum FirewallError {
    /// The endpoint has no protocol the rules know, or no port.
    #[error(
        "cannot make firewall rules for the endpoint `{0}`: give tcp/HOST:PORT or quic/HOST:PORT"
    )]
    Endpoint(String),
    /// Some users name no host: they would be locked out.
    #[error(
        "{0} name no host in the topology; give each station and console its PC's address \
         (host = \"10.0.0.5\"; a plant's cell router `router-<cell>`: in its [[cell]]), \
         or they are locked out"
    )]
    NoHost(String),
}

/// The rules for the router of a cell on its own, listening on
/// `endpoint` (`quic/…` or `tcp/…`): its stations' and consoles' hosts.
pub fn rules(topology: &Topology, endpoint: &str) -> Result<String, FirewallError> {
    let hosts = topology.user_hosts().map(|(u, h)| (u.to_string(), h));
    rules_for(&format!("cell {}", topology.cell()), hosts, endpoint)
}

/// The rules for a router of a plant listening on `endpoint`: the factory
/// router's (`cell` None: the operator's, the consoles' and each cell
/// router's hosts), or cell `cell`'s (its stations' hosts; its link up is
/// a connection it opens, not one to its port).
pub fn plant_rules(
    plant: &Plant,
    cell: Option<&PlantCell>,
    endpoint: &str,
) -> Result<String, FirewallError> {
    match cell {
        None => {
            let hosts = plant
                .factory()
                .user_hosts()
                .map(|(u, h)| (u.to_string(), h))
                .chain(
                    plant
                        .cells()
                        .iter()
                        .map(|c| (c.router_user().to_string(), c.host())),
                );
            rules_for(
                &format!("plant {}'s factory", plant.name()),
                hosts,
                endpoint,
            )
        }
        Some(c) => {
            let operator = &plant.operator().name;
            let hosts = c
                .topology()
                .stations()
                .iter()
                .filter(|s| &s.name != operator)
                .map(|s| (s.name.to_string(), s.host));
            rules_for(
                &format!("cell {} of plant {}", c.id(), plant.name()),
                hosts,
                endpoint,
            )
        }
    }
}

/// The rules for a router of `what` listening on `endpoint`, admitting
/// the hosts of these users.
fn rules_for(
    what: &str,
    users: impl Iterator<Item = (String, Option<IpAddr>)>,
    endpoint: &str,
) -> Result<String, FirewallError> {
    let bad = || FirewallError::Endpoint(endpoint.to_string());
    let (protocol, address) = endpoint.split_once('/').ok_or_else(bad)?;
    let layer4 = match protocol {
        "quic" => "udp",
        "tcp" => "tcp",
        _ => return Err(bad()),
    };
    let address = address.split(['#', '?']).next().unwrap_or(address);
    let port: u16 = address
        .rsplit_once(':')
        .and_then(|(_, p)| p.parse().ok())
        .ok_or_else(bad)?;
    let mut missing = Vec::new();
    let mut v4 = Vec::new();
    let mut v6 = Vec::new();
    for (user, host) in users {
        match host {
            None => missing.push(user),
            Some(IpAddr::V4(a)) if !v4.contains(&a) => v4.push(a),
            Some(IpAddr::V6(a)) if !v6.contains(&a) => v6.push(a),
            Some(_) => {}
        }
    }
    if !missing.is_empty() {
        return Err(FirewallError::NoHost(missing.join(", ")));
    }
    let set = |name: &str, kind: &str, hosts: Vec<String>| {
        if hosts.is_empty() {
            format!("    set {name} {{ type {kind}; }}\n")
        } else {
            format!(
                "    set {name} {{ type {kind}; elements = {{ {} }}; }}\n",
                hosts.join(", ")
            )
        }
    };
    let mut out = format!(
        "# falc-router firewall for {what}, router on {endpoint}\n\
         # Generated from the topology; apply with: falc-router firewall | nft -f -\n\
         table inet {TABLE}\n\
         delete table inet {TABLE}\n\
         table inet {TABLE} {{\n",
    );
    out += &set(
        "cell_hosts",
        "ipv4_addr",
        v4.iter().map(|a| a.to_string()).collect(),
    );
    out += &set(
        "cell_hosts6",
        "ipv6_addr",
        v6.iter().map(|a| a.to_string()).collect(),
    );
    out += &format!(
        "    chain input {{\n\
         \x20       type filter hook input priority filter - 10; policy accept;\n\
         \x20       iif \"lo\" accept\n\
         \x20       {layer4} dport {port} jump router_port\n\
         \x20   }}\n\
         \x20   chain router_port {{\n\
         \x20       ip saddr @cell_hosts jump cell_host\n\
         \x20       ip6 saddr @cell_hosts6 jump cell_host\n\
         \x20       limit rate {LOGGED_PER_SECOND}/second log prefix \"{LOG_PREFIX}\" level warn\n\
         \x20       counter drop\n\
         \x20   }}\n\
         \x20   chain cell_host {{\n\
         \x20       ct state new meter new_flows4 {{ ip saddr limit rate over {NEW_FLOWS_PER_SECOND}/second burst {NEW_FLOWS_PER_SECOND} packets }} drop\n\
         \x20       ct state new meter new_flows6 {{ ip6 saddr limit rate over {NEW_FLOWS_PER_SECOND}/second burst {NEW_FLOWS_PER_SECOND} packets }} drop\n\
         \x20       accept\n\
         \x20   }}\n\
         }}\n"
    );
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const TOPO: &str = r#"
cell = "falc1"
router = "quic/10.77.0.1:7447"
[[station]]
name = "operator"
kind = "operator"
host = "10.77.0.2"
[[station]]
name = "cell"
kind = "cell"
commander = "operator"
host = "10.77.0.2"
[[console]]
name = "console"
role = "operator"
host = "fd00::9"
"#;

    #[test]
    fn only_the_cells_hosts_reach_the_routers_port() {
        let t = Topology::parse(TOPO, "t").expect("valid");
        let r = rules(&t, t.router()).expect("rules");
        assert!(r.contains("udp dport 7447 jump router_port"), "{r}");
        assert!(
            r.contains("elements = { 10.77.0.2 }"),
            "one entry per host: {r}"
        );
        assert!(r.contains("elements = { fd00::9 }"), "{r}");
        assert!(r.contains(&format!("log prefix \"{LOG_PREFIX}\"")), "{r}");
        assert!(r.contains("limit rate over 20/second"), "{r}");
        assert!(r.trim_end().ends_with('}'));
        let tcp = rules(&t, "tcp/0.0.0.0:7000#iface=eth0").expect("tcp rules");
        assert!(tcp.contains("tcp dport 7000 jump router_port"), "{tcp}");
    }

    #[test]
    fn a_user_without_a_host_or_a_bad_endpoint_is_refused() {
        let t = Topology::parse(
            &TOPO.replace("host = \"10.77.0.2\"\n[[console]]", "[[console]]"),
            "t",
        )
        .expect("valid");
        let e = rules(&t, t.router())
            .expect_err("cell has no host")
            .to_string();
        assert!(e.contains("cell name no host"), "{e}");
        let t = Topology::parse(TOPO, "t").expect("valid");
        assert!(rules(&t, "quic/10.0.0.1").is_err());
        assert!(rules(&t, "serial/ttyS0").is_err());
    }

    #[test]
    fn a_plants_routers_admit_their_own_hosts_only() {
        let text = r#"
plant = "p"
router = "quic/10.0.0.1:7440"
[operator]
name = "operator"
host = "10.0.0.2"
[[console]]
name = "console"
role = "operator"
host = "10.0.0.3"
[[cell]]
cell = "falc1"
router = "quic/10.0.1.1:7441"
host = "10.0.0.11"
[[cell.station]]
name = "cell"
kind = "cell"
commander = "operator"
host = "10.0.1.2"
[[cell.station]]
name = "welding"
kind = "welding"
commander = "cell"
host = "10.0.1.3"
"#;
        let plant = Plant::parse(text, "p").expect("plant");
        let factory = plant_rules(&plant, None, plant.router()).expect("factory rules");
        assert!(
            factory.contains("elements = { 10.0.0.2, 10.0.0.3, 10.0.0.11 }"),
            "the operator, the console, cell 1's router: {factory}"
        );
        assert!(factory.contains("udp dport 7440"), "{factory}");
        let cell = &plant.cells()[0];
        let one = plant_rules(&plant, Some(cell), cell.topology().router()).expect("cell rules");
        assert!(
            one.contains("elements = { 10.0.1.2, 10.0.1.3 }"),
            "cell 1's stations only, not the operator: {one}"
        );
        assert!(one.contains("cell falc1 of plant p"), "{one}");
        // A cell router without a host would lock its link up out.
        let e = plant_rules(
            &Plant::parse(&text.replace("host = \"10.0.0.11\"\n", ""), "p").expect("plant"),
            None,
            plant.router(),
        )
        .expect_err("no host")
        .to_string();
        assert!(e.contains("router-falc1") && e.contains("[[cell]]"), "{e}");
    }
}
