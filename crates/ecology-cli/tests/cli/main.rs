//! The `ecology` binary, from the command line: outputs and exit codes.

mod netns;
mod plan_conditional;
mod processes;
mod readme;
mod ros2;
mod stopping;
mod support;
mod tuples;
mod tutorial;
mod view;

use std::path::PathBuf;
use std::process::{Command, Output};

use serde_json::Value;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn ecology(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ecology"))
        .args(args)
        .current_dir(root())
        .output()
        .expect("runs")
}

fn configure(extra: &[&str]) -> Output {
    configure_goal("(navigate astrid bedroom)", extra)
}

/// [`configure`] without `components` (`P:C`, each given to `--exclude`), with `extra`.
fn configure_without<'a>(components: &[&'a str], extra: &[&'a str]) -> Output {
    let mut args = Vec::new();
    for component in components {
        args.extend(["--exclude", component]);
    }
    args.extend_from_slice(extra);
    configure(&args)
}

/// `ecology configure` on the paper's domain and state, for `goal`.
fn configure_goal(goal: &str, extra: &[&str]) -> Output {
    let mut args = vec![
        "configure",
        "--domain",
        "domains/peis-home.eco",
        "--state",
        "domains/peis-home.facts",
        "--goal",
        goal,
    ];
    args.extend_from_slice(extra);
    ecology(&args)
}

fn stdout(out: &Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Asserts that `out` exited with `code` and said `why` on stderr.
#[track_caller]
fn exits(out: &Output, code: i32, why: &str) {
    assert_eq!(
        out.status.code(),
        Some(code),
        "{}{}",
        stdout(out),
        stderr(out)
    );
    assert!(stderr(out).contains(why), "{why:?} not in {}", stderr(out));
}

fn json(out: &Output) -> Value {
    serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("not JSON ({e}): {}", stdout(out)))
}

#[test]
fn configure_the_reference_goal() {
    let out = configure(&[]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let text = stdout(&out);
    assert!(
        text.contains("(tracking-system hsm tr1 astrid)     hsm:tr1 (on)  cost 20"),
        "{text}"
    );
    assert!(text.contains("(remote hsm → astrid)"), "{text}");
    assert!(text.contains("total cost 80 (proven optimal)"), "{text}");
}

#[test]
fn configure_all_lists_three() {
    let out = configure(&["--all"]);
    let totals: Vec<String> = stdout(&out)
        .lines()
        .filter(|l| l.contains("total cost"))
        .map(|l| l.trim().to_string())
        .collect();
    assert_eq!(
        totals,
        [
            "total cost 80 (proven optimal)",
            "total cost 170 (proven optimal)",
            "total cost 190 (proven optimal)"
        ]
    );
    let out = configure(&["--all", "--limit", "2", "--json"]);
    let costs: Vec<u64> = json(&out)["configurations"]
        .as_array()
        .expect("an array")
        .iter()
        .map(|c| c["cost"].as_u64().expect("a cost"))
        .collect();
    assert_eq!(costs, [80, 170]);
}

// An ecology of 33 components has more admissible configurations than can be
// listed (all of them ran past 30 s and 5 GB): `--all` lists the 1,000
// cheapest unless told otherwise, and says so.
#[test]
fn configure_all_lists_a_thousand_unless_told() {
    let (dir, goal) = sharing_instance("all", 8);
    let run = |extra: &[&str]| {
        let mut args = vec![
            "configure",
            "--domain",
            "domain.eco",
            "--state",
            "state.facts",
        ];
        args.extend(["--goal", &goal, "--all"]);
        args.extend_from_slice(extra);
        Command::new(env!("CARGO_BIN_EXE_ecology"))
            .args(&args)
            .current_dir(&dir)
            .output()
            .expect("runs")
    };
    let out = run(&[]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let text = stdout(&out);
    assert_eq!(text.matches("total cost").count(), 1000);
    assert!(text.contains("configuration 1000 of 1000 for (serve):"));
    assert!(text.contains("(the 1000 cheapest; there may be more: --limit N lists up to N)"));
    let v = json(&run(&["--limit", "1500", "--json"]));
    assert_eq!(v["limit"], 1500, "{v}");
    let costs: Vec<u64> = v["configurations"]
        .as_array()
        .expect("an array")
        .iter()
        .map(|c| c["cost"].as_u64().expect("a cost"))
        .collect();
    assert_eq!(costs.len(), 1500);
    assert!(costs.windows(2).all(|w| w[0] <= w[1]), "cheapest first");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn configure_json() {
    let out = configure(&["--json"]);
    assert_eq!(out.status.code(), Some(0));
    let v = json(&out);
    assert_eq!(v["cost"], 80);
    assert_eq!(v["optimal"], true);
    let tracking = v["functionalities"]
        .as_array()
        .expect("an array")
        .iter()
        .find(|f| f["name"] == "tracking-system")
        .expect("tracking system")
        .clone();
    assert_eq!(tracking["peis"], "hsm");
    assert_eq!(tracking["component"], "tr1");
    assert_eq!(tracking["state"], "on");
    assert_eq!(
        tracking["args"],
        serde_json::json!(["hsm", "tr1", "astrid"])
    );
    let remote: Vec<&Value> = v["channels"]
        .as_array()
        .expect("an array")
        .iter()
        .filter(|c| c["remote"] == true)
        .collect();
    assert_eq!(remote.len(), 1);
    assert_eq!(remote[0]["info"], "(global-pos astrid)");
    assert!(v["stats"]["expanded"].as_u64().is_some());
    assert!(v["stats"]["generated"].as_u64().is_some());
    assert!(v["stats"]["micros"].as_u64().is_some());
}

#[test]
fn configure_with_exclusions() {
    let v = json(&configure_without(&["hsm:tr1"], &["--json"]));
    assert_eq!(v["cost"], 170);
    let laser = v["functionalities"]
        .as_array()
        .expect("an array")
        .iter()
        .find(|f| f["component"] == "l1")
        .expect("the laser")
        .clone();
    assert_eq!(laser["state"], "off");
    assert_eq!(laser["cost"], 120);

    let v = json(&configure_without(&["hsm:tr1", "astrid:l1"], &["--json"]));
    assert_eq!(v["cost"], 190);

    let out = configure_without(&["hsm:tr1", "astrid:l1", "pippi:ol2"], &[]);
    assert_eq!(out.status.code(), Some(1));
    let text = stderr(&out);
    assert!(
        text.contains("no configuration for (navigate astrid bedroom)"),
        "{text}"
    );
    assert!(
        text.contains("input (position astrid) of f1 (navigation astrid tc1 bedroom)"),
        "{text}"
    );

    let out = configure_without(&["hsm:tr1", "astrid:l1", "pippi:ol2"], &["--json"]);
    assert_eq!(out.status.code(), Some(1));
    let v = json(&out);
    assert_eq!(v["error"], "no configuration");
    assert!(
        v["explanation"]["causes"][0]["reason"]
            .as_str()
            .expect("a reason")
            .contains("(position astrid)")
    );
}

// Several executives: given another executive's claims as `held` facts, the tracking system
// held for Bob is not available to Astrid (her laser at 170), the cameras held running the same
// instance are, and the explanation names who holds what.
#[test]
fn configure_with_claims_of_another_executive() {
    let held = |extra: &[&str]| {
        let mut args = vec![
            "configure",
            "--domain",
            "domains/peis-home.eco",
            "--state",
            "domains/peis-home-held.facts",
            "--goal",
            "(navigate astrid bedroom)",
        ];
        args.extend_from_slice(extra);
        ecology(&args)
    };
    let v = json(&held(&["--json"]));
    assert_eq!(v["cost"], 170);
    let out = held(&["--exclude", "astrid:l1", "--exclude", "pippi:ol2"]);
    assert_eq!(out.status.code(), Some(1));
    let text = stderr(&out);
    assert!(
        text.contains(
            "(tracking-system hsm tr1 astrid): component hsm:tr1 is held by exec-bob running (tracking-system hsm tr1 bob)"
        ),
        "{text}"
    );
    let bad = std::env::temp_dir().join(format!("ecology-held-{}.facts", std::process::id()));
    std::fs::write(&bad, "(peis hsm)\n(held hsm tr1)\n").expect("write");
    let out = ecology(&["check", &bad.display().to_string()]);
    let _ = std::fs::remove_file(&bad);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("`held` takes at least 4 arguments, given 2"),
        "{}",
        stderr(&out)
    );
}

#[test]
fn configure_dot() {
    let out = configure(&["--dot"]);
    let text = stdout(&out);
    assert!(text.starts_with("digraph configuration {"), "{text}");
    assert!(text.contains("subgraph cluster_"), "{text}");
    assert!(text.contains("label=\"hsm\""), "{text}");
    assert!(
        text.contains("\"f0/f1/f2\" -> \"f0/f2\" [label=\"(global-pos astrid)\", style=dashed];"),
        "{text}"
    );
}

#[test]
fn configure_under_a_budget_is_flagged() {
    // No node may be expanded: no configuration, only a bound.
    let out = configure(&["--max-nodes", "0", "--json"]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let v = json(&out);
    assert_eq!(v["error"], "budget exceeded", "{v}");
    assert!(v["lower_bound"].as_u64().is_some(), "{v}");
    assert_eq!(v["stats"]["expanded"], 0, "{v}");
    // No time: the same, the clock counting from the command's start, so
    // the budget is spent while reading.
    let v = json(&configure(&["--max-millis", "0", "--json"]));
    assert_eq!(v["error"], "budget exceeded", "{v}");
    assert_eq!(v["phase"], "reading", "{v}");
    // Proven answers carry no bound.
    let v = json(&configure(&["--json"]));
    assert!(v["lower_bound"].is_null(), "{v}");
    assert_eq!(v["optimal"], true, "{v}");
}

/// A shared-provider ecology of `peis` PEIS (96: about 9,500 facts) written
/// to a fresh directory: domain, state and goal for `ecology configure`.
fn sharing_instance(name: &str, peis: usize) -> (PathBuf, String) {
    let instance =
        ecology_config::synthetic::sharing(ecology_config::synthetic::Sharing::base(peis, 1))
            .expect("generates");
    let dir = std::env::temp_dir().join(format!("ecology-cli-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    std::fs::write(dir.join("domain.eco"), &instance.domain_text).expect("write");
    std::fs::write(dir.join("state.facts"), &instance.facts_text).expect("write");
    (dir, instance.goal_text)
}

#[test]
fn configure_stops_when_the_budget_is_spent_while_reading() {
    let (dir, goal) = sharing_instance("reading", 96);
    let run = |extra: &[&str]| {
        let domain = dir.join("domain.eco");
        let state = dir.join("state.facts");
        let mut args = vec![
            "configure",
            "--domain",
            domain.to_str().expect("utf-8 path"),
            "--state",
            state.to_str().expect("utf-8 path"),
            "--goal",
            &goal,
        ];
        args.extend_from_slice(extra);
        ecology(&args)
    };
    // Reading alone uses a budget of 0 ms: stopped before planning, no bound.
    let out = run(&["--max-millis", "0", "--json"]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let v = json(&out);
    assert_eq!(v["error"], "budget exceeded", "{v}");
    assert_eq!(v["phase"], "reading", "{v}");
    assert!(v["lower_bound"].is_null(), "{v}");
    assert_eq!(v["stats"]["expanded"], 0, "{v}");
    let out = run(&["--max-millis", "0"]);
    exits(&out, 1, "the budget was spent while reading the input");
    // A budget of nodes is spent while planning: not proven, with the bound.
    let v = json(&run(&["--max-nodes", "0", "--json"]));
    assert_eq!(v["error"], "budget exceeded", "{v}");
    assert_eq!(v["phase"], "planning", "{v}");
    let bound = v["lower_bound"].as_u64().expect("a bound");
    let out = run(&["--max-nodes", "0"]);
    exits(
        &out,
        1,
        &format!("within the budget (0 nodes expanded; none costs less than {bound})"),
    );
    // Unlimited: proven, and no cheaper than the bound.
    let out = run(&["--json"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let v = json(&out);
    assert_eq!(v["optimal"], true, "{v}");
    assert!(v["cost"].as_u64().expect("a cost") >= bound, "{v}");
    std::fs::remove_dir_all(&dir).ok();
}

/// Runs `ecology ARGS` in `dir` on a pseudo-terminal (`script` copies what it
/// writes to stdout); `None` when there is no `script`.
fn on_a_terminal(dir: &std::path::Path, args: &[&str]) -> Option<Output> {
    Command::new("script").arg("--version").output().ok()?;
    let command = std::iter::once(env!("CARGO_BIN_EXE_ecology"))
        .chain(args.iter().copied())
        .map(|a| format!("'{a}'"))
        .collect::<Vec<_>>()
        .join(" ");
    let out = Command::new("script")
        .args(["-qec", &command, "/dev/null"])
        .current_dir(dir)
        .output()
        .expect("runs script");
    Some(out)
}

/// Checks that a search of `args` (bounded to 2.6 s) drew progress lines
/// saying `progress` after one and two seconds on a terminal, erased them
/// before its `answer`, and drew none piped (in 1.3 s).
fn shows_progress(test: &str, dir: &std::path::Path, args: &[&str], progress: &str, answer: &str) {
    let Some(out) = on_a_terminal(dir, &[args, &["--max-millis", "2600"]].concat()) else {
        eprintln!("skipped {test}: no `script` to run a terminal");
        return;
    };
    let text = stdout(&out);
    assert_eq!(out.status.code(), Some(1), "{text}");
    let lines: Vec<&str> = text.split("\r\x1b[K").collect();
    for second in ["1", "2"] {
        assert!(
            lines
                .iter()
                .any(|l| l.starts_with(&format!("  … {second} s: ")) && l.contains(progress)),
            "{text:?}"
        );
    }
    // Erased before the answer, which stands on a line of its own.
    assert!(
        lines.last().is_some_and(|l| l.starts_with(answer)),
        "{text:?}"
    );
    let out = Command::new(env!("CARGO_BIN_EXE_ecology"))
        .args(args)
        .args(["--max-millis", "1300"])
        .current_dir(dir)
        .output()
        .expect("runs");
    exits(&out, 1, answer);
    assert!(!stderr(&out).contains(progress), "{}", stderr(&out));
}

// On a terminal, a search that runs past a second says how it is going, once
// a second, on one line of stderr that it erases at the end; piped, it says
// nothing of the kind.
#[test]
fn a_long_search_shows_its_progress_on_a_terminal() {
    let dir = std::env::temp_dir().join(format!("ecology-cli-progress-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    // A diamond whose configurations the tree search takes over a minute to list
    // (it searches every occurrence of a shared provider again).
    let config = ecology_config::synthetic::diamond(16, true).expect("generates");
    std::fs::write(dir.join("domain.eco"), &config.domain_text).expect("write");
    std::fs::write(dir.join("state.facts"), &config.facts_text).expect("write");
    shows_progress(
        "a_long_search_shows_its_progress_on_a_terminal",
        &dir,
        &[
            "configure",
            "--domain",
            "domain.eco",
            "--state",
            "state.facts",
            "--goal",
            "(ga0)",
            "--all",
        ],
        "nodes expanded; no configuration yet, none costs less than",
        "no configuration found for (ga0) within the budget",
    );
    // Sixteen blocks, searched blind for a cheapest plan.
    let blocks = ecology_actions::problems::blocks(16, 1).expect("generates");
    std::fs::write(dir.join("domain.pddl"), &blocks.domain_text).expect("write");
    std::fs::write(dir.join("problem.pddl"), &blocks.problem_text).expect("write");
    let plan = [
        "plan",
        "--domain",
        "domain.pddl",
        "--problem",
        "problem.pddl",
    ];
    shows_progress(
        "a_long_search_shows_its_progress_on_a_terminal",
        &dir,
        &[&plan[..], &["--optimal", "--heuristic", "blind"]].concat(),
        "states stored; no plan yet",
        "no plan found within the budget",
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn check_reports_diagnostics_and_exits_2() {
    let out = ecology(&[
        "check",
        "domains/peis-home.eco",
        "domains/peis-home.facts",
        "domains/fridge.eco",
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert!(stdout(&out).contains("domain `peis-home` is valid"));
    assert!(stdout(&out).contains("domains/peis-home.facts: 30 facts, valid"));
    assert!(stdout(&out).contains("domain `fridge` is valid"));

    let dir = std::env::temp_dir().join(format!("ecology-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let bad = dir.join("bad.eco");
    std::fs::write(
        &bad,
        "(define (domain bad)\n  (:task t :parameters (?r))\n  (:method m :parameters (?r) :task (t ?r) :subtasks ((a (fly ?r)))))\n",
    )
    .expect("write");
    let out = ecology(&["check", bad.to_str().expect("utf-8 path")]);
    assert_eq!(out.status.code(), Some(2));
    let text = stderr(&out);
    assert!(text.contains("bad.eco:3:58"), "{text}");
    assert!(
        text.contains("unknown task or functionality `fly`"),
        "{text}"
    );
    assert!(text.contains("1 error in"), "{text}");

    let out = ecology(&["check", "no/such/file.eco"]);
    exits(&out, 2, "cannot open no/such/file.eco");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_goals_and_arguments_exit_2() {
    let out = configure_goal("(fly astrid", &[]);
    exits(&out, 2, "<goal>:1:1");
    let out = configure_goal("(fly astrid)", &[]);
    exits(&out, 2, "unknown task or functionality `fly` in the goal");
    // Where in the goal: the name, under a caret.
    assert!(stderr(&out).contains("<goal>:1:2"), "{}", stderr(&out));
    assert!(
        stderr(&out).contains(" ^^^ no task or functionality has this name"),
        "{}",
        stderr(&out)
    );
    let out = configure(&[]);
    assert_eq!(out.status.code(), Some(0));
    let out = configure_goal("  (navigate astrid)", &[]);
    exits(&out, 2, "<goal>:1:3");
    assert!(
        stderr(&out).contains("takes 2 arguments, the goal gives 1"),
        "{}",
        stderr(&out)
    );
    let out = configure(&["--exclude", "a:b:c"]);
    assert_eq!(out.status.code(), Some(2));
    let out = ecology(&["frobnicate"]);
    assert_eq!(out.status.code(), Some(2));
}

fn plan(extra: &[&str]) -> Output {
    let mut args = vec![
        "plan",
        "--domain",
        "domains/peis-home.eco",
        "--problem",
        "domains/peis-home-task.problem",
    ];
    args.extend_from_slice(extra);
    ecology(&args)
}

#[test]
fn plan_the_peis_home_task() {
    // The paper's Section VIII: each action with the configuration goal that performs it.
    let out = plan(&[]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let text = stdout(&out);
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(
        lines[..5],
        [
            "(move astrid living-room entrance)  ; configure (navigate astrid entrance)",
            "(get astrid newspaper entrance)     ; configure (grasp astrid newspaper)",
            "(move astrid entrance bedroom)      ; configure (navigate astrid bedroom)",
            "(wake astrid johanna bedroom)       ; configure (wake-up astrid johanna)",
            "; cost = 4",
        ]
    );
}

#[test]
fn plan_json() {
    let out = plan(&["--optimal", "--json"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let value = json(&out);
    assert_eq!(
        value["plan"],
        serde_json::json!([
            "(move astrid living-room entrance)",
            "(get astrid newspaper entrance)",
            "(move astrid entrance bedroom)",
            "(wake astrid johanna bedroom)"
        ])
    );
    assert_eq!(value["configure"][3], "(wake-up astrid johanna)");
    assert_eq!(value["cost"], 4);
    assert_eq!(value["optimal"], true);
    assert!(value["stats"]["expanded"].as_u64().is_some_and(|n| n >= 4));
    assert!(value["stats"]["micros"].is_u64());
    // Greedy search's plan, proven cheapest by the improvement phase that
    // follows it; without that phase, not proven.
    let fast = json(&plan(&["--json"]));
    assert_eq!(fast["optimal"], true);
    assert_eq!(fast["plan"], value["plan"]);
    assert_eq!(fast["stats"]["first"]["cost"], 4);
    let first = json(&plan(&["--no-improve", "--json"]));
    assert_eq!(first["optimal"], false);
    assert!(first["stats"]["first"].is_null());
    assert_eq!(first["plan"], value["plan"]);
    assert!(first["stats"]["expanded"].as_u64() < fast["stats"]["expanded"].as_u64());
    let lazy = json(&plan(&["--lazy", "--json"]));
    assert_eq!(lazy["plan"], value["plan"]);
    let ff_alone = json(&plan(&["--no-landmarks", "--json"]));
    assert_eq!(ff_alone["plan"], value["plan"]);
    for flag in ["--lazy", "--no-landmarks", "--no-improve"] {
        let refused = plan(&[flag, "--optimal"]);
        assert_eq!(refused.status.code(), Some(2));
        assert!(
            stderr(&refused).contains("cannot be used with"),
            "{flag}: {}",
            stderr(&refused)
        );
    }
}

#[test]
fn plan_classic_pddl_optimally() {
    for (domain, problem, cost) in [
        ("gripper", "gripper-4", 11),
        ("blocks", "blocks-sussman", 6),
        ("blocks", "blocks-reverse-4", 8),
        ("logistics", "logistics-2", 26),
    ] {
        let out = ecology(&[
            "plan",
            "--domain",
            &format!("domains/pddl/{domain}.pddl"),
            "--problem",
            &format!("domains/pddl/{problem}.pddl"),
            "--optimal",
        ]);
        assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
        assert!(
            stdout(&out).contains(&format!("; cost = {cost}\n; proven optimal")),
            "{problem}: {}",
            stdout(&out)
        );
    }
}

#[test]
fn plan_without_a_plan_exits_1_with_a_reason() {
    let out = plan(&["--exclude", "(move astrid living-room entrance)"]);
    exits(&out, 1, "no plan: the goal is unreachable");
    let out = plan(&["--exclude", "(move astrid entrance bedroom)", "--json"]);
    assert_eq!(out.status.code(), Some(1));
    assert_eq!(json(&out)["error"], "unsolvable");

    let blocks = |extra: &[&str]| {
        let mut args = vec!["plan", "--domain", "domains/pddl/blocks.pddl"];
        args.extend([
            "--problem",
            "domains/pddl/blocks-reverse-4.pddl",
            "--optimal",
        ]);
        args.extend_from_slice(extra);
        ecology(&args)
    };
    let out = blocks(&["--heuristic", "blind", "--max-nodes", "5", "--json"]);
    assert_eq!(out.status.code(), Some(1));
    let value = json(&out);
    assert_eq!(value["error"], "budget exceeded");
    assert_eq!(value["stats"]["expanded"], 5);
    // Cut short, a search for a cheapest plan says what no plan undercuts:
    // with LM-cut, at least the start's estimate; never above the optimum, 8.
    let out = blocks(&["--max-nodes", "2"]);
    exits(&out, 1, "none costs less than");
    let bound: u64 = stderr(&out)
        .split("none costs less than ")
        .nth(1)
        .and_then(|rest| rest.split(')').next())
        .and_then(|n| n.parse().ok())
        .expect("a bound");
    assert!((1..=8).contains(&bound), "{}", stderr(&out));
    let value = json(&blocks(&["--max-nodes", "2", "--json"]));
    assert_eq!(value["lower_bound"], bound, "{value}");
}

#[test]
fn plan_bad_input_exits_2_with_positions() {
    let dir = std::env::temp_dir().join(format!("ecology-cli-plan-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let bad = dir.join("bad.problem");
    std::fs::write(
        &bad,
        "(define (problem bad) (:domain peis-home)\n  (:objects astrid - robot hall - room)\n  (:init (at astrid kitchen))\n  (:goal (awake astrid)))\n",
    )
    .expect("write");
    let out = plan_with_problem(bad.to_str().expect("utf-8 path"), &[]);
    assert_eq!(out.status.code(), Some(2));
    let text = stderr(&out);
    assert!(text.contains("bad.problem:3:10"), "{text}");
    assert!(text.contains("unknown object `kitchen`"), "{text}");
    assert!(text.contains("bad.problem:4:10"), "{text}");
    assert!(
        text.contains("`astrid` is a `robot`, but `awake` expects a `person` there"),
        "{text}"
    );
    std::fs::remove_dir_all(&dir).ok();

    for exclude in [
        "(fly astrid)",
        "(move astrid attic bedroom)",
        "(move astrid",
    ] {
        let out = plan(&["--exclude", exclude]);
        assert_eq!(out.status.code(), Some(2), "{exclude}");
    }
    let out = plan(&["--optimal", "--heuristic", "ff"]);
    exits(&out, 2, "admissible");
}

fn plan_with_problem(problem: &str, extra: &[&str]) -> Output {
    let mut args = vec![
        "plan",
        "--domain",
        "domains/peis-home.eco",
        "--problem",
        problem,
    ];
    args.extend_from_slice(extra);
    ecology(&args)
}

// The paper's Section VIII in simulation: the timeline names every step.
#[test]
fn demo_runs_the_papers_experiment() {
    let out = ecology(&["demo"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let text = stdout(&out);
    for line in [
        "plan: (move astrid living-room entrance) → (get astrid newspaper entrance) → (move astrid entrance bedroom) → (wake astrid johanna bedroom)",
        "configuration for (navigate astrid entrance): cost 80 (optimal; alternatives 80, 170, 190)",
        "[simulation] hsm:ca1 stalls (stops publishing)",
        "FAILURE hsm:tr1: no images from the cameras",
        "reconfigured for (navigate astrid bedroom): cost 170 (optimal; alternatives 170, 190)",
        "deploy: switch on astrid:l1; 3 channels",
        "task done",
    ] {
        assert!(text.contains(line), "missing `{line}` in\n{text}");
    }
    assert!(stderr(&out).contains("of wall time"), "{}", stderr(&out));
}

#[test]
fn demo_json_prints_the_event_log() {
    let out = ecology(&["demo", "--json", "--seed", "3"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let events: Vec<Value> = stdout(&out)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON ({e}): {l}")))
        .collect();
    let names: Vec<&str> = events.iter().filter_map(|e| e["event"].as_str()).collect();
    assert_eq!(names.first(), Some(&"plan"));
    assert_eq!(names.last(), Some(&"task_done"));
    let costs: Vec<u64> = events
        .iter()
        .filter(|e| e["event"] == "configuration")
        .filter_map(|e| e["cost"].as_u64())
        .collect();
    assert_eq!(costs, [80, 100, 80, 170, 20]);
    assert!(events.iter().all(|e| e["t"].is_number()));
}

#[test]
fn run_takes_a_scenario_file_and_reports_bad_ones() {
    let out = ecology(&["run", "scenarios/kitchen.toml"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert!(stdout(&out).contains("PEIS hsm left the ecology"));

    let dir = std::env::temp_dir().join(format!("ecology-cli-run-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, "name = \"bad\"\n[task]\ndomain = 3\n").expect("writes");
    let out = ecology(&["run", bad.to_str().expect("utf-8 path")]);
    exits(&out, 2, "bad.toml:3:10");
    let _ = std::fs::remove_dir_all(&dir);

    let out = ecology(&["demo", "--speed", "0"]);
    assert_eq!(out.status.code(), Some(2));
}

// Two tasks in one home, each with its executive: one timeline, each line
// naming its executive; JSON lines carry `executive`; exit 0 when both are done.
#[test]
fn run_plays_a_scenario_of_two_tasks_on_one_timeline() {
    let out = ecology(&["run", "scenarios/two-robots.toml"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let text = stdout(&out);
    for line in [
        "[exec-astrid] plan: (move astrid entrance bedroom)",
        "[exec-bob] plan: (move bob living-room kitchen)",
        "is held by exec-",
        "cost 170",
        "[exec-astrid] task done",
        "[exec-bob] task done",
    ] {
        assert!(text.contains(line), "missing `{line}` in\n{text}");
    }
    assert!(!stderr(&out).contains("warning"), "{}", stderr(&out));

    let out = ecology(&["run", "scenarios/two-robots.toml", "--json"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let events: Vec<Value> = stdout(&out)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON ({e}): {l}")))
        .collect();
    let done: Vec<&str> = events
        .iter()
        .filter(|e| e["event"] == "task_done")
        .filter_map(|e| e["executive"].as_str())
        .collect();
    assert_eq!(done.len(), 2, "{events:?}");
    assert!(
        done.contains(&"exec-astrid") && done.contains(&"exec-bob"),
        "{done:?}"
    );

    // As processes, it is refused with the reason.
    let out = ecology(&["run", "scenarios/two-robots.toml", "--processes"]);
    exits(&out, 2, "--processes runs one task that starts at once");
}

// A sweep of the two tasks: every seed's run checked against the ground truth,
// conflicts included.
#[test]
fn sweep_checks_that_no_component_serves_two_executives() {
    let out = ecology(&["sweep", "scenarios/two-robots.toml", "--seeds", "4"]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}\n{}",
        stdout(&out),
        stderr(&out)
    );
    let text = stdout(&out);
    assert!(text.contains("4 seeds (0..4) of two-robots"), "{text}");
    assert!(
        text.lines()
            .any(|l| l.trim_start().starts_with("conflicts") && l.contains(" 0   (")),
        "{text}"
    );
    assert!(!text.contains("conflict:"), "{text}");
}

#[test]
fn plan_max_millis_bounds_grounding_too() {
    // One action with six parameters over 40 objects and a static precondition
    // on all six: grounding tries 40^6 bindings, hours of work.
    let folder = std::env::temp_dir().join(format!("ecology-ground-{}", std::process::id()));
    std::fs::create_dir_all(&folder).expect("temp folder");
    let domain = folder.join("big.pddl");
    std::fs::write(
        &domain,
        "(define (domain big) (:requirements :strips)
           (:predicates (p ?a ?b ?c ?d ?e ?f) (q ?a))
           (:action a :parameters (?a ?b ?c ?d ?e ?f)
             :precondition (p ?a ?b ?c ?d ?e ?f) :effect (q ?a)))",
    )
    .expect("write domain");
    let objects: Vec<String> = (0..40).map(|i| format!("o{i}")).collect();
    let problem = folder.join("big-problem.pddl");
    std::fs::write(
        &problem,
        format!(
            "(define (problem big-1) (:domain big) (:objects {}) (:init) (:goal (q o0)))",
            objects.join(" ")
        ),
    )
    .expect("write problem");
    let mut child = Command::new(env!("CARGO_BIN_EXE_ecology"))
        .args(["plan", "--domain"])
        .arg(&domain)
        .arg("--problem")
        .arg(&problem)
        .args(["--max-millis", "200"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("runs");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    let status = loop {
        if let Some(status) = child.try_wait().expect("try_wait") {
            break status;
        }
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            panic!("`ecology plan --max-millis 200` was still grounding after 60 s");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    let out = child.wait_with_output().expect("output");
    let _ = std::fs::remove_dir_all(&folder);
    assert_eq!(status.code(), Some(1), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("grounding took longer than the time limit of 200ms"),
        "{}",
        stderr(&out)
    );
}

/// `ecology keys`: a new ecology, members, a grant and the listing; every mistake exits 2 with
/// the reason. A process without --keys says it is unauthenticated; one with --keys refuses
/// plain TCP endpoints and names it cannot prove.
#[test]
fn keys_make_an_ecology_and_processes_use_them() {
    let dir = std::env::temp_dir().join(format!("ecology-cli-keys-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let d = dir.to_str().expect("utf-8 path");
    let ok = |out: &Output| {
        assert_eq!(out.status.code(), Some(0), "{}{}", stdout(out), stderr(out));
        stdout(out)
    };
    ok(&ecology(&["keys", "init", d]));
    exits(
        &ecology(&["keys", "init", d]),
        2,
        "already holds an ecology's keys",
    );
    ok(&ecology(&["keys", "add", d, "astrid", "hsm"]));
    ok(&ecology(&[
        "keys",
        "add",
        d,
        "executive",
        "--role",
        "executive",
    ]));
    exits(
        &ecology(&["keys", "add", d, "hsm"]),
        2,
        "hsm is already a member",
    );
    exits(
        &ecology(&["keys", "add", d, "x", "--role", "king"]),
        2,
        "unknown role",
    );
    exits(&ecology(&["keys", "add", d, "ast rid"]), 2, "ast rid");
    ok(&ecology(&[
        "keys", "grant", d, "astrid", "*.fault", "--owner", "hsm",
    ]));
    exits(
        &ecology(&["keys", "grant", d, "nobody", "*.fault"]),
        2,
        "nobody is not a member",
    );
    exits(
        &ecology(&["keys", "grant", d, "astrid", "a..b"]),
        2,
        "invalid key pattern",
    );
    let list = ok(&ecology(&["keys", "list", d]));
    assert!(
        list.contains("astrid           peis       may set *.fault of hsm"),
        "{list}"
    );
    assert!(
        list.contains("executive        executive  may set components.*.reqState of every PEIS"),
        "{list}"
    );
    assert!(
        list.contains("hsm              peis       may set nothing of others"),
        "{list}"
    );

    // Joining with keys: TLS endpoints only, and only as a member.
    let scenario = "scenarios/peis-home.toml";
    let tcp = ecology(&[
        "peis",
        scenario,
        "--name",
        "hsm",
        "--keys",
        d,
        "--listen",
        "tcp/127.0.0.1:0",
    ]);
    assert_eq!(tcp.status.code(), Some(2), "bad input");
    assert!(
        stderr(&tcp).contains("write quic/127.0.0.1:"),
        "{}",
        stderr(&tcp)
    );
    let stranger = ecology(&[
        "peis",
        scenario,
        "--name",
        "pippi",
        "--keys",
        d,
        "--listen",
        "quic/127.0.0.1:0",
    ]);
    assert_eq!(stranger.status.code(), Some(2), "bad input");
    assert!(
        stderr(&stranger).contains("pippi is not a member"),
        "{}",
        stderr(&stranger)
    );
    let open = ecology(&["tuples", "get", "astrid", "x"]);
    assert!(
        stderr(&open).contains("runs UNAUTHENTICATED"),
        "{}",
        stderr(&open)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// `configure --svg`: the picture of the laser's configuration, drawn by Ecology, with the
/// excluded tracking system marked; a file that cannot be written exits 2.
#[test]
fn configure_writes_an_svg_picture() {
    let file = std::env::temp_dir().join(format!("ecology-config-{}.svg", std::process::id()));
    let path = file.to_str().expect("utf-8 path");
    let out = configure(&["--exclude", "hsm:tr1", "--svg", path]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert!(stdout(&out).contains("cost 170"), "{}", stdout(&out));
    let svg = std::fs::read_to_string(&file).expect("the picture");
    let _ = std::fs::remove_file(&file);
    assert!(svg.starts_with("<svg xmlns=\"http://www.w3.org/2000/svg\""));
    assert!(
        svg.contains("(navigate astrid bedroom): cost 170 (optimal)"),
        "{svg}"
    );
    assert!(svg.contains(r#"class="functionality switched-on" data-component="astrid:l1""#));
    assert!(svg.contains(r#"class="failed" data-component="hsm:tr1""#));
    assert_eq!(svg.matches("class=\"functionality").count(), 4, "{svg}");
    assert_eq!(svg.matches("<g class=\"channel").count(), 3, "{svg}");
    let bad = configure(&["--svg", "/nonexistent-dir/x.svg"]);
    exits(&bad, 2, "writing /nonexistent-dir/x.svg");
}

#[test]
fn peis_says_which_peis_of_a_file_it_cannot_run() {
    let file = "scenarios/peis-home.toml";
    exits(
        &ecology(&["peis", file]),
        2,
        "describes 3 PEIS (astrid, hsm, pippi): choose one with --name, or run them all with --all",
    );
    exits(
        &ecology(&["peis", file, "--name", "astrid,nobody"]),
        2,
        "has no PEIS nobody (it has astrid, hsm, pippi)",
    );
    exits(
        &ecology(&["peis", file, "--all", "--listen", "tcp/127.0.0.1:0"]),
        2,
        "3 PEIS cannot share --listen endpoints; connect them to a router instead",
    );
    exits(
        &ecology(&["peis", file, "--all", "--name", "hsm"]),
        2,
        "cannot be used with",
    );
}

#[test]
fn a_plan_whose_reader_goes_away_ends_quietly() {
    use std::os::unix::process::ExitStatusExt;
    // The reader closes its end before anything is printed, as `| head`
    // does after a few lines: the first write meets a closed pipe.
    let mut child = Command::new(env!("CARGO_BIN_EXE_ecology"))
        .args([
            "plan",
            "--domain",
            "domains/pddl/triangle-tire.pddl",
            "--problem",
            "domains/pddl/triangle-tire-8.pddl",
            "--conditional",
            "--horizon",
            "96",
        ])
        .current_dir(root())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("starts");
    drop(child.stdout.take());
    let out = child.wait_with_output().expect("ends");
    assert_eq!(
        out.status.signal(),
        Some(nix::sys::signal::Signal::SIGPIPE as i32),
        "{:?}: {}",
        out.status,
        stderr(&out)
    );
    assert!(stderr(&out).is_empty(), "{}", stderr(&out));
}

/// A time option out of range is bad input, refused before joining, and its
/// message says what the option takes: 0 only where 0 means "off".
#[test]
fn task_refuses_time_options_out_of_range() {
    let task = |option: &str| {
        ecology(&[
            "task",
            "--plan",
            "examples/tutorial/door.plan",
            "--domain",
            "domains/peis-home.eco",
            option,
        ])
    };
    let out = task("--return-wait=-1");
    exits(
        &out,
        2,
        "--return-wait must be 0 or a positive number of seconds, not -1",
    );
    let out = task("--settle=NaN");
    exits(
        &out,
        2,
        "--settle must be 0 or a positive number of seconds, not NaN",
    );
    let out = task("--waiting-grace=0");
    exits(
        &out,
        2,
        "--waiting-grace must be a positive number of seconds, not 0",
    );
}
