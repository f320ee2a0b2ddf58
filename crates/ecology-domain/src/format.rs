//! Value formats of information types: `(:information NAME :format FORMAT)`.
//!
//! A format says how a component writes one value of the information as text, so that a
//! producer and a consumer written apart (in any language) agree, `ecology check` reads it, and a
//! consumer can tell a value it cannot read from one that is missing:
//!
//! ```lisp
//! (:information global-pos :format ((x number) (y number) (theta number)))    ; "1.2 3.4 0.5"
//! (:information range-scan :format ((ranges number :many)))                   ; "1.2 0.8 3.0"
//! (:information image
//!   :format (records (name name) (x number) (y number) (theta number)))       ; "astrid 1 2 0; pippi 3 1 0"
//! ```
//!
//! `(FIELD …)` is one record: its fields in order, separated by white space. `(records FIELD …)`
//! is any number of such records separated by `;` (none: the empty text). A field is
//! `(NAME TYPE)`; its type is `number` (a finite decimal such as `-1.5`), `integer`, `name` (one
//! word) or `(one-of WORD …)`; the last field of a record may be `:many` (one or more values of
//! its type) or have the type `text` (the rest of the record, any words).

use std::fmt;

use crate::diagnostic::Span;
use crate::model::Name;
use crate::syntax::{Sexp, SexpKind};

/// The type of one field.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FieldType {
    /// A finite decimal number.
    Number,
    /// An integer.
    Integer,
    /// One word.
    Name,
    /// One of these words.
    OneOf(Vec<Name>),
    /// The rest of the record: any words (last field only).
    Text,
}

/// One field of a record.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Field {
    /// Its name, for people: `x`, `theta`.
    pub name: Name,
    /// What it holds.
    pub ty: FieldType,
    /// One or more values (last field only).
    pub many: bool,
}

/// How one value of an information type is written.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Format {
    /// The fields of one record.
    pub fields: Vec<Field>,
    /// Any number of records separated by `;`, rather than exactly one.
    pub records: bool,
}

/// `(:information NAME :format FORMAT)`: the declared format of an information type.
#[derive(Debug, Clone, PartialEq)]
pub struct Information {
    /// The information type, as functionalities name it in `:input` and `:output`.
    pub name: Name,
    /// How its values are written.
    pub format: Format,
    /// The whole form.
    pub span: Span,
    /// The name.
    pub name_span: Span,
}

/// Reads a format; the first problem with where it is.
pub(crate) fn parse_format(sexp: &Sexp) -> Result<Format, (Span, String)> {
    const EXPECTED: &str =
        "expected a format like `((x number) (y number))` or `(records (name name) (x number))`";
    let Some(items) = sexp.list() else {
        return Err((sexp.span, EXPECTED.to_string()));
    };
    let (records, fields) = match items.first().and_then(Sexp::atom) {
        Some("records") => (true, &items[1..]),
        _ => (false, items),
    };
    if fields.is_empty() {
        return Err((sexp.span, format!("{EXPECTED}: a format needs a field")));
    }
    let mut out: Vec<Field> = Vec::new();
    for (i, item) in fields.iter().enumerate() {
        let field = parse_field(item)?;
        if out.iter().any(|f| f.name == field.name) {
            return Err((item.span, format!("field `{}` is named twice", field.name)));
        }
        let last = i + 1 == fields.len();
        if !last && (field.many || field.ty == FieldType::Text) {
            let what = if field.many { "`:many`" } else { "type `text`" };
            return Err((
                item.span,
                format!("only the last field may have {what}: it takes the rest of the record"),
            ));
        }
        out.push(field);
    }
    Ok(Format {
        fields: out,
        records,
    })
}

fn parse_field(item: &Sexp) -> Result<Field, (Span, String)> {
    const EXPECTED: &str = "expected a field like `(x number)`";
    let Some(parts) = item.list() else {
        return Err((item.span, EXPECTED.to_string()));
    };
    let (name, ty, rest) = match parts {
        [name, ty, rest @ ..] => (name, ty, rest),
        _ => return Err((item.span, EXPECTED.to_string())),
    };
    let Some(name) = name.atom().filter(|n| !n.starts_with([':', '?'])) else {
        return Err((name.span, "expected a field name like `x`".to_string()));
    };
    let ty = parse_type(ty)?;
    let many = match rest {
        [] => false,
        [flag] if flag.atom() == Some(":many") => true,
        [other, ..] => {
            return Err((
                other.span,
                "after a field's type only `:many` may follow".to_string(),
            ));
        }
    };
    if many && ty == FieldType::Text {
        return Err((item.span, "a `text` field cannot be `:many`".to_string()));
    }
    Ok(Field {
        name: name.into(),
        ty,
        many,
    })
}

fn parse_type(sexp: &Sexp) -> Result<FieldType, (Span, String)> {
    const TYPES: &str = "types: number, integer, name, text, (one-of WORD …)";
    match &sexp.kind {
        SexpKind::Atom(atom) => match &**atom {
            "number" => Ok(FieldType::Number),
            "integer" => Ok(FieldType::Integer),
            "name" => Ok(FieldType::Name),
            "text" => Ok(FieldType::Text),
            other => Err((sexp.span, format!("unknown field type `{other}` ({TYPES})"))),
        },
        SexpKind::List(items) => {
            let words: Option<Vec<Name>> = match items.split_first() {
                Some((head, words)) if head.atom() == Some("one-of") && !words.is_empty() => words
                    .iter()
                    .map(|w| {
                        w.atom()
                            .filter(|a| !a.starts_with([':', '?']))
                            .map(Name::from)
                    })
                    .collect(),
                _ => None,
            };
            words
                .map(FieldType::OneOf)
                .ok_or_else(|| (sexp.span, format!("expected a field type ({TYPES})")))
        }
    }
}

impl Format {
    /// Whether `value` is written in this format; the reason when it is not, such as
    /// `expected X Y THETA, found "1,2;3"`.
    pub fn check(&self, value: &str) -> Result<(), String> {
        let fail = || {
            let mut shown: String = value.chars().take(40).collect();
            if value.chars().count() > 40 {
                shown.push('…');
            }
            format!("expected {self}, found {shown:?}")
        };
        if self.records {
            value
                .split(';')
                .map(str::trim)
                .filter(|r| !r.is_empty())
                .try_for_each(|record| self.check_record(record).ok_or(()))
                .map_err(|()| fail())
        } else {
            self.check_record(value.trim()).ok_or_else(fail)
        }
    }

    fn check_record(&self, record: &str) -> Option<()> {
        let words: Vec<&str> = record.split_whitespace().collect();
        let mut at = 0;
        for field in &self.fields {
            if field.ty == FieldType::Text {
                return Some(());
            }
            if field.many {
                let rest = words.get(at..).filter(|r| !r.is_empty())?;
                return rest.iter().all(|w| field.ty.accepts(w)).then_some(());
            }
            field.ty.accepts(words.get(at)?).then_some(())?;
            at += 1;
        }
        (at == words.len()).then_some(())
    }
}

impl FieldType {
    fn accepts(&self, word: &str) -> bool {
        match self {
            FieldType::Number => word.parse::<f64>().is_ok_and(f64::is_finite),
            FieldType::Integer => word.parse::<i64>().is_ok(),
            FieldType::Name => !word.contains(';'),
            FieldType::OneOf(words) => words.iter().any(|w| &**w == word),
            FieldType::Text => true,
        }
    }
}

/// How a value looks, for messages and docs: `X Y THETA`, `RANGES…`,
/// `NAME X Y THETA; …`, `STATE (awake|asleep)`.
impl fmt::Display for Format {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, field) in self.fields.iter().enumerate() {
            if i > 0 {
                f.write_str(" ")?;
            }
            write!(f, "{}", field.name.to_uppercase())?;
            if let FieldType::OneOf(words) = &field.ty {
                write!(f, " ({})", words.join("|"))?;
            }
            if field.many || field.ty == FieldType::Text {
                f.write_str("…")?;
            }
        }
        if self.records {
            f.write_str("; …")?;
        }
        Ok(())
    }
}
