//! Tests of the language of uncertainty: probabilistic effects, `:observe`,
//! uncertain `:init` facts, and their diagnostics.

use crate::{Effect, parse_domain, parse_problem, parse_problem_for};

const DOMAIN: &str = "(define (domain news)
  (:requirements :strips :typing :probabilistic-effects)
  (:types room thing)
  (:predicates (at ?t - thing ?x - room) (robot-at ?x - room) (holding ?t - thing))
  (:action look :parameters (?t - thing ?x - room)
    :precondition (robot-at ?x)
    :effect (and)
    :observe ((at ?t ?x)))
  (:action get :parameters (?t - thing ?x - room)
    :precondition (and (robot-at ?x) (at ?t ?x))
    :effect (and (not (at ?t ?x))
                 (probabilistic 0.9 (holding ?t) 1/20 (and (at ?t ?x)))))
  (:action go :parameters (?x ?y - room)
    :precondition (robot-at ?x)
    :effect (and (robot-at ?y) (not (robot-at ?x)))))";

const PROBLEM: &str = "(define (problem p) (:domain news)
  (:objects entrance kitchen - room newspaper - thing)
  (:init (robot-at kitchen)
    (probabilistic 0.7 (at newspaper entrance) 0.3 (at newspaper kitchen)))
  (:goal (holding newspaper)))";

fn errors(result: Result<impl std::fmt::Debug, crate::Diagnostics>) -> Vec<String> {
    match result {
        Ok(v) => panic!("expected errors, got {v:?}"),
        Err(d) => d.0.iter().map(|d| d.message.clone()).collect(),
    }
}

#[test]
fn probabilistic_effects_and_observations_parse() {
    let domain = parse_domain(DOMAIN.as_bytes()).expect("valid");
    let look = domain.action("look").expect("look");
    assert_eq!(look.observe.len(), 1);
    assert_eq!(look.observe[0].to_string(), "(at ?t ?x)");
    assert!(look.chances.is_empty());
    let get = domain.action("get").expect("get");
    assert_eq!(get.effects.len(), 1);
    assert!(matches!(get.effects[0], Effect::Del(_)));
    let chance = &get.chances[0];
    assert_eq!(chance.outcomes.len(), 2);
    assert_eq!(chance.outcomes[0].probability, 0.9);
    assert!((chance.outcomes[1].probability - 0.05).abs() < 1e-12);
    assert!((chance.rest() - 0.05).abs() < 1e-9);
    let problem = parse_problem_for(&domain, PROBLEM.as_bytes()).expect("valid problem");
    assert_eq!(problem.init.len(), 1);
    assert_eq!(problem.uncertain.len(), 1);
    assert_eq!(
        problem.uncertain[0].outcomes[1].items[0].to_string(),
        "(at newspaper kitchen)"
    );
}

#[test]
fn oneof_is_uniform() {
    let problem = parse_problem(
        b"(define (problem p) (:domain news) (:objects a b c - room)
          (:init (oneof (robot-at a) (robot-at b) (and (robot-at c))))
          (:goal (robot-at a)))",
    )
    .expect("valid");
    let outcomes = &problem.uncertain[0].outcomes;
    assert_eq!(outcomes.len(), 3);
    assert!(
        outcomes
            .iter()
            .all(|o| (o.probability - 1.0 / 3.0).abs() < 1e-12)
    );
    assert_eq!(problem.uncertain[0].rest(), 0.0);
}

#[test]
fn outcomes_that_sum_to_one_up_to_rounding_leave_no_rest() {
    // 0.7 + 0.2 + 0.1 is 0.9999999999999999: its leftover is rounding.
    let rest = |init: &str| {
        let text = format!(
            "(define (problem p) (:domain news) (:objects a b c - room)
              (:init (probabilistic {init})) (:goal (robot-at a)))"
        );
        parse_problem(text.as_bytes()).expect("valid").uncertain[0].rest()
    };
    assert_eq!(
        rest("0.7 (robot-at a) 0.2 (robot-at b) 0.1 (robot-at c)"),
        0.0
    );
    assert_eq!(
        rest("7/10 (robot-at a) 2/10 (robot-at b) 1/10 (robot-at c)"),
        0.0
    );
    assert_eq!(rest("0.6 (robot-at a) 0.4000001 (robot-at b)"), 0.0);
    assert!((rest("0.7 (robot-at a) 0.2 (robot-at b)") - 0.1).abs() < 1e-12);
    assert!((rest("0.999 (robot-at a)") - 0.001).abs() < 1e-12);
}

#[test]
fn bad_probabilities_are_reported_with_spans() {
    let bad = DOMAIN
        .replace("0.9 (holding ?t) 1/20", "0.9 (holding ?t) 0.2")
        .replace(
            ":observe ((at ?t ?x))",
            ":observe ((seen ?t) (not (at ?t ?x)))",
        );
    let messages = errors(parse_domain(bad.as_bytes()));
    assert!(
        messages
            .iter()
            .any(|m| m.contains("sum to") && m.contains("more than 1")),
        "{messages:?}"
    );
    assert!(
        messages
            .iter()
            .any(|m| m.contains("`:observe` lists atoms")),
        "{messages:?}"
    );
    assert!(
        messages
            .iter()
            .any(|m| m.contains("undeclared predicate `seen`")),
        "{messages:?}"
    );
    let bad = DOMAIN.replace("1/20", "1.5");
    let messages = errors(parse_domain(bad.as_bytes()));
    assert!(
        messages.iter().any(|m| m.contains("not in [0, 1]")),
        "{messages:?}"
    );
    let bad = DOMAIN.replace(
        "0.9 (holding ?t) 1/20 (and (at ?t ?x))",
        "0.9 (holding ?t) 0.1",
    );
    let messages = errors(parse_domain(bad.as_bytes()));
    assert!(messages.iter().any(|m| m.contains("pairs")), "{messages:?}");
    let bad = DOMAIN.replace("(holding ?t) 1/20", "(probabilistic 1 (holding ?t)) 1/20");
    let messages = errors(parse_domain(bad.as_bytes()));
    assert!(
        messages.iter().any(|m| m.contains("do not nest")),
        "{messages:?}"
    );
    let bad = DOMAIN.replace("(holding ?t) 1/20", "(holding ?u) 1/20");
    assert!(!errors(parse_domain(bad.as_bytes())).is_empty());
}

#[test]
fn uncertain_init_is_checked_against_the_domain() {
    let domain = parse_domain(DOMAIN.as_bytes()).expect("valid");
    let bad = PROBLEM.replace("0.3 (at newspaper kitchen)", "0.3 (at newspaper garage)");
    let messages = errors(parse_problem_for(&domain, bad.as_bytes()));
    assert!(
        messages
            .iter()
            .any(|m| m.contains("unknown object `garage`")),
        "{messages:?}"
    );
    let bad = PROBLEM.replace("0.3 (at newspaper kitchen)", "0.3 (at ?n kitchen)");
    let messages = errors(parse_problem(bad.as_bytes()));
    assert!(
        messages.iter().any(|m| m.contains("ground")),
        "{messages:?}"
    );
    let bad = PROBLEM
        .replace("(oneof", "(probabilistic")
        .replace("0.3 (at", "0.4 (at");
    let messages = errors(parse_problem(bad.as_bytes()));
    assert!(
        messages.iter().any(|m| m.contains("more than 1")),
        "{messages:?}"
    );
}

#[test]
fn random_mutations_of_uncertain_files_never_panic() {
    // A tiny deterministic generator: every input is replayable.
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    for source in [DOMAIN, PROBLEM] {
        let bytes = source.as_bytes();
        for _ in 0..2000 {
            let mut m = bytes.to_vec();
            for _ in 0..1 + next() % 4 {
                let i = (next() as usize) % m.len();
                match next() % 3 {
                    0 => {
                        m.remove(i);
                    }
                    1 => m.insert(i, b"()0.5/ ?-"[(next() % 9) as usize]),
                    _ => m[i] = b"()01./ab"[(next() % 8) as usize],
                }
            }
            let _ = parse_domain(&m);
            let _ = parse_problem(&m);
        }
    }
}
