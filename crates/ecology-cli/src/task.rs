//! `ecology task`: the executive as a process of its own. It plans the task
//! (or reads a plan), waits for the PEIS it is told to expect, and runs the
//! plan over Zenoh against whatever PEIS are present, printing the same
//! timeline (or JSON lines) as `ecology demo`. It also publishes every log
//! entry as its tuple `log` (JSON), so any PEIS can follow the task.

use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use clap::Args;
use ecology_domain::EcologyState;
use ecology_exec::{
    Controls, DriverConfig, ExecConfig, Executive, Plan, Replan, RunStatus, drive_until,
};
use ecology_sim::WorldReplanner;
use ecology_tuples::{Key, PeisId, SystemClock, TupleSpace, Value};

use crate::demo::Acquire;
use crate::input;
use crate::network::{self, NetArgs, seconds, seconds_or_zero};
use crate::peis::{join_failed, missing_peis};
use crate::{EXIT_BAD_INPUT, EXIT_NO_SOLUTION, EXIT_OK};
use ecology_config::WallClock;

/// Arguments of `ecology task`.
#[derive(Debug, Args)]
pub struct TaskArgs {
    /// The domain file (.eco): functionalities, methods and actions.
    #[arg(long)]
    pub domain: PathBuf,
    /// A problem file to plan for with the action planner.
    #[arg(long, conflicts_with = "plan", required_unless_present = "plan")]
    pub problem: Option<PathBuf>,
    /// A plan file to execute, as `ecology plan` prints it: `(action …)  ; configure (goal …)` a line.
    #[arg(long)]
    pub plan: Option<PathBuf>,
    /// Print the executive's event log as JSON lines instead of the timeline.
    #[arg(long)]
    pub json: bool,
    /// The executive's own PEIS name.
    #[arg(long, value_name = "PEIS", default_value = "executive")]
    pub name: String,
    /// Wait until these PEIS are present before starting (comma-separated or repeated).
    #[arg(long, value_name = "PEIS", value_delimiter = ',')]
    pub wait_for: Vec<String>,
    /// How long to wait for them, in seconds.
    #[arg(long, value_name = "SECONDS", default_value_t = 30.0)]
    pub wait_timeout: f64,
    /// How long every component of a configuration has to report running, in seconds.
    #[arg(long, value_name = "SECONDS", default_value_t = 10.0)]
    pub deploy_timeout: f64,
    /// How long a component may report waiting before it counts as failed, in seconds.
    #[arg(long, value_name = "SECONDS", default_value_t = 2.0)]
    pub waiting_grace: f64,
    /// How long one action may take, in seconds.
    #[arg(long, value_name = "SECONDS", default_value_t = 600.0)]
    pub action_timeout: f64,
    /// How long to wait for the ecology when most of it left at once (the executive lost its
    /// network or its router), in seconds; then the task fails.
    #[arg(long, value_name = "SECONDS", default_value_t = 30.0)]
    pub reconnect_timeout: f64,
    /// PEIS that leave within this many seconds of each other are judged together: when at least
    /// two, and more than half of those present, left, the executive lost the ecology and waits
    /// for it instead of blaming them.
    #[arg(long, value_name = "SECONDS", default_value_t = 1.0)]
    pub loss_window: f64,
    /// How long a remote set that got no answer waits before its component is blamed, in
    /// seconds: the PEIS's departure, or the loss of the ecology, shows first within the PEIS's
    /// lease and the loss window (raise it with longer leases).
    #[arg(long, value_name = "SECONDS", default_value_t = 3.0)]
    pub unanswered_grace: f64,
    /// How long an action left without a configuration by PEIS that left waits for them to
    /// return, in seconds, before it fails (a robot on a poor link is back shortly); also how much
    /// longer than the waiting grace a `waiting` component that no configuration can do without
    /// is given. 0 fails at once.
    #[arg(long, value_name = "SECONDS", default_value_t = 5.0)]
    pub return_wait: f64,
    /// How long to take in the ecology's tuples before the first action, in seconds.
    #[arg(long, value_name = "SECONDS", default_value_t = 0.5)]
    pub settle: f64,
    /// What of the ecology the executive reads: what the plan's goals can use, or every tuple.
    #[arg(long, value_enum, default_value_t = Acquire::OnDemand)]
    pub acquire: Acquire,
    /// Report on stderr at the end: state acquisition, planning per
    /// configuration, tuples and bytes taken in, peak memory.
    #[arg(long)]
    pub timings: bool,
    #[command(flatten)]
    pub net: NetArgs,
}

/// `ecology task …`
pub fn task(args: &TaskArgs) -> anyhow::Result<u8> {
    let Ok(domain) = input::domain(&args.domain)? else {
        return Ok(EXIT_BAD_INPUT);
    };
    let mut replanner = None;
    let plan = match (&args.problem, &args.plan) {
        (Some(path), _) => {
            let Ok(problem) = input::problem(path, &domain)? else {
                return Ok(EXIT_BAD_INPUT);
            };
            match ecology_sim::plan_actions(&domain, &problem) {
                Ok(plan) => {
                    // A failed action is planned around from the world as observed.
                    replanner = Some(WorldReplanner::new(domain.clone(), problem));
                    plan
                }
                Err(e) => {
                    eprintln!("error: {}: {e}", path.display());
                    return Ok(EXIT_NO_SOLUTION);
                }
            }
        }
        (None, Some(path)) => {
            let text = String::from_utf8(input::read_limited(path)?)
                .map_err(|_| anyhow::anyhow!("{} is not UTF-8", path.display()))?;
            match ecology_exec::parse_plan(&text) {
                Ok(plan) => plan,
                Err(e) => {
                    eprintln!("error: {}:{}: {}", path.display(), e.line, e.message);
                    return Ok(EXIT_BAD_INPUT);
                }
            }
        }
        (None, None) => {
            eprintln!("error: give the task as --problem FILE or --plan FILE");
            return Ok(EXIT_BAD_INPUT);
        }
    };
    let config = ExecConfig {
        deploy_timeout: seconds(args.deploy_timeout, "--deploy-timeout")?,
        waiting_grace: seconds(args.waiting_grace, "--waiting-grace")?,
        action_timeout: seconds(args.action_timeout, "--action-timeout")?,
        reconnect_timeout: seconds(args.reconnect_timeout, "--reconnect-timeout")?,
        loss_window: seconds(args.loss_window, "--loss-window")?,
        unanswered_grace: seconds(args.unanswered_grace, "--unanswered-grace")?,
        return_wait: seconds_or_zero(args.return_wait, "--return-wait")?,
        ..ExecConfig::default()
    };
    let settle = seconds_or_zero(args.settle, "--settle")?;
    let wait_timeout = seconds(args.wait_timeout, "--wait-timeout")?;
    let me = PeisId::new(&args.name).map_err(|e| anyhow::anyhow!("--name: {e}"))?;
    let mut expected = Vec::new();
    for name in &args.wait_for {
        expected.push(PeisId::new(name).map_err(|e| anyhow::anyhow!("--wait-for: {e}"))?);
    }
    network::runtime()?.block_on(async {
        let space = match network::join(me, &args.net).await {
            Ok(space) => space,
            Err(failure) => return Ok(join_failed(failure)),
        };
        let task = Task {
            domain: &domain,
            plan,
            config,
            settle,
            replanner,
            acquisition: args.acquire.into(),
            timings: args.timings,
        };
        let code = execute(&space, task, &expected, wait_timeout, args.json).await;
        network::stopping("leaving the ecology");
        space.close().await;
        code
    })
}

/// What the executive runs.
struct Task<'a> {
    domain: &'a ecology_domain::Domain,
    plan: Plan,
    config: ExecConfig,
    settle: Duration,
    replanner: Option<WorldReplanner>,
    acquisition: ecology_exec::Acquisition,
    /// Report the executive's timings on stderr at the end.
    timings: bool,
}

async fn execute(
    space: &ecology_zenoh::ZenohPeis,
    task: Task<'_>,
    expected: &[PeisId],
    wait_timeout: Duration,
    json: bool,
) -> anyhow::Result<u8> {
    let Task {
        domain,
        plan,
        config,
        settle,
        mut replanner,
        acquisition,
        timings,
    } = task;
    // One listener for the whole run: no SIGINT is lost between two waits.
    let stop = network::stop_signal();
    tokio::pin!(stop);
    // SIGUSR1 asks where the process stands: the driver adds the executive's part.
    let asked = Arc::new(tokio::sync::Notify::new());
    let _reporter = network::report_on_sigusr1("task", Some(asked.clone()));
    // Which routers hold the contract, followed from now on: the first questions of the task
    // then go out without asking it.
    space.follow_holders().await;
    // Wait for the PEIS the task needs, saying which are missing.
    let waited = Instant::now();
    let mut told = false;
    loop {
        let missing = missing_peis(space, expected).await;
        if missing.is_empty() {
            break;
        }
        let names: Vec<String> = missing.iter().map(ToString::to_string).collect();
        if waited.elapsed() >= wait_timeout {
            eprintln!(
                "error: PEIS {} not present after {:.0} s",
                names.join(", "),
                wait_timeout.as_secs_f64()
            );
            return Ok(EXIT_NO_SOLUTION);
        }
        if !told {
            eprintln!("waiting for PEIS {} …", names.join(", "));
            told = true;
        }
        tokio::select! {
            () = tokio::time::sleep(Duration::from_millis(100)) => {}
            which = &mut stop => {
                eprintln!("{which}: stopped before the task started");
                return Ok(EXIT_NO_SOLUTION);
            }
        }
    }

    let mut exec = Executive::new(domain.clone(), EcologyState::new(), plan, config)
        .with_stopwatch(Box::new(WallClock(Instant::now())));
    // The log also goes out as the tuple `log`; one owned task publishes it in order.
    let (log_tx, mut log_rx) = tokio::sync::mpsc::unbounded_channel::<String>();
    let publisher = {
        let space = space.clone();
        tokio::spawn(async move {
            let Ok(key) = Key::new("log") else { return };
            while let Some(line) = log_rx.recv().await {
                // The timeline on stdout is the record; a lost tuple only costs followers one entry.
                let _ = space.set(key.clone(), Value::text(line)).await;
            }
        })
    };
    let driver = DriverConfig {
        settle,
        limit: None,
        acquisition,
    };
    let status = drive_until(
        space,
        Arc::new(SystemClock),
        &mut exec,
        driver,
        |entry| {
            let line = ecology_view::log_json::json_line(entry, None);
            let mut out = std::io::stdout().lock();
            let _ = if json {
                writeln!(out, "{line}")
            } else {
                writeln!(out, "{entry}")
            };
            let _ = out.flush();
            let _ = log_tx.send(line);
        },
        async {
            let which = (&mut stop).await;
            eprintln!("{which}: stopping the task and switching off what it switched on");
            network::stopping("switching off what the task switched on");
        },
        Controls {
            replan: replanner.as_mut().map(|r| r as &mut dyn Replan),
            report: Some(&asked),
        },
    )
    .await;
    drop(log_tx);
    let _ = publisher.await;
    if timings {
        eprint!("{}", crate::demo::timings(exec.log(), exec.intake()));
    }
    match status? {
        RunStatus::Done => Ok(EXIT_OK),
        RunStatus::Failed { reason, .. } => {
            eprintln!("task failed: {}", reason.lines().next().unwrap_or(""));
            Ok(EXIT_NO_SOLUTION)
        }
        RunStatus::Idle | RunStatus::Running { .. } => {
            eprintln!("error: the ecology's tuple space closed before the task ended");
            Ok(EXIT_NO_SOLUTION)
        }
    }
}
