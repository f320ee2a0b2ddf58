//! How a PEIS joins an ecology over Zenoh: its name, endpoints, scouting, lease, clock and security.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use ecology_tuples::{Clock, PeisId, PeisOptions, SystemClock};
use serde_json::json;

use crate::ZenohError;
use crate::security::Identity;

/// How long a client's one dial of a router may take: TCP's first two SYNs (at 0 and 1 s) and the
/// handshake after them.
const CLIENT_OPEN_TIMEOUT: Duration = Duration::from_secs(3);

/// How a PEIS takes part in the Zenoh network.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Mode {
    /// A peer: it listens and connects to the other PEIS directly (one network).
    #[default]
    Peer,
    /// A client of a router: everything it sends and receives passes through the
    /// router it connects to (PEIS that cannot reach each other directly).
    Client,
}

/// Options of [`ZenohPeis::open`](crate::ZenohPeis::open).
#[derive(Clone, Debug)]
pub struct ZenohOptions {
    /// The PEIS to act as.
    pub name: PeisId,
    /// Peer (the default) or client of a router.
    pub mode: Mode,
    /// Remote-set policy, lease (the Zenoh transport lease, 2 s by default) and limits.
    pub peis: PeisOptions,
    /// Endpoints to listen on, such as `tcp/127.0.0.1:7447` (port 0 picks a free port).
    pub listen: Vec<String>,
    /// Endpoints of other PEIS to connect to.
    pub connect: Vec<String>,
    /// Whether to find peers by UDP multicast scouting (off unless asked for).
    pub multicast_scouting: bool,
    /// A Zenoh configuration file (JSON5) to start from; the fields above override it.
    pub zenoh_config: Option<PathBuf>,
    /// How long `get`, snapshots and remote sets wait for answers.
    pub query_timeout: Duration,
    /// How long opening keeps trying the `connect` endpoints before failing (30 s by default: on
    /// a lossy link, a TCP handshake alone can take several seconds of retransmissions).
    pub connect_timeout: Duration,
    /// The clock for timestamps and expiry.
    pub clock: Arc<dyn Clock>,
    /// Open, or authenticated with the member's certificate and the ecology's roster.
    pub security: Security,
    /// Where joining says what it waits for, a line at a time (none by default).
    pub notices: Option<Notices>,
}

/// Lines joining says to the user while it waits on something: the command line prints them on
/// stderr.
#[derive(Clone)]
pub struct Notices(pub Arc<dyn Fn(&str) + Send + Sync>);

impl std::fmt::Debug for Notices {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Notices(..)")
    }
}

impl ZenohOptions {
    /// Options for PEIS `name` with defaults: no endpoints, no multicast, 2 s lease, system clock.
    pub fn new(name: PeisId) -> Self {
        Self {
            name,
            mode: Mode::Peer,
            peis: PeisOptions::default(),
            listen: Vec::new(),
            connect: Vec::new(),
            multicast_scouting: false,
            zenoh_config: None,
            query_timeout: Duration::from_secs(2),
            connect_timeout: Duration::from_secs(30),
            clock: Arc::new(SystemClock),
            security: Security::Open,
            notices: None,
        }
    }

    /// The Zenoh configuration these options describe.
    pub(crate) fn zenoh_config(&self) -> Result<zenoh::Config, ZenohError> {
        let mut config = base_config(self.zenoh_config.as_deref())?;
        let config_ref = &mut config;
        match self.mode {
            Mode::Client => {
                insert(config_ref, "mode", json!("client"))?;
                // How long one dial of a router may take (Zenoh's default: 10 s). A client that
                // lost its router dials the routers it lists in turn, and a router whose host is
                // gone holds each round up this long; a client dials again until it is linked.
                insert(
                    config_ref,
                    "transport/unicast/open_timeout",
                    millis(CLIENT_OPEN_TIMEOUT),
                )?;
            }
            Mode::Peer if self.zenoh_config.is_none() => insert(config_ref, "mode", json!("peer"))?,
            Mode::Peer => {}
        }
        if !self.listen.is_empty() {
            insert(
                config_ref,
                "listen/endpoints",
                json!(in_order(&self.listen)),
            )?;
        }
        if !self.connect.is_empty() {
            insert(
                config_ref,
                "connect/endpoints",
                json!(in_order(&self.connect)),
            )?;
            // One try of every endpoint in turn, each bounded by Zenoh's open timeout: Zenoh 1.10,
            // given a timeout, retries the first endpoint until it runs out and never tries the
            // next, so a process whose first router was down never reached the second. Trying
            // again, until `connect_timeout`, is `relink::open`'s.
            insert(config_ref, "connect/timeout_ms", json!(0))?;
            insert(config_ref, "connect/exit_on_failure", json!(false))?;
        }
        if self.zenoh_config.is_none() || self.multicast_scouting {
            insert(
                config_ref,
                "scouting/multicast/enabled",
                json!(self.multicast_scouting),
            )?;
        }
        insert(
            config_ref,
            "transport/link/tx/lease",
            millis(self.peis.lease),
        )?;
        // Gossip tells each PEIS the endpoints of the others so the mesh completes (peers do not relay).
        // Only the PEIS with the greater Zenoh id dials, so two never dial each other at once and
        // lose both links.
        insert(
            config_ref,
            "scouting/gossip/autoconnect_strategy",
            json!({ "peer": { "to_router": "always", "to_peer": "greater-zid" } }),
        )?;
        secure(config_ref, &self.security)?;
        Ok(config)
    }
}

/// The endpoints as Zenoh is given them: a QUIC one on a single stream (`multistream=0`) unless
/// it says otherwise.
///
/// On several streams (Zenoh's default for QUIC, one per priority) a declaration and the data that
/// follows it travel apart: the first put on a new key can reach a router before the declaration
/// of that key, and the router drops it. A tuple published once (a component's one-shot output,
/// such as a gripper's `grasp`) was then lost. One stream keeps them in order.
pub(crate) fn in_order(endpoints: &[String]) -> Vec<String> {
    endpoints
        .iter()
        .map(|endpoint| {
            if !endpoint.starts_with("quic/") || endpoint.contains("multistream=") {
                return endpoint.clone();
            }
            let (locator, config) = match endpoint.split_once('#') {
                Some((locator, config)) => (locator, format!("#{config}")),
                None => (endpoint.as_str(), String::new()),
            };
            let separator = if locator.contains('?') { ';' } else { '?' };
            format!("{locator}{separator}multistream=0{config}")
        })
        .collect()
}

/// How a process proves who it is on the network.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum Security {
    /// No proof: anyone who reaches an endpoint may write anything (a quick start on one machine).
    #[default]
    Open,
    /// Mutual TLS with the member's certificate, and Zenoh's access control built from the roster.
    Authenticated(Box<Identity>),
}

/// Applies `security` to `config`, the final configuration whatever its source (the options, or a
/// `--zenoh-config` file): mutual TLS with the member's certificate on every link, and the
/// roster's access rules, over whatever the file said of them. What it cannot override without
/// guessing, it refuses, saying why:
///
/// - every endpoint, listened on or connected to, must be `quic/…` (TLS 1.3 over UDP): a `tcp/…`
///   one would carry no certificate at all, and Zenoh 1.10's `tls/` links read and write one TLS
///   stream from two tasks at once (upstream issue 2557), which drops links now and then under
///   load; its QUIC links keep the two directions apart;
/// - multicast scouting stays off: it answers anyone on the network with this process's
///   endpoints, and a secured ecology is joined by the endpoints its members are given.
pub(crate) fn secure(config: &mut zenoh::Config, security: &Security) -> Result<(), ZenohError> {
    let Security::Authenticated(identity) = security else {
        return Ok(());
    };
    let scouting = config
        .get_json("scouting/multicast/enabled")
        .ok()
        .and_then(|text| serde_json::from_str::<serde_json::Value>(&text).ok());
    if scouting == Some(json!(true)) {
        return Err(ZenohError::Config {
            what: "scouting/multicast/enabled".to_owned(),
            message: "with keys, multicast scouting stays off (it tells anyone on the network \
                      where this process listens): leave --multicast out, and set it false in \
                      a --zenoh-config file"
                .to_owned(),
        });
    }
    for endpoint in configured_endpoints(config) {
        if !endpoint.starts_with("quic/") {
            return Err(ZenohError::Config {
                what: format!("endpoint {endpoint}"),
                message: format!(
                    "with keys, every endpoint is QUIC (TLS 1.3 over UDP): write quic/{}",
                    endpoint
                        .split_once('/')
                        .map_or(endpoint.as_str(), |(_, rest)| rest)
                ),
            });
        }
    }
    let path = |p: &std::path::Path| json!(p.to_string_lossy());
    insert(
        config,
        "transport/link/tls/root_ca_certificate",
        path(&identity.ca_cert),
    )?;
    for side in ["listen", "connect"] {
        insert(
            config,
            &format!("transport/link/tls/{side}_certificate"),
            path(&identity.cert),
        )?;
        insert(
            config,
            &format!("transport/link/tls/{side}_private_key"),
            path(&identity.key),
        )?;
    }
    insert(config, "transport/link/tls/enable_mtls", json!(true))?;
    // Names are checked by the access rules against the certificate's common name, not against
    // the address dialled: PEIS are reached by IP address, and robots move between networks.
    insert(
        config,
        "transport/link/tls/verify_name_on_connect",
        json!(false),
    )?;
    insert(config, "access_control", identity.roster.access_control())
}

/// Every endpoint `config` listens on or connects to in its mode. Endpoints may be given per mode
/// (`{ router: [...], peer: [...], client: [...] }`, as Zenoh's defaults are: a router and a peer
/// listen on `tcp/[::]` unless told otherwise); only the process's own mode's count.
fn configured_endpoints(config: &zenoh::Config) -> Vec<String> {
    let json = |key: &str| {
        config
            .get_json(key)
            .ok()
            .and_then(|text| serde_json::from_str::<serde_json::Value>(&text).ok())
    };
    let mode = json("mode")
        .and_then(|m| m.as_str().map(str::to_owned))
        .unwrap_or_else(|| "peer".to_owned());
    let mut out = Vec::new();
    for key in ["listen/endpoints", "connect/endpoints"] {
        let endpoints = match json(key) {
            Some(serde_json::Value::Object(mut by_mode)) => by_mode.remove(&mode),
            other => other,
        };
        if let Some(serde_json::Value::Array(items)) = endpoints {
            out.extend(items.iter().filter_map(|v| v.as_str().map(str::to_owned)));
        }
    }
    out
}

/// The configuration in `file` (JSON5), or Zenoh's defaults.
pub(crate) fn base_config(file: Option<&std::path::Path>) -> Result<zenoh::Config, ZenohError> {
    match file {
        Some(path) => zenoh::Config::from_file(path).map_err(|e| ZenohError::Config {
            what: format!("reading {}", path.display()),
            message: e.to_string(),
        }),
        None => Ok(zenoh::Config::default()),
    }
}

/// Sets `key` to `value` in `config`.
pub(crate) fn insert(
    config: &mut zenoh::Config,
    key: &str,
    value: serde_json::Value,
) -> Result<(), ZenohError> {
    let value = value.to_string();
    config
        .insert_json5(key, &value)
        .map_err(|e| ZenohError::Config {
            what: format!("{key} = {}", value.chars().take(200).collect::<String>()),
            message: e.to_string(),
        })
}

pub(crate) fn millis(d: Duration) -> serde_json::Value {
    json!(u64::try_from(d.as_millis()).unwrap_or(u64::MAX).max(1))
}

#[cfg(test)]
mod tests {
    use super::in_order;

    #[test]
    fn quic_endpoints_keep_one_stream_unless_they_say_otherwise() {
        let given = [
            "quic/198.18.0.1:7447",
            "quic/198.18.0.1:7447?iface=eth0",
            "quic/198.18.0.1:7447#tls_close_link_on_expiration=true",
            "quic/198.18.0.1:7447?multistream=1",
            "tcp/198.18.0.1:7447",
        ]
        .map(String::from);
        assert_eq!(
            in_order(&given),
            [
                "quic/198.18.0.1:7447?multistream=0",
                "quic/198.18.0.1:7447?iface=eth0;multistream=0",
                "quic/198.18.0.1:7447?multistream=0#tls_close_link_on_expiration=true",
                "quic/198.18.0.1:7447?multistream=1",
                "tcp/198.18.0.1:7447",
            ]
        );
    }
}
