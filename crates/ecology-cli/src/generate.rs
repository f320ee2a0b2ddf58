//! `ecology generate home --peis N [--seed S] [--output FILE]`: a scenario file of a PEIS-Home
//! building with N PEIS, for running the paper's task in large ecologies.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args, Subcommand};

use crate::{EXIT_BAD_INPUT, EXIT_OK};

/// Arguments of `ecology generate`.
#[derive(Debug, Args)]
pub struct GenerateArgs {
    #[command(subcommand)]
    pub what: Generate,
}

/// What to generate.
#[derive(Debug, Subcommand)]
pub enum Generate {
    /// The PEIS-Home with a wing of rooms and more devices (monitors, robots, appliances): a
    /// scenario file for `ecology run`, `ecology peis` and `ecology world`.
    Home(HomeArgs),
}

/// Arguments of `ecology generate home`.
#[derive(Debug, Args)]
pub struct HomeArgs {
    /// How many PEIS in all, counting the world, astrid, hsm and pippi (at least 4).
    #[arg(long, value_name = "N")]
    pub peis: usize,
    /// The seed the devices and their costs are drawn from.
    #[arg(long, value_name = "S", default_value_t = 1)]
    pub seed: u64,
    /// Write the scenario here instead of to standard output.
    #[arg(long, short, value_name = "FILE")]
    pub output: Option<PathBuf>,
    /// The task's domain, written into the file as an absolute path.
    #[arg(long, value_name = "FILE", default_value = "domains/peis-building.eco")]
    pub domain: PathBuf,
    /// The task's problem, written into the file as an absolute path.
    #[arg(
        long,
        value_name = "FILE",
        default_value = "domains/peis-home-task.problem"
    )]
    pub problem: PathBuf,
}

/// Runs `ecology generate`.
pub fn generate(args: &GenerateArgs) -> anyhow::Result<u8> {
    let Generate::Home(args) = &args.what;
    let absolute = |path: &Path, what: &str| -> anyhow::Result<String> {
        let found = std::fs::canonicalize(path).with_context(|| {
            format!(
                "the {what} {} is not there (run from the repository's root, or pass --{what})",
                path.display()
            )
        })?;
        Ok(found.display().to_string())
    };
    let domain = absolute(&args.domain, "domain")?;
    let problem = absolute(&args.problem, "problem")?;
    let text = match ecology_sim::generate::home(args.peis, args.seed, &domain, &problem) {
        Ok(text) => text,
        Err(why) => {
            eprintln!("error: {why}");
            return Ok(EXIT_BAD_INPUT);
        }
    };
    match &args.output {
        Some(path) => {
            std::fs::write(path, &text).with_context(|| format!("writing {}", path.display()))?;
            eprintln!("wrote {} ({} PEIS)", path.display(), args.peis);
        }
        None => std::io::stdout()
            .lock()
            .write_all(text.as_bytes())
            .context("writing the scenario")?,
    }
    Ok(EXIT_OK)
}
