//! The executive's event log: every step, timestamped, as typed values (components,
//! functionalities and channels as data), and its one text rendering, the timeline (`Display`).
//! [`LogEvent::name`] names each event for the JSON form, whose codec is `ecology_view::log_json`
//! (JSON lives at the edge; the log types themselves are not serializable).

use std::fmt;
use std::time::Duration;

use ecology_domain::Name;

/// A component named in the log: its PEIS and its name, shown `peis:component`. Plain names,
/// not tuple-space ids: a configuration may name components the tuple space cannot.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct LogComponent {
    /// Its PEIS.
    pub peis: Name,
    /// The component's name on its PEIS.
    pub component: Name,
}

impl LogComponent {
    /// The component `component` of PEIS `peis`.
    pub fn new(peis: impl Into<Name>, component: impl Into<Name>) -> Self {
        Self {
            peis: peis.into(),
            component: component.into(),
        }
    }
}

impl fmt::Display for LogComponent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.peis, self.component)
    }
}

/// A functionality instance of a configuration, shown `(call) on peis:component`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogFunctionality {
    /// Its call, `(name arg…)`: the params its component is given.
    pub call: String,
    /// The component that runs it.
    pub component: LogComponent,
}

impl fmt::Display for LogFunctionality {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} on {}", self.call, self.component)
    }
}

/// A channel of a configuration, shown `from → to (information)`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogChannel {
    /// The producer.
    pub from: LogComponent,
    /// The consumer.
    pub to: LogComponent,
    /// The information, like `(image hsm)`.
    pub info: Name,
}

impl fmt::Display for LogChannel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} → {} {}", self.from, self.to, self.info)
    }
}

/// A component left out of a configuration because it reports an error, shown
/// `peis:component reports error (cause)`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogUnavailable {
    /// The component.
    pub component: LogComponent,
    /// The cause it reports.
    pub cause: String,
}

impl fmt::Display for LogUnavailable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} reports error ({})", self.component, self.cause)
    }
}

/// One logged event with its time.
#[derive(Debug, Clone, PartialEq)]
pub struct LogEntry {
    /// Time since the run started.
    pub t: Duration,
    /// What happened.
    pub event: LogEvent,
}

/// What the executive did or saw.
#[derive(Debug, Clone, PartialEq)]
pub enum LogEvent {
    /// A plan of actions to execute.
    Plan {
        /// The actions, in order (a conditional plan's, up to its first branching).
        actions: Vec<String>,
        /// The observations a conditional plan branches on after them; empty for a sequence.
        branches: Vec<String>,
    },
    /// An action failed and the task goes on with a new plan.
    Replanned {
        /// The action that failed.
        failed: String,
        /// The new plan's actions, in order (up to its first branching).
        actions: Vec<String>,
        /// The observations the new plan branches on after them; empty for a sequence.
        branches: Vec<String>,
    },
    /// An action started.
    ActionStarted {
        /// Its index in the plan.
        index: usize,
        /// The action.
        action: String,
    },
    /// The ecology state was acquired.
    StateAcquired {
        /// PEIS present.
        peis: usize,
        /// Components known on them.
        components: usize,
        /// Components left out, and why.
        unavailable: Vec<LogUnavailable>,
        /// How long building the state took (0 without a stopwatch).
        micros: u64,
    },
    /// A configuration was chosen.
    Configuration {
        /// The configuration goal.
        goal: String,
        /// Its cost.
        cost: u64,
        /// Whether proven optimal.
        optimal: bool,
        /// Its functionality instances.
        functionalities: Vec<LogFunctionality>,
        /// The costs of the alternatives considered, cheapest first (the chosen one included).
        alternatives: Vec<u64>,
        /// Whether this replaces a failed configuration.
        reconfiguration: bool,
        /// How long planning took (0 without a stopwatch).
        micros: u64,
    },
    /// Deploy commands were sent.
    Deployed {
        /// Components asked to switch on.
        switched_on: Vec<LogComponent>,
        /// Channels wired.
        channels: Vec<LogChannel>,
    },
    /// Every component of the configuration reports running.
    Running {
        /// Components of the previous configuration switched off.
        switched_off: Vec<LogComponent>,
    },
    /// A component failed.
    Failure {
        /// Its PEIS.
        peis: String,
        /// The component.
        component: String,
        /// Why.
        cause: String,
    },
    /// A PEIS joined while the task ran.
    PeisJoined {
        /// The PEIS.
        peis: String,
    },
    /// A PEIS left (withdrew its presence, or its lease ran out) while the task ran.
    PeisLeft {
        /// The PEIS.
        peis: String,
    },
    /// A PEIS started a new run (it restarted) while the task ran.
    PeisRestarted {
        /// The PEIS.
        peis: String,
    },
    /// A remote set the executive asked for failed.
    RemoteSetFailed {
        /// The owner of the tuple.
        owner: String,
        /// The key.
        key: String,
        /// Why.
        reason: String,
    },
    /// A component this executive asked for is held by other executives with other params or
    /// wiring (its owner refused the request): not a failure, it is left out until it is released.
    Held {
        /// The component's PEIS.
        peis: String,
        /// The component.
        component: String,
        /// Who holds it.
        holders: Vec<String>,
    },
    /// A remote set that got no answer from a PEIS still present was sent again.
    RemoteSetRetried {
        /// The owner of the tuple.
        owner: String,
        /// The key.
        key: String,
    },
    /// The task ended and released what it used.
    Released {
        /// Components the task had switched on, now switched off.
        switched_off: Vec<LogComponent>,
        /// Components it only borrowed (on before), whose params were cleared.
        stopped: Vec<LogComponent>,
        /// Components on PEIS out of reach, left to them: a PEIS host puts back by itself
        /// what an executive that is gone had asked for.
        unreachable: Vec<LogComponent>,
    },
    /// A PEIS that had left came back in the same run: what the task had written to it and
    /// no longer uses was put back.
    Reclaimed {
        /// The PEIS.
        peis: String,
        /// Components switched off.
        switched_off: Vec<LogComponent>,
        /// Components whose params were cleared.
        stopped: Vec<LogComponent>,
    },
    /// Most of the ecology left at once: the executive lost it (its own network, or the
    /// router), rather than those PEIS their components. It acts on nothing while it waits.
    EcologyLost {
        /// The PEIS that left.
        gone: Vec<String>,
        /// How many PEIS were present before.
        present: usize,
        /// How long it waits for them.
        waiting: Duration,
    },
    /// The action has no configuration without PEIS that left: it waits for them.
    AwaitingReturn {
        /// The PEIS it waits for.
        gone: Vec<String>,
        /// How long it waits.
        waiting: Duration,
    },
    /// A component still `waiting` when its grace ran out, which no configuration can do
    /// without, is given longer before it is blamed.
    WaitingLonger {
        /// Its PEIS.
        peis: String,
        /// The component.
        component: String,
        /// What it waits for: its cause (empty when it gave none).
        waited_for: String,
        /// How much longer.
        waiting: Duration,
    },
    /// Most of the lost ecology is back: the action goes on, reconfigured.
    EcologyBack {
        /// The PEIS back.
        back: Vec<String>,
        /// Those still gone.
        missing: Vec<String>,
    },
    /// The action is being reconfigured without what failed.
    Reconfiguration {
        /// Everything excluded for this action so far.
        excluded: Vec<String>,
    },
    /// An action completed.
    ActionDone {
        /// Its index.
        index: usize,
        /// The action.
        action: String,
    },
    /// A sensing action's configuration reported what it was to observe.
    Observed {
        /// The action's index.
        index: usize,
        /// The action.
        action: String,
        /// What it observed: `(atom)` or `(not (atom))`, joined by spaces.
        observation: String,
    },
    /// A conditional plan went on with the branch of what was observed.
    Branch {
        /// The branch's observation.
        observation: String,
        /// How probable the planner thought it.
        probability: f64,
        /// The branch's actions before its next branching.
        actions: Vec<String>,
    },
    /// An action failed: no configuration, or timeout.
    ActionFailed {
        /// Its index.
        index: usize,
        /// The action.
        action: String,
        /// Why, with the planner's explanation.
        reason: String,
    },
    /// Every action completed.
    TaskDone,
    /// The task failed.
    TaskFailed {
        /// Why.
        reason: String,
    },
}

impl LogEvent {
    /// The PEIS, component and cause of a [`LogEvent::Failure`]; `None` for any other event.
    pub fn failure(&self) -> Option<(&str, &str, &str)> {
        match self {
            LogEvent::Failure {
                peis,
                component,
                cause,
            } => Some((peis, component, cause)),
            _ => None,
        }
    }

    /// The event's name in the JSON-lines log.
    pub fn name(&self) -> &'static str {
        match self {
            LogEvent::Plan { .. } => "plan",
            LogEvent::Replanned { .. } => "replan",
            LogEvent::ActionStarted { .. } => "action_started",
            LogEvent::StateAcquired { .. } => "state_acquired",
            LogEvent::Configuration { .. } => "configuration",
            LogEvent::Deployed { .. } => "deployed",
            LogEvent::Running { .. } => "running",
            LogEvent::Failure { .. } => "failure",
            LogEvent::Reconfiguration { .. } => "reconfiguration",
            LogEvent::PeisJoined { .. } => "peis_joined",
            LogEvent::PeisLeft { .. } => "peis_left",
            LogEvent::PeisRestarted { .. } => "peis_restarted",
            LogEvent::RemoteSetFailed { .. } => "remote_set_failed",
            LogEvent::RemoteSetRetried { .. } => "remote_set_retried",
            LogEvent::Held { .. } => "held",
            LogEvent::Released { .. } => "released",
            LogEvent::Reclaimed { .. } => "reclaimed",
            LogEvent::EcologyLost { .. } => "ecology_lost",
            LogEvent::EcologyBack { .. } => "ecology_back",
            LogEvent::AwaitingReturn { .. } => "awaiting_return",
            LogEvent::WaitingLonger { .. } => "waiting_longer",
            LogEvent::ActionDone { .. } => "action_done",
            LogEvent::ActionFailed { .. } => "action_failed",
            LogEvent::Observed { .. } => "observed",
            LogEvent::Branch { .. } => "branch",
            LogEvent::TaskDone => "task_done",
            LogEvent::TaskFailed { .. } => "task_failed",
        }
    }
}

/// `items` shown and joined by `separator`.
fn joined<T: fmt::Display>(items: &[T], separator: &str) -> String {
    items
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(separator)
}

/// "switched off A, B", "stopped C": what a release did, for the timeline.
fn released_parts(switched_off: &[LogComponent], stopped: &[LogComponent]) -> Vec<String> {
    let mut parts = Vec::new();
    if !switched_off.is_empty() {
        parts.push(format!("switched off {}", joined(switched_off, ", ")));
    }
    if !stopped.is_empty() {
        parts.push(format!("stopped {}", joined(stopped, ", ")));
    }
    parts
}

/// `, then by what it observes: A | B` after a conditional plan's first actions.
fn write_branches(f: &mut fmt::Formatter<'_>, branches: &[String]) -> fmt::Result {
    if branches.is_empty() {
        Ok(())
    } else {
        write!(f, ", then by what it observes: {}", branches.join(" | "))
    }
}

/// The entry's line of the timeline: its time, then the event.
impl fmt::Display for LogEntry {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:>8.3}s  {}", self.t.as_secs_f64(), self.event)
    }
}

/// The event as the timeline says it: steps within an action are indented by two spaces, and
/// some events take more lines (a configuration's functionalities, a failure's explanation).
impl fmt::Display for LogEvent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LogEvent::Plan { actions, branches } => {
                write!(f, "plan: {}", actions.join(" → "))?;
                write_branches(f, branches)
            }
            LogEvent::Replanned {
                failed, actions, ..
            } if actions.is_empty() => {
                write!(f, "replan without {failed}: nothing left to do")
            }
            LogEvent::Replanned {
                failed,
                actions,
                branches,
            } => {
                write!(f, "replan without {failed}: {}", actions.join(" → "))?;
                write_branches(f, branches)
            }
            LogEvent::ActionStarted { index, action } => {
                write!(f, "action {}: {action}", index + 1)
            }
            LogEvent::StateAcquired {
                peis,
                components,
                unavailable,
                ..
            } => {
                write!(f, "  state acquired: {peis} PEIS, {components} components")?;
                if !unavailable.is_empty() {
                    write!(f, "; unavailable: {}", joined(unavailable, ", "))?;
                }
                Ok(())
            }
            LogEvent::Configuration {
                goal,
                cost,
                optimal,
                functionalities,
                alternatives,
                reconfiguration,
                ..
            } => {
                let what = if *reconfiguration {
                    "reconfigured"
                } else {
                    "configuration"
                };
                let proof = if *optimal {
                    "optimal"
                } else {
                    "not proven optimal"
                };
                let alts: Vec<String> = alternatives.iter().map(u64::to_string).collect();
                write!(
                    f,
                    "  {what} for {goal}: cost {cost} ({proof}; alternatives {})",
                    alts.join(", ")
                )?;
                for func in functionalities {
                    write!(f, "\n              {func}")?;
                }
                Ok(())
            }
            LogEvent::Deployed {
                switched_on,
                channels,
            } => {
                let on = if switched_on.is_empty() {
                    "nothing to switch on".to_string()
                } else {
                    format!("switch on {}", joined(switched_on, ", "))
                };
                write!(f, "  deploy: {on}; {} channels", channels.len())
            }
            LogEvent::Running { switched_off } if switched_off.is_empty() => {
                write!(f, "  running")
            }
            LogEvent::Running { switched_off } => {
                write!(f, "  running; switched off {}", joined(switched_off, ", "))
            }
            LogEvent::Failure {
                peis,
                component,
                cause,
            } => write!(f, "  FAILURE {peis}:{component}: {cause}"),
            LogEvent::Reconfiguration { excluded } => {
                write!(f, "  reconfiguring without {}", excluded.join(", "))
            }
            LogEvent::PeisJoined { peis } => write!(f, "  PEIS {peis} joined"),
            LogEvent::PeisLeft { peis } => write!(f, "  PEIS {peis} left"),
            LogEvent::PeisRestarted { peis } => write!(f, "  PEIS {peis} restarted"),
            LogEvent::RemoteSetFailed { owner, key, reason } => {
                write!(f, "  remote set of {owner}:{key} failed: {reason}")
            }
            LogEvent::Held {
                peis,
                component,
                holders,
            } => write!(
                f,
                "  {peis}:{component} is held by {}: done without until it is released",
                holders.join(", ")
            ),
            LogEvent::RemoteSetRetried { owner, key } => {
                write!(
                    f,
                    "  remote set of {owner}:{key} sent again: {owner} is still present"
                )
            }
            LogEvent::Released {
                switched_off,
                stopped,
                unreachable,
            } => {
                let mut parts = released_parts(switched_off, stopped);
                if !unreachable.is_empty() {
                    parts.push(format!(
                        "left to their PEIS, out of reach: {}",
                        joined(unreachable, ", ")
                    ));
                }
                write!(f, "released: {}", parts.join("; "))
            }
            LogEvent::Reclaimed {
                peis,
                switched_off,
                stopped,
            } => {
                let parts = released_parts(switched_off, stopped);
                write!(
                    f,
                    "  PEIS {peis} is back; no longer used: {}",
                    parts.join("; ")
                )
            }
            LogEvent::EcologyLost {
                gone,
                present,
                waiting,
            } => write!(
                f,
                "  LOST THE ECOLOGY: {} of {present} PEIS left at once ({}); waiting up to {waiting:?} for them",
                gone.len(),
                gone.join(", ")
            ),
            LogEvent::AwaitingReturn { gone, waiting } => write!(
                f,
                "  no configuration without {}: waiting up to {waiting:?} for {} to return",
                gone.join(", "),
                if gone.len() == 1 { "it" } else { "them" }
            ),
            LogEvent::WaitingLonger {
                peis,
                component,
                waited_for,
                waiting,
            } => {
                write!(
                    f,
                    "  no configuration without {peis}:{component}: waiting up to {waiting:?} more for"
                )?;
                if waited_for.is_empty() {
                    write!(f, " its inputs")
                } else {
                    write!(f, " {waited_for}")
                }
            }
            LogEvent::EcologyBack { back, missing } => {
                write!(f, "  the ecology is back: {}", back.join(", "))?;
                if !missing.is_empty() {
                    write!(f, " (still gone: {})", missing.join(", "))?;
                }
                Ok(())
            }
            LogEvent::ActionDone { index, action } => {
                write!(f, "action {} done: {action}", index + 1)
            }
            LogEvent::ActionFailed {
                index,
                action,
                reason,
            } => write!(f, "action {} FAILED: {action}\n{reason}", index + 1),
            LogEvent::Observed { observation, .. } => write!(f, "  observed {observation}"),
            LogEvent::Branch {
                observation,
                probability,
                actions,
            } => {
                let then = if actions.is_empty() {
                    "nothing left to do".to_string()
                } else {
                    actions.join(" → ")
                };
                write!(
                    f,
                    "branch on {observation} (probability {}): {then}",
                    (probability * 1e4).round() / 1e4
                )
            }
            LogEvent::TaskDone => write!(f, "task done"),
            LogEvent::TaskFailed { reason } => write!(f, "task FAILED: {reason}"),
        }
    }
}
