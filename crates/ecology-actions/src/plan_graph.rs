//! Conditional plans as graphs: a node runs an action and follows the branch
//! of what it observes, or stops. Branches that reach the same situation
//! share the rest of the plan, so a plan whose tree would repeat itself
//! (every move of triangle tireworld branches on the tire, and the branches
//! meet again down the road) is as small as the situations it passes
//! through. Printed, a node reached from more than one branch is written
//! once with a label, `[3] (move-car l-1-2 l-1-3)`, and every other branch
//! that reaches it ends with `go to [3]`.

use std::collections::HashMap;
use std::fmt;

use ecology_core::EPSILON;

use crate::Step;
use crate::relevance::Relevance;
use crate::task::{AtomId, State, Task};

/// A node of a conditional plan.
#[derive(Debug, Clone, PartialEq)]
pub enum PlanNode {
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

/// A branch of a conditional plan: an observation and the node it leads to.
#[derive(Debug, Clone, PartialEq)]
pub struct Branch {
    /// Each observed atom and whether it was seen to hold.
    pub observation: Vec<(AtomId, bool)>,
    /// The probability of this observation, given the path to the action.
    pub probability: f64,
    /// The index of the node that follows in [`PlanGraph::nodes`].
    pub next: usize,
}

/// A conditional plan: nodes, the first of which is where it starts. Every
/// branch leads to a later node, so the graph has no cycle.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanGraph {
    /// The nodes, the root first, each before the nodes its branches lead to.
    pub nodes: Vec<PlanNode>,
}

impl PlanGraph {
    /// A plan that stops at once.
    pub fn stop(success: f64) -> PlanGraph {
        PlanGraph {
            nodes: vec![PlanNode::Stop { success }],
        }
    }

    /// Where the plan starts.
    pub fn root(&self) -> &PlanNode {
        &self.nodes[0]
    }

    /// Actions in the graph, each shared node counted once.
    pub fn actions(&self) -> usize {
        self.nodes
            .iter()
            .filter(|n| matches!(n, PlanNode::Act { .. }))
            .count()
    }

    /// Actions in the tree the graph unfolds to (every branch counted, as
    /// many times as it is reached), saturating.
    pub fn tree_actions(&self) -> u64 {
        let mut count = vec![0u64; self.nodes.len()];
        for (i, node) in self.nodes.iter().enumerate().rev() {
            if let PlanNode::Act { branches, .. } = node {
                count[i] = branches
                    .iter()
                    .fold(1u64, |acc, b| acc.saturating_add(count[b.next]));
            }
        }
        count[0]
    }

    /// The most actions on one branch.
    pub fn depth(&self) -> usize {
        let mut depth = vec![0usize; self.nodes.len()];
        for (i, node) in self.nodes.iter().enumerate().rev() {
            if let PlanNode::Act { branches, .. } = node {
                depth[i] = 1 + branches.iter().map(|b| depth[b.next]).max().unwrap_or(0);
            }
        }
        depth[0]
    }

    /// How many branches lead to each node (the root counts one more).
    pub fn references(&self) -> Vec<usize> {
        let mut refs = vec![0usize; self.nodes.len()];
        refs[0] = 1;
        for node in &self.nodes {
            if let PlanNode::Act { branches, .. } = node {
                for b in branches {
                    refs[b.next] += 1;
                }
            }
        }
        refs
    }

    /// The labels of the nodes written once and joined from elsewhere:
    /// actions reached from more than one branch (or from a branch and the
    /// action before them), numbered from 1 in the order they are printed.
    pub fn labels(&self) -> Vec<Option<usize>> {
        let refs = self.references();
        let mut labels = vec![None; self.nodes.len()];
        let mut seen = vec![false; self.nodes.len()];
        let mut next = 0;
        // The order the text is written in: depth first, branches in order.
        let mut stack = vec![0];
        while let Some(id) = stack.pop() {
            if std::mem::replace(&mut seen[id], true) {
                continue;
            }
            if let PlanNode::Act { branches, .. } = &self.nodes[id] {
                if refs[id] > 1 {
                    next += 1;
                    labels[id] = Some(next);
                }
                stack.extend(branches.iter().rev().map(|b| b.next));
            }
        }
        labels
    }
}

/// Builds a [`PlanGraph`] bottom-up: equal nodes (the same action with the
/// same branches to the same nodes, or stops of equal probability) are
/// made once.
#[derive(Debug, Default)]
pub(crate) struct GraphBuilder {
    nodes: Vec<PlanNode>,
    ids: HashMap<NodeKey, usize>,
}

/// What makes two nodes equal: a stop's probability (to about 12 digits),
/// or an action with its branches' observations and targets.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
enum NodeKey {
    Stop(u64),
    Act(crate::OpId, Vec<(Vec<(AtomId, bool)>, usize)>),
}

impl GraphBuilder {
    /// The node `node`, made once; its branches must lead to nodes made
    /// before.
    pub(crate) fn add(&mut self, node: PlanNode) -> usize {
        let key = match &node {
            PlanNode::Stop { success } => NodeKey::Stop((success * 1e12).round() as u64),
            PlanNode::Act { step, branches } => NodeKey::Act(
                step.op,
                branches
                    .iter()
                    .map(|b| (b.observation.clone(), b.next))
                    .collect(),
            ),
        };
        *self.ids.entry(key).or_insert_with(|| {
            self.nodes.push(node);
            self.nodes.len() - 1
        })
    }

    /// The graph that starts at `root`, its nodes renumbered so that each
    /// comes before those its branches lead to (the reverse of the order in
    /// which a depth-first walk from the root leaves them); nodes the walk
    /// does not meet are left out.
    pub(crate) fn finish(self, root: usize) -> PlanGraph {
        const UNSEEN: usize = usize::MAX;
        let mut order = vec![UNSEEN; self.nodes.len()];
        let mut left = Vec::new();
        // (node, branches followed so far).
        let mut stack = vec![(root, 0)];
        order[root] = 0;
        while let Some((id, k)) = stack.pop() {
            let next = match &self.nodes[id] {
                PlanNode::Act { branches, .. } => branches.get(k).map(|b| b.next),
                PlanNode::Stop { .. } => None,
            };
            match next {
                Some(child) => {
                    stack.push((id, k + 1));
                    if order[child] == UNSEEN {
                        order[child] = 0;
                        stack.push((child, 0));
                    }
                }
                None => left.push(id),
            }
        }
        let walk: Vec<usize> = left.into_iter().rev().collect();
        for (i, &id) in walk.iter().enumerate() {
            order[id] = i;
        }
        let mut nodes: Vec<Option<PlanNode>> = self.nodes.into_iter().map(Some).collect();
        PlanGraph {
            nodes: walk
                .iter()
                .map(|&id| {
                    let mut node = nodes[id].take().unwrap_or_else(|| unreachable!());
                    if let PlanNode::Act { branches, .. } = &mut node {
                        for b in branches {
                            b.next = order[b.next];
                        }
                    }
                    node
                })
                .collect(),
        }
    }
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

/// `p` with at most 6 decimals, for people.
pub fn round(p: f64) -> f64 {
    // `+ 0.0` turns -0 (an empty sum) into 0.
    (p * 1e6).round() / 1e6 + 0.0
}

/// The plan as indented text: one action per line, under a sensing action
/// each observation with its probability, and shared nodes labelled and
/// joined.
#[derive(Debug)]
pub struct Display<'a> {
    pub(crate) task: &'a Task,
    pub(crate) graph: &'a PlanGraph,
}

impl PlanGraph {
    /// The plan as indented text (see [`Display`]).
    pub fn display<'a>(&'a self, task: &'a Task) -> Display<'a> {
        Display { task, graph: self }
    }
}

impl Display<'_> {
    fn write(
        &self,
        f: &mut fmt::Formatter<'_>,
        labels: &[Option<usize>],
        written: &mut [bool],
        start: usize,
        indent: usize,
    ) -> fmt::Result {
        let mut id = start;
        loop {
            if let Some(label) = labels[id] {
                if written[id] {
                    return writeln!(f, "{:indent$}go to [{label}]", "");
                }
                written[id] = true;
            }
            let tag = labels[id].map_or(String::new(), |l| format!("[{l}] "));
            match &self.graph.nodes[id] {
                PlanNode::Stop { success } => {
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
                PlanNode::Act { step, branches } => {
                    match &step.configure {
                        Some(goal) => writeln!(f, "{:indent$}{tag}{step}  ; configure {goal}", "")?,
                        None => writeln!(f, "{:indent$}{tag}{step}", "")?,
                    }
                    if let [only] = &branches[..]
                        && only.observation.is_empty()
                    {
                        id = only.next;
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
                        self.write(f, labels, written, b.next, indent + 4)?;
                    }
                    return Ok(());
                }
            }
        }
    }
}

impl fmt::Display for Display<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let labels = self.graph.labels();
        let mut written = vec![false; self.graph.nodes.len()];
        self.write(f, &labels, &mut written, 0, 0)
    }
}

/// The success probability and expected cost of `graph` run from `belief`,
/// by following beliefs through it (the planner's own reading; the oracle
/// has an independent one). `None` if an action does not apply in some
/// state or an observation has no branch. States are followed without the
/// atoms that can no longer matter, and each (node, belief) once.
pub fn evaluate(task: &Task, belief: &[(f64, State)], graph: &PlanGraph) -> Option<(f64, f64)> {
    let mut reader = Reader {
        task,
        graph,
        relevance: Relevance::new(task, &vec![false; task.operators().len()]),
    };
    let mut memo = HashMap::new();
    let belief: Vec<(f64, State)> = belief
        .iter()
        .map(|(p, s)| {
            let mut s = s.clone();
            reader.relevance.clear_irrelevant(task, &mut s);
            (*p, s)
        })
        .collect();
    reader.evaluate_at(&belief, 0, &mut memo)
}

struct Reader<'a> {
    task: &'a Task,
    graph: &'a PlanGraph,
    relevance: Relevance,
}

/// A belief as a key: its states and their probabilities to 12 digits.
type Key = (usize, Vec<(State, u64)>);

impl Reader<'_> {
    fn evaluate_at(
        &mut self,
        belief: &[(f64, State)],
        id: usize,
        memo: &mut HashMap<Key, Option<(f64, f64)>>,
    ) -> Option<(f64, f64)> {
        let (task, graph) = (self.task, self.graph);
        let key: Key = (
            id,
            belief
                .iter()
                .map(|(p, s)| (s.clone(), (p * 1e12).round() as u64))
                .collect(),
        );
        if let Some(&value) = memo.get(&key) {
            return value;
        }
        let value = match &graph.nodes[id] {
            PlanNode::Stop { .. } => Some((
                belief
                    .iter()
                    .filter(|(_, s)| task.is_goal(s))
                    .map(|(p, _)| p)
                    .sum(),
                0.0,
            )),
            PlanNode::Act { step, branches } => (|| {
                let mut split: Vec<Vec<(f64, State)>> = vec![Vec::new(); branches.len()];
                // Each state pays for and does what its variant of the action does.
                let mut cost = 0.0;
                for (p, s) in belief {
                    let o = task.operator(task.variant_in(s, step.op)?);
                    cost += p * o.cost as f64;
                    for (q, add, del) in o.each_outcome() {
                        let mut next = s.clone();
                        next.change(add, del);
                        let observed = |a: AtomId| next.holds(a);
                        let k = branches
                            .iter()
                            .position(|b| b.observation.iter().all(|&(a, v)| observed(a) == v))?;
                        self.relevance.clear_irrelevant(task, &mut next);
                        match split[k].iter_mut().find(|(_, t)| *t == next) {
                            Some((w, _)) => *w += p * q,
                            None => split[k].push((p * q, next)),
                        }
                    }
                }
                let (mut p, mut c) = (0.0, cost);
                for (mut part, b) in split.into_iter().zip(branches) {
                    let w: f64 = part.iter().map(|(p, _)| p).sum();
                    if w <= 0.0 {
                        continue;
                    }
                    part.sort_by(|a, b| a.1.words.cmp(&b.1.words));
                    for (q, _) in &mut part {
                        *q /= w;
                    }
                    let (bp, bc) = self.evaluate_at(&part, b.next, memo)?;
                    p += w * bp;
                    c += w * bc;
                }
                Some((p, c))
            })(),
        };
        memo.insert(key, value);
        value
    }
}
