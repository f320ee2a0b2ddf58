//! Tests of the executive, driven by events in virtual time against a small
//! scripted ecology that plays the PEIS side of the component contract.

use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap};
use std::time::Duration;

use ecology_domain::{EcologyState, parse_domain, parse_facts, parse_goal};

use ecology_tuples::{Key, PeisId};

use crate::{Command, Event, ExecConfig, Executive, LogEvent, PlannedAction, RunStatus, TimerId};

const PEIS_HOME: &str = include_str!("../../../domains/peis-home.eco");
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

/// Something scheduled in the scripted ecology.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
enum Due {
    /// Deliver an event to the executive.
    Deliver(EventOrd),
    /// A component finishes starting up: it is on.
    SwitchedOn(String, String),
    /// A component finishes its step: it reports `done`.
    Finish(String, String, u64),
}

/// `Event` with an order, for the schedule.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
enum EventOrd {
    Tuple(String, String, String, u64),
    Left(String),
}

#[derive(Debug, Default, Clone)]
struct Component {
    ty: String,
    cost: u64,
    on: bool,
    params: Option<String>,
    /// Never becomes running (a broken start-up).
    stuck: bool,
    /// Broken: reports error instead of running.
    broken: Option<String>,
    /// Bumped at each new params, to ignore finishes of older ones.
    generation: u64,
}

/// A scripted ecology: components start after a delay, run when they have
/// params, and those with a postcondition report `done` after `step_time`.
struct Ecology {
    components: BTreeMap<(String, String), Component>,
    seq: BTreeMap<(String, String), u64>,
    schedule: BinaryHeap<Reverse<(Duration, u64, Due)>>,
    order: u64,
    now: Duration,
    startup: Duration,
    step_time: Duration,
    gone: Vec<String>,
}

impl Ecology {
    fn from_facts(facts: &str) -> Ecology {
        let state = parse_facts(facts.as_bytes()).expect("facts");
        let mut components = BTreeMap::new();
        for f in state.with_predicate("pc") {
            let (p, ty, c) = (
                f.args[0].to_string(),
                f.args[1].to_string(),
                f.args[2].to_string(),
            );
            let cost = state.component_cost(&p, &c);
            components.insert(
                (p, c),
                Component {
                    ty,
                    cost: cost.map_or(10, |c| c.amount),
                    on: cost.is_some_and(|c| c.power == ecology_domain::Power::On),
                    ..Component::default()
                },
            );
        }
        Ecology {
            components,
            seq: BTreeMap::new(),
            schedule: BinaryHeap::new(),
            order: 0,
            now: Duration::ZERO,
            startup: secs(1.0),
            step_time: secs(5.0),
            gone: Vec::new(),
        }
    }

    fn at(&mut self, t: Duration, due: Due) {
        self.order += 1;
        self.schedule.push(Reverse((t, self.order, due)));
    }

    fn publish(&mut self, owner: &str, key: &str, value: &str, delay: Duration) {
        if self.gone.iter().any(|g| g == owner) {
            return;
        }
        let seq = self
            .seq
            .entry((owner.to_string(), key.to_string()))
            .or_insert(0);
        *seq += 1;
        let due = Due::Deliver(EventOrd::Tuple(
            owner.to_string(),
            key.to_string(),
            value.to_string(),
            *seq,
        ));
        self.at(self.now + delay, due);
    }

    /// Every init tuple, at time zero.
    fn boot(&mut self) {
        let all: Vec<((String, String), Component)> = self
            .components
            .iter()
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect();
        for ((p, c), comp) in all {
            self.publish(
                &p,
                &format!("components.{c}.type"),
                &comp.ty,
                Duration::ZERO,
            );
            self.publish(
                &p,
                &format!("components.{c}.cost"),
                &comp.cost.to_string(),
                Duration::ZERO,
            );
            let state = if comp.on { "on" } else { "off" };
            self.publish(
                &p,
                &format!("components.{c}.currState"),
                state,
                Duration::ZERO,
            );
            self.publish(&p, &format!("{c}.status"), "idle", Duration::ZERO);
        }
    }

    /// The PEIS side of a command.
    fn apply(&mut self, command: &Command, exec_timers: &mut Vec<(Duration, TimerId)>) {
        match command {
            Command::StartTimer { id, after } => exec_timers.push((self.now + *after, *id)),
            Command::CancelTimer(id) => exec_timers.retain(|(_, t)| t != id),
            Command::RemoteSet { owner, key, value } => {
                let (owner, key) = (&owner.to_string(), key.as_str());
                if self.gone.contains(owner) {
                    return;
                }
                if let Some(rest) = key.strip_prefix("components.") {
                    let c = rest.trim_end_matches(".reqState").to_string();
                    if value == "on" {
                        self.at(self.now + self.startup, Due::SwitchedOn(owner.clone(), c));
                    } else if let Some(comp) = self.components.get_mut(&(owner.clone(), c.clone()))
                    {
                        comp.on = false;
                        comp.params = None;
                        self.publish(
                            owner,
                            &format!("components.{c}.currState"),
                            "off",
                            Duration::ZERO,
                        );
                        self.publish(owner, &format!("{c}.status"), "idle", Duration::ZERO);
                    }
                } else if let Some(c) = key.strip_suffix(".params") {
                    let key = (owner.clone(), c.to_string());
                    if let Some(comp) = self.components.get_mut(&key) {
                        comp.params = Some(value.clone());
                        comp.generation += 1;
                    }
                    self.report(owner, c);
                }
                // `mi-` meta-tuples are accepted silently: inputs always flow here.
            }
        }
    }

    /// A component reports what it is doing now.
    fn report(&mut self, p: &str, c: &str) {
        let Some(comp) = self
            .components
            .get(&(p.to_string(), c.to_string()))
            .cloned()
        else {
            return;
        };
        if !comp.on || comp.stuck {
            return;
        }
        let Some(params) = comp.params else { return };
        if let Some(cause) = comp.broken {
            self.publish(p, &format!("{c}.cause"), &cause, Duration::ZERO);
            self.publish(p, &format!("{c}.status"), "error", Duration::ZERO);
            return;
        }
        self.publish(p, &format!("{c}.status"), "running", Duration::ZERO);
        let has_postcondition = ["(navigation ", "(gripper ", "(speaker "]
            .iter()
            .any(|n| params.starts_with(n));
        if has_postcondition {
            self.at(
                self.now + self.step_time,
                Due::Finish(p.to_string(), c.to_string(), comp.generation),
            );
        }
    }

    /// Runs the executive until it stops or `limit` passes; returns it.
    fn run(
        mut self,
        mut exec: Executive,
        limit: Duration,
        mut inject: impl FnMut(&mut Ecology, Duration),
    ) -> Executive {
        let mut timers: Vec<(Duration, TimerId)> = Vec::new();
        self.boot();
        let mut started = false;
        loop {
            let next_due = self.schedule.peek().map(|Reverse((t, _, _))| *t);
            let next_timer = timers.iter().map(|(t, _)| *t).min();
            let next = match (next_due, next_timer) {
                (Some(a), Some(b)) => a.min(b),
                (Some(a), None) | (None, Some(a)) => a,
                (None, None) => break,
            };
            if next > limit {
                break;
            }
            let before = self.now;
            self.now = next;
            inject(&mut self, before);
            let commands = if next_timer == Some(next) && next_due.is_none_or(|d| d > next) {
                let at = timers
                    .iter()
                    .position(|(t, _)| *t == next)
                    .expect("a timer");
                let (_, id) = timers.remove(at);
                exec.handle(next, Event::Timer(id))
            } else {
                let Some(Reverse((_, _, due))) = self.schedule.pop() else {
                    break;
                };
                match due {
                    Due::Deliver(EventOrd::Tuple(owner, key, value, seq)) => exec.handle(
                        next,
                        Event::Tuple {
                            owner: peis(&owner),
                            key: self::key(&key),
                            value,
                            epoch: 1,
                            seq,
                        },
                    ),
                    Due::Deliver(EventOrd::Left(p)) => exec.handle(next, Event::PeisLeft(peis(&p))),
                    Due::SwitchedOn(p, c) => {
                        if let Some(comp) = self.components.get_mut(&(p.clone(), c.clone())) {
                            comp.on = true;
                        }
                        self.publish(
                            &p,
                            &format!("components.{c}.currState"),
                            "on",
                            Duration::ZERO,
                        );
                        self.report(&p, &c);
                        Vec::new()
                    }
                    Due::Finish(p, c, generation) => {
                        let current = self
                            .components
                            .get(&(p.clone(), c.clone()))
                            .map(|x| x.generation);
                        if current == Some(generation) && !self.gone.contains(&p) {
                            self.publish(&p, &format!("{c}.status"), "done", Duration::ZERO);
                        }
                        Vec::new()
                    }
                }
            };
            for command in &commands {
                self.apply(command, &mut timers);
            }
            // Start once the init tuples of time zero are in.
            if !started
                && self
                    .schedule
                    .peek()
                    .is_none_or(|Reverse((t, _, _))| *t > Duration::ZERO)
            {
                started = true;
                let commands = exec.handle(self.now, Event::Start);
                for command in &commands {
                    self.apply(command, &mut timers);
                }
            }
            if matches!(exec.status(), RunStatus::Done | RunStatus::Failed { .. }) {
                break;
            }
        }
        exec
    }

    /// A component starts failing: it reports `error` with `cause`.
    fn break_component(&mut self, p: &str, c: &str, cause: &str) {
        if let Some(comp) = self.components.get_mut(&(p.to_string(), c.to_string())) {
            comp.broken = Some(cause.to_string());
        }
        self.report(p, c);
    }

    /// A PEIS vanishes: no more tuples from it, and presence says it left.
    fn vanish(&mut self, p: &str) {
        self.gone.push(p.to_string());
        self.at(self.now, Due::Deliver(EventOrd::Left(p.to_string())));
    }
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
#[test]
fn a_whole_plan_runs_to_completion() {
    let exec = Ecology::from_facts(PEIS_HOME_FACTS).run(executive(plan()), secs(600.0), |_, _| {});
    assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(&exec));
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
        } => Some((switched_off.clone(), stopped.clone())),
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

/// The paper's plan in the scripted ecology, the tracking system failing for
/// good at `at` seconds.
fn tracking_broken_at(at: f64) -> Executive {
    let mut broken = false;
    Ecology::from_facts(PEIS_HOME_FACTS).run(executive(plan()), secs(600.0), |eco, _| {
        if !broken && eco.now >= secs(at) {
            broken = true;
            eco.break_component("hsm", "tr1", "camera ca1 stopped producing images");
        }
    })
}

// The paper, Section VIII step 6: the tracking system fails while moving to the bedroom.
#[test]
fn a_failing_component_is_reconfigured_around() {
    // Fourteen seconds in, Astrid is on her way to the bedroom.
    let exec = tracking_broken_at(14.0);
    assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(&exec));
    assert_eq!(
        costs(&exec),
        [
            (80, false),
            (100, false),
            (80, false),
            (170, true),
            (20, false)
        ]
    );
    let failures: Vec<String> = exec
        .log()
        .iter()
        .filter_map(|e| match &e.event {
            LogEvent::Failure {
                peis,
                component,
                cause,
            } => Some(format!("{peis}:{component} {cause}")),
            _ => None,
        })
        .collect();
    assert_eq!(failures, ["hsm:tr1 camera ca1 stopped producing images"]);
    assert!(
        timeline(&exec).contains("switch on astrid:l1"),
        "{}",
        timeline(&exec)
    );
}

#[test]
fn a_vanishing_peis_is_reconfigured_around() {
    let mut gone = false;
    let exec =
        Ecology::from_facts(PEIS_HOME_FACTS).run(executive(plan()), secs(600.0), |eco, _| {
            if !gone && eco.now >= secs(14.0) {
                gone = true;
                eco.vanish("hsm");
            }
        });
    assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(&exec));
    assert_eq!(
        costs(&exec),
        [
            (80, false),
            (100, false),
            (80, false),
            (170, true),
            (20, false)
        ]
    );
    let text = timeline(&exec);
    assert!(
        text.contains("FAILURE hsm:ca1: PEIS hsm left the ecology"),
        "{text}"
    );
    assert!(
        text.contains("FAILURE hsm:tr1: PEIS hsm left the ecology"),
        "{text}"
    );
}

#[test]
fn no_configuration_fails_the_action_with_the_explanation() {
    // Without a laser and without Pippi, losing the tracking system leaves nothing.
    let facts: String = PEIS_HOME_FACTS
        .lines()
        .filter(|l| !l.contains("pippi") && !l.contains(" l1"))
        .collect::<Vec<_>>()
        .join("\n");
    let mut broken = false;
    let mut exec = Ecology::from_facts(&facts).run(executive(plan()), secs(600.0), |eco, _| {
        if !broken && eco.now >= secs(2.0) {
            broken = true;
            eco.break_component("hsm", "tr1", "camera failure");
        }
    });
    let RunStatus::Failed { index, reason } = exec.status().clone() else {
        panic!("the action should fail: {}", timeline(&exec));
    };
    assert_eq!(index, 0);
    assert!(reason.contains("input (position astrid)"), "{reason}");
    assert!(reason.contains("component hsm:tr1 is excluded"), "{reason}");
    assert_eq!(names(&exec).last(), Some(&"action_failed"));
    let _ = exec.abandon(secs(3.0));
    assert_eq!(names(&exec).last(), Some(&"task_failed"));
}

#[test]
fn a_component_that_never_runs_times_out_and_is_replaced() {
    let mut eco = Ecology::from_facts(PEIS_HOME_FACTS);
    if let Some(tr1) = eco
        .components
        .get_mut(&("hsm".to_string(), "tr1".to_string()))
    {
        tr1.stuck = true;
    }
    let exec = eco.run(executive(plan()[..1].to_vec()), secs(600.0), |_, _| {});
    assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(&exec));
    assert_eq!(costs(&exec), [(80, false), (170, true)]);
    let text = timeline(&exec);
    assert!(
        text.contains("FAILURE hsm:tr1: did not report running within 10s"),
        "{text}"
    );
}

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
    exec.handle(Duration::ZERO, Event::Start);
    for (p, c) in [
        ("astrid", "tc1"),
        ("astrid", "s1"),
        ("hsm", "ca1"),
        ("hsm", "tr1"),
    ] {
        exec.handle(secs(1.0), tuple(p, &format!("{c}.status"), "running", 2));
    }
    exec
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

#[test]
fn waiting_too_long_is_a_failure() {
    let mut exec = running_first_action();
    exec.handle(
        secs(2.0),
        tuple("astrid", "s1.cause", "(global-pos astrid)", 1),
    );
    let commands = exec.handle(secs(2.0), tuple("astrid", "s1.status", "waiting", 3));
    let Some(Command::StartTimer { id, after }) = commands.first().cloned() else {
        panic!("a grace timer: {commands:?}");
    };
    assert_eq!(after, ExecConfig::default().waiting_grace);
    exec.handle(secs(4.0), Event::Timer(id));
    let text = timeline(&exec);
    assert!(
        text.contains("FAILURE astrid:s1: waiting for longer than 2s: (global-pos astrid)"),
        "{text}"
    );
}

#[test]
fn a_component_in_error_stays_out_of_later_actions() {
    // On the way to the entrance, the tracking system fails for good.
    let exec = tracking_broken_at(2.0);
    assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(&exec));
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
        text.contains("unavailable: hsm:tr1 reports error (camera ca1 stopped producing images)"),
        "{text}"
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

#[test]
fn a_component_waiting_across_a_redeploy_is_still_timed() {
    let mut exec = running_first_action();
    exec.handle(secs(2.0), tuple("hsm", "tr1.status", "error", 3));
    // While the new configuration deploys, navigation loses its position.
    exec.handle(secs(2.1), tuple("astrid", "tc1.status", "waiting", 3));
    exec.handle(secs(2.2), tuple("astrid", "l1.status", "running", 2));
    exec.handle(secs(2.3), tuple("astrid", "od1.status", "running", 3));
    let commands = exec.handle(secs(2.4), tuple("astrid", "s1.status", "running", 3));
    assert_eq!(names(&exec).last(), Some(&"running"), "{}", timeline(&exec));
    let grace = ExecConfig::default().waiting_grace;
    let Some(id) = commands.iter().find_map(|c| match c {
        Command::StartTimer { id, after } if *after == grace => Some(*id),
        _ => None,
    }) else {
        panic!("no grace timer for the waiting navigation: {commands:?}");
    };
    exec.handle(secs(4.4), Event::Timer(id));
    let text = timeline(&exec);
    assert!(
        text.contains("FAILURE astrid:tc1: waiting for longer than 2s"),
        "{text}"
    );
}

#[test]
fn an_action_whose_configuration_has_no_postcondition_is_done_once_it_runs() {
    let localize = PlannedAction::new(
        "(localize astrid)".to_string(),
        Some(parse_goal("(get-position astrid)").expect("goal")),
    );
    let exec =
        Ecology::from_facts(PEIS_HOME_FACTS).run(executive(vec![localize]), secs(600.0), |_, _| {});
    assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(&exec));
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

#[test]
fn a_failed_remote_set_fails_its_component() {
    let mut exec = running_first_action();
    exec.handle(
        secs(2.0),
        Event::RemoteSetFailed {
            owner: peis("hsm"),
            key: key("tr1.params"),
            reason: "remote set of tr1.params is not allowed by hsm".to_string(),
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
        },
    );
    assert_eq!(costs(&exec), [(80, false), (150, true)]);
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

/// End to end on the in-process tuple space, in virtual time: PEIS hosts run
/// test components that honour the component contract, and the driver runs
/// the executive over the space.
mod on_the_tuple_space {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::time::Duration;

    use ecology_domain::{EcologyState, parse_domain, parse_facts};
    use ecology_peis::{Component, ComponentError, ComponentSpec, Context, run_host};
    use ecology_tuples::{
        Clock, InProcessPeis, InProcessSpace, Key, PeisId, PeisOptions, PresenceSubscription,
        Subscription, Tuple, TupleError, TuplePattern, TupleSpace, Value, VirtualClock,
    };

    use super::{PEIS_HOME, PEIS_HOME_FACTS, costs, names, plan, timeline};
    use crate::{DriverConfig, ExecConfig, Executive, RunStatus, drive};

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

    /// A component that follows the contract: `waiting` while an input is
    /// missing or stale, `running` while it works, `done` when its step ends;
    /// `broken` makes it fail with a cause.
    fn body(broken: Arc<AtomicBool>) -> Arc<dyn Component<InProcessPeis>> {
        Arc::new(move |ctx: Context<InProcessPeis>| {
            let broken = broken.clone();
            async move {
                let name = ctx
                    .params()
                    .trim_start_matches('(')
                    .split_whitespace()
                    .next()
                    .unwrap_or("")
                    .to_string();
                let (ins, outs, finish) = behaviour(&name);
                let mut inputs = ctx.inputs(ins).await?;
                let mut shown = String::new();
                let mut worked = Duration::ZERO;
                loop {
                    if broken.load(Ordering::Relaxed) {
                        return Err(ComponentError::Fault(
                            "camera ca1 stopped producing images".into(),
                        ));
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

    #[derive(Clone, Copy, PartialEq)]
    enum Fault {
        None,
        /// The tracking system reports an error at this time.
        BreakTracking(Duration),
        /// The home security monitor vanishes (crashes) at this time.
        VanishMonitor(Duration),
    }

    async fn run(fault: Fault) -> Executive {
        run_with(fault, None, plan()).await.0
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
        async fn delete(&self, key: Key) -> Result<bool, TupleError> {
            self.inner.delete(key).await
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
    }

    /// Runs `plan`; with `slow`, every remote set to that PEIS takes that long.
    /// Also returns hsm's `tr1.params` as it was first set, and when
    /// the driver started (log times count from it).
    async fn run_with(
        fault: Fault,
        slow: Option<(&str, Duration)>,
        plan: Vec<crate::PlannedAction>,
    ) -> (Executive, Option<Tuple>, ecology_tuples::Timestamp) {
        let clock = VirtualClock::default();
        let shared: Arc<dyn Clock> = Arc::new(clock.clone());
        let space = InProcessSpace::new(shared.clone());
        let facts = parse_facts(PEIS_HOME_FACTS.as_bytes()).expect("facts");
        let tracking_broken = Arc::new(AtomicBool::new(false));
        let healthy = Arc::new(AtomicBool::new(false));
        let mut hosts = Vec::new();
        let mut stops = Vec::new();
        let mut monitor = None;
        for peis in ["astrid", "hsm", "pippi"] {
            let handle = space
                .join(PeisId::new(peis).expect("name"), PeisOptions::default())
                .expect("joins");
            if peis == "hsm" {
                monitor = Some(handle.clone());
            }
            let mut specs = Vec::new();
            for f in facts.with_predicate("pc").filter(|f| &*f.args[0] == peis) {
                let c = f.args[2].to_string();
                let cost = facts.component_cost(peis, &c).expect("a cost");
                let broken = if (peis, c.as_str()) == ("hsm", "tr1") {
                    tracking_broken.clone()
                } else {
                    healthy.clone()
                };
                specs.push(ComponentSpec {
                    name: c,
                    kind: f.args[1].to_string(),
                    cost: cost.amount,
                    on: cost.power == ecology_domain::Power::On,
                    startup: Duration::from_millis(500),
                    body: body(broken),
                });
            }
            let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
            stops.push(stop);
            hosts.push(tokio::spawn(run_host(
                handle,
                shared.clone(),
                specs,
                async {
                    let _ = stopped.await;
                },
            )));
        }
        let me = space
            .join(
                PeisId::new("executive").expect("name"),
                PeisOptions::default(),
            )
            .expect("joins");
        // Virtual time moves only when every task has had its turn.
        let ticking = Arc::new(AtomicBool::new(true));
        let ticker = {
            let ticking = ticking.clone();
            let clock = clock.clone();
            let broken = tracking_broken.clone();
            let start = shared.now();
            let mut monitor = monitor;
            tokio::spawn(async move {
                while ticking.load(Ordering::Relaxed) {
                    for _ in 0..50 {
                        tokio::task::yield_now().await;
                    }
                    clock.advance(Duration::from_millis(20));
                    let now = clock_now(&clock).saturating_duration_since(start);
                    match fault {
                        Fault::BreakTracking(at) if now >= at => {
                            broken.store(true, Ordering::Relaxed)
                        }
                        Fault::VanishMonitor(at) if now >= at => {
                            if let Some(hsm) = monitor.take() {
                                hsm.vanish();
                            }
                        }
                        _ => {}
                    }
                }
            })
        };
        let domain = parse_domain(PEIS_HOME.as_bytes()).expect("domain");
        let mut exec = Executive::new(domain, EcologyState::new(), plan, ExecConfig::default());
        let config = DriverConfig {
            limit: Some(Duration::from_secs(300)),
            ..DriverConfig::default()
        };
        let mut probe = me
            .subscribe(TuplePattern::parse("hsm:tr1.params").expect("pattern"))
            .await
            .expect("subscribe");
        let started = shared.now();
        match slow {
            Some((peis, delay)) => {
                let space = SlowTo {
                    inner: me.clone(),
                    slow: PeisId::new(peis).expect("name"),
                    delay,
                    clock: shared.clone(),
                };
                drive(&space, shared.clone(), &mut exec, config).await
            }
            None => drive(&me, shared.clone(), &mut exec, config).await,
        }
        .expect("drives");
        let mut wired = None;
        while let Some(event) = probe.try_next() {
            if let ecology_tuples::TupleEvent::Changed(t) = event {
                wired.get_or_insert(t);
            }
        }
        ticking.store(false, Ordering::Relaxed);
        let _ = ticker.await;
        for stop in stops {
            let _ = stop.send(());
        }
        for (i, host) in hosts.into_iter().enumerate() {
            let result = host.await.expect("host task");
            // A vanished PEIS's host finds the space closed to it; the others stop cleanly.
            let vanished = i == 1 && matches!(fault, Fault::VanishMonitor(_));
            assert!(vanished || result.is_ok(), "host {i}: {result:?}");
        }
        space.shutdown().await;
        (exec, wired, started)
    }

    fn clock_now(clock: &VirtualClock) -> ecology_tuples::Timestamp {
        clock.now()
    }

    // Remote sets to one PEIS do not wait for those to another: a PEIS that
    // takes 2 s to answer each remote set delays only its own components.
    #[tokio::test]
    async fn remote_sets_to_different_peis_run_concurrently() {
        let slow = Duration::from_secs(2);
        let (exec, wired, started) =
            run_with(Fault::None, Some(("astrid", slow)), plan()[..1].to_vec()).await;
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

    // The paper's Section VIII on the real middleware (in-process), no failure.
    #[tokio::test]
    async fn a_plan_runs_on_the_tuple_space() {
        let exec = run(Fault::None).await;
        assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(&exec));
        assert_eq!(
            costs(&exec),
            [(80, false), (100, false), (80, false), (20, false)]
        );
        assert_eq!(names(&exec).last(), Some(&"task_done"));
    }

    // The paper's Section VIII step 6: the tracking system fails on the way to the bedroom.
    #[tokio::test]
    async fn a_failure_on_the_tuple_space_is_reconfigured() {
        let exec = run(Fault::BreakTracking(Duration::from_secs(6))).await;
        assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(&exec));
        let text = timeline(&exec);
        assert!(
            text.contains("FAILURE hsm:tr1: camera ca1 stopped producing images"),
            "{text}"
        );
        assert!(costs(&exec).contains(&(170, true)), "{text}");
    }

    // A PEIS that crashes (no goodbye) is reported as left after its lease (2 s).
    #[tokio::test]
    async fn a_vanishing_peis_on_the_tuple_space_is_reconfigured() {
        let exec = run(Fault::VanishMonitor(Duration::from_secs(6))).await;
        assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(&exec));
        let text = timeline(&exec);
        assert!(text.contains("PEIS hsm left the ecology"), "{text}");
        assert!(costs(&exec).contains(&(170, true)), "{text}");
    }
}

#[test]
fn a_planning_budget_that_runs_out_fails_the_action_with_that_reason() {
    let domain = parse_domain(PEIS_HOME.as_bytes()).expect("domain");
    let config = ExecConfig {
        planning: ecology_config::Budget {
            max_expansions: Some(0),
            max_time: None,
        },
        ..ExecConfig::default()
    };
    let exec = Ecology::from_facts(PEIS_HOME_FACTS).run(
        Executive::new(domain, EcologyState::new(), plan(), config),
        secs(600.0),
        |_, _| {},
    );
    let RunStatus::Failed { reason, .. } = exec.status().clone() else {
        panic!("the action should fail: {}", timeline(&exec));
    };
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
#[test]
fn the_planning_budget_counts_from_each_planning() {
    let exec = Ecology::from_facts(PEIS_HOME_FACTS).run(
        executive(plan()).with_stopwatch(Box::new(AnHourIn)),
        secs(600.0),
        |_, _| {},
    );
    assert_eq!(exec.status(), &RunStatus::Done, "{}", timeline(&exec));
}
