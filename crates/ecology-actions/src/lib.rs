//! The action planner of Ecology (step 1 of the paper's Section III): from a
//! domain's `:action` schemas and a problem, a plan of ground actions, each
//! carrying the `:configure` goal the sequencer hands to the configuration
//! planner.
//!
//! It speaks the STRIPS fragment of PDDL with `:typing`,
//! `:negative-preconditions`, `:equality` and `:action-costs`, and compiles
//! `:disjunctive-preconditions` and `:conditional-effects` away (one operator
//! per variant of an action). [`ground`] turns a domain and a problem into a
//! [`Task`] ([`ground_within`] with [`Instances::Reachable`] only what the
//! initial state reaches); [`plan`] searches it, greedy
//! best-first with the FF heuristic for fast plans or A* with LM-cut for
//! optimal ones, under a [`Budget`]. [`Request`] says where to start and
//! which action instances are unavailable, which is how the executive
//! replans. [`validate`] checks any plan against the schemas.
//!
//! The planner is sans-IO: time comes from a [`Clock`] the caller passes in.
//!
//! ```
//! use ecology_actions::{ground, plan, NoClock, Options, Request, Verdict};
//! let domain = ecology_domain::parse_domain(br#"(define (domain d)
//!   (:requirements :strips :typing)
//!   (:types room)
//!   (:predicates (at ?x - room) (door ?x ?y - room))
//!   (:action go :parameters (?x ?y - room)
//!     :precondition (and (at ?x) (door ?x ?y))
//!     :effect (and (at ?y) (not (at ?x)))))"#).unwrap();
//! let problem = ecology_domain::parse_problem(b"(define (problem p) (:domain d)
//!   (:objects a b c - room)
//!   (:init (at a) (door a b) (door b c))
//!   (:goal (at c)))").unwrap();
//! let task = ground(&domain, &problem).unwrap();
//! let outcome = plan(&Request::new(&task), &Options::default(), &NoClock);
//! let Verdict::Found(found) = &outcome.verdict else { panic!() };
//! assert_eq!(found.to_string(), "(go a b)\n(go b c)\n; cost = 2\n");
//! ```

pub mod conditional;
mod heuristic;
mod improve;
mod landmarks;
mod lmcut;
pub mod oracle;
pub mod oracle_conditional;
pub mod plan_graph;
pub mod problems;
mod queue;
mod relevance;
mod search;
mod task;
mod validate;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_conditional;

use std::fmt;
use std::time::Duration;

use ecology_domain::{Call, Name};

pub use conditional::{
    ConditionalOptions, ConditionalOutcome, ConditionalPlan, ConditionalRequest,
    ConditionalSnapshot, ConditionalVerdict, PlanGraph, PlanNode, plan_conditional,
    plan_conditional_observed,
};
use heuristic::Costs;
pub use heuristic::{Heuristic, HeuristicKind};
pub use task::{
    AtomId, Chance, GroundError, GroundLimits, InstanceError, Instances, MAX_OPERATORS,
    MAX_OUTCOMES, MAX_WORLDS, OpId, Operator, State, StateError, Task, ground, ground_within,
};
pub use validate::{PlanError, validate};

use improve::Neighbourhood;
use landmarks::LandmarkCount;
use search::{Algorithm, Engine, StepResult};

pub use ecology_core::{Budget, Clock, NoClock, WallClock};

/// Which search runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Strategy {
    /// Greedy best-first search: fast, not optimal. With `preferred`, the
    /// heuristic's preferred operators get their own queue. Like every
    /// search that is not proven optimal, its plan is then shortened by
    /// action elimination (detours removed; never costlier).
    Greedy {
        /// The heuristic.
        heuristic: HeuristicKind,
        /// Whether to use preferred operators (only FF offers them).
        preferred: bool,
        /// Whether the landmark count guides the search too, in turn with
        /// the heuristic, each with its own queues (as in LAMA).
        landmarks: bool,
    },
    /// Lazy greedy best-first search (LAMA's): a state's successors wait
    /// in the queue under its value and are evaluated only when taken, so
    /// a state with many successors costs one evaluation, not one each.
    /// With `preferred`, the successors by the heuristic's preferred
    /// operators get their own queue. Plans are shortened by action
    /// elimination, as for [`Strategy::Greedy`].
    Lazy {
        /// The heuristic.
        heuristic: HeuristicKind,
        /// Whether to use preferred operators (only FF offers them).
        preferred: bool,
        /// Whether the landmark count guides the search too, in turn with
        /// the heuristic, each with its own queues (as in LAMA).
        landmarks: bool,
    },
    /// A*: optimal when the heuristic is admissible.
    AStar {
        /// The heuristic.
        heuristic: HeuristicKind,
    },
    /// Weighted A* (best-first on `g + weight * h`): slower than greedy
    /// search, cheaper plans; with an admissible heuristic the plan costs at
    /// most `weight` times the optimum.
    Weighted {
        /// The heuristic.
        heuristic: HeuristicKind,
        /// The weight of `h`, at least 1.
        weight: u64,
    },
}

impl Strategy {
    /// Greedy best-first search with FF and its preferred operators, in
    /// turn with the landmark count (LAMA's pair of heuristics).
    pub const SATISFICING: Strategy = Strategy::Greedy {
        heuristic: HeuristicKind::Ff,
        preferred: true,
        landmarks: true,
    };
    /// Greedy best-first search with `heuristic` (and its preferred
    /// operators, if it is FF), eager or `lazy`, with the landmark count
    /// in turn or not.
    pub fn greedy(heuristic: HeuristicKind, lazy: bool, landmarks: bool) -> Strategy {
        let preferred = heuristic == HeuristicKind::Ff;
        if lazy {
            Strategy::Lazy {
                heuristic,
                preferred,
                landmarks,
            }
        } else {
            Strategy::Greedy {
                heuristic,
                preferred,
                landmarks,
            }
        }
    }

    /// A* with LM-cut.
    pub const OPTIMAL: Strategy = Strategy::AStar {
        heuristic: HeuristicKind::LmCut,
    };
}

/// How to search.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Options {
    /// The search and its heuristic.
    pub strategy: Strategy,
    /// When to stop early.
    pub budget: Budget,
    /// Whether a plan from a search that does not prove it cheapest (greedy
    /// search, weighted A*, A* with an inadmissible heuristic) is followed
    /// by a search for a cheaper one, as LAMA does: weighted A* with weights
    /// 5, 3, 2 and 1 in turn, its heuristic counting the task's costs (each
    /// plus one where some actions cost nothing), pruning every path as dear
    /// as the best plan so far. Its effort is bounded in heuristic
    /// evaluations (2,000 plus a quarter of the first search's), so the plan
    /// does not depend on the clock; when it explores all that is left, the
    /// plan is proven cheapest. Otherwise plan neighbourhood graph search
    /// follows: the cheapest path through the states around the best plan,
    /// with half the searches' work (evaluations times operators used) to
    /// find those states' successors. An outside budget that runs out
    /// during this phase leaves the best plan found.
    pub improve: bool,
}

impl Default for Options {
    fn default() -> Options {
        Options {
            strategy: Strategy::SATISFICING,
            budget: Budget::default(),
            improve: true,
        }
    }
}

impl Options {
    /// Options for an optimal plan (A* with LM-cut).
    pub fn optimal() -> Options {
        Options {
            strategy: Strategy::OPTIMAL,
            budget: Budget::default(),
            improve: false,
        }
    }
}

/// What to plan for: a task, the state to start from, and the action
/// instances not to use.
#[derive(Debug, Clone)]
pub struct Request<'t> {
    /// The ground task.
    pub task: &'t Task,
    /// Where the world is now (the problem's init, unless replanning).
    pub initial: State,
    /// Operators that are unavailable, for example because no configuration
    /// can perform them.
    pub excluded: Vec<OpId>,
}

impl<'t> Request<'t> {
    /// Plans from the task's initial state with every operator available.
    pub fn new(task: &'t Task) -> Request<'t> {
        Request {
            task,
            initial: task.initial().clone(),
            excluded: Vec::new(),
        }
    }

    /// Plans again from `state`, without the `excluded` operators: the
    /// executive's action-level recovery.
    pub fn replan(task: &'t Task, state: State, excluded: Vec<OpId>) -> Request<'t> {
        Request {
            task,
            initial: state,
            excluded,
        }
    }
}

/// One action of a plan.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    /// The operator.
    pub op: OpId,
    /// The action schema's name.
    pub action: Name,
    /// Its arguments.
    pub args: Vec<Name>,
    /// What it costs.
    pub cost: u64,
    /// The ground configuration goal that performs it, if the schema has one.
    pub configure: Option<Call>,
}

impl fmt::Display for Step {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "({}", self.action)?;
        for arg in &self.args {
            write!(f, " {arg}")?;
        }
        f.write_str(")")
    }
}

/// A plan: actions in order and their total cost.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// The actions.
    pub steps: Vec<Step>,
    /// Their total cost.
    pub cost: u64,
}

impl Plan {
    /// The plan made of `ops` in `task`.
    pub fn from_ops(task: &Task, ops: &[OpId]) -> Plan {
        let steps: Vec<Step> = ops
            .iter()
            .map(|&op| {
                let o = task.operator(op);
                Step {
                    op,
                    action: o.action.clone(),
                    args: o.args.clone(),
                    cost: o.cost,
                    configure: o.configure.clone(),
                }
            })
            .collect();
        Plan {
            cost: task.cost_of(ops),
            steps,
        }
    }

    /// The steps as ground calls `(action args...)`, as [`validate`] takes them.
    pub fn calls(&self) -> Vec<Call> {
        self.steps
            .iter()
            .map(|s| Call {
                name: s.action.clone(),
                args: s
                    .args
                    .iter()
                    .map(|a| ecology_domain::Term::Const(a.clone()))
                    .collect(),
                span: ecology_domain::Span::default(),
            })
            .collect()
    }
}

impl fmt::Display for Plan {
    /// One action per line, then `; cost = N`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for step in &self.steps {
            writeln!(f, "{step}")?;
        }
        writeln!(f, "; cost = {}", self.cost)
    }
}

/// Why there is no plan, as proven by the planner.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Unsolvable {
    /// Goal literals that no plan can achieve even when deletes are ignored
    /// (including static facts and equalities that are false).
    Unreachable {
        /// The literals, as written.
        goals: Vec<String>,
    },
    /// Every state reachable from the start was explored.
    Exhausted {
        /// How many states.
        states: u64,
    },
}

impl fmt::Display for Unsolvable {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Unsolvable::Unreachable { goals } => write!(
                f,
                "the goal is unreachable: no sequence of available actions achieves {}",
                goals.join(" ")
            ),
            Unsolvable::Exhausted { states } => write!(
                f,
                "no plan exists: all {states} reachable states were explored"
            ),
        }
    }
}

/// What the search concluded.
#[derive(Debug, Clone, PartialEq)]
pub enum Verdict {
    /// A plan.
    Found(Plan),
    /// Proven: no plan exists.
    Unsolvable(Unsolvable),
    /// The budget ran out before a plan was found or ruled out.
    BudgetExceeded,
}

/// Counts of one search.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Nodes expanded.
    pub expanded: u64,
    /// Successors generated.
    pub generated: u64,
    /// Heuristic evaluations.
    pub evaluated: u64,
    /// Distinct states stored.
    pub states: u64,
    /// The heuristic's estimate of the start state (`None`: a dead end).
    pub initial_h: Option<u64>,
    /// Time spent, by the caller's clock.
    pub micros: u64,
    /// The first plan, when the improvement phase ran after it (see
    /// [`Options::improve`]); the counts above include that phase.
    pub first: Option<FirstPlan>,
}

/// The plan the first search found, before the improvement phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FirstPlan {
    /// Its cost.
    pub cost: u64,
    /// The nodes expanded to find it.
    pub expanded: u64,
}

/// The result of a search.
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    /// The plan, or why there is none.
    pub verdict: Verdict,
    /// Whether the plan is proven cheapest (A* with an admissible heuristic).
    pub optimal: bool,
    /// When a search for a cheapest plan ran out of budget: no plan costs
    /// less than this.
    pub lower_bound: Option<u64>,
    /// Counts.
    pub stats: Stats,
}

/// What one call of [`Search::step`] reached.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Progress {
    /// More work remains.
    InProgress,
    /// The search is over; [`Search::finish`] has the result.
    Done,
}

/// A search that can be run in steps under an outside budget.
#[derive(Debug)]
pub struct Search<'t> {
    engine: Engine<'t>,
    task: &'t Task,
    excluded: Vec<bool>,
    /// The operators neither search uses (see [`Task::useless_operators`]).
    useless: Vec<bool>,
    kind: HeuristicKind,
    initial: State,
    optimal_search: bool,
    /// Whether a first plan is followed by [`Improvement`].
    improve: bool,
    improvement: Option<Improvement<'t>>,
    result: Option<Ended>,
}

/// How a search ended.
#[derive(Debug)]
enum Ended {
    /// With a plan; `true` if it is proven cheapest.
    Plan(Vec<OpId>, bool),
    /// Every reachable state explored, no plan.
    Exhausted,
}

/// The weights of the searches after a first plan, as LAMA's.
const IMPROVE_WEIGHTS: [u64; 4] = [5, 3, 2, 1];

/// The heuristic evaluations the improvement phase may spend beyond a
/// quarter of the first search's: enough for the searches that improve
/// small tasks (elevators-opt11 p01: 90 to 70 in 1,116 evaluations), a
/// few milliseconds where each is cheap.
const IMPROVE_FLOOR: u64 = 2000;

/// The plan neighbourhood rounds may do together 1/`GRAPH_SHARE` of the
/// searches' work before them. The searches' work is their heuristic
/// evaluations times the operators they use (an evaluation explores the
/// relaxed task, its time growing with the operators); the rounds' is the
/// operators looked at for successors, plus some for each transition and
/// each word of a new state (see [`Neighbourhood`]). Measured with timing
/// added for the purpose (not kept) on nine IPC domains, a unit of the
/// rounds' work took 1 to 3 ns and one of the searches' 4 to 22 ns, so the
/// rounds add at most about a third of the searches' time, mostly much less
/// (snake-opt18 p03: 0.6 s after 4.4 s; logistics98 prob04: 23 ms after
/// 370 ms).
const GRAPH_SHARE: u64 = 2;

/// The work the rounds may do however small the searches before them
/// (about a millisecond).
const GRAPH_FLOOR: u64 = 1_000_000;

/// LAMA's improvement phase, bounded: after a first plan, weighted A*
/// (with [`IMPROVE_WEIGHTS`] in turn, the heuristic counting the task's
/// costs, each plus one where some cost nothing) prunes every path that
/// costs as much as the cheapest plan so far.
/// A search that finds a plan gives the next weight the new bound; one
/// that exhausts what is left proves the plan cheapest. The phase ends
/// after [`Improvement::budget`] heuristic evaluations, so a plan never
/// depends on the clock; only the outside budget can cut it shorter.
/// Unless a search proved the plan cheapest, plan neighbourhood graph
/// search ([`Neighbourhood`]) follows around the cheapest plan so far,
/// with a share of the searches' work (see [`GRAPH_SHARE`]).
#[derive(Debug)]
struct Improvement<'t> {
    engine: Engine<'t>,
    /// The index of the engine's weight in [`IMPROVE_WEIGHTS`].
    weight: usize,
    /// Heuristic evaluations left (their cost is most of a search's).
    left: u64,
    /// The cheapest plan so far, and its cost.
    plan: Vec<OpId>,
    cost: u64,
    /// The first search's plan.
    first: FirstPlan,
    /// Counts of the searches before the engine's, and of the
    /// neighbourhood rounds finished.
    done: Stats,
    /// The plan neighbourhood round under way, once the weighted searches
    /// are over.
    graph: Option<Neighbourhood>,
    /// The work the rounds may do, all together: the first may do it all;
    /// one that ends with work left (it reached every state around the
    /// plan) and found a cheaper plan starts another around it, while at
    /// least half of it is left.
    graph_work: u64,
    /// The work the rounds may still do.
    graph_left: u64,
}

impl Improvement<'_> {
    /// The evaluations of the improvement phase after a first search of
    /// `first` evaluations.
    fn budget(first: u64) -> u64 {
        IMPROVE_FLOOR + first / 4
    }

    /// The work of the neighbourhood rounds together after searches that
    /// made `evaluated` heuristic evaluations over `operators` operators.
    fn graph_work(evaluated: u64, operators: u64) -> u64 {
        (evaluated.saturating_mul(operators) / GRAPH_SHARE).max(GRAPH_FLOOR)
    }
}

impl<'t> Search<'t> {
    /// Prepares a search: builds the heuristic and evaluates the start state.
    /// With `improve`, a first plan found by a search that does not prove
    /// it cheapest is followed by a bounded search for a cheaper one
    /// (LAMA's improvement phase; see [`Options::improve`]).
    pub fn new(request: &Request<'t>, strategy: Strategy, improve: bool) -> Search<'t> {
        let task = request.task;
        let mut excluded = vec![false; task.operators().len()];
        for op in &request.excluded {
            if let Some(slot) = excluded.get_mut(op.index()) {
                *slot = true;
            }
        }
        let (kind, algorithm, costs, landmarks) = match strategy {
            // Greedy search orders states by h alone: its heuristic counts
            // actions, whatever they cost.
            Strategy::Greedy {
                heuristic,
                preferred,
                landmarks,
            } => (
                heuristic,
                Algorithm::Greedy { preferred },
                Costs::One,
                landmarks,
            ),
            Strategy::Lazy {
                heuristic,
                preferred,
                landmarks,
            } => (
                heuristic,
                Algorithm::LazyGreedy { preferred },
                Costs::One,
                landmarks,
            ),
            Strategy::AStar { heuristic } => (
                heuristic,
                Algorithm::AStar { weight: 1 },
                Costs::Task,
                false,
            ),
            Strategy::Weighted { heuristic, weight } => (
                heuristic,
                Algorithm::AStar {
                    weight: weight.max(1),
                },
                Costs::Task,
                false,
            ),
        };
        let initial = task.fit(&request.initial);
        // Both the search and the heuristic go without the operators that
        // cannot matter from this start; `excluded` stays as asked, for
        // explaining unreachable goals.
        let useless = task.useless_operators(&initial, &excluded);
        let heuristic = kind.build_costed(task, &useless, costs);
        let landmarks = landmarks.then(|| {
            LandmarkCount::new(
                &heuristic::Relaxed::new(task, &useless),
                &initial,
                &|atom| task.predicate_of(atom),
            )
        });
        let engine = Engine::new(
            task,
            &initial,
            useless.clone(),
            heuristic,
            landmarks,
            algorithm,
        );
        let optimal_search =
            algorithm == (Algorithm::AStar { weight: 1 }) && engine.is_admissible();
        let result = if engine.initial_is_goal() {
            Some(Ended::Plan(Vec::new(), true))
        } else if engine.initial_h.is_none() {
            Some(Ended::Exhausted)
        } else {
            None
        };
        Search {
            optimal_search,
            engine,
            task,
            excluded,
            useless,
            kind,
            initial,
            improve,
            improvement: None,
            result,
        }
    }

    /// Runs at most `expansions` expansions.
    pub fn step(&mut self, expansions: u64) -> Progress {
        for _ in 0..expansions {
            if self.result.is_some() {
                return Progress::Done;
            }
            if self.improvement.is_some() {
                self.improve_step();
                continue;
            }
            match self.engine.step() {
                StepResult::Continue => {}
                StepResult::Solved(node) => {
                    let mut ops = self.engine.path(node);
                    if self.optimal_search {
                        self.result = Some(Ended::Plan(ops, true));
                    } else {
                        improve::eliminate_actions(self.task, &self.initial, &mut ops);
                        self.start_improving(ops);
                    }
                }
                StepResult::Exhausted => self.result = Some(Ended::Exhausted),
            }
        }
        if self.result.is_some() {
            Progress::Done
        } else {
            Progress::InProgress
        }
    }

    /// After a first plan `ops`: the improvement phase, or the end.
    fn start_improving(&mut self, plan: Vec<OpId>) {
        let cost = self.task.cost_of(&plan);
        if !self.improve || cost == 0 {
            self.result = Some(Ended::Plan(plan, cost == 0));
            return;
        }
        // Counting each action's cost plus one where some cost nothing, as
        // LAMA does: on such plateaus (openstacks) the task's costs alone
        // leave weighted A* nearly blind. Elsewhere the task's costs find
        // cheaper plans more often (petri-net-alignment-opt18 p01: 36
        // against 154 with plus one).
        let zero = self.task.operators().iter().any(|o| o.cost == 0);
        let costs = if zero { Costs::PlusOne } else { Costs::Task };
        let heuristic = self.kind.build_costed(self.task, &self.useless, costs);
        let engine = self.weighted(heuristic, IMPROVE_WEIGHTS[0], cost);
        self.improvement = Some(Improvement {
            engine,
            weight: 0,
            left: Improvement::budget(self.engine.evaluated),
            plan,
            cost,
            first: FirstPlan {
                cost,
                expanded: self.engine.expanded,
            },
            done: Stats::default(),
            graph: None,
            graph_work: 0,
            graph_left: 0,
        });
    }

    /// Weighted A* with `weight` from the start, pruning paths that cost
    /// `bound` or more.
    fn weighted(&self, heuristic: Box<dyn Heuristic + 't>, weight: u64, bound: u64) -> Engine<'t> {
        let mut engine = Engine::new(
            self.task,
            &self.initial,
            self.useless.clone(),
            heuristic,
            None,
            Algorithm::AStar { weight },
        );
        engine.bound = bound;
        engine
    }

    /// One expansion of the improvement phase.
    fn improve_step(&mut self) {
        let Some(mut imp) = self.improvement.take() else {
            return;
        };
        if imp.graph.is_some() {
            self.graph_step(&mut imp);
            self.improvement = Some(imp);
            return;
        }
        let before = imp.engine.evaluated;
        let step = imp.engine.step();
        imp.left = imp.left.saturating_sub(imp.engine.evaluated - before);
        match step {
            StepResult::Continue => {}
            StepResult::Solved(node) => {
                let mut ops = imp.engine.path(node);
                improve::eliminate_actions(self.task, &self.initial, &mut ops);
                imp.cost = self.task.cost_of(&ops);
                imp.plan = ops;
                imp.weight += 1;
                if imp.cost == 0 {
                    self.result = Some(Ended::Plan(std::mem::take(&mut imp.plan), true));
                } else if imp.weight < IMPROVE_WEIGHTS.len() {
                    // The next weight, from the start, under the new bound.
                    imp.done = imp.done.plus(&engine_stats(&imp.engine));
                    let old = imp.engine;
                    imp.engine =
                        self.weighted(old.into_heuristic(), IMPROVE_WEIGHTS[imp.weight], imp.cost);
                } else {
                    self.start_graph(&mut imp);
                }
            }
            // Nothing cheaper is reachable: the plan is the cheapest.
            StepResult::Exhausted => {
                self.result = Some(Ended::Plan(std::mem::take(&mut imp.plan), true));
            }
        }
        if imp.left == 0 && self.result.is_none() && imp.graph.is_none() {
            self.start_graph(&mut imp);
        }
        self.improvement = Some(imp);
    }

    /// A neighbourhood round around `plan` that may do `work`.
    fn round(&self, plan: &[OpId], work: u64) -> Neighbourhood {
        Neighbourhood::new(self.task, &self.initial, plan, work)
    }

    /// After the weighted searches: the first neighbourhood round around
    /// the cheapest plan, its size set by the evaluations so far.
    fn start_graph(&self, imp: &mut Improvement<'t>) {
        let evaluated = self.engine.evaluated + imp.done.evaluated + imp.engine.evaluated;
        let operators = self.useless.iter().filter(|&&u| !u).count() as u64;
        imp.graph_work = Improvement::graph_work(evaluated, operators);
        imp.graph_left = imp.graph_work;
        imp.graph = Some(self.round(&imp.plan, imp.graph_left));
    }

    /// One expansion of a neighbourhood round; at its end, the cheapest
    /// plan within it and, if that is cheaper, another round around it.
    fn graph_step(&mut self, imp: &mut Improvement<'t>) {
        let Some(graph) = &mut imp.graph else {
            return;
        };
        if graph.expand(self.task, &self.useless) {
            return;
        }
        imp.graph_left = imp.graph_left.saturating_sub(graph.work);
        imp.done = imp.done.plus(&graph_stats(graph));
        let better = graph
            .cheapest(self.task)
            .filter(|ops| self.task.cost_of(ops) < imp.cost);
        imp.graph = None;
        let Some(mut ops) = better else {
            self.result = Some(Ended::Plan(std::mem::take(&mut imp.plan), false));
            return;
        };
        improve::eliminate_actions(self.task, &self.initial, &mut ops);
        imp.cost = self.task.cost_of(&ops);
        imp.plan = ops;
        // A round cut short by a lack of work is worth little.
        if imp.graph_left >= imp.graph_work / 2 {
            imp.graph = Some(self.round(&imp.plan, imp.graph_left));
        } else {
            self.result = Some(Ended::Plan(std::mem::take(&mut imp.plan), false));
        }
    }

    /// Nodes expanded so far.
    pub fn expanded(&self) -> u64 {
        self.engine.expanded
            + self.improvement.as_ref().map_or(0, |imp| {
                imp.done.expanded
                    + imp.engine.expanded
                    + imp.graph.as_ref().map_or(0, |g| g.expanded)
            })
    }

    /// Where the search stands.
    pub fn snapshot(&self) -> Snapshot {
        Snapshot {
            expanded: self.expanded(),
            states: self.engine.states() as u64,
            best: self.improvement.as_ref().map(|imp| imp.cost),
            lower_bound: self.optimal_search.then_some(self.engine.floor),
        }
    }

    /// Ends the search; before [`Progress::Done`] the verdict is
    /// [`Verdict::BudgetExceeded`], unless a plan was found already: the
    /// improvement phase cut short leaves the cheapest found so far.
    pub fn finish(mut self, elapsed: Duration) -> Outcome {
        let mut stats = engine_stats(&self.engine);
        if let Some(imp) = &mut self.improvement {
            stats = stats.plus(&imp.done).plus(&engine_stats(&imp.engine));
            if let Some(graph) = &imp.graph {
                stats = stats.plus(&graph_stats(graph));
            }
            stats.first = Some(imp.first);
            if self.result.is_none() {
                self.result = Some(Ended::Plan(std::mem::take(&mut imp.plan), false));
            }
        }
        stats.initial_h = self.engine.initial_h;
        stats.micros = elapsed.as_micros() as u64;
        let (verdict, optimal) = match self.result {
            None => (Verdict::BudgetExceeded, false),
            Some(Ended::Plan(ops, optimal)) => {
                (Verdict::Found(Plan::from_ops(self.task, &ops)), optimal)
            }
            Some(Ended::Exhausted) => {
                let goals = heuristic::unreachable_goals(self.task, &self.excluded, &self.initial);
                let why = if goals.is_empty() {
                    Unsolvable::Exhausted {
                        states: stats.states,
                    }
                } else {
                    Unsolvable::Unreachable { goals }
                };
                (Verdict::Unsolvable(why), false)
            }
        };
        let lower_bound = (self.optimal_search && matches!(verdict, Verdict::BudgetExceeded))
            .then_some(self.engine.floor);
        Outcome {
            verdict,
            optimal,
            lower_bound,
            stats,
        }
    }
}

/// The counts of one neighbourhood round.
fn graph_stats(graph: &Neighbourhood) -> Stats {
    Stats {
        expanded: graph.expanded,
        generated: graph.generated,
        states: graph.states() as u64,
        ..Stats::default()
    }
}

/// The counts of one engine.
fn engine_stats(engine: &Engine<'_>) -> Stats {
    Stats {
        expanded: engine.expanded,
        generated: engine.generated,
        evaluated: engine.evaluated,
        states: engine.states() as u64,
        initial_h: engine.initial_h,
        micros: 0,
        first: None,
    }
}

impl Stats {
    /// The counts of two searches together (the first's `initial_h`,
    /// `micros` and `first`).
    fn plus(&self, other: &Stats) -> Stats {
        Stats {
            expanded: self.expanded + other.expanded,
            generated: self.generated + other.generated,
            evaluated: self.evaluated + other.evaluated,
            states: self.states + other.states,
            initial_h: self.initial_h,
            micros: self.micros,
            first: self.first,
        }
    }
}

/// How many expansions [`plan`] runs between two readings of the clock.
pub const TIME_CHECK_EXPANSIONS: u64 = 64;

/// Where a running search stands; [`plan_observed`] reports it between
/// steps, so that a long search can show its progress.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Snapshot {
    /// Nodes expanded so far, by every search of the plan.
    pub expanded: u64,
    /// States stored by the first search.
    pub states: u64,
    /// The cost of the cheapest plan so far, once the search that finds a
    /// first plan is followed by searches for a cheaper one.
    pub best: Option<u64>,
    /// Looking for a cheapest plan (A* with an admissible heuristic): no
    /// plan costs less than this.
    pub lower_bound: Option<u64>,
}

/// Plans for `request`, stopping when the budget runs out.
pub fn plan(request: &Request<'_>, options: &Options, clock: &dyn Clock) -> Outcome {
    plan_observed(request, options, clock, &mut |_| {})
}

/// As [`plan`], calling `observe` between steps of the search (every
/// [`TIME_CHECK_EXPANSIONS`] expansions) with where it stands.
pub fn plan_observed(
    request: &Request<'_>,
    options: &Options,
    clock: &dyn Clock,
    observe: &mut dyn FnMut(Snapshot),
) -> Outcome {
    const SLICE: u64 = TIME_CHECK_EXPANSIONS;
    let mut search = Search::new(request, options.strategy, options.improve);
    loop {
        let slice = match options.budget.max_expansions {
            Some(max) => SLICE.min(max.saturating_sub(search.expanded())),
            None => SLICE,
        };
        let over_time = options
            .budget
            .max_time
            .is_some_and(|t| clock.elapsed() >= t);
        if search.result.is_some() {
            return search.finish(clock.elapsed());
        }
        if slice == 0 || over_time {
            return search.finish(clock.elapsed());
        }
        if search.step(slice) == Progress::Done {
            return search.finish(clock.elapsed());
        }
        observe(search.snapshot());
    }
}
