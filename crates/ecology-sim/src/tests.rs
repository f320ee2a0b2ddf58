//! Tests of the simulator: the world's geometry and kinematics, scenario
//! files, and whole runs of the paper's experiment (Section VIII) and of
//! other scenarios in virtual time.

use std::path::{Path, PathBuf};
use std::time::Duration;

use ecology_exec::{Acquisition, LogChannel, LogComponent, LogEvent, LogFunctionality, RunStatus};

use crate::{
    FaultKind, FaultSpec, Map, PeisDef, Pose, Report, Rng, RunOptions, Scenario, ScenarioError,
    Trigger, match_scan, route, run, scan,
};

pub(crate) fn scenario_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scenarios")
        .join(name)
}

pub(crate) fn load(name: &str) -> Scenario {
    Scenario::load(&scenario_path(name)).expect("the scenario loads")
}

pub(crate) async fn run_seeded(scenario: &Scenario, seed: u64) -> Report {
    run(scenario, &RunOptions::seeded(seed), Box::new(|_| {}))
        .await
        .expect("the run completes")
}

pub(crate) fn timeline(report: &Report) -> String {
    let mut text = String::new();
    for (t, what) in &report.injected {
        text.push_str(&format!("{:>8.3}s  [sim] {what}\n", t.as_secs_f64()));
    }
    for entry in &report.tasks[0].log {
        text.push_str(&format!("{entry}\n"));
    }
    text
}

/// The configurations chosen, in order: (cost, reconfiguration, functionalities).
fn configurations(report: &Report) -> Vec<(u64, bool, Vec<String>)> {
    report.tasks[0]
        .log
        .iter()
        .filter_map(|e| match &e.event {
            LogEvent::Configuration {
                cost,
                reconfiguration,
                functionalities,
                ..
            } => Some((
                *cost,
                *reconfiguration,
                functionalities.iter().map(ToString::to_string).collect(),
            )),
            _ => None,
        })
        .collect()
}

/// The room robot `robot` is in at the end of the run.
fn room_of<'a>(report: &'a Report, robot: &str) -> Option<&'a str> {
    let pose = report.world.robots[robot].pose;
    report
        .world
        .map
        .room_at(pose.x, pose.y)
        .map(|r| r.name.as_str())
}

fn house() -> Map {
    let scenario = load("peis-home.toml");
    scenario.world.map
}

// --- the world -------------------------------------------------------------

#[test]
fn the_home_is_about_25_square_metres_and_routes_go_through_doors() {
    let map = house();
    let area: f64 = map
        .rooms
        .iter()
        .map(|r| (r.x1 - r.x0) * (r.y1 - r.y0))
        .sum();
    assert!((area - 25.0).abs() < 1e-9, "{area}");
    assert_eq!(
        route(&map, "living-room", "bedroom"),
        Some(vec![(2.75, 3.0), (2.5, 4.0), (1.25, 4.0)])
    );
    assert_eq!(route(&map, "bedroom", "bedroom"), Some(vec![(1.25, 4.0)]));
    assert_eq!(route(&map, "living-room", "garage"), None);
    assert_eq!(Map::parse(&map.to_string()), Ok(map));
}

#[test]
fn scan_matching_pulls_a_drifted_guess_back_to_the_truth() {
    let map = house();
    let truth = Pose::new(1.2, 1.9, 0.3);
    let ranges = scan(&map, truth);
    let drifted = Pose::new(1.4, 1.75, 0.33);
    let found = match_scan(&map, drifted, &ranges);
    assert!(found.distance_to(truth.x, truth.y) < 0.06, "{found:?}");
    assert!(drifted.distance_to(truth.x, truth.y) > 0.2);
}

#[test]
fn a_robot_drives_its_commanded_arc_with_bounded_noise() {
    let mut world = load("peis-home.toml").world;
    let mut rng = Rng::new(3);
    let robot = world.robots.get_mut("astrid").expect("astrid");
    let start = robot.pose;
    for _ in 0..20 {
        robot.command = (0.4, 0.0);
        robot.command_age = 0.0;
        robot.step(0.05, &mut rng);
    }
    let travelled = robot.pose.distance_to(start.x, start.y);
    assert!((travelled - 0.4).abs() < 0.03, "{travelled}");
    // Without commands the watchdog stops the base.
    let stopped = robot.pose;
    for _ in 0..40 {
        robot.step(0.05, &mut rng);
    }
    assert!(robot.pose.distance_to(stopped.x, stopped.y) < 0.25);
    assert_eq!(robot.command, (0.0, 0.0));
}

// --- scenario files ----------------------------------------------------------

fn parse(text: &str) -> Result<Scenario, ScenarioError> {
    let base = scenario_path("");
    Scenario::parse(text, "bad.toml", &|p: &Path| {
        std::fs::read(base.join(p)).map_err(|e| e.to_string())
    })
}

fn error_of(text: &str) -> String {
    match parse(text) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_scenario_files_are_reported_with_their_line() {
    let good = std::fs::read_to_string(scenario_path("kitchen.toml")).expect("reads");
    assert!(parse(&good).is_ok());

    let syntax = good.replace("seed = 11", "seed = = 11");
    let e = error_of(&syntax);
    assert!(e.starts_with("bad.toml:10:"), "{e}");

    let unknown_type = good.replace("type = \"laser\"", "type = \"lazer\"");
    let e = error_of(&unknown_type);
    assert!(e.starts_with("bad.toml:41:"), "{e}");
    assert!(e.contains("no simulated component of type `lazer`"), "{e}");

    let unknown_room = good.replace("[\"entrance\", \"bedroom\"]", "[\"entrance\", \"attic\"]");
    assert!(error_of(&unknown_room).starts_with("bad.toml:31:"));
    assert!(error_of(&unknown_room).contains("door to unknown room attic"));

    let unknown_peis = good.replace("peis = \"hsm\"\nafter", "peis = \"hms\"\nafter");
    let e = error_of(&unknown_peis);
    assert!(e.contains("fault on unknown PEIS hms"), "{e}");

    let unknown_field = good.replace("seed = 11", "sed = 11");
    assert!(error_of(&unknown_field).contains("unknown field `sed`"));

    // Times past what a Duration holds are errors, not panics.
    let forever = good.replace("time_limit = 120.0", "time_limit = 1.8e19");
    assert!(
        error_of(&forever).contains("time_limit must be a positive number of seconds"),
        "{}",
        error_of(&forever)
    );
    let late = good.replace("delay = 2.0", "delay = 1e300");
    assert!(
        error_of(&late).contains("delay must be seconds"),
        "{}",
        error_of(&late)
    );

    // A name that cannot be part of a tuple key used to hang the run.
    let spaced = good.replacen("name = \"astrid\"\nat", "name = \"ast rid\"\nat", 1);
    let e = error_of(&spaced);
    assert!(e.contains("`ast rid` cannot name a robot"), "{e}");
    assert!(e.starts_with("bad.toml:"), "{e}");
    let missing_domain = good.replace("../domains/peis-home.eco", "../domains/nowhere.eco");
    let e = error_of(&missing_domain);
    assert!(
        e.starts_with("bad.toml:15:") && e.contains("cannot read"),
        "{e}"
    );
}

/// A component may say which rooms it covers; they must be rooms of the map, each named once.
#[test]
fn the_rooms_a_camera_covers_are_rooms_of_the_map() {
    let good = std::fs::read_to_string(scenario_path("kitchen.toml")).expect("reads");
    let cams = "type = \"cams\",   cost = 20, on = true";
    assert!(good.contains(cams), "kitchen.toml changed");
    let covering = |rooms: &str| good.replace(cams, &format!("{cams}, covers = [{rooms}]"));
    let scenario = parse(&covering("\"kitchen\", \"living-room\"")).expect("loads");
    let hsm = scenario.peis.iter().find(|p| p.name == "hsm").expect("hsm");
    let covers: Vec<&[String]> = hsm.components.iter().map(|c| c.covers.as_slice()).collect();
    assert_eq!(covers, [&["kitchen", "living-room"][..], &[]]);

    let e = error_of(&covering("\"kitchen\", \"attic\""));
    assert!(e.starts_with("bad.toml:"), "{e}");
    assert!(
        e.contains("component hsm:ca1 covers attic, which is no room of the map"),
        "{e}"
    );
    let e = error_of(&covering("\"kitchen\", \"kitchen\""));
    assert!(e.contains("component ca1 covers kitchen twice"), "{e}");
    let e = error_of(&covering("\"kit chen\""));
    assert!(e.contains("`kit chen` cannot name a room it covers"), "{e}");
    let e = error_of(&covering("3"));
    assert!(e.starts_with("bad.toml:"), "{e}");
}

#[test]
fn scenario_files_are_read_with_a_size_limit_and_utf8_errors_have_a_place() {
    let e = PeisDef::load_all(Path::new("/dev/zero")).expect_err("not a scenario");
    assert!(
        e.to_string()
            .contains("larger than the limit of 8388608 bytes"),
        "{e}"
    );
    let folder = std::env::temp_dir().join(format!("ecology-utf8-{}", std::process::id()));
    std::fs::create_dir_all(&folder).expect("temp folder");
    let file = folder.join("bad.toml");
    std::fs::write(&file, b"name = \"x\"\n\n  seed = \"\xff\"\n").expect("write");
    let e = Scenario::load(&file).expect_err("not UTF-8");
    let _ = std::fs::remove_dir_all(&folder);
    assert!(
        e.to_string().ends_with("bad.toml:3:11: invalid UTF-8"),
        "{e}"
    );
}

// --- whole runs ---------------------------------------------------------------

// The paper's Section VIII, steps 1 to 7.
#[tokio::test]
async fn the_demo_reproduces_the_papers_experiment() {
    let report = run_seeded(&load("peis-home.toml"), 2007).await;
    let text = timeline(&report);
    assert_eq!(report.status, RunStatus::Done, "{text}");
    // Step 1: the plan.
    let Some(LogEvent::Plan { actions, .. }) = report.tasks[0].log.first().map(|e| &e.event) else {
        panic!("no plan first:\n{text}");
    };
    assert_eq!(
        actions,
        &[
            "(move astrid living-room entrance)",
            "(get astrid newspaper entrance)",
            "(move astrid entrance bedroom)",
            "(wake astrid johanna bedroom)",
        ]
    );
    // Steps 2 to 7: 80, the gripper, 80, the failure, 170 with the laser, the speaker.
    let configs = configurations(&report);
    let costs: Vec<(u64, bool)> = configs.iter().map(|(c, r, _)| (*c, *r)).collect();
    assert_eq!(
        costs,
        [
            (80, false),
            (100, false),
            (80, false),
            (170, true),
            (20, false)
        ],
        "{text}"
    );
    assert!(configs[1].2[0].contains("on astrid:gr1"), "{text}");
    assert!(configs[4].2[0].contains("on astrid:sp1"), "{text}");
    let failures: Vec<&LogEvent> = report.tasks[0]
        .log
        .iter()
        .map(|e| &e.event)
        .filter(|e| matches!(e, LogEvent::Failure { .. }))
        .collect();
    assert!(
        matches!(failures.as_slice(), [LogEvent::Failure { peis, component, cause }]
            if peis == "hsm" && component == "tr1" && cause.contains("camera")),
        "{text}"
    );
    let switched_on_laser = report.tasks[0].log.iter().any(|e| {
        matches!(&e.event, LogEvent::Deployed { switched_on, .. }
            if switched_on.iter().any(|c| c.to_string() == "astrid:l1"))
    });
    assert!(switched_on_laser, "{text}");
    assert_eq!(
        report.tasks[0].log.last().map(|e| e.event.name()),
        Some("task_done")
    );
    // And the world agrees: Astrid is in the bedroom holding the newspaper, Johanna awake.
    assert_eq!(
        room_of(&report, "astrid"),
        Some("bedroom"),
        "{:?}",
        report.world.robots["astrid"].pose
    );
    assert_eq!(
        report.world.things["newspaper"].holder.as_deref(),
        Some("astrid")
    );
    assert!(report.world.residents["johanna"].awake);
    assert!(!report.timed_out);
}

// Without the fault, the tracking system never fails and the laser stays off.
#[tokio::test]
async fn without_the_fault_the_cameras_serve_both_moves() {
    let mut scenario = load("peis-home.toml");
    scenario.faults.clear();
    let report = run_seeded(&scenario, 5).await;
    let costs: Vec<u64> = configurations(&report).iter().map(|c| c.0).collect();
    assert_eq!(costs, [80, 100, 80, 20], "{}", timeline(&report));
    assert_eq!(report.status, RunStatus::Done);
}

// A tracking system that writes global positions nobody can read is blamed
// by pose tracking, which keeps its place and runs scan matching instead.
#[tokio::test]
async fn a_producer_of_unreadable_values_is_excluded_and_its_consumer_is_not() {
    let mut scenario = load("peis-home.toml");
    scenario.faults = vec![FaultSpec {
        kind: FaultKind::Garble,
        peis: "hsm".into(),
        component: Some("tr1".into()),
        trigger: Trigger::At(Duration::ZERO),
        cause: String::new(),
    }];
    let report = run_seeded(&scenario, 7).await;
    let text = timeline(&report);
    assert_eq!(report.status, RunStatus::Done, "{text}");
    let failures: Vec<(&str, &str, &str)> = report.tasks[0]
        .log
        .iter()
        .filter_map(|e| e.event.failure())
        .collect();
    // Once in each move: exclusions last one action.
    assert_eq!(failures.len(), 2, "{text}");
    for (peis, component, cause) in failures {
        assert_eq!((peis, component), ("hsm", "tr1"), "{text}");
        assert!(
            cause.starts_with("astrid:s1 cannot read its global-pos: expected X Y THETA"),
            "{cause}"
        );
    }
    let costs: Vec<(u64, bool)> = configurations(&report).iter().map(|c| (c.0, c.1)).collect();
    assert_eq!(
        costs,
        [
            (80, false),
            (170, true),
            (100, false),
            (80, false),
            (170, true),
            (20, false)
        ],
        "{text}"
    );
    assert!(report.spurious.is_empty(), "{:?}", report.spurious);
}

// Every output the simulated components write in the paper's run is in the
// format the domain declares for its information type.
#[tokio::test]
async fn simulated_outputs_are_written_as_the_domain_declares() {
    use std::collections::BTreeMap;
    use std::sync::{Arc, Mutex};
    let scenario = load("peis-home.toml");
    let formats: BTreeMap<String, ecology_domain::Format> = scenario.tasks[0]
        .domain
        .information
        .iter()
        .map(|i| (i.name.to_string(), i.format.clone()))
        .collect();
    assert_eq!(formats.len(), 5, "{formats:?}");
    let seen: Arc<Mutex<Vec<(String, String)>>> = Arc::default();
    let sink = seen.clone();
    let options = RunOptions {
        observe_tuples: true,
        ..RunOptions::seeded(2007)
    };
    let report = run(
        &scenario,
        &options,
        Box::new(move |update| {
            if let crate::Update::Tuple(ecology_tuples::TupleEvent::Changed(t)) = update
                && let Some((_, info)) = t.key.as_str().split_once(".out.")
            {
                let text = t.text().unwrap_or("").to_string();
                sink.lock().expect("lock").push((info.to_string(), text));
            }
        }),
    )
    .await
    .expect("the run completes");
    assert_eq!(report.status, RunStatus::Done, "{}", timeline(&report));
    let seen = seen.lock().expect("lock");
    let mut checked: BTreeMap<&str, usize> = BTreeMap::new();
    for (info, text) in seen.iter() {
        if let Some(format) = formats.get(info) {
            assert_eq!(format.check(text), Ok(()), "{info}");
            *checked.entry(info).or_default() += 1;
        }
    }
    let kinds: Vec<&str> = checked.keys().copied().collect();
    assert_eq!(
        kinds,
        ["global-pos", "image", "odometry", "position", "range-scan"],
        "{checked:?}"
    );
}

// A second scenario: a PEIS crashes and comes back.
#[tokio::test]
async fn the_kitchen_scenario_survives_a_crash_of_the_monitor() {
    let report = run_seeded(&load("kitchen.toml"), 11).await;
    let text = timeline(&report);
    assert_eq!(report.status, RunStatus::Done, "{text}");
    assert!(text.contains("PEIS hsm left the ecology"), "{text}");
    let costs: Vec<(u64, bool)> = configurations(&report).iter().map(|c| (c.0, c.1)).collect();
    assert_eq!(costs, [(80, false), (170, true), (80, false)], "{text}");
    assert_eq!(room_of(&report, "astrid"), Some("bedroom"));
}

// Random fault schedules never leave the executive stuck: each run ends with
// the task done or failed with a reason, within the time limit, and the same
// seed gives the same run.
#[tokio::test]
async fn random_fault_schedules_always_end_and_are_reproducible() {
    let base = load("peis-home.toml");
    let mut outcomes = Vec::new();
    for seed in 0..10 {
        let scenario = crate::with_random_faults(&base, seed);
        let report = run_seeded(&scenario, seed).await;
        let text = timeline(&report);
        assert!(!report.timed_out, "seed {seed} is stuck:\n{text}");
        assert_eq!(
            report.spurious,
            Vec::<String>::new(),
            "seed {seed}:\n{text}"
        );
        match &report.status {
            RunStatus::Done => {}
            RunStatus::Failed { reason, .. } => {
                assert!(!reason.is_empty(), "seed {seed}:\n{text}")
            }
            other => panic!("seed {seed}: {other:?}\n{text}"),
        }
        let last = report.tasks[0].log.last().map(|e| e.event.name());
        assert!(
            matches!(last, Some("task_done" | "task_failed")),
            "seed {seed}:\n{text}"
        );
        assert!(report.sim_time <= scenario.time_limit + Duration::from_secs(1));
        outcomes.push((seed, report.status.clone()));
        if seed < 3 {
            let again = run_seeded(&scenario, seed).await;
            // The same events in the same order at the same virtual times.
            let lines = |r: &Report| {
                r.tasks[0]
                    .log
                    .iter()
                    .map(|e| format!("{e:?}"))
                    .collect::<Vec<_>>()
            };
            let (first, second) = (lines(&report), lines(&again));
            let differ = first.iter().zip(&second).find(|(a, b)| a != b);
            assert!(
                differ.is_none() && first.len() == second.len(),
                "seed {seed} is not reproducible: {differ:?}\n{text}"
            );
        }
    }
    // The schedules are varied enough to exercise both endings.
    assert!(
        outcomes.iter().any(|(_, s)| *s == RunStatus::Done),
        "{outcomes:?}"
    );
    assert!(
        outcomes
            .iter()
            .any(|(_, s)| matches!(s, RunStatus::Failed { .. })),
        "{outcomes:?}"
    );
}

// The paper's Section VII, action-level recovery: Astrid's move has no
// configuration left, the task is planned again without it from the world as
// observed, and Pippi wakes Johanna.
#[tokio::test]
async fn a_failed_action_is_planned_around_and_another_robot_goes() {
    let scenario = load("replan.toml");
    let report = run_seeded(&scenario, scenario.seed).await;
    let text = timeline(&report);
    assert_eq!(report.status, RunStatus::Done, "{text}");
    let replans: Vec<(String, Vec<String>)> = report.tasks[0]
        .log
        .iter()
        .filter_map(|e| match &e.event {
            LogEvent::Replanned {
                failed, actions, ..
            } => Some((failed.clone(), actions.clone())),
            _ => None,
        })
        .collect();
    assert_eq!(
        replans,
        [(
            "(move astrid living-room entrance)".to_string(),
            [
                "(move pippi kitchen living-room)",
                "(move pippi living-room entrance)",
                "(move pippi entrance bedroom)",
                "(wake pippi johanna bedroom)"
            ]
            .map(String::from)
            .to_vec()
        )],
        "{text}"
    );
    assert!(report.world.residents["johanna"].awake, "{text}");
    assert_eq!(room_of(&report, "pippi"), Some("bedroom"));
}

// With both robots unable to localize, no plan remains: the task fails with
// the action planner's reason, and what it switched on is switched off.
#[tokio::test]
async fn when_no_plan_remains_the_task_fails_and_switches_everything_off() {
    let scenario = load("no-plan.toml");
    let report = run_seeded(&scenario, scenario.seed).await;
    let text = timeline(&report);
    assert!(matches!(report.status, RunStatus::Failed { .. }), "{text}");
    let names: Vec<&str> = report.tasks[0].log.iter().map(|e| e.event.name()).collect();
    assert_eq!(
        names.iter().filter(|n| **n == "replan").count(),
        1,
        "{text}"
    );
    assert_eq!(
        names[names.len() - 2..],
        ["released", "task_failed"],
        "{text}"
    );
    let Some(LogEvent::Released { switched_off, .. }) = report.tasks[0]
        .log
        .iter()
        .map(|e| &e.event)
        .find(|e| e.name() == "released")
    else {
        panic!("released: {text}");
    };
    let switched_off: Vec<String> = switched_off.iter().map(ToString::to_string).collect();
    assert_eq!(switched_off, ["astrid:l1".to_string()], "{text}");
    let Some(LogEvent::TaskFailed { reason }) = report.tasks[0].log.last().map(|e| &e.event) else {
        panic!("task_failed: {text}");
    };
    assert!(
        reason.contains("no plan remains: the goal is unreachable"),
        "{reason}"
    );
}

// The world for replanning is what the world PEIS shows, not what the plan assumed.
#[test]
fn a_replan_starts_from_the_world_as_observed() {
    use ecology_exec::Replan;
    let scenario = load("replan.toml");
    let (problem, _) = scenario.tasks[0].problem.clone().expect("a problem");
    let mut replanner = crate::WorldReplanner::new(scenario.tasks[0].domain.clone(), problem);
    let tuple = world_tuple;
    // Astrid has already reached the entrance; the problem says the living room.
    let world = vec![
        tuple("map", &scenario.world.map.to_string()),
        tuple("robots.astrid.pose", "3.700 4.000 0.0000"),
        tuple("robots.pippi.pose", "4.000 1.500 3.1416"),
        tuple("residents.johanna.state", "asleep"),
    ];
    let plan = replanner.replan(&[], &[], &world).expect("a plan");
    let actions: Vec<&str> = plan.steps.iter().map(|a| a.action.as_str()).collect();
    assert_eq!(
        actions,
        [
            "(move astrid entrance bedroom)",
            "(wake astrid johanna bedroom)"
        ]
    );
    // Johanna already awake: nothing left to do.
    let awake = vec![tuple("residents.johanna.state", "awake")];
    assert_eq!(
        replanner.replan(&[], &[], &awake).expect("a plan"),
        ecology_exec::Plan::default()
    );
}

/// A tuple of the `world` PEIS, as the replanner reads it.
pub(crate) fn world_tuple(key: &str, value: &str) -> ecology_tuples::Tuple {
    use ecology_tuples::{Key, PeisId, Timestamp, Tuple};
    Tuple {
        owner: PeisId::new("world").expect("name"),
        key: Key::new(key).expect("key"),
        data: bytes_of(value),
        mimetype: ecology_tuples::Mimetype::new("text/plain").expect("mimetype"),
        ts_write: Timestamp(1),
        ts_user: None,
        expiry: None,
        seq: 1,
        epoch: 1,
        creator: None,
    }
}

fn bytes_of(text: &str) -> bytes::Bytes {
    bytes::Bytes::copy_from_slice(text.as_bytes())
}

/// The on-demand executive (the default) reads only the PEIS its goals name and those that cover
/// the rooms its actions start in, and chooses exactly the configurations the executive reading
/// everything chooses.
#[tokio::test]
async fn acquired_on_demand_the_configurations_are_those_of_the_whole_state() {
    let domain = scenario_path("../domains/peis-building.eco");
    let problem = scenario_path("../domains/peis-home-task.problem");
    let (domain, problem) = (domain.display().to_string(), problem.display().to_string());
    let mut reconfigured = 0;
    let mut intakes = Vec::new();
    for (peis, seed) in [(40, 11), (150, 12)] {
        let text = crate::generate::home(peis, seed, &domain, &problem).expect("generated");
        let load = |text: &str| {
            Scenario::parse(text, "home.toml", &|p: &Path| {
                std::fs::read(p).map_err(|e| e.to_string())
            })
            .expect("the generated scenario loads")
        };
        // The first move's tracking system, wherever it is, fails a second into the move.
        let first = run_seeded(&load(&text), seed).await;
        let tracker = configurations(&first)[0]
            .2
            .iter()
            .find_map(|f| {
                let on = f.split(" on ").nth(1)?;
                f.starts_with("(tracking-system").then(|| on.to_string())
            })
            .expect("the first move is tracked by a monitor");
        let (monitor, component) = tracker.split_once(':').expect("PEIS:COMPONENT");
        let faulted = format!(
            "{text}\n[[fault]]\nwhat = \"fail\"\npeis = \"{monitor}\"\ncomponent = \"{component}\"\n\
             after = {{ event = \"action_started\", action = 1 }}\ndelay = 1.0\n"
        );
        let scenario = load(&faulted);
        let with = |acquisition| RunOptions {
            acquisition,
            ..RunOptions::seeded(seed)
        };
        let quiet = || -> crate::Observer { Box::new(|_| {}) };
        let on_demand = run(&scenario, &with(Acquisition::OnDemand), quiet())
            .await
            .expect("runs");
        let everything = run(&scenario, &with(Acquisition::Everything), quiet())
            .await
            .expect("runs");
        let text = timeline(&on_demand);
        assert_eq!(on_demand.status, RunStatus::Done, "{text}");
        assert_eq!(
            configurations(&on_demand),
            configurations(&everything),
            "{peis} PEIS: on demand\n{text}\neverything\n{}",
            timeline(&everything)
        );
        reconfigured += configurations(&on_demand).iter().filter(|c| c.1).count();
        let (mine, all) = (on_demand.tasks[0].intake, everything.tasks[0].intake);
        assert!(
            !mine.everything && all.everything,
            "{mine:?} against {all:?}"
        );
        assert!(
            mine.tuples * 3 < all.tuples && mine.bytes * 3 < all.bytes,
            "{mine:?} against {all:?}"
        );
        // In the building's domain every PEIS a configuration can use is Astrid or covers the
        // room a move starts in: Astrid, hsm (the home's ceiling cameras) and Pippi (her camera
        // sees the living room she stands in), whatever the size of the building.
        assert_eq!(mine.scope, Some((3, 2)), "{mine:?}");
        intakes.push(mine.tuples);
    }
    assert!(reconfigured > 0, "no fault changed a configuration");
    // What on demand takes in does not grow with the building (it is not the same: each home
    // has its own seed, and its faulted tracker fails at its own moment).
    assert!(intakes[1] < intakes[0] * 2, "{intakes:?}");
}

// A generated building: the same seed gives the same file, it loads, and the paper's task is
// done in it. Some of its new monitors would be cheaper routes than hsm's, but their cameras
// cover wing rooms, not Astrid's: the navigation is tracked by hsm's, which cover the home.
#[tokio::test]
async fn a_generated_home_runs_the_papers_task() {
    let domain = scenario_path("../domains/peis-building.eco");
    let problem = scenario_path("../domains/peis-home-task.problem");
    let (domain, problem) = (domain.display().to_string(), problem.display().to_string());
    let text = crate::generate::home(60, 3, &domain, &problem).expect("generated");
    assert_eq!(
        text,
        crate::generate::home(60, 3, &domain, &problem).expect("generated")
    );
    assert_ne!(
        text,
        crate::generate::home(60, 4, &domain, &problem).expect("generated")
    );
    assert!(crate::generate::home(3, 3, &domain, &problem).is_err());
    let scenario = Scenario::parse(&text, "home-60.toml", &|p: &Path| {
        std::fs::read(p).map_err(|e| e.to_string())
    })
    .expect("the generated scenario loads");
    assert_eq!(scenario.peis.len(), 59, "every PEIS but the world");
    let report = run_seeded(&scenario, 3).await;
    let text = timeline(&report);
    assert_eq!(report.status, RunStatus::Done, "{text}");
    let cheaper = scenario.peis.iter().find(|p| {
        let cost = |ty: &str| p.components.iter().find(|c| c.kind == ty).map(|c| c.cost);
        p.name.starts_with("mon-")
            && p.components.iter().all(|c| c.on)
            && cost("cams")
                .zip(cost("tr-sys"))
                .is_some_and(|(a, b)| a + b < 40)
    });
    let cheaper = cheaper.expect("a monitor cheaper than hsm's cameras and tracker (40)");
    assert!(
        cheaper
            .components
            .iter()
            .any(|c| c.covers.iter().any(|r| r.starts_with("wing-"))),
        "{cheaper:?}"
    );
    let navigations: Vec<_> = configurations(&report)
        .into_iter()
        .filter(|c| c.2.iter().any(|f| f.starts_with("(navigation")))
        .collect();
    assert_eq!(navigations.len(), 2, "{text}");
    for (cost, _, functionalities) in navigations {
        assert_eq!(cost, 80, "{text}");
        assert!(
            functionalities
                .iter()
                .any(|f| f == "(tracking-system hsm tr1 astrid) on hsm:tr1"),
            "{functionalities:?}"
        );
    }
}

// --- several tasks -------------------------------------------------------------

/// The configurations' costs of the task of `executive`, in order.
fn costs_of(report: &Report, executive: &str) -> Vec<u64> {
    let task = report
        .tasks
        .iter()
        .find(|t| t.executive == executive)
        .unwrap_or_else(|| panic!("no task of {executive}"));
    task.log
        .iter()
        .filter_map(|e| match &e.event {
            LogEvent::Configuration { cost, .. } => Some(*cost),
            _ => None,
        })
        .collect()
}

/// Every task's timeline, one after the other.
fn timelines(report: &Report) -> String {
    let mut text = String::new();
    for task in &report.tasks {
        text.push_str(&format!("[{}] {:?}\n", task.executive, task.status));
        for entry in &task.log {
            text.push_str(&format!("[{}] {entry}\n", task.executive));
        }
    }
    text
}

// The paper's two robots each with an executive of its own (its Section VIII
// has each robot carry its own planners), one tracking system between them:
// its PEIS gives it to one and refuses the other, which takes its own laser.
#[tokio::test]
async fn two_tasks_share_the_home_and_one_tracking_system_serves_one_of_them() {
    let scenario = load("two-robots.toml");
    let executives: Vec<&str> = scenario
        .tasks
        .iter()
        .map(|t| t.executive.as_str())
        .collect();
    assert_eq!(executives, ["exec-astrid", "exec-bob"]);
    assert!(scenario.world.robots.contains_key("bob"));
    let report = run_seeded(&scenario, scenario.seed).await;
    let text = timelines(&report);
    assert_eq!(report.status, RunStatus::Done, "{text}");
    for task in &report.tasks {
        assert_eq!(task.status, RunStatus::Done, "{text}");
    }
    assert!(report.spurious.is_empty(), "{:?}", report.spurious);
    assert!(
        report.conflicts.is_empty(),
        "{:?}\n{text}",
        report.conflicts
    );
    // One takes the tracker (80); the other is refused it and takes its laser (170),
    // its first choice held, never failed.
    let mut last: Vec<u64> = ["exec-astrid", "exec-bob"]
        .iter()
        .map(|e| *costs_of(&report, e).last().expect("a configuration"))
        .collect();
    last.sort_unstable();
    assert_eq!(last, [80, 170], "{text}");
    assert!(text.contains("held"), "{text}");
    for task in &report.tasks {
        assert!(
            !task
                .log
                .iter()
                .any(|e| matches!(e.event, LogEvent::Failure { .. })),
            "{text}"
        );
    }
    assert_eq!(room_of(&report, "astrid"), Some("bedroom"), "{text}");
    assert_eq!(room_of(&report, "bob"), Some("kitchen"), "{text}");
}

// A task's executive joins at its start time, and its log is timed from the
// start of the run.
#[tokio::test]
async fn a_task_starts_at_its_start_time() {
    let text = std::fs::read_to_string(scenario_path("two-robots.toml")).expect("reads");
    let later = text.replacen("start = 0.0", "start = 2.0", 1);
    assert_ne!(text, later);
    let scenario = parse(&later).expect("parses");
    assert_eq!(scenario.tasks[0].start, Duration::from_secs(2));
    let report = run_seeded(&scenario, scenario.seed).await;
    let text = timelines(&report);
    assert_eq!(report.status, RunStatus::Done, "{text}");
    let plan_at = |executive: &str| {
        let task = report.tasks.iter().find(|t| t.executive == executive);
        let first = task.and_then(|t| t.log.first()).expect("a log");
        assert_eq!(first.event.name(), "plan", "{text}");
        first.t
    };
    assert!(plan_at("exec-astrid") >= Duration::from_secs(2), "{text}");
    assert!(plan_at("exec-bob") < Duration::from_secs(1), "{text}");
    assert!(report.conflicts.is_empty(), "{:?}", report.conflicts);
}

#[test]
fn bad_tasks_are_reported_with_their_line() {
    let good = std::fs::read_to_string(scenario_path("two-robots.toml")).expect("reads");
    assert!(parse(&good).is_ok());
    let twice = good.replacen("\"exec-bob\"", "\"exec-astrid\"", 1);
    let e = error_of(&twice);
    let (second, _) = twice
        .match_indices("executive = \"exec-astrid\"")
        .nth(1)
        .expect("twice");
    let line = twice[..second].lines().count() + 1;
    assert!(e.starts_with(&format!("bad.toml:{line}:")), "{e}");
    assert!(
        e.contains("executive exec-astrid is named by two tasks"),
        "{e}"
    );

    let a_peis = good.replacen("\"exec-bob\"", "\"hsm\"", 1);
    let e = error_of(&a_peis);
    assert!(
        e.contains("executive hsm has the name of a PEIS of the scenario"),
        "{e}"
    );
    let world = good.replacen("\"exec-bob\"", "\"world\"", 1);
    assert!(error_of(&world).contains("`world` cannot name an executive"));
    let spaced = good.replacen("\"exec-bob\"", "\"exec bob\"", 1);
    assert!(error_of(&spaced).contains("`exec bob` cannot name an executive"));

    let unnamed = good.replacen("executive = \"exec-bob\"\n", "", 1);
    let e = error_of(&unnamed);
    assert!(e.contains("a [[tasks]] table needs `executive`"), "{e}");
    assert!(e.starts_with("bad.toml:"), "{e}");

    let late = good.replacen("start = 0.0", "start = 500.0", 1);
    let e = error_of(&late);
    assert!(
        e.contains("start of exec-astrid must be seconds before the time_limit (120 s)"),
        "{e}"
    );

    let both = good.replacen(
        "[[tasks]]",
        "[task]\ndomain = \"../domains/peis-home.eco\"\nplan = []\n\n[[tasks]]",
        1,
    );
    let e = error_of(&both);
    assert!(e.contains("both [task] and [[tasks]]"), "{e}");
    let none = good.replace("[[tasks]]", "[[not-tasks]]");
    assert!(error_of(&none).contains("unknown field `not-tasks`"));

    // `[task]` stays one executive named `executive`, starting at once.
    let kitchen = std::fs::read_to_string(scenario_path("kitchen.toml")).expect("reads");
    let scenario = parse(&kitchen).expect("parses");
    assert_eq!(scenario.tasks.len(), 1);
    assert_eq!(scenario.tasks[0].executive, "executive");
    let named = kitchen.replacen("[task]\n", "[task]\nexecutive = \"exec-astrid\"\n", 1);
    let e = error_of(&named);
    assert!(
        e.contains("[task] runs one executive named `executive`"),
        "{e}"
    );
    let e = error_of("name = \"x\"\n[map]\nrooms = []\n");
    assert!(e.contains("no task: give one [task] table"), "{e}");

    // A fault after an event of an executive keys to the one named, or the first task's.
    let fault = |after: &str| {
        format!(
            "{good}\n[[fault]]\nwhat = \"fail\"\npeis = \"hsm\"\ncomponent = \"tr1\"\nafter = {after}\n"
        )
    };
    let scenario = parse(&fault(
        "{ event = \"action_started\", action = 1, executive = \"exec-bob\" }",
    ))
    .expect("parses");
    assert!(matches!(
        &scenario.faults[0].trigger,
        Trigger::After { executive: Some(e), .. } if e == "exec-bob"
    ));
    let e = error_of(&fault(
        "{ event = \"action_started\", executive = \"exec-carl\" }",
    ));
    assert!(
        e.contains("no task's executive is named exec-carl (executives: exec-astrid, exec-bob)"),
        "{e}"
    );
    let e = error_of(&fault(
        "{ event = \"action_started\", action = 2, executive = \"exec-bob\" }",
    ));
    assert!(e.contains("the plan of exec-bob has actions 1 to 1"), "{e}");
}

fn refs(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

// The ground-truth check of several executives, fed by hand: it fires when a
// component another executive runs is given other params or re-wired, and
// not for an executive's own reconfigurations, a lost race, sharing, or a
// component taken after its user let it go.
#[test]
fn the_conflict_check_fires_when_a_component_serves_two_executives() {
    use crate::conflicts::{Change, ConflictCheck};
    let component = |at: &str| {
        let (peis, component) = at.split_once(':').expect("P:C");
        LogComponent::new(peis, component)
    };
    let configuration = |functionalities: &[&str]| LogEvent::Configuration {
        goal: "(navigate astrid bedroom)".into(),
        cost: 80,
        optimal: true,
        functionalities: functionalities
            .iter()
            .map(|f| {
                // `(CALL ARG…) on PEIS:COMPONENT`
                let (call, at) = f.rsplit_once(" on ").expect("CALL on P:C");
                LogFunctionality {
                    call: call.to_string(),
                    component: component(at),
                }
            })
            .collect(),
        alternatives: vec![80],
        reconfiguration: false,
        micros: 0,
    };
    let deployed = |channels: &[&str]| LogEvent::Deployed {
        switched_on: Vec::new(),
        channels: channels
            .iter()
            .map(|c| {
                // `Q:D → P:C (INFO …)`
                let (from, rest) = c.split_once(" → ").expect("Q:D → P:C INFO");
                let (to, info) = rest.split_once(' ').expect("P:C INFO");
                LogChannel {
                    from: component(from),
                    to: component(to),
                    info: info.into(),
                }
            })
            .collect(),
    };
    let set = |check: &mut ConflictCheck, s: f64, key: &str, value: &str, by: &str| {
        let (owner, key) = key.split_once(':').expect("P:KEY");
        check.changed(
            Duration::from_secs_f64(s),
            Change {
                owner,
                key,
                value,
                epoch: 1,
                creator: Some(by),
            },
        );
    };
    let astrid = "(tracking-system hsm tr1 astrid)";
    let bob = "(tracking-system hsm tr1 bob)";
    let tracked = |who: &str| {
        vec![
            format!("(tracking-system hsm tr1 {who}) on hsm:tr1"),
            format!("(pose-tracking {who} s1) on {who}:s1"),
        ]
    };

    // Without arbitration: Bob's executive re-aims the tracker Astrid's runs.
    let mut check = ConflictCheck::default();
    let a = tracked("astrid");
    let b = tracked("bob");
    check.logged("exec-astrid", &configuration(&refs(&a)));
    check.logged("exec-bob", &configuration(&refs(&b)));
    set(&mut check, 0.2, "hsm:tr1.params", astrid, "exec-astrid");
    assert!(check.conflicts().is_empty(), "{:?}", check.conflicts());
    set(&mut check, 0.25, "hsm:tr1.params", bob, "exec-bob");
    assert_eq!(
        check.conflicts(),
        [
            "0.250s hsm:tr1 ran (tracking-system hsm tr1 astrid) for exec-astrid when exec-bob gave it (tracking-system hsm tr1 bob)"
        ]
    );

    // With arbitration: Bob's request is refused and he takes his laser; Astrid's
    // executive reconfigures its own tracker (make-before-break); she ends and
    // releases it, and then Bob may take it.
    let mut check = ConflictCheck::default();
    check.logged("exec-astrid", &configuration(&refs(&a)));
    check.logged("exec-bob", &configuration(&refs(&b)));
    set(&mut check, 0.2, "hsm:tr1.params", astrid, "exec-astrid");
    check.logged(
        "exec-bob",
        &configuration(&[
            "(laser bob l1) on bob:l1",
            "(pose-tracking bob s1) on bob:s1",
        ]),
    );
    check.logged(
        "exec-astrid",
        &configuration(&["(tracking-system hsm tr1 astrid-again) on hsm:tr1"]),
    );
    set(
        &mut check,
        3.0,
        "hsm:tr1.params",
        "(tracking-system hsm tr1 astrid-again)",
        "exec-astrid",
    );
    check.logged(
        "exec-astrid",
        &LogEvent::Released {
            switched_off: Vec::new(),
            stopped: vec![LogComponent::new("hsm", "tr1")],
            unreachable: Vec::new(),
        },
    );
    set(&mut check, 9.0, "hsm:tr1.params", "", "exec-astrid");
    check.logged("exec-bob", &configuration(&refs(&b)));
    set(&mut check, 9.5, "hsm:tr1.params", bob, "exec-bob");
    assert!(check.conflicts().is_empty(), "{:?}", check.conflicts());

    // Shared with the same params: not a conflict; then the input re-pointed
    // away from what Astrid's executive wired is one.
    let mut check = ConflictCheck::default();
    let wiring = ["hsm:tr1 → astrid:s1 (global-pos astrid)"];
    check.logged("exec-astrid", &configuration(&refs(&a)));
    check.logged("exec-astrid", &deployed(&wiring));
    set(
        &mut check,
        0.2,
        "astrid:s1.params",
        "(pose-tracking astrid s1)",
        "exec-astrid",
    );
    set(&mut check, 0.2, "hsm:tr1.params", astrid, "exec-astrid");
    check.logged("exec-bob", &configuration(&refs(&a)));
    set(&mut check, 0.3, "hsm:tr1.params", astrid, "exec-bob");
    set(
        &mut check,
        0.4,
        "astrid:s1.mi-global-pos",
        "(meta hsm tr1.out.global-pos)",
        "exec-astrid",
    );
    assert!(check.conflicts().is_empty(), "{:?}", check.conflicts());
    set(
        &mut check,
        0.5,
        "astrid:s1.mi-global-pos",
        "(meta bob s1.out.global-pos)",
        "exec-bob",
    );
    assert_eq!(
        check.conflicts(),
        [
            "0.500s astrid:s1's input global-pos was pointed at (meta bob s1.out.global-pos) by exec-bob while exec-astrid wires it to (meta hsm tr1.out.global-pos)"
        ]
    );

    // A PEIS that starts again runs nobody's params: taking its tracker then is no conflict.
    let mut check = ConflictCheck::default();
    check.logged("exec-astrid", &configuration(&refs(&a)));
    set(&mut check, 0.2, "hsm:tr1.params", astrid, "exec-astrid");
    check.changed(
        Duration::from_secs(5),
        Change {
            owner: "hsm",
            key: "components.tr1.type",
            value: "tr-sys",
            epoch: 2,
            creator: None,
        },
    );
    check.changed(
        Duration::from_secs(6),
        Change {
            owner: "hsm",
            key: "tr1.params",
            value: bob,
            epoch: 2,
            creator: Some("exec-bob"),
        },
    );
    assert!(check.conflicts().is_empty(), "{:?}", check.conflicts());

    // An executive that reconfigures twice in one instant: its first request lands after its
    // second configuration is logged (the PEIS applies its requests in order). Its own, so no
    // conflict; the same request from another executive is one.
    let scan = "(scan-matching astrid s1)";
    let track = "(pose-tracking astrid s1)";
    let twice = |by: &str| {
        let mut check = ConflictCheck::default();
        check.logged(
            "exec-astrid",
            &configuration(&[&format!("{track} on astrid:s1")]),
        );
        set(&mut check, 0.2, "astrid:s1.params", track, "exec-astrid");
        check.logged(
            "exec-astrid",
            &configuration(&[&format!("{scan} on astrid:s1")]),
        );
        check.logged(
            "exec-astrid",
            &configuration(&[&format!("{track} on astrid:s1")]),
        );
        set(&mut check, 9.1, "astrid:s1.params", scan, by);
        set(&mut check, 9.1, "astrid:s1.params", track, "exec-astrid");
        check.conflicts().to_vec()
    };
    assert_eq!(twice("exec-astrid"), Vec::<String>::new());
    assert_eq!(
        twice("exec-bob"),
        [
            "9.100s astrid:s1 ran (pose-tracking astrid s1) for exec-astrid when exec-bob gave it (scan-matching astrid s1)"
        ]
    );
}
