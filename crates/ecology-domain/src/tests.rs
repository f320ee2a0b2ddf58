//! Tests of the domain language, from source text to the model or to rendered diagnostics.

use expect_test::{Expect, expect};
use proptest::prelude::*;

use crate::{Literal, Term, parse_domain, parse_facts, parse_goal, parse_problem, render};

const PEIS_HOME: &str = include_str!("../../../domains/peis-home.eco");
const PEIS_HOME_FACTS: &str = include_str!("../../../domains/peis-home.facts");
const FRIDGE: &str = include_str!("../../../domains/fridge.eco");
const FRIDGE_FACTS: &str = include_str!("../../../domains/fridge.facts");

/// Parses `src` as a domain and compares the rendered diagnostics with `expected`.
fn check(src: &str, expected: Expect) {
    let actual = match parse_domain(src.as_bytes()) {
        Ok(_) => "ok".to_string(),
        Err(diags) => diags.render("test.eco", src.as_bytes()),
    };
    expected.assert_eq(&actual);
}

/// The messages of every diagnostic for `src`, in order.
fn messages(src: &[u8]) -> Vec<String> {
    match parse_domain(src) {
        Ok(_) => Vec::new(),
        Err(diags) => diags.0.into_iter().map(|d| d.message).collect(),
    }
}

fn assert_error(src: &str, fragment: &str) {
    let all = messages(src.as_bytes());
    assert!(
        all.iter().any(|m| m.contains(fragment)),
        "expected an error containing {fragment:?}, got {all:#?}"
    );
}

/// A minimal valid domain to which each test adds one mistake.
const BASE: &str = r#"(define (domain d)
  (:functionality cam :parameters (?p ?c) :component (?p ?c)
    :precondition (pc ?p cam ?c) :output ((image ?p)) :cost 5)
  (:functionality tracker :parameters (?p ?t ?o) :component (?p ?t)
    :precondition (pc ?p tr ?t) :input ((image ?p)) :output ((pos ?o)) :cost 5)
  (:task locate :parameters (?r) :output ((pos ?r)))
  (:method by-cam :parameters (?r ?p ?c ?t) :task (locate ?r)
    :precondition (and (pc ?p cam ?c) (pc ?p tr ?t))
    :subtasks ((f1 (cam ?p ?c)) (f2 (tracker ?p ?t ?r)))
    :channels ((f1 f2 (image ?p)))
    :outputs (((pos ?r) f2)))
"#;

fn with(extra: &str) -> String {
    format!("{BASE}{extra})")
}

#[test]
fn reference_domains_parse() {
    let home = parse_domain(PEIS_HOME.as_bytes()).expect("peis-home.eco is valid");
    assert_eq!(home.name.as_ref(), "peis-home");
    assert_eq!(home.methods_of("get-position").count(), 2);
    assert_eq!(home.methods_of("get-global-position").count(), 2);
    let tracking = home.functionality("tracking-system").expect("declared");
    assert_eq!(tracking.inputs[0].hz, Some(15.0));
    assert_eq!(tracking.component, ("p".into(), "t".into()));
    let method = home
        .methods_of("get-global-position")
        .next()
        .expect("a method");
    assert!(
        matches!(&method.precondition[4], Literal::Neq(Term::Var(a), Term::Var(b), _) if &**a == "r" && &**b == "p")
    );
    let mv = home.action("move").expect("declared");
    assert_eq!(
        mv.configure.as_ref().map(ToString::to_string).as_deref(),
        Some("(navigate ?r ?to)")
    );
    assert_eq!(mv.params[0].ty.as_deref(), Some("robot"));

    let state = parse_facts(PEIS_HOME_FACTS.as_bytes()).expect("peis-home.facts is valid");
    let laser = state.component_cost("astrid", "l1").expect("a cost fact");
    assert_eq!((laser.amount, laser.power), (100, crate::Power::Off));

    parse_domain(FRIDGE.as_bytes()).expect("fridge.eco is valid");
    parse_facts(FRIDGE_FACTS.as_bytes()).expect("fridge.facts is valid");
}

#[test]
fn base_is_valid() {
    check(&with(""), expect!["ok"]);
}

#[test]
fn every_error_is_reported_at_once_with_line_and_column() {
    let src = r#"(define (domain bad)
  (:functionality cam :parameters (?p ?c) :component (?p ?x)
    :precondition (pc ?p cam) :output ((image ?p)) :cost 12x)
  (:task t :parameters (?r))
  (:task t :parameters (?r))
  (:method m :parameters (?r ?q) :task (t ?r)
    :subtasks ((f1 (cam ?r ?q ?q)) (f2 (nothing ?r)) (f3 (t ?r)))
    :channels ((f1 f9 (image ?r)) (f1 f3 (sound ?r))))
  (:method m2 :parameters (?r) :task (u ?r)))
"#;
    check(
        src,
        expect![[r#"
            error: `:component` names `?x`, which is not a parameter of functionality `cam`
              ┌─ test.eco:2:19
              │
            2 │   (:functionality cam :parameters (?p ?c) :component (?p ?x)
              │                   ^^^
              │
              = `:component (?p ?c)` names the parameters bound to the PEIS and its component

            error: wrong arity: `pc` takes 3 arguments, given 2
              ┌─ test.eco:3:19
              │
            3 │     :precondition (pc ?p cam) :output ((image ?p)) :cost 12x)
              │                   ^^^^^^^^^^^

            error: malformed number `12x`
              ┌─ test.eco:3:58
              │
            3 │     :precondition (pc ?p cam) :output ((image ?p)) :cost 12x)
              │                                                          ^^^
              │
              = numbers are digits with an optional sign and fraction, like 25 or 12.5

            error: duplicate name `t`
              ┌─ test.eco:5:10
              │
            4 │   (:task t :parameters (?r))
              │          - first defined here
            5 │   (:task t :parameters (?r))
              │          ^

            error: variable `?q` is bound neither by the task `(t ?r)` nor by a precondition
              ┌─ test.eco:7:20
              │
            7 │     :subtasks ((f1 (cam ?r ?q ?q)) (f2 (nothing ?r)) (f3 (t ?r)))
              │                    ^^^^^^^^^^^^^^
              │
              = a positive precondition such as `(pc ?p TYPE ?q)` binds it

            error: wrong arity: `cam` takes 2 arguments, given 3
              ┌─ test.eco:7:20
              │
            7 │     :subtasks ((f1 (cam ?r ?q ?q)) (f2 (nothing ?r)) (f3 (t ?r)))
              │                    ^^^^^^^^^^^^^^

            error: unknown task or functionality `nothing`
              ┌─ test.eco:7:40
              │
            7 │     :subtasks ((f1 (cam ?r ?q ?q)) (f2 (nothing ?r)) (f3 (t ?r)))
              │                                        ^^^^^^^^^^^^ no `(:task ...)` or `(:functionality ...)` has this name

            error: recursive decomposition: task `t` can reach itself through its methods
              ┌─ test.eco:7:58
              │
            7 │     :subtasks ((f1 (cam ?r ?q ?q)) (f2 (nothing ?r)) (f3 (t ?r)))
              │                                                          ^^^^^^
              │
              = t → m → t
              = a configuration is finite; break the cycle

            error: no subtask labelled `f9` in method `m`
              ┌─ test.eco:8:16
              │
            8 │     :channels ((f1 f9 (image ?r)) (f1 f3 (sound ?r))))
              │                ^^^^^^^^^^^^^^^^^^
              │
              = labels: f1 f2 f3

            error: `t` does not input (sound ?r)
              ┌─ test.eco:8:42
              │
            7 │     :subtasks ((f1 (cam ?r ?q ?q)) (f2 (nothing ?r)) (f3 (t ?r)))
              │                                                          ------ the inputting subtask
            8 │     :channels ((f1 f9 (image ?r)) (f1 f3 (sound ?r))))
              │                                          ^^^^^^^^^^

            error: method `m2` is for undeclared task `u`
              ┌─ test.eco:9:38
              │
            9 │   (:method m2 :parameters (?r) :task (u ?r)))
              │                                      ^^^^^^
              │
              = declare it with `(:task u :parameters (...))`

        "#]],
    );
}

#[test]
fn unbalanced_parentheses() {
    check(
        "(define (domain d)\n  (:task t :parameters (?r))",
        expect![[r#"
            error: unbalanced parentheses
              ┌─ test.eco:1:1
              │
            1 │ (define (domain d)
              │ ^ this `(` is never closed

        "#]],
    );
    assert_error(&format!("{})", with("")), "unbalanced parentheses");
}

#[test]
fn unknown_subtask() {
    assert_error(
        &with("(:method m :parameters (?r) :task (locate ?r) :subtasks ((a (fly ?r))))"),
        "unknown task or functionality `fly`",
    );
}

#[test]
fn wrong_arity() {
    assert_error(
        &with(
            "(:method m :parameters (?r ?p ?c) :task (locate ?r) :precondition (pc ?p cam ?c) :subtasks ((a (cam ?p))))",
        ),
        "wrong arity: `cam` takes 2 arguments, given 1",
    );
    assert_error(
        &with("(:method m :parameters (?r) :task (locate ?r ?r))"),
        "wrong arity: task `locate` takes 1 argument, given 2",
    );
    assert_error(
        &with("(:method m :parameters (?r ?p) :task (locate ?r) :precondition (peis ?p ?r))"),
        "wrong arity: `peis` takes 1 argument, given 2",
    );
}

#[test]
fn unbound_variables() {
    assert_error(
        &with("(:method m :parameters (?r ?p ?c) :task (locate ?r) :subtasks ((a (cam ?p ?c))))"),
        "variable `?p` is bound neither by the task `(locate ?r)` nor by a precondition",
    );
    assert_error(
        &with("(:method m :parameters (?r) :task (locate ?r) :precondition (pc ?p cam ?c))"),
        "variable `?p` is not a parameter of method `m`",
    );
    assert_error(
        &with(
            "(:functionality f :parameters (?p ?c) :component (?p ?c) :precondition (pc ?p ?t ?c))",
        ),
        "variable `?t` is not a parameter of functionality `f`",
    );
}

#[test]
fn channels_must_connect_matching_information() {
    let method = |channel: &str| {
        with(&format!(
            "(:method m :parameters (?r ?p ?c ?t) :task (locate ?r)
               :precondition (and (pc ?p cam ?c) (pc ?p tr ?t))
               :subtasks ((f1 (cam ?p ?c)) (f2 (tracker ?p ?t ?r)))
               :channels ({channel}) :outputs (((pos ?r) f2)))"
        ))
    };
    check(&method("(f1 f2 (image ?p))"), expect!["ok"]);
    assert_error(
        &method("(f1 f7 (image ?p))"),
        "no subtask labelled `f7` in method `m`",
    );
    assert_error(
        &method("(f1 f2 (sound ?p))"),
        "`cam` does not output (sound ?p)",
    );
    assert_error(&method("(f2 f1 (pos ?r))"), "`cam` does not input (pos ?r)");
    assert_error(
        &method("(f1 f2 (image ?p ?p))"),
        "`cam` does not output (image ?p ?p)",
    );
    assert_error(
        &method("(f1 f1 (image ?p))"),
        "a channel from a subtask to itself",
    );
}

#[test]
fn declared_task_outputs_must_be_provided() {
    assert_error(
        &with(
            "(:method m :parameters (?r ?p ?c) :task (locate ?r) :precondition (pc ?p cam ?c) :subtasks ((f1 (cam ?p ?c))))",
        ),
        "method `m` does not say which subtask handles output (pos ?r) of task `locate`",
    );
}

#[test]
fn duplicate_names() {
    assert_error(
        &with("(:task locate :parameters (?x))"),
        "duplicate name `locate`",
    );
    assert_error(
        &with("(:task cam :parameters (?x))"),
        "duplicate name `cam`",
    );
    assert_error(
        &with("(:method by-cam :parameters (?r) :task (locate ?r) :outputs (((pos ?r) x)))"),
        "duplicate method `by-cam`",
    );
    assert_error(
        &with("(:task u :parameters (?x ?x))"),
        "duplicate parameter `x` in task `u`",
    );
    assert_error(
        &with(
            "(:method m :parameters (?r) :task (locate ?r) :subtasks ((a (locate ?r)) (a (locate ?r))))",
        ),
        "duplicate label `a` in method `m`",
    );
}

#[test]
fn method_for_an_undeclared_task() {
    assert_error(
        &with("(:method m :parameters (?r) :task (fly ?r))"),
        "method `m` is for undeclared task `fly`",
    );
}

#[test]
fn component_must_name_parameters() {
    assert_error(
        &with("(:functionality f :parameters (?p) :component (?p ?c))"),
        "`:component` names `?c`, which is not a parameter of functionality `f`",
    );
    assert_error(
        &with("(:functionality f :parameters (?p ?c))"),
        "functionality `f` has no `:component`",
    );
}

#[test]
fn recursion_through_methods_is_found_at_load_time() {
    let src = with(
        "(:task a :parameters (?r)) (:task b :parameters (?r))
         (:method a1 :parameters (?r) :task (a ?r) :subtasks ((x (b ?r))))
         (:method b1 :parameters (?r) :task (b ?r) :subtasks ((y (a ?r))))",
    );
    assert_error(
        &src,
        "recursive decomposition: task `a` can reach itself through its methods",
    );
    let diags = parse_domain(src.as_bytes()).expect_err("recursive");
    assert!(
        diags
            .0
            .iter()
            .any(|d| d.notes.iter().any(|n| n == "a → a1 → b → b1 → a"))
    );
}

#[test]
fn malformed_numbers() {
    assert_error(
        &with("(:functionality f :parameters (?p ?c) :component (?p ?c) :cost 1.2.3)"),
        "malformed number `1.2.3`",
    );
    assert_error(
        &with("(:functionality f :parameters (?p ?c) :component (?p ?c) :cost -4)"),
        "a cost must be a non-negative integer",
    );
    assert_error(
        &with("(:functionality f :parameters (?p ?c) :component (?p ?c) :output ((x ?p :hz 0)))"),
        "a rate must be a positive number of hertz",
    );
    let facts = parse_facts(b"(cost astrid l1 1o0 on) (cost astrid l2 5 maybe)").expect_err("bad");
    let text: Vec<&str> = facts.0.iter().map(|d| d.message.as_str()).collect();
    assert_eq!(
        text,
        [
            "malformed number `1o0`",
            "component state `maybe` is neither `on` nor `off`"
        ]
    );
}

#[test]
fn nesting_deeper_than_64() {
    let deep = format!("(define (domain d) {}{})", "(".repeat(70), ")".repeat(70));
    assert_error(&deep, "nesting deeper than 64 levels");
    // Far deeper nesting is reported the same way, without exhausting the stack.
    let hostile = "(".repeat(1_000_000);
    let all = messages(hostile.as_bytes());
    assert!(all.iter().any(|m| m == "nesting deeper than 64 levels"));
}

#[test]
fn invalid_utf8() {
    let mut src = b"(define (domain d)\n  (:task t\xff\xfe :parameters (?r)))".to_vec();
    let diags = parse_domain(&src).expect_err("invalid");
    expect![[r#"
        error: invalid UTF-8 in source file
          ┌─ test.eco:2:11
          │
        2 │   (:task t�� :parameters (?r)))
          │           ^ this byte sequence is not UTF-8

    "#]]
    .assert_eq(&render("test.eco", &src, &diags.0));
    src.truncate(5);
    src.push(0xc3);
    assert_eq!(messages(&src), ["invalid UTF-8 in source file"]);
}

#[test]
fn files_over_8_mib() {
    let big = vec![b' '; 8 * 1024 * 1024 + 1];
    assert_eq!(
        messages(&big),
        ["file is 8388609 bytes, larger than the limit of 8388608 bytes (8 MiB)"]
    );
}

#[test]
fn unsupported_pddl_is_named() {
    assert_error(
        "(define (domain d) (:requirements :strips :fluents))",
        "requirement `:fluents` is not supported",
    );
    // `:adl` is a declaration; what it allows is refused where it appears.
    assert_error(
        "(define (domain d) (:requirements :adl) (:predicates (p ?x) (q ?x))
           (:action a :parameters (?x) :precondition (exists (?y) (p ?y)) :effect (p ?x)))",
        "`exists` is not supported in conditions",
    );
    assert_error(
        "(define (domain d) (:action a :parameters (?x) :precondition (forall (?y) (p ?y))))",
        "`forall` is not supported in conditions",
    );
}

/// Writes an action's precondition as the parser read it: the shared literals, then each
/// disjunct of the rest.
fn precondition_of(src: &str) -> String {
    let domain = parse_domain(src.as_bytes()).expect("valid domain");
    let action = &domain.actions[0];
    let conjunction = |literals: &[Literal]| {
        literals
            .iter()
            .map(ToString::to_string)
            .collect::<Vec<_>>()
            .join(" ")
    };
    let mut out = conjunction(&action.precondition);
    for disjunct in &action.alternatives {
        out.push_str(&format!("\n| {}", conjunction(disjunct)));
    }
    out
}

fn action_with_precondition(precondition: &str) -> String {
    format!(
        "(define (domain d) (:requirements :adl)
           (:predicates (p ?x) (q ?x) (r ?x) (s ?x))
           (:action a :parameters (?x ?y) :precondition {precondition} :effect (p ?x)))"
    )
}

#[test]
fn disjunctive_preconditions_are_read_in_normal_form() {
    let read = |precondition: &str| precondition_of(&action_with_precondition(precondition));
    // A conjunction stays one.
    assert_eq!(read("(and (p ?x) (not (q ?x)))"), "(p ?x) (not (q ?x))");
    // Literals every disjunct shares are taken out of the disjunction.
    assert_eq!(
        read("(and (p ?x) (or (q ?x) (and (r ?x) (= ?x ?y))))"),
        "(p ?x)\n| (q ?x)\n| (r ?x) (= ?x ?y)"
    );
    // Conjunctions of disjunctions multiply out.
    assert_eq!(
        read("(and (or (p ?x) (q ?x)) (or (r ?x) (s ?x)))"),
        "\n| (p ?x) (r ?x)\n| (p ?x) (s ?x)\n| (q ?x) (r ?x)\n| (q ?x) (s ?x)"
    );
    // Negation is pushed onto atoms and equalities; `imply` is `or (not premise) conclusion`.
    assert_eq!(
        read("(not (or (p ?x) (= ?x ?y)))"),
        "(not (p ?x)) (not (= ?x ?y))"
    );
    assert_eq!(
        read("(not (and (p ?x) (not (q ?y))))"),
        "\n| (not (p ?x))\n| (q ?y)"
    );
    assert_eq!(read("(imply (p ?x) (q ?x))"), "\n| (not (p ?x))\n| (q ?x)");
    assert_eq!(read("(not (imply (p ?x) (q ?x)))"), "(p ?x) (not (q ?x))");
    // A disjunct that needs nothing more makes the disjunction always true.
    assert_eq!(read("(and (p ?x) (or (p ?x) (q ?x)))"), "(p ?x)");
    assert_eq!(read("(or (p ?x))"), "(p ?x)");
    // Variables in disjuncts are checked like any other.
    assert_error(
        &action_with_precondition("(or (p ?x) (q ?z))"),
        "`?z` is not a parameter of action `a`",
    );
    assert_error(
        &action_with_precondition("(or (p ?x) (q ?x ?y))"),
        "wrong arity: `q` takes 1 argument, given 2",
    );
}

#[test]
fn disjunctions_are_bounded_and_only_in_action_preconditions() {
    // Seven binary `or`s in a conjunction are 128 disjuncts, more than the limit of 64.
    let many = format!("(and {})", "(or (p ?x) (q ?y)) ".repeat(7));
    let src = action_with_precondition(&many);
    assert_eq!(
        messages(src.as_bytes()),
        ["this condition has more than 64 disjuncts in disjunctive normal form"]
    );
    // Six are 64: at the limit, read.
    let six = format!("(and {})", "(or (p ?x) (q ?y)) ".repeat(6));
    let domain = parse_domain(action_with_precondition(&six).as_bytes()).expect("64 disjuncts");
    assert_eq!(domain.actions[0].alternatives.len(), 64);
    assert_error(
        &action_with_precondition("(or)"),
        "an empty disjunction can never hold",
    );
    assert_error(
        &action_with_precondition("(imply (p ?x))"),
        "`imply` takes exactly two conditions",
    );
    // Elsewhere conditions are conjunctions; negation is still pushed inward.
    let goal = |goal: &str| {
        parse_problem(format!("(define (problem p) (:domain d) (:goal {goal}))").as_bytes())
            .map(|p| p.goal.iter().map(ToString::to_string).collect::<Vec<_>>())
            .map_err(|d| d.0.into_iter().map(|d| d.message).collect::<Vec<_>>())
    };
    assert_eq!(
        goal("(or (p a) (q a))"),
        Err(vec![
            "`or` is not supported here: it makes a disjunction".to_string()
        ])
    );
    assert_eq!(
        goal("(not (and (p a) (q a)))"),
        Err(vec![
            "`and` under `not` is not supported here: it makes a disjunction".to_string()
        ])
    );
    assert_eq!(
        goal("(not (or (p a) (q a)))"),
        Ok(vec!["(not (p a))".to_string(), "(not (q a))".to_string()])
    );
    assert_error(
        &with(
            "(:functionality f :parameters (?p ?c) :component (?p ?c)
               :precondition (or (pc ?p cam ?c) (pc ?p tr ?c)) :cost 1)",
        ),
        "`or` is not supported here: it makes a disjunction",
    );
}

#[test]
fn problems_and_goals() {
    let problem = parse_problem(
        b"(define (problem wake) (:domain peis-home)
           (:objects astrid - robot bedroom entrance - room)
           (:init (at astrid entrance) (= (distance entrance bedroom) 4))
           (:goal (and (at astrid bedroom) (not (at astrid entrance))))
           (:metric minimize (total-cost)))",
    )
    .expect("valid problem");
    assert_eq!(problem.objects.len(), 3);
    assert_eq!(problem.objects[2].ty.as_deref(), Some("room"));
    assert_eq!(problem.numeric_init[0].1, 4);
    assert_eq!(problem.goal.len(), 2);
    assert!(parse_problem(b"(define (problem p) (:init (at ?x)))").is_err());
    assert_eq!(
        parse_goal("(navigate astrid bedroom)")
            .expect("ground")
            .to_string(),
        "(navigate astrid bedroom)"
    );
    assert!(parse_goal("(navigate ?r bedroom)").is_err());
    assert!(parse_goal("(a) (b)").is_err());
}

#[test]
fn facts_must_be_ground_and_well_formed() {
    let diags = parse_facts(b"(peis ?x) (pc astrid laser) (peis astrid)").expect_err("bad");
    let text: Vec<&str> = diags.0.iter().map(|d| d.message.as_str()).collect();
    assert_eq!(
        text,
        [
            "facts are ground, but `?x` is a variable",
            "wrong arity: `pc` takes 3 arguments, given 2"
        ]
    );
}

/// Mutates `src` at byte positions chosen by `edits`.
fn mutate(src: &[u8], edits: &[(usize, u8, u8)]) -> Vec<u8> {
    let mut out = src.to_vec();
    for &(at, kind, byte) in edits {
        if out.is_empty() {
            out.push(byte);
            continue;
        }
        let at = at % out.len();
        match kind % 4 {
            0 => out[at] = byte,
            1 => {
                out.remove(at);
            }
            2 => out.insert(at, byte),
            _ => out.insert(at, b"()?:;-\n"[byte as usize % 7]),
        }
    }
    out
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 3000, failure_persistence: None, ..ProptestConfig::default() })]

    /// The parser never panics on random bytes.
    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        let _ = parse_domain(&bytes);
        let _ = parse_facts(&bytes);
        let _ = parse_problem(&bytes);
        if let Err(diags) = parse_domain(&bytes) {
            prop_assert!(!diags.0.is_empty());
            let _ = render("fuzz.eco", &bytes, &diags.0);
        }
    }

    /// Nor on random mutations of the reference domain; and every error it
    /// reports renders with a position inside the file.
    #[test]
    fn mutations_of_the_reference_domain_never_panic(
        edits in proptest::collection::vec((any::<usize>(), any::<u8>(), any::<u8>()), 1..8)
    ) {
        let src = mutate(PEIS_HOME.as_bytes(), &edits);
        if let Err(diags) = parse_domain(&src) {
            prop_assert!(!diags.0.is_empty());
            for d in &diags.0 {
                prop_assert!(d.span.start <= src.len() && d.span.end <= src.len() + 1);
            }
            let text = render("peis-home.eco", &src, &diags.0);
            prop_assert!(text.contains("peis-home.eco:"));
        }
        let facts = mutate(PEIS_HOME_FACTS.as_bytes(), &edits);
        let _ = parse_facts(&facts);
    }

    /// The fast path of `.facts` reads a file exactly as the general reader does: the same
    /// facts in the same order, or the same diagnostics (it hands over what it does not read).
    /// Most pieces are those of good facts, so that both paths are taken.
    #[test]
    fn facts_read_fast_are_those_the_general_reader_reads(
        pieces in proptest::collection::vec(
            prop_oneof![
                30 => proptest::sample::select(GOOD_FACT_PIECES),
                1 => proptest::sample::select(BAD_FACT_PIECES),
            ],
            0..60,
        )
    ) {
        let text: String = pieces.concat();
        let fast = parse_facts(text.as_bytes());
        let general = crate::facts_in_general(&text, &mut || false).map(|read| read.state);
        prop_assert_eq!(fast, general, "{}", text);
    }
}

/// Pieces of good `.facts` files, for the fast path's property.
const GOOD_FACT_PIECES: &[&str] = &[
    "(peis Astrid)",
    "(peis astrid)",
    "(pc astrid laser l1)",
    "(cost astrid l1 10 on)",
    "(cost astrid l1 10 off)",
    "(channel-cost astrid hsm 5)",
    "(status astrid l1 running)",
    "(at Astrid Kitchen -3 1.5)",
    " ",
    "\n",
    "\t",
    "; a note\n",
    "(peis\n hsm) ",
];

/// Pieces that only the general reader reads or reports.
const BAD_FACT_PIECES: &[&str] = &[
    "(",
    ")",
    "()",
    "(peis ?x)",
    "(peis :k)",
    "(1 a)",
    "(cost astrid l1 x on)",
    "(cost astrid l1 10 dim)",
    "(pc a b)",
    "(peis 1.2.3)",
    "(peis é)",
    "(peis \u{1})",
    "(peis (nested))",
    "word",
];

/// Checks `problem` against the PEIS-Home domain and compares the rendered
/// diagnostics with `expected`.
fn check_against_home(problem: &str, expected: Expect) {
    let home = parse_domain(PEIS_HOME.as_bytes()).expect("peis-home.eco is valid");
    let actual = match crate::parse_problem_for(&home, problem.as_bytes()) {
        Ok(_) => "ok".to_string(),
        Err(diags) => diags.render("test.problem", problem.as_bytes()),
    };
    expected.assert_eq(&actual);
}

#[test]
fn problems_are_checked_against_their_domain() {
    check_against_home(
        include_str!("../../../domains/peis-home-task.problem"),
        expect!["ok"],
    );
    check_against_home(
        r#"(define (problem p) (:domain peis-home)
  (:objects astrid - robot hall - corridor kitchen - room astrid - robot)
  (:init (at astrid kitchen) (at kitchen astrid) (at astrid) (flying astrid) (at astrid nowhere))
  (:goal (and (awake ?h) (= astrid ghost))))
"#,
        expect![[r#"
            error: unknown type `corridor`
              ┌─ test.problem:2:28
              │
            2 │   (:objects astrid - robot hall - corridor kitchen - room astrid - robot)
              │                            ^^^^
              │
              = declare it in the domain's `(:types ...)`

            error: duplicate object `astrid`
              ┌─ test.problem:2:59
              │
            2 │   (:objects astrid - robot hall - corridor kitchen - room astrid - robot)
              │             ------                                        ^^^^^^
              │             │                                              
              │             first declared here

            error: `kitchen` is a `room`, but `at` expects a `robot` there
              ┌─ test.problem:3:30
              │
            3 │   (:init (at astrid kitchen) (at kitchen astrid) (at astrid) (flying astrid) (at astrid nowhere))
              │                              ^^^^^^^^^^^^^^^^^^^
              │
              = the domain declares (at ?r - robot ?x - room)

            error: `astrid` is a `robot`, but `at` expects a `room` there
              ┌─ test.problem:3:30
              │
            3 │   (:init (at astrid kitchen) (at kitchen astrid) (at astrid) (flying astrid) (at astrid nowhere))
              │                              ^^^^^^^^^^^^^^^^^^^
              │
              = the domain declares (at ?r - robot ?x - room)

            error: wrong arity: `at` takes 2 arguments, given 1
              ┌─ test.problem:3:50
              │
            3 │   (:init (at astrid kitchen) (at kitchen astrid) (at astrid) (flying astrid) (at astrid nowhere))
              │                                                  ^^^^^^^^^^^

            error: unknown predicate `flying`
              ┌─ test.problem:3:62
              │
            3 │   (:init (at astrid kitchen) (at kitchen astrid) (at astrid) (flying astrid) (at astrid nowhere))
              │                                                              ^^^^^^^^^^^^^^^
              │
              = declare it in the domain's `(:predicates ...)`

            error: unknown object `nowhere`
              ┌─ test.problem:3:78
              │
            3 │   (:init (at astrid kitchen) (at kitchen astrid) (at astrid) (flying astrid) (at astrid nowhere))
              │                                                                              ^^^^^^^^^^^^^^^^^^^
              │
              = declare it in `(:objects ...)`

            error: problems are ground, but `?h` is a variable
              ┌─ test.problem:4:15
              │
            4 │   (:goal (and (awake ?h) (= astrid ghost))))
              │               ^^^^^^^^^^

            error: unknown object `ghost`
              ┌─ test.problem:4:26
              │
            4 │   (:goal (and (awake ?h) (= astrid ghost))))
              │                          ^^^^^^^^^^^^^^^^
              │
              = declare it in `(:objects ...)`

        "#]],
    );
    let home = parse_domain(PEIS_HOME.as_bytes()).expect("valid");
    let wrong_domain =
        parse_problem(b"(define (problem p) (:domain fridge) (:goal (and)))").expect("parses");
    let diags = crate::check_problem(&home, &wrong_domain).expect_err("wrong domain");
    assert_eq!(
        diags.0[0].message,
        "the problem is for domain `fridge`, but the domain is `peis-home`"
    );
}

#[test]
fn control_characters_are_refused_in_names() {
    let err = parse_facts(b"(peis ast\0rid)").expect_err("a NUL in a name");
    assert_eq!(err.0.len(), 1);
    assert_eq!(err.0[0].message, "control character U+0000 in a name");
    assert_eq!((err.0[0].span.start, err.0[0].span.end), (9, 10));
    let err = parse_goal("(navigate astrid bed\u{7}room)").expect_err("a bell in a name");
    assert!(
        err.0
            .iter()
            .any(|d| d.message == "control character U+0007 in a name")
    );
}

#[test]
fn rendered_diagnostics_stay_proportional_to_their_number() {
    // 8 MiB of `(` on one line: 65 errors, each used to repeat the whole line.
    let parens = "(".repeat(crate::syntax::MAX_FILE_BYTES - 16);
    let err = parse_domain(parens.as_bytes()).expect_err("unbalanced");
    let text = render("parens.eco", parens.as_bytes(), &err.0);
    assert!(err.0.len() > 60, "{}", err.0.len());
    assert!(text.len() < 300 * err.0.len(), "{} bytes", text.len());
    assert!(
        text.contains("parens.eco:1:"),
        "{}",
        &text[..text.len().min(500)]
    );
    // 30,000 errors on one line: the first hundred shown, the rest counted.
    let line = vec!["(define)"; 30_000].join(" ");
    let err = parse_domain(line.as_bytes()).expect_err("malformed");
    let text = render("line.eco", line.as_bytes(), &err.0);
    assert_eq!(err.0.len(), 30_000);
    assert!(text.len() < 40_000, "{} bytes", text.len());
    assert!(
        text.ends_with("… and 29900 more errors, not shown\n"),
        "{}",
        &text[text.len() - 200..]
    );
    assert!(
        text.contains("line.eco:1:10"),
        "the second error's column is exact"
    );
}

// Found by the fuzz harness: a 40 KB method name, quoted in every message
// about the method, took 85 MB for a 44 KB file.
#[test]
fn messages_quote_long_names_briefly() {
    let name = "m".repeat(40_000);
    let src = format!(
        "(define (domain d) (:method {name} {}))",
        "x ".repeat(2_000)
    );
    let err = parse_domain(src.as_bytes()).expect_err("no keywords");
    assert!(err.0.len() >= 1_000, "{} diagnostics", err.0.len());
    assert!(err.0.iter().any(|d| d.message.contains("mmmm")));
    let kept: usize = err.0.iter().map(|d| d.message.len()).sum();
    // Without the cap: 2,000 messages of 40 KB each.
    assert!(
        kept < 2 * crate::diagnostic::MAX_MESSAGE * err.0.len(),
        "{kept} bytes of messages"
    );
}

#[test]
fn reading_facts_stops_when_asked_and_otherwise_reads_them_all() {
    let text: String = (0..5000)
        .map(|i| format!("(pc robot{i} camera c{i}) (cost robot{i} c{i} {i} on)\n"))
        .collect();
    let whole = crate::parse_facts(text.as_bytes()).expect("valid facts");
    let never = crate::parse_facts_until(text.as_bytes(), &mut || false).expect("valid facts");
    assert!(never.complete);
    assert_eq!(never.state, whole);
    // Asked often enough to stop during reading, after reading, or while parsing facts.
    for allowed in [0, 1, 5, 11, 13] {
        let mut asked = 0;
        let stopped = crate::parse_facts_until(text.as_bytes(), &mut || {
            asked += 1;
            asked > allowed
        })
        .expect("valid facts");
        assert!(!stopped.complete, "not stopped after {allowed} checks");
        assert!(stopped.state.len() < whole.len());
        assert_eq!(asked, allowed + 1, "went on after being told to stop");
    }
}

#[test]
fn information_formats_are_read_and_check_values() {
    let src = with(
        "(:information pos :format ((x number) (y number) (theta number)))
         (:information image :format (records (name name) (x number) (y number)))",
    );
    let domain = parse_domain(src.as_bytes()).expect("valid");
    let formats: Vec<(String, String)> = domain
        .information
        .iter()
        .map(|i| (i.name.to_string(), i.format.to_string()))
        .collect();
    assert_eq!(
        formats,
        [
            ("pos".to_string(), "X Y THETA".to_string()),
            ("image".to_string(), "NAME X Y; …".to_string())
        ]
    );
    let pos = &domain.information[0].format;
    assert_eq!(pos.check(" 1.5 -2 0.25 "), Ok(()));
    assert_eq!(
        pos.check("1,2;3"),
        Err("expected X Y THETA, found \"1,2;3\"".to_string())
    );
    assert!(pos.check("1 2").is_err());
    assert!(pos.check("1 2 3 4").is_err());
    assert!(pos.check("1 2 inf").is_err());
    let image = &domain.information[1].format;
    assert_eq!(image.check("astrid 1 2; pippi 3 4"), Ok(()));
    assert_eq!(image.check(""), Ok(()), "no records: nothing in view");
    assert!(image.check("astrid 1 2; pippi 3").is_err());
}

#[test]
fn many_text_and_one_of_fields() {
    let src = with(
        "(:information image :format ((ranges number :many)))
         (:information pos :format ((state (one-of awake asleep)) (note text)))",
    );
    let domain = parse_domain(src.as_bytes()).expect("valid");
    let ranges = &domain.information[0].format;
    assert_eq!(ranges.to_string(), "RANGES…");
    assert_eq!(ranges.check("1.0 2.5 3"), Ok(()));
    assert!(ranges.check("").is_err(), "`:many` is one or more");
    assert!(ranges.check("1.0 x").is_err());
    let state = &domain.information[1].format;
    assert_eq!(state.to_string(), "STATE (awake|asleep) NOTE…");
    assert_eq!(state.check("awake since seven"), Ok(()));
    assert_eq!(state.check("asleep"), Ok(()));
    assert!(state.check("dozing").is_err());
}

#[test]
fn bad_information_declarations_are_reported() {
    assert_error(
        &with("(:information pos :format (x number))"),
        "expected a field like `(x number)`",
    );
    assert_error(
        &with("(:information pos :format ((x float)))"),
        "unknown field type `float`",
    );
    assert_error(
        &with("(:information pos :format ((x number :many) (y number)))"),
        "only the last field may have `:many`",
    );
    assert_error(
        &with("(:information pos :format ((x text) (y number)))"),
        "only the last field may have type `text`",
    );
    assert_error(
        &with("(:information pos :format ((x number) (x number)))"),
        "field `x` is named twice",
    );
    assert_error(
        &with("(:information pos :format ((x number) (x number :twice)))"),
        "after a field's type only `:many` may follow",
    );
    assert_error(
        &with("(:information pos :format ())"),
        "a format needs a field",
    );
    assert_error(
        &with("(:information pos)"),
        "information `pos` has no `:format`",
    );
    assert_error(
        &with("(:information depth :format ((d number)))"),
        "information `depth` is neither an input nor an output of any functionality",
    );
    assert_error(
        &with("(:information pos :format ((x number))) (:information pos :format ((y number)))"),
        "duplicate information `pos`",
    );
    assert_error(
        &with("(:information pos :format ((x number)) :hz 3)"),
        "`:hz`",
    );
}

#[test]
fn conditional_effects_are_read_with_their_variants() {
    let src = "(define (domain d) (:requirements :adl :action-costs)
       (:predicates (p ?x) (q ?x) (r ?x) (s ?x))
       (:action a :parameters (?x ?y)
         :precondition (or (p ?x) (p ?y))
         :effect (and (s ?x)
                      (when (and (q ?x) (not (= ?x ?y))) (and (r ?y) (not (q ?x))))
                      (when (r ?x) (increase (total-cost) 2)))))";
    let domain = parse_domain(src.as_bytes()).expect("valid");
    let action = &domain.actions[0];
    assert_eq!(action.effects.len(), 1);
    assert_eq!(action.conditional.len(), 2);
    assert_eq!(action.conditional[0].effects.len(), 2);
    // Two disjuncts, times three ways for the first condition (holds, or one of its two
    // literals fails), times two for the second.
    assert_eq!(action.variant_count(), 12);
    let variants: Vec<String> = action
        .variants()
        .iter()
        .map(|v| {
            let pre: Vec<String> = v.precondition.iter().map(ToString::to_string).collect();
            format!("{} => {:?}", pre.join(" "), v.conditional)
        })
        .collect();
    assert_eq!(variants.len(), 12);
    assert_eq!(
        variants[..6],
        [
            "(p ?x) (q ?x) (not (= ?x ?y)) (r ?x) => [0, 1]",
            "(p ?x) (q ?x) (not (= ?x ?y)) (not (r ?x)) => [0]",
            "(p ?x) (not (q ?x)) (r ?x) => [1]",
            "(p ?x) (not (q ?x)) (not (r ?x)) => []",
            "(p ?x) (= ?x ?y) (r ?x) => [1]",
            "(p ?x) (= ?x ?y) (not (r ?x)) => []",
        ]
    );
    // Variables and arities inside `when` are checked like any other.
    assert_error(
        &src.replace("(r ?y) (not", "(r ?z) (not"),
        "variable `?z` is not a parameter of action `a`",
    );
    assert_error(
        &src.replace("(when (r ?x)", "(when (r ?x ?y)"),
        "wrong arity: `r` takes 1 argument, given 2",
    );
}

#[test]
fn conditional_effects_are_bounded_and_do_not_nest() {
    let action = |effect: &str| {
        format!(
            "(define (domain d) (:requirements :adl :probabilistic-effects)
               (:predicates (p ?x) (q ?x))
               (:action a :parameters (?x) :precondition (p ?x) :effect {effect}))"
        )
    };
    assert_error(
        &action("(when (p ?x) (when (q ?x) (p ?x)))"),
        "`when` does not nest",
    );
    assert_error(
        &action("(when (p ?x) (probabilistic 0.5 (q ?x)))"),
        "`probabilistic` is not supported inside `when`",
    );
    assert_error(
        &action("(probabilistic 0.5 (when (p ?x) (q ?x)))"),
        "`when` is not supported inside `probabilistic`",
    );
    assert_error(
        &action("(when (p ?x))"),
        "`when` takes a condition and an effect",
    );
    assert_error(
        &action("(when (or (p ?x) (q ?x)) (q ?x))"),
        "`or` is not supported here: it makes a disjunction",
    );
    // Six one-literal conditions are 64 variants; seven are too many.
    let six = "(when (q ?x) (p ?x)) ".repeat(6);
    let domain = parse_domain(action(&format!("(and {six})")).as_bytes()).expect("64 variants");
    assert_eq!(domain.actions[0].variants().len(), 64);
    let seven = "(when (q ?x) (p ?x)) ".repeat(7);
    assert_eq!(
        messages(action(&format!("(and {seven})")).as_bytes()),
        [
            "action `a` has more than 64 variants: the disjuncts of its precondition times the \
          ways each `when` condition holds or fails"
        ]
    );
}
