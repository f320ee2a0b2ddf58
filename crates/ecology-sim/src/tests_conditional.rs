//! Conditional plans in the simulated home (`scenarios/newspaper.toml`): the
//! seed draws where the newspaper lies, Astrid looks with her own camera and
//! object localizer, and the executive follows the branch of what the object
//! localizer reports; a failed action is planned again from the belief that
//! what was observed leaves.

use std::time::Duration;

use ecology_exec::{LogEvent, Observation, Plan, Replan, RunStatus};

use crate::tests::{load, run_seeded, timeline, world_tuple};
use crate::{FaultKind, FaultSpec, Report, Scenario, Trigger, WorldReplanner};

/// Seeds that draw the newspaper at the entrance (probability 0.7) and in the kitchen (0.3).
const AT_THE_ENTRANCE: u64 = 1;
const IN_THE_KITCHEN: u64 = 12;

/// The room the newspaper lies in at the start of a run with `seed`.
fn drawn_room(scenario: &Scenario, seed: u64) -> String {
    let world = scenario.world_for(seed);
    let (x, y) = world.things["newspaper"].at;
    world.map.room_at(x, y).expect("in a room").name.clone()
}

/// What `pick` takes from each entry of the log, in order.
fn from_log<T>(report: &Report, pick: impl Fn(&LogEvent) -> Option<T>) -> Vec<T> {
    report.tasks[0]
        .log
        .iter()
        .filter_map(|e| pick(&e.event))
        .collect()
}

/// (action, observation) of every `observed` event, in order.
fn observations(report: &Report) -> Vec<(String, String)> {
    from_log(report, |e| match e {
        LogEvent::Observed {
            action,
            observation,
            ..
        } => Some((action.clone(), observation.clone())),
        _ => None,
    })
}

/// The observation of every branch taken, in order.
fn branches(report: &Report) -> Vec<String> {
    from_log(report, |e| match e {
        LogEvent::Branch { observation, .. } => Some(observation.clone()),
        _ => None,
    })
}

/// The actions started, in order.
fn started(report: &Report) -> Vec<String> {
    from_log(report, |e| match e {
        LogEvent::ActionStarted { action, .. } => Some(action.clone()),
        _ => None,
    })
}

/// The newspaper in Astrid's gripper and Johanna awake, by the ground truth.
fn task_achieved(report: &Report) -> bool {
    report.world.things["newspaper"].holder.as_deref() == Some("astrid")
        && report.world.residents["johanna"].awake
}

#[test]
fn the_seed_draws_where_the_newspaper_lies() {
    let scenario = load("newspaper.toml");
    assert_eq!(drawn_room(&scenario, AT_THE_ENTRANCE), "entrance");
    assert_eq!(drawn_room(&scenario, IN_THE_KITCHEN), "kitchen");
    // Over many seeds, about as often as the problem says (0.7 and 0.3).
    let at_entrance = (0..1000)
        .filter(|&seed| drawn_room(&scenario, seed) == "entrance")
        .count();
    assert!((650..750).contains(&at_entrance), "{at_entrance} of 1000");
}

#[test]
fn the_plan_looks_at_the_entrance_and_branches_on_what_it_sees() {
    let plan = &load("newspaper.toml").tasks[0].plan;
    let steps: Vec<&str> = plan.steps.iter().map(|s| s.action.as_str()).collect();
    assert_eq!(
        steps,
        [
            "(move astrid living-room entrance)",
            "(look astrid newspaper entrance)"
        ]
    );
    assert_eq!(
        plan.steps[1].observe,
        ["(thing-at newspaper entrance)".to_string()]
    );
    let seen: Vec<(bool, f64)> = plan
        .branches
        .iter()
        .map(|b| (b.observation[0].holds, b.probability))
        .collect();
    assert_eq!(seen.len(), 2);
    for (holds, p) in seen {
        let expected = if holds { 0.7 } else { 0.3 };
        assert!((p - expected).abs() < 1e-9, "{holds}: {p}");
    }
}

#[tokio::test]
async fn astrid_sees_the_newspaper_at_the_entrance_and_takes_it_there() {
    let scenario = load("newspaper.toml");
    let report = run_seeded(&scenario, AT_THE_ENTRANCE).await;
    let text = timeline(&report);
    assert_eq!(report.status, RunStatus::Done, "{text}");
    assert_eq!(
        observations(&report),
        [(
            "(look astrid newspaper entrance)".to_string(),
            "(thing-at newspaper entrance)".to_string()
        )],
        "{text}"
    );
    assert_eq!(
        branches(&report),
        ["(thing-at newspaper entrance)"],
        "{text}"
    );
    assert!(
        started(&report).contains(&"(get astrid newspaper entrance)".to_string()),
        "{text}"
    );
    assert!(task_achieved(&report), "{text}");
    assert!(report.spurious.is_empty(), "{:?}", report.spurious);
}

#[tokio::test]
async fn astrid_does_not_see_it_at_the_entrance_and_fetches_it_from_the_kitchen() {
    let scenario = load("newspaper.toml");
    let report = run_seeded(&scenario, IN_THE_KITCHEN).await;
    let text = timeline(&report);
    assert_eq!(report.status, RunStatus::Done, "{text}");
    assert_eq!(
        observations(&report),
        [(
            "(look astrid newspaper entrance)".to_string(),
            "(not (thing-at newspaper entrance))".to_string()
        )],
        "{text}"
    );
    assert_eq!(
        branches(&report),
        ["(not (thing-at newspaper entrance))"],
        "{text}"
    );
    let actions = started(&report);
    assert!(
        actions.contains(&"(get astrid newspaper kitchen)".to_string()),
        "{text}"
    );
    assert!(
        !actions.contains(&"(get astrid newspaper entrance)".to_string()),
        "{text}"
    );
    assert!(task_achieved(&report), "{text}");
    assert!(report.spurious.is_empty(), "{:?}", report.spurious);
}

// Action-level recovery under uncertainty: Astrid's camera falls silent as
// she looks at the entrance, so her object localizer never runs, the look
// has no configuration left without it, and fails. The task is planned again from the belief (nothing observed yet),
// without that look: she goes to look in the kitchen instead (her camera is
// back by then) and follows the branch of what she sees there.
#[tokio::test]
async fn a_failed_look_is_planned_around_from_the_belief() {
    let mut scenario = load("newspaper.toml");
    let after_look_starts = |kind, delay| FaultSpec {
        kind,
        peis: "astrid".to_string(),
        component: Some("ca3".to_string()),
        trigger: Trigger::After {
            executive: None,
            event: "action_started".to_string(),
            action: Some(2),
            delay: Duration::from_secs_f64(delay),
        },
        cause: "lens covered".to_string(),
    };
    scenario.faults = vec![
        after_look_starts(FaultKind::Stall, 0.0),
        after_look_starts(FaultKind::Recover, 15.0),
    ];
    for seed in [AT_THE_ENTRANCE, IN_THE_KITCHEN] {
        let report = run_seeded(&scenario, seed).await;
        let text = timeline(&report);
        assert_eq!(report.status, RunStatus::Done, "seed {seed}:\n{text}");
        let replans = from_log(&report, |e| match e {
            LogEvent::Replanned { failed, .. } => Some(failed.clone()),
            _ => None,
        });
        assert_eq!(
            replans,
            ["(look astrid newspaper entrance)"],
            "seed {seed}:\n{text}"
        );
        let looked: Vec<(String, String)> = observations(&report);
        let kitchen = if seed == IN_THE_KITCHEN {
            "(thing-at newspaper kitchen)"
        } else {
            "(not (thing-at newspaper kitchen))"
        };
        assert_eq!(
            looked,
            [(
                "(look astrid newspaper kitchen)".to_string(),
                kitchen.to_string()
            )],
            "seed {seed}:\n{text}"
        );
        assert!(task_achieved(&report), "seed {seed}:\n{text}");
    }
}

/// The world's tuples with Astrid at the entrance and Johanna asleep.
fn world_with_astrid_at_the_entrance(scenario: &Scenario) -> Vec<ecology_tuples::Tuple> {
    vec![
        world_tuple("map", &scenario.world.map.to_string()),
        world_tuple("robots.astrid.pose", "3.750 4.000 0.0000"),
        world_tuple("residents.johanna.state", "asleep"),
        world_tuple("things.newspaper.holder", ""),
    ]
}

fn replan(observed: &[Observation]) -> Result<Plan, String> {
    let scenario = load("newspaper.toml");
    let (problem, _) = scenario.tasks[0].problem.clone().expect("a problem");
    let world = world_with_astrid_at_the_entrance(&scenario);
    WorldReplanner::new(scenario.tasks[0].domain.clone(), problem).replan(&[], observed, &world)
}

fn not_at(room: &str) -> Observation {
    Observation {
        atom: format!("(thing-at newspaper {room})"),
        holds: false,
    }
}

#[test]
fn a_replan_starts_from_the_belief_that_the_observations_leave() {
    // Nothing observed: Astrid, at the entrance, still has to look.
    let plan = replan(&[]).expect("a plan");
    assert_eq!(plan.steps[0].action, "(look astrid newspaper entrance)");
    assert!(plan.is_conditional());

    // Not at the entrance: then in the kitchen, certainly. No looking, no branches.
    let plan = replan(&[not_at("entrance")]).expect("a plan");
    assert!(!plan.is_conditional(), "{plan:?}");
    let actions: Vec<&str> = plan.steps.iter().map(|s| s.action.as_str()).collect();
    assert!(
        actions.iter().all(|a| !a.starts_with("(look")),
        "{actions:?}"
    );
    assert!(
        actions.contains(&"(get astrid newspaper kitchen)"),
        "{actions:?}"
    );

    // Neither here nor there: no world of the problem is left.
    let why = replan(&[not_at("entrance"), not_at("kitchen")]).expect_err("no belief");
    assert!(why.contains("rules out every initial world"), "{why}");
}

/// Whether two plans have the same actions, goals, observations and
/// (to the printed precision) probabilities.
fn same(a: &Plan, b: &Plan) -> bool {
    // Goals compare as text: where they were parsed from differs.
    let steps = |p: &Plan| -> Vec<(String, Option<String>, Vec<String>)> {
        p.steps
            .iter()
            .map(|s| {
                let goal = s.goal.as_ref().map(ToString::to_string);
                (s.action.clone(), goal, s.observe.clone())
            })
            .collect()
    };
    steps(a) == steps(b)
        && (a.success - b.success).abs() < 1e-6
        && a.branches.len() == b.branches.len()
        && a.branches.iter().zip(&b.branches).all(|(x, y)| {
            x.observation == y.observation
                && (x.probability - y.probability).abs() < 1e-6
                && same(&x.plan, &y.plan)
        })
}

#[test]
fn a_printed_conditional_plan_reads_back_as_the_same_plan() {
    let scenario = load("newspaper.toml");
    let (problem, _) = scenario.tasks[0].problem.clone().expect("a problem");
    let task = ecology_actions::ground(&scenario.tasks[0].domain, &problem).expect("grounds");
    let outcome = ecology_actions::plan_conditional(
        &ecology_actions::ConditionalRequest::new(&task),
        &ecology_actions::ConditionalOptions::default(),
        &ecology_actions::NoClock,
    );
    let ecology_actions::ConditionalVerdict::Found(plan) = outcome.verdict else {
        panic!("no plan: {:?}", outcome.verdict);
    };
    // What `ecology plan --conditional` prints, as `ecology task --plan` reads it.
    let printed = plan.display(&task).to_string();
    let read = ecology_exec::parse_plan(&printed).expect("reads");
    let planned = crate::executive_plan(&task, &plan.graph);
    assert!(same(&read, &planned), "{printed}\n{read:#?}\n{planned:#?}");
    assert!(same(&read, &scenario.tasks[0].plan), "{printed}");
}

#[test]
fn a_printed_plan_whose_branches_join_reads_back_as_the_same_plan() {
    let inst = ecology_actions::problems::tireworld(3).expect("generated");
    let task = ecology_actions::ground(&inst.domain, &inst.problem).expect("grounds");
    let options = ecology_actions::ConditionalOptions {
        horizon: 36,
        ..ecology_actions::ConditionalOptions::default()
    };
    let outcome = ecology_actions::plan_conditional(
        &ecology_actions::ConditionalRequest::new(&task),
        &options,
        &ecology_actions::NoClock,
    );
    let ecology_actions::ConditionalVerdict::Found(plan) = outcome.verdict else {
        panic!("no plan: {:?}", outcome.verdict);
    };
    let printed = plan.display(&task).to_string();
    assert!(printed.contains("go to [1]"), "{printed}");
    let read = ecology_exec::parse_plan(&printed).expect("reads");
    let planned = crate::executive_plan(&task, &plan.graph);
    assert!(same(&read, &planned), "{printed}");
    // The executive's plan shares what the graph shares: the tree it stands
    // for has many more actions than the text has lines.
    assert_eq!(read.actions() as u64, plan.graph.tree_actions());
    assert!(
        read.actions() > 10 * printed.lines().count(),
        "{}",
        read.actions()
    );
}
