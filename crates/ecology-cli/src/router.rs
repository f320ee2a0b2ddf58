//! `ecology router`: a Zenoh router for PEIS that cannot reach each other
//! directly. Each PEIS then connects to it (`--connect tcp/ROUTER:7447`).

use std::io::Write;

use clap::Args;
use ecology_tuples::PeisId;
use ecology_zenoh::RouterOptions;

use crate::network::{self, NetArgs};
use crate::{EXIT_NO_SOLUTION, EXIT_OK};

/// Arguments of `ecology router`.
#[derive(Debug, Args)]
pub struct RouterArgs {
    /// The router's name in the roster, with --keys (a member with the router role).
    #[arg(long, default_value = "router", value_name = "NAME")]
    pub name: String,
    /// How many sessions (PEIS, other routers) it holds at once; past that, a PEIS that connects
    /// is refused until one leaves.
    #[arg(long, value_name = "N", default_value_t = ecology_zenoh::DEFAULT_MAX_SESSIONS as u32,
          value_parser = clap::value_parser!(u32).range(1..))]
    pub max_sessions: u32,
    /// Do not hold the component contract of every PEIS: every query that covers all PEIS is
    /// then answered by each of them, as it was before routers held it.
    #[arg(long)]
    pub no_contract_cache: bool,
    #[command(flatten)]
    pub net: NetArgs,
}

/// `ecology router --listen tcp/0.0.0.0:7447`.
pub fn router(args: &RouterArgs) -> anyhow::Result<u8> {
    if args.net.listen.is_empty() {
        eprintln!("error: a router needs --listen ENDPOINT, such as tcp/0.0.0.0:7447");
        return Ok(crate::EXIT_BAD_INPUT);
    }
    let mut options = RouterOptions {
        listen: args.net.listen.clone(),
        connect: args.net.connect.clone(),
        multicast_scouting: args.net.multicast,
        zenoh_config: args.net.zenoh_config.clone(),
        max_sessions: args.max_sessions as usize,
        hold_contract: !args.no_contract_cache,
        ..RouterOptions::default()
    };
    if let Some(lease) = args.net.lease {
        options.lease = network::seconds(lease, "--lease")?;
    }
    let name = match PeisId::new(&args.name) {
        Ok(name) => name,
        Err(e) => {
            eprintln!("error: {e}");
            return Ok(crate::EXIT_BAD_INPUT);
        }
    };
    options.security = args.net.security(&name)?;
    let describe = args.net.describe();
    let close_within = options.close_within;
    network::runtime()?.block_on(async {
        let stop = network::stop_signal();
        let _reporter = network::report_on_sigusr1("router", None);
        let result = ecology_zenoh::run_router(
            options,
            |zid| {
                let mut out = std::io::stdout().lock();
                let _ = writeln!(out, "router ready: zenoh id {zid}; {describe}");
                let _ = out.flush();
            },
            |max| {
                eprintln!(
                    "warning: the router holds {max} sessions, the most it takes (--max-sessions): \
                     a PEIS that connects now is refused until one leaves"
                );
            },
            async {
                let which = stop.await;
                println!("router: {which}: closing");
            },
        )
        .await;
        match result {
            Ok(ecology_zenoh::Closed::Cleanly) => Ok(EXIT_OK),
            Ok(ecology_zenoh::Closed::CutShort) => {
                println!(
                    "router: its sessions were still closing after {:.1} s (many PEIS leaving at \
                     once); stopped without waiting for them",
                    close_within.as_secs_f64()
                );
                Ok(EXIT_OK)
            }
            Err(e) => {
                eprintln!("error: {e}");
                Ok(EXIT_NO_SOLUTION)
            }
        }
    })
}
