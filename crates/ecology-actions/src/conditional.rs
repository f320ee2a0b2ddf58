//! The conditional planner (PTLplan's class of plans): actions with
//! probabilistic outcomes, sensing actions that reveal atoms, and uncertain
//! initial states. A plan is a tree of actions that branches on what the
//! sensing actions observe; it reaches the goal with some probability at an
//! expected cost.
//!
//! The search is AO* over beliefs: a belief is a probability distribution
//! over the ground [`State`]s, an OR node chooses an action applicable in
//! every state of its belief (or stops), and an AND node splits the
//! successor belief by observation. Nodes are (belief, actions left), so the
//! graph is acyclic and plans are at most `horizon` actions deep on every
//! branch. A plan is scored by `lambda * P(success) - E(cost)`; with `lambda`
//! infinite the score is lexicographic (most probable, then cheapest), and
//! the threshold is met by walking the upper convex hull of (cost,
//! probability) with finite `lambda`s between the cheapest plan below the
//! threshold and the cheapest above it. The bound of an unexpanded belief is
//! the fully observable, all-outcomes one: each state that is not a goal
//! counts as reached at the cost of an admissible deterministic heuristic
//! (h-max or LM-cut on [`Task::determinized`]), which overestimates the score.

use std::collections::{BTreeSet, HashMap};
use std::fmt;

use crate::heuristic::{Heuristic, HeuristicKind};
use crate::task::{AtomId, OpId, State, Task};
use crate::{Budget, Clock, Step};

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

/// A conditional plan: a node of the tree.
#[derive(Debug, Clone, PartialEq)]
pub enum PlanTree {
    /// The plan ends here; the goal holds with `success` probability given
    /// the observations that led here.
    Stop {
        /// The probability that the goal holds here.
        success: f64,
    },
    /// Run an action, then follow the branch of what it observes.
    Act {
        /// The action.
        step: Step,
        /// One branch per possible observation (one, with no atoms, for an
        /// action that senses nothing).
        branches: Vec<Branch>,
    },
}

/// A branch of a conditional plan: an observation and what follows it.
#[derive(Debug, Clone, PartialEq)]
pub struct Branch {
    /// Each observed atom and whether it was seen to hold.
    pub observation: Vec<(AtomId, bool)>,
    /// The probability of this observation, given the path to the action.
    pub probability: f64,
    /// The rest of the plan.
    pub next: PlanTree,
}

/// A conditional plan with its success probability and expected cost.
#[derive(Debug, Clone, PartialEq)]
pub struct ConditionalPlan {
    /// The tree.
    pub root: PlanTree,
    /// The probability that it ends with the goal holding.
    pub success: f64,
    /// The expected sum of the costs of the actions it runs.
    pub expected_cost: f64,
}

impl PlanTree {
    /// Actions in the tree (every branch counted).
    pub fn actions(&self) -> usize {
        match self {
            PlanTree::Stop { .. } => 0,
            PlanTree::Act { branches, .. } => {
                1 + branches.iter().map(|b| b.next.actions()).sum::<usize>()
            }
        }
    }

    /// The most actions on one branch.
    pub fn depth(&self) -> usize {
        match self {
            PlanTree::Stop { .. } => 0,
            PlanTree::Act { branches, .. } => {
                1 + branches.iter().map(|b| b.next.depth()).max().unwrap_or(0)
            }
        }
    }
}

impl ConditionalPlan {
    /// The plan as an indented tree: one action per line, and under a
    /// sensing action each observation with its probability.
    pub fn display<'a>(&'a self, task: &'a Task) -> impl fmt::Display + 'a {
        Tree {
            task,
            root: &self.root,
        }
    }
}

struct Tree<'a> {
    task: &'a Task,
    root: &'a PlanTree,
}

/// `(at newspaper entrance)` or `(not (at newspaper entrance))`, joined.
pub fn observation_text(task: &Task, observation: &[(AtomId, bool)]) -> String {
    observation
        .iter()
        .map(|&(a, holds)| {
            if holds {
                task.atom_name(a)
            } else {
                format!("(not {})", task.atom_name(a))
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

impl Tree<'_> {
    fn write(&self, f: &mut fmt::Formatter<'_>, node: &PlanTree, indent: usize) -> fmt::Result {
        let mut node = node;
        loop {
            match node {
                PlanTree::Stop { success } => {
                    if *success >= 1.0 - EPSILON {
                        return writeln!(f, "{:indent$}done", "");
                    }
                    return writeln!(
                        f,
                        "{:indent$}done ; goal holds with probability {}",
                        "",
                        round(*success)
                    );
                }
                PlanTree::Act { step, branches } => {
                    match &step.configure {
                        Some(goal) => writeln!(f, "{:indent$}{step}  ; configure {goal}", "")?,
                        None => writeln!(f, "{:indent$}{step}", "")?,
                    }
                    if let [only] = &branches[..]
                        && only.observation.is_empty()
                    {
                        node = &only.next;
                        continue;
                    }
                    for b in branches {
                        writeln!(
                            f,
                            "{:indent$}  if {} ; probability {}",
                            "",
                            observation_text(self.task, &b.observation),
                            round(b.probability)
                        )?;
                        self.write(f, &b.next, indent + 4)?;
                    }
                    return Ok(());
                }
            }
        }
    }
}

impl fmt::Display for Tree<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.write(f, self.root, 0)
    }
}

/// `p` with at most 6 decimals, for people.
pub fn round(p: f64) -> f64 {
    // `+ 0.0` turns -0 (an empty sum) into 0.
    (p * 1e6).round() / 1e6 + 0.0
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
    op: OpId,
    cost: u64,
    /// (probability, observation, node).
    children: Vec<(f64, Observation, u32)>,
}

#[derive(Debug, Clone)]
struct Node {
    belief: u32,
    /// Actions left.
    depth: u32,
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
    heuristic: Box<dyn Heuristic + 't>,
    h_cache: HashMap<State, Option<u64>>,
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
}

impl<'t> Engine<'t> {
    fn h(&mut self, state: &State) -> Option<u64> {
        if let Some(&h) = self.h_cache.get(state) {
            return h;
        }
        let h = self.heuristic.estimate(state, &mut Vec::new());
        self.h_cache.insert(state.clone(), h);
        h
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
        let h = states.iter().map(|s| self.h(s)).collect();
        let goal = states.iter().map(|s| self.task.is_goal(s)).collect();
        let id = self.beliefs.len() as u32;
        self.beliefs.push(Belief {
            states,
            probs,
            h,
            goal,
        });
        self.belief_ids.insert(key, id);
        self.stats.beliefs += 1;
        id
    }

    fn node(&mut self, belief: u32, depth: u32, parent: Option<u32>) -> u32 {
        let id = match self.node_ids.get(&(belief, depth)) {
            Some(&id) => id,
            None => {
                let id = self.nodes.len() as u32;
                self.nodes.push(Node {
                    belief,
                    depth,
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
            // The fully observable, all-outcomes bound.
            let b = &self.beliefs[node.belief as usize];
            let (mut p, mut c) = (0.0, 0.0);
            let mut open = false;
            for i in 0..b.states.len() {
                if b.goal[i] {
                    p += b.probs[i];
                } else if let Some(h) = b.h[i]
                    && lambda.counts(h)
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
                let mut c = choice.cost as f64;
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

    /// Builds node `id`'s choices: every operator applicable in all its
    /// states, its successor belief split by what it observes.
    fn expand(&mut self, id: u32) {
        self.stats.expanded += 1;
        let (belief, depth) = {
            let n = &self.nodes[id as usize];
            (n.belief, n.depth)
        };
        let b = self.beliefs[belief as usize].clone();
        let mut ops = Vec::new();
        self.task
            .for_each_applicable(&b.states[0], |op| ops.push(op));
        ops.retain(|&op| {
            !self.excluded[op.index()] && b.states[1..].iter().all(|s| self.task.applicable(s, op))
        });
        let mut choices = Vec::new();
        for op in ops {
            let o = self.task.operator(op);
            // Successor states grouped by observation.
            let mut groups: Vec<(Vec<bool>, Weighted)> = Vec::new();
            for (s, &p) in b.states.iter().zip(&b.probs) {
                for (q, add, del) in o.each_outcome() {
                    let mut next = s.clone();
                    next.change(add, del);
                    let seen: Vec<bool> = o.observe.iter().map(|&a| next.holds(a)).collect();
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
            let cost = o.cost;
            let children = children
                .into_iter()
                .map(|(w, obs, cb)| (w, obs, self.node(cb, depth - 1, Some(id))))
                .collect();
            choices.push(Choice { op, cost, children });
        }
        let node = &mut self.nodes[id as usize];
        node.choices = choices;
        node.expanded = true;
    }

    /// Re-evaluates `changed` nodes and their ancestors, children first.
    fn propagate(&mut self, changed: impl IntoIterator<Item = u32>) {
        let mut work: BTreeSet<(u32, u32)> = changed
            .into_iter()
            .map(|id| (self.nodes[id as usize].depth, id))
            .collect();
        while let Some((_, id)) = work.pop_first() {
            if self.evaluate(id) {
                for &parent in &self.nodes[id as usize].parents {
                    work.insert((self.nodes[parent as usize].depth, parent));
                }
            }
        }
    }

    /// Re-evaluates every node under a new lambda, children first.
    fn set_lambda(&mut self, lambda: Lambda) {
        self.lambda = lambda;
        let mut order: Vec<u32> = (0..self.nodes.len() as u32).collect();
        order.sort_by_key(|&id| self.nodes[id as usize].depth);
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

    /// The plan the best choices from `id` make (unexpanded nodes stop).
    fn extract(&self, id: u32) -> PlanTree {
        let n = &self.nodes[id as usize];
        let stop = PlanTree::Stop {
            success: self.stop_value(n.belief),
        };
        let Some(k) = n.best.filter(|_| n.expanded) else {
            return stop;
        };
        let choice = &n.choices[k as usize];
        let o = self.task.operator(choice.op);
        PlanTree::Act {
            step: Step {
                op: choice.op,
                action: o.action.clone(),
                args: o.args.clone(),
                cost: o.cost,
                configure: o.configure.clone(),
            },
            branches: choice
                .children
                .iter()
                .map(|(w, obs, child)| Branch {
                    observation: obs.clone(),
                    probability: *w,
                    next: self.extract(*child),
                })
                .collect(),
        }
    }
}

/// The success probability and expected cost of `tree` run from `belief`,
/// by following beliefs through it (the planner's own reading; the oracle
/// has an independent one). `None` if an action does not apply in some
/// state or an observation has no branch.
pub fn evaluate(task: &Task, belief: &[(f64, State)], tree: &PlanTree) -> Option<(f64, f64)> {
    match tree {
        PlanTree::Stop { .. } => Some((
            belief
                .iter()
                .filter(|(_, s)| task.is_goal(s))
                .map(|(p, _)| p)
                .sum(),
            0.0,
        )),
        PlanTree::Act { step, branches } => {
            let o = task.operator(step.op);
            let mut split: Vec<Vec<(f64, State)>> = vec![Vec::new(); branches.len()];
            for (p, s) in belief {
                if !task.applicable(s, step.op) {
                    return None;
                }
                for (q, add, del) in o.each_outcome() {
                    let mut next = s.clone();
                    next.change(add, del);
                    let k = branches
                        .iter()
                        .position(|b| b.observation.iter().all(|&(a, v)| next.holds(a) == v))?;
                    split[k].push((p * q, next));
                }
            }
            let (mut p, mut c) = (0.0, step.cost as f64);
            for (part, b) in split.iter().zip(branches) {
                let w: f64 = part.iter().map(|(p, _)| p).sum();
                if w <= 0.0 {
                    continue;
                }
                let normal: Vec<(f64, State)> =
                    part.iter().map(|(p, s)| (p / w, s.clone())).collect();
                let (bp, bc) = evaluate(task, &normal, &b.next)?;
                p += w * bp;
                c += w * bc;
            }
            Some((p, c))
        }
    }
}

/// How many expansions run between two readings of the clock.
const EXPANSIONS_PER_CHECK: usize = 16;

/// How many tips one walk over the best partial plan collects: expanding
/// them all before walking again keeps the walks (linear in the plan's
/// size) from dominating on large plans.
const TIPS_PER_WALK: usize = 1024;

/// Plans conditionally for `request`, stopping when the budget runs out.
pub fn plan_conditional(
    request: &ConditionalRequest<'_>,
    options: &ConditionalOptions,
    clock: &dyn Clock,
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
        heuristic: kind.build(&det, &det_excluded),
        h_cache: HashMap::new(),
        excluded,
        beliefs: Vec::new(),
        belief_ids: HashMap::new(),
        nodes: Vec::new(),
        node_ids: HashMap::new(),
        lambda: Lambda(None),
        stats: ConditionalStats::default(),
        stamp: Vec::new(),
        round: 0,
    };
    let start: Vec<(State, f64)> = request
        .belief
        .iter()
        .filter(|(p, _)| *p > 0.0)
        .map(|(p, s)| (task.fit(s), *p))
        .collect();
    let finish = |engine: &Engine<'_>, verdict, complete| {
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
            root: PlanTree::Stop { success: 0.0 },
            success: 0.0,
            expected_cost: 0.0,
        };
        return finish(&engine, ConditionalVerdict::BelowThreshold(plan), true);
    }
    let belief = engine.belief(start);
    let normal: Vec<(f64, State)> = {
        let b = &engine.beliefs[belief as usize];
        b.probs
            .iter()
            .copied()
            .zip(b.states.iter().cloned())
            .collect()
    };
    let root = engine.node(belief, options.horizon, None);
    let over = |engine: &Engine<'_>| {
        options
            .budget
            .max_expansions
            .is_some_and(|m| engine.stats.expanded >= m)
            || options
                .budget
                .max_time
                .is_some_and(|t| clock.elapsed() >= t)
    };
    // One AO* run under the engine's lambda: `false` if the budget ran out.
    let solve = |engine: &mut Engine<'_>| -> bool {
        engine.stats.rounds += 1;
        loop {
            // Never more expansions than the budget has left.
            let left = options
                .budget
                .max_expansions
                .map_or(u64::MAX, |m| m.saturating_sub(engine.stats.expanded));
            let batch = (TIPS_PER_WALK as u64).min(left.max(1)) as usize;
            let tips = engine.tips(root, batch);
            if tips.is_empty() {
                return true;
            }
            for chunk in tips.chunks(EXPANSIONS_PER_CHECK) {
                if over(engine) {
                    return false;
                }
                for &tip in chunk {
                    engine.expand(tip);
                }
                engine.propagate(chunk.iter().copied());
            }
        }
    };
    let plan_of = |engine: &Engine<'_>| {
        let tree = engine.extract(root);
        let (success, expected_cost) =
            evaluate(task, &normal, &tree).unwrap_or((0.0, f64::INFINITY));
        ConditionalPlan {
            root: tree,
            success,
            expected_cost,
        }
    };
    // The most probable plan, and the cheapest among those.
    if !solve(&mut engine) {
        let best = plan_of(&engine);
        return finish(
            &engine,
            ConditionalVerdict::BudgetExceeded(Some(best)),
            false,
        );
    }
    let most = plan_of(&engine);
    let threshold = match options.min_probability {
        None if most.success > EPSILON => {
            return finish(&engine, ConditionalVerdict::Found(most), true);
        }
        None => return finish(&engine, ConditionalVerdict::BelowThreshold(most), true),
        Some(t) if most.success < t - EPSILON || most.success <= EPSILON => {
            return finish(&engine, ConditionalVerdict::BelowThreshold(most), true);
        }
        Some(t) => t,
    };
    // Cheaper plans that still reach the threshold: between the cheapest
    // plan (stopping at once) and the most probable one, each finite lambda
    // is the slope of the segment joining a plan below the threshold and
    // one above; a plan scoring better than both splits the segment.
    let stop = ConditionalPlan {
        root: PlanTree::Stop {
            success: engine.stop_value(belief),
        },
        success: engine.stop_value(belief),
        expected_cost: 0.0,
    };
    if stop.success >= threshold - EPSILON {
        return finish(&engine, ConditionalVerdict::Found(stop), true);
    }
    let (mut low, mut high) = (stop, most);
    for _ in 0..64 {
        let dp = high.success - low.success;
        if dp <= EPSILON {
            break;
        }
        let lambda = (high.expected_cost - low.expected_cost) / dp;
        engine.set_lambda(Lambda(Some(lambda)));
        if !solve(&mut engine) {
            return finish(&engine, ConditionalVerdict::Found(high), false);
        }
        let plan = plan_of(&engine);
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
    finish(&engine, ConditionalVerdict::Found(high), true)
}
