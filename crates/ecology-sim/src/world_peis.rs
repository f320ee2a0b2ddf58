//! The world as a PEIS: it publishes ground truth and moves the robots by the
//! commands components publish, in one process with the ecology (virtual
//! time, driven by [`crate::run`]) or as a process of its own on any tuple
//! space in real time ([`run_world`]).
//!
//! The tuples it publishes and the component outputs it reads are the
//! contract of [`ecology_tuples::world`].

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use ecology_tuples::world::{ASLEEP, AWAKE, Command, Point, Pose, WORLD, WorldKey};
use ecology_tuples::{Clock, Key, Subscription, TupleError, TupleEvent, TupleSpace, Value};

use crate::world::World;
use ecology_core::Rng;

fn key(key: WorldKey<'_>) -> Result<Key, TupleError> {
    key.key().map_err(TupleError::Invalid)
}

/// The world's ground truth and the subscriptions to what components ask of it.
#[derive(Debug)]
pub struct WorldPeis {
    world: World,
    rng: Rng,
    velocities: Subscription,
    grasps: Subscription,
    sounds: Subscription,
    /// Each robot's pose as last published, in the order of the world's robots (which a run
    /// does not change): a thousand robots looked up by name every step cost more than the rest
    /// of publishing their poses.
    shown: Vec<Option<Pose>>,
    /// The still robot whose pose the next quiet step publishes again.
    beat: usize,
}

impl WorldPeis {
    /// Subscribes `space` (the `world` PEIS) to the components' commands and
    /// publishes the whole ground truth once.
    pub async fn join<S: TupleSpace>(
        space: &S,
        world: World,
        seed: u64,
    ) -> Result<WorldPeis, TupleError> {
        let mut peis = WorldPeis {
            velocities: space.subscribe(Command::Velocity.pattern()).await?,
            grasps: space.subscribe(Command::Grasp.pattern()).await?,
            sounds: space.subscribe(Command::Sound.pattern()).await?,
            world,
            rng: Rng::derive(seed, WORLD),
            shown: Vec::new(),
            beat: 0,
        };
        space
            .set(key(WorldKey::Map)?, Value::text(peis.world.map.to_string()))
            .await?;
        let poses = peis.poses_to_publish();
        publish(space, poses).await?;
        publish_things(&peis.world, space).await?;
        Ok(peis)
    }

    /// The ground truth now.
    pub fn world(&self) -> &World {
        &self.world
    }

    /// The world at the end.
    pub fn into_world(self) -> World {
        self.world
    }

    /// Takes in every command that has arrived; returns whether a thing or a
    /// resident changed (a grasp or a sound).
    fn take_commands(&mut self) -> bool {
        while let Some(event) = self.velocities.try_next() {
            if let TupleEvent::Changed(tuple) = event
                && let Some(robot) = self.world.robots.get_mut(tuple.owner.as_str())
            {
                let mut numbers = tuple
                    .text()
                    .unwrap_or("")
                    .split_whitespace()
                    .map(str::parse::<f64>);
                if let (Some(Ok(v)), Some(Ok(w))) = (numbers.next(), numbers.next())
                    && v.is_finite()
                    && w.is_finite()
                {
                    robot.command = (v, w);
                    robot.command_age = 0.0;
                }
            }
        }
        let mut changed = false;
        while let Some(event) = self.grasps.try_next() {
            if let TupleEvent::Changed(tuple) = event {
                let thing = tuple.text().unwrap_or("").trim().to_string();
                changed |= self.world.grasp(tuple.owner.as_str(), &thing);
            }
        }
        while let Some(event) = self.sounds.try_next() {
            if let TupleEvent::Changed(tuple) = event {
                changed |= !self.world.sound(tuple.owner.as_str()).is_empty();
            }
        }
        changed
    }

    /// One step of `dt`: the commands that arrived, the robots moved, the new
    /// truth published.
    pub async fn step<S: TupleSpace>(&mut self, space: &S, dt: Duration) -> Result<(), TupleError> {
        let changed = self.take_commands();
        self.world.step(dt.as_secs_f64(), &mut self.rng);
        let poses = self.poses_to_publish();
        publish(space, poses).await?;
        if changed {
            publish_things(&self.world, space).await?;
        }
        Ok(())
    }

    /// The poses that changed since they were last published; when none did, one still robot's
    /// pose again, in turn. A robot standing still costs its readers nothing, and the world
    /// is still heard from every step (its readers take a silence of a second for a world
    /// that left or froze).
    fn poses_to_publish(&mut self) -> Vec<(Key, String)> {
        let robots = &self.world.robots;
        self.shown.resize(robots.len(), None);
        let mut out = Vec::new();
        let mut moved = false;
        for ((name, robot), shown) in robots.iter().zip(self.shown.iter_mut()) {
            if *shown != Some(robot.pose) {
                moved = true;
                if let Ok(at) = key(WorldKey::RobotPose(name)) {
                    *shown = Some(robot.pose);
                    out.push((at, robot.pose.to_string()));
                }
            }
        }
        if !moved && !robots.is_empty() {
            self.beat = (self.beat + 1) % robots.len();
            if let Some((name, robot)) = robots.iter().nth(self.beat)
                && let Ok(at) = key(WorldKey::RobotPose(name))
            {
                self.shown[self.beat] = Some(robot.pose);
                out.push((at, robot.pose.to_string()));
            }
        }
        out
    }
}

// Free functions of the world alone: a `&WorldPeis` held across an await would
// not be `Send`, since subscriptions are not `Sync`.
async fn publish<S: TupleSpace>(space: &S, tuples: Vec<(Key, String)>) -> Result<(), TupleError> {
    for (at, text) in tuples {
        space.set(at, Value::text(text)).await?;
    }
    Ok(())
}

async fn publish_things<S: TupleSpace>(world: &World, space: &S) -> Result<(), TupleError> {
    for (name, thing) in &world.things {
        let holder = thing.holder.clone().unwrap_or_default();
        let at = match thing.holder {
            Some(_) => String::new(),
            None => Point::new(thing.at.0, thing.at.1).to_string(),
        };
        space
            .set(key(WorldKey::ThingAt(name))?, Value::text(at))
            .await?;
        space
            .set(key(WorldKey::ThingHolder(name))?, Value::text(holder))
            .await?;
    }
    for (name, resident) in &world.residents {
        let state = if resident.awake { AWAKE } else { ASLEEP };
        space
            .set(key(WorldKey::ResidentState(name))?, Value::text(state))
            .await?;
        let at = Point::new(resident.at.0, resident.at.1).to_string();
        space
            .set(key(WorldKey::ResidentAt(name))?, Value::text(at))
            .await?;
    }
    Ok(())
}

/// Runs `world` as the `world` PEIS on `space` in real time (steps of `step`
/// on `clock`) until `shutdown` completes; returns the world at the end.
///
/// A step that falls behind the clock (a slow machine) is taken at once, and
/// the steps missed are not made up for, so the world never jumps.
pub async fn run_world<S: TupleSpace>(
    space: &S,
    clock: Arc<dyn Clock>,
    world: World,
    seed: u64,
    step: Duration,
    shutdown: impl Future<Output = ()>,
) -> Result<World, TupleError> {
    let mut peis = WorldPeis::join(space, world, seed).await?;
    tokio::pin!(shutdown);
    let mut next = clock.now().saturating_add(step);
    loop {
        tokio::select! {
            biased;
            () = &mut shutdown => return Ok(peis.into_world()),
            () = clock.sleep_until(next) => {}
        }
        peis.step(space, step).await?;
        next = next.saturating_add(step).max(clock.now());
    }
}
