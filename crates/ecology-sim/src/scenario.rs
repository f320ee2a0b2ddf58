//! Scenario files (TOML): the PEIS and their components, the map, the task
//! (or several, each with its own executive), and fault injections. TOML and serde stay here, at the edge: the file is
//! read into private serde types, checked, and turned into a [`Scenario`]
//! of plain simulator types. Every error names the file, line and column.

use std::collections::{BTreeMap, BTreeSet};
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::Duration;

use ecology_domain::{Domain, Problem, parse_domain, parse_goal, parse_problem_for};
use ecology_exec::{Plan, PlannedAction};
use serde::Deserialize;
use toml::Spanned;

use crate::components::KINDS;
use crate::planning::{PlanError, plan_actions};
use crate::world::{Door, Map, Pose, Resident, Robot, Room, Thing, World};
use ecology_core::Rng;

/// Why a scenario could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    /// The scenario file is malformed or inconsistent at a place in it.
    #[error("{file}:{line}:{col}: {message}")]
    Invalid {
        /// The scenario file.
        file: String,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        col: usize,
        /// What is wrong.
        message: String,
    },
    /// A file could not be read.
    #[error("cannot read {path}: {message}")]
    Read {
        /// The file.
        path: String,
        /// The reason.
        message: String,
    },
    /// The domain or problem the scenario names has errors (rendered with
    /// their own `file:line:col`).
    #[error("{0}")]
    Task(String),
    /// The action planner found no plan for the task.
    #[error("no plan for the scenario's task: {0}")]
    NoPlan(String),
}

/// What happens to a component or a PEIS.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultKind {
    /// The component reports `error` with the fault's cause.
    Fail,
    /// The component falls silent (keeps running, publishes nothing): a dead camera.
    Stall,
    /// The component writes its outputs in a form nobody can read: a producer with a bug.
    Garble,
    /// The component's fault is cleared.
    Recover,
    /// The PEIS crashes: it stops without leaving, with all its components.
    Kill,
    /// A killed PEIS starts again, with its components as at the start.
    Revive,
    /// The component's latest status tuple is delivered once more (a
    /// duplicate, as a network may make).
    Duplicate,
    /// The component's status tuple before its latest is delivered again,
    /// after the latest (a late, out-of-order delivery).
    Late,
}

/// When a fault happens.
#[derive(Debug, Clone, PartialEq)]
pub enum Trigger {
    /// At this simulated time since the start.
    At(Duration),
    /// `delay` after the executive logs `event` (such as `action_started`),
    /// for action `action` (1-based) when given.
    After {
        /// Whose event: the PEIS name of a task's executive; `None` for the
        /// first task's.
        executive: Option<String>,
        /// The executive's event name (JSON-lines name).
        event: String,
        /// Which action's event, 1-based; any when `None`.
        action: Option<usize>,
        /// How long after.
        delay: Duration,
    },
}

impl Trigger {
    /// When executive event `event` (its JSON-lines name) of action `index`
    /// (0-based, the action running when it was logged) fires this trigger:
    /// how long after it the fault is due. `None` for `At` triggers and for
    /// events that do not fire it.
    pub fn fired_by(&self, event: &str, index: Option<usize>) -> Option<Duration> {
        match self {
            Trigger::After {
                event: wanted,
                action,
                delay,
                ..
            } if wanted == event && action.is_none_or(|a| index == Some(a - 1)) => Some(*delay),
            _ => None,
        }
    }
}

/// One fault injection.
#[derive(Debug, Clone, PartialEq)]
pub struct FaultSpec {
    /// What happens.
    pub kind: FaultKind,
    /// To which PEIS.
    pub peis: String,
    /// To which component (for fail, stall and recover).
    pub component: Option<String>,
    /// When.
    pub trigger: Trigger,
    /// The cause a failing component reports.
    pub cause: String,
}

/// One component of a PEIS in a scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct ComponentDef {
    /// Its name, such as `l1`.
    pub id: String,
    /// Its type, such as `laser` (one of [`KINDS`]).
    pub kind: String,
    /// Running cost when on, start-up cost when off.
    pub cost: u64,
    /// Whether it is on at the start.
    pub on: bool,
    /// How long it takes to switch on.
    pub startup: Duration,
    /// The ROS 2 lifecycle node it is, if it is one (`ros2` in the file), its topics resolved;
    /// else it is simulated.
    pub ros2: Option<ecology_ros2::NodeSpec>,
    /// The rooms it sees (`covers`), published as `components.C.covers`; empty when it does not
    /// say. A simulated ceiling camera (`cams`) that says sees only these rooms.
    pub covers: Vec<String>,
}

/// One PEIS of a scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct PeisDef {
    /// Its name.
    pub name: String,
    /// Its components.
    pub components: Vec<ComponentDef>,
}

/// A place where a thing may lie at the start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Place {
    /// Where, in metres.
    pub at: (f64, f64),
    /// How probable.
    pub probability: f64,
}

/// One task of a scenario, run by its own executive.
#[derive(Debug, Clone)]
pub struct ScenarioTask {
    /// The PEIS name its executive joins the ecology as (`executive` for a `[task]`).
    pub executive: String,
    /// When its executive joins, in simulated time since the start.
    pub start: Duration,
    /// The domain the executive configures with.
    pub domain: Domain,
    /// The domain file, as the scenario names it (relative to the scenario file's folder).
    pub domain_file: PathBuf,
    /// The problem the plan was made for (when the task gives one, not a
    /// plan), and its file as the scenario names it: for replanning.
    pub problem: Option<(Problem, PathBuf)>,
    /// The plan to execute (conditional when the problem is uncertain).
    pub plan: Plan,
}

/// The executive's PEIS name for a scenario's single `[task]`.
pub const EXECUTIVE: &str = "executive";

/// A loaded, checked scenario.
#[derive(Debug, Clone)]
pub struct Scenario {
    /// Its name.
    pub name: String,
    /// What it shows.
    pub description: String,
    /// The seed used when the run gives none.
    pub seed: u64,
    /// Simulated time after which a run is stopped.
    pub time_limit: Duration,
    /// How long one action may take before it fails.
    pub action_timeout: Duration,
    /// The tasks, each with its executive (never empty; one for a `[task]`).
    pub tasks: Vec<ScenarioTask>,
    /// The world at the start (a thing with uncertain `places` lies at its first).
    pub world: World,
    /// Things whose place at the start is uncertain: where each may lie, and
    /// how probably; a run draws one by its seed ([`Scenario::world_for`]).
    pub places: BTreeMap<String, Vec<Place>>,
    /// The PEIS and their components.
    pub peis: Vec<PeisDef>,
    /// The fault injections.
    pub faults: Vec<FaultSpec>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    name: String,
    #[serde(default)]
    description: String,
    #[serde(default)]
    seed: u64,
    #[serde(default = "default_time_limit")]
    time_limit: f64,
    #[serde(default = "default_action_timeout")]
    action_timeout: f64,
    task: Option<Spanned<TaskFile>>,
    tasks: Option<Vec<Spanned<TaskFile>>>,
    map: MapFile,
    #[serde(default, rename = "robot")]
    robots: Vec<Spanned<RobotFile>>,
    #[serde(default, rename = "thing")]
    things: Vec<Spanned<PlacedFile>>,
    #[serde(default, rename = "resident")]
    residents: Vec<Spanned<ResidentFile>>,
    #[serde(default, rename = "peis")]
    peis: Vec<PeisFile>,
    #[serde(default, rename = "fault")]
    faults: Vec<Spanned<FaultFile>>,
}

fn default_time_limit() -> f64 {
    300.0
}

fn default_action_timeout() -> f64 {
    120.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TaskFile {
    /// Only in `[[tasks]]`: the PEIS name of the task's executive.
    executive: Option<Spanned<String>>,
    /// Only in `[[tasks]]`: seconds of simulated time before the executive joins.
    start: Option<f64>,
    domain: Spanned<String>,
    problem: Option<Spanned<String>>,
    plan: Option<Vec<Spanned<StepFile>>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct StepFile {
    action: String,
    configure: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MapFile {
    rooms: Vec<Spanned<RoomFile>>,
    #[serde(default)]
    doors: Vec<Spanned<DoorFile>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RoomFile {
    name: String,
    x: [f64; 2],
    y: [f64; 2],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct DoorFile {
    between: [String; 2],
    at: [f64; 2],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RobotFile {
    name: String,
    at: [f64; 3],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PlacedFile {
    name: String,
    at: Option<[f64; 2]>,
    places: Option<Vec<PlaceFile>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PlaceFile {
    at: [f64; 2],
    probability: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ResidentFile {
    name: String,
    at: [f64; 2],
    #[serde(default = "yes")]
    asleep: bool,
}

fn yes() -> bool {
    true
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PeisFile {
    name: Spanned<String>,
    #[serde(default)]
    components: Vec<Spanned<ComponentFile>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ComponentFile {
    id: String,
    #[serde(rename = "type")]
    kind: String,
    cost: u64,
    #[serde(default)]
    on: bool,
    #[serde(default)]
    startup: f64,
    #[serde(default)]
    covers: Vec<String>,
    ros2: Option<Ros2File>,
}

/// `ros2 = { node = "/hsm/tr1", … }` of a component: the ROS 2 lifecycle node it is.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Ros2File {
    node: String,
    #[serde(default)]
    arguments: BTreeMap<String, usize>,
    #[serde(default)]
    inputs: Vec<PortFile>,
    #[serde(default)]
    outputs: Vec<PortFile>,
    #[serde(default)]
    feeds: Vec<FeedFile>,
    status_topic: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PortFile {
    info: String,
    topic: String,
    #[serde(rename = "type")]
    message: String,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FeedFile {
    tuple: String,
    topic: String,
    #[serde(rename = "type")]
    message: String,
}

impl Ros2File {
    /// The node's spec, checked and its topics resolved.
    fn spec(&self) -> Result<ecology_ros2::NodeSpec, String> {
        let port = |p: &PortFile| ecology_ros2::Port {
            info: p.info.clone(),
            topic: p.topic.clone(),
            message: p.message.clone(),
        };
        ecology_ros2::NodeSpec {
            node: self.node.clone(),
            arguments: self
                .arguments
                .iter()
                .map(|(k, v)| (k.clone(), *v))
                .collect(),
            inputs: self.inputs.iter().map(port).collect(),
            outputs: self.outputs.iter().map(port).collect(),
            feeds: self
                .feeds
                .iter()
                .map(|f| ecology_ros2::Feed {
                    tuple: f.tuple.clone(),
                    topic: f.topic.clone(),
                    message: f.message.clone(),
                })
                .collect(),
            status_topic: self.status_topic.clone(),
        }
        .resolved()
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FaultFile {
    what: String,
    peis: String,
    component: Option<String>,
    at: Option<f64>,
    after: Option<AfterFile>,
    #[serde(default)]
    delay: f64,
    cause: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct AfterFile {
    event: String,
    action: Option<usize>,
    /// Whose event (a task's executive); the first task's when absent.
    executive: Option<String>,
}

/// The executive's event names a fault may follow.
const EVENTS: &[&str] = &[
    "plan",
    "action_started",
    "state_acquired",
    "configuration",
    "deployed",
    "running",
    "failure",
    "reconfiguration",
    "action_done",
    "action_failed",
];

/// 1-based line and column of byte `offset` in `text`.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text.as_bytes()[..offset.min(text.len())];
    let line = before.iter().filter(|b| **b == b'\n').count() + 1;
    let start = before
        .iter()
        .rposition(|b| *b == b'\n')
        .map_or(0, |p| p + 1);
    let col = String::from_utf8_lossy(&before[start..]).chars().count() + 1;
    (line, col)
}

struct Checker<'a> {
    file: &'a str,
    text: &'a str,
}

impl Checker<'_> {
    /// `Ok` when `name` can name a `what` (a room, robot, thing or resident).
    fn name(&self, name: &str, what: &str, span: Range<usize>) -> Result<(), ScenarioError> {
        if is_name(name) {
            Ok(())
        } else {
            Err(self.at(
                span,
                format!("`{name}` cannot name a {what}: use letters, digits, `-` and `_`"),
            ))
        }
    }

    fn at(&self, span: Range<usize>, message: impl Into<String>) -> ScenarioError {
        let (line, col) = line_col(self.text, span.start);
        ScenarioError::Invalid {
            file: self.file.to_string(),
            line,
            col,
            message: message.into(),
        }
    }
}

/// The longest time a scenario may name: about 31 years.
const MAX_SECONDS: f64 = 1e9;

fn seconds(s: f64) -> Option<Duration> {
    (s.is_finite() && (0.0..=MAX_SECONDS).contains(&s))
        .then(|| Duration::try_from_secs_f64(s).ok())
        .flatten()
}

/// Whether `name` can name a room, robot, thing or resident: it becomes part
/// of tuple keys (`robots.NAME.pose`) and of planning facts.
fn is_name(name: &str) -> bool {
    ecology_tuples::Key::new(name).is_ok() && !name.contains('.')
}

/// The largest scenario or PEIS file read.
const MAX_FILE_BYTES: u64 = 8 * 1024 * 1024;

impl Scenario {
    /// Loads the scenario file at `path`; the task's domain and problem are
    /// read relative to the scenario file's folder.
    pub fn load(path: &Path) -> Result<Scenario, ScenarioError> {
        let base = path.parent().unwrap_or(Path::new("")).to_path_buf();
        let read = |p: &Path| -> Result<Vec<u8>, String> {
            std::fs::read(base.join(p)).map_err(|e| e.to_string())
        };
        let text = read_text(path)?;
        Scenario::parse(&text, &path.display().to_string(), &read)
    }

    /// Parses scenario `text` (named `file` in errors); `read` gives the
    /// bytes of the files it names (domain, problem), by their path as written.
    pub fn parse(
        text: &str,
        file: &str,
        read: &dyn Fn(&Path) -> Result<Vec<u8>, String>,
    ) -> Result<Scenario, ScenarioError> {
        let check = Checker { file, text };
        let parsed: File = toml::from_str(text).map_err(|e| {
            let span = e.span().unwrap_or(0..0);
            check.at(span, e.message().trim().to_string())
        })?;
        let read_named = |p: &Spanned<String>| -> Result<Vec<u8>, ScenarioError> {
            read(&PathBuf::from(p.get_ref()))
                .map_err(|e| check.at(p.span(), format!("cannot read {}: {e}", p.get_ref())))
        };

        let time_limit = seconds(parsed.time_limit)
            .ok_or_else(|| check.at(0..0, "time_limit must be a positive number of seconds"))?;
        let action_timeout = seconds(parsed.action_timeout)
            .ok_or_else(|| check.at(0..0, "action_timeout must be a positive number of seconds"))?;
        let map = parse_map(&check, &parsed.map)?;
        let (world, places) = parse_world(&check, &parsed, map)?;
        let peis = check_peis(&check, &parsed.peis)?;
        check_covers(&check, &parsed)?;
        let tasks = parse_tasks(&check, &parsed, &peis, time_limit, &read_named)?;
        let faults = parse_faults(&check, &parsed.faults, &peis, &tasks)?;
        Ok(Scenario {
            name: parsed.name,
            description: parsed.description,
            seed: parsed.seed,
            time_limit,
            action_timeout,
            tasks,
            world,
            places,
            peis,
            faults,
        })
    }
}

/// The tasks: one `[task]` (its executive named `executive`, starting at
/// once), or `[[tasks]]` tables, each naming its executive: a PEIS name of
/// its own, neither the world's nor one of the scenario's PEIS.
fn parse_tasks(
    check: &Checker<'_>,
    parsed: &File,
    peis: &[PeisDef],
    time_limit: Duration,
    read_named: &ReadNamed<'_>,
) -> Result<Vec<ScenarioTask>, ScenarioError> {
    let tables: Vec<(&Spanned<TaskFile>, bool)> = match (&parsed.task, &parsed.tasks) {
        (Some(task), None) => vec![(task, false)],
        (None, Some(tasks)) if !tasks.is_empty() => tasks.iter().map(|t| (t, true)).collect(),
        (None, Some(_)) => {
            return Err(check.at(
                0..0,
                "`tasks` is empty: give each task a [[tasks]] table with its `executive`",
            ));
        }
        (None, None) => {
            return Err(check.at(
                0..0,
                "no task: give one [task] table, or a [[tasks]] table per executive",
            ));
        }
        (Some(_), Some(tasks)) => {
            let span = tasks.first().map_or(0..0, Spanned::span);
            return Err(check.at(
                span,
                "both [task] and [[tasks]]: give one [task], or every task as [[tasks]]",
            ));
        }
    };
    let mut tasks: Vec<ScenarioTask> = Vec::new();
    for (table, named) in tables {
        let task = table.get_ref();
        let here = |message: String| check.at(table.span(), message);
        let executive = match (&task.executive, named) {
            (Some(name), true) => {
                let at = |message: String| check.at(name.span(), message);
                let name = name.get_ref();
                if ecology_tuples::PeisId::new(name).is_err()
                    || name == ecology_tuples::world::WORLD
                {
                    return Err(at(format!("`{name}` cannot name an executive")));
                }
                if peis.iter().any(|p| &p.name == name) {
                    return Err(at(format!(
                        "executive {name} has the name of a PEIS of the scenario"
                    )));
                }
                if tasks.iter().any(|t| &t.executive == name) {
                    return Err(at(format!("executive {name} is named by two tasks")));
                }
                name.clone()
            }
            (None, true) => {
                return Err(here(
                    "a [[tasks]] table needs `executive`, the PEIS name its executive joins as"
                        .to_string(),
                ));
            }
            (Some(name), false) => {
                return Err(check.at(
                    name.span(),
                    "[task] runs one executive named `executive`: use [[tasks]] tables to name executives",
                ));
            }
            (None, false) => EXECUTIVE.to_string(),
        };
        let start = match (task.start, named) {
            (None, _) => Duration::ZERO,
            (Some(_), false) => {
                return Err(here(
                    "[task] starts at once: use [[tasks]] tables to give start times".to_string(),
                ));
            }
            (Some(s), true) => match seconds(s) {
                Some(start) if start < time_limit => start,
                _ => {
                    return Err(here(format!(
                        "start of {executive} must be seconds before the time_limit ({} s)",
                        time_limit.as_secs_f64()
                    )));
                }
            },
        };
        let (domain, plan, problem) = parse_task(check, task, named, read_named)?;
        tasks.push(ScenarioTask {
            executive,
            start,
            domain,
            domain_file: PathBuf::from(task.domain.get_ref()),
            problem,
            plan,
        });
    }
    Ok(tasks)
}

/// What a task table gives: the domain, the plan, and the problem planned for (if any).
type ParsedTask = (Domain, Plan, Option<(Problem, PathBuf)>);

/// One task: a domain, and a problem to plan for or a plan (`named`: a
/// `[[tasks]]` table, not the `[task]`).
fn parse_task(
    check: &Checker<'_>,
    task: &TaskFile,
    named: bool,
    read_named: &ReadNamed<'_>,
) -> Result<ParsedTask, ScenarioError> {
    let domain_bytes = read_named(&task.domain)?;
    let domain = parse_domain(&domain_bytes)
        .map_err(|d| ScenarioError::Task(d.render(task.domain.get_ref(), &domain_bytes)))?;
    let mut planned_problem = None;
    let plan = match (&task.problem, &task.plan) {
        (Some(problem), None) => {
            let (plan, parsed_problem) = plan_for(&domain, problem, read_named)?;
            planned_problem = Some((parsed_problem, PathBuf::from(problem.get_ref())));
            plan
        }
        (None, Some(steps)) => {
            let mut plan = Vec::new();
            for step in steps {
                let goal = match &step.get_ref().configure {
                    None => None,
                    Some(text) => Some(parse_goal(text).map_err(|d| {
                        check.at(
                            step.span(),
                            format!("configure goal: {}", d.render("<goal>", text.as_bytes())),
                        )
                    })?),
                };
                plan.push(PlannedAction::new(step.get_ref().action.clone(), goal));
            }
            Plan::from(plan)
        }
        _ => {
            let table = if named { "[[tasks]]" } else { "[task]" };
            return Err(check.at(
                task.domain.span(),
                format!("{table} needs exactly one of `problem` (to plan for) or `plan`"),
            ));
        }
    };
    Ok((domain, plan, planned_problem))
}

/// The map: rooms with an area and unique names, doors between known rooms.
fn parse_map(check: &Checker<'_>, file: &MapFile) -> Result<Map, ScenarioError> {
    let mut map = Map::default();
    for room in &file.rooms {
        let r = room.get_ref();
        if r.x[1] <= r.x[0] || r.y[1] <= r.y[0] || !r.x.iter().chain(&r.y).all(|v| v.is_finite()) {
            return Err(check.at(room.span(), format!("room {} has no area", r.name)));
        }
        check.name(&r.name, "room", room.span())?;
        if map.room(&r.name).is_some() {
            return Err(check.at(room.span(), format!("room {} is defined twice", r.name)));
        }
        map.rooms.push(Room {
            name: r.name.clone(),
            x0: r.x[0],
            y0: r.y[0],
            x1: r.x[1],
            y1: r.y[1],
        });
    }
    for door in &file.doors {
        let d = door.get_ref();
        for name in &d.between {
            if map.room(name).is_none() {
                return Err(check.at(door.span(), format!("door to unknown room {name}")));
            }
        }
        map.doors.push(Door {
            a: d.between[0].clone(),
            b: d.between[1].clone(),
            x: d.at[0],
            y: d.at[1],
        });
    }
    Ok(map)
}

/// The world on `map`: robots, things and residents, each inside a room.
fn parse_world(
    check: &Checker<'_>,
    parsed: &File,
    map: Map,
) -> Result<(World, BTreeMap<String, Vec<Place>>), ScenarioError> {
    let inside = |x: f64, y: f64, span: Range<usize>, what: &str| {
        if map.room_at(x, y).is_some() {
            Ok(())
        } else {
            Err(check.at(span, format!("{what} at ({x}, {y}) is in no room")))
        }
    };
    let mut world = World {
        map: map.clone(),
        robots: Default::default(),
        things: Default::default(),
        residents: Default::default(),
    };
    for robot in &parsed.robots {
        let r = robot.get_ref();
        check.name(&r.name, "robot", robot.span())?;
        inside(r.at[0], r.at[1], robot.span(), &r.name)?;
        world.robots.insert(
            r.name.clone(),
            Robot {
                name: r.name.clone(),
                pose: Pose::new(r.at[0], r.at[1], r.at[2]),
                command: (0.0, 0.0),
                command_age: 0.0,
            },
        );
    }
    let mut uncertain = BTreeMap::new();
    for thing in &parsed.things {
        let t = thing.get_ref();
        check.name(&t.name, "thing", thing.span())?;
        let at = match (&t.at, &t.places) {
            (Some(at), None) => (at[0], at[1]),
            (None, Some(places)) => {
                let places = parse_places(check, places, thing.span(), &t.name, &map)?;
                let first = places[0].at;
                uncertain.insert(t.name.clone(), places);
                first
            }
            _ => {
                return Err(check.at(
                    thing.span(),
                    format!(
                        "thing {} needs exactly one of `at` or `places` (where it may lie, with probabilities)",
                        t.name
                    ),
                ));
            }
        };
        inside(at.0, at.1, thing.span(), &t.name)?;
        world.things.insert(
            t.name.clone(),
            Thing {
                name: t.name.clone(),
                at,
                holder: None,
            },
        );
    }
    for resident in &parsed.residents {
        let r = resident.get_ref();
        check.name(&r.name, "resident", resident.span())?;
        inside(r.at[0], r.at[1], resident.span(), &r.name)?;
        world.residents.insert(
            r.name.clone(),
            Resident {
                name: r.name.clone(),
                at: (r.at[0], r.at[1]),
                awake: !r.asleep,
            },
        );
    }
    Ok((world, uncertain))
}

/// A thing's uncertain places: each in a room, probabilities in (0, 1] summing to 1.
fn parse_places(
    check: &Checker<'_>,
    places: &[PlaceFile],
    span: Range<usize>,
    name: &str,
    map: &Map,
) -> Result<Vec<Place>, ScenarioError> {
    if places.is_empty() {
        return Err(check.at(span, format!("thing {name} has no places")));
    }
    let mut out = Vec::new();
    for place in places {
        let [x, y] = place.at;
        if map.room_at(x, y).is_none() {
            return Err(check.at(
                span,
                format!("a place of {name} at ({x}, {y}) is in no room"),
            ));
        }
        if !(place.probability > 0.0 && place.probability <= 1.0) {
            return Err(check.at(
                span,
                format!(
                    "a place of {name} has probability {}: it must be in (0, 1]",
                    place.probability
                ),
            ));
        }
        out.push(Place {
            at: (place.at[0], place.at[1]),
            probability: place.probability,
        });
    }
    let total: f64 = out.iter().map(|p| p.probability).sum();
    if (total - 1.0).abs() > 1e-6 {
        return Err(check.at(
            span,
            format!("the places of {name} have probabilities summing to {total}, not 1"),
        ));
    }
    Ok(out)
}

impl Scenario {
    /// The world at the start of a run with `seed`: each thing with
    /// uncertain places lies at one drawn by its probability (the same seed
    /// draws the same places).
    pub fn world_for(&self, seed: u64) -> World {
        let mut world = self.world.clone();
        for (name, places) in &self.places {
            let mut rng = Rng::derive(seed, &format!("places:{name}"));
            let mut draw = rng.uniform();
            let mut chosen = places[places.len() - 1].at;
            for place in places {
                if draw < place.probability {
                    chosen = place.at;
                    break;
                }
                draw -= place.probability;
            }
            if let Some(thing) = world.things.get_mut(name) {
                thing.at = chosen;
            }
        }
        world
    }
}

/// The faults: known kinds on known PEIS and components, each triggered at
/// a time or after a known event of an action of a task's plan.
fn parse_faults(
    check: &Checker<'_>,
    files: &[Spanned<FaultFile>],
    peis: &[PeisDef],
    tasks: &[ScenarioTask],
) -> Result<Vec<FaultSpec>, ScenarioError> {
    let mut faults = Vec::new();
    for fault in files {
        let f = fault.get_ref();
        let here = |message: String| check.at(fault.span(), message);
        let kind = match f.what.as_str() {
            "fail" => FaultKind::Fail,
            "stall" => FaultKind::Stall,
            "garble" => FaultKind::Garble,
            "recover" => FaultKind::Recover,
            "duplicate" => FaultKind::Duplicate,
            "late" => FaultKind::Late,
            "kill" => FaultKind::Kill,
            "revive" => FaultKind::Revive,
            other => {
                return Err(here(format!(
                    "unknown fault `{other}` (known: fail, stall, garble, recover, kill, revive, duplicate, late)"
                )));
            }
        };
        let Some(target) = peis.iter().find(|p| p.name == f.peis) else {
            return Err(here(format!("fault on unknown PEIS {}", f.peis)));
        };
        let needs_component = matches!(
            kind,
            FaultKind::Fail
                | FaultKind::Stall
                | FaultKind::Garble
                | FaultKind::Recover
                | FaultKind::Duplicate
                | FaultKind::Late
        );
        match (&f.component, needs_component) {
            (Some(c), true) if !target.components.iter().any(|d| &d.id == c) => {
                return Err(here(format!("{} has no component {c}", f.peis)));
            }
            (None, true) => return Err(here(format!("`{}` needs a component", f.what))),
            (Some(_), false) => {
                return Err(here(format!(
                    "`{}` acts on a whole PEIS: drop `component`",
                    f.what
                )));
            }
            _ => {}
        }
        let trigger = fault_trigger(f, tasks).map_err(here)?;
        faults.push(FaultSpec {
            kind,
            peis: f.peis.clone(),
            component: f.component.clone(),
            trigger,
            cause: f
                .cause
                .clone()
                .unwrap_or_else(|| "injected failure".to_string()),
        });
    }
    Ok(faults)
}

/// When fault `f` fires: at a time, or after an event of a task's executive
/// (the first task's unless it names another), plus its delay.
fn fault_trigger(f: &FaultFile, tasks: &[ScenarioTask]) -> Result<Trigger, String> {
    let delay = seconds(f.delay).ok_or_else(|| "delay must be seconds".to_string())?;
    match (f.at, &f.after) {
        (Some(at), None) => Ok(Trigger::At(
            seconds(at).ok_or_else(|| "`at` must be seconds".to_string())? + delay,
        )),
        (None, Some(after)) => {
            if !EVENTS.contains(&after.event.as_str()) {
                return Err(format!(
                    "unknown event `{}` (known: {})",
                    after.event,
                    EVENTS.join(", ")
                ));
            }
            let task = match &after.executive {
                None => tasks.first(),
                Some(name) => tasks.iter().find(|t| &t.executive == name),
            };
            let Some(task) = task else {
                let names: Vec<&str> = tasks.iter().map(|t| t.executive.as_str()).collect();
                return Err(format!(
                    "no task's executive is named {} (executives: {})",
                    after.executive.as_deref().unwrap_or_default(),
                    names.join(", ")
                ));
            };
            let actions = task.plan.depth();
            if after.action.is_some_and(|a| a == 0 || a > actions) {
                let whose = if tasks.len() > 1 {
                    format!(" of {}", task.executive)
                } else {
                    String::new()
                };
                return Err(format!("the plan{whose} has actions 1 to {actions}"));
            }
            Ok(Trigger::After {
                executive: after.executive.clone(),
                event: after.event.clone(),
                action: after.action,
                delay,
            })
        }
        _ => Err("a fault needs exactly one of `at` or `after`".to_string()),
    }
}

/// Checks the `[[peis]]` tables of a file.
fn check_peis(check: &Checker<'_>, files: &[PeisFile]) -> Result<Vec<PeisDef>, ScenarioError> {
    let mut peis = Vec::new();
    let mut names = BTreeSet::new();
    for p in files {
        let name = p.name.get_ref();
        if ecology_tuples::PeisId::new(name).is_err() || name == ecology_tuples::world::WORLD {
            return Err(check.at(p.name.span(), format!("`{name}` cannot name a PEIS")));
        }
        if !names.insert(name.clone()) {
            return Err(check.at(p.name.span(), format!("PEIS {name} is defined twice")));
        }
        let mut components: Vec<ComponentDef> = Vec::new();
        for c in &p.components {
            let def = c.get_ref();
            let ros2 = def
                .ros2
                .as_ref()
                .map(|r| {
                    r.spec()
                        .map_err(|e| check.at(c.span(), format!("component {}: {e}", def.id)))
                })
                .transpose()?;
            if ros2.is_none() && !KINDS.contains(&def.kind.as_str()) {
                return Err(check.at(
                    c.span(),
                    format!(
                        "no simulated component of type `{}` (known: {}; any type may be a ROS 2 node, with `ros2`)",
                        def.kind,
                        KINDS.join(", ")
                    ),
                ));
            }
            if ecology_tuples::Key::new(&format!("components.{}.type", def.id)).is_err() {
                return Err(check.at(c.span(), format!("`{}` cannot name a component", def.id)));
            }
            if components.iter().any(|other| other.id == def.id) {
                return Err(check.at(
                    c.span(),
                    format!("component {} is defined twice on {name}", def.id),
                ));
            }
            let startup = seconds(def.startup)
                .ok_or_else(|| check.at(c.span(), "startup must be a number of seconds"))?;
            let mut covers: Vec<String> = Vec::new();
            for place in &def.covers {
                if !is_name(place) {
                    return Err(check.at(
                        c.span(),
                        format!(
                            "component {}: `{place}` cannot name a room it covers",
                            def.id
                        ),
                    ));
                }
                if covers.contains(place) {
                    return Err(check.at(
                        c.span(),
                        format!("component {} covers {place} twice", def.id),
                    ));
                }
                covers.push(place.clone());
            }
            components.push(ComponentDef {
                id: def.id.clone(),
                kind: def.kind.clone(),
                cost: def.cost,
                on: def.on,
                startup,
                ros2,
                covers,
            });
        }
        peis.push(PeisDef {
            name: name.clone(),
            components,
        });
    }
    Ok(peis)
}

/// Every room a component covers is one of the map's.
fn check_covers(check: &Checker<'_>, parsed: &File) -> Result<(), ScenarioError> {
    let rooms: BTreeSet<&str> = parsed
        .map
        .rooms
        .iter()
        .map(|r| r.get_ref().name.as_str())
        .collect();
    for p in &parsed.peis {
        for c in &p.components {
            let def = c.get_ref();
            if let Some(place) = def.covers.iter().find(|r| !rooms.contains(r.as_str())) {
                return Err(check.at(
                    c.span(),
                    format!(
                        "component {}:{} covers {place}, which is no room of the map",
                        p.name.get_ref(),
                        def.id
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// A file read only for its `[[peis]]` tables (a scenario file, or a file of PEIS alone).
#[derive(Debug, Deserialize)]
struct PeisOnlyFile {
    #[serde(default, rename = "peis")]
    peis: Vec<PeisFile>,
}

impl PeisDef {
    /// The PEIS of the `[[peis]]` tables in `text` (named `file` in errors):
    /// a whole scenario file, or a file of nothing but `[[peis]]` tables.
    pub fn parse_all(text: &str, file: &str) -> Result<Vec<PeisDef>, ScenarioError> {
        let check = Checker { file, text };
        let parsed: PeisOnlyFile = toml::from_str(text).map_err(|e| {
            let span = e.span().unwrap_or(0..0);
            check.at(span, e.message().trim().to_string())
        })?;
        let peis = check_peis(&check, &parsed.peis)?;
        if peis.is_empty() {
            return Err(check.at(0..0, "no PEIS here: describe each in a [[peis]] table"));
        }
        Ok(peis)
    }

    /// [`PeisDef::parse_all`] of the file at `path`.
    pub fn load_all(path: &Path) -> Result<Vec<PeisDef>, ScenarioError> {
        let text = read_text(path)?;
        PeisDef::parse_all(&text, &path.display().to_string())
    }
}

/// The text of the file at `path`: at most 8 MiB of UTF-8.
fn read_text(path: &Path) -> Result<String, ScenarioError> {
    use std::io::Read;
    let fail = |message: String| ScenarioError::Read {
        path: path.display().to_string(),
        message,
    };
    let file = std::fs::File::open(path).map_err(|e| fail(e.to_string()))?;
    let mut bytes = Vec::new();
    file.take(MAX_FILE_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| fail(e.to_string()))?;
    if bytes.len() as u64 > MAX_FILE_BYTES {
        return Err(fail(format!(
            "larger than the limit of {MAX_FILE_BYTES} bytes (8 MiB)"
        )));
    }
    String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let (line, col) = line_col(&String::from_utf8_lossy(e.as_bytes()), at);
        ScenarioError::Invalid {
            file: path.display().to_string(),
            line,
            col,
            message: "invalid UTF-8".to_string(),
        }
    })
}

/// Reads a file the scenario names, with the name's place for errors.
type ReadNamed<'a> = dyn Fn(&Spanned<String>) -> Result<Vec<u8>, ScenarioError> + 'a;

/// Plans for the problem file with the action planner; each action's
/// `:configure` goal becomes its configuration goal.
fn plan_for(
    domain: &Domain,
    problem: &Spanned<String>,
    read: &ReadNamed<'_>,
) -> Result<(Plan, Problem), ScenarioError> {
    let bytes = read(problem)?;
    let parsed = parse_problem_for(domain, &bytes)
        .map_err(|d| ScenarioError::Task(d.render(problem.get_ref(), &bytes)))?;
    let plan = plan_actions(domain, &parsed).map_err(|e| match e {
        PlanError::Task(message) => {
            ScenarioError::Task(format!("{}: {message}", problem.get_ref()))
        }
        PlanError::NoPlan(why) => ScenarioError::NoPlan(why),
    })?;
    Ok((plan, parsed))
}
