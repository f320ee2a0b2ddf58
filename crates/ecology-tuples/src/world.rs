//! The tuple contract of the `world` PEIS (the simulated home's ground truth), spelt once for the
//! simulator that publishes it and everything that reads it (the simulated components, the
//! replanner, the live view).
//!
//! The world publishes `map` (rooms and doors: `room NAME X0 Y0 X1 Y1; door A B X Y; …`),
//! `robots.R.pose` (`X Y THETA`), `things.T.at` (`X Y` where it lies, empty while held),
//! `things.T.holder` (the robot holding it, or empty), `residents.H.state` (`asleep` or `awake`)
//! and `residents.H.at` (`X Y`). It reads every component's outputs `C.out.velocity` (`V W`: m/s
//! and rad/s, for the robot that is the component's PEIS), `C.out.grasp` (the thing to grasp) and
//! `C.out.sound` (a sound in the robot's room).
//!
//! The text forms are read by programs outside this workspace too (the Python examples, scenario
//! tests), so [`Map`], [`Pose`] and [`Point`] write exactly what they always wrote, and their
//! parsers return an error, never panic, on any input.

use std::fmt::{self, Write};
use std::sync::{Arc, Mutex, PoisonError};

use crate::contract::quoted;
use crate::name::{Key, ValidationError};
use crate::pattern::TuplePattern;

/// The name of the PEIS that holds the world's ground truth.
pub const WORLD: &str = "world";

/// `residents.H.state` of a resident who is awake.
pub const AWAKE: &str = "awake";
/// `residents.H.state` of a resident who is asleep.
pub const ASLEEP: &str = "asleep";

/// The pattern of every tuple the world publishes (`world:**`).
pub fn world_pattern() -> TuplePattern {
    // `WORLD` is a valid PEIS name and `**` a valid key pattern, so this cannot fail; the
    // fallback only keeps a panic out of the code.
    TuplePattern::parse(&format!("{WORLD}:**")).unwrap_or_else(|_| TuplePattern::everything())
}

/// One key the world publishes; names are key segments (a robot's PEIS, a thing or a resident of
/// the domain's problem).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum WorldKey<'a> {
    /// `map`: the rooms and doors, a [`Map`]'s text.
    Map,
    /// `robots.R.pose`: where robot R truly is, a [`Pose`]'s text.
    RobotPose(&'a str),
    /// `things.T.at`: where thing T lies, a [`Point`]'s text; empty while a robot holds it.
    ThingAt(&'a str),
    /// `things.T.holder`: the robot holding thing T, or empty.
    ThingHolder(&'a str),
    /// `residents.H.state`: [`AWAKE`] or [`ASLEEP`].
    ResidentState(&'a str),
    /// `residents.H.at`: where resident H is, a [`Point`]'s text.
    ResidentAt(&'a str),
}

impl<'a> WorldKey<'a> {
    /// The key, when the name is a valid key segment.
    pub fn key(self) -> Result<Key, ValidationError> {
        Key::new(&self.to_string())
    }

    /// The pattern of this one tuple of the world (`world:KEY`), when the name is a valid key
    /// segment.
    pub fn pattern(self) -> Result<TuplePattern, ValidationError> {
        TuplePattern::parse(&format!("{WORLD}:{self}"))
    }

    /// Which world key `key` is; `None` for any other key, or a name that is not one segment.
    pub fn parse(key: &'a str) -> Option<WorldKey<'a>> {
        if key == "map" {
            return Some(WorldKey::Map);
        }
        let (kind, rest) = key.split_once('.')?;
        let (name, field) = rest.split_once('.')?;
        if name.is_empty() || field.contains('.') {
            return None;
        }
        match (kind, field) {
            ("robots", "pose") => Some(WorldKey::RobotPose(name)),
            ("things", "at") => Some(WorldKey::ThingAt(name)),
            ("things", "holder") => Some(WorldKey::ThingHolder(name)),
            ("residents", "state") => Some(WorldKey::ResidentState(name)),
            ("residents", "at") => Some(WorldKey::ResidentAt(name)),
            _ => None,
        }
    }
}

impl fmt::Display for WorldKey<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            WorldKey::Map => f.write_str("map"),
            WorldKey::RobotPose(name) => write!(f, "robots.{name}.pose"),
            WorldKey::ThingAt(name) => write!(f, "things.{name}.at"),
            WorldKey::ThingHolder(name) => write!(f, "things.{name}.holder"),
            WorldKey::ResidentState(name) => write!(f, "residents.{name}.state"),
            WorldKey::ResidentAt(name) => write!(f, "residents.{name}.at"),
        }
    }
}

/// A command a component gives the world through one of its outputs (`C.out.INFO`); the world
/// applies it to the robot that is the component's PEIS.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Command {
    /// `C.out.velocity`: `V W`, the linear (m/s) and angular (rad/s) velocity.
    Velocity,
    /// `C.out.grasp`: the thing to grasp.
    Grasp,
    /// `C.out.sound`: a sound in the robot's room (it wakes who sleeps there).
    Sound,
}

impl Command {
    /// The output's information name (the `INFO` of `C.out.INFO`).
    pub fn info(self) -> &'static str {
        match self {
            Command::Velocity => "velocity",
            Command::Grasp => "grasp",
            Command::Sound => "sound",
        }
    }

    /// The pattern of this output of every component of every PEIS (`*:*.out.INFO`).
    pub fn pattern(self) -> TuplePattern {
        // A constant, valid pattern; the fallback only keeps a panic out of the code.
        TuplePattern::parse(&format!("*:*.out.{}", self.info()))
            .unwrap_or_else(|_| TuplePattern::everything())
    }
}

/// Why a text of the world's contract could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("expected {expected}, found {found}")]
pub struct TextError {
    /// The form expected (`X Y THETA`).
    pub expected: &'static str,
    /// What was found, quoted and cut short.
    pub found: String,
}

impl TextError {
    fn new(expected: &'static str, found: &str) -> TextError {
        TextError {
            expected,
            found: quoted(found, 40),
        }
    }
}

/// Exactly `N` finite numbers separated by white space.
fn numbers<const N: usize>(text: &str) -> Option<[f64; N]> {
    if text.is_ascii() {
        numbers_ascii(text)
    } else {
        numbers_by_char(text)
    }
}

/// [`numbers`] of any text, split into words by `char`.
fn numbers_by_char<const N: usize>(text: &str) -> Option<[f64; N]> {
    let mut words = text.split_whitespace();
    let mut out = [0.0; N];
    for slot in &mut out {
        *slot = number(words.next()?).filter(|v| v.is_finite())?;
    }
    words.next().is_none().then_some(out)
}

/// Whether an ASCII byte is white space as `char::is_whitespace` says (vertical tab included,
/// which `u8::is_ascii_whitespace` leaves out).
fn ascii_space(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\n' | 0x0b | 0x0c | b'\r')
}

/// [`numbers`] of ASCII text, byte by byte: what every pose the world and the cameras write is,
/// and splitting it by `char` was most of reading it.
fn numbers_ascii<const N: usize>(text: &str) -> Option<[f64; N]> {
    let bytes = text.as_bytes();
    let mut at = 0;
    let mut out = [0.0; N];
    for slot in &mut out {
        while bytes.get(at).is_some_and(|&b| ascii_space(b)) {
            at += 1;
        }
        let start = at;
        while bytes.get(at).is_some_and(|&b| !ascii_space(b)) {
            at += 1;
        }
        // `at` stops at an ASCII byte or the end: a character boundary.
        let word = text.get(start..at).filter(|w| !w.is_empty())?;
        *slot = number(word).filter(|v| v.is_finite())?;
    }
    bytes[at..].iter().all(|&b| ascii_space(b)).then_some(out)
}

/// A number's text read as `str::parse` reads it, the same value to the last bit. Numbers as the
/// world and the components write them (`-12.345`: a sign, at most 15 digits, at most one point)
/// take a short way: the digits as an integer, divided by a power of ten, both exact in an `f64`,
/// so the division rounds the exact quotient once, as `parse` does. A building's ceiling cameras
/// write thousands of poses a second, and `parse` was a tenth of a large simulation's time.
fn number(word: &str) -> Option<f64> {
    const POWERS: [f64; 16] = [
        1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
    ];
    let (negative, digits) = match word.as_bytes() {
        [b'-', rest @ ..] => (true, rest),
        rest => (false, rest),
    };
    let mut mantissa: u64 = 0;
    let mut count = 0;
    let mut decimals = None;
    for (i, &b) in digits.iter().enumerate() {
        match b {
            b'0'..=b'9' if count < 15 => {
                mantissa = mantissa * 10 + u64::from(b - b'0');
                count += 1;
                if let Some(d) = decimals.as_mut() {
                    *d += 1;
                }
            }
            b'.' if decimals.is_none() && i > 0 && i + 1 < digits.len() => decimals = Some(0),
            _ => return word.parse().ok(),
        }
    }
    if count == 0 {
        return word.parse().ok();
    }
    // At most 15 digits: below 2^53, exact.
    #[allow(clippy::cast_precision_loss)]
    let value = mantissa as f64 / POWERS[decimals.unwrap_or(0)];
    Some(if negative { -value } else { value })
}

/// A 2-D pose: position in metres, heading in radians. Its text is `X Y THETA`.
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
    /// The form of a pose's text, for errors and causes.
    pub const FORM: &'static str = "X Y THETA (three numbers)";

    /// A pose.
    pub fn new(x: f64, y: f64, theta: f64) -> Pose {
        Pose { x, y, theta }
    }

    /// Distance to the point (x, y).
    pub fn distance_to(&self, x: f64, y: f64) -> f64 {
        (self.x - x).hypot(self.y - y)
    }

    /// Parses `X Y THETA`: exactly three finite numbers.
    pub fn parse(text: &str) -> Result<Pose, TextError> {
        let [x, y, theta] = numbers(text).ok_or_else(|| TextError::new(Pose::FORM, text))?;
        Ok(Pose { x, y, theta })
    }

    /// Appends the pose's text to `out`, as `Display` writes it, without formatting machinery:
    /// a building's ceiling camera writes a thousand poses into each image.
    pub fn push_to(&self, out: &mut String) {
        Fixed::<3>(self.x).push_to(out);
        out.push(' ');
        Fixed::<3>(self.y).push_to(out);
        out.push(' ');
        Fixed::<4>(self.theta).push_to(out);
    }
}

/// `X Y THETA`: millimetres and tenths of a milliradian.
impl fmt::Display for Pose {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} {} {}",
            Fixed::<3>(self.x),
            Fixed::<3>(self.y),
            Fixed::<4>(self.theta)
        )
    }
}

/// A number with `D` decimals, rounded half away from zero; what `{:.D}` writes, but through
/// integers: the exact float-to-decimal conversion behind `{:.D}` was a tenth of a large
/// simulation's time, whose ceiling cameras write the poses of every robot 20 times a second.
/// A value too large for that (over 10^15 scaled) is written by `{:.D}`; zero is never negative.
struct Fixed<const D: u32>(f64);

impl<const D: u32> Fixed<D> {
    /// The text, written into `text`; `None` when the value is too large for integers.
    fn short<'t>(&self, text: &'t mut [u8; 24]) -> Option<&'t str> {
        let unit = 10u64.pow(D);
        let scaled = (self.0 * unit as f64).round();
        if !scaled.is_finite() || scaled.abs() >= 1e15 {
            return None;
        }
        let n = scaled as i64;
        // The digits from the last, into a buffer long enough for a sign, 15 digits and a point.
        let mut at = text.len();
        let mut put = |byte: u8| {
            at -= 1;
            text[at] = byte;
        };
        let mut m = n.unsigned_abs();
        let digit = |m: u64| b'0' + u8::try_from(m % 10).unwrap_or(0);
        if D == 0 {
            put(b'0');
        }
        for _ in 0..D {
            put(digit(m));
            m /= 10;
        }
        put(b'.');
        loop {
            put(digit(m));
            m /= 10;
            if m == 0 {
                break;
            }
        }
        if n < 0 {
            put(b'-');
        }
        std::str::from_utf8(&text[at..]).ok()
    }

    /// Writes the text to `out`: a `String` directly, or a formatter for `Display`.
    fn write_to(&self, out: &mut impl Write) -> fmt::Result {
        let mut text = [0u8; 24];
        match self.short(&mut text) {
            Some(short) => out.write_str(short),
            None => write!(out, "{:.*}", D as usize, self.0),
        }
    }

    /// Appends the text to `out`, as `Display` writes it, without formatting machinery for the
    /// values that fit in integers.
    fn push_to(&self, out: &mut String) {
        // Writing into a `String` cannot fail.
        let _ = self.write_to(out);
    }
}

impl<const D: u32> fmt::Display for Fixed<D> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.write_to(f)
    }
}

/// A position in metres. Its text is `X Y`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    /// x, metres.
    pub x: f64,
    /// y, metres.
    pub y: f64,
}

impl Point {
    /// The form of a point's text, for errors and causes.
    pub const FORM: &'static str = "X Y (two numbers)";

    /// A point.
    pub fn new(x: f64, y: f64) -> Point {
        Point { x, y }
    }

    /// Parses `X Y`: exactly two finite numbers.
    pub fn parse(text: &str) -> Result<Point, TextError> {
        let [x, y] = numbers(text).ok_or_else(|| TextError::new(Point::FORM, text))?;
        Ok(Point { x, y })
    }
}

/// `X Y`, in millimetres.
impl fmt::Display for Point {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} {}", Fixed::<3>(self.x), Fixed::<3>(self.y))
    }
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

/// The map: rooms and the doors between them. Its text is `room NAME X0 Y0 X1 Y1; door A B X Y; …`
/// (rooms first, numbers as Rust writes an `f64`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Map {
    /// The rooms.
    pub rooms: Vec<Room>,
    /// The doors.
    pub doors: Vec<Door>,
}

impl Map {
    /// The form of a map's item, for errors.
    pub const FORM: &'static str = "room NAME X0 Y0 X1 Y1 or door A B X Y";

    /// The room called `name`.
    pub fn room(&self, name: &str) -> Option<&Room> {
        self.rooms.iter().find(|r| r.name == name)
    }

    /// The room at (x, y): the first that contains it, or, within 0.2 m of a wall (the width of a
    /// door frame), the nearest.
    ///
    /// This is part of the contract, not of one reader: the simulator's sensors, its replanner
    /// (a pose as `(at R ROOM)`) and the live view must name the same room for the same pose.
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

    /// [`Map::parse`], shared: the map the last call in this process read, when `text` is the
    /// same (every robot's host and every camera of a simulated building reads the world's one
    /// map, a thousand rooms' worth of numbers each time).
    pub fn parse_shared(text: &str) -> Result<Arc<Map>, TextError> {
        static LAST: Mutex<Option<(String, Arc<Map>)>> = Mutex::new(None);
        let mut last = LAST.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some((read, map)) = last.as_ref()
            && read == text
        {
            return Ok(map.clone());
        }
        let map = Arc::new(Map::parse(text)?);
        *last = Some((text.to_string(), map.clone()));
        Ok(map)
    }

    /// Parses the map's text: every item (between `;`) a room or a door, every number finite.
    /// The empty text is the empty map.
    pub fn parse(text: &str) -> Result<Map, TextError> {
        let mut map = Map::default();
        for item in text.split(';').map(str::trim).filter(|s| !s.is_empty()) {
            let bad = || TextError::new(Map::FORM, item);
            let words: Vec<&str> = item.split_whitespace().collect();
            match words.as_slice() {
                ["room", name, rest @ ..] if rest.len() == 4 => {
                    let [x0, y0, x1, y1] = numbers(&rest.join(" ")).ok_or_else(bad)?;
                    map.rooms.push(Room {
                        name: (*name).to_string(),
                        x0,
                        y0,
                        x1,
                        y1,
                    });
                }
                ["door", a, b, rest @ ..] if rest.len() == 2 => {
                    let [x, y] = numbers(&rest.join(" ")).ok_or_else(bad)?;
                    map.doors.push(Door {
                        a: (*a).to_string(),
                        b: (*b).to_string(),
                        x,
                        y,
                    });
                }
                _ => return Err(bad()),
            }
        }
        Ok(map)
    }
}

/// The map's text: items separated by `; `, no separator after the last.
impl fmt::Display for Map {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut separator = "";
        for r in &self.rooms {
            write!(
                f,
                "{separator}room {} {} {} {} {}",
                r.name, r.x0, r.y0, r.x1, r.y1
            )?;
            separator = "; ";
        }
        for d in &self.doors {
            write!(f, "{separator}door {} {} {} {}", d.a, d.b, d.x, d.y)?;
            separator = "; ";
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::strategy::Strategy as _;

    /// The PEIS-Home's map as its world publishes it.
    const PEIS_HOME: &str = "room living-room 0 0 3 3; room kitchen 3 0 5 3; \
        room entrance 2.5 3 5 5; room bedroom 0 3 2.5 5; door living-room kitchen 3 1.5; \
        door living-room entrance 2.75 3; door entrance bedroom 2.5 4";

    #[test]
    fn every_world_key_reads_back_as_itself() {
        let keys = [
            WorldKey::Map,
            WorldKey::RobotPose("astrid"),
            WorldKey::ThingAt("newspaper"),
            WorldKey::ThingHolder("newspaper"),
            WorldKey::ResidentState("johanna"),
            WorldKey::ResidentAt("johanna"),
        ];
        let texts: Vec<String> = keys.iter().map(ToString::to_string).collect();
        assert_eq!(
            texts,
            [
                "map",
                "robots.astrid.pose",
                "things.newspaper.at",
                "things.newspaper.holder",
                "residents.johanna.state",
                "residents.johanna.at"
            ]
        );
        for (key, text) in keys.iter().zip(&texts) {
            assert_eq!(WorldKey::parse(text), Some(*key));
            assert_eq!(key.key().map(|k| k.to_string()).as_ref(), Ok(text));
        }
        for other in [
            "",
            "maps",
            "robots.pose",
            "robots..pose",
            "robots.a.b.pose",
            "things.t.where",
            "people.h.state",
            "astrid.out.velocity",
        ] {
            assert_eq!(WorldKey::parse(other), None, "{other:?}");
        }
        assert!(WorldKey::RobotPose("<b>").key().is_err());
    }

    #[test]
    fn the_patterns_are_the_world_and_the_commands() {
        assert_eq!(world_pattern().to_string(), "world:**");
        let commands = [Command::Velocity, Command::Grasp, Command::Sound];
        let patterns: Vec<String> = commands.iter().map(|c| c.pattern().to_string()).collect();
        assert_eq!(
            patterns,
            ["*:*.out.velocity", "*:*.out.grasp", "*:*.out.sound"]
        );
    }

    #[test]
    fn a_pose_and_a_point_round_trip_through_their_text() {
        let pose = Pose::new(3.7, 4.0, std::f64::consts::PI);
        assert_eq!(pose.to_string(), "3.700 4.000 3.1416");
        // Millimetres and four decimals of a heading: what is read back is that close.
        let back = Pose::parse(&pose.to_string()).expect("parses");
        assert_eq!((back.x, back.y), (3.7, 4.0));
        assert!((back.theta - pose.theta).abs() < 1e-4, "{back:?}");
        assert_eq!(back.to_string(), pose.to_string());
        assert_eq!(Pose::parse("  1 2\t3 "), Ok(Pose::new(1.0, 2.0, 3.0)));
        assert_eq!(Point::new(4.2, 4.3).to_string(), "4.200 4.300");
        assert_eq!(Point::parse("4.200 4.300"), Ok(Point::new(4.2, 4.3)));
        for bad in ["", "here", "1 2", "1 2 3 4", "1 x 3", "NaN 1 1", "1 inf 1"] {
            let error = Pose::parse(bad).expect_err(bad);
            assert_eq!(error.expected, Pose::FORM);
        }
        for bad in ["", "1", "1 2 3", "1 NaN"] {
            assert!(Point::parse(bad).is_err(), "{bad:?}");
        }
        assert_eq!(
            Pose::parse("1,2;3").map_err(|e| e.to_string()),
            Err("expected X Y THETA (three numbers), found \"1,2;3\"".to_string())
        );
    }

    #[test]
    fn the_map_text_round_trips_and_bad_text_is_an_error() {
        let map = Map::parse(PEIS_HOME).expect("parses");
        assert_eq!(map.to_string(), PEIS_HOME);
        assert_eq!((map.rooms.len(), map.doors.len()), (4, 3));
        assert_eq!(map.rooms[2].name, "entrance");
        assert_eq!((map.doors[2].x, map.doors[2].y), (2.5, 4.0));
        assert_eq!(map.room("kitchen").map(Room::centre), Some((4.0, 1.5)));
        // Rooms come first whatever the order read; the empty map is the empty text.
        let mixed = Map::parse("door a b 1 2; room a 0 0 1.5 1").expect("parses");
        assert_eq!(mixed.to_string(), "room a 0 0 1.5 1; door a b 1 2");
        assert_eq!(Map::parse(""), Ok(Map::default()));
        // Shared: the same text gives the same map, read once; another text its own.
        let shared = Map::parse_shared(PEIS_HOME).expect("parses");
        assert_eq!(*shared, map);
        assert!(Arc::ptr_eq(
            &shared,
            &Map::parse_shared(PEIS_HOME).expect("parses")
        ));
        assert_eq!(*Map::parse_shared("").expect("parses"), Map::default());
        assert!(Map::parse_shared("room a 0 0 1").is_err());
        assert_eq!(Map::default().to_string(), "");
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
            assert!(Map::parse(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn the_room_of_a_position_is_the_room_containing_it_or_the_nearest_within_a_door_frame() {
        let map = Map::parse(PEIS_HOME).expect("parses");
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

    #[test]
    fn numbers_are_written_with_their_decimals() {
        assert_eq!(Pose::new(1.0, 2.0, 0.0).to_string(), "1.000 2.000 0.0000");
        assert_eq!(
            Pose::new(-0.25, 12.3456, -2.5).to_string(),
            "-0.250 12.346 -2.5000"
        );
        assert_eq!(
            Pose::new(-0.0001, 0.0, -0.00001).to_string(),
            "0.000 0.000 0.0000"
        );
        assert_eq!(
            Point::new(1e20, -2.0).to_string(),
            format!("{:.3} -2.000", 1e20)
        );
    }

    proptest::proptest! {
        /// The text is `{:.3}`'s but for the rounding of a last digit (half away from zero, of the
        /// scaled value), and reads back within half a unit of that digit.
        #[test]
        fn a_pose_is_written_as_format_writes_it(
            x in -1e6f64..1e6,
            y in -1e6f64..1e6,
            theta in -7.0f64..7.0,
        ) {
            let text = Pose::new(x, y, theta).to_string();
            let back = Pose::parse(&text).expect("reads back");
            proptest::prop_assert!((back.x - x).abs() <= 0.0005 + 1e-9);
            proptest::prop_assert!((back.y - y).abs() <= 0.0005 + 1e-9);
            proptest::prop_assert!((back.theta - theta).abs() <= 0.00005 + 1e-9);
            let words: Vec<&str> = text.split(' ').collect();
            let exact = [
                (format!("{x:.3}"), 0.001),
                (format!("{y:.3}"), 0.001),
                (format!("{theta:.4}"), 0.0001),
            ];
            proptest::prop_assert_eq!(words.len(), 3);
            for (word, (exact, unit)) in words.iter().zip(&exact) {
                proptest::prop_assert_eq!(
                    word.split_once('.').map(|(_, d)| d.len()),
                    exact.split_once('.').map(|(_, d)| d.len())
                );
                let (a, b): (f64, f64) = (word.parse().expect("a number"), exact.parse().expect("a number"));
                proptest::prop_assert!((a - b).abs() <= unit + 1e-9, "{word} against {exact}");
            }
        }
    }

    proptest::proptest! {
        /// A number's text reads as `str::parse` reads it, to the last bit, on the short way
        /// (plain decimals) and off it (exponents, `+`, `.5`, `inf`, junk).
        #[test]
        fn a_number_reads_as_parse_reads_it(
            value in -1e9f64..1e9,
            decimals in 0usize..7,
            other in "[-+.0-9eEinfa]{1,12}",
        ) {
            let text = format!("{value:.decimals$}");
            proptest::prop_assert_eq!(
                number(&text).map(f64::to_bits),
                text.parse::<f64>().ok().map(f64::to_bits),
                "{}", text
            );
            proptest::prop_assert_eq!(
                number(&other).map(f64::to_bits),
                other.parse::<f64>().ok().map(f64::to_bits),
                "{}", other
            );
        }
    }

    proptest::proptest! {
        /// A pose appended to a string reads as its `Display`, large values and zeros too.
        #[test]
        fn a_pose_pushed_is_its_display(
            x in proptest::prop_oneof![-1e4f64..1e4, proptest::strategy::Just(-0.0), proptest::strategy::Just(1e300), proptest::strategy::Just(-2e12)],
            y in -1e4f64..1e4,
            theta in -4f64..4.0,
        ) {
            let pose = Pose::new(x, y, theta);
            let mut pushed = String::from("a ");
            pose.push_to(&mut pushed);
            proptest::prop_assert_eq!(pushed, format!("a {pose}"));
        }
    }

    proptest::proptest! {
        /// Three numbers in ASCII text, read byte by byte, read as splitting the text by `char`
        /// reads them, with any white space (the vertical tab too) and around non-ASCII text.
        #[test]
        fn numbers_read_byte_by_byte_as_by_char(
            text in proptest::prop_oneof![
                "[-0-9. \t\n\u{b}\u{c}\rxe\u{a0}\u{85}]{0,24}",
                (
                    proptest::collection::vec("[ \t\n\u{b}\u{c}\r\u{a0}]{0,2}", 4),
                    proptest::collection::vec(-1e4f64..1e4, 3),
                ).prop_map(|(spaces, values)| {
                    let mut text = spaces[0].clone();
                    for (value, space) in values.iter().zip(&spaces[1..]) {
                        text.push_str(&format!("{value:.3}"));
                        text.push_str(if space.is_empty() { " " } else { space });
                    }
                    text
                }),
            ],
        ) {
            let bits = |n: Option<[f64; 3]>| n.map(|n| n.map(f64::to_bits));
            proptest::prop_assert_eq!(
                bits(numbers::<3>(&text)),
                bits(numbers_by_char::<3>(&text)),
                "{:?}",
                text
            );
        }
    }

    #[test]
    fn numbers_on_and_off_the_short_way_read_as_parse_reads_them() {
        for text in [
            "0",
            "-0",
            "0.000",
            "-0.000",
            "1.5",
            "12345.678",
            "999999999999999",
            "9999999999999999",
            "1.0000000000000001",
            "1e3",
            "+1",
            ".5",
            "5.",
            "1..2",
            "-",
            "",
            "inf",
            "NaN",
            "0.1",
            "0.3",
            "-2.5000",
        ] {
            assert_eq!(
                number(text).map(f64::to_bits),
                text.parse::<f64>().ok().map(f64::to_bits),
                "{text:?}"
            );
        }
    }
}
