//! The `TupleSpace` trait every implementation provides, and the options a PEIS joins with.

use std::future::Future;
use std::time::Duration;

use crate::error::TupleError;
use crate::model::{Limits, MetaPointer, Tuple, Value};
use crate::name::{Key, PeisId};
use crate::pattern::{KeyPattern, TuplePattern};
use crate::subscription::{PresenceSubscription, Resubscribe, Subscription};

/// The tuple space as seen by one PEIS: a handle bound to that PEIS.
///
/// The handle publishes only its own PEIS's tuples ([`TupleSpace::set`], [`TupleSpace::delete`]);
/// it changes another PEIS's tuple only by asking that PEIS ([`TupleSpace::set_remote`]), which applies
/// the request itself under its [`RemoteSetPolicy`] and arbitrates claims on its components
/// ([`crate::claims`]). Reads and subscriptions cover every PEIS.
/// Handles are cheap to clone; clones act as the same PEIS.
pub trait TupleSpace: Clone + Send + Sync + 'static {
    /// The PEIS this handle acts as.
    fn peis(&self) -> &PeisId;

    /// Sets this PEIS's tuple `key` to `value` and publishes it; returns the tuple as written.
    fn set(&self, key: Key, value: Value)
    -> impl Future<Output = Result<Tuple, TupleError>> + Send;

    /// Whether anyone subscribes to this PEIS's tuple `key` now: a subscription of any PEIS (this
    /// one included) whose pattern matches it, directly or through a meta-tuple pointing at it.
    /// A component asks before it computes and publishes an output, so that an output nobody
    /// reads costs nothing (see `ecology_peis::Context::output`). An implementation that cannot
    /// know yet says `true`: a value published in vain costs less than one withheld from a reader.
    fn is_read(&self, key: &Key) -> bool;

    /// Whether anyone subscribes to this PEIS's tuple `key`, kept current as readers come and
    /// go: a component that withholds an output nobody reads waits on it to produce at once when
    /// a reader comes (`ecology_peis::Context::readers_came`). Unlike [`TupleSpace::is_read`], it
    /// says only what is known: `false` while an implementation cannot know yet.
    fn watch_readers(&self, key: &Key) -> tokio::sync::watch::Receiver<bool>;

    /// Deletes this PEIS's tuple `key`; returns whether it existed.
    fn delete(&self, key: Key) -> impl Future<Output = Result<bool, TupleError>> + Send;

    /// Drops `holder` from the holders of every component of this PEIS it holds, putting back
    /// those it was the last to hold (see [`crate::claims`]), as the owner does once a holder is
    /// gone; returns the tuples written. Atomic with the arbitration of remote sets.
    fn release_claims(
        &self,
        holder: PeisId,
    ) -> impl Future<Output = Result<Vec<Tuple>, TupleError>> + Send;

    /// The current tuple (owner, key), if it exists and has not expired.
    fn get(
        &self,
        owner: PeisId,
        key: Key,
    ) -> impl Future<Output = Result<Option<Tuple>, TupleError>> + Send;

    /// Every current tuple matching `pattern`, ordered by owner and key.
    fn get_matching(
        &self,
        pattern: TuplePattern,
    ) -> impl Future<Output = Result<Vec<Tuple>, TupleError>> + Send;

    /// Subscribes to tuples matching `pattern`: the current ones first, then every change.
    fn subscribe(
        &self,
        pattern: TuplePattern,
    ) -> impl Future<Output = Result<Subscription, TupleError>> + Send;

    /// Asks `owner` to set its tuple `key` to `value`; returns the tuple once the owner has applied it.
    ///
    /// When `owner` is this PEIS, this is [`TupleSpace::set`].
    fn set_remote(
        &self,
        owner: PeisId,
        key: Key,
        value: Value,
    ) -> impl Future<Output = Result<Tuple, TupleError>> + Send;

    /// The PEIS present in the ecology, this one included, sorted.
    fn peers(&self) -> impl Future<Output = Result<Vec<PeisId>, TupleError>> + Send;

    /// Subscribes to presence: `Joined` for every PEIS present now, then joins and leaves.
    fn subscribe_presence(
        &self,
    ) -> impl Future<Output = Result<PresenceSubscription, TupleError>> + Send;

    /// Subscribes to the presence of one PEIS, `peis`: `Joined` if it is present now, then its
    /// joins and leaves. No event says that it is absent now: a watcher that needs to know gives
    /// it a deadline to be seen by. Costs the ecology only what that PEIS does, where
    /// [`TupleSpace::subscribe_presence`] hears every join and leave of every PEIS.
    fn subscribe_presence_of(
        &self,
        peis: PeisId,
    ) -> impl Future<Output = Result<PresenceSubscription, TupleError>> + Send;

    /// Sets this PEIS's tuple `key` to the meta-tuple value `(meta OWNER KEY)` pointing at `target`.
    fn set_meta(
        &self,
        key: Key,
        target: &MetaPointer,
    ) -> impl Future<Output = Result<Tuple, TupleError>> + Send {
        self.set(key, target.to_value())
    }

    /// Subscribes through meta-tuple (`meta_owner`, `meta_key`): to the tuple it points at, re-following
    /// whenever the pointer changes. See [`Subscription::follow_meta`] for the events.
    fn subscribe_meta(
        &self,
        meta_owner: PeisId,
        meta_key: Key,
    ) -> impl Future<Output = Result<Subscription, TupleError>> + Send {
        let space = self.clone();
        async move {
            let pointer = space
                .subscribe(TuplePattern::exact(meta_owner.clone(), &meta_key))
                .await?;
            let resubscribe: Resubscribe = Box::new(move |target: MetaPointer| {
                let space = space.clone();
                Box::pin(async move {
                    space
                        .subscribe(TuplePattern::exact(target.owner, &target.key))
                        .await
                })
            });
            Ok(Subscription::follow_meta(
                meta_owner,
                meta_key,
                pointer,
                resubscribe,
            ))
        }
    }
}

/// Which of its keys a PEIS lets others set through remote set.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RemoteSetPolicy {
    allowed: Vec<KeyPattern>,
}

impl RemoteSetPolicy {
    /// Every key may be set remotely (the PEIS default).
    pub fn allow_all() -> Self {
        Self {
            allowed: vec![KeyPattern::any()],
        }
    }

    /// No key may be set remotely.
    pub fn deny_all() -> Self {
        Self {
            allowed: Vec::new(),
        }
    }

    /// Only keys matching one of `patterns` may be set remotely.
    pub fn allow(patterns: impl IntoIterator<Item = KeyPattern>) -> Self {
        Self {
            allowed: patterns.into_iter().collect(),
        }
    }

    /// Whether a remote set of `key` is allowed.
    pub fn permits(&self, key: &Key) -> bool {
        self.allowed.iter().any(|p| p.matches(key))
    }
}

impl Default for RemoteSetPolicy {
    fn default() -> Self {
        Self::allow_all()
    }
}

/// How a PEIS joins the ecology.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PeisOptions {
    /// Which keys others may set through remote set.
    pub remote_set: RemoteSetPolicy,
    /// How long after a PEIS vanishes (stops without leaving) the others report it as left. 2 s by default.
    pub lease: Duration,
    /// Limits on values written and received.
    pub limits: Limits,
}

impl Default for PeisOptions {
    fn default() -> Self {
        Self {
            remote_set: RemoteSetPolicy::allow_all(),
            lease: Duration::from_secs(2),
            limits: Limits::default(),
        }
    }
}
