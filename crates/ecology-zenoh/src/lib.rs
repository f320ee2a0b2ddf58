//! The Ecology tuple space over Eclipse Zenoh: the only crate of the workspace that imports zenoh.
//!
//! [`ZenohPeis`] implements [`ecology_tuples::TupleSpace`] with the mapping of DESIGN.md section 5:
//! tuple (OWNER, `a.b.c`) is the key expression `peis/OWNER/a/b/c`, its metadata rides in the
//! sample attachment ([`wire`] documents the bytes), each PEIS answers `get` for its own subtree
//! with a queryable, remote sets are queries to `peis/OWNER/@set/KEY` that the owner applies,
//! and presence is the liveliness token `peis/OWNER/@alive`, whose lease is the transport lease.

mod cache;
mod config;
mod peis;
mod relink;
mod router;
pub mod security;
pub mod wire;

pub use config::{Mode, Notices, Security, ZenohOptions};
pub use peis::ZenohPeis;
pub use router::{Closed, DEFAULT_MAX_SESSIONS, RouterOptions, run_router};

use ecology_tuples::TupleError;

/// Sends Zenoh's own log to stderr when the `RUST_LOG` environment variable asks for it (such as
/// `RUST_LOG=zenoh_transport=debug`); does nothing otherwise. Never to stdout, which carries a
/// command's output (JSON lines, tables).
pub fn log_from_env() {
    let Ok(filter) = tracing_subscriber::EnvFilter::try_from_default_env() else {
        return;
    };
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}

/// Zenoh's receive runtime as an Ecology process sets it: `ZENOH_RUNTIME`'s value when the
/// environment does not give one.
const RUNTIME: &str = "(rx: (worker_threads: 16))";

/// Gives Zenoh's receive runtime 16 threads instead of 2, unless `ZENOH_RUNTIME` already says.
///
/// When a link is lost (a cable, a partition, a router), Zenoh 1.10 closes its TCP socket from a
/// receive thread, and the socket lingers up to 10 s in `close()`: with two threads, losing three
/// PEIS at once delays the third's departure by those 10 s. With 16, that many can close at once.
/// Zenoh reads the variable once, when it first starts a runtime.
///
/// # Safety
///
/// It sets an environment variable: call it before any other thread runs (first thing in `main`,
/// before a tokio runtime is built).
#[allow(unsafe_code)]
pub unsafe fn set_runtime_threads() {
    if std::env::var_os("ZENOH_RUNTIME").is_none() {
        // SAFETY: the caller guarantees no other thread runs, so none reads the environment now.
        unsafe { std::env::set_var("ZENOH_RUNTIME", RUNTIME) };
    }
}

/// Why a PEIS could not join an ecology over Zenoh.
#[derive(Debug, thiserror::Error)]
pub enum ZenohError {
    /// The Zenoh configuration (file or option) is invalid.
    #[error("invalid zenoh configuration ({what}): {message}")]
    Config {
        /// Which file or setting.
        what: String,
        /// Zenoh's message.
        message: String,
    },
    /// The session could not be opened (an endpoint could not be listened on or connected to).
    #[error("cannot open the zenoh session: {message}")]
    Open {
        /// Zenoh's message.
        message: String,
    },
    /// Whether another PEIS holds the name could not be told: the presence queries went
    /// unanswered (a router still busy with many PEIS joining, say).
    #[error(
        "could not tell whether the name {name} is free: {message}; a router still taking in \
         many PEIS joining answers late, so try again shortly"
    )]
    NameUnknown {
        /// The name asked after.
        name: String,
        /// What the queries got instead of an answer.
        message: String,
    },
    /// The tuple space refused the PEIS (for example, its name is taken).
    #[error(transparent)]
    Space(#[from] TupleError),
}
