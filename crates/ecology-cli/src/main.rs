//! The `ecology` command-line tool.
//!
//! Exit codes, for every subcommand:
//! - 0: success;
//! - 1: no solution (no configuration, no plan) or the task failed;
//! - 2: bad input or usage, with `file:line:col` diagnostics on stderr.

/// mimalloc: the planners allocate many small, short-lived vectors, and
/// glibc's allocator took a third of a small configuration's time.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

mod configure;
mod demo;
mod generate;
mod input;
mod keys;
mod network;
mod peis;
mod plan;
mod plan_conditional;
mod processes;
mod progress;
mod router;
mod sweep;
mod task;
mod tuples;
mod view;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Exit code: success.
pub const EXIT_OK: u8 = 0;
/// Exit code: no solution, or the task failed.
pub const EXIT_NO_SOLUTION: u8 = 1;
/// Exit code: bad input or usage.
pub const EXIT_BAD_INPUT: u8 = 2;
/// Exit code of `ecology tuples`: the tuple or PEIS was not found, or the owner refused (the
/// code of "no solution").
pub const EXIT_NOT_FOUND: u8 = EXIT_NO_SOLUTION;
/// When this environment variable is set, `ecology` only checks its arguments, then exits 0.
const PARSE_ONLY: &str = "ECOLOGY_PARSE_ONLY";

/// Ecology: self-configuration of an ecology of robots.
#[derive(Debug, Parser)]
#[command(name = "ecology", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Validate domain (.eco) and state (.facts) files, reporting every problem in them.
    Check(configure::CheckArgs),
    /// Find the cheapest admissible configuration for a goal.
    Configure(configure::ConfigureArgs),
    /// Watch, get and set tuples of a live ecology over Zenoh.
    Tuples(tuples::TuplesArgs),
    /// Plan actions for a problem: a plan whose actions each carry their configuration goal.
    Plan(plan::PlanArgs),
    /// Run the paper's experiment (Section VIII) in the simulated PEIS-Home.
    Demo(demo::RunArgs),
    /// Run a scenario file (TOML) in the simulated PEIS-Home.
    Run(demo::ScenarioArgs),
    /// Run one PEIS of a TOML file as a process on Zenoh: its init component, components and presence.
    Peis(peis::PeisArgs),
    /// Run the simulated world of a scenario as a PEIS process on Zenoh, in real time.
    World(peis::WorldArgs),
    /// Plan a task and execute it over Zenoh with whatever PEIS are present (the executive).
    Task(task::TaskArgs),
    /// Run a Zenoh router, for PEIS that cannot reach each other directly.
    Router(router::RouterArgs),
    /// Run a scenario under many random fault schedules and tabulate how the runs end.
    Sweep(sweep::SweepArgs),
    /// Create an ecology's keys: its certificate authority, members' certificates, the roster.
    Keys(keys::KeysArgs),
    /// Generate large ecologies to run: `generate home --peis N` writes a scenario file.
    Generate(generate::GenerateArgs),
    /// Serve a live web view of an ecology over Zenoh: PEIS, components, plan, configuration, tuples.
    View(view::ViewArgs),
}

/// Turns transparent huge pages off for this process, for the commands that run an ecology
/// (a PEIS, the world, a router, the executive, a simulation). mimalloc asks the kernel for
/// huge pages; a process that keeps many small tuples and states for its whole life then holds
/// a third more memory (`ecology run` on a home of 1,000 PEIS: 68 MB at its peak against 51 MB
/// without), and on a kernel that compacts memory to find a huge page when one is first touched
/// (`defrag` set to `madvise`, a common default) the executive's first state took 12 ms to build
/// instead of 1.5 ms in a process started after a pause. The one-shot planning commands keep
/// huge pages: the configuration planner's benchmark instances planned 2–7% faster with them.
/// Best effort: a kernel without the setting leaves things as they were.
fn without_huge_pages() {
    #[cfg(target_os = "linux")]
    let _ = nix::sys::prctl::set_thp_disable(true);
}

#[allow(unsafe_code)]
fn main() -> ExitCode {
    // SAFETY: first thing in the process: no other thread runs yet.
    unsafe { ecology_zenoh::set_runtime_threads() };
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(err) => {
            let code = if err.use_stderr() {
                EXIT_BAD_INPUT
            } else {
                EXIT_OK
            };
            let _ = err.print();
            return ExitCode::from(code);
        }
    };
    // For documentation tests: a command line that would start a long-running process (a PEIS,
    // a router, a real-time run) is checked for valid arguments only.
    if std::env::var_os(PARSE_ONLY).is_some() {
        println!("{PARSE_ONLY}: the arguments are valid");
        return ExitCode::from(EXIT_OK);
    }
    // One-shot commands, whose output may go to a pipe; the others run an ecology.
    let one_shot = matches!(
        cli.command,
        Command::Check(_)
            | Command::Configure(_)
            | Command::Plan(_)
            | Command::Generate(_)
            | Command::Keys(_)
    );
    let in_process = matches!(
        cli.command,
        Command::Demo(_) | Command::Run(_) | Command::Sweep(_)
    );
    if one_shot {
        stop_quietly_on_a_closed_pipe();
    } else {
        without_huge_pages();
    }
    let result = match cli.command {
        Command::Check(args) => configure::check(&args),
        Command::Configure(args) => configure::configure(&args),
        Command::Tuples(args) => tuples::run(args),
        Command::Plan(args) => plan::plan(&args),
        Command::Demo(args) => demo::demo(&args),
        Command::Run(args) => demo::run(&args),
        Command::Peis(args) => peis::peis(&args),
        Command::World(args) => peis::world(&args),
        Command::Task(args) => task::task(&args),
        Command::Router(args) => router::router(&args),
        Command::Sweep(args) => sweep::sweep(&args),
        Command::Keys(args) => keys::keys(&args),
        Command::View(args) => view::view(&args),
        Command::Generate(args) => generate::generate(&args),
    };
    let code = match result {
        Ok(code) => code,
        Err(err) => {
            eprintln!("error: {err:#}");
            EXIT_BAD_INPUT
        }
    };
    if in_process {
        exit_at_once(code);
    }
    ExitCode::from(code)
}

/// Ends the process with `code` once what it wrote is out, without giving back the memory of a
/// simulation it has finished with: the allocator's return of every page to the kernel at exit
/// (one `madvise` per range) took a tenth of a second after a run of 10,000 PEIS, and the kernel
/// takes the pages back with the process anyway. Only for the commands that run everything in
/// this process, after they have stopped every task and closed every file they opened.
#[allow(unsafe_code)]
fn exit_at_once(code: u8) -> ! {
    use std::io::Write;
    let _ = std::io::stdout().flush();
    let _ = std::io::stderr().flush();
    // SAFETY: `_exit` ends the process; nothing runs after it, and nothing of this process's
    // state needs an exit handler (no socket, child or temporary file is left to clean up).
    unsafe { libc::_exit(i32::from(code)) }
}

/// Lets a command that only reads files and prints end as other Unix tools
/// do when its reader goes away (`ecology plan … | head`): killed by
/// SIGPIPE, silently, instead of a panic at the next `println!`. Only for
/// commands without sockets: Rust ignores SIGPIPE so that a write to a
/// closed socket is an error the networking code handles.
#[allow(unsafe_code)]
fn stop_quietly_on_a_closed_pipe() {
    use nix::sys::signal::{SigHandler, Signal, signal};
    // SAFETY: no other thread runs yet, and the default action installs no
    // handler code.
    let _ = unsafe { signal(Signal::SIGPIPE, SigHandler::SigDfl) };
}
