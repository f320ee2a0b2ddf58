//! `ecology check` and `ecology configure`: the domain language and the configuration planner.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::Args;
use ecology_config::{
    Budget, Clock, Configuration, Exclusion, Explanation, Options, Outcome, PaperCost, Request,
    Snapshot, Status, WallClock,
};
use ecology_domain::Power;
use ecology_view::{Drawing, Edge, Mark, Node};
use serde_json::{Value, json};

use crate::input::{self, Reported};
use crate::progress::{ProgressLine, standing};
use crate::{EXIT_BAD_INPUT, EXIT_NO_SOLUTION, EXIT_OK};

/// Arguments of `ecology check`.
#[derive(Debug, Args)]
pub struct CheckArgs {
    /// Domain files (.eco), or state files (.facts); every problem in each is reported.
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
}

/// Arguments of `ecology configure`.
#[derive(Debug, Args)]
pub struct ConfigureArgs {
    /// The domain file (.eco).
    #[arg(long)]
    pub domain: PathBuf,
    /// The ecology state (.facts).
    #[arg(long)]
    pub state: PathBuf,
    /// The goal, a ground task or functionality: '(navigate astrid bedroom)'.
    #[arg(long)]
    pub goal: String,
    /// A failed component (PEIS:COMPONENT) or PEIS (PEIS) not to use; repeatable.
    #[arg(long, value_name = "PEIS:COMPONENT")]
    pub exclude: Vec<Exclusion>,
    /// List the admissible configurations, cheapest first (the 1,000 cheapest unless --limit says otherwise).
    #[arg(long)]
    pub all: bool,
    /// With --all, list at most this many [default: 1000].
    #[arg(long, requires = "all")]
    pub limit: Option<usize>,
    /// Stop after expanding this many search nodes (the result is then not proven).
    #[arg(long, value_name = "N")]
    pub max_nodes: Option<u64>,
    /// Stop after this many milliseconds (the result is then not proven).
    #[arg(long, value_name = "MS")]
    pub max_millis: Option<u64>,
    /// Print JSON.
    #[arg(long, conflicts_with = "dot")]
    pub json: bool,
    /// Print Graphviz DOT.
    #[arg(long)]
    pub dot: bool,
    /// Also write the (cheapest) configuration as an SVG picture drawn by Ecology itself, with
    /// excluded components marked.
    #[arg(long, value_name = "FILE")]
    pub svg: Option<PathBuf>,
}

/// `ecology check FILE...`
pub fn check(args: &CheckArgs) -> anyhow::Result<u8> {
    let mut code = EXIT_OK;
    for path in &args.files {
        let is_facts = path.extension().is_some_and(|e| e == "facts");
        if is_facts {
            match input::facts(path)? {
                Ok(state) => println!("{}: {} facts, valid", path.display(), state.len()),
                Err(Reported) => code = EXIT_BAD_INPUT,
            }
            continue;
        }
        match input::domain(path)? {
            Ok(domain) => {
                let formats = match domain.information.len() {
                    0 => String::new(),
                    n => format!(", {n} information formats"),
                };
                println!(
                    "{}: domain `{}` is valid: {} functionalities, {} tasks, {} methods, {} actions{formats}",
                    path.display(),
                    domain.name,
                    domain.functionalities.len(),
                    domain.tasks.len(),
                    domain.methods.len(),
                    domain.actions.len()
                );
            }
            Err(Reported) => code = EXIT_BAD_INPUT,
        }
    }
    Ok(code)
}

/// How many configurations `--all` lists without `--limit`: small ecologies
/// have a handful, but the count grows exponentially with the ecology (with
/// 33 components, listing them all ran past 30 s and 5 GB without an end).
const ALL_LIMIT: usize = 1000;

/// `ecology configure ...`
pub fn configure(args: &ConfigureArgs) -> anyhow::Result<u8> {
    let clock = WallClock(Instant::now());
    let Ok(domain) = input::domain(&args.domain)? else {
        return Ok(EXIT_BAD_INPUT);
    };
    // The state (the large file) is read under the budget too: reading stops when it is spent.
    let spent = |clock: &WallClock| {
        args.max_millis
            .is_some_and(|max| clock.elapsed() >= Duration::from_millis(max))
    };
    let Ok(read) = input::facts_until(&args.state, &mut || spent(&clock))? else {
        return Ok(EXIT_BAD_INPUT);
    };
    let Ok(goal) = input::goal(&args.goal) else {
        return Ok(EXIT_BAD_INPUT);
    };
    // A budget spent while reading is not handed to the planner as if it were left.
    if !read.complete || spent(&clock) {
        print_spent_reading(args, clock.elapsed());
        exit_now(read);
        return Ok(EXIT_NO_SOLUTION);
    }
    let state = read.state;
    let request = Request {
        domain: &domain,
        state: &state,
        goal: &goal,
        exclusions: &args.exclude,
    };
    let limit = args.limit.unwrap_or(ALL_LIMIT);
    let options = Options {
        count: if args.all { limit } else { 1 },
        budget: Budget {
            max_expansions: args.max_nodes,
            max_time: args.max_millis.map(Duration::from_millis),
        },
        explain: true,
    };
    let mut line = ProgressLine::new(!args.json);
    let mut observe = |s: Snapshot| line.update(clock.elapsed(), || searching(&s));
    let planned =
        ecology_config::plan_observed(&request, &PaperCost, &options, &clock, &mut observe);
    line.clear();
    let outcome = match planned {
        Ok(outcome) => outcome,
        Err(err) => {
            eprint!("{}", goal_error(&args.goal, &goal, &err));
            return Ok(EXIT_BAD_INPUT);
        }
    };
    if outcome.configurations.is_empty() {
        print_none(args, &outcome);
        exit_now((domain, state, outcome));
        return Ok(EXIT_NO_SOLUTION);
    }
    if let Some(file) = &args.svg {
        let picture = drawing(&outcome.configurations[0], &args.goal, &args.exclude).svg();
        if let Err(e) = std::fs::write(file, picture) {
            eprintln!("error: writing {}: {e}", file.display());
            return Ok(EXIT_BAD_INPUT);
        }
    }
    if args.json {
        let value = if args.all {
            json!({
                "configurations": outcome.configurations.iter().map(|c| config_json(c, &outcome)).collect::<Vec<_>>(),
                "limit": limit,
                "lower_bound": outcome.lower_bound,
                "stats": stats_json(&outcome),
            })
        } else {
            config_json(&outcome.configurations[0], &outcome)
        };
        println!("{value}");
    } else if args.dot {
        for config in &outcome.configurations {
            print!("{}", dot(config, &args.goal));
        }
    } else {
        print_human(args, &outcome);
    }
    exit_now((domain, state, outcome));
    Ok(EXIT_OK)
}

/// What the progress line says of a running search.
fn searching(s: &Snapshot) -> String {
    format!(
        "{} nodes expanded; {} (--max-millis bounds the search)",
        s.expanded,
        standing("configuration", s.best, s.lower_bound)
    )
}

/// The budget ran out while reading the input: nothing planned, no bound.
fn print_spent_reading(args: &ConfigureArgs, elapsed: Duration) {
    let micros = elapsed.as_micros() as u64;
    if args.json {
        let value = json!({
            "error": "budget exceeded",
            "phase": "reading",
            "explanation": null,
            "lower_bound": null,
            "stats": {"expanded": 0, "generated": 0, "alternatives": 0, "micros": micros, "first_micros": null},
        });
        println!("{value}");
    } else {
        eprintln!(
            "no configuration found for {}: the budget was spent while reading the input ({} ms)",
            args.goal,
            micros / 1000
        );
    }
}

fn print_none(args: &ConfigureArgs, outcome: &Outcome) {
    let budget = outcome.status == Status::BudgetExceeded;
    if args.json {
        let value = match &outcome.explanation {
            Some(e) => {
                json!({"error": "no configuration", "explanation": explanation_json(e), "stats": stats_json(outcome)})
            }
            None => json!({
                "error": if budget { "budget exceeded" } else { "no configuration" },
                "phase": if budget { Some("planning") } else { None },
                "explanation": null,
                "lower_bound": outcome.lower_bound,
                "stats": stats_json(outcome),
            }),
        };
        println!("{value}");
        return;
    }
    match &outcome.explanation {
        Some(e) => eprint!("{e}"),
        None if budget => eprintln!(
            "no configuration found for {} within the budget ({} nodes expanded{})",
            args.goal,
            outcome.stats.expanded,
            outcome
                .lower_bound
                .map_or(String::new(), |b| format!("; none costs less than {b}"))
        ),
        None => eprintln!("no configuration for {}", args.goal),
    }
}

fn print_human(args: &ConfigureArgs, outcome: &Outcome) {
    let n = outcome.configurations.len();
    for (i, config) in outcome.configurations.iter().enumerate() {
        if args.all {
            println!("configuration {} of {n} for {}:", i + 1, args.goal);
        } else {
            println!("configuration for {}:", args.goal);
        }
        for line in config.to_string().lines() {
            println!("  {line}");
        }
        if i + 1 < n {
            println!();
        }
    }
    if args.all && args.limit.is_none() && n == ALL_LIMIT {
        println!("  (the {ALL_LIMIT} cheapest; there may be more: --limit N lists up to N)");
    }
    if outcome.status == Status::BudgetExceeded {
        let bound = outcome.lower_bound.map_or(String::new(), |b| {
            format!("; no configuration costs less than {b}")
        });
        println!(
            "  (the budget ran out after {} nodes{bound})",
            outcome.stats.expanded
        );
    }
    println!(
        "  search: {} nodes expanded, {} generated, {} alternatives, {} µs",
        outcome.stats.expanded,
        outcome.stats.generated,
        outcome.stats.alternatives,
        outcome.stats.micros
    );
}

fn stats_json(outcome: &Outcome) -> Value {
    json!({
        "expanded": outcome.stats.expanded,
        "generated": outcome.stats.generated,
        "alternatives": outcome.stats.alternatives,
        "micros": outcome.stats.micros,
        "first_micros": outcome.stats.first_micros,
    })
}

/// The JSON object of one configuration (the format is documented in README).
pub fn config_json(config: &Configuration, outcome: &Outcome) -> Value {
    json!({
        "cost": config.cost,
        "optimal": config.optimal,
        // Under an exhausted budget: no configuration costs less (null when proven).
        "lower_bound": outcome.lower_bound,
        "functionalities": config.functionalities.iter().map(|f| json!({
            "label": f.label,
            "name": f.name,
            "args": f.args,
            "peis": f.peis,
            "component": f.component,
            "state": match f.power { Power::On => "on", Power::Off => "off" },
            "cost": f.cost,
        })).collect::<Vec<_>>(),
        "channels": config.channels.iter().map(|c| json!({
            "from": c.from,
            "to": c.to,
            "info": c.info,
            "remote": c.remote,
        })).collect::<Vec<_>>(),
        "stats": stats_json(outcome),
    })
}

fn explanation_json(e: &Explanation) -> Value {
    json!({
        "subject": e.subject,
        "reason": e.reason,
        "causes": e.causes.iter().map(explanation_json).collect::<Vec<_>>(),
    })
}

fn dot_escape(s: &str) -> String {
    s.replace('\\', "\\\\").replace('"', "\\\"")
}

/// The configuration as a Graphviz digraph: PEIS as clusters, functionality
/// instances as nodes, channels as edges.
fn dot(config: &Configuration, goal: &str) -> String {
    let mut out = String::new();
    out.push_str(&format!(
        "digraph configuration {{\n  label=\"{} — cost {}\";\n  labelloc=t;\n  node [shape=box, style=rounded];\n",
        dot_escape(goal),
        config.cost
    ));
    let mut peis: Vec<&str> = config.functionalities.iter().map(|f| &*f.peis).collect();
    peis.sort_unstable();
    peis.dedup();
    for (i, p) in peis.iter().enumerate() {
        out.push_str(&format!(
            "  subgraph cluster_{i} {{\n    label=\"{}\";\n",
            dot_escape(p)
        ));
        for f in config.functionalities.iter().filter(|f| &*f.peis == *p) {
            let state = match f.power {
                Power::On => "on",
                Power::Off => "off",
            };
            out.push_str(&format!(
                "    \"{}\" [label=\"{}\\n{}:{} ({state}) cost {}\"];\n",
                dot_escape(&f.label),
                dot_escape(&f.call()),
                dot_escape(&f.peis),
                dot_escape(&f.component),
                f.cost
            ));
        }
        out.push_str("  }\n");
    }
    for c in &config.channels {
        let style = if c.remote { ", style=dashed" } else { "" };
        out.push_str(&format!(
            "  \"{}\" -> \"{}\" [label=\"{}\"{style}];\n",
            dot_escape(&c.from),
            dot_escape(&c.to),
            dot_escape(&c.info)
        ));
    }
    out.push_str("}\n");
    out
}

/// Leaves `big` for the operating system to reclaim when the process ends, which is now:
/// freeing a large state piece by piece takes tens of milliseconds that `--max-millis` covers.
fn exit_now<T>(big: T) {
    std::mem::forget(big);
}

/// The configuration as a picture: the same drawing as the live view's, components excluded on
/// the command line marked as failed.
fn drawing(config: &Configuration, goal: &str, excluded: &[Exclusion]) -> Drawing {
    let mut drawing = Drawing {
        title: format!(
            "{goal}: cost {}{}",
            config.cost,
            if config.optimal { " (optimal)" } else { "" }
        ),
        ..Drawing::default()
    };
    for f in &config.functionalities {
        let (state, mark) = match f.power {
            Power::On => ("on", Mark::Normal),
            Power::Off => ("off, switched on", Mark::SwitchedOn),
        };
        drawing.nodes.push(Node {
            peis: f.peis.to_string(),
            component: f.component.to_string(),
            label: f.call(),
            detail: format!("cost {} ({state})", f.cost),
            mark,
        });
    }
    for c in &config.channels {
        let index = |label: &str| {
            config
                .functionalities
                .iter()
                .position(|f| &*f.label == label)
        };
        if let (Some(from), Some(to)) = (index(&c.from), index(&c.to)) {
            drawing.edges.push(Edge {
                from,
                to,
                info: c.info.to_string(),
            });
        }
    }
    for e in excluded {
        if let Exclusion::Component { peis, component } = e
            && drawing.node(peis, component).is_none()
        {
            drawing.nodes.push(Node {
                peis: peis.clone(),
                component: component.clone(),
                label: format!("FAILED {peis}:{component}"),
                detail: "excluded".into(),
                mark: Mark::Failed,
            });
        }
    }
    drawing
}

/// A goal the domain cannot plan for, shown at its place in the goal's text.
fn goal_error(
    text: &str,
    goal: &ecology_domain::Call,
    err: &ecology_config::RequestError,
) -> String {
    use ecology_config::RequestError;
    use ecology_domain::{Diagnostic, Span};
    let whole = goal.span;
    let span = match err {
        RequestError::UnknownGoal { name } => {
            // The name follows the `(` and any spaces.
            let inner = &text[whole.start.min(text.len())..whole.end.min(text.len())];
            let skip = inner
                .char_indices()
                .find(|(_, c)| *c != '(' && !c.is_whitespace())
                .map_or(0, |(i, _)| i);
            let start = whole.start + skip;
            Span::new(start, (start + name.len()).min(whole.end))
        }
        RequestError::NotGround(var) => text
            .find(&format!("?{var}"))
            .map_or(whole, |at| Span::new(at, at + var.len() + 1)),
        RequestError::Arity { .. } => whole,
    };
    let label = match err {
        RequestError::UnknownGoal { .. } => "no task or functionality has this name",
        RequestError::Arity { .. } => "this goal",
        RequestError::NotGround(_) => "a goal names objects, not variables",
    };
    let diagnostic = Diagnostic::error(span, err.to_string()).with_label(label);
    ecology_domain::render("<goal>", text.as_bytes(), &[diagnostic])
}
