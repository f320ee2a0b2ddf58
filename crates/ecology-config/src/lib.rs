//! The configuration planner of Ecology (the paper's Section V).
//!
//! Given a [`Domain`], an [`EcologyState`] and a goal such as
//! `(navigate astrid bedroom)`, it finds the cheapest *admissible*
//! configuration: functionality instances on PEIS-components and the channels
//! between them, such that every precondition holds in the state and every
//! input is connected to a compatible output at a sufficient rate. It can
//! also list admissible configurations cheapest first, and when none exists it
//! says why with an [`Explanation`].
//!
//! The planner is sans-IO: time comes from a [`Clock`] the caller passes in.
//!
//! ```
//! use ecology_config::{plan, Options, Request, Status};
//! let domain = ecology_domain::parse_domain(br#"(define (domain d)
//!   (:functionality cam :parameters (?p ?c) :component (?p ?c)
//!     :precondition (pc ?p cam ?c) :output ((image ?p)) :cost 5)
//!   (:task see :parameters (?p))
//!   (:method see-with-camera :parameters (?p ?c) :task (see ?p)
//!     :precondition (pc ?p cam ?c) :subtasks ((f1 (cam ?p ?c)))))"#).unwrap();
//! let state = ecology_domain::parse_facts(b"(pc robot cam c1) (cost robot c1 3 on)").unwrap();
//! let goal = ecology_domain::parse_goal("(see robot)").unwrap();
//! let request = Request { domain: &domain, state: &state, goal: &goal, exclusions: &[] };
//! let outcome = plan(&request, &Options::default(), &ecology_config::NoClock).unwrap();
//! assert_eq!(outcome.status, Status::Proven);
//! assert_eq!(outcome.configurations[0].cost, 3);
//! ```

mod compile;
mod cost;
mod explain;
mod ground;
pub mod oracle;
mod relaxed;
mod relevant;
mod search;
mod share;
pub mod synthetic;

#[cfg(test)]
mod tests;

use std::fmt;
use std::str::FromStr;
use std::time::Duration;

use ecology_domain::{Call, Domain, EcologyState, Name, Power};

pub use cost::{CostModel, PaperCost};
/// The budget and the caller's clock live in `ecology-core`, shared with the action planner.
pub use ecology_core::{Budget, Clock, NoClock, WallClock};
pub use explain::Explanation;
pub use relevant::component_types;

use compile::{Callee, Compiled, Schema};
use ground::{Ctx, Excluded};

use search::Engine;

/// The planner's first step alone, for the benchmark of reading a state: every name of the
/// state interned and its facts indexed for the domain's preconditions. Returns the number of
/// symbols.
#[doc(hidden)]
pub fn compile_state(domain: &Domain, state: &EcologyState) -> usize {
    let schema = std::sync::Arc::new(compile::Schema::new(domain));
    compile::Compiled::new_until(schema, state, &|| false)
        .syms
        .len()
}

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
    fn of(complete: bool) -> Status {
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

/// Where a running search stands; [`plan_observed`] reports it between
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

/// A search that can be run in steps under an outside budget.
pub struct Search<'a> {
    engine: Engine<'a>,
    /// The search over chosen providers, when the domain has provider shape.
    shared: Option<share::Shared>,
    count: usize,
    explain: bool,
    dived: bool,
}

impl fmt::Debug for Search<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Search")
            .field("count", &self.count)
            .field("expanded", &self.engine.expanded)
            .finish_non_exhaustive()
    }
}

/// What one call of [`Search::step`] reached.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Progress {
    /// More work remains.
    InProgress,
    /// The search is over; [`Search::finish`] has the proven result.
    Done,
}

impl<'a> Search<'a> {
    /// Prepares a search: compiles the domain and state, grounds the goal.
    pub fn new(
        request: &Request<'a>,
        cost_model: &'a dyn CostModel,
        options: &Options,
    ) -> Result<Search<'a>, RequestError> {
        let (schema, goal) = schema_and_goal(request, None)?;
        Ok(Search::new_until(
            request,
            schema,
            goal,
            cost_model,
            options,
            &|| false,
        ))
    }

    /// Like [`Search::new`], asking `over` between phases and now and then
    /// while grounding whether the budget ran out; if it did, the search is
    /// [`Search::cut`] and finishes at once with nothing and no bound.
    /// `schema` is the request's domain compiled, `goal` its goal checked
    /// against it ([`check_goal`]).
    fn new_until(
        request: &Request<'a>,
        schema: std::sync::Arc<Schema>,
        (callee, goal_args): Goal<'_>,
        cost_model: &'a dyn CostModel,
        options: &Options,
        over: &dyn Fn() -> bool,
    ) -> Search<'a> {
        let mut compiled = Compiled::new_until(schema, request.state, over);
        let args: Vec<compile::Sym> = goal_args
            .iter()
            .map(|a| compiled.syms.intern_str(a))
            .collect();
        let excluded = excluded(&mut compiled, request.exclusions);
        let cut = compiled.cut || over();
        let ctx = Ctx::new(request.domain, compiled, cost_model, excluded, callee);
        let mut engine = Engine::new(ctx, callee, &args, cut, options.count <= 1, &|| over());
        let shared = if engine.graph.cut || over() {
            engine.graph.cut = true;
            None
        } else if engine.graph.item(engine.root).lb == ground::INFEASIBLE {
            // Nothing can be provided (an information without a provider that
            // is not excluded, say): proven at once, without building the
            // search; the tree search finishes with the explanation.
            None
        } else {
            let mut cut = false;
            let shared = share::Shared::new(&engine, options.count, over, &mut cut);
            engine.graph.cut = cut;
            shared
        };
        Search {
            engine,
            shared,
            count: options.count.max(1),
            explain: options.explain,
            dived: false,
        }
    }

    /// Runs at most `expansions` steps.
    pub fn step(&mut self, expansions: u64) -> Progress {
        self.step_until(expansions, &|| false)
    }

    /// Like [`Search::step`], asking `over` now and then during the provider
    /// search's dives (which may wire a whole configuration in one step)
    /// whether the budget ran out; if so, returns early.
    fn step_until(&mut self, expansions: u64, over: &dyn Fn() -> bool) -> Progress {
        if let Some(shared) = &mut self.shared {
            return if shared.step(expansions, over) {
                Progress::Done
            } else {
                Progress::InProgress
            };
        }
        if !self.dived && self.count == 1 {
            self.dived = true;
            self.engine.dive(expansions.max(1));
        }
        for _ in 0..expansions {
            if self.engine.accepted.len() >= self.count || self.engine.is_exhausted() {
                return Progress::Done;
            }
            self.engine.step(self.count == 1);
        }
        if self.engine.accepted.len() >= self.count || self.engine.is_exhausted() {
            Progress::Done
        } else {
            Progress::InProgress
        }
    }

    /// Nodes expanded so far.
    pub fn expanded(&self) -> u64 {
        match &self.shared {
            Some(shared) => shared.expanded,
            None => self.engine.expanded,
        }
    }

    /// Whether preparing the search was cut short by the budget: it has
    /// nothing to search, and its bound means nothing.
    fn cut(&self) -> bool {
        self.engine.graph.cut
    }

    /// Where the search stands.
    pub fn snapshot(&self) -> Snapshot {
        Snapshot {
            expanded: self.expanded(),
            best: self.best(),
            lower_bound: match &self.shared {
                Some(shared) => shared.lower_bound(),
                None => self.engine.lower_bound(),
            },
        }
    }

    /// The cost of the cheapest configuration found so far.
    fn best(&self) -> Option<u64> {
        match &self.shared {
            Some(shared) => shared.best(),
            None => {
                let engine = &self.engine;
                let best = engine.accepted.first().or(engine.incumbent.as_ref());
                best.map(|c| c.cost)
            }
        }
    }

    /// Whether a configuration has been found (not necessarily the best).
    pub fn found(&self) -> bool {
        self.best().is_some()
    }

    /// Ends the search. With `complete` false (the budget ran out), returns
    /// the best found so far, not proven.
    pub fn finish(self, complete: bool, elapsed: Duration) -> Outcome {
        self.finish_until(complete, elapsed, &|| false)
    }

    /// Like [`Search::finish`], asking `over` between the configurations it
    /// builds whether the budget ran out; if so, the list is cut short (the
    /// ones built are still the cheapest, but the outcome is not proven).
    fn finish_until(
        mut self,
        complete: bool,
        elapsed: Duration,
        over: &dyn Fn() -> bool,
    ) -> Outcome {
        if let Some(mut shared) = self.shared.take() {
            let lower_bound = if complete { None } else { shared.lower_bound() };
            let (configurations, explanation, whole) =
                shared.finish(&mut self.engine, complete, self.explain, over);
            let lower_bound = match (lower_bound, whole) {
                (None, false) => configurations.last().map(|c| c.cost),
                (bound, _) => bound,
            };
            return Outcome {
                configurations,
                status: Status::of(complete && whole),
                explanation,
                lower_bound,
                stats: Stats {
                    expanded: shared.expanded,
                    generated: shared.generated,
                    alternatives: self.engine.graph.alternatives,
                    micros: elapsed.as_micros() as u64,
                    first_micros: None,
                },
            };
        }
        let mut configurations = std::mem::take(&mut self.engine.accepted);
        let proven_count = configurations.len();
        if configurations.is_empty()
            && let Some(incumbent) = self.engine.incumbent.take()
        {
            configurations.push(incumbent);
        }
        for (i, c) in configurations.iter_mut().enumerate() {
            c.optimal = complete || i < proven_count;
        }
        let explanation = (configurations.is_empty() && complete && self.explain).then(|| {
            explain::explain(
                &self.engine.ctx,
                &self.engine.graph,
                self.engine.root,
                &self.engine.rejections,
            )
        });
        Outcome {
            configurations,
            status: Status::of(complete),
            explanation,
            lower_bound: if complete {
                None
            } else {
                self.engine.lower_bound()
            },
            stats: Stats {
                expanded: self.engine.expanded,
                generated: self.engine.generated,
                alternatives: self.engine.graph.alternatives,
                micros: elapsed.as_micros() as u64,
                first_micros: None,
            },
        }
    }
}

/// Plans with the paper's cost model; see [`plan_with`].
pub fn plan<'a>(
    request: &Request<'a>,
    options: &Options,
    clock: &dyn Clock,
) -> Result<Outcome, RequestError> {
    plan_with(request, &PaperCost, options, clock)
}

/// Finds the cheapest admissible configuration (or the `options.count`
/// cheapest), stopping early when the budget runs out. Compiles the domain
/// first; to plan many times with one domain, see [`Planner`].
pub fn plan_with<'a>(
    request: &Request<'a>,
    cost_model: &'a dyn CostModel,
    options: &Options,
    clock: &dyn Clock,
) -> Result<Outcome, RequestError> {
    plan_prepared(request, None, cost_model, options, clock, &mut |_| {})
}

/// As [`plan_with`], calling `observe` between steps of the search (every
/// few dozen expansions) with where it stands: a caller can show the
/// progress of a long search.
pub fn plan_observed<'a>(
    request: &Request<'a>,
    cost_model: &'a dyn CostModel,
    options: &Options,
    clock: &dyn Clock,
    observe: &mut dyn FnMut(Snapshot),
) -> Result<Outcome, RequestError> {
    plan_prepared(request, None, cost_model, options, clock, observe)
}

/// A domain compiled once, to plan with it again and again: the executive
/// plans every action of a task with one domain and a new state. A plan
/// through it does the work of [`plan`] less compiling the domain's schemas;
/// the results are the same.
///
/// ```
/// use ecology_config::{NoClock, Options, Planner, Request};
/// let domain = ecology_domain::parse_domain(br#"(define (domain d)
///   (:functionality cam :parameters (?p ?c) :component (?p ?c)
///     :precondition (pc ?p cam ?c) :output ((image ?p)) :cost 5)
///   (:task see :parameters (?p))
///   (:method see-with-camera :parameters (?p ?c) :task (see ?p)
///     :precondition (pc ?p cam ?c) :subtasks ((f1 (cam ?p ?c)))))"#).unwrap();
/// let goal = ecology_domain::parse_goal("(see robot)").unwrap();
/// let planner = Planner::new(domain);
/// // One state, then the next: the domain is compiled once.
/// for (facts, cost) in [("(pc robot cam c1) (cost robot c1 3 on)", 3),
///                       ("(pc robot cam c2) (cost robot c2 2 on)", 2)] {
///     let state = ecology_domain::parse_facts(facts.as_bytes()).unwrap();
///     let request = Request { domain: planner.domain(), state: &state, goal: &goal, exclusions: &[] };
///     let outcome = planner.plan(&request, &Options::default(), &NoClock).unwrap();
///     assert_eq!(outcome.configurations[0].cost, cost);
/// }
/// ```
#[derive(Debug, Clone)]
pub struct Planner {
    domain: Domain,
    schema: std::sync::Arc<Schema>,
}

impl Planner {
    /// Compiles `domain`, and keeps it.
    pub fn new(domain: Domain) -> Planner {
        let schema = std::sync::Arc::new(Schema::new(&domain));
        Planner { domain, schema }
    }

    /// The domain it plans with.
    pub fn domain(&self) -> &Domain {
        &self.domain
    }

    /// Whether `domain` is this planner's own ([`Planner::domain`]). An
    /// equal copy is not recognised: telling would cost a comparison of
    /// whole domains on every plan.
    fn prepared_for(&self, domain: &Domain) -> bool {
        std::ptr::eq(domain, &self.domain)
    }

    /// Plans with the paper's cost model; see [`Planner::plan_with`].
    pub fn plan(
        &self,
        request: &Request<'_>,
        options: &Options,
        clock: &dyn Clock,
    ) -> Result<Outcome, RequestError> {
        plan_prepared(request, Some(self), &PaperCost, options, clock, &mut |_| {})
    }

    /// As [`plan_with`], with the domain compiled already: the request's
    /// `domain` must be [`Planner::domain`] for that. A request with any
    /// other domain (an equal copy too) is planned as [`plan_with`] plans
    /// it, compiling that domain.
    pub fn plan_with<'a>(
        &self,
        request: &Request<'a>,
        cost_model: &'a dyn CostModel,
        options: &Options,
        clock: &dyn Clock,
    ) -> Result<Outcome, RequestError> {
        plan_prepared(request, Some(self), cost_model, options, clock, &mut |_| {})
    }
}

fn plan_prepared<'a>(
    request: &Request<'a>,
    planner: Option<&Planner>,
    cost_model: &'a dyn CostModel,
    options: &Options,
    clock: &dyn Clock,
    observe: &mut dyn FnMut(Snapshot),
) -> Result<Outcome, RequestError> {
    const SLICE: u64 = 64;
    let over_time = || {
        options
            .budget
            .max_time
            .is_some_and(|t| clock.elapsed() >= t)
    };
    let (schema, goal) = schema_and_goal(request, planner)?;
    if !options.explain
        && schema.relaxed.proves_none(
            &schema,
            request.state,
            goal.0,
            &goal.1,
            request.exclusions,
            &over_time,
        )
    {
        return Ok(Outcome {
            configurations: Vec::new(),
            status: Status::Proven,
            explanation: None,
            lower_bound: None,
            stats: Stats {
                micros: clock.elapsed().as_micros() as u64,
                ..Stats::default()
            },
        });
    }
    let mut search = Search::new_until(request, schema, goal, cost_model, options, &over_time);
    if search.cut() {
        // The bound is the goal's when grounding was complete, else none.
        return Ok(search.finish(false, clock.elapsed()));
    }
    let mut first = None;
    let finish = |search: Search<'a>, complete: bool, first: Option<Duration>| {
        let mut outcome = search.finish_until(complete, Duration::ZERO, &over_time);
        outcome.stats.micros = clock.elapsed().as_micros() as u64;
        outcome.stats.first_micros = first
            .filter(|_| !outcome.configurations.is_empty())
            .map(|t: Duration| t.as_micros() as u64);
        outcome
    };
    // The provider search's first step is its greedy dive alone, one
    // expansion per input it wires: allow it a whole configuration.
    const DIVE: u64 = 1024;
    let mut started = false;
    loop {
        let cap = if !started && search.shared.is_some() {
            DIVE
        } else {
            SLICE
        };
        started = true;
        let slice = match options.budget.max_expansions {
            Some(max) => cap.min(max.saturating_sub(search.expanded())),
            None => cap,
        };
        if slice == 0 || over_time() {
            return Ok(finish(search, false, first));
        }
        let progress = search.step_until(slice, &over_time);
        if first.is_none() && search.found() {
            first = Some(clock.elapsed());
        }
        observe(search.snapshot());
        if progress == Progress::Done {
            return Ok(finish(search, true, first));
        }
    }
}

/// Maps exclusions onto interned symbols; unknown names exclude nothing.
fn excluded(compiled: &mut Compiled, exclusions: &[Exclusion]) -> Excluded {
    let mut out = Excluded::default();
    for e in exclusions {
        match e {
            Exclusion::Component { peis, component } => {
                let p = compiled.syms.intern_str(peis);
                let c = compiled.syms.intern_str(component);
                out.components.insert((p, c));
            }
            Exclusion::Peis(peis) => {
                let p = compiled.syms.intern_str(peis);
                out.peis.insert(p);
            }
        }
    }
    out
}

/// A goal checked against its domain: its callee and arguments.
type Goal<'g> = (Callee, Vec<&'g str>);

/// The request's domain compiled (`planner`'s when it was prepared from that
/// domain), and its goal checked against it.
fn schema_and_goal<'g>(
    request: &Request<'g>,
    planner: Option<&Planner>,
) -> Result<(std::sync::Arc<Schema>, Goal<'g>), RequestError> {
    let schema = match planner {
        Some(planner) if planner.prepared_for(request.domain) => planner.schema.clone(),
        _ => std::sync::Arc::new(Schema::new(request.domain)),
    };
    let goal = check_goal(request.domain, &schema, request.goal)?;
    Ok((schema, goal))
}

/// The goal's callee and arguments, checked against the domain.
fn check_goal<'g>(
    domain: &Domain,
    schema: &Schema,
    goal: &'g Call,
) -> Result<Goal<'g>, RequestError> {
    let Some(&callee) = schema.callee_by_name.get(&goal.name) else {
        return Err(RequestError::UnknownGoal {
            name: goal.name.to_string(),
        });
    };
    let expected = match callee {
        Callee::Func(f) => domain.functionalities[schema.funcs[f as usize].src]
            .params
            .len(),
        Callee::Task(t) => domain.tasks[schema.tasks[t as usize].src].params.len(),
    };
    if expected != goal.args.len() {
        return Err(RequestError::Arity {
            name: goal.name.to_string(),
            expected,
            given: goal.args.len(),
        });
    }
    let mut args = Vec::new();
    for t in &goal.args {
        match t {
            ecology_domain::Term::Const(c) => args.push(&**c),
            ecology_domain::Term::Var(v) => return Err(RequestError::NotGround(format!("?{v}"))),
        }
    }
    Ok((callee, args))
}
