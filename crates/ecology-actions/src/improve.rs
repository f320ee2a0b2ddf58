//! Making a found plan cheaper without searching again: greedy action
//! elimination (Fink and Yang; Nakhost and Müller). Greedy best-first
//! search often wanders (in the blocks world, a block picked up and put
//! down again); removing such detours keeps the plan valid and never makes
//! it costlier.

use crate::task::{OpId, State, Task};

/// Removes from `ops`, first to last, each action whose removal (together
/// with the later actions that no longer apply without it) still reaches
/// the goal from `initial`: the plan gets shorter and, costs being
/// non-negative, no costlier. `ops` must be a plan from `initial`; the
/// result is one too. Quadratic in the plan's length.
pub(crate) fn eliminate_actions(task: &Task, initial: &State, ops: &mut Vec<OpId>) {
    // The state before `ops[i]`.
    let mut before = initial.clone();
    let mut state = initial.clone();
    let mut kept: Vec<OpId> = Vec::with_capacity(ops.len());
    let mut i = 0;
    while i < ops.len() {
        state.words.copy_from_slice(&before.words);
        kept.clear();
        for &op in &ops[i + 1..] {
            if task.applicable(&state, op) {
                task.apply_in_place(&mut state, op);
                kept.push(op);
            }
        }
        if task.is_goal(&state) {
            ops.truncate(i);
            ops.extend_from_slice(&kept);
            // `ops[i]` is now another action: try again from the same state.
        } else {
            task.apply_in_place(&mut before, ops[i]);
            i += 1;
        }
    }
}
