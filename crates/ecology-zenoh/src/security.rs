//! Who may write what on the network: identities, the roster, and the access rules Zenoh enforces.
//!
//! Each member of an ecology (a PEIS, the executive, a router) holds a certificate whose common
//! name is its PEIS name, signed by the ecology's own certificate authority. Every link is mutual
//! TLS, so each end knows the other's name, and Zenoh's access control, generated here from the
//! roster, lets through only what the name may do:
//!
//! - a member publishes, deletes, answers queries for, declares queryables on and is present
//!   (liveliness token) under `peis/NAME/…` only: its own tuples;
//! - any member may subscribe to and query tuples and presence;
//! - a remote set names its requester (a query to `peis/OWNER/@by/REQUESTER/KEY`), and passes
//!   only when REQUESTER is the member's own name and a grant lets it set that key of that
//!   owner: by default the executive may set `components.*.reqState`, `*.params` and `*.mi-*`;
//!   nobody else anything. So the owner knows who asked (the holder of a claim) from the key
//!   expression, and refuses the unnamed form `peis/OWNER/@set/KEY` of the open mode. The same
//!   grants let a member send that unnamed form, for an owner that reads only the earlier
//!   contract (version 1) and takes no other; such an owner keeps no claims, so who asked does
//!   not matter to it;
//! - a router is trusted to have enforced the same rules on what it forwards.
//!
//! A peer that cannot show a certificate of the ecology cannot open a link at all; one whose name
//! is not in the roster gets nothing through. `docs/security.md` has the threat model.
//!
//! A keys directory holds `ca.crt` (everyone), `ca.key` (only where members are added),
//! `NAME.crt` and `NAME.key` for each member, and the roster `ecology.toml`.

use std::fmt;
use std::path::{Path, PathBuf};

use ecology_tuples::{Key, PeisId};
use rcgen::{
    BasicConstraints, CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, IsCa,
    Issuer, KeyPair, KeyUsagePurpose,
};
use serde::{Deserialize, Serialize};
use serde_json::{Value as Json, json};

/// The roster's file name in a keys directory.
pub const ROSTER_FILE: &str = "ecology.toml";
/// The certificate authority's certificate in a keys directory.
pub const CA_CERT_FILE: &str = "ca.crt";
/// The certificate authority's private key in a keys directory.
pub const CA_KEY_FILE: &str = "ca.key";

/// Why keys could not be created or read.
#[derive(Debug, thiserror::Error)]
pub enum KeysError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// The roster file is not valid.
    #[error("{path}: {message}")]
    Roster {
        /// The roster file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The directory already holds an ecology.
    #[error("{0} already holds an ecology's keys (ca.crt); use another directory")]
    AlreadyInitialised(PathBuf),
    /// The directory cannot sign new members.
    #[error(
        "{0} has no ca.key: add members in the directory where the ecology was initialised, then copy their files"
    )]
    NoAuthority(PathBuf),
    /// The member is already in the roster.
    #[error("{name} is already a member of the ecology in {dir}")]
    AlreadyMember {
        /// The member.
        name: PeisId,
        /// The keys directory.
        dir: PathBuf,
    },
    /// The member is not in the roster, or its files are missing.
    #[error("{name} is not a member of the ecology in {dir}: {why}")]
    NotMember {
        /// The name asked for.
        name: PeisId,
        /// The keys directory.
        dir: PathBuf,
        /// What is missing.
        why: String,
    },
    /// A grant's key pattern is not valid.
    #[error(
        "invalid key pattern {pattern:?}: segments are names, `*` (one segment), `**` (any number) or a name with `*` inside (such as mi-*)"
    )]
    Pattern {
        /// The pattern.
        pattern: String,
    },
    /// Certificate generation failed.
    #[error("generating a certificate: {0}")]
    Certificate(#[from] rcgen::Error),
}

/// What a member is to the ecology.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// A PEIS: owns its tuples; remote-sets nothing unless granted.
    #[default]
    Peis,
    /// The executive: a PEIS that may also switch components on and off and wire them
    /// (remote sets of `components.*.reqState`, `*.params`, `*.mi-*` on every PEIS).
    Executive,
    /// A Zenoh router: trusted to enforce the same rules on what it forwards.
    Router,
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Role::Peis => "peis",
            Role::Executive => "executive",
            Role::Router => "router",
        })
    }
}

impl std::str::FromStr for Role {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "peis" => Ok(Role::Peis),
            "executive" => Ok(Role::Executive),
            "router" => Ok(Role::Router),
            other => Err(format!(
                "unknown role {other:?} (peis, executive or router)"
            )),
        }
    }
}

/// A member of the ecology: a name that holds a certificate.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Member {
    /// The PEIS name, also the certificate's common name.
    pub name: PeisId,
    /// What it may do besides owning its tuples.
    pub role: Role,
}

/// Keys of a PEIS that a requester may remote-set, besides what its role allows.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Grant {
    /// Who may ask.
    pub requester: PeisId,
    /// Whose keys: one PEIS, or every one (`None`).
    pub owner: Option<PeisId>,
    /// Which keys.
    pub keys: Vec<GrantPattern>,
}

/// A pattern of tuple keys in a grant: dotted segments, each a name, `*` (exactly one segment),
/// `**` (any number of segments), or a name with `*` inside it (`mi-*`: any segment starting `mi-`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GrantPattern(String);

impl GrantPattern {
    /// Checks `pattern`.
    pub fn new(pattern: &str) -> Result<Self, KeysError> {
        let valid_segment = |s: &str| {
            s == "*"
                || s == "**"
                || (!s.is_empty()
                    && !s.contains("**")
                    && s.chars()
                        .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '*'))
        };
        if pattern.is_empty() || pattern.len() > 255 || !pattern.split('.').all(valid_segment) {
            return Err(KeysError::Pattern {
                pattern: pattern.chars().take(80).collect(),
            });
        }
        Ok(Self(pattern.to_owned()))
    }

    /// The pattern as written.
    pub fn as_str(&self) -> &str {
        &self.0
    }

    /// The key expression chunks: `mi-*` becomes Zenoh's sub-chunk wildcard `mi-$*`.
    fn chunks(&self) -> String {
        self.0
            .split('.')
            .map(|s| {
                if s == "*" || s == "**" {
                    s.to_owned()
                } else {
                    s.replace('*', "$*")
                }
            })
            .collect::<Vec<_>>()
            .join("/")
    }
}

/// The key patterns the executive role may remote-set on every PEIS.
pub const EXECUTIVE_KEYS: [&str; 4] = ["components.*.reqState", "*.params", "*.mi-*", "*.mi-*.**"];

/// Who is in the ecology and who may set what: the same file on every device.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Roster {
    /// The certificate authority's name (its certificate's subject).
    pub authority: String,
    /// Every member.
    pub members: Vec<Member>,
    /// Remote sets granted beyond the roles.
    pub grants: Vec<Grant>,
}

/// The roster file, as TOML.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RosterFile {
    authority: String,
    #[serde(default)]
    member: Vec<MemberFile>,
    #[serde(default)]
    grant: Vec<GrantFile>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct MemberFile {
    name: String,
    #[serde(default)]
    role: Role,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct GrantFile {
    requester: String,
    #[serde(default = "any_owner")]
    owner: String,
    keys: Vec<String>,
}

fn any_owner() -> String {
    "*".to_owned()
}

impl Roster {
    /// The member called `name`.
    pub fn member(&self, name: &PeisId) -> Option<&Member> {
        self.members.iter().find(|m| &m.name == name)
    }

    /// Reads a roster from TOML text.
    pub fn parse(text: &str) -> Result<Self, String> {
        let file: RosterFile = toml::from_str(text).map_err(|e| e.to_string())?;
        let name = |s: &str| PeisId::new(s).map_err(|e| e.to_string());
        let mut members: Vec<Member> = Vec::new();
        for m in file.member {
            let member = Member {
                name: name(&m.name)?,
                role: m.role,
            };
            if members.iter().any(|x| x.name == member.name) {
                return Err(format!("{} is listed twice", member.name));
            }
            members.push(member);
        }
        let mut grants = Vec::new();
        for g in file.grant {
            let owner = match g.owner.as_str() {
                "*" => None,
                owner => Some(name(owner)?),
            };
            let keys = g
                .keys
                .iter()
                .map(|k| GrantPattern::new(k).map_err(|e| e.to_string()))
                .collect::<Result<Vec<_>, _>>()?;
            grants.push(Grant {
                requester: name(&g.requester)?,
                owner,
                keys,
            });
        }
        Ok(Self {
            authority: file.authority,
            members,
            grants,
        })
    }

    /// The roster as TOML text.
    pub fn to_toml(&self) -> String {
        let file = RosterFile {
            authority: self.authority.clone(),
            member: self
                .members
                .iter()
                .map(|m| MemberFile {
                    name: m.name.to_string(),
                    role: m.role,
                })
                .collect(),
            grant: self
                .grants
                .iter()
                .map(|g| GrantFile {
                    requester: g.requester.to_string(),
                    owner: g.owner.as_ref().map_or_else(any_owner, PeisId::to_string),
                    keys: g.keys.iter().map(|k| k.0.clone()).collect(),
                })
                .collect(),
        };
        let body = toml::to_string(&file).unwrap_or_default();
        format!(
            "# The members of this ecology and what each may do; the same file on every device.\n\
             # Written by `ecology keys`; roles: peis, executive, router.\n{body}"
        )
    }

    /// Whether `requester` may remote-set `key` of `owner` under this roster.
    ///
    /// The decision Zenoh's access control takes from [`Roster::access_control`], stated on its own
    /// so the rules can be read and tested without a network.
    pub fn permits_remote_set(&self, requester: &PeisId, owner: &PeisId, key: &Key) -> bool {
        let Some(member) = self.member(requester) else {
            return false;
        };
        let matches = |pattern: &str| segments_match(pattern.split('.'), key.segments());
        (member.role == Role::Executive && EXECUTIVE_KEYS.iter().any(|p| matches(p)))
            || self.grants.iter().any(|g| {
                &g.requester == requester
                    && g.owner.as_ref().is_none_or(|o| o == owner)
                    && g.keys.iter().any(|k| matches(k.as_str()))
            })
    }

    /// Zenoh's `access_control` configuration for this roster.
    pub fn access_control(&self) -> Json {
        // A remote set of `key` by `name`, in both forms: named (`@by/NAME`), and unnamed (`@set`)
        // for an owner that reads only the earlier contract (version 1), which takes no other.
        // An owner of today refuses the unnamed form itself, and it announced that it reads
        // version 2, so no writer of today sends it there.
        fn requests(owner: &str, name: &str, key: &GrantPattern) -> [String; 2] {
            [
                format!("peis/{owner}/@by/{name}/{}", key.chunks()),
                format!("peis/{owner}/@set/{}", key.chunks()),
            ]
        }
        const ALL: [&str; 9] = [
            "put",
            "delete",
            "declare_subscriber",
            "query",
            "declare_queryable",
            "reply",
            "liveliness_token",
            "declare_liveliness_subscriber",
            "liveliness_query",
        ];
        // `**` does not cover chunks that start with `@`, so the verbatim ones are listed.
        // The routers that hold the contract say so at `@ecology/holds-contract/ZID` (and
        // `…/ZID/routed`), and answer questions asked under `@ecology/held/`.
        let everything = json!([
            "**",
            "peis/*/@set/**",
            "peis/*/@by/**",
            "peis/*/@alive",
            "@ecology/holds-contract/**",
            "@ecology/held/**"
        ]);
        let mut rules = vec![
            json!({"id": "read", "messages": ["declare_subscriber", "query",
                    "declare_liveliness_subscriber", "liveliness_query"],
                   "flows": ["ingress"], "permission": "allow",
                   "key_exprs": ["peis/**", "peis/*/@alive", "@ecology/holds-contract/**",
                                 "@ecology/held/**"]}),
            json!({"id": "send", "messages": ALL, "flows": ["egress"], "permission": "allow",
                   "key_exprs": everything}),
            json!({"id": "relay", "messages": ALL, "flows": ["ingress"], "permission": "allow",
                   "key_exprs": everything}),
        ];
        let mut subjects = Vec::new();
        let mut policies = Vec::new();
        for member in &self.members {
            let name = member.name.as_str();
            rules.push(json!({
                "id": format!("own-{name}"),
                "messages": ["put", "delete", "reply", "declare_queryable", "liveliness_token"],
                "flows": ["ingress"], "permission": "allow",
                "key_exprs": [format!("peis/{name}/**"), format!("peis/{name}/@set/**"),
                              format!("peis/{name}/@by/**"), format!("peis/{name}/@alive")],
            }));
            subjects.push(json!({"id": format!("member-{name}"), "cert_common_names": [name]}));
            let mut own_rules = vec![json!(format!("own-{name}")), json!("read"), json!("send")];
            match member.role {
                Role::Peis => {}
                // A remote set names its requester (`@by/NAME`), and a member may name only itself.
                Role::Executive => {
                    let id = format!("executive-{name}");
                    rules.push(json!({
                        "id": id, "messages": ["query"], "flows": ["ingress"],
                        "permission": "allow",
                        "key_exprs": EXECUTIVE_KEYS.iter()
                            .flat_map(|k| requests("*", name, &GrantPattern(k.to_string())))
                            .collect::<Vec<_>>(),
                    }));
                    own_rules.push(json!(id));
                }
                Role::Router => own_rules.push(json!("relay")),
            }
            for (i, grant) in self.grants.iter().enumerate() {
                if grant.requester != member.name {
                    continue;
                }
                let owner = grant.owner.as_ref().map_or("*", PeisId::as_str);
                let id = format!("grant-{i}");
                rules.push(json!({
                    "id": id, "messages": ["query"], "flows": ["ingress"], "permission": "allow",
                    "key_exprs": grant.keys.iter()
                        .flat_map(|k| requests(owner, name, k))
                        .collect::<Vec<_>>(),
                }));
                own_rules.push(json!(id));
            }
            policies.push(json!({"rules": own_rules, "subjects": [format!("member-{name}")]}));
        }
        json!({
            "enabled": true,
            "default_permission": "deny",
            "rules": rules,
            "subjects": subjects,
            "policies": policies,
        })
    }
}

/// Whether key segments match pattern segments (`*` one, `**` any number, `x*y` within one).
fn segments_match<'a, 'b>(
    pattern: impl Iterator<Item = &'a str> + Clone,
    key: impl Iterator<Item = &'b str> + Clone,
) -> bool {
    let pattern: Vec<&str> = pattern.collect();
    let key: Vec<&str> = key.collect();
    fn go(p: &[&str], k: &[&str]) -> bool {
        match p.split_first() {
            None => k.is_empty(),
            Some((&"**", rest)) => (0..=k.len()).any(|i| go(rest, &k[i..])),
            Some((first, rest)) => k
                .split_first()
                .is_some_and(|(head, tail)| chunk_matches(first, head) && go(rest, tail)),
        }
    }
    go(&pattern, &key)
}

/// Whether one key segment matches one pattern segment, where `*` stands for any characters.
fn chunk_matches(pattern: &str, segment: &str) -> bool {
    let parts: Vec<&str> = pattern.split('*').collect();
    if parts.len() == 1 {
        return pattern == segment;
    }
    let (first, last) = (parts[0], parts[parts.len() - 1]);
    if !segment.starts_with(first) || segment.len() < first.len() + last.len() {
        return false;
    }
    let mut rest = &segment[first.len()..segment.len() - last.len()];
    if !segment.ends_with(last) {
        return false;
    }
    for middle in &parts[1..parts.len() - 1] {
        match rest.find(middle) {
            Some(at) => rest = &rest[at + middle.len()..],
            None => return false,
        }
    }
    true
}

/// A keys directory: the ecology's authority, the members' certificates and the roster.
#[derive(Clone, Debug)]
pub struct KeysDir {
    dir: PathBuf,
    roster: Roster,
}

/// What one member needs to join: its certificate and key, the authority's certificate, the roster.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Identity {
    /// The member's name.
    pub name: PeisId,
    /// The authority's certificate (PEM).
    pub ca_cert: PathBuf,
    /// The member's certificate (PEM).
    pub cert: PathBuf,
    /// The member's private key (PEM, PKCS#8).
    pub key: PathBuf,
    /// Who is who.
    pub roster: Roster,
}

impl KeysDir {
    /// Creates a new ecology in `dir`: a certificate authority and an empty roster.
    pub fn init(dir: &Path) -> Result<Self, KeysError> {
        if dir.join(CA_CERT_FILE).exists() {
            return Err(KeysError::AlreadyInitialised(dir.to_owned()));
        }
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let key = KeyPair::generate()?;
        // A name of its own, so the certificates of two ecologies never look alike.
        let authority = format!("ecology authority {}", hex(&key.public_key_raw()[1..9]));
        let cert = authority_params(&authority).self_signed(&key)?;
        write(&dir.join(CA_CERT_FILE), &cert.pem(), false)?;
        write(&dir.join(CA_KEY_FILE), &key.serialize_pem(), true)?;
        let keys = Self {
            dir: dir.to_owned(),
            roster: Roster {
                authority,
                members: Vec::new(),
                grants: Vec::new(),
            },
        };
        keys.save()?;
        Ok(keys)
    }

    /// Opens the keys directory `dir`.
    pub fn open(dir: &Path) -> Result<Self, KeysError> {
        let path = dir.join(ROSTER_FILE);
        let text = std::fs::read_to_string(&path).map_err(io(&path))?;
        let roster = Roster::parse(&text).map_err(|message| KeysError::Roster {
            path: path.clone(),
            message,
        })?;
        Ok(Self {
            dir: dir.to_owned(),
            roster,
        })
    }

    /// The directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The roster.
    pub fn roster(&self) -> &Roster {
        &self.roster
    }

    /// Adds member `name` with `role`: signs its certificate and lists it in the roster.
    pub fn add(&mut self, name: PeisId, role: Role) -> Result<(), KeysError> {
        if self.roster.member(&name).is_some() {
            return Err(KeysError::AlreadyMember {
                name,
                dir: self.dir.clone(),
            });
        }
        let authority_key = self.authority_key()?;
        let issuer = Issuer::new(authority_params(&self.roster.authority), authority_key);
        let key = KeyPair::generate()?;
        let mut params = CertificateParams::new(vec![name.to_string()])?;
        params.distinguished_name = DistinguishedName::new();
        params
            .distinguished_name
            .push(DnType::CommonName, name.as_str());
        params.extended_key_usages = vec![
            ExtendedKeyUsagePurpose::ServerAuth,
            ExtendedKeyUsagePurpose::ClientAuth,
        ];
        params.key_usages = vec![KeyUsagePurpose::DigitalSignature];
        let cert = params.signed_by(&key, &issuer)?;
        write(&self.dir.join(format!("{name}.crt")), &cert.pem(), false)?;
        write(
            &self.dir.join(format!("{name}.key")),
            &key.serialize_pem(),
            true,
        )?;
        self.roster.members.push(Member { name, role });
        self.save()
    }

    /// Lets `requester` remote-set `keys` of `owner` (every PEIS when `None`).
    pub fn grant(
        &mut self,
        requester: PeisId,
        owner: Option<PeisId>,
        keys: Vec<GrantPattern>,
    ) -> Result<(), KeysError> {
        self.roster.grants.push(Grant {
            requester,
            owner,
            keys,
        });
        self.save()
    }

    /// What member `name` needs to join.
    pub fn identity(&self, name: &PeisId) -> Result<Identity, KeysError> {
        let not_member = |why: String| KeysError::NotMember {
            name: name.clone(),
            dir: self.dir.clone(),
            why,
        };
        if self.roster.member(name).is_none() {
            return Err(not_member(format!(
                "not in {ROSTER_FILE} (add it with `ecology keys add {} {name}`)",
                self.dir.display()
            )));
        }
        let identity = Identity {
            name: name.clone(),
            ca_cert: self.dir.join(CA_CERT_FILE),
            cert: self.dir.join(format!("{name}.crt")),
            key: self.dir.join(format!("{name}.key")),
            roster: self.roster.clone(),
        };
        for file in [&identity.ca_cert, &identity.cert, &identity.key] {
            if !file.is_file() {
                return Err(not_member(format!("{} is missing", file.display())));
            }
        }
        Ok(identity)
    }

    fn authority_key(&self) -> Result<KeyPair, KeysError> {
        let path = self.dir.join(CA_KEY_FILE);
        let pem = match std::fs::read_to_string(&path) {
            Ok(pem) => pem,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(KeysError::NoAuthority(self.dir.clone()));
            }
            Err(e) => return Err(io(&path)(e)),
        };
        Ok(KeyPair::from_pem(&pem)?)
    }

    fn save(&self) -> Result<(), KeysError> {
        write(&self.dir.join(ROSTER_FILE), &self.roster.to_toml(), false)
    }
}

fn authority_params(authority: &str) -> CertificateParams {
    let mut params = CertificateParams::default();
    params.distinguished_name = DistinguishedName::new();
    params
        .distinguished_name
        .push(DnType::CommonName, authority);
    params.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
    params.key_usages = vec![
        KeyUsagePurpose::KeyCertSign,
        KeyUsagePurpose::CrlSign,
        KeyUsagePurpose::DigitalSignature,
    ];
    params
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> KeysError + '_ {
    move |source| KeysError::Io {
        path: path.to_owned(),
        source,
    }
}

/// Writes `text` to `path`; a secret is readable by its owner only.
fn write(path: &Path, text: &str, secret: bool) -> Result<(), KeysError> {
    use std::io::Write;
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create(true).truncate(true);
    #[cfg(unix)]
    if secret {
        use std::os::unix::fs::OpenOptionsExt;
        options.mode(0o600);
    }
    let mut file = options.open(path).map_err(io(path))?;
    file.write_all(text.as_bytes()).map_err(io(path))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn peis(name: &str) -> PeisId {
        PeisId::new(name).expect("valid name")
    }

    fn key(k: &str) -> Key {
        Key::new(k).expect("valid key")
    }

    fn roster() -> Roster {
        Roster {
            authority: "test authority".to_owned(),
            members: vec![
                Member {
                    name: peis("hsm"),
                    role: Role::Peis,
                },
                Member {
                    name: peis("executive"),
                    role: Role::Executive,
                },
                Member {
                    name: peis("launcher"),
                    role: Role::Peis,
                },
            ],
            grants: vec![Grant {
                requester: peis("launcher"),
                owner: Some(peis("hsm")),
                keys: vec![GrantPattern::new("*.fault").expect("valid pattern")],
            }],
        }
    }

    #[test]
    fn only_granted_requesters_may_set_keys() {
        let roster = roster();
        let (hsm, executive, launcher) = (peis("hsm"), peis("executive"), peis("launcher"));
        let may =
            |who: &PeisId, owner: &PeisId, k: &str| roster.permits_remote_set(who, owner, &key(k));
        assert!(may(&executive, &hsm, "components.ca1.reqState"));
        assert!(may(&executive, &hsm, "tr1.params"));
        assert!(may(&executive, &hsm, "tr1.mi-image"));
        assert!(may(&executive, &hsm, "tr1.mi-image.hsm.x"));
        assert!(!may(&executive, &hsm, "components.ca1.cost"));
        assert!(!may(&executive, &hsm, "tr1.fault"));
        assert!(!may(&executive, &hsm, "tr1.params.x"));
        assert!(may(&launcher, &hsm, "ca1.fault"));
        assert!(!may(&launcher, &executive, "ca1.fault"));
        assert!(!may(&launcher, &hsm, "tr1.params"));
        assert!(!may(&hsm, &hsm, "tr1.params"));
        assert!(!may(&peis("mallory"), &hsm, "tr1.params"));
    }

    #[test]
    fn grant_patterns_become_key_expressions() {
        let chunks = |p: &str| GrantPattern::new(p).expect("valid").chunks();
        assert_eq!(chunks("components.*.reqState"), "components/*/reqState");
        assert_eq!(chunks("*.mi-*.**"), "*/mi-$*/**");
        for bad in ["", "a..b", "a.***", "a b", "a.$x", "a/b"] {
            assert!(GrantPattern::new(bad).is_err(), "{bad:?} accepted");
        }
        assert!(chunk_matches("mi-*", "mi-image"));
        assert!(chunk_matches("mi-*", "mi-"));
        assert!(!chunk_matches("mi-*", "params"));
        assert!(chunk_matches("a*b*c", "axxbyyc"));
        assert!(!chunk_matches("a*b*c", "axxc"));
    }

    #[test]
    fn the_roster_round_trips_and_bad_rosters_are_refused() {
        let roster = roster();
        assert_eq!(Roster::parse(&roster.to_toml()), Ok(roster));
        let twice = "authority = \"a\"\n[[member]]\nname = \"x\"\n[[member]]\nname = \"x\"\n";
        assert_eq!(Roster::parse(twice), Err("x is listed twice".to_owned()));
        let bad_role = "authority = \"a\"\n[[member]]\nname = \"x\"\nrole = \"king\"\n";
        assert!(Roster::parse(bad_role).is_err());
        let bad_name = "authority = \"a\"\n[[member]]\nname = \"x/y\"\n";
        assert!(Roster::parse(bad_name).is_err());
    }

    #[test]
    fn the_access_rules_give_each_member_its_own_subtree() {
        let acl = roster().access_control();
        let rule = |id: &str| {
            acl["rules"]
                .as_array()
                .and_then(|rules| rules.iter().find(|r| r["id"] == id))
                .cloned()
                .unwrap_or(Json::Null)
        };
        assert_eq!(
            rule("own-hsm")["key_exprs"],
            json!([
                "peis/hsm/**",
                "peis/hsm/@set/**",
                "peis/hsm/@by/**",
                "peis/hsm/@alive"
            ])
        );
        // A grant in both forms: named, and unnamed for an owner of the earlier contract.
        assert_eq!(
            rule("grant-0")["key_exprs"],
            json!(["peis/hsm/@by/launcher/*/fault", "peis/hsm/@set/*/fault"])
        );
        // An executive sets the contract's keys of every PEIS, naming only itself.
        let executive = &rule("executive-executive")["key_exprs"];
        assert_eq!(
            executive[0],
            json!("peis/*/@by/executive/components/*/reqState")
        );
        assert_eq!(executive[1], json!("peis/*/@set/components/*/reqState"));
        let named = executive.as_array().into_iter().flatten();
        assert!(
            named
                .filter_map(Json::as_str)
                .all(|k| k.starts_with("peis/*/@by/executive/") || k.starts_with("peis/*/@set/")),
            "{executive}"
        );
        let policy = |subject: &str| {
            acl["policies"]
                .as_array()
                .and_then(|p| p.iter().find(|p| p["subjects"][0] == subject))
                .map(|p| p["rules"].clone())
                .unwrap_or(Json::Null)
        };
        assert_eq!(
            policy("member-executive"),
            json!(["own-executive", "read", "send", "executive-executive"])
        );
        assert_eq!(
            policy("member-launcher"),
            json!(["own-launcher", "read", "send", "grant-0"])
        );
        assert_eq!(acl["default_permission"], "deny");
    }

    #[test]
    fn a_keys_directory_signs_members_and_names_what_is_missing() {
        let dir = std::env::temp_dir().join(format!("ecology-keys-test-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut keys = KeysDir::init(&dir).expect("init");
        assert!(matches!(
            KeysDir::init(&dir),
            Err(KeysError::AlreadyInitialised(_))
        ));
        keys.add(peis("astrid"), Role::Peis).expect("add astrid");
        assert!(matches!(
            keys.add(peis("astrid"), Role::Peis),
            Err(KeysError::AlreadyMember { .. })
        ));
        let reopened = KeysDir::open(&dir).expect("open");
        assert_eq!(reopened.roster(), keys.roster());
        let identity = reopened.identity(&peis("astrid")).expect("identity");
        assert!(
            std::fs::read_to_string(&identity.cert)
                .expect("cert")
                .starts_with("-----BEGIN CERTIFICATE-----")
        );
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&identity.key)
                .expect("key")
                .permissions()
                .mode();
            assert_eq!(mode & 0o077, 0, "the private key is readable by others");
        }
        assert!(matches!(
            reopened.identity(&peis("hsm")),
            Err(KeysError::NotMember { .. })
        ));
        std::fs::remove_file(dir.join(CA_KEY_FILE)).expect("remove ca.key");
        let mut copy = KeysDir::open(&dir).expect("open");
        assert!(matches!(
            copy.add(peis("hsm"), Role::Peis),
            Err(KeysError::NoAuthority(_))
        ));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
