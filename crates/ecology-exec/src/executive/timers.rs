//! The executive's timers: [`Timer`], what each one times, and [`Executive::on_timer`], where
//! each one that runs out is acted on.

use std::time::Duration;

use super::{Command, ComponentKey, Executive};

/// A timer the executive asks for, named by what it times.
///
/// A value names what is timed, not one start of it, so a driver keeps one deadline per `Timer`:
/// [`Command::StartTimer`] of a timer that runs replaces its deadline, and
/// [`Command::CancelTimer`] removes it. A timer therefore fires only for its latest start, and
/// never once cancelled: no firing is stale. The executive acts on
/// [`Event::Timer`](crate::Event::Timer) only while its own state has that timer running (an event
/// handed to it directly may be any), and ignores it otherwise.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Timer {
    /// The action's time runs out
    /// ([`ExecConfig::action_timeout`](crate::ExecConfig::action_timeout)).
    Action,
    /// The components of the new configuration had their time to report `running`
    /// ([`ExecConfig::deploy_timeout`](crate::ExecConfig::deploy_timeout)).
    Deploy,
    /// The component reports `waiting` for longer than
    /// [`ExecConfig::waiting_grace`](crate::ExecConfig::waiting_grace) (or, when nothing can stand
    /// in for it, [`ExecConfig::return_wait`](crate::ExecConfig::return_wait) more).
    Waiting(ComponentKey),
    /// A remote set to the component got no answer for
    /// [`ExecConfig::unanswered_grace`](crate::ExecConfig::unanswered_grace).
    Unanswered(ComponentKey),
    /// The window of departures closes
    /// ([`ExecConfig::loss_window`](crate::ExecConfig::loss_window)): they are judged.
    LossWindow,
    /// The lost ecology did not come back in time
    /// ([`ExecConfig::reconnect_timeout`](crate::ExecConfig::reconnect_timeout)).
    Reconnect,
    /// A loss window after the latest return of a PEIS of the lost ecology.
    LostSettle,
    /// The PEIS an action without a configuration waits for did not return in time
    /// ([`ExecConfig::return_wait`](crate::ExecConfig::return_wait)).
    ReturnWait,
    /// A loss window after the latest return of a PEIS the action waits for.
    ReturnSettle,
}

/// Starts `timer`, to fire `after` from now (instead of when it was to, if it runs already).
pub(super) fn start(timer: Timer, after: Duration) -> Command {
    Command::StartTimer { timer, after }
}

impl Executive {
    /// A timer ran out: what it timed is acted on, if it still runs in the executive's state.
    pub(super) fn on_timer(&mut self, timer: Timer, out: &mut Vec<Command>) {
        let lost_own = matches!(
            timer,
            Timer::LossWindow | Timer::Reconnect | Timer::LostSettle
        );
        if self.lost.is_some() && !lost_own {
            // While lost, only its own timers count: whatever else ran out timed the network.
            return;
        }
        match timer {
            Timer::LossWindow => self.judge_departures(out),
            Timer::Reconnect => self.give_up(out),
            Timer::LostSettle => {
                if self.lost.as_ref().is_some_and(|lost| lost.settle) {
                    self.try_resume(out);
                }
            }
            Timer::ReturnSettle => {
                if self.awaited.as_ref().is_some_and(|a| a.settle) {
                    self.settle_returns(out);
                }
            }
            Timer::ReturnWait => self.return_wait_over(out),
            Timer::Action => {
                if self.run.is_some() {
                    let reason = format!(
                        "the action did not finish within {:?}",
                        self.config.action_timeout
                    );
                    self.fail_action(reason, out);
                }
            }
            Timer::Deploy => self.deploy_timed_out(out),
            Timer::Unanswered(key) => self.unanswered_over(key, out),
            Timer::Waiting(key) => self.waiting_over(key, out),
        }
    }

    /// Stops timing the components of the action: its deploy timeout, waiting grace periods and
    /// unanswered remote sets.
    pub(super) fn stop_component_timers(&mut self, out: &mut Vec<Command>) {
        let Some(run) = &mut self.run else { return };
        if std::mem::take(&mut run.deploy_timer) {
            out.push(Command::CancelTimer(Timer::Deploy));
        }
        out.extend(
            run.take_component_timers()
                .into_iter()
                .map(Command::CancelTimer),
        );
    }
}
