//! The driver: connects the sans-IO [`Executive`] to a tuple space.
//!
//! It subscribes to every tuple and to presence, turns what arrives into
//! [`Event`]s, carries out the [`Command`]s (remote sets, timers on the
//! space's clock), and returns when the run is over. It spawns nothing: the
//! whole loop is one future the caller owns.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use ecology_tuples::{
    Clock, Key, PeisId, PresenceEvent, Timestamp, TupleError, TupleEvent, TuplePattern, TupleSpace,
    Value,
};

use crate::executive::{Command, Event, Executive, RunStatus, TimerId};
use crate::log::LogEntry;

/// How the driver runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DriverConfig {
    /// How long to take in the ecology's current tuples before starting.
    pub settle: Duration,
    /// Give up after this long (the run is then still `Running`).
    pub limit: Option<Duration>,
}

impl Default for DriverConfig {
    fn default() -> DriverConfig {
        DriverConfig {
            settle: Duration::from_millis(200),
            limit: None,
        }
    }
}

/// Runs `exec` on `space` until the task is done or failed (or the limit passes).
pub async fn drive<S: TupleSpace>(
    space: &S,
    clock: Arc<dyn Clock>,
    exec: &mut Executive,
    config: DriverConfig,
) -> Result<RunStatus, TupleError> {
    drive_observed(space, clock, exec, config, |_| {}).await
}

/// [`drive`], calling `observe` with every log entry as soon as the executive
/// writes it (a live timeline, or fault injection keyed to executive events).
pub async fn drive_observed<S: TupleSpace>(
    space: &S,
    clock: Arc<dyn Clock>,
    exec: &mut Executive,
    config: DriverConfig,
    mut observe: impl FnMut(&LogEntry),
) -> Result<RunStatus, TupleError> {
    let mut observed = exec.log().len();
    let start = clock.now();
    let elapsed = |clock: &Arc<dyn Clock>| clock.now().saturating_duration_since(start);
    let mut tuples = space.subscribe(TuplePattern::everything()).await?;
    let mut presence = space.subscribe_presence().await?;
    let mut timers: BTreeMap<TimerId, Timestamp> = BTreeMap::new();
    let settle_until = start.saturating_add(config.settle);
    let mut started = false;
    loop {
        if matches!(exec.status(), RunStatus::Done | RunStatus::Failed { .. }) {
            return Ok(exec.status().clone());
        }
        if config.limit.is_some_and(|limit| elapsed(&clock) >= limit) {
            return Ok(exec.status().clone());
        }
        let next_timer = timers
            .iter()
            .min_by_key(|(_, at)| **at)
            .map(|(id, at)| (*id, *at));
        let wake_at = match (started, next_timer) {
            (false, _) => Some(settle_until),
            (true, Some((_, at))) => Some(at),
            (true, None) => None,
        };
        let wake_at = match (wake_at, config.limit) {
            (Some(at), Some(limit)) => Some(at.min(start.saturating_add(limit))),
            (None, Some(limit)) => Some(start.saturating_add(limit)),
            (at, None) => at,
        };
        let sleep = async {
            match wake_at {
                Some(at) => clock.sleep_until(at).await,
                None => std::future::pending().await,
            }
        };
        let commands = tokio::select! {
            event = tuples.next() => match event {
                Some(TupleEvent::Changed(t)) => {
                    let value = t.text().unwrap_or_default().to_string();
                    exec.handle(elapsed(&clock), Event::Tuple {
                        owner: t.owner.to_string(),
                        key: t.key.to_string(),
                        value,
                        seq: t.seq,
                    })
                }
                Some(_) => Vec::new(),
                None => return Ok(exec.status().clone()),
            },
            event = presence.next() => match event {
                Some(PresenceEvent::Joined(p)) => exec.handle(elapsed(&clock), Event::PeisJoined(p.to_string())),
                Some(PresenceEvent::Left(p)) => exec.handle(elapsed(&clock), Event::PeisLeft(p.to_string())),
                None => Vec::new(),
            },
            () = sleep => {
                let now = clock.now();
                if !started && now >= settle_until {
                    started = true;
                    exec.handle(elapsed(&clock), Event::Start)
                } else if let Some((id, at)) = next_timer.filter(|(_, at)| *at <= now) {
                    let _ = at;
                    timers.remove(&id);
                    exec.handle(elapsed(&clock), Event::Timer(id))
                } else {
                    Vec::new()
                }
            }
        };
        for entry in &exec.log()[observed..] {
            observe(entry);
        }
        observed = exec.log().len();
        for command in commands {
            match command {
                Command::StartTimer { id, after } => {
                    timers.insert(id, clock.now().saturating_add(after));
                }
                Command::CancelTimer(id) => {
                    timers.remove(&id);
                }
                Command::RemoteSet { owner, key, value } => {
                    let (Ok(owner), Ok(key)) = (PeisId::new(&owner), Key::new(&key)) else {
                        continue;
                    };
                    // An unreachable owner shows up as a failure through presence
                    // or a deploy timeout; the executive handles both.
                    let _ = if owner == *space.peis() {
                        space.set(key, Value::text(value)).await
                    } else {
                        space.set_remote(owner, key, Value::text(value)).await
                    };
                }
            }
        }
    }
}
