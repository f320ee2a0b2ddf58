//! Simulated PEIS-components, one for every component type of the
//! PEIS-Home (DESIGN section 8), following the component contract of
//! DESIGN section 6.
//!
//! Sensors read ground truth from the `world` PEIS through the tuple space
//! (its `robots.NAME.pose`, `map`, `things.…` and `residents.…` tuples, read
//! through [`ecology_tuples::world`]) and add seeded noise; processors read
//! their inputs through `mi-` meta-tuples; actuators act on the world by
//! publishing outputs the world subscribes to (`C.out.velocity`,
//! `C.out.grasp`, `C.out.sound`). Each reports its own
//! status: `waiting` naming what is missing, `running`, `done`, or `error`
//! with a cause. Injected faults make a component fail (`error`) or stall
//! (stay `running` but fall silent, as a dead camera does).
//!
//! An output goes out only while someone reads it (`Context::output`, which
//! keeps the last value back and publishes it the moment a reader comes while
//! a body waits on `Body::next` or `Body::pause`); the cameras do not even
//! write out an image nobody reads (`Context::output_with`). Status flows
//! whether or not anyone reads.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use ecology_peis::{BoxFuture, Component, ComponentError, Context, Inputs};
use ecology_tuples::contract::{quoted, unreadable_cause};
use ecology_tuples::world::{AWAKE, Command, Point, WORLD, WorldKey, world_pattern};
use ecology_tuples::{Clock, Subscription, Timestamp, TupleEvent, TupleSpace, Value};

use crate::world::{self, MAX_SPEED, MAX_TURN, Map, Pose, Room, ray, wrap_angle};
use ecology_core::Rng;

/// The component types the simulator provides (the `pc` facts' types).
pub const KINDS: &[&str] = &[
    "cams", "tr-sys", "cam", "obj-loc", "laser", "odomet", "self-loc", "tc", "gripp", "speak",
    "player",
];

/// How often sensors sample, and how long processors wait for an input
/// before checking staleness.
const PERIOD: Duration = Duration::from_millis(50);
/// An input older than this is stale.
const STALE: Duration = Duration::from_millis(500);
/// A tracking system whose images stopped for this long reports `error`.
const IMAGES_LOST: Duration = Duration::from_secs(1);
/// A sensor that reads the world's ground truth reports `error` when
/// nothing new came from the world for this long (the world publishes every
/// robot's pose at every step, 20 times a second): the world left or froze.
/// Components that read only the map from it (navigation, scan matching)
/// do not judge its silence: the map does not change, and what they steer
/// by comes through their inputs, whose staleness they judge.
pub const WORLD_SILENT: Duration = Duration::from_secs(1);

/// An injected fault of one component.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct FaultState {
    /// The component fails with this cause (reports `error`).
    pub failed: Option<String>,
    /// The component falls silent: it keeps its status but publishes nothing.
    pub stalled: bool,
    /// The component writes its outputs in a form nobody can read (commas
    /// and semicolons for spaces): a producer with a bug.
    pub garbled: bool,
}

/// The injected faults of every component, shared by the fault schedule and
/// the component bodies.
#[derive(Debug, Clone, Default)]
pub struct Faults(Arc<Mutex<BTreeMap<(String, String), FaultState>>>);

impl Faults {
    /// The fault state of `peis:component`.
    pub fn get(&self, peis: &str, component: &str) -> FaultState {
        let map = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        map.get(&(peis.to_string(), component.to_string()))
            .cloned()
            .unwrap_or_default()
    }

    /// Changes the fault state of `peis:component`.
    pub fn update(&self, peis: &str, component: &str, change: impl FnOnce(&mut FaultState)) {
        let mut map = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        change(
            map.entry((peis.to_string(), component.to_string()))
                .or_default(),
        );
    }
}

/// A simulated component of one type.
#[derive(Debug, Clone)]
pub struct Simulated {
    kind: String,
    faults: Faults,
    seed: u64,
    /// The rooms a ceiling camera sees; empty: every room.
    covers: Arc<[String]>,
}

impl Simulated {
    /// The simulated component of type `kind` (one of [`KINDS`]), or `None`
    /// for a type the simulator does not know.
    pub fn new(kind: &str, faults: Faults, seed: u64) -> Option<Simulated> {
        KINDS.contains(&kind).then(|| Simulated {
            kind: kind.to_string(),
            faults,
            seed,
            covers: Arc::from([]),
        })
    }

    /// The same component, seeing only the rooms `covers` names when it is a ceiling camera
    /// (`cams`); with none, it sees every room.
    pub fn covering(mut self, covers: &[String]) -> Simulated {
        self.covers = Arc::from(covers);
        self
    }
}

/// What a camera sees.
enum Sight {
    /// Every room of the map: ceiling cameras that do not say what they cover.
    Everywhere,
    /// These rooms: ceiling cameras mounted over them.
    Rooms(Arc<[String]>),
    /// Within this many metres in its own room, itself aside: a robot's camera.
    Range(f64),
}

impl<S: TupleSpace> Component<S> for Simulated {
    fn run(&self, ctx: Context<S>) -> BoxFuture<Result<(), ComponentError>> {
        let sim = self.clone();
        Box::pin(async move {
            let functionality = ctx.functionality().to_string();
            let name = format!(
                "{}:{}:{}",
                ctx.peis(),
                ctx.component(),
                ctx.clock().now().as_nanos()
            );
            let rng = Rng::derive(sim.seed, &name);
            let mut body = Body {
                ctx,
                faults: sim.faults.clone(),
                rng,
                shown: None,
            };
            match (sim.kind.as_str(), functionality.as_str()) {
                ("cams", _) if sim.covers.is_empty() => body.cameras(Sight::Everywhere).await,
                ("cams", _) => body.cameras(Sight::Rooms(sim.covers.clone())).await,
                ("cam", _) => body.cameras(Sight::Range(3.5)).await,
                ("tr-sys", _) => body.tracker(true).await,
                ("obj-loc", _) => body.localizer().await,
                ("laser", _) => body.laser().await,
                ("odomet", _) => body.odometry().await,
                ("self-loc", "scan-matching") => body.scan_matching().await,
                ("self-loc", "pose-tracking") => body.pose_tracking().await,
                ("tc", "navigation") => body.navigation().await,
                ("gripp", _) => body.gripper().await,
                ("speak", _) => body.speaker().await,
                ("player", _) => body.idle().await,
                (kind, f) => Err(ComponentError::Fault(format!(
                    "a {kind} component cannot run {f}"
                ))),
            }
        })
    }
}

/// The world's ground truth as one component sees it, through the tuple space.
struct Truth {
    subscription: Subscription,
    latest: BTreeMap<String, String>,
    /// The map, read once each time it changes (not at every look: a building's map is long).
    map: Option<Arc<Map>>,
    /// The robots' poses and the things' places, read once each time they change (a camera
    /// looks at every robot of a building 20 times a second), by their key: in `latest`'s order.
    robots: BTreeMap<String, (Arc<str>, Pose)>,
    things: BTreeMap<String, (Arc<str>, (f64, f64))>,
    clock: Arc<dyn Clock>,
    /// When the last tuple of the world arrived.
    heard: Option<Timestamp>,
}

impl Truth {
    async fn follow<S: TupleSpace>(ctx: &Context<S>) -> Result<Truth, ComponentError> {
        Ok(Truth {
            subscription: ctx.space().subscribe(world_pattern()).await?,
            latest: BTreeMap::new(),
            map: None,
            robots: BTreeMap::new(),
            things: BTreeMap::new(),
            clock: ctx.clock().clone(),
            heard: None,
        })
    }

    /// Takes in what the world published; an error once the world, heard
    /// before, has said nothing for [`WORLD_SILENT`].
    fn poll(&mut self) -> Result<(), ComponentError> {
        let now = self.take_in();
        match self.heard {
            Some(heard) if now.saturating_duration_since(heard) > WORLD_SILENT => {
                Err(fault(format!(
                    "no ground truth from the {WORLD} PEIS for {} s: the world left or froze",
                    WORLD_SILENT.as_secs_f64()
                )))
            }
            _ => Ok(()),
        }
    }

    /// Takes in what the world published, judging nothing; returns the time.
    fn take_in(&mut self) -> Timestamp {
        let now = self.clock.now();
        while let Some(event) = self.subscription.try_next() {
            self.heard = Some(now);
            match event {
                TupleEvent::Changed(t) => {
                    if let Ok(text) = t.text() {
                        let key = t.key.as_str();
                        match WorldKey::parse(key) {
                            Some(WorldKey::Map) => self.map = Map::parse_shared(text).ok(),
                            Some(WorldKey::RobotPose(name)) => match Pose::parse(text) {
                                Ok(pose) => {
                                    self.robots.insert(key.to_string(), (name.into(), pose));
                                }
                                Err(_) => {
                                    self.robots.remove(key);
                                }
                            },
                            Some(WorldKey::ThingAt(name)) => match Point::parse(text) {
                                Ok(at) => {
                                    let place = (name.into(), (at.x, at.y));
                                    self.things.insert(key.to_string(), place);
                                }
                                Err(_) => {
                                    self.things.remove(key);
                                }
                            },
                            _ => {}
                        }
                        self.latest.insert(key.to_string(), text.to_string());
                    }
                }
                TupleEvent::Removed { key, .. } => {
                    if WorldKey::parse(key.as_str()) == Some(WorldKey::Map) {
                        self.map = None;
                    }
                    self.robots.remove(key.as_str());
                    self.things.remove(key.as_str());
                    self.latest.remove(key.as_str());
                }
                TupleEvent::Retargeted { .. } => {}
            }
        }
        now
    }

    fn text(&self, key: &str) -> Option<&str> {
        self.latest.get(key).map(String::as_str)
    }

    fn robot(&self, name: &str) -> Option<Pose> {
        let key = WorldKey::RobotPose(name).to_string();
        self.robots.get(&key).map(|(_, pose)| *pose)
    }

    fn robots(&self) -> Vec<(Arc<str>, Pose)> {
        self.robots.values().cloned().collect()
    }

    fn map(&self) -> Option<Arc<Map>> {
        self.map.clone()
    }

    fn things(&self) -> impl Iterator<Item = &(Arc<str>, (f64, f64))> {
        self.things.values()
    }

    /// Whether `name` is a thing of the world (not a robot).
    fn is_thing(&self, name: &str) -> bool {
        self.latest
            .contains_key(&WorldKey::ThingHolder(name).to_string())
    }
}

struct Body<S: TupleSpace> {
    ctx: Context<S>,
    faults: Faults,
    rng: Rng,
    shown: Option<(String, String)>,
}

fn fault(text: impl Into<String>) -> ComponentError {
    ComponentError::Fault(text.into())
}

impl<S: TupleSpace> Body<S> {
    /// Applies injected faults: `Err` when failed, `Ok(true)` when stalled.
    fn injected(&self) -> Result<bool, ComponentError> {
        let state = self
            .faults
            .get(self.ctx.peis().as_str(), self.ctx.component());
        match state.failed {
            Some(cause) => Err(fault(cause)),
            None => Ok(state.stalled),
        }
    }

    /// Reports a status and cause, only when they change.
    async fn report(&mut self, status: &str, cause: &str) -> Result<(), ComponentError> {
        let now = (status.to_string(), cause.to_string());
        if self.shown.as_ref() != Some(&now) {
            let cause = (!cause.is_empty()).then_some(cause);
            self.ctx.status(status, cause).await?;
            self.shown = Some(now);
        }
        Ok(())
    }

    async fn output(&self, info: &str, text: String) -> Result<(), ComponentError> {
        self.output_with(info, move || text).await
    }

    /// Publishes output `info` as `make` makes it, made only if it goes out
    /// (`Context::output_with`); garbled if a fault says so.
    async fn output_with(
        &self,
        info: &str,
        make: impl FnOnce() -> String + Send + 'static,
    ) -> Result<(), ComponentError> {
        let garbled = self
            .faults
            .get(self.ctx.peis().as_str(), self.ctx.component())
            .garbled;
        self.ctx
            .output_with(info, move || {
                let text = make();
                Value::text(if garbled { garble(&text) } else { text })
            })
            .await?;
        Ok(())
    }

    /// The latest value of input `info` read by `parse`: `Ok(None)` when it
    /// is missing or older than [`STALE`], and `Err` with the contract's
    /// `unreadable INFO: …` cause when it is there but cannot be read, so the
    /// executive blames its producer, not this component.
    fn read<T>(
        &self,
        inputs: &Inputs,
        info: &str,
        expected: &str,
        parse: impl Fn(&str) -> Option<T>,
    ) -> Result<Option<T>, String> {
        if inputs.missing(STALE).iter().any(|m| m == info) {
            return Ok(None);
        }
        let Some(tuple) = inputs.latest(info) else {
            return Ok(None);
        };
        let text = tuple.text().unwrap_or("");
        parse(text).map(Some).ok_or_else(|| {
            unreadable_cause(
                info,
                &format!("expected {expected}, found {}", quoted(text, 40)),
            )
        })
    }

    /// Waits for the next input update, or one period; an output kept back because nobody
    /// read it is published meanwhile as soon as a reader comes.
    async fn next(&self, inputs: &mut Inputs) -> Result<(), ComponentError> {
        let deadline = self.ctx.clock().now().saturating_add(PERIOD);
        loop {
            tokio::select! {
                biased;
                open = inputs.changed() => {
                    if !open {
                        self.ctx.clock().sleep_until(deadline).await;
                    }
                    return Ok(());
                }
                () = self.ctx.clock().sleep_until(deadline) => return Ok(()),
                came = self.ctx.readers_came() => came?,
            }
        }
    }

    /// Waits one period; an output kept back because nobody read it is published meanwhile as
    /// soon as a reader comes.
    async fn pause(&self) -> Result<(), ComponentError> {
        let deadline = self.ctx.clock().now().saturating_add(PERIOD);
        loop {
            tokio::select! {
                biased;
                () = self.ctx.clock().sleep_until(deadline) => return Ok(()),
                came = self.ctx.readers_came() => came?,
            }
        }
    }

    fn arg(&self, i: usize) -> Result<String, ComponentError> {
        self.ctx
            .args()
            .get(i)
            .map(|s| s.to_string())
            .ok_or_else(|| {
                fault(format!(
                    "params {} lack argument {}",
                    self.ctx.params(),
                    i + 1
                ))
            })
    }

    /// Ceiling cameras (they see the rooms they cover, or the whole home) or a robot's camera
    /// (sees robots and things within range in the same room): `image` holds what it sees, as
    /// `NAME X Y THETA; …` (a thing's heading is 0).
    async fn cameras(&mut self, sight: Sight) -> Result<(), ComponentError> {
        let mut truth = Truth::follow(&self.ctx).await?;
        let me = self.ctx.peis().to_string();
        loop {
            let stalled = self.injected()?;
            truth.poll()?;
            let mut robots = truth.robots();
            robots.extend(
                truth
                    .things()
                    .map(|(name, (x, y))| (name.clone(), Pose::new(*x, *y, 0.0))),
            );
            if robots.is_empty() {
                self.report("waiting", "ground truth").await?;
            } else {
                self.report("running", "").await?;
                if !stalled {
                    // What the image shows, its noise drawn whether or not anyone reads it (so
                    // that a seeded run does not change with who watches it); the image is
                    // written out only if someone reads it, now or before the next one.
                    let map = truth.map().unwrap_or_default();
                    let viewpoint = truth.robot(&me);
                    let covered: Vec<&Room> = match &sight {
                        Sight::Rooms(names) => map
                            .rooms
                            .iter()
                            .filter(|r| names.contains(&r.name))
                            .collect(),
                        Sight::Everywhere | Sight::Range(_) => Vec::new(),
                    };
                    let mut seen = Vec::new();
                    for (name, pose) in robots {
                        let visible = match (&sight, viewpoint) {
                            (Sight::Everywhere, _) | (Sight::Range(_), None) => true,
                            (Sight::Rooms(_), _) => {
                                covered.iter().any(|r| r.contains(pose.x, pose.y))
                            }
                            (Sight::Range(range), Some(eye)) => {
                                let same_room = map.room_at(eye.x, eye.y).map(|r| &r.name)
                                    == map.room_at(pose.x, pose.y).map(|r| &r.name);
                                *name != *me
                                    && same_room
                                    && eye.distance_to(pose.x, pose.y) <= *range
                            }
                        };
                        if !visible {
                            continue;
                        }
                        let noisy = Pose::new(
                            pose.x + self.rng.gaussian(0.02),
                            pose.y + self.rng.gaussian(0.02),
                            wrap_angle(pose.theta + self.rng.gaussian(0.01)),
                        );
                        seen.push((name, noisy));
                    }
                    self.output_with("image", move || image_text(&seen)).await?;
                }
            }
            self.pause().await?;
        }
    }

    /// The tracking system (`strict`: images that stop are an error) or an
    /// object localizer: finds robot `?o` in the images, outputs `global-pos`.
    async fn tracker(&mut self, strict: bool) -> Result<(), ComponentError> {
        let target = self.arg(2)?;
        let mut inputs = self.ctx.inputs(&["image"]).await?;
        let mut ever = false;
        loop {
            let stalled = self.injected()?;
            inputs.poll();
            ever |= inputs.latest("image").is_some();
            if strict && ever && !inputs.missing(IMAGES_LOST).is_empty() {
                return Err(fault(format!(
                    "no images from the cameras for {} s: a camera stopped producing images",
                    IMAGES_LOST.as_secs_f64()
                )));
            }
            let seen = |image: &str| pose_in_image(image, &target);
            match self.read(&inputs, "image", IMAGE_FORMAT, seen) {
                Err(cause) => self.report("waiting", &cause).await?,
                Ok(None) => self.report("waiting", "image").await?,
                Ok(Some(seen)) => match seen {
                    None => {
                        self.report("waiting", &format!("{target} not in view"))
                            .await?
                    }
                    Some(pose) => {
                        self.report("running", "").await?;
                        if !stalled {
                            self.output("global-pos", pose.to_string()).await?;
                        }
                    }
                },
            }
            self.next(&mut inputs).await?;
        }
    }

    /// An object localizer: tracks a robot (`global-pos`, as [`Body::tracker`])
    /// or, when its params name a thing, looks for the thing.
    async fn localizer(&mut self) -> Result<(), ComponentError> {
        let target = self.arg(2)?;
        let mut truth = Truth::follow(&self.ctx).await?;
        loop {
            self.injected()?;
            truth.poll()?;
            if truth.map().is_some() {
                break;
            }
            self.report("waiting", "ground truth").await?;
            self.ctx.sleep(PERIOD).await;
        }
        if truth.is_thing(&target) {
            self.look_for(&target, truth).await
        } else {
            self.tracker(false).await
        }
    }

    /// A sensing component: looks for `thing` in the images and writes what
    /// it saw as `C.observed`, in the PEIS-Home domain's words: `(thing-at
    /// THING ROOM)` for the room it is seen in, and `(not (thing-at THING
    /// ROOM))` for the room of this PEIS when it is not seen there.
    async fn look_for(&mut self, thing: &str, mut truth: Truth) -> Result<(), ComponentError> {
        let mut inputs = self.ctx.inputs(&["image"]).await?;
        let me = self.ctx.peis().to_string();
        loop {
            let stalled = self.injected()?;
            inputs.poll();
            truth.poll()?;
            let image = match self.read(&inputs, "image", IMAGE_FORMAT, parse_image) {
                Ok(Some(image)) => image,
                Ok(None) => {
                    self.report("waiting", "image").await?;
                    self.next(&mut inputs).await?;
                    continue;
                }
                Err(cause) => {
                    self.report("waiting", &cause).await?;
                    self.next(&mut inputs).await?;
                    continue;
                }
            };
            self.report("running", "").await?;
            let map = truth.map().unwrap_or_default();
            let seen_in = seen_in_image(&image, thing)
                .and_then(|pose| map.room_at(pose.x, pose.y))
                .map(|room| room.name.clone());
            let here = truth
                .robot(&me)
                .and_then(|eye| map.room_at(eye.x, eye.y))
                .map(|room| room.name.clone());
            let mut literals = Vec::new();
            if let Some(room) = &seen_in {
                literals.push(format!("(thing-at {thing} {room})"));
            }
            if let Some(room) = here.filter(|room| seen_in.as_ref() != Some(room)) {
                literals.push(format!("(not (thing-at {thing} {room}))"));
            }
            if !stalled && !literals.is_empty() {
                self.ctx.observed(&literals.join(" ")).await?;
            }
            self.next(&mut inputs).await?;
        }
    }

    /// The laser: 8 ranges, every 45°, from the robot's true pose, with noise.
    async fn laser(&mut self) -> Result<(), ComponentError> {
        let mut truth = Truth::follow(&self.ctx).await?;
        let me = self.ctx.peis().to_string();
        loop {
            let stalled = self.injected()?;
            truth.poll()?;
            match (truth.robot(&me), truth.map()) {
                (Some(pose), Some(map)) => {
                    self.report("running", "").await?;
                    if !stalled {
                        let scan: Vec<String> = scan(&map, pose)
                            .into_iter()
                            .map(|r| format!("{:.3}", r + self.rng.gaussian(0.01)))
                            .collect();
                        self.output("range-scan", scan.join(" ")).await?;
                    }
                }
                _ => self.report("waiting", "ground truth").await?,
            }
            self.pause().await?;
        }
    }

    /// Odometry: integrates the wheels' motion with a seeded scale error and
    /// heading drift, so that it wanders off the truth as the robot moves.
    async fn odometry(&mut self) -> Result<(), ComponentError> {
        let mut truth = Truth::follow(&self.ctx).await?;
        let me = self.ctx.peis().to_string();
        let scale = 1.0 + 0.03 + self.rng.gaussian(0.01);
        let drift = 0.02 + self.rng.gaussian(0.005);
        let mut last: Option<Pose> = None;
        let mut estimate: Option<Pose> = None;
        loop {
            let stalled = self.injected()?;
            truth.poll()?;
            let Some(now) = truth.robot(&me) else {
                self.report("waiting", "ground truth").await?;
                self.ctx.sleep(PERIOD).await;
                continue;
            };
            let mut est = estimate.unwrap_or(now);
            if let Some(before) = last {
                let forward = (now.x - before.x) * before.theta.cos()
                    + (now.y - before.y) * before.theta.sin();
                let turn = wrap_angle(now.theta - before.theta);
                let d = forward * scale + self.rng.gaussian(0.0005);
                let dth = turn + drift * forward.abs() + self.rng.gaussian(0.0005);
                let mid = est.theta + dth / 2.0;
                est = Pose::new(
                    est.x + d * mid.cos(),
                    est.y + d * mid.sin(),
                    wrap_angle(est.theta + dth),
                );
            }
            last = Some(now);
            estimate = Some(est);
            self.report("running", "").await?;
            if !stalled {
                self.output("odometry", est.to_string()).await?;
            }
            self.pause().await?;
        }
    }

    /// Self-localization by scan matching: odometry corrected by matching
    /// the laser's ranges against the map around the odometry's guess.
    async fn scan_matching(&mut self) -> Result<(), ComponentError> {
        let mut inputs = self.ctx.inputs(&["range-scan", "odometry"]).await?;
        let mut truth = Truth::follow(&self.ctx).await?;
        let mut correction = (0.0, 0.0, 0.0);
        // Match once per new pair of readings, whichever arrives first, so
        // that the result does not depend on the order of their arrival.
        let mut used = (0u64, 0u64);
        loop {
            let stalled = self.injected()?;
            inputs.poll();
            truth.take_in();
            let missing = inputs.missing(STALE);
            let Some(map) = truth.map() else {
                self.report("waiting", "map").await?;
                self.next(&mut inputs).await?;
                continue;
            };
            if !missing.is_empty() {
                self.report("waiting", &missing.join(" ")).await?;
                self.next(&mut inputs).await?;
                continue;
            }
            let seqs = (
                inputs.latest("range-scan").map_or(0, |t| t.seq),
                inputs.latest("odometry").map_or(0, |t| t.seq),
            );
            if seqs.0 == used.0 || seqs.1 == used.1 {
                self.next(&mut inputs).await?;
                continue;
            }
            used = seqs;
            let odometry = self.read(&inputs, "odometry", Pose::FORM, |text| {
                Pose::parse(text).ok()
            });
            let ranges = self.read(&inputs, "range-scan", SCAN_FORMAT, parse_ranges);
            let (odometry, ranges) = match (odometry, ranges) {
                (Ok(Some(odometry)), Ok(Some(ranges))) => (odometry, ranges),
                (Err(cause), _) | (_, Err(cause)) => {
                    self.report("waiting", &cause).await?;
                    self.next(&mut inputs).await?;
                    continue;
                }
                _ => {
                    self.next(&mut inputs).await?;
                    continue;
                }
            };
            let guess = Pose::new(
                odometry.x + correction.0,
                odometry.y + correction.1,
                wrap_angle(odometry.theta + correction.2),
            );
            let best = match_scan(&map, guess, &ranges);
            correction = (
                best.x - odometry.x,
                best.y - odometry.y,
                wrap_angle(best.theta - odometry.theta),
            );
            self.report("running", "").await?;
            if !stalled {
                self.output("position", best.to_string()).await?;
            }
            self.next(&mut inputs).await?;
        }
    }

    /// Pose tracking: the robot's position from a global position measured
    /// elsewhere (ceiling cameras, another robot).
    async fn pose_tracking(&mut self) -> Result<(), ComponentError> {
        let mut inputs = self.ctx.inputs(&["global-pos"]).await?;
        loop {
            let stalled = self.injected()?;
            inputs.poll();
            match self.read(&inputs, "global-pos", Pose::FORM, |text| {
                Pose::parse(text).ok()
            }) {
                Ok(Some(pose)) => {
                    self.report("running", "").await?;
                    if !stalled {
                        self.output("position", pose.to_string()).await?;
                    }
                }
                Ok(None) => self.report("waiting", "global-pos").await?,
                Err(cause) => self.report("waiting", &cause).await?,
            }
            self.next(&mut inputs).await?;
        }
    }

    /// Navigation on the thinking cap: drives to the room in its params
    /// through the doors on the way, steering by its `position` input, and
    /// reports `done` on arrival. When the position goes stale it stops the
    /// base and reports `waiting`.
    async fn navigation(&mut self) -> Result<(), ComponentError> {
        let destination = self.arg(2)?;
        let mut inputs = self.ctx.inputs(&["position"]).await?;
        let mut truth = Truth::follow(&self.ctx).await?;
        let mut route: Option<Vec<(f64, f64)>> = None;
        loop {
            let stalled = self.injected()?;
            inputs.poll();
            truth.take_in();
            let position = self.read(&inputs, "position", Pose::FORM, |text| {
                Pose::parse(text).ok()
            });
            let Ok(Some(pose)) = position else {
                if !stalled {
                    self.output(Command::Velocity.info(), "0 0".into()).await?;
                }
                let cause = position.err().unwrap_or_else(|| "position".to_string());
                self.report("waiting", &cause).await?;
                self.next(&mut inputs).await?;
                continue;
            };
            let Some(map) = truth.map() else {
                self.report("waiting", "map").await?;
                self.next(&mut inputs).await?;
                continue;
            };
            if route.is_none() {
                let here = map
                    .room_at(pose.x, pose.y)
                    .ok_or_else(|| fault(format!("position {pose} is outside the map")))?;
                route =
                    Some(world::route(&map, &here.name, &destination).ok_or_else(|| {
                        fault(format!("no way from {} to {destination}", here.name))
                    })?);
            }
            let waypoints = route.as_mut().ok_or_else(|| fault("no route"))?;
            while waypoints.len() > 1 && pose.distance_to(waypoints[0].0, waypoints[0].1) < 0.2 {
                waypoints.remove(0);
            }
            let Some(&(wx, wy)) = waypoints.first() else {
                return Err(fault("empty route"));
            };
            let distance = pose.distance_to(wx, wy);
            if waypoints.len() == 1 && distance < 0.15 {
                self.output(Command::Velocity.info(), "0 0".into()).await?;
                self.report("done", "").await?;
                return Ok(());
            }
            let error = wrap_angle((wy - pose.y).atan2(wx - pose.x) - pose.theta);
            let w = (2.5 * error).clamp(-MAX_TURN, MAX_TURN);
            let v = if error.abs() > 0.7 {
                0.0
            } else {
                (0.8 * distance).min(0.8 * MAX_SPEED) * error.cos()
            };
            self.report("running", "").await?;
            if !stalled {
                self.output(Command::Velocity.info(), format!("{v:.4} {w:.4}"))
                    .await?;
            }
            self.next(&mut inputs).await?;
        }
    }

    /// Waits up to `limit` for world tuple `key` to read `want`.
    async fn await_world(
        &mut self,
        truth: &mut Truth,
        key: &str,
        want: &str,
        limit: Duration,
    ) -> Result<bool, ComponentError> {
        let mut waited = Duration::ZERO;
        while waited <= limit {
            self.injected()?;
            truth.poll()?;
            if truth.text(key) == Some(want) {
                return Ok(true);
            }
            self.ctx.sleep(PERIOD).await;
            waited += PERIOD;
        }
        Ok(false)
    }

    /// The gripper: reaches out, grasps the thing in its params if it is
    /// within reach, and reports `done` holding it.
    async fn gripper(&mut self) -> Result<(), ComponentError> {
        let thing = self.arg(2)?;
        let me = self.ctx.peis().to_string();
        let mut truth = Truth::follow(&self.ctx).await?;
        self.report("running", "").await?;
        let holder = WorldKey::ThingHolder(&thing).to_string();
        if !self
            .await_world(&mut truth, &holder, &me, Duration::from_secs(1))
            .await?
        {
            if !self.injected()? {
                self.output(Command::Grasp.info(), thing.clone()).await?;
            }
            if !self
                .await_world(&mut truth, &holder, &me, Duration::from_secs(2))
                .await?
            {
                return Err(fault(format!("{thing} is out of reach")));
            }
        }
        self.report("done", "").await?;
        Ok(())
    }

    /// The speaker: gives the wake-up signal and reports `done` once the
    /// person in its params is awake.
    async fn speaker(&mut self) -> Result<(), ComponentError> {
        let person = self.arg(2)?;
        let mut truth = Truth::follow(&self.ctx).await?;
        self.report("running", "").await?;
        self.ctx.sleep(Duration::from_millis(500)).await;
        if !self.injected()? {
            self.output(Command::Sound.info(), format!("wake up, {person}"))
                .await?;
        }
        let state = WorldKey::ResidentState(&person).to_string();
        if !self
            .await_world(&mut truth, &state, AWAKE, Duration::from_secs(2))
            .await?
        {
            return Err(fault(format!("{person} did not wake up")));
        }
        self.report("done", "").await?;
        Ok(())
    }

    /// A component with no functionality in the domain (the Player servers).
    async fn idle(&mut self) -> Result<(), ComponentError> {
        loop {
            self.injected()?;
            self.report("running", "").await?;
            self.ctx.sleep(Duration::from_secs(1)).await;
        }
    }
}

/// An image's text: `NAME X Y THETA; …`.
fn image_text(seen: &[(Arc<str>, Pose)]) -> String {
    // A name and three numbers of at most a dozen characters each.
    let mut text = String::with_capacity(seen.iter().map(|(name, _)| name.len() + 42).sum());
    for (i, (name, pose)) in seen.iter().enumerate() {
        if i > 0 {
            text.push_str("; ");
        }
        text.push_str(name);
        text.push(' ');
        pose.push_to(&mut text);
    }
    text
}

/// Where a read `image` shows `name`.
fn seen_in_image(image: &[(String, Pose)], name: &str) -> Option<Pose> {
    image
        .iter()
        .find(|(seen, _)| seen == name)
        .map(|(_, pose)| *pose)
}

/// Where `image` (read as [`parse_image`] reads it) shows `name` (`Some(None)`: not in it);
/// `None` when any entry is not of its form. Names are compared, not copied.
fn pose_in_image(image: &str, name: &str) -> Option<Option<Pose>> {
    let mut found = None;
    for entry in image.split(';').map(str::trim).filter(|e| !e.is_empty()) {
        let (seen, pose) = entry.split_once(char::is_whitespace)?;
        let pose = Pose::parse(pose).ok()?;
        if seen == name && found.is_none() {
            found = Some(pose);
        }
    }
    Some(found)
}

/// What an `image` shows: `NAME X Y THETA` entries separated by `;` (none
/// for an empty image); `None` when any entry is not of that form.
fn parse_image(image: &str) -> Option<Vec<(String, Pose)>> {
    image
        .split(';')
        .map(str::trim)
        .filter(|entry| !entry.is_empty())
        .map(|entry| {
            let (name, pose) = entry.split_once(char::is_whitespace)?;
            Some((name.to_string(), Pose::parse(pose).ok()?))
        })
        .collect()
}

/// A `range-scan`: one or more ranges separated by white space.
fn parse_ranges(text: &str) -> Option<Vec<f64>> {
    let ranges: Option<Vec<f64>> = text
        .split_whitespace()
        .map(|r| r.parse::<f64>().ok().filter(|r| r.is_finite()))
        .collect();
    ranges.filter(|r| !r.is_empty())
}

/// The same text in a form nobody reads: white space becomes commas, and
/// the last comma a semicolon (`1.0 2.0 0.5` → `1.0,2.0;0.5`).
fn garble(text: &str) -> String {
    let mut out = text.split_whitespace().collect::<Vec<_>>().join(",");
    if let Some(i) = out.rfind(',') {
        out.replace_range(i..=i, ";");
    }
    if out.is_empty() { "?".to_string() } else { out }
}

/// What an `image` looks like, for causes.
const IMAGE_FORMAT: &str = "NAME X Y THETA entries separated by ;";
/// What a `range-scan` looks like, for causes.
const SCAN_FORMAT: &str = "ranges in metres separated by spaces";

/// The 8 ranges a laser at `pose` measures in `map`, every 45° from its heading.
pub fn scan(map: &Map, pose: Pose) -> Vec<f64> {
    (0..8)
        .map(|k| {
            let angle = pose.theta + f64::from(k) * std::f64::consts::FRAC_PI_4;
            ray(map, pose.x, pose.y, angle)
        })
        .collect()
}

/// The pose near `guess` whose expected scan best matches `ranges`: a grid
/// search over ±0.3 m and ±0.06 rad, with residuals capped at 1 m so that
/// one bad ray cannot dominate.
pub fn match_scan(map: &Map, guess: Pose, ranges: &[f64]) -> Pose {
    let mut best = (f64::INFINITY, guess);
    for i in -6i32..=6 {
        for j in -6i32..=6 {
            for k in -2i32..=2 {
                let candidate = Pose::new(
                    guess.x + f64::from(i) * 0.05,
                    guess.y + f64::from(j) * 0.05,
                    wrap_angle(guess.theta + f64::from(k) * 0.03),
                );
                let error: f64 = scan(map, candidate)
                    .iter()
                    .zip(ranges)
                    .map(|(e, m)| (e - m).abs().min(1.0).powi(2))
                    .sum::<f64>()
                    + 0.001 * f64::from(i * i + j * j + k * k);
                if error < best.0 {
                    best = (error, candidate);
                }
            }
        }
    }
    best.1
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::{parse_image, pose_in_image, seen_in_image};

    /// An image's text from entries drawn among well-formed ones, the same name twice, and
    /// malformed ones, with any spacing.
    fn image() -> impl Strategy<Value = String> {
        let entry = prop_oneof![
            ("[a-c]", -50i32..50, -50i32..50, -314i32..314).prop_map(|(n, x, y, t)| format!(
                "{n} {}.{:02} {y} {t}e-2",
                x / 10,
                x.abs() % 10
            )),
            Just(String::new()),
            Just("a 1 2".to_string()),
            Just("b x 2 3".to_string()),
            Just("c".to_string()),
            Just("  a  0.5 -0.25 1.0  ".to_string()),
        ];
        prop::collection::vec(entry, 0..6).prop_map(|entries| entries.join(";"))
    }

    proptest! {
        /// The tracker's lookup reads an image as the whole reading of it does.
        #[test]
        fn a_pose_is_found_in_an_image_as_reading_all_of_it_finds_it(text in image(), name in "[a-d]") {
            let whole = parse_image(&text).map(|image| seen_in_image(&image, &name));
            prop_assert_eq!(pose_in_image(&text, &name), whole);
        }
    }
}
