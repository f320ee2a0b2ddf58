//! Errors of the tuple space: validation of names and values, and failures of operations.

use crate::model::{Key, PeisId};

/// A name, key, pattern or value that breaks the rules of the tuple model.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ValidationError {
    /// A PEIS name is empty, too long, or has a character outside `[A-Za-z0-9_-]`.
    #[error("invalid PEIS name {name:?}: {reason}")]
    PeisId {
        /// The rejected name.
        name: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A key is empty, too long, has an empty segment, or a character outside `[A-Za-z0-9_-]` in a segment.
    #[error("invalid key {key:?}: {reason}")]
    Key {
        /// The rejected key.
        key: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A key or owner pattern is malformed (for example `a.b*` or `a..b`).
    #[error("invalid pattern {pattern:?}: {reason}")]
    Pattern {
        /// The rejected pattern.
        pattern: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A mimetype is empty, longer than 255 bytes or not printable ASCII.
    #[error("invalid mimetype {mimetype:?}: {reason}")]
    Mimetype {
        /// The rejected mimetype.
        mimetype: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A value is larger than the configured limit.
    #[error("value of {size} bytes for key {key} is over the limit of {limit} bytes")]
    ValueTooLarge {
        /// The key the value was meant for.
        key: Key,
        /// Size of the value in bytes.
        size: usize,
        /// The configured limit in bytes.
        limit: usize,
    },
    /// A value that must be text (for example a meta-tuple) is not valid UTF-8.
    #[error("value of ({owner} {key}) is not UTF-8 text: invalid byte at offset {offset}")]
    NotUtf8 {
        /// Owner of the tuple.
        owner: PeisId,
        /// Key of the tuple.
        key: Key,
        /// Offset of the first invalid byte.
        offset: usize,
    },
    /// A value that must be a meta-tuple pointer is not of the form `(meta OWNER KEY)`.
    #[error("value of ({owner} {key}) is not a meta-tuple `(meta OWNER KEY)`: {reason}")]
    NotMeta {
        /// Owner of the tuple.
        owner: PeisId,
        /// Key of the tuple.
        key: Key,
        /// What is wrong with it.
        reason: String,
    },
}

/// Why an operation on the tuple space failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TupleError {
    /// The input broke a rule of the tuple model.
    #[error(transparent)]
    Invalid(#[from] ValidationError),
    /// A PEIS with this name is already present in the ecology.
    #[error("PEIS {0} is already present in the ecology")]
    AlreadyPresent(PeisId),
    /// The PEIS this handle is bound to has left the ecology; the handle can no longer be used.
    #[error("PEIS {0} has left the ecology")]
    Departed(PeisId),
    /// The owner of a remote set is not present, or did not answer (on an authenticated ecology,
    /// a request the access rules do not grant is dropped unanswered, so it ends here too).
    #[error(
        "no answer from PEIS {owner} to a remote set of {key}: it is not present, or this PEIS may not set that key"
    )]
    OwnerUnreachable {
        /// The PEIS that was asked.
        owner: PeisId,
        /// The key it was asked to set.
        key: Key,
    },
    /// The owner refused a remote set (its policy does not allow remote sets of this key).
    #[error("PEIS {owner} refused a remote set of {key}: {reason}")]
    RemoteSetRefused {
        /// The PEIS that refused.
        owner: PeisId,
        /// The key it was asked to set.
        key: Key,
        /// The reason it gave.
        reason: String,
    },
    /// The transport below the tuple space failed (network implementations only).
    #[error("transport error during {operation}: {message}")]
    Transport {
        /// The operation that failed, such as `put` or `get`.
        operation: &'static str,
        /// The message of the underlying error.
        message: String,
    },
}
