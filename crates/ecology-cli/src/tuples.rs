//! `ecology tuples`: watch, get and set tuples of a live ecology over Zenoh (like PEIS tupleview).
//!
//! Exit codes: 0 success, 1 not found (no such tuple, owner not reachable, remote set refused),
//! 2 bad input (malformed name, key, pattern or value). Failing to join the ecology is an error (1).

use std::io::{BufRead, Write};
use std::time::Duration;

use anyhow::Context;
use ecology_tuples::{
    Clock, Key, PeisId, PresenceEvent, SystemClock, Tuple, TupleError, TupleEvent, TuplePattern,
    TupleSpace, ValidationError, Value,
};
use ecology_zenoh::ZenohPeis;

use crate::network::{self, JoinFailure, NetArgs};

use crate::{EXIT_BAD_INPUT, EXIT_NOT_FOUND, EXIT_OK};

/// `ecology tuples`: options to join an ecology, and what to do there.
#[derive(clap::Args, Debug)]
pub struct TuplesArgs {
    /// The PEIS name to join as (default: tuples-PID; with --keys, a member of the roster).
    #[arg(long, global = true, value_name = "PEIS")]
    name: Option<String>,
    #[command(flatten)]
    net: NetArgs,
    #[command(subcommand)]
    command: TuplesCommand,
}

#[derive(clap::Subcommand, Debug)]
enum TuplesCommand {
    /// Show tuples as they change: owner, key, value preview and age.
    Watch {
        /// OWNER:KEYPATTERN, such as 'astrid:components.*.status' ('*' one segment, '**' any); default every tuple.
        pattern: Option<String>,
        /// Print one JSON object per change.
        #[arg(long)]
        json: bool,
        /// Stop after this many tuple changes.
        #[arg(long, value_name = "N")]
        count: Option<u64>,
    },
    /// Print the value of tuple (OWNER, KEY).
    Get {
        /// The owning PEIS.
        owner: String,
        /// The dotted key.
        key: String,
    },
    /// Set tuple (OWNER, KEY) to VALUE; a remote set when OWNER is another PEIS.
    Set {
        /// The owning PEIS.
        owner: String,
        /// The dotted key.
        key: String,
        /// The value, as text.
        value: String,
        /// After setting, stay in the ecology (print `ready`) until standard input closes.
        #[arg(long)]
        hold: bool,
    },
    /// List the PEIS present.
    Peers,
}

/// Runs `ecology tuples` and returns the exit code.
pub fn run(args: TuplesArgs) -> anyhow::Result<u8> {
    network::runtime()?.block_on(run_async(args))
}

fn bad_input(e: &ValidationError) -> u8 {
    eprintln!("ecology tuples: {e}");
    EXIT_BAD_INPUT
}

async fn run_async(args: TuplesArgs) -> anyhow::Result<u8> {
    let name = match &args.name {
        Some(name) => PeisId::new(name),
        None => PeisId::new(&format!("tuples-{}", std::process::id())),
    };
    let name = match name {
        Ok(name) => name,
        Err(e) => return Ok(bad_input(&e)),
    };
    // Validate the command before joining, so bad input fails fast and joins nothing.
    let command = match Command::parse(&args.command) {
        Ok(command) => command,
        Err(e) => return Ok(bad_input(&e)),
    };
    let peis = match network::join(name, &args.net).await {
        Ok(peis) => peis,
        Err(JoinFailure::NameTaken(id)) => {
            eprintln!(
                "ecology tuples: a PEIS named {id} is already present; choose another --name"
            );
            return Ok(EXIT_BAD_INPUT);
        }
        Err(JoinFailure::BadConfig(e)) => {
            eprintln!("ecology tuples: {e:#}");
            return Ok(EXIT_BAD_INPUT);
        }
        Err(JoinFailure::Other(e)) => {
            // Unreachable endpoints are "not found", as an unreachable owner is.
            eprintln!("ecology tuples: {e:#}");
            return Ok(EXIT_NOT_FOUND);
        }
    };
    let code = command.execute(&peis).await;
    peis.close().await;
    code
}

enum Command {
    Watch {
        pattern: TuplePattern,
        json: bool,
        count: Option<u64>,
    },
    Get {
        owner: PeisId,
        key: Key,
    },
    Set {
        owner: PeisId,
        key: Key,
        value: String,
        hold: bool,
    },
    Peers,
}

impl Command {
    fn parse(command: &TuplesCommand) -> Result<Self, ValidationError> {
        Ok(match command {
            TuplesCommand::Watch {
                pattern,
                json,
                count,
            } => Self::Watch {
                pattern: match pattern {
                    Some(p) => TuplePattern::parse(p)?,
                    None => TuplePattern::everything(),
                },
                json: *json,
                count: *count,
            },
            TuplesCommand::Get { owner, key } => Self::Get {
                owner: PeisId::new(owner)?,
                key: Key::new(key)?,
            },
            TuplesCommand::Set {
                owner,
                key,
                value,
                hold,
            } => Self::Set {
                owner: PeisId::new(owner)?,
                key: Key::new(key)?,
                value: value.clone(),
                hold: *hold,
            },
            TuplesCommand::Peers => Self::Peers,
        })
    }

    async fn execute(self, peis: &ZenohPeis) -> anyhow::Result<u8> {
        let mut out = std::io::stdout().lock();
        match self {
            Self::Get { owner, key } => match peis.get(owner.clone(), key.clone()).await? {
                Some(tuple) => {
                    out.write_all(&tuple.data)?;
                    writeln!(out)?;
                    Ok(EXIT_OK)
                }
                None => {
                    eprintln!("ecology tuples: no tuple ({owner} {key})");
                    Ok(EXIT_NOT_FOUND)
                }
            },
            Self::Set {
                owner,
                key,
                value,
                hold,
            } => {
                match peis.set_remote(owner, key, Value::text(value)).await {
                    Ok(tuple) => writeln!(out, "{} {} seq {}", tuple.owner, tuple.key, tuple.seq)?,
                    Err(TupleError::Invalid(e)) => return Ok(bad_input(&e)),
                    Err(
                        e @ (TupleError::OwnerUnreachable { .. }
                        | TupleError::RemoteSetRefused { .. }),
                    ) => {
                        eprintln!("ecology tuples: {e}");
                        return Ok(EXIT_NOT_FOUND);
                    }
                    Err(e) => return Err(e).context("setting the tuple"),
                }
                if hold {
                    writeln!(out, "ready")?;
                    out.flush()?;
                    drop(out);
                    wait_for_stdin_to_close().await?;
                }
                Ok(EXIT_OK)
            }
            Self::Peers => {
                drop(out);
                let peers = settled_peers(peis).await?;
                let mut out = std::io::stdout().lock();
                for id in peers {
                    writeln!(out, "{id}")?;
                }
                Ok(EXIT_OK)
            }
            Self::Watch {
                pattern,
                json,
                count,
            } => {
                drop(out);
                watch(peis, pattern, json, count).await
            }
        }
    }
}

async fn wait_for_stdin_to_close() -> anyhow::Result<()> {
    let reader = tokio::task::spawn_blocking(|| {
        let mut line = String::new();
        let mut stdin = std::io::stdin().lock();
        while stdin.read_line(&mut line).is_ok_and(|n| n > 0) {
            line.clear();
        }
    });
    tokio::select! {
        done = reader => done.context("waiting for standard input")?,
        _ = crate::network::stop_signal() => {}
    }
    Ok(())
}

/// The PEIS present, once the mesh has formed: a process that has just joined
/// is linked to the PEIS it connected to at first, and to the others only when
/// gossip has told it their endpoints, so presence is gathered until no PEIS
/// has joined for a moment (at most [`SETTLE_MAX`]).
async fn settled_peers(peis: &ZenohPeis) -> anyhow::Result<Vec<PeisId>> {
    const QUIET: Duration = Duration::from_millis(400);
    const SETTLE_MAX: Duration = Duration::from_secs(3);
    let mut presence = peis.subscribe_presence().await?;
    let mut present = std::collections::BTreeSet::new();
    let deadline = tokio::time::Instant::now() + SETTLE_MAX;
    loop {
        let quiet = tokio::time::Instant::now() + QUIET;
        match tokio::time::timeout_at(quiet.min(deadline), presence.next()).await {
            Ok(Some(PresenceEvent::Joined(id))) => {
                present.insert(id);
            }
            Ok(Some(PresenceEvent::Left(id))) => {
                present.remove(&id);
            }
            Ok(None) | Err(_) => break,
        }
    }
    present.insert(peis.peis().clone());
    Ok(present.into_iter().collect())
}

async fn watch(
    peis: &ZenohPeis,
    pattern: TuplePattern,
    json: bool,
    count: Option<u64>,
) -> anyhow::Result<u8> {
    // One listener for the whole watch: a SIGINT that came between two
    // changes was lost when each wait made a listener of its own.
    let stop = crate::network::stop_signal();
    let _reporter = crate::network::report_on_sigusr1("tuples watch", None);
    tokio::pin!(stop);
    let mut tuples = peis.subscribe(pattern).await?;
    let mut presence = peis.subscribe_presence().await?;
    let clock = SystemClock;
    let mut seen = 0;
    loop {
        if count.is_some_and(|c| seen >= c) {
            return Ok(EXIT_OK);
        }
        let line = tokio::select! {
            // Tuples first: a PEIS that leaves reports its components off before its presence
            // ends, and a watcher shows them in that order.
            biased;
            event = tuples.next() => match event {
                Some(event) => {
                    seen += 1;
                    if json { event_json(&event, &clock) } else { event_line(&event, &clock) }
                }
                None => return Ok(EXIT_OK),
            },
            event = presence.next(), if !json => match event {
                Some(PresenceEvent::Joined(id)) => format!("+ {id} joined"),
                Some(PresenceEvent::Left(id)) => format!("- {id} left"),
                None => return Ok(EXIT_OK),
            },
            _ = &mut stop => return Ok(EXIT_OK),
        };
        let mut out = std::io::stdout().lock();
        writeln!(out, "{line}")?;
        out.flush()?;
    }
}

/// At most 60 characters of the value: text as is (control characters escaped), bytes in hex.
fn preview(tuple: &Tuple) -> String {
    const MAX: usize = 60;
    match tuple.text() {
        Ok(text) => {
            let escaped: String = text.chars().flat_map(char::escape_default).collect();
            if escaped.chars().count() > MAX {
                let cut: String = escaped.chars().take(MAX).collect();
                format!("\"{cut}…\"")
            } else {
                format!("\"{escaped}\"")
            }
        }
        Err(_) => {
            let hex: String = tuple
                .data
                .iter()
                .take(MAX / 2)
                .map(|b| format!("{b:02x}"))
                .collect();
            let more = if tuple.data.len() > MAX / 2 {
                "…"
            } else {
                ""
            };
            format!("0x{hex}{more} ({} bytes)", tuple.data.len())
        }
    }
}

fn age(tuple: &Tuple, clock: &dyn Clock) -> Duration {
    clock.now().saturating_duration_since(tuple.ts_write)
}

fn event_line(event: &TupleEvent, clock: &dyn Clock) -> String {
    match event {
        TupleEvent::Changed(t) => format!(
            "{:<12} {:<32} {}  ({} seq {}, age {:.1}s{})",
            t.owner,
            t.key,
            preview(t),
            t.mimetype,
            t.seq,
            age(t, clock).as_secs_f64(),
            t.creator
                .as_ref()
                .map(|c| format!(", set by {c}"))
                .unwrap_or_default()
        ),
        TupleEvent::Removed {
            owner, key, reason, ..
        } => format!("{owner:<12} {key:<32} removed ({reason:?})"),
        TupleEvent::Retargeted {
            meta_owner,
            meta_key,
            target,
        } => format!("{meta_owner:<12} {meta_key:<32} points at {target:?}"),
    }
}

fn event_json(event: &TupleEvent, clock: &dyn Clock) -> String {
    let value = match event {
        TupleEvent::Changed(t) => {
            let mut object = serde_json::json!({
                "event": "changed",
                "owner": t.owner.as_str(),
                "key": t.key.as_str(),
                "mimetype": t.mimetype.as_str(),
                "seq": t.seq,
                "epoch": t.epoch,
                "ts_write_ns": t.ts_write.as_nanos(),
                "age_ms": u64::try_from(age(t, clock).as_millis()).unwrap_or(u64::MAX),
            });
            match t.text() {
                Ok(text) => object["value"] = serde_json::Value::from(text),
                Err(_) => {
                    let hex: String = t.data.iter().map(|b| format!("{b:02x}")).collect();
                    object["value_hex"] = serde_json::Value::from(hex);
                }
            }
            if let Some(ts) = t.ts_user {
                object["ts_user_ns"] = serde_json::Value::from(ts.as_nanos());
            }
            if let Some(expiry) = t.expiry {
                object["expiry_ns"] = serde_json::Value::from(expiry.as_nanos());
            }
            // Who set it by remote set: with keys, the member that sent the request.
            if let Some(creator) = &t.creator {
                object["set_by"] = serde_json::Value::from(creator.as_str());
            }
            object
        }
        TupleEvent::Removed {
            owner,
            key,
            seq,
            reason,
            ..
        } => serde_json::json!({
            "event": "removed",
            "owner": owner.as_str(),
            "key": key.as_str(),
            "seq": seq,
            "reason": format!("{reason:?}").to_lowercase(),
        }),
        TupleEvent::Retargeted {
            meta_owner,
            meta_key,
            target,
        } => serde_json::json!({
            "event": "retargeted",
            "owner": meta_owner.as_str(),
            "key": meta_key.as_str(),
            "target": target.as_ref().map(ToString::to_string),
        }),
    };
    value.to_string()
}
