//! Checking a problem against its domain: the domain's name, object types,
//! and every atom of `:init` and `:goal` (declared predicate, arity, known
//! objects of the right types).

use std::collections::HashMap;

use crate::diagnostic::{Diagnostic, Diagnostics, Span};
use crate::model::{Atom, Domain, Literal, Name, Param, PredicateDecl, Problem, Term};

/// Checks `problem` against `domain`, returning every diagnostic found.
pub fn check_problem(domain: &Domain, problem: &Problem) -> Result<(), Diagnostics> {
    let mut c = Checker {
        diags: Vec::new(),
        objects: HashMap::new(),
        parents: domain
            .types
            .iter()
            .map(|t| (t.name.clone(), t.parent.clone()))
            .collect(),
    };
    if problem.domain != domain.name {
        c.diags.push(
            Diagnostic::error(
                problem.domain_span,
                format!(
                    "the problem is for domain `{}`, but the domain is `{}`",
                    problem.domain, domain.name
                ),
            )
            .with_note("`(:domain NAME)` must name the domain file's `(domain NAME)`"),
        );
    }
    let mut first_seen: HashMap<Name, Span> = HashMap::new();
    for p in &domain.constants {
        c.objects.insert(p.name.clone(), ty_of(p));
    }
    for p in &problem.objects {
        if let Some(&first) = first_seen.get(&p.name) {
            c.diags.push(
                Diagnostic::error(p.span, format!("duplicate object `{}`", p.name))
                    .with_secondary(first, "first declared here"),
            );
            continue;
        }
        if domain.constants.iter().any(|k| k.name == p.name) {
            c.diags.push(Diagnostic::error(
                p.span,
                format!("`{}` is already a constant of the domain", p.name),
            ));
            continue;
        }
        first_seen.insert(p.name.clone(), p.span);
        let ty = ty_of(p);
        if &*ty != "object" && !domain.types.iter().any(|t| t.name == ty) {
            c.diags.push(
                Diagnostic::error(p.span, format!("unknown type `{ty}`"))
                    .with_note("declare it in the domain's `(:types ...)`"),
            );
        }
        c.objects.insert(p.name.clone(), ty);
    }
    for atom in &problem.init {
        c.atom(atom, &domain.predicates, "predicate");
    }
    for atom in problem
        .uncertain
        .iter()
        .flat_map(|u| &u.outcomes)
        .flat_map(|o| &o.items)
    {
        c.atom(atom, &domain.predicates, "predicate");
    }
    for (call, _) in &problem.numeric_init {
        if &*call.name == "total-cost" && call.args.is_empty() {
            continue;
        }
        let atom = Atom {
            predicate: call.name.clone(),
            args: call.args.clone(),
            span: call.span,
        };
        c.atom(&atom, &domain.functions, "function");
    }
    for literal in &problem.goal {
        match literal {
            Literal::Pos(atom) | Literal::Neg(atom) => {
                c.atom(atom, &domain.predicates, "predicate")
            }
            Literal::Eq(a, b, span) | Literal::Neq(a, b, span) => {
                for t in [a, b] {
                    c.term(t, *span);
                }
            }
        }
    }
    if c.diags.is_empty() {
        Ok(())
    } else {
        c.diags.sort_by_key(|d| (d.span.start, d.span.end));
        Err(Diagnostics(c.diags))
    }
}

fn ty_of(p: &Param) -> Name {
    p.ty.clone().unwrap_or_else(|| "object".into())
}

struct Checker {
    diags: Vec<Diagnostic>,
    /// Objects and constants with their types.
    objects: HashMap<Name, Name>,
    parents: HashMap<Name, Name>,
}

impl Checker {
    fn is_a(&self, ty: &Name, ancestor: &str) -> bool {
        let mut t = ty;
        // Bounded: a malformed hierarchy may have a cycle.
        for _ in 0..64 {
            if ancestor == "object" || &**t == ancestor {
                return true;
            }
            match self.parents.get(t) {
                Some(p) => t = p,
                None => return false,
            }
        }
        false
    }

    /// The term's type, if it is a known object; reports it otherwise.
    fn term(&mut self, term: &Term, span: Span) -> Option<Name> {
        match term {
            Term::Var(v) => {
                self.diags.push(Diagnostic::error(
                    span,
                    format!("problems are ground, but `?{v}` is a variable"),
                ));
                None
            }
            Term::Const(name) => match self.objects.get(name) {
                Some(ty) => Some(ty.clone()),
                None => {
                    self.diags.push(
                        Diagnostic::error(span, format!("unknown object `{name}`"))
                            .with_note("declare it in `(:objects ...)`"),
                    );
                    None
                }
            },
        }
    }

    fn atom(&mut self, atom: &Atom, declared: &[PredicateDecl], what: &str) {
        let decl = declared.iter().find(|p| p.name == atom.predicate);
        let types: Vec<Option<Name>> = atom.args.iter().map(|t| self.term(t, atom.span)).collect();
        let Some(decl) = decl else {
            // Without `(:predicates ...)` a domain declares nothing to check against.
            if !declared.is_empty() || what == "function" {
                self.diags.push(
                    Diagnostic::error(atom.span, format!("unknown {what} `{}`", atom.predicate))
                        .with_note(format!("declare it in the domain's `(:{what}s ...)`")),
                );
            }
            return;
        };
        if decl.params.len() != atom.args.len() {
            let n = decl.params.len();
            self.diags.push(Diagnostic::error(
                atom.span,
                format!(
                    "wrong arity: `{}` takes {n} argument{}, given {}",
                    atom.predicate,
                    if n == 1 { "" } else { "s" },
                    atom.args.len()
                ),
            ));
            return;
        }
        for ((param, ty), arg) in decl.params.iter().zip(types).zip(&atom.args) {
            if let (Some(expected), Some(ty)) = (&param.ty, ty)
                && !self.is_a(&ty, expected)
            {
                self.diags.push(
                    Diagnostic::error(
                        atom.span,
                        format!(
                            "`{arg}` is a `{ty}`, but `{}` expects a `{expected}` there",
                            atom.predicate
                        ),
                    )
                    .with_note(format!("the domain declares {}", declaration(decl))),
                );
            }
        }
    }
}

/// `(at ?r - robot ?x - room)`, for notes.
fn declaration(decl: &PredicateDecl) -> String {
    let mut out = format!("({}", decl.name);
    for p in &decl.params {
        out.push_str(&format!(" ?{}", p.name));
        if let Some(ty) = &p.ty {
            out.push_str(&format!(" - {ty}"));
        }
    }
    out.push(')');
    out
}
