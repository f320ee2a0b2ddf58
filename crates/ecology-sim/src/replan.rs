//! Action-level recovery for the simulated PEIS-Home: when an action fails,
//! the task is planned again from the world as the `world` PEIS shows it,
//! without the action instances that failed.
//!
//! The world's tuples become the planning domain's facts by the PEIS-Home's
//! conventions: `robots.R.pose` in a room of the `map` is `(at R ROOM)`,
//! `things.T.holder` naming robot R is `(holding R T)` (and the thing is no
//! longer `thing-at` anywhere), and `residents.H.state` is `(awake H)` or
//! `(asleep H)`. Every other fact is the problem's `:init`, as written.

use std::collections::BTreeMap;

use ecology_domain::{Domain, Problem, Term, parse_goal};
use ecology_exec::{PlannedAction, Replan};

use crate::scenario::run_action_planner;
use ecology_tuples::{Tuple, TuplePattern};

use crate::components::WORLD;
use crate::world::{Map, Pose};

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
        .find(|t| t.key.as_str() == "map")
        .and_then(|t| Map::parse(&text(t)));
    let mut observed = Observed::default();
    for t in world {
        let key = t.key.as_str();
        if let Some(robot) = key
            .strip_prefix("robots.")
            .and_then(|k| k.strip_suffix(".pose"))
            && let (Some(map), Some(pose)) = (&map, Pose::parse(&text(t)))
            && let Some(room) = map.room_at(pose.x, pose.y)
        {
            observed.rooms.insert(robot.to_string(), room.name.clone());
        } else if let Some(thing) = key
            .strip_prefix("things.")
            .and_then(|k| k.strip_suffix(".holder"))
        {
            let holder = text(t);
            observed
                .holders
                .insert(thing.to_string(), (!holder.is_empty()).then_some(holder));
        } else if let Some(person) = key
            .strip_prefix("residents.")
            .and_then(|k| k.strip_suffix(".state"))
        {
            observed
                .awake
                .insert(person.to_string(), text(t) == "awake");
        }
    }
    observed
}

impl WorldReplanner {
    /// A replanner for `problem` in `domain`.
    pub fn new(domain: Domain, problem: Problem) -> WorldReplanner {
        WorldReplanner { domain, problem }
    }

    /// The facts that hold: the problem's `:init` with what `world` observes in place.
    fn facts(&self, world: &[Tuple]) -> Vec<(String, Vec<String>)> {
        let observed = observe(world);
        let mut facts = Vec::new();
        for atom in &self.problem.init {
            let args: Vec<String> = atom
                .args
                .iter()
                .map(|t| match t {
                    Term::Const(c) | Term::Var(c) => c.to_string(),
                })
                .collect();
            let first = args.first().map(String::as_str).unwrap_or("");
            let second = args.get(1).map(String::as_str).unwrap_or("");
            let replaced = match &*atom.predicate {
                "at" => observed.rooms.contains_key(first),
                "holding" => observed.holders.contains_key(second),
                "thing-at" => observed.holders.get(first).is_some_and(Option::is_some),
                "awake" | "asleep" => observed.awake.contains_key(first),
                _ => false,
            };
            if !replaced {
                facts.push((atom.predicate.to_string(), args));
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
}

impl Replan for WorldReplanner {
    fn observe(&self) -> TuplePattern {
        TuplePattern::parse(&format!("{WORLD}:**")).unwrap_or_else(|_| TuplePattern::everything())
    }

    fn replan(&mut self, failed: &[String], world: &[Tuple]) -> Result<Vec<PlannedAction>, String> {
        let task =
            ecology_actions::ground(&self.domain, &self.problem).map_err(|e| e.to_string())?;
        let facts = self.facts(world);
        let state = task
            .state_from(
                facts
                    .iter()
                    .map(|(p, args)| (p.as_str(), args.iter().map(String::as_str).collect())),
            )
            .map_err(|e| e.to_string())?;
        let mut excluded = Vec::new();
        for action in failed {
            let call = parse_goal(action).map_err(|_| format!("`{action}` is not an action"))?;
            if let Some(op) = task.find_operator(&call).map_err(|e| e.to_string())? {
                excluded.push(op);
            }
        }
        run_action_planner(&ecology_actions::Request::replan(&task, state, excluded))
    }
}
