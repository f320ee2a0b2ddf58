//! Diagnostics: byte spans, error messages, and their rendering for people.
//!
//! Parsers collect every [`Diagnostic`] and keep going; [`render`] turns them
//! into `file:line:col` headers with a caret excerpt (through
//! `codespan-reporting`), and [`line_col`] gives the position for tools.

use std::fmt;

use codespan_reporting::diagnostic as cs;
use codespan_reporting::files::SimpleFile;
use codespan_reporting::term;

/// A half-open byte range `start..end` in a source file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Span {
    /// First byte.
    pub start: usize,
    /// One past the last byte.
    pub end: usize,
}

impl Span {
    /// The span `start..end`.
    pub fn new(start: usize, end: usize) -> Span {
        Span { start, end }
    }

    /// An empty span at `at`.
    pub fn empty(at: usize) -> Span {
        Span { start: at, end: at }
    }

    /// The smallest span covering both.
    pub fn to(self, other: Span) -> Span {
        Span::new(self.start.min(other.start), self.end.max(other.end))
    }
}

/// One problem found in a source file.
#[derive(Debug, Clone, PartialEq)]
pub struct Diagnostic {
    /// Where the problem is.
    pub span: Span,
    /// A plain, lowercase sentence saying what is wrong.
    pub message: String,
    /// A short note under the caret, if any.
    pub label: Option<String>,
    /// Other places that explain this one (for example "first defined here").
    pub secondary: Vec<(Span, String)>,
    /// Hints printed after the excerpt.
    pub notes: Vec<String>,
}

/// The longest message, label or note kept, in characters: a name of 40 KB
/// quoted in every message about it made output and memory grow with the
/// square of the input.
pub const MAX_MESSAGE: usize = 300;

/// `text` cut to [`MAX_MESSAGE`] characters, ending in `…` when cut.
fn bounded(text: String) -> String {
    match text.char_indices().nth(MAX_MESSAGE) {
        Some((end, _)) => format!("{}…", &text[..end]),
        None => text,
    }
}

impl Diagnostic {
    /// An error at `span` with `message`.
    pub fn error(span: Span, message: impl Into<String>) -> Diagnostic {
        Diagnostic {
            span,
            message: bounded(message.into()),
            label: None,
            secondary: Vec::new(),
            notes: Vec::new(),
        }
    }

    /// Adds the note under the caret.
    pub fn with_label(mut self, label: impl Into<String>) -> Diagnostic {
        self.label = Some(bounded(label.into()));
        self
    }

    /// Adds another place that explains this one.
    pub fn with_secondary(mut self, span: Span, label: impl Into<String>) -> Diagnostic {
        self.secondary.push((span, bounded(label.into())));
        self
    }

    /// Adds a hint printed after the excerpt.
    pub fn with_note(mut self, note: impl Into<String>) -> Diagnostic {
        self.notes.push(bounded(note.into()));
        self
    }
}

/// Every diagnostic of one failed parse, in source order.
#[derive(Debug, Clone, PartialEq)]
pub struct Diagnostics(pub Vec<Diagnostic>);

impl Diagnostics {
    /// Renders all of them for people; see [`render`].
    pub fn render(&self, file_name: &str, source: &[u8]) -> String {
        render(file_name, source, &self.0)
    }
}

impl fmt::Display for Diagnostics {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, diag) in self.0.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(
                f,
                "{}..{}: {}",
                diag.span.start, diag.span.end, diag.message
            )?;
        }
        Ok(())
    }
}

impl std::error::Error for Diagnostics {}

/// The 1-based line and column (in characters) of byte `offset` in `source`.
///
/// Bytes that are not UTF-8 count as one column each, so positions stay
/// meaningful for the invalid-UTF-8 diagnostic.
pub fn line_col(source: &[u8], offset: usize) -> (usize, usize) {
    let offset = offset.min(source.len());
    let before = &source[..offset];
    let line_start = before
        .iter()
        .rposition(|&b| b == b'\n')
        .map_or(0, |i| i + 1);
    let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
    let column = String::from_utf8_lossy(&before[line_start..])
        .chars()
        .count()
        + 1;
    (line, column)
}

/// At most this many diagnostics are rendered; the rest are counted.
pub const MAX_RENDERED: usize = 100;
/// A source line longer than this (in bytes) is shown as an excerpt around
/// the error, so output stays proportional to the number of errors, not to
/// their number times the line's length.
pub const MAX_LINE: usize = 240;
/// Characters shown either side of an error on a long line.
const EXCERPT: usize = 40;

/// Renders diagnostics as `error: message` followed by `┌─ file:line:col` and a
/// caret excerpt, one after the other, without colour. At most
/// [`MAX_RENDERED`] are shown, then how many more there are; on a line longer
/// than [`MAX_LINE`] only the part around the error is shown.
pub fn render(file_name: &str, source: &[u8], diags: &[Diagnostic]) -> String {
    // Offsets stay exact up to the first invalid byte, which is all a UTF-8
    // diagnostic needs; valid sources are unchanged.
    let text = String::from_utf8_lossy(source);
    let files = SimpleFile::new(file_name, text.as_ref());
    let config = term::Config::default();
    let mut out = String::new();
    for diag in diags.iter().take(MAX_RENDERED) {
        if let Some(short) = render_on_long_line(file_name, &text, source, diag) {
            out.push_str(&short);
            continue;
        }
        // Spans are clamped to the file and widened to character boundaries, so
        // a span over an invalid byte (replaced by U+FFFD above) still renders.
        let clamp = |span: Span| {
            let mut end = span.end.min(text.len());
            while !text.is_char_boundary(end) {
                end += 1;
            }
            let mut start = span.start.min(end);
            while !text.is_char_boundary(start) {
                start -= 1;
            }
            start..end
        };
        let mut primary = cs::Label::primary((), clamp(diag.span));
        if let Some(label) = &diag.label {
            primary = primary.with_message(label);
        }
        let mut labels = vec![primary];
        for (span, label) in &diag.secondary {
            labels.push(cs::Label::secondary((), clamp(*span)).with_message(label));
        }
        let rendered = cs::Diagnostic::error()
            .with_message(&diag.message)
            .with_labels(labels)
            .with_notes(diag.notes.clone());
        match term::emit_into_string(&config, &files, &rendered) {
            Ok(piece) => out.push_str(&piece),
            Err(_) => {
                // Only reachable if a span falls outside the file, which clamping
                // prevents; still, never lose the message.
                let (line, col) = line_col(source, diag.span.start);
                out.push_str(&format!(
                    "error: {}\n  --> {file_name}:{line}:{col}\n",
                    diag.message
                ));
            }
        }
    }
    if diags.len() > MAX_RENDERED {
        out.push_str(&format!(
            "… and {} more errors, not shown\n",
            diags.len() - MAX_RENDERED
        ));
    }
    out
}

/// A diagnostic whose primary span lies on a line longer than [`MAX_LINE`],
/// rendered as an excerpt of that line around the span; `None` otherwise.
fn render_on_long_line(
    file_name: &str,
    text: &str,
    source: &[u8],
    diag: &Diagnostic,
) -> Option<String> {
    let at = diag.span.start.min(text.len());
    let line_start = text[..floor_boundary(text, at)]
        .rfind('\n')
        .map_or(0, |i| i + 1);
    let line_end = text[at..].find('\n').map_or(text.len(), |i| at + i);
    if line_end - line_start <= MAX_LINE {
        return None;
    }
    let (line, col) = line_col(source, at);
    let before: String = {
        let head = &text[line_start..floor_boundary(text, at)];
        let chars: Vec<char> = head.chars().collect();
        let from = chars.len().saturating_sub(EXCERPT);
        let cut = if from > 0 { "…" } else { "" };
        format!("{cut}{}", chars[from..].iter().collect::<String>())
    };
    let rest = &text[floor_boundary(text, at)..line_end];
    let span_chars = text
        [floor_boundary(text, at)..floor_boundary(text, diag.span.end.min(line_end).max(at))]
        .chars()
        .count()
        .clamp(1, EXCERPT);
    let after: String = rest.chars().take(EXCERPT + span_chars).collect();
    let cut = if rest.chars().nth(EXCERPT + span_chars).is_some() {
        "…"
    } else {
        ""
    };
    let pad = " ".repeat(before.chars().count());
    let carets = "^".repeat(span_chars);
    let label = diag.label.as_deref().unwrap_or("");
    let mut out = format!(
        "error: {}\n  ┌─ {file_name}:{line}:{col}\n  │\n{line:>2}│ {before}{after}{cut}\n  │ {pad}{carets} {label}\n",
        diag.message
    );
    for note in &diag.notes {
        out.push_str(&format!("  = {note}\n"));
    }
    out.push('\n');
    Some(out)
}

/// The largest char boundary of `text` at or before `i`.
fn floor_boundary(text: &str, i: usize) -> usize {
    let mut i = i.min(text.len());
    while !text.is_char_boundary(i) {
        i -= 1;
    }
    i
}
