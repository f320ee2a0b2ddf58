//! The simulated apartment: rooms, doors, robots, things and residents, and
//! a deterministic kinematic step (differential drive, fixed time step,
//! seeded noise).
//!
//! The world is data here; `run` makes it a PEIS (`world`) that publishes its
//! ground truth as tuples and takes motor commands, grasps and sounds from the
//! other PEIS' component outputs.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::fmt::Write as _;

use ecology_core::Rng;

/// A 2-D pose: position in metres, heading in radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// x, metres.
    pub x: f64,
    /// y, metres.
    pub y: f64,
    /// Heading, radians, counter-clockwise from the x axis.
    pub theta: f64,
}

impl Pose {
    /// A pose.
    pub fn new(x: f64, y: f64, theta: f64) -> Pose {
        Pose { x, y, theta }
    }

    /// Distance to the point (x, y).
    pub fn distance_to(&self, x: f64, y: f64) -> f64 {
        (self.x - x).hypot(self.y - y)
    }

    /// As tuple text: `x y theta`.
    pub fn to_text(&self) -> String {
        format!("{:.3} {:.3} {:.4}", self.x, self.y, self.theta)
    }

    /// Parses `x y theta`: exactly three finite numbers.
    pub fn parse(text: &str) -> Option<Pose> {
        let mut it = text.split_whitespace().map(str::parse::<f64>);
        let (Some(Ok(x)), Some(Ok(y)), Some(Ok(theta)), None) =
            (it.next(), it.next(), it.next(), it.next())
        else {
            return None;
        };
        [x, y, theta]
            .iter()
            .all(|v| v.is_finite())
            .then_some(Pose { x, y, theta })
    }
}

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

/// A rectangular room.
#[derive(Debug, Clone, PartialEq)]
pub struct Room {
    /// Its name, as in the domain's problem (`bedroom`).
    pub name: String,
    /// Lower-left corner x.
    pub x0: f64,
    /// Lower-left corner y.
    pub y0: f64,
    /// Upper-right corner x.
    pub x1: f64,
    /// Upper-right corner y.
    pub y1: f64,
}

impl Room {
    /// Whether (x, y) lies in the room (borders included).
    pub fn contains(&self, x: f64, y: f64) -> bool {
        x >= self.x0 && x <= self.x1 && y >= self.y0 && y <= self.y1
    }

    /// The room's centre.
    pub fn centre(&self) -> (f64, f64) {
        ((self.x0 + self.x1) / 2.0, (self.y0 + self.y1) / 2.0)
    }

    /// Its area in square metres.
    pub fn area(&self) -> f64 {
        (self.x1 - self.x0) * (self.y1 - self.y0)
    }
}

/// A door: a passage between two rooms at a point on their common wall.
#[derive(Debug, Clone, PartialEq)]
pub struct Door {
    /// One room.
    pub a: String,
    /// The other room.
    pub b: String,
    /// The passage point x.
    pub x: f64,
    /// The passage point y.
    pub y: f64,
}

/// The map: rooms and the doors between them.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Map {
    /// The rooms.
    pub rooms: Vec<Room>,
    /// The doors.
    pub doors: Vec<Door>,
}

/// The longest range a simulated laser measures, metres.
pub const MAX_RANGE: f64 = 8.0;

impl Map {
    /// The room at (x, y): the first that contains it, or, within 0.2 m of a
    /// wall (the width of a door frame), the nearest.
    pub fn room_at(&self, x: f64, y: f64) -> Option<&Room> {
        // Nowhere is in no room (NaN would read as on every wall).
        if !x.is_finite() || !y.is_finite() {
            return None;
        }
        if let Some(room) = self.rooms.iter().find(|r| r.contains(x, y)) {
            return Some(room);
        }
        self.rooms
            .iter()
            .map(|r| {
                let dx = (r.x0 - x).max(x - r.x1).max(0.0);
                let dy = (r.y0 - y).max(y - r.y1).max(0.0);
                (dx.hypot(dy), r)
            })
            .filter(|(d, _)| *d <= 0.2)
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, r)| r)
    }

    /// The room called `name`.
    pub fn room(&self, name: &str) -> Option<&Room> {
        self.rooms.iter().find(|r| r.name == name)
    }

    /// Waypoints from room `from` to the centre of room `to`: each door on
    /// the way (fewest doors first), then the centre.
    pub fn route(&self, from: &str, to: &str) -> Option<Vec<(f64, f64)>> {
        let target = self.room(to)?;
        let mut previous: BTreeMap<&str, (&str, &Door)> = BTreeMap::new();
        let mut seen: BTreeSet<&str> = BTreeSet::from([from]);
        let mut queue = VecDeque::from([from]);
        while let Some(room) = queue.pop_front() {
            if room == to {
                break;
            }
            for door in &self.doors {
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

    /// Distance from (x, y) along `angle` to the walls of the room it is in
    /// (doors are not modelled as openings), at most [`MAX_RANGE`].
    pub fn ray(&self, x: f64, y: f64, angle: f64) -> f64 {
        let Some(r) = self.room_at(x, y) else {
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

    /// The map as one tuple's text: `room NAME X0 Y0 X1 Y1; door A B X Y; …`.
    pub fn to_text(&self) -> String {
        let mut text = String::new();
        for r in &self.rooms {
            let _ = write!(
                text,
                "room {} {} {} {} {}; ",
                r.name, r.x0, r.y0, r.x1, r.y1
            );
        }
        for d in &self.doors {
            let _ = write!(text, "door {} {} {} {}; ", d.a, d.b, d.x, d.y);
        }
        text.trim_end_matches([';', ' ']).to_string()
    }

    /// Parses [`Map::to_text`]'s form: every item a room or a door, every number finite.
    pub fn parse(text: &str) -> Option<Map> {
        let mut map = Map::default();
        for item in text.split(';').map(str::trim).filter(|s| !s.is_empty()) {
            let words: Vec<&str> = item.split_whitespace().collect();
            let num = |i: usize| {
                words
                    .get(i)
                    .and_then(|w| w.parse::<f64>().ok())
                    .filter(|v| v.is_finite())
            };
            match words.first() {
                Some(&"room") if words.len() == 6 => map.rooms.push(Room {
                    name: words[1].to_string(),
                    x0: num(2)?,
                    y0: num(3)?,
                    x1: num(4)?,
                    y1: num(5)?,
                }),
                Some(&"door") if words.len() == 5 => map.doors.push(Door {
                    a: words[1].to_string(),
                    b: words[2].to_string(),
                    x: num(3)?,
                    y: num(4)?,
                }),
                _ => return None,
            }
        }
        Some(map)
    }
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
        let map = Map::parse(&peis_home().to_text()).expect("parses");
        assert_eq!(map, peis_home());
        assert_eq!((map.rooms.len(), map.doors.len()), (4, 3));
        assert_eq!(map.rooms[2].name, "entrance");
        assert_eq!((map.doors[2].x, map.doors[2].y), (2.5, 4.0));
        for bad in [
            "room",
            "room a 1 2 3",
            "room a 1 2 3 4 5",
            "room a x 2 3 4",
            "room a NaN 0 1 1",
            "room a inf 0 1 1",
            "door a b 1",
            "door a b 1 y",
            "window a 1 2",
            "room a 0 0 1 1; junk",
        ] {
            assert_eq!(Map::parse(bad), None, "{bad:?}");
        }
        assert_eq!(Map::parse(""), Some(Map::default()));
    }

    #[test]
    fn the_room_of_a_position_is_the_room_containing_it_or_the_nearest_within_a_door_frame() {
        let map = peis_home();
        let name = |x: f64, y: f64| map.room_at(x, y).map(|r| r.name.as_str());
        assert_eq!(name(1.5, 1.5), Some("living-room"));
        assert_eq!(name(4.2, 4.3), Some("entrance"));
        // On a wall: the first room listed that has it.
        assert_eq!(name(3.0, 1.5), Some("living-room"));
        // Just outside the home, within a door frame of the bedroom; too far from any room.
        assert_eq!(name(-0.1, 4.0), Some("bedroom"));
        assert_eq!(name(-1.0, 4.0), None);
        assert_eq!(name(f64::NAN, 1.0), None);
        assert_eq!(name(f64::INFINITY, 1.0), None);
        assert_eq!(Map::default().room_at(1.0, 1.0), None);
    }
}
