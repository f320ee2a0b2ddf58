//! What the executive runs: a plan of actions that may branch on what a
//! sensing action observes (a conditional plan, the class of PTLplan's), and
//! the observations themselves.
//!
//! A [`Plan`] is a sequence of [`PlannedAction`]s followed by the
//! [`PlanBranch`]es of its last action, each naming the observation that
//! selects it; a plan without branches is the plain sequence the
//! deterministic planner makes. An [`Observation`] is one ground atom and
//! whether it was seen to hold, written `(thing-at newspaper kitchen)` or
//! `(not (thing-at newspaper entrance))` in the `C.observed` tuple a sensing
//! component writes.

use std::collections::HashMap;
use std::fmt;
use std::sync::Arc;

use ecology_domain::{Call, Literal, parse_literals};

/// One step of a plan: an action and the configuration goal that performs it.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedAction {
    /// The action, like `(move astrid living-room entrance)`.
    pub action: String,
    /// Its `:configure` goal, like `(navigate astrid entrance)`; `None` when it
    /// needs no configuration.
    pub goal: Option<Call>,
    /// The ground atoms the action reveals (a sensing action's `:observe`),
    /// written `(thing-at newspaper kitchen)`; empty for an action that
    /// senses nothing. The action is done only once its configuration has
    /// reported every one of them.
    pub observe: Vec<String>,
}

impl PlannedAction {
    /// An action that senses nothing.
    pub fn new(action: impl Into<String>, goal: Option<Call>) -> PlannedAction {
        PlannedAction {
            action: action.into(),
            goal,
            observe: Vec::new(),
        }
    }
}

/// A plan: actions in order, then (after a sensing action) one branch per
/// possible observation.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// The actions before any branching.
    pub steps: Vec<PlannedAction>,
    /// What follows the last step, by what it observed; empty: the plan ends.
    pub branches: Vec<PlanBranch>,
    /// When the plan ends after its steps (no branches): how probable the
    /// planner thought it that the goal then holds, given the observations
    /// that led here. 1 for a deterministic plan; a conditional plan may
    /// give up where no action helps (0).
    pub success: f64,
}

impl Default for Plan {
    fn default() -> Plan {
        Plan::from(Vec::new())
    }
}

/// A branch of a conditional plan.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanBranch {
    /// The observation that selects this branch: every atom with its value.
    pub observation: Vec<Observation>,
    /// How probable the planner thought this observation, given the path to it.
    pub probability: f64,
    /// The rest of the plan, shared with the other branches that lead to
    /// the same place (a conditional plan is a graph).
    pub plan: Arc<Plan>,
}

impl From<Vec<PlannedAction>> for Plan {
    fn from(steps: Vec<PlannedAction>) -> Plan {
        Plan::branching(steps, Vec::new())
    }
}

impl Plan {
    /// A plan that branches after `steps` (ends there when `branches` is empty).
    pub fn branching(steps: Vec<PlannedAction>, branches: Vec<PlanBranch>) -> Plan {
        Plan {
            steps,
            branches,
            success: 1.0,
        }
    }

    /// Whether the plan branches anywhere.
    pub fn is_conditional(&self) -> bool {
        !self.branches.is_empty()
    }

    /// The most actions on one path through the plan.
    pub fn depth(&self) -> usize {
        self.fold(&mut HashMap::new(), &|steps, below| {
            steps + below.iter().copied().max().unwrap_or(0)
        })
    }

    /// Actions in the whole tree, every branch counted (a part that
    /// branches share counted once for each), saturating.
    pub fn actions(&self) -> usize {
        self.fold(&mut HashMap::new(), &|steps, below| {
            below.iter().fold(steps, |a, &b| a.saturating_add(b))
        })
    }

    /// `combine(steps, values of the branches)` from the leaves up, each
    /// shared part computed once.
    fn fold(
        &self,
        memo: &mut HashMap<*const Plan, usize>,
        combine: &dyn Fn(usize, &[usize]) -> usize,
    ) -> usize {
        let below: Vec<usize> = self
            .branches
            .iter()
            .map(|b| {
                let key = Arc::as_ptr(&b.plan);
                if let Some(&v) = memo.get(&key) {
                    return v;
                }
                let v = b.plan.fold(memo, combine);
                memo.insert(key, v);
                v
            })
            .collect();
        combine(self.steps.len(), &below)
    }
}

/// One ground atom and whether it was seen to hold.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct Observation {
    /// The atom, like `(thing-at newspaper kitchen)` (as [`Call`] prints it).
    pub atom: String,
    /// Whether it holds.
    pub holds: bool,
}

impl fmt::Display for Observation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.holds {
            f.write_str(&self.atom)
        } else {
            write!(f, "(not {})", self.atom)
        }
    }
}

/// Observations joined by spaces, as the log and `C.observed` write them.
pub fn observations_text(observations: &[Observation]) -> String {
    observations
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(" ")
}

/// The most literals one `C.observed` tuple is read for.
const MAX_LITERALS: usize = 256;

/// The literals of a `C.observed` value: `(atom …)` or `(not (atom …))`,
/// separated by white space, read by the language's own reader
/// ([`parse_literals`]). `Err` says what is malformed.
pub fn parse_observations(text: &str) -> Result<Vec<Observation>, String> {
    let literals = parse_literals(text).map_err(|d| {
        d.0.first()
            .map_or_else(|| "malformed".to_string(), |d| d.message.clone())
    })?;
    if literals.len() > MAX_LITERALS {
        return Err(format!("more than {MAX_LITERALS} literals"));
    }
    Ok(literals
        .into_iter()
        .filter_map(|literal| match literal {
            Literal::Pos(atom) => Some(Observation {
                atom: atom.to_string(),
                holds: true,
            }),
            Literal::Neg(atom) => Some(Observation {
                atom: atom.to_string(),
                holds: false,
            }),
            // `parse_literals` accepts atoms and negated atoms only.
            Literal::Eq(..) | Literal::Neq(..) => None,
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn literals_read_positive_and_negative_atoms() {
        let read = parse_observations(
            "(thing-at newspaper   kitchen)\n(not (thing-at newspaper entrance))",
        )
        .expect("literals");
        assert_eq!(
            read,
            vec![
                Observation {
                    atom: "(thing-at newspaper kitchen)".to_string(),
                    holds: true
                },
                Observation {
                    atom: "(thing-at newspaper entrance)".to_string(),
                    holds: false
                },
            ]
        );
        assert_eq!(
            observations_text(&read),
            "(thing-at newspaper kitchen) (not (thing-at newspaper entrance))"
        );
        assert_eq!(parse_observations("  ").expect("nothing"), vec![]);
    }

    #[test]
    fn malformed_literals_are_errors_not_panics() {
        for bad in [
            "(a b",
            "a b)",
            "x (a b)",
            "(not)",
            "((a) b)",
            "(not (a (b)))",
            "()",
        ] {
            assert!(parse_observations(bad).is_err(), "{bad} was read");
        }
        let many = "(a b) ".repeat(MAX_LITERALS + 1);
        assert!(
            parse_observations(&many)
                .expect_err("too many")
                .contains("more than")
        );
    }
}
