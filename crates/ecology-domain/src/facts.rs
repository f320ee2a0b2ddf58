//! The fast path for `.facts` files: flat facts of plain names and numbers, read straight into
//! the state, without building S-expressions first.
//!
//! Anything else (a nested or empty list, a variable, a keyword, a character outside printable
//! ASCII, unbalanced parentheses, a malformed number, a fact its predicate's rules refuse) sends
//! the whole file to the general reader, which says what is wrong: the diagnostics are the
//! general reader's, and this path needs none.

use rustc_hash::FxHashMap;

use crate::parse::{AtomKind, classify, is_well_formed_number};
use crate::state::{self, EcologyState, Fact};
use crate::syntax::{CHECK_EVERY, is_delimiter};
use crate::{Name, Span};

/// What the fast path made of a file.
pub(crate) enum Read {
    /// Every fact, all of them well-formed.
    Done(EcologyState),
    /// The facts read before `stop` said to give up.
    Stopped(EcologyState),
    /// Something only the general reader reads, or reports.
    Unusual,
}

/// Reads `text` as flat facts, asking `stop` every 16 KiB whether to give up.
pub(crate) fn read(text: &str, stop: &mut dyn FnMut() -> bool) -> Read {
    let bytes = text.as_bytes();
    // A fact takes some 25 bytes of a generated file: room for all of them at once.
    let mut state = EcologyState::with_capacity(bytes.len() / 24);
    // Each distinct name is made once and shared by every fact that names it.
    let mut names: FxHashMap<&str, Name> = FxHashMap::default();
    let mut pos = 0;
    let mut next_check = 0;
    loop {
        pos = skip_blank(bytes, pos);
        if pos == bytes.len() {
            return Read::Done(state);
        }
        if pos >= next_check {
            if stop() {
                return Read::Stopped(state);
            }
            next_check = pos + CHECK_EVERY;
        }
        if bytes[pos] != b'(' {
            return Read::Unusual;
        }
        let Some((fact, end)) = fact(text, pos + 1, &mut names) else {
            return Read::Unusual;
        };
        if state::check_fact(&fact, Span::empty(pos)).is_some() {
            return Read::Unusual;
        }
        state.insert(fact);
        pos = end;
    }
}

/// The fact whose `(` is just before `pos`, and where it ends (after its `)`).
fn fact<'t>(
    text: &'t str,
    mut pos: usize,
    names: &mut FxHashMap<&'t str, Name>,
) -> Option<(Fact, usize)> {
    let bytes = text.as_bytes();
    let mut predicate: Option<Name> = None;
    let mut args = Vec::with_capacity(4);
    loop {
        pos = skip_blank(bytes, pos);
        match bytes.get(pos)? {
            b')' => {
                return Some((
                    Fact {
                        predicate: predicate?,
                        args,
                    },
                    pos + 1,
                ));
            }
            b'(' => return None,
            _ => {
                let start = pos;
                while pos < bytes.len() && !is_delimiter(bytes[pos]) {
                    // A `?` (a variable, or one glued to a name) is the general reader's.
                    if !bytes[pos].is_ascii_graphic() || bytes[pos] == b'?' {
                        return None;
                    }
                    pos += 1;
                }
                let atom = &text[start..pos];
                let name = match names.get(atom) {
                    Some(name) if predicate.is_some() || classify(atom) == AtomKind::Symbol => {
                        name.clone()
                    }
                    Some(_) => return None,
                    None => {
                        let name = match classify(atom) {
                            AtomKind::Symbol => lowercase(atom),
                            AtomKind::Number
                                if predicate.is_some() && is_well_formed_number(atom) =>
                            {
                                atom.into()
                            }
                            _ => return None,
                        };
                        names.insert(atom, name.clone());
                        name
                    }
                };
                match predicate {
                    None => predicate = Some(name),
                    Some(_) => args.push(name),
                }
            }
        }
    }
}

/// The position of the first byte at or after `pos` that is neither whitespace nor in a comment.
fn skip_blank(bytes: &[u8], mut pos: usize) -> usize {
    while let Some(&byte) = bytes.get(pos) {
        if byte == b';' {
            while pos < bytes.len() && bytes[pos] != b'\n' {
                pos += 1;
            }
        } else if byte.is_ascii_whitespace() {
            pos += 1;
        } else {
            break;
        }
    }
    pos
}

/// Names are case-insensitive, kept lowercase.
fn lowercase(atom: &str) -> Name {
    if atom.bytes().any(|b| b.is_ascii_uppercase()) {
        atom.to_ascii_lowercase().into()
    } else {
        atom.into()
    }
}
