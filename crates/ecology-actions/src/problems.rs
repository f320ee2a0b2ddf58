//! Problem generators for tests and benchmarks: the classic domains of
//! `domains/pddl/` at growing sizes, and random small domains for property
//! tests against the [`crate::oracle`].
//!
//! Each generator writes PDDL text and parses it back, so the parser is
//! exercised too. Randomness comes from a seeded generator: the same seed
//! gives the same problem everywhere.

pub use ecology_core::Rng;
use std::fmt::Write;

use ecology_domain::{Diagnostics, Domain, Problem};

/// The gripper domain's source.
pub const GRIPPER: &str = include_str!("../../../domains/pddl/gripper.pddl");
/// The blocks world domain's source.
pub const BLOCKS: &str = include_str!("../../../domains/pddl/blocks.pddl");
/// The logistics domain's source (with action costs).
pub const LOGISTICS: &str = include_str!("../../../domains/pddl/logistics.pddl");
/// The parking domain's source (with action costs).
pub const PARKING: &str = include_str!("../../../domains/pddl/parking.pddl");

/// A generated problem, as text and parsed.
#[derive(Debug, Clone)]
pub struct Instance {
    /// A short name such as `gripper-10`.
    pub name: String,
    /// The domain's source.
    pub domain_text: String,
    /// The problem's source.
    pub problem_text: String,
    /// The parsed domain.
    pub domain: Domain,
    /// The parsed problem.
    pub problem: Problem,
    /// The optimal plan cost, when known in closed form.
    pub optimal_cost: Option<u64>,
}

/// A generated text did not parse: a generator bug, with the text.
#[derive(Debug, Clone, thiserror::Error)]
#[error("generated {what} does not parse: {diagnostics}\n{text}")]
pub struct GeneratorError {
    /// `domain` or `problem`.
    pub what: &'static str,
    /// The parser's diagnostics.
    pub diagnostics: Diagnostics,
    /// The text.
    pub text: String,
}

fn instance(
    name: String,
    domain_text: String,
    problem_text: String,
    optimal_cost: Option<u64>,
) -> Result<Instance, GeneratorError> {
    let domain =
        ecology_domain::parse_domain(domain_text.as_bytes()).map_err(|d| GeneratorError {
            what: "domain",
            diagnostics: d,
            text: domain_text.clone(),
        })?;
    let problem =
        ecology_domain::parse_problem(problem_text.as_bytes()).map_err(|d| GeneratorError {
            what: "problem",
            diagnostics: d,
            text: problem_text.clone(),
        })?;
    Ok(Instance {
        name,
        domain_text,
        problem_text,
        domain,
        problem,
        optimal_cost,
    })
}

/// Gripper with `balls` balls, all from `rooma` to `roomb`. The optimum is
/// known: each trip carries two balls, so `2n + 2⌈n/2⌉ - 1` actions.
pub fn gripper(balls: usize) -> Result<Instance, GeneratorError> {
    let mut p = String::new();
    let _ = writeln!(p, "(define (problem gripper-{balls}) (:domain gripper)");
    p.push_str("  (:objects rooma roomb - room left right - gripper");
    for b in 1..=balls {
        let _ = write!(p, " ball{b}");
    }
    p.push_str(" - ball)\n  (:init (at-robby rooma) (free left) (free right)");
    for b in 1..=balls {
        let _ = write!(p, " (at ball{b} rooma)");
    }
    p.push_str(")\n  (:goal (and");
    for b in 1..=balls {
        let _ = write!(p, " (at ball{b} roomb)");
    }
    p.push_str(")))\n");
    let optimum = (2 * balls + 2 * balls.div_ceil(2)).saturating_sub(1) as u64;
    instance(
        format!("gripper-{balls}"),
        GRIPPER.to_string(),
        p,
        Some(optimum),
    )
}

/// Writes `(:objects ...)`: for each `(prefix, count, type)`, the objects
/// `prefix0` to `prefix{count - 1}` of that type.
fn write_objects(p: &mut String, groups: &[(&str, usize, &str)]) {
    p.push_str("  (:objects");
    for &(prefix, count, kind) in groups {
        for i in 0..count {
            let _ = write!(p, " {prefix}{i}");
        }
        let _ = write!(p, " - {kind}");
    }
    p.push(')');
}

/// Random towers of `blocks` blocks, as `(below, above)` pairs and bottoms.
fn towers(blocks: usize, rng: &mut Rng) -> Vec<Vec<usize>> {
    let mut order: Vec<usize> = (0..blocks).collect();
    rng.shuffle(&mut order);
    let mut towers: Vec<Vec<usize>> = Vec::new();
    for b in order {
        match towers.last_mut() {
            Some(t) if !rng.chance(0.3) => t.push(b),
            _ => towers.push(vec![b]),
        }
    }
    towers
}

/// Blocks world: a random start and a random goal tower arrangement of
/// `blocks` blocks, from `seed`.
pub fn blocks(blocks: usize, seed: u64) -> Result<Instance, GeneratorError> {
    let mut rng = Rng::new(seed);
    let start = towers(blocks, &mut rng);
    let goal = towers(blocks, &mut rng);
    let mut p = String::new();
    let _ = writeln!(p, "(define (problem blocks-{blocks}) (:domain blocks)");
    p.push_str("  (:objects");
    for b in 0..blocks {
        let _ = write!(p, " b{b}");
    }
    p.push_str(" - block)\n  (:init (handempty)");
    for t in &start {
        let _ = write!(p, " (ontable b{})", t[0]);
        for w in t.windows(2) {
            let _ = write!(p, " (on b{} b{})", w[1], w[0]);
        }
        let _ = write!(p, " (clear b{})", t[t.len() - 1]);
    }
    p.push_str(")\n  (:goal (and");
    for t in &goal {
        let _ = write!(p, " (ontable b{})", t[0]);
        for w in t.windows(2) {
            let _ = write!(p, " (on b{} b{})", w[1], w[0]);
        }
    }
    p.push_str(")))\n");
    instance(format!("blocks-{blocks}"), BLOCKS.to_string(), p, None)
}

/// Logistics with `cities` cities (an airport and a post office each, one
/// truck each), `cities / 3 + 1` airplanes and `packages` packages with
/// random origins and destinations, from `seed`. Flights cost 5 to 14.
pub fn logistics(cities: usize, packages: usize, seed: u64) -> Result<Instance, GeneratorError> {
    let mut rng = Rng::new(seed);
    let planes = cities / 3 + 1;
    let mut p = String::new();
    let _ = writeln!(
        p,
        "(define (problem logistics-{cities}-{packages}) (:domain logistics)"
    );
    p.push_str("  (:objects");
    for c in 0..cities {
        let _ = write!(
            p,
            " c{c} - city ap{c} - airport po{c} - location t{c} - truck"
        );
    }
    for a in 0..planes {
        let _ = write!(p, " plane{a} - airplane");
    }
    for k in 0..packages {
        let _ = write!(p, " p{k} - package");
    }
    p.push_str(")\n  (:init");
    for c in 0..cities {
        let _ = write!(
            p,
            " (in-city ap{c} c{c}) (in-city po{c} c{c}) (at t{c} po{c})"
        );
    }
    for a in 0..planes {
        let _ = write!(p, " (at plane{a} ap{})", rng.index(cities));
    }
    for from in 0..cities {
        for to in 0..cities {
            let cost = if from == to { 0 } else { 5 + rng.index(10) };
            let _ = write!(p, " (= (flight-cost ap{from} ap{to}) {cost})");
        }
    }
    let place = |rng: &mut Rng| {
        let c = rng.index(cities);
        if rng.chance(0.5) {
            format!("ap{c}")
        } else {
            format!("po{c}")
        }
    };
    let mut goal = String::new();
    for k in 0..packages {
        let _ = write!(p, " (at p{k} {})", place(&mut rng));
        let _ = write!(goal, " (at p{k} {})", place(&mut rng));
    }
    let _ = write!(
        p,
        ")\n  (:goal (and{goal}))\n  (:metric minimize (total-cost)))\n"
    );
    instance(
        format!("logistics-{cities}-{packages}"),
        LOGISTICS.to_string(),
        p,
        None,
    )
}

/// A random arrangement of `cars` cars at `curbs` curbs: each car, in a
/// random order, goes to a random free place (a free curb, or beside a car
/// parked at a curb with no one beside it yet). For each car, where it is:
/// `Ok(curb)` parked at a curb, `Err(car)` beside that car.
fn arrangement(cars: usize, curbs: usize, rng: &mut Rng) -> Vec<Result<usize, usize>> {
    let mut order: Vec<usize> = (0..cars).collect();
    rng.shuffle(&mut order);
    let mut place = vec![Ok(usize::MAX); cars];
    let mut curb_taken = vec![false; curbs];
    let mut beside_taken = vec![true; cars];
    for car in order {
        let free: Vec<Result<usize, usize>> = (0..curbs)
            .filter(|&c| !curb_taken[c])
            .map(Ok)
            .chain((0..cars).filter(|&f| !beside_taken[f]).map(Err))
            .collect();
        let chosen = free[rng.index(free.len())];
        match chosen {
            Ok(c) => {
                curb_taken[c] = true;
                beside_taken[car] = false;
            }
            Err(front) => beside_taken[front] = true,
        }
        place[car] = chosen;
    }
    place
}

/// Parking with `curbs` curbs and `2 * (curbs - 1)` cars, as in the IPC's
/// instances: a random arrangement to another, from `seed`.
pub fn parking(curbs: usize, seed: u64) -> Result<Instance, GeneratorError> {
    let mut rng = Rng::new(seed);
    let cars = 2 * curbs.saturating_sub(1);
    let initial = arrangement(cars, curbs, &mut rng);
    let goal = arrangement(cars, curbs, &mut rng);
    let mut p = String::new();
    let _ = writeln!(
        p,
        "(define (problem parking-{curbs}-{seed}) (:domain parking)"
    );
    write_objects(&mut p, &[("car", cars, "car"), ("curb", curbs, "curb")]);
    p.push_str("\n  (:init (= (total-cost) 0)");
    let mut clear = vec![true; cars];
    let mut empty = vec![true; curbs];
    for (car, place) in initial.iter().enumerate() {
        match *place {
            Ok(curb) => {
                empty[curb] = false;
                let _ = write!(p, " (at-curb car{car}) (at-curb-num car{car} curb{curb})");
            }
            Err(front) => {
                clear[front] = false;
                let _ = write!(p, " (behind-car car{car} car{front})");
            }
        }
    }
    for car in (0..cars).filter(|&c| clear[c]) {
        let _ = write!(p, " (car-clear car{car})");
    }
    for curb in (0..curbs).filter(|&c| empty[c]) {
        let _ = write!(p, " (curb-clear curb{curb})");
    }
    p.push_str(")\n  (:goal (and");
    for (car, place) in goal.iter().enumerate() {
        let _ = match *place {
            Ok(curb) => write!(p, " (at-curb-num car{car} curb{curb})"),
            Err(front) => write!(p, " (behind-car car{car} car{front})"),
        };
    }
    p.push_str("))\n  (:metric minimize (total-cost)))\n");
    instance(
        format!("parking-{curbs}-{seed}"),
        PARKING.to_string(),
        p,
        None,
    )
}

/// A random small domain and problem: two types, four predicates, four
/// actions with positive, negative, equality and disjunctive preconditions,
/// conditional effects and costs,
/// three or four objects. Small enough for [`crate::oracle::cheapest`].
pub fn random_small(seed: u64) -> Result<Instance, GeneratorError> {
    let mut rng = Rng::new(seed);
    let action_costs = rng.chance(0.5);
    let mut d = String::new();
    let _ = writeln!(
        d,
        "(define (domain random-{seed})\n  (:requirements :strips :typing :negative-preconditions :equality \
         :disjunctive-preconditions :conditional-effects{})",
        if action_costs { " :action-costs" } else { "" }
    );
    d.push_str(
        "  (:types t0 t1)\n  (:predicates (p0 ?a - t0) (p1 ?a - t0 ?b - t1) (p2 ?b - t1) (flag))\n",
    );
    if action_costs {
        d.push_str("  (:functions (total-cost) - number (weight ?b - t1) - number)\n");
    }
    for k in 0..4 {
        // Parameters: ?x - t0 and ?y ?z - t1.
        let vars = [("x", "t0"), ("y", "t1"), ("z", "t1")];
        let arg = |rng: &mut Rng, ty: &str| -> &'static str {
            match (ty, rng.index(2)) {
                ("t0", _) => "?x",
                (_, 0) => "?y",
                _ => "?z",
            }
        };
        let atom = |rng: &mut Rng| -> String {
            match rng.index(8) {
                0 | 1 => format!("(p0 {})", arg(rng, "t0")),
                2..=4 => format!("(p1 {} {})", arg(rng, "t0"), arg(rng, "t1")),
                5 | 6 => format!("(p2 {})", arg(rng, "t1")),
                _ => "(flag)".to_string(),
            }
        };
        let mut pre = Vec::new();
        for _ in 0..1 + rng.index(2) {
            pre.push(sometimes_negated(atom(&mut rng), &mut rng, 0.25));
        }
        if rng.chance(0.3) {
            pre.push("(not (= ?y ?z))".to_string());
        }
        if rng.chance(0.3) {
            let either = sometimes_negated(atom(&mut rng), &mut rng, 0.25);
            let or = sometimes_negated(atom(&mut rng), &mut rng, 0.25);
            pre.push(format!("(or {either} {or})"));
        }
        let mut eff = Vec::new();
        for _ in 0..2 + rng.index(2) {
            eff.push(sometimes_negated(atom(&mut rng), &mut rng, 0.25));
        }
        if rng.chance(0.3) {
            let condition = sometimes_negated(atom(&mut rng), &mut rng, 0.25);
            let effect = sometimes_negated(atom(&mut rng), &mut rng, 0.25);
            eff.push(format!("(when {condition} {effect})"));
        }
        if action_costs {
            if rng.chance(0.5) {
                eff.push(format!("(increase (total-cost) {})", rng.index(4)));
            } else {
                eff.push("(increase (total-cost) (weight ?y))".to_string());
            }
        }
        let params: Vec<String> = vars.iter().map(|(v, t)| format!("?{v} - {t}")).collect();
        let _ = writeln!(
            d,
            "  (:action a{k} :parameters ({}) :precondition (and {}) :effect (and {}))",
            params.join(" "),
            pre.join(" "),
            eff.join(" ")
        );
    }
    d.push_str(")\n");
    let t0 = 1 + rng.index(2);
    let t1 = 2;
    let mut p = String::new();
    let _ = writeln!(p, "(define (problem random-{seed}) (:domain random-{seed})");
    write_objects(&mut p, &[("o", t0, "t0"), ("u", t1, "t1")]);
    p.push_str("\n  (:init");
    let mut ground: Vec<String> = vec!["(flag)".to_string()];
    for i in 0..t0 {
        ground.push(format!("(p0 o{i})"));
        for j in 0..t1 {
            ground.push(format!("(p1 o{i} u{j})"));
        }
    }
    for j in 0..t1 {
        ground.push(format!("(p2 u{j})"));
    }
    let initial = write_initial(&mut p, &mut rng, &ground, 0.5);
    if action_costs {
        for j in 0..t1 {
            let _ = write!(p, " (= (weight u{j}) {})", rng.index(5));
        }
    }
    write_goal(&mut p, &mut rng, &ground, &initial);
    instance(format!("random-{seed}"), d, p, None)
}

/// `atom`, negated with probability `chance`.
fn sometimes_negated(atom: String, rng: &mut Rng, chance: f64) -> String {
    if rng.chance(chance) {
        format!("(not {atom})")
    } else {
        atom
    }
}

/// Writes to the problem `p` each of the `ground` atoms that holds
/// initially (each with probability `chance`); which ones hold.
fn write_initial(
    p: &mut String,
    rng: &mut Rng,
    ground: &[impl AsRef<str>],
    chance: f64,
) -> Vec<bool> {
    let mut initial = vec![false; ground.len()];
    for (g, holds) in ground.iter().zip(&mut initial) {
        if rng.chance(chance) {
            *holds = true;
            let _ = write!(p, " {}", g.as_ref());
        }
    }
    initial
}

/// Ends the problem `p` with its goal: one or two of the `ground` atoms,
/// each as it does not hold `initial`ly, so that most problems need a plan.
fn write_goal(p: &mut String, rng: &mut Rng, ground: &[impl AsRef<str>], initial: &[bool]) {
    p.push_str(")\n  (:goal (and");
    for _ in 0..1 + rng.index(2) {
        let k = rng.index(ground.len());
        let atom = ground[k].as_ref();
        if initial[k] {
            let _ = write!(p, " (not {atom})");
        } else {
            let _ = write!(p, " {atom}");
        }
    }
    p.push_str(")))\n");
}

/// A random small problem with uncertainty, for property tests of the
/// conditional planner against [`crate::oracle_conditional`]: four actions
/// over one `t0` and two `t1` objects, some with a `(probabilistic ...)`
/// effect (two outcomes, or three that sum to 1 only up to rounding, such
/// as 0.7, 0.2 and 0.1), some observing an atom (`:observe`), some with a
/// disjunctive precondition (`or`) or a conditional effect (`when`), and
/// uncertain initial facts (two outcomes or three), on which the `or`s and
/// `when`s often depend: each world may take a different disjunct or
/// variant of an action.
pub fn random_uncertain(seed: u64) -> Result<Instance, GeneratorError> {
    let mut rng = Rng::new(seed ^ 0x5eed_0fc0_ffee);
    let mut d = String::new();
    let _ = writeln!(
        d,
        "(define (domain runc-{seed})\n  (:requirements :strips :typing :negative-preconditions :probabilistic-effects :disjunctive-preconditions :conditional-effects)"
    );
    d.push_str(
        "  (:types t0 t1)\n  (:predicates (p0 ?a - t0) (p1 ?a - t0 ?b - t1) (p2 ?b - t1) (flag))\n",
    );
    let atom = |rng: &mut Rng| -> String {
        match rng.index(7) {
            0 | 1 => "(p0 ?x)".to_string(),
            2 | 3 => "(p1 ?x ?y)".to_string(),
            4 | 5 => "(p2 ?y)".to_string(),
            _ => "(flag)".to_string(),
        }
    };
    let literal = |rng: &mut Rng| -> String { sometimes_negated(atom(rng), rng, 0.2) };
    const PROBABILITIES: [(&str, &str); 4] = [
        ("0.5", "0.5"),
        ("0.7", "0.3"),
        ("0.2", "0.6"),
        ("1/3", "1/3"),
    ];
    // Each sums to 1 only up to rounding in binary.
    const THREE: [(&str, &str, &str); 3] = [
        ("0.7", "0.2", "0.1"),
        ("0.1", "0.2", "0.7"),
        ("7/10", "2/10", "1/10"),
    ];
    for k in 0..4 {
        let mut pre: Vec<String> = (0..rng.index(3)).map(|_| literal(&mut rng)).collect();
        if rng.chance(0.3) {
            pre.push(format!("(or {} {})", literal(&mut rng), literal(&mut rng)));
        }
        let mut eff: Vec<String> = (0..1 + rng.index(3)).map(|_| literal(&mut rng)).collect();
        if rng.chance(0.3) {
            eff.push(format!(
                "(when {} {})",
                literal(&mut rng),
                literal(&mut rng)
            ));
        }
        if rng.chance(0.2) {
            // Every outcome does `common` too (as every roll of a die
            // leaves a number on top): it happens surely, or not at all if
            // a rest of rounding were an outcome.
            let (p, q, r) = THREE[rng.index(THREE.len())];
            let common = literal(&mut rng);
            eff.push(format!(
                "(probabilistic {p} (and {} {common}) {q} (and {} {common}) {r} (and {} {common}))",
                literal(&mut rng),
                literal(&mut rng),
                literal(&mut rng)
            ));
        } else if rng.chance(0.6) {
            let (p, q) = PROBABILITIES[rng.index(PROBABILITIES.len())];
            eff.push(format!(
                "(probabilistic {p} {} {q} (and {}))",
                literal(&mut rng),
                literal(&mut rng)
            ));
        }
        let observe = if rng.chance(0.5) {
            format!(" :observe {}", atom(&mut rng))
        } else {
            String::new()
        };
        let _ = writeln!(
            d,
            "  (:action a{k} :parameters (?x - t0 ?y - t1) :precondition (and {}) :effect (and {}){observe})",
            pre.join(" "),
            eff.join(" ")
        );
    }
    d.push_str(")\n");
    let ground = [
        "(flag)",
        "(p0 o0)",
        "(p1 o0 u0)",
        "(p1 o0 u1)",
        "(p2 u0)",
        "(p2 u1)",
    ];
    let mut p = String::new();
    let _ = writeln!(p, "(define (problem runc-{seed}) (:domain runc-{seed})");
    p.push_str("  (:objects o0 - t0 u0 u1 - t1)\n  (:init");
    let initial = write_initial(&mut p, &mut rng, &ground, 0.4);
    let (a, b) = (rng.index(ground.len()), rng.index(ground.len()));
    if rng.chance(0.25) {
        let (pa, pb, pc) = THREE[rng.index(THREE.len())];
        let c = rng.index(ground.len());
        let _ = write!(
            p,
            " (probabilistic {pa} {} {pb} {} {pc} {})",
            ground[a], ground[b], ground[c]
        );
    } else {
        let (pa, pb) = PROBABILITIES[rng.index(PROBABILITIES.len())];
        let _ = write!(p, " (probabilistic {pa} {} {pb} {})", ground[a], ground[b]);
    }
    write_goal(&mut p, &mut rng, &ground, &initial);
    instance(format!("random-uncertain-{seed}"), d, p, None)
}

/// The triangle tireworld domain of IPPC 2006/2008 (Little and Thiébaux,
/// "Probabilistic planning vs. replanning", 2007), reimplemented: a car
/// drives from one corner of a triangular road map to another; each move
/// flattens the tire with probability 1/2, and spares lie only off the
/// shortest road. IPPC's planners observe the state fully, so `move-car`
/// here observes whether the tire is flat (`:observe`).
pub const TIREWORLD: &str = "(define (domain triangle-tire)
  (:requirements :typing :strips :probabilistic-effects)
  (:types location)
  (:predicates (vehicle-at ?loc - location) (spare-in ?loc - location)
    (road ?from - location ?to - location) (not-flattire) (hasspare))
  (:action move-car
    :parameters (?from - location ?to - location)
    :precondition (and (vehicle-at ?from) (road ?from ?to) (not-flattire))
    :effect (and (vehicle-at ?to) (not (vehicle-at ?from))
                 (probabilistic 0.5 (not (not-flattire))))
    :observe (not-flattire))
  (:action loadtire
    :parameters (?loc - location)
    :precondition (and (vehicle-at ?loc) (spare-in ?loc))
    :effect (and (hasspare) (not (spare-in ?loc))))
  (:action changetire
    :parameters ()
    :precondition (hasspare)
    :effect (and (not (hasspare)) (not-flattire))))
";

/// Triangle tireworld problem `n` (IPPC's p0n): a triangle of side
/// `2n + 1` locations, from its corner `l-1-1` to `l-1-(2n+1)`. The road
/// along the top is the shortest and has no spares; the roads along the
/// other two sides have a spare at every location, so a plan reaches the
/// goal surely by taking them (with a long enough horizon).
pub fn tireworld(n: usize) -> Result<Instance, GeneratorError> {
    let m = 2 * n + 1;
    // Row i (1-based) has m + 1 - i locations.
    let len = |i: usize| m + 1 - i;
    let loc = |i: usize, j: usize| format!("l-{i}-{j}");
    let mut objects = Vec::new();
    let mut facts: Vec<String> = vec![
        format!("(vehicle-at {})", loc(1, 1)),
        "(not-flattire)".into(),
    ];
    for i in 1..=m {
        for j in 1..=len(i) {
            objects.push(loc(i, j));
        }
    }
    for i in 1..=m {
        let odd = i % 2 == 1;
        if odd {
            for j in 1..len(i) {
                facts.push(format!("(road {} {})", loc(i, j), loc(i, j + 1)));
            }
            if i > 1 {
                facts.push(format!("(spare-in {})", loc(i, 1)));
                if len(i) > 1 {
                    facts.push(format!("(spare-in {})", loc(i, len(i))));
                }
            }
            if i < m {
                // Down to the even row below and diagonally back up.
                for j in 1..=len(i + 1) {
                    facts.push(format!("(road {} {})", loc(i, j), loc(i + 1, j)));
                    facts.push(format!("(road {} {})", loc(i + 1, j), loc(i, j + 1)));
                }
            }
        } else {
            for j in 1..=len(i) {
                facts.push(format!("(spare-in {})", loc(i, j)));
            }
            for j in (1..=len(i + 1)).step_by(2) {
                facts.push(format!("(road {} {})", loc(i, j), loc(i + 1, j)));
                facts.push(format!("(road {} {})", loc(i + 1, j), loc(i, j + 1)));
            }
        }
    }
    let mut p = String::new();
    let _ = writeln!(
        p,
        "(define (problem triangle-tire-{n}) (:domain triangle-tire)"
    );
    let _ = writeln!(p, "  (:objects {} - location)", objects.join(" "));
    let _ = writeln!(p, "  (:init {})", facts.join(" "));
    let _ = writeln!(p, "  (:goal (vehicle-at {})))", loc(1, m));
    instance(format!("tireworld-{n}"), TIREWORLD.to_string(), p, None)
}

/// A straight corridor of `length` moves, with `facts` independent
/// uncertain faults (each broken with probability 1/2) that the goal wants
/// repaired, one action each: planned within a horizon of `length` plus
/// fewer than `facts` actions, the repairs compete for the actions the
/// walk leaves, and every belief of a position and a set of repairs is a
/// candidate.
pub fn corridor(length: usize, facts: usize) -> Result<Instance, GeneratorError> {
    let domain = "(define (domain corridor)
  (:requirements :strips :negative-preconditions :probabilistic-effects)
  (:predicates (at ?c) (next ?a ?b) (fault ?i) (broken ?i))
  (:action move :parameters (?a ?b)
    :precondition (and (at ?a) (next ?a ?b))
    :effect (and (at ?b) (not (at ?a))))
  (:action repair :parameters (?i)
    :precondition (fault ?i)
    :effect (not (broken ?i))))
";
    let mut p = String::new();
    let _ = writeln!(
        p,
        "(define (problem corridor-{length}-{facts}) (:domain corridor)"
    );
    p.push_str("  (:objects");
    for c in 0..=length {
        let _ = write!(p, " c{c}");
    }
    for i in 0..facts {
        let _ = write!(p, " f{i}");
    }
    p.push_str(")\n  (:init (at c0)");
    for c in 0..length {
        let _ = write!(p, " (next c{c} c{})", c + 1);
    }
    for i in 0..facts {
        let _ = write!(p, " (fault f{i}) (probabilistic 0.5 (broken f{i}))");
    }
    let _ = write!(p, ")\n  (:goal (and (at c{length})");
    for i in 0..facts {
        let _ = write!(p, " (not (broken f{i}))");
    }
    p.push_str(")))\n");
    instance(
        format!("corridor-{length}-{facts}"),
        domain.to_string(),
        p,
        None,
    )
}
