//! A brute-force oracle for tests and benchmarks: uniform-cost search over
//! worlds of named atoms, enumerating every typed argument tuple of every
//! schema in every world.
//!
//! It shares nothing with the planner's grounding, bitsets, heuristics or
//! search, only the validator's reading of the schemas, so that agreeing with
//! it means something. It is exponential; use it on small problems only.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashMap};

use ecology_domain::{Domain, Name, Problem};

use crate::validate::{Semantics, World};

/// What the oracle concluded.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Cheapest {
    /// The optimal cost, and one optimal plan as `(action args...)` lines.
    Cost(u64, Vec<String>),
    /// No plan exists.
    Unsolvable,
    /// More than the allowed number of worlds were reached.
    TooLarge,
}

/// The cheapest plan's cost for `problem`, never using the action instances
/// written in `excluded` (such as `(move astrid bedroom entrance)`), visiting
/// at most `max_worlds` worlds.
pub fn cheapest(
    domain: &Domain,
    problem: &Problem,
    excluded: &[String],
    max_worlds: usize,
) -> Cheapest {
    let semantics = Semantics::new(domain, problem);
    // Every typed argument tuple of every action, named.
    let mut instances: Vec<(usize, Vec<Name>, String)> = Vec::new();
    for (i, action) in domain.actions.iter().enumerate() {
        for args in semantics.arguments(action) {
            let text = format!("({} {})", action.name, args.join(" "));
            let text = text.replace(" )", ")");
            if !excluded.contains(&text) {
                instances.push((i, args, text));
            }
        }
    }
    let start = semantics.initial();
    let mut best: HashMap<World, (u64, Option<(World, usize)>)> = HashMap::new();
    best.insert(start.clone(), (0, None));
    let mut heap = BinaryHeap::new();
    heap.push(Reverse((0u64, start)));
    while let Some(Reverse((cost, world))) = heap.pop() {
        if best.get(&world).is_some_and(|(c, _)| *c < cost) {
            continue;
        }
        if semantics.unmet_goals(&world).is_empty() {
            let mut lines = Vec::new();
            let mut at = world;
            while let Some((_, Some((parent, instance)))) = best.get(&at) {
                lines.push(instances[*instance].2.clone());
                at = parent.clone();
            }
            lines.reverse();
            return Cheapest::Cost(cost, lines);
        }
        for (k, (action, args, _)) in instances.iter().enumerate() {
            let Ok((next, c)) = semantics.apply(&domain.actions[*action], args, &world) else {
                continue;
            };
            let total = cost.saturating_add(c);
            if best.get(&next).is_none_or(|(old, _)| total < *old) {
                if best.len() >= max_worlds {
                    return Cheapest::TooLarge;
                }
                best.insert(next.clone(), (total, Some((world.clone(), k))));
                heap.push(Reverse((total, next)));
            }
        }
    }
    Cheapest::Unsolvable
}
