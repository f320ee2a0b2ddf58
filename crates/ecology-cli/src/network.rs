//! What every networked command shares: the options to join an ecology over
//! Zenoh, the runtime Zenoh needs, and the signals that stop a process.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use ecology_tuples::{PeisId, TupleError};
use ecology_zenoh::security::KeysDir;
use ecology_zenoh::{Security, ZenohError, ZenohOptions, ZenohPeis};

/// How to reach the ecology.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct NetArgs {
    /// Endpoint to listen on, such as tcp/127.0.0.1:7447, or quic/… with --keys (repeatable);
    /// port 0 takes a free port, which the readiness line shows.
    #[arg(long, global = true, value_name = "ENDPOINT", value_parser = listen_endpoint)]
    pub listen: Vec<String>,
    /// Endpoint of a PEIS or router to connect to, such as tcp/127.0.0.1:7447 (repeatable: it
    /// joins through whichever takes it, and a client that loses its router dials them all again).
    #[arg(long, global = true, value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// A Zenoh configuration file (JSON5); --listen and --connect override it.
    #[arg(long, global = true, value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
    /// Find peers by UDP multicast scouting (off by default).
    #[arg(long, global = true)]
    pub multicast: bool,
    /// Join as a client of the router given by --connect (all traffic through it) instead of as a peer.
    #[arg(long, global = true)]
    pub client: bool,
    /// How long joining keeps trying the --connect endpoints, in seconds (default 30): on a lossy
    /// link a session can take several attempts. After 5 s it says it is still trying.
    #[arg(long, global = true, value_name = "SECONDS")]
    pub connect_timeout: Option<f64>,
    /// Presence lease in seconds: when this process freezes or its network is cut, the others
    /// notice within this long (default 2; 5 for a process of 100 PEIS or more, which its router
    /// could otherwise drop while it is busy starting them). A PEIS joining waits this long plus
    /// 1 s for another of its name to leave (a run that just stopped) before it takes the name as
    /// taken.
    #[arg(long, global = true, value_name = "SECONDS")]
    pub lease: Option<f64>,
    /// The ecology's keys directory (made by `ecology keys`): join with this PEIS's certificate
    /// over mutual TLS, under the roster's access rules. Without it the process runs
    /// unauthenticated, and says so.
    #[arg(long, global = true, value_name = "DIR", env = "ECOLOGY_KEYS")]
    pub keys: Option<PathBuf>,
}

/// Whether this process has said that it runs unauthenticated.
static WARNED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// How long joining goes on before the process says that it is still trying.
const STILL_JOINING: Duration = Duration::from_secs(5);

/// Whether this process has said that it is still joining: said once, not for each of the PEIS of
/// `ecology peis --all`.
static SAID_STILL_JOINING: std::sync::atomic::AtomicBool =
    std::sync::atomic::AtomicBool::new(false);

impl NetArgs {
    /// The Zenoh options of PEIS `name`.
    pub fn options(&self, name: PeisId) -> anyhow::Result<ZenohOptions> {
        let mut options = ZenohOptions::new(name);
        options.listen = self.listen.clone();
        options.connect = self.connect.clone();
        options.zenoh_config = self.zenoh_config.clone();
        options.multicast_scouting = self.multicast;
        if self.client {
            options.mode = ecology_zenoh::Mode::Client;
        }
        if let Some(lease) = self.lease {
            options.peis.lease = seconds(lease, "--lease")?;
        }
        if let Some(timeout) = self.connect_timeout {
            options.connect_timeout = seconds(timeout, "--connect-timeout")?;
        }
        options.security = self.security(&options.name)?;
        options.notices = Some(ecology_zenoh::Notices(std::sync::Arc::new(|line| {
            eprintln!("{line}")
        })));
        Ok(options)
    }

    /// How `name` proves who it is: its identity in `--keys`, or nothing, said loudly on stderr.
    pub fn security(&self, name: &PeisId) -> anyhow::Result<Security> {
        match &self.keys {
            Some(dir) => {
                let keys = KeysDir::open(dir)
                    .with_context(|| format!("reading the keys in {}", dir.display()))?;
                Ok(Security::Authenticated(Box::new(keys.identity(name)?)))
            }
            // Said once a process: a process of many PEIS (`ecology peis --all`) would say it for each.
            None if WARNED.swap(true, std::sync::atomic::Ordering::Relaxed) => Ok(Security::Open),
            None => {
                eprintln!(
                    "warning: {name} runs UNAUTHENTICATED: anyone who reaches its endpoints can write \
                     any PEIS's tuples, answer for it and switch its components. Use this on one \
                     machine only; for a real ecology run `ecology keys init DIR` and pass --keys DIR."
                );
                Ok(Security::Open)
            }
        }
    }

    /// The endpoints, for a readiness line: `listening on …; connected to …`.
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        if !self.listen.is_empty() {
            parts.push(format!("listening on {}", self.listen.join(", ")));
        }
        if !self.connect.is_empty() {
            parts.push(format!("connected to {}", self.connect.join(", ")));
        }
        if parts.is_empty() {
            parts.push("no endpoints".to_string());
        }
        parts.join("; ")
    }
}

/// A `--listen` endpoint as given, except that port 0 (`tcp/127.0.0.1:0`) becomes a port free
/// now, so that the readiness line names the port others can connect to. The port is found by
/// binding it for a moment (TCP for `tcp/`, UDP for `quic/` and `udp/`); when that fails, the
/// endpoint is kept as it is and Zenoh reports the problem when it listens.
fn listen_endpoint(text: &str) -> Result<String, String> {
    Ok(with_free_port(text).unwrap_or_else(|| text.to_string()))
}

fn with_free_port(endpoint: &str) -> Option<String> {
    let (protocol, rest) = endpoint.split_once('/')?;
    let end = rest.find(['?', '#']).unwrap_or(rest.len());
    let (address, suffix) = rest.split_at(end);
    let (host, port) = address.rsplit_once(':')?;
    if port != "0" {
        return None;
    }
    let bare = host.trim_start_matches('[').trim_end_matches(']');
    let port = match protocol {
        "tcp" => std::net::TcpListener::bind((bare, 0))
            .and_then(|l| l.local_addr())
            .ok()?
            .port(),
        "quic" | "udp" => std::net::UdpSocket::bind((bare, 0))
            .and_then(|s| s.local_addr())
            .ok()?
            .port(),
        _ => return None,
    };
    Some(format!("{protocol}/{host}:{port}{suffix}"))
}

/// Whether `value` is a positive, finite number of seconds a `Duration` holds.
fn positive(value: f64) -> bool {
    value.is_finite() && value > 0.0 && value < 1e9
}

/// A positive, finite number of seconds.
pub fn seconds(value: f64, what: &str) -> anyhow::Result<Duration> {
    if positive(value) {
        Ok(Duration::from_secs_f64(value))
    } else {
        anyhow::bail!("{what} must be a positive number of seconds, not {value}")
    }
}

/// Zero, or a positive, finite number of seconds.
pub fn seconds_or_zero(value: f64, what: &str) -> anyhow::Result<Duration> {
    if value == 0.0 {
        Ok(Duration::ZERO)
    } else if positive(value) {
        Ok(Duration::from_secs_f64(value))
    } else {
        anyhow::bail!("{what} must be 0 or a positive number of seconds, not {value}")
    }
}

/// Why a process could not join.
#[derive(Debug)]
pub enum JoinFailure {
    /// Its name is taken: exit 2 (bad usage).
    NameTaken(PeisId),
    /// Its options, keys or Zenoh configuration are unusable (an unreadable keys
    /// directory, a name not in the roster, a `tcp/` endpoint with keys): exit 2.
    BadConfig(anyhow::Error),
    /// Anything else (an endpoint that cannot be opened): the error.
    Other(anyhow::Error),
}

/// Joins the ecology as `name`.
pub async fn join(name: PeisId, net: &NetArgs) -> Result<ZenohPeis, JoinFailure> {
    let options = net.options(name).map_err(JoinFailure::BadConfig)?;
    let timeout = options.connect_timeout;
    let open = ZenohPeis::open(options);
    tokio::pin!(open);
    let opened = tokio::select! {
        opened = &mut open => opened,
        () = tokio::time::sleep(STILL_JOINING), if !net.connect.is_empty() && timeout > STILL_JOINING => {
            if !SAID_STILL_JOINING.swap(true, std::sync::atomic::Ordering::Relaxed) {
                eprintln!(
                    "still joining: nothing at {} has taken the session for {}s; trying for {}s \
                     in all (--connect-timeout)",
                    net.connect.join(", "),
                    STILL_JOINING.as_secs(),
                    timeout.as_secs_f64()
                );
            }
            open.await
        }
    };
    match opened {
        Ok(peis) => Ok(peis),
        Err(ZenohError::Space(TupleError::AlreadyPresent(id))) => Err(JoinFailure::NameTaken(id)),
        Err(e @ ZenohError::Config { .. }) => Err(JoinFailure::BadConfig(
            anyhow::Error::new(e).context("joining the ecology"),
        )),
        // Zenoh's words when no endpoint took the session within the connect timeout.
        Err(e) if matches!(&e, ZenohError::Open { message } if message.contains("Unable to connect")) =>
        {
            let context = format!(
                "joining the ecology (nothing at {} took this session within {}s \
                 (--connect-timeout): is it up, and if it is a router, not full at its \
                 --max-sessions?)",
                net.connect.join(", "),
                timeout.as_secs_f64()
            );
            Err(JoinFailure::Other(anyhow::Error::new(e).context(context)))
        }
        Err(e) => Err(JoinFailure::Other(
            anyhow::Error::new(e).context("joining the ecology"),
        )),
    }
}

/// The multi-thread runtime Zenoh needs.
pub fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    ecology_zenoh::log_from_env();
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the async runtime")
}

/// How long a process takes at most to stop once asked (SIGINT or SIGTERM): it releases what it
/// holds and leaves as well as the network lets it, and exits when this runs out whatever is still
/// pending, saying what. `ECOLOGY_STOP_WITHIN` (seconds) changes it.
pub const STOP_WITHIN: Duration = Duration::from_secs(10);

/// The bound on stopping: [`STOP_WITHIN`], or `ECOLOGY_STOP_WITHIN` seconds.
pub fn stop_within() -> Duration {
    std::env::var("ECOLOGY_STOP_WITHIN")
        .ok()
        .and_then(|s| s.trim().parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s > 0.0 && *s <= 3600.0)
        .map_or(STOP_WITHIN, Duration::from_secs_f64)
}

/// What the process is doing while it stops, for the message of a stop that runs out of time.
static STOPPING: std::sync::Mutex<&'static str> = std::sync::Mutex::new("stopping");

/// Says what the process does now while it stops (`releasing what the task switched on`).
pub fn stopping(what: &'static str) {
    *STOPPING
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner) = what;
}

/// Prints where the process stands on stderr at every SIGUSR1, without stopping it: its command,
/// what it is doing (or stopping), its runtime's workers and live tasks, and its threads by name
/// and state (from `/proc/self/task`); then wakes `more`, for the part only its owner can tell
/// (the executive's state machine, timers and remote sets). Dropped, it stops listening.
#[derive(Debug)]
pub struct Reporter(tokio::task::JoinHandle<()>);

impl Drop for Reporter {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// Starts the [`Reporter`] of command `command`.
pub fn report_on_sigusr1(
    command: &'static str,
    more: Option<std::sync::Arc<tokio::sync::Notify>>,
) -> Reporter {
    use tokio::signal::unix::{SignalKind, signal};
    let asked = signal(SignalKind::user_defined1());
    Reporter(tokio::spawn(async move {
        let Ok(mut asked) = asked else { return };
        while asked.recv().await.is_some() {
            let metrics = tokio::runtime::Handle::current().metrics();
            let doing = *STOPPING
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            eprintln!(
                "== ecology {command} (pid {}), asked by SIGUSR1\nstate: {}\nruntime: {} workers, {} tasks alive\nthreads: {}",
                std::process::id(),
                if doing == "stopping" {
                    "running (not asked to stop)"
                } else {
                    doing
                },
                metrics.num_workers(),
                metrics.num_alive_tasks(),
                threads()
            );
            if let Some(more) = &more {
                more.notify_one();
            }
        }
    }))
}

/// This process's threads, counted by name and state (`R` running, `S` asleep, `D` in the kernel).
fn threads() -> String {
    let mut counted: std::collections::BTreeMap<(String, String), usize> =
        std::collections::BTreeMap::new();
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return "unknown (no /proc/self/task)".to_string();
    };
    for task in tasks.flatten() {
        let path = task.path();
        let name = std::fs::read_to_string(path.join("comm")).unwrap_or_default();
        let stat = std::fs::read_to_string(path.join("stat")).unwrap_or_default();
        // The state follows the name in parentheses, which may itself hold spaces.
        let state = stat
            .rsplit_once(") ")
            .and_then(|(_, rest)| rest.split_whitespace().next())
            .unwrap_or("?");
        *counted
            .entry((name.trim().to_string(), state.to_string()))
            .or_default() += 1;
    }
    let total: usize = counted.values().sum();
    let each: Vec<String> = counted
        .iter()
        .map(|((name, state), n)| format!("{n} {name} ({state})"))
        .collect();
    format!("{total}: {}", each.join(", "))
}

/// Completes on SIGINT or SIGTERM, with the signal's name.
///
/// The handlers are installed when this is called, not when the future is
/// first polled: from then on the signals are caught (and not lost between
/// two polls), so call it before saying that the process is ready.
///
/// Stopping is bounded, whatever the process is doing: a thread of its own waits for the first
/// SIGINT or SIGTERM, so that from then on a second one ends the process at once (the signal's
/// default action), and after [`stop_within`] it says what was still pending and exits with 1.
/// Neither needs this future to be polled: a process stuck in a wait that does not also wait for
/// it (as an executive once was, inside Zenoh, before its task began) still stops.
pub fn stop_signal() -> impl std::future::Future<Output = &'static str> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    // Set when the first signal has come: from then on these signals take their default action.
    let asked = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    for second in [SIGINT, SIGTERM] {
        let _ = signal_hook::flag::register_conditional_default(second, asked.clone());
    }
    let (told, first) = tokio::sync::oneshot::channel::<&'static str>();
    let watching = signal_hook::iterator::Signals::new([SIGINT, SIGTERM]).map(|mut signals| {
        std::thread::spawn(move || {
            let Some(signal) = signals.forever().next() else {
                return;
            };
            asked.store(true, std::sync::atomic::Ordering::SeqCst);
            let which = if signal == SIGINT {
                "SIGINT"
            } else {
                "SIGTERM"
            };
            let _ = told.send(which);
            let bound = stop_within();
            std::thread::sleep(bound);
            let what = *STOPPING
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            eprintln!(
                "error: {which}: not stopped within {:.1} s (still {what}); exiting now, \
                 without finishing",
                bound.as_secs_f64()
            );
            std::process::exit(i32::from(crate::EXIT_NO_SOLUTION));
        })
    });
    async move {
        match (watching, first.await) {
            (Ok(_), Ok(which)) => which,
            // Without a handler the default ones stay: the process still stops, only abruptly.
            _ => std::future::pending().await,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn port_zero_becomes_a_free_port() {
        let chosen = listen_endpoint("tcp/127.0.0.1:0").expect("endpoint");
        let port: u16 = chosen
            .strip_prefix("tcp/127.0.0.1:")
            .and_then(|p| p.parse().ok())
            .expect("a port");
        assert_ne!(port, 0);
        let quic = listen_endpoint("quic/127.0.0.1:0#multistream=0").expect("endpoint");
        assert!(quic.starts_with("quic/127.0.0.1:") && quic.ends_with("#multistream=0"));
        assert!(!quic.contains(":0#"), "{quic}");
        for kept in [
            "tcp/127.0.0.1:7447",
            "tcp/nowhere",
            "serial/ttyUSB0",
            "tcp/[::1]:7447",
        ] {
            assert_eq!(listen_endpoint(kept).as_deref(), Ok(kept));
        }
    }
}
