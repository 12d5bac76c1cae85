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
//! What each router lets through is `falc_bus::acl::factory_access_control`
//! and `cell_router_access_control`; which routers it admits besides
//! clients is [`crate::modes::Admit`].

use crate::modes::Admit;
use anyhow::{Context, Result};
use falc_bus::config::{self, Place};
use falc_bus::{acl, credentials};
use falc_model::ids::CellId;
use falc_model::plant::Plant;
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
/// cell's stations' (the operator logs in at the factory router only).
/// Returns the files, factory first.
pub fn ensure_credentials(plant: &Plant, dir: &Path) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    crate::private_dir(dir)?;
    for user in factory_users(plant) {
        credentials::ensure(dir, &user)?;
        files.push(dir.join(format!("{user}.toml")));
    }
    for cell in plant.cells() {
        let cdir = cell_dir(dir, cell.id());
        crate::private_dir(&cdir)?;
        for st in cell_users(plant, cell.id()) {
            credentials::ensure(&cdir, &st)?;
            files.push(cdir.join(format!("{st}.toml")));
        }
    }
    Ok(files)
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

/// Refuses the secure transport in a plant until the routers' own
/// certificates are made (a plant runs on `tcp/` for now).
fn tcp_only(plant: &Plant) -> Result<()> {
    let endpoints =
        std::iter::once(plant.router()).chain(plant.cells().iter().map(|c| c.topology().router()));
    for e in endpoints {
        if falc_bus::certificates::is_secure(e) {
            anyhow::bail!(
                "router `{e}`: a plant's routers run on tcp/ for now; the secure transport \
                 between routers (QUIC with the plant's certificates) is not made yet"
            );
        }
    }
    Ok(())
}

/// The factory router: listens on `listen` (default the plant's router),
/// admits each cell router and the factory users.
pub fn factory(plant: &Plant, dir: &Path, listen: Option<String>) -> Result<Router> {
    tcp_only(plant)?;
    ensure_credentials(plant, dir)?;
    let dict = dir.join("router.dict");
    write_dictionary(dir, &factory_users(plant), &dict)?;
    let listen = listen.unwrap_or_else(|| plant.router().to_string());
    let config = config::router(
        &listen,
        plant.lease(),
        &dict,
        None,
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
    tcp_only(plant)?;
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
    let config = config::router(
        &listen,
        plant.lease(),
        &dict,
        None,
        acl::cell_router_access_control(plant, cell),
        Place::CellInPlant {
            uplink: cell.uplink().unwrap_or(plant.router()),
            credentials: &up,
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
