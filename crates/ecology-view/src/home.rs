//! The home as the `world` PEIS publishes it: its `map` tuple (rooms and doors, as
//! `room NAME X0 Y0 X1 Y1; door A B X Y; …`), `robots.R.pose` (`X Y THETA`), `things.T.at`
//! (`X Y`, empty while held), `things.T.holder` (a robot, or empty), `residents.H.state` and
//! `residents.H.at` (`X Y`).
//! The keys, the map and poses are read through the world's contract (`ecology_tuples::world`):
//! a map that does not parse shows no rooms, a pose that does not parse drops its robot;
//! nothing panics. Drawn as SVG beside the
//! configuration: rooms as rectangles, doors on their walls, robots as arrows showing their
//! heading, things where they lie or beside who holds them, residents where they are (listed
//! under the map while the world has not said) with their state.

use std::collections::BTreeMap;
use std::fmt::Write;

use serde_json::{Value as Json, json};

use ecology_tuples::world::{AWAKE, Map, Point, Pose, WorldKey};

use crate::svg::escape;

/// Robots, things and residents kept at most (each); past it, new names are ignored.
const MAX_ITEMS: usize = 1_000;
/// Rooms and doors kept at most.
const MAX_ROOMS: usize = 1_000;
/// The longer side of the drawn home, pixels.
const SIDE: f64 = 300.0;
const MARGIN: f64 = 8.0;
const TOP: f64 = 8.0;
/// A robot's marker, metres from its centre to its nose.
const ROBOT: f64 = 0.22;

#[derive(Clone, Debug, Default, PartialEq)]
struct Thing {
    at: Option<(f64, f64)>,
    holder: Option<String>,
}

/// A point, `X Y`: exactly two finite numbers.
fn point(text: &str) -> Option<(f64, f64)> {
    Point::parse(text).ok().map(|p| (p.x, p.y))
}

/// A resident: their state (`asleep`, `awake`) and where they are, when the world says.
#[derive(Clone, Debug, Default, PartialEq)]
struct Resident {
    state: String,
    at: Option<(f64, f64)>,
}

/// The home as the view sees it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Home {
    map: Map,
    robots: BTreeMap<String, Pose>,
    things: BTreeMap<String, Thing>,
    residents: BTreeMap<String, Resident>,
    seen: bool,
}

fn text_or_none(text: &str) -> Option<String> {
    let text = text.trim();
    (!text.is_empty()).then(|| text.to_owned())
}

impl Home {
    /// Takes in a tuple of the `world` PEIS, `key` = `text` (`None`: removed). Other keys are
    /// ignored.
    pub fn tuple(&mut self, key: &str, text: Option<&str>) {
        let Some(key) = WorldKey::parse(key) else {
            return;
        };
        let fits = |len: usize, has: bool| has || len < MAX_ITEMS;
        match (key, text) {
            (WorldKey::Map, text) => {
                // A map that does not parse shows no rooms; a huge one, its first rooms.
                self.map = Map::parse(text.unwrap_or("")).unwrap_or_default();
                self.map.rooms.truncate(MAX_ROOMS);
                self.map.doors.truncate(MAX_ROOMS);
            }
            (WorldKey::RobotPose(name), Some(text)) => match Pose::parse(text) {
                Ok(pose) if fits(self.robots.len(), self.robots.contains_key(name)) => {
                    self.robots.insert(name.to_owned(), pose);
                }
                Ok(_) => {}
                Err(_) => {
                    self.robots.remove(name);
                }
            },
            (WorldKey::RobotPose(name), None) => {
                self.robots.remove(name);
            }
            (WorldKey::ThingAt(name) | WorldKey::ThingHolder(name), text) => {
                let has = self.things.contains_key(name);
                if !fits(self.things.len(), has) {
                    return;
                }
                let thing = self.things.entry(name.to_owned()).or_default();
                let text = text.unwrap_or("");
                if let WorldKey::ThingAt(_) = key {
                    thing.at = point(text);
                } else {
                    thing.holder = text_or_none(text);
                }
            }
            (WorldKey::ResidentState(name) | WorldKey::ResidentAt(name), text) => {
                if !fits(self.residents.len(), self.residents.contains_key(name)) {
                    return;
                }
                let resident = self.residents.entry(name.to_owned()).or_default();
                let text = text.unwrap_or("");
                if let WorldKey::ResidentState(_) = key {
                    resident.state = text.trim().to_owned();
                } else {
                    resident.at = point(text);
                }
            }
        }
        self.seen = true;
    }

    /// The room a robot is in now.
    pub fn robot_room(&self, robot: &str) -> Option<&str> {
        let pose = self.robots.get(robot)?;
        self.map.room_at(pose.x, pose.y).map(|r| r.name.as_str())
    }

    /// Where a thing is: where it lies, or where its holder is.
    fn thing_at(&self, thing: &Thing) -> Option<(f64, f64)> {
        match &thing.holder {
            Some(holder) => self.robots.get(holder).map(|p| (p.x, p.y)),
            None => thing.at,
        }
    }

    /// The home as JSON for the page (`null` until the world has published anything).
    pub fn snapshot(&self) -> Json {
        if !self.seen {
            return Json::Null;
        }
        let room_of = |x: f64, y: f64| self.map.room_at(x, y).map(|r| r.name.clone());
        json!({
            "rooms": self.map.rooms.iter().map(|r| json!({"name": r.name, "x0": r.x0, "y0": r.y0, "x1": r.x1, "y1": r.y1})).collect::<Vec<_>>(),
            "doors": self.map.doors.iter().map(|d| json!({"between": [d.a, d.b], "x": d.x, "y": d.y})).collect::<Vec<_>>(),
            "robots": self.robots.iter().map(|(name, p)| json!({"name": name, "x": p.x, "y": p.y, "theta": p.theta, "room": room_of(p.x, p.y)})).collect::<Vec<_>>(),
            "things": self.things.iter().map(|(name, t)| {
                let at = self.thing_at(t);
                json!({"name": name, "at": t.at.map(|(x, y)| [x, y]), "holder": t.holder,
                       "room": at.and_then(|(x, y)| room_of(x, y))})
            }).collect::<Vec<_>>(),
            "residents": self.residents.iter().map(|(name, r)| json!({"name": name, "state": r.state, "at": r.at.map(|(x, y)| [x, y]),
                                                                     "room": r.at.and_then(|(x, y)| room_of(x, y))})).collect::<Vec<_>>(),
            "svg": self.svg(),
        })
    }

    /// The bounding box of everything with a position: (x0, y0, x1, y1).
    fn bounds(&self) -> Option<(f64, f64, f64, f64)> {
        let mut points: Vec<(f64, f64)> = Vec::new();
        for r in &self.map.rooms {
            points.push((r.x0, r.y0));
            points.push((r.x1, r.y1));
        }
        points.extend(self.map.doors.iter().map(|d| (d.x, d.y)));
        points.extend(self.robots.values().map(|p| (p.x, p.y)));
        points.extend(self.things.values().filter_map(|t| t.at));
        points.extend(self.residents.values().filter_map(|r| r.at));
        let (first, rest) = points.split_first()?;
        Some(rest.iter().fold(
            (first.0, first.1, first.0, first.1),
            |(x0, y0, x1, y1), &(x, y)| (x0.min(x), y0.min(y), x1.max(x), y1.max(y)),
        ))
    }

    /// The home as a standalone SVG document: north (+y) up.
    pub fn svg(&self) -> String {
        let (bx0, by0, bx1, by1) = self.bounds().unwrap_or((0.0, 0.0, 1.0, 1.0));
        // Half a metre around everything, so markers at the edge stay inside.
        let (bx0, by0, bx1, by1) = (bx0 - 0.3, by0 - 0.3, bx1 + 0.3, by1 + 0.3);
        let scale = SIDE / (bx1 - bx0).max(by1 - by0).max(1e-3);
        let px = |x: f64| MARGIN + (x - bx0) * scale;
        let py = |y: f64| TOP + (by1 - y) * scale;
        // Residents whose place is not known are listed under the map.
        let residents = self.residents.values().filter(|r| r.at.is_none()).count() as f64;
        let width = 2.0 * MARGIN + (bx1 - bx0) * scale;
        let height = TOP + (by1 - by0) * scale + 10.0 + residents * 18.0;
        let mut out = String::new();
        let _ = writeln!(
            out,
            r##"<svg xmlns="http://www.w3.org/2000/svg" width="{width:.0}" height="{height:.0}" viewBox="0 0 {width:.0} {height:.0}" font-family="sans-serif" font-size="11">
<rect width="100%" height="100%" fill="#ffffff"/>"##
        );
        for r in &self.map.rooms {
            let _ = writeln!(
                out,
                r##"<g class="room" data-room="{n}"><rect x="{x:.1}" y="{y:.1}" width="{w:.1}" height="{h:.1}" fill="#f7f4ec" stroke="#5d6d7e" stroke-width="2"/><text x="{tx:.1}" y="{ty:.1}" fill="#5d6d7e">{n}</text></g>"##,
                n = escape(&r.name),
                x = px(r.x0),
                y = py(r.y1),
                w = (r.x1 - r.x0) * scale,
                h = (r.y1 - r.y0) * scale,
                tx = px(r.x0) + 5.0,
                ty = py(r.y1) + 14.0,
            );
        }
        for d in &self.map.doors {
            // On a vertical wall when a room's side runs through it, else on a horizontal one.
            let vertical = self.map.rooms.iter().any(|r| {
                ((r.x0 - d.x).abs() < 1e-6 || (r.x1 - d.x).abs() < 1e-6)
                    && d.y >= r.y0
                    && d.y <= r.y1
            });
            let half = 0.35;
            let (x1, y1, x2, y2) = if vertical {
                (d.x, d.y - half, d.x, d.y + half)
            } else {
                (d.x - half, d.y, d.x + half, d.y)
            };
            let _ = writeln!(
                out,
                r##"<line class="door" data-door="{a}-{b}" x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="#c8a165" stroke-width="5"/>"##,
                px(x1),
                py(y1),
                px(x2),
                py(y2),
                a = escape(&d.a),
                b = escape(&d.b),
            );
        }
        for (name, t) in &self.things {
            let Some((x, y)) = self.thing_at(t) else {
                continue;
            };
            let held = t.holder.as_deref().map(escape);
            let (dx, dy) = if held.is_some() {
                (8.0, 6.0)
            } else {
                (0.0, 0.0)
            };
            let label = match &held {
                Some(h) => format!("{} (held by {h})", escape(name)),
                None => escape(name),
            };
            let _ = writeln!(
                out,
                r##"<g class="thing" data-thing="{n}"{holder}><rect x="{x:.1}" y="{y:.1}" width="9" height="9" fill="#f5b041" stroke="#7e5109"/><text x="{tx:.1}" y="{ty:.1}" font-size="10" fill="#7e5109">{label}</text></g>"##,
                n = escape(name),
                holder = held
                    .as_ref()
                    .map(|h| format!(r#" data-holder="{h}""#))
                    .unwrap_or_default(),
                x = px(x) + dx - 4.5,
                y = py(y) + dy - 4.5,
                tx = px(x) + dx + 8.0,
                ty = py(y) + dy + 12.0,
            );
        }
        for (name, p) in &self.robots {
            let corner = |angle: f64, length: f64| {
                let a = p.theta + angle;
                format!(
                    "{:.1},{:.1}",
                    px(p.x + length * a.cos()),
                    py(p.y + length * a.sin())
                )
            };
            let room = self
                .robot_room(name)
                .map(|r| format!(r#" data-room="{}""#, escape(r)))
                .unwrap_or_default();
            let _ = writeln!(
                out,
                r##"<g class="robot" data-robot="{n}"{room}><polygon points="{} {} {}" fill="#2e86c1" stroke="#1b4f72" stroke-width="1.5"/><text x="{tx:.1}" y="{ty:.1}" font-weight="bold" fill="#1b4f72">{n}</text></g>"##,
                corner(0.0, ROBOT),
                corner(2.5, ROBOT),
                corner(-2.5, ROBOT),
                n = escape(name),
                tx = px(p.x) + 12.0,
                ty = py(p.y) - 8.0,
            );
        }
        let mut y = TOP + (by1 - by0) * scale + 16.0;
        for (name, resident) in &self.residents {
            let fill = if resident.state == AWAKE {
                "#e74c3c"
            } else {
                "#aab7b8"
            };
            let (cx, cy, tx, ty) = match resident.at {
                Some((x, ry)) => (px(x), py(ry), px(x) + 9.0, py(ry) + 4.0),
                None => {
                    y += 18.0;
                    (MARGIN + 5.0, y - 22.0, MARGIN + 16.0, y - 18.0)
                }
            };
            let room = resident
                .at
                .and_then(|(x, ry)| self.map.room_at(x, ry))
                .map(|r| format!(r#" data-room="{}""#, escape(&r.name)))
                .unwrap_or_default();
            let _ = writeln!(
                out,
                r##"<g class="resident" data-resident="{n}" data-state="{s}"{room}><circle cx="{cx:.1}" cy="{cy:.1}" r="6" fill="{fill}" stroke="#7b241c" stroke-width="1"/><text x="{tx:.1}" y="{ty:.1}">{n} ({s})</text></g>"##,
                n = escape(name),
                s = escape(&resident.state),
            );
        }
        out.push_str("</svg>\n");
        out
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The PEIS-Home's `map` tuple, as its world publishes it (`ecology-sim`'s world tests check
    /// that the simulator writes exactly this text for `scenarios/peis-home.toml`).
    const PEIS_HOME_MAP: &str = "room living-room 0 0 3 3; room kitchen 3 0 5 3; \
        room entrance 2.5 3 5 5; room bedroom 0 3 2.5 5; door living-room kitchen 3 1.5; \
        door living-room entrance 2.75 3; door entrance bedroom 2.5 4";

    /// [`PEIS_HOME_MAP`] as a `String`, for the view's tests.
    pub(crate) fn peis_home_map() -> String {
        PEIS_HOME_MAP.to_owned()
    }

    #[test]
    fn the_world_tuples_make_the_home_and_its_drawing() {
        let mut home = Home::default();
        assert_eq!(home.snapshot(), Json::Null);
        home.tuple("map", Some(PEIS_HOME_MAP));
        home.tuple("robots.astrid.pose", Some("1.500 1.500 0.0000"));
        home.tuple("robots.pippi.pose", Some("0.6 0.6 0.8"));
        home.tuple("things.newspaper.at", Some("4.200 4.300"));
        home.tuple("things.newspaper.holder", Some(""));
        home.tuple("residents.johanna.state", Some("asleep"));
        home.tuple("unrelated", Some("x"));
        assert_eq!(home.robot_room("astrid"), Some("living-room"));
        let snapshot = home.snapshot();
        assert_eq!(snapshot["rooms"].as_array().map(Vec::len), Some(4));
        assert_eq!(snapshot["doors"].as_array().map(Vec::len), Some(3));
        assert_eq!(snapshot["robots"][0]["name"], "astrid");
        assert_eq!(snapshot["robots"][0]["room"], "living-room");
        assert_eq!(snapshot["things"][0]["room"], "entrance");
        assert_eq!(snapshot["residents"][0]["state"], "asleep");
        let svg = snapshot["svg"].as_str().expect("svg");
        assert!(svg.contains(r#"class="robot" data-robot="astrid" data-room="living-room""#));
        assert!(svg.contains(r#"data-thing="newspaper""#));
        assert!(svg.contains(r#"data-resident="johanna" data-state="asleep""#));
        assert_eq!(svg.matches(r#"class="room""#).count(), 4);
        assert_eq!(svg.matches(r#"class="door""#).count(), 3);

        // Astrid walks into the bedroom holding the newspaper; Johanna wakes.
        home.tuple("robots.astrid.pose", Some("1.0 4.0 3.14"));
        home.tuple("things.newspaper.at", Some(""));
        home.tuple("things.newspaper.holder", Some("astrid"));
        home.tuple("residents.johanna.state", Some("awake"));
        home.tuple("residents.johanna.at", Some("1.5 4.5"));
        let snapshot = home.snapshot();
        assert_eq!(snapshot["residents"][0]["room"], "bedroom");
        assert_eq!(snapshot["robots"][0]["room"], "bedroom");
        assert_eq!(snapshot["things"][0]["holder"], "astrid");
        assert_eq!(snapshot["things"][0]["room"], "bedroom");
        let svg = snapshot["svg"].as_str().expect("svg");
        assert!(svg.contains(r#"data-robot="astrid" data-room="bedroom""#));
        assert!(svg.contains("newspaper (held by astrid)"));
        assert!(svg.contains(r#"data-resident="johanna" data-state="awake" data-room="bedroom""#));

        // Bad values: the robot is dropped, nothing panics; removals are taken in.
        home.tuple("robots.astrid.pose", Some("here"));
        home.tuple("things.newspaper.at", Some("1 2 3"));
        home.tuple("residents.<b>.state", Some("<asleep>"));
        home.tuple("map", Some("nonsense"));
        home.tuple("robots.pippi.pose", None);
        let snapshot = home.snapshot();
        assert_eq!(snapshot["robots"].as_array().map(Vec::len), Some(0));
        assert_eq!(snapshot["rooms"].as_array().map(Vec::len), Some(0));
        let svg = snapshot["svg"].as_str().expect("svg");
        assert!(svg.contains("&lt;b&gt; (&lt;asleep&gt;)"), "{svg}");
        assert!(svg.trim_end().ends_with("</svg>"));
    }
}
