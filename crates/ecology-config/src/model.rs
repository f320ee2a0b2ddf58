//! The configuration planner's vocabulary: what a caller asks ([`Request`],
//! [`Options`], [`Exclusion`]) and what it gets back ([`Outcome`] with its
//! [`Configuration`]s, [`Status`], [`Stats`]), plus the goal errors
//! ([`RequestError`]). Plain data, no planning.

use std::fmt;
use std::str::FromStr;

use ecology_core::Budget;
use ecology_domain::{Call, Domain, EcologyState, Name, Power};

use crate::explain::Explanation;

/// What to plan for.
#[derive(Debug, Clone, Copy)]
pub struct Request<'a> {
    /// The functionalities, tasks and methods.
    pub domain: &'a Domain,
    /// The acquired ecology state.
    pub state: &'a EcologyState,
    /// The ground goal: a task or functionality instance.
    pub goal: &'a Call,
    /// Components and PEIS that must not be used (failed ones).
    pub exclusions: &'a [Exclusion],
}

/// Something the planner must not use.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Exclusion {
    /// One component, written `PEIS:COMPONENT`.
    Component {
        /// The PEIS.
        peis: String,
        /// The component on it.
        component: String,
    },
    /// Every component of a PEIS, written `PEIS`.
    Peis(String),
}

impl FromStr for Exclusion {
    type Err = String;

    fn from_str(s: &str) -> Result<Exclusion, String> {
        let s = s.trim().to_lowercase();
        let valid = |part: &str| {
            !part.is_empty()
                && !part
                    .chars()
                    .any(|c| c.is_whitespace() || "():;?".contains(c))
        };
        match s.split_once(':') {
            Some((peis, component)) if valid(peis) && valid(component) => {
                Ok(Exclusion::Component {
                    peis: peis.to_string(),
                    component: component.to_string(),
                })
            }
            None if valid(&s) => Ok(Exclusion::Peis(s)),
            _ => Err(format!("`{s}` is not PEIS:COMPONENT or PEIS")),
        }
    }
}

impl fmt::Display for Exclusion {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Exclusion::Component { peis, component } => write!(f, "{peis}:{component}"),
            Exclusion::Peis(peis) => f.write_str(peis),
        }
    }
}

/// How to search.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Options {
    /// How many configurations to return, cheapest first (1: the optimum).
    pub count: usize,
    /// When to stop early.
    pub budget: Budget,
    /// When no configuration exists, say why ([`Outcome::explanation`]).
    /// Without it, a goal that cannot be provided even with every binding
    /// forgotten is answered before grounding: a caller that only asks
    /// whether a configuration exists gets the answer in a fraction of the
    /// time.
    pub explain: bool,
}

impl Default for Options {
    fn default() -> Options {
        Options {
            count: 1,
            budget: Budget::default(),
            explain: true,
        }
    }
}

/// A goal the domain cannot plan for.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RequestError {
    /// No task or functionality has the goal's name.
    #[error("unknown task or functionality `{name}` in the goal")]
    UnknownGoal {
        /// The goal's name.
        name: String,
    },
    /// The goal has the wrong number of arguments.
    #[error("wrong arity: `{name}` takes {expected} arguments, the goal gives {given}")]
    Arity {
        /// The goal's name.
        name: String,
        /// Parameters of the task or functionality.
        expected: usize,
        /// Arguments in the goal.
        given: usize,
    },
    /// The goal has a variable.
    #[error("the goal must be ground, but `{0}` is a variable")]
    NotGround(String),
}

/// A functionality instance in a configuration.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FunctionalityInstance {
    /// Where it sits in the decomposition, like `f0/f1/f2`.
    pub label: Name,
    /// The functionality's name.
    pub name: Name,
    /// Its ground arguments.
    pub args: Vec<Name>,
    /// The PEIS it runs on.
    pub peis: Name,
    /// The component that runs it.
    pub component: Name,
    /// Whether the component is running now (off means it must be started).
    pub power: Power,
    /// What it costs in this configuration.
    pub cost: u64,
    /// Its inputs, ground, like `(image hsm)`.
    pub inputs: Vec<Name>,
    /// Its outputs, ground.
    pub outputs: Vec<Name>,
    /// Its postcondition, ground; a component with one reports `done`.
    pub postcondition: Vec<Name>,
}

impl FunctionalityInstance {
    /// `(name arg ...)`
    pub fn call(&self) -> String {
        let mut out = format!("({}", self.name);
        for a in &self.args {
            out.push(' ');
            out.push_str(a);
        }
        out.push(')');
        out
    }
}

/// A channel: an output of one functionality feeding an input of another.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelInstance {
    /// The producer's label.
    pub from: Name,
    /// The consumer's label.
    pub to: Name,
    /// The information, like `(image hsm)`.
    pub info: Name,
    /// The kind of information alone, like `image`: the suffix of the
    /// producer's output tuple `C.out.image` and the consumer's input `C.mi-image`.
    pub info_name: Name,
    /// The producer's PEIS.
    pub from_peis: Name,
    /// The producer's component.
    pub from_component: Name,
    /// The consumer's PEIS.
    pub to_peis: Name,
    /// The consumer's component.
    pub to_component: Name,
    /// Whether it crosses between PEIS.
    pub remote: bool,
    /// What it costs.
    pub cost: u64,
}

/// An admissible configuration.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Configuration {
    /// Its total cost.
    pub cost: u64,
    /// Whether it is proven to be among the cheapest (see [`Outcome::status`]).
    pub optimal: bool,
    /// Its functionality instances, one per component.
    pub functionalities: Vec<FunctionalityInstance>,
    /// Its channels.
    pub channels: Vec<ChannelInstance>,
}

impl Configuration {
    /// Whether it uses component `component` of `peis`.
    pub fn uses(&self, peis: &str, component: &str) -> bool {
        self.functionalities
            .iter()
            .any(|f| *f.peis == *peis && *f.component == *component)
    }

    /// A canonical text identifying the configuration regardless of labels.
    pub fn signature(&self) -> String {
        let mut parts: Vec<String> = self
            .functionalities
            .iter()
            .map(|f| format!("{}:{}={}", f.peis, f.component, f.call()))
            .collect();
        parts.sort();
        let mut channels: Vec<String> = self
            .channels
            .iter()
            .map(|c| {
                format!(
                    "{}:{}>{}:{}{}",
                    c.from_peis, c.from_component, c.to_peis, c.to_component, c.info
                )
            })
            .collect();
        channels.sort();
        parts.extend(channels);
        parts.join(" ")
    }
}

impl fmt::Display for Configuration {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let width = self
            .functionalities
            .iter()
            .map(|x| x.label.len())
            .max()
            .unwrap_or(0);
        for x in &self.functionalities {
            let power = match x.power {
                Power::On => "on",
                Power::Off => "off, started",
            };
            writeln!(
                f,
                "{:width$}  {:<36} {}:{} ({power})  cost {}",
                x.label,
                x.call(),
                x.peis,
                x.component,
                x.cost
            )?;
        }
        if !self.channels.is_empty() {
            writeln!(f, "channels:")?;
            for c in &self.channels {
                let place = if c.remote {
                    format!("remote {} → {}", c.from_peis, c.to_peis)
                } else {
                    format!("local on {}", c.from_peis)
                };
                let cost = if c.cost > 0 {
                    format!("  cost {}", c.cost)
                } else {
                    String::new()
                };
                writeln!(f, "  {} → {}  {}  ({place}){cost}", c.from, c.to, c.info)?;
            }
        }
        let proof = if self.optimal {
            "proven optimal"
        } else {
            "not proven optimal"
        };
        write!(f, "total cost {} ({proof})", self.cost)
    }
}

/// How a search ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Status {
    /// The configurations returned are proven to be the cheapest (all of them,
    /// when fewer than asked for exist; none, when no configuration exists).
    Proven,
    /// The budget ran out: the configurations are the best found, not proven.
    BudgetExceeded,
}

impl Status {
    /// `Proven` for a search that ran to its end, `BudgetExceeded` for one cut short.
    pub(crate) fn of(complete: bool) -> Status {
        if complete {
            Status::Proven
        } else {
            Status::BudgetExceeded
        }
    }
}

/// Counts of one search.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Search nodes expanded.
    pub expanded: u64,
    /// Search nodes generated.
    pub generated: u64,
    /// Ground method alternatives built (method and binding pairs).
    pub alternatives: u64,
    /// Time spent, by the caller's clock.
    pub micros: u64,
    /// When the first configuration was found, by the caller's clock.
    pub first_micros: Option<u64>,
}

/// The result of a search.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// Admissible configurations, cheapest first.
    pub configurations: Vec<Configuration>,
    /// Whether they are proven.
    pub status: Status,
    /// When there are none and [`Options::explain`] asked: why.
    pub explanation: Option<Explanation>,
    /// When the budget ran out: no configuration costs less than this.
    pub lower_bound: Option<u64>,
    /// Counts.
    pub stats: Stats,
}

/// Where a running search stands; [`crate::plan_observed`] reports it between
/// steps, so that a long search can show its progress.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Snapshot {
    /// Search nodes expanded so far.
    pub expanded: u64,
    /// The cost of the cheapest configuration found so far.
    pub best: Option<u64>,
    /// No configuration not yet accepted costs less than this.
    pub lower_bound: Option<u64>,
}
