//! A Zenoh router for PEIS that cannot reach each other directly (other
//! subnets, NAT, a robot on Wi-Fi that only reaches a base station): each
//! PEIS connects to the router, which routes tuples, queries and presence
//! between them. It is Zenoh in router mode; it is no PEIS. It holds the
//! component contract of every PEIS (not their outputs) and answers the
//! queries that cover it, so that asking all PEIS is one round trip to it.

use std::future::Future;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use serde_json::json;
use zenoh::sample::SampleKind;

use crate::ZenohError;
use crate::config::{Security, base_config, in_order, insert, millis, secure};

/// Options of [`run_router`].
#[derive(Clone, Debug)]
pub struct RouterOptions {
    /// Endpoints to listen on, such as `tcp/0.0.0.0:7447`.
    pub listen: Vec<String>,
    /// Other routers to connect to.
    pub connect: Vec<String>,
    /// Whether to answer UDP multicast scouting (off unless asked for).
    pub multicast_scouting: bool,
    /// A Zenoh configuration file (JSON5) to start from; the fields above override it.
    pub zenoh_config: Option<PathBuf>,
    /// The transport lease: how long a silent PEIS stays connected.
    pub lease: Duration,
    /// Open, or authenticated as a member with the router role.
    pub security: Security,
    /// How many sessions (PEIS, other routers) it holds at once; past that it refuses new ones.
    pub max_sessions: usize,
    /// Whether it holds the component contract of every PEIS and answers queries on it
    /// (see the module `cache`): on by default.
    pub hold_contract: bool,
    /// How long a router told to stop waits for its sessions to close before it stops without
    /// them: with a thousand PEIS that left at once, Zenoh was still taking their declarations
    /// back after 10 s. Its PEIS see the connection end either way.
    pub close_within: Duration,
}

/// How a router's stop ended (see [`run_router`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Closed {
    /// Its sessions were closed.
    Cleanly,
    /// They were still closing after [`RouterOptions::close_within`]; it stopped without them.
    CutShort,
}

/// [`RouterOptions::max_sessions`] by default: room for a building of PEIS, each its own session
/// (Zenoh's own default, 1,000, refused the executive of a home of a thousand PEIS).
pub const DEFAULT_MAX_SESSIONS: usize = 10_000;

impl Default for RouterOptions {
    fn default() -> Self {
        Self {
            listen: Vec::new(),
            connect: Vec::new(),
            multicast_scouting: false,
            zenoh_config: None,
            lease: Duration::from_secs(2),
            security: Security::Open,
            max_sessions: DEFAULT_MAX_SESSIONS,
            hold_contract: true,
            close_within: Duration::from_secs(2),
        }
    }
}

/// Runs a Zenoh router until `shutdown` completes. `ready` is called once it
/// listens, with its Zenoh id; `full` each time it comes to hold
/// [`RouterOptions::max_sessions`] sessions, with that number: from then on, until one leaves,
/// a PEIS that connects is refused (and sees only that it could not connect). Once `shutdown`
/// completes, it closes its sessions, waiting for them at most [`RouterOptions::close_within`]
/// (given none, it stops without them).
pub async fn run_router(
    options: RouterOptions,
    ready: impl FnOnce(String),
    full: impl Fn(usize) + Send + Sync + 'static,
    shutdown: impl Future<Output = ()>,
) -> Result<Closed, ZenohError> {
    let mut config = base_config(options.zenoh_config.as_deref())?;
    let c = &mut config;
    insert(c, "mode", json!("router"))?;
    if !options.listen.is_empty() {
        insert(c, "listen/endpoints", json!(in_order(&options.listen)))?;
    }
    if !options.connect.is_empty() {
        insert(c, "connect/endpoints", json!(in_order(&options.connect)))?;
    }
    insert(
        c,
        "scouting/multicast/enabled",
        json!(options.multicast_scouting),
    )?;
    insert(c, "transport/link/tx/lease", millis(options.lease))?;
    insert(
        c,
        "transport/unicast/max_sessions",
        json!(options.max_sessions),
    )?;
    secure(c, &options.security)?;
    let session = zenoh::open(config).await.map_err(|e| ZenohError::Open {
        message: e.to_string(),
    })?;
    let max = options.max_sessions;
    let held = AtomicUsize::new(0);
    let _sessions = session
        .info()
        .transport_events_listener()
        .history(true)
        .callback(move |event| {
            if event.transport().is_multicast() {
                return;
            }
            if event.kind() == SampleKind::Put {
                if held.fetch_add(1, Ordering::Relaxed) + 1 == max {
                    full(max);
                }
            } else {
                held.fetch_sub(1, Ordering::Relaxed);
            }
        })
        .await
        .map_err(|e| ZenohError::Open {
            message: e.to_string(),
        })?;
    let _held = match options.hold_contract {
        true => Some(
            crate::cache::start(&session)
                .await
                .map_err(|e| ZenohError::Open {
                    message: e.to_string(),
                })?,
        ),
        false => None,
    };
    ready(session.zid().to_string());
    shutdown.await;
    // Given no time, it does not start a close it will not wait for (a close of one idle session
    // sometimes ended within Zenoh's zero timeout, and sometimes not).
    let cleanly = !options.close_within.is_zero()
        && session.close().timeout(options.close_within).await.is_ok();
    if cleanly {
        return Ok(Closed::Cleanly);
    }
    // Its drop would wait for the close again: the process ends without it.
    std::mem::forget(session);
    Ok(Closed::CutShort)
}
