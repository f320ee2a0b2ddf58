//! The landmark-count heuristic, LAMA's second heuristic (Richter and
//! Westphal 2010), over landmarks found by label propagation in the delete
//! relaxation (Zhu and Givan 2003) and then by backchaining from each
//! landmark (Richter, Helmert and Westphal 2008; see [`backchain`]).
//!
//! A *landmark* is a fact that every plan from the start makes true at
//! some point, or a set of facts one of which it makes true. Each fact of
//! the relaxation gets a label: the facts that every relaxed way of
//! reaching it passes through. A fact true at the start is its own label;
//! an operator's label is the union of its preconditions' labels; a fact's
//! label is itself plus the intersection of its achievers' labels. Labels
//! start at "every fact" and only shrink, so the propagation reaches the
//! same fixpoint in any order. The goal facts' labels together are the
//! first landmarks: a plan reaches the goal only through each of them, and
//! every relaxed plan is a plan of the relaxation.
//!
//! The count is path dependent: a landmark is *accepted* once some state
//! on the path to the current one made it true, and each state keeps the
//! set accepted on the path by which the search first reached it (Fast
//! Downward's eager search also intersects the sets of later paths; ours
//! keeps the first path's: tried on twelve IPC problems, intersecting
//! changed one plan, termes-opt18 p05's, from cost 420 to 422). The estimate is the number of landmarks not yet
//! accepted, plus the accepted ones that are needed again: a goal that is
//! false now, or a landmark false now that every (first) achiever of a
//! landmark not yet accepted needs. Like LAMA's, it counts one per landmark
//! whatever the actions cost, offers no preferred operators, and is not
//! admissible: it guides greedy search alongside FF, not A*.

use std::collections::HashMap;

use crate::heuristic::{Lists, Relaxed};
use crate::task::{AtomId, State};

const NONE: u32 = u32::MAX;

/// The landmark-count heuristic, with the accepted landmarks of every
/// state the search has made a node: node `i`'s are `accepted[i]`.
#[derive(Debug, Clone)]
pub(crate) struct LandmarkCount {
    /// Each landmark's literals: an atom that must hold (`true`) or not.
    /// A landmark of several holds when one of them does.
    literals: Lists<(AtomId, bool)>,
    /// Whether each landmark is a goal fact.
    goal: Vec<bool>,
    /// For each landmark, the landmarks it is a precondition of every
    /// (first) achiever of.
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

/// How much work (operators and preconditions visited) the search for
/// landmarks before landmarks may do in all: one restricted exploration per
/// landmark, which on large tasks would take longer than the search.
const BACKCHAIN_WORK: u64 = 30_000_000;

/// The largest disjunctive landmark kept (Fast Downward's limit too).
const MAX_DISJUNCTION: usize = 4;

/// The landmarks being found: each a sorted set of facts, one of which
/// every plan makes true; with the landmarks ordered before each.
struct Found {
    facts: Vec<Vec<u32>>,
    before: Vec<Vec<u32>>,
    /// The landmark that is the single fact `f`, or `NONE`.
    simple: Vec<u32>,
    /// The disjunctive landmark fact `f` is in, or `NONE`.
    within: Vec<u32>,
    disjunctive: HashMap<Vec<u32>, u32>,
}

impl Found {
    /// The landmark of `facts`, added if new; `None` for a disjunction
    /// overlapping another one (as Fast Downward, which keeps the first).
    fn add(&mut self, facts: Vec<u32>) -> Option<u32> {
        let existing = match facts[..] {
            [f] => Some(self.simple[f as usize]).filter(|&l| l != NONE),
            _ => self.disjunctive.get(&facts).copied(),
        };
        if existing.is_some() {
            return existing;
        }
        let l = self.facts.len() as u32;
        match facts[..] {
            [f] => self.simple[f as usize] = l,
            _ => {
                if facts.iter().any(|&f| self.within[f as usize] != NONE) {
                    return None;
                }
                for &f in &facts {
                    self.within[f as usize] = l;
                }
                self.disjunctive.insert(facts.clone(), l);
            }
        }
        self.facts.push(facts);
        self.before.push(Vec::new());
        Some(l)
    }

    fn order(&mut self, first: u32, then: u32) {
        if first != then && !self.before[then as usize].contains(&first) {
            self.before[then as usize].push(first);
        }
    }
}

impl LandmarkCount {
    /// The landmarks of `relaxed` from `initial`, the search's start;
    /// `predicate` names each atom's predicate (disjunctive landmarks are
    /// sets of facts of one predicate, all true or all false).
    pub(crate) fn new(
        relaxed: &Relaxed,
        initial: &State,
        predicate: &dyn Fn(AtomId) -> u32,
    ) -> LandmarkCount {
        let facts = relaxed.facts();
        let literal = relaxed.literals();
        let class: Vec<u32> = literal
            .iter()
            .map(|&(atom, positive)| predicate(atom) * 2 + u32::from(!positive))
            .collect();
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
        let mut found = Found {
            facts: Vec::new(),
            before: Vec::new(),
            simple: vec![NONE; facts],
            within: vec![NONE; facts],
            disjunctive: Default::default(),
        };
        for &f in &fact {
            found.add(vec![f]);
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
                let l = found.simple[p as usize];
                if l == NONE || holds[p as usize] {
                    continue;
                }
                let mut mine: Vec<u32> = pre
                    .iter()
                    .map(|&q| found.simple[q as usize])
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
        for (p, before) in shared.iter().enumerate() {
            for &q in before.iter().flatten() {
                found.order(q, p as u32);
            }
        }
        backchain(relaxed, &holds, &class, &mut found);
        let mut needed_by = vec![Vec::new(); found.facts.len()];
        for (p, before) in found.before.iter().enumerate() {
            for &q in before {
                needed_by[q as usize].push(p as u32);
            }
        }
        let literals: Vec<Vec<(AtomId, bool)>> = found
            .facts
            .iter()
            .map(|set| set.iter().map(|&f| literal[f as usize]).collect())
            .collect();
        LandmarkCount {
            words: found.facts.len().div_ceil(64),
            goal: found
                .facts
                .iter()
                .map(|set| matches!(set[..], [f] if relaxed.is_goal(f)))
                .collect(),
            literals: Lists::from_lists(literals.iter().map(Vec::as_slice)),
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
        let literals = &self.literals;
        let true_now = |i: usize| {
            literals
                .get(i)
                .iter()
                .any(|&(atom, positive)| state.holds(atom) == positive)
        };
        for i in 0..literals.len() {
            if true_now(i) {
                set_bit(accepted, i as u32);
            }
        }
        let mut h = 0;
        for i in 0..literals.len() {
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

/// Richter, Helmert and Westphal's search for landmarks before landmarks
/// (2008), from the landmarks found so far. A plan first makes a landmark
/// true by an operator whose preconditions could all be reached without
/// it: a *first achiever*. Which operators can be is found by exploring the
/// relaxation without the landmark's achievers. A fact every first achiever
/// needs is a landmark before it (even one true at the start: once false
/// again, it is needed again while the later landmark is not reached); and
/// so is a set of facts of one predicate when every first achiever needs
/// one of them (at most [`MAX_DISJUNCTION`], none true at the start or
/// already a landmark alone, none in another such set): in gripper, each
/// ball carried by one gripper or the other.
fn backchain(relaxed: &Relaxed, holds: &[bool], class: &[u32], found: &mut Found) {
    let facts = relaxed.facts();
    let pre = Lists::from_lists(relaxed.ops().map(|(pre, _, _)| pre));
    let add = Lists::from_lists(relaxed.ops().map(|(_, add, _)| add));
    let consumers = pre.inverse(facts);
    let achievers = add.inverse(facts);
    let mut work: u64 = 0;
    let mut reached = vec![false; facts];
    let mut missing = vec![0u32; pre.len()];
    let mut excluded = vec![false; pre.len()];
    let mut queue = Vec::new();
    let mut next = 0;
    while next < found.facts.len() && work < BACKCHAIN_WORK {
        let l = next as u32;
        next += 1;
        let lm = found.facts[l as usize].clone();
        if lm.iter().any(|&f| holds[f as usize]) {
            continue;
        }
        // What the relaxation reaches without achieving the landmark.
        for &f in &lm {
            for &o in achievers.get(f as usize) {
                excluded[o as usize] = true;
            }
        }
        reached.copy_from_slice(holds);
        queue.clear();
        queue.extend((0..facts as u32).filter(|&f| holds[f as usize]));
        for o in 0..pre.len() {
            missing[o] = pre.get(o).len() as u32;
            if missing[o] == 0 && !excluded[o] {
                for &p in add.get(o) {
                    if !reached[p as usize] {
                        reached[p as usize] = true;
                        queue.push(p);
                    }
                }
            }
        }
        work += pre.len() as u64;
        while let Some(f) = queue.pop() {
            for &o in consumers.get(f as usize) {
                work += 1;
                let o = o as usize;
                missing[o] -= 1;
                if missing[o] == 0 && !excluded[o] {
                    for &p in add.get(o) {
                        if !reached[p as usize] {
                            reached[p as usize] = true;
                            queue.push(p);
                        }
                    }
                }
            }
        }
        // Its first achievers, the preconditions they share, and their
        // preconditions false at the start by predicate.
        let mut first: Vec<u32> = lm
            .iter()
            .flat_map(|&f| achievers.get(f as usize).iter().copied())
            .filter(|&o| pre.get(o as usize).iter().all(|&q| reached[q as usize]))
            .collect();
        first.sort_unstable();
        first.dedup();
        for &f in &lm {
            for &o in achievers.get(f as usize) {
                excluded[o as usize] = false;
            }
        }
        if first.is_empty() {
            continue;
        }
        let mut by_class: HashMap<u32, (Vec<u32>, usize)> = Default::default();
        let mut common: Option<Vec<u32>> = None;
        let mut meet = Vec::new();
        for (k, &o) in first.iter().enumerate() {
            let mut needs: Vec<u32> = pre.get(o as usize).to_vec();
            needs.sort_unstable();
            common = Some(match common {
                None => needs.clone(),
                Some(c) => {
                    intersect(&c, &needs, &mut meet);
                    std::mem::take(&mut meet)
                }
            });
            for &q in needs.iter().filter(|&&q| !holds[q as usize]) {
                let (set, users) = by_class.entry(class[q as usize]).or_default();
                set.push(q);
                // How many achievers from the first on need one of the
                // class: all of them, if it reaches their number.
                if *users == k {
                    *users = k + 1;
                }
            }
        }
        let mut new = Vec::new();
        for q in common.unwrap_or_default() {
            new.push(vec![q]);
        }
        let mut classes: Vec<(u32, (Vec<u32>, usize))> = by_class.into_iter().collect();
        classes.sort_unstable_by_key(|c| c.0);
        for (_, (mut set, users)) in classes {
            set.sort_unstable();
            set.dedup();
            if users == first.len()
                && (2..=MAX_DISJUNCTION).contains(&set.len())
                && set.iter().all(|&q| found.simple[q as usize] == NONE)
            {
                new.push(set);
            }
        }
        for set in new {
            // A guard on memory: far more landmarks than facts would be
            // mostly disjunctions, and each costs every search node a bit.
            if found.facts.len() >= 4 * facts + 64 {
                return;
            }
            if let Some(before) = found.add(set) {
                found.order(before, l);
            }
        }
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
        let count = LandmarkCount::new(&Relaxed::new(&task, &[]), task.initial(), &|atom| {
            task.predicate_of(atom)
        });
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
        for i in 0..count.literals.len() {
            let literals = count.literals.get(i);
            assert!(
                states.iter().any(|s| literals
                    .iter()
                    .any(|&(atom, positive)| s.holds(atom) == positive)),
                "{}: landmark {literals:?} (one true) never holds on a plan",
                instance.name
            );
        }
        assert_eq!(
            h, 0,
            "{}: a goal state still counts landmarks",
            instance.name
        );
        count.literals.len()
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
    fn gripper_counts_each_ball_carried_and_delivered_and_the_room_reached() {
        let instance = problems::gripper(3).expect("generates");
        let (task, mut count) = count(&instance);
        // Each ball at room b is a goal, and before it the ball carried by
        // one gripper or the other: a disjunctive landmark, since no single
        // fact is (label propagation alone finds only the goals and the
        // robot's visit to room b, h = 4).
        let h = count.push(None, task.initial());
        assert_eq!(h, 7, "3 balls to carry and deliver, room b to reach");
        let carried = (0..count.literals.len())
            .filter(|&i| count.literals.get(i).len() == 2)
            .map(|i| {
                let names: Vec<String> = count
                    .literals
                    .get(i)
                    .iter()
                    .map(|&(a, _)| task.atom_name(a))
                    .collect();
                names.join(" or ")
            })
            .collect::<Vec<_>>();
        assert_eq!(carried.len(), 3, "{carried:?}");
        assert!(
            carried.iter().all(|d| d.matches("(carry ").count() == 2),
            "{carried:?}"
        );
        // Picking up a second ball while holding the first is progress.
        let pick = |state: &State, call: &str| {
            let call = ecology_domain::parse_goal(call).expect("parses");
            let op = task
                .find_operator(&call)
                .expect("grounds")
                .expect("an operator");
            task.apply(state, op)
        };
        let one = pick(task.initial(), "(pick ball1 rooma left)");
        let two = pick(&one, "(pick ball2 rooma right)");
        assert_eq!(count.push(Some(0), &one), 6);
        assert_eq!(count.push(Some(1), &two), 5);
    }
}
