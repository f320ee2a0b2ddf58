//! A simulated PEIS-Home for Ecology (the paper's Section VIII): a small,
//! deterministic kinematic world of rooms, doors, differential-drive robots,
//! things and residents; simulated components for every component type of
//! the reference ecology; scenario files; fault injection; and [`run`], which
//! runs a scenario's plan with the executive on the in-process tuple space in
//! virtual time.
//!
//! The world is a PEIS of its own (`world`): it publishes ground truth
//! (`map`, `robots.NAME.pose`, `things.NAME.holder`, `residents.NAME.state`:
//! the contract of [`ecology_tuples::world`]) and reads the robots' motor commands, grasps and sounds from component
//! outputs, so every sensor and actuator goes through the real middleware.

mod components;
mod conflicts;
pub mod generate;
mod host;
mod planning;
mod replan;
mod run;
mod scenario;
mod schedule;
mod world;
mod world_peis;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_conditional;

pub use components::{FaultState, Faults, KINDS, Simulated, match_scan, scan};
pub use ecology_core::Rng;
pub use ecology_tuples::world::WORLD;
pub use host::{host_peis, parse_fault, ros2_components, simulated_components};
pub use planning::{PlanError, executive_plan, plan_actions};
pub use replan::WorldReplanner;
pub use run::{Observer, Pace, Report, RunError, RunOptions, Update, run};
pub use scenario::{
    ComponentDef, EXECUTIVE, FaultKind, FaultSpec, PeisDef, Place, Scenario, ScenarioError,
    ScenarioTask, Trigger,
};
pub use schedule::with_random_faults;
pub use world::{
    Door, MAX_RANGE, MAX_SPEED, MAX_TURN, Map, Pose, REACH, Resident, Robot, Room, Thing, World,
    ray, route, wrap_angle,
};
pub use world_peis::{WorldPeis, run_world};
