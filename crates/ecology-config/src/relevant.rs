//! Which component types a goal can use: what an executive must acquire of
//! the ecology to plan for it (the paper's Section V, "acquired on demand");
//! and which facts of the world an action starts in its methods read.
//!
//! The ecology state facts that come from PEIS are `(pc P TYPE C)`, `(cost P C
//! N on|off)` and `(status P C S)`. Every functionality and method the goal
//! can reach names the components it may use through `pc` literals; when each
//! of them names its type as a constant, only PEIS with a component of one of
//! those types can take part in a configuration, and the rest of the ecology
//! need not be read. Anything less precise (a type given by a variable, a
//! negated `pc`, a `cost` or `status` of a component no constant-type `pc`
//! binds) needs the whole state.

use std::collections::{BTreeSet, HashMap};

use ecology_domain::{Call, Domain, Fact, Literal, Name, Term};

/// The component types a configuration for `goal` can use, or `None` when
/// the goal's methods and functionalities could use a component of any type
/// (or the goal is unknown), so that every component must be acquired.
pub fn component_types(domain: &Domain, goal: &Call) -> Option<BTreeSet<String>> {
    let mut types = BTreeSet::new();
    let mut seen = BTreeSet::new();
    let mut todo = vec![&*goal.name];
    while let Some(name) = todo.pop() {
        if !seen.insert(name) {
            continue;
        }
        if let Some(f) = domain.functionality(name) {
            types_of(&f.precondition, &mut types)?;
        } else if domain.task(name).is_some() {
            for method in domain.methods_of(name) {
                types_of(&method.precondition, &mut types)?;
                todo.extend(method.subtasks.iter().map(|s| &*s.call.name));
            }
        } else {
            return None;
        }
    }
    Some(types)
}

/// Adds the types `precondition`'s `pc` literals name; `None` when it may
/// use a component whose type it does not name.
fn types_of(precondition: &[Literal], types: &mut BTreeSet<String>) -> Option<()> {
    let mut typed = BTreeSet::new();
    for literal in precondition {
        match literal {
            Literal::Pos(atom) if &*atom.predicate == "pc" => {
                let [_, Term::Const(ty), component] = atom.args.as_slice() else {
                    return None;
                };
                types.insert(ty.to_string());
                if let Term::Var(v) = component {
                    typed.insert(&**v);
                }
            }
            Literal::Neg(atom) if &*atom.predicate == "pc" => return None,
            _ => {}
        }
    }
    for literal in precondition {
        let (Literal::Pos(atom) | Literal::Neg(atom)) = literal else {
            continue;
        };
        if matches!(&*atom.predicate, "cost" | "status") {
            let bound = match atom.args.get(1) {
                Some(Term::Var(v)) => typed.contains(&**v),
                _ => false,
            };
            if !bound {
                return None;
            }
        }
    }
    Some(())
}

/// The PEIS a configuration for a goal can use, when each is named or covers a given room.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Scope {
    /// The PEIS the goal's methods name (Astrid, in `(navigate astrid entrance)`).
    pub peis: BTreeSet<String>,
    /// The rooms whose covering PEIS the methods can use (a camera with `(covers ?p ?c ?x)`,
    /// where the robot is in room `?x`).
    pub rooms: BTreeSet<String>,
}

impl Scope {
    /// Adds what `other` holds.
    pub fn extend(&mut self, other: Scope) {
        self.peis.extend(other.peis);
        self.rooms.extend(other.rooms);
    }
}

/// The predicates of the ecology state whose first argument is a PEIS: the facts an executive
/// acquires from each PEIS's tuples.
const OF_A_PEIS: [&str; 6] = ["peis", "pc", "cost", "status", "held", "covers"];

/// What one argument of a call is known to be while the goal's methods are walked.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
enum Known {
    /// This constant.
    Is(Name),
    /// A PEIS that covers a room of the scope: one of those the executive finds by room.
    Covering,
    /// Anything.
    Unknown,
}

/// The PEIS a configuration for `goal` can use, in a world where `facts` hold (the facts the
/// action starts with, such as `(at astrid living-room)`), when every functionality and method
/// the goal can reach reads the facts of PEIS that are either named (by the goal, or through the
/// facts) or cover a room the facts name (`(covers ?p ?c ?x)` with `?x` known); `None` when some
/// method could use any PEIS (the paper's *another robot's camera*, which names no room), or the
/// goal is unknown. An executive then acquires the contract of those PEIS alone, whatever the
/// size of the ecology.
pub fn component_scope(domain: &Domain, goal: &Call, facts: &[Fact]) -> Option<Scope> {
    let args = goal
        .args
        .iter()
        .map(|t| match t {
            Term::Const(c) => Known::Is(c.clone()),
            Term::Var(_) => Known::Unknown,
        })
        .collect();
    let mut scope = Scope::default();
    let mut seen = BTreeSet::new();
    let mut todo: Vec<(Name, Vec<Known>)> = vec![(goal.name.clone(), args)];
    while let Some((name, args)) = todo.pop() {
        if !seen.insert((name.clone(), args.clone())) {
            continue;
        }
        if let Some(f) = domain.functionality(&name) {
            let mut bound: HashMap<&str, Known> = HashMap::new();
            for (param, arg) in f.params.iter().zip(&args) {
                bound.insert(&param.name, arg.clone());
            }
            scope_of(&f.precondition, &mut bound, facts, &mut scope)?;
            // The PEIS that implements it is one of those the precondition reads.
            if matches!(bound.get(&*f.component.0), None | Some(Known::Unknown)) {
                return None;
            }
        } else if domain.task(&name).is_some() {
            for method in domain.methods_of(&name) {
                let mut bound: HashMap<&str, Known> = HashMap::new();
                let mut applies = true;
                for (term, arg) in method.task.args.iter().zip(&args) {
                    match (term, arg) {
                        (Term::Var(v), _) => {
                            let was = bound.insert(v, arg.clone());
                            // The same variable twice, given two constants: never this method.
                            if let (Some(Known::Is(a)), Known::Is(b)) = (was, arg) {
                                applies &= a == *b;
                            }
                        }
                        (Term::Const(c), Known::Is(a)) => applies &= c == a,
                        (Term::Const(_), _) => {}
                    }
                }
                if !applies {
                    continue;
                }
                scope_of(&method.precondition, &mut bound, facts, &mut scope)?;
                for subtask in &method.subtasks {
                    let args = subtask
                        .call
                        .args
                        .iter()
                        .map(|t| match t {
                            Term::Const(c) => Known::Is(c.clone()),
                            Term::Var(v) => bound.get(&**v).cloned().unwrap_or(Known::Unknown),
                        })
                        .collect();
                    todo.push((subtask.call.name.clone(), args));
                }
            }
        } else {
            return None;
        }
    }
    Some(scope)
}

/// Adds to `scope` the PEIS and rooms `precondition` reads the facts of, given what `bound` knows
/// of its variables (which it extends); `None` when it reads the facts of a PEIS it neither
/// names nor finds by room.
fn scope_of<'a>(
    precondition: &'a [Literal],
    bound: &mut HashMap<&'a str, Known>,
    facts: &[Fact],
    scope: &mut Scope,
) -> Option<()> {
    let is = |bound: &HashMap<&str, Known>, term: &Term| -> Option<Name> {
        match term {
            Term::Const(c) => Some(c.clone()),
            Term::Var(v) => match bound.get(&**v) {
                Some(Known::Is(c)) => Some(c.clone()),
                _ => None,
            },
        }
    };
    // What the world's facts tell of the variables (`(at ?r ?x)` with `?r` known gives `?x`),
    // until they tell nothing more; a variable that several facts give different values stays
    // unknown.
    let mut more = true;
    while more {
        more = false;
        for literal in precondition {
            let Literal::Pos(atom) = literal else {
                continue;
            };
            if OF_A_PEIS.contains(&&*atom.predicate) {
                continue;
            }
            let known: Vec<Option<Name>> = atom.args.iter().map(|t| is(bound, t)).collect();
            let mut matching = facts.iter().filter(|f| {
                f.predicate == atom.predicate
                    && f.args.len() == known.len()
                    && f.args
                        .iter()
                        .zip(&known)
                        .all(|(a, k)| k.as_ref().is_none_or(|k| k == a))
            });
            let Some(first) = matching.next() else {
                continue;
            };
            let rest: Vec<&Fact> = matching.collect();
            for (i, term) in atom.args.iter().enumerate() {
                let Term::Var(v) = term else { continue };
                if known[i].is_some() || rest.iter().any(|f| f.args[i] != first.args[i]) {
                    continue;
                }
                bound.insert(v, Known::Is(first.args[i].clone()));
                more = true;
            }
        }
    }
    // A PEIS that covers a known room is found by asking who covers it.
    for literal in precondition {
        let Literal::Pos(atom) = literal else {
            continue;
        };
        if &*atom.predicate != "covers" {
            continue;
        }
        if let [Term::Var(p), _, room] = atom.args.as_slice()
            && let Some(room) = is(bound, room)
            && !matches!(bound.get(&**p), Some(Known::Is(_)))
        {
            scope.rooms.insert(room.to_string());
            bound.insert(p, Known::Covering);
        }
    }
    for literal in precondition {
        let (Literal::Pos(atom) | Literal::Neg(atom)) = literal else {
            continue;
        };
        if !OF_A_PEIS.contains(&&*atom.predicate) {
            continue;
        }
        match atom.args.first() {
            Some(Term::Const(p)) => {
                scope.peis.insert(p.to_string());
            }
            Some(Term::Var(v)) => match bound.get(&**v) {
                Some(Known::Is(p)) => {
                    scope.peis.insert(p.to_string());
                }
                Some(Known::Covering) => {}
                _ => return None,
            },
            None => return None,
        }
    }
    Some(())
}

/// The ground atoms of `action`'s precondition (an action of `domain` written `(move astrid
/// living-room entrance)`) whose predicates `reads` says some functionality or method reads; see
/// [`crate::Planner::facts_at_action`]. Empty for an action `domain` does not know, or written
/// otherwise.
pub(crate) fn facts_at_action(
    domain: &Domain,
    action: &str,
    reads: impl Fn(&str) -> bool,
) -> Vec<Fact> {
    let Ok(call) = ecology_domain::parse_goal(action) else {
        return Vec::new();
    };
    let Some(schema) = domain.action(&call.name) else {
        return Vec::new();
    };
    if schema.params.len() != call.args.len() {
        return Vec::new();
    }
    let mut bound = HashMap::new();
    for (param, arg) in schema.params.iter().zip(&call.args) {
        let Term::Const(value) = arg else {
            return Vec::new();
        };
        bound.insert(&*param.name, value.clone());
    }
    schema
        .precondition
        .iter()
        .filter_map(|literal| match literal {
            Literal::Pos(atom) if reads(&atom.predicate) => Some(atom),
            _ => None,
        })
        .filter_map(|atom| {
            let args = atom
                .args
                .iter()
                .map(|term| match term {
                    Term::Const(c) => Some(c.clone()),
                    Term::Var(v) => bound.get(&**v).cloned(),
                })
                .collect::<Option<Vec<_>>>()?;
            Some(Fact {
                predicate: atom.predicate.clone(),
                args,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn domain(text: &str) -> Domain {
        ecology_domain::parse_domain(text.as_bytes()).expect("a domain")
    }

    fn goal(text: &str) -> Call {
        ecology_domain::parse_goal(text).expect("a goal")
    }

    const SEE: &str = r#"(define (domain d)
      (:functionality cam :parameters (?p ?c) :component (?p ?c)
        :precondition (pc ?p cam ?c) :output ((image ?p)) :cost 5)
      (:functionality laser :parameters (?p ?c) :component (?p ?c)
        :precondition (pc ?p laser ?c) :output ((scan ?p)) :cost 5)
      (:functionality any :parameters (?p ?t ?c) :component (?p ?c)
        :precondition (pc ?p ?t ?c) :output ((image ?p)) :cost 5)
      (:task see :parameters (?p))
      (:method see-with-camera :parameters (?p ?c) :task (see ?p)
        :precondition (and (pc ?p cam ?c) (status ?p ?c running)) :subtasks ((f1 (cam ?p ?c))))
      (:task look :parameters (?p))
      (:method look-with-anything :parameters (?p ?c ?t) :task (look ?p)
        :precondition (pc ?p ?t ?c) :subtasks ((f1 (any ?p ?t ?c)))))"#;

    #[test]
    fn a_goal_uses_the_types_its_methods_and_functionalities_name() {
        let d = domain(SEE);
        let types = component_types(&d, &goal("(see robot)")).expect("types");
        assert_eq!(types, BTreeSet::from(["cam".to_string()]));
        let types = component_types(&d, &goal("(laser robot l1)")).expect("types");
        assert_eq!(types, BTreeSet::from(["laser".to_string()]));
    }

    #[test]
    fn a_type_given_by_a_variable_or_an_unknown_goal_needs_everything() {
        let d = domain(SEE);
        assert_eq!(component_types(&d, &goal("(look robot)")), None);
        assert_eq!(component_types(&d, &goal("(fly robot)")), None);
    }

    const MOVE: &str = r#"(define (domain d)
      (:requirements :strips :typing)
      (:types robot room)
      (:predicates (at ?r - robot ?x - room) (connected ?a ?b - room) (lit ?x - room))
      (:functionality cam :parameters (?p ?c) :component (?p ?c)
        :precondition (pc ?p cam ?c) :output ((image ?p)) :cost 5)
      (:task see :parameters (?r))
      (:method see-where-it-is :parameters (?r ?p ?c ?x) :task (see ?r)
        :precondition (and (at ?r ?x) (covers ?p ?c ?x) (pc ?p cam ?c))
        :subtasks ((f1 (cam ?p ?c))))
      (:action move :parameters (?r - robot ?from ?to - room)
        :precondition (and (at ?r ?from) (connected ?from ?to) (lit ?to) (not (= ?from ?to)))
        :effect (and (at ?r ?to) (not (at ?r ?from)))
        :configure (see ?r)))"#;

    #[test]
    fn an_action_brings_the_atoms_of_its_precondition_that_methods_read() {
        let planner = crate::Planner::new(domain(MOVE));
        let facts = planner.facts_at_action("(move astrid hall kitchen)");
        let shown: Vec<String> = facts
            .iter()
            .map(|f| format!("({} {})", f.predicate, f.args.join(" ")))
            .collect();
        // `connected` and `lit` hold too, but no method or functionality reads them.
        assert_eq!(shown, ["(at astrid hall)"]);
    }

    #[test]
    fn an_action_the_domain_does_not_know_brings_nothing() {
        let planner = crate::Planner::new(domain(MOVE));
        assert!(
            planner
                .facts_at_action("(fly astrid hall kitchen)")
                .is_empty()
        );
        assert!(planner.facts_at_action("(move astrid hall)").is_empty());
        assert!(
            planner
                .facts_at_action("move astrid hall kitchen")
                .is_empty()
        );
        assert!(
            planner
                .facts_at_action("(move astrid ?x kitchen)")
                .is_empty()
        );
        assert!(planner.facts_at_action("").is_empty());
    }

    #[test]
    fn the_papers_navigation_uses_the_position_sources_and_nothing_else() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../domains/peis-home.eco");
        let d = domain(&std::fs::read_to_string(path).expect("the domain file"));
        let types = component_types(&d, &goal("(navigate astrid kitchen)")).expect("types");
        for ty in ["laser", "odomet", "self-loc", "cams", "tr-sys"] {
            assert!(types.contains(ty), "{ty} missing from {types:?}");
        }
        assert!(!types.contains("player"), "{types:?}");
    }

    fn domain_file(name: &str) -> Domain {
        let path = format!("{}/../../domains/{name}", env!("CARGO_MANIFEST_DIR"));
        domain(&std::fs::read_to_string(path).expect("the domain file"))
    }

    fn scope(peis: &[&str], rooms: &[&str]) -> Scope {
        Scope {
            peis: peis.iter().map(|p| p.to_string()).collect(),
            rooms: rooms.iter().map(|r| r.to_string()).collect(),
        }
    }

    #[test]
    fn in_a_building_a_navigation_uses_the_robot_and_who_covers_its_room() {
        let d = domain_file("peis-building.eco");
        let at = [Fact::new("at", &["astrid", "living-room"])];
        assert_eq!(
            component_scope(&d, &goal("(navigate astrid entrance)"), &at),
            Some(scope(&["astrid"], &["living-room"]))
        );
        // Grasping reads Astrid's gripper alone; where she is does not matter.
        assert_eq!(
            component_scope(&d, &goal("(grasp astrid newspaper)"), &at),
            Some(scope(&["astrid"], &[]))
        );
        // Two facts that disagree on where she is name no room: any camera could serve.
        let twice = [
            Fact::new("at", &["astrid", "living-room"]),
            Fact::new("at", &["astrid", "kitchen"]),
        ];
        assert_eq!(
            component_scope(&d, &goal("(navigate astrid entrance)"), &twice),
            None
        );
        // Not knowing where she is, neither.
        assert_eq!(
            component_scope(&d, &goal("(navigate astrid entrance)"), &[]),
            None
        );
        // Another robot's whereabouts say nothing of hers.
        let pippi = [Fact::new("at", &["pippi", "living-room"])];
        assert_eq!(
            component_scope(&d, &goal("(navigate astrid entrance)"), &pippi),
            None
        );
        assert_eq!(component_scope(&d, &goal("(fly astrid)"), &at), None);
    }

    #[test]
    fn in_the_papers_home_another_robot_could_be_any_peis() {
        let d = domain_file("peis-home.eco");
        let at = [Fact::new("at", &["astrid", "living-room"])];
        assert_eq!(
            component_scope(&d, &goal("(navigate astrid entrance)"), &at),
            None
        );
        assert_eq!(
            component_scope(&d, &goal("(grasp astrid newspaper)"), &at),
            Some(scope(&["astrid"], &[]))
        );
    }
}
