//! The `Component` trait and the context a component body runs in (DESIGN section 6).
//!
//! A component body runs one functionality instance, given by its `params`
//! (such as `(navigation astrid tc1 bedroom)`): it reads its inputs through
//! the `C.mi-INFO` meta-tuples the deployer points at producers' outputs,
//! writes its outputs as `C.out.INFO`, and reports `C.status` (`running`,
//! `waiting` with the missing inputs in `C.cause`, `done`) itself. Returning an
//! error reports `error` with the error as the cause; the host does that.

use std::collections::{BTreeMap, BTreeSet};
use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;

use ecology_tuples::contract::{ComponentField, input_key, output_key};
use ecology_tuples::{
    Clock, ComponentId, PeisId, Subscription, Timestamp, Tuple, TupleError, TupleEvent, TupleSpace,
    Value,
};

/// An output's value, made only if it goes out.
type Later = Box<dyn FnOnce() -> Value + Send>;

/// A boxed, sendable future: what a component body returns.
pub type BoxFuture<T> = Pin<Box<dyn Future<Output = T> + Send + 'static>>;

/// Why a component body stopped with an error.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ComponentError {
    /// The component's own fault, in its words (becomes `C.cause`).
    #[error("{0}")]
    Fault(String),
    /// The tuple space refused an operation.
    #[error("tuple space: {0}")]
    Space(String),
}

impl From<TupleError> for ComponentError {
    fn from(e: TupleError) -> ComponentError {
        ComponentError::Space(e.to_string())
    }
}

/// The body of a PEIS-component.
pub trait Component<S: TupleSpace>: Send + Sync + 'static {
    /// Runs the functionality instance in `ctx.params()` until it finishes
    /// (returning `Ok` after reporting `done`, if it has an end), fails, or is
    /// cancelled by the host (the future is dropped).
    fn run(&self, ctx: Context<S>) -> BoxFuture<Result<(), ComponentError>>;
}

impl<S, F, Fut> Component<S> for F
where
    S: TupleSpace,
    F: Fn(Context<S>) -> Fut + Send + Sync + 'static,
    Fut: Future<Output = Result<(), ComponentError>> + Send + 'static,
{
    fn run(&self, ctx: Context<S>) -> BoxFuture<Result<(), ComponentError>> {
        Box::pin(self(ctx))
    }
}

/// What a component body sees: its PEIS, its name, its params, its clock.
#[derive(Clone)]
pub struct Context<S: TupleSpace> {
    space: S,
    component: String,
    params: String,
    clock: Arc<dyn Clock>,
    /// The outputs written and not deleted since, so that one going unread is deleted once.
    written: Arc<std::sync::Mutex<BTreeSet<String>>>,
    /// The last value of each output withheld because nobody read it, not yet made, to make and
    /// publish when a reader comes ([`Context::readers_came`]).
    withheld: Arc<std::sync::Mutex<BTreeMap<String, Later>>>,
}

impl<S: TupleSpace> std::fmt::Debug for Context<S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Context")
            .field("peis", self.space.peis())
            .field("component", &self.component)
            .field("params", &self.params)
            .finish()
    }
}

impl<S: TupleSpace> Context<S> {
    pub(crate) fn new(
        space: S,
        component: String,
        params: String,
        clock: Arc<dyn Clock>,
    ) -> Context<S> {
        Context {
            space,
            component,
            params,
            clock,
            written: Arc::default(),
            withheld: Arc::default(),
        }
    }

    /// The PEIS this component runs on.
    pub fn peis(&self) -> &PeisId {
        self.space.peis()
    }

    /// The component's name, such as `tc1`.
    pub fn component(&self) -> &str {
        &self.component
    }

    /// The functionality instance to run, such as `(navigation astrid tc1 bedroom)`.
    pub fn params(&self) -> &str {
        &self.params
    }

    /// The functionality's name: the params' first word, such as `navigation`.
    pub fn functionality(&self) -> &str {
        self.params
            .trim_matches(|c| c == '(' || c == ')')
            .split_whitespace()
            .next()
            .unwrap_or("")
    }

    /// The params' arguments after the functionality name.
    pub fn args(&self) -> Vec<&str> {
        self.params
            .trim_matches(|c| c == '(' || c == ')')
            .split_whitespace()
            .skip(1)
            .collect()
    }

    /// The tuple space, as this PEIS.
    pub fn space(&self) -> &S {
        &self.space
    }

    /// The clock.
    pub fn clock(&self) -> &Arc<dyn Clock> {
        &self.clock
    }

    /// This component's name as the contract's keys take it.
    fn component_id(&self) -> Result<ComponentId, ComponentError> {
        ComponentId::new(&self.component).map_err(|e| ComponentError::Space(e.to_string()))
    }

    /// Reports `C.status` (and `C.cause`, cleared when `None`).
    pub async fn status(&self, status: &str, cause: Option<&str>) -> Result<(), ComponentError> {
        let c = self.component_id()?;
        self.space
            .set(
                ComponentField::Cause.key(&c),
                Value::text(cause.unwrap_or("")),
            )
            .await?;
        self.space
            .set(ComponentField::Status.key(&c), Value::text(status))
            .await?;
        Ok(())
    }

    /// Reports what a sensing component observed as `C.observed`: literals
    /// over the domain's predicates, `(thing-at newspaper kitchen)` or
    /// `(not (thing-at newspaper entrance))`, separated by spaces. The
    /// executive completes a sensing action once its configuration has
    /// reported every atom the action reveals.
    pub async fn observed(&self, literals: &str) -> Result<(), ComponentError> {
        let c = self.component_id()?;
        self.space
            .set(ComponentField::Observed.key(&c), Value::text(literals))
            .await?;
        Ok(())
    }

    /// Whether anyone reads output `info` (`C.out.INFO`) now: a consumer whose input the
    /// executive pointed at it, or anyone else subscribed to it ([`TupleSpace::is_read`]). A body
    /// asks before it does the work of an output, so that an output nobody reads costs nothing.
    pub fn is_read(&self, info: &str) -> Result<bool, ComponentError> {
        let key = output_key(&self.component_id()?, info)
            .map_err(|e| ComponentError::Space(e.to_string()))?;
        Ok(self.space.is_read(&key))
    }

    /// Publishes output `info` as `C.out.INFO` while someone reads it ([`Context::is_read`]),
    /// returning the tuple written; `None` when nobody reads it. An output that goes unread is
    /// deleted, once: a reader who comes later never gets an old value as if new. Its last value
    /// is kept back instead, and published the moment a reader comes if the body waits on
    /// [`Context::readers_came`].
    pub async fn output(&self, info: &str, value: Value) -> Result<Option<Tuple>, ComponentError> {
        self.output_with(info, move || value).await
    }

    /// [`Context::output`] of the value `make` makes, made only if it goes out: now if someone
    /// reads it, else when a reader comes while the body waits on [`Context::readers_came`]. For
    /// an output whose making is the work, such as a camera's image of a whole building.
    pub async fn output_with(
        &self,
        info: &str,
        make: impl FnOnce() -> Value + Send + 'static,
    ) -> Result<Option<Tuple>, ComponentError> {
        let key = output_key(&self.component_id()?, info)
            .map_err(|e| ComponentError::Space(e.to_string()))?;
        if self.space.is_read(&key) {
            lock(&self.withheld).remove(info);
            let tuple = self.space.set(key, make()).await?;
            lock(&self.written).insert(info.to_string());
            return Ok(Some(tuple));
        }
        self.withdraw(info).await?;
        lock(&self.withheld).insert(info.to_string(), Box::new(make));
        Ok(None)
    }

    /// Waits until someone reads output `info` (at once if someone does now).
    async fn until_read(&self, info: &str) -> Result<(), ComponentError> {
        let key = output_key(&self.component_id()?, info)
            .map_err(|e| ComponentError::Space(e.to_string()))?;
        let mut readers = self.space.watch_readers(&key);
        if readers.wait_for(|read| *read).await.is_err() {
            // The space cannot tell: never.
            std::future::pending::<()>().await;
        }
        Ok(())
    }

    /// Waits until a reader comes for an output kept back because nobody read it, and publishes
    /// its last value then; pending while nothing is kept back. A body waits on it beside its
    /// inputs and its period, so that a consumer wired to it gets a value at once rather than at
    /// the body's next output.
    pub async fn readers_came(&self) -> Result<(), ComponentError> {
        let infos: Vec<String> = lock(&self.withheld).keys().cloned().collect();
        if infos.is_empty() {
            std::future::pending::<()>().await;
        }
        let waits = infos.into_iter().map(|info| {
            Box::pin(async move {
                self.until_read(&info).await?;
                Ok::<String, ComponentError>(info)
            })
        });
        let (came, _, _) = futures_util::future::select_all(waits).await;
        let info = came?;
        let make = lock(&self.withheld).remove(&info);
        if let Some(make) = make {
            self.output_with(&info, make).await?;
        }
        Ok(())
    }

    /// Deletes output `info` if this run wrote it and has not withdrawn it since: what a body
    /// does that stops producing an output nobody reads (`Context::output` does it itself).
    /// Nothing of it is kept back.
    pub async fn withdraw(&self, info: &str) -> Result<(), ComponentError> {
        lock(&self.withheld).remove(info);
        if lock(&self.written).remove(info) {
            let key = output_key(&self.component_id()?, info)
                .map_err(|e| ComponentError::Space(e.to_string()))?;
            self.space.delete(key).await?;
        }
        Ok(())
    }

    /// Follows the inputs `infos` through their `C.mi-INFO` meta-tuples.
    pub async fn inputs(&self, infos: &[&str]) -> Result<Inputs, ComponentError> {
        let mut subscriptions = Vec::new();
        for info in infos {
            let meta = input_key(&self.component_id()?, info, &[])
                .map_err(|e| ComponentError::Space(e.to_string()))?;
            let sub = self.space.subscribe_meta(self.peis().clone(), meta).await?;
            subscriptions.push((info.to_string(), sub));
        }
        Ok(Inputs {
            subscriptions,
            latest: BTreeMap::new(),
            clock: self.clock.clone(),
        })
    }

    /// Sleeps for `d` on the PEIS's clock.
    pub async fn sleep(&self, d: Duration) {
        let deadline = self.clock.now().saturating_add(d);
        self.clock.sleep_until(deadline).await;
    }
}

fn lock<T>(mutex: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A component's inputs: the latest value of each, as it arrives.
pub struct Inputs {
    subscriptions: Vec<(String, Subscription)>,
    latest: BTreeMap<String, (Tuple, Timestamp)>,
    clock: Arc<dyn Clock>,
}

impl std::fmt::Debug for Inputs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Inputs")
            .field(
                "infos",
                &self
                    .subscriptions
                    .iter()
                    .map(|(i, _)| i)
                    .collect::<Vec<_>>(),
            )
            .finish_non_exhaustive()
    }
}

impl Inputs {
    /// Takes in every update that has arrived, without waiting.
    pub fn poll(&mut self) {
        let now = self.clock.now();
        for (info, sub) in &mut self.subscriptions {
            while let Some(event) = sub.try_next() {
                match event {
                    TupleEvent::Changed(t) => {
                        self.latest.insert(info.clone(), (t, now));
                    }
                    TupleEvent::Removed { .. } | TupleEvent::Retargeted { .. } => {
                        self.latest.remove(info);
                    }
                }
            }
        }
    }

    /// Waits for the next update of any input and takes it in; `false` when
    /// every subscription has ended.
    pub async fn changed(&mut self) -> bool {
        let event = std::future::poll_fn(|cx| {
            let mut open = false;
            for (i, (_, sub)) in self.subscriptions.iter_mut().enumerate() {
                match sub.poll_event(cx) {
                    std::task::Poll::Ready(Some(event)) => {
                        return std::task::Poll::Ready(Some((i, event)));
                    }
                    std::task::Poll::Ready(None) => {}
                    std::task::Poll::Pending => open = true,
                }
            }
            if open {
                std::task::Poll::Pending
            } else {
                std::task::Poll::Ready(None)
            }
        })
        .await;
        let Some((i, event)) = event else {
            return false;
        };
        // Received now, when it arrived, not when the wait began.
        let now = self.clock.now();
        let info = self.subscriptions[i].0.clone();
        match event {
            TupleEvent::Changed(t) => {
                self.latest.insert(info, (t, now));
            }
            TupleEvent::Removed { .. } | TupleEvent::Retargeted { .. } => {
                self.latest.remove(&info);
            }
        }
        self.poll();
        true
    }

    /// The latest value of `info`, if any.
    pub fn latest(&self, info: &str) -> Option<&Tuple> {
        self.latest.get(info).map(|(t, _)| t)
    }

    /// The inputs with no value received within `max_age` (self-monitoring:
    /// a component with missing inputs reports `waiting` naming them).
    pub fn missing(&self, max_age: Duration) -> Vec<String> {
        let now = self.clock.now();
        self.subscriptions
            .iter()
            .filter(|(info, _)| {
                self.latest
                    .get(info)
                    .is_none_or(|(_, at)| now.saturating_duration_since(*at) > max_age)
            })
            .map(|(info, _)| info.clone())
            .collect()
    }
}
