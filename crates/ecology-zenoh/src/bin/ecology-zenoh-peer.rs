//! `ecology-zenoh-peer`: hosts one PEIS over Zenoh until its standard input closes (used by tests as a separate process).
//!
//! Usage: `ecology-zenoh-peer --name NAME [--listen EP]... [--connect EP]... [--lease-ms MS] [KEY=VALUE]...`
//! It sets each KEY=VALUE as a text tuple, prints `ready` on standard output, and leaves when standard input closes.

use std::io::{BufRead, Write};
use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;
use ecology_tuples::{Key, PeisId, TupleSpace, Value};
use ecology_zenoh::{ZenohOptions, ZenohPeis};

/// Hosts one PEIS over Zenoh until standard input closes.
#[derive(Debug, Parser)]
#[command(name = "ecology-zenoh-peer")]
struct Args {
    /// The PEIS's name.
    #[arg(long)]
    name: PeisId,
    /// Zenoh endpoints to listen on.
    #[arg(long)]
    listen: Vec<String>,
    /// Zenoh endpoints to connect to.
    #[arg(long)]
    connect: Vec<String>,
    /// The presence lease, in milliseconds.
    #[arg(long = "lease-ms")]
    lease_ms: Option<u64>,
    /// Text tuples to set, as KEY=VALUE.
    #[arg(value_parser = parse_tuple)]
    tuples: Vec<(Key, String)>,
}

/// `KEY=VALUE` as a key and its text.
fn parse_tuple(arg: &str) -> Result<(Key, String), String> {
    let (k, v) = arg
        .split_once('=')
        .ok_or_else(|| format!("expected KEY=VALUE, got {arg:?}"))?;
    Ok((Key::new(k).map_err(|e| e.to_string())?, v.to_owned()))
}

impl Args {
    fn options(&self) -> ZenohOptions {
        let mut options = ZenohOptions::new(self.name.clone());
        options.listen.clone_from(&self.listen);
        options.connect.clone_from(&self.connect);
        if let Some(ms) = self.lease_ms {
            options.peis.lease = Duration::from_millis(ms);
        }
        options
    }
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> ExitCode {
    // Bad arguments exit with 2, as before clap.
    let args = Args::parse();
    let peis = match ZenohPeis::open(args.options()).await {
        Ok(peis) => peis,
        Err(e) => {
            eprintln!("ecology-zenoh-peer: {e}");
            return ExitCode::FAILURE;
        }
    };
    for (key, value) in args.tuples {
        if let Err(e) = peis.set(key, Value::text(value)).await {
            eprintln!("ecology-zenoh-peer: {e}");
            return ExitCode::FAILURE;
        }
    }
    println!("ready");
    let _ = std::io::stdout().flush();
    // Block until standard input closes: the parent's end of the pipe going away ends this PEIS.
    let waited = tokio::task::spawn_blocking(|| {
        let mut line = String::new();
        let mut stdin = std::io::stdin().lock();
        while stdin.read_line(&mut line).is_ok_and(|n| n > 0) {
            line.clear();
        }
    })
    .await;
    peis.close().await;
    if waited.is_err() {
        return ExitCode::FAILURE;
    }
    ExitCode::SUCCESS
}
