//! Names of the tuple model (PEIS names, dotted keys, component names, mimetypes) and the errors of validating them.

use std::borrow::Borrow;
use std::fmt;
use std::sync::Arc;

/// Longest PEIS name, key or pattern accepted, in bytes.
pub const MAX_NAME_LEN: usize = 255;

/// Whether `c` may appear in a PEIS name or a key segment.
fn is_name_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '-' || c == '_'
}

/// What every name type shares: `as_str`, `Display` and `Debug` as its text,
/// `FromStr` through its validating `new`, and `Borrow<str>` (names hash and
/// compare as their text, so maps keyed by them can be looked up by `&str`).
macro_rules! text_name {
    ($name:ident) => {
        impl $name {
            /// The name as text.
            pub fn as_str(&self) -> &str {
                &self.0
            }

            /// The name's text, shared: a clone of it copies no text.
            pub fn shared(&self) -> &Arc<str> {
                &self.0
            }
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(&self.0)
            }
        }

        impl fmt::Debug for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                fmt::Debug::fmt(&*self.0, f)
            }
        }

        impl std::str::FromStr for $name {
            type Err = ValidationError;
            fn from_str(s: &str) -> Result<Self, Self::Err> {
                Self::new(s)
            }
        }

        impl Borrow<str> for $name {
            fn borrow(&self) -> &str {
                &self.0
            }
        }
    };
}

text_name!(PeisId);
text_name!(ComponentId);
text_name!(Key);
text_name!(Mimetype);

/// What is wrong with `name` as a PEIS or component name of at most `max` bytes.
fn name_problem(name: &str, max: usize, too_long: &'static str) -> Option<&'static str> {
    if name.is_empty() {
        Some("it is empty")
    } else if name.len() > max {
        Some(too_long)
    } else if !name.chars().all(is_name_char) {
        Some("only letters, digits, '-' and '_' are allowed")
    } else {
        None
    }
}

/// The name of a PEIS, such as `astrid`: 1 to 255 characters from `[A-Za-z0-9_-]`.
///
/// Cloning is cheap (a reference count).
#[derive(Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct PeisId(Arc<str>);

impl PeisId {
    /// Validates `name` as a PEIS name.
    pub fn new(name: &str) -> Result<Self, ValidationError> {
        match name_problem(name, MAX_NAME_LEN, "it is longer than 255 bytes") {
            Some(reason) => Err(ValidationError::PeisId {
                name: name.to_owned(),
                reason,
            }),
            None => Ok(Self(name.into())),
        }
    }
}

/// A dotted tuple key such as `components.l1.status`: non-empty segments of `[A-Za-z0-9_-]`, at most 255 bytes.
///
/// Cloning is cheap (a reference count).
#[derive(Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Key(Arc<str>);

impl Key {
    /// Validates `key` as a dotted key.
    pub fn new(key: &str) -> Result<Self, ValidationError> {
        let reason = if key.is_empty() {
            Some("it is empty")
        } else if key.len() > MAX_NAME_LEN {
            Some("it is longer than 255 bytes")
        } else if key.split('.').any(str::is_empty) {
            Some("a segment between dots is empty")
        } else if !key.split('.').all(|s| s.chars().all(is_name_char)) {
            Some("segments may only hold letters, digits, '-' and '_'")
        } else {
            None
        };
        match reason {
            Some(reason) => Err(ValidationError::Key {
                key: key.to_owned(),
                reason,
            }),
            None => Ok(Self(key.into())),
        }
    }

    /// A key the caller built from validated parts (see `contract`).
    pub(crate) fn from_checked(key: String) -> Self {
        debug_assert!(Key::new(&key).is_ok(), "invalid key {key:?}");
        Self(key.into())
    }

    /// The segments of the key, in order.
    pub fn segments(&self) -> std::str::Split<'_, char> {
        self.0.split('.')
    }
}

/// Longest component name accepted, in bytes: the longest key of the component
/// contract, `components.NAME.currState`, then fits in [`MAX_NAME_LEN`].
pub const MAX_COMPONENT_LEN: usize = MAX_NAME_LEN - "components.".len() - ".currState".len();

/// The name of a component within its PEIS, such as `l1`: one key segment of
/// 1 to [`MAX_COMPONENT_LEN`] characters from `[A-Za-z0-9_-]`.
///
/// Cloning is cheap (a reference count).
#[derive(Clone, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ComponentId(Arc<str>);

impl ComponentId {
    /// Validates `name` as a component name.
    pub fn new(name: &str) -> Result<Self, ValidationError> {
        match name_problem(name, MAX_COMPONENT_LEN, "it is longer than 234 bytes") {
            Some(reason) => Err(ValidationError::ComponentId {
                name: name.to_owned(),
                reason,
            }),
            None => Ok(Self(name.into())),
        }
    }
}

/// The mimetype of a tuple's data, such as `text/plain`: printable ASCII, 1 to 255 bytes.
#[derive(Clone, PartialEq, Eq, Hash)]
pub struct Mimetype(Arc<str>);

impl Mimetype {
    /// The mimetype of text values (`text/plain`); also the default of [`Value::text`].
    pub const TEXT: &'static str = "text/plain";
    /// The mimetype of raw bytes (`application/octet-stream`); the default of samples without metadata.
    pub const OCTET_STREAM: &'static str = "application/octet-stream";

    /// Validates `mimetype`.
    pub fn new(mimetype: &str) -> Result<Self, ValidationError> {
        let reason = if mimetype.is_empty() {
            Some("it is empty")
        } else if mimetype.len() > MAX_NAME_LEN {
            Some("it is longer than 255 bytes")
        } else if !mimetype.bytes().all(|b| b.is_ascii_graphic() || b == b' ') {
            Some("only printable ASCII is allowed")
        } else {
            None
        };
        match reason {
            Some(reason) => Err(ValidationError::Mimetype {
                mimetype: mimetype.to_owned(),
                reason,
            }),
            None => Ok(Self(mimetype.into())),
        }
    }

    /// `text/plain`.
    pub fn text() -> Self {
        Self(Self::TEXT.into())
    }

    /// `application/octet-stream`.
    pub fn octet_stream() -> Self {
        Self(Self::OCTET_STREAM.into())
    }
}

/// A name, key, pattern or value that breaks the rules of the tuple model.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ValidationError {
    /// A PEIS name is empty, too long, or has a character outside `[A-Za-z0-9_-]`.
    #[error("invalid PEIS name {name:?}: {reason}")]
    PeisId {
        /// The rejected name.
        name: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A component name is empty, too long, or has a character outside `[A-Za-z0-9_-]`.
    #[error("invalid component name {name:?}: {reason}")]
    ComponentId {
        /// The rejected name.
        name: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A key is empty, too long, has an empty segment, or a character outside `[A-Za-z0-9_-]` in a segment.
    #[error("invalid key {key:?}: {reason}")]
    Key {
        /// The rejected key.
        key: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A key or owner pattern is malformed (for example `a.b*` or `a..b`).
    #[error("invalid pattern {pattern:?}: {reason}")]
    Pattern {
        /// The rejected pattern.
        pattern: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A mimetype is empty, longer than 255 bytes or not printable ASCII.
    #[error("invalid mimetype {mimetype:?}: {reason}")]
    Mimetype {
        /// The rejected mimetype.
        mimetype: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A value is larger than the configured limit.
    #[error("value of {size} bytes for key {key} is over the limit of {limit} bytes")]
    ValueTooLarge {
        /// The key the value was meant for.
        key: Key,
        /// Size of the value in bytes.
        size: usize,
        /// The configured limit in bytes.
        limit: usize,
    },
    /// A value that must be text (for example a meta-tuple) is not valid UTF-8.
    #[error("value of ({owner} {key}) is not UTF-8 text: invalid byte at offset {offset}")]
    NotUtf8 {
        /// Owner of the tuple.
        owner: PeisId,
        /// Key of the tuple.
        key: Key,
        /// Offset of the first invalid byte.
        offset: usize,
    },
    /// A value that must be a meta-tuple pointer is not of the form `(meta OWNER KEY)`.
    #[error("value of ({owner} {key}) is not a meta-tuple `(meta OWNER KEY)`: {reason}")]
    NotMeta {
        /// Owner of the tuple.
        owner: PeisId,
        /// Key of the tuple.
        key: Key,
        /// What is wrong with it.
        reason: String,
    },
}
