//! A component whose body is a ROS 2 lifecycle node, driven through the [`Agent`].
//!
//! A run (the host starts one when the component is on and has params) asks the agent to set the
//! node's parameters, configure and activate it; it publishes each input's tuple to the node's
//! input topic as it changes, each feed's tuple to its topic, and the node's outputs as the
//! component's `C.out.INFO` tuples; the node's status becomes `C.status`. The run ends when the
//! node reports `done` (`Ok`), fails or vanishes (`Err`, which the host reports as `error` with
//! the cause), or the host cancels it (params changed or cleared, switched off): then the node is
//! deactivated and cleaned up.
//!
//! A channel from another ROS 2 node's output stays in DDS: each such output is announced as the
//! tuple `C.topic.INFO` = `TOPIC TYPE` ([`announce_topics`]), and when an input's meta-tuple points
//! at an output so announced, of the input's message type, the agent relays that topic to the
//! input's topic instead of passing on the tuple.
//!
//! An output goes out only while someone reads it: the run asks who reads each output every
//! [`READERS_EVERY`] and tells the agent, which subscribes to the output's topic only while
//! someone does. The node then sees no subscriber on a topic nobody reads.

use std::collections::HashMap;
use std::time::Duration;

use ecology_peis::{BoxFuture, Component, ComponentError, Context};
use ecology_tuples::contract::input_key;
use ecology_tuples::{
    ComponentId, Key, MetaPointer, Subscription, TupleError, TupleEvent, TuplePattern, TupleSpace,
    Value,
};

use crate::agent::{Agent, AgentEvent};
use crate::spec::NodeSpec;

/// How often a run asks whether anyone reads each output of its node.
pub const READERS_EVERY: Duration = Duration::from_millis(250);

/// Component `id` (`PEIS:C`) backed by the node of `spec`.
#[derive(Debug, Clone)]
pub struct Ros2Component {
    agent: Agent,
    id: String,
    spec: NodeSpec,
}

impl Ros2Component {
    /// The component `id` (`PEIS:C`), whose node `spec` describes (resolved); declares it to
    /// the agent.
    pub fn new(agent: Agent, id: String, spec: NodeSpec) -> Ros2Component {
        agent.declare(&id, &spec);
        Ros2Component { agent, id, spec }
    }
}

/// The key `C.topic.INFO` announcing the topic of component `c`'s output `info`.
pub fn topic_key(c: &str, info: &str) -> Result<Key, TupleError> {
    Key::new(&format!("{c}.topic.{info}")).map_err(TupleError::Invalid)
}

/// Publishes `C.topic.INFO` = `TOPIC TYPE` for each output of component `c`'s node, so that a
/// ROS 2 node wired to it reads the topic directly (through the agent's relay).
pub async fn announce_topics<S: TupleSpace>(
    space: &S,
    c: &str,
    spec: &NodeSpec,
) -> Result<(), TupleError> {
    for output in &spec.outputs {
        let text = format!("{} {}", output.topic, output.message);
        space
            .set(topic_key(c, &output.info)?, Value::text(text))
            .await?;
    }
    Ok(())
}

/// The topic to relay to an input of message type `message` whose meta-tuple now reads `meta`:
/// the announced topic of the output it points at, when that output is a ROS 2 topic of the same
/// type.
async fn relayed_topic<S: TupleSpace>(space: &S, meta: &str, message: &str) -> Option<String> {
    let pointer = MetaPointer::parse(meta).ok()?;
    let (producer, info) = pointer.key.as_str().split_once(".out.")?;
    let announced = space
        .get(pointer.owner.clone(), topic_key(producer, info).ok()?)
        .await
        .ok()??;
    let text = announced.text().ok()?;
    let (topic, kind) = text.trim().split_once(' ')?;
    (kind.trim() == message).then(|| topic.to_string())
}

/// Puts the node back when its run ends, however it ends.
struct PutBack {
    agent: Agent,
    id: String,
    run: u64,
}

impl Drop for PutBack {
    fn drop(&mut self) {
        self.agent.stop_node(&self.id, self.run);
    }
}

impl<S: TupleSpace> Component<S> for Ros2Component {
    fn run(&self, ctx: Context<S>) -> BoxFuture<Result<(), ComponentError>> {
        let agent = self.agent.clone();
        let id = self.id.clone();
        let spec = self.spec.clone();
        Box::pin(async move {
            let parameters = spec
                .parameters(&ctx.args())
                .map_err(ComponentError::Fault)?;
            let (mut events, run) = agent.begin(&id);
            let _put_back = PutBack {
                agent: agent.clone(),
                id: id.clone(),
                run,
            };
            agent.start_node(&id, ctx.params(), &parameters);
            let infos: Vec<&str> = spec.inputs.iter().map(|p| p.info.as_str()).collect();
            let mut inputs = ctx.inputs(&infos).await?;
            let mut inputs_open = !infos.is_empty();
            // What was last passed on of each input: (epoch, seq), so each version goes once.
            let mut passed: HashMap<String, (u64, u64)> = HashMap::new();
            let mut feeds = Vec::new();
            for feed in &spec.feeds {
                let pattern = TuplePattern::parse(&feed.tuple)
                    .map_err(|e| ComponentError::Fault(format!("feed {}: {e}", feed.tuple)))?;
                feeds.push((feed.tuple.clone(), ctx.space().subscribe(pattern).await?));
            }
            // Each input's meta-tuple, to relay what another node publishes in DDS; the inputs
            // relayed are not passed on as tuples.
            let me = ComponentId::new(ctx.component())
                .map_err(|e| ComponentError::Space(e.to_string()))?;
            let mut wiring = Vec::new();
            for input in &spec.inputs {
                let key = input_key(&me, &input.info, &[])
                    .map_err(|e| ComponentError::Space(e.to_string()))?;
                let pattern = TuplePattern::exact(ctx.peis().clone(), &key);
                wiring.push((input.info.clone(), ctx.space().subscribe(pattern).await?));
            }
            let mut relayed: HashMap<String, String> = HashMap::new();
            // Whether each output was read when last asked; said to the agent at the first ask
            // and at every change, so that it forwards only outputs someone reads.
            let mut read: HashMap<String, bool> = HashMap::new();
            let mut ask_readers = ctx.clock().now();
            loop {
                tokio::select! {
                    () = ctx.clock().sleep_until(ask_readers), if !spec.outputs.is_empty() => {
                        for output in &spec.outputs {
                            let now_read = ctx.is_read(&output.info)?;
                            if read.insert(output.info.clone(), now_read) != Some(now_read) {
                                agent.read(&id, &output.info, now_read);
                                if !now_read {
                                    ctx.withdraw(&output.info).await?;
                                }
                            }
                        }
                        ask_readers = ask_readers.saturating_add(READERS_EVERY);
                    }
                    event = events.recv() => match event {
                        Some(AgentEvent::Status { status, cause }) => match status.as_str() {
                            "error" => return Err(ComponentError::Fault(cause)),
                            "done" => {
                                ctx.status("done", None).await?;
                                return Ok(());
                            }
                            _ => {
                                let cause = (!cause.is_empty()).then_some(cause.as_str());
                                ctx.status(&status, cause).await?;
                            }
                        },
                        Some(AgentEvent::Output { info, text }) => {
                            ctx.output(&info, Value::text(text)).await?;
                        }
                        Some(AgentEvent::Stopped(_)) => {}
                        Some(AgentEvent::Gone(why)) => return Err(ComponentError::Fault(why)),
                        None => {
                            return Err(ComponentError::Fault("the ROS 2 agent is gone".into()));
                        }
                    },
                    open = inputs.changed(), if inputs_open => {
                        inputs_open = open;
                        for info in &infos {
                            if relayed.contains_key(*info) {
                                continue;
                            }
                            let Some(tuple) = inputs.latest(info) else { continue };
                            let version = (tuple.epoch, tuple.seq);
                            if passed.get(*info) == Some(&version) {
                                continue;
                            }
                            passed.insert((*info).to_string(), version);
                            if let Ok(text) = tuple.text() {
                                agent.input(&id, info, text);
                            }
                        }
                    }
                    (info, event) = next_feed(&mut wiring), if !wiring.is_empty() => {
                        let Some(input) = spec.inputs.iter().find(|p| p.info == info) else { continue };
                        let topic = match &event {
                            TupleEvent::Changed(meta) => match meta.text() {
                                Ok(text) => relayed_topic(ctx.space(), text, &input.message).await,
                                Err(_) => None,
                            },
                            _ => None,
                        };
                        match topic {
                            Some(topic) if relayed.get(&info) != Some(&topic) => {
                                agent.relay(&id, &info, &topic);
                                relayed.insert(info, topic);
                            }
                            Some(_) => {}
                            None => {
                                if relayed.remove(&info).is_some() {
                                    agent.unrelay(&id, &info);
                                    passed.remove(&info);
                                }
                            }
                        }
                    }
                    (name, event) = next_feed(&mut feeds), if !feeds.is_empty() => {
                        if let TupleEvent::Changed(tuple) = event
                            && let Ok(text) = tuple.text()
                        {
                            agent.feed(&id, &name, text);
                        }
                    }
                }
            }
        })
    }
}

/// The next change of any of `subscriptions`, with its name; pending while there is none.
async fn next_feed(subscriptions: &mut [(String, Subscription)]) -> (String, TupleEvent) {
    std::future::poll_fn(|cx| {
        for (name, sub) in subscriptions.iter_mut() {
            if let std::task::Poll::Ready(Some(event)) = sub.poll_event(cx) {
                return std::task::Poll::Ready((name.clone(), event));
            }
        }
        std::task::Poll::Pending
    })
    .await
}
