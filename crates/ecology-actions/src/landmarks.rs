//! The landmark-count heuristic, LAMA's second heuristic (Richter and
//! Westphal 2010), over landmarks found by label propagation in the delete
//! relaxation (Zhu and Givan 2003).
//!
//! A *landmark* is a fact that every plan from the start makes true at
//! some point. Each fact of the relaxation gets a label: the facts that
//! every relaxed way of reaching it passes through. A fact true at the
//! start is its own label; an operator's label is the union of its
//! preconditions' labels; a fact's label is itself plus the intersection
//! of its achievers' labels. Labels start at "every fact" and only shrink,
//! so the propagation reaches the same fixpoint in any order. The goal
//! facts' labels together are the landmarks: a plan reaches the goal only
//! through each of them, and every relaxed plan is a plan of the
//! relaxation.
//!
//! The count is path dependent: a landmark is *accepted* once some state
//! on the path to the current one made it true, and each state keeps the
//! set accepted on the path by which the search first reached it (Fast
//! Downward's eager search also merges in the sets of later paths; ours
//! keeps the first path's). The estimate is the number of landmarks not yet
//! accepted, plus the accepted ones that are needed again: a goal that is
//! false now, or a fact false now that is a precondition of every achiever
//! of a landmark not yet accepted. Like LAMA's, it counts one per landmark
//! whatever the actions cost, offers no preferred operators, and is not
//! admissible: it guides greedy search alongside FF, not A*.

use crate::heuristic::{Lists, Relaxed};
use crate::task::{AtomId, State};

const NONE: u32 = u32::MAX;

/// The landmark-count heuristic, with the accepted landmarks of every
/// state the search has made a node: node `i`'s are `accepted[i]`.
#[derive(Debug, Clone)]
pub(crate) struct LandmarkCount {
    /// Each landmark, as an atom that must hold (`true`) or not.
    literal: Vec<(AtomId, bool)>,
    /// Whether each landmark is a goal fact.
    goal: Vec<bool>,
    /// For each landmark, the landmarks it is a precondition of every
    /// achiever of.
    needed_by: Lists,
    /// Words per node in `accepted`.
    words: usize,
    accepted: Vec<u64>,
}

fn bit(set: &[u64], i: u32) -> bool {
    set[(i / 64) as usize] & (1 << (i % 64)) != 0
}

fn set_bit(set: &mut [u64], i: u32) {
    set[(i / 64) as usize] |= 1 << (i % 64);
}

/// The sorted intersection of two sorted lists, into `out`.
fn intersect(a: &[u32], b: &[u32], out: &mut Vec<u32>) {
    out.clear();
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        match a[i].cmp(&b[j]) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => {
                out.push(a[i]);
                i += 1;
                j += 1;
            }
        }
    }
}

/// Each fact's label at the fixpoint (`None`: unreachable), for the
/// relaxation `relaxed` from the facts `initial`.
fn labels(relaxed: &Relaxed, initial: &[bool]) -> Vec<Option<Vec<u32>>> {
    let facts = relaxed.facts();
    let pre = Lists::from_lists(relaxed.ops().map(|(pre, _, _)| pre));
    let add = Lists::from_lists(relaxed.ops().map(|(_, add, _)| add));
    let consumers = pre.inverse(facts);
    let mut label: Vec<Option<Vec<u32>>> = vec![None; facts];
    let mut queue = std::collections::VecDeque::new();
    let mut queued = vec![false; facts];
    for (f, &holds) in initial.iter().enumerate() {
        if holds {
            label[f] = Some(vec![f as u32]);
        }
    }
    let mut union = Vec::new();
    let mut meet = Vec::new();
    let mut process = |o: usize,
                       label: &mut Vec<Option<Vec<u32>>>,
                       queue: &mut std::collections::VecDeque<u32>,
                       queued: &mut Vec<bool>| {
        union.clear();
        for &q in pre.get(o) {
            match &label[q as usize] {
                Some(l) => union.extend_from_slice(l),
                None => return,
            }
        }
        union.sort_unstable();
        union.dedup();
        for &p in add.get(o) {
            if initial[p as usize] {
                continue;
            }
            let mut new = union.clone();
            if let Err(at) = new.binary_search(&p) {
                new.insert(at, p);
            }
            let changed = match &label[p as usize] {
                None => {
                    label[p as usize] = Some(new);
                    true
                }
                Some(old) => {
                    intersect(old, &new, &mut meet);
                    if meet.len() < old.len() {
                        label[p as usize] = Some(std::mem::take(&mut meet));
                        true
                    } else {
                        false
                    }
                }
            };
            if changed && !queued[p as usize] {
                queued[p as usize] = true;
                queue.push_back(p);
            }
        }
    };
    for o in 0..pre.len() {
        if pre.get(o).is_empty() {
            process(o, &mut label, &mut queue, &mut queued);
        }
    }
    for (f, &holds) in initial.iter().enumerate() {
        if holds && !queued[f] {
            queued[f] = true;
            queue.push_back(f as u32);
        }
    }
    while let Some(f) = queue.pop_front() {
        queued[f as usize] = false;
        for &o in consumers.get(f as usize) {
            process(o as usize, &mut label, &mut queue, &mut queued);
        }
    }
    label
}

impl LandmarkCount {
    /// The landmarks of `relaxed` from `initial`, the search's start.
    pub(crate) fn new(relaxed: &Relaxed, initial: &State) -> LandmarkCount {
        let facts = relaxed.facts();
        let mut holds = vec![false; facts];
        relaxed.state_facts(initial, |f| holds[f as usize] = true);
        let label = labels(relaxed, &holds);
        let mut fact: Vec<u32> = Vec::new();
        if relaxed.goal().iter().all(|&g| label[g as usize].is_some()) {
            for &g in relaxed.goal() {
                fact.extend(label[g as usize].iter().flatten());
            }
        }
        fact.sort_unstable();
        fact.dedup();
        let mut index = vec![NONE; facts];
        for (i, &f) in fact.iter().enumerate() {
            index[f as usize] = i as u32;
        }
        let mut goal = vec![false; fact.len()];
        for &g in relaxed.goal() {
            if index[g as usize] != NONE {
                goal[index[g as usize] as usize] = true;
            }
        }
        // Necessary orderings: a landmark false at the start needs every
        // precondition its reachable achievers share.
        let mut shared: Vec<Option<Vec<u32>>> = vec![None; fact.len()];
        let mut meet = Vec::new();
        for (pre, add, _) in relaxed.ops() {
            if pre.iter().any(|&q| label[q as usize].is_none()) {
                continue;
            }
            for &p in add {
                let l = index[p as usize];
                if l == NONE || holds[p as usize] {
                    continue;
                }
                let mut mine: Vec<u32> = pre
                    .iter()
                    .map(|&q| index[q as usize])
                    .filter(|&q| q != NONE)
                    .collect();
                mine.sort_unstable();
                match &mut shared[l as usize] {
                    slot @ None => *slot = Some(mine),
                    Some(old) => {
                        intersect(old, &mine, &mut meet);
                        std::mem::swap(old, &mut meet);
                    }
                }
            }
        }
        let mut needed_by = vec![Vec::new(); fact.len()];
        for (p, before) in shared.iter().enumerate() {
            for &q in before.iter().flatten() {
                if q as usize != p {
                    needed_by[q as usize].push(p as u32);
                }
            }
        }
        LandmarkCount {
            literal: fact.iter().map(|&f| relaxed.literal(f)).collect(),
            words: fact.len().div_ceil(64),
            goal,
            needed_by: Lists::from_lists(needed_by.iter().map(Vec::as_slice)),
            accepted: Vec::new(),
        }
    }

    /// Makes the next node, whose state is `state`, reached from node
    /// `parent` (`None`: the start), and returns its estimate.
    pub(crate) fn push(&mut self, parent: Option<u32>, state: &State) -> u64 {
        let start = self.accepted.len();
        match parent {
            Some(p) => {
                let from = p as usize * self.words;
                self.accepted.extend_from_within(from..from + self.words);
            }
            None => self.accepted.resize(start + self.words, 0),
        }
        let accepted = &mut self.accepted[start..];
        let true_now = |i: usize| {
            let (atom, positive) = self.literal[i];
            state.holds(atom) == positive
        };
        for i in 0..self.literal.len() {
            if true_now(i) {
                set_bit(accepted, i as u32);
            }
        }
        let mut h = 0;
        for i in 0..self.literal.len() {
            let needed = if !bit(accepted, i as u32) {
                true
            } else if true_now(i) {
                false
            } else {
                self.goal[i] || self.needed_by.get(i).iter().any(|&p| !bit(accepted, p))
            };
            h += u64::from(needed);
        }
        h
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problems::{self, Instance};
    use crate::{Options, Request, Verdict, ground, plan};
    use ecology_core::NoClock;

    fn count(instance: &Instance) -> (crate::Task, LandmarkCount) {
        let task = ground(&instance.domain, &instance.problem).expect("grounds");
        let count = LandmarkCount::new(&Relaxed::new(&task, &[]), task.initial());
        (task, count)
    }

    /// Follows a valid plan: every landmark must be true somewhere on it
    /// (so it is accepted by the end) and the count must be 0 at its goal.
    fn check_along_plan(instance: &Instance) -> usize {
        let (task, mut count) = count(instance);
        let outcome = plan(&Request::new(&task), &Options::default(), &NoClock);
        let Verdict::Found(found) = outcome.verdict else {
            return 0;
        };
        let mut states = vec![task.initial().clone()];
        let mut h = count.push(None, &states[0]);
        for (i, step) in found.steps.iter().enumerate() {
            let next = task.apply(&states[i], step.op);
            h = count.push(Some(i as u32), &next);
            states.push(next);
        }
        for &(atom, positive) in &count.literal {
            assert!(
                states.iter().any(|s| s.holds(atom) == positive),
                "{}: landmark {atom:?} (true: {positive}) never holds on a plan",
                instance.name
            );
        }
        assert_eq!(
            h, 0,
            "{}: a goal state still counts landmarks",
            instance.name
        );
        count.literal.len()
    }

    #[test]
    fn every_landmark_is_true_on_every_plan_found() {
        let mut found = 0;
        for seed in 0..150 {
            found += check_along_plan(&problems::random_small(seed).expect("generates"));
        }
        for instance in [
            problems::gripper(4).expect("generates"),
            problems::blocks(6, 3).expect("generates"),
            problems::logistics(2, 3, 5).expect("generates"),
        ] {
            found += check_along_plan(&instance);
        }
        assert!(found > 200, "only {found} landmarks in all");
    }

    #[test]
    fn gripper_counts_each_ball_delivered_and_the_room_reached() {
        let instance = problems::gripper(3).expect("generates");
        let (task, mut count) = count(&instance);
        // Each ball at room b is a goal; the robot in room b, and each ball
        // carried by some gripper, are not single facts: (at-robby rooma)
        // is true at the start. Goals and the robot's visit to room b are.
        let h = count.push(None, task.initial());
        assert_eq!(
            h, 4,
            "3 balls to deliver and room b to reach: {:?}",
            count.literal
        );
    }
}
