//! Reading input files and reporting their diagnostics.

use std::fs::File;
use std::io::Read;
use std::path::Path;

use anyhow::Context;
use ecology_domain::syntax::MAX_FILE_BYTES;
use ecology_domain::{Diagnostics, Domain, EcologyState};

/// A file's bytes, read up to one byte past the size limit so that the parser
/// reports an oversized file without reading all of it.
pub fn read_limited(path: &Path) -> anyhow::Result<Vec<u8>> {
    let file = File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let mut bytes = Vec::new();
    file.take(MAX_FILE_BYTES as u64 + 1)
        .read_to_end(&mut bytes)
        .with_context(|| format!("cannot read {}", path.display()))?;
    Ok(bytes)
}

/// Either the parsed value, or diagnostics already printed to stderr.
pub type Parsed<T> = Result<T, Reported>;

/// Diagnostics were printed; the caller exits 2.
#[derive(Debug)]
pub struct Reported;

fn report(path: &Path, bytes: &[u8], diags: &Diagnostics) -> Reported {
    eprint!("{}", diags.render(&path.display().to_string(), bytes));
    let n = diags.0.len();
    eprintln!(
        "{n} error{} in {}",
        if n == 1 { "" } else { "s" },
        path.display()
    );
    Reported
}

/// Reads and validates a domain file.
pub fn domain(path: &Path) -> anyhow::Result<Parsed<Domain>> {
    let bytes = read_limited(path)?;
    Ok(ecology_domain::parse_domain(&bytes).map_err(|d| report(path, &bytes, &d)))
}

/// Reads a facts file.
pub fn facts(path: &Path) -> anyhow::Result<Parsed<EcologyState>> {
    let bytes = read_limited(path)?;
    Ok(ecology_domain::parse_facts(&bytes).map_err(|d| report(path, &bytes, &d)))
}

/// Reads a facts file, giving up as soon as `stop` says so.
pub fn facts_until(
    path: &Path,
    stop: &mut dyn FnMut() -> bool,
) -> anyhow::Result<Parsed<ecology_domain::FactsRead>> {
    let bytes = read_limited(path)?;
    Ok(ecology_domain::parse_facts_until(&bytes, stop).map_err(|d| report(path, &bytes, &d)))
}

/// Parses a goal given on the command line.
pub fn goal(text: &str) -> Parsed<ecology_domain::Call> {
    ecology_domain::parse_goal(text).map_err(|d| report(Path::new("<goal>"), text.as_bytes(), &d))
}

/// Reads a problem file and checks it against `domain`.
pub fn problem(path: &Path, domain: &Domain) -> anyhow::Result<Parsed<ecology_domain::Problem>> {
    let bytes = read_limited(path)?;
    Ok(ecology_domain::parse_problem_for(domain, &bytes).map_err(|d| report(path, &bytes, &d)))
}
