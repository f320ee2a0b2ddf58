//! The sequencer: the plan, action by action. Starts an action, finishes it once its
//! configuration has done its part (taking the branch of what it observed), or fails it.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use ecology_config::{Configuration, Exclusion};
use ecology_tuples::Key;

use crate::log::LogEvent;
use crate::plan::{Observation, Plan, observations_text};

use super::deployment::components_of;
use super::timers::{Timer, start};
use super::{Command, ComponentKey, Executive, RunStatus};

/// Where the action's configuration stands.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) enum Phase {
    /// Waiting for the components of the new configuration to run.
    Deploying { pending: BTreeSet<ComponentKey> },
    /// Running; waiting for postconditions.
    Running,
}

/// The action being run: what it excludes and what failed, its configuration, and its timers.
#[derive(Debug)]
pub(super) struct ActionRun {
    pub(super) index: usize,
    pub(super) excluded: Vec<Exclusion>,
    pub(super) failed: BTreeSet<ComponentKey>,
    /// Components whose owner refused a request because other executives hold them: left out
    /// of this action's configurations until their holders change. Not failures.
    pub(super) held: BTreeSet<ComponentKey>,
    pub(super) config: Option<Configuration>,
    pub(super) phase: Phase,
    /// Whether [`Timer::Deploy`] runs. [`Timer::Action`] runs as long as the action does.
    pub(super) deploy_timer: bool,
    /// The components whose [`Timer::Waiting`] runs, or ran out while the ecology was lost.
    pub(super) waiting: BTreeSet<ComponentKey>,
    /// Components whose waiting was given longer, since nothing could stand in for them: once
    /// per spell of waiting (until they report another status).
    pub(super) waited_longer: BTreeSet<ComponentKey>,
    /// Components whose remote set got no answer, each timed by its [`Timer::Unanswered`]: the
    /// set's key (an answer to it, sent again, clears the component), and the failure's cause,
    /// should they be blamed when the timer runs out.
    pub(super) unanswered: BTreeMap<ComponentKey, (Key, String)>,
    pub(super) done: BTreeSet<ComponentKey>,
    /// Inputs to re-point once their new producer runs (make-before-break):
    /// the producer, and the remote set that wires its consumer.
    pub(super) deferred: Vec<(ComponentKey, Command)>,
    /// What the configuration reported of the atoms a sensing action reveals.
    pub(super) observed: BTreeMap<String, bool>,
}

impl ActionRun {
    /// Takes the timers of the configuration's components: their waiting grace periods and
    /// their remote sets that got no answer.
    pub(super) fn take_component_timers(&mut self) -> Vec<Timer> {
        let waiting = std::mem::take(&mut self.waiting).into_iter();
        let unanswered = std::mem::take(&mut self.unanswered).into_keys();
        waiting
            .map(Timer::Waiting)
            .chain(unanswered.map(Timer::Unanswered))
            .collect()
    }
}

impl Executive {
    /// Starts action `index` of the plan, or ends the task past the last one.
    pub(super) fn start_action(&mut self, index: usize, out: &mut Vec<Command>) {
        if index >= self.plan.len() && self.success <= ecology_core::EPSILON {
            // A conditional plan that gives up here: nothing the robots can
            // do reaches the goal from what was observed.
            let reason =
                "the plan gives up here: from what was observed, no action reaches the goal"
                    .to_string();
            self.status = RunStatus::Failed {
                index: index.saturating_sub(1),
                reason: reason.clone(),
            };
            self.run = None;
            self.release(out);
            self.record(LogEvent::TaskFailed { reason });
            return;
        }
        if index >= self.plan.len() {
            self.status = RunStatus::Done;
            self.run = None;
            self.release(out);
            self.record(LogEvent::TaskDone);
            return;
        }
        self.status = RunStatus::Running { index };
        let action = self.plan[index].action.clone();
        self.record(LogEvent::ActionStarted {
            index,
            action: action.clone(),
        });
        out.push(start(Timer::Action, self.config.action_timeout));
        self.run = Some(ActionRun {
            index,
            excluded: Vec::new(),
            failed: BTreeSet::new(),
            held: BTreeSet::new(),
            config: None,
            phase: Phase::Running,
            deploy_timer: false,
            waiting: BTreeSet::new(),
            waited_longer: BTreeSet::new(),
            unanswered: BTreeMap::new(),
            done: BTreeSet::new(),
            deferred: Vec::new(),
            observed: BTreeMap::new(),
        });
        if self.plan[index].goal.is_none() {
            if !self.plan[index].observe.is_empty() {
                // Nothing would be deployed to report what it observes.
                let reason = format!(
                    "it observes {} but has no configuration goal to observe with",
                    self.plan[index].observe.join(" ")
                );
                self.fail_action(reason, out);
                return;
            }
            self.finish_action(out);
            return;
        }
        self.configure(false, out);
    }

    /// Finishes the action once its configuration runs and has done its part.
    pub(super) fn check_done(&mut self, out: &mut Vec<Command>) {
        let Some(run) = &self.run else { return };
        if run.phase != Phase::Running {
            return;
        }
        let Some(config) = &run.config else { return };
        let finishing = components_of(config, |f| !f.postcondition.is_empty());
        // An action is done when every functionality with a postcondition
        // reports `done`; one whose configuration has none (it only provides
        // information) is done as soon as its configuration runs.
        let observed = self.plan[run.index]
            .observe
            .iter()
            .all(|atom| run.observed.contains_key(atom));
        if observed && finishing.iter().all(|k| run.done.contains(k)) {
            self.finish_action(out);
        }
    }

    /// The action is done: what it observed is kept, the branch that agrees with it taken when
    /// the plan branches here, and the next action started.
    fn finish_action(&mut self, out: &mut Vec<Command>) {
        let Some(run) = &self.run else { return };
        let index = run.index;
        let action = self.plan[index].action.clone();
        let observation: Vec<Observation> = self.plan[index]
            .observe
            .iter()
            .filter_map(|atom| {
                run.observed.get(atom).map(|&holds| Observation {
                    atom: atom.clone(),
                    holds,
                })
            })
            .collect();
        if !observation.is_empty() {
            for o in &observation {
                self.knowledge.insert(o.atom.clone(), o.holds);
            }
            self.record(LogEvent::Observed {
                index,
                action: action.clone(),
                observation: observations_text(&observation),
            });
        }
        let branch = if index + 1 == self.plan.len() && !self.branches.is_empty() {
            let Some(chosen) = self.branches.iter().position(|b| {
                b.observation
                    .iter()
                    .all(|o| self.knowledge.get(&o.atom) == Some(&o.holds))
            }) else {
                let reason = format!(
                    "it observed {}, which no branch of the plan expects",
                    observations_text(&self.observations())
                );
                self.fail_action(reason, out);
                return;
            };
            Some(std::mem::take(&mut self.branches).swap_remove(chosen))
        } else {
            None
        };
        let Some(mut run) = self.run.take() else {
            return;
        };
        out.push(Command::CancelTimer(Timer::Action));
        out.extend(
            run.take_component_timers()
                .into_iter()
                .map(Command::CancelTimer),
        );
        // Inputs still waiting for their producer are wired all the same:
        // the next action may keep them.
        out.extend(run.deferred.into_iter().map(|(_, wire)| wire));
        self.record(LogEvent::ActionDone { index, action });
        if let Some(branch) = branch {
            self.record(LogEvent::Branch {
                observation: observations_text(&branch.observation),
                probability: branch.probability,
                actions: branch.plan.steps.iter().map(|a| a.action.clone()).collect(),
            });
            self.continue_with(Arc::unwrap_or_clone(branch.plan));
        }
        self.start_action(index + 1, out);
    }

    /// Goes on with `plan` after the actions of the path so far.
    pub(super) fn continue_with(&mut self, plan: Plan) {
        self.plan.extend(plan.steps);
        self.branches = plan.branches;
        self.success = plan.success;
    }

    /// The observations the pending branches expect, for the log.
    pub(super) fn branch_observations(&self) -> Vec<String> {
        self.branches
            .iter()
            .map(|b| observations_text(&b.observation))
            .collect()
    }

    /// The action fails with `reason`; what follows is the caller's ([`Executive::replan`] or
    /// [`Executive::abandon`]).
    pub(super) fn fail_action(&mut self, reason: String, out: &mut Vec<Command>) {
        self.stop_awaiting(out);
        let Some(mut run) = self.run.take() else {
            return;
        };
        out.push(Command::CancelTimer(Timer::Action));
        if run.deploy_timer {
            out.push(Command::CancelTimer(Timer::Deploy));
        }
        out.extend(
            run.take_component_timers()
                .into_iter()
                .map(Command::CancelTimer),
        );
        self.failed_actions
            .push(self.plan[run.index].action.clone());
        self.record(LogEvent::ActionFailed {
            index: run.index,
            action: self.plan[run.index].action.clone(),
            reason: reason.clone(),
        });
        self.status = RunStatus::Failed {
            index: run.index,
            reason,
        };
    }
}
