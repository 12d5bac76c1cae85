//! Who may use the OPC UA gateway, and what each may do: the users file
//! (`<credentials-dir>/opcua-users.toml`, private like every credentials
//! file) maps an OPC UA user name and password onto a FALC role, and
//! [`Users`] is the server's `AuthManager`: no anonymous session, a user
//! name and password on every endpoint, a method executable only by a role
//! the operator API grants its call ([`Call::role`], the same rule the
//! router's ACL enforces for consoles). The gateway itself speaks to the
//! operator as one console user, so no OPC UA user can do more than that
//! user's role: the file is capped at it when it is made, and a user
//! above it is refused when it is read.

use crate::front::{Clients, Limits};
use crate::throttle::{self, Verdict};
use async_trait::async_trait;
use falc_bus::credentials::{self, CredentialsError};
use falc_model::api::Call;
use falc_model::topology::{Role, Topology};
use opcua::crypto::{SecurityPolicy, Thumbprint, X509};
use opcua::server::address_space::AccessLevel;
use opcua::server::authenticator::{
    user_pass_security_policy_id, AuthManager, Password, UserToken,
};
use opcua::server::ServerEndpoint;
use opcua::types::{Error, NodeId, StatusCode, UAString, UserTokenPolicy, UserTokenType};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// One OPC UA user of the file.
#[derive(Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct User {
    /// The user name an OPC UA client logs in with.
    pub name: String,
    /// What it may do.
    pub role: Role,
    /// Its password ("": it logs in with its certificate only).
    #[serde(default)]
    pub password: String,
    /// Its X.509 user certificate (DER or PEM; relative to the users
    /// file's directory): a client may log in with it instead of the
    /// password.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub certificate: Option<PathBuf>,
}

impl std::fmt::Debug for User {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "User {{ name: {:?}, role: {:?} }}", self.name, self.role)
    }
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct UsersFile {
    #[serde(rename = "user", default)]
    users: Vec<User>,
}

/// The gateway's OPC UA users, as the server's authenticator.
#[derive(Debug, Clone)]
pub struct Users {
    by_name: BTreeMap<String, User>,
    /// The thumbprint of each user certificate, and whose it is.
    by_certificate: Vec<(Thumbprint, String)>,
    /// The clients' addresses and their failed logins (`front`).
    clients: Arc<Clients>,
}

impl Users {
    /// Reads the users file at `path` (it must be private); if there is
    /// none, makes one: every console user of the topology but the
    /// gateway's own (`me`), each with its role capped at `ceiling` and a
    /// new password.
    pub fn ensure(
        path: &Path,
        topology: &Topology,
        me: &str,
        ceiling: Role,
    ) -> Result<Self, CredentialsError> {
        if !path.exists() {
            let users = topology
                .consoles()
                .iter()
                .filter(|c| c.name.as_str() != me)
                .map(|c| User {
                    name: c.name.to_string(),
                    role: c.role.min(ceiling),
                    password: credentials::new_password(),
                    certificate: None,
                })
                .collect();
            let text =
                toml::to_string(&UsersFile { users }).map_err(|e| CredentialsError::Syntax {
                    path: path.to_path_buf(),
                    message: e.to_string(),
                })?;
            credentials::write_private(
                path,
                &format!(
                    "# OPC UA users of falc-opcua: name, role (observer, operator), password,\n\
                     # and optionally certificate = \"user.der\" (an X.509 user certificate).\n\
                     # Keep this file private (mode 0600).\n{text}"
                ),
            )?;
        }
        Self::load(path, ceiling)
    }

    /// Reads a users file: private, valid, names unique, no role above
    /// `ceiling` (the gateway's own console role), no empty password.
    pub fn load(path: &Path, ceiling: Role) -> Result<Self, CredentialsError> {
        credentials::check_private(path)?;
        let syntax = |message: String| CredentialsError::Syntax {
            path: path.to_path_buf(),
            message,
        };
        let text = std::fs::read_to_string(path).map_err(|source| CredentialsError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let file: UsersFile = toml::from_str(&text).map_err(|e| syntax(e.to_string()))?;
        let mut by_name = BTreeMap::new();
        let mut by_certificate = Vec::new();
        for u in file.users {
            if u.name.is_empty() || (u.password.is_empty() && u.certificate.is_none()) {
                return Err(syntax(format!(
                    "user \"{}\": a user needs a name, and a password or a certificate",
                    u.name
                )));
            }
            if let Some(c) = &u.certificate {
                let at = path.parent().unwrap_or(Path::new(".")).join(c);
                let bytes = std::fs::read(&at).map_err(|source| CredentialsError::Io {
                    path: at.clone(),
                    source,
                })?;
                let cert = X509::from_der(&bytes)
                    .or_else(|_| X509::from_pem(&bytes))
                    .map_err(|e| {
                        syntax(format!(
                            "user \"{}\": certificate {}: not an X.509 certificate (DER or PEM): {e}",
                            u.name,
                            at.display()
                        ))
                    })?;
                by_certificate.push((cert.thumbprint(), u.name.clone()));
            }
            if u.role > ceiling {
                return Err(syntax(format!(
                    "user \"{}\" has role {:?}, above the gateway's own console role {ceiling:?}: \
                     the router would refuse its calls; give it {ceiling:?} or less",
                    u.name, u.role
                )));
            }
            if let Some(old) = by_name.insert(u.name.clone(), u) {
                return Err(syntax(format!("user \"{}\" is listed twice", old.name)));
            }
        }
        Ok(Self {
            by_name,
            by_certificate,
            clients: Arc::new(Clients::new(Limits::default(), throttle::LOCKOUT)),
        })
    }

    /// Logins are counted per client address by the front's `clients`.
    pub fn with_clients(mut self, clients: Arc<Clients>) -> Self {
        self.clients = clients;
        self
    }

    /// The role of an authenticated user (a token is the user's name).
    pub fn role(&self, token: &UserToken) -> Option<Role> {
        self.by_name.get(&token.0).map(|u| u.role)
    }

    /// Whether `token`'s user may make `call`; why not, if not.
    pub fn may(&self, token: &UserToken, call: Call) -> Result<(), String> {
        match self.role(token) {
            Some(role) if role >= call.role() => Ok(()),
            Some(role) => Err(format!(
                "user \"{}\" ({role:?}) may not {call}: it needs role {:?}",
                token.0,
                call.role()
            )),
            None => Err(format!("user \"{}\" is not known", token.0)),
        }
    }

    /// Refuses a login of `who` from client `key` unchecked while the
    /// address is locked (a login already under way when it locked).
    fn unlocked(&self, key: &str, who: &str) -> Result<(), Error> {
        let Verdict::Locked(left) = self.clients.check_login(key) else {
            return Ok(());
        };
        // A source of its own: the lock is logged beside the failures.
        falc_bus::log_limit::warn(
            &format!("{key} (locked)"),
            &format!(
                "OPC UA login of {who} from {key} refused unchecked: the address is locked for {} s more after {} failed logins",
                left.as_secs(),
                throttle::LOCK_AFTER
            ),
        );
        Err(Error::new(
            StatusCode::BadUserAccessDenied,
            format!(
                "{key} is locked for {} s after {} failed logins",
                left.as_secs().max(1),
                throttle::LOCK_AFTER
            ),
        ))
    }
}

/// Compares two secrets in time that does not depend on where they differ.
fn same_secret(a: &str, b: &str) -> bool {
    a.len() == b.len()
        && a.bytes()
            .zip(b.bytes())
            .fold(0u8, |acc, (x, y)| acc | (x ^ y))
            == 0
}

#[async_trait]
impl AuthManager for Users {
    async fn authenticate_username_identity_token(
        &self,
        endpoint: &ServerEndpoint,
        username: &str,
        password: &Password,
    ) -> Result<UserToken, Error> {
        // A stranger's text: quoted short and escaped wherever it is
        // logged (here, and by async-opcua with the error).
        let quoted = falc_model::ids::excerpt(username);
        // The client's address (the front's): a guesser's failures lock
        // its own address, never the name for its real user elsewhere.
        let key = self.clients.login_key();
        self.unlocked(&key, &format!("\"{quoted}\""))?;
        match self.by_name.get(username) {
            // A success forgets no failure of the address (`throttle`).
            Some(u) if !u.password.is_empty() && same_secret(&u.password, password.get()) => {
                tracing::info!(
                    user = username,
                    from = %key,
                    endpoint = %endpoint.security_policy,
                    mode = %endpoint.security_mode,
                    "OPC UA session authenticated"
                );
                Ok(UserToken(u.name.clone()))
            }
            _ => {
                let (failures, delay) = self.clients.failed_login(&key);
                falc_bus::log_limit::warn(
                    &key,
                    &format!(
                        "OPC UA login of \"{quoted}\" from {key} refused: unknown user or wrong password ({failures} failed from this address in a row; answered after {} ms{})",
                        delay.as_millis(),
                        if failures >= throttle::LOCK_AFTER { ", the address now locked" } else { "" }
                    ),
                );
                tokio::time::sleep(delay).await;
                Err(Error::new(
                    StatusCode::BadUserAccessDenied,
                    format!("cannot authenticate \"{quoted}\""),
                ))
            }
        }
    }

    async fn authenticate_x509_identity_token(
        &self,
        _endpoint: &ServerEndpoint,
        signing_thumbprint: &Thumbprint,
    ) -> Result<UserToken, Error> {
        let key = self.clients.login_key();
        self.unlocked(&key, "a user certificate")?;
        match self
            .by_certificate
            .iter()
            .find(|(t, _)| t == signing_thumbprint)
        {
            Some((_, name)) => {
                tracing::info!(
                    user = name,
                    from = %key,
                    "OPC UA session authenticated by user certificate"
                );
                Ok(UserToken(name.clone()))
            }
            None => {
                let (failures, delay) = self.clients.failed_login(&key);
                falc_bus::log_limit::warn(
                    &key,
                    &format!(
                        "OPC UA login from {key} refused: a user certificate no user of the users file has ({failures} failed from this address in a row; answered after {} ms)",
                        delay.as_millis()
                    ),
                );
                tokio::time::sleep(delay).await;
                Err(Error::new(
                    StatusCode::BadIdentityTokenRejected,
                    "unknown user certificate",
                ))
            }
        }
    }

    fn effective_user_access_level(
        &self,
        _token: &UserToken,
        user_access_level: AccessLevel,
        _node_id: &NodeId,
    ) -> AccessLevel {
        // Nothing is written through OPC UA: the cell is driven by methods.
        user_access_level & !AccessLevel::CURRENT_WRITE
    }

    fn is_user_executable(&self, token: &UserToken, method_id: &NodeId) -> bool {
        match crate::space::Method::of(method_id) {
            Some(m) => self.may(token, m.call()).is_ok(),
            // The server's own methods (GetMonitoredItems …) stay open to
            // every authenticated user.
            None => self.role(token).is_some(),
        }
    }

    fn user_token_policies(&self, endpoint: &ServerEndpoint) -> Vec<UserTokenPolicy> {
        // A password crosses a None channel encrypted with the server's key.
        let security_policy_uri = match endpoint.password_security_policy() {
            SecurityPolicy::None => UAString::from(SecurityPolicy::Basic256Sha256.to_uri()),
            _ => UAString::null(),
        };
        let mut policies = vec![UserTokenPolicy {
            policy_id: user_pass_security_policy_id(endpoint),
            token_type: UserTokenType::UserName,
            issued_token_type: UAString::null(),
            issuer_endpoint_url: UAString::null(),
            security_policy_uri,
        }];
        if !self.by_certificate.is_empty() {
            policies.push(UserTokenPolicy {
                // async-opcua's own policy id for X.509 user tokens.
                policy_id: UAString::from("x509"),
                token_type: UserTokenType::Certificate,
                issued_token_type: UAString::null(),
                issuer_endpoint_url: UAString::null(),
                // The user signs with the channel's policy (async-opcua
                // needs it named), on a None channel with Basic256Sha256.
                security_policy_uri: UAString::from(match endpoint.security_policy() {
                    SecurityPolicy::None => SecurityPolicy::Basic256Sha256.to_uri(),
                    p => p.to_uri(),
                }),
            });
        }
        policies
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn topology() -> Topology {
        Topology::parse(
            r#"
cell = "falc1"
router = "tcp/127.0.0.1:7447"
[[station]]
name = "operator"
kind = "operator"
[[console]]
name = "console"
role = "operator"
[[console]]
name = "observer"
role = "observer"
[[console]]
name = "maintainer"
role = "maintainer"
[[console]]
name = "opcua"
role = "operator"
"#,
            "test",
        )
        .expect("topology")
    }

    #[test]
    fn the_file_is_made_private_from_the_topology_capped_at_the_gateways_role() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("opcua-users.toml");
        let users = Users::ensure(&path, &topology(), "opcua", Role::Operator).expect("made");
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(&path).expect("file").permissions().mode();
        assert_eq!(mode & 0o777, 0o600);
        let names: Vec<_> = users.by_name.keys().cloned().collect();
        assert_eq!(names, ["console", "maintainer", "observer"]);
        let t = |n: &str| UserToken(n.into());
        assert_eq!(users.role(&t("maintainer")), Some(Role::Operator));
        assert_eq!(users.role(&t("opcua")), None);
        assert!(users.may(&t("console"), Call::Start).is_ok());
        let e = users.may(&t("observer"), Call::Start).expect_err("refused");
        assert!(e.contains("may not start"), "{e}");
        assert!(users.may(&t("observer"), Call::Status).is_ok());
        // Read again: the same passwords.
        let again = Users::ensure(&path, &topology(), "opcua", Role::Operator).expect("read");
        assert_eq!(
            again.by_name["console"].password,
            users.by_name["console"].password
        );
    }

    #[test]
    fn a_bad_users_file_is_refused_naming_the_problem() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("u.toml");
        let cases = [
            ("[[user]]\nname = \"a\"\nrole = \"engineer\"\npassword = \"x\"\n", "above the gateway"),
            ("[[user]]\nname = \"a\"\nrole = \"observer\"\npassword = \"\"\n", "and a password or a certificate"),
            (
                "[[user]]\nname = \"a\"\nrole = \"observer\"\npassword = \"x\"\n[[user]]\nname = \"a\"\nrole = \"observer\"\npassword = \"y\"\n",
                "listed twice",
            ),
            ("[[user]]\nname = \"a\"\nrole = \"boss\"\npassword = \"x\"\n", "unknown variant"),
        ];
        for (text, why) in cases {
            credentials::write_private(&path, text).expect("write");
            let e = Users::load(&path, Role::Operator)
                .expect_err(why)
                .to_string();
            assert!(e.contains(why) && e.contains("u.toml"), "{e}");
        }
        std::fs::write(&path, cases[1].0).expect("write");
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).expect("chmod");
        let e = Users::load(&path, Role::Operator)
            .expect_err("too open")
            .to_string();
        assert!(e.contains("private"), "{e}");
    }

    #[tokio::test]
    async fn a_user_certificate_logs_its_user_in_and_no_other() {
        let dir = tempfile::tempdir().expect("tempdir");
        let make = |name: &str| {
            let c = rcgen::generate_simple_self_signed(vec![name.to_string()]).expect("cert");
            let der = c.cert.der().to_vec();
            std::fs::write(dir.path().join(format!("{name}.der")), &der).expect("write");
            X509::from_der(&der).expect("x509").thumbprint()
        };
        let scada = make("scada");
        let stranger = make("stranger");
        let path = dir.path().join("opcua-users.toml");
        credentials::write_private(
            &path,
            "[[user]]\nname = \"scada\"\nrole = \"observer\"\ncertificate = \"scada.der\"\n",
        )
        .expect("write");
        let users = Users::load(&path, Role::Operator).expect("loaded");
        let endpoint = ServerEndpoint::new(
            "/",
            SecurityPolicy::Basic256Sha256,
            opcua::types::MessageSecurityMode::SignAndEncrypt,
            &[],
        );
        let token = users
            .authenticate_x509_identity_token(&endpoint, &scada)
            .await
            .expect("scada's certificate");
        assert_eq!(token.0, "scada");
        assert_eq!(users.role(&token), Some(Role::Observer));
        assert!(users
            .authenticate_x509_identity_token(&endpoint, &stranger)
            .await
            .is_err());
        // No password: a password login of that user fails.
        assert!(users
            .authenticate_username_identity_token(&endpoint, "scada", &Password::new(String::new()))
            .await
            .is_err());
        // A stranger's user name with a line of its own in it: refused,
        // and the refusal quotes it escaped and short.
        let forged = format!(
            "x\n2026-01-01T00:00:00Z  INFO falc_opcua: forged{}",
            "y".repeat(500)
        );
        let e = users
            .authenticate_username_identity_token(&endpoint, &forged, &Password::new("p".into()))
            .await
            .expect_err("unknown user");
        let text = format!("{e:?}");
        assert!(!text.contains('\n') && text.contains(r"x\\n2026"), "{text}");
        assert!(text.len() < 300, "{text}");
        let kinds: Vec<_> = users
            .user_token_policies(&endpoint)
            .into_iter()
            .map(|p| p.token_type)
            .collect();
        assert_eq!(kinds, [UserTokenType::UserName, UserTokenType::Certificate]);
        // A certificate file that is none is named.
        std::fs::write(dir.path().join("scada.der"), "not a certificate").expect("write");
        let e = Users::load(&path, Role::Operator)
            .expect_err("bad")
            .to_string();
        assert!(e.contains("scada.der") && e.contains("not an X.509"), "{e}");
    }

    #[test]
    fn secrets_compare_whole() {
        assert!(same_secret("abc", "abc"));
        assert!(!same_secret("abc", "abd"));
        assert!(!same_secret("abc", "abcd"));
        assert!(!same_secret("", "a"));
    }
}
