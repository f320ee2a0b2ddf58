//! The reader: bytes to S-expressions with byte spans, never panicking.
//!
//! Every `.eco`, `.facts` and problem file goes through here first. The reader
//! checks the limits that protect the rest of the pipeline (file size, UTF-8,
//! nesting depth) and reports unbalanced parentheses, then hands a forest of
//! [`Sexp`] to the parser. It is iterative, so hostile nesting cannot overflow
//! the stack.

use crate::diagnostic::{Diagnostic, Span};

/// Largest file the reader accepts, in bytes.
pub const MAX_FILE_BYTES: usize = 8 * 1024 * 1024;

/// Deepest nesting of parentheses the reader accepts.
pub const MAX_DEPTH: usize = 64;

/// One S-expression: a parenthesized list or an atom, with its byte span.
#[derive(Debug, Clone, PartialEq)]
pub struct Sexp {
    /// What the expression is.
    pub kind: SexpKind,
    /// Where it stands in the source, in bytes.
    pub span: Span,
}

/// The two shapes of an S-expression.
#[derive(Debug, Clone, PartialEq)]
pub enum SexpKind {
    /// `( ... )`
    List(Vec<Sexp>),
    /// A symbol, variable, keyword or number, lowercased (PDDL is case-insensitive).
    Atom(Box<str>),
}

impl Sexp {
    /// The atom's text, if this is an atom.
    pub fn atom(&self) -> Option<&str> {
        match &self.kind {
            SexpKind::Atom(text) => Some(text),
            SexpKind::List(_) => None,
        }
    }

    /// The list's items, if this is a list.
    pub fn list(&self) -> Option<&[Sexp]> {
        match &self.kind {
            SexpKind::List(items) => Some(items),
            SexpKind::Atom(_) => None,
        }
    }
}

/// Checks the byte-level limits and decodes the source as UTF-8.
///
/// On failure the returned diagnostic points at the offending byte (or at the
/// start of the file when it is too large).
pub fn decode(bytes: &[u8]) -> Result<&str, Diagnostic> {
    if bytes.len() > MAX_FILE_BYTES {
        return Err(Diagnostic::error(
            Span::empty(0),
            format!(
                "file is {} bytes, larger than the limit of {} bytes (8 MiB)",
                bytes.len(),
                MAX_FILE_BYTES
            ),
        ));
    }
    std::str::from_utf8(bytes).map_err(|err| {
        let at = err.valid_up_to();
        let len = err.error_len().unwrap_or(bytes.len() - at).max(1);
        Diagnostic::error(Span::new(at, at + len), "invalid UTF-8 in source file")
            .with_label("this byte sequence is not UTF-8")
    })
}

/// Reads every top-level S-expression of `src`, pushing problems into `diags`.
///
/// Unbalanced parentheses and excessive nesting are reported; reading goes on
/// so that later errors are found in the same pass.
pub fn read(src: &str, diags: &mut Vec<Diagnostic>) -> Vec<Sexp> {
    read_until(src, diags, &mut || false).unwrap_or_default()
}

/// How many bytes are read between two calls of a `stop` check.
pub(crate) const CHECK_EVERY: usize = 16 * 1024;

/// [`read`], asking `stop` every 16 KiB whether to give up; `None` when it did.
pub fn read_until(
    src: &str,
    diags: &mut Vec<Diagnostic>,
    stop: &mut dyn FnMut() -> bool,
) -> Option<Vec<Sexp>> {
    let bytes = src.as_bytes();
    let mut next_check = 0;
    let mut top = Vec::new();
    // Open lists: the byte offset of their '(' and the items read so far.
    let mut open: Vec<(usize, Vec<Sexp>)> = Vec::new();
    // While > 0 we are inside a list nested too deeply and only count parens.
    let mut skipping = 0usize;
    let mut pos = 0;
    while pos < bytes.len() {
        if pos >= next_check {
            if stop() {
                return None;
            }
            next_check = pos + CHECK_EVERY;
        }
        let byte = bytes[pos];
        match byte {
            b';' => {
                while pos < bytes.len() && bytes[pos] != b'\n' {
                    pos += 1;
                }
            }
            b'(' => {
                if skipping > 0 {
                    skipping += 1;
                } else if open.len() >= MAX_DEPTH {
                    diags.push(
                        Diagnostic::error(
                            Span::new(pos, pos + 1),
                            format!("nesting deeper than {MAX_DEPTH} levels"),
                        )
                        .with_label("this list is too deeply nested"),
                    );
                    skipping = 1;
                } else {
                    open.push((pos, Vec::new()));
                }
                pos += 1;
            }
            b')' => {
                if skipping > 0 {
                    skipping -= 1;
                } else if let Some((start, items)) = open.pop() {
                    let sexp = Sexp {
                        kind: SexpKind::List(items),
                        span: Span::new(start, pos + 1),
                    };
                    push(&mut open, &mut top, sexp);
                } else {
                    diags.push(
                        Diagnostic::error(Span::new(pos, pos + 1), "unbalanced parentheses")
                            .with_label("this `)` closes nothing"),
                    );
                }
                pos += 1;
            }
            _ if byte.is_ascii_whitespace() => pos += 1,
            _ => {
                let start = pos;
                // A `?` ends a name glued to a variable, as other PDDL readers take it:
                // `(aircraft?a)` is `(aircraft ?a)`.
                while pos < bytes.len()
                    && !is_delimiter(bytes[pos])
                    && !(bytes[pos] == b'?' && pos > start)
                {
                    pos += 1;
                }
                if let Some((offset, c)) =
                    src[start..pos].char_indices().find(|(_, c)| c.is_control())
                {
                    let at = start + offset;
                    diags.push(
                        Diagnostic::error(
                            Span::new(at, at + c.len_utf8()),
                            format!("control character U+{:04X} in a name", u32::from(c)),
                        )
                        .with_label("names are printable"),
                    );
                }
                if skipping == 0 {
                    let text = src[start..pos].to_lowercase().into_boxed_str();
                    let sexp = Sexp {
                        kind: SexpKind::Atom(text),
                        span: Span::new(start, pos),
                    };
                    push(&mut open, &mut top, sexp);
                }
            }
        }
    }
    while let Some((start, items)) = open.pop() {
        diags.push(
            Diagnostic::error(Span::new(start, start + 1), "unbalanced parentheses")
                .with_label("this `(` is never closed"),
        );
        let sexp = Sexp {
            kind: SexpKind::List(items),
            span: Span::new(start, src.len()),
        };
        push(&mut open, &mut top, sexp);
    }
    Some(top)
}

fn push(open: &mut [(usize, Vec<Sexp>)], top: &mut Vec<Sexp>, sexp: Sexp) {
    match open.last_mut() {
        Some((_, items)) => items.push(sexp),
        None => top.push(sexp),
    }
}

pub(crate) fn is_delimiter(byte: u8) -> bool {
    matches!(byte, b'(' | b')' | b';') || byte.is_ascii_whitespace()
}
