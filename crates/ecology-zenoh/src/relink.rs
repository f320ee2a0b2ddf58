//! Links lost on one side only, dialled again.
//!
//! Peers meet through gossip: a PEIS dials a peer it hears of only when it holds no link to it,
//! and hears of it once, when it links to a neighbour. When a partition heals before this side's
//! lease on a link ran out (the other side, with a shorter lease, has already dropped it), this
//! side still holds its half when gossip names the other; it does not dial, and learns a moment
//! later, from a reset, that the link is dead. Nothing names the other again, so the two would not
//! meet until something else changed. Hence: a link this session dialled and lost is dialled
//! again, soon and then a few times over a few seconds, until a link to that peer is back.
//! A link the other side dialled is theirs to dial again.

use std::time::Duration;

use tokio::sync::{mpsc, watch};
use zenoh::Session;
use zenoh::config::{Locator, ZenohId};
use zenoh::internal::runtime::{Runtime, RuntimeBuilder};
use zenoh::sample::SampleKind;
use zenoh::session::LinkEventsListener;

use crate::peis::AbortOnDrop;
use crate::{Mode, ZenohError, ZenohOptions};

/// Pauses before each new dial of a lost link (4.35 s in all): the first is short, as the link
/// usually died of a reset on a path that is back (the pause lets its transport go first).
const PAUSES: [Duration; 5] = [
    Duration::from_millis(100),
    Duration::from_millis(250),
    Duration::from_millis(500),
    Duration::from_secs(1),
    Duration::from_millis(2500),
];

/// The first pause between two tries at joining; each later one is twice as long, up to
/// [`JOIN_PAUSE_MAX`].
const JOIN_PAUSE: Duration = Duration::from_millis(250);
const JOIN_PAUSE_MAX: Duration = Duration::from_secs(2);

/// What Zenoh says when no `connect` endpoint took the session; `ecology` matches it.
const UNABLE: &str = "Unable to connect";

/// Opens a session as `zenoh::open` does, keeping its runtime to dial with.
///
/// With `connect` endpoints, each try dials every one in turn, once (Zenoh's open timeout bounds
/// each), and the session is open when one took it; while none did, it tries again, after a pause,
/// until `connect_timeout`. Zenoh's own retries stay on the first endpoint until its timeout, so a
/// process whose first router was down never reached the second.
pub(crate) async fn open(options: &ZenohOptions) -> Result<(Session, OwnedRuntime), ZenohError> {
    let deadline = tokio::time::Instant::now() + options.connect_timeout;
    // Built once (it may read a file): each try takes a copy.
    let config = options.zenoh_config()?;
    let mut pause = JOIN_PAUSE;
    let mut last = None;
    loop {
        let remaining = deadline.saturating_duration_since(tokio::time::Instant::now());
        let tried = tokio::time::timeout(remaining, open_once(config.clone(), options)).await;
        let why = match tried {
            Ok(Ok(opened)) => return Ok(opened),
            Ok(Err(Tried::Failed(message))) => return Err(ZenohError::Open { message }),
            Ok(Err(Tried::Unlinked(why))) => why,
            // Cut off by the deadline: what the try before found says more.
            Err(_) => last
                .take()
                .unwrap_or_else(|| "no endpoint took it in time".to_string()),
        };
        if tokio::time::Instant::now() + pause >= deadline {
            return Err(ZenohError::Open {
                message: format!(
                    "{UNABLE} to any of {:?} within {}s: {why}",
                    options.connect,
                    options.connect_timeout.as_secs_f64()
                ),
            });
        }
        last = Some(why);
        tokio::time::sleep(pause).await;
        pause = (pause * 2).min(JOIN_PAUSE_MAX);
    }
}

/// Why one try at opening a session did not.
enum Tried {
    /// No `connect` endpoint took it: worth another try.
    Unlinked(String),
    /// Anything else (an endpoint that cannot be listened on): final.
    Failed(String),
}

/// One try: the runtime, the session on it, every endpoint dialled once.
async fn open_once(
    config: zenoh::Config,
    options: &ZenohOptions,
) -> Result<(Session, OwnedRuntime), Tried> {
    let failed = |e: zenoh::Error| Tried::Failed(e.to_string());
    let mut runtime = RuntimeBuilder::new(config).build().await.map_err(failed)?;
    // Closes the runtime if this try goes no further.
    let owned = OwnedRuntime(runtime.clone());
    let session = zenoh::session::init(runtime.clone().into())
        .await
        .map_err(failed)?;
    let unlinked = match runtime.start().await {
        // A client is started only once it holds its link to a router.
        Ok(()) if options.mode == Mode::Client => None,
        Ok(()) => {
            let linked = options.connect.is_empty()
                || session.info().peers_zid().await.next().is_some()
                || session.info().routers_zid().await.next().is_some();
            (!linked).then(|| "none of them took the session".to_string())
        }
        Err(e) if e.to_string().contains(UNABLE) => Some(e.to_string()),
        Err(e) => {
            let _ = session.close().await;
            return Err(Tried::Failed(e.to_string()));
        }
    };
    if let Some(why) = unlinked {
        let _ = session.close().await;
        return Err(Tried::Unlinked(why));
    }
    Ok((session, owned))
}

/// The runtime under a session [`open`] opened. A session opened on a runtime of one's own does
/// not close it (its listeners, its links): this does, when told or at the latest when dropped.
pub(crate) struct OwnedRuntime(Runtime);

impl OwnedRuntime {
    /// A handle on the runtime, to dial with.
    pub(crate) fn runtime(&self) -> Runtime {
        self.0.clone()
    }

    /// Closes the runtime (after its session).
    pub(crate) async fn close(&self) {
        if !self.0.is_closed() {
            let _ = self.0.close().await;
        }
    }
}

impl Drop for OwnedRuntime {
    fn drop(&mut self) {
        if !self.0.is_closed() {
            let _ = zenoh::Wait::wait(self.0.close());
        }
    }
}

impl std::fmt::Debug for OwnedRuntime {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("OwnedRuntime")
    }
}

/// Dials lost links again while it lives (until `shutdown` turns true).
pub(crate) struct Relink {
    _listener: LinkEventsListener<()>,
    _task: AbortOnDrop,
}

impl std::fmt::Debug for Relink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Relink")
    }
}

/// Watches `session`'s links and dials again those it dialled and lost.
pub(crate) async fn relink(
    session: &Session,
    runtime: Runtime,
    shutdown: watch::Receiver<bool>,
) -> zenoh::Result<Relink> {
    // Each lost link: the peer, this end's address and the other end's.
    let (lost, mut losses) = mpsc::unbounded_channel::<(ZenohId, Locator, Locator)>();
    let listener = session
        .info()
        .link_events_listener()
        .history(false)
        .callback(move |event| {
            if event.kind() == SampleKind::Delete {
                let link = event.link();
                let _ = lost.send((*link.zid(), link.src().clone(), link.dst().clone()));
            }
        })
        .await?;
    let session = session.clone();
    let task = tokio::spawn(async move {
        let mut shutdown = shutdown;
        loop {
            let (zid, src, dst) = tokio::select! {
                _ = shutdown.changed() => return,
                next = losses.recv() => match next {
                    Some(next) => next,
                    None => return,
                },
            };
            // A link whose end here is an address this session listens on was dialled by the
            // other side (this end of a link it dialled is an ephemeral port).
            let listening = runtime.get_locators();
            if listening.iter().any(|l| l.address() == src.address()) {
                continue;
            }
            tokio::spawn(dial_again(
                session.clone(),
                runtime.clone(),
                zid,
                dst,
                shutdown.clone(),
            ));
        }
    });
    Ok(Relink {
        _listener: listener,
        _task: AbortOnDrop(task),
    })
}

/// Dials `dst` for `zid` until a link to `zid` is back, the pauses run out, or the session ends.
async fn dial_again(
    session: Session,
    runtime: Runtime,
    zid: ZenohId,
    dst: Locator,
    shutdown: watch::Receiver<bool>,
) {
    for pause in PAUSES {
        tokio::time::sleep(pause).await;
        if *shutdown.borrow() || session.is_closed() {
            return;
        }
        if session.info().peers_zid().await.any(|peer| peer == zid) {
            return;
        }
        runtime
            .connect_peer(&zid.into(), std::slice::from_ref(&dst))
            .await;
    }
}
