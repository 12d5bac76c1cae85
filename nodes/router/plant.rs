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
//! certificate of the same user, and admits only its own users. The PC
//! that holds the CA's key (`ca.key`, the factory router's) issues every
//! certificate (`falc-router --plant … credentials`); a router on a PC
//! given only the CA's certificate uses the certificate it was given.
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
    let authority = if secure { authority(plant, dir)? } else { None };
    if let Some(ca) = &authority {
        ca.ensure_router_in(dir, &router_hosts(plant, None)?)?;
    }
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
            ca.ensure_router_in(&cdir, &router_hosts(plant, Some(cell))?)?;
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

/// The plant's certificate authority when this PC holds its key, or none
/// exists yet (made now); None on a PC given only the CA's certificate.
fn authority(plant: &Plant, dir: &Path) -> Result<Option<Authority>> {
    let files = TlsFiles::of(dir, certificates::CA);
    if files.ca.exists() && !files.key.exists() {
        return Ok(None);
    }
    Ok(Some(Authority::ensure(
        dir,
        &format!("plant {}", plant.name()),
    )?))
}

/// The hosts a router's certificate names: the factory router's (`cell`
/// None) the plant's router and every cell's link up; cell `cell`'s its
/// router.
fn router_hosts<'a>(plant: &'a Plant, cell: Option<&'a PlantCell>) -> Result<Vec<&'a str>> {
    let endpoints: Vec<&str> = match cell {
        None => std::iter::once(plant.router())
            .chain(plant.cells().iter().filter_map(|c| c.uplink()))
            .collect(),
        Some(c) => vec![c.topology().router()],
    };
    endpoints
        .into_iter()
        .map(|e| {
            certificates::endpoint_host(e)
                .with_context(|| format!("router endpoint `{e}` names no host"))
        })
        .collect()
}

/// A router's server certificate at its start: issued afresh (so it
/// names the hosts the plant file gives now) on the PC that holds the
/// CA's key, else the one this PC was given. Each router issues only its
/// own at its start: another's files are never rewritten under it.
fn router_certificate(plant: &Plant, dir: &Path, cell: Option<&PlantCell>) -> Result<TlsFiles> {
    let at = cell.map_or_else(|| dir.to_path_buf(), |c| cell_dir(dir, c.id()));
    match authority(plant, dir)? {
        Some(ca) => Ok(ca.issue_router_in(&at, &router_hosts(plant, cell)?)?),
        None => {
            let files = TlsFiles::of(&at, certificates::ROUTER);
            files.check().with_context(|| {
                format!(
                    "this PC has the plant CA's certificate but not its key: copy {} and {} \
                     as made on the factory router's PC (falc-router --plant … credentials)",
                    files.cert.display(),
                    files.key.display()
                )
            })?;
            Ok(files)
        }
    }
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

/// What one PC of the plant needs (`falc-router --plant F bundle USER
/// --out OUT [--cell C]`), made on the PC that holds the plant's
/// credentials: the user's password and, on the secure transport, its
/// certificate, key and the CA's certificate (never its key), laid out as
/// the nodes look for them under `OUT/credentials`, and the plant file as
/// `OUT/factory.toml`. A cell router's PC (`router-<cell>`) also gets its
/// cell's directory: the stations' passwords (its dictionary) and its
/// server certificate.
pub fn bundle(
    plant: &Plant,
    plant_file: &Path,
    dir: &Path,
    user: &str,
    cell: Option<&CellId>,
    out: &Path,
) -> Result<Vec<crate::BundleFile>> {
    use crate::BundleFile;
    let secure = transport(plant)?;
    ensure_credentials(plant, dir)?;
    let to = out.join("credentials");
    // A user's password, and on the secure transport its certificate,
    // key and the CA's certificate, from `from` into `into`.
    let user_files = |from: &Path, into: &Path, user: &str| {
        let tls = TlsFiles::of(from, user);
        let mut files = vec![BundleFile::into_dir(
            from.join(format!("{user}.toml")),
            into,
            true,
        )];
        if secure {
            files.push(BundleFile::into_dir(tls.key, into, true));
            files.push(BundleFile::into_dir(tls.cert, into, false));
            files.push(BundleFile::into_dir(tls.ca, into, false));
        }
        files
    };
    let mut copies = match cell {
        Some(id) => {
            if !cell_users(plant, id).iter().any(|u| u == user) {
                anyhow::bail!("`{user}` is no station of cell `{id}` of the plant");
            }
            user_files(&cell_dir(dir, id), &cell_dir(&to, id), user)
        }
        None => {
            if !factory_users(plant).iter().any(|u| u == user) {
                anyhow::bail!(
                    "`{user}` is neither the operator, a console nor a cell router of the plant \
                     (a station's PC: give --cell)"
                );
            }
            let mut files = user_files(dir, &to, user);
            if let Some(c) = plant
                .cells()
                .iter()
                .find(|c| c.router_user().as_str() == user)
            {
                let (from, into) = (cell_dir(dir, c.id()), cell_dir(&to, c.id()));
                for st in cell_users(plant, c.id()) {
                    files.push(BundleFile::into_dir(
                        from.join(format!("{st}.toml")),
                        &into,
                        true,
                    ));
                }
                if secure {
                    let router = TlsFiles::of(&from, certificates::ROUTER);
                    files.push(BundleFile::into_dir(router.key, &into, true));
                    files.push(BundleFile::into_dir(router.cert, &into, false));
                    files.push(BundleFile::into_dir(router.ca, &into, false));
                }
            }
            files
        }
    };
    copies.push(BundleFile {
        from: plant_file.to_path_buf(),
        to: out.join("factory.toml"),
        private: false,
    });
    Ok(copies)
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
        let one = cell(&plant, &cell_id, &creds, None).expect("cell router");
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
        assert!(tls(&one.config, "listen_certificate").contains("falc1/router.crt"));
        assert!(tls(&one.config, "connect_certificate").contains("router-falc1.crt"));
        // A cell router's PC given the CA's certificate but not its key
        // (what the factory PC made, copied): it runs on the certificate
        // it was given, issuing nothing.
        let given = std::fs::read(creds.join("falc1/router.crt")).expect("cert");
        std::fs::remove_file(creds.join("ca.key")).expect("no CA key");
        cell(&plant, &cell_id, &creds, None).expect("cell router on a PC without the CA key");
        assert_eq!(
            std::fs::read(creds.join("falc1/router.crt")).expect("cert"),
            given
        );
        std::fs::remove_file(creds.join("falc1/router.key")).expect("no key");
        let e = cell(&plant, &cell_id, &creds, None)
            .err()
            .expect("nothing to run on")
            .to_string();
        assert!(e.contains("not its key"), "{e}");
    }

    #[test]
    fn a_bundle_holds_what_one_pc_of_the_plant_needs_and_never_the_ca_key() {
        let dir = tempfile::tempdir().expect("tempdir");
        let text =
            "plant = \"p\"\nrouter = \"quic/10.0.0.1:7440\"\n[operator]\nname = \"operator\"\n\
             [[cell]]\ncell = \"falc1\"\nrouter = \"quic/10.0.1.1:7441\"\n\
             [[cell.station]]\nname = \"cell\"\nkind = \"cell\"\ncommander = \"operator\"\n\
             [[cell.station]]\nname = \"welding\"\nkind = \"welding\"\ncommander = \"cell\"\n";
        let plant = Plant::parse(text, "p").expect("plant");
        let file = dir.path().join("factory.toml");
        let creds = dir.path().join("credentials");
        let out = dir.path().join("out");
        let names = |copies: &[crate::BundleFile]| -> Vec<String> {
            copies
                .iter()
                .map(|c| {
                    c.to.strip_prefix(&out)
                        .expect("under out")
                        .display()
                        .to_string()
                })
                .collect()
        };
        let id = CellId::new("falc1").expect("id");
        let welding = bundle(&plant, &file, &creds, "welding", Some(&id), &out).expect("welding");
        assert_eq!(
            names(&welding),
            [
                "credentials/falc1/welding.toml",
                "credentials/falc1/welding.key",
                "credentials/falc1/welding.crt",
                "credentials/falc1/ca.crt",
                "factory.toml"
            ]
        );
        let router = bundle(&plant, &file, &creds, "router-falc1", None, &out).expect("router");
        let router = names(&router);
        for f in [
            "credentials/router-falc1.toml",
            "credentials/router-falc1.key",
            "credentials/falc1/cell.toml",
            "credentials/falc1/welding.toml",
            "credentials/falc1/router.key",
            "credentials/falc1/router.crt",
        ] {
            assert!(router.iter().any(|n| n == f), "{f} in {router:?}");
        }
        assert!(welding.iter().all(|c| !c.from.ends_with("ca.key")));
        assert!(router.iter().all(|n| !n.ends_with("ca.key")), "{router:?}");
        let e = bundle(&plant, &file, &creds, "welding", None, &out)
            .err()
            .expect("a station needs its cell")
            .to_string();
        assert!(e.contains("give --cell"), "{e}");
    }
}
