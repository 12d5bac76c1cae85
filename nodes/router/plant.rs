//! The routers of a plant (`launch/factory.toml`): the factory router and
//! one router per cell, each on its own network, each cell router logged
//! in at the factory router with its own credentials (zenoh's own
//! router-to-router routing; nothing home-made).
//!
//! Credentials: the factory router's users (the operator, the console
//! users, one `router-<cell>` per cell) in the credentials directory, each
//! cell's stations in `<dir>/<cell>/`, with each router's dictionary
//! beside its users. The cell router reads its own `router-<cell>.toml`
//! from the directory above its cell's.
//!
//! On the secure transport (every router of the plant on `quic/…`), one
//! certificate authority for the plant (`<dir>/ca.crt`, copied into each
//! cell's directory): a client certificate beside each password, the
//! factory router's server certificate in `<dir>/router.crt`, each cell
//! router's in `<dir>/<cell>/router.crt`; a cell router shows
//! `router-<cell>.crt` on its link up. A certificate of the plant opens
//! nothing by itself: every router asks for the password and the
//! certificate of the same user, and admits only its own users.
//!
//! What each router lets through is `falc_bus::acl::factory_access_control`
//! and `cell_router_access_control`; which routers it admits besides
//! clients is [`crate::modes::Admit`].

use crate::modes::Admit;
use anyhow::{Context, Result};
use falc_bus::certificates::{self, Authority, TlsFiles};
use falc_bus::config::{self, Place};
use falc_bus::{acl, credentials};
use falc_model::ids::CellId;
use falc_model::plant::{Plant, PlantCell};
use std::path::{Path, PathBuf};

/// What one router of the plant runs with.
pub struct Router {
    /// Its zenoh configuration.
    pub config: zenoh::Config,
    /// The routers it admits besides clients.
    pub admit: Admit,
    /// Where it listens.
    pub listen: String,
}

/// The directory of cell `cell`'s stations' credentials.
pub fn cell_dir(dir: &Path, cell: &CellId) -> PathBuf {
    dir.join(cell.as_str())
}

/// Creates what is missing: the factory users' credentials and each
/// cell's stations' (the operator logs in at the factory router only),
/// and on the secure transport their certificates and the routers'.
/// Returns the password files, factory first.
pub fn ensure_credentials(plant: &Plant, dir: &Path) -> Result<Vec<PathBuf>> {
    let secure = transport(plant)?;
    let mut files = Vec::new();
    crate::private_dir(dir)?;
    let authority = secure
        .then(|| Authority::ensure(dir, &format!("plant {}", plant.name())))
        .transpose()?;
    for user in factory_users(plant) {
        credentials::ensure(dir, &user)?;
        if let Some(ca) = &authority {
            ca.ensure_client(&user)?;
        }
        files.push(dir.join(format!("{user}.toml")));
    }
    for cell in plant.cells() {
        let cdir = cell_dir(dir, cell.id());
        crate::private_dir(&cdir)?;
        if let Some(ca) = &authority {
            ca.share(&cdir)?;
        }
        for st in cell_users(plant, cell.id()) {
            credentials::ensure(&cdir, &st)?;
            if let Some(ca) = &authority {
                ca.ensure_client_in(&cdir, &st)?;
            }
            files.push(cdir.join(format!("{st}.toml")));
        }
    }
    Ok(files)
}

/// Issues a router's server certificate afresh at its start (so it names
/// the hosts the plant file gives now): the factory router's (`cell`
/// None), in the credentials directory, for the plant's router and every
/// cell's link up; or cell `cell`'s, in its directory. Each router issues
/// only its own: another's files are never rewritten under it.
fn router_certificate(plant: &Plant, dir: &Path, cell: Option<&PlantCell>) -> Result<TlsFiles> {
    let authority = Authority::ensure(dir, &format!("plant {}", plant.name()))?;
    let (at, endpoints): (PathBuf, Vec<&str>) = match cell {
        None => (
            dir.to_path_buf(),
            std::iter::once(plant.router())
                .chain(plant.cells().iter().filter_map(|c| c.uplink()))
                .collect(),
        ),
        Some(c) => (cell_dir(dir, c.id()), vec![c.topology().router()]),
    };
    let hosts = endpoints
        .iter()
        .map(|e| {
            certificates::endpoint_host(e)
                .with_context(|| format!("router endpoint `{e}` names no host"))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(authority.issue_router_in(&at, &hosts)?)
}

/// The factory router's users: the operator, the console users and each
/// cell's router.
fn factory_users(plant: &Plant) -> Vec<String> {
    plant
        .factory()
        .users()
        .map(|u| u.as_str().to_string())
        .chain(plant.cells().iter().map(|c| c.router_user().to_string()))
        .collect()
}

/// A cell router's users: the cell's stations (not the operator).
fn cell_users(plant: &Plant, cell: &CellId) -> Vec<String> {
    let operator = &plant.operator().name;
    plant
        .cell(cell)
        .map(|c| {
            c.topology()
                .stations()
                .iter()
                .filter(|s| &s.name != operator)
                .map(|s| s.name.as_str().to_string())
                .collect()
        })
        .unwrap_or_default()
}

/// Writes a router's dictionary of `users` from `dir` to `dict`.
fn write_dictionary(dir: &Path, users: &[String], dict: &Path) -> Result<()> {
    let creds = users
        .iter()
        .map(|u| credentials::ensure(dir, u))
        .collect::<Result<Vec<_>, _>>()?;
    credentials::write_private(dict, &credentials::dictionary(&creds))?;
    Ok(())
}

/// Whether the plant runs on the secure transport: every router's
/// endpoint (and every link up) on `quic/…`, or none (a plant half on
/// tcp/ is refused, naming the odd one).
pub fn transport(plant: &Plant) -> Result<bool> {
    let secure = certificates::is_secure(plant.router());
    let endpoints = plant
        .cells()
        .iter()
        .flat_map(|c| std::iter::once(c.topology().router()).chain(c.uplink()));
    for e in endpoints {
        if certificates::is_secure(e) != secure {
            anyhow::bail!(
                "router `{e}` and the factory router `{}`: every router of a plant runs on \
                 quic/ (the secure transport) or none does",
                plant.router()
            );
        }
    }
    Ok(secure)
}

/// The factory router: listens on `listen` (default the plant's router),
/// admits each cell router and the factory users.
pub fn factory(plant: &Plant, dir: &Path, listen: Option<String>) -> Result<Router> {
    let secure = transport(plant)?;
    ensure_credentials(plant, dir)?;
    let dict = dir.join("router.dict");
    write_dictionary(dir, &factory_users(plant), &dict)?;
    let listen = listen.unwrap_or_else(|| plant.router().to_string());
    let tls = secure
        .then(|| router_certificate(plant, dir, None))
        .transpose()?;
    let config = config::router(
        &listen,
        plant.lease(),
        &dict,
        tls.as_ref(),
        acl::factory_access_control(plant),
        Place::Factory {
            plant: plant.name(),
        },
    )?;
    let admit = Admit {
        routers: plant
            .cells()
            .iter()
            .map(|c| c.router_user().to_string())
            .collect(),
        uplink: None,
    };
    Ok(Router {
        config,
        admit,
        listen,
    })
}

/// Cell `cell`'s router: listens on `listen` (default the cell's router),
/// admits the cell's stations, and links up to the factory router.
pub fn cell(plant: &Plant, id: &CellId, dir: &Path, listen: Option<String>) -> Result<Router> {
    let secure = transport(plant)?;
    let cell = plant.cell(id).with_context(|| {
        let ids: Vec<&str> = plant.cells().iter().map(|c| c.id().as_str()).collect();
        format!("the plant has no cell `{id}` (it has: {})", ids.join(", "))
    })?;
    ensure_credentials(plant, dir)?;
    let cdir = cell_dir(dir, id);
    let dict = cdir.join("router.dict");
    write_dictionary(&cdir, &cell_users(plant, id), &dict)?;
    let up = credentials::load(&dir.join(format!("{}.toml", cell.router_user())))?;
    let listen = listen.unwrap_or_else(|| cell.topology().router().to_string());
    let tls = secure
        .then(|| router_certificate(plant, dir, Some(cell)))
        .transpose()?;
    let uplink_tls = secure.then(|| TlsFiles::of(dir, cell.router_user().as_str()));
    let config = config::router(
        &listen,
        plant.lease(),
        &dict,
        tls.as_ref(),
        acl::cell_router_access_control(plant, cell),
        Place::CellInPlant {
            uplink: cell.uplink().unwrap_or(plant.router()),
            credentials: &up,
            uplink_tls: uplink_tls.as_ref(),
        },
    )?;
    let admit = Admit {
        routers: Default::default(),
        uplink: Some(config::factory_router_id(plant.name())),
    };
    Ok(Router {
        config,
        admit,
        listen,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plant of two cells with these router endpoints.
    fn plant(factory: &str, one: &str, two: &str) -> Result<bool> {
        let text = format!(
            "plant = \"p\"\nrouter = \"{factory}\"\n[operator]\nname = \"operator\"\n\
             [[cell]]\ncell = \"falc1\"\nrouter = \"{one}\"\n\
             [[cell.station]]\nname = \"cell\"\nkind = \"cell\"\ncommander = \"operator\"\n\
             [[cell]]\ncell = \"falc2\"\nrouter = \"{two}\"\n\
             [[cell.station]]\nname = \"cell\"\nkind = \"cell\"\ncommander = \"operator\"\n"
        );
        transport(&Plant::parse(&text, "p").expect("plant"))
    }

    #[test]
    fn a_plant_runs_on_quic_everywhere_or_nowhere() {
        let tcp = plant(
            "tcp/10.0.0.1:7440",
            "tcp/10.0.1.1:7441",
            "tcp/10.0.2.1:7441",
        );
        assert!(!tcp.expect("tcp"));
        let quic = plant(
            "quic/10.0.0.1:7440",
            "quic/10.0.1.1:7441",
            "quic/10.0.2.1:7441",
        );
        assert!(quic.expect("quic"));
        let e = plant(
            "quic/10.0.0.1:7440",
            "quic/10.0.1.1:7441",
            "tcp/10.0.2.1:7441",
        )
        .expect_err("half on tcp");
        assert!(e.to_string().contains("tcp/10.0.2.1:7441"), "{e}");
    }

    #[test]
    fn each_router_of_a_secure_plant_has_its_own_certificate_from_one_authority() {
        let dir = tempfile::tempdir().expect("tempdir");
        let text =
            "plant = \"p\"\nrouter = \"quic/10.0.0.1:7440\"\n[operator]\nname = \"operator\"\n\
             [[console]]\nname = \"console\"\nrole = \"operator\"\n\
             [[cell]]\ncell = \"falc1\"\nrouter = \"quic/10.0.1.1:7441\"\n\
             [[cell.station]]\nname = \"cell\"\nkind = \"cell\"\ncommander = \"operator\"\n";
        let plant = Plant::parse(text, "p").expect("plant");
        let creds = dir.path().join("credentials");
        let factory = factory(&plant, &creds, None).expect("factory router");
        let cell_id = CellId::new("falc1").expect("id");
        let cell = cell(&plant, &cell_id, &creds, None).expect("cell router");
        for file in [
            "ca.crt",
            "router.crt",
            "operator.crt",
            "console.crt",
            "router-falc1.crt",
            "falc1/ca.crt",
            "falc1/router.crt",
            "falc1/cell.crt",
        ] {
            assert!(creds.join(file).exists(), "{file}");
        }
        assert_eq!(
            std::fs::read(creds.join("ca.crt")).expect("ca"),
            std::fs::read(creds.join("falc1/ca.crt")).expect("cell's ca"),
            "one authority, its certificate byte for byte in the cell"
        );
        let tls = |c: &zenoh::Config, key: &str| {
            c.get_json(&format!("transport/link/tls/{key}")).expect(key)
        };
        assert!(tls(&factory.config, "listen_certificate").contains("credentials/router.crt"));
        assert!(tls(&cell.config, "listen_certificate").contains("falc1/router.crt"));
        assert!(tls(&cell.config, "connect_certificate").contains("router-falc1.crt"));
    }
}
