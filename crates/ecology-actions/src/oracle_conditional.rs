//! A brute-force oracle for conditional plans, for tests and benchmarks: the
//! success probability and expected cost of a given plan by enumerating every
//! initial world and every outcome, and the best plan of a bounded depth by
//! enumerating every action of every node.
//!
//! It reads the schemas through the validator's named worlds (sets of
//! `(predicate, args)`), and shares nothing with the planner's grounding,
//! bitset states, beliefs or search; it follows each world through the plan
//! alone, where the planner follows beliefs. It is exponential: small
//! problems only.

use std::collections::HashMap;

use ecology_domain::{
    Action, Domain, Effect, Name, PROBABILITY_EPSILON, Probabilistic, Problem, Term,
};

use crate::conditional::EPSILON;
use crate::plan_graph::{PlanGraph, PlanNode};
use crate::task::Task;
use crate::validate::{Semantics, World, binding};

/// A conditional plan written with names, as the oracle reads it: nodes,
/// the first where it starts, each branch naming the node it leads to.
#[derive(Debug, Clone, PartialEq)]
pub struct NamedPlan {
    /// The nodes.
    pub nodes: Vec<NamedNode>,
}

/// A node of a [`NamedPlan`].
#[derive(Debug, Clone, PartialEq)]
pub enum NamedNode {
    /// The plan ends.
    Stop,
    /// Run `(action args...)`, then the branch whose observation matches.
    Act {
        /// The action schema.
        action: Name,
        /// Its arguments.
        args: Vec<Name>,
        /// Each branch: the observed atoms as text with their truth, and
        /// the node it leads to.
        branches: Vec<(Vec<(String, bool)>, usize)>,
    },
}

/// `graph` with names instead of ids.
pub fn named(task: &Task, graph: &PlanGraph) -> NamedPlan {
    let nodes = graph
        .nodes
        .iter()
        .map(|node| match node {
            PlanNode::Stop { .. } => NamedNode::Stop,
            PlanNode::Act { step, branches } => NamedNode::Act {
                action: step.action.clone(),
                args: step.args.clone(),
                branches: branches
                    .iter()
                    .map(|b| {
                        let observation = b
                            .observation
                            .iter()
                            .map(|&(a, v)| (task.atom_name(a), v))
                            .collect();
                        (observation, b.next)
                    })
                    .collect(),
            },
        })
        .collect();
    NamedPlan { nodes }
}

type Fact = (Name, Vec<Name>);

fn text(fact: &Fact) -> String {
    let mut out = format!("({}", fact.0);
    for a in &fact.1 {
        out.push(' ');
        out.push_str(a);
    }
    out.push(')');
    out
}

fn ground(args: &[Term], bind: &HashMap<&str, &Name>) -> Vec<Name> {
    args.iter()
        .map(|t| match t {
            Term::Const(c) => c.clone(),
            Term::Var(v) => bind.get(&**v).map_or_else(|| v.clone(), |n| (*n).clone()),
        })
        .collect()
}

struct Oracle<'a> {
    semantics: Semantics<'a>,
    domain: &'a Domain,
}

impl Oracle<'_> {
    /// The initial worlds and their probabilities.
    fn initial(&self, problem: &Problem) -> Vec<(World, f64)> {
        let mut worlds = vec![(self.semantics.initial(), 1.0)];
        for form in &problem.uncertain {
            let mut next = Vec::new();
            for (world, p) in &worlds {
                for o in &form.outcomes {
                    let mut w = world.clone();
                    for atom in &o.items {
                        w.insert((atom.predicate.clone(), ground(&atom.args, &HashMap::new())));
                    }
                    next.push((w, p * o.probability));
                }
                if let Some(rest) = rest(form) {
                    next.push((world.clone(), p * rest));
                }
            }
            worlds = next;
        }
        merge(worlds)
    }

    /// `action(args)` in `world`: `None` if it does not apply, else its cost
    /// and each outcome's world, probability and observation.
    #[allow(clippy::type_complexity)]
    fn step(
        &self,
        action: &Action,
        args: &[Name],
        world: &World,
    ) -> Option<(u64, Vec<(World, f64, Vec<(String, bool)>)>)> {
        let (_, cost) = self.semantics.apply(action, args, world).ok()?;
        let bind = binding(action, args);
        // Every combination of the `probabilistic` forms' outcomes.
        let effects = Semantics::effects_in(action, &bind, world);
        let mut combos: Vec<(f64, Vec<&Effect>)> = vec![(1.0, effects)];
        for form in &action.chances {
            let mut next = Vec::new();
            for (p, effects) in &combos {
                for o in &form.outcomes {
                    let mut e = effects.clone();
                    e.extend(&o.items);
                    next.push((p * o.probability, e));
                }
                if let Some(rest) = rest(form) {
                    next.push((p * rest, effects.clone()));
                }
            }
            combos = next;
        }
        let mut out = Vec::new();
        for (p, effects) in combos {
            if p <= 0.0 {
                continue;
            }
            let mut next = world.clone();
            let mut adds = Vec::new();
            for effect in effects {
                match effect {
                    Effect::Del(atom) => {
                        next.remove(&(atom.predicate.clone(), ground(&atom.args, &bind)));
                    }
                    Effect::Add(atom) => {
                        adds.push((atom.predicate.clone(), ground(&atom.args, &bind)))
                    }
                    Effect::IncreaseCost(..) => {}
                }
            }
            // Adding wins over deleting.
            next.extend(adds);
            let observation = action
                .observe
                .iter()
                .map(|atom| {
                    let fact = (atom.predicate.clone(), ground(&atom.args, &bind));
                    (text(&fact), next.contains(&fact))
                })
                .collect();
            out.push((next, p, observation));
        }
        Some((cost, out))
    }

    fn success(&self, belief: &[(World, f64)]) -> f64 {
        belief
            .iter()
            .filter(|(w, _)| self.semantics.unmet_goals(w).is_empty())
            .map(|(_, p)| p)
            .sum()
    }

    /// The probability that `plan` from node `id` ends in a goal world and
    /// its expected cost, run from `world`; each (node, world) is followed
    /// once, so a plan whose branches join is not followed once per path.
    fn run(
        &self,
        world: &World,
        plan: &NamedPlan,
        id: usize,
        memo: &mut HashMap<(usize, World), (f64, f64)>,
    ) -> Result<(f64, f64), String> {
        if let Some(&value) = memo.get(&(id, world.clone())) {
            return Ok(value);
        }
        let node = plan
            .nodes
            .get(id)
            .ok_or_else(|| format!("a branch leads to node {id}, which the plan does not have"))?;
        let value = match node {
            NamedNode::Stop => (
                if self.semantics.unmet_goals(world).is_empty() {
                    1.0
                } else {
                    0.0
                },
                0.0,
            ),
            NamedNode::Act {
                action,
                args,
                branches,
            } => {
                let schema = self
                    .domain
                    .action(action)
                    .ok_or_else(|| format!("unknown action `{action}`"))?;
                let call = format!("({action} {})", args.join(" "));
                let (cost, outcomes) = self
                    .step(schema, args, world)
                    .ok_or_else(|| format!("{call} does not apply in a world the plan reaches"))?;
                let mut total = (0.0, cost as f64);
                for (next, q, observation) in outcomes {
                    let mut seen = observation.clone();
                    seen.sort();
                    let branch = branches.iter().find(|(obs, _)| {
                        let mut obs = obs.clone();
                        obs.sort();
                        obs == seen
                    });
                    let Some(&(_, rest)) = branch else {
                        return Err(format!(
                            "{call} can observe {observation:?}, which has no branch"
                        ));
                    };
                    if rest <= id {
                        return Err(format!("a branch of {call} leads back to an earlier node"));
                    }
                    let (p, c) = self.run(&next, plan, rest, memo)?;
                    total.0 += q * p;
                    total.1 += q * c;
                }
                total
            }
        };
        memo.insert((id, world.clone()), value);
        Ok(value)
    }
}

/// The probability that none of `form`'s outcomes happens, if it is more
/// than rounding: read here from the outcomes as written rather than by
/// [`Probabilistic::rest`], which grounding uses, so that the oracle judges
/// that reading too.
fn rest<T>(form: &Probabilistic<T>) -> Option<f64> {
    let rest = 1.0 - form.outcomes.iter().map(|o| o.probability).sum::<f64>();
    (rest > PROBABILITY_EPSILON).then_some(rest)
}

/// Merges equal worlds, adding their probabilities.
fn merge(worlds: Vec<(World, f64)>) -> Vec<(World, f64)> {
    let mut out: Vec<(World, f64)> = Vec::new();
    for (w, p) in worlds {
        match out.iter_mut().find(|(v, _)| *v == w) {
            Some((_, q)) => *q += p,
            None => out.push((w, p)),
        }
    }
    out
}

/// The success probability and expected cost of `plan` for `problem`, by
/// following every initial world through every outcome; `Err` says why the
/// plan cannot run (an action that does not apply, an observation without
/// a branch).
pub fn evaluate(
    domain: &Domain,
    problem: &Problem,
    plan: &NamedPlan,
) -> Result<(f64, f64), String> {
    let oracle = Oracle {
        semantics: Semantics::new(domain, problem),
        domain,
    };
    let mut total = (0.0, 0.0);
    let mut memo = HashMap::new();
    for (world, p) in oracle.initial(problem) {
        let (q, c) = oracle.run(&world, plan, 0, &mut memo)?;
        total.0 += p * q;
        total.1 += p * c;
    }
    Ok(total)
}

/// What the exhaustive search found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Exhaustive {
    /// The highest success probability of any plan of at most `horizon`
    /// actions per branch, and the least expected cost among those plans.
    Best {
        /// Success probability.
        success: f64,
        /// Expected cost.
        cost: f64,
    },
    /// More than the allowed number of nodes.
    TooLarge,
}

/// The best plan of at most `horizon` actions per branch (most probable,
/// then cheapest), by trying every action instance applicable in every world
/// of every node; at most `max_nodes` nodes.
pub fn most_probable(
    domain: &Domain,
    problem: &Problem,
    horizon: u32,
    max_nodes: usize,
) -> Exhaustive {
    exhaustive(domain, problem, horizon, max_nodes, &better)
}

/// The plan of at most `horizon` actions per branch with the highest
/// `lambda * success - cost` (the more probable of equal ones), and its
/// success probability and expected cost, as [`most_probable`] finds it.
pub fn best_for_lambda(
    domain: &Domain,
    problem: &Problem,
    horizon: u32,
    lambda: f64,
    max_nodes: usize,
) -> Exhaustive {
    let scored = move |(p, c): (f64, f64), (q, d): (f64, f64)| {
        let (a, b) = (lambda * p - c, lambda * q - d);
        a > b + EPSILON || (a > b - EPSILON && p > q + EPSILON)
    };
    exhaustive(domain, problem, horizon, max_nodes, &scored)
}

type Better<'a> = &'a dyn Fn((f64, f64), (f64, f64)) -> bool;

fn exhaustive(
    domain: &Domain,
    problem: &Problem,
    horizon: u32,
    max_nodes: usize,
    better: Better<'_>,
) -> Exhaustive {
    let oracle = Oracle {
        semantics: Semantics::new(domain, problem),
        domain,
    };
    let mut instances: Vec<(&Action, Vec<Name>)> = Vec::new();
    for action in &domain.actions {
        let arguments = oracle.semantics.arguments(action);
        instances.extend(arguments.into_iter().map(|args| (action, args)));
    }
    let mut nodes = 0usize;
    let start = oracle.initial(problem);
    match best(
        &oracle, &instances, &start, horizon, &mut nodes, max_nodes, better,
    ) {
        Some((success, cost)) => Exhaustive::Best { success, cost },
        None => Exhaustive::TooLarge,
    }
}

fn better((p, c): (f64, f64), (q, d): (f64, f64)) -> bool {
    p > q + EPSILON || (p > q - EPSILON && c < d - EPSILON)
}

#[allow(clippy::type_complexity)]
fn best(
    oracle: &Oracle<'_>,
    instances: &[(&Action, Vec<Name>)],
    belief: &[(World, f64)],
    depth: u32,
    nodes: &mut usize,
    max_nodes: usize,
    better: Better<'_>,
) -> Option<(f64, f64)> {
    *nodes += 1;
    if *nodes > max_nodes {
        return None;
    }
    let mut value = (oracle.success(belief), 0.0);
    if depth == 0 {
        return Some(value);
    }
    'instances: for (action, args) in instances {
        // Each world pays what the action costs there (a `when` may add to it).
        let mut cost = 0.0;
        let mut groups: Vec<(Vec<(String, bool)>, Vec<(World, f64)>)> = Vec::new();
        for (world, p) in belief {
            let Some((c, outcomes)) = oracle.step(action, args, world) else {
                continue 'instances;
            };
            cost += p * c as f64;
            for (next, q, observation) in outcomes {
                match groups.iter_mut().find(|(o, _)| *o == observation) {
                    Some((_, worlds)) => worlds.push((next, p * q)),
                    None => groups.push((observation, vec![(next, p * q)])),
                }
            }
        }
        let mut p = 0.0;
        let mut c = cost;
        for (_, worlds) in groups {
            let w: f64 = worlds.iter().map(|(_, p)| p).sum();
            if w <= 0.0 {
                continue;
            }
            let normal = merge(worlds.into_iter().map(|(x, p)| (x, p / w)).collect());
            let (bp, bc) = best(
                oracle,
                instances,
                &normal,
                depth - 1,
                nodes,
                max_nodes,
                better,
            )?;
            p += w * bp;
            c += w * bc;
        }
        if better((p, c), value) {
            value = (p, c);
        }
    }
    Some(value)
}
