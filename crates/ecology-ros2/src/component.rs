//! A component whose body is a ROS 2 lifecycle node, driven through the [`Agent`].
//!
//! A run (the host starts one when the component is on and has params) asks the agent to set the
//! node's parameters, configure and activate it; it publishes each input's tuple to the node's
//! input topic as it changes, each feed's tuple to its topic, and the node's outputs as the
//! component's `C.out.INFO` tuples; the node's status becomes `C.status`. The run ends when the
//! node reports `done` (`Ok`), fails or vanishes (`Err`, which the host reports as `error` with
//! the cause), or the host cancels it (params changed or cleared, switched off): then the node is
//! deactivated and cleaned up.

use std::collections::HashMap;

use ecology_peis::{BoxFuture, Component, ComponentError, Context};
use ecology_tuples::{TupleEvent, TuplePattern, TupleSpace};

use crate::agent::{Agent, AgentEvent};
use crate::spec::NodeSpec;

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
            loop {
                tokio::select! {
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
                            ctx.output(&info, ecology_tuples::Value::text(text)).await?;
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

/// The next change of any feed's tuple; pending while there is none.
async fn next_feed(feeds: &mut [(String, ecology_tuples::Subscription)]) -> (String, TupleEvent) {
    std::future::poll_fn(|cx| {
        for (name, sub) in feeds.iter_mut() {
            if let std::task::Poll::Ready(Some(event)) = sub.poll_event(cx) {
                return std::task::Poll::Ready((name.clone(), event));
            }
        }
        std::task::Poll::Pending
    })
    .await
}
