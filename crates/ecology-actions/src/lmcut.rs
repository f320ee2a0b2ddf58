//! LM-cut (Helmert and Domshlak 2009) with incremental h-max: after each
//! cut only the facts whose h-max value falls are explored again, from the
//! cut's operators, as in Fast Downward's implementation. Admissible.
//!
//! The relaxed task is laid out flat (one array of preconditions, effects,
//! consumers and achievers each) with two artificial facts, as in the
//! paper: `start`, true in every state and the precondition of operators
//! without one, and `goal`, added by an artificial zero-cost operator whose
//! preconditions are the goal facts. So h-max of the goal is h-max of
//! `goal`, and the goal zone grows from `goal` alone.

use crate::heuristic::{Heuristic, Lists, Relaxed};
use crate::queue::Queue;
use crate::task::{OpId, State};

const INF: u64 = u64::MAX;
const NONE: u32 = u32::MAX;

/// The operators whose supporter each fact is, as intrusive doubly linked
/// lists: the cut search and the incremental update then follow exactly
/// the justification graph's edges instead of testing every consumer.
#[derive(Debug, Clone)]
struct Supported {
    head: Vec<u32>,
    next: Vec<u32>,
    prev: Vec<u32>,
}

impl Supported {
    fn link(&mut self, op: u32, fact: u32) {
        let first = self.head[fact as usize];
        self.next[op as usize] = first;
        self.prev[op as usize] = NONE;
        if first != NONE {
            self.prev[first as usize] = op;
        }
        self.head[fact as usize] = op;
    }

    fn unlink(&mut self, op: u32, fact: u32) {
        let (p, n) = (self.prev[op as usize], self.next[op as usize]);
        if p == NONE {
            self.head[fact as usize] = n;
        } else {
            self.next[p as usize] = n;
        }
        if n != NONE {
            self.prev[n as usize] = p;
        }
    }
}

/// LM-cut: repeatedly finds a cut of operators that every relaxed plan must
/// use, adds its cheapest cost, lowers the cut's costs by it and updates
/// h-max. Each cut is a disjunctive action landmark whose costs are
/// partitioned among the cuts, so the sum never exceeds the cost of an
/// optimal relaxed plan, hence of an optimal plan: admissible, and at least
/// h-max (the first cut alone costs no less).
#[derive(Debug, Clone)]
pub(crate) struct LmCut {
    relaxed: Relaxed,
    pre: Lists,
    eff: Lists,
    /// Operators with each fact as a precondition.
    consumers: Lists,
    /// Operators adding each fact.
    achievers: Lists,
    base_cost: Vec<u64>,
    start_fact: u32,
    goal_fact: u32,
    /// Per evaluation: operator costs left after the cuts so far.
    cost: Vec<u64>,
    unsatisfied: Vec<u32>,
    /// The precondition with the highest h-max (the one satisfied last).
    supporter: Vec<u32>,
    supporter_cost: Vec<u64>,
    supported: Supported,
    fact_cost: Vec<u64>,
    /// `2 * round` when the fact is in the goal zone of the current cut,
    /// `2 * round + 1` when it was reached before the goal zone.
    zone: Vec<u32>,
    /// `round` when the operator adds a fact of the goal zone.
    into_zone: Vec<u32>,
    round: u32,
    queue: Queue,
    stack: Vec<u32>,
    cut: Vec<u32>,
    /// The facts of the state being evaluated, for every round's cut search.
    state_facts: Vec<u32>,
    /// Per fact, how many operators achieve it at no cost left: from the
    /// task's costs (`base_zero_achievers`), counted up as cuts bring costs
    /// to 0. A fact with none is on the border of the goal zone.
    zero_achievers: Vec<u32>,
    base_zero_achievers: Vec<u32>,
}

impl LmCut {
    pub(crate) fn new(relaxed: Relaxed) -> LmCut {
        let facts = relaxed.facts();
        let start_fact = facts as u32;
        let goal_fact = facts as u32 + 1;
        let start = [start_fact];
        let mut pre: Vec<&[u32]> = relaxed
            .ops()
            .map(|(p, _, _)| if p.is_empty() { &start[..] } else { p })
            .collect();
        let goal_pre = if relaxed.goal().is_empty() {
            &start[..]
        } else {
            relaxed.goal()
        };
        pre.push(goal_pre);
        let goal = [goal_fact];
        let mut eff: Vec<&[u32]> = relaxed.ops().map(|(_, a, _)| a).collect();
        eff.push(&goal);
        let mut base_cost: Vec<u64> = relaxed.ops().map(|(_, _, c)| c).collect();
        base_cost.push(0);
        let pre = Lists::from_lists(pre);
        let eff = Lists::from_lists(eff);
        let consumers = pre.inverse(facts + 2);
        let achievers = eff.inverse(facts + 2);
        let ops = base_cost.len();
        let mut base_zero_achievers = vec![0; facts + 2];
        for (op, &c) in base_cost.iter().enumerate() {
            if c == 0 {
                for &e in eff.get(op) {
                    base_zero_achievers[e as usize] += 1;
                }
            }
        }
        LmCut {
            relaxed,
            pre,
            eff,
            consumers,
            achievers,
            cost: base_cost.clone(),
            base_cost,
            start_fact,
            goal_fact,
            unsatisfied: vec![0; ops],
            supporter: vec![NONE; ops],
            supporter_cost: vec![0; ops],
            supported: Supported {
                head: vec![NONE; facts + 2],
                next: vec![NONE; ops],
                prev: vec![NONE; ops],
            },
            fact_cost: vec![INF; facts + 2],
            zone: vec![0; facts + 2],
            into_zone: vec![0; ops],
            round: 0,
            queue: Queue::default(),
            stack: Vec::new(),
            cut: Vec::new(),
            state_facts: Vec::new(),
            zero_achievers: base_zero_achievers.clone(),
            base_zero_achievers,
        }
    }

    // The phases below stay out of line so that profiles tell them apart;
    // each runs a few times per evaluation, so the calls cost nothing.

    /// h-max from `state` with the full operator costs, every reachable fact
    /// explored (the cuts need all of them).
    #[inline(never)]
    fn first_exploration(&mut self, state: &State) {
        let LmCut {
            relaxed,
            pre,
            eff,
            consumers,
            base_cost,
            cost,
            unsatisfied,
            supporter,
            supporter_cost,
            supported,
            fact_cost,
            queue,
            start_fact,
            state_facts,
            zero_achievers,
            base_zero_achievers,
            ..
        } = self;
        fact_cost.fill(INF);
        // Operators this state cannot reach must have no supporter: the goal
        // zone follows supporters of zero-cost operators.
        supporter.fill(NONE);
        supported.head.fill(NONE);
        cost.copy_from_slice(base_cost);
        zero_achievers.copy_from_slice(base_zero_achievers);
        for (slot, w) in unsatisfied.iter_mut().zip(pre.start.windows(2)) {
            *slot = w[1] - w[0];
        }
        queue.clear();
        fact_cost[*start_fact as usize] = 0;
        queue.push(0, *start_fact);
        state_facts.clear();
        relaxed.state_facts(state, |f| {
            fact_cost[f as usize] = 0;
            queue.push(0, f);
            state_facts.push(f);
        });
        while let Some((c, f)) = queue.pop() {
            if c > fact_cost[f as usize] {
                continue;
            }
            for &op in consumers.get(f as usize) {
                let op = op as usize;
                unsatisfied[op] -= 1;
                if unsatisfied[op] == 0 {
                    supporter[op] = f;
                    supporter_cost[op] = c;
                    supported.link(op as u32, f);
                    let target = c.saturating_add(cost[op]);
                    for &e in eff.get(op) {
                        if target < fact_cost[e as usize] {
                            fact_cost[e as usize] = target;
                            queue.push(target, e);
                        }
                    }
                }
            }
        }
    }

    /// After the cut's costs fell: h-max again, from the cut's effects,
    /// through operators whose supporter became cheaper. Costs only fall, so
    /// this is a Dijkstra over the facts whose value falls.
    #[inline(never)]
    fn incremental_exploration(&mut self) {
        let LmCut {
            pre,
            eff,
            cost,
            supporter,
            supporter_cost,
            supported,
            fact_cost,
            queue,
            cut,
            ..
        } = self;
        queue.clear();
        for &op in cut.iter() {
            let op = op as usize;
            let target = supporter_cost[op].saturating_add(cost[op]);
            for &e in eff.get(op) {
                if target < fact_cost[e as usize] {
                    fact_cost[e as usize] = target;
                    queue.push(target, e);
                }
            }
        }
        while let Some((c, f)) = queue.pop() {
            if c > fact_cost[f as usize] {
                continue;
            }
            let mut next = supported.head[f as usize];
            while next != NONE {
                let op = next as usize;
                next = supported.next[op];
                if supporter_cost[op] <= c {
                    continue;
                }
                // `f` fell; the costliest precondition may now be another
                // one (the supporter stays on ties, as in the first pass).
                let old = supporter_cost[op];
                let mut best = f;
                let mut best_cost = c;
                for &p in pre.get(op) {
                    let pc = fact_cost[p as usize];
                    if pc > best_cost {
                        best = p;
                        best_cost = pc;
                    }
                }
                if best != f {
                    supported.unlink(op as u32, f);
                    supported.link(op as u32, best);
                    supporter[op] = best;
                }
                supporter_cost[op] = best_cost;
                if best_cost < old {
                    let target = best_cost.saturating_add(cost[op]);
                    for &e in eff.get(op) {
                        if target < fact_cost[e as usize] {
                            fact_cost[e as usize] = target;
                            queue.push(target, e);
                        }
                    }
                }
            }
        }
    }

    /// Marks the goal zone: facts from which `goal` is reached through
    /// zero-cost operators of the justification graph.
    ///
    /// A zero-cost operator whose supporter ties with other preconditions
    /// (equal h-max) is first given, among them, the one that grows the
    /// zone least: one already in it or on its border (no zero-cost
    /// operator achieves it), else the one with the fewest zero-cost
    /// achievers; the first of equals. Any tied precondition is a valid
    /// supporter, so the value stays admissible; a small zone makes the cuts
    /// land on different landmarks. It matters most for the artificial goal
    /// operator, which costs nothing and has every goal as a precondition:
    /// in visitall, where the goals tie, it is the difference between 24
    /// and 28 on visitall-opt14 p-05-7 (Fast Downward's: 28). And in barman,
    /// where serving a cocktail needs a shaken shaker (any shake does it)
    /// and the cocktail in it (one shake does): following the first puts
    /// every ingredient in the zone and all their fills in one cut; 17
    /// against 37 on barman-opt11 pfile01-001 (Fast Downward's: 39).
    #[inline(never)]
    fn mark_goal_zone(&mut self) {
        let LmCut {
            pre,
            achievers,
            cost,
            supporter,
            supporter_cost,
            supported,
            fact_cost,
            zero_achievers,
            zone,
            into_zone,
            stack,
            goal_fact,
            round,
            ..
        } = self;
        let goal_mark = 2 * *round;
        stack.clear();
        zone[*goal_fact as usize] = goal_mark;
        stack.push(*goal_fact);
        while let Some(f) = stack.pop() {
            for &op in achievers.get(f as usize) {
                let op = op as usize;
                into_zone[op] = *round;
                if cost[op] != 0 || supporter[op] == NONE {
                    continue;
                }
                // Among the tied preconditions, the one that grows the zone
                // least: one in it or on its border, else the one with the
                // fewest zero-cost achievers; the first of equals.
                let growth = |p: u32| {
                    if zone[p as usize] == goal_mark {
                        0
                    } else {
                        zero_achievers[p as usize]
                    }
                };
                let tied = pre
                    .get(op)
                    .iter()
                    .copied()
                    .filter(|&p| fact_cost[p as usize] == supporter_cost[op])
                    .min_by_key(|&p| growth(p));
                if let Some(p) = tied
                    && p != supporter[op]
                {
                    supported.unlink(op as u32, supporter[op]);
                    supported.link(op as u32, p);
                    supporter[op] = p;
                }
                let p = supporter[op];
                if zone[p as usize] != goal_mark {
                    zone[p as usize] = goal_mark;
                    stack.push(p);
                }
            }
        }
    }

    /// Forward from the state through the justification graph, stopping at
    /// the goal zone: the operators crossing into it form the cut.
    #[inline(never)]
    fn find_cut(&mut self) {
        let LmCut {
            state_facts,
            eff,
            supported,
            zone,
            into_zone,
            stack,
            cut,
            start_fact,
            round,
            ..
        } = self;
        let goal_mark = 2 * *round;
        let before_mark = goal_mark + 1;
        cut.clear();
        stack.clear();
        zone[*start_fact as usize] = before_mark;
        stack.push(*start_fact);
        for &f in state_facts.iter() {
            zone[f as usize] = before_mark;
            stack.push(f);
        }
        while let Some(f) = stack.pop() {
            let mut next = supported.head[f as usize];
            while next != NONE {
                let op = next as usize;
                next = supported.next[op];
                if into_zone[op] == *round {
                    cut.push(op as u32);
                } else {
                    for &e in eff.get(op) {
                        if zone[e as usize] != before_mark {
                            zone[e as usize] = before_mark;
                            stack.push(e);
                        }
                    }
                }
            }
        }
    }

    fn next_round(&mut self) {
        if self.round >= u32::MAX / 2 - 1 {
            self.zone.fill(0);
            self.into_zone.fill(0);
            self.round = 0;
        }
        self.round += 1;
    }
}

impl Heuristic for LmCut {
    fn name(&self) -> &'static str {
        "lmcut"
    }

    fn is_admissible(&self) -> bool {
        true
    }

    fn estimate(&mut self, state: &State, _: &mut Vec<OpId>) -> Option<u64> {
        if self.relaxed.impossible() {
            return None;
        }
        self.first_exploration(state);
        if self.fact_cost[self.goal_fact as usize] == INF {
            return None;
        }
        let mut total = 0u64;
        while self.fact_cost[self.goal_fact as usize] != 0 {
            self.next_round();
            self.mark_goal_zone();
            self.find_cut();
            let m = self
                .cut
                .iter()
                .map(|&op| self.cost[op as usize])
                .min()
                .unwrap_or(0);
            if m == 0 {
                // A cut of positive-cost operators always exists while the
                // goal costs more than 0; stop rather than loop if not.
                break;
            }
            total = total.saturating_add(m);
            for &op in &self.cut {
                let op = op as usize;
                self.cost[op] -= m;
                if self.cost[op] == 0 {
                    for &e in self.eff.get(op) {
                        self.zero_achievers[e as usize] += 1;
                    }
                }
            }
            self.incremental_exploration();
        }
        Some(total)
    }
}
