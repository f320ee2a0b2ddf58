//! The tuple model: timestamps, values, tuples, events, meta-tuple pointers and limits.

use std::fmt;
use std::time::Duration;

use bytes::Bytes;

use crate::name::{Key, Mimetype, PeisId, ValidationError};

/// A point in time: nanoseconds since the UNIX epoch, on the clock of the tuple space.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Timestamp(pub u64);

impl Timestamp {
    /// Nanoseconds since the UNIX epoch.
    pub fn as_nanos(self) -> u64 {
        self.0
    }

    /// This time plus `d`, saturating at the end of representable time.
    pub fn saturating_add(self, d: Duration) -> Self {
        let nanos = u64::try_from(d.as_nanos()).unwrap_or(u64::MAX);
        Self(self.0.saturating_add(nanos))
    }

    /// Time elapsed from `earlier` to `self`, zero if `earlier` is later.
    pub fn saturating_duration_since(self, earlier: Self) -> Duration {
        Duration::from_nanos(self.0.saturating_sub(earlier.0))
    }
}

impl fmt::Display for Timestamp {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}.{:09}",
            self.0 / 1_000_000_000,
            self.0 % 1_000_000_000
        )
    }
}

/// What a PEIS writes: data with its mimetype, an optional user timestamp and an optional time to live.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Value {
    /// The data bytes.
    pub data: Bytes,
    /// The mimetype of the data.
    pub mimetype: Mimetype,
    /// A timestamp chosen by the writer (for example when a sensor reading was taken).
    pub ts_user: Option<Timestamp>,
    /// How long the tuple lives after it is written; `None` lives until deleted or replaced.
    pub time_to_live: Option<Duration>,
    /// Who asked for it: `None` when the owner writes it itself, the requester's name in a remote
    /// set (stamped by [`TupleSpace::set_remote`](crate::TupleSpace::set_remote)).
    pub creator: Option<PeisId>,
}

impl Value {
    /// A `text/plain` value.
    pub fn text(text: impl Into<String>) -> Self {
        Self {
            data: Bytes::from(text.into()),
            mimetype: Mimetype::text(),
            ts_user: None,
            time_to_live: None,
            creator: None,
        }
    }

    /// An `application/octet-stream` value.
    pub fn bytes(data: impl Into<Bytes>) -> Self {
        Self {
            data: data.into(),
            mimetype: Mimetype::octet_stream(),
            ts_user: None,
            time_to_live: None,
            creator: None,
        }
    }

    /// The same value with another mimetype.
    pub fn with_mimetype(mut self, mimetype: Mimetype) -> Self {
        self.mimetype = mimetype;
        self
    }

    /// The same value with a user timestamp.
    pub fn with_ts_user(mut self, ts_user: Timestamp) -> Self {
        self.ts_user = Some(ts_user);
        self
    }

    /// The same value, expiring `ttl` after it is written.
    pub fn with_time_to_live(mut self, ttl: Duration) -> Self {
        self.time_to_live = Some(ttl);
        self
    }

    /// The same value, asked for by `creator` (a remote set's requester).
    pub fn with_creator(mut self, creator: PeisId) -> Self {
        self.creator = Some(creator);
        self
    }
}

/// A tuple as stored and delivered: who owns it, its key, value and metadata.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Tuple {
    /// The PEIS that owns (and alone publishes) the tuple.
    pub owner: PeisId,
    /// The dotted key.
    pub key: Key,
    /// The data bytes.
    pub data: Bytes,
    /// The mimetype of the data.
    pub mimetype: Mimetype,
    /// When the owner wrote it, on the owner's clock.
    pub ts_write: Timestamp,
    /// A timestamp chosen by the writer, if any.
    pub ts_user: Option<Timestamp>,
    /// When it expires, on the owner's clock, if it does.
    pub expiry: Option<Timestamp>,
    /// Version of (owner, key): increases with every set, delete and expiry. 0 means unknown (a sample without metadata).
    pub seq: u64,
    /// The run of the owner that wrote it: chosen when the PEIS joins, greater for a later run. A PEIS
    /// that restarts numbers its tuples from 1 again, so versions compare as `(epoch, seq)`. 0 means unknown.
    pub epoch: u64,
    /// The PEIS whose remote set wrote this value (the PEIS middleware's *creator*); `None` when the
    /// owner wrote it itself. As the requester states it: who may remote-set at all is the owner's
    /// policy and, with keys, the ecology's access rules.
    pub creator: Option<PeisId>,
}

impl Tuple {
    /// The data as UTF-8 text.
    pub fn text(&self) -> Result<&str, ValidationError> {
        std::str::from_utf8(&self.data).map_err(|e| ValidationError::NotUtf8 {
            owner: self.owner.clone(),
            key: self.key.clone(),
            offset: e.valid_up_to(),
        })
    }

    /// Whether the tuple has expired at `now`.
    pub fn is_expired_at(&self, now: Timestamp) -> bool {
        self.expiry.is_some_and(|e| e <= now)
    }

    /// The meta-tuple pointer this tuple holds, if its value is `(meta OWNER KEY)`.
    pub fn meta_pointer(&self) -> Result<MetaPointer, ValidationError> {
        let text = self.text()?;
        MetaPointer::parse(text).map_err(|reason| ValidationError::NotMeta {
            owner: self.owner.clone(),
            key: self.key.clone(),
            reason,
        })
    }
}

/// Why a tuple disappeared.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RemovalReason {
    /// Its owner deleted it.
    Deleted,
    /// Its time to live ran out.
    Expired,
}

/// A change seen through a [`Subscription`](crate::Subscription).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TupleEvent {
    /// A tuple was set (or is current when the subscription starts).
    Changed(Tuple),
    /// A tuple was deleted or expired.
    Removed {
        /// Owner of the tuple.
        owner: PeisId,
        /// Key of the tuple.
        key: Key,
        /// Version of the removal (0 when unknown).
        seq: u64,
        /// The owner's run that removed it (see [`Tuple::epoch`]).
        epoch: u64,
        /// Deleted or expired.
        reason: RemovalReason,
    },
    /// The meta-tuple a subscription follows now points elsewhere (only on meta subscriptions).
    Retargeted {
        /// Owner of the meta-tuple.
        meta_owner: PeisId,
        /// Key of the meta-tuple.
        meta_key: Key,
        /// The new target, or `None` when the meta-tuple was removed or does not hold a valid pointer.
        target: Option<MetaPointer>,
    },
}

impl TupleEvent {
    /// The owner and key the event is about (for `Retargeted`, the meta-tuple).
    pub fn subject(&self) -> (&PeisId, &Key) {
        match self {
            TupleEvent::Changed(t) => (&t.owner, &t.key),
            TupleEvent::Removed { owner, key, .. } => (owner, key),
            TupleEvent::Retargeted {
                meta_owner,
                meta_key,
                ..
            } => (meta_owner, meta_key),
        }
    }
}

/// A PEIS appearing in or disappearing from the ecology.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PresenceEvent {
    /// The PEIS is present (joined, or was present when the subscription started).
    Joined(PeisId),
    /// The PEIS left, or vanished and its lease ran out.
    Left(PeisId),
}

/// The target of a meta-tuple: the value `(meta OWNER KEY)` points at tuple (OWNER, KEY).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct MetaPointer {
    /// Owner of the target tuple.
    pub owner: PeisId,
    /// Key of the target tuple.
    pub key: Key,
}

impl MetaPointer {
    /// Parses `(meta OWNER KEY)` (whitespace-separated, surrounding whitespace allowed).
    pub fn parse(text: &str) -> Result<Self, String> {
        let inner = text
            .trim()
            .strip_prefix('(')
            .and_then(|s| s.strip_suffix(')'))
            .ok_or_else(|| "it is not in parentheses".to_owned())?;
        let mut words = inner.split_whitespace();
        match (words.next(), words.next(), words.next(), words.next()) {
            (Some("meta"), Some(owner), Some(key), None) => Ok(Self {
                owner: PeisId::new(owner).map_err(|e| e.to_string())?,
                key: Key::new(key).map_err(|e| e.to_string())?,
            }),
            (Some("meta"), ..) => Err("it needs exactly an owner and a key".to_owned()),
            _ => Err("it does not start with `meta`".to_owned()),
        }
    }

    /// The value a meta-tuple holds to point here.
    pub fn to_value(&self) -> Value {
        Value::text(self.to_string())
    }
}

impl fmt::Display for MetaPointer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "(meta {} {})", self.owner, self.key)
    }
}

/// Limits a tuple space enforces on what is written and received.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest value accepted, in bytes (1 MiB by default).
    pub max_value_bytes: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_value_bytes: 1 << 20,
        }
    }
}

impl Limits {
    /// Checks `value` against the limits, for key `key`.
    pub fn check(&self, key: &Key, value: &Value) -> Result<(), ValidationError> {
        if value.data.len() > self.max_value_bytes {
            return Err(ValidationError::ValueTooLarge {
                key: key.clone(),
                size: value.data.len(),
                limit: self.max_value_bytes,
            });
        }
        Ok(())
    }
}
