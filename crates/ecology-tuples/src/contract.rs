//! The tuple keys of the component contract (docs/components.md), spelt once for the PEIS runtime and the executive.
//!
//! A PEIS's init component publishes `components.C.type`, `.cost` and `.currState` and takes
//! `components.C.reqState`; each component publishes `C.status` and `C.cause` (and, when it senses,
//! `C.observed`), takes `C.params`,
//! writes its outputs as `C.out.INFO` and reads its inputs through `C.mi-INFO` meta-tuples.
//! Building these keys from a [`ComponentField`] makes a misspelt one a compile error.

use crate::name::{ComponentId, Key, ValidationError};

/// One tuple of the contract that names a component and a fixed field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ComponentField {
    /// `components.C.type`: the component's type (init component).
    Type,
    /// `components.C.cost`: its cost (init component).
    Cost,
    /// `components.C.currState`: `on` or `off` (init component).
    CurrState,
    /// `components.C.reqState`: `on` or `off`, as asked by remote set.
    ReqState,
    /// `components.C.holders`: who holds the component (see [`crate::claims`]), names separated
    /// by spaces; empty or absent when it is free (init component).
    Holders,
    /// `C.status`: `initializing`, `idle`, `running`, `waiting`, `done` or `error`.
    Status,
    /// `C.cause`: why the component reports what it does.
    Cause,
    /// `C.params`: the functionality instance it runs (empty: none).
    Params,
    /// `C.observed`: what a sensing component saw, as literals over the
    /// domain's predicates (`(thing-at newspaper kitchen)`,
    /// `(not (thing-at newspaper entrance))`).
    Observed,
    /// `components.C.covers`: the places a sensor sees, such as the rooms a ceiling camera is
    /// mounted over, names separated by spaces (init component). Optional: a component that does
    /// not say is not known to cover any place.
    Covers,
}

impl ComponentField {
    const ALL: [ComponentField; 10] = [
        ComponentField::Type,
        ComponentField::Cost,
        ComponentField::CurrState,
        ComponentField::ReqState,
        ComponentField::Holders,
        ComponentField::Status,
        ComponentField::Cause,
        ComponentField::Params,
        ComponentField::Observed,
        ComponentField::Covers,
    ];

    /// The last segment of the key.
    pub fn name(self) -> &'static str {
        match self {
            ComponentField::Type => "type",
            ComponentField::Cost => "cost",
            ComponentField::CurrState => "currState",
            ComponentField::ReqState => "reqState",
            ComponentField::Holders => "holders",
            ComponentField::Status => "status",
            ComponentField::Cause => "cause",
            ComponentField::Params => "params",
            ComponentField::Observed => "observed",
            ComponentField::Covers => "covers",
        }
    }

    /// Whether the init component owns the field (`components.C.FIELD`) rather than the component (`C.FIELD`).
    fn of_init(self) -> bool {
        matches!(
            self,
            ComponentField::Type
                | ComponentField::Cost
                | ComponentField::CurrState
                | ComponentField::ReqState
                | ComponentField::Holders
                | ComponentField::Covers
        )
    }

    /// The key of this field of `component`.
    pub fn key(self, component: &ComponentId) -> Key {
        let text = if self.of_init() {
            format!("components.{component}.{}", self.name())
        } else {
            format!("{component}.{}", self.name())
        };
        // A component name is one segment short enough for the longest field
        // (`MAX_COMPONENT_LEN`), so the key is valid by construction.
        Key::from_checked(text)
    }

    /// The component and field `key` is, when it is one of the contract's fixed fields.
    pub fn parse(key: &Key) -> Option<(ComponentId, ComponentField)> {
        let (component, field) = ComponentField::parse_str(key.as_str())?;
        Some((ComponentId::new(component).ok()?, field))
    }

    /// The component's name and the field `key` is, when it is one of the contract's fixed
    /// fields; the name is not checked (a reader that knows the component already skips that).
    pub fn parse_str(key: &str) -> Option<(&str, ComponentField)> {
        let (of_init, rest) = match key.strip_prefix("components.") {
            Some(rest) => (true, rest),
            None => (false, key),
        };
        let (component, field) = rest.split_once('.')?;
        let field = ComponentField::ALL
            .into_iter()
            .find(|f| f.of_init() == of_init && f.name() == field)?;
        Some((component, field))
    }
}

/// The key `C.out.INFO` where `component` writes its output `info`.
pub fn output_key(component: &ComponentId, info: &str) -> Result<Key, ValidationError> {
    Key::new(&format!("{component}.out.{info}"))
}

/// The meta-tuple key `C.mi-INFO` through which `component` reads its input
/// `info`; `args` tell apart two inputs of the same kind (`C.mi-INFO.ARG…`).
pub fn input_key(
    component: &ComponentId,
    info: &str,
    args: &[&str],
) -> Result<Key, ValidationError> {
    if args.is_empty() {
        Key::new(&format!("{component}.mi-{info}"))
    } else {
        Key::new(&format!("{component}.mi-{info}.{}", args.join(".")))
    }
}

/// The first segment of a room key ([`room_key`]).
pub const ROOMS: &str = "rooms";

/// The key `rooms.ROOM.C` by which a PEIS says that its `component` covers `room` (the same
/// places as its `components.C.covers`, a key each): an executive asks who covers a room with one
/// wildcard question (`*:rooms.ROOM.*`, [`room_pattern`]) instead of reading every PEIS's
/// directory. Its value is the component's type.
pub fn room_key(room: &str, component: &ComponentId) -> Result<Key, ValidationError> {
    Key::new(&format!("{ROOMS}.{room}.{component}"))
}

/// The room and the component a room key `rooms.ROOM.C` names; `None` for any other key.
pub fn parse_room_key(key: &str) -> Option<(&str, &str)> {
    let (room, component) = key
        .strip_prefix(ROOMS)?
        .strip_prefix('.')?
        .split_once('.')?;
    (!room.is_empty() && !component.is_empty() && !component.contains('.'))
        .then_some((room, component))
}

/// Every PEIS's room keys for `room` (`*:rooms.ROOM.*`): who covers it.
pub fn room_pattern(room: &str) -> Result<crate::TuplePattern, ValidationError> {
    crate::TuplePattern::parse(&format!("*:{ROOMS}.{room}.*"))
}

/// Whether the contract lets a remote set write `data` to `key`: `components.C.reqState` takes
/// only `on` or `off` (white space around them aside); every other key any value. A PEIS refuses
/// the request with the reason, so the asker learns at once, instead of a value that changes
/// nothing.
pub fn check_request(key: &Key, data: &[u8]) -> Result<(), String> {
    if let Some((_, ComponentField::ReqState)) = ComponentField::parse(key) {
        let text = std::str::from_utf8(data).unwrap_or("").trim();
        if text != "on" && text != "off" {
            let shown = String::from_utf8_lossy(data);
            return Err(format!(
                "{key} must be on or off, not {}",
                quoted(&shown, 40)
            ));
        }
    }
    Ok(())
}

/// The word that starts the cause of a consumer that cannot read an input.
const UNREADABLE: &str = "unreadable";

/// The `C.cause` of a consumer that reports `waiting` because the value of
/// its input `input` (the meta-tuple key's suffix after `mi-`: `global-pos`,
/// or `image.left` for one of two images) cannot be read:
/// `unreadable global-pos: expected X Y THETA, found "1,2;3"`. The executive
/// blames the input's producer, not the consumer.
pub fn unreadable_cause(input: &str, detail: &str) -> String {
    format!("{UNREADABLE} {input}: {detail}")
}

/// The input and the detail of an [`unreadable_cause`]; `None` for any other cause.
pub fn parse_unreadable(cause: &str) -> Option<(&str, &str)> {
    let rest = cause.trim().strip_prefix(UNREADABLE)?;
    let rest = rest.strip_prefix(char::is_whitespace)?.trim_start();
    let (input, detail) = rest.split_once(':').unwrap_or((rest, ""));
    let input = input.trim();
    (!input.is_empty() && !input.contains(char::is_whitespace)).then_some((input, detail.trim()))
}

/// How a value shows in a cause: quoted, with control characters escaped,
/// cut to `max` characters (`…` marks the cut), so a cause stays one short line
/// whatever a producer wrote.
pub fn quoted(value: &str, max: usize) -> String {
    let mut out = String::from("\"");
    for (i, ch) in value.chars().enumerate() {
        if i == max {
            out.push('…');
            break;
        }
        out.extend(ch.escape_debug());
    }
    out.push('"');
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unreadable_cause_names_its_input() {
        let cause = unreadable_cause("global-pos", "expected X Y THETA, found \"1,2;3\"");
        assert_eq!(
            cause,
            "unreadable global-pos: expected X Y THETA, found \"1,2;3\""
        );
        assert_eq!(
            parse_unreadable(&cause),
            Some(("global-pos", "expected X Y THETA, found \"1,2;3\""))
        );
        assert_eq!(
            parse_unreadable("  unreadable image.left  "),
            Some(("image.left", ""))
        );
        assert_eq!(parse_unreadable("global-pos"), None);
        assert_eq!(parse_unreadable("unreadable"), None);
        assert_eq!(parse_unreadable("unreadables x: y"), None);
        assert_eq!(parse_unreadable("unreadable a b: c"), None);
    }

    #[test]
    fn a_room_key_names_the_room_and_the_component() {
        let ca1 = ComponentId::new("ca1").expect("a name");
        let key = room_key("living-room", &ca1).expect("a key");
        assert_eq!(key.as_str(), "rooms.living-room.ca1");
        assert_eq!(parse_room_key(key.as_str()), Some(("living-room", "ca1")));
        let pattern = room_pattern("living-room").expect("a pattern");
        assert!(pattern.matches(&crate::PeisId::new("hsm").expect("a name"), &key));
        let elsewhere = room_key("kitchen", &ca1).expect("a key");
        assert!(!pattern.matches(&crate::PeisId::new("hsm").expect("a name"), &elsewhere));
        for other in [
            "rooms",
            "rooms.kitchen",
            "rooms..ca1",
            "rooms.kitchen.",
            "rooms.a.b.c",
            "ca1.out.x",
        ] {
            assert_eq!(parse_room_key(other), None, "{other}");
        }
        assert!(room_key("no room", &ca1).is_err());
        assert!(room_pattern("no room").is_err());
    }

    #[test]
    fn req_state_takes_on_or_off_only() {
        let req = Key::new("components.l1.reqState").expect("key");
        assert_eq!(check_request(&req, b"on"), Ok(()));
        assert_eq!(check_request(&req, b" off\n"), Ok(()));
        assert_eq!(
            check_request(&req, b"restart"),
            Err("components.l1.reqState must be on or off, not \"restart\"".to_string())
        );
        assert!(check_request(&req, b"").is_err());
        let other = Key::new("l1.params").expect("key");
        assert_eq!(check_request(&other, b"anything"), Ok(()));
    }

    #[test]
    fn a_quoted_value_is_short_and_on_one_line() {
        assert_eq!(quoted("1,2;3", 10), "\"1,2;3\"");
        assert_eq!(quoted("a\nb", 10), "\"a\\nb\"");
        assert_eq!(quoted("abcdef", 3), "\"abc…\"");
    }
}
