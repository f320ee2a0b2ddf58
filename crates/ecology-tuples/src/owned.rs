//! The tuples one PEIS owns: values, per-key sequence numbers and expiry, shared by every implementation.

use std::collections::{BTreeMap, BTreeSet};

use rustc_hash::FxHashMap;

use crate::model::{RemovalReason, Timestamp, Tuple, TupleEvent, Value};
use crate::name::{Key, PeisId};
use crate::pattern::KeyPattern;

/// The store of one owner's tuples. It does not validate: callers check keys and limits first.
#[derive(Debug)]
pub struct OwnedTuples {
    owner: PeisId,
    epoch: u64,
    tuples: BTreeMap<Key, Tuple>,
    // Sequence numbers outlive deletes, so a key set again after a delete keeps increasing.
    seqs: FxHashMap<Key, u64>,
    // May hold stale entries (overwritten or deleted tuples); `expire_due` skips them.
    expiry: BTreeSet<(Timestamp, Key)>,
}

impl OwnedTuples {
    /// An empty store for run `epoch` of `owner` (see [`Tuple::epoch`]).
    pub fn new(owner: PeisId, epoch: u64) -> Self {
        Self {
            owner,
            epoch,
            tuples: BTreeMap::new(),
            seqs: FxHashMap::default(),
            expiry: BTreeSet::new(),
        }
    }

    /// The owner of the tuples.
    pub fn owner(&self) -> &PeisId {
        &self.owner
    }

    /// The owner's run these tuples belong to.
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    fn next_seq(&mut self, key: &Key) -> u64 {
        let seq = self.seqs.entry(key.clone()).or_insert(0);
        *seq += 1;
        *seq
    }

    /// Writes `value` at `key` at time `now`; returns the new tuple.
    pub fn set(&mut self, key: Key, value: Value, now: Timestamp) -> Tuple {
        let seq = self.next_seq(&key);
        let expiry = value.time_to_live.map(|ttl| now.saturating_add(ttl));
        let tuple = Tuple {
            owner: self.owner.clone(),
            key: key.clone(),
            data: value.data,
            mimetype: value.mimetype,
            ts_write: now,
            ts_user: value.ts_user,
            expiry,
            seq,
            epoch: self.epoch,
            creator: value.creator,
        };
        if let Some(at) = expiry {
            self.expiry.insert((at, key.clone()));
        }
        self.tuples.insert(key, tuple.clone());
        tuple
    }

    /// Decides a remote set of `key` to `value` from `requester` under the claims rules
    /// ([`crate::claims::arbitrate`]) and makes its writes, all at `now`. Returns the tuples
    /// written, in order, and the one to answer the requester with: the request's own tuple
    /// when it was written, else the current one at `key` (or, when there is none, the
    /// component's holders); `Err` with the reason when the request is refused.
    pub fn set_requested(
        &mut self,
        requester: Option<&PeisId>,
        key: Key,
        value: Value,
        now: Timestamp,
    ) -> Result<(Vec<Tuple>, Tuple), String> {
        let writes = match crate::claims::arbitrate(requester, &key, &value, |k| self.get(k, now)) {
            crate::claims::Arbitration::Apply(writes) => writes,
            crate::claims::Arbitration::Refuse(reason) => return Err(reason),
        };
        let written: Vec<Tuple> = writes
            .into_iter()
            .map(|(k, v)| self.set(k, v, now))
            .collect();
        let answer = written
            .iter()
            .find(|t| t.key == key)
            .or_else(|| self.get(&key, now))
            .or_else(|| written.last())
            .cloned()
            .unwrap_or_else(|| self.absent(key, now));
        Ok((written, answer))
    }

    /// Drops `holder` from every component it holds here, as the owner does once it is gone
    /// ([`crate::claims::release_holder`]); returns the tuples written.
    pub fn release_holder(&mut self, holder: &PeisId, now: Timestamp) -> Vec<Tuple> {
        let holders = KeyPattern::new("components.*.holders").unwrap_or_else(|_| KeyPattern::any());
        let writes = crate::claims::release_holder(holder, self.matching(&holders, now), |k| {
            self.get(k, now)
        });
        writes
            .into_iter()
            .map(|(k, v)| self.set(k, v, now))
            .collect()
    }

    /// The answer to a request that wrote nothing at a key nobody wrote: an empty tuple, not stored.
    fn absent(&self, key: Key, now: Timestamp) -> Tuple {
        Tuple {
            owner: self.owner.clone(),
            key,
            data: bytes::Bytes::new(),
            mimetype: crate::name::Mimetype::text(),
            ts_write: now,
            ts_user: None,
            expiry: None,
            seq: 0,
            epoch: self.epoch,
            creator: None,
        }
    }

    /// Deletes `key`; returns the removal event if the tuple existed.
    pub fn delete(&mut self, key: &Key) -> Option<TupleEvent> {
        self.tuples.remove(key)?;
        Some(TupleEvent::Removed {
            owner: self.owner.clone(),
            key: key.clone(),
            seq: self.next_seq(key),
            epoch: self.epoch,
            reason: RemovalReason::Deleted,
        })
    }

    /// The tuple at `key` if it exists and has not expired at `now`.
    pub fn get(&self, key: &Key, now: Timestamp) -> Option<&Tuple> {
        self.tuples.get(key).filter(|t| !t.is_expired_at(now))
    }

    /// The tuples matching `pattern` that have not expired at `now`, ordered by key.
    pub fn matching<'a>(
        &'a self,
        pattern: &'a KeyPattern,
        now: Timestamp,
    ) -> impl Iterator<Item = &'a Tuple> + 'a {
        self.tuples
            .values()
            .filter(move |t| pattern.matches(&t.key) && !t.is_expired_at(now))
    }

    /// When the next tuple expires, if any does (possibly a stale entry; then `expire_due` does nothing).
    pub fn next_expiry(&self) -> Option<Timestamp> {
        self.expiry.first().map(|(at, _)| *at)
    }

    /// Removes every tuple whose expiry is at or before `now`; returns their removal events.
    pub fn expire_due(&mut self, now: Timestamp) -> Vec<TupleEvent> {
        let mut events = Vec::new();
        while let Some((at, key)) = self.expiry.first().cloned() {
            if at > now {
                break;
            }
            self.expiry.pop_first();
            let current = self.tuples.get(&key).and_then(|t| t.expiry);
            if current == Some(at) {
                self.tuples.remove(&key);
                events.push(TupleEvent::Removed {
                    owner: self.owner.clone(),
                    key: key.clone(),
                    seq: self.next_seq(&key),
                    epoch: self.epoch,
                    reason: RemovalReason::Expired,
                });
            }
        }
        events
    }

    /// Number of tuples stored (expired ones not yet removed included).
    pub fn len(&self) -> usize {
        self.tuples.len()
    }

    /// Whether the store is empty.
    pub fn is_empty(&self) -> bool {
        self.tuples.is_empty()
    }
}
