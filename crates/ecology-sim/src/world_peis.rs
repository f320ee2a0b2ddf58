//! The world as a PEIS: it publishes ground truth and moves the robots by the
//! commands components publish, in one process with the ecology (virtual
//! time, driven by [`crate::run`]) or as a process of its own on any tuple
//! space in real time ([`run_world`]).
//!
//! Tuples of the `world` PEIS: `map` (the rooms and doors, as text),
//! `robots.NAME.pose` (`X Y THETA`), `things.NAME.at` (`X Y` where it lies,
//! empty while held), `things.NAME.holder` (the robot holding it, or empty),
//! `residents.NAME.state` (`asleep` or `awake`) and `residents.NAME.at` (`X Y`). It reads
//! every component's `C.out.velocity` (`V W`: m/s and rad/s, for the robot
//! that is the component's PEIS), `C.out.grasp` (the thing to grasp) and
//! `C.out.sound` (a sound in the robot's room).

use std::future::Future;
use std::sync::Arc;
use std::time::Duration;

use ecology_tuples::{
    Clock, Key, Subscription, TupleError, TupleEvent, TuplePattern, TupleSpace, Value,
};

use crate::components::WORLD;
use crate::world::World;
use ecology_core::Rng;

fn key(text: &str) -> Result<Key, TupleError> {
    Key::new(text).map_err(TupleError::Invalid)
}

/// The world's ground truth and the subscriptions to what components ask of it.
#[derive(Debug)]
pub struct WorldPeis {
    world: World,
    rng: Rng,
    velocities: Subscription,
    grasps: Subscription,
    sounds: Subscription,
}

impl WorldPeis {
    /// Subscribes `space` (the `world` PEIS) to the components' commands and
    /// publishes the whole ground truth once.
    pub async fn join<S: TupleSpace>(
        space: &S,
        world: World,
        seed: u64,
    ) -> Result<WorldPeis, TupleError> {
        let subscribe = |what: &str| {
            TuplePattern::parse(&format!("*:*.out.{what}")).map_err(TupleError::Invalid)
        };
        let peis = WorldPeis {
            velocities: space.subscribe(subscribe("velocity")?).await?,
            grasps: space.subscribe(subscribe("grasp")?).await?,
            sounds: space.subscribe(subscribe("sound")?).await?,
            world,
            rng: Rng::derive(seed, WORLD),
        };
        space
            .set(key("map")?, Value::text(peis.world.map.to_text()))
            .await?;
        publish_poses(&peis.world, space).await?;
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
        publish_poses(&self.world, space).await?;
        if changed {
            publish_things(&self.world, space).await?;
        }
        Ok(())
    }
}

// Free functions of the world alone: a `&WorldPeis` held across an await would
// not be `Send`, since subscriptions are not `Sync`.
async fn publish_poses<S: TupleSpace>(world: &World, space: &S) -> Result<(), TupleError> {
    for (name, robot) in &world.robots {
        space
            .set(
                key(&format!("robots.{name}.pose"))?,
                Value::text(robot.pose.to_text()),
            )
            .await?;
    }
    Ok(())
}

async fn publish_things<S: TupleSpace>(world: &World, space: &S) -> Result<(), TupleError> {
    for (name, thing) in &world.things {
        let holder = thing.holder.clone().unwrap_or_default();
        let at = match thing.holder {
            Some(_) => String::new(),
            None => format!("{:.3} {:.3}", thing.at.0, thing.at.1),
        };
        space
            .set(key(&format!("things.{name}.at"))?, Value::text(at))
            .await?;
        space
            .set(key(&format!("things.{name}.holder"))?, Value::text(holder))
            .await?;
    }
    for (name, resident) in &world.residents {
        let state = if resident.awake { "awake" } else { "asleep" };
        space
            .set(key(&format!("residents.{name}.state"))?, Value::text(state))
            .await?;
        let at = format!("{:.3} {:.3}", resident.at.0, resident.at.1);
        space
            .set(key(&format!("residents.{name}.at"))?, Value::text(at))
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
