//! The agent: one Python process per `ecology peis` process, on `rclpy`, that drives the ROS 2
//! nodes of its components (lifecycle transitions, parameters, the topics of their inputs and
//! outputs) and watches them. It speaks JSON lines on its stdin and stdout; its source is
//! `agent/ecology_ros2_agent.py`, built into the binary, whose docstring is the protocol.

use std::collections::{HashMap, VecDeque};
use std::process::Stdio;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use serde_json::{Value as Json, json};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::process::{Child, Command};
use tokio::sync::mpsc;
use tokio::task::JoinSet;

use crate::spec::NodeSpec;

/// The agent's source, run as `PYTHON -c SOURCE`.
pub const AGENT_SOURCE: &str = include_str!("../agent/ecology_ros2_agent.py");

/// How long the agent may take to bring `rclpy` up.
const READY_WITHIN: Duration = Duration::from_secs(20);
/// How long the agent may take to put its nodes back and exit when asked.
const QUIT_WITHIN: Duration = Duration::from_secs(5);
/// How many of the agent's last stderr lines an error quotes.
const TAIL: usize = 12;

/// The environment variable naming the Python that runs the agent.
pub const PYTHON_VARIABLE: &str = "ECOLOGY_ROS2_PYTHON";

/// Why the agent could not run.
#[derive(Debug, thiserror::Error)]
pub enum AgentError {
    /// The Python could not be started.
    #[error("cannot run `{python}` for the ROS 2 agent: {error}")]
    Spawn {
        /// The Python.
        python: String,
        /// Why.
        error: std::io::Error,
    },
    /// The agent exited, or did not say it was ready in time.
    #[error("the ROS 2 agent on `{python}` did not start: {why}{hint}")]
    NotReady {
        /// The Python.
        python: String,
        /// What it said or did.
        why: String,
        /// What to do about it.
        hint: String,
    },
}

/// What the agent says of one component.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum AgentEvent {
    /// Its status changed (`initializing`, `running`, `waiting`, `done`, `error`), with a cause.
    Status {
        /// The status.
        status: String,
        /// Why, or empty.
        cause: String,
    },
    /// Its node published an output, as text.
    Output {
        /// The information.
        info: String,
        /// The value.
        text: String,
    },
    /// It was put back: the node's lifecycle state now (`unconfigured`, or `gone`).
    Stopped(String),
    /// The agent is gone, and why.
    Gone(String),
}

/// A handle on the running agent; clones share it.
#[derive(Clone)]
pub struct Agent {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for Agent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Agent")
            .field("python", &self.inner.python)
            .field("rmw", &self.inner.rmw)
            .finish_non_exhaustive()
    }
}

struct Inner {
    python: String,
    rmw: String,
    lines: mpsc::UnboundedSender<String>,
    log: Arc<dyn Fn(String) + Send + Sync>,
    shared: Arc<Mutex<Shared>>,
    child: tokio::sync::Mutex<Option<Child>>,
    tasks: Mutex<JoinSet<()>>,
}

/// What the agent's reader and the components share.
#[derive(Default)]
struct Shared {
    /// Where each component's events go.
    routes: HashMap<String, mpsc::UnboundedSender<AgentEvent>>,
    /// Each component's current run: a stop is sent only for the run that is still current.
    runs: HashMap<String, u64>,
    /// The agent's last stderr lines.
    tail: VecDeque<String>,
    /// Why the agent is gone, once it is.
    gone: Option<String>,
    /// Whether it said it was ready: until then its stderr is only kept, for the error that
    /// quotes it.
    ready: bool,
}

fn lock(shared: &Mutex<Shared>) -> MutexGuard<'_, Shared> {
    shared.lock().unwrap_or_else(PoisonError::into_inner)
}

/// The Python that runs the agent: `ECOLOGY_ROS2_PYTHON`, else `python3`.
pub fn default_python() -> String {
    std::env::var(PYTHON_VARIABLE).unwrap_or_else(|_| "python3".to_string())
}

impl Agent {
    /// Starts the agent on `python` and waits until `rclpy` is up. `log` receives the agent's
    /// stderr lines and its complaints about requests.
    pub async fn start(
        python: &str,
        log: Arc<dyn Fn(String) + Send + Sync>,
    ) -> Result<Agent, AgentError> {
        let mut child = Command::new(python)
            .arg("-u")
            .arg("-c")
            .arg(AGENT_SOURCE)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .kill_on_drop(true)
            .spawn()
            .map_err(|error| AgentError::Spawn {
                python: python.to_string(),
                error,
            })?;
        let (Some(mut stdin), Some(stdout), Some(stderr)) =
            (child.stdin.take(), child.stdout.take(), child.stderr.take())
        else {
            return Err(AgentError::NotReady {
                python: python.to_string(),
                why: "its pipes could not be opened".to_string(),
                hint: String::new(),
            });
        };
        let shared = Arc::new(Mutex::new(Shared::default()));
        let mut tasks = JoinSet::new();
        let tail_of = shared.clone();
        let stderr_log = log.clone();
        tasks.spawn(async move {
            let mut lines = BufReader::new(stderr).lines();
            while let Ok(Some(line)) = lines.next_line().await {
                let mut s = lock(&tail_of);
                if s.tail.len() == TAIL {
                    s.tail.pop_front();
                }
                s.tail.push_back(line.clone());
                let ready = s.ready;
                drop(s);
                if ready {
                    stderr_log(line);
                }
            }
        });
        let mut stdout = BufReader::new(stdout).lines();
        let ready = tokio::time::timeout(READY_WITHIN, async {
            loop {
                match stdout.next_line().await {
                    Ok(Some(line)) => {
                        if let Ok(event) = serde_json::from_str::<Json>(&line)
                            && event["ev"] == "ready"
                        {
                            return Ok(event);
                        }
                    }
                    Ok(None) | Err(_) => return Err("it exited".to_string()),
                }
            }
        })
        .await;
        let ready = match ready {
            Ok(Ok(ready)) => ready,
            Ok(Err(why)) => {
                // Let the stderr reader take in the last lines before quoting them.
                let status = child.wait().await.ok();
                tokio::time::sleep(Duration::from_millis(50)).await;
                return Err(not_ready(python, &shared, why, status));
            }
            Err(_) => {
                let why = format!("it did not say it was ready within {READY_WITHIN:?}");
                return Err(not_ready(python, &shared, why, None));
            }
        };
        let rmw = ready["rmw"]
            .as_str()
            .unwrap_or("an unknown RMW")
            .to_string();
        lock(&shared).ready = true;
        let (lines, mut outgoing) = mpsc::unbounded_channel::<String>();
        tasks.spawn(async move {
            while let Some(line) = outgoing.recv().await {
                if stdin.write_all(line.as_bytes()).await.is_err()
                    || stdin.write_all(b"\n").await.is_err()
                    || stdin.flush().await.is_err()
                {
                    break;
                }
            }
        });
        let routes = shared.clone();
        let route_log = log.clone();
        tasks.spawn(async move {
            loop {
                let line = stdout.next_line().await;
                let Ok(Some(line)) = line else { break };
                route(&routes, &line, &*route_log);
            }
            let mut s = lock(&routes);
            let why = match s.tail.back() {
                Some(last) => format!("the ROS 2 agent exited (its last words: {last})"),
                None => "the ROS 2 agent exited".to_string(),
            };
            s.gone = Some(why.clone());
            for route in s.routes.values() {
                let _ = route.send(AgentEvent::Gone(why.clone()));
            }
        });
        Ok(Agent {
            inner: Arc::new(Inner {
                python: python.to_string(),
                rmw,
                lines,
                log,
                shared,
                child: tokio::sync::Mutex::new(Some(child)),
                tasks: Mutex::new(tasks),
            }),
        })
    }

    /// The ROS middleware the agent runs on, such as `rmw_fastrtps_cpp`.
    pub fn rmw(&self) -> &str {
        &self.inner.rmw
    }

    fn send(&self, request: Json) {
        let _ = self.inner.lines.send(request.to_string());
    }

    /// Tells the agent of component `id` (`PEIS:C`) and its node.
    pub fn declare(&self, id: &str, spec: &NodeSpec) {
        let port =
            |p: &crate::spec::Port| json!({"info": p.info, "topic": p.topic, "type": p.message});
        let feeds: Vec<Json> = spec
            .feeds
            .iter()
            .map(|f| json!({"name": f.tuple, "topic": f.topic, "type": f.message}))
            .collect();
        self.send(json!({
            "op": "declare",
            "id": id,
            "node": spec.node,
            "inputs": spec.inputs.iter().map(port).collect::<Vec<_>>(),
            "outputs": spec.outputs.iter().map(port).collect::<Vec<_>>(),
            "feeds": feeds,
            "status_topic": spec.status_topic,
        }));
    }

    /// Starts a new run of component `id`: its events from now on, and the run's number.
    pub(crate) fn begin(&self, id: &str) -> (mpsc::UnboundedReceiver<AgentEvent>, u64) {
        let (tx, rx) = mpsc::unbounded_channel();
        let mut s = lock(&self.inner.shared);
        if let Some(why) = &s.gone {
            let _ = tx.send(AgentEvent::Gone(why.clone()));
        }
        s.routes.insert(id.to_string(), tx);
        let run = s.runs.entry(id.to_string()).or_insert(0);
        *run += 1;
        (rx, *run)
    }

    /// Asks for the functionality instance `params` on component `id`, with its ROS parameters.
    pub(crate) fn start_node(&self, id: &str, params: &str, parameters: &[(String, String)]) {
        let parameters: serde_json::Map<String, Json> = parameters
            .iter()
            .map(|(k, v)| (k.clone(), Json::String(v.clone())))
            .collect();
        self.send(json!({"op": "start", "id": id, "params": params, "parameters": parameters}));
    }

    /// Puts component `id`'s node back (deactivate, clean up), if `run` is still its current run.
    pub(crate) fn stop_node(&self, id: &str, run: u64) {
        let current = lock(&self.inner.shared).runs.get(id).copied();
        if current == Some(run) {
            self.send(json!({"op": "stop", "id": id}));
        }
    }

    /// Publishes `text` to component `id`'s input `info`.
    pub(crate) fn input(&self, id: &str, info: &str, text: &str) {
        self.send(json!({"op": "input", "id": id, "info": info, "text": text}));
    }

    /// Relays topic `from` to component `id`'s input `info`, in DDS.
    pub(crate) fn relay(&self, id: &str, info: &str, from: &str) {
        (self.inner.log)(format!("{id} reads {info} from {from}, relayed in DDS"));
        self.send(json!({"op": "relay", "id": id, "info": info, "from": from}));
    }

    /// Stops relaying to component `id`'s input `info`.
    pub(crate) fn unrelay(&self, id: &str, info: &str) {
        (self.inner.log)(format!("{id} reads {info} as tuples again"));
        self.send(json!({"op": "unrelay", "id": id, "info": info}));
    }

    /// Tells the agent whether anyone reads component `id`'s output `info`: it forwards the
    /// output's topic only while someone does.
    pub(crate) fn read(&self, id: &str, info: &str, read: bool) {
        let op = if read { "read" } else { "unread" };
        self.send(json!({"op": op, "id": id, "info": info}));
    }

    /// Publishes `text` on component `id`'s feed of tuple `name`.
    pub(crate) fn feed(&self, id: &str, name: &str, text: &str) {
        self.send(json!({"op": "feed", "id": id, "name": name, "text": text}));
    }

    /// Asks the agent to put every node back and exit, and waits for it (at most 5 s, then it is
    /// killed). Returns what could not be done, if anything.
    pub async fn quit(&self) -> Option<String> {
        self.send(json!({"op": "quit"}));
        let mut child = self.inner.child.lock().await;
        let outcome = match child.as_mut() {
            None => None,
            Some(c) => match tokio::time::timeout(QUIT_WITHIN, c.wait()).await {
                Ok(Ok(status)) if status.success() => None,
                Ok(Ok(status)) => Some(format!("the ROS 2 agent exited with {status}")),
                Ok(Err(e)) => Some(format!("the ROS 2 agent could not be waited for: {e}")),
                Err(_) => {
                    let _ = c.kill().await;
                    Some(format!(
                        "the ROS 2 agent did not exit within {QUIT_WITHIN:?} and was killed: \
                         some nodes may still be active"
                    ))
                }
            },
        };
        *child = None;
        let mut tasks = std::mem::take(
            &mut *self
                .inner
                .tasks
                .lock()
                .unwrap_or_else(PoisonError::into_inner),
        );
        tasks.shutdown().await;
        outcome
    }
}

/// The error of an agent that did not come up, quoting its stderr and saying what to install.
fn not_ready(
    python: &str,
    shared: &Mutex<Shared>,
    why: String,
    status: Option<std::process::ExitStatus>,
) -> AgentError {
    let s = lock(shared);
    let mut why = why;
    if let Some(status) = status {
        why.push_str(&format!(" ({status})"));
    }
    let tail: Vec<&str> = s.tail.iter().map(String::as_str).collect();
    if !tail.is_empty() {
        why.push_str(&format!(":\n  {}", tail.join("\n  ")));
    }
    let hint = if tail.iter().any(|l| l.contains("No module named")) {
        format!(
            "\nhint: install ROS 2 from PyPI into that Python (`pip install ros-rclpy ros-rmw-fastrtps-cpp \
             ros-std-msgs ros-geometry-msgs ros-sensor-msgs ros-lifecycle-msgs`), or name a Python that \
             has it with {PYTHON_VARIABLE}"
        )
    } else {
        String::new()
    };
    AgentError::NotReady {
        python: python.to_string(),
        why,
        hint,
    }
}

/// Sends one line the agent printed to the component it concerns.
fn route(shared: &Mutex<Shared>, line: &str, log: &(dyn Fn(String) + Send + Sync)) {
    let Ok(event) = serde_json::from_str::<Json>(line) else {
        log(format!(
            "ros2 agent printed a line that is not JSON: {line}"
        ));
        return;
    };
    let text = |field: &str| event[field].as_str().unwrap_or("").to_string();
    let parsed = match event["ev"].as_str() {
        Some("status") => AgentEvent::Status {
            status: text("status"),
            cause: text("cause"),
        },
        Some("output") => AgentEvent::Output {
            info: text("info"),
            text: text("text"),
        },
        Some("stopped") => AgentEvent::Stopped(text("state")),
        Some("error") => {
            log(format!("ros2 agent: {}", text("text")));
            return;
        }
        _ => return,
    };
    let id = text("id");
    if let Some(route) = lock(shared).routes.get(&id) {
        let _ = route.send(parsed);
    }
}
