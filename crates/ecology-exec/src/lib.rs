//! The executive of Ecology (the paper's Sections IV, VI and VII): it acquires
//! the ecology state from tuples, configures each action of a plan with the
//! configuration planner, deploys the configuration, monitors it, and
//! reconfigures when a component or a PEIS fails.
//!
//! [`Executive`] is sans-IO: an event loop `handle(now, Event) -> Vec<Command>`
//! over a closed [`Event`] type. A driver connects it to a tuple space:
//! subscription changes and presence in, remote sets and timers out.

mod driver;
mod executive;
mod interest;
mod log;
mod mirror;
mod plan;
mod plan_file;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_conditional;

pub use driver::{Acquisition, Controls, DriverConfig, Replan, drive, drive_observed, drive_until};
pub use executive::{Command, Event, ExecConfig, Executive, RunStatus, Timer};
pub use interest::{Intake, Interest};
pub use log::{LogChannel, LogComponent, LogEntry, LogEvent, LogFunctionality, LogUnavailable};
pub use mirror::{Change, Changes, ComponentView, Mirror, PeisView};
pub use plan::{
    Observation, Plan, PlanBranch, PlannedAction, observations_text, parse_observations,
};
pub use plan_file::{PlanFileError, parse_plan};
