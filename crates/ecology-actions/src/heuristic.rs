//! Heuristics: estimates of the cost from a state to the goal, from the
//! delete relaxation of the task.
//!
//! The relaxation works on *facts*: every fluent atom, plus a complement fact
//! "`a` is false" for each atom that some precondition or the goal requires
//! to be false. An operator that deletes `a` adds its complement, so negative
//! preconditions are relaxed as faithfully as positive ones. Operators the
//! caller excludes are not in the relaxation.

use crate::queue::Queue;
use crate::task::{OpId, State, Task};

/// A cost-to-goal estimate for states of one task.
pub trait Heuristic {
    /// A short name, such as `ff`.
    fn name(&self) -> &'static str;

    /// Whether the estimate never exceeds the true cost to the goal, so that
    /// A* with it returns optimal plans.
    fn is_admissible(&self) -> bool;

    /// The estimate for `state`, or `None` when the goal is unreachable from
    /// it even in the relaxation (a proven dead end). Appends to `preferred`
    /// the operators it recommends in `state`, if it has any to recommend.
    fn estimate(&mut self, state: &State, preferred: &mut Vec<OpId>) -> Option<u64>;
}

/// The heuristics this crate offers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeuristicKind {
    /// 0 everywhere: uniform-cost search under A*. Admissible.
    Blind,
    /// h-max: the costliest goal fact in the relaxation. Admissible.
    Max,
    /// h-add: the sum of goal fact costs in the relaxation. Not admissible.
    Add,
    /// FF: the cost of a relaxed plan, with preferred operators. Not admissible.
    Ff,
    /// LM-cut: landmark cuts of the h-max justification graph. Admissible,
    /// and at least as informed as h-max.
    LmCut,
}

impl HeuristicKind {
    /// Whether the heuristic is admissible.
    pub fn is_admissible(self) -> bool {
        matches!(
            self,
            HeuristicKind::Blind | HeuristicKind::Max | HeuristicKind::LmCut
        )
    }

    /// The heuristic for `task`, ignoring the `excluded` operators.
    pub fn build<'t>(self, task: &'t Task, excluded: &[bool]) -> Box<dyn Heuristic + 't> {
        self.build_costed(task, excluded, Costs::Task)
    }

    /// The heuristic for `task` counting operator costs as `costs` says.
    pub(crate) fn build_costed<'t>(
        self,
        task: &'t Task,
        excluded: &[bool],
        costs: Costs,
    ) -> Box<dyn Heuristic + 't> {
        let mut relaxed = Relaxed::new(task, excluded);
        match costs {
            Costs::Task => {}
            Costs::One => relaxed.ops.iter_mut().for_each(|o| o.cost = 1),
            Costs::PlusOne => relaxed
                .ops
                .iter_mut()
                .for_each(|o| o.cost = o.cost.saturating_add(1)),
        }
        match self {
            HeuristicKind::Blind => Box::new(Blind),
            HeuristicKind::Max => Box::new(HMax(Exploration::new(relaxed))),
            HeuristicKind::Add => Box::new(HAdd(Exploration::new(relaxed))),
            HeuristicKind::Ff => Box::new(HFf {
                explore: Exploration::new(relaxed),
                marked: Vec::new(),
                seen: Vec::new(),
                stack: Vec::new(),
            }),
            HeuristicKind::LmCut => Box::new(crate::lmcut::LmCut::new(relaxed)),
        }
    }
}

impl std::str::FromStr for HeuristicKind {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "blind" => Ok(HeuristicKind::Blind),
            "max" | "hmax" => Ok(HeuristicKind::Max),
            "add" | "hadd" => Ok(HeuristicKind::Add),
            "ff" => Ok(HeuristicKind::Ff),
            "lmcut" | "lm-cut" => Ok(HeuristicKind::LmCut),
            _ => Err(format!(
                "unknown heuristic `{s}` (blind, max, add, ff, lmcut)"
            )),
        }
    }
}

const INF: u64 = u64::MAX;

/// The operator costs a heuristic counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Costs {
    /// The task's own.
    Task,
    /// 1 each: the estimate counts actions, not their costs, as
    /// `lama-first`'s does. Greedy search is after a plan soon: counted
    /// this way, actions that cost nothing still make a relaxed plan
    /// longer (openstacks, where every state of a plateau would otherwise
    /// look alike), and cheap detours do not look better than a short way
    /// (data-network-opt18 p04: 122,516 expansions counting each action's
    /// cost plus one, 12 counting actions).
    One,
    /// Each its own plus one, as LAMA's improvement phase counts them:
    /// guided by the costs, yet actions that cost nothing still count.
    PlusOne,
}

/// A relaxed operator: preconditions and effects as facts.
#[derive(Debug, Clone)]
struct RelaxedOp {
    pre: Vec<u32>,
    add: Vec<u32>,
    cost: u64,
    op: OpId,
}

/// The delete relaxation of a task.
#[derive(Debug, Clone)]
pub(crate) struct Relaxed {
    facts: usize,
    atoms: usize,
    /// Complement fact of each atom, or `u32::MAX`.
    complement: Vec<u32>,
    ops: Vec<RelaxedOp>,
    /// Relaxed operators having each fact as a precondition.
    pre_of: Vec<Vec<u32>>,
    goal: Vec<u32>,
    /// Whether each fact is a goal fact.
    is_goal: Vec<bool>,
    /// The goal is false for a static reason.
    impossible: bool,
    /// `(atom, complement fact)` for the atoms that have a complement.
    complemented: Vec<(u32, u32)>,
}

impl Relaxed {
    pub(crate) fn new(task: &Task, excluded: &[bool]) -> Relaxed {
        let atoms = task.atom_count();
        let mut complement = vec![u32::MAX; atoms];
        let mut facts = atoms as u32;
        let mut need = |a: usize, complement: &mut Vec<u32>| {
            if complement[a] == u32::MAX {
                complement[a] = facts;
                facts += 1;
            }
        };
        for o in task.operators() {
            for a in &o.pre_neg {
                need(a.0 as usize, &mut complement);
            }
        }
        for a in task.goal_neg() {
            need(a.0 as usize, &mut complement);
        }
        let mut ops = Vec::new();
        for (i, o) in task.operators().iter().enumerate() {
            if excluded.get(i).copied().unwrap_or(false) {
                continue;
            }
            let mut pre: Vec<u32> = o.pre.iter().map(|a| a.0).collect();
            pre.extend(o.pre_neg.iter().map(|a| complement[a.0 as usize]));
            let mut add: Vec<u32> = o.add.iter().map(|a| a.0).collect();
            add.extend(
                o.del
                    .iter()
                    .map(|a| complement[a.0 as usize])
                    .filter(|&c| c != u32::MAX),
            );
            ops.push(RelaxedOp {
                pre,
                add,
                cost: o.cost,
                op: OpId(i as u32),
            });
        }
        let mut pre_of = vec![Vec::new(); facts as usize];
        for (i, o) in ops.iter().enumerate() {
            for &f in &o.pre {
                pre_of[f as usize].push(i as u32);
            }
        }
        let mut goal: Vec<u32> = task.goal().iter().map(|a| a.0).collect();
        goal.extend(task.goal_neg().iter().map(|a| complement[a.0 as usize]));
        goal.sort_unstable();
        goal.dedup();
        let mut is_goal = vec![false; facts as usize];
        for &g in &goal {
            is_goal[g as usize] = true;
        }
        let complemented = complement
            .iter()
            .enumerate()
            .filter(|&(_, &c)| c != u32::MAX)
            .map(|(a, &c)| (a as u32, c))
            .collect();
        Relaxed {
            complemented,
            is_goal,
            facts: facts as usize,
            atoms,
            complement,
            ops,
            pre_of,
            goal,
            impossible: !task.goal_false().is_empty(),
        }
    }

    /// Calls `f` with each fact true in `state`.
    pub(crate) fn state_facts(&self, state: &State, mut f: impl FnMut(u32)) {
        for a in state.atoms() {
            if (a.0 as usize) < self.atoms {
                f(a.0);
            }
        }
        for &(a, c) in &self.complemented {
            if !state.holds(crate::task::AtomId(a)) {
                f(c);
            }
        }
    }

    /// For every fact in order, its atom and whether the fact is that atom
    /// being true (not its complement).
    pub(crate) fn literals(&self) -> Vec<(crate::task::AtomId, bool)> {
        let mut out: Vec<_> = (0..self.facts as u32)
            .map(|f| (crate::task::AtomId(f), true))
            .collect();
        for &(atom, c) in &self.complemented {
            out[c as usize] = (crate::task::AtomId(atom), false);
        }
        out
    }

    /// Whether `fact` is a goal fact.
    pub(crate) fn is_goal(&self, fact: u32) -> bool {
        self.is_goal[fact as usize]
    }

    /// How many facts: atoms and complements.
    pub(crate) fn facts(&self) -> usize {
        self.facts
    }

    /// Each relaxed operator's preconditions, effects and cost.
    pub(crate) fn ops(&self) -> impl Iterator<Item = (&[u32], &[u32], u64)> + '_ {
        self.ops.iter().map(|o| (&o.pre[..], &o.add[..], o.cost))
    }

    /// The goal facts.
    pub(crate) fn goal(&self) -> &[u32] {
        &self.goal
    }

    /// Whether the goal is false for a static reason.
    pub(crate) fn impossible(&self) -> bool {
        self.impossible
    }
}

/// Lists stored flat: list `i` is `items[start[i]..start[i + 1]]`.
#[derive(Debug, Clone)]
pub(crate) struct Lists<T = u32> {
    pub(crate) start: Vec<u32>,
    pub(crate) items: Vec<T>,
}

impl<T: Copy> Lists<T> {
    pub(crate) fn from_lists<'a>(lists: impl IntoIterator<Item = &'a [T]>) -> Lists<T>
    where
        T: 'a,
    {
        let mut out = Lists {
            start: vec![0],
            items: Vec::new(),
        };
        for list in lists {
            out.items.extend_from_slice(list);
            out.start.push(out.items.len() as u32);
        }
        out
    }

    pub(crate) fn len(&self) -> usize {
        self.start.len() - 1
    }

    pub(crate) fn get(&self, i: usize) -> &[T] {
        &self.items[self.start[i] as usize..self.start[i + 1] as usize]
    }
}

impl Lists {
    /// The lists `i` appears in, for `i` in `0..n`: the reverse relation.
    pub(crate) fn inverse(&self, n: usize) -> Lists {
        let mut lists = vec![Vec::new(); n];
        for i in 0..self.len() {
            for &x in self.get(i) {
                lists[x as usize].push(i as u32);
            }
        }
        Lists::from_lists(lists.iter().map(Vec::as_slice))
    }
}

/// How preconditions combine in an exploration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Combine {
    Sum,
    Max,
}

/// A generalized Dijkstra over facts: h-add or h-max costs, with the
/// supporter of each fact and each operator's costliest precondition.
#[derive(Debug, Clone)]
struct Exploration {
    relaxed: Relaxed,
    cost: Vec<u64>,
    supporter: Vec<u32>,
    unsatisfied: Vec<u32>,
    op_cost: Vec<u64>,
    /// The precondition that made each operator fire last (its h-max argmax).
    last_pre: Vec<u32>,
    /// Equal costs pop last pushed first, which decides the supporters.
    queue: Queue,
    /// The relaxed task laid out flat for the hot loops: each operator's
    /// precondition count, effects and cost, each fact's consumers (in
    /// operator order, as in `relaxed`, so ties break the same way).
    pre_count: Vec<u32>,
    add: Lists,
    base_cost: Vec<u64>,
    consumers: Lists,
    no_pre: Vec<u32>,
}

impl Exploration {
    fn new(relaxed: Relaxed) -> Exploration {
        let facts = relaxed.facts;
        let ops = relaxed.ops.len();
        let consumers = Lists::from_lists(relaxed.pre_of.iter().map(Vec::as_slice));
        Exploration {
            pre_count: relaxed.ops.iter().map(|o| o.pre.len() as u32).collect(),
            add: Lists::from_lists(relaxed.ops.iter().map(|o| &o.add[..])),
            base_cost: relaxed.ops.iter().map(|o| o.cost).collect(),
            consumers,
            no_pre: (0..ops as u32)
                .filter(|&i| relaxed.ops[i as usize].pre.is_empty())
                .collect(),
            relaxed,
            cost: vec![INF; facts],
            supporter: vec![u32::MAX; facts],
            unsatisfied: vec![0; ops],
            op_cost: vec![0; ops],
            last_pre: vec![u32::MAX; ops],
            queue: Queue::default(),
        }
    }

    /// Explores from `state` with operator costs `costs` (by relaxed
    /// operator); returns the goal's combined cost, or `None` if unreachable.
    /// With `full`, explores every reachable fact rather than stopping once
    /// the goal facts are settled.
    fn run(
        &mut self,
        state: &State,
        combine: Combine,
        costs: Option<&[u64]>,
        full: bool,
    ) -> Option<u64> {
        if self.relaxed.impossible {
            return None;
        }
        let Exploration {
            relaxed,
            cost,
            supporter,
            unsatisfied,
            op_cost,
            last_pre,
            queue,
            pre_count,
            add,
            base_cost,
            consumers,
            no_pre,
        } = self;
        cost.fill(INF);
        supporter.fill(u32::MAX);
        last_pre.fill(u32::MAX);
        queue.clear();
        unsatisfied.copy_from_slice(pre_count);
        op_cost.fill(0);
        let costs: &[u64] = costs.unwrap_or(base_cost);
        let mut fire = |i: usize, op_cost: u64, cost: &mut [u64], queue: &mut Queue| {
            let value = op_cost.saturating_add(costs[i]);
            for &g in add.get(i) {
                if value < cost[g as usize] {
                    cost[g as usize] = value;
                    supporter[g as usize] = i as u32;
                    queue.push(value, g);
                }
            }
        };
        relaxed.state_facts(state, |f| {
            cost[f as usize] = 0;
            queue.push(0, f);
        });
        for &i in no_pre.iter() {
            fire(i as usize, 0, cost, queue);
        }
        let mut goals_left = relaxed.goal.len();
        loop {
            if goals_left == 0 && !full {
                break;
            }
            let Some((c, f)) = queue.pop() else {
                break;
            };
            if c > cost[f as usize] {
                continue;
            }
            if relaxed.is_goal[f as usize] {
                goals_left -= 1;
            }
            for &i in consumers.get(f as usize) {
                let i = i as usize;
                op_cost[i] = match combine {
                    Combine::Sum => op_cost[i].saturating_add(c),
                    Combine::Max => op_cost[i].max(c),
                };
                unsatisfied[i] -= 1;
                if unsatisfied[i] == 0 {
                    last_pre[i] = f;
                    fire(i, op_cost[i], cost, queue);
                }
            }
        }
        if goals_left > 0 {
            return None;
        }
        let mut total = 0u64;
        for &g in &relaxed.goal {
            let c = cost[g as usize];
            total = match combine {
                Combine::Sum => total.saturating_add(c),
                Combine::Max => total.max(c),
            };
        }
        Some(total)
    }
}

/// 0 for every state.
#[derive(Debug, Clone, Copy)]
struct Blind;

impl Heuristic for Blind {
    fn name(&self) -> &'static str {
        "blind"
    }

    fn is_admissible(&self) -> bool {
        true
    }

    fn estimate(&mut self, _: &State, _: &mut Vec<OpId>) -> Option<u64> {
        Some(0)
    }
}

/// h-max (Bonet and Geffner): admissible.
#[derive(Debug, Clone)]
struct HMax(Exploration);

impl Heuristic for HMax {
    fn name(&self) -> &'static str {
        "max"
    }

    fn is_admissible(&self) -> bool {
        true
    }

    fn estimate(&mut self, state: &State, _: &mut Vec<OpId>) -> Option<u64> {
        self.0.run(state, Combine::Max, None, false)
    }
}

/// h-add (Bonet and Geffner): informative, not admissible.
#[derive(Debug, Clone)]
struct HAdd(Exploration);

impl Heuristic for HAdd {
    fn name(&self) -> &'static str {
        "add"
    }

    fn is_admissible(&self) -> bool {
        false
    }

    fn estimate(&mut self, state: &State, _: &mut Vec<OpId>) -> Option<u64> {
        self.0.run(state, Combine::Sum, None, false)
    }
}

/// FF (Hoffmann and Nebel): the cost of a relaxed plan extracted from h-add
/// supporters; its operators applicable in the state are preferred. Not
/// admissible.
#[derive(Debug, Clone)]
struct HFf {
    explore: Exploration,
    marked: Vec<bool>,
    seen: Vec<bool>,
    stack: Vec<u32>,
}

impl Heuristic for HFf {
    fn name(&self) -> &'static str {
        "ff"
    }

    fn is_admissible(&self) -> bool {
        false
    }

    fn estimate(&mut self, state: &State, preferred: &mut Vec<OpId>) -> Option<u64> {
        self.explore.run(state, Combine::Sum, None, false)?;
        let e = &self.explore;
        self.marked.clear();
        self.marked.resize(e.relaxed.ops.len(), false);
        self.stack.clear();
        self.stack.extend(&e.relaxed.goal);
        let seen = &mut self.seen;
        seen.clear();
        seen.resize(e.relaxed.facts, false);
        let mut total = 0u64;
        while let Some(f) = self.stack.pop() {
            if seen[f as usize] || e.cost[f as usize] == 0 {
                continue;
            }
            seen[f as usize] = true;
            let op = e.supporter[f as usize] as usize;
            if op == u32::MAX as usize || self.marked[op] {
                continue;
            }
            self.marked[op] = true;
            let o = &e.relaxed.ops[op];
            total = total.saturating_add(o.cost);
            if o.pre.iter().all(|&p| e.cost[p as usize] == 0) {
                preferred.push(o.op);
            }
            self.stack.extend(&o.pre);
        }
        Some(total)
    }
}

/// LM-cut (Helmert and Domshlak) computing h-max from scratch after every
/// cut: the straightforward version [`crate::lmcut::LmCut`] replaced, kept
/// as a test oracle. Admissible.
#[cfg(test)]
#[derive(Debug, Clone)]
pub(crate) struct LmCutFromScratch {
    explore: Exploration,
    costs: Vec<u64>,
    in_zone: Vec<bool>,
    reached: Vec<bool>,
    adders: Vec<Vec<u32>>,
    by_last_pre: Vec<Vec<u32>>,
    no_pre: Vec<u32>,
}

#[cfg(test)]
impl LmCutFromScratch {
    pub(crate) fn new(relaxed: Relaxed) -> LmCutFromScratch {
        let mut adders = vec![Vec::new(); relaxed.facts];
        for (i, o) in relaxed.ops.iter().enumerate() {
            for &f in &o.add {
                adders[f as usize].push(i as u32);
            }
        }
        let facts = relaxed.facts;
        LmCutFromScratch {
            costs: relaxed.ops.iter().map(|o| o.cost).collect(),
            explore: Exploration::new(relaxed),
            in_zone: vec![false; facts],
            reached: vec![false; facts],
            adders,
            by_last_pre: vec![Vec::new(); facts],
            no_pre: Vec::new(),
        }
    }
}

#[cfg(test)]
impl Heuristic for LmCutFromScratch {
    fn name(&self) -> &'static str {
        "lmcut"
    }

    fn is_admissible(&self) -> bool {
        true
    }

    fn estimate(&mut self, state: &State, _: &mut Vec<OpId>) -> Option<u64> {
        for (c, o) in self.costs.iter_mut().zip(&self.explore.relaxed.ops) {
            *c = o.cost;
        }
        let mut total = 0u64;
        let mut h = self
            .explore
            .run(state, Combine::Max, Some(&self.costs), true)?;
        while h > 0 {
            let e = &self.explore;
            let ops = &e.relaxed.ops;
            // The goal zone: facts from which the goal is reached through
            // zero-cost operators of the justification graph.
            self.in_zone.fill(false);
            let mut stack: Vec<u32> = Vec::new();
            // The artificial goal operator's costliest precondition.
            let goal_pcf = e
                .relaxed
                .goal
                .iter()
                .copied()
                .max_by_key(|&g| e.cost[g as usize])
                .unwrap_or(0);
            self.in_zone[goal_pcf as usize] = true;
            stack.push(goal_pcf);
            while let Some(f) = stack.pop() {
                for &i in &self.adders[f as usize] {
                    let i = i as usize;
                    let p = e.last_pre[i];
                    if self.costs[i] == 0
                        && p != u32::MAX
                        && e.cost[p as usize] != INF
                        && !self.in_zone[p as usize]
                    {
                        self.in_zone[p as usize] = true;
                        stack.push(p);
                    }
                }
            }
            // Operators of the justification graph, by costliest precondition.
            for v in &mut self.by_last_pre {
                v.clear();
            }
            self.no_pre.clear();
            for (i, o) in ops.iter().enumerate() {
                if o.pre.is_empty() {
                    self.no_pre.push(i as u32);
                } else if e.last_pre[i] != u32::MAX {
                    self.by_last_pre[e.last_pre[i] as usize].push(i as u32);
                }
            }
            // Forward from the state, stopping at the zone: the operators
            // crossing into it form the cut.
            self.reached.fill(false);
            let mut cut: Vec<u32> = Vec::new();
            let mut cut_seen = vec![false; ops.len()];
            let reached = &mut self.reached;
            e.relaxed.state_facts(state, |f| {
                if !reached[f as usize] {
                    reached[f as usize] = true;
                    stack.push(f);
                }
            });
            let mut visit = |i: u32, stack: &mut Vec<u32>, reached: &mut Vec<bool>| {
                let o = &ops[i as usize];
                if o.add.iter().any(|&g| self.in_zone[g as usize]) {
                    if !cut_seen[i as usize] {
                        cut_seen[i as usize] = true;
                        cut.push(i);
                    }
                } else {
                    for &g in &o.add {
                        if !reached[g as usize] {
                            reached[g as usize] = true;
                            stack.push(g);
                        }
                    }
                }
            };
            for k in 0..self.no_pre.len() {
                visit(self.no_pre[k], &mut stack, reached);
            }
            while let Some(f) = stack.pop() {
                if self.in_zone[f as usize] {
                    continue;
                }
                for &i in &self.by_last_pre[f as usize] {
                    visit(i, &mut stack, reached);
                }
            }
            let m = cut
                .iter()
                .map(|&i| self.costs[i as usize])
                .min()
                .unwrap_or(0);
            if m == 0 {
                // Cannot happen with a correct cut; stop rather than loop.
                break;
            }
            total = total.saturating_add(m);
            for &i in &cut {
                self.costs[i as usize] -= m;
            }
            h = self
                .explore
                .run(state, Combine::Max, Some(&self.costs), true)
                .unwrap_or(0);
        }
        Some(total)
    }
}

/// The goal facts unreachable in the relaxation from `state`, named for
/// people: why the task is unsolvable, when the relaxation can tell.
pub(crate) fn unreachable_goals(task: &Task, excluded: &[bool], state: &State) -> Vec<String> {
    let relaxed = Relaxed::new(task, excluded);
    let mut explore = Exploration::new(relaxed);
    if explore.run(state, Combine::Max, None, false).is_some() {
        return Vec::new();
    }
    let mut out: Vec<String> = task.goal_false().to_vec();
    for &a in task.goal() {
        if explore.cost[a.0 as usize] == INF {
            out.push(task.atom_name(a));
        }
    }
    for &a in task.goal_neg() {
        let c = explore.relaxed.complement[a.0 as usize];
        if c != u32::MAX && explore.cost[c as usize] == INF {
            out.push(format!("(not {})", task.atom_name(a)));
        }
    }
    out
}
