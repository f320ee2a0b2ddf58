//! The `.eco` domain language of Ecology: functionalities, tasks, methods,
//! actions and problems, plus `.facts` files describing an ecology state.
//!
//! Every entry point takes bytes and returns either the validated model or
//! every [`Diagnostic`] found, each with a byte span; [`render`] shows them as
//! `file:line:col` with a caret excerpt. Nothing here does IO, and no input
//! makes it panic.
//!
//! ```
//! let src = b"(define (domain tiny)
//!   (:functionality camera :parameters (?p ?c) :component (?p ?c)
//!     :precondition (pc ?p cam ?c) :output ((image ?p)) :cost 5))";
//! let domain = ecology_domain::parse_domain(src).unwrap();
//! assert_eq!(domain.functionalities[0].cost, 5);
//! ```

mod diagnostic;
mod facts;
mod format;
mod model;
mod parse;
mod problem;
mod state;
pub mod syntax;
mod validate;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_uncertain;

pub use diagnostic::{Diagnostic, Diagnostics, Span, line_col, render};
pub use format::{Field, FieldType, Format, Information};
pub use model::{
    Action, Atom, Call, ChannelSpec, Conditional, Domain, Effect, Functionality, Info, Literal,
    Method, Metric, Name, NumExpr, Param, PredicateDecl, Probabilistic, Problem, Redirect, Subtask,
    Task, Term, TypeDecl, Variant, Weighted,
};
pub use parse::{MAX_DISJUNCTS, PROBABILITY_EPSILON, SUPPORTED_REQUIREMENTS};
pub use problem::check_problem;
pub use state::{ComponentCost, EcologyState, Fact, Power};
pub use validate::ECOLOGY_PREDICATES;

use parse::Parser;

fn finish<T>(value: T, mut diags: Vec<Diagnostic>) -> Result<T, Diagnostics> {
    if diags.is_empty() {
        Ok(value)
    } else {
        diags.sort_by_key(|d| (d.span.start, d.span.end));
        Err(Diagnostics(diags))
    }
}

fn read(source: &[u8]) -> Result<(Vec<syntax::Sexp>, Parser, Span), Diagnostics> {
    let text = syntax::decode(source).map_err(|d| Diagnostics(vec![d]))?;
    let mut parser = Parser::default();
    let forms = syntax::read(text, &mut parser.diags);
    Ok((forms, parser, Span::new(0, text.len())))
}

/// Facts are parsed this many at a time between two `stop` checks.
const FACTS_PER_CHECK: usize = 1024;

/// Parses and validates a domain file.
pub fn parse_domain(source: &[u8]) -> Result<Domain, Diagnostics> {
    let (forms, mut parser, whole) = read(source)?;
    let Some((name, items)) = parser.define(&forms, "domain", whole) else {
        return Err(Diagnostics(parser.diags));
    };
    let mut domain = parser.domain_body(name, items);
    let mut diags = parser.diags;
    diags.extend(validate::validate(&mut domain));
    finish(domain, diags)
}

/// Parses a problem file; [`parse_problem_for`] also checks it against its domain.
pub fn parse_problem(source: &[u8]) -> Result<Problem, Diagnostics> {
    let (forms, mut parser, whole) = read(source)?;
    let Some((name, items)) = parser.define(&forms, "problem", whole) else {
        return Err(Diagnostics(parser.diags));
    };
    let problem = parser.problem_body(name, items);
    finish(problem, parser.diags)
}

/// Parses a problem file and checks it against `domain` ([`check_problem`]),
/// returning every diagnostic of both.
pub fn parse_problem_for(domain: &Domain, source: &[u8]) -> Result<Problem, Diagnostics> {
    let problem = parse_problem(source)?;
    check_problem(domain, &problem)?;
    Ok(problem)
}

/// Parses a `.facts` file: ground facts, one S-expression each.
pub fn parse_facts(source: &[u8]) -> Result<EcologyState, Diagnostics> {
    parse_facts_until(source, &mut || false).map(|read| read.state)
}

/// What [`parse_facts_until`] read.
#[derive(Debug)]
pub struct FactsRead {
    /// The facts read: all of them when `complete`, else those read before it stopped.
    pub state: EcologyState,
    /// Whether the whole file was read (`stop` never said to give up).
    pub complete: bool,
}

/// [`parse_facts`], asking `stop` now and then (every 16 KiB read, every 1,024 facts) whether to
/// give up, so that a budget for a whole command covers reading. When it gives up, the facts
/// read so far come back with `complete: false` (a large state takes a while to free: the
/// caller decides when).
pub fn parse_facts_until(
    source: &[u8],
    stop: &mut dyn FnMut() -> bool,
) -> Result<FactsRead, Diagnostics> {
    let text = syntax::decode(source).map_err(|d| Diagnostics(vec![d]))?;
    match facts::read(text, stop) {
        facts::Read::Done(state) => Ok(FactsRead {
            state,
            complete: true,
        }),
        facts::Read::Stopped(state) => Ok(FactsRead {
            state,
            complete: false,
        }),
        // The general reader, for what it says about the file.
        facts::Read::Unusual => facts_in_general(text, stop),
    }
}

/// [`parse_facts_until`] through the general reader (S-expressions, then facts), which reads
/// and reports anything.
fn facts_in_general(text: &str, stop: &mut dyn FnMut() -> bool) -> Result<FactsRead, Diagnostics> {
    let mut parser = Parser::default();
    let mut state = EcologyState::new();
    let stopped = |state| {
        Ok(FactsRead {
            state,
            complete: false,
        })
    };
    let Some(forms) = syntax::read_until(text, &mut parser.diags, stop) else {
        return stopped(state);
    };
    for (i, form) in forms.iter().enumerate() {
        if i % FACTS_PER_CHECK == FACTS_PER_CHECK - 1 && stop() {
            return stopped(state);
        }
        let Some(call) = parser.call(form, "a fact like `(peis astrid)`") else {
            continue;
        };
        let mut args = Vec::with_capacity(call.args.len());
        for arg in call.args {
            match arg {
                Term::Const(name) => args.push(name),
                Term::Var(var) => parser.diags.push(Diagnostic::error(
                    call.span,
                    format!("facts are ground, but `?{var}` is a variable"),
                )),
            }
        }
        if args.len() != form.list().map_or(0, |l| l.len() - 1) {
            continue;
        }
        let fact = Fact {
            predicate: call.name,
            args,
        };
        match state::check_fact(&fact, call.span) {
            Some(diag) => parser.diags.push(diag),
            None => {
                state.insert(fact);
            }
        }
    }
    finish(state, parser.diags).map(|state| FactsRead {
        state,
        complete: true,
    })
}

/// Parses ground literals separated by white space, such as `(thing-at
/// newspaper kitchen) (not (thing-at newspaper entrance))` (what a sensing
/// component reports): atoms and negated atoms, with no variables.
pub fn parse_literals(source: &str) -> Result<Vec<Literal>, Diagnostics> {
    let (forms, mut parser, _) = read(source.as_bytes())?;
    let mut literals = Vec::new();
    for form in &forms {
        if form.list().is_some_and(<[_]>::is_empty) {
            parser
                .diags
                .push(Diagnostic::error(form.span, "expected a literal, not `()`"));
        }
        for literal in parser.condition(form) {
            match &literal {
                Literal::Pos(atom) | Literal::Neg(atom) => {
                    if let Some(var) = atom.args.iter().find_map(Term::var) {
                        parser.diags.push(Diagnostic::error(
                            atom.span,
                            format!("a literal here is ground, but `?{var}` is a variable"),
                        ));
                    }
                    literals.push(literal);
                }
                Literal::Eq(_, _, span) | Literal::Neq(_, _, span) => {
                    parser.diags.push(Diagnostic::error(
                        *span,
                        "expected an atom or a negated atom",
                    ));
                }
            }
        }
    }
    finish(literals, parser.diags)
}

/// Parses a ground goal such as `(navigate astrid bedroom)`.
pub fn parse_goal(source: &str) -> Result<Call, Diagnostics> {
    let (forms, mut parser, whole) = read(source.as_bytes())?;
    let call = match &forms[..] {
        [form] => parser.call(form, "a goal like `(navigate astrid bedroom)`"),
        _ => {
            parser.diags.push(Diagnostic::error(
                whole,
                "expected one goal like `(navigate astrid bedroom)`",
            ));
            None
        }
    };
    if let Some(call) = &call
        && let Some(var) = call.args.iter().find_map(Term::var)
    {
        parser.diags.push(Diagnostic::error(
            call.span,
            format!("a goal is ground, but `?{var}` is a variable"),
        ));
    }
    match call {
        Some(call) => finish(call, parser.diags),
        None => Err(Diagnostics(parser.diags)),
    }
}
