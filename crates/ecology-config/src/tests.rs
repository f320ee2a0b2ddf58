//! Tests of the configuration planner, through its public face: a domain, a
//! state and a goal in, configurations or an explanation out.

use std::time::Duration;

use ecology_domain::{
    ComponentCost, EcologyState, Name, Power, parse_domain, parse_facts, parse_goal,
};
use expect_test::expect;
use proptest::prelude::*;

use crate::oracle::{self, Limit};
use crate::synthetic::{self, Shape};
use crate::{
    Budget, Clock, Configuration, CostModel, Exclusion, NoClock, Options, Outcome, PaperCost,
    Request, Snapshot, Status, plan, plan_observed, plan_with,
};

const PEIS_HOME: &str = include_str!("../../../domains/peis-home.eco");
const PEIS_HOME_FACTS: &str = include_str!("../../../domains/peis-home.facts");
const FRIDGE: &str = include_str!("../../../domains/fridge.eco");
const FRIDGE_FACTS: &str = include_str!("../../../domains/fridge.facts");

fn exclusions(list: &[&str]) -> Vec<Exclusion> {
    list.iter()
        .map(|e| e.parse().expect("valid exclusion"))
        .collect()
}

/// `f` of the request for `goal` in `facts` with `domain`, without `exclude`.
fn with_request<T>(
    domain: &str,
    facts: &str,
    goal: &str,
    exclude: &[&str],
    f: impl FnOnce(&Request<'_>) -> T,
) -> T {
    let domain = parse_domain(domain.as_bytes()).expect("domain parses");
    let state = parse_facts(facts.as_bytes()).expect("facts parse");
    let goal = parse_goal(goal).expect("goal parses");
    let exclusions = exclusions(exclude);
    f(&Request {
        domain: &domain,
        state: &state,
        goal: &goal,
        exclusions: &exclusions,
    })
}

fn run(domain: &str, facts: &str, goal: &str, exclude: &[&str], count: usize) -> Outcome {
    let options = Options {
        count,
        ..Options::default()
    };
    with_request(domain, facts, goal, exclude, |request| {
        plan(request, &options, &NoClock).expect("goal is valid")
    })
}

fn home(goal: &str, exclude: &[&str]) -> Outcome {
    run(PEIS_HOME, PEIS_HOME_FACTS, goal, exclude, 1)
}

fn components(config: &Configuration) -> Vec<String> {
    let mut out: Vec<String> = config
        .functionalities
        .iter()
        .map(|f| format!("{}:{}", f.peis, f.component))
        .collect();
    out.sort();
    out
}

/// The paper's Fig. 6, configuration 2: the ceiling cameras and the tracking system.
const CAMERAS_80: &str = "\
(ceiling-cameras hsm ca1) on hsm:ca1 (On) cost 20\n\
(navigation astrid tc1 bedroom) on astrid:tc1 (On) cost 20\n\
(pose-tracking astrid s1) on astrid:s1 (On) cost 20\n\
(tracking-system hsm tr1 astrid) on hsm:tr1 (On) cost 20\n\
astrid:s1 → astrid:tc1 (position astrid) cost 0\n\
hsm:ca1 → hsm:tr1 (image hsm) cost 0\n\
hsm:tr1 → astrid:s1 (global-pos astrid) cost 0\n\
total 80\n\
";

/// The paper's Fig. 6, configuration 3: Astrid's laser (off, started) and scan matching.
const LASER_170: &str = "\
(laser astrid l1) on astrid:l1 (Off) cost 120\n\
(navigation astrid tc1 bedroom) on astrid:tc1 (On) cost 20\n\
(odometry astrid od1) on astrid:od1 (On) cost 10\n\
(scan-matching astrid s1) on astrid:s1 (On) cost 20\n\
astrid:l1 → astrid:s1 (range-scan astrid) cost 0\n\
astrid:od1 → astrid:s1 (odometry astrid) cost 0\n\
astrid:s1 → astrid:tc1 (position astrid) cost 0\n\
total 170\n\
";

/// The paper's Fig. 6, configuration 4: Pippi's camera watches Astrid.
const PIPPI_190: &str = "\
(camera pippi ca2) on pippi:ca2 (On) cost 20\n\
(navigation astrid tc1 bedroom) on astrid:tc1 (On) cost 20\n\
(object-localizer pippi ol2 astrid) on pippi:ol2 (On) cost 130\n\
(pose-tracking astrid s1) on astrid:s1 (On) cost 20\n\
astrid:s1 → astrid:tc1 (position astrid) cost 0\n\
pippi:ca2 → pippi:ol2 (image pippi) cost 0\n\
pippi:ol2 → astrid:s1 (global-pos astrid) cost 0\n\
total 190\n\
";

/// What a configuration does, in a stable order: each functionality with its
/// component, power and cost, each channel with its ends and cost, and the
/// total, checked to be the sum of its parts (costs are additive).
fn shape(config: &Configuration) -> String {
    let mut functionalities: Vec<String> = config
        .functionalities
        .iter()
        .map(|f| {
            format!(
                "{} on {}:{} ({:?}) cost {}",
                f.call(),
                f.peis,
                f.component,
                f.power,
                f.cost
            )
        })
        .collect();
    functionalities.sort();
    let mut channels: Vec<String> = config
        .channels
        .iter()
        .map(|c| {
            format!(
                "{}:{} → {}:{} {} cost {}",
                c.from_peis, c.from_component, c.to_peis, c.to_component, c.info, c.cost
            )
        })
        .collect();
    channels.sort();
    let parts: u64 = config.functionalities.iter().map(|f| f.cost).sum::<u64>()
        + config.channels.iter().map(|c| c.cost).sum::<u64>();
    assert_eq!(config.cost, parts, "{config}");
    let mut lines = functionalities;
    lines.extend(channels);
    lines.push(format!("total {}\n", config.cost));
    lines.join("\n")
}

/// The explanation of `outcome`, which must say `why`.
#[track_caller]
fn explained(outcome: Outcome, why: &str) -> String {
    let text = outcome.explanation.expect("explained").to_string();
    assert!(text.contains(why), "{why:?} not in {text}");
    text
}

/// The shapes of every configuration of `outcome`, cheapest first.
fn shapes(outcome: &Outcome) -> String {
    outcome
        .configurations
        .iter()
        .map(shape)
        .collect::<Vec<_>>()
        .join("--\n")
}

// The paper, Section VIII step 3: the ceiling cameras win at 80.
#[test]
fn navigate_uses_the_ceiling_cameras_at_80() {
    let outcome = home("(navigate astrid bedroom)", &[]);
    assert_eq!(outcome.status, Status::Proven);
    let best = &outcome.configurations[0];
    assert_eq!(best.cost, 80);
    assert!(best.optimal);
    assert_eq!(
        components(best),
        ["astrid:s1", "astrid:tc1", "hsm:ca1", "hsm:tr1"]
    );
    let remote: Vec<&str> = best
        .channels
        .iter()
        .filter(|c| c.remote)
        .map(|c| &*c.info)
        .collect();
    assert_eq!(remote, ["(global-pos astrid)"]);
    expect![[r#"
          f1        (navigation astrid tc1 bedroom)      astrid:tc1 (on)  cost 20
          f0/f2     (pose-tracking astrid s1)            astrid:s1 (on)  cost 20
          f0/f1/f1  (ceiling-cameras hsm ca1)            hsm:ca1 (on)  cost 20
          f0/f1/f2  (tracking-system hsm tr1 astrid)     hsm:tr1 (on)  cost 20
          channels:
            f0/f2 → f1  (position astrid)  (local on astrid)
            f0/f1/f2 → f0/f2  (global-pos astrid)  (remote hsm → astrid)
            f0/f1/f1 → f0/f1/f2  (image hsm)  (local on hsm)
          total cost 80 (proven optimal)"#]]
    .assert_eq(&best.to_string());
}

// The paper, Fig. 6: exactly three ways to navigate, at 80, 170 and 190.
#[test]
fn all_lists_the_three_position_sources_cheapest_first() {
    let outcome = run(
        PEIS_HOME,
        PEIS_HOME_FACTS,
        "(navigate astrid bedroom)",
        &[],
        usize::MAX,
    );
    let costs: Vec<u64> = outcome.configurations.iter().map(|c| c.cost).collect();
    assert_eq!(costs, [80, 170, 190]);
    assert!(outcome.configurations.iter().all(|c| c.optimal));
    // The cameras, the laser with scan matching, Pippi watching Astrid.
    assert_eq!(
        shapes(&outcome),
        [CAMERAS_80, LASER_170, PIPPI_190].join("--\n")
    );
}

// The paper, Section VIII step 6: without the tracking system, the laser (off, started) at 170.
#[test]
fn excluding_the_tracking_system_switches_the_laser_on() {
    let outcome = home("(navigate astrid bedroom)", &["hsm:tr1"]);
    let best = &outcome.configurations[0];
    assert_eq!(best.cost, 170);
    let laser = best
        .functionalities
        .iter()
        .find(|f| &*f.component == "l1")
        .expect("uses the laser");
    assert_eq!(laser.power, Power::Off);
    assert_eq!(laser.cost, 120, "start-up 100 plus default 20");
    assert!(!best.uses("hsm", "tr1"));
    assert_eq!(shape(best), LASER_170);

    let outcome = home("(navigate astrid bedroom)", &["hsm:tr1", "astrid:l1"]);
    let best = &outcome.configurations[0];
    assert!(!best.uses("hsm", "tr1") && !best.uses("astrid", "l1"));
    assert_eq!(shape(best), PIPPI_190);
}

// Several executives: another's claim on the tracking system, in the state as a `held` fact.
// Held running for Bob, it is not available for Astrid (the laser at 170 instead), and the
// explanation names who holds it; held running for Astrid, it is shared at its running cost.
#[test]
fn a_component_held_by_another_executive_is_shared_only_running_the_same() {
    let held = |instance: &str| {
        format!("{PEIS_HOME_FACTS}\n(held hsm tr1 exec-bob tracking-system hsm tr1 {instance})\n")
    };
    let for_bob = held("bob");
    let outcome = run(PEIS_HOME, &for_bob, "(navigate astrid bedroom)", &[], 1);
    let best = &outcome.configurations[0];
    assert_eq!((best.cost, shape(best)), (170, LASER_170.to_string()));
    let outcome = run(
        PEIS_HOME,
        &for_bob,
        "(navigate astrid bedroom)",
        &["astrid:l1", "pippi:ol2"],
        1,
    );
    explained(
        outcome,
        "(tracking-system hsm tr1 astrid): component hsm:tr1 is held by exec-bob running (tracking-system hsm tr1 bob)",
    );
    // The camera is held by Bob's executive too, for the same instance: shared.
    let shared = format!(
        "{}(held hsm ca1 exec-bob ceiling-cameras hsm ca1)\n",
        held("astrid")
    );
    let outcome = run(PEIS_HOME, &shared, "(navigate astrid bedroom)", &[], 1);
    let best = &outcome.configurations[0];
    assert_eq!((best.cost, shape(best)), (80, CAMERAS_80.to_string()));
}

#[test]
fn no_position_source_left_is_explained() {
    let outcome = home(
        "(navigate astrid bedroom)",
        &["hsm:tr1", "astrid:l1", "pippi:ol2"],
    );
    assert!(outcome.configurations.is_empty());
    assert_eq!(outcome.status, Status::Proven);
    let explanation = outcome.explanation.expect("an explanation");
    expect![[r#"
        no configuration for (navigate astrid bedroom): no method applies
        └─ method navigate-with-position with ?tc = tc1: input (position astrid) of f1 (navigation astrid tc1 bedroom) cannot be provided by f0
           └─ (get-position astrid): no method applies
              ├─ method position-by-scan-matching with ?l = l1, ?o = od1, ?s = s1: input (range-scan astrid) of f3 (scan-matching astrid s1) cannot be provided by f1
              │  └─ (laser astrid l1): component astrid:l1 is excluded
              └─ method position-from-global-position with ?s = s1: input (global-pos astrid) of f2 (pose-tracking astrid s1) cannot be provided by f1
                 └─ (get-global-position astrid): no method applies
                    ├─ method global-position-by-ceiling-cameras with ?p = hsm, ?t = tr1, ?c = ca1: output (global-pos astrid) cannot be provided by f2
                    │  └─ (tracking-system hsm tr1 astrid): component hsm:tr1 is excluded
                    └─ method global-position-by-other-robot with ?p = pippi, ?c = ca2, ?l = ol2: output (global-pos astrid) cannot be provided by f2
                       └─ (object-localizer pippi ol2 astrid): component pippi:ol2 is excluded
    "#]]
    .assert_eq(&explanation.to_string());
}

/// A chain of `depth` tasks, each decomposed by any of `width` components
/// and needing the next task, whose last level has no provider.
fn chain(depth: usize, width: usize) -> (String, String) {
    let mut domain = String::from("(define (domain chain)\n");
    let mut facts = String::new();
    for i in 0..=depth {
        let (pre, input) = if i < depth {
            (format!("(sig ?p ?c s{i})"), format!("(t{})", i + 1))
        } else {
            ("(never ?p ?c)".to_string(), String::new())
        };
        domain.push_str(&format!(
            "(:functionality f{i} :parameters (?p ?c) :component (?p ?c) :precondition {pre} \
             :input ({input}) :output ((t{i})) :cost 1)\n(:task g{i} :parameters () :output ((t{i})))\n"
        ));
        let (subtasks, channels) = if i < depth {
            (
                format!(" (s1 (g{}))", i + 1),
                format!(" :channels ((s1 s0 (t{})))", i + 1),
            )
        } else {
            (String::new(), String::new())
        };
        domain.push_str(&format!(
            "(:method m{i} :parameters (?p ?c) :task (g{i}) :precondition (sig ?p ?c s{i}) \
             :subtasks ((s0 (f{i} ?p ?c)){subtasks}){channels} :outputs (((t{i}) s0)))\n"
        ));
        for k in 0..width {
            facts.push_str(&format!("(sig p{k} c{i} s{i})\n"));
        }
    }
    domain.push(')');
    (domain, facts)
}

// A task that several bindings need is explained once: repeating it under
// each binding made the tree grow as width^depth (ten levels of three
// components printed 531,441 lines).
#[test]
fn a_shared_failure_is_explained_once() {
    let (domain, facts) = chain(10, 3);
    let outcome = run(&domain, &facts, "(g0)", &[], 1);
    assert!(outcome.configurations.is_empty());
    let text = explained(
        outcome,
        "(f10 p0 c10): precondition (never p0 c10) does not hold",
    );
    assert!(text.lines().count() < 100, "{} lines", text.lines().count());
    assert_eq!(
        text.matches("(g5): no method applies").count(),
        3,
        "once in full, twice pointing above: {text}"
    );
    assert_eq!(
        text.matches("(g5): no method applies (see above)").count(),
        2
    );
}

// 24 levels would unfold into 16 million task occurrences. Assembly shares a
// subtree it has built, and the configuration has one instance per level
// (before, it was refused as "too large a decomposition").
#[test]
fn providers_shared_level_after_level_assemble_once() {
    let depth = 24;
    let instance = synthetic::diamond(depth, false).expect("generates");
    let outcome = plan(&instance.request(), &Options::default(), &NoClock).expect("valid");
    assert_eq!(outcome.status, Status::Proven);
    let best = outcome.configurations.first().expect("a configuration");
    assert_eq!(best.functionalities.len(), depth + 1);
    assert_eq!(best.channels.len(), 2 * depth);
    assert_eq!(
        best.cost,
        depth as u64 + 1,
        "one component per level, local channels"
    );
}

/// The snapshots `plan_observed` reports for a search for the `count`
/// cheapest configurations, and its outcome.
fn observed(request: &Request<'_>, count: usize) -> (Vec<Snapshot>, Outcome) {
    let mut seen = Vec::new();
    let options = Options {
        count,
        ..Options::default()
    };
    let outcome = plan_observed(request, &PaperCost, &options, &NoClock, &mut |s| {
        seen.push(s)
    })
    .expect("valid goal");
    (seen, outcome)
}

// Both searches report where they stand while they run: nodes expanded only
// grow, the best found is never below the optimum and the bound never above.
#[test]
fn a_running_search_reports_where_it_stands() {
    let sharing = synthetic::sharing(synthetic::Sharing::base(32, 1)).expect("generates");
    // Listing configurations, the tree search searches each occurrence of a
    // shared provider again: hundreds of nodes.
    let diamond = synthetic::diamond(8, true).expect("generates");
    for (request, count, anytime) in [(sharing.request(), 1, true), (diamond.request(), 2, false)] {
        let (seen, outcome) = observed(&request, count);
        let optimum = outcome.configurations[0].cost;
        assert!(seen.len() >= 3, "{} snapshots", seen.len());
        assert!(seen.windows(2).all(|w| w[0].expanded <= w[1].expanded));
        assert_eq!(
            seen.last().map(|s| s.expanded),
            Some(outcome.stats.expanded)
        );
        assert!(seen.iter().all(|s| s.best.is_none_or(|b| b >= optimum)));
        // The bound is on what is not yet accepted: past the first of a
        // list, it may pass the optimum.
        let bounded = seen.iter().take_while(|s| count == 1 || s.best.is_none());
        assert!(
            bounded
                .into_iter()
                .all(|s| s.lower_bound.is_none_or(|b| b <= optimum))
        );
        assert_eq!(seen.last().and_then(|s| s.best), Some(optimum));
        // The provider search's first dive finds a configuration before the
        // search proves it: both ends show while it runs.
        let bracketed = seen
            .iter()
            .any(|s| s.best.is_some() && s.lower_bound.is_some());
        assert!(bracketed || !anytime, "{seen:?}");
    }
}

// A task instance needed twice with the same alternative, whose output comes
// from a functionality of its own, is searched once: the cheapest
// configuration of 16 levels of shared providers (each method also running a
// functionality of its own, so the tree search plans it) takes under a
// hundred nodes, where searching every occurrence ran past a minute. Listing
// configurations searches every occurrence still, and finds the same one.
#[test]
fn the_tree_search_shares_a_repeated_provider() {
    let small = synthetic::diamond(6, true).expect("generates");
    let (_, listed) = observed(&small.request(), 2);
    let (_, cheapest) = observed(&small.request(), 1);
    assert_eq!(listed.configurations.len(), 1);
    assert_eq!(shapes(&listed), shapes(&cheapest));
    assert!(cheapest.stats.expanded * 4 < listed.stats.expanded);
    let large = synthetic::diamond(16, true).expect("generates");
    let (_, outcome) = observed(&large.request(), 1);
    assert_eq!(outcome.status, Status::Proven);
    let best = &outcome.configurations[0];
    assert_eq!(best.cost, 2 * 17, "an h and a k component per level");
    assert_eq!(best.functionalities.len(), 2 * 17);
    assert!(outcome.stats.expanded < 100, "{:?}", outcome.stats);
}

#[test]
fn excluding_a_peis_excludes_its_components() {
    let outcome = home("(navigate astrid bedroom)", &["hsm"]);
    let best = &outcome.configurations[0];
    assert!(best.functionalities.iter().all(|f| &*f.peis != "hsm"));
    assert!(
        best.channels
            .iter()
            .all(|c| &*c.from_peis != "hsm" && &*c.to_peis != "hsm")
    );
    assert_eq!(shape(best), LASER_170);
    let outcome = home("(navigate astrid bedroom)", &["hsm", "pippi", "astrid:l1"]);
    let text = explained(outcome, "PEIS hsm is excluded");
    assert!(text.contains("PEIS pippi is excluded"), "{text}");
}

#[test]
fn grasp_and_wake_up_start_their_components() {
    let grasp = home("(grasp astrid newspaper)", &[]);
    assert_eq!(
        grasp.configurations[0].cost, 100,
        "gripper start-up 90 + default 10"
    );
    assert_eq!(components(&grasp.configurations[0]), ["astrid:gr1"]);
    expect![[r#"
        (gripper astrid gr1 newspaper) on astrid:gr1 (Off) cost 100
        total 100
    "#]]
    .assert_eq(&shape(&grasp.configurations[0]));
    let wake = home("(wake-up astrid johanna)", &[]);
    assert_eq!(
        wake.configurations[0].cost, 20,
        "speaker start-up 10 + default 10"
    );
    assert_eq!(
        wake.configurations[0].functionalities[0].postcondition,
        [Name::from("(awake johanna)")]
    );
    expect![[r#"
        (speaker astrid sp1 johanna) on astrid:sp1 (Off) cost 20
        total 20
    "#]]
    .assert_eq(&shape(&wake.configurations[0]));
}

#[test]
fn a_missing_component_type_is_named() {
    let outcome = home("(grasp pippi newspaper)", &[]);
    explained(
        outcome,
        "precondition (pc ?r gripp ?g) does not hold with ?r = pippi",
    );
}

// The paper's Fig. 1: the fridge opens its own door for the robot's nose.
#[test]
fn fridge_inspection_uses_the_cameras_and_the_fridge_door() {
    let outcome = run(
        FRIDGE,
        FRIDGE_FACTS,
        "(inspect-food robby fridge1)",
        &[],
        usize::MAX,
    );
    let best = &outcome.configurations[0];
    assert!(best.uses("fridge1", "d1"), "{best}");
    assert!(best.uses("monitor", "tr1"), "{best}");
    assert!(best.uses("robby", "nose1"), "{best}");
    assert!(
        outcome.configurations.len() >= 2,
        "self-localization is the alternative"
    );
    expect![[r#"
        (ceiling-cameras monitor ca1) on monitor:ca1 (On) cost 20
        (door-opener fridge1 d1) on fridge1:d1 (On) cost 5
        (e-nose robby nose1 fridge1) on robby:nose1 (Off) cost 25
        (navigation robby tc1 fridge1) on robby:tc1 (On) cost 20
        (pose-tracking robby s1) on robby:s1 (On) cost 20
        (tracking-system monitor tr1 robby) on monitor:tr1 (On) cost 20
        monitor:ca1 → monitor:tr1 (image monitor) cost 0
        monitor:tr1 → robby:s1 (global-pos robby) cost 0
        robby:s1 → robby:tc1 (position robby) cost 0
        total 110
        --
        (dead-reckoning robby s1) on robby:s1 (On) cost 20
        (door-opener fridge1 d1) on fridge1:d1 (On) cost 5
        (e-nose robby nose1 fridge1) on robby:nose1 (Off) cost 25
        (navigation robby tc1 fridge1) on robby:tc1 (On) cost 20
        (odometry robby od1) on robby:od1 (Off) cost 60
        robby:od1 → robby:s1 (odometry robby) cost 0
        robby:s1 → robby:tc1 (position robby) cost 0
        total 130
    "#]]
    .assert_eq(&shapes(&outcome));
    let fallback = run(
        FRIDGE,
        FRIDGE_FACTS,
        "(inspect-food robby fridge1)",
        &["monitor"],
        1,
    );
    assert!(
        fallback.configurations[0].uses("robby", "od1"),
        "{}",
        fallback.configurations[0]
    );
    assert!(
        fallback.configurations[0]
            .functionalities
            .iter()
            .all(|f| &*f.peis != "monitor")
    );
    // Without the monitor, the alternative above is the best.
    assert_eq!(
        shape(&fallback.configurations[0]),
        shape(&outcome.configurations[1])
    );
}

#[test]
fn rates_must_be_met() {
    let domain = r#"(define (domain rates)
      (:functionality cam :parameters (?p ?c) :component (?p ?c)
        :precondition (pc ?p cam ?c) :output ((image ?p :hz 10)) :cost 1)
      (:functionality fast-cam :parameters (?p ?c) :component (?p ?c)
        :precondition (pc ?p fast-cam ?c) :output ((image ?p :hz 30)) :cost 5)
      (:functionality tracker :parameters (?p ?t) :component (?p ?t)
        :precondition (pc ?p tracker ?t) :input ((image ?p :hz 25)) :output ((pos ?p)) :cost 1)
      (:task track :parameters (?p))
      (:method with-cam :parameters (?p ?c ?t) :task (track ?p)
        :precondition (and (pc ?p cam ?c) (pc ?p tracker ?t))
        :subtasks ((a (cam ?p ?c)) (b (tracker ?p ?t))) :channels ((a b (image ?p))))
      (:method with-fast-cam :parameters (?p ?c ?t) :task (track ?p)
        :precondition (and (pc ?p fast-cam ?c) (pc ?p tracker ?t))
        :subtasks ((a (fast-cam ?p ?c)) (b (tracker ?p ?t))) :channels ((a b (image ?p)))))"#;
    let facts = "(pc r cam c1) (pc r fast-cam c2) (pc r tracker t1)";
    let outcome = run(domain, facts, "(track r)", &[], usize::MAX);
    assert_eq!(
        outcome.configurations.len(),
        1,
        "the 10 Hz camera is too slow"
    );
    assert_eq!(outcome.configurations[0].cost, 6);
    expect![[r#"
        (fast-cam r c2) on r:c2 (Off) cost 5
        (tracker r t1) on r:t1 (Off) cost 1
        r:c2 → r:t1 (image r) cost 0
        total 6
    "#]]
    .assert_eq(&shape(&outcome.configurations[0]));
    let outcome = run(domain, facts, "(track r)", &["r:c2"], 1);
    explained(
        outcome,
        "needs (image r) at 25 Hz but (cam r c1) offers 10 Hz",
    );
}

#[test]
fn a_shared_component_is_paid_once() {
    let domain = r#"(define (domain share)
      (:functionality cam :parameters (?p ?c) :component (?p ?c)
        :precondition (pc ?p cam ?c) :output ((image ?p)) :cost 10)
      (:functionality user :parameters (?p ?u) :component (?p ?u)
        :precondition (pc ?p user ?u) :input ((image ?p)) :cost 1)
      (:task see :parameters (?p ?u))
      (:method see-with-cam :parameters (?p ?u ?c) :task (see ?p ?u)
        :precondition (pc ?p cam ?c)
        :subtasks ((a (cam ?p ?c)) (b (user ?p ?u))) :channels ((a b (image ?p))))
      (:task both :parameters (?p))
      (:method both-users :parameters (?p ?u1 ?u2) :task (both ?p)
        :precondition (and (pc ?p user ?u1) (pc ?p user ?u2) (not (= ?u1 ?u2)))
        :subtasks ((x (see ?p ?u1)) (y (see ?p ?u2)))))"#;
    let facts = "(pc r cam c1) (pc r user u1) (pc r user u2) (cost r c1 10 on)";
    let outcome = run(domain, facts, "(both r)", &[], 1);
    let best = &outcome.configurations[0];
    assert_eq!(best.cost, 12, "the camera is shared: 10 + 1 + 1");
    // One camera instance feeds both users.
    expect![[r#"
        (cam r c1) on r:c1 (On) cost 10
        (user r u1) on r:u1 (Off) cost 1
        (user r u2) on r:u2 (Off) cost 1
        r:c1 → r:u1 (image r) cost 0
        r:c1 → r:u2 (image r) cost 0
        total 12
    "#]]
    .assert_eq(&shape(best));
}

#[test]
fn channel_costs_count_between_peis() {
    let facts = format!("{PEIS_HOME_FACTS}\n(channel-cost hsm astrid 100)");
    let outcome = run(
        PEIS_HOME,
        &facts,
        "(navigate astrid bedroom)",
        &[],
        usize::MAX,
    );
    let costs: Vec<u64> = outcome.configurations.iter().map(|c| c.cost).collect();
    assert_eq!(costs, [170, 180, 190], "the cameras now cost 80 + 100");
    // The same cameras, the remote channel hsm → astrid carrying the 100.
    let cameras = CAMERAS_80
        .replace("(global-pos astrid) cost 0", "(global-pos astrid) cost 100")
        .replace("total 80", "total 180");
    assert_eq!(
        shapes(&outcome),
        [LASER_170, &cameras, PIPPI_190].join("--\n")
    );
}

/// Prefers Astrid's own components, whatever they cost.
#[derive(Debug)]
struct SelfReliant;

impl CostModel for SelfReliant {
    fn component_cost(&self, peis: &str, _: &str, _: Option<ComponentCost>, _: u64) -> u64 {
        if peis == "astrid" { 1 } else { 100 }
    }
    fn channel_cost(&self, _: &str, _: &str, _: Option<u64>) -> u64 {
        0
    }
}

/// The PEIS-Home, its state, and the goal `(navigate astrid bedroom)`.
fn navigate_home() -> (ecology_domain::Domain, EcologyState, ecology_domain::Call) {
    (
        parse_domain(PEIS_HOME.as_bytes()).expect("parses"),
        parse_facts(PEIS_HOME_FACTS.as_bytes()).expect("parses"),
        parse_goal("(navigate astrid bedroom)").expect("parses"),
    )
}

#[test]
fn the_cost_model_is_pluggable() {
    let (domain, state, goal) = navigate_home();
    let request = Request {
        domain: &domain,
        state: &state,
        goal: &goal,
        exclusions: &[],
    };
    let options = Options {
        count: 3,
        ..Options::default()
    };
    let outcome = plan_with(&request, &SelfReliant, &options, &NoClock).expect("valid");
    let costs: Vec<u64> = outcome.configurations.iter().map(|c| c.cost).collect();
    assert_eq!(costs, [4, 202, 202]);
    assert!(outcome.configurations[0].uses("astrid", "l1"));
    expect![[r#"
        (laser astrid l1) on astrid:l1 (Off) cost 1
        (navigation astrid tc1 bedroom) on astrid:tc1 (On) cost 1
        (odometry astrid od1) on astrid:od1 (On) cost 1
        (scan-matching astrid s1) on astrid:s1 (On) cost 1
        astrid:l1 → astrid:s1 (range-scan astrid) cost 0
        astrid:od1 → astrid:s1 (odometry astrid) cost 0
        astrid:s1 → astrid:tc1 (position astrid) cost 0
        total 4
    "#]]
    .assert_eq(&shape(&outcome.configurations[0]));
}

#[test]
fn bad_goals_are_request_errors() {
    let domain = parse_domain(PEIS_HOME.as_bytes()).expect("parses");
    let state = EcologyState::new();
    for (goal, message) in [
        (
            "(fly astrid)",
            "unknown task or functionality `fly` in the goal",
        ),
        (
            "(navigate astrid)",
            "wrong arity: `navigate` takes 2 arguments, the goal gives 1",
        ),
    ] {
        let goal = parse_goal(goal).expect("parses");
        let request = Request {
            domain: &domain,
            state: &state,
            goal: &goal,
            exclusions: &[],
        };
        let err = plan(&request, &Options::default(), &NoClock).expect_err("rejected");
        assert_eq!(err.to_string(), message);
    }
}

/// A clock that advances one `step` each time it is read, and counts its reads.
#[derive(Debug)]
struct Stepping {
    step: Duration,
    reads: std::cell::Cell<u64>,
}

impl Stepping {
    /// One second a read.
    fn seconds() -> Self {
        Self::by(Duration::from_secs(1))
    }

    /// One millisecond a read.
    fn millis() -> Self {
        Self::by(Duration::from_millis(1))
    }

    fn by(step: Duration) -> Self {
        Self {
            step,
            reads: std::cell::Cell::new(0),
        }
    }
}

impl Clock for Stepping {
    fn elapsed(&self) -> Duration {
        self.reads.set(self.reads.get() + 1);
        self.step * u32::try_from(self.reads.get()).unwrap_or(u32::MAX)
    }
}

#[test]
fn budgets_stop_the_search_with_the_best_found_flagged() {
    let instance = synthetic::ecology(Shape {
        peis: 60,
        components_per_peis: 10,
        types: 8,
        methods: 3,
        depth: 4,
        seed: 7,
    })
    .expect("generates");
    let request = instance.request();
    let full = plan(&request, &Options::default(), &NoClock).expect("valid");
    assert_eq!(full.status, Status::Proven);
    let optimum = full.configurations[0].cost;

    for budget in [
        Budget {
            max_expansions: Some(1),
            max_time: None,
        },
        Budget {
            max_expansions: None,
            max_time: Some(Duration::from_millis(500)),
        },
    ] {
        let options = Options {
            count: 1,
            budget,
            ..Options::default()
        };
        let outcome = plan(&request, &options, &Stepping::seconds()).expect("valid");
        assert_eq!(outcome.status, Status::BudgetExceeded);
        if let Some(found) = outcome.configurations.first() {
            assert!(!found.optimal);
            assert!(found.cost >= optimum);
        }
        assert!(outcome.lower_bound.is_none_or(|lb| lb <= optimum));
    }
}

/// Whether the planner agrees with the oracle on a `small` instance; `Ok(false)`
/// when the oracle could not enumerate it.
#[test]
fn budgets_hold_for_the_provider_search() {
    let instance = synthetic::sharing(synthetic::Sharing::base(24, 5)).expect("generates");
    let request = instance.request();
    let full = plan(&request, &Options::default(), &NoClock).expect("valid");
    assert_eq!(full.status, Status::Proven);
    assert!(full.configurations[0].optimal);
    assert_eq!(full.lower_bound, None);
    let optimum = full.configurations[0].cost;
    let with = |budget| {
        let options = Options {
            count: 1,
            budget,
            ..Options::default()
        };
        plan(&request, &options, &Stepping::millis()).expect("valid")
    };
    // No node: nothing found, but a bound.
    let none = with(Budget {
        max_expansions: Some(0),
        max_time: None,
    });
    assert_eq!(none.status, Status::BudgetExceeded);
    assert!(none.configurations.is_empty());
    assert_eq!(none.stats.expanded, 0);
    assert!(none.lower_bound.is_some_and(|lb| lb <= optimum));
    // A few nodes, or a little time: the dive's configuration, flagged, with its gap.
    let reads = {
        let clock = Stepping::millis();
        let budget = Budget {
            max_expansions: None,
            max_time: Some(Duration::from_secs(3600)),
        };
        plan(
            &request,
            &Options {
                count: 1,
                budget,
                ..Options::default()
            },
            &clock,
        )
        .expect("valid");
        clock.reads.get()
    };
    // The first budget of time (a millisecond per clock reading) that finds
    // one without proving it.
    let timed = (0..reads)
        .map(|ms| Budget {
            max_expansions: None,
            max_time: Some(Duration::from_millis(ms)),
        })
        .find(|&budget| {
            let outcome = with(budget);
            outcome.status == Status::BudgetExceeded && !outcome.configurations.is_empty()
        })
        .expect("a budget that stops after the dive");
    for budget in [
        Budget {
            max_expansions: Some(40),
            max_time: None,
        },
        timed,
    ] {
        let outcome = with(budget);
        assert_eq!(outcome.status, Status::BudgetExceeded, "{budget:?}");
        let found = &outcome.configurations[0];
        assert!(!found.optimal && found.cost >= optimum, "{budget:?}");
        let lb = outcome.lower_bound.expect("a bound");
        assert!(lb <= optimum && lb <= found.cost, "{budget:?}");
        assert!(outcome.stats.first_micros.is_some());
    }
}

fn oracle_agrees(seed: u64, exclude_one: bool) -> Result<bool, TestCaseError> {
    let instance = synthetic::small(seed).map_err(|e| TestCaseError::fail(e.0))?;
    agrees_on(&instance, seed, exclude_one)
}

/// Whether the planner agrees with the oracle on `instance` (with its own
/// exclusions, and one more component when `exclude_one`); `Ok(false)` when
/// the oracle could not enumerate it.
fn agrees_on(
    instance: &synthetic::Instance,
    seed: u64,
    exclude_one: bool,
) -> Result<bool, TestCaseError> {
    let mut exclusions = instance.exclusions.clone();
    if exclude_one && !instance.components.is_empty() {
        let (peis, component) =
            &instance.components[(seed % instance.components.len() as u64) as usize];
        exclusions.push(Exclusion::Component {
            peis: peis.clone(),
            component: component.clone(),
        });
    }
    let Some(expected) = oracle::enumerate(
        &instance.domain,
        &instance.state,
        &instance.goal,
        &exclusions,
        &PaperCost,
        Limit(20_000),
    ) else {
        return Ok(false); // Too large for the oracle: counted by the callers.
    };
    let request = Request {
        domain: &instance.domain,
        state: &instance.state,
        goal: &instance.goal,
        exclusions: &exclusions,
    };
    let context = || {
        format!(
            "seed {seed} excluding {exclusions:?}\n{}\n{}\ngoal {}",
            instance.domain_text, instance.facts_text, instance.goal_text
        )
    };

    // The optimum; asked only whether one exists (no explanation), the same
    // answer, through the relaxation when it proves "none".
    let optimum = |explain| {
        let options = Options {
            explain,
            ..Options::default()
        };
        plan(&request, &options, &NoClock).expect("valid goal")
    };
    let (best, quick) = (optimum(true), optimum(false));
    for outcome in [&best, &quick] {
        prop_assert_eq!(outcome.status, Status::Proven);
        prop_assert_eq!(
            outcome.configurations.first().map(|c| c.cost),
            expected.first().map(|c| c.cost),
            "{}",
            context()
        );
    }
    // Every admissible configuration, cheapest first, and each is admissible.
    let options = Options {
        count: usize::MAX,
        ..Options::default()
    };
    let all = plan(&request, &options, &NoClock).expect("valid goal");
    let costs: Vec<u64> = all.configurations.iter().map(|c| c.cost).collect();
    let expected_costs: Vec<u64> = expected.iter().map(|c| c.cost).collect();
    prop_assert_eq!(&costs, &expected_costs, "{}", context());
    let mut got: Vec<String> = all
        .configurations
        .iter()
        .map(Configuration::signature)
        .collect();
    let mut want: Vec<String> = expected.iter().map(|c| c.signature.clone()).collect();
    got.sort();
    want.sort();
    prop_assert_eq!(got, want, "{}", context());
    // A proven "none" comes with an explanation, when one is asked for.
    if expected.is_empty() {
        prop_assert!(best.explanation.is_some());
    }
    prop_assert!(quick.explanation.is_none());
    // Excluding a component used by the optimum never makes it cheaper.
    if let Some(first) = best.configurations.first() {
        for f in &first.functionalities {
            let mut more = exclusions.clone();
            more.push(Exclusion::Component {
                peis: f.peis.to_string(),
                component: f.component.to_string(),
            });
            let request = Request {
                exclusions: &more,
                ..request
            };
            let outcome = plan(&request, &Options::default(), &NoClock).expect("valid goal");
            if let Some(c) = outcome.configurations.first() {
                prop_assert!(c.cost >= first.cost, "{}", context());
            }
        }
    }
    Ok(true)
}

/// A small shared-provider ecology (issue 11) for the oracle; even seeds
/// have rates.
fn small_sharing(seed: u64) -> synthetic::Instance {
    small_sharing_with(seed, seed % 2 == 0)
}

fn small_sharing_with(seed: u64, rates: bool) -> synthetic::Instance {
    let mut rng = synthetic::Rng::new(seed);
    let types = 1 + rng.below(2) as usize;
    let shape = synthetic::Sharing {
        peis: 1 + rng.below(4) as usize,
        levels: 1 + rng.below(3) as usize,
        types,
        per_level: 1 + rng.below(2) as usize,
        needs: 1 + rng.below(types as u64) as usize,
        failed: if rng.chance(0.5) { 0.2 } else { 0.0 },
        rates,
        seed,
    };
    synthetic::sharing(shape).unwrap_or_else(|e| panic!("seed {seed}: {}", e.0))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, failure_persistence: None, ..ProptestConfig::default() })]

    // Equal optimum, equal k-best lists, every configuration admissible; on
    // thousands of random small domains and states, with and without an exclusion.
    #[test]
    fn the_planner_agrees_with_brute_force(seed in any::<u64>(), exclude in any::<bool>()) {
        // A case too large for the oracle is rejected, and proptest counts
        // the rejections (failing when they pass its global limit).
        prop_assume!(oracle_agrees(seed, exclude)?, "too large for the oracle");
    }
}

/// Runs `check` on seeds `0..cases`; fails on a disagreement, or when the
/// oracle could not enumerate more than a tenth of the cases. Prints the count.
fn against_the_oracle(
    what: &str,
    seeds: std::ops::Range<u64>,
    check: impl Fn(u64) -> Result<bool, TestCaseError>,
) {
    let mut skipped = 0;
    let cases = seeds.end - seeds.start;
    for seed in seeds {
        match check(seed) {
            Ok(true) => {}
            Ok(false) => skipped += 1,
            Err(e) => panic!("{what}, seed {seed}: {e}"),
        }
    }
    eprintln!("{what}: the oracle could not enumerate {skipped} of {cases} cases");
    assert!(
        skipped * 10 <= cases,
        "{what}: the oracle could not enumerate {skipped} of {cases} cases"
    );
}

// The same check on fixed seeds, counting the cases too large for the oracle.
#[test]
fn the_oracle_enumerates_most_small_cases() {
    against_the_oracle("small", 0..400, |seed| oracle_agrees(seed, seed % 2 == 1));
}

// Rates bind in the small shared-provider ecologies the oracle checks: on
// some seeds they change the optimum or rule out every configuration.
#[test]
fn rates_matter_in_the_small_sharing_ecologies() {
    // The rates matter: on some seeds they change the optimum or rule out
    // every configuration (each checked against brute force below).
    let binding = (0..400)
        .step_by(2)
        .filter(|&seed| {
            let cost = |rates| {
                let instance = small_sharing_with(seed, rates);
                let outcome = plan(&instance.request(), &Options::default(), &NoClock);
                outcome
                    .expect("valid")
                    .configurations
                    .first()
                    .map(|c| c.cost)
            };
            cost(true) != cost(false)
        })
        .count();
    eprintln!("sharing: rates change the optimum on {binding} of 200 seeds");
    assert!(
        binding >= 20,
        "rates change the optimum on only {binding} of 200 seeds"
    );
}

// Shared providers, channel costs and rates (issue 11): the provider search
// agrees with brute force on optimum, k-best list and exclusions. Two halves
// of the seeds, so that the test harness runs them side by side.
#[test]
fn the_provider_search_agrees_with_brute_force() {
    provider_search_against_the_oracle(0..200);
}

#[test]
fn the_provider_search_agrees_with_brute_force_more() {
    provider_search_against_the_oracle(200..400);
}

fn provider_search_against_the_oracle(seeds: std::ops::Range<u64>) {
    against_the_oracle("sharing", seeds, |seed| {
        let instance = small_sharing(seed);
        let request = instance.request();
        let search = crate::Search::new(&request, &PaperCost, &Options::default()).expect("valid");
        // Every instance is searched by providers, except those grounding
        // already proves have no configuration (nothing to search).
        let hopeless = search.engine.graph.item(search.engine.root).lb == crate::ground::INFEASIBLE;
        prop_assert!(
            search.shared.is_some() || hopeless,
            "seed {seed}: not searched by providers"
        );
        agrees_on(&instance, seed, seed % 3 == 0)
    });
}

/// Whether the relaxation proves that `request` has no configuration.
fn relaxation_proves_none(request: &Request<'_>) -> bool {
    let (prepared, (callee, args)) =
        crate::planner::prepared_and_goal(request, None).expect("valid");
    prepared.relaxed.proves_none(
        &prepared.schema,
        request.state,
        callee,
        &args,
        request.exclusions,
        &|| false,
    )
}

// The relaxation that answers "none" without grounding is sound (it proves
// none only where the oracle finds none) and not idle (it proves most of the
// cases without a configuration), on random domains, shared-provider
// ecologies and the paper's, with a component or PEIS excluded.
#[test]
fn the_relaxation_proves_none_only_where_there_is_none() {
    let (mut none, mut proven) = (0, 0);
    let mut check = |instance: &synthetic::Instance, seed: u64| {
        let mut cases = vec![instance.exclusions.clone()];
        if !instance.components.is_empty() {
            let (peis, component) =
                &instance.components[(seed % instance.components.len() as u64) as usize];
            let mut more = instance.exclusions.clone();
            more.push(Exclusion::Component {
                peis: peis.clone(),
                component: component.clone(),
            });
            cases.push(more.clone());
            more.push(Exclusion::Peis(peis.clone()));
            cases.push(more);
        }
        for exclusions in &cases {
            let request = Request {
                exclusions,
                ..instance.request()
            };
            let Some(expected) = oracle::enumerate(
                request.domain,
                request.state,
                request.goal,
                exclusions,
                &PaperCost,
                Limit(20_000),
            ) else {
                continue;
            };
            let proves = relaxation_proves_none(&request);
            assert!(
                !proves || expected.is_empty(),
                "seed {seed} excluding {exclusions:?}: proved none, the oracle found {}\n{}\n{}",
                expected.len(),
                instance.domain_text,
                instance.facts_text
            );
            if expected.is_empty() {
                none += 1;
                proven += usize::from(proves);
            }
        }
    };
    for seed in 0..300 {
        check(
            &synthetic::small(seed).unwrap_or_else(|e| panic!("seed {seed}: {}", e.0)),
            seed,
        );
        check(&small_sharing(seed), seed);
    }
    eprintln!("the relaxation proved {proven} of {none} cases without a configuration");
    assert!(
        proven * 2 >= none && none >= 100,
        "the relaxation proved {proven} of {none} cases without a configuration"
    );
    // The paper's ecology: without Astrid's laser and the PEIS with cameras
    // (hsm's ceiling and Pippi), nothing localizes her; with Pippi there, her
    // camera does.
    let goal = "(navigate astrid kitchen)";
    for (exclude, none) in [
        (&["astrid:l1", "hsm", "pippi"][..], true),
        (&["astrid:l1", "hsm"], false),
    ] {
        let proves = with_request(PEIS_HOME, PEIS_HOME_FACTS, goal, exclude, |request| {
            relaxation_proves_none(request)
        });
        assert_eq!(proves, none, "{exclude:?}");
        assert_eq!(
            home(goal, exclude).configurations.is_empty(),
            none,
            "{exclude:?}"
        );
    }
}

#[test]
fn the_generators_are_deterministic() {
    let a = synthetic::small(42).expect("generates");
    let b = synthetic::small(42).expect("generates");
    assert_eq!(a.domain_text, b.domain_text);
    assert_eq!(a.facts_text, b.facts_text);
    // Many seeds produce valid instances, and some have configurations.
    let mut solvable = 0;
    for seed in 0..200 {
        let instance = synthetic::small(seed).unwrap_or_else(|e| panic!("seed {seed}: {}", e.0));
        let request = instance.request();
        if !plan(&request, &Options::default(), &NoClock)
            .expect("valid")
            .configurations
            .is_empty()
        {
            solvable += 1;
        }
    }
    assert!(
        solvable > 40,
        "only {solvable} of 200 random instances are solvable"
    );
}

#[test]
fn a_component_cannot_run_two_functionalities() {
    // One camera would have to stream and record at once: inadmissible.
    let domain = r#"(define (domain clash)
      (:functionality stream :parameters (?p ?c) :component (?p ?c)
        :precondition (pc ?p cam ?c) :output ((image ?p)) :cost 1)
      (:functionality record :parameters (?p ?c) :component (?p ?c)
        :precondition (pc ?p cam ?c) :cost 1)
      (:task watch :parameters (?p))
      (:method stream-and-record :parameters (?p ?c ?d) :task (watch ?p)
        :precondition (and (pc ?p cam ?c) (pc ?p cam ?d))
        :subtasks ((a (stream ?p ?c)) (b (record ?p ?d))))
      (:task show :parameters (?p))
      (:method show-stream :parameters (?p ?c) :task (show ?p)
        :precondition (pc ?p cam ?c) :subtasks ((a (stream ?p ?c))))
      (:task keep :parameters (?p))
      (:method keep-record :parameters (?p ?c) :task (keep ?p)
        :precondition (pc ?p cam ?c) :subtasks ((a (record ?p ?c))))
      (:task both :parameters (?p))
      (:method both-tasks :parameters (?p) :task (both ?p)
        :subtasks ((x (show ?p)) (y (keep ?p)))))"#;
    let one = "(pc r cam c1)";
    let outcome = run(domain, one, "(watch r)", &[], 1);
    explained(
        outcome,
        "(stream r c1) and (record r c1) would both run on component r:c1",
    );
    // Across tasks, the clash is found by the search.
    let outcome = run(domain, one, "(both r)", &[], 1);
    let text = explained(outcome, "every decomposition is inadmissible");
    assert!(text.contains("component r:c1 would run both"), "{text}");
    // With two cameras, both work.
    let outcome = run(domain, "(pc r cam c1) (pc r cam c2)", "(both r)", &[], 1);
    assert_eq!(outcome.configurations[0].cost, 2);
}

#[test]
fn a_time_budget_stops_grounding() {
    // Grounding 1,000 PEIS takes thousands of items; the clock ticks a second
    // at each reading, so the budget runs out while grounding.
    let instance = synthetic::ecology(Shape {
        peis: 1000,
        components_per_peis: 10,
        types: 20,
        methods: 3,
        depth: 4,
        seed: 3,
    })
    .expect("generates");
    let (outcome, reads) = out_of_time(&instance.request(), Duration::from_secs(3));
    assert_eq!(outcome.stats.expanded, 0);
    // It stopped early: a handful of readings, not one per 256 items of the whole graph.
    assert!(reads <= 4, "read the clock {reads} times");
}

/// Plans `request` under a time budget of `limit` on a [`Stepping::seconds`] clock,
/// checks that it ran out with nothing found and no bound, and returns the
/// outcome and how many times the planner read the clock.
fn out_of_time(request: &Request<'_>, limit: Duration) -> (Outcome, u64) {
    let options = Options {
        count: 1,
        budget: Budget {
            max_expansions: None,
            max_time: Some(limit),
        },
        ..Options::default()
    };
    let clock = Stepping::seconds();
    let outcome = plan(request, &options, &clock).expect("valid");
    assert_eq!(outcome.status, Status::BudgetExceeded);
    assert!(outcome.configurations.is_empty());
    assert_eq!(outcome.lower_bound, None);
    (outcome, clock.reads.get())
}

#[test]
fn a_time_budget_stops_reading_the_state() {
    // 128 PEIS: over 16,000 channel costs. The clock ticks a second at each
    // reading; the second look, 2,048 facts in, is past the budget.
    let instance = synthetic::sharing(synthetic::Sharing::base(128, 1)).expect("generates");
    let (outcome, reads) = out_of_time(&instance.request(), Duration::from_millis(1500));
    // Cut before grounding anything.
    assert_eq!(outcome.stats.alternatives, 0);
    assert!(reads <= 4, "read the clock {reads} times");
}

#[test]
fn every_phase_of_the_provider_search_checks_the_budget() {
    let instance = synthetic::sharing(synthetic::Sharing::base(64, 2)).expect("generates");
    let request = instance.request();
    let full = plan(&request, &Options::default(), &NoClock).expect("valid");
    let optimum = full.configurations[0].cost;
    // How often an unlimited search reads the clock.
    let clock = Stepping::millis();
    let unlimited = Options {
        count: 1,
        budget: Budget {
            max_expansions: None,
            max_time: Some(Duration::from_secs(3600)),
        },
        ..Options::default()
    };
    plan(&request, &unlimited, &clock).expect("valid");
    let reads = clock.reads.get();
    // Every budget short of that stops somewhere: each outcome is flagged, its
    // configuration (if any) no cheaper than the optimum, its bound no higher.
    let mut mid_dive = false;
    for ms in 0..reads.min(400) {
        let options = Options {
            count: 1,
            budget: Budget {
                max_expansions: None,
                max_time: Some(Duration::from_millis(ms)),
            },
            ..Options::default()
        };
        let outcome = plan(&request, &options, &Stepping::millis()).expect("valid");
        if outcome.status == Status::Proven {
            assert_eq!(outcome.configurations[0].cost, optimum, "{ms} ms");
            continue;
        }
        if let Some(found) = outcome.configurations.first() {
            assert!(!found.optimal && found.cost >= optimum, "{ms} ms");
        }
        assert!(
            outcome.lower_bound.is_none_or(|lb| lb <= optimum),
            "{ms} ms"
        );
        // The first dive wires a whole configuration in one step; stopped
        // inside it, steps were taken but nothing was found.
        mid_dive |= outcome.stats.expanded > 0 && outcome.configurations.is_empty();
    }
    assert!(mid_dive, "no budget stopped the first dive");
}

#[test]
fn a_budget_cuts_a_long_list_short() {
    let instance = synthetic::sharing(synthetic::Sharing::base(4, 3)).expect("generates");
    let request = instance.request();
    let thirty = Options {
        count: 30,
        ..Options::default()
    };
    let full = plan(&request, &thirty, &NoClock).expect("valid");
    assert_eq!(full.configurations.len(), 30);
    let clock = Stepping::millis();
    let unlimited = Options {
        budget: Budget {
            max_expansions: None,
            max_time: Some(Duration::from_secs(3600)),
        },
        ..thirty
    };
    plan(&request, &unlimited, &clock).expect("valid");
    let mut shorter = false;
    for ms in 0..clock.reads.get() {
        let options = Options {
            budget: Budget {
                max_expansions: None,
                max_time: Some(Duration::from_millis(ms)),
            },
            ..thirty
        };
        let outcome = plan(&request, &options, &Stepping::millis()).expect("valid");
        let n = outcome.configurations.len();
        // What it lists is the start of the whole list, all of it only when proven.
        for (got, want) in outcome.configurations.iter().zip(&full.configurations) {
            assert_eq!(got.cost, want.cost, "{ms} ms");
        }
        assert_eq!(outcome.status == Status::Proven, n == 30, "{ms} ms");
        if outcome.status == Status::BudgetExceeded {
            shorter |= n > 1 && outcome.configurations.iter().all(|c| c.optimal);
        }
    }
    assert!(shorter, "no budget cut the list of proven ones short");
}

/// A [`crate::Planner`] compiles its domain once; planning through it, with
/// one state after another, gives what [`plan`] gives, and a request with
/// another domain than the planner's is planned with that domain.
#[test]
fn a_planner_reused_across_states_plans_as_plan_does() {
    let outcomes = |outcome: &Outcome| {
        let costs: Vec<(u64, String)> = outcome
            .configurations
            .iter()
            .map(|c| (c.cost, c.signature()))
            .collect();
        (
            costs,
            outcome.status,
            outcome.explanation.as_ref().map(|e| e.to_string()),
        )
    };
    let options = Options {
        count: 3,
        ..Options::default()
    };
    let shape = |seed| synthetic::Sharing {
        peis: 3,
        levels: 2,
        types: 2,
        per_level: 1,
        needs: 1,
        failed: 0.2,
        rates: seed % 2 == 0,
        seed,
    };
    let mut compared = 0;
    for seed in 0..4 {
        let instance = synthetic::sharing(shape(seed)).expect("generates");
        let planner = crate::Planner::new(instance.domain.clone());
        // One domain, many states: the instance's, and each without one of
        // its facts (a component gone, a cost or a channel unknown).
        let lines: Vec<&str> = instance.facts_text.lines().collect();
        for drop in (0..=lines.len()).step_by(3) {
            let text: Vec<&str> = lines
                .iter()
                .enumerate()
                .filter(|&(i, _)| i != drop)
                .map(|(_, l)| *l)
                .collect();
            let state = parse_facts(text.join("\n").as_bytes()).expect("parses");
            // The planner's own domain, or an equal copy (compiled again).
            let domain = if drop % 2 == 0 {
                planner.domain()
            } else {
                &instance.domain
            };
            let request = Request {
                domain,
                state: &state,
                ..instance.request()
            };
            let reused = planner.plan(&request, &options, &NoClock).expect("valid");
            let fresh = plan(&request, &options, &NoClock).expect("valid");
            assert_eq!(
                outcomes(&reused),
                outcomes(&fresh),
                "seed {seed}, without line {drop}"
            );
            compared += usize::from(!fresh.configurations.is_empty());
        }
    }
    assert!(compared >= 12, "only {compared} states had a configuration");
    let planner = crate::Planner::new(synthetic::sharing(shape(0)).expect("generates").domain);
    // The PEIS-Home through the sharing domain's planner: planned as itself.
    let (domain, state, goal) = navigate_home();
    let request = Request {
        domain: &domain,
        state: &state,
        goal: &goal,
        exclusions: &[],
    };
    let through = planner.plan(&request, &options, &NoClock).expect("valid");
    let direct = plan(&request, &options, &NoClock).expect("valid");
    assert!(!direct.configurations.is_empty());
    assert_eq!(outcomes(&through), outcomes(&direct));
}

/// The planner interns a state's names by address first: a reader shares one
/// `Name` per distinct name, a state built fact by fact does not. Both must
/// plan alike, and names equal in text must be one symbol either way.
#[test]
fn a_state_plans_alike_whether_its_names_are_shared_or_not() {
    let (domain, shared, goal) = navigate_home();
    let copied: EcologyState = shared
        .facts()
        .iter()
        .map(|f| {
            let args: Vec<&str> = f.args.iter().map(|a| &**a).collect();
            ecology_domain::Fact::new(&f.predicate, &args)
        })
        .collect();
    let astrid = |state: &EcologyState| -> Vec<Name> {
        state
            .facts()
            .iter()
            .flat_map(|f| f.args.iter())
            .filter(|a| &***a == "astrid")
            .cloned()
            .collect()
    };
    // The two states differ in exactly what the planner's shortcut relies on.
    let (a, b) = (astrid(&shared), astrid(&copied));
    assert!(a.len() > 1 && a.len() == b.len());
    assert!(a.windows(2).all(|w| std::sync::Arc::ptr_eq(&w[0], &w[1])));
    assert!(b.windows(2).all(|w| !std::sync::Arc::ptr_eq(&w[0], &w[1])));
    let outcome = |state: &EcologyState| {
        let request = Request {
            domain: &domain,
            state,
            goal: &goal,
            exclusions: &[],
        };
        let options = Options {
            count: 3,
            ..Options::default()
        };
        let out = plan(&request, &options, &NoClock).expect("valid");
        out.configurations
            .iter()
            .map(|c| (c.cost, c.signature()))
            .collect::<Vec<_>>()
    };
    let (a, b) = (outcome(&shared), outcome(&copied));
    assert_eq!(a.len(), 3);
    assert_eq!(a[0].0, 80, "the paper's cheapest configuration");
    assert_eq!(a, b);
}

/// Planning from only the components of the types a goal's methods name (as the executive does)
/// finds the configurations the whole state gives, for each of the paper's goals, with and
/// without a component excluded and with another executive's claims.
#[test]
fn a_state_cut_to_the_goals_component_types_plans_the_same() {
    let domain = parse_domain(PEIS_HOME.as_bytes()).expect("domain parses");
    let held = include_str!("../../../domains/peis-home-held.facts");
    for facts in [PEIS_HOME_FACTS, held] {
        let state = parse_facts(facts.as_bytes()).expect("facts parse");
        for goal in [
            "(navigate astrid bedroom)",
            "(grasp astrid newspaper)",
            "(wake-up astrid johanna)",
        ] {
            let goal = parse_goal(goal).expect("goal parses");
            let types = crate::component_types(&domain, &goal).expect("the goal names its types");
            // The components of other types, and every fact about them.
            let other: Vec<(Name, Name)> = state
                .facts()
                .iter()
                .filter(|f| &*f.predicate == "pc" && !types.contains(&*f.args[1]))
                .map(|f| (f.args[0].clone(), f.args[2].clone()))
                .collect();
            assert!(!other.is_empty(), "{goal}: every component is of its types");
            let about_other = |f: &ecology_domain::Fact| {
                let (p, c) = match (&*f.predicate, f.args.as_slice()) {
                    ("pc", [p, _, c, ..]) | ("cost" | "status" | "held", [p, c, ..]) => (p, c),
                    _ => return false,
                };
                other.iter().any(|(op, oc)| op == p && oc == c)
            };
            let cut: EcologyState = state
                .facts()
                .iter()
                .filter(|f| !about_other(f))
                .cloned()
                .collect();
            for exclude in [&[][..], &["hsm:ca1"][..]] {
                let exclusions = exclusions(exclude);
                let outcome = |state: &EcologyState| {
                    let request = Request {
                        domain: &domain,
                        state,
                        goal: &goal,
                        exclusions: &exclusions,
                    };
                    let options = Options {
                        count: 3,
                        ..Options::default()
                    };
                    plan(&request, &options, &NoClock).expect("valid")
                };
                let (whole, part) = (outcome(&state), outcome(&cut));
                assert!(
                    !whole.configurations.is_empty(),
                    "{goal} without {exclude:?}"
                );
                assert_eq!(
                    whole.configurations, part.configurations,
                    "{goal} without {exclude:?}"
                );
            }
        }
    }
}
