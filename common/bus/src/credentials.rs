//! Per-node credentials: one TOML file per zenoh user (`user`, `password`),
//! created with mode 0600 and refused when group or others may read it, so
//! passwords never appear on a command line or in a world-readable file.
//! The router's usrpwd dictionary (`user:password` lines) is written from
//! the same files.

use rand::distributions::Alphanumeric;
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};

/// A zenoh user name and password.
#[derive(Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Credentials {
    /// The user (the station name, or a console user).
    pub user: String,
    /// The password.
    pub password: String,
}

impl std::fmt::Debug for Credentials {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Credentials {{ user: {:?}, password: <hidden> }}",
            self.user
        )
    }
}

/// Why credentials could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum CredentialsError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// Group or others may read the file.
    #[error("{path} has mode {mode:o}; credentials must be private (chmod 600 {path})")]
    TooOpen {
        /// The file.
        path: PathBuf,
        /// Its permission bits.
        mode: u32,
    },
    /// The file is not valid credentials TOML.
    #[error("{path}: {message}")]
    Syntax {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> CredentialsError + '_ {
    move |source| CredentialsError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// Refuses a secret file (a password, a private key) that is missing or
/// that group or others may read.
pub fn check_private(path: &Path) -> Result<(), CredentialsError> {
    let meta = std::fs::metadata(path).map_err(io(path))?;
    let mode = meta.permissions().mode() & 0o777;
    if mode & 0o077 != 0 {
        return Err(CredentialsError::TooOpen {
            path: path.to_path_buf(),
            mode,
        });
    }
    Ok(())
}

/// Reads a credentials file, refusing one that group or others can read.
pub fn load(path: &Path) -> Result<Credentials, CredentialsError> {
    check_private(path)?;
    let text = std::fs::read_to_string(path).map_err(io(path))?;
    let creds: Credentials = toml::from_str(&text).map_err(|e| CredentialsError::Syntax {
        path: path.to_path_buf(),
        message: e.to_string().trim_end().to_string(),
    })?;
    if creds.user.is_empty() || creds.user.contains(':') || creds.password.contains(['\n', ':']) {
        return Err(CredentialsError::Syntax {
            path: path.to_path_buf(),
            message: "user must be non-empty and neither field may hold `:` or a newline".into(),
        });
    }
    Ok(creds)
}

/// Writes a private file (mode 0600) atomically: a temporary file, then rename.
pub fn write_private(path: &Path, text: &str) -> Result<(), CredentialsError> {
    let tmp = path.with_extension("tmp");
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(0o600)
        .open(&tmp)
        .map_err(io(&tmp))?;
    f.write_all(text.as_bytes()).map_err(io(&tmp))?;
    f.sync_all().map_err(io(&tmp))?;
    std::fs::set_permissions(&tmp, std::fs::Permissions::from_mode(0o600)).map_err(io(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io(path))
}

/// Writes a file others may read (mode 0644: a certificate, the topology),
/// atomically as [`write_private`].
pub fn write_public(path: &Path, text: &str) -> Result<(), CredentialsError> {
    write_private(path, text)?;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o644)).map_err(io(path))
}

/// The credentials file of `user` in `dir`, created with a fresh random
/// password if it does not exist yet.
pub fn ensure(dir: &Path, user: &str) -> Result<Credentials, CredentialsError> {
    let path = dir.join(format!("{user}.toml"));
    if path.exists() {
        return load(&path);
    }
    let creds = Credentials {
        user: user.to_string(),
        password: new_password(),
    };
    let text = format!(
        "# zenoh credentials of `{user}`; keep this file private (mode 0600)\n{}",
        toml::to_string(&creds).map_err(|e| CredentialsError::Syntax {
            path: path.clone(),
            message: e.to_string(),
        })?
    );
    write_private(&path, &text)?;
    Ok(creds)
}

/// Creates `dir` if missing and makes it private (0700).
pub fn private_dir(dir: &Path) -> Result<(), CredentialsError> {
    let io = |source| CredentialsError::Io {
        path: dir.to_path_buf(),
        source,
    };
    std::fs::create_dir_all(dir).map_err(io)?;
    std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o700)).map_err(io)
}

/// A new random password: 32 letters and digits.
pub fn new_password() -> String {
    rand::thread_rng()
        .sample_iter(&Alphanumeric)
        .take(32)
        .map(char::from)
        .collect()
}

/// The usrpwd dictionary text for these credentials.
pub fn dictionary(all: &[Credentials]) -> String {
    all.iter()
        .map(|c| format!("{}:{}\n", c.user, c.password))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ensure_creates_private_files_and_reuses_them() {
        let dir = tempfile::tempdir().expect("tempdir");
        let a = ensure(dir.path(), "welding").expect("created");
        let path = dir.path().join("welding.toml");
        let mode = std::fs::metadata(&path)
            .expect("exists")
            .permissions()
            .mode()
            & 0o777;
        assert_eq!(mode, 0o600);
        assert_eq!(a.password.len(), 32);
        let b = ensure(dir.path(), "welding").expect("reused");
        assert_eq!(a, b);
        assert_eq!(
            dictionary(std::slice::from_ref(&a)),
            format!("welding:{}\n", a.password)
        );
        assert!(
            !format!("{a:?}").contains(&a.password),
            "Debug hides the password"
        );
    }

    #[test]
    fn refuses_open_files_and_bad_syntax() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("cell.toml");
        std::fs::write(&path, "user = \"cell\"\npassword = \"x\"\n").expect("write");
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).expect("chmod");
        assert!(matches!(
            load(&path),
            Err(CredentialsError::TooOpen { mode: 0o644, .. })
        ));
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).expect("chmod");
        assert!(load(&path).is_ok());
        std::fs::write(&path, "user = \"a:b\"\npassword = \"x\"\n").expect("write");
        assert!(matches!(load(&path), Err(CredentialsError::Syntax { .. })));
        std::fs::write(&path, "usr = 1\n").expect("write");
        assert!(matches!(load(&path), Err(CredentialsError::Syntax { .. })));
    }
}
