//! Action-level recovery for the simulated PEIS-Home: when an action fails,
//! the task is planned again from the world as the `world` PEIS shows it,
//! without the action instances that failed.
//!
//! The world's tuples become the planning domain's facts by the PEIS-Home's
//! conventions: `robots.R.pose` in a room of the `map` is `(at R ROOM)`,
//! `things.T.holder` naming robot R is `(holding R T)` (and the thing is no
//! longer `thing-at` anywhere), and `residents.H.state` is `(awake H)` or
//! `(asleep H)`. Every other fact is the problem's `:init`, as written.
//!
//! When the problem is uncertain, the task is planned again conditionally
//! from a belief: the problem's possible initial worlds that agree with what
//! the task's sensing actions observed (their probabilities scaled to sum
//! to 1), each with what the world's tuples show in place. The replanner
//! reads only what robots could know: where robots are, what they hold,
//! who is awake; never where a thing lies (that is what looking is for).

use std::collections::BTreeMap;

use ecology_actions::{AtomId, ConditionalRequest, State, Task};
use ecology_domain::{Domain, Problem, Term, parse_goal};
use ecology_exec::{Observation, Plan, Replan};

use crate::planning::{run_action_planner, run_conditional_planner};
use ecology_tuples::world::{AWAKE, Map, Pose, WorldKey, world_pattern};
use ecology_tuples::{Tuple, TuplePattern};

/// Plans a problem again from the observed world (see the module documentation).
#[derive(Debug, Clone)]
pub struct WorldReplanner {
    domain: Domain,
    problem: Problem,
}

/// What the world's tuples say.
#[derive(Debug, Default)]
struct Observed {
    rooms: BTreeMap<String, String>,
    holders: BTreeMap<String, Option<String>>,
    awake: BTreeMap<String, bool>,
}

fn observe(world: &[Tuple]) -> Observed {
    let text = |t: &Tuple| t.text().unwrap_or("").trim().to_string();
    let map = world
        .iter()
        .find(|t| WorldKey::parse(t.key.as_str()) == Some(WorldKey::Map))
        .and_then(|t| Map::parse(&text(t)).ok());
    let mut observed = Observed::default();
    for t in world {
        match WorldKey::parse(t.key.as_str()) {
            Some(WorldKey::RobotPose(robot)) => {
                if let (Some(map), Ok(pose)) = (&map, Pose::parse(&text(t)))
                    && let Some(room) = map.room_at(pose.x, pose.y)
                {
                    observed.rooms.insert(robot.to_string(), room.name.clone());
                }
            }
            Some(WorldKey::ThingHolder(thing)) => {
                let holder = text(t);
                observed
                    .holders
                    .insert(thing.to_string(), (!holder.is_empty()).then_some(holder));
            }
            Some(WorldKey::ResidentState(person)) => {
                observed.awake.insert(person.to_string(), text(t) == AWAKE);
            }
            _ => {}
        }
    }
    observed
}

impl WorldReplanner {
    /// A replanner for `problem` in `domain`.
    pub fn new(domain: Domain, problem: Problem) -> WorldReplanner {
        WorldReplanner { domain, problem }
    }

    /// The problem's certain `:init` facts, as (predicate, arguments).
    fn init(&self) -> Vec<(String, Vec<String>)> {
        self.problem
            .init
            .iter()
            .map(|atom| {
                let args = names(&atom.args);
                (atom.predicate.to_string(), args)
            })
            .collect()
    }

    /// The facts that hold: `base` (the problem's `:init`, or one of its
    /// possible initial worlds) with what `observed` shows in place.
    fn facts(base: &[(String, Vec<String>)], observed: &Observed) -> Vec<(String, Vec<String>)> {
        let mut facts = Vec::new();
        for (predicate, args) in base {
            let first = args.first().map(String::as_str).unwrap_or("");
            let second = args.get(1).map(String::as_str).unwrap_or("");
            let replaced = match predicate.as_str() {
                "at" => observed.rooms.contains_key(first),
                "holding" => observed.holders.contains_key(second),
                "thing-at" => observed.holders.get(first).is_some_and(Option::is_some),
                "awake" | "asleep" => observed.awake.contains_key(first),
                _ => false,
            };
            if !replaced {
                facts.push((predicate.clone(), args.clone()));
            }
        }
        for (robot, room) in &observed.rooms {
            facts.push(("at".to_string(), vec![robot.clone(), room.clone()]));
        }
        for (thing, holder) in &observed.holders {
            if let Some(robot) = holder {
                facts.push(("holding".to_string(), vec![robot.clone(), thing.clone()]));
            }
        }
        for (person, awake) in &observed.awake {
            let predicate = if *awake { "awake" } else { "asleep" };
            facts.push((predicate.to_string(), vec![person.clone()]));
        }
        facts
    }

    /// The possible worlds now: the problem's initial worlds that agree with
    /// every observation, each with what the world's tuples show in place,
    /// their probabilities scaled to sum to 1.
    fn belief(
        &self,
        task: &Task,
        observed: &[Observation],
        seen: &Observed,
    ) -> Result<Vec<(f64, State)>, String> {
        let init = self.init();
        let uncertain = uncertain_atoms(task);
        let evidence: Vec<(AtomId, bool)> = observed
            .iter()
            .filter_map(|o| Some((atom_id(task, &o.atom)?, o.holds)))
            .collect();
        let mut belief = Vec::new();
        for (p, world) in task.initial_belief() {
            if evidence.iter().any(|&(a, holds)| world.holds(a) != holds) {
                continue;
            }
            let mut base = init.clone();
            for &a in &uncertain {
                if world.holds(a)
                    && let Some(fact) = fact_of(&task.atom_name(a))
                {
                    base.push(fact);
                }
            }
            belief.push((*p, state_of(task, &Self::facts(&base, seen))?));
        }
        let total: f64 = belief.iter().map(|(p, _)| p).sum();
        if total <= 0.0 {
            return Err(format!(
                "what the task observed ({}) rules out every initial world the problem allows",
                ecology_exec::observations_text(observed)
            ));
        }
        for (p, _) in &mut belief {
            *p /= total;
        }
        Ok(belief)
    }
}

impl Replan for WorldReplanner {
    fn observe(&self) -> TuplePattern {
        world_pattern()
    }

    fn replan(
        &mut self,
        failed: &[String],
        observed: &[Observation],
        world: &[Tuple],
    ) -> Result<Plan, String> {
        let task =
            ecology_actions::ground(&self.domain, &self.problem).map_err(|e| e.to_string())?;
        let mut excluded = Vec::new();
        for action in failed {
            let call = parse_goal(action).map_err(|_| format!("`{action}` is not an action"))?;
            excluded.extend(task.find_operators(&call).map_err(|e| e.to_string())?);
        }
        let seen = observe(world);
        if task.is_uncertain() {
            let belief = self.belief(&task, observed, &seen)?;
            return run_conditional_planner(&ConditionalRequest {
                task: &task,
                belief,
                excluded,
            });
        }
        let state = state_of(&task, &Self::facts(&self.init(), &seen))?;
        run_action_planner(&ecology_actions::Request::replan(&task, state, excluded))
            .map(Plan::from)
    }
}

/// The atoms whose value differs between the task's possible initial worlds.
fn uncertain_atoms(task: &Task) -> Vec<AtomId> {
    let worlds = task.initial_belief();
    let Some((_, first)) = worlds.first() else {
        return Vec::new();
    };
    let mut atoms: Vec<_> = worlds
        .iter()
        .flat_map(|(_, w)| w.atoms())
        .filter(|&a| worlds.iter().any(|(_, w)| w.holds(a) != first.holds(a)))
        .collect();
    atoms.sort_unstable();
    atoms.dedup();
    atoms
}

/// `(predicate arg …)` as (predicate, arguments).
fn fact_of(atom: &str) -> Option<(String, Vec<String>)> {
    let call = parse_goal(atom).ok()?;
    Some((call.name.to_string(), names(&call.args)))
}

/// Ground arguments as names.
fn names(args: &[Term]) -> Vec<String> {
    args.iter()
        .map(|t| match t {
            Term::Const(c) | Term::Var(c) => c.to_string(),
        })
        .collect()
}

/// The task's atom written `atom`, if it is one.
fn atom_id(task: &Task, atom: &str) -> Option<AtomId> {
    let (predicate, args) = fact_of(atom)?;
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    task.atom(&predicate, &args)
}

/// The task's state where exactly `facts` hold.
fn state_of(task: &Task, facts: &[(String, Vec<String>)]) -> Result<State, String> {
    task.state_from(
        facts
            .iter()
            .map(|(p, args)| (p.as_str(), args.iter().map(String::as_str).collect())),
    )
    .map_err(|e| e.to_string())
}
