//! The cell's certificates for mutual TLS between PCs, which zenoh's QUIC
//! link (`quic/…`) carries: TLS 1.3 inside QUIC (rcgen, no
//! hand-written crypto). One certificate authority per cell; a client
//! certificate per node and console user whose common name is the user
//! name, so the router's ACL can ask for the certificate and the usrpwd
//! user together; the router's server certificate, naming the host the
//! topology's `router` endpoint gives. All of it lives in the credentials
//! directory next to the usrpwd files:
//!
//! | file | what | mode | on which PC |
//! |---|---|---|---|
//! | `ca.crt` | the cell CA's certificate | 0644 | every PC |
//! | `ca.key` | the cell CA's private key | 0600 | the router PC only |
//! | `<user>.crt`, `<user>.key` | a node's or console user's certificate and key | 0644, 0600 | that user's PC |
//! | `router.crt`, `router.key` | the router's server certificate and key | 0644, 0600 | the router PC |
//!
//! `ca` and `router` are therefore not allowed as station or console names
//! (the topology refuses them).

use crate::credentials::{check_private, write_private, write_public, CredentialsError};
use rcgen::{
    BasicConstraints, CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, IsCa,
    KeyPair, KeyUsagePurpose, SanType,
};
use std::path::{Path, PathBuf};

/// The CA's file stem in the credentials directory.
pub const CA: &str = "ca";
/// The router's file stem in the credentials directory.
pub const ROUTER: &str = "router";
/// The common name of the router's server certificate.
pub const ROUTER_COMMON_NAME: &str = "falc-router";

/// The zenoh link protocol of the secure transport between PCs: QUIC,
/// whose TLS 1.3 handshake authenticates both ends with the cell's
/// certificates. (zenoh's `tls/` link is not used: it shares one TLS
/// stream between its reading and writing tasks, zenoh issue #2557.)
pub const SECURE_PROTOCOL: &str = "quic";

/// Whether a zenoh endpoint is on the secure transport (`quic/host:port`).
pub fn is_secure(endpoint: &str) -> bool {
    endpoint
        .strip_prefix(SECURE_PROTOCOL)
        .is_some_and(|rest| rest.starts_with('/'))
}

/// The host of a `proto/host:port[#config]` endpoint (without the brackets
/// of an IPv6 address), as the router's certificate must name it.
pub fn endpoint_host(endpoint: &str) -> Option<&str> {
    let (_, rest) = endpoint.split_once('/')?;
    let address = rest.split(['#', '?']).next()?;
    let (host, _port) = address.rsplit_once(':')?;
    let host = host.trim_start_matches('[').trim_end_matches(']');
    (!host.is_empty()).then_some(host)
}

/// The three files one TLS party needs: the cell CA's certificate (to
/// check the other side), its own certificate and its private key.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TlsFiles {
    /// The cell CA's certificate.
    pub ca: PathBuf,
    /// This party's certificate.
    pub cert: PathBuf,
    /// This party's private key (mode 0600).
    pub key: PathBuf,
}

impl TlsFiles {
    /// The files of `stem` (a user name, or [`ROUTER`]) in `dir`.
    pub fn of(dir: &Path, stem: &str) -> Self {
        Self {
            ca: dir.join(format!("{CA}.crt")),
            cert: dir.join(format!("{stem}.crt")),
            key: dir.join(format!("{stem}.key")),
        }
    }

    /// The files next to a credentials file `<dir>/<user>.toml`.
    pub fn beside(credentials_file: &Path) -> Self {
        let dir = credentials_file.parent().unwrap_or(Path::new("."));
        let stem = credentials_file
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        Self::of(dir, &stem)
    }

    /// Checks that all three exist and the key is private, so that a node
    /// says what is missing instead of a bare TLS failure.
    pub fn check(&self) -> Result<(), CredentialsError> {
        for path in [&self.ca, &self.cert] {
            std::fs::metadata(path).map_err(|source| CredentialsError::Io {
                path: path.clone(),
                source,
            })?;
        }
        check_private(&self.key)
    }
}

fn cert_error(path: &Path, what: impl std::fmt::Display) -> CredentialsError {
    CredentialsError::Syntax {
        path: path.to_path_buf(),
        message: what.to_string(),
    }
}

fn read(path: &Path) -> Result<String, CredentialsError> {
    std::fs::read_to_string(path).map_err(|source| CredentialsError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// The cell's certificate authority, loaded or created in a credentials
/// directory (the router PC's).
pub struct Authority {
    cert: rcgen::Certificate,
    key: KeyPair,
    dir: PathBuf,
    /// Made just now: every certificate of the directory was issued by a
    /// CA that is gone, and is issued again.
    fresh: bool,
}

/// A certificate's parameters named `common_name`, valid 2025–2045 (the
/// CA's and every certificate it issues alike).
fn named(common_name: &str) -> CertificateParams {
    let mut params = CertificateParams::default();
    let mut dn = DistinguishedName::new();
    dn.push(DnType::CommonName, common_name);
    params.distinguished_name = dn;
    params.not_before = rcgen::date_time_ymd(2025, 1, 1);
    params.not_after = rcgen::date_time_ymd(2045, 1, 1);
    params
}

fn leaf_params(common_name: &str) -> CertificateParams {
    let mut params = named(common_name);
    params.key_usages = vec![
        KeyUsagePurpose::DigitalSignature,
        KeyUsagePurpose::KeyEncipherment,
    ];
    params
}

impl Authority {
    /// Loads the CA of `dir` (`ca.crt`, `ca.key`), or creates one named
    /// after the cell if neither exists.
    pub fn ensure(dir: &Path, cell: &str) -> Result<Self, CredentialsError> {
        let files = TlsFiles::of(dir, CA);
        if files.ca.exists() || files.key.exists() {
            files.check()?;
            let key_pem = read(&files.key)?;
            let key = KeyPair::from_pem(&key_pem).map_err(|e| cert_error(&files.key, e))?;
            let cert_pem = read(&files.ca)?;
            let params = CertificateParams::from_ca_cert_pem(&cert_pem)
                .map_err(|e| cert_error(&files.ca, e))?;
            let cert = params
                .self_signed(&key)
                .map_err(|e| cert_error(&files.ca, e))?;
            return Ok(Self {
                cert,
                key,
                dir: dir.to_path_buf(),
                fresh: false,
            });
        }
        let key = KeyPair::generate().map_err(|e| cert_error(&files.key, e))?;
        let mut params = named(&format!("FALC cell {cell} CA"));
        params.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
        params.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
        let cert = params
            .self_signed(&key)
            .map_err(|e| cert_error(&files.ca, e))?;
        write_private(&files.key, &key.serialize_pem())?;
        write_public(&files.ca, &cert.pem())?;
        Ok(Self {
            cert,
            key,
            dir: dir.to_path_buf(),
            fresh: true,
        })
    }

    /// The client certificate of `user` (common name = user), created if
    /// it does not exist yet or the CA was made anew.
    pub fn ensure_client(&self, user: &str) -> Result<TlsFiles, CredentialsError> {
        self.ensure_client_in(&self.dir, user)
    }

    /// The same in directory `dir` (a plant's cell: its stations'
    /// certificates beside their passwords, [`Authority::share`]).
    pub fn ensure_client_in(&self, dir: &Path, user: &str) -> Result<TlsFiles, CredentialsError> {
        let files = TlsFiles::of(dir, user);
        if self.kept(&files)? {
            return Ok(files);
        }
        let mut params = leaf_params(user);
        params.extended_key_usages = vec![ExtendedKeyUsagePurpose::ClientAuth];
        self.issue(params, &files)?;
        Ok(files)
    }

    /// The router's server certificate for `hosts` (the host of the
    /// topology's `router`; `localhost` and `127.0.0.1` are always added),
    /// issued afresh each time so it always names the topology's host.
    pub fn issue_router(&self, hosts: &[&str]) -> Result<TlsFiles, CredentialsError> {
        self.issue_router_in(&self.dir, hosts)
    }

    /// The same in directory `dir` (a plant's cell router's).
    pub fn issue_router_in(
        &self,
        dir: &Path,
        hosts: &[&str],
    ) -> Result<TlsFiles, CredentialsError> {
        let files = TlsFiles::of(dir, ROUTER);
        let mut params = leaf_params(ROUTER_COMMON_NAME);
        params.extended_key_usages = vec![ExtendedKeyUsagePurpose::ServerAuth];
        for &name in hosts.iter().chain(&["localhost", "127.0.0.1"]) {
            let san = match name.parse::<std::net::IpAddr>() {
                Ok(ip) => SanType::IpAddress(ip),
                Err(_) => SanType::DnsName(
                    name.to_string()
                        .try_into()
                        .map_err(|e| cert_error(&files.cert, format!("host `{name}`: {e}")))?,
                ),
            };
            if !params.subject_alt_names.contains(&san) {
                params.subject_alt_names.push(san);
            }
        }
        self.issue(params, &files)?;
        Ok(files)
    }

    /// A router's server certificate in `dir` for `hosts`, issued if it
    /// does not exist yet or the CA was made anew (a plant's routers: each
    /// issues its own afresh at its start, [`Authority::issue_router_in`]).
    pub fn ensure_router_in(
        &self,
        dir: &Path,
        hosts: &[&str],
    ) -> Result<TlsFiles, CredentialsError> {
        let files = TlsFiles::of(dir, ROUTER);
        if self.kept(&files)? {
            return Ok(files);
        }
        self.issue_router_in(dir, hosts)
    }

    /// Whether `files` stay as they are: both there (the key private) and
    /// issued by this CA, not one made anew since.
    fn kept(&self, files: &TlsFiles) -> Result<bool, CredentialsError> {
        if self.fresh || !files.cert.exists() || !files.key.exists() {
            return Ok(false);
        }
        files.check()?;
        Ok(true)
    }

    /// Writes the CA's certificate into `dir` too (a plant's cell
    /// directory: its PCs check the routers against it).
    pub fn share(&self, dir: &Path) -> Result<(), CredentialsError> {
        let (to, from) = (TlsFiles::of(dir, CA).ca, TlsFiles::of(&self.dir, CA).ca);
        if to == from {
            return Ok(());
        }
        // The file as written when the CA was made, byte for byte.
        write_public(&to, &read(&from)?)
    }

    fn issue(&self, params: CertificateParams, files: &TlsFiles) -> Result<(), CredentialsError> {
        let key = KeyPair::generate().map_err(|e| cert_error(&files.key, e))?;
        let cert = params
            .signed_by(&key, &self.cert, &self.key)
            .map_err(|e| cert_error(&files.cert, e))?;
        write_private(&files.key, &key.serialize_pem())?;
        write_public(&files.cert, &cert.pem())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    #[test]
    fn endpoint_hosts() {
        assert_eq!(endpoint_host("quic/10.0.0.1:7447"), Some("10.0.0.1"));
        assert_eq!(endpoint_host("quic/router.cell:7447"), Some("router.cell"));
        assert_eq!(endpoint_host("quic/[::1]:7447#x=1"), Some("::1"));
        assert_eq!(endpoint_host("quic/:7447"), None);
        assert!(is_secure("quic/a:1") && !is_secure("tcp/a:1") && !is_secure("tls/a:1"));
        assert!(!is_secure("quicx/a:1"));
    }

    #[test]
    fn authority_issues_private_keys_and_is_reloaded() {
        let dir = tempfile::tempdir().expect("tempdir");
        let ca = Authority::ensure(dir.path(), "falc1").expect("created");
        let files = ca.ensure_client("welding").expect("issued");
        files.check().expect("complete and private");
        let mode = |p: &Path| std::fs::metadata(p).expect("exists").permissions().mode() & 0o777;
        assert_eq!(mode(&files.key), 0o600);
        assert_eq!(mode(&dir.path().join("ca.key")), 0o600);
        assert_eq!(mode(&files.cert), 0o644);
        let first = std::fs::read_to_string(&files.cert).expect("cert");
        let ca_file = std::fs::read_to_string(dir.path().join("ca.crt")).expect("ca");
        // Loaded again: the same CA, the existing certificate kept.
        let again = Authority::ensure(dir.path(), "falc1").expect("loaded");
        again.ensure_client("welding").expect("kept");
        assert_eq!(std::fs::read_to_string(&files.cert).expect("cert"), first);
        // The CA is not made anew: its file is kept as it was.
        assert_eq!(
            std::fs::read_to_string(dir.path().join("ca.crt")).expect("ca"),
            ca_file
        );
        // A CA deleted to withdraw every certificate: a new one, and the
        // certificates it did not issue are issued again.
        std::fs::remove_file(dir.path().join("ca.crt")).expect("rm");
        std::fs::remove_file(dir.path().join("ca.key")).expect("rm");
        let renewed = Authority::ensure(dir.path(), "falc1").expect("new CA");
        renewed.ensure_client("welding").expect("issued again");
        assert_ne!(std::fs::read_to_string(&files.cert).expect("cert"), first);
        assert_ne!(
            std::fs::read_to_string(dir.path().join("ca.crt")).expect("ca"),
            ca_file
        );
        let router = renewed.issue_router(&["10.7.0.1"]).expect("router");
        router.check().expect("router files");
        // A key that others may read is refused, naming the file.
        std::fs::set_permissions(&files.key, std::fs::Permissions::from_mode(0o644))
            .expect("chmod");
        assert!(matches!(
            files.check(),
            Err(CredentialsError::TooOpen { .. })
        ));
    }
}
