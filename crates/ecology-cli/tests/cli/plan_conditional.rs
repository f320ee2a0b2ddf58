//! `ecology plan --conditional`: the newspaper task of `domains/`, the tree,
//! its JSON, triangle tireworld's graphs, thresholds that cannot be met, and bad input.

use std::process::Output;

use crate::{ecology, json, stderr, stdout};

fn plan_newspaper(extra: &[&str]) -> Output {
    let mut args = vec![
        "plan",
        "--domain",
        "domains/peis-home-uncertain.eco",
        "--problem",
        "domains/newspaper-uncertain.problem",
        "--conditional",
    ];
    args.extend_from_slice(extra);
    ecology(&args)
}

#[test]
fn plan_conditional_newspaper_tree() {
    let out = plan_newspaper(&[]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let text = stdout(&out);
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "; success probability 1, expected cost 5.9");
    assert_eq!(
        lines[2..6],
        [
            "(move astrid living-room entrance)  ; configure (navigate astrid entrance)",
            "(look astrid newspaper entrance)  ; configure (look-for astrid newspaper)",
            "  if (thing-at newspaper entrance) ; probability 0.7",
            "    (get astrid newspaper entrance)  ; configure (grasp astrid newspaper)",
        ]
    );
    assert!(
        text.contains("  if (not (thing-at newspaper entrance)) ; probability 0.3\n"),
        "{text}"
    );
    assert!(
        text.contains("    (get astrid newspaper kitchen)"),
        "{text}"
    );
}

#[test]
fn plan_conditional_json() {
    let out = plan_newspaper(&["--json"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let value = json(&out);
    assert_eq!(value["success"], 1.0);
    assert_eq!(value["expected_cost"], 5.9);
    assert_eq!(value["complete"], true);
    let plan = &value["plan"];
    assert_eq!(plan["action"], "(move astrid living-room entrance)");
    let look = &plan["branches"][0]["plan"];
    assert_eq!(look["action"], "(look astrid newspaper entrance)");
    assert_eq!(look["configure"], "(look-for astrid newspaper)");
    let seen = &look["branches"][0];
    assert_eq!(seen["probability"], 0.7);
    assert_eq!(
        seen["observation"],
        serde_json::json!([{"atom": "(thing-at newspaper entrance)", "holds": true}])
    );
    assert_eq!(look["branches"][1]["probability"], 0.3);
    assert!(value["stats"]["expanded"].as_u64().is_some_and(|n| n > 0));
}

/// Triangle tireworld's problem `n` of `domains/pddl/`, planned with a
/// horizon of 12n.
fn plan_tireworld(n: usize, extra: &[&str]) -> Output {
    let problem = format!("domains/pddl/triangle-tire-{n}.pddl");
    let horizon = (12 * n).to_string();
    let mut args = vec![
        "plan",
        "--domain",
        "domains/pddl/triangle-tire.pddl",
        "--problem",
        &problem,
        "--conditional",
        "--horizon",
        &horizon,
    ];
    args.extend_from_slice(extra);
    ecology(&args)
}

#[test]
fn plan_conditional_prints_a_graph_whose_branches_join() {
    let out = plan_tireworld(1, &[]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let text = stdout(&out);
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[0], "; success probability 1, expected cost 6.25");
    assert!(
        lines[1].starts_with("; 14 actions in the graph (21 as a tree), at most 10 per branch"),
        "{text}"
    );
    // A labelled action, written once, and a branch that joins it.
    let labelled = text
        .lines()
        .filter(|l| l.trim_start().starts_with("[1] (move-car"))
        .count();
    assert_eq!(labelled, 1, "{text}");
    assert!(text.contains("\n        go to [1]\n"), "{text}");

    let value = json(&plan_tireworld(1, &["--json"]));
    assert_eq!(
        (
            &value["stats"]["actions"],
            &value["stats"]["tree_actions"],
            &value["stats"]["shared"]
        ),
        (
            &serde_json::json!(14),
            &serde_json::json!(21),
            &serde_json::json!(true)
        )
    );
    let text = value["plan"].to_string();
    assert_eq!(text.matches("\"label\":1").count(), 1, "{text}");
    assert!(text.contains("{\"go_to\":1}"), "{text}");
}

#[test]
fn plan_conditional_tireworld_8_surely_in_a_graph_of_153_actions() {
    let out = plan_tireworld(8, &[]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let text = stdout(&out);
    let lines: Vec<&str> = text.lines().collect();
    assert!(
        lines[0].starts_with("; success probability 1, "),
        "{}",
        lines[0]
    );
    assert!(
        lines[1].starts_with("; 153 actions in the graph (2147500044 as a tree)"),
        "{}",
        lines[1]
    );
    assert!(lines[1].contains("search complete"), "{}", lines[1]);
}

#[test]
fn plan_conditional_threshold_trades_probability_for_cost() {
    let out = plan_newspaper(&["--min-probability", "0.6", "--json"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let value = json(&out);
    let success = value["success"].as_f64().expect("number");
    let cost = value["expected_cost"].as_f64().expect("number");
    assert!(success >= 0.6 && cost < 5.9, "{value}");
}

#[test]
fn plan_conditional_below_threshold_exits_1_with_the_best_probability() {
    // Two actions are not enough to look and fetch: the best plan stops.
    let out = plan_newspaper(&["--horizon", "2", "--min-probability", "0.5"]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stderr(&out).contains("no plan: no plan of at most 2 actions per branch reaches the goal with probability 0.5; the best reaches it with probability 0"),
        "{}",
        stderr(&out)
    );
    let out = plan_newspaper(&["--horizon", "5", "--min-probability", "0.9", "--json"]);
    assert_eq!(out.status.code(), Some(1));
    let value = json(&out);
    assert_eq!(value["error"], "below threshold");
    assert_eq!(value["best_probability"], 0.7);
    let out = plan_newspaper(&["--max-nodes", "1", "--json"]);
    assert_eq!(out.status.code(), Some(1));
    assert_eq!(json(&out)["error"], "budget exceeded");
}

#[test]
fn plan_conditional_bad_input_exits_2() {
    // The uncertain problem without --conditional.
    let out = ecology(&[
        "plan",
        "--domain",
        "domains/peis-home-uncertain.eco",
        "--problem",
        "domains/newspaper-uncertain.problem",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("--conditional"), "{}", stderr(&out));
    let out = plan_newspaper(&["--min-probability", "1.5"]);
    assert_eq!(out.status.code(), Some(2));
    let out = plan_newspaper(&["--heuristic", "ff"]);
    assert_eq!(out.status.code(), Some(2));
    // --min-probability means nothing without --conditional.
    let out = ecology(&[
        "plan",
        "--domain",
        "domains/peis-home.eco",
        "--problem",
        "domains/peis-home-task.problem",
        "--min-probability",
        "0.5",
    ]);
    assert_eq!(out.status.code(), Some(2));
}
