//! The `ecology` command-line tool.

mod tuples;

use clap::Parser;

/// Dynamic self-configuration of an ecology of robots.
#[derive(Parser, Debug)]
#[command(name = "ecology", version)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Subcommand, Debug)]
enum Command {
    /// Watch, get and set tuples of a live ecology over Zenoh.
    Tuples(tuples::TuplesArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Tuples(args) => tuples::run(args),
    };
    match result {
        Ok(code) => std::process::ExitCode::from(u8::try_from(code).unwrap_or(1)),
        Err(e) => {
            eprintln!("ecology: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
