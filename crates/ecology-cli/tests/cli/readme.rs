//! Every command README and the pages of docs/ in `PAGES` show, run or checked, so none goes stale: the quick ones are run and
//! their exit codes and costs compared with what README says next to them (`# exit 1`, `# 80: …`);
//! the ones that start a long-running process (a PEIS, a router, a real-time run, a sweep of
//! 10,000 seeds) have their arguments checked by the binary (`ECOLOGY_PARSE_ONLY`); and every other
//! command must be one of the scripts and benchmarks listed here, which CI or a person runs.

use std::collections::BTreeMap;
use std::process::Command;

use crate::support::root;

/// Commands README shows that are not `ecology` itself.
const OTHERS: &[&str] = &[
    "scripts/test",                              // README's test command: CI runs it
    "cargo test -p ecology-cli --test cli ros2", // part of scripts/test
    "scripts/bench-config",                      // benchmarks: run by hand, minutes each
    "cargo bench -p ecology-config --bench configure",
    "cargo bench -p ecology-config --bench facts",
    "cargo bench -p ecology-cli --bench fuzz",
    "cargo bench -p ecology-cli --bench faults",
    "cargo bench -p ecology-cli --bench large",
    "cargo bench -p ecology-exec --bench reconfigure",
    "cargo bench -p ecology-actions --bench plan",
    "cargo bench -p ecology-actions --bench conditional",
    "cargo bench -p ecology-zenoh --bench loopback",
    "LOOPBACK_TLS=1 cargo bench -p ecology-zenoh --bench loopback",
    "scripts/bench-actions",
    "scripts/bench-budget",
    "scripts/soak-executives",
];

/// Subcommands and options that start something long-running: checked, not run.
fn long_running(args: &[String]) -> bool {
    let first = args.first().map(String::as_str).unwrap_or("");
    matches!(
        first,
        "world" | "peis" | "task" | "router" | "view" | "sweep" | "tuples"
    ) || args
        .iter()
        .any(|a| a == "--realtime" || a == "--view" || a == "--processes")
}

/// The shell words of `line` (single and double quotes; no other shell syntax is used in README).
fn words(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut word = String::new();
    let mut quote = None;
    let mut any = false;
    for c in line.chars() {
        match (quote, c) {
            (Some(q), c) if c == q => quote = None,
            (Some(_), c) => word.push(c),
            (None, '\'' | '"') => {
                quote = Some(c);
                any = true;
            }
            (None, c) if c.is_whitespace() => {
                if any || !word.is_empty() {
                    out.push(std::mem::take(&mut word));
                    any = false;
                }
            }
            (None, c) => word.push(c),
        }
    }
    if any || !word.is_empty() {
        out.push(word);
    }
    out
}

/// Commands of README's `sh` blocks: continuation lines joined, `VAR="…"` expanded, `&&` split,
/// with the comment after each.
fn commands(readme: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut vars: BTreeMap<String, String> = BTreeMap::new();
    let mut in_sh = false;
    let mut pending = String::new();
    for line in readme.lines() {
        if line.starts_with("```") {
            in_sh = line.trim() == "```sh";
            continue;
        }
        if !in_sh {
            continue;
        }
        if let Some(head) = line.strip_suffix('\\') {
            pending.push_str(head);
            continue;
        }
        let full = std::mem::take(&mut pending) + line;
        // A `#` starts a comment only after whitespace (not inside `'*.fault'` or a URL).
        let (code, comment) = match full.find(" #") {
            Some(at) => (&full[..at], full[at + 2..].trim()),
            None if full.trim_start().starts_with('#') => ("", full.trim_start()),
            None => (full.as_str(), ""),
        };
        let code = code.trim();
        if code.is_empty() {
            continue;
        }
        if let Some((name, value)) = code.split_once('=')
            && !name.contains(' ')
            && value.starts_with('"')
        {
            let expanded = expand(value.trim_matches('"'), &vars);
            vars.insert(name.to_owned(), expanded);
            continue;
        }
        for part in code.split("&&") {
            out.push((expand(part.trim(), &vars), comment.to_owned()));
        }
    }
    out
}

fn expand(text: &str, vars: &BTreeMap<String, String>) -> String {
    let mut text = text.to_owned();
    for (name, value) in vars {
        text = text.replace(&format!("${name}"), value);
    }
    text
}

/// What README says a command does: its exit code (`exit N`, else 0) and a cost it prints
/// (a comment starting `N:` or `N,` is a cost: `cost N`, or a plan's `; cost = N`).
fn expectation(comment: &str) -> (i32, Option<u64>) {
    let code = comment
        .split("exit ")
        .nth(1)
        .and_then(|rest| rest.chars().next())
        .and_then(|c| c.to_digit(10))
        .map_or(0, |d| d as i32);
    let digits: String = comment.chars().take_while(char::is_ascii_digit).collect();
    let cost = comment[digits.len()..]
        .starts_with([':', ','])
        .then(|| digits.parse().ok())
        .flatten();
    (code, cost)
}

/// The pages whose commands are run: README and the pages of docs/ written as `cargo run`
/// commands from the repository (the language reference and the tuple, component and security
/// pages show the installed `ecology` on files of their own).
const PAGES: &[&str] = &[
    "README.md",
    "docs/planning.md",
    "docs/executive.md",
    "docs/network.md",
    "docs/benchmarks.md",
    "docs/tutorial.md",
];

/// Each page's name and text, in the order of [`PAGES`].
fn pages() -> Vec<(String, String)> {
    PAGES
        .iter()
        .map(|page| {
            let text = std::fs::read_to_string(root().join(page)).expect("a page");
            (page.to_string(), text)
        })
        .collect()
}

#[test]
fn every_command_in_readme_runs_as_readme_says() {
    let keys = std::env::temp_dir().join(format!("ecology-readme-keys-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&keys);
    let (mut ran, mut checked, mut others) = (0, 0, 0);
    let shown: Vec<(String, String, String)> = pages()
        .into_iter()
        .flat_map(|(page, text)| {
            commands(&text)
                .into_iter()
                .map(move |(command, comment)| (page.clone(), command, comment))
        })
        .collect();
    let mut last_page = String::new();
    for (page, command, comment) in shown {
        // Each page makes its keys afresh.
        if page != last_page {
            let _ = std::fs::remove_dir_all(&keys);
            last_page = page.clone();
        }
        let prefix = [
            "cargo run -q --release --bin ecology -- ",
            "cargo run --release --bin ecology -- ",
        ]
        .iter()
        .find(|p| command.starts_with(*p));
        let Some(prefix) = prefix else {
            // Environment settings before a script (`BENCH_LARGE=1 scripts/bench-actions`).
            let mut bare = command.as_str();
            while let Some((first, rest)) = bare.split_once(' ')
                && first.contains('=')
            {
                bare = rest;
            }
            assert!(
                OTHERS.iter().any(|o| bare.starts_with(o)),
                "{page} shows a command no test or script covers: {command}"
            );
            others += 1;
            continue;
        };
        let mut args = words(&command[prefix.len()..]);
        // The pages' keys directory is made in a temporary folder instead of the repository.
        for a in &mut args {
            if a == "./home-keys" {
                *a = keys.display().to_string();
            }
        }
        let mut run = Command::new(env!("CARGO_BIN_EXE_ecology"));
        run.args(&args).current_dir(root());
        let long = long_running(&args);
        if long {
            run.env("ECOLOGY_PARSE_ONLY", "1");
        }
        let out = run.output().expect("runs");
        let stdout = String::from_utf8_lossy(&out.stdout);
        let (code, cost) = expectation(&comment);
        let expected = if long { 0 } else { code };
        assert_eq!(
            out.status.code(),
            Some(expected),
            "`{command}` ({page}: {comment:?}):\n{stdout}\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        if let (Some(cost), false) = (cost, long) {
            assert!(
                stdout.contains(&format!("cost {cost}"))
                    || stdout.contains(&format!("; cost = {cost}\n")),
                "`{command}` should print cost {cost} ({page}: {comment:?}):\n{stdout}"
            );
        }
        if long {
            checked += 1;
        } else {
            ran += 1;
        }
    }
    let _ = std::fs::remove_dir_all(&keys);
    println!(
        "README and docs: {ran} commands run, {checked} long-running ones checked, {others} scripts and benchmarks"
    );
    assert!(
        ran >= 15 && checked >= 8,
        "README's commands were not found"
    );
}
