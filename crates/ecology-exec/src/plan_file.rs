//! Plan files: a plan of actions as text, in the form `ecology plan` prints
//! it, so that a plan can be saved, edited by hand and executed.
//!
//! One action a line, an S-expression, optionally followed by its
//! configuration goal: `(move astrid living-room entrance)  ; configure
//! (navigate astrid entrance)`. Any other text after `;` is a comment, and
//! lines that are empty or start with `;` are skipped.

use ecology_domain::parse_goal;

use crate::plan::PlannedAction;

/// A line of a plan file that is not an action.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("line {line}: {message}")]
pub struct PlanFileError {
    /// 1-based line.
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

/// The actions of plan file `text`, in order.
pub fn parse_plan(text: &str) -> Result<Vec<PlannedAction>, PlanFileError> {
    let mut plan = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let fail = |message: String| PlanFileError { line, message };
        let (action, comment) = raw.split_once(';').unwrap_or((raw, ""));
        let action = action.trim();
        if action.is_empty() {
            continue;
        }
        let call = parse_goal(action).map_err(|d| {
            fail(format!(
                "`{action}` is not an action: {}",
                d.0.first().map_or("malformed", |d| d.message.as_str())
            ))
        })?;
        let goal = match comment.trim().strip_prefix("configure") {
            Some(goal) => Some(parse_goal(goal.trim()).map_err(|d| {
                fail(format!(
                    "`{}` is not a configuration goal: {}",
                    goal.trim(),
                    d.0.first().map_or("malformed", |d| d.message.as_str())
                ))
            })?),
            None => None,
        };
        plan.push(PlannedAction::new(call.to_string(), goal));
    }
    if plan.is_empty() {
        return Err(PlanFileError {
            line: text.lines().count().max(1),
            message: "the plan has no action".to_string(),
        });
    }
    Ok(plan)
}
