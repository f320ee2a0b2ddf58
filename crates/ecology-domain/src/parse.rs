//! The parser: S-expressions to the domain model, collecting every syntax error.
//!
//! Each `parse_*` method reports what is wrong with its form and returns the
//! best model it could build, so one pass finds every problem in a file.
//! Semantic checks (names, arities, bindings, recursion) live in `validate`.

use crate::diagnostic::{Diagnostic, Span};
use crate::format::Information;
use crate::model::*;
use crate::syntax::Sexp;

/// How far from 1 a sum of probabilities may be and still be 1 (decimal
/// rounding, `1/3`): above it is an error, below it leaves no rest
/// ([`Probabilistic::rest`]).
pub const PROBABILITY_EPSILON: f64 = 1e-6;

/// Requirements read as declarations only, as other PDDL readers take them (IPC domains declare
/// `:adl` and use little of it): the constructs they allow beyond what is supported (`forall`,
/// `exists`, …) are still refused where they appear, with the construct named.
pub const DECLARED_ONLY_REQUIREMENTS: &[&str] = &[
    "adl",
    "quantified-preconditions",
    "existential-preconditions",
    "universal-preconditions",
];

/// The requirements the language supports.
pub const SUPPORTED_REQUIREMENTS: &[&str] = &[
    "strips",
    "typing",
    "negative-preconditions",
    "equality",
    "action-costs",
    "probabilistic-effects",
    "disjunctive-preconditions",
    "conditional-effects",
];

/// The most disjuncts an action's precondition may have in disjunctive normal form: each
/// becomes operators of its own when the action is grounded.
pub const MAX_DISJUNCTS: usize = 64;

/// A condition in disjunctive normal form: the conjunctions of literals one of which must hold.
type Dnf = Vec<Vec<Literal>>;

/// Whether a condition may be disjunctive (an action's precondition) or must be a conjunction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Disjunctions {
    Read,
    Refused,
}

/// What kind of atom a token is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum AtomKind {
    Symbol,
    Variable,
    Keyword,
    Number,
}

pub(crate) fn classify(text: &str) -> AtomKind {
    let mut chars = text.chars();
    match chars.next() {
        Some('?') => AtomKind::Variable,
        Some(':') => AtomKind::Keyword,
        Some(c) if c.is_ascii_digit() => AtomKind::Number,
        Some('-' | '+' | '.') if chars.next().is_some_and(|c| c.is_ascii_digit()) => {
            AtomKind::Number
        }
        _ => AtomKind::Symbol,
    }
}

/// Whether `text` is a well-formed number: digits, optionally a sign and a
/// fractional part (`25`, `-3`, `12.5`).
pub(crate) fn is_well_formed_number(text: &str) -> bool {
    let body = text.strip_prefix(['-', '+']).unwrap_or(text);
    let (int, frac) = match body.split_once('.') {
        Some((int, frac)) => (int, Some(frac)),
        None => (body, None),
    };
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    digits(int) && frac.is_none_or(digits)
}

/// Accumulates diagnostics while converting S-expressions.
#[derive(Debug, Default)]
pub(crate) struct Parser {
    pub(crate) diags: Vec<Diagnostic>,
}

/// The `:keyword value` pairs of a form, in order.
type Fields<'a> = Vec<(&'a str, Span, &'a Sexp)>;

impl Parser {
    fn error(&mut self, span: Span, message: impl Into<String>) {
        self.diags.push(Diagnostic::error(span, message));
    }

    fn push(&mut self, diag: Diagnostic) {
        self.diags.push(diag);
    }

    /// Checks that the file holds exactly one `(define (KIND NAME) ...)` and
    /// returns its name and the remaining items.
    pub(crate) fn define<'a>(
        &mut self,
        forms: &'a [Sexp],
        kind: &str,
        whole_file: Span,
    ) -> Option<(Name, &'a [Sexp])> {
        let Some(first) = forms.first() else {
            self.error(
                whole_file,
                format!("empty file: expected `(define ({kind} NAME) ...)`"),
            );
            return None;
        };
        for extra in &forms[1..] {
            self.push(
                Diagnostic::error(extra.span, "unexpected form after the `define`")
                    .with_label("a file holds one `(define ...)`"),
            );
        }
        let items = first.list().unwrap_or(&[]);
        if items.first().and_then(Sexp::atom) != Some("define") {
            self.error(first.span, format!("expected `(define ({kind} NAME) ...)`"));
            return None;
        }
        let header = items.get(1);
        let name = match header.and_then(Sexp::list) {
            Some([head, name]) if head.atom() == Some(kind) => self.symbol(name, "a name"),
            _ => {
                self.error(
                    header.map_or(first.span, |h| h.span),
                    format!("expected `({kind} NAME)` after `define`"),
                );
                None
            }
        };
        Some((name.unwrap_or_default(), &items[2.min(items.len())..]))
    }

    /// Reads `:keyword value` pairs, reporting unknown, repeated and valueless keys.
    fn fields<'a>(&mut self, items: &'a [Sexp], allowed: &[&str], what: &str) -> Fields<'a> {
        let mut fields: Fields<'a> = Vec::new();
        let mut iter = items.iter();
        while let Some(key) = iter.next() {
            let Some(text) = key.atom().filter(|t| classify(t) == AtomKind::Keyword) else {
                self.push(
                    Diagnostic::error(key.span, format!("expected a `:keyword` in {what}"))
                        .with_note(format!("fields of {what}: {}", allowed.join(" "))),
                );
                continue;
            };
            let Some(value) = iter.next() else {
                self.error(key.span, format!("`{text}` has no value"));
                break;
            };
            if !allowed.contains(&text) {
                self.push(
                    Diagnostic::error(key.span, format!("unknown field `{text}` in {what}"))
                        .with_note(format!("fields of {what}: {}", allowed.join(" "))),
                );
                continue;
            }
            if let Some((_, first, _)) = fields.iter().find(|(k, _, _)| *k == text) {
                let first = *first;
                self.push(
                    Diagnostic::error(key.span, format!("`{text}` given twice in {what}"))
                        .with_secondary(first, "first given here"),
                );
                continue;
            }
            fields.push((text, key.span, value));
        }
        fields
    }

    fn field<'a>(fields: &Fields<'a>, key: &str) -> Option<&'a Sexp> {
        fields
            .iter()
            .find(|(k, _, _)| *k == key)
            .map(|(_, _, v)| *v)
    }

    /// Field `key` read by `read`, or the empty value when it is absent.
    fn optional<'a, T: Default>(
        &mut self,
        fields: &Fields<'a>,
        key: &str,
        read: impl FnOnce(&mut Self, &'a Sexp) -> T,
    ) -> T {
        match Self::field(fields, key) {
            Some(sexp) => read(self, sexp),
            None => T::default(),
        }
    }

    fn require<'a>(
        &mut self,
        fields: &Fields<'a>,
        key: &str,
        what: &str,
        at: Span,
    ) -> Option<&'a Sexp> {
        let value = Self::field(fields, key);
        if value.is_none() {
            self.error(at, format!("{what} has no `{key}`"));
        }
        value
    }

    /// A symbol (not a variable, keyword or number).
    pub(crate) fn symbol(&mut self, sexp: &Sexp, expected: &str) -> Option<Name> {
        match sexp.atom() {
            Some(text) if classify(text) == AtomKind::Symbol => Some(text.into()),
            Some(text) if classify(text) == AtomKind::Number => {
                self.check_number(text, sexp.span);
                self.error(
                    sexp.span,
                    format!("expected {expected}, found number `{text}`"),
                );
                None
            }
            Some(text) => {
                self.error(sexp.span, format!("expected {expected}, found `{text}`"));
                None
            }
            None => {
                self.error(sexp.span, format!("expected {expected}, found a list"));
                None
            }
        }
    }

    fn check_number(&mut self, text: &str, span: Span) -> bool {
        if is_well_formed_number(text) {
            return true;
        }
        self.push(
            Diagnostic::error(span, format!("malformed number `{text}`")).with_note(
                "numbers are digits with an optional sign and fraction, like 25 or 12.5",
            ),
        );
        false
    }

    /// A non-negative integer such as a cost.
    fn natural(&mut self, sexp: &Sexp, what: &str) -> Option<u64> {
        let text = sexp.atom().filter(|t| classify(t) == AtomKind::Number);
        let Some(text) = text else {
            self.error(
                sexp.span,
                format!("expected {what}, a non-negative integer"),
            );
            return None;
        };
        if !self.check_number(text, sexp.span) {
            return None;
        }
        match text.parse::<u64>() {
            Ok(n) => Some(n),
            Err(_) => {
                self.push(
                    Diagnostic::error(sexp.span, format!("{what} must be a non-negative integer"))
                        .with_label(format!("`{text}` is not")),
                );
                None
            }
        }
    }

    /// A positive rate in hertz.
    fn rate(&mut self, sexp: &Sexp) -> Option<f64> {
        let text = sexp.atom().filter(|t| classify(t) == AtomKind::Number);
        let Some(text) = text else {
            self.error(sexp.span, "expected a rate in hertz after `:hz`");
            return None;
        };
        if !self.check_number(text, sexp.span) {
            return None;
        }
        match text.parse::<f64>() {
            Ok(hz) if hz.is_finite() && hz > 0.0 => Some(hz),
            _ => {
                self.error(sexp.span, "a rate must be a positive number of hertz");
                None
            }
        }
    }

    /// A variable or constant.
    pub(crate) fn term(&mut self, sexp: &Sexp) -> Option<Term> {
        let Some(text) = sexp.atom() else {
            self.error(sexp.span, "expected a variable or constant, found a list");
            return None;
        };
        match classify(text) {
            AtomKind::Variable if text.len() > 1 => Some(Term::Var(text[1..].into())),
            AtomKind::Variable => {
                self.error(sexp.span, "`?` must be followed by a variable name");
                None
            }
            AtomKind::Keyword => {
                self.error(
                    sexp.span,
                    format!("expected a variable or constant, found keyword `{text}`"),
                );
                None
            }
            AtomKind::Number => self
                .check_number(text, sexp.span)
                .then(|| Term::Const(text.into())),
            AtomKind::Symbol => Some(Term::Const(text.into())),
        }
    }

    fn terms(&mut self, items: &[Sexp]) -> Vec<Term> {
        items.iter().filter_map(|item| self.term(item)).collect()
    }

    /// `(name arg ...)`
    pub(crate) fn call(&mut self, sexp: &Sexp, expected: &str) -> Option<Call> {
        let Some(items) = sexp.list() else {
            self.error(sexp.span, format!("expected {expected} in parentheses"));
            return None;
        };
        let Some(head) = items.first() else {
            self.error(sexp.span, format!("expected {expected}, found `()`"));
            return None;
        };
        let name = self.symbol(head, "a name")?;
        Some(Call {
            name,
            args: self.terms(&items[1..]),
            span: sexp.span,
        })
    }

    fn atom(&mut self, sexp: &Sexp) -> Option<Atom> {
        let call = self.call(sexp, "an atom like `(pc ?p laser ?l)`")?;
        Some(Atom {
            predicate: call.name,
            args: call.args,
            span: call.span,
        })
    }

    /// Parameters `(?a ?b - type ?c)`; with `variables` false, plain names
    /// (objects and constants) instead of variables.
    fn params(&mut self, sexp: &Sexp, variables: bool) -> Vec<Param> {
        let Some(items) = sexp.list() else {
            self.error(sexp.span, "expected a parameter list in parentheses");
            return Vec::new();
        };
        self.typed_list(items, variables)
    }

    fn typed_list(&mut self, items: &[Sexp], variables: bool) -> Vec<Param> {
        self.typed_list_either(items, variables, false)
    }

    /// [`Parser::typed_list`]; with `either`, an `(either T …)` type is read (as `object`:
    /// where predicates are declared, the types of their arguments are not used).
    fn typed_list_either(&mut self, items: &[Sexp], variables: bool, either: bool) -> Vec<Param> {
        let mut params: Vec<Param> = Vec::new();
        let mut untyped_from = 0;
        let mut iter = items.iter();
        while let Some(item) = iter.next() {
            if item.atom() == Some("-") {
                let ty = match iter.next() {
                    Some(ty) if either && self.either_type(ty) => None,
                    Some(ty) if ty.list().is_some() => {
                        self.push(
                            Diagnostic::error(ty.span, "`either` types are not supported here")
                                .with_note(
                                    "only in `:predicates`; declare a common supertype instead",
                                ),
                        );
                        None
                    }
                    Some(ty) => self.symbol(ty, "a type name"),
                    None => {
                        self.error(item.span, "`-` must be followed by a type");
                        None
                    }
                };
                if untyped_from == params.len() {
                    self.error(item.span, "a type with nothing before it to apply to");
                }
                for param in &mut params[untyped_from..] {
                    param.ty.clone_from(&ty);
                }
                untyped_from = params.len();
                continue;
            }
            let name = if variables {
                match item.atom() {
                    Some(text) if classify(text) == AtomKind::Variable && text.len() > 1 => {
                        Some(Name::from(&text[1..]))
                    }
                    _ => {
                        self.error(item.span, "expected a variable like `?r`");
                        None
                    }
                }
            } else {
                self.symbol(item, "a name")
            };
            if let Some(name) = name {
                params.push(Param {
                    name,
                    ty: None,
                    span: item.span,
                });
            }
        }
        params
    }

    /// Whether `ty` is `(either T …)` with type names.
    fn either_type(&mut self, ty: &Sexp) -> bool {
        let Some([head, types @ ..]) = ty.list() else {
            return false;
        };
        head.atom() == Some("either")
            && !types.is_empty()
            && types
                .iter()
                .all(|t| self.symbol(t, "a type name").is_some())
    }

    /// A condition that must be a conjunction: `()`, a literal, `(and ...)`, or a list of
    /// literals. Negation is pushed onto atoms (`(not (or a b))` reads as `(not a) (not b)`);
    /// what would make it a disjunction is refused.
    pub(crate) fn condition(&mut self, sexp: &Sexp) -> Vec<Literal> {
        let mut dnf = self.dnf(sexp, false, Disjunctions::Refused);
        // Refusing every disjunction leaves exactly one conjunction.
        dnf.pop().unwrap_or_default()
    }

    /// An action's precondition, which may be disjunctive (`or`, `imply`, a negated `and`):
    /// the literals every disjunct of its disjunctive normal form shares, and what else each
    /// disjunct needs (empty when one conjunction is all there is).
    fn action_precondition(&mut self, sexp: &Sexp) -> (Vec<Literal>, Vec<Vec<Literal>>) {
        let mut dnf = self.dnf(sexp, false, Disjunctions::Read);
        if dnf.len() <= 1 {
            return (dnf.pop().unwrap_or_default(), Vec::new());
        }
        // The same literal written in two places differs in its span alone.
        let text = |d: &[Literal]| d.iter().map(ToString::to_string).collect::<Vec<_>>();
        let texts: Vec<Vec<String>> = dnf.iter().map(|d| text(d)).collect();
        let mut common_texts: Vec<&String> = Vec::new();
        let mut common: Vec<Literal> = Vec::new();
        for (literal, t) in dnf[0].iter().zip(&texts[0]) {
            if !common_texts.contains(&t) && texts[1..].iter().all(|d| d.contains(t)) {
                common_texts.push(t);
                common.push(literal.clone());
            }
        }
        for (disjunct, texts) in dnf.iter_mut().zip(&texts) {
            let mut keep = texts.iter().map(|t| !common_texts.contains(&t));
            disjunct.retain(|_| keep.next().unwrap_or(true));
        }
        if dnf.iter().any(Vec::is_empty) {
            // One disjunct needs nothing beyond the shared literals: the disjunction always holds.
            dnf.clear();
        }
        (common, dnf)
    }

    /// `sexp`, negated when `negated`, in disjunctive normal form: the conjunctions of literals
    /// one of which must hold, with negation pushed onto atoms. A malformed or refused part is
    /// reported and read as true, so that one pass finds every error.
    fn dnf(&mut self, sexp: &Sexp, negated: bool, disjunctions: Disjunctions) -> Dnf {
        let truth = vec![Vec::new()];
        let Some(items) = sexp.list() else {
            self.error(sexp.span, "expected a condition in parentheses");
            return truth;
        };
        let Some(head) = items.first() else {
            return truth;
        };
        // `and` joins its parts, `or` offers them; under `not` each is the other.
        let (any, parts) = if head.list().is_some() {
            // An implicit conjunction: `((peis ?p) (pc ?p cams ?c))`.
            (negated, items)
        } else {
            match head.atom() {
                Some("and") => (negated, &items[1..]),
                Some("or") => (!negated, &items[1..]),
                Some("not") => {
                    let [_, inner] = items else {
                        self.error(sexp.span, "`not` takes exactly one condition");
                        return truth;
                    };
                    if inner.list().is_none() {
                        // Reported as the atom it should be.
                        self.atom(inner);
                        return truth;
                    }
                    return self.dnf(inner, !negated, disjunctions);
                }
                Some("imply") => {
                    let [_, premise, conclusion] = items else {
                        self.error(sexp.span, "`imply` takes exactly two conditions");
                        return truth;
                    };
                    // `(imply a b)` is `(or (not a) b)`; negated, `(and a (not b))`.
                    let premise = self.dnf(premise, !negated, disjunctions);
                    let conclusion = self.dnf(conclusion, negated, disjunctions);
                    let parts = vec![premise, conclusion];
                    return if negated {
                        self.all_of(parts, sexp.span)
                    } else {
                        self.any_of(parts, sexp.span, head, negated, disjunctions)
                    };
                }
                Some("=") => {
                    let [_, a, b] = items else {
                        self.error(sexp.span, "`=` takes exactly two arguments");
                        return truth;
                    };
                    let (Some(a), Some(b)) = (self.term(a), self.term(b)) else {
                        return truth;
                    };
                    let literal = if negated {
                        Literal::Neq(a, b, sexp.span)
                    } else {
                        Literal::Eq(a, b, sexp.span)
                    };
                    return vec![vec![literal]];
                }
                _ if is_connective(head) => {
                    self.unsupported(head, "in conditions");
                    return truth;
                }
                _ => {
                    let Some(atom) = self.atom(sexp) else {
                        return truth;
                    };
                    let literal = if negated {
                        Literal::Neg(atom)
                    } else {
                        Literal::Pos(atom)
                    };
                    return vec![vec![literal]];
                }
            }
        };
        let parts: Vec<Dnf> = parts
            .iter()
            .map(|part| self.dnf(part, negated, disjunctions))
            .collect();
        if any {
            self.any_of(parts, sexp.span, head, negated, disjunctions)
        } else {
            self.all_of(parts, sexp.span)
        }
    }

    /// The disjunction of `parts`, each in disjunctive normal form.
    fn any_of(
        &mut self,
        parts: Vec<Dnf>,
        span: Span,
        head: &Sexp,
        negated: bool,
        disjunctions: Disjunctions,
    ) -> Dnf {
        let truth = vec![Vec::new()];
        if parts.is_empty() {
            self.error(span, "an empty disjunction can never hold");
            return truth;
        }
        if parts.len() == 1 {
            return parts.into_iter().flatten().collect();
        }
        if disjunctions == Disjunctions::Refused {
            let name = head.atom().unwrap_or("and");
            let under = if negated { " under `not`" } else { "" };
            self.push(
                Diagnostic::error(
                    head.span,
                    format!("`{name}`{under} is not supported here: it makes a disjunction"),
                )
                .with_note(
                    "only an action's `:precondition` may be disjunctive; goals and the \
                     conditions of functionalities and methods are conjunctions",
                ),
            );
            return truth;
        }
        let disjuncts: usize = parts.iter().map(Vec::len).sum();
        if disjuncts > MAX_DISJUNCTS {
            self.too_many_disjuncts(span);
            return truth;
        }
        parts.into_iter().flatten().collect()
    }

    /// The conjunction of `parts`, each in disjunctive normal form: every way to pick one
    /// disjunct of each.
    fn all_of(&mut self, parts: Vec<Dnf>, span: Span) -> Dnf {
        let disjuncts = parts
            .iter()
            .fold(1usize, |n, part| n.saturating_mul(part.len()));
        if disjuncts > MAX_DISJUNCTS {
            self.too_many_disjuncts(span);
            return vec![Vec::new()];
        }
        let mut out: Dnf = vec![Vec::new()];
        for part in parts {
            out = out
                .iter()
                .flat_map(|left| {
                    part.iter().map(move |right| {
                        let mut both = left.clone();
                        both.extend(right.iter().cloned());
                        both
                    })
                })
                .collect();
        }
        out
    }

    fn too_many_disjuncts(&mut self, span: Span) {
        self.push(
            Diagnostic::error(
                span,
                format!(
                    "this condition has more than {MAX_DISJUNCTS} disjuncts in disjunctive normal form"
                ),
            )
            .with_note("each disjunct becomes operators of its own; rewrite the action as several"),
        );
    }

    fn unsupported(&mut self, head: &Sexp, context: &str) {
        let name = head.atom().unwrap_or("?");
        self.push(
            Diagnostic::error(head.span, format!("`{name}` is not supported {context}")).with_note(
                format!(
                    "supported requirements: {}",
                    SUPPORTED_REQUIREMENTS
                        .iter()
                        .map(|r| format!(":{r}"))
                        .collect::<Vec<_>>()
                        .join(" ")
                ),
            ),
        );
    }

    /// An information type, `(image ?p)` or `(image ?p :hz 25)`.
    fn info(&mut self, sexp: &Sexp) -> Option<Info> {
        let Some(items) = sexp.list() else {
            self.error(sexp.span, "expected information like `(image ?p)`");
            return None;
        };
        let Some(head) = items.first() else {
            self.error(
                sexp.span,
                "expected information like `(image ?p)`, found `()`",
            );
            return None;
        };
        let name = self.symbol(head, "an information name")?;
        let mut args = Vec::new();
        let mut hz = None;
        let mut iter = items[1..].iter();
        while let Some(item) = iter.next() {
            if item.atom() == Some(":hz") {
                match iter.next() {
                    Some(value) => hz = self.rate(value),
                    None => self.error(item.span, "`:hz` needs a rate"),
                }
            } else if let Some(term) = self.term(item) {
                args.push(term);
            }
        }
        Some(Info {
            name,
            args,
            hz,
            span: sexp.span,
        })
    }

    /// `((image ?p) (odometry ?r))`, `(image ?p)` alone, or `()`.
    fn infos(&mut self, sexp: &Sexp) -> Vec<Info> {
        match sexp.list() {
            Some([]) => Vec::new(),
            Some([first, ..]) if first.atom().is_some() => self.info(sexp).into_iter().collect(),
            Some(items) => items.iter().filter_map(|item| self.info(item)).collect(),
            None => {
                self.error(
                    sexp.span,
                    "expected a list of information like `((image ?p))`",
                );
                Vec::new()
            }
        }
    }

    fn list_of<'a>(&mut self, sexp: &'a Sexp, what: &str) -> &'a [Sexp] {
        match sexp.list() {
            Some(items) => items,
            None => {
                self.error(sexp.span, format!("expected a list of {what}"));
                &[]
            }
        }
    }

    /// `(:functionality NAME :parameters ... )`
    pub(crate) fn functionality(&mut self, form: &Sexp, items: &[Sexp]) -> Option<Functionality> {
        let name_sexp = items.get(1)?;
        let name = self.symbol(name_sexp, "a functionality name")?;
        let what = format!("functionality `{name}`");
        let fields = self.fields(
            &items[2..],
            &[
                ":parameters",
                ":component",
                ":precondition",
                ":input",
                ":output",
                ":postcondition",
                ":cost",
            ],
            &what,
        );
        let params = self.optional(&fields, ":parameters", |p, sexp| p.params(sexp, true));
        let component = match self.require(&fields, ":component", &what, name_sexp.span) {
            Some(sexp) => match sexp.list() {
                Some([p, c]) => match (self.term(p), self.term(c)) {
                    (Some(Term::Var(p)), Some(Term::Var(c))) => Some((p, c)),
                    (Some(_), Some(_)) => {
                        self.error(
                            sexp.span,
                            "`:component` takes two parameters, like `(?p ?c)`",
                        );
                        None
                    }
                    _ => None,
                },
                _ => {
                    self.push(
                        Diagnostic::error(sexp.span, "`:component` takes two parameters")
                            .with_note("the PEIS and the component, like `:component (?p ?c)`"),
                    );
                    None
                }
            },
            None => None,
        };
        let precondition = self.optional(&fields, ":precondition", Self::condition);
        let inputs = self.optional(&fields, ":input", Self::infos);
        let outputs = self.optional(&fields, ":output", Self::infos);
        let postcondition = self.optional(&fields, ":postcondition", Self::condition);
        let cost = match Self::field(&fields, ":cost") {
            // A malformed cost is reported; keep the functionality so that its
            // name still resolves and later checks do not cascade.
            Some(sexp) => self.natural(sexp, "a cost").unwrap_or(0),
            None => 0,
        };
        Some(Functionality {
            name,
            params,
            // An empty component means it was missing or malformed (already reported).
            component: component.unwrap_or_default(),
            precondition,
            inputs,
            outputs,
            postcondition,
            cost,
            span: form.span,
            name_span: name_sexp.span,
        })
    }

    /// `(:task NAME :parameters ... [:input ...] [:output ...])`
    pub(crate) fn task(&mut self, form: &Sexp, items: &[Sexp]) -> Option<Task> {
        let name_sexp = items.get(1)?;
        let name = self.symbol(name_sexp, "a task name")?;
        let what = format!("task `{name}`");
        let fields = self.fields(&items[2..], &[":parameters", ":input", ":output"], &what);
        let params = self.optional(&fields, ":parameters", |p, sexp| p.params(sexp, true));
        let inputs = self.optional(&fields, ":input", Self::infos);
        let outputs = self.optional(&fields, ":output", Self::infos);
        Some(Task {
            name,
            params,
            inputs,
            outputs,
            span: form.span,
            name_span: name_sexp.span,
        })
    }

    /// `(:information NAME :format FORMAT)`
    fn information(&mut self, form: &Sexp, items: &[Sexp]) -> Option<Information> {
        let name_sexp = items.get(1)?;
        let name = self.symbol(name_sexp, "an information name like `global-pos`")?;
        let what = format!("information `{name}`");
        let fields = self.fields(&items[2..], &[":format"], &what);
        let sexp = self.require(&fields, ":format", &what, name_sexp.span)?;
        match crate::format::parse_format(sexp) {
            Ok(format) => Some(Information {
                name,
                format,
                span: form.span,
                name_span: name_sexp.span,
            }),
            Err((span, message)) => {
                self.error(span, message);
                None
            }
        }
    }

    /// `(:method NAME :parameters ... :task ... :subtasks ...)`
    pub(crate) fn method(&mut self, form: &Sexp, items: &[Sexp]) -> Option<Method> {
        let name_sexp = items.get(1)?;
        let name = self.symbol(name_sexp, "a method name")?;
        let what = format!("method `{name}`");
        let fields = self.fields(
            &items[2..],
            &[
                ":parameters",
                ":task",
                ":precondition",
                ":subtasks",
                ":channels",
                ":inputs",
                ":outputs",
            ],
            &what,
        );
        let params = self.optional(&fields, ":parameters", |p, sexp| p.params(sexp, true));
        let task = self
            .require(&fields, ":task", &what, name_sexp.span)
            .and_then(|t| self.call(t, "the task this method decomposes"));
        let precondition = self.optional(&fields, ":precondition", Self::condition);
        let mut subtasks = Vec::new();
        if let Some(sexp) = Self::field(&fields, ":subtasks") {
            for item in self.list_of(sexp, "subtasks like `((f1 (cameras ?p ?c)))`") {
                match item.list() {
                    Some([label, call]) => {
                        let label = self.symbol(label, "a subtask label");
                        let call = self.call(call, "a subtask like `(cameras ?p ?c)`");
                        if let (Some(label), Some(call)) = (label, call) {
                            subtasks.push(Subtask {
                                label,
                                call,
                                span: item.span,
                            });
                        }
                    }
                    _ => self.error(item.span, "expected a subtask like `(f1 (cameras ?p ?c))`"),
                }
            }
        }
        let mut channels = Vec::new();
        if let Some(sexp) = Self::field(&fields, ":channels") {
            for item in self.list_of(sexp, "channels like `((f1 f2 (image ?p)))`") {
                match item.list() {
                    Some([from, to, info]) => {
                        let from = self.symbol(from, "a subtask label");
                        let to = self.symbol(to, "a subtask label");
                        let info = self.info(info);
                        if let (Some(from), Some(to), Some(info)) = (from, to, info) {
                            channels.push(ChannelSpec {
                                from,
                                to,
                                info,
                                span: item.span,
                            });
                        }
                    }
                    _ => self.error(item.span, "expected a channel like `(f1 f2 (image ?p))`"),
                }
            }
        }
        let inputs = self.optional(&fields, ":inputs", Self::redirects);
        let outputs = self.optional(&fields, ":outputs", Self::redirects);
        Some(Method {
            name,
            params,
            task: task?,
            precondition,
            subtasks,
            channels,
            inputs,
            outputs,
            span: form.span,
            name_span: name_sexp.span,
        })
    }

    fn redirects(&mut self, sexp: &Sexp) -> Vec<Redirect> {
        let mut out = Vec::new();
        for item in self.list_of(sexp, "entries like `(((global-pos ?r) f2))`") {
            match item.list() {
                Some([info, label]) => {
                    let info = self.info(info);
                    let label = self.symbol(label, "a subtask label");
                    if let (Some(info), Some(label)) = (info, label) {
                        out.push(Redirect {
                            info,
                            label,
                            span: item.span,
                        });
                    }
                }
                _ => self.error(item.span, "expected an entry like `((global-pos ?r) f2)`"),
            }
        }
        out
    }

    /// `(:action NAME :parameters ... :precondition ... :effect ... [:configure ...])`
    pub(crate) fn action(&mut self, form: &Sexp, items: &[Sexp]) -> Option<Action> {
        let name_sexp = items.get(1)?;
        let name = self.symbol(name_sexp, "an action name")?;
        let what = format!("action `{name}`");
        let fields = self.fields(
            &items[2..],
            &[
                ":parameters",
                ":precondition",
                ":effect",
                ":configure",
                ":observe",
            ],
            &what,
        );
        let params = self.optional(&fields, ":parameters", |p, sexp| p.params(sexp, true));
        let (precondition, alternatives) =
            self.optional(&fields, ":precondition", Self::action_precondition);
        let mut effects = Vec::new();
        let mut chances = Vec::new();
        let mut conditional = Vec::new();
        if let Some(sexp) = Self::field(&fields, ":effect") {
            self.effect_into(
                sexp,
                &mut effects,
                Some(&mut chances),
                Some(&mut conditional),
            );
        }
        let configure = Self::field(&fields, ":configure")
            .and_then(|c| self.call(c, "a configuration goal like `(navigate ?r ?to)`"));
        let observe = self.optional(&fields, ":observe", Self::observe);
        let action = Action {
            name,
            params,
            precondition,
            alternatives,
            effects,
            conditional,
            configure,
            chances,
            observe,
            span: form.span,
            name_span: name_sexp.span,
        };
        if action.variant_count() > MAX_DISJUNCTS {
            self.push(
                Diagnostic::error(
                    name_sexp.span,
                    format!(
                        "action `{}` has more than {MAX_DISJUNCTS} variants: the disjuncts of its \
                         precondition times the ways each `when` condition holds or fails",
                        action.name
                    ),
                )
                .with_note("each becomes operators of its own; write the action as several"),
            );
        }
        Some(action)
    }

    /// `:observe`: an atom, a list of atoms or `(and ...)` of atoms.
    fn observe(&mut self, sexp: &Sexp) -> Vec<Atom> {
        let mut atoms = Vec::new();
        for literal in self.condition(sexp) {
            match literal {
                Literal::Pos(atom) => atoms.push(atom),
                other => self.push(
                    Diagnostic::error(other.span(), "`:observe` lists atoms, such as `(at ?t ?x)`")
                        .with_note("the action reveals whether each atom holds, true or false"),
                ),
            }
        }
        atoms
    }

    /// A probability: a number in `[0, 1]`, decimal (`0.7`) or a fraction (`1/3`).
    fn probability(&mut self, sexp: &Sexp) -> Option<f64> {
        let text = sexp.atom().filter(|t| classify(t) == AtomKind::Number);
        let Some(text) = text else {
            self.push(
                Diagnostic::error(sexp.span, "expected a probability like `0.7` or `1/3`")
                    .with_note("`(probabilistic P1 OUTCOME1 P2 OUTCOME2 ...)`"),
            );
            return None;
        };
        let value = match text.split_once('/') {
            Some((num, den))
                if is_well_formed_number(num) && den.bytes().all(|b| b.is_ascii_digit()) =>
            {
                match (num.parse::<f64>(), den.parse::<f64>()) {
                    (Ok(n), Ok(d)) if d > 0.0 => Some(n / d),
                    _ => None,
                }
            }
            Some(_) => None,
            None if self.check_number(text, sexp.span) => text.parse::<f64>().ok(),
            None => return None,
        };
        match value {
            Some(p) if (0.0..=1.0).contains(&p) => Some(p),
            Some(_) => {
                self.push(
                    Diagnostic::error(sexp.span, format!("probability `{text}` is not in [0, 1]"))
                        .with_label("out of range"),
                );
                None
            }
            None => {
                self.error(sexp.span, format!("malformed probability `{text}`"));
                None
            }
        }
    }

    /// `(probabilistic P1 X1 P2 X2 ...)` or `(oneof X1 X2 ...)`, whose
    /// outcomes `item` reads; checks that the probabilities sum to at most 1.
    pub(crate) fn probabilistic<T>(
        &mut self,
        sexp: &Sexp,
        items: &[Sexp],
        mut item: impl FnMut(&mut Self, &Sexp) -> Vec<T>,
    ) -> Option<Probabilistic<T>> {
        let oneof = items.first().and_then(Sexp::atom) == Some("oneof");
        let mut outcomes = Vec::new();
        if oneof {
            let n = items.len() - 1;
            if n == 0 {
                self.error(sexp.span, "`oneof` needs at least one outcome");
                return None;
            }
            for x in &items[1..] {
                outcomes.push(Weighted {
                    probability: 1.0 / n as f64,
                    items: item(self, x),
                    span: x.span,
                });
            }
        } else {
            let rest = &items[1..];
            if rest.is_empty() || rest.len() % 2 != 0 {
                self.push(
                    Diagnostic::error(
                        sexp.span,
                        "`probabilistic` takes pairs of a probability and an outcome",
                    )
                    .with_note(
                        "`(probabilistic 0.7 (at newspaper entrance) 0.3 (at newspaper kitchen))`",
                    ),
                );
                return None;
            }
            let mut ok = true;
            for pair in rest.chunks(2) {
                let probability = self.probability(&pair[0]);
                let items = item(self, &pair[1]);
                match probability {
                    Some(probability) => outcomes.push(Weighted {
                        probability,
                        items,
                        span: pair[0].span.to(pair[1].span),
                    }),
                    None => ok = false,
                }
            }
            let sum: f64 = outcomes.iter().map(|o| o.probability).sum();
            if ok && sum > 1.0 + PROBABILITY_EPSILON {
                self.push(
                    Diagnostic::error(
                        sexp.span,
                        format!("the probabilities sum to {sum}, more than 1"),
                    )
                    .with_note("outcomes exclude each other: their probabilities sum to at most 1 (the rest is \"nothing happens\")"),
                );
                return None;
            }
            if !ok {
                return None;
            }
        }
        Some(Probabilistic {
            outcomes,
            span: sexp.span,
        })
    }

    /// Reads an effect into `out`; a `(probabilistic ...)` form goes to
    /// `chances`, which is `None` inside one (they do not nest).
    fn effect_into(
        &mut self,
        sexp: &Sexp,
        out: &mut Vec<Effect>,
        mut chances: Option<&mut Vec<Probabilistic<Effect>>>,
        mut conditional: Option<&mut Vec<Conditional>>,
    ) {
        let Some(items) = sexp.list() else {
            self.error(sexp.span, "expected an effect in parentheses");
            return;
        };
        let Some(head) = items.first() else {
            return;
        };
        if head.list().is_some() {
            for item in items {
                self.effect_into(
                    item,
                    out,
                    chances.as_deref_mut(),
                    conditional.as_deref_mut(),
                );
            }
            return;
        }
        match head.atom() {
            Some("and") => {
                for item in &items[1..] {
                    self.effect_into(
                        item,
                        out,
                        chances.as_deref_mut(),
                        conditional.as_deref_mut(),
                    );
                }
            }
            Some("when") => {
                let Some(conditional) = conditional else {
                    self.error(head.span, "`when` is not supported inside `probabilistic`");
                    return;
                };
                let [_, condition, effect] = items else {
                    self.error(sexp.span, "`when` takes a condition and an effect");
                    return;
                };
                let condition = self.condition(condition);
                let (mut effects, mut chances, mut nested) = (Vec::new(), Vec::new(), Vec::new());
                self.effect_into(effect, &mut effects, Some(&mut chances), Some(&mut nested));
                if let Some(form) = chances.first() {
                    self.error(form.span, "`probabilistic` is not supported inside `when`");
                }
                if let Some(inner) = nested.first() {
                    self.error(inner.span, "`when` does not nest")
                }
                conditional.push(Conditional {
                    condition,
                    effects,
                    span: sexp.span,
                });
            }
            Some("probabilistic" | "oneof") => match chances {
                Some(chances) => {
                    let form = self.probabilistic(sexp, items, |p, x| {
                        let mut effects = Vec::new();
                        p.effect_into(x, &mut effects, None, None);
                        effects
                    });
                    chances.extend(form);
                }
                None => self.push(
                    Diagnostic::error(head.span, "probabilistic effects do not nest")
                        .with_note("write the combined outcomes in one `(probabilistic ...)`"),
                ),
            },
            Some("not") => match items {
                [_, inner] => {
                    if let Some(atom) = self.atom(inner) {
                        out.push(Effect::Del(atom));
                    }
                }
                _ => self.error(sexp.span, "`not` takes exactly one atom"),
            },
            Some("increase") => match items {
                [_, target, amount] => {
                    let target_ok = target
                        .list()
                        .is_some_and(|t| t.len() == 1 && t[0].atom() == Some("total-cost"));
                    if !target_ok {
                        self.push(
                            Diagnostic::error(target.span, "only `(total-cost)` can be increased")
                                .with_note("`:action-costs` allows `(increase (total-cost) N)`"),
                        );
                        return;
                    }
                    let amount = if amount.atom().is_some() {
                        self.natural(amount, "a cost").map(NumExpr::Number)
                    } else {
                        self.call(amount, "a numeric function like `(distance ?a ?b)`")
                            .map(NumExpr::Function)
                    };
                    if let Some(amount) = amount {
                        out.push(Effect::IncreaseCost(amount, sexp.span));
                    }
                }
                _ => self.error(sexp.span, "`increase` takes `(total-cost)` and an amount"),
            },
            _ if is_connective(head) || head.atom() == Some("decrease") => {
                self.unsupported(head, "in effects")
            }
            _ => {
                if let Some(atom) = self.atom(sexp) {
                    out.push(Effect::Add(atom));
                }
            }
        }
    }

    /// The items of a domain after `(domain NAME)`.
    pub(crate) fn domain_body(&mut self, name: Name, items: &[Sexp]) -> Domain {
        let mut domain = Domain {
            name,
            ..Domain::default()
        };
        for form in items {
            let Some(list) = form.list() else {
                self.error(form.span, "expected a section like `(:functionality ...)`");
                continue;
            };
            let head = list.first().and_then(Sexp::atom);
            if head.is_some() && list.len() < 2 {
                self.error(
                    form.span,
                    format!("`{}` is empty", head.unwrap_or_default()),
                );
                continue;
            }
            match head {
                Some(":requirements") => {
                    for item in &list[1..] {
                        match item.atom().and_then(|t| t.strip_prefix(':')) {
                            Some(req)
                                if SUPPORTED_REQUIREMENTS.contains(&req)
                                    || DECLARED_ONLY_REQUIREMENTS.contains(&req) =>
                            {
                                domain.requirements.push(req.into())
                            }
                            Some(req) => self.push(
                                Diagnostic::error(
                                    item.span,
                                    format!("requirement `:{req}` is not supported"),
                                )
                                .with_note(format!(
                                    "supported: {}",
                                    SUPPORTED_REQUIREMENTS
                                        .iter()
                                        .map(|r| format!(":{r}"))
                                        .collect::<Vec<_>>()
                                        .join(" ")
                                )),
                            ),
                            None => self.error(item.span, "expected a requirement like `:strips`"),
                        }
                    }
                }
                Some(":types") => {
                    for param in self.typed_list(&list[1..], false) {
                        let parent = param.ty.unwrap_or_else(|| "object".into());
                        // A type may be listed again (IPC's storage lists `area` under `object`
                        // and under `surface`): a parent refines `object`, and the same parent
                        // again changes nothing. Two other parents: validation says so.
                        if let Some(known) = domain.types.iter_mut().find(|t| t.name == param.name)
                        {
                            if &*parent == "object" || known.parent == parent {
                                continue;
                            }
                            if &*known.parent == "object" {
                                known.parent = parent;
                                continue;
                            }
                        }
                        domain.types.push(TypeDecl {
                            name: param.name,
                            parent,
                            span: param.span,
                        });
                    }
                }
                Some(":constants") => domain.constants = self.typed_list(&list[1..], false),
                Some(":predicates") => domain.predicates = self.declarations(&list[1..]),
                Some(":functions") => {
                    // `- number` after a function is PDDL's numeric type; drop it.
                    let mut rest = Vec::new();
                    let mut iter = list[1..].iter().peekable();
                    while let Some(item) = iter.next() {
                        if item.atom() == Some("-") {
                            match iter.next() {
                                Some(ty) if ty.atom() == Some("number") => {}
                                Some(ty) => self
                                    .error(ty.span, "functions have type `number`, nothing else"),
                                None => self.error(item.span, "`-` must be followed by a type"),
                            }
                        } else {
                            rest.push(item.clone());
                        }
                    }
                    domain.functions = self.declarations(&rest);
                }
                Some(":functionality") => {
                    if let Some(f) = self.functionality(form, list) {
                        domain.functionalities.push(f);
                    }
                }
                Some(":task") => {
                    if let Some(t) = self.task(form, list) {
                        domain.tasks.push(t);
                    }
                }
                Some(":method") => {
                    if let Some(m) = self.method(form, list) {
                        domain.methods.push(m);
                    }
                }
                Some(":action") => {
                    if let Some(a) = self.action(form, list) {
                        domain.actions.push(a);
                    }
                }
                Some(":information") => {
                    if let Some(i) = self.information(form, list) {
                        domain.information.push(i);
                    }
                }
                _ => self.push(
                    Diagnostic::error(
                        list.first().map_or(form.span, |h| h.span),
                        "unknown section in domain",
                    )
                    .with_note(
                        "sections: :requirements :types :constants :predicates :functions \
                         :functionality :task :method :action :information",
                    ),
                ),
            }
        }
        domain
    }

    fn declarations(&mut self, items: &[Sexp]) -> Vec<PredicateDecl> {
        let mut out = Vec::new();
        for item in items {
            let Some(list) = item.list() else {
                self.error(item.span, "expected a declaration like `(at ?r ?x)`");
                continue;
            };
            let Some(head) = list.first() else {
                self.error(
                    item.span,
                    "expected a declaration like `(at ?r ?x)`, found `()`",
                );
                continue;
            };
            if let Some(name) = self.symbol(head, "a predicate name") {
                out.push(PredicateDecl {
                    name,
                    params: self.typed_list_either(&list[1..], true, true),
                    span: item.span,
                });
            }
        }
        out
    }

    /// An outcome of an uncertain `:init` fact: a ground atom or `(and ...)` of them.
    fn ground_atoms(&mut self, sexp: &Sexp) -> Vec<Atom> {
        let mut atoms = Vec::new();
        for literal in self.condition(sexp) {
            match literal {
                Literal::Pos(atom) => match atom.args.iter().find_map(Term::var) {
                    Some(var) => self.error(
                        atom.span,
                        format!("`:init` facts are ground, but `?{var}` is a variable"),
                    ),
                    None => atoms.push(atom),
                },
                other => self.push(
                    Diagnostic::error(other.span(), "an uncertain `:init` outcome lists atoms")
                        .with_note("what is not listed is false (closed world)"),
                ),
            }
        }
        atoms
    }

    /// The items of a problem after `(problem NAME)`.
    pub(crate) fn problem_body(&mut self, name: Name, items: &[Sexp]) -> Problem {
        let mut problem = Problem {
            name,
            ..Problem::default()
        };
        let mut saw_domain = false;
        let mut saw_goal = false;
        for form in items {
            let Some(list) = form.list() else {
                self.error(form.span, "expected a section like `(:init ...)`");
                continue;
            };
            match list.first().and_then(Sexp::atom) {
                Some(":domain") => match list {
                    [_, name] => {
                        saw_domain = true;
                        problem.domain = self.symbol(name, "a domain name").unwrap_or_default();
                        problem.domain_span = name.span;
                    }
                    _ => self.error(form.span, "expected `(:domain NAME)`"),
                },
                Some(":objects") => problem.objects = self.typed_list(&list[1..], false),
                Some(":init") => {
                    for item in &list[1..] {
                        match item.list() {
                            Some([eq, fluent, value]) if eq.atom() == Some("=") => {
                                let fluent = self.call(fluent, "a numeric fluent");
                                let value = self.natural(value, "a fluent value");
                                if let (Some(fluent), Some(value)) = (fluent, value) {
                                    problem.numeric_init.push((fluent, value));
                                }
                            }
                            Some([head, ..])
                                if matches!(head.atom(), Some("probabilistic" | "oneof")) =>
                            {
                                let items = item.list().unwrap_or_default();
                                let form =
                                    self.probabilistic(item, items, |p, x| p.ground_atoms(x));
                                problem.uncertain.extend(form);
                            }
                            _ => {
                                if let Some(atom) = self.atom(item) {
                                    if let Some(var) = atom.args.iter().find_map(Term::var) {
                                        self.error(
                                            atom.span,
                                            format!("`:init` facts are ground, but `?{var}` is a variable"),
                                        );
                                    } else {
                                        problem.init.push(atom);
                                    }
                                }
                            }
                        }
                    }
                }
                Some(":goal") => match list {
                    [_, goal] => {
                        saw_goal = true;
                        problem.goal = self.condition(goal);
                    }
                    _ => self.error(form.span, "expected `(:goal CONDITION)`"),
                },
                Some(":metric") => {
                    let ok = matches!(list, [_, dir, target]
                        if dir.atom() == Some("minimize")
                        && target.list().is_some_and(|t| t.len() == 1 && t[0].atom() == Some("total-cost")));
                    if ok {
                        problem.metric = Some(Metric::MinimizeTotalCost);
                    } else {
                        self.error(
                            form.span,
                            "only `(:metric minimize (total-cost))` is supported",
                        );
                    }
                }
                Some(":requirements") => {}
                _ => self.push(
                    Diagnostic::error(
                        list.first().map_or(form.span, |h| h.span),
                        "unknown section in problem",
                    )
                    .with_note("sections: :domain :objects :init :goal :metric"),
                ),
            }
        }
        let whole = items
            .first()
            .map_or(Span::empty(0), |f| f.span.to(items[items.len() - 1].span));
        if !saw_domain {
            self.error(whole, "problem has no `(:domain NAME)`");
        }
        if !saw_goal {
            self.error(whole, "problem has no `(:goal ...)`");
        }
        problem
    }
}

fn is_connective(head: &Sexp) -> bool {
    matches!(
        head.atom(),
        Some("or" | "imply" | "forall" | "exists" | "when" | "either")
    )
}
