//! Subscriptions: streams of tuple and presence events, including subscriptions that follow a meta-tuple.

use std::fmt;
use std::future::Future;
use std::pin::Pin;
use std::task::{Context, Poll};

use tokio::sync::mpsc;

use crate::error::TupleError;
use crate::model::{MetaPointer, PresenceEvent, TupleEvent};
use crate::name::{Key, PeisId};

/// The sending half of a subscription's events, made by [`events`].
#[derive(Debug)]
pub struct EventSender(futures_channel::mpsc::UnboundedSender<TupleEvent>);

/// The receiving half of a subscription's events, for [`Subscription::from_channel`].
#[derive(Debug)]
pub struct EventReceiver(futures_channel::mpsc::UnboundedReceiver<TupleEvent>);

/// A channel of tuple events for one subscription, unbounded.
///
/// It holds nothing until an event is sent, and each event in its own allocation: a PEIS host
/// keeps a few subscriptions open that seldom see an event, and a thousand hosts in one process
/// would otherwise hold a block of 32 events' room for each (tokio's channel) whether or not any
/// came.
pub fn events() -> (EventSender, EventReceiver) {
    let (tx, rx) = futures_channel::mpsc::unbounded();
    (EventSender(tx), EventReceiver(rx))
}

impl EventSender {
    /// Sends `event`; `false` if the subscription is gone.
    pub fn send(&self, event: TupleEvent) -> bool {
        self.0.unbounded_send(event).is_ok()
    }

    /// Whether the subscription is gone.
    pub fn is_closed(&self) -> bool {
        self.0.is_closed()
    }
}

/// A future that opens a subscription on the target of a meta-tuple.
pub type SubscribeFuture = Pin<Box<dyn Future<Output = Result<Subscription, TupleError>> + Send>>;

/// Opens a subscription on a meta-tuple's target; used by [`Subscription::follow_meta`].
pub type Resubscribe = Box<dyn FnMut(MetaPointer) -> SubscribeFuture + Send>;

/// A live stream of [`TupleEvent`]s: first the current tuples matching, then every change.
///
/// Events of one (owner, key) arrive in the order of their `seq`. Dropping the subscription ends it.
/// It is a [`futures_core::Stream`], and [`Subscription::next`] awaits one event, so an event loop
/// can `select!` over it.
pub struct Subscription {
    kind: Kind,
}

enum Kind {
    Channel {
        events: EventReceiver,
        // Dropped with the subscription; implementations use it to unsubscribe.
        _guard: Box<dyn Send>,
    },
    Meta(Box<MetaFollow>),
}

struct MetaFollow {
    meta_owner: PeisId,
    meta_key: Key,
    pointer: Subscription,
    current: Option<MetaPointer>,
    target: Option<Subscription>,
    pending: Option<SubscribeFuture>,
    resubscribe: Resubscribe,
}

impl Subscription {
    /// A subscription fed by `events`; `guard` is dropped when the subscription is (to unsubscribe).
    pub fn from_channel(events: EventReceiver, guard: impl Send + 'static) -> Self {
        Self {
            kind: Kind::Channel {
                events,
                _guard: Box::new(guard),
            },
        }
    }

    /// A subscription that follows meta-tuple (`meta_owner`, `meta_key`).
    ///
    /// `pointer` is a subscription on exactly that meta-tuple. Whenever its value changes to
    /// `(meta OWNER KEY)`, the stream yields [`TupleEvent::Retargeted`], drops the subscription on
    /// the old target (no event of the old target follows) and opens one on the new target with
    /// `resubscribe`, whose current value comes next. A removed meta-tuple, or one that does not
    /// hold a valid pointer, yields `Retargeted` with no target and follows nothing. If opening the
    /// subscription on the new target fails, the stream yields `Retargeted` with no target.
    pub fn follow_meta(
        meta_owner: PeisId,
        meta_key: Key,
        pointer: Subscription,
        resubscribe: Resubscribe,
    ) -> Self {
        Self {
            kind: Kind::Meta(Box::new(MetaFollow {
                meta_owner,
                meta_key,
                pointer,
                current: None,
                target: None,
                pending: None,
                resubscribe,
            })),
        }
    }

    /// The next event; `None` once the tuple space behind the subscription is gone.
    pub async fn next(&mut self) -> Option<TupleEvent> {
        std::future::poll_fn(|cx| self.poll_event(cx)).await
    }

    /// The next event if one is ready now, without waiting.
    ///
    /// Every event that has arrived is returned, however many: a channel is read with
    /// `try_recv`, which no cooperative budget limits (tokio's limits a task to 128 operations a
    /// turn; a subscriber that receives more than that between turns, such as a sensor following
    /// the poses of 150 robots, would fall further behind with every turn).
    pub fn try_next(&mut self) -> Option<TupleEvent> {
        if let Kind::Channel { events, .. } = &mut self.kind {
            return events.0.try_recv().ok();
        }
        let waker = std::task::Waker::noop();
        let mut cx = Context::from_waker(waker);
        match self.poll_event(&mut cx) {
            Poll::Ready(event) => event,
            Poll::Pending => None,
        }
    }

    /// Polls for the next event.
    pub fn poll_event(&mut self, cx: &mut Context<'_>) -> Poll<Option<TupleEvent>> {
        match &mut self.kind {
            Kind::Channel { events, .. } => {
                futures_core::Stream::poll_next(Pin::new(&mut events.0), cx)
            }
            Kind::Meta(follow) => follow.poll_event(cx),
        }
    }
}

impl MetaFollow {
    fn poll_event(&mut self, cx: &mut Context<'_>) -> Poll<Option<TupleEvent>> {
        loop {
            // Finish opening the new target first, so that its current value comes right after `Retargeted`.
            if let Some(pending) = &mut self.pending {
                match pending.as_mut().poll(cx) {
                    Poll::Pending => return Poll::Pending,
                    Poll::Ready(result) => {
                        self.pending = None;
                        match result {
                            Ok(target) => self.target = Some(target),
                            Err(_) => {
                                self.current = None;
                                return Poll::Ready(Some(self.retargeted(None)));
                            }
                        }
                    }
                }
            }
            match self.pointer.poll_event(cx) {
                Poll::Ready(None) => return Poll::Ready(None),
                Poll::Ready(Some(event)) => {
                    let new = match event {
                        TupleEvent::Changed(tuple) => tuple.meta_pointer().ok(),
                        TupleEvent::Removed { .. } => None,
                        TupleEvent::Retargeted { .. } => continue,
                    };
                    if new == self.current {
                        // The same pointer written again: keep following without a gap.
                        continue;
                    }
                    self.current = new.clone();
                    self.target = None;
                    if let Some(target) = &new {
                        self.pending = Some((self.resubscribe)(target.clone()));
                    }
                    return Poll::Ready(Some(self.retargeted(new)));
                }
                Poll::Pending => {}
            }
            return match &mut self.target {
                Some(target) => match target.poll_event(cx) {
                    Poll::Ready(Some(event)) => Poll::Ready(Some(event)),
                    // The target's space is gone; the pointer may still move, so keep waiting on it.
                    Poll::Ready(None) => {
                        self.target = None;
                        Poll::Pending
                    }
                    Poll::Pending => Poll::Pending,
                },
                None => Poll::Pending,
            };
        }
    }

    fn retargeted(&self, target: Option<MetaPointer>) -> TupleEvent {
        TupleEvent::Retargeted {
            meta_owner: self.meta_owner.clone(),
            meta_key: self.meta_key.clone(),
            target,
        }
    }
}

impl futures_core::Stream for Subscription {
    type Item = TupleEvent;
    fn poll_next(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<TupleEvent>> {
        self.get_mut().poll_event(cx)
    }
}

impl fmt::Debug for Subscription {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.kind {
            Kind::Channel { events, .. } => f
                .debug_struct("Subscription")
                .field(
                    "open",
                    &!futures_core::stream::FusedStream::is_terminated(&events.0),
                )
                .finish_non_exhaustive(),
            Kind::Meta(follow) => f
                .debug_struct("Subscription")
                .field("meta_owner", &follow.meta_owner)
                .field("meta_key", &follow.meta_key)
                .field("target", &follow.current)
                .finish_non_exhaustive(),
        }
    }
}

/// A live stream of [`PresenceEvent`]s: first `Joined` for every PEIS present, then every change.
pub struct PresenceSubscription {
    events: mpsc::UnboundedReceiver<PresenceEvent>,
    _guard: Box<dyn Send + Sync>,
}

impl PresenceSubscription {
    /// A presence subscription fed by `events`; `guard` is dropped when the subscription is.
    pub fn from_channel(
        events: mpsc::UnboundedReceiver<PresenceEvent>,
        guard: impl Send + Sync + 'static,
    ) -> Self {
        Self {
            events,
            _guard: Box::new(guard),
        }
    }

    /// The next event; `None` once the tuple space behind the subscription is gone.
    pub async fn next(&mut self) -> Option<PresenceEvent> {
        self.events.recv().await
    }

    /// Polls for the next event.
    pub fn poll_event(&mut self, cx: &mut Context<'_>) -> Poll<Option<PresenceEvent>> {
        self.events.poll_recv(cx)
    }
}

impl futures_core::Stream for PresenceSubscription {
    type Item = PresenceEvent;
    fn poll_next(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<PresenceEvent>> {
        self.get_mut().events.poll_recv(cx)
    }
}

impl fmt::Debug for PresenceSubscription {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PresenceSubscription")
            .field("queued", &self.events.len())
            .finish_non_exhaustive()
    }
}
