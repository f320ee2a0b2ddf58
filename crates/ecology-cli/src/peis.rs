//! `ecology peis FILE --name P`: one PEIS as a process of its own on Zenoh,
//! with its init component, its simulated components and its presence (or
//! several, `--name P,Q` or `--all`, each with its own identity); and
//! `ecology world SCENARIO`: the simulated world as a PEIS process.

use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use clap::Args;
use ecology_sim::{PeisDef, Scenario, WORLD};
use ecology_tuples::{KeyPattern, OwnerPattern, PeisId, SystemClock, TuplePattern, TupleSpace};
use ecology_zenoh::ZenohPeis;
use futures_util::StreamExt;

use crate::network::{self, JoinFailure, NetArgs};
use crate::{EXIT_BAD_INPUT, EXIT_NO_SOLUTION, EXIT_OK};

/// Arguments of `ecology peis`.
#[derive(Debug, Args)]
pub struct PeisArgs {
    /// A TOML file with [[peis]] tables (a scenario file, or PEIS alone).
    pub file: PathBuf,
    /// Which PEIS of the file to run (needed when it describes several); several, comma-separated
    /// or repeated, run in this one process, each with its own identity and presence.
    #[arg(
        long,
        value_name = "PEIS",
        value_delimiter = ',',
        conflicts_with = "all"
    )]
    pub name: Vec<String>,
    /// Run every PEIS of the file in this one process, each with its own identity and presence
    /// (best as clients of a router: --connect ROUTER --client).
    #[arg(long)]
    pub all: bool,
    /// The seed of the simulated components' noise.
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub seed: u64,
    #[command(flatten)]
    pub net: NetArgs,
}

/// Arguments of `ecology world`.
#[derive(Debug, Args)]
pub struct WorldArgs {
    /// The scenario file (TOML) whose map, robots, things and residents to simulate.
    pub scenario: PathBuf,
    /// The seed of the world's noise (default: the scenario's).
    #[arg(long, value_name = "N")]
    pub seed: Option<u64>,
    /// The simulation's time step, in milliseconds.
    #[arg(long, value_name = "MS", default_value_t = 50)]
    pub step_ms: u64,
    #[command(flatten)]
    pub net: NetArgs,
}

/// How many PEIS of one process open their Zenoh sessions at once: a thousand handshakes at once
/// on a small machine outlast the connect timeout, and some PEIS would not join.
const JOINING_AT_ONCE: usize = 32;

/// From how many PEIS a process holds, its presence lease defaults to [`BUSY_LEASE`] seconds
/// instead of 2 (`--lease` still chooses).
const MANY_PEIS: usize = 100;

/// The default presence lease of a process of [`MANY_PEIS`] or more. A router drops a link it has
/// heard nothing on for the lease its PEIS announced; a process of a thousand PEIS on 2 cores,
/// busy starting them, went 2 s without a word on some of its sessions in about half of the runs
/// (16 to 161 sessions dropped and joined again), and in none of three with 5 s.
const BUSY_LEASE: f64 = 5.0;

/// `net` with the presence lease a process of `peis` PEIS gets by default.
fn with_default_lease(net: &NetArgs, peis: usize) -> NetArgs {
    let mut net = net.clone();
    if net.lease.is_none() && peis >= MANY_PEIS {
        net.lease = Some(BUSY_LEASE);
        say(&format!(
            "{peis} PEIS in one process: presence lease {BUSY_LEASE} s (--lease to choose)"
        ));
    }
    net
}

/// How often one PEIS of a process of several tries to join when its session cannot be opened
/// while another PEIS of the process has joined through the same endpoints (so they can be
/// reached, and the failure was the moment's: a router busy with hundreds of handshakes).
const JOIN_ATTEMPTS: u32 = 3;

/// Joins the ecology as `id`, trying again as [`JOIN_ATTEMPTS`] says.
async fn join_retrying(
    id: PeisId,
    net: &NetArgs,
    joined_any: &AtomicBool,
) -> Result<ZenohPeis, JoinFailure> {
    let mut attempt = 1;
    loop {
        match network::join(id.clone(), net).await {
            Ok(space) => {
                joined_any.store(true, Ordering::Relaxed);
                return Ok(space);
            }
            Err(JoinFailure::Other(e))
                if attempt < JOIN_ATTEMPTS && joined_any.load(Ordering::Relaxed) =>
            {
                say(&format!("{id}: could not join ({e:#}); trying again"));
                attempt += 1;
            }
            Err(e) => return Err(e),
        }
    }
}

fn say(line: &str) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{line}");
    let _ = out.flush();
}

/// `ecology peis FILE [--name P[,Q…] | --all]`.
pub fn peis(args: &PeisArgs) -> anyhow::Result<u8> {
    let defs = match PeisDef::load_all(&args.file) {
        Ok(defs) => defs,
        Err(e) => {
            eprintln!("error: {e}");
            return Ok(EXIT_BAD_INPUT);
        }
    };
    let chosen = match choose(&args.file, &defs, &args.name, args.all) {
        Ok(chosen) => chosen,
        Err(message) => {
            eprintln!("error: {message}");
            return Ok(EXIT_BAD_INPUT);
        }
    };
    if chosen.len() > 1 && !args.net.listen.is_empty() {
        eprintln!(
            "error: {} PEIS cannot share --listen endpoints; connect them to a router instead \
             (--connect ROUTER --client)",
            chosen.len()
        );
        return Ok(EXIT_BAD_INPUT);
    }
    let ids = chosen
        .iter()
        .map(|def| PeisId::new(&def.name))
        .collect::<Result<Vec<_>, _>>()?;
    network::runtime()?.block_on(async {
        // Installed before any readiness line, so that no signal is lost.
        let stop = network::stop_signal();
        let _reporter = network::report_on_sigusr1("peis", None);
        let (stopping, stopped) = tokio::sync::watch::channel(None::<&'static str>);
        tokio::pin!(stop);
        // ROS 2 nodes are driven through one agent for the whole process, started before anyone
        // joins: a Python without rclpy is a clear error, not a PEIS whose nodes never start.
        let agent = match start_agent(&chosen).await {
            Ok(agent) => agent,
            Err(e) => {
                eprintln!("error: {e}");
                return Ok(EXIT_BAD_INPUT);
            }
        };
        // Up to JOINING_AT_ONCE PEIS join at a time (each join waits for the mesh to settle, so
        // not one after the other), in the file's order.
        let total = ids.len();
        let net = with_default_lease(&args.net, total);
        let joined_any = AtomicBool::new(false);
        let mut joining = futures_util::stream::iter(ids)
            .map(|id| join_retrying(id, &net, &joined_any))
            .buffered(JOINING_AT_ONCE);
        let mut spaces = Vec::new();
        // Each second of a long join says how far it is.
        let mut progress = tokio::time::interval_at(
            tokio::time::Instant::now() + Duration::from_secs(1),
            Duration::from_secs(1),
        );
        // Why joining ended before every PEIS joined: a signal, or a PEIS that could not join.
        let cut_short = loop {
            tokio::select! {
                which = &mut stop => break Some(Ok(which)),
                joined = joining.next() => match joined {
                    Some(Ok(space)) => spaces.push(space),
                    Some(Err(failure)) => break Some(Err(failure)),
                    None => break None,
                },
                _ = progress.tick() => say(&format!("… {} of {total} PEIS joined", spaces.len())),
            }
        };
        drop(joining);
        if let Some(why) = cut_short {
            // Those that joined leave again: nothing is left behind for a PEIS that did not start.
            let joined = spaces.len();
            futures_util::future::join_all(spaces.into_iter().map(|s| s.close())).await;
            return Ok(match why {
                Ok(which) => {
                    say(&format!(
                        "{which} while joining: {joined} of {total} PEIS had joined, and left again"
                    ));
                    EXIT_OK
                }
                Err(failure) => join_failed(failure),
            });
        }
        let mut hosts = tokio::task::JoinSet::new();
        for (def, space) in chosen.into_iter().zip(spaces) {
            let id = space.peis().clone();
            let components: Vec<String> = def
                .components
                .iter()
                .map(|c| {
                    let power = if c.on { "on" } else { "off" };
                    format!("{} ({}, {power})", c.id, c.kind)
                })
                .collect();
            say(&format!(
                "{id} ready: components {}; {}",
                components.join(", "),
                args.net.describe()
            ));
            let mut stopped = stopped.clone();
            let seed = args.seed;
            let agent = agent.clone();
            hosts.spawn(async move {
                let name = id.clone();
                let result = ecology_sim::host_peis(
                    space.clone(),
                    Arc::new(SystemClock),
                    &def,
                    seed,
                    agent.as_ref(),
                    move |note| say(&format!("{name}: {note}")),
                    async move {
                        let _ = stopped.wait_for(Option::is_some).await;
                    },
                )
                .await;
                space.close().await;
                (id, result)
            });
        }
        if hosts.len() > 1 {
            say(&format!("{} PEIS ready", hosts.len()));
        }
        let mut code = EXIT_OK;
        let mut signalled = false;
        loop {
            tokio::select! {
                which = &mut stop, if !signalled => {
                    signalled = true;
                    network::stopping("switching its components off and leaving the ecology");
                    let _ = stopping.send(Some(which));
                }
                done = hosts.join_next() => {
                    let Some(done) = done else { break };
                    let which = (*stopping.borrow()).unwrap_or("shutdown");
                    match done {
                        Ok((id, Ok(()))) => say(&format!(
                            "{id}: {which}: components switched off, presence withdrawn"
                        )),
                        Ok((id, Err(e))) => {
                            eprintln!("error: PEIS {id}: {e}");
                            code = EXIT_NO_SOLUTION;
                        }
                        Err(e) => {
                            eprintln!("error: a PEIS host failed: {e}");
                            code = EXIT_NO_SOLUTION;
                        }
                    }
                }
            }
        }
        if let Some(agent) = agent
            && let Some(trouble) = agent.quit().await
        {
            eprintln!("warning: {trouble}");
        }
        Ok(code)
    })
}

/// The ROS 2 agent, when any chosen PEIS has a component that is a ROS 2 node.
async fn start_agent(chosen: &[PeisDef]) -> anyhow::Result<Option<ecology_ros2::Agent>> {
    let nodes: Vec<String> = chosen
        .iter()
        .flat_map(|def| {
            def.components.iter().filter_map(move |c| {
                Some(format!("{}:{} ({})", def.name, c.id, c.ros2.as_ref()?.node))
            })
        })
        .collect();
    if nodes.is_empty() {
        return Ok(None);
    }
    let python = ecology_ros2::default_python();
    let log: Arc<dyn Fn(String) + Send + Sync> = Arc::new(|line| eprintln!("ros2 agent: {line}"));
    let agent = ecology_ros2::Agent::start(&python, log).await?;
    say(&format!(
        "ROS 2 agent ready on {} ({python}): nodes {}",
        agent.rmw(),
        nodes.join(", ")
    ));
    Ok(Some(agent))
}

/// The PEIS of `defs` to run: those named, every one with `all`, or the only one.
fn choose(
    file: &std::path::Path,
    defs: &[PeisDef],
    names: &[String],
    all: bool,
) -> Result<Vec<PeisDef>, String> {
    let listed = || {
        let names: Vec<&str> = defs.iter().map(|d| d.name.as_str()).collect();
        names.join(", ")
    };
    if all {
        return Ok(defs.to_vec());
    }
    match (names, defs) {
        ([], [only]) => Ok(vec![only.clone()]),
        ([], _) => Err(format!(
            "{} describes {} PEIS ({}): choose one with --name, or run them all with --all",
            file.display(),
            defs.len(),
            listed()
        )),
        (names, _) => {
            let mut chosen = Vec::new();
            for name in names {
                let Some(def) = defs.iter().find(|d| &d.name == name) else {
                    return Err(format!(
                        "{} has no PEIS {name} (it has {})",
                        file.display(),
                        listed()
                    ));
                };
                if !chosen.iter().any(|c: &PeisDef| c.name == def.name) {
                    chosen.push(def.clone());
                }
            }
            Ok(chosen)
        }
    }
}

/// `ecology world SCENARIO`.
pub fn world(args: &WorldArgs) -> anyhow::Result<u8> {
    let scenario = match Scenario::load(&args.scenario) {
        Ok(scenario) => scenario,
        Err(e) => {
            eprintln!("error: {e}");
            return Ok(EXIT_BAD_INPUT);
        }
    };
    if args.step_ms == 0 || args.step_ms > 10_000 {
        eprintln!("error: --step-ms must be between 1 and 10000");
        return Ok(EXIT_BAD_INPUT);
    }
    let id = PeisId::new(WORLD)?;
    let seed = args.seed.unwrap_or(scenario.seed);
    network::runtime()?.block_on(async {
        let space = match network::join(id, &args.net).await {
            Ok(space) => space,
            Err(failure) => return Ok(join_failed(failure)),
        };
        let stop = network::stop_signal();
        let _reporter = network::report_on_sigusr1("world", None);
        // A thing whose place is uncertain lies where the seed draws it.
        let world = scenario.world_for(seed);
        let robots: Vec<&str> = world.robots.keys().map(String::as_str).collect();
        say(&format!(
            "world ready: {} rooms, robots {}, {} things, {} residents; {}",
            world.map.rooms.len(),
            robots.join(", "),
            world.things.len(),
            world.residents.len(),
            args.net.describe()
        ));
        let result = ecology_sim::run_world(
            &space,
            Arc::new(SystemClock),
            world,
            seed,
            Duration::from_millis(args.step_ms),
            async {
                stop.await;
            },
        )
        .await;
        space.close().await;
        match result {
            Ok(world) => {
                for (name, robot) in &world.robots {
                    let room = world
                        .map
                        .room_at(robot.pose.x, robot.pose.y)
                        .map_or("no room", |r| r.name.as_str());
                    say(&format!("world: {name} ends at {} in {room}", robot.pose));
                }
                Ok(EXIT_OK)
            }
            Err(e) => {
                eprintln!("error: world: {e}");
                Ok(EXIT_NO_SOLUTION)
            }
        }
    })
}

/// Reports a failure to join and returns the exit code.
pub fn join_failed(failure: JoinFailure) -> u8 {
    match failure {
        JoinFailure::NameTaken(id) => {
            eprintln!("error: a PEIS named {id} is already present in the ecology");
            EXIT_BAD_INPUT
        }
        JoinFailure::BadConfig(e) => {
            eprintln!("error: {e:#}");
            EXIT_BAD_INPUT
        }
        JoinFailure::Other(e) => {
            eprintln!("error: {e:#}");
            EXIT_NO_SOLUTION
        }
    }
}

/// The PEIS of `names` that `space` cannot use yet: not present, or present but not yet
/// answering for its tuples (its presence can arrive before a link that carries its answers).
pub async fn missing_peis<S: TupleSpace>(space: &S, names: &[PeisId]) -> Vec<PeisId> {
    let present = space.peers().await.unwrap_or_default();
    let mut missing = Vec::new();
    for name in names {
        let answers = present.contains(name)
            && space
                .get_matching(TuplePattern {
                    owner: OwnerPattern::Exact(name.clone()),
                    key: KeyPattern::any(),
                })
                .await
                .is_ok_and(|tuples| !tuples.is_empty());
        if !answers {
            missing.push(name.clone());
        }
    }
    missing
}
