//! Several executives in one ecology, each with its own task, on one in-process tuple space in
//! virtual time: the owners of the components arbitrate their claims (`ecology_tuples::claims`).
//! Astrid and Bob each navigate with their own executive, as the paper's two robots each carry
//! their own planners (Section VIII).

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Duration;

use ecology_domain::parse_facts;
use ecology_tuples::{
    Clock, InProcessSpace, PeisOptions, TupleEvent, TuplePattern, TupleSpace, VirtualClock,
};

use super::on_the_tuple_space::{Broken, STARTUP, body, tick};
use super::peis_home::Hosts;
use super::{PEIS_HOME_FACTS, executive, peis, timeline};
use crate::{DriverConfig, Executive, LogEvent, PlannedAction, RunStatus, drive_observed};

/// Bob: a second robot with his own laser, odometry, thinking cap and self-localisation.
const BOB: &str = "
(peis bob)
(pc bob laser l1) (cost bob l1 100 off)
(pc bob odomet od1) (cost bob od1 10 on)
(pc bob tc tc1) (cost bob tc1 20 on)
(pc bob self-loc s1) (cost bob s1 20 on)
";

/// A second tracking system on the home security monitor, fed by the same ceiling cameras.
const SECOND_TRACKER: &str = "(pc hsm tr-sys tr2) (cost hsm tr2 20 on)";

fn moves(robot: &str, rooms: &[&str]) -> Vec<PlannedAction> {
    let mut from = "living-room";
    rooms
        .iter()
        .map(|to| {
            let action = format!("(move {robot} {from} {to})");
            from = to;
            let goal = ecology_domain::parse_goal(&format!("(navigate {robot} {to})"));
            PlannedAction::new(action, Some(goal.expect("goal")))
        })
        .collect()
}

/// One executive's task: its PEIS name, its plan, when it starts, and when (if ever) it is
/// killed.
struct Task {
    name: &'static str,
    plan: Vec<PlannedAction>,
    after: Duration,
    killed_at: Option<Duration>,
}

impl Task {
    fn new(name: &'static str, plan: Vec<PlannedAction>) -> Task {
        Task {
            name,
            plan,
            after: Duration::ZERO,
            killed_at: None,
        }
    }
}

/// What a run of several executives leaves.
struct Together {
    /// Each executive, by name, once its task ended (or it was killed).
    execs: BTreeMap<&'static str, Executive>,
    /// Every value written to hsm's tuples, in order, by key.
    hsm: BTreeMap<String, Vec<String>>,
    /// Every tuple of the ecology at the end.
    end: BTreeMap<String, String>,
}

impl Together {
    fn exec(&self, name: &str) -> &Executive {
        &self.execs[name]
    }

    /// The costs of the configurations `name`'s executive chose, in order.
    fn costs(&self, name: &str) -> Vec<u64> {
        self.exec(name)
            .log()
            .iter()
            .filter_map(|e| match &e.event {
                LogEvent::Configuration { cost, .. } => Some(*cost),
                _ => None,
            })
            .collect()
    }

    /// Whether `name`'s executive logged a failure of any component.
    fn failures(&self, name: &str) -> usize {
        let log = self.exec(name).log();
        log.iter()
            .filter(|e| matches!(e.event, LogEvent::Failure { .. }))
            .count()
    }

    /// No component served two tasks with different params: between two params of hsm's
    /// components, the component was released (empty params).
    fn never_re_aimed(&self) {
        for (key, values) in &self.hsm {
            if !key.ends_with(".params") {
                continue;
            }
            for pair in values.windows(2) {
                assert!(
                    pair[0].is_empty() || pair[1].is_empty() || pair[0] == pair[1],
                    "hsm:{key} was re-aimed while held: {values:?}"
                );
            }
        }
    }

    /// `name`'s task is done, no component of it failed, and every configuration it chose
    /// has a cost `costs` accepts.
    fn done_unharmed(&self, name: &str, costs: impl Fn(u64) -> bool) {
        let exec = self.exec(name);
        assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(exec));
        assert_eq!(self.failures(name), 0, "{}", timeline(exec));
        assert!(
            self.costs(name).into_iter().all(costs),
            "{name}'s costs: {}",
            timeline(exec)
        );
    }

    /// hsm's cameras were held by both executives, then by Bob's alone, then by nobody.
    fn cameras_left_to_bob(&self) {
        let holders = &self.hsm["components.ca1.holders"];
        let both = holders
            .iter()
            .position(|h| h.split(' ').count() == 2)
            .unwrap_or_else(|| panic!("ca1 was never shared: {holders:?}"));
        assert_eq!(
            holders[both + 1..],
            ["exec-bob".to_string(), String::new()],
            "{holders:?}"
        );
    }

    /// Everything the tasks used is put back: no holder left, and no params left.
    fn all_released(&self) {
        for (tuple, value) in &self.end {
            if tuple.ends_with(".holders") || tuple.ends_with(".params") {
                assert_eq!(
                    value, "",
                    "{tuple} is still {value:?} after every task ended"
                );
            }
        }
    }
}

/// Runs `tasks` together, each with its own executive on its own PEIS, against hosts for
/// `facts`, until every task has ended.
async fn together(facts: &str, tasks: Vec<Task>) -> Together {
    let clock = VirtualClock::default();
    let shared: Arc<dyn Clock> = Arc::new(clock.clone());
    let space = InProcessSpace::new(shared.clone());
    let facts = parse_facts(facts.as_bytes()).expect("facts");
    let broken = Broken::default();
    let hosts = Hosts::start(&space, &shared, &facts, STARTUP, |_, _| {
        body(broken.clone())
    })
    .expect("the hosts start");
    let watcher = space
        .join(peis("watcher"), PeisOptions::default())
        .expect("joins");
    let mut hsm_tuples = watcher
        .subscribe(TuplePattern::parse("hsm:**").expect("pattern"))
        .await
        .expect("subscribe");

    let on = &space;
    let runs = tasks.into_iter().map(|task| {
        let shared = shared.clone();
        async move {
            shared
                .sleep_until(shared.now().saturating_add(task.after))
                .await;
            let mut exec = executive(task.plan);
            let me = on
                .join(peis(task.name), PeisOptions::default())
                .expect("joins");
            let config = DriverConfig {
                limit: Some(Duration::from_secs(300)),
                ..DriverConfig::default()
            };
            let driving = drive_observed(&me, shared.clone(), &mut exec, config, |_| {});
            let killed = async {
                match task.killed_at {
                    Some(at) => shared.sleep_until(shared.now().saturating_add(at)).await,
                    None => std::future::pending().await,
                }
            };
            tokio::select! {
                driven = driving => {
                    driven.expect("drives");
                }
                () = killed => me.clone().vanish(),
            }
            (task.name, exec)
        }
    });
    let all = futures_util::future::join_all(runs);
    let execs = tokio::select! {
        biased;
        execs = all => execs.into_iter().collect(),
        never = tick(&clock) => match never {},
    };
    // The hosts' dead man's switch for a killed executive: its lease, then a second.
    let drain = async {
        tokio::time::sleep(Duration::from_secs(4)).await;
    };
    tokio::select! {
        biased;
        () = drain => {},
        never = tick(&clock) => match never {},
    }
    let mut hsm = BTreeMap::<String, Vec<String>>::new();
    while let Some(event) = hsm_tuples.try_next() {
        if let TupleEvent::Changed(t) = event {
            let text = t.text().unwrap_or("").trim().to_string();
            hsm.entry(t.key.to_string()).or_default().push(text);
        }
    }
    let end = watcher
        .get_matching(TuplePattern::everything())
        .await
        .expect("get")
        .into_iter()
        .map(|t| {
            let text = t.text().unwrap_or("").trim().to_string();
            (format!("{}:{}", t.owner, t.key), text)
        })
        .collect();
    for (p, outcome) in hosts.stop().await {
        assert!(outcome.is_ok(), "host {p}: {outcome:?}");
    }
    space.shutdown().await;
    Together { execs, hsm, end }
}

// The two robots, started together: both plan the ceiling cameras from the same state,
// hsm grants the tracking system to the first request and refuses the other naming its holder;
// the other takes its own laser, nobody is blamed, both arrive, and everything is put back.
#[tokio::test(start_paused = true)]
async fn two_robots_needing_the_one_tracker_each_arrive() {
    let facts = format!("{PEIS_HOME_FACTS}{BOB}");
    let ran = together(
        &facts,
        vec![
            Task::new("exec-astrid", moves("astrid", &["bedroom"])),
            Task::new("exec-bob", moves("bob", &["kitchen"])),
        ],
    )
    .await;
    for name in ["exec-astrid", "exec-bob"] {
        ran.done_unharmed(name, |_| true);
    }
    let last = |name| ran.costs(name).last().copied();
    let mut ends = [last("exec-astrid"), last("exec-bob")];
    ends.sort();
    assert_eq!(ends, [Some(80), Some(170)], "one tracker, one laser");
    let held: Vec<&LogEvent> = ran
        .execs
        .values()
        .flat_map(|e| e.log().iter().map(|entry| &entry.event))
        .filter(|e| matches!(e, LogEvent::Held { .. }))
        .collect();
    assert!(
        held.len() <= 1,
        "at most the loser of the race was refused: {held:?}"
    );
    ran.never_re_aimed();
    ran.all_released();
}

// With a second tracker, the ceiling cameras serve both: shared (one holder set with both
// executives), switched off by neither while the other still moves. Bob moves twice, so Astrid
// ends first and releases her claim under him.
#[tokio::test(start_paused = true)]
async fn a_shared_camera_serves_two_trackers_until_its_last_holder_releases_it() {
    let facts = format!("{PEIS_HOME_FACTS}{BOB}{SECOND_TRACKER}");
    let ran = together(
        &facts,
        vec![
            Task::new("exec-astrid", moves("astrid", &["bedroom"])),
            Task::new("exec-bob", moves("bob", &["kitchen", "bedroom"])),
        ],
    )
    .await;
    for name in ["exec-astrid", "exec-bob"] {
        ran.done_unharmed(name, |c| c == 80);
    }
    // Astrid's release left Bob holding the cameras; his own put them back.
    ran.cameras_left_to_bob();
    ran.never_re_aimed();
    ran.all_released();
}

// Astrid's and Bob's executives share the ceiling cameras (each with a tracker of its own) when
// Astrid's is killed mid-move. Her claims lapse with her presence (hsm's dead man's switch, per
// holder): her tracker is put back, and the cameras keep running for Bob, whose task goes on
// unharmed on them.
#[tokio::test(start_paused = true)]
async fn an_executive_killed_while_sharing_takes_nothing_from_the_other() {
    let facts = format!("{PEIS_HOME_FACTS}{BOB}{SECOND_TRACKER}");
    let ran = together(
        &facts,
        vec![
            Task {
                killed_at: Some(Duration::from_secs(2)),
                ..Task::new("exec-astrid", moves("astrid", &["bedroom", "kitchen"]))
            },
            Task::new(
                "exec-bob",
                moves("bob", &["kitchen", "bedroom", "entrance"]),
            ),
        ],
    )
    .await;
    ran.done_unharmed("exec-bob", |c| c == 80);
    // Astrid's claim lapsing left Bob holding the cameras, never nobody while he moved.
    ran.cameras_left_to_bob();
    ran.never_re_aimed();
    ran.all_released();
}

// Astrid's executive holds the only tracker when it is cut off mid-move (it stops being heard, as
// in a partition or a crash): Bob, on his laser, is not disturbed, and once hsm's dead man's
// switch has dropped its claims (its lease, then a second), Bob's next move takes the tracker.
#[tokio::test(start_paused = true)]
async fn a_cut_off_executive_s_claims_lapse_and_another_takes_them() {
    let facts = format!("{PEIS_HOME_FACTS}{BOB}");
    let ran = together(
        &facts,
        vec![
            Task {
                killed_at: Some(Duration::from_secs(2)),
                ..Task::new("exec-astrid", moves("astrid", &["bedroom", "kitchen"]))
            },
            // Bob starts once Astrid holds the tracker, and sees that she does.
            Task {
                after: Duration::from_millis(500),
                ..Task::new(
                    "exec-bob",
                    moves("bob", &["kitchen", "bedroom", "entrance"]),
                )
            },
        ],
    )
    .await;
    ran.done_unharmed("exec-bob", |_| true);
    let bob = ran.exec("exec-bob");
    let costs = ran.costs("exec-bob");
    assert_eq!(costs.first(), Some(&170), "{}", timeline(bob));
    assert_eq!(costs.last(), Some(&80), "{}", timeline(bob));
    ran.never_re_aimed();
    ran.all_released();
}
