//! The conditional planner (PTLplan's class of plans): actions with
//! probabilistic outcomes, sensing actions that reveal atoms, and uncertain
//! initial states. A plan is a graph of actions that branches on what the
//! sensing actions observe, its branches joining where they meet the same
//! belief again; it reaches the goal with some probability at an expected
//! cost.
//!
//! The search is AO* over beliefs: a belief is a probability distribution
//! over the ground [`State`]s, an OR node chooses an action instance that
//! applies in every state of its belief, each state by its own variant
//! ([`Task::variants`]: the disjunct of the precondition that holds there,
//! the `when` effects whose conditions hold there), or stops, and an AND
//! node splits the
//! successor belief by observation. A node is first a belief alone, however
//! many actions led to it; if the beliefs met form a cycle, or the best plan
//! is deeper than the horizon, the search is run again on nodes (belief,
//! actions left), whose graph is acyclic and whose plans are at most
//! `horizon` actions deep on every branch. A plan is scored by `lambda *
//! P(success) - E(cost)`; with `lambda` infinite the score is lexicographic
//! (most probable, then cheapest), and the threshold is met by walking the
//! upper convex hull of (cost, probability) with finite `lambda`s between
//! the cheapest plan below the threshold and the cheapest above it. The
//! bound of an unexpanded belief is the fully observable, all-outcomes one:
//! each state that is not a goal counts as reached at the cost of an
//! admissible deterministic heuristic (h-max or LM-cut on
//! [`Task::determinized`]), which overestimates the score.

use std::cmp::Reverse;
use std::collections::{BTreeSet, HashMap};

use crate::heuristic::{Costs, Heuristic, HeuristicKind};
use crate::plan_graph::{self, GraphBuilder};
use crate::relevance::Relevance;
use crate::task::{AtomId, OpId, State, Task};
use crate::{Budget, Clock, Step};

pub use crate::plan_graph::{Branch, PlanGraph, PlanNode, evaluate, observation_text, round};

pub use ecology_core::EPSILON;

/// How to plan conditionally.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConditionalOptions {
    /// The least success probability wanted; `None`: as probable as possible.
    pub min_probability: Option<f64>,
    /// The most actions on any branch.
    pub horizon: u32,
    /// The deterministic heuristic on the determinized task: `Max`,
    /// `LmCut` or `Blind`. An inadmissible one would cut off plans, so it
    /// is replaced by `LmCut`.
    pub heuristic: HeuristicKind,
    /// When to stop early.
    pub budget: Budget,
}

impl Default for ConditionalOptions {
    fn default() -> ConditionalOptions {
        ConditionalOptions {
            min_probability: None,
            horizon: 20,
            heuristic: HeuristicKind::LmCut,
            budget: Budget::default(),
        }
    }
}

/// Where to start: a belief (the task's initial one, or the executive's
/// current one when replanning) and the operators that are unavailable.
#[derive(Debug, Clone)]
pub struct ConditionalRequest<'t> {
    /// The ground task.
    pub task: &'t Task,
    /// Possible states with their probabilities (summing to 1).
    pub belief: Vec<(f64, State)>,
    /// Operators not to use.
    pub excluded: Vec<OpId>,
}

impl<'t> ConditionalRequest<'t> {
    /// From the task's initial belief, with every operator available.
    pub fn new(task: &'t Task) -> ConditionalRequest<'t> {
        ConditionalRequest {
            task,
            belief: task.initial_belief().to_vec(),
            excluded: Vec::new(),
        }
    }
}

/// A conditional plan with its success probability and expected cost.
#[derive(Debug, Clone, PartialEq)]
pub struct ConditionalPlan {
    /// The plan.
    pub graph: PlanGraph,
    /// The probability that it ends with the goal holding.
    pub success: f64,
    /// The expected sum of the costs of the actions it runs.
    pub expected_cost: f64,
}

impl ConditionalPlan {
    /// The plan as indented text: one action per line, under a sensing
    /// action each observation with its probability, shared parts labelled
    /// and joined.
    pub fn display<'a>(&'a self, task: &'a Task) -> plan_graph::Display<'a> {
        self.graph.display(task)
    }
}

/// What the conditional planner concluded.
#[derive(Debug, Clone, PartialEq)]
pub enum ConditionalVerdict {
    /// A plan that reaches the goal with at least the probability asked
    /// (the most probable one when none was asked).
    Found(ConditionalPlan),
    /// No plan within the horizon reaches the threshold: the most probable
    /// plan found, whose `success` is the best probability.
    BelowThreshold(ConditionalPlan),
    /// The budget ran out: the best plan found so far (unexpanded beliefs
    /// end it), if any.
    BudgetExceeded(Option<ConditionalPlan>),
}

/// Counts of one conditional search.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ConditionalStats {
    /// Belief nodes expanded.
    pub expanded: u64,
    /// Belief nodes created.
    pub nodes: u64,
    /// Distinct beliefs.
    pub beliefs: u64,
    /// AO* runs (one per `lambda`).
    pub rounds: u64,
    /// Whether one node per belief sufficed (no cycle among the beliefs
    /// met, a plan within the horizon); otherwise nodes are (belief,
    /// actions left), and the counts include the first search.
    pub shared: bool,
    /// Time spent, by the caller's clock.
    pub micros: u64,
}

/// The result of [`plan_conditional`].
#[derive(Debug, Clone, PartialEq)]
pub struct ConditionalOutcome {
    /// The plan, or the best probability found.
    pub verdict: ConditionalVerdict,
    /// Whether the search finished (within the horizon: the probability is
    /// the best possible, and the cost the least on the convex hull of
    /// (cost, probability) among plans reaching the threshold).
    pub complete: bool,
    /// Counts.
    pub stats: ConditionalStats,
}

/// A belief: states (sorted, distinct) and their probabilities (sum 1).
#[derive(Debug, Clone)]
struct Belief {
    states: Vec<State>,
    probs: Vec<f64>,
    /// Each state's heuristic value (`None`: a dead end).
    h: Vec<Option<u64>>,
    /// Each state's lower bound on the number of actions to the goal
    /// (`None`: a dead end).
    steps: Vec<Option<u64>>,
    /// Whether each state is a goal state.
    goal: Vec<bool>,
}

/// Beliefs are the same when their states are and their probabilities agree
/// to about 12 digits (probabilities reached along different paths differ
/// in the last bits).
type BeliefKey = (Vec<State>, Vec<u64>);

fn key_of(states: &[State], probs: &[f64]) -> BeliefKey {
    (
        states.to_vec(),
        probs.iter().map(|p| (p * 1e12).round() as u64).collect(),
    )
}

/// An observation: each observed atom and whether it holds.
type Observation = Vec<(AtomId, bool)>;

/// States with their probabilities (not necessarily summing to 1).
type Weighted = Vec<(State, f64)>;

#[derive(Debug, Clone)]
struct Choice {
    /// The action instance (its first variant, [`Task::variants`]).
    op: OpId,
    /// Its expected cost over the belief (each state pays its variant's).
    cost: f64,
    /// (probability, observation, node).
    children: Vec<(f64, Observation, u32)>,
}

#[derive(Debug, Clone)]
struct Node {
    belief: u32,
    /// Actions left ([`UNBOUNDED`] when beliefs are shared across depths).
    depth: u32,
    /// The most actions on a path from the root in the graph built so far:
    /// a child's level is greater than its parents', so the levels order
    /// the nodes children first.
    level: u32,
    expanded: bool,
    choices: Vec<Choice>,
    parents: Vec<u32>,
    /// The value under the current lambda: success probability and cost.
    p: f64,
    c: f64,
    /// The best choice (`None`: stop).
    best: Option<u32>,
    /// Whether stopping is known to be best without expanding.
    settled: bool,
}

/// The score `lambda * p - c`, with `lambda = None` meaning infinity.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Lambda(Option<f64>);

impl Lambda {
    /// Whether (p, c) scores strictly better than (q, d); ties go to the
    /// more probable.
    fn better(self, (p, c): (f64, f64), (q, d): (f64, f64)) -> bool {
        match self.0 {
            None => p > q + EPSILON || (p > q - EPSILON && c < d - EPSILON),
            Some(l) => {
                let (a, b) = (l * p - c, l * q - d);
                let tol = EPSILON * (1.0 + l.abs() + c.abs() + d.abs());
                a > b + tol || (a > b - tol && p > q + EPSILON)
            }
        }
    }

    /// Whether a state at heuristic distance `h` from the goal counts in
    /// the bound: never when `lambda * 1 - h <= 0`.
    fn counts(self, h: u64) -> bool {
        match self.0 {
            None => true,
            Some(l) => (h as f64) < l,
        }
    }
}

struct Engine<'t> {
    task: &'t Task,
    relevance: Relevance,
    heuristic: Box<dyn Heuristic + 't>,
    h_cache: HashMap<State, Option<u64>>,
    /// The heuristic on the determinization with every action costing 1,
    /// when actions have costs of their own (otherwise `heuristic` counts
    /// actions already): a lower bound on the actions a state needs.
    steps: Option<Box<dyn Heuristic + 't>>,
    steps_cache: HashMap<State, Option<u64>>,
    excluded: Vec<bool>,
    beliefs: Vec<Belief>,
    belief_ids: HashMap<BeliefKey, u32>,
    nodes: Vec<Node>,
    node_ids: HashMap<(u32, u32), u32>,
    lambda: Lambda,
    stats: ConditionalStats,
    /// Visit stamps for walks over the solution graph.
    stamp: Vec<u32>,
    round: u32,
    /// Whether an expansion closed a cycle (only when sharing beliefs
    /// across depths).
    cyclic: bool,
}

/// The depth of nodes when beliefs are shared across depths.
const UNBOUNDED: u32 = u32::MAX;

impl<'t> Engine<'t> {
    fn h(&mut self, state: &State) -> Option<u64> {
        if let Some(&h) = self.h_cache.get(state) {
            return h;
        }
        let h = self.heuristic.estimate(state, &mut Vec::new());
        self.h_cache.insert(state.clone(), h);
        h
    }

    /// At least how many actions reach the goal from `state`.
    fn steps(&mut self, state: &State, h: Option<u64>) -> Option<u64> {
        let Some(steps) = &mut self.steps else {
            return h;
        };
        if let Some(&n) = self.steps_cache.get(state) {
            return n;
        }
        let n = steps.estimate(state, &mut Vec::new());
        self.steps_cache.insert(state.clone(), n);
        n
    }

    /// Interns the belief of `weighted` states (merging equal ones; the
    /// weights need not sum to 1).
    fn belief(&mut self, mut weighted: Vec<(State, f64)>) -> u32 {
        weighted.sort_by(|a, b| a.0.words.cmp(&b.0.words));
        let mut states: Vec<State> = Vec::with_capacity(weighted.len());
        let mut probs: Vec<f64> = Vec::with_capacity(weighted.len());
        for (s, p) in weighted {
            if states.last() == Some(&s) {
                *probs.last_mut().unwrap_or_else(|| unreachable!()) += p;
            } else {
                states.push(s);
                probs.push(p);
            }
        }
        let total: f64 = probs.iter().sum();
        for p in &mut probs {
            *p /= total;
        }
        let key = key_of(&states, &probs);
        if let Some(&id) = self.belief_ids.get(&key) {
            return id;
        }
        let h: Vec<Option<u64>> = states.iter().map(|s| self.h(s)).collect();
        let steps = states
            .iter()
            .zip(&h)
            .map(|(s, &h)| self.steps(s, h))
            .collect();
        let goal = states.iter().map(|s| self.task.is_goal(s)).collect();
        let id = self.beliefs.len() as u32;
        self.beliefs.push(Belief {
            states,
            probs,
            h,
            steps,
            goal,
        });
        self.belief_ids.insert(key, id);
        self.stats.beliefs += 1;
        id
    }

    fn node(&mut self, belief: u32, depth: u32, parent: Option<u32>) -> u32 {
        let level = parent.map_or(0, |p| self.nodes[p as usize].level + 1);
        let id = match self.node_ids.get(&(belief, depth)) {
            Some(&id) => {
                if self.nodes[id as usize].level < level {
                    self.raise(id, level, parent);
                }
                id
            }
            None => {
                let id = self.nodes.len() as u32;
                self.nodes.push(Node {
                    belief,
                    depth,
                    level,
                    expanded: false,
                    choices: Vec::new(),
                    parents: Vec::new(),
                    p: 0.0,
                    c: 0.0,
                    best: None,
                    settled: false,
                });
                self.stamp.push(0);
                self.node_ids.insert((belief, depth), id);
                self.stats.nodes += 1;
                self.evaluate(id);
                id
            }
        };
        if let Some(parent) = parent
            && !self.nodes[id as usize].parents.contains(&parent)
        {
            self.nodes[id as usize].parents.push(parent);
        }
        id
    }

    /// Raises node `id` to `level` and its descendants below it, keeping
    /// children's levels above their parents'; reaching `parent` (the node
    /// whose new edge leads to `id`) means that edge closes a cycle.
    fn raise(&mut self, id: u32, level: u32, parent: Option<u32>) {
        let mut stack = vec![(id, level)];
        while let Some((id, level)) = stack.pop() {
            if Some(id) == parent {
                self.cyclic = true;
                return;
            }
            let node = &mut self.nodes[id as usize];
            if node.level >= level {
                continue;
            }
            node.level = level;
            for choice in &node.choices {
                stack.extend(choice.children.iter().map(|&(_, _, c)| (c, level + 1)));
            }
        }
    }

    /// The goal's probability in `belief`: what stopping there scores.
    fn stop_value(&self, belief: u32) -> f64 {
        let b = &self.beliefs[belief as usize];
        b.probs
            .iter()
            .zip(&b.goal)
            .filter(|(_, g)| **g)
            .map(|(p, _)| p)
            .sum::<f64>()
            + 0.0
    }

    /// Recomputes node `id`'s value: its bound if unexpanded, else the best
    /// of stopping and its choices. Returns whether the value changed.
    fn evaluate(&mut self, id: u32) -> bool {
        let lambda = self.lambda;
        let node = &self.nodes[id as usize];
        let stop = (self.stop_value(node.belief), 0.0);
        let (value, best, settled) = if node.depth == 0 {
            (stop, None, true)
        } else if !node.expanded {
            // The fully observable, all-outcomes bound. A state that needs
            // more actions than are left reaches nothing within the horizon.
            let b = &self.beliefs[node.belief as usize];
            let (mut p, mut c) = (0.0, 0.0);
            let mut open = false;
            let within = |steps: Option<u64>| {
                node.depth == UNBOUNDED || steps.is_some_and(|n| n <= u64::from(node.depth))
            };
            for i in 0..b.states.len() {
                if b.goal[i] {
                    p += b.probs[i];
                } else if let Some(h) = b.h[i]
                    && lambda.counts(h)
                    && within(b.steps[i])
                {
                    p += b.probs[i];
                    c += b.probs[i] * h as f64;
                    open = true;
                }
            }
            ((p, c), None, !open)
        } else {
            let mut value = stop;
            let mut best = None;
            for (k, choice) in node.choices.iter().enumerate() {
                let mut p = 0.0;
                let mut c = choice.cost;
                for &(w, _, child) in &choice.children {
                    let n = &self.nodes[child as usize];
                    p += w * n.p;
                    c += w * n.c;
                }
                if lambda.better((p, c), value) {
                    value = (p, c);
                    best = Some(k as u32);
                }
            }
            (value, best, false)
        };
        let node = &mut self.nodes[id as usize];
        let changed = (node.p - value.0).abs() > EPSILON * 1e-3
            || (node.c - value.1).abs() > EPSILON * 1e-3 * (1.0 + value.1.abs());
        node.p = value.0;
        node.c = value.1;
        node.best = best;
        node.settled = settled;
        changed
    }

    /// Builds node `id`'s choices: every action instance applicable in all
    /// its states, its successor belief split by what it observes. An
    /// instance applies in a state where one of its variants does (a
    /// disjunct of its precondition holds, its `when` conditions hold or
    /// fail), and each state takes its own variant's effects.
    fn expand(&mut self, id: u32) {
        self.stats.expanded += 1;
        let (belief, depth) = {
            let n = &self.nodes[id as usize];
            (n.belief, n.depth)
        };
        let child_depth = if depth == UNBOUNDED {
            UNBOUNDED
        } else {
            depth - 1
        };
        let b = self.beliefs[belief as usize].clone();
        let (task, excluded) = (self.task, &self.excluded);
        let mut instances = Vec::new();
        task.for_each_applicable(&b.states[0], |op| {
            if !excluded[op.index()] {
                instances.extend(task.variants(op).next());
            }
        });
        instances.sort_unstable();
        instances.dedup();
        // Each applicable instance with each state's variant.
        let applicable: Vec<(OpId, Vec<OpId>)> = instances
            .into_iter()
            .filter_map(|op| {
                let variants = b.states.iter().map(|s| {
                    task.variants(op)
                        .find(|&v| !excluded[v.index()] && task.applicable(s, v))
                });
                Some((op, variants.collect::<Option<Vec<OpId>>>()?))
            })
            .collect();
        let mut choices = Vec::new();
        for (op, variants) in applicable {
            let o = task.operator(op);
            // Successor states grouped by observation.
            let mut groups: Vec<(Vec<bool>, Weighted)> = Vec::new();
            let mut cost = 0.0;
            for ((s, &p), &v) in b.states.iter().zip(&b.probs).zip(&variants) {
                let variant = task.operator(v);
                cost += p * variant.cost as f64;
                for (q, add, del) in variant.each_outcome() {
                    let mut next = s.clone();
                    next.change(add, del);
                    let seen: Vec<bool> = o.observe.iter().map(|&a| next.holds(a)).collect();
                    self.relevance.clear_irrelevant(self.task, &mut next);
                    match groups.iter_mut().find(|(g, _)| *g == seen) {
                        Some((_, states)) => states.push((next, p * q)),
                        None => groups.push((seen, vec![(next, p * q)])),
                    }
                }
            }
            groups.sort_by(|a, b| b.0.cmp(&a.0));
            let mut children = Vec::new();
            for (seen, states) in groups {
                let w: f64 = states.iter().map(|(_, p)| p).sum();
                if w <= 0.0 {
                    continue;
                }
                let child_belief = self.belief(states);
                let observation = o.observe.iter().copied().zip(seen).collect();
                children.push((w, observation, child_belief));
            }
            // An action that leaves the belief as it is never helps.
            if let [(_, _, only)] = &children[..]
                && *only == belief
            {
                continue;
            }
            let children = children
                .into_iter()
                .map(|(w, obs, cb)| (w, obs, self.node(cb, child_depth, Some(id))))
                .collect();
            choices.push(Choice { op, cost, children });
        }
        let node = &mut self.nodes[id as usize];
        node.choices = choices;
        node.expanded = true;
    }

    /// Re-evaluates `changed` nodes and their ancestors, children first.
    fn propagate(&mut self, changed: impl IntoIterator<Item = u32>) {
        let key = |n: &Node, id: u32| (Reverse(n.level), id);
        let mut work: BTreeSet<(Reverse<u32>, u32)> = changed
            .into_iter()
            .map(|id| key(&self.nodes[id as usize], id))
            .collect();
        while let Some((_, id)) = work.pop_first() {
            if self.evaluate(id) {
                for &parent in &self.nodes[id as usize].parents {
                    work.insert(key(&self.nodes[parent as usize], parent));
                }
            }
        }
    }

    /// Re-evaluates every node under a new lambda, children first.
    fn set_lambda(&mut self, lambda: Lambda) {
        self.lambda = lambda;
        let mut order: Vec<u32> = (0..self.nodes.len() as u32).collect();
        order.sort_by_key(|&id| Reverse(self.nodes[id as usize].level));
        for id in order {
            self.evaluate(id);
        }
    }

    /// The unexpanded nodes of the best partial plan from `root` (at most `max`).
    fn tips(&mut self, root: u32, max: usize) -> Vec<u32> {
        self.round += 1;
        let round = self.round;
        let mut tips = Vec::new();
        let mut stack = vec![root];
        while let Some(id) = stack.pop() {
            if self.stamp[id as usize] == round {
                continue;
            }
            self.stamp[id as usize] = round;
            let n = &self.nodes[id as usize];
            if !n.expanded {
                if !n.settled {
                    tips.push(id);
                    if tips.len() >= max {
                        break;
                    }
                }
                continue;
            }
            if let Some(k) = n.best {
                // Most probable branches last, so they are visited first.
                let mut kids: Vec<(f64, u32)> = n.choices[k as usize]
                    .children
                    .iter()
                    .map(|&(w, _, c)| (w, c))
                    .collect();
                kids.sort_by(|a, b| a.0.total_cmp(&b.0));
                stack.extend(kids.into_iter().map(|(_, c)| c));
            }
        }
        tips
    }

    /// The nodes of the best partial plan from `root`, each with the most
    /// actions on a branch from it (its height).
    fn heights(&mut self, root: u32) -> HashMap<u32, u32> {
        self.round += 1;
        let round = self.round;
        let mut seen = Vec::new();
        let mut stack = vec![root];
        while let Some(id) = stack.pop() {
            if std::mem::replace(&mut self.stamp[id as usize], round) == round {
                continue;
            }
            seen.push(id);
            let n = &self.nodes[id as usize];
            if let Some(k) = n.best.filter(|_| n.expanded) {
                stack.extend(n.choices[k as usize].children.iter().map(|&(_, _, c)| c));
            }
        }
        // Children first.
        seen.sort_by_key(|&id| Reverse(self.nodes[id as usize].level));
        let mut heights = HashMap::with_capacity(seen.len());
        for id in seen {
            let n = &self.nodes[id as usize];
            let h = match n.best.filter(|_| n.expanded) {
                Some(k) => {
                    1 + n.choices[k as usize]
                        .children
                        .iter()
                        .map(|(_, _, c)| heights[c])
                        .max()
                        .unwrap_or(0)
                }
                None => 0,
            };
            heights.insert(id, h);
        }
        heights
    }

    /// The plan the best choices from `root` make (unexpanded nodes stop),
    /// cut after `horizon` actions on every branch, and whether it needed
    /// no cut (it fits in the horizon).
    fn extract(&mut self, root: u32, horizon: u32) -> (PlanGraph, bool) {
        let heights = self.heights(root);
        let mut builder = GraphBuilder::default();
        let mut made = HashMap::new();
        let top = self.extract_at(root, horizon, &heights, &mut builder, &mut made);
        (builder.finish(top), heights[&root] <= horizon)
    }

    fn extract_at(
        &self,
        id: u32,
        left: u32,
        heights: &HashMap<u32, u32>,
        builder: &mut GraphBuilder,
        made: &mut HashMap<u32, usize>,
    ) -> usize {
        // A node whose plan fits in what is left is the same wherever it is
        // reached from.
        let whole = heights[&id] <= left;
        if whole && let Some(&done) = made.get(&id) {
            return done;
        }
        let n = &self.nodes[id as usize];
        let node = match n.best.filter(|_| n.expanded && left > 0) {
            None => PlanNode::Stop {
                success: self.stop_value(n.belief),
            },
            Some(k) => {
                let choice = &n.choices[k as usize];
                let o = self.task.operator(choice.op);
                let branches = choice
                    .children
                    .iter()
                    .map(|(w, obs, child)| Branch {
                        observation: obs.clone(),
                        probability: *w,
                        next: self.extract_at(*child, left - 1, heights, builder, made),
                    })
                    .collect();
                PlanNode::Act {
                    step: Step {
                        op: choice.op,
                        action: o.action.clone(),
                        args: o.args.clone(),
                        cost: o.cost,
                        configure: o.configure.clone(),
                    },
                    branches,
                }
            }
        };
        let at = builder.add(node);
        if whole {
            made.insert(id, at);
        }
        at
    }

    /// Forgets every node (keeping beliefs and heuristic values), to search
    /// again with nodes of another kind.
    fn clear_nodes(&mut self) {
        self.nodes.clear();
        self.node_ids.clear();
        self.stamp.clear();
        self.lambda = Lambda(None);
        self.cyclic = false;
    }
}

/// How many expansions run between two readings of the clock.
const EXPANSIONS_PER_CHECK: usize = 16;

/// How many tips one walk over the best partial plan collects: expanding
/// them all before walking again keeps the walks (linear in the plan's
/// size) from dominating on large plans.
const TIPS_PER_WALK: usize = 1024;

/// Plans conditionally for `request`, stopping when the budget runs out.
///
/// Beliefs are first searched once whatever the number of actions left (a
/// graph search: a belief reached along paths of different lengths is one
/// node). That is exact when the beliefs the search meets form no cycle and
/// the plan it finds is no deeper than the horizon: every plan within the
/// horizon is among those it weighs. Otherwise, and only then, the search
/// runs again on nodes (belief, actions left), which the horizon bounds.
pub fn plan_conditional(
    request: &ConditionalRequest<'_>,
    options: &ConditionalOptions,
    clock: &dyn Clock,
) -> ConditionalOutcome {
    plan_conditional_observed(request, options, clock, &mut |_| {})
}

/// Where a running conditional search stands; [`plan_conditional_observed`]
/// reports it between batches of expansions, so that a long search can show
/// its progress.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConditionalSnapshot {
    /// Belief nodes expanded so far.
    pub expanded: u64,
    /// Distinct beliefs met so far.
    pub beliefs: u64,
}

/// As [`plan_conditional`], calling `observe` between batches of
/// expansions with where the search stands.
pub fn plan_conditional_observed(
    request: &ConditionalRequest<'_>,
    options: &ConditionalOptions,
    clock: &dyn Clock,
    observe: &mut dyn FnMut(ConditionalSnapshot),
) -> ConditionalOutcome {
    let task = request.task;
    let (det, origin) = task.determinized();
    let mut det_excluded = vec![false; det.operators().len()];
    let mut excluded = vec![false; task.operators().len()];
    for op in &request.excluded {
        if let Some(slot) = excluded.get_mut(op.index()) {
            *slot = true;
        }
    }
    for (i, o) in origin.iter().enumerate() {
        det_excluded[i] = excluded[o.index()];
    }
    let kind = if options.heuristic.is_admissible() {
        options.heuristic
    } else {
        HeuristicKind::LmCut
    };
    let mut engine = Engine {
        task,
        relevance: Relevance::new(task, &excluded),
        heuristic: kind.build(&det, &det_excluded),
        h_cache: HashMap::new(),
        steps: task
            .has_action_costs()
            .then(|| kind.build_costed(&det, &det_excluded, Costs::One)),
        steps_cache: HashMap::new(),
        excluded,
        beliefs: Vec::new(),
        belief_ids: HashMap::new(),
        nodes: Vec::new(),
        node_ids: HashMap::new(),
        lambda: Lambda(None),
        stats: ConditionalStats::default(),
        stamp: Vec::new(),
        round: 0,
        cyclic: false,
    };
    let start: Vec<(State, f64)> = request
        .belief
        .iter()
        .filter(|(p, _)| *p > 0.0)
        .map(|(p, s)| {
            let mut s = task.fit(s);
            engine.relevance.clear_irrelevant(task, &mut s);
            (s, *p)
        })
        .collect();
    let finish = |engine: &Engine<'_>, (verdict, complete)| {
        let mut stats = engine.stats;
        stats.micros = clock.elapsed().as_micros() as u64;
        ConditionalOutcome {
            verdict,
            complete,
            stats,
        }
    };
    if start.is_empty() {
        let plan = ConditionalPlan {
            graph: PlanGraph::stop(0.0),
            success: 0.0,
            expected_cost: 0.0,
        };
        return finish(&engine, (ConditionalVerdict::BelowThreshold(plan), true));
    }
    let belief = engine.belief(start);
    let b = &engine.beliefs[belief as usize];
    let search = Search {
        options,
        clock,
        observe: std::cell::RefCell::new(observe),
        belief,
        start: b
            .probs
            .iter()
            .copied()
            .zip(b.states.iter().cloned())
            .collect(),
    };
    engine.stats.shared = true;
    if let Some(result) = search.run(&mut engine, UNBOUNDED) {
        return finish(&engine, result);
    }
    engine.clear_nodes();
    engine.stats.shared = false;
    let result = search
        .run(&mut engine, options.horizon)
        .unwrap_or_else(|| unreachable!("nodes bounded by the horizon form no cycle"));
    finish(&engine, result)
}

/// One search from a belief.
struct Search<'a> {
    options: &'a ConditionalOptions,
    clock: &'a dyn Clock,
    /// Told where the search stands between batches of expansions.
    observe: std::cell::RefCell<&'a mut dyn FnMut(ConditionalSnapshot)>,
    belief: u32,
    /// That belief's states with their probabilities, which plans are
    /// evaluated from.
    start: Vec<(f64, State)>,
}

/// How one AO* run under the engine's lambda ended.
enum Solved {
    /// The best plan is complete.
    Done,
    /// The budget ran out.
    Budget,
    /// Sharing beliefs across depths met a cycle, or a tip at the horizon.
    Cyclic,
}

impl Search<'_> {
    /// Whether the budget has run out.
    fn over(&self, engine: &Engine<'_>) -> bool {
        let budget = &self.options.budget;
        budget
            .max_expansions
            .is_some_and(|m| engine.stats.expanded >= m)
            || budget.max_time.is_some_and(|t| self.clock.elapsed() >= t)
    }

    /// One AO* run under the engine's lambda.
    fn solve(&self, engine: &mut Engine<'_>, root: u32) -> Solved {
        engine.stats.rounds += 1;
        loop {
            // Never more expansions than the budget has left.
            let left = self
                .options
                .budget
                .max_expansions
                .map_or(u64::MAX, |m| m.saturating_sub(engine.stats.expanded));
            let batch = (TIPS_PER_WALK as u64).min(left.max(1)) as usize;
            let tips = engine.tips(root, batch);
            if tips.is_empty() {
                return Solved::Done;
            }
            // Sharing beliefs, a tip as many actions from the root as the
            // horizon allows (along some path) would make the plan deeper
            // than the horizon if it were expanded and chosen: the nodes
            // that count the actions left are needed.
            if engine.nodes[root as usize].depth == UNBOUNDED
                && tips
                    .iter()
                    .any(|&t| engine.nodes[t as usize].level >= self.options.horizon)
            {
                return Solved::Cyclic;
            }
            for chunk in tips.chunks(EXPANSIONS_PER_CHECK) {
                (self.observe.borrow_mut())(ConditionalSnapshot {
                    expanded: engine.stats.expanded,
                    beliefs: engine.beliefs.len() as u64,
                });
                if self.over(engine) {
                    return Solved::Budget;
                }
                for &tip in chunk {
                    engine.expand(tip);
                    if engine.cyclic {
                        return Solved::Cyclic;
                    }
                }
                engine.propagate(chunk.iter().copied());
            }
        }
    }

    /// The best plan from `root`, cut at the horizon, with its probability
    /// and expected cost, and whether it fits in the horizon uncut.
    fn plan_of(&self, engine: &mut Engine<'_>, root: u32) -> (ConditionalPlan, bool) {
        let (graph, fits) = engine.extract(root, self.options.horizon);
        let (success, expected_cost) =
            evaluate(engine.task, &self.start, &graph).unwrap_or((0.0, f64::INFINITY));
        let plan = ConditionalPlan {
            graph,
            success,
            expected_cost,
        };
        (plan, fits)
    }

    /// Searches with nodes of `depth` actions left: the verdict and whether
    /// the search finished, or `None` if sharing beliefs across depths
    /// (`depth` [`UNBOUNDED`]) met a cycle or a plan deeper than the horizon.
    fn run(&self, engine: &mut Engine<'_>, depth: u32) -> Option<(ConditionalVerdict, bool)> {
        let root = engine.node(self.belief, depth, None);
        // The most probable plan, and the cheapest among those.
        match self.solve(engine, root) {
            Solved::Done => {}
            Solved::Budget => {
                let (best, _) = self.plan_of(engine, root);
                return Some((ConditionalVerdict::BudgetExceeded(Some(best)), false));
            }
            Solved::Cyclic => return None,
        }
        let (most, fits) = self.plan_of(engine, root);
        if !fits {
            return None;
        }
        let threshold = match self.options.min_probability {
            None if most.success > EPSILON => {
                return Some((ConditionalVerdict::Found(most), true));
            }
            None => return Some((ConditionalVerdict::BelowThreshold(most), true)),
            // A threshold of 0 is met by stopping at once, even where no
            // plan reaches the goal.
            Some(t) if most.success < t - EPSILON || (most.success <= EPSILON && t > EPSILON) => {
                return Some((ConditionalVerdict::BelowThreshold(most), true));
            }
            Some(t) => t,
        };
        // Cheaper plans that still reach the threshold: between the cheapest
        // plan (stopping at once) and the most probable one, each finite
        // lambda is the slope of the segment joining a plan below the
        // threshold and one above; a plan scoring better than both splits
        // the segment.
        let stopping = engine.stop_value(self.belief);
        let stop = ConditionalPlan {
            graph: PlanGraph::stop(stopping),
            success: stopping,
            expected_cost: 0.0,
        };
        if stop.success >= threshold - EPSILON {
            return Some((ConditionalVerdict::Found(stop), true));
        }
        let (mut low, mut high) = (stop, most);
        for _ in 0..64 {
            let dp = high.success - low.success;
            if dp <= EPSILON {
                break;
            }
            let lambda = (high.expected_cost - low.expected_cost) / dp;
            engine.set_lambda(Lambda(Some(lambda)));
            match self.solve(engine, root) {
                Solved::Done => {}
                Solved::Budget => return Some((ConditionalVerdict::Found(high), false)),
                Solved::Cyclic => return None,
            }
            let (plan, fits) = self.plan_of(engine, root);
            if !fits {
                return None;
            }
            let score = |p: &ConditionalPlan| lambda * p.success - p.expected_cost;
            let tol = EPSILON * (1.0 + lambda.abs() + high.expected_cost);
            if score(&plan) <= score(&high) + tol {
                break;
            }
            if plan.success >= threshold - EPSILON {
                high = plan;
            } else {
                low = plan;
            }
        }
        Some((ConditionalVerdict::Found(high), true))
    }
}
