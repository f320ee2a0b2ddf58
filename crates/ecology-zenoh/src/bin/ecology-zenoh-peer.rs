//! `ecology-zenoh-peer`: hosts one PEIS over Zenoh until its standard input closes (used by tests as a separate process).
//!
//! Usage: `ecology-zenoh-peer --name NAME [--listen EP]... [--connect EP]... [--lease-ms MS] [KEY=VALUE]...`
//! It sets each KEY=VALUE as a text tuple, prints `ready` on standard output, and leaves when standard input closes.

use std::io::{BufRead, Write};
use std::process::ExitCode;
use std::time::Duration;

use ecology_tuples::{Key, PeisId, TupleSpace, Value};
use ecology_zenoh::{ZenohOptions, ZenohPeis};

struct Args {
    options: ZenohOptions,
    tuples: Vec<(Key, String)>,
}

fn parse_args(mut args: impl Iterator<Item = String>) -> Result<Args, String> {
    let mut name = None;
    let mut listen = Vec::new();
    let mut connect = Vec::new();
    let mut lease = None;
    let mut tuples = Vec::new();
    while let Some(arg) = args.next() {
        let mut value = |flag: &str| args.next().ok_or_else(|| format!("{flag} needs a value"));
        match arg.as_str() {
            "--name" => name = Some(PeisId::new(&value("--name")?).map_err(|e| e.to_string())?),
            "--listen" => listen.push(value("--listen")?),
            "--connect" => connect.push(value("--connect")?),
            "--lease-ms" => {
                let ms: u64 = value("--lease-ms")?
                    .parse()
                    .map_err(|e| format!("--lease-ms: {e}"))?;
                lease = Some(Duration::from_millis(ms));
            }
            other => {
                let (k, v) = other
                    .split_once('=')
                    .ok_or_else(|| format!("unexpected argument {other:?}"))?;
                tuples.push((Key::new(k).map_err(|e| e.to_string())?, v.to_owned()));
            }
        }
    }
    let mut options = ZenohOptions::new(name.ok_or("--name is required")?);
    options.listen = listen;
    options.connect = connect;
    if let Some(lease) = lease {
        options.peis.lease = lease;
    }
    Ok(Args { options, tuples })
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> ExitCode {
    let args = match parse_args(std::env::args().skip(1)) {
        Ok(args) => args,
        Err(message) => {
            eprintln!("ecology-zenoh-peer: {message}");
            return ExitCode::from(2);
        }
    };
    let peis = match ZenohPeis::open(args.options).await {
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
