//! Semantic checks of what actions add for uncertainty: the atoms of
//! `(probabilistic ...)` outcomes and of `:observe` (declared predicates,
//! arities, variables among the parameters).
//!
//! A child of `validate` so that it reuses the validator's checks; kept apart
//! so that deterministic domains go through `validate` unchanged.

use super::{Validator, names};
use crate::diagnostic::Diagnostic;
use crate::model::{Action, Domain, Effect};

impl Validator {
    pub(super) fn uncertain_action(&mut self, domain: &Domain, a: &Action) {
        let what = format!("action `{}`", a.name);
        let params = names(&a.params);
        for outcome in a.chances.iter().flat_map(|c| &c.outcomes) {
            for effect in &outcome.items {
                match effect {
                    Effect::Add(atom) | Effect::Del(atom) => {
                        self.vars_declared(&atom.args, atom.span, &params, &what);
                        self.predicate_arity(domain, atom, true);
                    }
                    // One cost per action keeps expected costs a sum over
                    // the actions a branch runs.
                    Effect::IncreaseCost(_, span) => self.diags.push(
                        Diagnostic::error(*span, "an outcome cannot change the action's cost")
                            .with_note(
                                "put `(increase (total-cost) N)` outside `(probabilistic ...)`",
                            ),
                    ),
                }
            }
        }
        for atom in &a.observe {
            self.vars_declared(&atom.args, atom.span, &params, &what);
            if domain.predicates.iter().any(|p| p.name == atom.predicate) {
                self.predicate_arity(domain, atom, true);
            } else {
                self.diags.push(
                    Diagnostic::error(
                        atom.span,
                        format!("`:observe` names undeclared predicate `{}`", atom.predicate),
                    )
                    .with_note("an action observes atoms of the domain's `(:predicates ...)`"),
                );
            }
        }
    }
}
