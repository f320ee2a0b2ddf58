//! The executive running conditional plans, event by event: a sensing action
//! is done once its configuration reported every atom it reveals (in
//! `C.observed`), the plan goes on with the branch of what was observed,
//! and what cannot be read or was not foreseen fails as it should.

use std::time::Duration;

use ecology_domain::{EcologyState, parse_domain, parse_goal};
use ecology_tuples::{Key, PeisId};

use crate::{
    Event, ExecConfig, Executive, LogEvent, Observation, Plan, PlanBranch, PlannedAction, RunStatus,
};

/// A robot with an eye that looks for things.
const EYES: &str = "
(define (domain eyes)
  (:functionality look-at :parameters (?r ?e ?t) :component (?r ?e)
    :precondition (pc ?r eye ?e) :cost 1)
  (:task look-for :parameters (?r ?t))
  (:method look-with-eye :parameters (?r ?t ?e) :task (look-for ?r ?t)
    :precondition (pc ?r eye ?e)
    :subtasks ((f1 (look-at ?r ?e ?t)))))
";

const BALL_IN_KITCHEN: &str = "(at ball kitchen)";

fn tuple(owner: &str, key: &str, value: &str, seq: u64) -> Event {
    Event::Tuple {
        owner: PeisId::new(owner).expect("name"),
        key: Key::new(key).expect("key"),
        value: value.to_string(),
        epoch: 1,
        seq,
    }
}

/// An action that needs no configuration: done as soon as it starts.
fn plain(action: &str) -> PlannedAction {
    PlannedAction::new(action, None)
}

fn look() -> PlannedAction {
    PlannedAction {
        action: "(look robot ball kitchen)".to_string(),
        goal: Some(parse_goal("(look-for robot ball)").expect("goal")),
        observe: vec![BALL_IN_KITCHEN.to_string()],
    }
}

fn branch(holds: bool, then: &str) -> PlanBranch {
    PlanBranch {
        observation: vec![Observation {
            atom: BALL_IN_KITCHEN.to_string(),
            holds,
        }],
        probability: if holds { 0.6 } else { 0.4 },
        plan: Plan::from(vec![plain(then)]).into(),
    }
}

/// Look, then fetch the ball from the kitchen or from the garden.
fn plan() -> Plan {
    Plan::branching(
        vec![look()],
        vec![
            branch(true, "(fetch robot ball kitchen)"),
            branch(false, "(fetch robot ball garden)"),
        ],
    )
}

/// An executive for `plan` whose look is deployed and running on `robot:e1`.
fn looking(plan: Plan) -> Executive {
    let domain = parse_domain(EYES.as_bytes()).expect("domain");
    let mut exec = Executive::new(domain, EcologyState::new(), plan, ExecConfig::default());
    for (key, value) in [
        ("components.e1.type", "eye"),
        ("components.e1.cost", "1"),
        ("components.e1.currState", "on"),
        ("e1.status", "idle"),
    ] {
        exec.handle(Duration::ZERO, tuple("robot", key, value, 1));
    }
    exec.handle(Duration::ZERO, Event::Start);
    exec.handle(
        Duration::from_secs(1),
        tuple("robot", "e1.status", "running", 2),
    );
    exec
}

fn started(exec: &Executive) -> Vec<&str> {
    exec.log()
        .iter()
        .filter_map(|e| match &e.event {
            LogEvent::ActionStarted { action, .. } => Some(action.as_str()),
            _ => None,
        })
        .collect()
}

fn timeline(exec: &Executive) -> String {
    exec.log().iter().map(|e| format!("{e}\n")).collect()
}

#[test]
fn the_plan_goes_on_with_the_branch_of_what_was_observed() {
    for (observed, fetch) in [
        ("(at ball kitchen)", "(fetch robot ball kitchen)"),
        ("(not (at ball kitchen))", "(fetch robot ball garden)"),
    ] {
        let mut exec = looking(plan());
        assert_eq!(
            exec.log().first().map(|e| &e.event),
            Some(&LogEvent::Plan {
                actions: vec!["(look robot ball kitchen)".to_string()],
                branches: vec![
                    "(at ball kitchen)".to_string(),
                    "(not (at ball kitchen))".to_string()
                ],
            })
        );
        assert_eq!(
            exec.status(),
            &RunStatus::Running { index: 0 },
            "running is not enough for a sensing action:\n{}",
            timeline(&exec)
        );
        exec.handle(
            Duration::from_secs(2),
            tuple("robot", "e1.observed", observed, 1),
        );
        assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(&exec));
        assert_eq!(
            started(&exec),
            ["(look robot ball kitchen)", fetch],
            "{}",
            timeline(&exec)
        );
        let logged: Vec<&LogEvent> = exec
            .log()
            .iter()
            .map(|e| &e.event)
            .filter(|e| matches!(e, LogEvent::Observed { .. } | LogEvent::Branch { .. }))
            .collect();
        assert_eq!(
            logged,
            [
                &LogEvent::Observed {
                    index: 0,
                    action: "(look robot ball kitchen)".to_string(),
                    observation: observed.to_string(),
                },
                &LogEvent::Branch {
                    observation: observed.to_string(),
                    probability: if observed.starts_with("(not") {
                        0.4
                    } else {
                        0.6
                    },
                    actions: vec![fetch.to_string()],
                },
            ]
        );
        assert_eq!(
            exec.observations(),
            [Observation {
                atom: BALL_IN_KITCHEN.to_string(),
                holds: !observed.starts_with("(not"),
            }]
        );
    }
}

#[test]
fn only_the_atoms_the_action_reveals_from_its_own_configuration_count() {
    let mut exec = looking(plan());
    // Another atom, and the right atom from a component outside the configuration.
    exec.handle(
        Duration::from_secs(2),
        tuple("robot", "e1.observed", "(at ball garden)", 1),
    );
    exec.handle(
        Duration::from_secs(2),
        tuple("other", "e9.observed", BALL_IN_KITCHEN, 1),
    );
    assert_eq!(exec.status(), &RunStatus::Running { index: 0 });
    assert!(exec.observations().is_empty());
    // Several literals in one tuple: the one the action reveals counts.
    exec.handle(
        Duration::from_secs(3),
        tuple(
            "robot",
            "e1.observed",
            "(at ball garden)  (not   (at ball kitchen))",
            2,
        ),
    );
    assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(&exec));
    assert_eq!(
        started(&exec).last(),
        Some(&"(fetch robot ball garden)"),
        "{}",
        timeline(&exec)
    );
}

#[test]
fn an_observation_that_cannot_be_read_fails_its_component() {
    let mut exec = looking(plan());
    exec.handle(
        Duration::from_secs(2),
        tuple("robot", "e1.observed", "(at ball", 1),
    );
    let failure = exec.log().iter().find_map(|e| match &e.event {
        LogEvent::Failure {
            peis,
            component,
            cause,
        } => Some(format!("{peis}:{component}: {cause}")),
        _ => None,
    });
    assert_eq!(
        failure.as_deref(),
        Some("robot:e1: it wrote an observation that cannot be read: unbalanced parentheses"),
        "{}",
        timeline(&exec)
    );
    // The only eye failed: the look has no configuration left.
    assert!(
        matches!(exec.status(), RunStatus::Failed { index: 0, .. }),
        "{}",
        timeline(&exec)
    );
}

#[test]
fn an_observation_no_branch_expects_fails_the_sensing_action() {
    let only_in_kitchen = Plan::branching(
        vec![look()],
        vec![branch(true, "(fetch robot ball kitchen)")],
    );
    let mut exec = looking(only_in_kitchen);
    exec.handle(
        Duration::from_secs(2),
        tuple("robot", "e1.observed", "(not (at ball kitchen))", 1),
    );
    let RunStatus::Failed { index, reason } = exec.status() else {
        panic!("not failed:\n{}", timeline(&exec));
    };
    assert_eq!(*index, 0);
    assert_eq!(
        reason,
        "it observed (not (at ball kitchen)), which no branch of the plan expects"
    );
    assert_eq!(exec.failed_actions(), ["(look robot ball kitchen)"]);
    // What was observed is kept for the replanner.
    assert_eq!(exec.observations().len(), 1);
}

#[test]
fn a_branch_that_gives_up_fails_the_task_and_releases_what_it_used() {
    let gives_up = Plan {
        steps: Vec::new(),
        branches: Vec::new(),
        success: 0.0,
    };
    let mut plan = plan();
    plan.branches[1].plan = gives_up.into();
    let mut exec = looking(plan);
    exec.handle(
        Duration::from_secs(2),
        tuple("robot", "e1.observed", "(not (at ball kitchen))", 1),
    );
    let RunStatus::Failed { reason, .. } = exec.status() else {
        panic!("not failed:\n{}", timeline(&exec));
    };
    assert!(reason.contains("the plan gives up here"), "{reason}");
    assert!(exec.finished(), "released, and not to be planned again");
    let names: Vec<&str> = exec.log().iter().map(|e| e.event.name()).collect();
    assert_eq!(
        names[names.len() - 3..],
        ["branch", "released", "task_failed"],
        "{}",
        timeline(&exec)
    );
}

#[test]
fn a_sensing_action_without_a_configuration_goal_fails_at_once() {
    let blind = PlannedAction {
        goal: None,
        ..look()
    };
    let mut plan = plan();
    plan.steps = vec![blind];
    let domain = parse_domain(EYES.as_bytes()).expect("domain");
    let mut exec = Executive::new(domain, EcologyState::new(), plan, ExecConfig::default());
    exec.handle(Duration::ZERO, Event::Start);
    let RunStatus::Failed { reason, .. } = exec.status() else {
        panic!("not failed:\n{}", timeline(&exec));
    };
    assert_eq!(
        reason,
        "it observes (at ball kitchen) but has no configuration goal to observe with"
    );
}

#[test]
fn a_plan_without_branches_runs_as_a_sequence() {
    let plan: Plan = vec![plain("(a)"), plain("(b)")].into();
    assert!(!plan.is_conditional());
    assert_eq!((plan.depth(), plan.actions()), (2, 2));
    assert_eq!((self::plan().depth(), self::plan().actions()), (2, 3));
    let domain = parse_domain(EYES.as_bytes()).expect("domain");
    let mut exec = Executive::new(domain, EcologyState::new(), plan, ExecConfig::default());
    exec.handle(Duration::ZERO, Event::Start);
    assert_eq!(exec.status(), &RunStatus::Done);
    assert_eq!(started(&exec), ["(a)", "(b)"]);
}
