//! Owner and key patterns: `*` matches one key segment (or any owner), `**` any number of segments.

use std::fmt;

use crate::name::{Key, MAX_NAME_LEN, PeisId, ValidationError};

/// One segment of a [`KeyPattern`].
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub enum Segment {
    /// Exactly this segment.
    Exact(Box<str>),
    /// `*`: any one segment.
    One,
    /// `**`: any number of segments, including none.
    Any,
}

/// A dotted key pattern such as `components.*.status` or `tc1.**`.
#[derive(Clone, PartialEq, Eq, Hash)]
pub struct KeyPattern {
    segments: Vec<Segment>,
}

impl KeyPattern {
    /// Parses a key pattern: dotted segments, each `*`, `**` or a key segment.
    pub fn new(pattern: &str) -> Result<Self, ValidationError> {
        let fail = |reason| ValidationError::Pattern {
            pattern: pattern.to_owned(),
            reason,
        };
        if pattern.is_empty() {
            return Err(fail("it is empty"));
        }
        if pattern.len() > MAX_NAME_LEN {
            return Err(fail("it is longer than 255 bytes"));
        }
        let mut segments = Vec::new();
        for segment in pattern.split('.') {
            let parsed = match segment {
                "" => return Err(fail("a segment between dots is empty")),
                "*" => Segment::One,
                "**" => Segment::Any,
                s if s.contains('*') => {
                    return Err(fail("'*' and '**' must be whole segments"));
                }
                s => {
                    Key::new(s)
                        .map_err(|_| fail("segments may only hold letters, digits, '-' and '_'"))?;
                    Segment::Exact(s.into())
                }
            };
            // `**.**` means the same as `**`; keep one so every pattern has one canonical form.
            if parsed == Segment::Any && segments.last() == Some(&Segment::Any) {
                continue;
            }
            segments.push(parsed);
        }
        Ok(Self { segments })
    }

    /// The pattern matching exactly `key`.
    pub fn exact(key: &Key) -> Self {
        Self {
            segments: key.segments().map(|s| Segment::Exact(s.into())).collect(),
        }
    }

    /// The pattern matching every key (`**`).
    pub fn any() -> Self {
        Self {
            segments: vec![Segment::Any],
        }
    }

    /// The segments of the pattern.
    pub fn segments(&self) -> &[Segment] {
        &self.segments
    }

    /// The key this pattern matches if it has no wildcard.
    pub fn as_exact(&self) -> Option<Key> {
        if self.segments.iter().all(|s| matches!(s, Segment::Exact(_))) {
            Key::new(&self.to_string()).ok()
        } else {
            None
        }
    }

    /// Whether `key` matches the pattern.
    pub fn matches(&self, key: &Key) -> bool {
        // A pattern that ends in a segment of its own matches only keys that end in it, and most
        // keys a space tries against a PEIS's patterns (`components.*.reqState`, `*.params`) end
        // otherwise: told from the end of the key, without walking it.
        if let Some(Segment::Exact(last)) = self.segments.last() {
            let (key, last) = (key.as_str().as_bytes(), last.as_bytes());
            let Some(head) = key.len().checked_sub(last.len()) else {
                return false;
            };
            if &key[head..] != last || (head > 0 && key[head - 1] != b'.') {
                return false;
            }
        }
        match_segments(&self.segments, key.as_str())
    }
}

/// Splits the first segment off a dotted remainder.
fn split_first(rest: &str) -> (&str, Option<&str>) {
    match rest.split_once('.') {
        Some((first, tail)) => (first, Some(tail)),
        None => (rest, None),
    }
}

/// Glob matching over segments without allocating: `**` is the backtracking star, `*` matches one segment.
fn match_segments(pattern: &[Segment], key: &str) -> bool {
    let mut p = 0;
    let mut rest = Some(key);
    let mut star: Option<(usize, Option<&str>)> = None;
    loop {
        if p < pattern.len() && pattern[p] == Segment::Any {
            p += 1;
            star = Some((p, rest));
            continue;
        }
        match rest {
            None if p == pattern.len() => return true,
            None => {}
            Some(r) => {
                let (segment, tail) = split_first(r);
                let step = match pattern.get(p) {
                    Some(Segment::One) => true,
                    Some(Segment::Exact(s)) => **s == *segment,
                    Some(Segment::Any) | None => false,
                };
                if step {
                    p += 1;
                    rest = tail;
                    continue;
                }
            }
        }
        // Mismatch: let the last `**` swallow one more segment, if there is one.
        match star {
            Some((after_star, Some(r))) => {
                let (_, tail) = split_first(r);
                star = Some((after_star, tail));
                p = after_star;
                rest = tail;
            }
            _ => return false,
        }
    }
}

impl fmt::Display for KeyPattern {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, s) in self.segments.iter().enumerate() {
            if i > 0 {
                f.write_str(".")?;
            }
            match s {
                Segment::Exact(s) => f.write_str(s)?,
                Segment::One => f.write_str("*")?,
                Segment::Any => f.write_str("**")?,
            }
        }
        Ok(())
    }
}

impl fmt::Debug for KeyPattern {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "KeyPattern({self})")
    }
}

impl std::str::FromStr for KeyPattern {
    type Err = ValidationError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::new(s)
    }
}

/// Which owners a subscription covers: one PEIS or any (`*`).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub enum OwnerPattern {
    /// Tuples of this PEIS only.
    Exact(PeisId),
    /// Tuples of any PEIS (`*` or `**`).
    Any,
}

impl OwnerPattern {
    /// Parses `*`, `**` or a PEIS name.
    pub fn new(pattern: &str) -> Result<Self, ValidationError> {
        match pattern {
            "*" | "**" => Ok(Self::Any),
            name => PeisId::new(name)
                .map(Self::Exact)
                .map_err(|_| ValidationError::Pattern {
                    pattern: pattern.to_owned(),
                    reason: "an owner pattern is '*' or a PEIS name",
                }),
        }
    }

    /// Whether `owner` matches.
    pub fn matches(&self, owner: &PeisId) -> bool {
        match self {
            Self::Exact(id) => id == owner,
            Self::Any => true,
        }
    }
}

impl fmt::Display for OwnerPattern {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Exact(id) => write!(f, "{id}"),
            Self::Any => f.write_str("*"),
        }
    }
}

/// An owner pattern and a key pattern, written `OWNER:KEY` (for example `*:components.*.status`).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct TuplePattern {
    /// Which owners.
    pub owner: OwnerPattern,
    /// Which keys.
    pub key: KeyPattern,
}

impl TuplePattern {
    /// The pattern matching exactly tuple (owner, key).
    pub fn exact(owner: PeisId, key: &Key) -> Self {
        Self {
            owner: OwnerPattern::Exact(owner),
            key: KeyPattern::exact(key),
        }
    }

    /// The pattern matching every tuple (`*:**`).
    pub fn everything() -> Self {
        Self {
            owner: OwnerPattern::Any,
            key: KeyPattern::any(),
        }
    }

    /// Parses `OWNER:KEYPATTERN`; without a colon, the text is a key pattern for any owner.
    pub fn parse(text: &str) -> Result<Self, ValidationError> {
        match text.split_once(':') {
            Some((owner, key)) => Ok(Self {
                owner: OwnerPattern::new(owner)?,
                key: KeyPattern::new(key)?,
            }),
            None => Ok(Self {
                owner: OwnerPattern::Any,
                key: KeyPattern::new(text)?,
            }),
        }
    }

    /// Whether tuple (owner, key) matches.
    pub fn matches(&self, owner: &PeisId, key: &Key) -> bool {
        self.owner.matches(owner) && self.key.matches(key)
    }
}

impl fmt::Display for TuplePattern {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.owner, self.key)
    }
}

impl std::str::FromStr for TuplePattern {
    type Err = ValidationError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::parse(s)
    }
}
