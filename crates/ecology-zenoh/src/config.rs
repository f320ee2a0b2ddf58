//! How a PEIS joins an ecology over Zenoh: its name, endpoints, scouting, lease and clock.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use ecology_tuples::{Clock, PeisId, PeisOptions, SystemClock};

use crate::ZenohError;

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
    /// How long opening waits for the `connect` endpoints before failing.
    pub connect_timeout: Duration,
    /// The clock for timestamps and expiry.
    pub clock: Arc<dyn Clock>,
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
            connect_timeout: Duration::from_secs(5),
            clock: Arc::new(SystemClock),
        }
    }

    /// The Zenoh configuration these options describe.
    pub(crate) fn zenoh_config(&self) -> Result<zenoh::Config, ZenohError> {
        let mut config = base_config(self.zenoh_config.as_deref())?;
        let mut insert = |key: &str, value: String| insert(&mut config, key, value);
        match self.mode {
            Mode::Client => insert("mode", json_string("client"))?,
            Mode::Peer if self.zenoh_config.is_none() => insert("mode", json_string("peer"))?,
            Mode::Peer => {}
        }
        if !self.listen.is_empty() {
            insert("listen/endpoints", json_array(&self.listen))?;
        }
        if !self.connect.is_empty() {
            insert("connect/endpoints", json_array(&self.connect))?;
            insert("connect/timeout_ms", millis(self.connect_timeout))?;
            insert("connect/exit_on_failure", "true".to_owned())?;
        }
        if self.zenoh_config.is_none() || self.multicast_scouting {
            insert(
                "scouting/multicast/enabled",
                self.multicast_scouting.to_string(),
            )?;
        }
        insert("transport/link/tx/lease", millis(self.peis.lease))?;
        // Gossip tells each PEIS the endpoints of the others so the mesh completes (peers do not relay).
        // Only the PEIS with the greater Zenoh id dials, so two never dial each other at once and
        // lose both links.
        insert(
            "scouting/gossip/autoconnect_strategy",
            r#"{ peer: { to_router: "always", to_peer: "greater-zid" } }"#.to_owned(),
        )?;
        Ok(config)
    }
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

/// Sets `key` to the JSON5 `value` in `config`.
pub(crate) fn insert(
    config: &mut zenoh::Config,
    key: &str,
    value: String,
) -> Result<(), ZenohError> {
    config
        .insert_json5(key, &value)
        .map_err(|e| ZenohError::Config {
            what: format!("{key} = {value}"),
            message: e.to_string(),
        })
}

pub(crate) fn millis(d: Duration) -> String {
    d.as_millis().max(1).to_string()
}

pub(crate) fn json_string(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if c.is_control() => out.push_str(&format!("\\u{:04x}", u32::from(c))),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

pub(crate) fn json_array(items: &[String]) -> String {
    let items: Vec<String> = items.iter().map(|s| json_string(s)).collect();
    format!("[{}]", items.join(","))
}
