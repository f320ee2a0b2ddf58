//! One simulated PEIS on any tuple space: its init component with simulated
//! component bodies, and faults injected by tuples.
//!
//! A fault reaches a PEIS that runs as a process of its own as its tuple
//! `C.fault`, set by remote set from anywhere (`ecology tuples set hsm
//! ca1.fault stall`): `stall` (the component falls silent), `garble` (it
//! writes its outputs in a form nobody reads), `fail CAUSE` (it reports
//! `error` with CAUSE), `recover` or an empty value (the fault is cleared).

use std::future::Future;
use std::sync::Arc;

use futures_util::StreamExt;
use futures_util::stream::SelectAll;

use ecology_peis::{ComponentSpec, HostError, HostOptions, announce_covers, run_host_with};
use ecology_ros2::{Agent, Ros2Component, announce_topics};
use ecology_tuples::world::{Map, Pose, WorldKey};
use ecology_tuples::{
    Clock, ComponentId, Subscription, TupleError, TupleEvent, TuplePattern, TupleSpace,
};

use crate::components::{FaultState, Faults, Simulated};
use crate::scenario::PeisDef;

/// The component specs of PEIS `def`, with simulated bodies sharing `faults`; its ROS 2 nodes
/// are left out.
pub fn simulated_components<S: TupleSpace>(
    def: &PeisDef,
    faults: &Faults,
    seed: u64,
) -> Vec<ComponentSpec<S>> {
    def.components
        .iter()
        .filter(|c| c.ros2.is_none())
        .filter_map(|c| {
            let body = Simulated::new(&c.kind, faults.clone(), seed)?.covering(&c.covers);
            Some(ComponentSpec {
                name: c.id.clone(),
                kind: c.kind.clone(),
                cost: c.cost,
                on: c.on,
                startup: c.startup,
                covers: c.covers.clone(),
                body: Arc::new(body),
            })
        })
        .collect()
}

/// A fault as written in a `C.fault` tuple; `None` when the text is none of them.
pub fn parse_fault(text: &str) -> Option<FaultState> {
    let text = text.trim();
    let (word, rest) = text.split_once(char::is_whitespace).unwrap_or((text, ""));
    match word {
        "" | "recover" => Some(FaultState::default()),
        "stall" => Some(FaultState {
            stalled: true,
            ..FaultState::default()
        }),
        "garble" => Some(FaultState {
            garbled: true,
            ..FaultState::default()
        }),
        "fail" => Some(FaultState {
            failed: Some(match rest.trim() {
                "" => "injected failure".to_string(),
                cause => cause.to_string(),
            }),
            ..FaultState::default()
        }),
        _ => None,
    }
}

/// The component specs of PEIS `def`'s ROS 2 nodes, each driven through `agent`.
pub fn ros2_components<S: TupleSpace>(def: &PeisDef, agent: &Agent) -> Vec<ComponentSpec<S>> {
    def.components
        .iter()
        .filter_map(|c| {
            let spec = c.ros2.clone()?;
            let body = Ros2Component::new(agent.clone(), format!("{}:{}", def.name, c.id), spec);
            Some(ComponentSpec {
                name: c.id.clone(),
                kind: c.kind.clone(),
                cost: c.cost,
                on: c.on,
                startup: c.startup,
                covers: c.covers.clone(),
                body: Arc::new(body),
            })
        })
        .collect()
}

/// Runs PEIS `def` on `space` (which acts as that PEIS) with simulated
/// components, and its ROS 2 nodes through `agent` (needed when it has any),
/// until `shutdown` completes, applying `C.fault` tuples as they
/// are set and telling `note` about each (`ca1 stalls`), and about what the
/// host puts back by itself when the PEIS that asked for it is gone.
pub async fn host_peis<S: TupleSpace>(
    space: S,
    clock: Arc<dyn Clock>,
    def: &PeisDef,
    seed: u64,
    agent: Option<&Agent>,
    note: impl Fn(String) + Send + Sync + 'static,
    shutdown: impl Future<Output = ()> + Send,
) -> Result<(), HostError> {
    let note: Arc<dyn Fn(String) + Send + Sync> = Arc::new(note);
    let faults = Faults::default();
    let me = space.peis().clone();
    let pattern = TuplePattern::parse(&format!("{me}:*.fault"))
        .map_err(|e| HostError::Space(TupleError::Invalid(e)))?;
    let mut fault_tuples = space.subscribe(pattern).await?;
    let options = HostOptions {
        note: note.clone(),
        ..HostOptions::default()
    };
    let mut components = simulated_components(def, &faults, seed);
    if let Some(agent) = agent {
        components.extend(ros2_components(def, agent));
        for c in &def.components {
            if let Some(spec) = &c.ros2 {
                announce_topics(&space, &c.id, spec).await?;
            }
        }
    }
    let host = run_host_with(space.clone(), clock, components, options, shutdown);
    let with_faults = async {
        tokio::pin!(host);
        loop {
            tokio::select! {
            biased;
            result = &mut host => return result,
            Some(event) = fault_tuples.next() => {
                let TupleEvent::Changed(tuple) = event else { continue };
                let Some(component) = tuple.key.as_str().strip_suffix(".fault") else { continue };
                if !def.components.iter().any(|c| c.id == component) {
                    note(format!("fault for unknown component {component} ignored"));
                    continue;
                }
                let text = tuple.text().unwrap_or("");
                match parse_fault(text) {
                    Some(state) => {
                        let what = match (&state.failed, state.stalled, state.garbled) {
                            (Some(cause), _, _) => format!("{component} fails: {cause}"),
                            (None, true, _) => format!("{component} stalls (stops publishing)"),
                            (None, false, true) => {
                                format!("{component} garbles its outputs")
                            }
                            (None, false, false) => format!("{component} recovers"),
                        };
                        faults.update(me.as_str(), component, |s| *s = state);
                        note(what);
                    }
                    None => note(format!(
                        "fault `{text}` for {component} ignored (known: stall, garble, fail CAUSE, recover)"
                    )),
                }
            }
            }
        }
    };
    with_robot_room(space, def, with_faults).await
}

/// Runs `host` (PEIS `def`'s host on `space`) until it ends, with its robot cameras saying the
/// room the robot is in ([`RobotRoom`]).
pub(crate) async fn with_robot_room<S: TupleSpace>(
    space: S,
    def: &PeisDef,
    host: impl Future<Output = Result<(), HostError>>,
) -> Result<(), HostError> {
    let mut rooms = RobotRoom::follow(&space, def).await?;
    tokio::pin!(host);
    loop {
        tokio::select! {
            biased;
            result = &mut host => return result,
            Some(event) = rooms.next() => rooms.take(&space, event).await?,
        }
    }
}

/// The room a robot PEIS is in, said by its cameras (`cam`) that say nothing of what they cover:
/// a robot's camera sees the room the robot is in (within its range), so each says it covers that
/// room, as the world places the robot, and says so again each time the robot enters another.
pub(crate) struct RobotRoom {
    /// The cameras, with their types.
    cameras: Vec<(ComponentId, String)>,
    /// The world's map and this robot's pose; empty when the PEIS has no such camera.
    subscriptions: SelectAll<Subscription>,
    map: Option<Arc<Map>>,
    at: Option<(f64, f64)>,
    /// The room the cameras last said they cover.
    said: Vec<String>,
}

impl RobotRoom {
    /// The cameras of `def` that say the room their robot is in: simulated `cam`s that say
    /// nothing of what they cover.
    fn cameras(def: &PeisDef) -> impl Iterator<Item = &crate::scenario::ComponentDef> {
        def.components
            .iter()
            .filter(|c| c.kind == "cam" && c.covers.is_empty() && c.ros2.is_none())
    }

    /// Whether PEIS `def` has such cameras.
    pub(crate) fn needed(def: &PeisDef) -> bool {
        RobotRoom::cameras(def).next().is_some()
    }

    async fn follow<S: TupleSpace>(space: &S, def: &PeisDef) -> Result<RobotRoom, TupleError> {
        let cameras: Vec<(ComponentId, String)> = RobotRoom::cameras(def)
            .filter_map(|c| Some((ComponentId::new(&c.id).ok()?, c.kind.clone())))
            .collect();
        let mut subscriptions = SelectAll::new();
        if !cameras.is_empty() {
            for key in [WorldKey::Map, WorldKey::RobotPose(&def.name)] {
                subscriptions.push(space.subscribe(key.pattern()?).await?);
            }
        }
        Ok(RobotRoom {
            cameras,
            subscriptions,
            map: None,
            at: None,
            said: Vec::new(),
        })
    }

    /// The next change of the map or the pose; never, without cameras.
    async fn next(&mut self) -> Option<TupleEvent> {
        if self.subscriptions.is_empty() {
            return std::future::pending().await;
        }
        self.subscriptions.next().await
    }

    /// Takes in `event`, and has the cameras say the room the robot is now in if it changed.
    async fn take<S: TupleSpace>(&mut self, space: &S, event: TupleEvent) -> Result<(), HostError> {
        let TupleEvent::Changed(tuple) = event else {
            return Ok(());
        };
        let text = tuple.text().unwrap_or("");
        match WorldKey::parse(tuple.key.as_str()) {
            Some(WorldKey::Map) => self.map = Map::parse_shared(text).ok(),
            Some(WorldKey::RobotPose(_)) => self.at = Pose::parse(text).ok().map(|p| (p.x, p.y)),
            _ => return Ok(()),
        }
        let room = match (&self.map, self.at) {
            (Some(map), Some((x, y))) => map.room_at(x, y).map(|r| r.name.clone()),
            _ => None,
        };
        let now: Vec<String> = room.into_iter().collect();
        if now != self.said {
            for (camera, kind) in &self.cameras {
                announce_covers(space, camera, kind, &self.said, &now).await?;
            }
            self.said = now;
        }
        Ok(())
    }
}
