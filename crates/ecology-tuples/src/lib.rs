//! The Ecology tuple space: the tuple model, the `TupleSpace` trait and the in-process implementation.
//!
//! All PEIS of an ecology talk through a tuple space (DESIGN.md section 5). Each PEIS owns the tuples
//! under its name and alone publishes them; anyone may read and subscribe; another PEIS changes a
//! tuple only by a remote-set request that the owner applies. A meta-tuple holds `(meta OWNER KEY)`
//! and subscriptions can follow it. Presence events say which PEIS joined and left.
//!
//! [`InProcessSpace`] runs a whole ecology in one process on an injected [`Clock`]
//! ([`VirtualClock`] in tests); `ecology-zenoh` implements the same [`TupleSpace`] over the network.

pub mod claims;
mod clock;
pub mod contract;
mod error;
mod in_process;
mod model;
mod name;
mod owned;
mod pattern;
mod space;
mod subscription;
pub mod world;

#[cfg(any(test, feature = "conformance"))]
pub mod conformance;

#[cfg(test)]
mod tests;

pub use clock::{Clock, Sleep, SystemClock, VirtualClock};
pub use error::TupleError;
pub use in_process::{InProcessPeis, InProcessSpace};
pub use model::{
    Limits, MetaPointer, PresenceEvent, RemovalReason, Timestamp, Tuple, TupleEvent, Value,
};
pub use name::{
    ComponentId, Key, MAX_COMPONENT_LEN, MAX_NAME_LEN, Mimetype, PeisId, ValidationError,
};
pub use owned::OwnedTuples;
pub use pattern::{KeyPattern, OwnerPattern, Segment, TuplePattern};
pub use space::{PeisOptions, RemoteSetPolicy, TupleSpace};
pub use subscription::{
    EventReceiver, EventSender, PresenceSubscription, Resubscribe, SubscribeFuture, Subscription,
    events,
};
