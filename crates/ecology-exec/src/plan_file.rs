//! Plan files: a plan of actions as text, in the form `ecology plan` prints
//! it (and `ecology plan --conditional` for a conditional plan), so that a
//! plan can be saved, edited by hand and executed.
//!
//! One action a line, an S-expression, optionally followed by its
//! configuration goal: `(move astrid living-room entrance)  ; configure
//! (navigate astrid entrance)`. Any other text after `;` is a comment, and
//! lines that are empty or start with `;` are skipped.
//!
//! A conditional plan branches after a sensing action: indented under it,
//! each branch is a line `if OBSERVATION ; probability P` (the observation
//! as literals, `(thing-at newspaper entrance)` or `(not (thing-at newspaper
//! entrance))`) followed by the branch's plan, indented further, ending with
//! `done`. The atoms the branches name are what the sensing action observes.
//!
//! Branches of a conditional plan may join: an action that more than one
//! branch reaches is written once with a label, `[3] (move-car l-1-2
//! l-1-3)`, and another branch that reaches it ends with the line `go to
//! [3]`: it goes on with the labelled action and everything written after
//! it in its block (its branches included). A label is defined before it is
//! joined, and never from inside its own block.

use std::collections::{HashMap, HashSet};
use std::sync::Arc;

use ecology_domain::parse_goal;

use crate::plan::{Plan, PlanBranch, PlannedAction, parse_observations};

/// A line of a plan file that is not an action.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("line {line}: {message}")]
pub struct PlanFileError {
    /// 1-based line.
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

/// How deeply branches may nest.
const MAX_DEPTH: usize = 64;

/// One line of a plan file that says something.
struct Line<'a> {
    /// 1-based.
    number: usize,
    /// Spaces before it.
    indent: usize,
    /// The text before any `;`, trimmed.
    text: &'a str,
    /// The text after the first `;`, trimmed.
    comment: &'a str,
}

impl Line<'_> {
    /// An error at this line.
    fn error(&self, message: impl Into<String>) -> PlanFileError {
        PlanFileError {
            line: self.number,
            message: message.into(),
        }
    }
}

/// The plan of plan file `text`.
pub fn parse_plan(text: &str) -> Result<Plan, PlanFileError> {
    let lines: Vec<Line<'_>> = text
        .lines()
        .enumerate()
        .filter_map(|(i, raw)| {
            let (body, comment) = raw.split_once(';').unwrap_or((raw, ""));
            let body = body.trim_end();
            let content = body.trim_start();
            (!content.is_empty()).then(|| Line {
                number: i + 1,
                indent: body.len() - content.len(),
                text: content,
                comment: comment.trim(),
            })
        })
        .collect();
    let Some(first) = lines.first() else {
        return Err(PlanFileError {
            line: text.lines().count().max(1),
            message: "the plan has no action".to_string(),
        });
    };
    let mut at = 0;
    let mut labels = Labels::default();
    let plan = block(&lines, &mut at, first.indent, 0, &mut labels)?;
    if let Some(extra) = lines.get(at) {
        return Err(extra.error("this line is indented less than the plan it ends"));
    }
    Ok(plan)
}

/// The labelled parts of a plan: those whose block is read, and those
/// whose block is being read.
#[derive(Default)]
struct Labels {
    done: HashMap<u64, Plan>,
    open: HashSet<u64>,
}

/// `[N]` at the start of `text`: `N` and what follows.
fn label(line: &Line<'_>, text: &str) -> Result<Option<(u64, usize)>, PlanFileError> {
    let Some(rest) = text.strip_prefix('[') else {
        return Ok(None);
    };
    let Some((number, _)) = rest.split_once(']') else {
        return Err(line.error(format!("`{text}`: a label is `[N]`")));
    };
    let n = number
        .trim()
        .parse::<u64>()
        .map_err(|_| line.error(format!("`[{number}]` is not a label: labels are numbers")))?;
    Ok(Some((n, number.len() + 2)))
}

/// The plan whose lines start at `lines[*at]`, indented `indent`: actions,
/// then either `done`, `go to [N]`, the end, or the branches of the last
/// action.
fn block(
    lines: &[Line<'_>],
    at: &mut usize,
    indent: usize,
    depth: usize,
    labels: &mut Labels,
) -> Result<Plan, PlanFileError> {
    let mut plan = Plan::default();
    // The labels of this block, each with the index of its action.
    let mut here: Vec<(u64, usize)> = Vec::new();
    let plan = loop {
        let Some(line) = lines.get(*at) else {
            break plan;
        };
        if line.indent < indent {
            break plan;
        }
        if line.indent > indent && !line.text.starts_with("if ") {
            return Err(line.error("an action indented more than the one before it"));
        }
        if line.text.starts_with("if ") {
            plan.branches = branches(lines, at, line.indent, depth, labels)?;
            let Some(sensing) = plan.steps.last_mut() else {
                return Err(line.error("a branch before any action"));
            };
            let mut atoms: Vec<String> = plan
                .branches
                .iter()
                .flat_map(|b| b.observation.iter().map(|o| o.atom.clone()))
                .collect();
            atoms.sort();
            atoms.dedup();
            sensing.observe = atoms;
            break plan;
        }
        *at += 1;
        if line.text == "done" {
            if let Some(p) = line.comment.strip_prefix("goal holds with probability") {
                plan.success = probability(line, p)?;
            }
            break plan;
        }
        if let Some(target) = line.text.strip_prefix("go to ") {
            let target = target.trim();
            let Some((n, _)) = label(line, target)?.filter(|&(_, len)| len == target.len()) else {
                return Err(line.error(format!("`go to {target}`: a join is `go to [N]`")));
            };
            let Some(rest) = labels.done.get(&n) else {
                let why = if labels.open.contains(&n) {
                    "it would go back to an action before it (a loop)"
                } else {
                    "no action before it has that label"
                };
                return Err(line.error(format!("`go to [{n}]`: {why}")));
            };
            plan.steps.extend(rest.steps.iter().cloned());
            plan.branches = rest.branches.clone();
            plan.success = rest.success;
            break plan;
        }
        let mut text = line.text;
        if let Some((n, len)) = label(line, text)? {
            if labels.done.contains_key(&n) || !labels.open.insert(n) {
                return Err(line.error(format!("label [{n}] is given twice")));
            }
            here.push((n, plan.steps.len()));
            text = text[len..].trim_start();
        }
        plan.steps.push(action(line, text)?);
    };
    for (n, k) in here {
        labels.open.remove(&n);
        let rest = Plan {
            steps: plan.steps[k..].to_vec(),
            branches: plan.branches.clone(),
            success: plan.success,
        };
        labels.done.insert(n, rest);
    }
    Ok(plan)
}

/// The `if` lines at `indent` from `lines[*at]`, each with its plan.
fn branches(
    lines: &[Line<'_>],
    at: &mut usize,
    indent: usize,
    depth: usize,
    labels: &mut Labels,
) -> Result<Vec<PlanBranch>, PlanFileError> {
    let mut branches = Vec::new();
    while let Some(line) = lines.get(*at).filter(|l| l.indent == indent) {
        let Some(observed) = line.text.strip_prefix("if ") else {
            return Err(line.error("after the branches of an action, only more branches (`if …`)"));
        };
        if depth == MAX_DEPTH {
            return Err(line.error(format!("branches nest more than {MAX_DEPTH} deep")));
        }
        let observation = parse_observations(observed)
            .map_err(|why| line.error(format!("`{observed}` is not an observation: {why}")))?;
        if observation.is_empty() {
            return Err(line.error("a branch without an observation"));
        }
        let probability = match line.comment.strip_prefix("probability") {
            Some(p) => probability(line, p)?,
            None => 0.0,
        };
        *at += 1;
        let inner = lines
            .get(*at)
            .filter(|l| l.indent > indent)
            .ok_or_else(|| line.error("a branch needs its plan, indented under it"))?
            .indent;
        let plan = block(lines, at, inner, depth + 1, labels)?;
        branches.push(PlanBranch {
            observation,
            probability,
            plan: Arc::new(plan),
        });
    }
    Ok(branches)
}

/// `text` as a probability, or an error at `line`.
fn probability(line: &Line<'_>, text: &str) -> Result<f64, PlanFileError> {
    text.trim()
        .parse::<f64>()
        .ok()
        .filter(|p| (0.0..=1.0).contains(p))
        .ok_or_else(|| line.error(format!("`{}` is not a probability", text.trim())))
}

/// The action `text` of an action line.
fn action(line: &Line<'_>, text: &str) -> Result<PlannedAction, PlanFileError> {
    let call = parse_goal(text).map_err(|d| {
        line.error(format!(
            "`{}` is not an action: {}",
            text,
            d.0.first().map_or("malformed", |d| d.message.as_str())
        ))
    })?;
    let goal = match line.comment.strip_prefix("configure") {
        Some(goal) => Some(parse_goal(goal.trim()).map_err(|d| {
            line.error(format!(
                "`{}` is not a configuration goal: {}",
                goal.trim(),
                d.0.first().map_or("malformed", |d| d.message.as_str())
            ))
        })?),
        None => None,
    };
    Ok(PlannedAction::new(call.to_string(), goal))
}

#[cfg(test)]
mod tests {
    use super::*;

    const TREE: &str = "\
(move r a b)  ; configure (navigate r b)
(look r x b)  ; configure (look-for r x)
  if (at x b) ; probability 0.7
    (get r x b)  ; configure (grasp r x)
    done
  if (not (at x b)) ; probability 0.3
    (move r b c)
    (look r x c)
      if (at x c) ; probability 0.5
        (get r x c)
        done
      if (not (at x c)) ; probability 0.5
        done ; goal holds with probability 0
";

    /// The configuration goal of step `i`, as text.
    fn goal(plan: &Plan, i: usize) -> Option<String> {
        plan.steps[i].goal.as_ref().map(ToString::to_string)
    }

    #[test]
    fn a_conditional_plan_reads_as_a_tree() {
        let plan = parse_plan(TREE).expect("a plan");
        let actions =
            |p: &Plan| -> Vec<String> { p.steps.iter().map(|s| s.action.clone()).collect() };
        assert_eq!(actions(&plan), ["(move r a b)", "(look r x b)"]);
        assert_eq!(plan.steps[1].observe, ["(at x b)"]);
        assert_eq!(goal(&plan, 1).as_deref(), Some("(look-for r x)"));
        let [seen, unseen] = &plan.branches[..] else {
            panic!("two branches: {plan:?}");
        };
        assert_eq!((seen.observation[0].holds, seen.probability), (true, 0.7));
        assert_eq!(actions(&seen.plan), ["(get r x b)"]);
        assert_eq!(
            (unseen.observation[0].holds, unseen.probability),
            (false, 0.3)
        );
        assert_eq!(actions(&unseen.plan), ["(move r b c)", "(look r x c)"]);
        let [found, gives_up] = &unseen.plan.branches[..] else {
            panic!("two branches: {unseen:?}");
        };
        assert_eq!(actions(&found.plan), ["(get r x c)"]);
        assert_eq!(found.plan.success, 1.0);
        assert!(gives_up.plan.steps.is_empty());
        assert_eq!(gives_up.plan.success, 0.0);
        assert_eq!((plan.depth(), plan.actions()), (5, 6));
    }

    /// Triangle tireworld's first problem as `ecology plan --conditional`
    /// prints it: branches that meet again join a labelled action.
    const GRAPH: &str = "\
(move-car l-1-1 l-2-1)
  if (not-flattire) ; probability 0.5
    (loadtire l-2-1)
    (move-car l-2-1 l-1-2)
      if (not-flattire) ; probability 0.5
        [1] (move-car l-1-2 l-1-3)
          if (not-flattire) ; probability 0.5
            done
          if (not (not-flattire)) ; probability 0.5
            done
      if (not (not-flattire)) ; probability 0.5
        (changetire)
        go to [1]
  if (not (not-flattire)) ; probability 0.5
    (loadtire l-2-1)
    (changetire)
    [2] (move-car l-2-1 l-3-1)
      if (not-flattire) ; probability 0.5
        done
      if (not (not-flattire)) ; probability 0.5
        go to [2]
";

    #[test]
    fn a_join_goes_on_with_the_labelled_action_and_shares_its_branches() {
        let text = GRAPH.replace(
            "        go to [2]\n",
            "        (loadtire l-3-1)\n        done\n",
        );
        let plan = parse_plan(&text).expect("a plan");
        let actions =
            |p: &Plan| -> Vec<String> { p.steps.iter().map(|s| s.action.clone()).collect() };
        let flat = &plan.branches[0].plan;
        let [straight, changed] = &flat.branches[..] else {
            panic!("two branches: {flat:?}");
        };
        let (straight, changed) = (&straight.plan, &changed.plan);
        assert_eq!(actions(straight), ["(move-car l-1-2 l-1-3)"]);
        assert_eq!(actions(changed), ["(changetire)", "(move-car l-1-2 l-1-3)"]);
        assert_eq!(changed.steps[1].observe, ["(not-flattire)"]);
        // The branches after the joined action are the labelled one's.
        for (a, b) in straight.branches.iter().zip(&changed.branches) {
            assert!(Arc::ptr_eq(&a.plan, &b.plan));
        }
        assert_eq!((plan.depth(), plan.actions()), (5, 10));
    }

    #[test]
    fn a_join_names_a_label_written_before_it_outside_its_own_block() {
        // `go to [2]` under [2] itself would loop.
        let e = parse_plan(GRAPH).expect_err("a loop");
        assert_eq!(e.line, 21, "{e}");
        assert!(e.message.contains("a loop"), "{e}");
        for (text, line, says) in [
            (
                "(a)\n  if (p) ; probability 1\n    go to [4]\n",
                3,
                "no action before it",
            ),
            ("[1] (a)\n[1] (b)\n", 2, "given twice"),
            ("[x] (a)\n", 1, "labels are numbers"),
            ("[1 (a)\n", 1, "a label is `[N]`"),
            ("(a)\ngo to 1\n", 2, "a join is `go to [N]`"),
            ("(a)\ngo to [1] (b)\n", 2, "a join is `go to [N]`"),
        ] {
            let e = parse_plan(text).expect_err(text);
            assert_eq!(e.line, line, "{text:?}: {e}");
            assert!(e.message.contains(says), "{text:?}: {e}");
        }
    }

    #[test]
    fn a_sequence_is_a_plan_without_branches() {
        let plan = parse_plan("; a comment\n(a x)\n\n(b y) ; configure (g y)\n").expect("a plan");
        assert!(!plan.is_conditional());
        assert_eq!(plan.steps.len(), 2);
        assert_eq!(goal(&plan, 1).as_deref(), Some("(g y)"));
    }

    #[test]
    fn malformed_plans_name_their_line() {
        for (text, line, says) in [
            ("", 1, "no action"),
            ("(a)\n  (b)\n", 2, "indented more"),
            ("if (p) ; probability 1\n  (a)\n", 1, "before any action"),
            (
                "(a)\n  if (p ; probability 1\n    (b)\n",
                2,
                "not an observation",
            ),
            (
                "(a)\n  if (p) ; probability 2\n    (b)\n",
                2,
                "not a probability",
            ),
            ("(a)\n  if (p) ; probability 1\n", 2, "needs its plan"),
            ("(a)\n  if (p)\n    (b)\n  (c)\n", 4, "only more branches"),
            ("  (a)\n(b)\n", 2, "indented less"),
            ("(a) ; configure nonsense\n", 1, "not a configuration goal"),
        ] {
            let e = parse_plan(text).expect_err(text);
            assert_eq!(e.line, line, "{text:?}: {e}");
            assert!(e.message.contains(says), "{text:?}: {e}");
        }
    }

    #[test]
    fn deep_nesting_is_an_error_not_a_stack_overflow() {
        let mut text = String::new();
        for depth in 0..1000 {
            let pad = " ".repeat(depth * 4);
            text.push_str(&format!("{pad}(a)\n{pad}  if (p) ; probability 1\n"));
        }
        let e = parse_plan(&text).expect_err("too deep");
        assert!(e.message.contains("nest more than"), "{e}");
    }
}
