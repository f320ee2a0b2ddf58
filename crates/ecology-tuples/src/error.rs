//! Failures of operations on the tuple space.

use crate::name::{Key, PeisId, ValidationError};

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
