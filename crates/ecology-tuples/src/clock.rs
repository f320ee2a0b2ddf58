//! The injected clock: wall time in production, virtual time that tests advance by hand.

use std::fmt;
use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use crate::model::Timestamp;

/// A future that completes when a clock reaches a deadline.
pub type Sleep = Pin<Box<dyn Future<Output = ()> + Send + 'static>>;

/// Where a tuple space takes its time from (timestamps, expiry, leases).
pub trait Clock: Send + Sync + fmt::Debug + 'static {
    /// The current time.
    fn now(&self) -> Timestamp;
    /// Completes once [`Clock::now`] is at or after `deadline`.
    fn sleep_until(&self, deadline: Timestamp) -> Sleep;
}

/// The system's wall clock; sleeping uses tokio timers, so it needs a tokio runtime.
#[derive(Clone, Copy, Debug, Default)]
pub struct SystemClock;

impl Clock for SystemClock {
    fn now(&self) -> Timestamp {
        let since_epoch = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .unwrap_or(Duration::ZERO);
        Timestamp(u64::try_from(since_epoch.as_nanos()).unwrap_or(u64::MAX))
    }

    fn sleep_until(&self, deadline: Timestamp) -> Sleep {
        let wait = deadline.saturating_duration_since(self.now());
        Box::pin(async move {
            // The wall clock can be stepped; re-check after each wake rather than trusting one sleep.
            let mut wait = wait;
            while !wait.is_zero() {
                tokio::time::sleep(wait).await;
                wait = deadline.saturating_duration_since(SystemClock.now());
            }
        })
    }
}

/// Virtual time: it stands still until [`VirtualClock::advance`] moves it. Clones share one time.
#[derive(Clone)]
pub struct VirtualClock {
    now: Arc<tokio::sync::watch::Sender<Timestamp>>,
}

impl VirtualClock {
    /// A virtual clock starting at `start`.
    pub fn new(start: Timestamp) -> Self {
        Self {
            now: Arc::new(tokio::sync::watch::Sender::new(start)),
        }
    }

    /// Moves time forward by `d`, waking every sleeper whose deadline is reached.
    pub fn advance(&self, d: Duration) {
        self.now.send_modify(|now| *now = now.saturating_add(d));
    }
}

impl Default for VirtualClock {
    /// Starts at 2007-10-29 (the IROS 2007 conference), a fixed, readable epoch for tests.
    fn default() -> Self {
        Self::new(Timestamp(1_193_616_000 * 1_000_000_000))
    }
}

impl fmt::Debug for VirtualClock {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("VirtualClock")
            .field("now", &*self.now.borrow())
            .finish()
    }
}

impl Clock for VirtualClock {
    fn now(&self) -> Timestamp {
        *self.now.borrow()
    }

    fn sleep_until(&self, deadline: Timestamp) -> Sleep {
        let mut rx = self.now.subscribe();
        Box::pin(async move {
            // `wait_for` returns an error only if the clock is gone; then time never comes, so wait forever.
            if rx.wait_for(|now| *now >= deadline).await.is_err() {
                std::future::pending::<()>().await;
            }
        })
    }
}
