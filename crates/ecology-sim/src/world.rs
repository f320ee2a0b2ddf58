//! The simulated apartment: rooms, doors, robots, things and residents, and
//! a deterministic kinematic step (differential drive, fixed time step,
//! seeded noise).
//!
//! The world is data here; `run` makes it a PEIS (`world`) that publishes its
//! ground truth as tuples and takes motor commands, grasps and sounds from the
//! other PEIS' component outputs.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use ecology_core::Rng;
// The map and poses are the world's tuple contract; the simulator adds their
// geometry (routes, laser rays) here.
pub use ecology_tuples::world::{Door, Map, Pose, Room};

/// The angle `a` wrapped into (-π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let tau = std::f64::consts::TAU;
    let mut a = a % tau;
    if a > std::f64::consts::PI {
        a -= tau;
    } else if a <= -std::f64::consts::PI {
        a += tau;
    }
    a
}

/// The longest range a simulated laser measures, metres.
pub const MAX_RANGE: f64 = 8.0;

/// Waypoints from room `from` to the centre of room `to` in `map`: each door
/// on the way (fewest doors first), then the centre.
pub fn route(map: &Map, from: &str, to: &str) -> Option<Vec<(f64, f64)>> {
    let target = map.room(to)?;
    let mut previous: BTreeMap<&str, (&str, &Door)> = BTreeMap::new();
    let mut seen: BTreeSet<&str> = BTreeSet::from([from]);
    let mut queue = VecDeque::from([from]);
    while let Some(room) = queue.pop_front() {
        if room == to {
            break;
        }
        for door in &map.doors {
            let next = if door.a == room {
                door.b.as_str()
            } else if door.b == room {
                door.a.as_str()
            } else {
                continue;
            };
            if seen.insert(next) {
                previous.insert(next, (room, door));
                queue.push_back(next);
            }
        }
    }
    if !seen.contains(to) {
        return None;
    }
    let mut doors = Vec::new();
    let mut at = to;
    while let Some((before, door)) = previous.get(at) {
        doors.push((door.x, door.y));
        at = before;
    }
    doors.reverse();
    doors.push(target.centre());
    Some(doors)
}

/// Distance from (x, y) along `angle` to the walls of the room of `map` it is
/// in (doors are not modelled as openings), at most [`MAX_RANGE`].
pub fn ray(map: &Map, x: f64, y: f64, angle: f64) -> f64 {
    let Some(r) = map.room_at(x, y) else {
        return MAX_RANGE;
    };
    let (dx, dy) = (angle.cos(), angle.sin());
    let mut best = MAX_RANGE;
    if dx > 1e-9 {
        best = best.min((r.x1 - x) / dx);
    } else if dx < -1e-9 {
        best = best.min((r.x0 - x) / dx);
    }
    if dy > 1e-9 {
        best = best.min((r.y1 - y) / dy);
    } else if dy < -1e-9 {
        best = best.min((r.y0 - y) / dy);
    }
    best.max(0.0)
}

/// Top speeds of the simulated differential-drive base.
pub const MAX_SPEED: f64 = 0.5;
/// Top turn rate, radians per second.
pub const MAX_TURN: f64 = 1.5;

/// A differential-drive robot in the world.
#[derive(Debug, Clone, PartialEq)]
pub struct Robot {
    /// Its name (the PEIS that drives it).
    pub name: String,
    /// Where it truly is.
    pub pose: Pose,
    /// The commanded (linear, angular) velocity.
    pub command: (f64, f64),
    /// Seconds since the last command; a base stops when its commands stop
    /// for half a second (a watchdog, like a real base's).
    pub command_age: f64,
}

impl Robot {
    /// One kinematic step of `dt` seconds, with seeded noise on the wheels.
    pub fn step(&mut self, dt: f64, rng: &mut Rng) {
        self.command_age += dt;
        if self.command_age > 0.5 {
            self.command = (0.0, 0.0);
        }
        let (v, w) = self.command;
        if v == 0.0 && w == 0.0 {
            return;
        }
        let v = v.clamp(-MAX_SPEED, MAX_SPEED) * (1.0 + rng.gaussian(0.02));
        let w = w.clamp(-MAX_TURN, MAX_TURN) + rng.gaussian(0.01);
        let mid = self.pose.theta + w * dt / 2.0;
        self.pose.x += v * dt * mid.cos();
        self.pose.y += v * dt * mid.sin();
        self.pose.theta = wrap_angle(self.pose.theta + w * dt);
    }
}

/// A thing that can be picked up.
#[derive(Debug, Clone, PartialEq)]
pub struct Thing {
    /// Its name, as in the problem (`newspaper`).
    pub name: String,
    /// Where it lies, when no robot holds it.
    pub at: (f64, f64),
    /// The robot holding it.
    pub holder: Option<String>,
}

/// A person living in the home.
#[derive(Debug, Clone, PartialEq)]
pub struct Resident {
    /// Their name, as in the problem (`johanna`).
    pub name: String,
    /// Where they are.
    pub at: (f64, f64),
    /// Whether they are awake.
    pub awake: bool,
}

/// How close a gripper must be to a thing to grasp it, metres.
pub const REACH: f64 = 1.0;

/// The whole world: ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct World {
    /// The map.
    pub map: Map,
    /// The robots, by name.
    pub robots: BTreeMap<String, Robot>,
    /// The things, by name.
    pub things: BTreeMap<String, Thing>,
    /// The residents, by name.
    pub residents: BTreeMap<String, Resident>,
}

impl World {
    /// Robot `robot` tries to grasp `thing`: it succeeds when the thing is free
    /// and within [`REACH`]. Returns whether the robot now holds it.
    pub fn grasp(&mut self, robot: &str, thing: &str) -> bool {
        let Some(pose) = self.robots.get(robot).map(|r| r.pose) else {
            return false;
        };
        let Some(t) = self.things.get_mut(thing) else {
            return false;
        };
        if t.holder.as_deref() == Some(robot) {
            return true;
        }
        if t.holder.is_none() && pose.distance_to(t.at.0, t.at.1) <= REACH {
            t.holder = Some(robot.to_string());
            return true;
        }
        false
    }

    /// Robot `robot` makes a sound: every resident in the same room wakes up.
    /// Returns who woke.
    pub fn sound(&mut self, robot: &str) -> Vec<String> {
        let Some(pose) = self.robots.get(robot).map(|r| r.pose) else {
            return Vec::new();
        };
        let Some(room) = self.map.room_at(pose.x, pose.y).map(|r| r.name.clone()) else {
            return Vec::new();
        };
        let mut woke = Vec::new();
        for resident in self.residents.values_mut() {
            let here = self
                .map
                .room_at(resident.at.0, resident.at.1)
                .is_some_and(|r| r.name == room);
            if here && !resident.awake {
                resident.awake = true;
                woke.push(resident.name.clone());
            }
        }
        woke
    }

    /// Moves every robot one step of `dt` seconds; held things move along.
    pub fn step(&mut self, dt: f64, rng: &mut Rng) {
        for robot in self.robots.values_mut() {
            robot.step(dt, rng);
        }
        for thing in self.things.values_mut() {
            if let Some(pose) = thing.holder.as_ref().and_then(|h| self.robots.get(h)) {
                thing.at = (pose.pose.x, pose.pose.y);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The PEIS-Home's map, from its scenario file.
    fn peis_home() -> Map {
        let file =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios/peis-home.toml");
        crate::Scenario::load(&file)
            .expect("loads")
            .world_for(1)
            .map
    }

    #[test]
    fn the_map_text_parses_back_into_the_map() {
        let text = peis_home().to_string();
        // The text the live view's tests and the Python examples read, byte for byte.
        assert_eq!(
            text,
            "room living-room 0 0 3 3; room kitchen 3 0 5 3; room entrance 2.5 3 5 5; \
             room bedroom 0 3 2.5 5; door living-room kitchen 3 1.5; \
             door living-room entrance 2.75 3; door entrance bedroom 2.5 4"
        );
        let map = Map::parse(&text).expect("parses");
        assert_eq!(map, peis_home());
        assert_eq!((map.rooms.len(), map.doors.len()), (4, 3));
        assert_eq!(map.rooms[2].name, "entrance");
        assert_eq!((map.doors[2].x, map.doors[2].y), (2.5, 4.0));
        // Bad map texts are the contract's to refuse: `ecology_tuples::world`'s tests.
    }
}
