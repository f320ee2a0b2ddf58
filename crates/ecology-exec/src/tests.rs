//! Tests of the executive: [`Executive::handle`] fed events directly, and
//! whole runs against the real PEIS host (`ecology_peis::run_host`) on the
//! in-process tuple space, in virtual time.

mod claims;
mod peis_home;

use std::time::Duration;

use ecology_domain::{EcologyState, parse_domain, parse_facts, parse_goal};

use ecology_tuples::{ComponentId, Key, PeisId, Timestamp};

use crate::driver::Timers;
use crate::{Command, Event, ExecConfig, Executive, LogEvent, PlannedAction, RunStatus, Timer};

const PEIS_HOME: &str = include_str!("../../../domains/peis-home.eco");
const PEIS_BUILDING: &str = include_str!("../../../domains/peis-building.eco");
const PEIS_HOME_FACTS: &str = include_str!("../../../domains/peis-home.facts");

fn secs(s: f64) -> Duration {
    Duration::from_secs_f64(s)
}

fn peis(name: &str) -> PeisId {
    PeisId::new(name).expect("a PEIS name")
}

fn key(text: &str) -> Key {
    Key::new(text).expect("a key")
}

/// The component `name` of the PEIS `peis_name`.
fn component(peis_name: &str, name: &str) -> (PeisId, ComponentId) {
    (
        peis(peis_name),
        ComponentId::new(name).expect("a component name"),
    )
}

fn plan() -> Vec<PlannedAction> {
    let step = |action: &str, goal: &str| {
        PlannedAction::new(action.to_string(), Some(parse_goal(goal).expect("goal")))
    };
    vec![
        step(
            "(move astrid living-room entrance)",
            "(navigate astrid entrance)",
        ),
        step(
            "(get astrid newspaper entrance)",
            "(grasp astrid newspaper)",
        ),
        step(
            "(move astrid entrance bedroom)",
            "(navigate astrid bedroom)",
        ),
        step("(wake astrid johanna bedroom)", "(wake-up astrid johanna)"),
    ]
}

fn executive(plan: Vec<PlannedAction>) -> Executive {
    let domain = parse_domain(PEIS_HOME.as_bytes()).expect("domain");
    Executive::new(domain, EcologyState::new(), plan, ExecConfig::default())
}

fn costs(exec: &Executive) -> Vec<(u64, bool)> {
    exec.log()
        .iter()
        .filter_map(|e| match &e.event {
            LogEvent::Configuration {
                cost,
                reconfiguration,
                ..
            } => Some((*cost, *reconfiguration)),
            _ => None,
        })
        .collect()
}

fn names(exec: &Executive) -> Vec<&'static str> {
    exec.log().iter().map(|e| e.event.name()).collect()
}

fn timeline(exec: &Executive) -> String {
    exec.log().iter().map(|e| format!("{e}\n")).collect()
}

// The paper, Section VIII, steps 1-5 and 7 without the failure.
fn tuple(owner: &str, key: &str, value: &str, seq: u64) -> Event {
    tuple_of_run(owner, key, value, 1, seq)
}

fn tuple_of_run(owner: &str, key: &str, value: &str, epoch: u64, seq: u64) -> Event {
    Event::Tuple {
        owner: peis(owner),
        key: self::key(key),
        value: value.to_string(),
        epoch,
        seq,
    }
}

/// An executive for the first action, fed the init tuples of every component
/// (all on, so nothing is switched on), started, with the ceiling-camera
/// configuration running at one second.
fn running_first_action() -> Executive {
    let mut exec = started_first_action();
    for (p, c) in [
        ("astrid", "tc1"),
        ("astrid", "s1"),
        ("hsm", "ca1"),
        ("hsm", "tr1"),
    ] {
        answered(
            &mut exec,
            secs(1.0),
            tuple(p, &format!("{c}.status"), "running", 2),
        );
    }
    exec
}

/// An executive for the first action, fed the init tuples of every
/// component (all on) and started: deploying the ceiling-camera configuration.
fn started_first_action() -> Executive {
    let mut exec = executive(plan()[..1].to_vec());
    let state = parse_facts(PEIS_HOME_FACTS.as_bytes()).expect("facts");
    for f in state.with_predicate("pc") {
        let (p, ty, c) = (&*f.args[0], &*f.args[1], &*f.args[2]);
        let cost = state.component_cost(p, c).map_or(10, |c| c.amount);
        exec.handle(
            Duration::ZERO,
            tuple(p, &format!("components.{c}.type"), ty, 1),
        );
        exec.handle(
            Duration::ZERO,
            tuple(p, &format!("components.{c}.cost"), &cost.to_string(), 1),
        );
        exec.handle(
            Duration::ZERO,
            tuple(p, &format!("components.{c}.currState"), "on", 1),
        );
    }
    answered(&mut exec, Duration::ZERO, Event::Start);
    exec
}

/// Hands `exec` the event, then tells it that each remote set it asks for was answered, as over
/// a network that works; returns the commands.
fn answered(exec: &mut Executive, now: Duration, event: Event) -> Vec<Command> {
    let commands = exec.handle(now, event);
    answer_all(exec, now, &commands);
    commands
}

/// Tells `exec` at `now` that each remote set among `commands` was answered.
fn answer_all(exec: &mut Executive, now: Duration, commands: &[Command]) {
    for command in commands {
        if let Command::RemoteSet { owner, key, .. } = command {
            exec.handle(
                now,
                Event::RemoteSetAnswered {
                    owner: owner.clone(),
                    key: key.clone(),
                },
            );
        }
    }
}

#[test]
fn duplicate_late_and_stale_status_tuples_cause_one_reconfiguration() {
    let mut exec = running_first_action();
    assert_eq!(costs(&exec), [(80, false)]);
    // tr1 fails; the same tuple arrives twice, then an older one late.
    exec.handle(secs(2.0), tuple("hsm", "tr1.status", "error", 4));
    exec.handle(secs(2.0), tuple("hsm", "tr1.status", "error", 4));
    exec.handle(secs(2.1), tuple("hsm", "tr1.status", "running", 3));
    // A new error from the already-excluded tr1, and one from ca1, which the
    // new configuration no longer uses.
    exec.handle(secs(2.2), tuple("hsm", "tr1.status", "error", 5));
    exec.handle(secs(2.3), tuple("hsm", "ca1.status", "error", 3));
    // Everything is on here, so the laser costs its running cost: 100 + 10 + 20 + 20.
    assert_eq!(
        costs(&exec),
        [(80, false), (150, true)],
        "{}",
        timeline(&exec)
    );
    assert_eq!(names(&exec).iter().filter(|n| **n == "failure").count(), 1);
    assert_eq!(
        names(&exec)
            .iter()
            .filter(|n| **n == "reconfiguration")
            .count(),
        1
    );
}

/// The tracking system waits past its grace; the laser can stand in for it, so it is blamed.
#[test]
fn waiting_too_long_is_a_failure() {
    let mut exec = running_first_action();
    exec.handle(secs(2.0), tuple("hsm", "tr1.cause", "(image hsm)", 1));
    let commands = exec.handle(secs(2.0), tuple("hsm", "tr1.status", "waiting", 3));
    let timer = Timer::Waiting(component("hsm", "tr1"));
    assert_eq!(
        commands.first(),
        Some(&Command::StartTimer {
            timer: timer.clone(),
            after: ExecConfig::default().waiting_grace
        }),
        "a grace timer: {commands:?}"
    );
    exec.handle(secs(4.0), Event::Timer(timer));
    let text = timeline(&exec);
    assert!(
        text.contains("FAILURE hsm:tr1: waiting for longer than 2s: (image hsm)"),
        "{text}"
    );
}

/// The failures the executive logged, as `P:C cause`.
fn failures(exec: &Executive) -> Vec<String> {
    exec.log()
        .iter()
        .filter_map(|e| e.event.failure())
        .map(|(peis, component, cause)| format!("{peis}:{component} {cause}"))
        .collect()
}

#[test]
fn a_consumer_that_cannot_read_its_input_blames_its_producer_at_once() {
    let mut exec = running_first_action();
    exec.handle(
        secs(2.0),
        tuple(
            "astrid",
            "s1.cause",
            "unreadable global-pos: expected X Y THETA, found \"1,2;3\"",
            1,
        ),
    );
    let commands = exec.handle(secs(2.0), tuple("astrid", "s1.status", "waiting", 3));
    assert_eq!(
        failures(&exec),
        ["hsm:tr1 astrid:s1 cannot read its global-pos: expected X Y THETA, found \"1,2;3\""]
    );
    // The consumer keeps its place: scan matching on s1 replaces the cameras.
    assert_eq!(costs(&exec), [(80, false), (150, true)]);
    assert_eq!(
        set_of(&commands, "astrid", "s1.params"),
        Some("(scan-matching astrid s1)")
    );
    // No grace period is timed for the consumer's waiting.
    assert!(
        !commands
            .iter()
            .any(|c| matches!(c, Command::StartTimer { after, .. } if *after == ExecConfig::default().waiting_grace)),
        "{commands:?}"
    );
}

#[test]
fn an_unreadable_input_is_blamed_on_its_producer_while_deploying() {
    let mut exec = started_first_action();
    exec.handle(secs(0.5), tuple("hsm", "tr1.status", "running", 2));
    exec.handle(
        secs(0.6),
        tuple("astrid", "s1.cause", "unreadable global-pos", 1),
    );
    exec.handle(secs(0.6), tuple("astrid", "s1.status", "waiting", 2));
    assert_eq!(
        failures(&exec),
        ["hsm:tr1 astrid:s1 cannot read its global-pos"]
    );
}

/// Pose tracking waits past its grace, and no configuration can do without it (both ways to a
/// position end in s1): it is given as long again as a PEIS that left is waited for, then
/// blamed; or, reporting `running` meanwhile, it is not blamed at all.
#[test]
fn a_waiting_component_nothing_can_stand_in_for_is_given_longer() {
    let grace = ExecConfig::default().waiting_grace;
    let longer = ExecConfig::default().return_wait;
    let s1 = Timer::Waiting(component("astrid", "s1"));
    for recovers in [false, true] {
        let mut exec = running_first_action();
        exec.handle(
            secs(2.0),
            tuple("astrid", "s1.cause", "(global-pos astrid)", 1),
        );
        let commands = exec.handle(secs(2.0), tuple("astrid", "s1.status", "waiting", 3));
        let more = exec.handle(secs(4.0), fired(&commands, &s1, grace));
        let text = timeline(&exec);
        assert!(failures(&exec).is_empty(), "{text}");
        assert!(
            text.contains(
                "no configuration without astrid:s1: waiting up to 5s more for (global-pos astrid)"
            ),
            "{text}"
        );
        let given_longer = fired(&more, &s1, longer);
        if recovers {
            let commands = exec.handle(secs(5.0), tuple("astrid", "s1.status", "running", 4));
            assert!(
                commands.contains(&Command::CancelTimer(s1.clone())),
                "{commands:?}"
            );
            assert!(failures(&exec).is_empty(), "{}", timeline(&exec));
            // A later spell of waiting is given longer again.
            let commands = exec.handle(secs(6.0), tuple("astrid", "s1.status", "waiting", 5));
            let more = exec.handle(secs(8.0), fired(&commands, &s1, grace));
            assert!(failures(&exec).is_empty(), "{}", timeline(&exec));
            exec.handle(secs(13.0), fired(&more, &s1, longer));
            assert_eq!(
                failures(&exec),
                ["astrid:s1 waiting for longer than 7s: (global-pos astrid)"]
            );
        } else {
            exec.handle(secs(9.0), given_longer);
            assert_eq!(
                failures(&exec),
                ["astrid:s1 waiting for longer than 7s: (global-pos astrid)"]
            );
        }
    }
}

#[test]
fn an_unreadable_cause_naming_no_input_of_the_component_is_plain_waiting() {
    let mut exec = running_first_action();
    exec.handle(
        secs(2.0),
        tuple("hsm", "tr1.cause", "unreadable range-scan: ?", 1),
    );
    let commands = exec.handle(secs(2.0), tuple("hsm", "tr1.status", "waiting", 3));
    assert!(failures(&exec).is_empty(), "{}", timeline(&exec));
    let timer = Timer::Waiting(component("hsm", "tr1"));
    assert!(
        matches!(commands.first(), Some(Command::StartTimer { timer: t, .. }) if *t == timer),
        "a grace timer: {commands:?}"
    );
    exec.handle(secs(4.0), Event::Timer(timer));
    assert_eq!(
        failures(&exec),
        ["hsm:tr1 waiting for longer than 2s: unreadable range-scan: ?"]
    );
}

/// The first `RemoteSet` of `key` on `owner` among `commands`.
fn set_of<'a>(commands: &'a [Command], owner: &str, key: &str) -> Option<&'a str> {
    commands.iter().find_map(|c| match c {
        Command::RemoteSet {
            owner: o,
            key: k,
            value,
        } if o.as_str() == owner && k.as_str() == key => Some(value.as_str()),
        _ => None,
    })
}

#[test]
fn inputs_are_repointed_only_once_their_new_producer_runs() {
    let mut exec = running_first_action();
    // Everything is on; the tracking system fails: scan matching on the laser
    // replaces it, and l1, od1 and s1 get new params.
    let commands = exec.handle(secs(2.0), tuple("hsm", "tr1.status", "error", 3));
    assert_eq!(costs(&exec), [(80, false), (150, true)]);
    assert_eq!(
        set_of(&commands, "astrid", "s1.params"),
        Some("(scan-matching astrid s1)")
    );
    // Navigation still reads the old position until scan matching runs.
    assert_eq!(set_of(&commands, "astrid", "tc1.mi-position"), None);
    assert_eq!(set_of(&commands, "astrid", "s1.mi-range-scan"), None);
    let commands = exec.handle(secs(2.2), tuple("astrid", "l1.status", "running", 2));
    assert_eq!(
        set_of(&commands, "astrid", "s1.mi-range-scan"),
        Some("(meta astrid l1.out.range-scan)")
    );
    exec.handle(secs(2.3), tuple("astrid", "od1.status", "running", 3));
    let commands = exec.handle(secs(2.4), tuple("astrid", "s1.status", "running", 3));
    assert_eq!(
        set_of(&commands, "astrid", "tc1.mi-position"),
        Some("(meta astrid s1.out.position)")
    );
}

/// The laser configuration's components report `running` at 2.2, 2.3 and 2.4 s, their sets
/// answered; the commands of the last.
fn laser_configuration_runs(exec: &mut Executive) -> Vec<Command> {
    answered(exec, secs(2.2), tuple("astrid", "l1.status", "running", 2));
    answered(exec, secs(2.3), tuple("astrid", "od1.status", "running", 3));
    answered(exec, secs(2.4), tuple("astrid", "s1.status", "running", 3))
}

#[test]
fn a_component_waiting_across_a_redeploy_is_still_timed() {
    let mut exec = running_first_action();
    answered(&mut exec, secs(2.0), tuple("hsm", "tr1.status", "error", 3));
    // While the new configuration deploys, navigation loses its position.
    answered(
        &mut exec,
        secs(2.1),
        tuple("astrid", "tc1.status", "waiting", 3),
    );
    let commands = laser_configuration_runs(&mut exec);
    assert_eq!(names(&exec).last(), Some(&"running"), "{}", timeline(&exec));
    let grace = ExecConfig::default().waiting_grace;
    let tc1 = Timer::Waiting(component("astrid", "tc1"));
    // Nothing can stand in for navigation: it is given longer, then blamed.
    let more = exec.handle(secs(4.4), fired(&commands, &tc1, grace));
    exec.handle(
        secs(9.4),
        fired(&more, &tc1, ExecConfig::default().return_wait),
    );
    let text = timeline(&exec);
    assert!(
        text.contains("FAILURE astrid:tc1: waiting for longer than 7s"),
        "{text}"
    );
}

const STEREO: &str = "
(define (domain stereo)
  (:functionality camera :parameters (?p ?c) :component (?p ?c)
    :precondition (pc ?p cam ?c) :output ((image ?p)) :cost 1)
  (:functionality fuse :parameters (?r ?s ?a ?b) :component (?r ?s)
    :precondition (pc ?r stereo ?s) :input ((image ?a) (image ?b)) :postcondition (seen ?r) :cost 1)
  (:task see :parameters (?r))
  (:method see-with-two-cameras :parameters (?r ?s ?a ?ca ?b ?cb) :task (see ?r)
    :precondition (and (pc ?r stereo ?s) (pc ?a cam ?ca) (pc ?b cam ?cb) (not (= ?a ?b)))
    :subtasks ((f1 (camera ?a ?ca)) (f2 (camera ?b ?cb)) (f3 (fuse ?r ?s ?a ?b)))
    :channels ((f1 f3 (image ?a)) (f2 f3 (image ?b)))))
";

#[test]
fn two_inputs_of_the_same_kind_get_keys_of_their_own() {
    let domain = parse_domain(STEREO.as_bytes()).expect("domain");
    let see = PlannedAction::new(
        "(look robot)".to_string(),
        Some(parse_goal("(see robot)").expect("goal")),
    );
    let mut exec = Executive::new(
        domain,
        EcologyState::new(),
        vec![see],
        ExecConfig::default(),
    );
    for (p, ty, c) in [
        ("robot", "stereo", "s1"),
        ("left", "cam", "c1"),
        ("right", "cam", "c2"),
    ] {
        exec.handle(
            Duration::ZERO,
            tuple(p, &format!("components.{c}.type"), ty, 1),
        );
        exec.handle(
            Duration::ZERO,
            tuple(p, &format!("components.{c}.cost"), "1", 1),
        );
        exec.handle(
            Duration::ZERO,
            tuple(p, &format!("components.{c}.currState"), "on", 1),
        );
    }
    exec.handle(Duration::ZERO, Event::Start);
    let mut wired = Vec::new();
    for (p, c) in [("left", "c1"), ("right", "c2")] {
        for command in exec.handle(secs(1.0), tuple(p, &format!("{c}.status"), "running", 2)) {
            if let Command::RemoteSet { key, value, .. } = command {
                wired.push(format!("{key} = {value}"));
            }
        }
    }
    wired.sort();
    assert_eq!(
        wired,
        [
            "s1.mi-image.left = (meta left c1.out.image)",
            "s1.mi-image.right = (meta right c2.out.image)"
        ],
        "{}",
        timeline(&exec)
    );
}

#[test]
fn a_restarted_peis_fails_its_components_and_its_new_run_counts() {
    let mut exec = running_first_action();
    // hsm restarts before anyone noticed it leave: its tuples come numbered
    // from 1 again, in a later run.
    exec.handle(
        secs(2.0),
        tuple_of_run("hsm", "components.tr1.type", "tr-sys", 2, 1),
    );
    let text = timeline(&exec);
    assert!(text.contains("PEIS hsm restarted"), "{text}");
    assert!(
        text.contains("FAILURE hsm:tr1: PEIS hsm restarted")
            && text.contains("FAILURE hsm:ca1: PEIS hsm restarted"),
        "{text}"
    );
    assert_eq!(costs(&exec), [(80, false), (150, true)], "{text}");
    // The new run's tuples are taken in although their numbers are low ...
    exec.handle(secs(2.1), tuple_of_run("hsm", "tr1.status", "idle", 2, 1));
    let view = exec.mirror().component("hsm", "tr1").cloned();
    assert_eq!(view.and_then(|v| v.status), Some("idle".to_string()));
    assert_eq!(
        exec.mirror().component("hsm", "ca1"),
        None,
        "the old run's components are forgotten"
    );
    // ... and a late tuple of the old run is stale.
    exec.handle(
        secs(2.2),
        tuple_of_run("hsm", "tr1.status", "running", 1, 9),
    );
    let view = exec.mirror().component("hsm", "tr1").cloned();
    assert_eq!(view.and_then(|v| v.status), Some("idle".to_string()));
}

#[test]
fn a_late_tuple_does_not_bring_back_a_peis_that_left() {
    let mut exec = running_first_action();
    exec.handle(secs(2.0), Event::PeisLeft(peis("hsm")));
    assert_eq!(costs(&exec), [(80, false), (150, true)]);
    // Sent before it left, delivered after: hsm stays absent.
    exec.handle(secs(2.1), tuple("hsm", "ca1.status", "running", 7));
    assert!(!exec.mirror().peis()["hsm"].present);
    // Its presence coming back does bring it back, with the same run's numbering.
    exec.handle(secs(3.0), Event::PeisJoined(peis("hsm")));
    assert!(exec.mirror().peis()["hsm"].present);
    exec.handle(secs(3.1), tuple("hsm", "ca1.status", "error", 6));
    let view = exec.mirror().component("hsm", "ca1").cloned();
    assert_eq!(view.and_then(|v| v.status), Some("running".to_string()));
    // One reconfiguration, for the departure only.
    assert_eq!(costs(&exec), [(80, false), (150, true)]);
}

/// The remote sets to `owner` among `commands`, as (key, value).
fn sets_to(commands: &[Command], owner: &str) -> Vec<(String, String)> {
    commands
        .iter()
        .filter_map(|c| match c {
            Command::RemoteSet {
                owner: o,
                key,
                value,
            } if o.as_str() == owner => Some((key.to_string(), value.clone())),
            _ => None,
        })
        .collect()
}

/// `timer` firing, which `commands` started to run for `after`.
fn fired(commands: &[Command], timer: &Timer, after: Duration) -> Event {
    let start = Command::StartTimer {
        timer: timer.clone(),
        after,
    };
    assert!(commands.contains(&start), "no {start:?} in {commands:?}");
    Event::Timer(timer.clone())
}

/// The driver keeps one deadline per timer: one started again fires once, for its latest start;
/// one cancelled never; timers due at once fire in the order they were last started.
#[test]
fn the_driver_fires_a_timer_for_its_latest_start_only() {
    let at = |s: u64| Timestamp(s * 1_000_000_000);
    let tc1 = Timer::Waiting(component("astrid", "tc1"));
    let mut timers = Timers::default();
    timers.start(Timer::Action, at(10));
    timers.start(Timer::Deploy, at(3));
    timers.start(tc1.clone(), at(4));
    timers.start(Timer::LossWindow, at(4));
    timers.start(Timer::ReturnWait, at(2));
    // Started again: it fires at 5, not at 3, and after the loss window, due at once.
    timers.start(Timer::Deploy, at(5));
    timers.start(Timer::LostSettle, at(5));
    timers.start(tc1.clone(), at(5));
    timers.cancel(&Timer::ReturnWait);
    let mut fired = Vec::new();
    while let Some((timer, when)) = timers.next() {
        timers.cancel(&timer);
        fired.push((timer, when));
    }
    assert_eq!(
        fired,
        [
            (Timer::LossWindow, at(4)),
            (Timer::Deploy, at(5)),
            (Timer::LostSettle, at(5)),
            (tc1, at(5)),
            (Timer::Action, at(10)),
        ]
    );
}

#[test]
fn a_peis_back_from_a_partition_is_released_of_what_is_no_longer_used() {
    let mut exec = running_first_action();
    let left = exec.handle(secs(2.0), Event::PeisLeft(peis("hsm")));
    assert_eq!(
        costs(&exec),
        [(80, false), (150, true)],
        "reconfigured at once"
    );
    let window = ExecConfig::default().loss_window;
    exec.handle(secs(3.0), fired(&left, &Timer::LossWindow, window));
    // It comes back in the same run, still running the old configuration's params.
    let back = exec.handle(secs(5.0), Event::PeisJoined(peis("hsm")));
    assert_eq!(
        sets_to(&back, "hsm"),
        [
            ("ca1.params".to_string(), String::new()),
            ("tr1.params".to_string(), String::new())
        ]
    );
    let text = timeline(&exec);
    assert!(
        text.contains("PEIS hsm is back; no longer used: stopped hsm:ca1, hsm:tr1"),
        "{text}"
    );
    // At the end of the task nothing of it is released twice.
    let end = exec.stop(secs(6.0), "stopped by the operator");
    assert!(sets_to(&end, "hsm").is_empty(), "{end:?}");
}

/// Every PEIS leaves within the window, and a remote set fails meanwhile: the executive acts on
/// each departure at once, but once the window closes it knows it lost the ecology (its own
/// network): the action does not fail, and what the departures excluded is allowed again.
fn losing_the_ecology() -> (Executive, Vec<Command>) {
    let mut exec = running_first_action();
    let first = exec.handle(secs(2.0), Event::PeisLeft(peis("hsm")));
    exec.handle(secs(2.3), Event::PeisLeft(peis("astrid")));
    exec.handle(secs(2.6), Event::PeisLeft(peis("pippi")));
    exec.handle(
        secs(2.7),
        Event::RemoteSetFailed {
            owner: peis("astrid"),
            key: key("tc1.params"),
            reason: "no reply within 2s".to_string(),
            unanswered: true,
        },
    );
    let lost = exec.handle(
        secs(3.0),
        fired(
            &first,
            &Timer::LossWindow,
            ExecConfig::default().loss_window,
        ),
    );
    let text = timeline(&exec);
    assert!(
        text.contains(
            "LOST THE ECOLOGY: 3 of 3 PEIS left at once (astrid, hsm, pippi); waiting up to 30s for them"
        ),
        "{text}"
    );
    assert!(!names(&exec).contains(&"action_failed"), "{text}");
    assert_eq!(exec.status(), &RunStatus::Running { index: 0 }, "{text}");
    assert!(lost.iter().all(|c| !matches!(c, Command::RemoteSet { .. })));
    (exec, lost)
}

#[test]
fn an_executive_that_lost_the_ecology_goes_on_when_it_is_back() {
    let (mut exec, _) = losing_the_ecology();
    exec.handle(secs(10.0), Event::PeisJoined(peis("hsm")));
    exec.handle(secs(10.2), Event::PeisJoined(peis("astrid")));
    let last = exec.handle(secs(10.4), Event::PeisJoined(peis("pippi")));
    let before = costs(&exec).len();
    let settle = fired(&last, &Timer::LostSettle, ExecConfig::default().loss_window);
    let resumed = exec.handle(secs(11.4), settle);
    let text = timeline(&exec);
    assert!(
        text.contains("the ecology is back: astrid, hsm, pippi"),
        "{text}"
    );
    // From the ecology as it is, with nothing the loss excluded: the cameras again.
    assert_eq!(costs(&exec)[before..], [(80, true)], "{text}");
    assert_eq!(exec.status(), &RunStatus::Running { index: 0 });
    // What still runs is kept as it is: the cameras keep their params.
    let rewritten = sets_to(&resumed, "hsm");
    assert!(
        rewritten.iter().all(|(k, _)| !k.ends_with(".params")),
        "{rewritten:?}"
    );
}

#[test]
fn an_executive_whose_ecology_stays_lost_fails_saying_so() {
    let (mut exec, lost) = losing_the_ecology();
    // One comes back, which is not most of them.
    let back = exec.handle(secs(10.0), Event::PeisJoined(peis("pippi")));
    exec.handle(
        secs(11.0),
        fired(&back, &Timer::LostSettle, ExecConfig::default().loss_window),
    );
    assert!(!names(&exec).contains(&"ecology_back"));
    let deadline = fired(
        &lost,
        &Timer::Reconnect,
        ExecConfig::default().reconnect_timeout,
    );
    let end = exec.handle(secs(33.0), deadline);
    let RunStatus::Failed { reason, .. } = exec.status().clone() else {
        panic!("the task should fail: {}", timeline(&exec));
    };
    assert!(
        reason.starts_with(
            "the executive lost the ecology: 3 of the 3 PEIS present (astrid, hsm, pippi) left at once, and only pippi came back within 30s"
        ),
        "{reason}"
    );
    assert!(exec.finished());
    // Nothing is sent to PEIS out of reach (their hosts put back what it asked for).
    assert!(
        end.iter().all(|c| !matches!(c, Command::RemoteSet { .. })),
        "{end:?}"
    );
    let text = timeline(&exec);
    assert!(
        text.contains("left to their PEIS, out of reach: "),
        "{text}"
    );
    assert!(text.contains("hsm:ca1, hsm:tr1"), "{text}");
}

#[test]
fn a_failed_remote_set_fails_its_component() {
    let mut exec = running_first_action();
    exec.handle(
        secs(2.0),
        Event::RemoteSetFailed {
            owner: peis("hsm"),
            key: key("tr1.params"),
            reason: "remote set of tr1.params is not allowed by hsm".to_string(),
            unanswered: false,
        },
    );
    let text = timeline(&exec);
    assert!(
        text.contains(
            "remote set of hsm:tr1.params failed: remote set of tr1.params is not allowed by hsm"
        ),
        "{text}"
    );
    assert!(
        text.contains(
            "FAILURE hsm:tr1: could not set tr1.params: remote set of tr1.params is not allowed by hsm"
        ),
        "{text}"
    );
    assert_eq!(costs(&exec), [(80, false), (150, true)], "{text}");
    // A failed switch-off of a component outside the configuration is logged only.
    exec.handle(
        secs(2.5),
        Event::RemoteSetFailed {
            owner: peis("pippi"),
            key: key("components.ol2.reqState"),
            reason: "pippi cannot be reached".to_string(),
            unanswered: true,
        },
    );
    assert_eq!(costs(&exec), [(80, false), (150, true)]);
}

/// Another executive asked hsm for its tracking system first, with other params: hsm refuses,
/// naming the holder. Not a failure: nothing is blamed or excluded for good, the action is
/// configured again without it, and once its holders change it is considered again.
#[test]
fn a_component_held_by_another_executive_is_done_without_not_blamed() {
    let mut exec = running_first_action();
    let refusal = "PEIS hsm refused a remote set of tr1.params: held by exec-bob: tr1 runs (tracking-system hsm tr1 bob)";
    exec.handle(
        secs(2.0),
        Event::RemoteSetFailed {
            owner: peis("hsm"),
            key: key("tr1.params"),
            reason: refusal.to_string(),
            unanswered: false,
        },
    );
    // The wiring of tr1 refused as well, for the same reason: acted on once.
    exec.handle(
        secs(2.0),
        Event::RemoteSetFailed {
            owner: peis("hsm"),
            key: key("tr1.mi-image"),
            reason: refusal.replace("tr1.params", "tr1.mi-image"),
            unanswered: false,
        },
    );
    let text = timeline(&exec);
    assert!(
        text.contains("hsm:tr1 is held by exec-bob: done without until it is released"),
        "{text}"
    );
    assert!(!text.contains("FAILURE"), "blamed:\n{text}");
    assert_eq!(costs(&exec), [(80, false), (150, true)], "{text}");
    // Bob's executive releases it; the next configuration of the action may take it again.
    exec.handle(secs(3.0), tuple("hsm", "components.tr1.holders", "", 3));
    exec.handle(secs(3.5), tuple("astrid", "l1.cause", "laser broke", 3));
    exec.handle(secs(3.5), tuple("astrid", "l1.status", "error", 3));
    assert_eq!(costs(&exec)[2..], [(80, true)], "{}", timeline(&exec));
}

/// A remote set that got no answer, from a PEIS still present: the component is blamed, but
/// only once the grace has passed without its PEIS leaving or the ecology being lost.
#[test]
fn an_unanswered_remote_set_fails_its_component_after_a_grace() {
    let mut exec = running_first_action();
    let held = exec.handle(secs(2.0), unanswered("hsm", "tr1.params"));
    let text = timeline(&exec);
    assert!(!text.contains("FAILURE"), "blamed at once:\n{text}");
    assert_eq!(costs(&exec), [(80, false)], "{text}");
    let grace = ExecConfig::default().unanswered_grace;
    exec.handle(
        secs(5.0),
        fired(&held, &Timer::Unanswered(component("hsm", "tr1")), grace),
    );
    let text = timeline(&exec);
    assert!(
        text.contains(
            "FAILURE hsm:tr1: could not set tr1.params: no answer (hsm is still present 3s later)"
        ),
        "{text}"
    );
    assert_eq!(costs(&exec), [(80, false), (150, true)], "{text}");
}

/// A remote set that got no answer from a PEIS still present goes again (a lossy link drops a
/// query now and then); the answer to it clears the component, and the grace then runs out
/// without blame.
#[test]
fn an_unanswered_remote_set_is_sent_again_and_its_answer_clears_the_component() {
    let mut exec = running_first_action();
    // The tracking system fails: the laser configuration gives s1 new params, not yet answered.
    let commands = exec.handle(secs(2.0), tuple("hsm", "tr1.status", "error", 3));
    let params = set_of(&commands, "astrid", "s1.params").map(str::to_string);
    assert_eq!(params.as_deref(), Some("(scan-matching astrid s1)"));
    let held = exec.handle(secs(4.0), unanswered("astrid", "s1.params"));
    assert_eq!(set_of(&held, "astrid", "s1.params"), params.as_deref());
    assert!(
        timeline(&exec)
            .contains("remote set of astrid:s1.params sent again: astrid is still present"),
        "{}",
        timeline(&exec)
    );
    let grace = Timer::Unanswered(component("astrid", "s1"));
    let expired = fired(&held, &grace, ExecConfig::default().unanswered_grace);
    let cleared = exec.handle(
        secs(4.5),
        Event::RemoteSetAnswered {
            owner: peis("astrid"),
            key: key("s1.params"),
        },
    );
    assert_eq!(cleared, [Command::CancelTimer(grace)]);
    // Delivered all the same, the cancelled grace blames nobody.
    exec.handle(secs(7.0), expired);
    assert!(
        failures(&exec).iter().all(|f| !f.starts_with("astrid:s1")),
        "{}",
        timeline(&exec)
    );
    assert_eq!(costs(&exec), [(80, false), (150, true)]);
}

/// A set sent again only while it is the last of its key: a later set of the same key, asked
/// before the first failed, carries the newer value anyway.
#[test]
fn an_unanswered_remote_set_with_a_later_one_of_its_key_is_not_sent_again() {
    let mut exec = running_first_action();
    exec.handle(secs(2.0), tuple("hsm", "tr1.status", "error", 3));
    // The laser fails before any answer: the camera configuration on pippi gives s1 new params.
    let second = exec.handle(secs(2.5), tuple("astrid", "l1.status", "error", 3));
    assert!(
        set_of(&second, "astrid", "s1.params").is_some(),
        "{}",
        timeline(&exec)
    );
    let held = exec.handle(secs(4.0), unanswered("astrid", "s1.params"));
    assert_eq!(set_of(&held, "astrid", "s1.params"), None, "{held:?}");
}

/// A component waiting while a remote set to its PEIS has been neither answered nor failed is
/// not blamed when its grace runs out: what it waits for may be held up on the same way. Its
/// grace starts again, and once the way is shown to work it is blamed as before.
#[test]
fn a_component_waiting_while_its_peis_has_not_answered_is_timed_again() {
    let mut exec = running_first_action();
    // The laser configuration's sets to astrid go unanswered for now.
    let sets = exec.handle(secs(2.0), tuple("hsm", "tr1.status", "error", 3));
    laser_configuration_runs(&mut exec);
    let commands = answered(
        &mut exec,
        secs(2.5),
        tuple("astrid", "tc1.status", "waiting", 4),
    );
    let grace = ExecConfig::default().waiting_grace;
    let again = exec.handle(
        secs(4.5),
        fired(
            &commands,
            &Timer::Waiting(component("astrid", "tc1")),
            grace,
        ),
    );
    assert_eq!(failures(&exec), ["hsm:tr1 error"], "{}", timeline(&exec));
    // The sets are answered; the grace that started again runs out: navigation is to blame.
    answer_all(&mut exec, secs(5.0), &sets);
    // Nothing can stand in for navigation: it is given longer, then blamed.
    let more = exec.handle(
        secs(6.5),
        fired(&again, &Timer::Waiting(component("astrid", "tc1")), grace),
    );
    assert_eq!(failures(&exec), ["hsm:tr1 error"], "{}", timeline(&exec));
    exec.handle(
        secs(11.5),
        fired(
            &more,
            &Timer::Waiting(component("astrid", "tc1")),
            ExecConfig::default().return_wait,
        ),
    );
    assert_eq!(
        failures(&exec),
        ["hsm:tr1 error", "astrid:tc1 waiting for longer than 7s"],
        "{}",
        timeline(&exec)
    );
}

/// The executive cut off while it deploys: its remote sets get no answer, then every PEIS seems
/// to leave. Nothing is blamed on a component, and the action waits for the ecology instead of
/// failing for want of a configuration.
#[test]
fn unanswered_remote_sets_of_an_executive_cut_off_blame_no_component() {
    let mut exec = running_first_action();
    let held = exec.handle(secs(2.0), unanswered("astrid", "tc1.params"));
    exec.handle(secs(2.1), unanswered("hsm", "ca1.params"));
    let first = exec.handle(secs(2.5), Event::PeisLeft(peis("hsm")));
    exec.handle(secs(2.6), Event::PeisLeft(peis("astrid")));
    exec.handle(secs(2.7), Event::PeisLeft(peis("pippi")));
    let window = ExecConfig::default().loss_window;
    exec.handle(secs(3.5), fired(&first, &Timer::LossWindow, window));
    // Cancelled at the loss; delivered all the same, it changes nothing.
    let grace = ExecConfig::default().unanswered_grace;
    exec.handle(
        secs(5.0),
        fired(&held, &Timer::Unanswered(component("astrid", "tc1")), grace),
    );
    let text = timeline(&exec);
    assert!(text.contains("LOST THE ECOLOGY"), "{text}");
    assert!(!text.contains("could not set"), "{text}");
    assert!(!names(&exec).contains(&"action_failed"), "{text}");
    exec.handle(secs(6.0), Event::PeisJoined(peis("hsm")));
    let last = exec.handle(secs(6.1), Event::PeisJoined(peis("astrid")));
    exec.handle(secs(7.1), fired(&last, &Timer::LostSettle, window));
    let text = timeline(&exec);
    assert!(text.contains("the ecology is back"), "{text}");
    assert_eq!(costs(&exec).last(), Some(&(80, true)), "{text}");
}

/// A remote set that failed after its PEIS was taken for gone: what the executive wrote there is
/// unknown, so once the lost ecology is back it writes it again, and only that.
#[test]
fn a_remote_set_that_failed_while_its_peis_was_away_is_written_again_on_its_return() {
    let mut exec = running_first_action();
    let first = exec.handle(secs(2.0), Event::PeisLeft(peis("hsm")));
    exec.handle(secs(2.1), Event::PeisLeft(peis("astrid")));
    exec.handle(secs(2.2), Event::PeisLeft(peis("pippi")));
    exec.handle(secs(2.3), unanswered("hsm", "tr1.params"));
    let window = ExecConfig::default().loss_window;
    exec.handle(secs(3.0), fired(&first, &Timer::LossWindow, window));
    exec.handle(secs(6.0), Event::PeisJoined(peis("hsm")));
    exec.handle(secs(6.1), Event::PeisJoined(peis("astrid")));
    let last = exec.handle(secs(6.2), Event::PeisJoined(peis("pippi")));
    let resumed = exec.handle(secs(7.2), fired(&last, &Timer::LostSettle, window));
    let text = timeline(&exec);
    assert_eq!(costs(&exec).last(), Some(&(80, true)), "{text}");
    let rewritten: Vec<String> = sets_to(&resumed, "hsm")
        .into_iter()
        .filter(|(k, _)| k.ends_with(".params"))
        .map(|(k, _)| k)
        .collect();
    assert_eq!(rewritten, ["tr1.params"], "{text}");
}

/// Astrid away for less than the window: the action found no configuration without her, but
/// when the departures are judged she is back, so the action is configured again instead of
/// failing for a reason that no longer holds.
#[test]
fn a_peis_back_before_its_departure_is_judged_is_forgiven() {
    let mut exec = running_first_action();
    let left = exec.handle(secs(2.0), Event::PeisLeft(peis("astrid")));
    exec.handle(secs(2.4), Event::PeisJoined(peis("astrid")));
    let window = ExecConfig::default().loss_window;
    exec.handle(secs(3.0), fired(&left, &Timer::LossWindow, window));
    let text = timeline(&exec);
    assert!(
        text.contains("FAILURE astrid:tc1: PEIS astrid left the ecology"),
        "{text}"
    );
    assert!(!names(&exec).contains(&"action_failed"), "{text}");
    assert_eq!(exec.status(), &RunStatus::Running { index: 0 }, "{text}");
    assert_eq!(costs(&exec).last(), Some(&(80, true)), "{text}");
}

/// The executive's process stalled: on waking it hears the cameras leave, deploys the laser
/// configuration to Astrid, then hears her leave before any of it echoed, and everyone join
/// again. Configured on the cameras again, it takes back what it wrote to Astrid, though her
/// mirror still shows the laser off and the odometry's params empty from before: that is no
/// one else's doing but its own writes not seen yet, which may still land after her return.
/// The cameras' host, meanwhile, put back the params the executive had given them (it was gone
/// too long): those are written again, not taken for running.
#[test]
fn writes_not_yet_echoed_when_a_peis_left_are_taken_back_on_its_return() {
    let mut exec = running_first_action();
    exec.handle(secs(1.0), tuple("astrid", "od1.params", "", 1));
    exec.handle(
        secs(1.0),
        tuple("astrid", "components.l1.currState", "off", 2),
    );
    let left = exec.handle(secs(2.0), Event::PeisLeft(peis("hsm")));
    let sent = sets_to(&left, "astrid");
    for written in [
        ("components.l1.reqState", "on"),
        ("od1.params", "(odometry astrid od1)"),
    ] {
        assert!(
            sent.contains(&(written.0.to_string(), written.1.to_string())),
            "{sent:?}"
        );
    }
    exec.handle(secs(2.01), Event::PeisLeft(peis("astrid")));
    exec.handle(secs(2.02), Event::PeisJoined(peis("astrid")));
    exec.handle(secs(2.03), Event::PeisJoined(peis("hsm")));
    exec.handle(secs(2.5), tuple("hsm", "ca1.params", "", 9));
    let window = ExecConfig::default().loss_window;
    let judged = exec.handle(secs(3.0), fired(&left, &Timer::LossWindow, window));
    let text = timeline(&exec);
    assert_eq!(costs(&exec).last(), Some(&(80, true)), "{text}");
    let cameras = sets_to(&judged, "hsm");
    assert!(
        cameras
            .iter()
            .any(|(key, value)| key == "ca1.params" && !value.is_empty()),
        "{cameras:?}\n{text}"
    );
    let back = sets_to(&judged, "astrid");
    for put_back in [("components.l1.reqState", "off"), ("od1.params", "")] {
        assert!(
            back.contains(&(put_back.0.to_string(), put_back.1.to_string())),
            "{back:?}\n{text}"
        );
    }
}

/// The first move running, Astrid seen gone at 2 s and her departure judged at 3 s: the
/// executive, and the commands of the judgement.
fn astrid_gone_and_judged() -> (Executive, Vec<Command>) {
    let mut exec = running_first_action();
    let left = exec.handle(secs(2.0), Event::PeisLeft(peis("astrid")));
    let window = ExecConfig::default().loss_window;
    let judged = exec.handle(secs(3.0), fired(&left, &Timer::LossWindow, window));
    (exec, judged)
}

/// Astrid's lease ran out on a poor link, and she is back 3 s later, after her departure was
/// judged: the move, which has no configuration without her, waits for her instead of failing,
/// and is configured again a loss window after her return (her tuples read again meanwhile).
#[test]
fn an_action_left_without_a_configuration_waits_for_the_peis_to_return() {
    let (mut exec, judged) = astrid_gone_and_judged();
    let window = ExecConfig::default().loss_window;
    let text = timeline(&exec);
    assert!(
        text.contains("no configuration without astrid: waiting up to 5s for it to return"),
        "{text}"
    );
    assert!(!names(&exec).contains(&"action_failed"), "{text}");
    let joined = exec.handle(secs(5.0), Event::PeisJoined(peis("astrid")));
    assert_eq!(
        costs(&exec).len(),
        1,
        "not before her tuples are read again"
    );
    exec.handle(secs(6.0), fired(&joined, &Timer::ReturnSettle, window));
    let text = timeline(&exec);
    assert_eq!(costs(&exec).last(), Some(&(80, true)), "{text}");
    // The wait was called off: its timer changes nothing.
    let wait = ExecConfig::default().return_wait;
    exec.handle(secs(8.0), fired(&judged, &Timer::ReturnWait, wait));
    assert!(!names(&exec).contains(&"action_failed"), "{text}");
    assert_eq!(exec.status(), &RunStatus::Running { index: 0 }, "{text}");
}

/// Not back within the wait: the action fails, saying that it waited.
#[test]
fn an_action_waits_for_a_peis_that_left_only_so_long() {
    let (mut exec, judged) = astrid_gone_and_judged();
    assert!(!names(&exec).contains(&"action_failed"));
    let wait = ExecConfig::default().return_wait;
    exec.handle(secs(8.0), fired(&judged, &Timer::ReturnWait, wait));
    let RunStatus::Failed { index: 0, reason } = exec.status() else {
        panic!("{:?}\n{}", exec.status(), timeline(&exec));
    };
    assert!(
        reason.starts_with(
            "no configuration for (navigate astrid entrance): no method applies; astrid left and \
             was not back within 5s\n"
        ),
        "{reason}"
    );
}

/// Astrid gone, then hsm, and Astrid back just before the wait runs out, while her tuples are
/// read again: the move is configured again at once, without hsm (on Astrid's laser), instead
/// of failing.
#[test]
fn a_peis_back_as_the_wait_runs_out_is_configured_with_at_once() {
    let (mut exec, _) = astrid_gone_and_judged();
    let window = ExecConfig::default().loss_window;
    let left = exec.handle(secs(3.5), Event::PeisLeft(peis("hsm")));
    let judged = exec.handle(secs(4.5), fired(&left, &Timer::LossWindow, window));
    let text = timeline(&exec);
    assert!(
        text.contains("no configuration without astrid, hsm: waiting up to 5s"),
        "{text}"
    );
    exec.handle(secs(9.2), Event::PeisJoined(peis("astrid")));
    let wait = ExecConfig::default().return_wait;
    exec.handle(secs(9.5), fired(&judged, &Timer::ReturnWait, wait));
    let text = timeline(&exec);
    assert!(!names(&exec).contains(&"action_failed"), "{text}");
    assert_eq!(costs(&exec).last(), Some(&(150, true)), "{text}");
}

/// An unanswered remote set to `peis`'s tuple `key`.
fn unanswered(peis_name: &str, key_text: &str) -> Event {
    Event::RemoteSetFailed {
        owner: peis(peis_name),
        key: key(key_text),
        reason: "no answer".to_string(),
        unanswered: true,
    }
}

#[test]
fn stopping_a_task_releases_what_it_used_and_fails_it() {
    let mut exec = running_first_action();
    let commands = exec.stop(secs(2.0), "stopped by the operator");
    assert_eq!(
        exec.status(),
        &RunStatus::Failed {
            index: 0,
            reason: "stopped by the operator".to_string()
        }
    );
    let cleared: Vec<String> = commands
        .iter()
        .filter_map(|c| match c {
            Command::RemoteSet { owner, key, value } if value.is_empty() => {
                Some(format!("{owner}:{key}"))
            }
            _ => None,
        })
        .collect();
    assert_eq!(
        cleared,
        [
            "astrid:s1.params",
            "astrid:tc1.params",
            "hsm:ca1.params",
            "hsm:tr1.params"
        ]
    );
    assert_eq!(names(&exec).last(), Some(&"task_failed"));
    // Stopping twice does nothing more.
    assert!(exec.stop(secs(3.0), "again").is_empty());
}

/// Whole runs: the paper's PEIS-Home as real PEIS hosts (`run_host`) running
/// test components that honour the component contract, and the driver running
/// the executive, on the in-process tuple space in virtual time.
mod on_the_tuple_space {
    use std::collections::BTreeMap;
    use std::convert::Infallible;
    use std::sync::{Arc, Mutex};
    use std::time::Duration;

    use ecology_domain::{EcologyState, parse_domain, parse_facts, parse_goal};
    use ecology_peis::{Component, ComponentError, Context};
    use ecology_tuples::{
        Clock, InProcessPeis, InProcessSpace, Key, PeisId, PeisOptions, PresenceSubscription,
        Subscription, Timestamp, Tuple, TupleError, TupleEvent, TuplePattern, TupleSpace, Value,
        VirtualClock,
    };

    use super::peis_home::Hosts;
    use super::{
        PEIS_BUILDING, PEIS_HOME, PEIS_HOME_FACTS, costs, executive, failures, names, peis, plan,
        secs, timeline,
    };
    use crate::{
        DriverConfig, ExecConfig, Executive, LogEntry, LogEvent, PlannedAction, RunStatus,
        drive_observed,
    };

    /// How long each component takes to switch on.
    pub(super) const STARTUP: Duration = Duration::from_millis(500);

    /// How far virtual time moves in one step.
    const STEP: Duration = Duration::from_millis(20);

    /// (inputs, outputs, seconds of fresh input until done) of each functionality.
    fn behaviour(
        functionality: &str,
    ) -> (
        &'static [&'static str],
        &'static [&'static str],
        Option<u64>,
    ) {
        match functionality {
            "laser" => (&[], &["range-scan"], None),
            "odometry" => (&[], &["odometry"], None),
            "ceiling-cameras" | "camera" => (&[], &["image"], None),
            "scan-matching" => (&["range-scan", "odometry"], &["position"], None),
            "pose-tracking" => (&["global-pos"], &["position"], None),
            "tracking-system" | "object-localizer" => (&["image"], &["global-pos"], None),
            "navigation" => (&["position"], &[], Some(3)),
            _ => (&[], &[], Some(1)),
        }
    }

    /// The components that have failed for good, by (PEIS, component), with
    /// their causes.
    pub(super) type Broken = Arc<Mutex<BTreeMap<(String, String), String>>>;

    /// A component that follows the contract: `waiting` while an input is
    /// missing or stale, `running` while it works, `done` when its step ends;
    /// once `broken` holds a cause for it, it fails with that cause (again
    /// whenever it is started).
    pub(super) fn body(broken: Broken) -> Arc<dyn Component<InProcessPeis>> {
        Arc::new(move |ctx: Context<InProcessPeis>| {
            let broken = broken.clone();
            async move {
                let me = (ctx.peis().to_string(), ctx.component().to_string());
                let (ins, outs, finish) = behaviour(ctx.functionality());
                let mut inputs = ctx.inputs(ins).await?;
                let mut shown = String::new();
                let mut worked = Duration::ZERO;
                loop {
                    let cause = broken.lock().expect("lock").get(&me).cloned();
                    if let Some(cause) = cause {
                        return Err(ComponentError::Fault(cause));
                    }
                    inputs.poll();
                    let missing = inputs.missing(Duration::from_millis(500));
                    let status = if missing.is_empty() {
                        "running"
                    } else {
                        "waiting"
                    };
                    if status != shown {
                        let cause = (!missing.is_empty()).then(|| missing.join(" "));
                        ctx.status(status, cause.as_deref()).await?;
                        shown = status.to_string();
                    }
                    if missing.is_empty() {
                        for out in outs {
                            ctx.output(out, Value::text(ctx.args().join(" "))).await?;
                        }
                        worked += Duration::from_millis(100);
                        if finish.is_some_and(|s| worked >= Duration::from_secs(s)) {
                            ctx.status("done", None).await?;
                            return Ok(());
                        }
                    }
                    ctx.sleep(Duration::from_millis(100)).await;
                }
            }
        })
    }

    /// A component whose start-up hangs: it never reports anything, so its
    /// host shows it `initializing` for ever.
    fn hung_body() -> Arc<dyn Component<InProcessPeis>> {
        Arc::new(|_ctx: Context<InProcessPeis>| std::future::pending())
    }

    /// What goes wrong in a run.
    #[derive(Clone, Copy, Debug)]
    enum Fault {
        /// Component `.1` of PEIS `.0` fails for good, with cause `.2`.
        Break(&'static str, &'static str, &'static str),
        /// The PEIS crashes: it stops without a goodbye, and the others see it
        /// leave once its lease (2 s) has run out.
        Vanish(&'static str),
    }

    /// A run of an executive against real hosts, until its task ends (or
    /// 300 s of virtual time pass).
    struct Run {
        /// The ecology: a host for each PEIS with a `pc` fact, a component for each `pc`.
        facts: String,
        exec: Executive,
        /// Components whose start-up hangs.
        hung: &'static [(&'static str, &'static str)],
        /// `.1` strikes as soon as the configuration of action `.0` (from 0) runs.
        fault: Option<(usize, Fault)>,
        /// Every remote set to this PEIS takes this long: a PEIS that answers slowly.
        slow: Option<(&'static str, Duration)>,
        /// The PEIS of these facts join as the configuration of action `.0` runs.
        arrives: Option<(usize, &'static str)>,
    }

    /// What a run leaves.
    struct Ran {
        exec: Executive,
        /// hsm's `tr1.params` as it was first set.
        wired: Option<Tuple>,
        /// When the driver started (log times count from it).
        started: Timestamp,
    }

    impl Run {
        /// `exec` in the paper's PEIS-Home, nothing going wrong.
        fn of(exec: Executive) -> Run {
            Run {
                facts: PEIS_HOME_FACTS.to_string(),
                exec,
                hung: &[],
                fault: None,
                slow: None,
                arrives: None,
            }
        }

        async fn go(self) -> Ran {
            let Run {
                facts,
                mut exec,
                hung,
                fault,
                slow,
                arrives,
            } = self;
            let clock = VirtualClock::default();
            let shared: Arc<dyn Clock> = Arc::new(clock.clone());
            let space = InProcessSpace::new(shared.clone());
            let facts = parse_facts(facts.as_bytes()).expect("facts");
            let broken = Broken::default();
            let mut hosts = Hosts::start(&space, &shared, &facts, STARTUP, |p, c| {
                if hung.contains(&(p, c)) {
                    hung_body()
                } else {
                    body(broken.clone())
                }
            })
            .expect("the hosts start");
            let me = space
                .join(peis("executive"), PeisOptions::default())
                .expect("joins");
            let mut probe = me
                .subscribe(TuplePattern::parse("hsm:tr1.params").expect("pattern"))
                .await
                .expect("subscribe");

            // The fault strikes as the executive logs that the action's configuration runs.
            let mut pending = fault;
            let mut arriving = arrives;
            let mut arrived = None;
            let mut action = None;
            let observe = |entry: &LogEntry| match entry.event {
                LogEvent::ActionStarted { index, .. } => action = Some(index),
                LogEvent::Running { .. } => {
                    if let Some((_, facts)) = arriving.take_if(|(at, _)| Some(*at) == action) {
                        let facts = parse_facts(facts.as_bytes()).expect("facts");
                        let body = |_: &str, _: &str| body(broken.clone());
                        arrived = Some(
                            Hosts::start(&space, &shared, &facts, STARTUP, body).expect("starts"),
                        );
                    }
                    match pending.take_if(|(at, _)| Some(*at) == action) {
                        Some((_, Fault::Break(p, c, cause))) => {
                            broken
                                .lock()
                                .expect("lock")
                                .insert((p.to_string(), c.to_string()), cause.to_string());
                        }
                        Some((_, Fault::Vanish(p))) => hosts.vanish(p),
                        None => {}
                    }
                }
                _ => {}
            };
            let config = DriverConfig {
                limit: Some(secs(300.0)),
                ..DriverConfig::default()
            };
            let started = shared.now();
            let driving = async {
                match slow {
                    Some((p, delay)) => {
                        let space = SlowTo {
                            inner: me.clone(),
                            slow: peis(p),
                            delay,
                            clock: shared.clone(),
                        };
                        drive_observed(&space, shared.clone(), &mut exec, config, observe).await
                    }
                    None => drive_observed(&me, shared.clone(), &mut exec, config, observe).await,
                }
            };
            let driven = tokio::select! {
                biased;
                driven = driving => driven,
                never = tick(&clock) => match never {},
            };
            driven.expect("drives");
            assert!(
                pending.is_none(),
                "the fault never struck: {}",
                timeline(&exec)
            );

            let mut wired = None;
            while let Some(event) = probe.try_next() {
                if let TupleEvent::Changed(t) = event {
                    wired.get_or_insert(t);
                }
            }
            let vanished = match fault {
                Some((_, Fault::Vanish(p))) => Some(p),
                _ => None,
            };
            let late = match arrived {
                Some(arrived) => arrived.stop().await,
                None => Vec::new(),
            };
            for (p, outcome) in hosts.stop().await.into_iter().chain(late) {
                // A vanished PEIS's host finds the space closed to it; the others stop cleanly.
                assert!(
                    outcome.is_ok() || vanished == Some(p.as_str()),
                    "host {p}: {outcome:?}"
                );
            }
            space.shutdown().await;
            Ran {
                exec,
                wired,
                started,
            }
        }
    }

    impl Run {
        /// Runs; the executive, whose task must be done.
        async fn done(self) -> Executive {
            let exec = self.go().await.exec;
            assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(&exec));
            exec
        }

        /// Runs; the executive, whose task must have failed, with the
        /// failed action's index and the reason.
        async fn failed(self) -> (Executive, usize, String) {
            let exec = self.go().await.exec;
            let RunStatus::Failed { index, reason } = exec.status().clone() else {
                panic!("the task should fail: {}", timeline(&exec));
            };
            (exec, index, reason)
        }
    }

    /// Moves virtual time on, a `STEP` at a time, whenever every task waits.
    /// The tests run on tokio's paused clock (`start_paused`), which moves on
    /// (ending this sleep) only when no task can run: so each step comes once
    /// everything the last one set off has been handled, however many turns
    /// that took.
    pub(super) async fn tick(clock: &VirtualClock) -> Infallible {
        loop {
            tokio::time::sleep(STEP).await;
            clock.advance(STEP);
        }
    }

    /// The executive's own space, with every remote set to one PEIS delayed:
    /// a PEIS that answers slowly.
    #[derive(Clone)]
    struct SlowTo {
        inner: InProcessPeis,
        slow: PeisId,
        delay: Duration,
        clock: Arc<dyn Clock>,
    }

    impl TupleSpace for SlowTo {
        fn peis(&self) -> &PeisId {
            self.inner.peis()
        }
        async fn set(&self, key: Key, value: Value) -> Result<Tuple, TupleError> {
            self.inner.set(key, value).await
        }
        fn is_read(&self, key: &Key) -> bool {
            self.inner.is_read(key)
        }
        fn watch_readers(&self, key: &Key) -> tokio::sync::watch::Receiver<bool> {
            self.inner.watch_readers(key)
        }
        async fn delete(&self, key: Key) -> Result<bool, TupleError> {
            self.inner.delete(key).await
        }
        async fn release_claims(&self, holder: PeisId) -> Result<Vec<Tuple>, TupleError> {
            self.inner.release_claims(holder).await
        }
        async fn get(&self, owner: PeisId, key: Key) -> Result<Option<Tuple>, TupleError> {
            self.inner.get(owner, key).await
        }
        async fn get_matching(&self, pattern: TuplePattern) -> Result<Vec<Tuple>, TupleError> {
            self.inner.get_matching(pattern).await
        }
        async fn subscribe(&self, pattern: TuplePattern) -> Result<Subscription, TupleError> {
            self.inner.subscribe(pattern).await
        }
        async fn set_remote(
            &self,
            owner: PeisId,
            key: Key,
            value: Value,
        ) -> Result<Tuple, TupleError> {
            if owner == self.slow {
                let until = self.clock.now().saturating_add(self.delay);
                self.clock.sleep_until(until).await;
            }
            self.inner.set_remote(owner, key, value).await
        }
        async fn peers(&self) -> Result<Vec<PeisId>, TupleError> {
            self.inner.peers().await
        }
        async fn subscribe_presence(&self) -> Result<PresenceSubscription, TupleError> {
            self.inner.subscribe_presence().await
        }
        async fn subscribe_presence_of(
            &self,
            peis: PeisId,
        ) -> Result<PresenceSubscription, TupleError> {
            self.inner.subscribe_presence_of(peis).await
        }
    }

    // The paper, Section VIII, steps 1-5 and 7 without the failure.
    #[tokio::test(start_paused = true)]
    async fn a_whole_plan_runs_to_completion() {
        let exec = Run::of(executive(plan())).done().await;
        assert_eq!(
            costs(&exec),
            [(80, false), (100, false), (80, false), (20, false)]
        );
        assert_eq!(names(&exec).last(), Some(&"task_done"));
        assert_eq!(
            names(&exec).iter().filter(|n| **n == "action_done").count(),
            4
        );
        // The gripper was started for action 2 and switched off once unneeded.
        let text = timeline(&exec);
        assert!(text.contains("switch on astrid:gr1"), "{text}");
        assert!(text.contains("switched off astrid:gr1"), "{text}");
        // At the end the task leaves the ecology as it found it: the speaker it
        // switched on goes off, and the components it borrowed lose their params.
        let released = exec.log().iter().find_map(|e| match &e.event {
            LogEvent::Released {
                switched_off,
                stopped,
                ..
            } => Some((
                switched_off.iter().map(ToString::to_string).collect(),
                stopped.iter().map(ToString::to_string).collect(),
            )),
            _ => None,
        });
        assert_eq!(
            released,
            Some((
                vec!["astrid:sp1".to_string()],
                ["astrid:s1", "astrid:tc1", "hsm:ca1", "hsm:tr1"]
                    .map(String::from)
                    .to_vec()
            )),
            "{text}"
        );
        assert_eq!(names(&exec)[names(&exec).len() - 2], "released");
    }

    /// The paper's plan with `fault` striking on the way to the bedroom
    /// (action 3): the laser stands in for the home security monitor's
    /// tracking for that action, then the last action runs as planned.
    async fn reconfigured_on_the_way_to_the_bedroom(fault: Fault) -> Executive {
        let exec = Run {
            fault: Some((2, fault)),
            ..Run::of(executive(plan()))
        }
        .done()
        .await;
        assert_eq!(
            costs(&exec),
            [
                (80, false),
                (100, false),
                (80, false),
                (170, true),
                (20, false)
            ],
            "{}",
            timeline(&exec)
        );
        let text = timeline(&exec);
        assert!(text.contains("switch on astrid:l1"), "{text}");
        exec
    }

    /// The paper's costs with hsm's tracker failing on the way to the bedroom and a monitor that
    /// joined meanwhile (costs of 5) taking over: 80, 100, 80, then 50, then 20.
    const ONTO_THE_MONITOR: [(u64, bool); 5] = [
        (80, false),
        (100, false),
        (80, false),
        (50, true),
        (20, false),
    ];

    // Acquired on demand, the state still takes in a PEIS that joins during the task with a
    // component the goal can use: the next configuration may use it.
    #[tokio::test(start_paused = true)]
    async fn a_peis_that_joins_with_a_usable_component_is_used_at_the_next_configuration() {
        const MONITOR: &str = "(pc mon cams ca9) (cost mon ca9 5 on) \
                               (pc mon tr-sys tr9) (cost mon tr9 5 on) \
                               (pc mon player pl9) (cost mon pl9 5 on)";
        let exec = Run {
            fault: Some((2, Fault::Break("hsm", "tr1", "camera failure"))),
            arrives: Some((2, MONITOR)),
            ..Run::of(executive(plan()))
        }
        .done()
        .await;
        let text = timeline(&exec);
        assert_eq!(
            costs(&exec),
            ONTO_THE_MONITOR,
            "mon's own costs (5 each), not its functionalities' defaults: {text}"
        );
        assert!(text.contains("on mon:tr9"), "{text}");
        assert!(!exec.intake().everything, "the contract only, no outputs");
    }

    // In the building's domain, on demand follows Astrid and whoever covers the rooms her moves
    // start in, not every PEIS. A monitor that joins during the task covering the entrance says so
    // by its room key, is followed from then on, and tracks her when hsm's tracker fails there; a
    // monitor that covers no room of the task is never read.
    #[tokio::test(start_paused = true)]
    async fn a_peis_that_comes_to_cover_a_room_of_the_task_is_followed_and_used() {
        const HSM_COVERS: &str = "(covers hsm ca1 living-room) (covers hsm ca1 entrance) \
                                  (covers hsm ca1 kitchen) (covers hsm ca1 bedroom)";
        const MONITORS: &str = "(pc mon cams ca9) (cost mon ca9 5 on) (covers mon ca9 entrance) \
                                (pc mon tr-sys tr9) (cost mon tr9 5 on) \
                                (pc far cams ca8) (cost far ca8 1 on) (covers far ca8 attic) \
                                (pc far tr-sys tr8) (cost far tr8 1 on)";
        let domain = parse_domain(PEIS_BUILDING.as_bytes()).expect("domain");
        let exec = Executive::new(domain, EcologyState::new(), plan(), ExecConfig::default());
        let exec = Run {
            facts: format!("{PEIS_HOME_FACTS} {HSM_COVERS}"),
            fault: Some((2, Fault::Break("hsm", "tr1", "camera failure"))),
            arrives: Some((2, MONITORS)),
            ..Run::of(exec)
        }
        .done()
        .await;
        let text = timeline(&exec);
        assert_eq!(costs(&exec), ONTO_THE_MONITOR, "{text}");
        assert!(text.contains("on mon:tr9"), "{text}");
        // Astrid, hsm and mon; the living room and the entrance. Not Pippi, whose camera says no
        // room it covers, nor `far`.
        assert_eq!(exec.intake().scope, Some((3, 2)), "{text}");
        assert!(exec.mirror().component("far", "ca8").is_none(), "{text}");
    }

    // The paper, Section VIII step 6: the tracking system fails while moving to the bedroom.
    #[tokio::test(start_paused = true)]
    async fn a_failing_component_is_reconfigured_around() {
        let exec = reconfigured_on_the_way_to_the_bedroom(Fault::Break(
            "hsm",
            "tr1",
            "camera ca1 stopped producing images",
        ))
        .await;
        assert_eq!(
            failures(&exec),
            ["hsm:tr1 camera ca1 stopped producing images"],
            "{}",
            timeline(&exec)
        );
    }

    // A PEIS that crashes (no goodbye) is reported as left after its lease (2 s).
    #[tokio::test(start_paused = true)]
    async fn a_vanishing_peis_is_reconfigured_around() {
        let exec = reconfigured_on_the_way_to_the_bedroom(Fault::Vanish("hsm")).await;
        let text = timeline(&exec);
        assert!(text.contains("PEIS hsm left the ecology"), "{text}");
        assert_eq!(
            failures(&exec),
            [
                "hsm:ca1 PEIS hsm left the ecology",
                "hsm:tr1 PEIS hsm left the ecology"
            ],
            "{text}"
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_component_in_error_stays_out_of_later_actions() {
        // On the way to the entrance, the tracking system fails for good.
        let exec = Run {
            fault: Some((
                0,
                Fault::Break("hsm", "tr1", "camera ca1 stopped producing images"),
            )),
            ..Run::of(executive(plan()))
        }
        .done()
        .await;
        // Moving to the bedroom does not try the broken tracking system again.
        assert_eq!(
            costs(&exec),
            [
                (80, false),
                (170, true),
                (100, false),
                (170, false),
                (20, false)
            ],
            "{}",
            timeline(&exec)
        );
        assert_eq!(names(&exec).iter().filter(|n| **n == "failure").count(), 1);
        let text = timeline(&exec);
        assert!(
            text.contains(
                "unavailable: hsm:tr1 reports error (camera ca1 stopped producing images)"
            ),
            "{text}"
        );
    }

    #[tokio::test(start_paused = true)]
    async fn no_configuration_fails_the_action_with_the_explanation() {
        // Without a laser and without Pippi, losing the tracking system leaves nothing.
        let facts: String = PEIS_HOME_FACTS
            .lines()
            .filter(|l| !l.contains("pippi") && !l.contains(" l1"))
            .collect::<Vec<_>>()
            .join("\n");
        let (exec, index, reason) = Run {
            facts,
            fault: Some((0, Fault::Break("hsm", "tr1", "camera failure"))),
            ..Run::of(executive(plan()))
        }
        .failed()
        .await;
        assert_eq!(index, 0);
        assert!(reason.contains("input (position astrid)"), "{reason}");
        assert!(reason.contains("component hsm:tr1 is excluded"), "{reason}");
        // Without a replanner the driver abandons the task.
        let names = names(&exec);
        assert!(names.contains(&"action_failed"), "{}", timeline(&exec));
        assert_eq!(names.last(), Some(&"task_failed"), "{}", timeline(&exec));
    }

    // A component that never reports running is failed after the deploy
    // timeout and replaced. The one that hangs is the navigation controller,
    // with a second one to stand in for it: a hung producer would leave its
    // consumers waiting for inputs that are wired only once it runs, and they
    // would time out with it.
    #[tokio::test(start_paused = true)]
    async fn a_component_that_never_runs_times_out_and_is_replaced() {
        let exec = Run {
            facts: format!("{PEIS_HOME_FACTS}\n(pc astrid tc tc2) (cost astrid tc2 30 on)\n"),
            hung: &[("astrid", "tc1")],
            ..Run::of(executive(plan()[..1].to_vec()))
        }
        .done()
        .await;
        assert_eq!(
            costs(&exec),
            [(80, false), (90, true)],
            "{}",
            timeline(&exec)
        );
        assert_eq!(
            failures(&exec),
            ["astrid:tc1 did not report running within 10s"],
            "{}",
            timeline(&exec)
        );
    }

    // A producer that never runs leaves its consumers waiting for inputs that
    // are wired only once it runs: when the deploy timeout passes, the
    // producer alone is blamed, and the consumers serve the next configuration.
    #[tokio::test(start_paused = true)]
    async fn a_hung_producer_is_blamed_not_the_consumers_waiting_for_it() {
        let exec = Run {
            hung: &[("hsm", "tr1")],
            ..Run::of(executive(plan()[..1].to_vec()))
        }
        .done()
        .await;
        assert_eq!(
            failures(&exec),
            ["hsm:tr1 did not report running within 10s"],
            "{}",
            timeline(&exec)
        );
        assert_eq!(
            costs(&exec),
            [(80, false), (170, true)],
            "{}",
            timeline(&exec)
        );
    }

    #[tokio::test(start_paused = true)]
    async fn an_action_whose_configuration_has_no_postcondition_is_done_once_it_runs() {
        let localize = PlannedAction::new(
            "(localize astrid)",
            Some(parse_goal("(get-position astrid)").expect("goal")),
        );
        let exec = Run::of(executive(vec![localize])).done().await;
        // Long before the action's 600 s timeout: as soon as it runs.
        let done_at = exec
            .log()
            .iter()
            .find(|e| e.event.name() == "action_done")
            .map(|e| e.t);
        assert!(
            done_at.is_some_and(|t| t < secs(5.0)),
            "{}",
            timeline(&exec)
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_planning_budget_that_runs_out_fails_the_action_with_that_reason() {
        let domain = parse_domain(PEIS_HOME.as_bytes()).expect("domain");
        let config = ExecConfig {
            planning: ecology_config::Budget {
                max_expansions: Some(0),
                max_time: None,
            },
            ..ExecConfig::default()
        };
        let exec = Executive::new(domain, EcologyState::new(), plan(), config);
        let (_, _, reason) = Run::of(exec).failed().await;
        assert!(
            reason.starts_with("the configuration planner's budget ran out"),
            "{reason}"
        );
    }

    /// A stopwatch that has been running for an hour and stands still.
    struct AnHourIn;

    impl ecology_config::Clock for AnHourIn {
        fn elapsed(&self) -> Duration {
            secs(3600.0)
        }
    }

    // The planning budget counts from when planning starts, not from when the
    // executive started: an hour into a task, a 2 s budget is not spent already.
    #[tokio::test(start_paused = true)]
    async fn the_planning_budget_counts_from_each_planning() {
        Run::of(executive(plan()).with_stopwatch(Box::new(AnHourIn)))
            .done()
            .await;
    }

    // Remote sets to one PEIS do not wait for those to another: a PEIS that
    // takes 2 s to answer each remote set delays only its own components.
    #[tokio::test(start_paused = true)]
    async fn remote_sets_to_different_peis_run_concurrently() {
        let slow = Duration::from_secs(2);
        let Ran {
            exec,
            wired,
            started,
        } = Run {
            slow: Some(("astrid", slow)),
            ..Run::of(executive(plan()[..1].to_vec()))
        }
        .go()
        .await;
        assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(&exec));
        let deployed_at = exec
            .log()
            .iter()
            .find(|e| e.event.name() == "deployed")
            .map(|e| e.t)
            .expect("deployed");
        let running_at = exec
            .log()
            .iter()
            .find(|e| e.event.name() == "running")
            .map(|e| e.t)
            .expect("running");
        // astrid's two params follow each other (4 s) before her components run.
        assert!(running_at >= deployed_at + 2 * slow, "{}", timeline(&exec));
        // hsm's params, asked for after astrid's, were not held up behind them.
        let wired = wired.expect("hsm's tr1.params");
        assert_eq!(wired.seq, 1);
        let wired_at = wired.ts_write.saturating_duration_since(started);
        assert!(
            wired_at < deployed_at + Duration::from_millis(500),
            "hsm's params were set at {wired_at:?}, deployed at {deployed_at:?}"
        );
    }
}
